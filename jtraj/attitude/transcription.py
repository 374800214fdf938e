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
from jtraj.attitude.benchmarks import Benchmark
from jtraj.attitude.formulations import AbstractFormulation
from jtraj.nlp import ConstraintGroup, CostGroup, Dep, KnotNLP, Layout

__all__ = ["build_nlp", "warm_start", "StateTrajectory", "decode"]


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


def build_nlp(bench: Benchmark, formulation: AbstractFormulation) -> KnotNLP:
    """The sparse NLP of ``bench`` in ``formulation`` (see the module docstring)."""
    model = bench.model
    N, nx, nu = bench.n_knots, model.nx, model.nu
    layout = Layout((("x", nx), ("u", nu)))
    dynamics = model.dynamics
    fm = formulation

    def defect(h, x, u, x_next):
        return fm.defect(x_next, M.rk4(dynamics, x, u, h))

    K = N - 1
    nd = fm.defect_dim(nx)
    groups = [
        ConstraintGroup(
            name="dynamics",
            deps=(Dep("x"), Dep("u"), Dep("x", 1)),
            fn=defect,
            knots=np.arange(K),
            lower=np.zeros((K, nd)),
            upper=np.zeros((K, nd)),
            active=np.ones((K, nd), bool),
            data=jnp.full((K,), bench.h),
        )
    ]
    if bench.targets:
        knots = np.array([t.knot for t in bench.targets])
        nt = fm.target_dim
        groups.append(
            ConstraintGroup(
                name="attitude_target",
                deps=(Dep("x"),),
                fn=lambda q_ref, x: fm.attitude_error(x[M.QUAT], q_ref),
                knots=knots,
                lower=np.zeros((knots.size, nt)),
                upper=np.zeros((knots.size, nt)),
                active=np.ones((knots.size, nt), bool),
                data=jnp.asarray(np.array([t.q for t in bench.targets])),
            )
        )
    if fm.unit_norm:
        knots = np.arange(1, N)
        groups.append(
            ConstraintGroup(
                name="unit_norm",
                deps=(Dep("x"),),
                fn=lambda data, x: jnp.atleast_1d(x[M.QUAT] @ x[M.QUAT] - 1.0),
                knots=knots,
                lower=np.zeros((knots.size, 1)),
                upper=np.zeros((knots.size, 1)),
                active=np.ones((knots.size, 1), bool),
            )
        )
    if bench.keep_out is not None:
        ko = bench.keep_out
        knots = np.asarray(ko.knots)
        cam, sun = jnp.asarray(ko.camera_body), jnp.asarray(ko.sun_world)
        groups.append(
            ConstraintGroup(
                name="keep_out",
                deps=(Dep("x"),),
                fn=lambda data, x: jnp.atleast_1d(sun @ quat.rotate(x[M.QUAT], cam)),
                knots=knots,
                lower=np.full((knots.size, 1), -np.inf),
                upper=np.full((knots.size, 1), math.cos(math.radians(ko.angle_deg))),
                active=np.ones((knots.size, 1), bool),
            )
        )

    not_quat = np.ones(nx)
    not_quat[M.QUAT] = 0.0
    Qm = bench.Q * not_quat

    def stage_cost(data, x, u):
        x_ref, Qk, wq, u_ref, Rk = data
        dx = x - x_ref
        du = u - u_ref
        return 0.5 * dx @ (Qk * dx) + wq * fm.attitude_cost(x[M.QUAT], x_ref[M.QUAT]) + 0.5 * du @ (Rk * du)

    cost = CostGroup(
        name="stage",
        deps=(Dep("x"), Dep("u")),
        fn=stage_cost,
        knots=np.arange(N),
        data=tuple(jnp.asarray(a) for a in (bench.x_ref, Qm, bench.q_weight, bench.u_ref, bench.R)),
    )
    lower = np.concatenate([bench.x_lower, bench.u_lower], axis=1)
    upper = np.concatenate([bench.x_upper, bench.u_upper], axis=1)
    return KnotNLP(layout, N, [cost], groups, lower, upper)
