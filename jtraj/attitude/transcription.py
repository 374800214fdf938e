"""The sparse NLP of an attitude benchmark in a formulation, and its decoded solution.

Multiple shooting with one RK4 step per interval (`jtraj.attitude.models.rk4`); per knot the
variables are ``z_k = [x_k, u_k]`` (`jtraj.nlp.Layout` slots ``x`` and ``u``); ``u`` at the last
knot is unused and fixed. The initial state, the non-attitude part of the goal state, input
limits and the floor are variable bounds; everything else is a `jtraj.nlp.ConstraintGroup`
written for one knot: the dynamics defects, attitude targets and the attitude cost as the
formulation (`jtraj.attitude.formulations`) defines them, unit-norm rows where it asks for
them, and the satellite's keep-out cone (eq. 43).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np

from jtraj import quaternion as quat
from jtraj.attitude import models as M
from jtraj.attitude.benchmarks import Benchmark, KeepOut
from jtraj.attitude.formulations import AbstractFormulation
from jtraj.nlp import ConstraintGroup, CostGroup, Dep, KnotNLP, Layout

__all__ = ["build_nlp", "dynamics_group", "target_group", "unit_norm_group", "keep_out_group", "stage_cost", "warm_start", "StateTrajectory", "decode"]


@dataclasses.dataclass(frozen=True)
class StateTrajectory:
    """A rigid-body solution: ``t`` (N,) knot times (s), ``X`` (N, nx) states, ``U`` (N - 1,
    nu) inputs (the last knot's input is not part of the motion)."""

    t: np.ndarray
    X: np.ndarray
    U: np.ndarray

    def plot_result(self, result: Any, path: str | Path | None = None, **kwargs: Any) -> Any:
        """`jtraj.attitude.benchmarks.plot_benchmark` (what `jtraj.result.Result.plot` calls)."""
        from jtraj.attitude.benchmarks import plot_benchmark

        return plot_benchmark(result, path, **kwargs)


def warm_start(bench: Benchmark, nlp: KnotNLP) -> np.ndarray:
    """The benchmark's guess ``[x_init, u_init]`` per knot, flattened and clipped into the bounds."""
    z0 = np.concatenate([bench.x_init, bench.u_init], axis=1).reshape(-1)
    return np.clip(z0, nlp.x_lower, nlp.x_upper)


def decode(bench: Benchmark, z: np.ndarray) -> StateTrajectory:
    """The flat NLP vector (N * (nx + nu),) as a `StateTrajectory`."""
    Z = np.asarray(z).reshape(bench.n_knots, -1)
    nx = bench.model.nx
    return StateTrajectory(t=bench.t, X=Z[:, :nx], U=Z[:-1, nx:])


def _equalities(name: str, deps: tuple[Dep, ...], fn: Any, knots: np.ndarray, rows: int, data: Any = None) -> ConstraintGroup:
    """``fn(theta, data_k, *deps_k) = 0`` (``rows`` rows) at every knot of ``knots`` (the
    benchmarks' numbers are constants: theta is None)."""
    K = knots.size
    return ConstraintGroup(name=name, deps=deps, fn=fn, knots=knots, lower=np.zeros((K, rows)), upper=np.zeros((K, rows)), active=np.ones((K, rows), bool), data=data)


def dynamics_group(bench: Benchmark, fm: AbstractFormulation) -> ConstraintGroup:
    """The formulation's defect between knot k + 1 and the RK4 step from knot k (k < N - 1)."""
    dynamics = bench.model.dynamics

    def defect(theta, h, x, u, x_next):
        return fm.defect(x_next, M.rk4(dynamics, x, u, h))

    K = bench.n_knots - 1
    return _equalities("dynamics", (Dep("x"), Dep("u"), Dep("x", 1)), defect, np.arange(K), fm.defect_dim(bench.model.nx), jnp.full((K,), bench.h))


def target_group(bench: Benchmark, fm: AbstractFormulation) -> ConstraintGroup:
    """The attitude targets in the formulation's error (``target_dim`` rows each)."""
    knots = np.array([t.knot for t in bench.targets])
    q_refs = jnp.asarray(np.array([t.q for t in bench.targets]))
    return _equalities("attitude_target", (Dep("x"),), lambda theta, q_ref, x: fm.attitude_error(x[M.QUAT], q_ref), knots, fm.target_dim, q_refs)


def unit_norm_group(bench: Benchmark) -> ConstraintGroup:
    """``|q_k|^2 = 1`` at every knot after the first (whose state is fixed)."""
    return _equalities("unit_norm", (Dep("x"),), lambda theta, data, x: jnp.atleast_1d(x[M.QUAT] @ x[M.QUAT] - 1.0), np.arange(1, bench.n_knots), 1)


def keep_out_group(ko: KeepOut) -> ConstraintGroup:
    """Eq. 43: ``sun_world . A(q) camera_body <= cos(angle)`` at the keep-out knots."""
    knots = np.asarray(ko.knots)
    cam, sun = jnp.asarray(ko.camera_body), jnp.asarray(ko.sun_world)
    return ConstraintGroup(
        name="keep_out",
        deps=(Dep("x"),),
        fn=lambda theta, data, x: jnp.atleast_1d(sun @ quat.rotate(x[M.QUAT], cam)),
        knots=knots,
        lower=np.full((knots.size, 1), -np.inf),
        upper=np.full((knots.size, 1), math.cos(math.radians(ko.angle_deg))),
        active=np.ones((knots.size, 1), bool),
    )


def stage_cost(bench: Benchmark, fm: AbstractFormulation) -> CostGroup:
    """The benchmark's tracking cost (see `Benchmark`), the attitude term the formulation's."""
    not_quat = np.ones(bench.model.nx)
    not_quat[M.QUAT] = 0.0

    def cost(theta, data, x, u):
        x_ref, Qk, wq, u_ref, Rk = data
        dx = x - x_ref
        du = u - u_ref
        return 0.5 * dx @ (Qk * dx) + wq * fm.attitude_cost(x[M.QUAT], x_ref[M.QUAT]) + 0.5 * du @ (Rk * du)

    data = tuple(jnp.asarray(a) for a in (bench.x_ref, bench.Q * not_quat, bench.q_weight, bench.u_ref, bench.R))
    return CostGroup(name="stage", deps=(Dep("x"), Dep("u")), fn=cost, knots=np.arange(bench.n_knots), data=data)


def build_nlp(bench: Benchmark, formulation: AbstractFormulation) -> KnotNLP:
    """The sparse NLP of ``bench`` in ``formulation`` (see the module docstring): one builder
    per group, in this order."""
    fm = formulation
    groups = [dynamics_group(bench, fm)]
    if bench.targets:
        groups.append(target_group(bench, fm))
    if fm.unit_norm:
        groups.append(unit_norm_group(bench))
    if bench.keep_out is not None:
        groups.append(keep_out_group(bench.keep_out))
    layout = Layout((("x", bench.model.nx), ("u", bench.model.nu)))
    lower = np.concatenate([bench.x_lower, bench.u_lower], axis=1)
    upper = np.concatenate([bench.x_upper, bench.u_upper], axis=1)
    return KnotNLP(layout, bench.n_knots, [stage_cost(bench, fm)], groups, lower, upper)
