"""Tasks as validated data: robot, timestep, contact phases, target, weights, warm start.

A task is a frozen `Task`; the paper's six tasks live in ``tasks/*.toml`` (`load`), and a
user can write a TOML file of the same form (`from_file`) or build a `Task` in Python.
`Task.validate(robot)` checks everything a solve relies on and raises `TaskError` naming the
field, the offending value and what was expected.

TOML form (see ``tasks/big_jump.toml``)::

    name = "big_jump"
    robot = "talos"
    timestep = 0.05
    friction = 0.9
    max_delta_force = 100.0          # optional, N per knot and component
    [target]
    translation = [1.0, 0.0, 0.0]    # base displacement from the standing pose, world frame (m)
    rotation_rpy = [0.0, 0.0, 0.0]   # base rotation from the standing pose (rad)
    [costs]
    configuration = 0.0              # 1/2 w |q_joints - q_joints_standing|^2 per knot
    acceleration = 0.0               # 1/2 w |a_joints|^2 per knot
    [[phases]]
    contacts = ["left_foot", "right_foot"]
    duration = 1.0
    [[warm_start]]                   # optional base-rotation rules on top of the stance
    profile = "ramp"                 # "ramp" (0 -> angle over the phases) or "hold"
    axis = [0.0, 1.0, 0.0]
    angle = -6.283185307179586
    phases = [1]
    [[warm_start_joints]]            # optional joint overrides during phases
    phases = [2]
    joints = { arm_left_2_joint = 2.8 }
    place_on_terrain = true          # shift the base so the touching points rest on the ground
"""

from __future__ import annotations

import dataclasses
import enum
import importlib.resources
import math
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["TaskError", "Phase", "Profile", "RotationRule", "JointRule", "Task", "Schedule", "load", "from_file", "from_dict", "available"]


class TaskError(ValueError):
    """A task definition that cannot be solved as written."""


@dataclasses.dataclass(frozen=True)
class Phase:
    """A contact phase: the contact groups touching the ground, for ``duration`` seconds."""

    contacts: tuple[str, ...]
    duration: float


