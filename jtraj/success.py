"""Did the solve do the task? A check on the motion that a converged solve can still fail.

Converging is not doing the task: the comparative study marks with an asterisk the runs of
Table III that converged to a plain jump instead of a flip. The final pose cannot tell the two
apart (it is fixed by the variable bounds, and a flip ends where a jump does), so the check
looks at the rotation of the base over the whole motion.

The accumulated rotation vector ``a = sum_k Log(R_{k+1} R_k^T)`` (world frame, radians) sums
the rotation increments between knots; for a rotation about a fixed axis it is the axis times
the total angle, full turns included (``Log`` alone would wrap at pi). Then, with ``e`` the task's
unit flip axis and ``n`` its expected signed number of turns (``flip_turns``; a back-flip about
+y is -1, a forward flip +1, a double back-flip -2):

- flip tasks: the turns about the axis ``a . e / 2 pi`` are within `TURN_TOLERANCE` of ``n``
  (so the sign must match and a double flip is not a single one), and the rotation is mainly
  about the axis: the off-axis part ``|a - (a . e) e|`` is at most `OFF_AXIS_SHARE` of
  ``|a|`` (a flip about a tilted axis, or a twist, is not the task's flip);
- other tasks: no unplanned somersault or spin: ``a`` is within `TURN_TOLERANCE` turns of the
  rotation from the first to the last attitude, ``r = Log(R_N R_0^T)`` (the turn the task
  plans, e.g. its target yaw; zero for most tasks), ``|a - r| / 2 pi < TURN_TOLERANCE``. A
  handstand that rotates forward onto the hands and back accumulates about zero; one that goes
  on over the top accumulates a full turn and fails; a task whose target turns the base by 90
  degrees about the vertical passes when it turns that way. Where ``|r|`` is within
  `LONG_WAY_WINDOW` of pi (a half turn, where ``Log`` picks the axis' sign by rounding, and a
  target angle may reach `jtraj.task.RPY_LIMIT`), the other way round to the last attitude
  (``r`` minus a full turn along its axis) counts too; elsewhere turning the long way round is
  a spin (a target yaw of 144 degrees reached by turning -216 degrees fails).

The step between two knots must stay below pi for ``Log`` to see its direction: `evaluate`
reports a trajectory whose largest step is above `MAX_STEP` rad as failed instead of guessing.

Feasibility: a solve counts as converged when Ipopt reports success (or an acceptable level),
and as feasible when moreover its largest constraint violation (in the constraints' own units,
m, N, N m, m/s) is below `FEASIBILITY_TOL`; the task succeeds only when it is feasible and
`evaluate` passes.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from jtraj.lie import rotation_steps
from jtraj.numbers import is_real, unit_and_length

__all__ = ["TURN_TOLERANCE", "OFF_AXIS_SHARE", "MAX_STEP", "FEASIBILITY_TOL", "LONG_WAY_WINDOW", "TaskCheck", "rotation_vector", "evaluate"]

#: Largest distance, in turns, between the measured and the expected number of turns.
TURN_TOLERANCE = 0.25
#: Largest off-axis share ``|a_off| / |a|`` of the accumulated rotation of a flip.
OFF_AXIS_SHARE = 0.25
#: Largest rotation between two knots (rad) for which the direction of a step is unambiguous.
MAX_STEP = 0.9 * math.pi
#: Largest constraint violation of a solve that counts as feasible (constraint units).
FEASIBILITY_TOL = 1e-2
#: How close to pi (rad) the first-to-last rotation's angle must be for the long way round
#: to count as the planned turn: twice `jtraj.task.RPY_LIMIT`'s margin past pi.
LONG_WAY_WINDOW = 2e-3


@dataclasses.dataclass(frozen=True)
class TaskCheck:
    """Outcome of `evaluate`.

    ok: the motion does the task.
    turns: signed turns about the flip axis (None for tasks without one).
    total_turns: ``|a| / 2 pi``, turns of the accumulated rotation about any axis.
    off_axis_share: ``|a_off| / |a|`` for flips (0 when ``a`` is zero), else None.
    reason: why the check failed ("" when ok), one line.
    """

    ok: bool
    turns: float | None
    total_turns: float
    off_axis_share: float | None
    reason: str


def rotation_vector(base_xyz_wxyz: np.ndarray) -> tuple[np.ndarray, float]:
    """Accumulated world-frame rotation vector of a base trajectory, and its largest step.

    Args:
        base_xyz_wxyz: (n_knots, 7) base position and unit quaternion (wxyz) per knot.
    Returns:
        ``a`` (3,) in radians, ``sum_k Log(R_{k+1} R_k^T)``, and the largest ``|Log(...)|`` (rad).
    """
    q = np.asarray(base_xyz_wxyz, float)
    if q.ndim != 2 or q.shape[1] != 7 or q.shape[0] < 1:
        raise ValueError(f"base_xyz_wxyz has shape {q.shape}; expected (n_knots, 7)")
    if q.shape[0] < 2:
        return np.zeros(3), 0.0
    steps = np.asarray(rotation_steps(q[:, 3:7]))
    return steps.sum(axis=0), float(np.max(np.linalg.norm(steps, axis=-1)))


def _turns_beyond_net_rotation(base_xyz_wxyz: np.ndarray, a: np.ndarray) -> float:
    """``min |a - r| / 2 pi`` over the rotation vectors ``r`` of the first-to-last rotation
    (see the module docstring)."""
    if base_xyz_wxyz.shape[0] < 2:
        return float(np.linalg.norm(a)) / (2 * math.pi)
    net = np.asarray(rotation_steps(base_xyz_wxyz[[0, -1], 3:7]))[0]
    angle = float(np.linalg.norm(net))
    candidates = [net]
    # only near a half turn: the window was |r| >= 3 pi / 4, so turning -216 degrees to a
    # target yaw of 144 degrees, a full turn more than planned, passed
    if angle > 0 and math.pi - angle <= LONG_WAY_WINDOW:
        candidates.append(net - 2 * math.pi * net / angle)
    return min(float(np.linalg.norm(a - r)) for r in candidates) / (2 * math.pi)


def evaluate(base_xyz_wxyz: np.ndarray, flip_axis=None, flip_turns: float | None = None) -> TaskCheck:
    """Check the base motion against the task (see the module docstring).

    Args:
        base_xyz_wxyz: (n_knots, 7) base pose per knot (world frame, m, unit quaternion wxyz).
        flip_axis: the task's flip axis (3,), world frame, any nonzero length; None for tasks
            without a flip.
        flip_turns: expected signed turns about ``flip_axis`` (right-hand rule); required with
            ``flip_axis``.
    """
    a, max_step = rotation_vector(base_xyz_wxyz)
    norm = float(np.linalg.norm(a))
    total = norm / (2 * math.pi)
    # NaN compares False with every threshold below: without this check a trajectory with NaN
    # (a diverged solve) or a zero quaternion would pass every test and read as done.
    finite = bool(np.all(np.isfinite(base_xyz_wxyz))) and math.isfinite(norm) and math.isfinite(max_step)
    not_finite = "the base trajectory has NaN or infinite values (or a zero quaternion); no motion to check"
    if flip_axis is None:
        if flip_turns is not None:
            raise ValueError("flip_turns needs a flip_axis")
        if not finite:
            return TaskCheck(False, None, total, None, not_finite)
        if max_step > MAX_STEP:
            return TaskCheck(False, None, total, None, f"the base turns {max_step:.2f} rad between two knots; too coarse to tell its rotation")
        beyond = _turns_beyond_net_rotation(np.asarray(base_xyz_wxyz, float), a)
        if beyond >= TURN_TOLERANCE:
            return TaskCheck(
                False, None, total, None, f"the base turns {total:.2f} turns in all, {beyond:.2f} beyond the rotation from its first to its last attitude; expected no somersault (< {TURN_TOLERANCE})"
            )
        return TaskCheck(True, None, total, None, "")
    e = np.asarray(flip_axis, float)
    if e.shape != (3,) or not np.all(np.isfinite(e)):
        raise ValueError(f"flip_axis is {flip_axis!r}; expected a nonzero 3-vector")
    # normalized without overflow or underflow: np.linalg.norm made [0, 1e200, 0] a zero axis
    # (a done back-flip then failed) and refused [1e-200, 0, 0] as zero
    e, length = unit_and_length(e)
    if length == 0:
        raise ValueError(f"flip_axis is {flip_axis!r}; expected a nonzero 3-vector")
    if flip_turns is None:
        raise ValueError("flip_axis needs flip_turns (expected signed turns about it)")
    if not (is_real(flip_turns) and math.isfinite(flip_turns)):
        # NaN compared False with the turn test, which every motion then passed
        raise ValueError(f"flip_turns is {flip_turns!r}; expected a finite number of signed turns about flip_axis")
    along = float(a @ e)
    turns = along / (2 * math.pi)
    share = float(np.linalg.norm(a - along * e) / norm) if norm > 0 else 0.0
    if not finite:
        return TaskCheck(False, turns, total, share, not_finite)
    if max_step > MAX_STEP:
        return TaskCheck(False, turns, total, share, f"the base turns {max_step:.2f} rad between two knots; too coarse to tell its rotation")
    if abs(turns - flip_turns) > TURN_TOLERANCE:
        return TaskCheck(False, turns, total, share, f"{turns:+.2f} turns about the flip axis; expected {flip_turns:+g} +- {TURN_TOLERANCE}")
    if share > OFF_AXIS_SHARE:
        return TaskCheck(False, turns, total, share, f"{share:.0%} of the rotation is off the flip axis; expected at most {OFF_AXIS_SHARE:.0%}")
    return TaskCheck(True, turns, total, share, "")
