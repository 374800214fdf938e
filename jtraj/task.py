"""Tasks as validated data: robot, timestep, contact phases, target, weights, warm start.

A task is a frozen `Task`; the paper's six tasks live in ``tasks/*.toml`` (`load`), and a
user can write a TOML file of the same form (`from_file`) or build a `Task` in Python.
Every field is checked when a `Task` is built (from TOML, a dict or Python), before anything
compiles; `Task.validate(robot)` adds the checks that need the robot model (contact and joint
names, joint limits). Both raise `TaskError` naming the field, the offending value and what
was expected.

TOML form (see ``tasks/*.toml``; this example loads as it is, a back-flip of Talos)::

    name = "my_flip"                 # names the run folders (runs/my_flip_se3): no '/', not '.'-first
    robot = "talos"
    timestep = 0.05
    friction = 0.9
    max_delta_force = 100.0          # optional, N per knot and component
    max_iter = 200                   # optional, Ipopt's iteration limit for this task
    force_limit_factor = 1.5         # optional: |f| <= factor * m g per force component
    terrain_height = 0.0             # optional: height of the flat ground (m)
    description = "..."              # optional, free text (not part of the content hash)
    flip_axis = [0.0, 1.0, 0.0]      # optional: the task is a flip about this world axis
    flip_turns = -1                  # its expected signed turns (right-hand rule; whole, with no rotation_rpy)
    [target]
    translation = [1.0, 0.0, 0.0]    # base displacement from the standing pose, world frame (m)
    rotation_rpy = [0.0, 0.0, 0.0]   # base rotation from the standing pose (rad, each in [-pi, pi])
    # joints = [...]                 # optional: the final joint angles, one per joint (rad)
    [costs]
    configuration = 0.0              # 1/2 w |q_joints - q_joints_standing|^2 per knot
    acceleration = 0.0               # 1/2 w |a_joints|^2 per knot
    [[phases]]                       # phase 0: stance
    contacts = ["left_foot", "right_foot"]
    duration = 0.5
    [[phases]]                       # phase 1: flight
    contacts = []
    duration = 0.6
    [[phases]]                       # phase 2: landing
    contacts = ["left_foot", "right_foot"]
    duration = 0.5
    [[warm_start_rules]]             # optional base-rotation rules on top of the stance
    profile = "ramp"                 # "ramp" (0 -> angle over the phases) or "hold"
    axis = [0.0, 1.0, 0.0]
    angle = -6.283185307179586
    phases = [1]
    [[warm_start_joints]]            # optional joint overrides during phases
    phases = [1]
    joints = { arm_left_2_joint = 2.8 }
    place_on_terrain = true          # shift the base so the touching points rest on the ground

``[[warm_start]]`` (and ``Task(warm_start=...)``) is the former name of ``warm_start_rules``:
still read, with a `DeprecationWarning`.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import importlib.resources
import math
import tomllib
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from jtraj.deprecation import warn_renamed
from jtraj.numbers import unit_and_length

__all__ = ["TaskError", "Phase", "Profile", "RotationRule", "JointRule", "Task", "Schedule", "load", "from_file", "from_dict", "available", "retarget", "task_argument", "MAX_KNOTS", "MAX_ITER", "RPY_LIMIT"]

#: The most knots a task may have (the largest built-in task, the walk, has 125): every knot's variables,
#: rows and Jacobian blocks are allocated, and a timestep of 1e-7 s (23 million knots) ran
#: out of memory
MAX_KNOTS = 100_000
#: The largest iteration limit: Ipopt's max_iter is a C int, and a larger one passed the task
#: check to fail inside Ipopt's option check
MAX_ITER = 2**31 - 1
#: The largest |angle| (rad) of ``target_rotation_rpy``: half a turn, with a margin (3.1416,
#: float32's pi, is half a turn). A larger angle is a smaller one's attitude (a spin of 2 pi
#: solved as a plain hop) or degrees typed for radians (90 solved as 116.6 degrees).
RPY_LIMIT = math.pi + 1e-3


class TaskError(ValueError):
    """A task definition that cannot be solved as written.

    ``field`` is the TOML path of the offending entry (``target.translation``,
    ``phases[1].duration``), ``value`` what was given and ``expected`` what would be accepted;
    ``source`` is the file (or ``<dict>``) it came from, if any. ``str(error)`` is one line,
    ``"SOURCE: FIELD: VALUE: EXPECTED"``.
    """

    def __init__(self, field: str, value: Any, expected: str, source: str | None = None):
        self.field, self.value, self.expected, self.source = field, value, expected, source
        super().__init__(self._line())

    def __reduce__(self):
        # rebuilt from its fields (pickled from a worker process: the default rebuilt it from
        # the one-line message alone, which __init__ does not take)
        return (type(self), (self.field, self.value, self.expected, self.source))

    def _line(self) -> str:
        value = self.value if isinstance(self.value, _Raw) else repr(self.value)
        head = f"{self.source}: " if self.source else ""
        return f"{head}{self.field}: {value}: {self.expected}"

    def with_source(self, source: str, renamed: dict[str, str] | None = None) -> TaskError:
        """The same error, attributed to ``source`` (a file name), its field named by its TOML
        path (``target_joints[3]`` is ``target.joints[3]`` there); ``renamed`` adds names the
        file uses instead (a former name)."""
        field = self.field
        for python, toml in (_TOML_NAMES if renamed is None else {**_TOML_NAMES, **renamed}).items():
            if field == python or field.startswith((f"{python}[", f"{python}.")):
                field = toml + field[len(python) :]
                break
        return TaskError(field, self.value, self.expected, source)


class _Raw(str):
    """A value already written for the message (not repr'd again)."""


@dataclasses.dataclass(frozen=True)
class Phase:
    """A contact phase: the contact groups touching the ground, for ``duration`` seconds."""

    contacts: tuple[str, ...]
    duration: float


class Profile(enum.Enum):
    """How a `RotationRule` turns the base over its phases."""

    RAMP = "ramp"  # the angle grows linearly from 0 to `angle` over the phases, then stays
    HOLD = "hold"  # the angle is `angle` during the phases, 0 elsewhere


@dataclasses.dataclass(frozen=True)
class RotationRule:
    """Warm-start rule: rotate the base about a world axis during some phases."""

    profile: Profile
    axis: tuple[float, float, float]
    angle: float
    phases: tuple[int, ...]


@dataclasses.dataclass(frozen=True)
class JointRule:
    """Warm-start rule: set some joints during some phases; optionally shift the base
    vertically so that the points touching the ground in those knots rest on the terrain."""

    phases: tuple[int, ...]
    joints: tuple[tuple[str, float], ...]
    place_on_terrain: bool = False


@dataclasses.dataclass(frozen=True)
class Schedule:
    """Knots of a task: phase of each knot and which contact points touch at each knot."""

    n_knots: int  # N + 1
    phase_of_knot: np.ndarray  # (n_knots,)
    points: tuple[int, ...]  # robot contact-point indices the task uses
    in_contact: np.ndarray  # (n_knots, len(points)) bool
    phase_knots: tuple[int, ...]  # knots per phase


@dataclasses.dataclass(frozen=True)
class Task:
    """A trajectory-optimization task (see the module docstring for the fields' meaning)."""

    name: str
    robot: str
    timestep: float
    phases: tuple[Phase, ...]
    target_translation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    target_rotation_rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    target_joints: tuple[float, ...] | None = None
    friction: float = 0.9
    max_delta_force: float | None = None
    force_limit_factor: float = 1.5  # |f_i| <= factor * m g per component
    configuration_weight: float = 0.0
    acceleration_weight: float = 0.0
    warm_start_rules: tuple[RotationRule, ...] = ()
    warm_start_joints: tuple[JointRule, ...] = ()
    flip_axis: tuple[float, float, float] | None = None  # world axis of the flip, any length
    flip_turns: float | None = None  # expected signed turns about flip_axis (back-flip about +y: -1)
    max_iter: int = 200
    terrain_height: float = 0.0
    description: str = ""

    def __post_init__(self):
        # robot-independent checks, whichever way the task is built (TOML, dict, Python)
        _check_and_normalize(self)

    # -------------------------------------------------------------- knots and contacts
    def phase_knot_counts(self) -> tuple[int, ...]:
        """Knots per phase, ``round(duration / h)`` (the study's public code truncates,
        ``int(duration / h)``: 0.3 / 0.05 gives 5)."""
        return tuple(int(round(p.duration / self.timestep)) for p in self.phases)

    @property
    def n_intervals(self) -> int:
        return sum(self.phase_knot_counts())

    @property
    def n_knots(self) -> int:
        return self.n_intervals + 1

    def schedule(self, robot) -> Schedule:
        counts = self.phase_knot_counts()
        phase_of_knot = np.repeat(np.arange(len(counts)), counts)
        phase_of_knot = np.append(phase_of_knot, len(counts) - 1)  # last knot: last phase
        points: list[int] = []
        for phase in self.phases:
            for group in phase.contacts:
                for idx in robot.contact_groups[group]:
                    if idx not in points:
                        points.append(idx)
        points.sort()
        in_contact = np.zeros((phase_of_knot.size, len(points)), bool)
        for k, pi in enumerate(phase_of_knot):
            touching = {i for g in self.phases[pi].contacts for i in robot.contact_groups[g]}
            in_contact[k] = [p in touching for p in points]
        return Schedule(phase_of_knot.size, phase_of_knot, tuple(points), in_contact, counts)

    def warm_start_angles(self, after_ramp: str = "hold") -> list[tuple[np.ndarray, np.ndarray]]:
        """Per rule: (axis, angle at every knot) of the base rotation of the warm start.

        ``after_ramp``: the knots after a ramp's last knot keep its final angle (``"hold"``,
        the default: for a full turn, the same rotation as the start) or go back to 0
        (``"standing"``), as the study's flip scripts leave the nodes after the ramp."""
        if after_ramp not in ("hold", "standing"):
            raise ValueError(f"after_ramp={after_ramp!r}: expected 'hold' or 'standing'")
        counts = self.phase_knot_counts()
        starts = np.concatenate([[0], np.cumsum(counts)])
        out = []
        for rule in self.warm_start_rules:
            angles = np.zeros(self.n_knots)
            first = starts[min(rule.phases)]
            last = starts[max(rule.phases) + 1]
            if rule.profile is Profile.RAMP:
                k = np.arange(self.n_knots)
                angles = rule.angle * np.clip((k - first) / max(last - first, 1), 0.0, 1.0)
                if after_ramp == "standing":
                    angles[k > last] = 0.0
            else:
                for p in rule.phases:
                    angles[starts[p] : starts[p + 1]] = rule.angle
            out.append((unit_and_length(rule.axis)[0], angles))
        return out

    # -------------------------------------------------------------- validation
    def error(self, field: str, value: Any, expected: str) -> TaskError:
        """A `TaskError` about this task's ``field``, naming the file the task came from where
        it came from one (`from_file`, `load`), as `validate`'s errors do."""
        error = TaskError(field, value, expected)
        source = getattr(self, "_source", None)
        return error if source is None else error.with_source(source)

    def validate(self, robot=None) -> Task:
        """Raise `TaskError` for what needs the robot model (contact and joint names, joint
        limits); the rest was checked when the task was built. Return self. The error of a
        task loaded from a file (`from_file`, `load`) names the file."""
        source = getattr(self, "_source", None)
        try:
            return self._validate(robot)
        except TaskError as e:
            if source is None:
                raise
            raise e.with_source(source) from None

    def _validate(self, robot) -> Task:
        from jtraj import robot as robot_module

        if robot is None:
            robot = robot_module.load(self.robot)
        groups = sorted(robot.contact_groups)
        for i, phase in enumerate(self.phases):
            for c in phase.contacts:
                if c not in robot.contact_groups:
                    raise TaskError(f"phases[{i}].contacts", c, f"expected a contact of robot {robot.name!r}: one of {groups}")
        for i, rule in enumerate(self.warm_start_joints):
            for joint, value in rule.joints:
                if joint not in robot.joint_names:
                    raise TaskError(f"warm_start_joints[{i}].joints", joint, f"unknown joint; expected one of {list(robot.joint_names)}")
                j = robot.joint_names.index(joint)
                if not robot.q_lower[j] <= value <= robot.q_upper[j]:
                    raise TaskError(
                        f"warm_start_joints[{i}].joints.{joint}", value, f"outside the joint limits [{robot.q_lower[j]:g}, {robot.q_upper[j]:g}] rad"
                    )
        if self.target_joints is not None:
            tj = np.asarray(self.target_joints, float)
            if tj.shape != (robot.nj,):
                raise TaskError("target_joints", _Raw(f"{tj.size} values"), f"expected {robot.nj} (one per joint of {robot.name!r})")
            lo, hi = robot.q_lower, robot.q_upper
            outside = robot.joints_outside_limits(tj)
            if outside.size:
                j = outside[0]
                raise TaskError(f"target_joints[{j}] ({robot.joint_names[j]})", float(tj[j]), f"outside the joint limits [{lo[j]:g}, {hi[j]:g}] rad")
        return self

    def content_hash(self) -> str:
        """A hex digest of everything that defines the problem (every field but the
        description): equal for equal tasks, whatever file or name they came from."""
        import hashlib
        import json

        data = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "description"}
        # hashed under its former name: the digests of earlier runs (runs.jsonl keys) stay valid
        data["warm_start"] = data.pop("warm_start_rules")
        text = json.dumps(data, default=lambda o: o.value if isinstance(o, enum.Enum) else dataclasses.asdict(o), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def replace(self, **changes: Any) -> Task:
        return dataclasses.replace(self, **changes)


# ``warm_start`` is the former name of ``warm_start_rules``: the constructor still takes it and
# reading it still works, both with a warning. It is not a field, so `dataclasses.replace` and
# the content hash see only the new name.
_dataclass_init = Task.__init__


@functools.wraps(_dataclass_init)
def _task_init(self: Task, *args: Any, warm_start: tuple[RotationRule, ...] | None = None, **kwargs: Any) -> None:
    if warm_start is not None:
        if kwargs.get("warm_start_rules"):
            raise TaskError("warm_start", _Raw("given with warm_start_rules"), "expected only warm_start_rules (warm_start is its former name)")
        warn_renamed("Task(warm_start=...)", "Task(warm_start_rules=...)")
        kwargs["warm_start_rules"] = warm_start
    _dataclass_init(self, *args, **kwargs)


def _former_warm_start(task: Task) -> tuple[RotationRule, ...]:
    warn_renamed("Task.warm_start", "Task.warm_start_rules")
    return task.warm_start_rules


Task.__init__ = _task_init
Task.warm_start = property(_former_warm_start)  # type: ignore[attr-defined]


# ------------------------------------------------------------------ checks
def _is_real(x: Any) -> bool:
    if not isinstance(x, (int, float, np.integer, np.floating)) or isinstance(x, (bool, np.bool_)):
        return False
    try:
        return math.isfinite(float(x))
    except OverflowError:  # an integer past float's range (TOML reads any size): a traceback before
        return False


def _is_list(value: Any, *single: type) -> bool:
    """Whether ``value`` is a list of items: iterable, and not a string (whose characters would
    be the items) nor one item of the types ``single`` given in place of the list."""
    return not isinstance(value, (str, bytes, *single)) and hasattr(value, "__iter__")


def _real(value: Any, field: str, expected: str = "expected a number", positive: bool = False, nonnegative: bool = False) -> float:
    if not _is_real(value):
        raise TaskError(field, value, expected)
    x = float(value)
    if (positive and not x > 0) or (nonnegative and not x >= 0):
        raise TaskError(field, value, expected)
    return x


def _vector(value: Any, field: str, n: int = 3, nonzero: bool = False) -> tuple[float, ...]:
    """``value`` as ``n`` floats; ``nonzero``: an axis, whose length must be nonzero and finite
    where it is computed without scaling (np.linalg.norm, as `jtraj.success` does): [1e-200, 0, 0]
    has the length 0 there, [1e200, 1e200, 0] an infinite one, and dividing by it gave NaN or a
    zero axis."""
    expected = f"expected a list of {n} numbers" + (", not all zero" if nonzero else "")
    shown = _Raw(repr(list(value)) if isinstance(value, (tuple, np.ndarray)) else repr(value))
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != n or not all(_is_real(x) for x in value):
        raise TaskError(field, shown, expected)
    out = tuple(float(x) for x in value)
    if nonzero and not any(out):
        raise TaskError(field, shown, expected)
    if nonzero and not 1e-300 <= sum(x * x for x in out) <= 1e300:  # a length in [1e-150, 1e150]
        raise TaskError(field, shown, "expected an axis of length between 1e-150 and 1e150, e.g. [1, 0, 0] (its length does not matter, only its direction)")
    return out


def _indices(value: Any, field: str, n_phases: int) -> tuple[int, ...]:
    expected = f"expected a non-empty list of phase indices in 0..{n_phases - 1}"
    if not _is_list(value):
        raise TaskError(field, value, expected)
    items = tuple(value)
    if not items or not all(isinstance(p, (int, np.integer)) and not isinstance(p, bool) and 0 <= p < n_phases for p in items):
        raise TaskError(field, _Raw(repr(list(items))), expected)
    return tuple(int(p) for p in items)


#: the longest task name, in UTF-8 bytes: room in a 255-byte folder name for "_" and a
#: parameterization's name, and for a sweep's suffixes
MAX_NAME_BYTES = 200


def _check_and_normalize(t: Task) -> None:
    """Check every field that does not need the robot model; store tuples and floats.

    Field names in errors are the Python names; `from_dict` maps them to TOML paths."""
    from jtraj import robot as robot_module

    def put(name: str, value: Any) -> None:
        object.__setattr__(t, name, value)

    if not isinstance(t.name, str) or not t.name.strip():
        raise TaskError("name", t.name, "expected a non-empty string")  # (" " named the folder runs/ _se3)
    if t.name != t.name.strip():
        raise TaskError("name", t.name, "expected a name without leading or trailing spaces (it names the run folders)")
    # the name is a folder's in runs/ (runs/NAME_PARAM, a sweep's OUT/NAME_PARAM): "../x" wrote outside it
    if t.name.startswith(".") or any(sep in t.name for sep in ("/", "\\")) or not t.name.isprintable():
        raise TaskError("name", t.name, "expected a plain name for the run folders (e.g. my_jump): no '/' or '\\', no control characters, not starting with '.'")
    # a folder name of NAME_PARAM must fit the file system's 255 bytes (300 characters ended
    # jtraj solve in OSError "File name too long")
    if len(t.name.encode()) > MAX_NAME_BYTES:
        raise TaskError("name", t.name, f"expected a name of at most {MAX_NAME_BYTES} bytes (it names the run folders)")
    robots = robot_module.available()
    if t.robot not in robots:
        raise TaskError("robot", t.robot, f"expected one of {list(robots)}")
    put("timestep", _real(t.timestep, "timestep", "expected a positive number of seconds", positive=True))
    if not _is_list(t.phases):
        raise TaskError("phases", t.phases, "expected a list of phases (each with contacts and duration)")
    phases = tuple(t.phases)
    if not phases:
        raise TaskError("phases", _Raw("[]"), "expected at least one contact phase")
    checked = []
    for i, phase in enumerate(phases):
        if not isinstance(phase, Phase):
            raise TaskError(f"phases[{i}]", phase, "expected a Phase(contacts, duration)")
        contacts = phase.contacts
        if not _is_list(contacts) or not all(isinstance(c, str) for c in contacts):
            raise TaskError(f"phases[{i}].contacts", contacts, 'expected a list of contact names, e.g. ["FL_foot", "FR_foot"] ([] for flight)')
        repeated = sorted({c for c in contacts if list(contacts).count(c) > 1})
        if repeated:  # (accepted without a word; likely a slip for another contact)
            raise TaskError(f"phases[{i}].contacts", contacts, f"{', '.join(map(repr, repeated))} given more than once; expected each contact once")
        duration = _real(phase.duration, f"phases[{i}].duration", "expected a positive number of seconds", positive=True)
        knots = duration / t.timestep
        if knots < 1 - 1e-6:
            raise TaskError(f"phases[{i}].duration", duration, f"shorter than one knot (timestep {t.timestep:g} s); expected at least {t.timestep:g} s")
        # (before rounding: a timestep of 5e-324 s made the count infinite, and round() failed)
        if not knots + 1 <= MAX_KNOTS:  # (the phase's knots: its intervals and one end)
            raise TaskError(
                f"phases[{i}].duration", duration, f"{knots + 1:.6g} knots at the timestep {t.timestep:g} s; expected at most {MAX_KNOTS} knots in a task (a longer timestep or a shorter phase)"
            )
        # a phase is a whole number of knot intervals: rounding 0.12 s to 0.1 s at 0.05 s
        # would silently change the motion (a shorter flight) from what the file says
        if abs(knots - round(knots)) > 1e-6 * max(1.0, knots):
            below, above = math.floor(knots) * t.timestep, math.ceil(knots) * t.timestep
            raise TaskError(f"phases[{i}].duration", duration, f"not a whole number of timesteps ({t.timestep:g} s); expected a multiple such as {below:.6g} or {above:.6g} s")
        checked.append(Phase(tuple(contacts), duration))
    put("phases", tuple(checked))
    n_knots = sum(round(p.duration / t.timestep) for p in checked) + 1
    if n_knots > MAX_KNOTS:
        total = math.fsum(p.duration for p in checked)
        raise TaskError("timestep", t.timestep, f"{n_knots} knots over the phases' {total:g} s; expected at most {MAX_KNOTS} knots in a task (a longer timestep or shorter phases)")
    if not checked[0].contacts:
        raise TaskError("phases[0].contacts", _Raw("[]"), "expected the task to start in contact (it starts at rest)")
    if not checked[-1].contacts:
        raise TaskError(f"phases[{len(checked) - 1}].contacts", _Raw("[]"), "expected the task to end in contact (it ends at rest)")
    put("target_translation", _vector(t.target_translation, "target_translation"))
    put("target_rotation_rpy", _vector(t.target_rotation_rpy, "target_rotation_rpy"))
    # an angle past half a turn is the attitude of a smaller one: [0, 0, 2 pi] (a spin meant)
    # solved as a plain hop, and degrees typed for radians (90) as 116.6 degrees
    if any(abs(a) > RPY_LIMIT for a in t.target_rotation_rpy):
        raise TaskError(
            "target_rotation_rpy", list(t.target_rotation_rpy),
            "expected angles (rad) within [-pi, pi]: the target is an attitude, so a larger angle is a smaller one's attitude; whole turns on the way are flip_axis and flip_turns",
        )
    if t.target_joints is not None:
        tj = t.target_joints
        if not _is_list(tj) or not all(_is_real(x) for x in tj):
            raise TaskError("target_joints", tj, "expected a list of joint angles (rad)")
        put("target_joints", tuple(float(x) for x in tj))
    put("friction", _real(t.friction, "friction", "expected a positive friction coefficient", positive=True))
    if t.max_delta_force is not None:
        put("max_delta_force", _real(t.max_delta_force, "max_delta_force", "expected a positive force (N) or no entry", positive=True))
    put("force_limit_factor", _real(t.force_limit_factor, "force_limit_factor", "expected a positive factor of m g", positive=True))
    put("configuration_weight", _real(t.configuration_weight, "configuration_weight", "expected a weight >= 0", nonnegative=True))
    put("acceleration_weight", _real(t.acceleration_weight, "acceleration_weight", "expected a weight >= 0", nonnegative=True))
    rules = []
    # one rule, or None, in place of the tuple: "'RotationRule' object is not iterable" before
    if not _is_list(t.warm_start_rules, RotationRule):
        raise TaskError("warm_start_rules", t.warm_start_rules, "expected a list of RotationRule (empty: none)")
    if not _is_list(t.warm_start_joints, JointRule):
        raise TaskError("warm_start_joints", t.warm_start_joints, "expected a list of JointRule (empty: none)")
    for i, rule in enumerate(tuple(t.warm_start_rules)):
        if not isinstance(rule, RotationRule):
            raise TaskError(f"warm_start_rules[{i}]", rule, "expected a RotationRule(profile, axis, angle, phases)")
        profile = rule.profile
        if isinstance(profile, str) and profile in {p.value for p in Profile}:  # "ramp" was refused as not 'ramp'
            profile = Profile(profile)
            rule = dataclasses.replace(rule, profile=profile)
        if not isinstance(profile, Profile):
            raise TaskError(f"warm_start_rules[{i}].profile", rule.profile, "expected 'ramp' or 'hold'")
        axis = _vector(rule.axis, f"warm_start_rules[{i}].axis", nonzero=True)
        angle = _real(rule.angle, f"warm_start_rules[{i}].angle", "expected an angle in radians")
        phases_i = _indices(rule.phases, f"warm_start_rules[{i}].phases", len(checked))
        if rule.profile is Profile.RAMP and sorted(set(phases_i)) != list(range(min(phases_i), max(phases_i) + 1)):
            # a ramp runs from its first phase's start to its last phase's end: a gap in the
            # list would be ramped through as if it were listed
            raise TaskError(
                f"warm_start_rules[{i}].phases", _Raw(repr(list(phases_i))), f"a ramp spans consecutive phases; expected every index from {min(phases_i)} to {max(phases_i)}"
            )
        rules.append(RotationRule(rule.profile, axis, angle, phases_i))
    put("warm_start_rules", tuple(rules))
    joint_rules = []
    set_by: dict[tuple[int, str], int] = {}  # (phase, joint) -> the rule that sets it
    for i, rule in enumerate(tuple(t.warm_start_joints)):
        if not isinstance(rule, JointRule):
            raise TaskError(f"warm_start_joints[{i}]", rule, "expected a JointRule(phases, joints, place_on_terrain)")
        phases_i = _indices(rule.phases, f"warm_start_joints[{i}].phases", len(checked))
        joints = []
        for item in tuple(rule.joints):
            if not (isinstance(item, tuple) and len(item) == 2 and isinstance(item[0], str)):
                raise TaskError(f"warm_start_joints[{i}].joints", item, "expected joint = angle (rad) entries")
            joints.append((item[0], _real(item[1], f"warm_start_joints[{i}].joints.{item[0]}", "expected an angle in radians")))
        if not joints:
            raise TaskError(f"warm_start_joints[{i}].joints", _Raw("{}"), "expected at least one joint = angle (rad)")
        if not isinstance(rule.place_on_terrain, bool):
            raise TaskError(f"warm_start_joints[{i}].place_on_terrain", rule.place_on_terrain, "expected true or false")
        for joint, value in joints:
            for p in phases_i:
                # two rules for one joint in one phase: the later one won without a word
                j = set_by.setdefault((p, joint), i)
                if j != i:
                    raise TaskError(f"warm_start_joints[{i}].joints.{joint}", value, f"also set in phase {p} by warm_start_joints[{j}]; expected each joint set by one rule per phase")
        joint_rules.append(JointRule(phases_i, tuple(joints), rule.place_on_terrain))
    put("warm_start_joints", tuple(joint_rules))
    if t.flip_axis is not None:
        put("flip_axis", _vector(t.flip_axis, "flip_axis", nonzero=True))
        turns = _real(t.flip_turns, "flip_turns", "expected the signed number of turns about flip_axis (e.g. -1 for a back-flip about +y), nonzero")
        put("flip_turns", turns)
        if turns == 0:
            raise TaskError("flip_turns", t.flip_turns, "expected a nonzero signed number of turns (a task without a flip has no flip_axis)")
        if not any(t.target_rotation_rpy) and abs(turns - round(turns)) > 1e-9:
            # the motion ends at the target's attitude: with an upright target it turns whole turns
            raise TaskError("flip_turns", t.flip_turns, "expected a whole number of turns: the target's attitude is the standing one (target.rotation_rpy zero), where the motion ends")
    elif t.flip_turns is not None:
        raise TaskError("flip_turns", t.flip_turns, "expected no flip_turns without a flip_axis")
    if isinstance(t.max_iter, bool) or not isinstance(t.max_iter, (int, np.integer)) or not 1 <= t.max_iter <= MAX_ITER:
        raise TaskError("max_iter", t.max_iter, f"expected a positive whole number of iterations, at most {MAX_ITER} (Ipopt's limit)")
    put("max_iter", int(t.max_iter))
    put("terrain_height", _real(t.terrain_height, "terrain_height", "expected a height in m"))
    if not isinstance(t.description, str):
        raise TaskError("description", t.description, "expected a string")


# ------------------------------------------------------------------ loading
#: Python field names -> TOML paths, for errors of tasks loaded from files
_TOML_NAMES = {
    "target_translation": "target.translation",
    "target_rotation_rpy": "target.rotation_rpy",
    "target_joints": "target.joints",
    "configuration_weight": "costs.configuration",
    "acceleration_weight": "costs.acceleration",
}
_TOP_KEYS = (
    "name", "robot", "timestep", "phases", "target", "costs", "friction", "max_delta_force", "force_limit_factor",
    "warm_start_rules", "warm_start", "warm_start_joints", "flip_axis", "flip_turns", "max_iter", "terrain_height", "description",
)
_TABLE_KEYS = {
    "target": ("translation", "rotation_rpy", "joints"),
    "costs": ("configuration", "acceleration"),
    "phases": ("contacts", "duration"),
    "warm_start_rules": ("profile", "axis", "angle", "phases"),
    "warm_start": ("profile", "axis", "angle", "phases"),  # the former name of warm_start_rules
    "warm_start_joints": ("phases", "joints", "place_on_terrain"),
}


def _table(value: Any, field: str, keys: tuple[str, ...]) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise TaskError(field, value, f"expected a table with keys {list(keys)}")
    for k in value:
        if k not in keys:
            raise _unknown_key(f"{field}.{k}", k, list(keys))
    return value


def _unknown_key(field: str, key: str, keys: list[str]) -> TaskError:
    """The error of a key a task table does not take, with the nearest one it does (the top
    level said "unknown field", the tables "unknown key", and neither named the one meant)."""
    import difflib

    near = difflib.get_close_matches(str(key), keys, n=1)
    return TaskError(field, _Raw("unknown key"), (f"did you mean {near[0]!r}? " if near else "") + f"expected one of {keys}")


def _tables(data: dict[str, Any], key: str) -> list[dict[str, Any]]:
    value = data.get(key, [])
    if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
        raise TaskError(key, value, f"expected an array of tables [[{key}]] with keys {list(_TABLE_KEYS[key])}")
    return [_table(v, f"{key}[{i}]", _TABLE_KEYS[key]) for i, v in enumerate(value)]


def _need(table: dict[str, Any], key: str, field: str, expected: str) -> Any:
    if key not in table:
        raise TaskError(f"{field}.{key}", _Raw("missing"), expected)
    return table[key]


def _text(value: Any, field: str) -> str:
    if not isinstance(value, str):
        raise TaskError(field, value, "expected a string")
    return value


def from_dict(data: dict[str, Any], source: str = "<dict>") -> Task:
    """Build a task from the TOML structure (see the module docstring).

    Every key at every level must be known, and every value of the right type; a `TaskError`
    names the first one that is not, with ``source`` as its origin."""
    try:
        task = _from_dict(data)
    except TaskError as e:
        # a file with the former name: its key as the file writes it
        former = isinstance(data, dict) and "warm_start" in data and "warm_start_rules" not in data
        raise e.with_source(source, {"warm_start_rules": "warm_start"} if former else None) from None
    # not a field (equality, the content hash and `replace` ignore it): validate() names it
    object.__setattr__(task, "_source", source)
    return task


def _from_dict(data: dict[str, Any]) -> Task:
    if not isinstance(data, dict):
        raise TaskError("task", data, "expected a table of fields")
    for k in data:
        if k not in _TOP_KEYS:
            raise _unknown_key(k, k, sorted(_TOP_KEYS))
    for key in ("name", "robot", "timestep", "phases"):
        _need(data, key, "task", f"a task needs {key!r}")
    phases = []
    for i, p in enumerate(_tables(data, "phases")):
        contacts = _need(p, "contacts", f"phases[{i}]", "expected a list of contact names ([] for flight)")
        if not isinstance(contacts, list):
            raise TaskError(f"phases[{i}].contacts", contacts, 'expected a list of contact names, e.g. ["FL_foot", "FR_foot"] ([] for flight)')
        phases.append(Phase(tuple(contacts), _need(p, "duration", f"phases[{i}]", "expected a duration in seconds")))
    target = _table(data.get("target", {}), "target", _TABLE_KEYS["target"])
    costs = _table(data.get("costs", {}), "costs", _TABLE_KEYS["costs"])
    rules = []
    rules_key = "warm_start_rules"
    if "warm_start" in data:
        if rules_key in data:
            raise TaskError("warm_start", _Raw("given with [[warm_start_rules]]"), "expected only [[warm_start_rules]] ([[warm_start]] is its former name)")
        warnings.warn("[[warm_start]] in a task file is deprecated: it is now called [[warm_start_rules]]", DeprecationWarning, stacklevel=4)
        rules_key = "warm_start"
    for i, w in enumerate(_tables(data, rules_key)):
        profile = w.get("profile", "ramp")
        try:
            profile = Profile(profile)
        except ValueError:
            raise TaskError(f"{rules_key}[{i}].profile", profile, "expected 'ramp' or 'hold'") from None
        rules.append(
            RotationRule(
                profile,
                _need(w, "axis", f"{rules_key}[{i}]", "expected a rotation axis, a list of 3 numbers"),
                _need(w, "angle", f"{rules_key}[{i}]", "expected a rotation angle in radians"),
                _need(w, "phases", f"{rules_key}[{i}]", "expected a list of phase indices"),
            )
        )
    joint_rules = []
    for i, w in enumerate(_tables(data, "warm_start_joints")):
        joints = _need(w, "joints", f"warm_start_joints[{i}]", "expected a table of joint = angle (rad)")
        if not isinstance(joints, dict):
            raise TaskError(f"warm_start_joints[{i}].joints", joints, "expected a table of joint = angle (rad)")
        phases_i = _need(w, "phases", f"warm_start_joints[{i}]", "expected a list of phase indices")
        joint_rules.append(JointRule(phases_i, tuple(joints.items()), w.get("place_on_terrain", False)))
    return Task(
        name=_text(data["name"], "name"),
        robot=_text(data["robot"], "robot"),
        timestep=data["timestep"],
        phases=tuple(phases),
        target_translation=target.get("translation", (0.0, 0.0, 0.0)),
        target_rotation_rpy=target.get("rotation_rpy", (0.0, 0.0, 0.0)),
        target_joints=target.get("joints"),
        friction=data.get("friction", 0.9),
        max_delta_force=data.get("max_delta_force"),
        force_limit_factor=data.get("force_limit_factor", 1.5),
        configuration_weight=costs.get("configuration", 0.0),
        acceleration_weight=costs.get("acceleration", 0.0),
        warm_start_rules=tuple(rules),
        warm_start_joints=tuple(joint_rules),
        flip_axis=data.get("flip_axis"),
        flip_turns=data.get("flip_turns"),
        max_iter=data.get("max_iter", 200),
        terrain_height=data.get("terrain_height", 0.0),
        description=data.get("description", ""),
    )


def from_file(path: str | Path) -> Task:
    """Load a task from a TOML file."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except FileNotFoundError:
        raise TaskError("task file", str(path), "does not exist; expected a .toml task file") from None
    except IsADirectoryError:
        raise TaskError("task file", str(path), "is a folder; expected a .toml task file") from None
    except tomllib.TOMLDecodeError as e:
        raise TaskError("task file", str(path), f"not valid TOML ({e})") from None
    except UnicodeDecodeError as e:  # TOML is UTF-8: a Latin-1 description, say
        raise TaskError("task file", str(path), f"not UTF-8 text ({e.reason} at byte {e.start}); expected a TOML file in UTF-8") from None
    return from_dict(data, source=str(path))


def retarget(task: Task, robots: dict[str, str]) -> Task:
    """``task`` on another model of its robot: ``robots`` maps a robot name to the one to use
    instead (``{"talos": "talos_full"}``, the study's Talos); a task on a robot that is not a
    key comes back as it is. Only the robot changes (the content hash with it), so the new
    robot needs the task's contact groups and joints: `Task.validate` checks them."""
    new = robots.get(task.robot, task.robot)
    if new == task.robot:
        return task
    moved = dataclasses.replace(task, robot=new)
    if (source := getattr(task, "_source", None)) is not None:  # its errors still name its file
        object.__setattr__(moved, "_source", source)
    return moved


def available() -> list[str]:
    """Names of the built-in tasks (``tasks/*.toml``)."""
    root = importlib.resources.files("jtraj.tasks")
    return sorted(p.name[:-5] for p in root.iterdir() if p.name.endswith(".toml"))


def task_argument(name: str) -> str:
    """argparse ``type=`` for a task on a command line (the benchmarks'): ``name`` itself when it
    loads (a built-in task or a task file), else argparse's one-line usage error, before
    anything compiles or solves."""
    import argparse

    try:
        load(name)
    except TaskError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return name


def load(name: str | Path | Task) -> Task:
    """A built-in task by name (``big_jump``), or a task file path."""
    if isinstance(name, Task):
        return name
    if isinstance(name, Path) or str(name).lower().endswith(".toml"):  # (TINY.TOML was "unknown task")
        return from_file(name)
    if name not in available():
        hint = " (a file of that name exists: give its path with the .toml extension)" if isinstance(name, str) and Path(name).is_file() else ""
        raise TaskError("task", name, f"unknown task; expected one of {available()} or a path to a .toml file{hint}")
    with importlib.resources.files("jtraj.tasks").joinpath(f"{name}.toml").open("rb") as f:
        return from_dict(tomllib.load(f), source=f"tasks/{name}.toml")