class Profile(enum.Enum):
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
    warm_start: tuple[RotationRule, ...] = ()
    warm_start_joints: tuple[JointRule, ...] = ()
    flip_axis: tuple[float, float, float] | None = None  # success needs a full turn about it
    max_iter: int = 200
    terrain_height: float = 0.0
    description: str = ""

    # -------------------------------------------------------------- knots and contacts
    def phase_knot_counts(self) -> tuple[int, ...]:
        """Knots per phase, ``round(duration / h)`` (the paper's code truncates; see REFERENCE.md)."""
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

    def warm_start_angles(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per rule: (axis, angle at every knot) of the base rotation of the warm start."""
        counts = self.phase_knot_counts()
        starts = np.concatenate([[0], np.cumsum(counts)])
        out = []
        for rule in self.warm_start:
            angles = np.zeros(self.n_knots)
            first = starts[min(rule.phases)]
            last = starts[max(rule.phases) + 1]
            if rule.profile is Profile.RAMP:
                k = np.arange(self.n_knots)
                angles = rule.angle * np.clip((k - first) / max(last - first, 1), 0.0, 1.0)
            else:
                for p in rule.phases:
                    angles[starts[p] : starts[p + 1]] = rule.angle
            out.append((np.asarray(rule.axis, float) / np.linalg.norm(rule.axis), angles))
        return out

    # -------------------------------------------------------------- validation
    def validate(self, robot=None) -> Task:
        """Raise `TaskError` for a task that cannot be solved; return self."""
        from jtraj import robot as robot_module

        if self.robot not in robot_module.available():
            raise TaskError(f"task {self.name!r}: field 'robot' is {self.robot!r}; expected one of {sorted(robot_module.available())}")
        if not (isinstance(self.timestep, (int, float)) and self.timestep > 0 and math.isfinite(self.timestep)):
            raise TaskError(f"task {self.name!r}: field 'timestep' is {self.timestep!r}; expected a positive number of seconds")
        if not self.phases:
            raise TaskError(f"task {self.name!r}: field 'phases' is empty; expected at least one contact phase")
        for i, phase in enumerate(self.phases):
            if not (isinstance(phase.duration, (int, float)) and phase.duration > 0 and math.isfinite(phase.duration)):
                raise TaskError(f"task {self.name!r}: phases[{i}].duration is {phase.duration!r}; expected a positive number of seconds")
            if round(phase.duration / self.timestep) < 1:
                raise TaskError(
                    f"task {self.name!r}: phases[{i}].duration {phase.duration} s is shorter than one knot "
                    f"(timestep {self.timestep} s); expected at least {self.timestep / 2:g} s"
                )
        if not self.phases[0].contacts:
            raise TaskError(f"task {self.name!r}: phases[0].contacts is empty; expected the task to start in contact (it starts at rest)")
        if not self.phases[-1].contacts:
            raise TaskError(f"task {self.name!r}: phases[-1].contacts is empty; expected the task to end in contact (it ends at rest)")
        if not (self.friction > 0):
            raise TaskError(f"task {self.name!r}: field 'friction' is {self.friction!r}; expected a positive coefficient")
        if self.max_delta_force is not None and not (self.max_delta_force > 0):
            raise TaskError(f"task {self.name!r}: field 'max_delta_force' is {self.max_delta_force!r}; expected a positive force (N) or none")
        if self.configuration_weight < 0 or self.acceleration_weight < 0:
            raise TaskError(f"task {self.name!r}: cost weights must be >= 0, got configuration={self.configuration_weight}, acceleration={self.acceleration_weight}")
        for i, rule in enumerate(self.warm_start):
            if np.linalg.norm(rule.axis) == 0:
                raise TaskError(f"task {self.name!r}: warm_start[{i}].axis is zero; expected a nonzero 3-vector")
            bad = [p for p in rule.phases if not 0 <= p < len(self.phases)]
            if bad or not rule.phases:
                raise TaskError(f"task {self.name!r}: warm_start[{i}].phases is {list(rule.phases)}; expected indices in 0..{len(self.phases) - 1}")
        if robot is None:
            robot = robot_module.load(self.robot)
        for i, rule in enumerate(self.warm_start_joints):
            bad = [p for p in rule.phases if not 0 <= p < len(self.phases)]
            if bad or not rule.phases:
                raise TaskError(f"task {self.name!r}: warm_start_joints[{i}].phases is {list(rule.phases)}; expected indices in 0..{len(self.phases) - 1}")
            for joint, value in rule.joints:
                if joint not in robot.joint_names:
                    raise TaskError(f"task {self.name!r}: warm_start_joints[{i}] names unknown joint {joint!r}; expected one of {list(robot.joint_names)}")
                j = robot.joint_names.index(joint)
                if not robot.q_lower[j] <= value <= robot.q_upper[j]:
                    raise TaskError(
                        f"task {self.name!r}: warm_start_joints[{i}] sets {joint!r} = {value:g} rad, outside its limits "
                        f"[{robot.q_lower[j]:g}, {robot.q_upper[j]:g}]"
                    )
        groups = sorted(robot.contact_groups)
        for i, phase in enumerate(self.phases):
            for c in phase.contacts:
                if c not in robot.contact_groups:
                    raise TaskError(f"task {self.name!r}: phases[{i}].contacts has unknown contact {c!r}; expected one of {groups} for robot {robot.name!r}")
        if self.target_joints is not None:
            tj = np.asarray(self.target_joints, float)
            if tj.shape != (robot.nj,):
                raise TaskError(f"task {self.name!r}: field 'target_joints' has {tj.size} values; expected {robot.nj} (one per joint of {robot.name!r})")
            lo, hi = robot.q_lower, robot.q_upper
            outside = np.flatnonzero((tj < lo) | (tj > hi))
            if outside.size:
                j = outside[0]
                raise TaskError(
                    f"task {self.name!r}: target joint {robot.joint_names[j]!r} = {tj[j]:g} rad is outside its limits "
                    f"[{lo[j]:g}, {hi[j]:g}]"
                )
        return self

    def replace(self, **changes: Any) -> Task:
        return dataclasses.replace(self, **changes)


# ------------------------------------------------------------------ loading
_KNOWN = {
    "name", "robot", "timestep", "phases", "target", "costs", "friction", "max_delta_force",
    "force_limit_factor", "warm_start", "warm_start_joints", "flip_axis", "max_iter", "terrain_height", "description",
}


def _vec3(value: Any, where: str) -> tuple[float, float, float]:
    try:
        arr = tuple(float(x) for x in value)
    except TypeError:
        raise TaskError(f"{where} is {value!r}; expected a list of 3 numbers") from None
    if len(arr) != 3:
        raise TaskError(f"{where} is {value!r}; expected a list of 3 numbers")
    return arr  # type: ignore[return-value]


def from_dict(data: dict[str, Any], source: str = "<dict>") -> Task:
    """Build a task from the TOML structure (see the module docstring)."""
    unknown = set(data) - _KNOWN
    if unknown:
        raise TaskError(f"{source}: unknown field(s) {sorted(unknown)}; expected some of {sorted(_KNOWN)}")
    for field in ("name", "robot", "timestep", "phases"):
        if field not in data:
            raise TaskError(f"{source}: missing field {field!r}")
    phases = []
    for i, p in enumerate(data["phases"]):
        if "contacts" not in p or "duration" not in p:
            raise TaskError(f"{source}: phases[{i}] needs 'contacts' (list of contact names) and 'duration' (s)")
        phases.append(Phase(tuple(p["contacts"]), p["duration"]))
    target = data.get("target", {})
    costs = data.get("costs", {})
    rules = []
    for i, w in enumerate(data.get("warm_start", [])):
        try:
            profile = Profile(w.get("profile", "ramp"))
        except ValueError:
            raise TaskError(f"{source}: warm_start[{i}].profile is {w.get('profile')!r}; expected 'ramp' or 'hold'") from None
        rules.append(RotationRule(profile, _vec3(w.get("axis"), f"{source}: warm_start[{i}].axis"), float(w["angle"]), tuple(int(p) for p in w["phases"])))
    joint_rules = []
    for i, w in enumerate(data.get("warm_start_joints", [])):
        if "phases" not in w or "joints" not in w:
            raise TaskError(f"{source}: warm_start_joints[{i}] needs 'phases' (list of phase indices) and 'joints' (table of joint = angle)")
        joints = tuple((str(k), float(v)) for k, v in w["joints"].items())
        joint_rules.append(JointRule(tuple(int(p) for p in w["phases"]), joints, bool(w.get("place_on_terrain", False))))
    task = Task(
        name=str(data["name"]),
        robot=str(data["robot"]),
        timestep=data["timestep"],
        phases=tuple(phases),
        target_translation=_vec3(target.get("translation", (0, 0, 0)), f"{source}: target.translation"),
        target_rotation_rpy=_vec3(target.get("rotation_rpy", (0, 0, 0)), f"{source}: target.rotation_rpy"),
        target_joints=tuple(target["joints"]) if "joints" in target else None,
        friction=float(data.get("friction", 0.9)),
        max_delta_force=data.get("max_delta_force"),
        force_limit_factor=float(data.get("force_limit_factor", 1.5)),
        configuration_weight=float(costs.get("configuration", 0.0)),
        acceleration_weight=float(costs.get("acceleration", 0.0)),
        warm_start=tuple(rules),
        warm_start_joints=tuple(joint_rules),
        flip_axis=_vec3(data["flip_axis"], f"{source}: flip_axis") if "flip_axis" in data else None,
        max_iter=int(data.get("max_iter", 200)),
        terrain_height=float(data.get("terrain_height", 0.0)),
        description=str(data.get("description", "")),
    )
    return task


def from_file(path: str | Path) -> Task:
    """Load a task from a TOML file."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except FileNotFoundError:
        raise TaskError(f"task file {str(path)!r} does not exist") from None
    except tomllib.TOMLDecodeError as e:
        raise TaskError(f"task file {str(path)!r} is not valid TOML: {e}") from None
    return from_dict(data, source=str(path))


def available() -> list[str]:
    """Names of the built-in tasks (``tasks/*.toml``)."""
    root = importlib.resources.files("jtraj.tasks")
    return sorted(p.name[:-5] for p in root.iterdir() if p.name.endswith(".toml"))


def load(name: str | Path | Task) -> Task:
    """A built-in task by name (``big_jump``), or a task file path."""
    if isinstance(name, Task):
        return name
    if isinstance(name, Path) or str(name).endswith(".toml"):
        return from_file(name)
    if name not in available():
        raise TaskError(f"unknown task {name!r}; expected one of {available()} or a path to a .toml file")
    with importlib.resources.files("jtraj.tasks").joinpath(f"{name}.toml").open("rb") as f:
        return from_dict(tomllib.load(f), source=f"tasks/{name}.toml")

