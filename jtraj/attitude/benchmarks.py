"""The trajectory-optimization benchmarks of "Planning with Attitude" (Section VI), solved with
jtraj's sparse Ipopt transcription in two formulations.

Transcription (both formulations): multiple shooting with one RK4 step per interval
(`jtraj.attitude.models.rk4`); per knot the variables are ``z_k = [x_k, u_k]``
(`jtraj.nlp.Layout` slots ``x`` and ``u``); ``u`` at the last knot is unused and fixed. The
initial state, the non-attitude part of the goal state, input limits and the floor are
variable bounds; everything else is a `jtraj.nlp.ConstraintGroup` written for one knot.

Formulations (one contract, `AbstractFormulation`; pick one with `FORMULATIONS[name]`):

- ``naive`` (`NaiveFormulation`): the quaternion is a plain vector of R^4. Dynamics defects
  ``x_{k+1} - rk4(x_k, u_k)`` (nx rows), attitude costs ``w/2 |q - q_ref|^2`` and attitude
  targets (waypoints, goal) ``q - q_ref = 0`` (4 rows), with ``q_ref`` on the quaternion branch
  that the motion follows (a 360 degree flip ends at ``[-1, 0, 0, 0]``).
- ``attitude`` (`AttitudeFormulation`): attitude-aware, Section V. Defects in the error state
  (eq. 25; ``nx - 1`` rows): position/velocity/other differences and the Rodrigues parameter
  ``cayley_inv(L(q_pred)^T q_{k+1})`` of the rotation from the RK4 prediction to the next
  knot; attitude costs are the geodesic cost ``w (1 - |q_ref^T q|)`` (eq. 40), whose gradient
  and Hessian in the rotation coordinates are eqs. 41-42 (JAX differentiates through it;
  the `jtraj.quaternion` tests check that autodiff composed with ``G(q)`` equals them);
  attitude targets are ``cayley_inv(L(q_ref)^T q) = 0`` (3 rows). Because Ipopt still sees the
  four quaternion coordinates, and the error-state defect only fixes the direction of
  ``q_{k+1}`` (it is invariant under scaling), a unit-norm constraint ``|q_k|^2 = 1`` is added at
  every knot after the first, which also removes the RK4 norm drift the naive defect carries.
  Both formulations weigh attitude equally to first order on the unit sphere
  (``1/2 |q - q_ref|^2 = 1 - q_ref^T q``).

Ipopt settings (`IPOPT_OPTIONS`): exact Hessian of the Lagrangian from JAX (the paper's
ALTRO is a second-order method too), ``constr_viol_tol = 1e-5`` (the paper's constraint
tolerance) also as the *acceptable* violation, so that a returned "converged" solution always
satisfies the constraints to 1e-5; ``tol = 1e-6`` on Ipopt's scaled KKT error; Ipopt's
default gradient-based NLP scaling; MUMPS; 1000 iterations at most.

Benchmarks (`BENCHMARKS`; values of the paper and its public code where given, documented
choices otherwise, see each factory): ``quadflip`` (`quadrotor_flip`), ``barrelroll``
(`barrel_roll`), ``satellite`` (`satellite_slew`). `solve_benchmark` solves one;
`main_attitude` is the command-line entry; `compare_benchmarks` runs the table.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from jtraj import quaternion as quat
from jtraj.attitude import models as M
from jtraj.nlp import ConstraintGroup, CostGroup, Dep, KnotNLP, Layout
from jtraj.result import _json_default
from jtraj import solvers
from jtraj.solvers import AbstractOptions, AbstractSolver, IpoptOptions, IpoptSolver, Progress, resolve_progress

__all__ = [
    "AbstractFormulation",
    "NaiveFormulation",
    "AttitudeFormulation",
    "FORMULATIONS",
    "KeepOut",
    "AttitudeTarget",
    "Benchmark",
    "quadrotor_flip",
    "barrel_roll",
    "satellite_slew",
    "BENCHMARKS",
    "PAPER_ITERATIONS",
    "IPOPT_OPTIONS",
    "BenchmarkStatus",
    "BenchmarkResult",
    "build_nlp",
    "solve_benchmark",
    "accumulated_rotation",
    "plot_benchmark",
    "main_attitude",
    "compare_benchmarks",
]


# ----------------------------------------------------------------------------------------
# Formulations


class AbstractFormulation:
    """How the quaternion is treated by the transcription. Methods act on ONE knot.

    - ``defect(x_next, x_pred)``: dynamics defect rows (``defect_dim(nx)``);
    - ``attitude_cost(q, q_ref)``: scalar, multiplied by the knot's attitude weight;
    - ``attitude_error(q, q_ref)``: rows of an attitude target constraint (``target_dim``);
    - ``unit_norm``: whether ``|q|^2 = 1`` rows are added at every free knot.
    """

    name: ClassVar[str]
    target_dim: ClassVar[int]
    unit_norm: ClassVar[bool]

    def defect_dim(self, nx: int) -> int:
        raise NotImplementedError

    def defect(self, x_next: jax.Array, x_pred: jax.Array) -> jax.Array:
        raise NotImplementedError

    def attitude_cost(self, q: jax.Array, q_ref: jax.Array) -> jax.Array:
        raise NotImplementedError

    def attitude_error(self, q: jax.Array, q_ref: jax.Array) -> jax.Array:
        raise NotImplementedError


@dataclasses.dataclass(frozen=True)
class NaiveFormulation(AbstractFormulation):
    """Quaternion as a vector of R^4: additive defects, costs and targets."""

    name: ClassVar[str] = "naive"
    target_dim: ClassVar[int] = 4
    unit_norm: ClassVar[bool] = False

    def defect_dim(self, nx: int) -> int:
        return nx

    def defect(self, x_next, x_pred):
        return x_next - x_pred

    def attitude_cost(self, q, q_ref):
        d = q - q_ref
        return 0.5 * d @ d

    def attitude_error(self, q, q_ref):
        return q - q_ref


@dataclasses.dataclass(frozen=True)
class AttitudeFormulation(AbstractFormulation):
    """Error-state defects (eq. 25), geodesic cost (eq. 40), Cayley-map targets, unit norm."""

    name: ClassVar[str] = "attitude"
    target_dim: ClassVar[int] = 3
    unit_norm: ClassVar[bool] = True

    def defect_dim(self, nx: int) -> int:
        return nx - 1

    def defect(self, x_next, x_pred):
        return M.error_state(x_next, x_pred)

    def attitude_cost(self, q, q_ref):
        return quat.geodesic_cost(q, q_ref)

    def attitude_error(self, q, q_ref):
        return quat.cayley_inv(quat.L(q_ref).T @ q)


FORMULATIONS: dict[str, AbstractFormulation] = {"naive": NaiveFormulation(), "attitude": AttitudeFormulation()}


# ----------------------------------------------------------------------------------------
# Problem data


@dataclasses.dataclass(frozen=True)
class KeepOut:
    """Eq. 43: ``sun_world . A(q) camera_body <= cos(angle)`` at ``knots`` (unit vectors)."""

    camera_body: tuple[float, float, float]
    sun_world: tuple[float, float, float]
    angle_deg: float
    knots: tuple[int, ...]


@dataclasses.dataclass(frozen=True)
class AttitudeTarget:
    """A hard attitude constraint at ``knot`` (0-based): the body must have attitude ``q``
    (wxyz, on the branch the motion follows, which only the naive formulation cares about)."""

    knot: int
    q: tuple[float, float, float, float]
    label: str = ""


@dataclasses.dataclass(frozen=True, eq=False)
class Benchmark:
    """A trajectory-optimization problem with an attitude, as data (numpy arrays).

    Cost, summed over knots k (``u`` terms for k < N - 1 only)::

        1/2 sum_i Q[k, i] (x[k, i] - x_ref[k, i])^2        (i outside the quaternion)
        + q_weight[k] * attitude_cost(q_k, x_ref[k, QUAT])   (formulation-dependent)
        + 1/2 sum_j R[k, j] (u[k, j] - u_ref[k, j])^2

    Constraints: dynamics, ``targets`` (attitude), optional ``keep_out``, the variable bounds
    ``x_lower/x_upper`` (N, nx) and ``u_lower/u_upper`` (N, nu) (the initial state and the
    non-attitude goal are fixed through them). ``x_init``/``u_init``: the warm start.
    """

    name: str
    model: Any
    tf: float
    x_ref: np.ndarray
    Q: np.ndarray
    q_weight: np.ndarray
    u_ref: np.ndarray
    R: np.ndarray
    targets: tuple[AttitudeTarget, ...]
    x_lower: np.ndarray
    x_upper: np.ndarray
    u_lower: np.ndarray
    u_upper: np.ndarray
    x_init: np.ndarray
    u_init: np.ndarray
    keep_out: KeepOut | None = None
    description: str = ""

    @property
    def n_knots(self) -> int:
        return self.x_ref.shape[0]

    @property
    def h(self) -> float:
        return self.tf / (self.n_knots - 1)

    @property
    def t(self) -> np.ndarray:
        return np.linspace(0.0, self.tf, self.n_knots)

    def __post_init__(self):
        N, nx, nu = self.n_knots, self.model.nx, self.model.nu
        shapes = {
            "x_ref": (N, nx), "Q": (N, nx), "q_weight": (N,), "u_ref": (N, nu), "R": (N, nu),
            "x_lower": (N, nx), "x_upper": (N, nx), "u_lower": (N, nu), "u_upper": (N, nu),
            "x_init": (N, nx), "u_init": (N, nu),
        }  # fmt: skip
        for field, shape in shapes.items():
            got = np.shape(getattr(self, field))
            if got != shape:
                raise ValueError(f"benchmark {self.name}: {field} has shape {got}, expected {shape}")
        for tgt in self.targets:
            if not 0 <= tgt.knot < N:
                raise ValueError(f"benchmark {self.name}: attitude target at knot {tgt.knot} outside 0..{N - 1}")
        if np.any(self.x_lower > self.x_upper) or np.any(self.u_lower > self.u_upper):
            raise ValueError(f"benchmark {self.name}: a lower bound exceeds its upper bound")


def _scaled_knot(k_full: int, n_full: int, n_knots: int) -> int:
    """Knot index of the full-size problem mapped to a horizon of n_knots (same time)."""
    return int(round(k_full * (n_knots - 1) / (n_full - 1)))


def _bounds(N: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    return np.full((N, n), -np.inf), np.full((N, n), np.inf)


def _check_n_knots(name: str, n_knots: int, minimum: int) -> None:
    if not isinstance(n_knots, (int, np.integer)) or n_knots < minimum:
        raise ValueError(f"benchmark {name}: n_knots must be an integer >= {minimum}, got {n_knots!r}")


def _slerp_path(q0: np.ndarray, axis, angle: float, n: int) -> np.ndarray:
    """(n, 4): q0 followed by a uniform rotation by ``angle`` about the world ``axis``."""
    return np.stack([M.quat_about_axis(axis, angle * s) for s in np.linspace(0, 1, n)]) @ np.asarray(quat.R(q0)).T


def quadrotor_flip(n_knots: int = 101, tf: float = 5.0) -> Benchmark:
    """Quadrotor flip (paper Section VI-C; numbers of the paper's public code).

    From rest at (0, -1, 1), level, to rest at (0, 1, 1) (2 m along +y) after a full 360 degree
    roll about world x, in ``tf`` = 5 s with N = 101 knots (h = 0.05 s). Waypoints: the paper's
    code lists knots 20, 45, 51, 55, 75 (1-based, i.e. indices 19, 44, 50, 54, 74 here, at
    t = 0.95, 2.2, 2.5, 2.7, 3.7 s) with roll 0, 90, 180, 270, 360 degrees and positions
    (0, 1, 1), (0, 1.5, 1.5), (0, 1, 2.5), (0, 0.5, 1.5), (0, 0.65, 1) on a loop in the y-z plane.
    Interpretation used here: the first waypoint (roll 0) brings the quadrotor over the goal,
    the four others make the flip. Every waypoint attitude is a HARD attitude target, every
    waypoint position a soft cost (weight 10 per m^2, as the code's waypoint costs are soft),
    and the goal (position, velocity, angular velocity and the 360 degree attitude) is hard.
    The floor is ``z >= 0``. Stage costs: 1/2 (1e-3 |v|^2 + 1e-2 |omega|^2 + 1e-2 |u - u_hover|^2)
    and an attitude weight of 1e-2 toward the goal attitude. Warm start (dynamically
    infeasible, as in the paper): position linear from start to goal, attitude turning
    uniformly through 360 degrees about x, v = omega = 0, hover thrust.
    For ``n_knots < 101`` the waypoint knots are scaled to the same times.
    """
    _check_n_knots("quadflip", n_knots, 11)
    model = M.Quadrotor()
    N, nx, nu = n_knots, model.nx, model.nu
    ex = (1.0, 0.0, 0.0)
    r0, rg = np.array([0.0, -1.0, 1.0]), np.array([0.0, 1.0, 1.0])
    x0 = M.rigid_state(r=r0)
    q_goal = M.quat_about_axis(ex, 2 * np.pi)
    xg = M.rigid_state(r=rg, q=q_goal)
    waypoints = [  # (1-based knot of the paper's code, roll deg, position)
        (20, 0.0, (0.0, 1.0, 1.0)),
        (45, 90.0, (0.0, 1.5, 1.5)),
        (51, 180.0, (0.0, 1.0, 2.5)),
        (55, 270.0, (0.0, 0.5, 1.5)),
        (75, 360.0, (0.0, 0.65, 1.0)),
    ]
    u_hover = model.hover_control()
    x_ref = np.tile(xg, (N, 1))
    Q = np.zeros((N, nx))
    Q[:, M.VEL] = 1e-3
    Q[:, M.OMEGA] = 1e-2
    q_weight = np.full(N, 1e-2)
    R = np.full((N, nu), 1e-2)
    R[-1] = 0.0
    targets = []
    for k1, roll, pos in waypoints:
        k = _scaled_knot(k1 - 1, 101, N)
        x_ref[k, M.POS] = pos
        Q[k, M.POS] = 10.0
        targets.append(AttitudeTarget(k, tuple(M.quat_about_axis(ex, math.radians(roll))), f"roll {roll:.0f} deg"))
    targets.append(AttitudeTarget(N - 1, tuple(q_goal), "goal"))
    xl, xu = _bounds(N, nx)
    xl[:, 2] = 0.0  # floor
    xl[0] = xu[0] = x0
    for sl in (M.POS, M.VEL, M.OMEGA):
        xl[-1, sl] = xu[-1, sl] = xg[sl]
    ul, uu = _bounds(N, nu)
    ul[-1] = uu[-1] = u_hover
    s = np.linspace(0.0, 1.0, N)
    x_init = np.zeros((N, nx))
    x_init[:, M.POS] = (1 - s)[:, None] * r0 + s[:, None] * rg
    x_init[:, M.QUAT] = _slerp_path(x0[M.QUAT], ex, 2 * np.pi, N)
    return Benchmark(
        name="quadflip",
        model=model,
        tf=tf,
        x_ref=x_ref,
        Q=Q,
        q_weight=q_weight,
        u_ref=np.tile(u_hover, (N, 1)),
        R=R,
        targets=tuple(targets),
        x_lower=xl,
        x_upper=xu,
        u_lower=ul,
        u_upper=uu,
        x_init=x_init,
        u_init=np.tile(u_hover, (N, 1)),
        description="quadrotor: 360 degree flip about x with attitude waypoints, 2 m along +y, z >= 0",
    )


def barrel_roll(n_knots: int = 101, tf: float = 1.25, speed: float = 5.0, roll_guess: bool = True) -> Benchmark:
    """Airplane barrel roll to inverted flight (paper Section VI-B).

    From (-3, 0, 1.5) in level trimmed flight at 5 m/s (`jtraj.attitude.models.Airplane.trim`)
    to (3, 0, 1.5) at 5 m/s along +x, ``omega = 0`` and upside down: the trim attitude rolled
    180 degrees about the body x axis (nose still up by the trim angle of attack, which is
    what inverted level flight needs), in ``tf`` = 1.25 s with N = 101 knots. The goal is hard.
    Stage costs: 1/2 (0.1 |v - v_goal|^2 + 0.1 |omega|^2) and an attitude weight of 0.1 toward
    the goal attitude (pulling the roll along), plus 1/2 R |u - u_trim|^2 with
    R = (10, 1, 1, 1) per N^2 / rad^2. Limits: thrust in [0, 2] N, surface deflections within
    +-60 degrees. Warm start ("initialized at level-flight trim"): trim inputs at every knot
    and states on the trimmed straight flight path; with ``roll_guess`` (default) the guessed
    attitude turns uniformly through the 180 degree roll about the body x axis (a dynamically
    infeasible guess, like the quadrotor's). ``roll_guess=False`` keeps the trim attitude
    (the exact trim rollout); its last knot is then exactly 180 degrees from the goal, where
    the Cayley-map goal error of the attitude formulation is singular (q_s = 0), so that
    start is only usable by the naive formulation.
    """
    _check_n_knots("barrelroll", n_knots, 11)
    model = M.Airplane()
    N, nx, nu = n_knots, model.nx, model.nu
    trim = model.trim(speed)
    q_trim = trim.x[M.QUAT]
    q_goal = np.asarray(quat.multiply(jnp.asarray(q_trim), jnp.asarray(M.quat_about_axis((1, 0, 0), np.pi))))
    x0 = M.rigid_state(r=(-3.0, 0.0, 1.5), q=q_trim, v=(speed, 0.0, 0.0))
    xg = M.rigid_state(r=(3.0, 0.0, 1.5), q=q_goal, v=(speed, 0.0, 0.0))
    x_ref = np.tile(xg, (N, 1))
    Q = np.zeros((N, nx))
    Q[:, M.VEL] = 0.1
    Q[:, M.OMEGA] = 0.1
    R = np.tile([10.0, 1.0, 1.0, 1.0], (N, 1))
    R[-1] = 0.0
    xl, xu = _bounds(N, nx)
    xl[0] = xu[0] = x0
    for sl in (M.POS, M.VEL, M.OMEGA):
        xl[-1, sl] = xu[-1, sl] = xg[sl]
    max_deflection = math.radians(60.0)
    ul = np.tile([0.0, -max_deflection, -max_deflection, -max_deflection], (N, 1))
    uu = np.tile([2.0, max_deflection, max_deflection, max_deflection], (N, 1))
    ul[-1] = uu[-1] = trim.u
    t = np.linspace(0.0, tf, N)
    x_init = np.tile(x0, (N, 1))
    x_init[:, 0] = x0[0] + speed * t
    if roll_guess:
        # q_trim (x) R_x(s pi): rolling about the body x axis
        rolls = np.stack([M.quat_about_axis((1.0, 0.0, 0.0), np.pi * s) for s in np.linspace(0.0, 1.0, N)])
        x_init[:, M.QUAT] = rolls @ np.asarray(quat.L(jnp.asarray(q_trim))).T
    return Benchmark(
        name="barrelroll",
        model=model,
        tf=tf,
        x_ref=x_ref,
        Q=Q,
        q_weight=np.full(N, 0.1),
        u_ref=np.tile(trim.u, (N, 1)),
        R=R,
        targets=(AttitudeTarget(N - 1, tuple(q_goal), "inverted"),),
        x_lower=xl,
        x_upper=xu,
        u_lower=ul,
        u_upper=uu,
        x_init=x_init,
        u_init=np.tile(trim.u, (N, 1)),
        description=f"airplane: level flight at {speed} m/s to inverted flight 6 m further in {tf} s",
    )


#: Camera (star tracker) axis in the body frame, normalized, and sun direction (paper eq. 43).
CAMERA_BODY = tuple(np.array([0.360, -0.930, 0.079]) / np.linalg.norm([0.360, -0.930, 0.079]))
SUN_WORLD = (1.0, 0.0, 0.0)


def satellite_slew(n_knots: int = 401, tf: float = 100.0, keep_out_deg: float | None = 40.0) -> Benchmark:
    """Flexible spacecraft: 150 degree slew with a sun keep-out cone (paper Section VI-A).

    From rest at a rotation of 150 degrees about (1, 2, 3) (normalized) to rest at the identity
    attitude, modes at rest (``eta = eta_dot = 0``), wheels free, in ``tf`` = 100 s with
    N = 401 knots (h = 0.25 s); wheel torques ``|u_i| <= 0.5`` N m; the camera axis
    (0.360, -0.930, 0.079) must stay ``keep_out_deg`` (40) degrees or more from the sun
    direction (1, 0, 0) at every knot (eq. 43; None drops it). The geodesic (constant-axis)
    slew passes 35 degrees from the sun, so the constraint is active. Stage costs (documented
    choices): 1/2 (10 |omega|^2 + 10 |eta|^2 + 10 |eta_dot|^2 + |u|^2) and an attitude weight
    of 1 toward the goal. Warm start: at rest at the initial attitude, zero torques (the
    rollout of zero inputs, as ALTRO starts).

    The RK4 step must resolve the fastest flexible mode: ``2 pi f_max h`` above 2.5 raises.
    """
    _check_n_knots("satellite", n_knots, 11)
    model = M.FlexibleSpacecraft()
    N, nx, nu = n_knots, model.nx, model.nu
    h = tf / (N - 1)
    stiffest = 2 * math.pi * max(model.modal_frequencies_hz) * h
    if stiffest > 2.5:
        raise ValueError(
            f"satellite: step {h:.3g} s is too long for the {max(model.modal_frequencies_hz)} Hz mode "
            f"(2 pi f h = {stiffest:.2f} > 2.5, RK4 loses stability); use more knots or a shorter tf"
        )
    q0 = M.quat_about_axis((1.0, 2.0, 3.0), math.radians(150.0))
    x0 = np.zeros(nx)
    x0[M.QUAT] = q0
    xg = np.zeros(nx)
    xg[M.QUAT] = (1.0, 0.0, 0.0, 0.0)
    Q = np.zeros((N, nx))
    Q[:, M.OMEGA] = 10.0
    Q[:, model.ETA] = 10.0
    Q[:, model.ETA_DOT] = 10.0
    R = np.ones((N, nu))
    R[-1] = 0.0
    xl, xu = _bounds(N, nx)
    xl[0] = xu[0] = x0
    for sl in (M.OMEGA, model.ETA, model.ETA_DOT):
        xl[-1, sl] = xu[-1, sl] = xg[sl]
    ul = np.full((N, nu), -model.torque_limit)
    uu = np.full((N, nu), model.torque_limit)
    ul[-1] = uu[-1] = 0.0
    keep_out = None
    if keep_out_deg is not None:
        keep_out = KeepOut(CAMERA_BODY, SUN_WORLD, float(keep_out_deg), tuple(range(1, N)))
    return Benchmark(
        name="satellite",
        model=model,
        tf=tf,
        x_ref=np.tile(xg, (N, 1)),
        Q=Q,
        q_weight=np.ones(N),
        u_ref=np.zeros((N, nu)),
        R=R,
        targets=(AttitudeTarget(N - 1, (1.0, 0.0, 0.0, 0.0), "goal"),),
        x_lower=xl,
        x_upper=xu,
        u_lower=ul,
        u_upper=uu,
        x_init=np.tile(x0, (N, 1)),
        u_init=np.zeros((N, nu)),
        keep_out=keep_out,
        description=f"flexible spacecraft: 150 degree slew, |u| <= 0.5 N m, camera {keep_out_deg} deg from the sun",
    )


BENCHMARKS: dict[str, Callable[..., Benchmark]] = {
    "quadflip": quadrotor_flip,
    "barrelroll": barrel_roll,
    "satellite": satellite_slew,
}

#: Iterations reported by the paper (Table VI), ALTRO naive / modified.
PAPER_ITERATIONS: dict[str, tuple[int, int]] = {"barrelroll": (53, 40), "quadflip": (58, 22), "satellite": (35, 35)}
#: Solve times reported by the paper (ms), naive / modified.
PAPER_TIME_MS: dict[str, tuple[float, float]] = {"barrelroll": (94.93, 76.48), "quadflip": (419.08, 138.63), "satellite": (392.66, 460.08)}


# ----------------------------------------------------------------------------------------
# Transcription


def build_nlp(bench: Benchmark, formulation: AbstractFormulation) -> KnotNLP:
    """The sparse NLP of ``bench`` in ``formulation`` (see the module docstring)."""
    model = bench.model
    N, nx, nu = bench.n_knots, model.nx, model.nu
    layout = Layout((("x", nx), ("u", nu)))
    dynamics = model.dynamics
    fm = formulation

    def defect(theta, h, x, u, x_next):
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
                fn=lambda theta, q_ref, x: fm.attitude_error(x[M.QUAT], q_ref),
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
                fn=lambda theta, data, x: jnp.atleast_1d(x[M.QUAT] @ x[M.QUAT] - 1.0),
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
                fn=lambda theta, data, x: jnp.atleast_1d(sun @ quat.rotate(x[M.QUAT], cam)),
                knots=knots,
                lower=np.full((knots.size, 1), -np.inf),
                upper=np.full((knots.size, 1), math.cos(math.radians(ko.angle_deg))),
                active=np.ones((knots.size, 1), bool),
            )
        )

    not_quat = np.ones(nx)
    not_quat[M.QUAT] = 0.0
    Qm = bench.Q * not_quat

    def stage_cost(theta, data, x, u):
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


#: Ipopt options of every benchmark solve (see the module docstring).
IPOPT_OPTIONS = IpoptOptions(
    tol=1e-6,
    constr_viol_tol=1e-5,
    acceptable_constr_viol_tol=1e-5,
    acceptable_tol=1e-4,
    max_iter=1000,
    hessian="exact",
    nlp_scaling_method="gradient-based",
    linear_solver="mumps",
    max_wall_time=1800.0,
)


# ----------------------------------------------------------------------------------------
# Results


class BenchmarkStatus(enum.Enum):
    SOLVED = "solved"  # Ipopt converged (violation <= 1e-5) and the task check passed
    SOLVED_TASK_FAILED = "converged_but_task_failed"
    NOT_CONVERGED = "not_converged"


@dataclasses.dataclass
class BenchmarkResult:
    """Outcome of `solve_benchmark`. Times in seconds; ``time_s`` excludes JAX compilation.

    ``X`` (N, nx) states, ``U`` (N - 1, nu) inputs, ``t`` (N,) knot times; ``metrics`` holds
    the benchmark's task checks (`_metrics`), e.g. ``min_sun_angle_deg`` for the satellite.
    """

    name: str
    variant: str
    status: BenchmarkStatus
    ipopt_status: str
    status_msg: str
    converged: bool
    iterations: int
    time_s: float
    time_compile: float
    time_derivatives: float
    time_ipopt: float
    objective: float
    constraint_violation: float
    violation_by_group: dict[str, float]
    n_knots: int
    tf: float
    n_variables: int
    n_constraints: int
    metrics: dict[str, Any]
    options: dict[str, Any]
    history: list[dict[str, float]]
    t: np.ndarray
    X: np.ndarray
    U: np.ndarray

    @property
    def success(self) -> bool:
        return self.status is BenchmarkStatus.SOLVED

    def summary(self) -> str:
        return (
            f"{self.name} [{self.variant}] {self.status.value}: {self.iterations} iterations, "
            f"{self.time_s:.2f} s (compile {self.time_compile:.1f} s), constraint violation "
            f"{self.constraint_violation:.2e}, objective {self.objective:.6g}"
        )

    def to_json(self) -> dict[str, Any]:
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name not in ("t", "X", "U")}
        out["status"] = self.status.value
        out["success"] = self.success
        return out

    def save(self, directory: str | Path) -> tuple[Path, Path]:
        """Write ``{name}_{variant}.json`` (everything but the arrays) and ``{name}_{variant}.npz``
        (t, X, U) into ``directory`` (created); returns both paths."""
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        stem = f"{self.name}_{self.variant}"
        with open(d / f"{stem}.json", "w") as f:
            json.dump(self.to_json(), f, indent=2, default=_json_default)
        np.savez_compressed(d / f"{stem}.npz", t=self.t, X=self.X, U=self.U)
        return d / f"{stem}.json", d / f"{stem}.npz"



def accumulated_rotation(q: np.ndarray, frame: str = "world") -> np.ndarray:
    """(N, 4) attitudes -> (N, 3) rotation accumulated about the world axes (rad), summing the
    world-frame increments ``Log(q_{k+1} q_k^*)`` so that a 360 degree flip reads 2 pi; with
    ``frame="body"`` the body-frame increments ``Log(q_k^* q_{k+1})`` (roll about the body x
    axis for an airplane)."""
    from jtraj.lie import SO3

    if frame not in ("world", "body"):
        raise ValueError(f"frame must be 'world' or 'body', got {frame!r}")
    q = np.asarray(q, float)
    q = jnp.asarray(q / np.linalg.norm(q, axis=1, keepdims=True))
    if frame == "world":
        steps = jax.vmap(lambda a, b: SO3(a).multiply(SO3(b).inverse()).log())(q[1:], q[:-1])
    else:
        steps = jax.vmap(lambda a, b: SO3(b).inverse().multiply(SO3(a)).log())(q[1:], q[:-1])
    return np.vstack([np.zeros(3), np.cumsum(np.asarray(steps), axis=0)])


def _angle_between(qa: np.ndarray, qb: np.ndarray) -> float:
    """Rotation angle (deg) between two (possibly non-unit) quaternions."""
    qa, qb = qa / np.linalg.norm(qa), qb / np.linalg.norm(qb)
    return math.degrees(2 * math.acos(min(1.0, abs(float(qa @ qb)))))


def _metrics(bench: Benchmark, X: np.ndarray, U: np.ndarray) -> tuple[dict[str, Any], bool]:
    """Task checks: (metrics, task_ok)."""
    qn = np.linalg.norm(X[:, M.QUAT], axis=1)
    out: dict[str, Any] = {"max_quaternion_norm_error": float(np.max(np.abs(qn - 1.0)))}
    out["target_errors_deg"] = {f"{t.label}@{t.knot}": _angle_between(X[t.knot, M.QUAT], np.asarray(t.q)) for t in bench.targets}
    ok = max(out["target_errors_deg"].values(), default=0.0) < 0.1
    roll = accumulated_rotation(X[:, M.QUAT])
    if bench.name == "quadflip":
        out["roll_turns"] = float(roll[-1, 0] / (2 * np.pi))
        out["min_altitude_m"] = float(X[:, 2].min())
        out["final_position_error_m"] = float(np.linalg.norm(X[-1, M.POS] - bench.x_lower[-1, M.POS]))
        ok &= abs(out["roll_turns"] - 1.0) < 0.05 and out["min_altitude_m"] > -1e-5
    elif bench.name == "barrelroll":
        # the goal attitude is a hard target (checked above); the body-axis roll is reported
        out["roll_deg"] = float(np.degrees(accumulated_rotation(X[:, M.QUAT], "body")[-1, 0]))
        out["min_altitude_m"] = float(X[:, 2].min())
        out["final_position_error_m"] = float(np.linalg.norm(X[-1, M.POS] - bench.x_lower[-1, M.POS]))
    elif bench.name == "satellite":
        ko = bench.keep_out
        cam, sun = np.asarray(CAMERA_BODY), np.asarray(SUN_WORLD)
        if ko is not None:
            cam, sun = np.asarray(ko.camera_body), np.asarray(ko.sun_world)
        ang = np.degrees(np.asarray(jax.vmap(lambda q: M.FlexibleSpacecraft.sun_angle(q / jnp.linalg.norm(q), jnp.asarray(cam), jnp.asarray(sun)))(jnp.asarray(X[:, M.QUAT]))))
        out["sun_angle_deg"] = ang.tolist()
        out["min_sun_angle_deg"] = float(ang.min())
        out["max_abs_torque"] = float(np.abs(U).max())
        if ko is not None:
            out["keep_out_deg"] = ko.angle_deg
            out["keep_out_margin_deg"] = float(ang.min() - ko.angle_deg)
            ok &= out["keep_out_margin_deg"] > -1e-3
    return out, bool(ok)


def _formulation(variant: str | AbstractFormulation) -> AbstractFormulation:
    if isinstance(variant, AbstractFormulation):
        return variant
    try:
        return FORMULATIONS[variant]
    except KeyError:
        raise ValueError(f"unknown variant {variant!r}; expected one of {sorted(FORMULATIONS)}") from None


def _benchmark(name: str | Benchmark, n_knots: int | None, **kwargs) -> Benchmark:
    if isinstance(name, Benchmark):
        return name
    try:
        factory = BENCHMARKS[name]
    except KeyError:
        raise ValueError(f"unknown benchmark {name!r}; expected one of {sorted(BENCHMARKS)}") from None
    if n_knots is not None:
        kwargs["n_knots"] = n_knots
    return factory(**kwargs)


#: The paper's constraint tolerance: a converged solve must satisfy the constraints to it.
CONSTRAINT_TOLERANCE = 1e-5


def _options(backend: AbstractSolver, options: AbstractOptions | dict[str, Any] | None) -> AbstractOptions:
    """The benchmarks' settings of ``backend`` (`IPOPT_OPTIONS` for Ipopt) with ``options``
    over them (an options object replaces them)."""
    if isinstance(options, AbstractOptions):
        return backend.options(options)
    if isinstance(backend, IpoptSolver):
        return IPOPT_OPTIONS.merge(options)
    return backend.options(options)


def solve_benchmark(
    name: str | Benchmark,
    variant: str | AbstractFormulation = "attitude",
    out: str | Path | None = None,
    n_knots: int | None = None,
    progress: Progress = True,
    ipopt_options: IpoptOptions | dict[str, Any] | None = None,
    solver: str | AbstractSolver = "ipopt",
    **benchmark_kwargs,
) -> BenchmarkResult:
    """Solve a benchmark (a name of `BENCHMARKS` or a `Benchmark`) in one formulation.

    ``n_knots`` (and any ``benchmark_kwargs``, e.g. ``tf``) go to the benchmark factory;
    ``ipopt_options`` override `IPOPT_OPTIONS`. JAX functions are compiled before Ipopt starts,
    so ``time_s`` is the solve alone. With ``out``, writes ``{name}_{variant}.json/.npz``.
    ``progress``: a stream for Ipopt's per-iteration line (None: silent).
    """
    from jtraj import config

    config.enable_compilation_cache()
    fm = _formulation(variant)
    bench = _benchmark(name, n_knots, **benchmark_kwargs)
    t0 = time.perf_counter()
    nlp = build_nlp(bench, fm)
    z0 = np.concatenate([bench.x_init, bench.u_init], axis=1).reshape(-1)
    z0 = np.clip(z0, nlp.x_lower, nlp.x_upper)
    x0 = jnp.asarray(z0)
    nlp.build_hessian()
    for fn in (nlp.objective, nlp.gradient, nlp.constraints, nlp.jacobian):
        jax.block_until_ready(fn(x0, nlp.theta))
    jax.block_until_ready(nlp.hessian(x0, jnp.ones(nlp.m), 1.0, nlp.theta))
    time_compile = time.perf_counter() - t0
    backend = solvers.get(solver)
    options = _options(backend, ipopt_options)
    outcome = backend.solve(nlp, z0, None, options, resolve_progress(progress, 10))
    Z = outcome.x.reshape(bench.n_knots, -1)
    nx = bench.model.nx
    X, U = Z[:, :nx], Z[:-1, nx:]
    metrics, task_ok = _metrics(bench, X, U)
    converged = outcome.converged and outcome.constraint_violation <= CONSTRAINT_TOLERANCE
    status = BenchmarkStatus.NOT_CONVERGED
    if converged:
        status = BenchmarkStatus.SOLVED if task_ok else BenchmarkStatus.SOLVED_TASK_FAILED
    result = BenchmarkResult(
        name=bench.name,
        variant=fm.name,
        status=status,
        ipopt_status=outcome.status.value,
        status_msg=outcome.message,
        converged=converged,
        iterations=outcome.stats.iterations,
        time_s=outcome.stats.time_total,
        time_compile=time_compile,
        time_derivatives=outcome.stats.time_evaluations,
        time_ipopt=outcome.stats.time_solver,
        objective=outcome.objective,
        constraint_violation=outcome.constraint_violation,
        violation_by_group=nlp.violation_by_group(outcome.x),
        n_knots=bench.n_knots,
        tf=bench.tf,
        n_variables=nlp.n,
        n_constraints=nlp.m,
        metrics=metrics,
        options=options.as_dict(),
        history=[it.as_dict() for it in outcome.history],
        t=bench.t,
        X=X,
        U=U,
    )
    if out is not None:
        result.save(out)
    return result


# ----------------------------------------------------------------------------------------
# Figures and entry points


def plot_benchmark(result: BenchmarkResult, path: str | Path | None = None, ax=None):
    """The benchmark's telling curve: quadflip roll angle (accumulated, deg) against time with
    the attitude waypoints; barrelroll path (y and z against x) and roll angle; satellite
    camera-sun angle against time with the keep-out bound. Returns the matplotlib Figure
    (drawn into ``ax`` when given); writes it to ``path`` when given."""
    from matplotlib.figure import Figure

    if ax is None:
        fig = Figure(figsize=(6.4, 3.6))
        ax = fig.add_subplot()
    else:
        fig = ax.figure
    t, X = result.t, result.X
    label = f"{result.variant} ({result.iterations} it.)"
    if result.name == "quadflip":
        roll = np.degrees(accumulated_rotation(X[:, M.QUAT])[:, 0])
        ax.plot(t, roll, label=label)
        ax.set_ylabel("roll about x (deg, accumulated)")
        ax.set_yticks([0, 90, 180, 270, 360])
    elif result.name == "barrelroll":
        roll = np.degrees(accumulated_rotation(X[:, M.QUAT], "body")[:, 0])
        ax.plot(X[:, 0], X[:, 2], label=f"z, {label}")
        ax.plot(X[:, 0], X[:, 1], ls="--", label=f"y, {label}")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y, z (m)")
        twin = ax.twinx()
        twin.plot(X[:, 0], roll, color="0.6", lw=0.8)
        twin.set_ylabel("roll (deg)", color="0.5")
    elif result.name == "satellite":
        ax.plot(t, result.metrics["sun_angle_deg"], label=label)
        bound = result.metrics.get("keep_out_deg")
        if bound is not None:
            ax.axhspan(0.0, bound, color="tab:red", alpha=0.15, lw=0)
            ax.axhline(bound, color="tab:red", lw=0.8)
        ax.set_ylabel("camera-sun angle (deg)")
    if result.name != "barrelroll":
        ax.set_xlabel("time (s)")
    ax.set_title(result.name)
    ax.grid(True, alpha=0.4)
    ax.legend(fontsize=8)
    if path is not None:
        fig.savefig(path, dpi=150, bbox_inches="tight")
    return fig


def main_attitude(bench: str, variant: str = "attitude", out_dir: str | Path | None = None, n_knots: int | None = None, solver: str = "ipopt") -> BenchmarkResult:
    """Command-line entry (``jtraj attitude BENCH --variant ... --out DIR``): solve, print
    iterations, time and constraint violation, save ``{bench}_{variant}.json/.npz/.png``."""
    out = Path(out_dir) if out_dir is not None else Path("runs") / "attitude"
    result = solve_benchmark(bench, variant, out=out, n_knots=n_knots, progress=True, solver=solver)
    plot_benchmark(result, out / f"{result.name}_{result.variant}.png")
    print(result.summary())
    for key in ("min_sun_angle_deg", "roll_turns", "roll_deg", "max_quaternion_norm_error"):
        if key in result.metrics:
            print(f"  {key}: {result.metrics[key]:.6g}")
    paper = PAPER_ITERATIONS.get(result.name)
    if paper is not None:
        print(f"  paper (ALTRO) iterations naive/modified: {paper[0]}/{paper[1]}")
    print(f"wrote {out}/{result.name}_{result.variant}.json, .npz, .png")
    return result


def compare_benchmarks(
    out_dir: str | Path,
    names: tuple[str, ...] = ("barrelroll", "quadflip", "satellite"),
    variants: tuple[str, ...] = ("naive", "attitude"),
    n_knots: int | None = None,
    progress: Progress = False,
    solver: str = "ipopt",
) -> list[dict[str, Any]]:
    """Solve every benchmark in every variant; write ``out_dir``/table.json and table.md
    (iterations, time, violation, status next to the paper's iterations) and each result's
    files; prints the table (``jtraj attitude all``)."""
    out = Path(out_dir)
    rows = []
    for name in names:
        for variant in variants:
            r = solve_benchmark(name, variant, out=out, n_knots=n_knots, progress=progress, solver=solver)
            rows.append(
                {
                    "benchmark": name,
                    "variant": variant,
                    "status": r.status.value,
                    "iterations": r.iterations,
                    "time_s": r.time_s,
                    "time_compile_s": r.time_compile,
                    "constraint_violation": r.constraint_violation,
                    "objective": r.objective,
                    "paper_iterations": PAPER_ITERATIONS[name][{"naive": 0, "attitude": 1}[variant]],
                    **{k: v for k, v in r.metrics.items() if isinstance(v, (int, float))},
                }
            )
            print(r.summary(), flush=True)
    (out / "table.json").write_text(json.dumps(rows, indent=2) + "\n")
    lines = ["| benchmark | variant | status | iterations | paper (ALTRO) | time (s) | violation |", "|---|---|---|---|---|---|---|"]
    for row in rows:
        lines.append(
            f"| {row['benchmark']} | {row['variant']} | {row['status']} | {row['iterations']} | {row['paper_iterations']} | "
            f"{row['time_s']:.2f} | {row['constraint_violation']:.1e} |"
        )
    (out / "table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return rows
