"""The first and last knots are fixed (the standing pose lowered onto the terrain, the target
pose): a task that puts a contact point below the terrain there, or a touching point off it, is
refused before the NLP is built, naming the task's key. No solve: the checks take the forward
kinematics of the two poses."""

import importlib.resources
import re

import numpy as np
import pytest
from conftest import mujoco_contact_positions

from jtraj import parameterization
from jtraj import robot as robot_lib
from jtraj import task as tasks
from jtraj.task import TaskError
from jtraj.transcription import Transcription

HANDS_FIRST = 'contacts = ["left_hand", "right_hand"]'


def _transcription(task: tasks.Task) -> Transcription:
    return Transcription(robot_lib.load(task.robot), task, parameterization.get("se3"))


#: How far (m) from the terrain a touching point of a built-in task may be at a fixed knot: the
#: standing poses put each robot's feet level to far better (~1e-16 m), so this is rounding only.
ON_TERRAIN = 1e-9


def _assert_on_the_terrain(tr: Transcription) -> None:
    """At the first knot (the initial pose, the standing joints) the contact points of the first
    phase rest on the terrain, at the last knot (the target pose and joints) those of the last
    phase do; the task's other contact points are not below it. The points are read from the
    task's phases and the robot's groups, not from the transcription's schedule."""
    task, robot = tr.task, tr.robot
    h = task.terrain_height

    def points(*phases):
        return {i for phase in phases for group in phase.contacts for i in robot.group(group)}

    used = points(*task.phases)
    q_target = robot.q_joints_standing if task.target_joints is None else np.asarray(task.target_joints, float)
    for knot, pose, q_joints, phase in (("first", tr.initial_xyz_wxyz, robot.q_joints_standing, task.phases[0]), ("last", tr.target_xyz_wxyz, q_target, task.phases[-1])):
        z = mujoco_contact_positions(robot, np.concatenate([pose, q_joints]))[:, 2]  # (MuJoCo's kinematics, not the transcription's)
        touching = points(phase)
        assert touching, (knot, phase)  # every built-in task starts and ends on its feet
        for i in sorted(used):
            name = robot.contact_names[i]
            if i in touching:
                assert abs(z[i] - h) <= ON_TERRAIN, (knot, name, z[i] - h)
            else:
                assert z[i] >= h - ON_TERRAIN, (knot, name, z[i] - h)


def _same_rotation(wxyz, expected) -> bool:
    """Unit quaternions of the same rotation (q and -q are one)."""
    wxyz, expected = np.asarray(wxyz, float), np.asarray(expected, float)
    return min(np.abs(wxyz - expected).max(), np.abs(wxyz + expected).max()) < 1e-12


def _file(tmp_path, old: str, new: str) -> str:
    """big_jump as a task file, with ``old`` replaced by ``new``."""
    text = (importlib.resources.files("jtraj.tasks") / "big_jump.toml").read_text()
    assert old in text
    path = tmp_path / "mine.toml"
    path.write_text(text.replace(old, new, 1))
    return str(path)


@pytest.mark.parametrize(
    "name, robot",
    [(name, None) for name in tasks.available()] + [(name, "talos_full") for name in tasks.available() if tasks.load(name).robot == "talos"],
)
def test_builtin_tasks_stand_on_the_terrain_at_both_ends(name, robot):
    task = tasks.load(name) if robot is None else tasks.retarget(tasks.load(name), {"talos": robot})
    tr = _transcription(task)
    standing = tr.robot.base_xyz_wxyz_standing
    # the first knot is the standing pose moved vertically only, the last that pose moved by
    # the task's target (no built-in task turns the base: its attitude is the standing one)
    assert task.target_rotation_rpy == (0.0, 0.0, 0.0)
    np.testing.assert_array_equal(tr.initial_xyz_wxyz[[0, 1, 3, 4, 5, 6]], standing[[0, 1, 3, 4, 5, 6]])
    np.testing.assert_allclose(tr.target_xyz_wxyz[:3], tr.initial_xyz_wxyz[:3] + task.target_translation, rtol=0, atol=1e-12)
    assert _same_rotation(tr.target_xyz_wxyz[3:], standing[3:])
    _assert_on_the_terrain(tr)


