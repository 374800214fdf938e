"""Tasks as validated data: the six built-in tasks load, and bad definitions raise errors that
name the field and what was expected."""

import dataclasses

import numpy as np
import pytest

from jtraj import task as tasks
from jtraj.task import JointRule, Phase, Task, TaskError

FEET = ("FL_foot", "FR_foot", "RL_foot", "RR_foot")


@pytest.fixture(scope="module")
def go2():
    from jtraj import robot

    return robot.load("go2")


def small_task(**changes):
    base = Task(name="hop", robot="go2", timestep=0.05, phases=(Phase(FEET, 0.1), Phase((), 0.1), Phase(FEET, 0.1)), target_translation=(0.05, 0.0, 0.0))
    return dataclasses.replace(base, **changes)


def test_builtin_tasks_load_with_paper_knot_counts():
    assert tasks.available() == ["backflip", "big_jump", "handstand", "hopscotch", "sideflip", "walk"]
    expected = {  # round(duration / h) per phase, summed (REFERENCE.md)
        "walk": 20 + 3 * (8 + 6 + 8 + 6) + 20,
        "hopscotch": 6 + 4 + 10 + 4 + 10 + 4 + 10 + 4 + 10 + 4 + 20,
        "big_jump": 20 + 6 + 20,
        "handstand": 10 + 4 + 40 + 4 + 10,
        "backflip": 20 + 8 + 20,
        "sideflip": 50 + 20 + 50,
    }
    for name, n in expected.items():
        t = tasks.load(name)
        assert t.n_intervals == n, name
        assert t.n_knots == n + 1


def test_builtin_tasks_validate():
    for name in tasks.available():
        tasks.load(name).validate()


def test_schedule_of_big_jump():
    from jtraj import robot

    t = tasks.load("big_jump")
    s = t.schedule(robot.load("talos"))
    assert len(s.points) == 8  # four corners per foot
    assert s.in_contact[:20].all() and not s.in_contact[20:26].any() and s.in_contact[26:].all()


def test_warm_start_ramp_reaches_full_turn_over_flight():
    t = tasks.load("backflip")
    (axis, angles), = t.warm_start_angles()
    np.testing.assert_allclose(axis, [0, 1, 0])
    assert angles[20] == 0.0 and abs(angles[28] + 2 * np.pi) < 1e-12 and abs(angles[-1] + 2 * np.pi) < 1e-12
    assert np.all(np.diff(angles) <= 1e-15)


@pytest.mark.parametrize(
    "changes, match",
    [
        (dict(robot="atlas"), r"field 'robot' is 'atlas'; expected one of \['g1', 'go2', 'talos'\]"),
        (dict(timestep=0.0), r"field 'timestep' is 0.0; expected a positive number"),
        (dict(phases=(Phase(FEET, 0.1), Phase((), -0.2), Phase(FEET, 0.1))), r"phases\[1\].duration is -0.2; expected a positive"),
        (dict(phases=(Phase(FEET, 0.1), Phase((), 0.01), Phase(FEET, 0.1))), r"phases\[1\].duration 0.01 s is shorter than one knot"),
        (dict(phases=(Phase(("FL_foot", "left_paw"), 0.1), Phase(FEET, 0.1))), r"unknown contact 'left_paw'; expected one of \['FL_foot'"),
        (dict(target_joints=(0.0,) * 11), r"'target_joints' has 11 values; expected 12"),
        (dict(target_joints=(0.0, 0.7, -1.5) * 3 + (0.0, 0.7, 5.0)), r"target joint 'RR_calf_joint' = 5 rad is outside its limits"),
        (dict(friction=-0.5), r"field 'friction' is -0.5"),
        (dict(phases=(Phase((), 0.1), Phase(FEET, 0.1))), r"phases\[0\].contacts is empty"),
        (dict(warm_start_joints=(JointRule((1,), (("FL_knee", 0.0),)),)), r"warm_start_joints\[0\] names unknown joint 'FL_knee'"),
        (dict(warm_start_joints=(JointRule((1,), (("FL_calf_joint", 0.5),)),)), r"sets 'FL_calf_joint' = 0.5 rad, outside its limits"),
        (dict(warm_start_joints=(JointRule((7,), (("FL_calf_joint", -1.0),)),)), r"warm_start_joints\[0\].phases is \[7\]"),
    ],
)
def test_bad_tasks_raise_actionable_errors(go2, changes, match):
    with pytest.raises(TaskError, match=match):
        small_task(**changes).validate(go2)


def test_joint_rule_shapes_the_warm_start(go2):
    from jtraj.parameterization import get
    from jtraj.transcription import Transcription

    rule = JointRule((1,), (("FL_calf_joint", -2.0),), place_on_terrain=False)
    tr = Transcription(go2, small_task(warm_start_joints=(rule,)), get("se3"))
    Z = tr.warm_start()
    calf = tr.param.nq + go2.joint_names.index("FL_calf_joint")
    flight = tr.schedule.phase_of_knot == 1
    np.testing.assert_allclose(Z[flight, calf], -2.0)
    np.testing.assert_allclose(Z[~flight, calf], go2.q_joints_standing[go2.joint_names.index("FL_calf_joint")])


def test_task_files(tmp_path):
    path = tmp_path / "mine.toml"
    path.write_text(
        'name = "mine"\nrobot = "go2"\ntimestep = 0.05\n'
        '[[phases]]\ncontacts = ["FL_foot", "FR_foot", "RL_foot", "RR_foot"]\nduration = 0.2\n'
    )
    t = tasks.load(str(path))
    assert t.n_knots == 5 and t.phases[0].contacts == FEET
    path.write_text('name = "x"\nrobot = "go2"\ntimestep = 0.05\nphases = []\nspeed = 3\n')
    with pytest.raises(TaskError, match=r"unknown field\(s\) \['speed'\]"):
        tasks.load(str(path))
    with pytest.raises(TaskError, match="does not exist"):
        tasks.load(str(tmp_path / "missing.toml"))
    with pytest.raises(TaskError, match="unknown task 'moonwalk'"):
        tasks.load("moonwalk")
