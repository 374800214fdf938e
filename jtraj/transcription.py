"""Inverse-dynamics direct transcription (paper eqs. 11-18) for any floating-base parameterization.

Variables of knot k (one `Layout` for all knots; the NLP fixes by bounds what a knot does not
use, and Ipopt removes fixed variables):

    q  (param.nq + nj)   base coordinates in the parameterization's chart, joint positions
    v  (nv)              body twist of the base and joint rates
    a  (nv)              its time derivative
    f  (3 P)             world-frame forces at the task's P contact points (0 when not touching)
    c  (3 P)             contact positions (0 when not touching)

Constraint groups, each written for ONE knot and vmapped (rows of inactive contacts dropped),
each made by one stage builder (`dynamics_stage`, ...; `CONSTRAINT_STAGES` in row order):

    dynamics      tau(q, v, a, f; masses): base rows = 0, joint rows within the effort limits
    integration   v' = v + a h;  param.difference(param.integrate(q_b, V_b', h), q_b') = 0;
                  q_j' = q_j + qd_j' h                    (semi-implicit Euler, Table I;
                  `position_step="stepped"` writes V' as v + a h, as the study's code)
    contact       FK_j(q) = c_j for touching points; c_z is the terrain height (a bound)
    stationary    (c_j')_xy = (c_j)_xy while a point keeps touching
    clearance     FK_j(q)_z >= terrain height for points in the air
    friction      4-facet pyramid |f_x|, |f_y| <= mu f_z (f_z >= 0 and |f_i| <= F are bounds, F =
                  force_limit_factor m g, 1.5 m g by default; `TranscriptionOptions.force_limits`)
    force_rate    |f_j' - f_j| <= max_delta_force per component (tasks that set it; with
                  `liftoff_force_rate` also where a point lifts off, f_j' = 0)
    chart         the parameterization's own constraint (e.g. unit quaternion norm), if any

Costs (`cost_terms`): 1/2 w_q |q_j - q_j,standing|^2 and 1/2 w_a |a_j|^2 per knot. Boundary
conditions are bounds: knot 0 at the standing pose at rest, the last knot at the target pose
at rest, a = 0.

Parameters. Every number of the task a user may vary or differentiate is a field of
`TaskParams`, the ``theta`` of the NLP's functions (`jtraj.nlp`): the target, the timestep
(the knot count stays the task's), friction, force bounds, cost weights, the body masses
(they enter inverse dynamics and its analytical Jacobians, see `jtraj.dynamics`) and the
standing pose. `Transcription.default_theta` gives the task's values; changing theta never
recompiles.

Knot structure (the variables with accelerations, "compact" and "paper"): the state of knot k is
``x_k = (q_k, v_k)``, the controls ``u_k = (a_k, f_k)`` (and ``c_k`` with the paper's variables), and
the integration rows encode the explicit step ``x_{k+1} = F(x_k, u_k, theta)``:
``v' = v + a h``, ``q_b' = param.integrate(q_b, v'_b, h)``, ``q_j' = q_j + v'_j h``
(`Transcription.step`, `KnotNLP.structure`).

Nothing here imports cyipopt; `Transcription.build_nlp` returns a `jtraj.nlp.KnotNLP`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from functools import cached_property
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxlie import SE3, SO3

from jtraj import dynamics, lie
from jtraj.constants import GRAVITY
from jtraj.deprecation import warn_renamed
from jtraj.nlp import ConstraintGroup, CostGroup, Dep, KnotNLP, KnotStructure, Layout
from jtraj.numbers import is_real, unit_and_length
from jtraj.parameterization import AbstractParameterization
from jtraj.robot import Robot
from jtraj.task import RPY_LIMIT, Task, _Raw

__all__ = [
    "Transcription",
    "TranscriptionOptions",
    "TaskParams",
    "PAPER_VARIABLES",
    "COMPACT_VARIABLES",
    "LEAN_VARIABLES",
    "Trajectory",
    "CONSTRAINT_STAGES",
    "dynamics_stage",
    "integration_stage",
    "contact_stage",
    "clearance_stage",
    "friction_stage",
    "force_limit",
    "force_limit_stage",
    "force_rate_stage",
    "chart_stage",
    "cost_terms",
]



@dataclasses.dataclass(frozen=True)
class TranscriptionOptions:
    """Variables per knot (``variables=`` of `jtraj.solve`; `jtraj.nlp.Layout` is where they
    sit in a knot's vector).

    Attributes:
        contact_variables: keep the contact positions c_{j,k} as variables with
            ``FK_j(q_k) = c_{j,k}`` (the paper). False substitutes ``FK_j(q_k)``: the contact
            rows become ``FK_j(q_k)_z = terrain`` and stationarity ``FK_j(q_{k+1})_xy =
            FK_j(q_k)_xy``.
        acceleration_variables: keep a_k as variables with ``v_{k+1} = v_k + a_k h`` (the
            paper). False substitutes ``a_k = (v_{k+1} - v_k) / h`` (and a_N = 0).
        position_step: which velocity the position row is written with. ``"next"``:
            ``difference(integrate(q_k, v_{k+1}, h), q_{k+1})``. ``"stepped"`` (the study's
            public code, `SemiEulerIntegration`): ``v_k + a_k h`` in place of ``v_{k+1}``, so
            the row reads q_k, v_k, a_k and q_{k+1}. Equal on the feasible set (the velocity
            row makes ``v_{k+1} = v_k + a_k h``), different linearizations off it: measured on
            the walk with the code's configuration cost, 39 Ipopt iterations with ``"next"``,
            27 with ``"stepped"`` (docs/reproduction.md). Needs ``acceleration_variables``.
        force_limits: how a touching point's force is limited. ``"bounds"``: variable bounds
            ``0 <= f_z <= F``, ``|f_x|, |f_y| <= F`` (F = force_limit_factor m g). ``"rows"``
            (the study's code, `TerrainGridFrictionConstraints`): the force is a free variable
            with the rows ``f_z >= 0`` and ``|f| <= F`` (Euclidean norm). The box contains the
            ball, and the friction pyramid (``|f_x|, |f_y| <= mu f_z``) keeps both inside
            ``|f| <= F`` wherever ``f_z sqrt(1 + 2 mu^2) <= F``.
        contact_height: how a touching point's contact position keeps to the terrain (with
            ``contact_variables``). ``"bound"``: ``c_z`` fixed by its bounds (Ipopt removes
            it). ``"row"`` (the study's code, `TerrainGridContactConstraints`): ``c_z`` a free
            variable with the row ``c_z - terrain = 0``, and the stationarity rows keep z as
            well as x, y while the point touches at k and k+1 (three rows, the z row dependent
            on the two height rows, as in the code).
        liftoff_force_rate: the force-change bound ``|f_{k+1} - f_k| <= max_delta_force``
            also where a point lifts off (``f_{k+1} = 0``): the push-off force must end below
            the bound, as in the study's code (`TerrainGridFrictionConstraints`). False bounds
            only knots where the point touches at k and k+1.
        warm_start_quaternions: how the warm start writes a quaternion parameterization's rho
            (Quaternion #1-#3; the others ignore it). ``"continuous"``: the quaternion carried
            along the warm start's rotation, so a flip's warm start turns rho_0 into -rho_0
            (the double cover) while the last knot is held at the target's rho_0.
            ``"matrix"``: each knot's quaternion converted from its rotation matrix
            (``SO3.from_matrix``, one sign per rotation as Eigen's and Pinocchio's conversions
            choose). The study's code builds its warm starts through rotation matrices
            (`rpy2rep`), so this sign changes mid-flip and the warm start ends at rho_0.
            Measured on the back-flip (docs/reproduction.md, section 6): ``"matrix"`` takes
            Quaternion #1 and #2 to the plain jump the paper reports. `PAPER_VARIABLES` uses
            ``"matrix"``; a warm start that turns less than half a turn gets the same quaternions
            either way, to rounding (bitwise on the walk, hopscotch and big_jump).
        warm_start_euler: how the warm start writes the Euler-angle parameterization's angles
            (the others ignore it). ``"matrix"``: each knot's roll, pitch and yaw extracted
            from its rotation matrix, the pitch kept `jtraj.euler.GIMBAL_MARGIN` away from
            +-pi/2 (a flip's warm start then jumps by 2 pi or pi in the middle of the
            flight, and passes no gimbal lock). ``"angles"``: the task's warm-start angle
            added to the roll, pitch or yaw of its axis (a principal axis) over the rule's
            knots, the knots after a ramp left at the standing orientation: what the study's
            flip scripts (``rpy2rep(q, [0, theta, 0])`` on the ramp's nodes, the others
            untouched) write for a chart whose coordinates are roll, pitch and yaw. A flip's
            warm start then ramps to -2 pi and jumps back to 0 at landing, and a back-flip's
            pitch passes -pi/2 and -3 pi/2, where the rate matrix W is singular. Measured
            (docs/reproduction.md, section 6): with it Euler fails on both flips, as in the
            paper; from ``"matrix"`` it converges to plain jumps. `PAPER_VARIABLES` uses
            ``"angles"``; warm starts without rotation rules are the same either way.
    Both substitutions eliminate equality constraints exactly: the feasible trajectories are
    the same, the NLP is smaller.
    """

    contact_variables: bool = True
    acceleration_variables: bool = True
    position_step: str = "next"
    liftoff_force_rate: bool = False
    force_limits: str = "bounds"
    contact_height: str = "bound"
    warm_start_quaternions: str = "continuous"
    warm_start_euler: str = "matrix"

    def __post_init__(self):
        for name in ("contact_variables", "acceleration_variables", "liftoff_force_rate"):
            value = getattr(self, name)
            if not isinstance(value, (bool, np.bool_)):  # the string "false" is true
                raise ValueError(f"{name}={value!r}: expected True or False")
        if self.warm_start_euler not in ("matrix", "angles"):
            raise ValueError(f"warm_start_euler={self.warm_start_euler!r}: expected 'matrix' or 'angles'")
        if self.warm_start_quaternions not in ("continuous", "matrix"):
            raise ValueError(f"warm_start_quaternions={self.warm_start_quaternions!r}: expected 'continuous' or 'matrix'")
        if self.position_step not in ("next", "stepped"):
            raise ValueError(f"position_step={self.position_step!r}: expected 'next' or 'stepped'")
        if self.force_limits not in ("bounds", "rows"):
            raise ValueError(f"force_limits={self.force_limits!r}: expected 'bounds' or 'rows'")
        if self.contact_height not in ("bound", "row"):
            raise ValueError(f"contact_height={self.contact_height!r}: expected 'bound' or 'row'")
        if self.contact_height == "row" and not self.contact_variables:
            raise ValueError("contact_height='row' writes a row on the contact positions c: it needs contact_variables=True")
        if self.position_step == "stepped" and not self.acceleration_variables:
            raise ValueError("position_step='stepped' writes the position row with a_k: it needs acceleration_variables=True")


#: The study's public code: its variables per knot (q, v, a, f, c), its position row, its
#: force-change bound at lift-off, its warm start's quaternions written from rotation
#: matrices and its Euler angles as they are (docs/reproduction.md lists what else differs
#: and why).
PAPER_VARIABLES = TranscriptionOptions(position_step="stepped", liftoff_force_rate=True, warm_start_quaternions="matrix", warm_start_euler="angles")
#: Contact positions substituted by forward kinematics: (q, v, a, f) at every knot.
COMPACT_VARIABLES = TranscriptionOptions(contact_variables=False, acceleration_variables=True)
#: Contact positions and accelerations substituted: (q, v, f) at every knot.
LEAN_VARIABLES = TranscriptionOptions(contact_variables=False, acceleration_variables=False)

#: How far (m) a point may be off the terrain where the first or last knot, fixed, puts it
#: (beyond the stance's own error at the first knot, where phase 0's contacts touch the terrain
#: on average): a check of the task, not a solver tolerance.
HEIGHT_TOLERANCE = 1e-6
#: How far apart in height (m) phase 0's contact points may be in the standing pose. The first
#: knot is fixed, so the spread is violation of its contact rows that no solver can remove
#: (half of it, the base lowered to their mean): on a Go2 hop a 0.046 mm spread solved
#: (violation 3.4e-5), 0.15 mm stopped at the iteration limit (1.15e-4), against Ipopt's
#: constr_viol_tol of 1e-4.
STANCE_SPREAD = 1e-4

_FORMER_NAMES = {"PAPER_LAYOUT": "PAPER_VARIABLES", "COMPACT_LAYOUT": "COMPACT_VARIABLES", "LEAN_LAYOUT": "LEAN_VARIABLES"}


def __getattr__(name: str) -> Any:
    if name in _FORMER_NAMES:  # deprecated spellings of the constants above
        warn_renamed(f"jtraj.transcription.{name}", f"jtraj.transcription.{_FORMER_NAMES[name]}")
        return globals()[_FORMER_NAMES[name]]
    raise AttributeError(f"module 'jtraj.transcription' has no attribute {name!r}")


@dataclasses.dataclass(frozen=True, eq=False)
class TaskParams:
    """The parameters theta of a whole-body task: a pytree of float64 arrays.

    Attributes (units SI, frames as in `jtraj.task.Task`):
        target_translation: (3,) base displacement from the standing pose, world frame (m).
        target_rotation_rpy: (3,) base rotation from the standing pose (rad): roll, pitch,
            yaw, composed about world axes as Rz Ry Rx.
        timestep: () h (s); the knot count stays the task's.
        friction: () coefficient mu of the friction pyramid.
        force_limit_factor: () |f_i| <= factor * (sum of body_masses) * g per component.
        max_delta_force: () N per knot and component; inf for no bound: a task without one
            has no force-rate rows, and a task's rows with the bounds -inf and inf bind
            nothing (both solvers leave out a row without a finite bound). For a task without
            the rows a finite value is refused (`Transcription.resolve_theta`) unless it is
            being traced (under ``jit``/``grad``): then it cannot be looked at, and has no
            effect, since the task has no force-rate rows to bound.
        configuration_weight, acceleration_weight: () cost weights.
        body_masses: (nbody,) kg, one per MuJoCo body, world first (`dynamics.model_masses`;
            the world's must be 0: no dynamics has it).
        base_xyz_wxyz_standing: (7,) standing base pose (before it is lowered so the first
            phase's contact points touch the terrain). Its height therefore has no effect on
            the NLP (the lowering replaces it: its derivative is exactly 0); x, y and the
            attitude do.
        q_joints_standing: (nj,) standing joint positions (rad), also the configuration
            cost's reference and the target joints of tasks that set none.

    Build one with `Transcription.default_theta` and change it with `replace` (which checks
    names and shapes): passing values of another shape or dtype would compile again.
    """

    target_translation: jax.Array
    target_rotation_rpy: jax.Array
    timestep: jax.Array
    friction: jax.Array
    force_limit_factor: jax.Array
    max_delta_force: jax.Array
    configuration_weight: jax.Array
    acceleration_weight: jax.Array
    body_masses: jax.Array
    base_xyz_wxyz_standing: jax.Array
    q_joints_standing: jax.Array

    def replace(self, **overrides: Any) -> "TaskParams":
        """A copy with some fields replaced, as float64 arrays of the same shapes. Values must
        be numbers (Python's or numpy's, lists of them, arrays): a bool or a string is refused,
        as the task file refuses it (``True`` became 1.0, ``"0.5"`` 0.5)."""
        names = [f.name for f in dataclasses.fields(self)]
        values = {}
        for name, value in overrides.items():
            if name not in names:
                raise ValueError(f"unknown task parameter {name!r}; expected one of {names}")
            old = getattr(self, name)
            if not _numeric(value):
                raise ValueError(f"task parameter {name!r} must be numbers of shape {old.shape}, got {value!r}")
            try:
                new = jnp.asarray(value, dtype=jnp.float64)
            except (TypeError, ValueError) as err:
                raise ValueError(f"task parameter {name!r} must be numbers of shape {old.shape}, got {value!r} ({err})") from None
            if new.shape != old.shape:
                raise ValueError(f"task parameter {name!r} must have shape {old.shape}, got {new.shape}")
            values[name] = new
        return dataclasses.replace(self, **values)

    def check(self) -> "TaskParams":
        """Raise ValueError for values no task can have (the task file's rules: a positive
        timestep, friction, force factor and force-rate bound, weights >= 0, masses >= 0 and
        the world body's (the first) 0, target angles within [-pi, pi] (`jtraj.task.RPY_LIMIT`), all
        finite but the force-rate bound, which may be inf (no bound, see ``max_delta_force``);
        and a unit standing quaternion). Values being traced (under ``jit``, ``grad`` or
        ``vmap``) are not looked at. Returns self."""
        def positive(v):
            return np.isfinite(v) & (v > 0)

        def nonnegative(v):
            return np.isfinite(v) & (v >= 0)

        rules = {
            "timestep": ("a positive number of seconds", positive),
            "friction": ("a positive friction coefficient", positive),
            "force_limit_factor": ("a positive factor of m g", positive),
            "max_delta_force": ("a positive force (N), or inf for none", lambda v: v > 0),
            "configuration_weight": ("a weight >= 0", nonnegative),
            "acceleration_weight": ("a weight >= 0", nonnegative),
            # as the task file's target.rotation_rpy: 90 (degrees typed for radians) was a
            # rotation of 116.6 degrees
            "target_rotation_rpy": (
                "angles (rad) within [-pi, pi]: the target is an attitude, so a larger angle is a smaller one's attitude",
                lambda v: np.isfinite(v) & (np.abs(v) <= RPY_LIMIT),
            ),
            # the world body's (first) is in no subtree: inverse dynamics ignores it, while the
            # force bound and the warm start's weight summed it
            "body_masses": ("masses >= 0 (kg), the first (the world body's) 0", lambda v: nonnegative(v) & ((np.arange(v.size) > 0) | (v == 0))),
            # a quaternion of another norm is written into the boundary knots' coordinates as
            # it is (a chart of unit quaternions, or NaN from a zero quaternion)
            "base_xyz_wxyz_standing": (
                "finite numbers: a position (m) then a unit quaternion (w, x, y, z); normalize it",
                lambda v: np.isfinite(v).all() and abs(np.linalg.norm(v[3:]) - 1.0) <= 1e-9,
            ),
        }
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, jax.core.Tracer):
                continue
            v = np.asarray(value)
            expected, ok = rules.get(f.name, ("finite values", np.isfinite))
            if not np.all(ok(v)):
                shown = v.item() if v.ndim == 0 else v.tolist()
                raise ValueError(f"theta.{f.name}={shown!r}: expected {expected}")
        return self


def _numeric(value: Any) -> bool:
    """Whether ``value`` is numbers: a real number (not a bool), a list or tuple of them, or an
    array of integers or floats (a JAX one may be traced)."""
    if isinstance(value, (list, tuple)):
        return all(_numeric(v) for v in value)
    if isinstance(value, (np.ndarray, jax.Array)):
        return value.dtype.kind in "iuf"
    return is_real(value)


jax.tree_util.register_dataclass(TaskParams, data_fields=[f.name for f in dataclasses.fields(TaskParams)], meta_fields=[])


@dataclasses.dataclass
class Trajectory:
    """A decoded trajectory; arrays have the knot axis first."""

    t: np.ndarray  # (K,) s
    base_xyz_wxyz: np.ndarray  # (K, 7) base pose, MJX free-joint convention
    q_base: np.ndarray  # (K, param.nq) base coordinates in the parameterization's chart
    q_joints: np.ndarray  # (K, nj) rad
    v: np.ndarray  # (K, nv) body twist + joint rates
    a: np.ndarray  # (K, nv)
    tau: np.ndarray  # (K, nv) generalized forces from inverse dynamics (base rows ~ 0)
    forces: np.ndarray  # (K, P, 3) N, world frame
    contact_positions: np.ndarray  # (K, P, 3) m, forward kinematics of the contact points
    in_contact: np.ndarray  # (K, P) bool
    contact_names: tuple[str, ...]


def _check_euler_warm_start(task: Task, param_name: str, options: TranscriptionOptions) -> None:
    """Refuse, naming the task's key (and file), a warm-start rotation rule the Euler-angle
    parameterization cannot write with ``warm_start_euler="angles"`` (the study's variables):
    those add a rule's angle to one Euler angle, so its axis must be x, y or z. A task file's
    rules may be about any axis (of any length: its direction is what counts, as in
    `jtraj.task.Task.warm_start_angles`); the other parameterizations and variables rotate the
    poses. Checked where the task's own warm start is built (`Transcription.warm_start`) and by
    the command line before a solve or sweep starts; a transcription given another warm start
    does not need it."""
    if param_name != "euler" or options.warm_start_euler != "angles":
        return
    for i, rule in enumerate(task.warm_start_rules):
        unit = unit_and_length(rule.axis)[0]
        if np.count_nonzero(np.abs(unit) > 1e-12) != 1:  # `_warm_start_coords`' test
            raise task.error(
                f"warm_start_rules[{i}].axis", np.asarray(rule.axis, float).tolist(),
                "with the Euler angles and warm_start_euler='angles' (the study's variables) a rule's angle is added to one Euler angle; "
                "expected a principal axis (x, y or z), or other variables (e.g. compact)",
            )


class Transcription:
    """The transcription of ``task`` for ``robot`` in parameterization ``param``."""

    def __init__(self, robot: Robot, task: Task, param: AbstractParameterization, options: TranscriptionOptions = COMPACT_VARIABLES):
        # names (what `jtraj.solve` takes) ended in an AttributeError ('str' object has no
        # attribute 'validate')
        if not isinstance(robot, Robot):
            raise TypeError(f"robot must be a Robot (jtraj.robot.load({robot!r}) for a name), got {type(robot).__name__}")
        if not isinstance(task, Task):
            raise TypeError(f"task must be a Task (jtraj.task.load({task!r}) for a name or a file), got {type(task).__name__}")
        if not isinstance(param, AbstractParameterization):
            raise TypeError(f"param must be a parameterization (jtraj.parameterization.get({param!r}) for a name), got {type(param).__name__}")
        if not isinstance(options, TranscriptionOptions):
            raise TypeError(f"options must be a TranscriptionOptions (jtraj.solver.VARIABLES[{options!r}] for a name), got {type(options).__name__}")
        task.validate(robot)
        self.options = options
        self.robot = robot
        self.task = task
        self.param = param
        self.schedule = task.schedule(robot)
        self.points = np.asarray(self.schedule.points, int)
        self.P = len(self.points)
        self.nj = robot.nj
        self.nv = robot.nv
        self.nq = param.nq + robot.nj
        self.N = self.schedule.n_knots - 1
        #: the task's timestep (s), the default; a theta's ``timestep`` overrides it in the NLP
        #: and in `step`, `bounds`, `decode`, not here: read ``theta.timestep`` where theta is given
        self.h = float(task.timestep)
        slots = [("q", self.nq), ("v", self.nv)]
        if options.acceleration_variables:
            slots.append(("a", self.nv))
        slots.append(("f", 3 * self.P))
        if options.contact_variables:
            slots.append(("c", 3 * self.P))
        self.layout = Layout(tuple(slots))
        self.contact_names = tuple(robot.contact_names[i] for i in self.points)

    # -------------------------------------------------------------------- parameters
    def default_theta(self) -> TaskParams:
        """The task's and the robot's values of the parameters, as float64 arrays."""
        task, robot = self.task, self.robot

        def arr(x):
            return jnp.asarray(np.asarray(x, float))

        return TaskParams(
            target_translation=arr(task.target_translation),
            target_rotation_rpy=arr(task.target_rotation_rpy),
            timestep=arr(task.timestep),
            friction=arr(task.friction),
            force_limit_factor=arr(task.force_limit_factor),
            max_delta_force=arr(np.inf if task.max_delta_force is None else task.max_delta_force),
            configuration_weight=arr(task.configuration_weight),
            acceleration_weight=arr(task.acceleration_weight),
            body_masses=arr(dynamics.model_masses(robot)),
            base_xyz_wxyz_standing=arr(robot.base_xyz_wxyz_standing),
            q_joints_standing=arr(robot.q_joints_standing),
        )

    def resolve_theta(self, theta: TaskParams | Mapping[str, Any] | None = None, base: TaskParams | None = None) -> TaskParams:
        """``theta`` as `TaskParams`: None is ``base`` (default `default_theta`), a mapping
        overrides some of its fields (``{"friction": 0.5}``), a `TaskParams` is checked against
        its shapes; both are checked for values (`TaskParams.check`). A `TaskParams` carries no
        task: one made for another task on the same robot (same shapes) is taken as it is, every
        field of it, so start from this transcription's own (`default_theta`, a
        `jtraj.differentiate.DifferentiableTask`'s ``theta``) or pass a mapping."""
        default = self.default_theta() if base is None else base
        if theta is None:
            return default
        if isinstance(theta, TaskParams):
            overrides = {f.name: getattr(theta, f.name) for f in dataclasses.fields(theta)}
        elif isinstance(theta, Mapping):
            overrides = dict(theta)
        else:
            raise TypeError(f"theta must be None, a mapping of parameter overrides or a TaskParams, got {type(theta).__name__}")
        # Without force-rate rows only inf (the default, no bound) says what the problem is;
        # a finite bound would be ignored, with a gradient of 0. Both forms are held to this
        # (a TaskParams carries every field); a traced value is not looked at, as in
        # `TaskParams.check`.
        bound = overrides.get("max_delta_force", np.inf)
        if self.task.max_delta_force is None and not isinstance(bound, jax.core.Tracer) and np.isfinite(np.asarray(bound, float)).any():
            raise ValueError(f"task {self.task.name!r} sets no max_delta_force, so it has no force-rate rows to bound; set it in the task")
        return self._within_joint_limits(default.replace(**overrides).check())

    #: the fields that place the fixed first and last knots
    _BOUNDARY_FIELDS = ("base_xyz_wxyz_standing", "q_joints_standing", "target_translation", "target_rotation_rpy")

    def check_boundaries(self, theta: TaskParams) -> None:
        """Refuse a theta (`resolve_theta`'s) whose fixed first or last knot is off the terrain
        where the task's phases touch it (`_boundary_problem`; a changed standing pose or
        target): no solver could meet those knots' rows. `jtraj.solve` checks a given theta so;
        values being traced are not looked at. (Not part of `resolve_theta`: a pose of such a
        theta can still be asked for, e.g. `target_xyz_wxyz_of`.)"""
        if any(isinstance(getattr(theta, name), jax.core.Tracer) for name in self._BOUNDARY_FIELDS):
            return
        problem = self._boundary_problem(theta)
        if problem is not None:
            kind, said = problem
            # the last knot's pose is the standing one moved by the target, so all four place it
            fields = "theta.q_joints_standing and theta.base_xyz_wxyz_standing" + ("" if kind != "last" else ", theta.target_translation and theta.target_rotation_rpy")
            raise ValueError(f"{fields}: the pose they give {said}; expected the fixed {'last' if kind == 'last' else 'first'} knot to touch the terrain as the task's phases do")

    def _within_joint_limits(self, theta: TaskParams) -> TaskParams:
        """Refuse standing joint positions outside the robot's limits (values being traced are
        not looked at): the first knot is fixed at them while every other knot keeps within the
        limits, so the solver could only report an infeasible problem. Task files' target
        joints are checked against the same limits."""
        q = theta.q_joints_standing
        if isinstance(q, jax.core.Tracer):
            return theta
        q = np.asarray(q, float)
        lo, hi = self.robot.q_lower, self.robot.q_upper
        outside = self.robot.joints_outside_limits(q)
        if outside.size:
            j = int(outside[0])
            raise ValueError(
                f"theta.q_joints_standing[{j}] ({self.robot.joint_names[j]})={q[j]!r}: outside the joint limits [{lo[j]:g}, {hi[j]:g}] rad of {self.robot.name!r}"
            )
        return theta

    # -------------------------------------------------------------------- host-side helpers
    # Poses on the host are numpy xyz_wxyz arrays and every JAX computation here is jitted
    # and batched over knots: evaluated op by op, each primitive would compile on its own
    # (measured: 235 compilations, half a minute, for the warm start of big_jump).
    @cached_property
    def _host(self):
        def rotate(axis_angle, wxyz):
            """Rotations Exp(axis_angle) R about world axes, batched."""
            return jax.vmap(lambda w, R: (lie.exp(SO3, w) @ SO3(R)).wxyz)(axis_angle, wxyz)

        def from_matrix(wxyz):
            """The quaternion a rotation-matrix conversion gives for each rotation, batched."""
            return jax.vmap(lambda w: SO3.from_matrix(SO3(w).as_matrix()).wxyz)(wxyz)

        return dict(
            coords=jax.jit(self._coords),
            rotate=jax.jit(rotate),
            from_matrix=jax.jit(from_matrix),
            fk=jax.jit(jax.vmap(self._fk)),
            initial=jax.jit(self._initial_xyz_wxyz),
            # the target from the initial pose: its forward kinematics are initial's, compiled
            # once (a jit of _target_xyz_wxyz compiled them again: 2.5 to 5 s per task)
            target=jax.jit(self._target_from_initial),
        )

    def _coords(self, xyz_wxyz: jax.Array, qj: jax.Array) -> jax.Array:
        """Configuration q of base poses (K, 7) and joint positions (K, nj)."""
        T = SE3.from_rotation_and_translation(SO3(xyz_wxyz[..., 3:]), xyz_wxyz[..., :3])
        return jnp.concatenate([jax.vmap(self.param.from_pose)(T), qj], axis=-1)

    def _initial_xyz_wxyz(self, theta: TaskParams) -> jax.Array:
        """(7,) standing base pose of theta, shifted vertically so that the first phase's
        contact points touch the terrain (on average)."""
        xyz_wxyz = theta.base_xyz_wxyz_standing
        q = self._coords(xyz_wxyz[None], theta.q_joints_standing[None])[0]
        p_z = self._fk(q)[:, 2]
        touching = np.flatnonzero(self.schedule.in_contact[0])
        return xyz_wxyz.at[2].add(-(jnp.mean(p_z[touching]) - self.task.terrain_height))

    def _target_xyz_wxyz(self, theta: TaskParams) -> jax.Array:
        """(7,) target base pose: theta's displacement and rotation applied to the initial pose."""
        return self._target_from_initial(self._initial_xyz_wxyz(theta), theta)

    @staticmethod
    def _target_from_initial(T0: jax.Array, theta: TaskParams) -> jax.Array:
        """`_target_xyz_wxyz` given the initial pose ``T0`` (7,)."""
        roll, pitch, yaw = theta.target_rotation_rpy
        # jaxlie's from_rpy_radians is Rz(yaw) Ry(pitch) Rx(roll) (jtraj.euler's convention),
        # applied about world axes
        R = SO3.from_rpy_radians(roll=roll, pitch=pitch, yaw=yaw) @ SO3(T0[3:])
        return jnp.concatenate([T0[:3] + theta.target_translation, R.wxyz])

    def _q_joints_target(self, theta: TaskParams) -> jax.Array:
        if self.task.target_joints is not None:
            return jnp.asarray(self.task.target_joints, float)
        return theta.q_joints_standing

    def _boundary_problem(self, theta: TaskParams, x0: np.ndarray | None = None) -> tuple[str, str] | None:
        """What keeps the fixed first or last knot of ``theta`` (concrete values) off the
        terrain the task's phases put them on, or None: ``("stance", said)`` phase 0's contact
        points more than `STANCE_SPREAD` apart in height in the standing pose; ``("first", said)`` another
        point below the terrain at the first knot (the stance lowered onto the terrain); ``("last",
        said)`` a point touching in the last phase off the terrain at the target pose (with the
        target joints), or another one below it. No solver could meet those knots' contact or
        clearance rows (the heights are the fixed knots' alone). ``x0``: theta's initial pose
        (`_initial_xyz_wxyz`), where the caller has it."""
        host, task = self._host, self.task
        x0 = np.asarray(host["initial"](theta)) if x0 is None else x0
        xN = np.asarray(host["target"](x0, theta))
        qj0 = np.asarray(theta.q_joints_standing, float)
        qjN = qj0 if task.target_joints is None else np.asarray(task.target_joints, float)
        z = np.asarray(host["fk"](host["coords"](np.stack([x0, xN]), np.stack([qj0, qjN]))))[:, :, 2]
        h = task.terrain_height
        first, last = self.schedule.in_contact[0], self.schedule.in_contact[-1]
        spread = float(np.ptp(z[0, first]))
        if spread > STANCE_SPREAD:
            return "stance", f"puts the contact points of phase 0 {spread * 1000:.3g} mm apart in height (on flat ground: within {STANCE_SPREAD * 1000:g} mm, which the fixed first knot's contact rows allow)"
        # the stance's own error at the first knot (its contacts touch the terrain on average,
        # within their spread) is allowed at both ends
        tol = HEIGHT_TOLERANCE + float(np.max(np.abs(z[0, first] - h)))
        below = np.flatnonzero(~first & (z[0] < h - tol))
        if below.size:
            i = below[np.argmin(z[0, below])]
            return "first", f"lowered until phase 0's contacts touch the terrain puts {self.contact_names[i]} {h - z[0, i]:.3g} m below it at the first knot"
        off = np.where(last, np.abs(z[1] - h), h - z[1])  # distance from the terrain (touching), depth below it (others)
        if np.any(off > tol):
            i = int(np.argmax(off))
            where = "above" if z[1, i] > h else "below"
            said = f"puts {self.contact_names[i]} {abs(z[1, i] - h):.3g} m {where} the terrain at the last knot" + (f", where phase {len(task.phases) - 1} touches it" if last[i] else "")
            # where the last phase's contacts are level (new joint angles that lengthen or
            # shorten the legs), the height that puts them on the terrain, to the digit: the
            # 3 digits above did not reach the tolerance of 1e-6 m
            shift = float(np.mean(z[1, last] - h)) if last.any() else 0.0
            if last.any() and np.ptp(z[1, last]) <= HEIGHT_TOLERANCE and not np.any(~last & (z[1] - shift < h - tol)):
                said += f" (target translation z = {round(float(np.asarray(theta.target_translation)[2]) - shift, 9) + 0.0:.9g} puts them on it)"
            return "last", said
        return None

    @cached_property
    def initial_xyz_wxyz(self) -> np.ndarray:
        """Standing base pose, lowered/raised so the first phase's contact points touch the
        terrain. Checks the task's fixed first and last knots (`_boundary_problem`), naming the
        robot or the task file's key."""
        theta = self.default_theta()
        x0 = np.asarray(self._host["initial"](theta))
        problem = self._boundary_problem(theta, x0)
        if problem is not None:
            kind, said = problem
            task = self.task
            if kind == "stance":
                # phase 0's contacts (e.g. the feet and a hand) are what the standing pose does
                # not put level, more often than the robot's standing pose itself
                raise self.task.error(
                    "phases[0].contacts", list(task.phases[0].contacts),
                    f"the standing pose of {self.robot.name!r} {said}; expected contacts of phase 0 that the robot's standing pose puts level (its feet, on a biped or quadruped)",
                )
            if kind == "first":
                # a point lower than phase 0's contacts in the standing pose (the feet, for a
                # task that starts on the hands)
                raise self.task.error(
                    "phases[0].contacts", list(task.phases[0].contacts),
                    f"the standing pose of {self.robot.name!r} {said}; expected the contacts of phase 0 to be the lowest points of the standing pose",
                )
            # the key most likely at fault: a height, else a roll or pitch (a yaw about the
            # vertical lifts no foot: with new joints it was blamed for theirs), else the joints
            if task.target_translation[2] != 0:
                field, value = "target_translation", list(task.target_translation)
            elif any(task.target_rotation_rpy[:2]) or (any(task.target_rotation_rpy) and task.target_joints is None):
                field, value = "target_rotation_rpy", list(task.target_rotation_rpy)
            elif task.target_joints is not None:
                field, value = "target_joints", _Raw(f"{len(task.target_joints)} joint angles")
            else:
                field, value = "target_translation", list(task.target_translation)
            raise self.task.error(field, value, f"{said}; expected a target whose touching points rest on the terrain and others above it (the last knot is fixed at the target)")
        return x0

    @cached_property
    def target_xyz_wxyz(self) -> np.ndarray:
        """Target base pose: the task's displacement and rotation applied to the initial pose."""
        return self.target_xyz_wxyz_of(None)

    def target_xyz_wxyz_of(self, theta: TaskParams | None) -> np.ndarray:
        """Target base pose (7,) for parameters ``theta`` (None: the task's)."""
        if theta is None:
            _ = self.initial_xyz_wxyz  # checks the standing pose
        theta = self.resolve_theta(theta)
        return np.asarray(self._host["target"](self._host["initial"](theta), theta))

    @property
    def initial_pose(self) -> SE3:
        x = self.initial_xyz_wxyz
        return SE3.from_rotation_and_translation(SO3(jnp.asarray(x[3:])), jnp.asarray(x[:3]))

    @property
    def target_pose(self) -> SE3:
        x = self.target_xyz_wxyz
        return SE3.from_rotation_and_translation(SO3(jnp.asarray(x[3:])), jnp.asarray(x[:3]))

    @cached_property
    def q_joints_target(self) -> np.ndarray:
        return np.asarray(self._q_joints_target(self.default_theta()))

    # -------------------------------------------------------------------- functions of one knot
    # Jitted so that the groups which call them (and vmap / jacfwd of those) reuse one traced
    # jaxpr: tracing the unrolled kinematic tree costs about a second each time.
    def _forces_all(self, f: jax.Array) -> jax.Array:
        """(3 P,) task forces -> (ncontact, 3) forces at all the robot's contact points."""
        F = jnp.zeros((len(self.robot.contact_names), 3), f.dtype)
        return F.at[self.points].set(f.reshape(self.P, 3))

    @cached_property
    def _tau(self):
        """``tau(q, v, a, f, masses)`` (nv,) for the task's contact forces f (3 P,)."""
        return jax.jit(lambda q, v, a, f, masses: dynamics.inverse_dynamics(self.robot, self.param, q, v, a, self._forces_all(f), masses))

    @cached_property
    def _fk(self):
        return jax.jit(lambda q: dynamics.contact_positions(self.robot, self.param, q)[self.points])

    def step(self, x: jax.Array, u: jax.Array, theta: TaskParams | Mapping[str, Any]) -> jax.Array:
        """The semi-implicit Euler step ``x_{k+1} = F(x_k, u_k, theta)`` of one knot.

        Args:
            x: (nq + nv,) state (q_k, v_k).
            u: (nv + 3 P [+ 3 P],) controls (a_k, f_k[, c_k]); only a_k enters.
            theta: the parameters (the timestep h); a mapping overrides the task's
                (`resolve_theta`).
        Returns:
            (nq + nv,) state ``(q_{k+1}, v_{k+1})`` with ``v' = v + a h``,
            ``q_b' = param.integrate(q_b, v'_b, h)`` and ``q_j' = q_j + v'_j h``.
        """
        if not self.options.acceleration_variables:
            raise ValueError("the step x' = F(x, u) needs the accelerations as controls; these variables (lean) substitute them")
        if isinstance(theta, Mapping):  # as warm_start and decode take it
            theta = self.resolve_theta(theta)
        nq, nv, nqb, h = self.nq, self.nv, self.param.nq, theta.timestep
        q, v, a = x[:nq], x[nq:], u[:nv]
        v1 = v + a * h
        q1 = jnp.concatenate([self.param.integrate(q[:nqb], v1[:6], h), q[nqb:] + v1[6:] * h])
        return jnp.concatenate([q1, v1])

    @property
    def structure(self) -> KnotStructure | None:
        """State (q, v), controls and `step` of a knot; None for the variables without accelerations (lean)."""
        if not self.options.acceleration_variables:
            return None
        control = tuple(name for name, _ in self.layout.slots if name not in ("q", "v"))
        return KnotStructure(self.layout, ("q", "v"), control, self.step)

    # -------------------------------------------------------------------- the NLP
    def build_nlp(self, stages: tuple[Callable[[Transcription], list[ConstraintGroup]], ...] | None = None) -> KnotNLP:
        """The NLP of the task: the groups of ``stages`` (default `CONSTRAINT_STAGES`, in
        that row order), `cost_terms`, the variable `bounds`, parameters `default_theta`."""
        _ = self.initial_xyz_wxyz  # checks that the standing pose and the target stand on the terrain
        groups = [g for stage in (CONSTRAINT_STAGES if stages is None else stages) for g in stage(self)]
        return KnotNLP(
            self.layout, self.N + 1, cost_terms(self), groups,
            lambda theta: self.bounds(theta)[0], lambda theta: self.bounds(theta)[1],
            theta=self.default_theta(), structure=self.structure,
        )

    def bounds(self, theta: TaskParams | Mapping[str, Any] | None = None) -> tuple[jax.Array, jax.Array]:
        """Variable bounds (n_knots, nz): limits, contacts, boundary conditions (jit-able in
        theta). ``theta`` as `resolve_theta` takes it (None: the task's; a mapping overrides
        some of its values); a `TaskParams` is taken as it is."""
        if not isinstance(theta, TaskParams):
            theta = self.resolve_theta(theta)
        robot, param, L = self.robot, self.param, self.layout
        n_knots, P, nqb = self.N + 1, self.P, param.nq
        lower = np.full((n_knots, L.nz), -np.inf)
        upper = np.full((n_knots, L.nz), np.inf)
        sq, sv, sf = L.slice("q"), L.slice("v"), L.slice("f")
        # joint position and velocity limits
        lower[:, sq.start + nqb : sq.stop] = robot.q_lower
        upper[:, sq.start + nqb : sq.stop] = robot.q_upper
        lower[:, sv.start + 6 : sv.stop] = -np.asarray(robot.v_max)
        upper[:, sv.start + 6 : sv.stop] = np.asarray(robot.v_max)
        contact = self.schedule.in_contact
        if self.options.contact_variables:
            # contact positions: touching points on the terrain (z fixed), others unused (0)
            # (with contact_height="row" c_z is free and a row holds it on the terrain)
            bound = self.options.contact_height == "bound"
            cz_lo, cz_hi = (self.task.terrain_height,) * 2 if bound else (-np.inf, np.inf)
            sc = L.slice("c")
            lower[:, sc] = np.where(contact[:, :, None], np.array([-np.inf, -np.inf, cz_lo]), 0.0).reshape(n_knots, 3 * P)
            upper[:, sc] = np.where(contact[:, :, None], np.array([np.inf, np.inf, cz_hi]), 0.0).reshape(n_knots, 3 * P)
        if self.options.acceleration_variables:
            lower[-1, L.slice("a")] = upper[-1, L.slice("a")] = 0.0
        lower[[0, -1], sv] = upper[[0, -1], sv] = 0.0
        lower, upper = jnp.asarray(lower), jnp.asarray(upper)
        # forces: touching points f_z in [0, F], |f_x|, |f_y| <= F (force_limits="rows": free,
        # limited by rows); others 0
        rows = self.options.force_limits == "rows"
        F = jnp.inf if rows else force_limit(theta)
        touching = np.repeat(contact, 3, axis=1)
        below = touching & (np.tile([True, True, False], P)[None] | rows)  # bounded below by -F
        lower = lower.at[:, sf].set(jnp.where(below, -F, 0.0))
        upper = upper.at[:, sf].set(jnp.where(touching, F, 0.0))
        # boundary conditions: at rest (above) at the standing and the target pose
        q0, qN = self._coords(
            jnp.stack([self._initial_xyz_wxyz(theta), self._target_xyz_wxyz(theta)]),
            jnp.stack([theta.q_joints_standing, self._q_joints_target(theta)]),
        )
        lower = lower.at[0, sq].set(q0).at[-1, sq].set(qN)
        upper = upper.at[0, sq].set(q0).at[-1, sq].set(qN)
        return lower, upper

    # -------------------------------------------------------------------- warm start
    def warm_start(self, theta: TaskParams | Mapping[str, Any] | None = None) -> np.ndarray:
        """The paper's non-informative warm start (plus the task's rotation rules): every knot
        at the standing pose at rest, the weight shared among the touching points.

        (n_knots, nz). The standing pose (base and joints) and the body masses are theta's
        (`resolve_theta`; None: the task's and robot's)."""
        robot, L = self.robot, self.layout
        n_knots, P = self.N + 1, self.P
        _check_euler_warm_start(self.task, self.param.name, self.options)  # a TaskError, not _warm_start_coords' ValueError
        host = self._host
        # the default theta's pose is initial_xyz_wxyz, which also checks the robot's stance
        resolved = self.resolve_theta(theta)
        initial = self.initial_xyz_wxyz if theta is None else np.asarray(host["initial"](resolved))
        theta = resolved
        poses = np.tile(initial, (n_knots, 1))
        # Euler angles written as they are (`TranscriptionOptions.warm_start_euler`): added to
        # the coordinates below instead of rotating the poses
        euler_angles = self.param.name == "euler" and self.options.warm_start_euler == "angles"
        rules = self.task.warm_start_angles(after_ramp="standing" if euler_angles else "hold")
        for axis, angles in [] if euler_angles else rules:
            poses[:, 3:] = np.asarray(host["rotate"](axis[None] * angles[:, None], poses[:, 3:]))
        if self.options.warm_start_quaternions == "matrix" and self.param.name.startswith("quat"):
            poses[:, 3:] = np.asarray(host["from_matrix"](poses[:, 3:]))
        qj = np.tile(np.asarray(theta.q_joints_standing, float), (n_knots, 1))
        placed = np.zeros(n_knots, bool)
        for rule in self.task.warm_start_joints:
            knots = np.isin(self.schedule.phase_of_knot, rule.phases)
            for joint, value in rule.joints:
                qj[knots, robot.joint_names.index(joint)] = value
            placed |= knots & rule.place_on_terrain
        contact = self.schedule.in_contact
        q = self._warm_start_coords(poses, qj, rules if euler_angles else [])
        if placed.any():
            # rest the touching points of the placed knots on the terrain (vertical shift)
            fk = np.asarray(host["fk"](q))
            for k in np.flatnonzero(placed & contact.any(axis=1)):
                poses[k, 2] -= float(np.mean(fk[k, contact[k], 2])) - self.task.terrain_height
            q = self._warm_start_coords(poses, qj, rules if euler_angles else [])
        Z = np.zeros((n_knots, L.nz))
        Z[:, L.slice("q")] = q
        n_touch = contact.sum(axis=1)
        f = np.zeros((n_knots, P, 3))
        weight = float(robot_mass(np.asarray(theta.body_masses))) * GRAVITY  # robot.total_mass g for the default
        f[:, :, 2] = np.where(contact, weight / np.maximum(n_touch, 1)[:, None], 0.0)
        Z[:, L.slice("f")] = f.reshape(n_knots, -1)
        if self.options.contact_variables:
            c = np.array(host["fk"](q))
            c[:, :, 2] = self.task.terrain_height
            Z[:, L.slice("c")] = np.where(contact[:, :, None], c, 0.0).reshape(n_knots, -1)
        return Z

    def _warm_start_coords(self, poses: np.ndarray, qj: np.ndarray, euler_rules: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
        """The coordinates q (n_knots, nq) of base poses (xyz_wxyz) and joint angles, with the
        Euler-angle rules' angles added to the roll, pitch or yaw of their axis."""
        q = np.array(self._host["coords"](poses, qj))
        for axis, angles in euler_rules:
            principal = np.flatnonzero(np.abs(axis) > 1e-12)
            if principal.size != 1:
                raise ValueError(f"warm_start_euler='angles' needs a warm-start rule about a principal axis (x, y or z), not {axis.tolist()}")
            i = int(principal[0])
            q[:, 3 + i] += np.sign(axis[i]) * angles  # (x, y, z, roll, pitch, yaw)
        return q

    # -------------------------------------------------------------------- decoding
    @cached_property
    def _decode_arrays(self):
        @jax.jit
        def arrays(q, v, a, f, masses):
            tau = jax.vmap(self._tau, in_axes=(0, 0, 0, 0, None))(q, v, a, f, masses)
            fk = jax.vmap(self._fk)(q)
            qpos = jax.vmap(self.param.to_qpos)(q[:, : self.param.nq])
            return tau, fk, qpos

        return arrays

    def decode(self, x: np.ndarray, theta: TaskParams | Mapping[str, Any] | None = None) -> Trajectory:
        """The trajectory of the solution ``x`` (n,) of the NLP at parameters ``theta``
        (`resolve_theta`: None is the task's, a mapping overrides some of them; a `TaskParams`,
        which solves have resolved already, is taken as it is)."""
        if not isinstance(theta, TaskParams):
            theta = self.resolve_theta(theta)
        h = float(theta.timestep)
        L, param = self.layout, self.param
        Z = jnp.asarray(np.asarray(x).reshape(self.N + 1, L.nz))
        s = L.split(Z)
        q, v, f = s["q"], s["v"], s["f"]
        if self.options.acceleration_variables:
            a = s["a"]
        else:
            a = jnp.concatenate([(v[1:] - v[:-1]) / h, jnp.zeros_like(v[:1])])
        tau, fk, qpos = self._decode_arrays(q, v, a, f, theta.body_masses)
        return Trajectory(
            t=np.arange(self.N + 1) * h,
            base_xyz_wxyz=np.asarray(qpos),
            q_base=np.asarray(q[:, : param.nq]),
            q_joints=np.asarray(q[:, param.nq :]),
            v=np.asarray(v),
            a=np.asarray(a),
            tau=np.asarray(tau),
            forces=np.asarray(f).reshape(-1, self.P, 3),
            contact_positions=np.asarray(fk),
            in_contact=self.schedule.in_contact.copy(),
            contact_names=self.contact_names,
        )


# ------------------------------------------------------------------------ stage builders
# Each builder returns the constraint groups of one stage of ``tr``'s NLP, written for one
# knot; a group's function takes ``(theta, data, *deps)`` (`jtraj.nlp.ConstraintGroup`).


def _dynamics_derivatives(tr: Transcription, theta: TaskParams, Q, V, A, Fv):
    """Analytical RNEA Jacobians at K knots; d tau / d a = M and d tau / d f = -J^T need no
    autodiff. Returns them and d tau / d f restricted to the task's points (K, nv, 3 P)."""
    nv, P = tr.nv, tr.P
    d = dynamics.batched_inverse_dynamics_derivatives(tr.robot, tr.param, Q, V, A, jax.vmap(tr._forces_all)(Fv), theta.body_masses)
    df = d.df.reshape(Q.shape[0], nv, -1, 3)[:, :, tr.points, :].reshape(Q.shape[0], nv, 3 * P)
    return d, df


def dynamics_stage(tr: Transcription) -> list[ConstraintGroup]:
    """Inverse dynamics: base rows 0 (no actuation), joint rows within the effort limits."""
    n_knots, N, nv = tr.N + 1, tr.N, tr.nv
    effort = np.asarray(tr.robot.tau_max, float)
    lo = np.concatenate([np.zeros(6), -effort])
    hi = np.concatenate([np.zeros(6), effort])
    tau = tr._tau

    if tr.options.acceleration_variables:

        def dyn(theta, data, q, v, a, f):
            return tau(q, v, a, f, theta.body_masses)

        def dyn_jac(theta, data, Q, V, A, Fv):
            d, df = _dynamics_derivatives(tr, theta, Q, V, A, Fv)
            return jnp.concatenate([d.dq, d.dv, d.da, df], axis=-1)

        return [
            ConstraintGroup(
                "dynamics", (Dep("q"), Dep("v"), Dep("a"), Dep("f")), dyn, np.arange(n_knots),
                np.tile(lo, (n_knots, 1)), np.tile(hi, (n_knots, 1)), np.ones((n_knots, nv), bool),
                batched_jacobian=dyn_jac,
            )
        ]

    # a_k = (v_{k+1} - v_k) / h at k < N; a_N = 0 (the final knot is at rest)
    def dyn_pair(theta, data, q, v, f, v1):
        return tau(q, v, (v1 - v) / theta.timestep, f, theta.body_masses)

    def dyn_pair_jac(theta, data, Q, V, Fv, V1):
        h = theta.timestep
        d, df = _dynamics_derivatives(tr, theta, Q, V, (V1 - V) / h, Fv)
        return jnp.concatenate([d.dq, d.dv - d.da / h, df, d.da / h], axis=-1)

    def dyn_last(theta, data, q, v, f):
        return tau(q, v, jnp.zeros_like(v), f, theta.body_masses)

    def dyn_last_jac(theta, data, Q, V, Fv):
        d, df = _dynamics_derivatives(tr, theta, Q, V, jnp.zeros_like(V), Fv)
        return jnp.concatenate([d.dq, d.dv, df], axis=-1)

    return [
        ConstraintGroup(
            "dynamics", (Dep("q"), Dep("v"), Dep("f"), Dep("v", 1)), dyn_pair, np.arange(N),
            np.tile(lo, (N, 1)), np.tile(hi, (N, 1)), np.ones((N, nv), bool),
            batched_jacobian=dyn_pair_jac,
        ),
        ConstraintGroup(
            "dynamics", (Dep("q"), Dep("v"), Dep("f")), dyn_last, np.array([N]),
            lo[None], hi[None], np.ones((1, nv), bool), batched_jacobian=dyn_last_jac,
        ),
    ]


def integration_stage(tr: Transcription) -> list[ConstraintGroup]:
    """Semi-implicit Euler between knots k and k+1 (see `Transcription.step`)."""
    param, N, nqb, nj, nv = tr.param, tr.N, tr.param.nq, tr.nj, tr.nv

    def position_step(h, q, q1, v1):
        r_base = param.difference(param.integrate(q[:nqb], v1[:6], h), q1[:nqb])
        r_j = q1[nqb:] - q[nqb:] - v1[6:] * h
        return jnp.concatenate([r_base, r_j])

    if tr.options.acceleration_variables:

        stepped = tr.options.position_step == "stepped"

        def integ(theta, data, q, v, a, q1, v1):
            h = theta.timestep
            # "stepped": v_k + a_k h stands for v_{k+1} (equal where the velocity row holds)
            return jnp.concatenate([v1 - v - a * h, position_step(h, q, q1, v + a * h if stepped else v1)])

        deps = (Dep("q"), Dep("v"), Dep("a"), Dep("q", 1), Dep("v", 1))
        n_rows = nv + param.ndiff + nj
    else:

        def integ(theta, data, q, q1, v1):
            return position_step(theta.timestep, q, q1, v1)

        deps = (Dep("q"), Dep("q", 1), Dep("v", 1))
        n_rows = param.ndiff + nj
    zeros = np.zeros((N, n_rows))
    return [ConstraintGroup("integration", deps, integ, np.arange(N), zeros, zeros, np.ones((N, n_rows), bool))]


def contact_stage(tr: Transcription) -> list[ConstraintGroup]:
    """Touching points on the terrain, and their x, y kept while they keep touching."""
    n_knots, N, P, fk = tr.N + 1, tr.N, tr.P, tr._fk
    if not P:
        return []
    contact = tr.schedule.in_contact
    both = contact[:-1] & contact[1:]
    knots, pairs = np.arange(n_knots), np.arange(N)
    stay = np.zeros((N, 2 * P))
    if tr.options.contact_variables:
        # FK = c; c_z is the terrain height (a bound, or with contact_height="row" a row, and
        # the stationarity rows keep z too)
        rows = tr.options.contact_height == "row"
        kept = 3 if rows else 2
        groups = [
            ConstraintGroup(
                "contact", (Dep("q"), Dep("c")), lambda theta, data, q, c: (fk(q) - c.reshape(P, 3)).reshape(-1), knots,
                np.zeros((n_knots, 3 * P)), np.zeros((n_knots, 3 * P)), np.repeat(contact, 3, axis=1),
            ),
            ConstraintGroup(
                "stationary", (Dep("c"), Dep("c", 1)),
                lambda theta, data, c, c1: (c1.reshape(P, 3)[:, :kept] - c.reshape(P, 3)[:, :kept]).reshape(-1), pairs,
                np.zeros((N, kept * P)), np.zeros((N, kept * P)), np.repeat(both, kept, axis=1),
            ),
        ]
        if rows:
            height = np.full((n_knots, P), tr.task.terrain_height)
            groups.insert(1, ConstraintGroup("height", (Dep("c"),), lambda theta, data, c: c.reshape(P, 3)[:, 2], knots, height, height, contact))
        return groups
    terrain = np.full((n_knots, P), tr.task.terrain_height)
    return [
        ConstraintGroup("contact", (Dep("q"),), lambda theta, data, q: fk(q)[:, 2], knots, terrain, terrain, contact),
        ConstraintGroup(
            "stationary", (Dep("q"), Dep("q", 1)), lambda theta, data, q, q1: (fk(q1)[:, :2] - fk(q)[:, :2]).reshape(-1), pairs,
            stay, stay, np.repeat(both, 2, axis=1),
        ),
    ]


def clearance_stage(tr: Transcription) -> list[ConstraintGroup]:
    """Points in the air stay above the terrain."""
    n_knots, P, fk = tr.N + 1, tr.P, tr._fk
    if not P:
        return []
    return [
        ConstraintGroup(
            "clearance", (Dep("q"),), lambda theta, data, q: fk(q)[:, 2], np.arange(n_knots),
            np.full((n_knots, P), tr.task.terrain_height), np.full((n_knots, P), np.inf), ~tr.schedule.in_contact,
        )
    ]


def friction_stage(tr: Transcription) -> list[ConstraintGroup]:
    """The 4-facet friction pyramid ``|f_x|, |f_y| <= mu f_z`` of touching points."""
    n_knots, P = tr.N + 1, tr.P
    if not P:
        return []

    def friction(theta, data, f):
        mu = theta.friction
        f = f.reshape(P, 3)
        fx, fy, fz = f[:, 0], f[:, 1], f[:, 2]
        return jnp.stack([mu * fz - fx, mu * fz + fx, mu * fz - fy, mu * fz + fy], axis=1).reshape(-1)

    return [
        ConstraintGroup(
            "friction", (Dep("f"),), friction, np.arange(n_knots),
            np.zeros((n_knots, 4 * P)), np.full((n_knots, 4 * P), np.inf), np.repeat(tr.schedule.in_contact, 4, axis=1),
        )
    ]


def robot_mass(body_masses):
    """The robot's mass m from ``body_masses`` (numpy's on the host, JAX's in the NLP): the
    bodies' sum less the world body's (first; 0 when checked: no dynamics has it). The whole sum
    first, as before the world's was left out: the sum of the others rounds differently
    (16.085000000000004 against 16.085 kg on the Go2), and the side-flip's iterations follow it."""
    return body_masses.sum() - body_masses[0]


def force_limit(theta: TaskParams) -> jax.Array:
    """F = force_limit_factor m g (N): the largest contact force of a point (its components'
    bound, or with `TranscriptionOptions.force_limits` ``"rows"`` its norm's)."""
    return theta.force_limit_factor * robot_mass(theta.body_masses) * GRAVITY


def force_limit_stage(tr: Transcription) -> list[ConstraintGroup]:
    """With `TranscriptionOptions.force_limits` ``"rows"``: ``f_z >= 0`` and ``|f| <= F`` (F =
    force_limit_factor m g, the Euclidean norm) of touching points, as the study's code writes
    them; with ``"bounds"`` (the default) variable bounds do this and there are no rows."""
    n_knots, P = tr.N + 1, tr.P
    if not P or tr.options.force_limits == "bounds":
        return []

    def limits(theta, data, f):
        F = force_limit(theta)
        f = f.reshape(P, 3)
        # the norm's gradient f / |f| is 0 rather than NaN at f = 0
        norm = jnp.sqrt(jnp.maximum(jnp.sum(f * f, axis=1), 1e-300))
        return jnp.stack([f[:, 2], F - norm], axis=1).reshape(-1)

    return [
        ConstraintGroup(
            "force_limit", (Dep("f"),), limits, np.arange(n_knots),
            np.zeros((n_knots, 2 * P)), np.full((n_knots, 2 * P), np.inf), np.repeat(tr.schedule.in_contact, 2, axis=1),
        )
    ]


def force_rate_stage(tr: Transcription) -> list[ConstraintGroup]:
    """``|f_j' - f_j| <= max_delta_force`` per component while a point keeps touching (with
    `TranscriptionOptions.liftoff_force_rate` also where it lifts off: f_j' is 0 there, fixed by
    bounds, so the row bounds the last stance force)."""
    if not tr.P or tr.task.max_delta_force is None:
        return []
    contact = tr.schedule.in_contact
    rated = contact[:-1] if tr.options.liftoff_force_rate else contact[:-1] & contact[1:]
    return [
        ConstraintGroup(
            "force_rate", (Dep("f"), Dep("f", 1)), lambda theta, data, f, f1: f1 - f, np.arange(tr.N),
            lambda theta: -theta.max_delta_force, lambda theta: theta.max_delta_force,
            np.repeat(rated, 3, axis=1),
        )
    ]


def chart_stage(tr: Transcription) -> list[ConstraintGroup]:
    """The parameterization's own constraint (a unit quaternion norm), if it has one, at the
    interior knots: the first and last knots' coordinates are fixed by their bounds (the
    standing and the target pose, unit quaternions), so a row there would read no free variable
    and constrain nothing (an empty Jacobian row; measured harmless to Ipopt on big_jump with
    Quaternion #3, 12 iterations either way, but no constraint)."""
    param, n_inner = tr.param, tr.N - 1
    if not param.ncon:
        return []
    zeros = np.zeros((n_inner, param.ncon))
    return [
        ConstraintGroup(
            "chart", (Dep("q"),), lambda theta, data, q: param.constraint(q[: param.nq]), np.arange(1, tr.N),
            zeros, zeros, np.ones((n_inner, param.ncon), bool),
        )
    ]


#: The constraint stages of a transcription, in the order of the NLP's rows.
CONSTRAINT_STAGES = (dynamics_stage, integration_stage, contact_stage, clearance_stage, friction_stage, force_limit_stage, force_rate_stage, chart_stage)


def cost_terms(tr: Transcription) -> list[CostGroup]:
    """1/2 w_q |q_j - q_j,standing|^2 and 1/2 w_a |a_j|^2 per knot; both are kept when a
    weight is 0, so that theta can make it positive."""
    nqb, knots = tr.param.nq, np.arange(tr.N + 1)

    def configuration(theta, data, q):
        return 0.5 * theta.configuration_weight * jnp.sum((q[nqb:] - theta.q_joints_standing) ** 2)

    costs = [CostGroup("configuration", (Dep("q"),), configuration, knots)]
    if tr.options.acceleration_variables:
        costs.append(CostGroup("acceleration", (Dep("a"),), lambda theta, data, a: 0.5 * theta.acceleration_weight * jnp.sum(a[6:] ** 2), knots))
    else:  # a_N = 0 adds nothing

        def acceleration(theta, data, v, v1):
            return 0.5 * theta.acceleration_weight * jnp.sum(((v1 - v)[6:] / theta.timestep) ** 2)

        costs.append(CostGroup("acceleration", (Dep("v"), Dep("v", 1)), acceleration, np.arange(tr.N)))
    return costs