def test_a_first_phase_on_the_hands_is_refused(tmp_path):
    # the base was lowered until the hands touched, the feet 0.74 m below the ground at the
    # fixed first knot: accepted, and no solve could succeed
    path = _file(tmp_path, 'contacts = ["left_foot", "right_foot"]', HANDS_FIRST)
    tr = _transcription(tasks.load(path))
    expected = (
        rf"^{re.escape(path)}: phases\[0\].contacts: \['left_hand', 'right_hand'\]: the standing pose of 'talos' lowered until phase 0's contacts touch the terrain "
        r"puts left_foot_\w+ 0.74 m below it at the first knot; expected the contacts of phase 0 to be the lowest points of the standing pose$"
    )
    with pytest.raises(TaskError, match=expected):
        tr.build_nlp()  # before anything is built
    with pytest.raises(TaskError, match=expected):
        tr.warm_start()


def test_a_first_phase_the_standing_pose_does_not_put_level_is_refused(tmp_path):
    # the feet and a hand: the standing pose holds the hand far above the feet, which was a
    # ValueError blaming the robot (a traceback from the command line), not the task's key
    path = _file(tmp_path, 'contacts = ["left_foot", "right_foot"]', 'contacts = ["left_foot", "right_foot", "left_hand"]')
    tr = _transcription(tasks.load(path))
    expected = (
        rf"^{re.escape(path)}: phases\[0\].contacts: \['left_foot', 'right_foot', 'left_hand'\]: the standing pose of 'talos' puts the contact points of phase 0 "
        r"\d+ mm apart in height \(on flat ground: within 0.1 mm, which the fixed first knot's contact rows allow\); expected contacts of phase 0 that the robot's standing pose puts level"
    )
    with pytest.raises(TaskError, match=expected):
        tr.build_nlp()


def test_a_first_phase_on_one_foot_is_accepted():
    # the other foot is as low, not lower: it stays on the terrain, where clearance allows it
    task = tasks.load("big_jump")
    task = task.replace(phases=(tasks.Phase(("left_foot",), 1.0), *task.phases[1:]))
    z = _transcription(task).initial_xyz_wxyz[2]
    assert abs(z - _transcription(tasks.load("big_jump")).initial_xyz_wxyz[2]) < 1e-9


@pytest.mark.parametrize(
    "old, new, match",
    [
        # a pitch lifted the feet 0.18 m while the last phase stands on them
        ("translation = [1.0, 0.0, 0.0]", "translation = [1.0, 0.0, 0.0]\nrotation_rpy = [0.0, 0.5, 0.0]", r"target.rotation_rpy: \[0.0, 0.5, 0.0\]: puts left_foot_\w+ 0.178 m above the terrain at the last knot, where phase 2 touches it"),
        ("translation = [1.0, 0.0, 0.0]", "translation = [1.0, 0.0, 0.1]", r"target.translation: \[1.0, 0.0, 0.1\]: puts left_foot_\w+ 0.1 m above the terrain at the last knot, where phase 2 touches it \(target translation z = 0 puts them on it\)"),
        ("translation = [1.0, 0.0, 0.0]", "translation = [1.0, 0.0, -0.1]", r"target.translation: \[1.0, 0.0, -0.1\]: puts left_foot_\w+ 0.1 m below the terrain at the last knot, where phase 2 touches it \(target translation z = 0 puts them on it\)"),
    ],
)
def test_a_target_that_lifts_the_last_contacts_off_the_terrain_is_refused(tmp_path, old, new, match):
    path = _file(tmp_path, old, new)
    tr = _transcription(tasks.load(path))
    with pytest.raises(TaskError, match=rf"^{re.escape(path)}: {match}; expected a target whose touching points rest on the terrain and others above it \(the last knot is fixed at the target\)$"):
        tr.build_nlp()


@pytest.mark.parametrize(
    "rpy, wxyz",
    [
        ((0.0, 0.0, 0.5), (np.cos(0.25), 0.0, 0.0, np.sin(0.25))),  # 0.5 rad about +z (Talos stands unrotated)
        ((0.0, 0.0, -np.pi), (0.0, 0.0, 0.0, -1.0)),  # half a turn, the most an angle takes
    ],
)
def test_targets_that_keep_the_feet_on_the_terrain_are_accepted(rpy, wxyz):
    # turns about the vertical (whole turns are flip_axis and flip_turns, with an upright target)
    task = tasks.load("big_jump").replace(target_rotation_rpy=rpy)
    tr = _transcription(task)
    assert tr.robot.base_xyz_wxyz_standing[3:].tolist() == [1.0, 0.0, 0.0, 0.0]  # what wxyz assumes
    assert _same_rotation(tr.target_xyz_wxyz[3:], wxyz), tr.target_xyz_wxyz[3:]
    np.testing.assert_allclose(tr.target_xyz_wxyz[:3], tr.initial_xyz_wxyz[:3] + task.target_translation, rtol=0, atol=1e-12)
    _assert_on_the_terrain(tr)


