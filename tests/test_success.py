"""The task-success check on synthetic base trajectories (jtraj.success)."""

import numpy as np
import pytest

from jtraj import success
from jtraj.task import RPY_LIMIT


def _about(axis, angles, xyz=None):
    """(n, 7) base trajectory rotating about a fixed world axis through the given angles."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    angles = np.asarray(angles, float)
    wxyz = np.concatenate([np.cos(angles / 2)[:, None], np.sin(angles / 2)[:, None] * axis], axis=1)
    xyz = np.zeros((angles.size, 3)) if xyz is None else xyz
    return np.concatenate([xyz, wxyz], axis=1)


def _ramp(total, n=25):
    return np.concatenate([np.zeros(5), np.linspace(0.0, total, n), np.full(5, total)])


Y = [0.0, 1.0, 0.0]
BACKFLIP = dict(flip_axis=Y, flip_turns=-1)


def test_backflip_counts():
    check = success.evaluate(_about(Y, _ramp(-2 * np.pi)), **BACKFLIP)
    assert check.ok, check.reason
    assert check.turns == pytest.approx(-1.0, abs=1e-12)
    assert check.off_axis_share == pytest.approx(0.0, abs=1e-12)


def test_axis_length_does_not_matter():
    assert success.evaluate(_about(Y, _ramp(-2 * np.pi)), flip_axis=[0, 3.0, 0], flip_turns=-1).ok


@pytest.mark.parametrize(
    "angle, reason",
    [(2 * np.pi, "+1.00 turns"), (-4 * np.pi, "-2.00 turns"), (0.0, "+0.00 turns"), (-1.4 * np.pi, "-0.70 turns")],
    ids=["forward_flip", "double_flip", "no_flip", "short_flip"],
)
def test_wrong_flips_fail(angle, reason):
    check = success.evaluate(_about(Y, _ramp(angle, n=40)), **BACKFLIP)
    assert not check.ok
    assert reason in check.reason


def test_flip_about_another_axis_fails():
    # a full turn about a tilted axis projects to -0.77 turns on y: the count alone would pass
    tilted = [0.0, -np.cos(0.7), np.sin(0.7)]
    check = success.evaluate(_about(tilted, _ramp(2 * np.pi)), **BACKFLIP)
    assert abs(check.turns + 1) <= success.TURN_TOLERANCE
    assert not check.ok and "off the flip axis" in check.reason


def test_zero_axis_and_missing_turns_are_errors():
    traj = _about(Y, _ramp(-2 * np.pi))
    with pytest.raises(ValueError, match="nonzero 3-vector"):
        success.evaluate(traj, flip_axis=[0, 0, 0], flip_turns=-1)
    with pytest.raises(ValueError, match="flip_turns"):
        success.evaluate(traj, flip_axis=Y)


def test_nan_turns_and_extreme_axis_lengths():
    """NaN flip_turns passed every motion (NaN compares False with the turn test); an axis of
    length 1e200 normalized to zero (a done back-flip failed) and one of 1e-200 was refused."""
    traj = _about(Y, _ramp(-2 * np.pi))
    with pytest.raises(ValueError, match=r"flip_turns is nan; expected a finite number of signed turns"):
        success.evaluate(_about(Y, np.zeros(10)), flip_axis=Y, flip_turns=float("nan"))
    for length in (1e200, 1e-200):
        check = success.evaluate(traj, flip_axis=[0.0, length, 0.0], flip_turns=-1)
        assert check.ok and check.turns == pytest.approx(-1.0, abs=1e-12), check.reason


def test_tasks_without_flip_reject_a_somersault():
    there_and_back = np.concatenate([_ramp(np.pi), np.linspace(np.pi, 0.0, 20)])
    assert success.evaluate(_about(Y, there_and_back)).ok  # a handstand: over and back
    over_the_top = np.concatenate([_ramp(np.pi), np.linspace(np.pi, 2 * np.pi, 20)])
    check = success.evaluate(_about(Y, over_the_top))
    assert not check.ok and "somersault" in check.reason


def test_too_coarse_steps_are_not_guessed():
    check = success.evaluate(_about(Y, [0.0, -0.95 * np.pi, -1.9 * np.pi, -2 * np.pi]), **BACKFLIP)
    assert not check.ok and "too coarse" in check.reason


@pytest.mark.parametrize("where", ["nan_quaternion", "nan_position", "zero_quaternion"])
def test_regression_non_finite_trajectory_fails(where):
    """Regression: NaN compares False with every threshold, so a diverged solve's trajectory
    (NaN) or one with a zero quaternion passed both checks and read as done."""
    traj = _about(Y, _ramp(-2 * np.pi))
    if where == "nan_quaternion":
        traj[10, 3:7] = np.nan
    elif where == "nan_position":
        traj[10, 0] = np.nan
    else:
        traj[10, 3:7] = 0.0
    for kwargs in (BACKFLIP, {}):
        check = success.evaluate(traj, **kwargs)
        assert not check.ok and "NaN or infinite" in check.reason, (kwargs, check)


@pytest.mark.parametrize("degrees", [90.0, 135.0, 180.0, -180.0, 180.0 + 1e-9, np.degrees(RPY_LIMIT), -np.degrees(RPY_LIMIT)])
def test_regression_a_planned_turn_is_not_a_somersault(degrees):
    """Regression: tasks without a flip failed whenever the base turned a quarter turn in all,
    so a task whose target turns the base (``target.rotation_rpy``, here a yaw) failed as a
    somersault when it did that turn; the check now measures the rotation beyond the turn
    from the first to the last attitude, which a spin on top of the planned turn still fails.
    Past half a turn ``Log`` of the first-to-last rotation is the short way round (a target yaw
    of `RPY_LIMIT`, just past 180 deg, reads as just under -180 deg), so near a half turn the
    check also takes the long way; the cases past 180 deg need it."""
    Z = [0.0, 0.0, 1.0]
    turn = np.radians(degrees)
    assert success.evaluate(_about(Z, _ramp(turn))).ok
    spin = success.evaluate(_about(Z, _ramp(turn + np.sign(turn) * 2 * np.pi, n=60)))
    assert not spin.ok and "somersault" in spin.reason
    assert spin.total_turns == pytest.approx(abs(degrees) / 360 + 1.0)


@pytest.mark.parametrize("degrees", [144.0, -144.0, 179.0])
def test_regression_the_long_way_round_to_a_planned_turn_is_a_spin(degrees):
    """Regression: the long way round to the last attitude counted as the planned turn whenever
    that turn was 135 degrees or more, so reaching a target yaw of 144 degrees by turning -216
    degrees (a full turn more than planned) passed. It counts only near a half turn now."""
    Z = [0.0, 0.0, 1.0]
    turn = np.radians(degrees)
    assert success.evaluate(_about(Z, _ramp(turn))).ok
    long_way = success.evaluate(_about(Z, _ramp(turn - np.sign(turn) * 2 * np.pi, n=60)))
    assert not long_way.ok and "somersault" in long_way.reason