def _rule_file(tmp_path, axis: str = "[1.0, 1.0, 0.0]") -> str:
    """backflip with its rotation rule about ``axis`` (a task file may give any axis)."""
    text = (importlib.resources.files("jtraj.tasks") / "backflip.toml").read_text()
    assert "\naxis = [0.0, 1.0, 0.0]" in text
    path = tmp_path / "rule.toml"
    path.write_text(text.replace("\naxis = [0.0, 1.0, 0.0]", f"\naxis = {axis}", 1))
    return str(path)


def test_a_rule_the_euler_angles_cannot_write_is_a_task_error(tmp_path):
    # with the study's variables the Euler warm start adds a rule's angle to one Euler angle:
    # a diagonal axis was a ValueError (a traceback from the command line)
    from jtraj.transcription import COMPACT_VARIABLES, PAPER_VARIABLES

    path = _rule_file(tmp_path)
    task = tasks.load(path)
    robot = robot_lib.load(task.robot)
    expected = rf"^{re.escape(path)}: warm_start_rules\[0\].axis: \[1.0, 1.0, 0.0\]: with the Euler angles and warm_start_euler='angles' \(the study's variables\)"
    tr = Transcription(robot, task, parameterization.get("euler"), PAPER_VARIABLES)  # a given warm start needs no rule
    with pytest.raises(TaskError, match=expected):
        tr.warm_start()
    # the poses are rotated instead with other variables or another chart: accepted
    for param, options in (("euler", COMPACT_VARIABLES), ("se3", PAPER_VARIABLES)):
        tr = Transcription(robot, task, parameterization.get(param), options)
        assert tr.warm_start().shape == (tr.N + 1, tr.layout.nz)


@pytest.mark.parametrize(("axis", "principal"), [("[0.0, 1e-13, 0.0]", True), ("[1e-11, 1000.0, 0.0]", True), ("[1e-13, 1e-10, 0.0]", False)])
def test_the_euler_rule_check_reads_the_axis_direction(tmp_path, axis, principal):
    """Its length does not count (the warm start reads the unit axis): the check tested the raw
    entries, refusing [0, 1e-13, 0] and passing [1e-13, 1e-10, 0] to warm_start's ValueError."""
    from jtraj.transcription import PAPER_VARIABLES

    task = tasks.load(_rule_file(tmp_path, axis))
    tr = Transcription(robot_lib.load(task.robot), task, parameterization.get("euler"), PAPER_VARIABLES)
    if principal:
        assert tr.warm_start().shape == (tr.N + 1, tr.layout.nz)
    else:
        with pytest.raises(TaskError, match=r"warm_start_rules\[0\].axis"):
            tr.warm_start()



def test_a_yaw_is_not_blamed_for_what_the_target_joints_do(tmp_path):
    """Target joints that lift a foot, with a yaw beside them: the message blamed
    target.rotation_rpy, which turns about the vertical and lifts nothing."""
    path = tmp_path / "hop_yaw.toml"
    path.write_text(
        'name = "hop_yaw"\nrobot = "go2"\ntimestep = 0.05\n[target]\ntranslation = [0.1, 0.05, 0.0]\nrotation_rpy = [0.0, 0.0, 0.3]\n'
        "joints = [0.1, 0.8, -1.5, -0.1, 0.8, -1.5, 0.1, 1.0, -1.5, -0.1, 1.0, -1.5]\n"
        '[[phases]]\ncontacts = ["FL_foot", "FR_foot", "RL_foot", "RR_foot"]\nduration = 0.2\n'
        "[[phases]]\ncontacts = []\nduration = 0.1\n"
        '[[phases]]\ncontacts = ["FL_foot", "FR_foot", "RL_foot", "RR_foot"]\nduration = 0.2\n'
    )
    with pytest.raises(TaskError, match=r": target.joints: 12 joint angles: puts \w+ 0.0203 m above the terrain at the last knot"):
        _transcription(tasks.load(str(path))).build_nlp()
