"""Tasks as validated data: the six built-in tasks load, and bad definitions raise errors that
name the field and what was expected."""

import dataclasses
import importlib.resources
import math
import re
import tomllib

import numpy as np
import pytest

from jtraj import robot as robot_lib
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
    expected = {  # round(duration / h) per phase, summed (the paper's phase durations and time steps)
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
    names = tasks.available()
    assert {"walk", "hopscotch", "big_jump", "handstand", "backflip", "sideflip"} <= set(names)
    for name in names:
        t = tasks.load(name)
        assert t.validate() is t and t.name == name
        # what validate() stands for, checked here against the robot itself
        robot = robot_lib.load(t.robot)
        contacts = {c for phase in t.phases for c in phase.contacts}
        assert contacts <= set(robot.contact_groups), (name, contacts - set(robot.contact_groups))


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
    (_, standing), = t.warm_start_angles(after_ramp="standing")  # the study's scripts: later nodes untouched
    np.testing.assert_array_equal(standing[:29], angles[:29])
    assert np.all(standing[29:] == 0.0)
    with pytest.raises(ValueError, match="after_ramp='back'"):
        t.warm_start_angles(after_ramp="back")


@pytest.mark.parametrize(
    "changes, match",
    [
        (dict(robot="atlas"), r"^robot: 'atlas': expected one of \['g1', 'go2', 'talos', 'talos_full'\]$"),
        # the name is the run folders' (runs/NAME_PARAM): "../../x" wrote outside runs/
        *[(dict(name=name), rf"^name: {re.escape(repr(name))}: expected a plain name for the run folders") for name in ("../../escaped", "a/b", "a\\b", ".", "..", ".hidden", "a\nb")],
        (dict(timestep=0.0), r"^timestep: 0.0: expected a positive number of seconds$"),
        (dict(timestep=-0.05), r"^timestep: -0.05: expected a positive"),
        (dict(phases=(Phase(FEET, 0.1), Phase((), -0.2), Phase(FEET, 0.1))), r"^phases\[1\].duration: -0.2: expected a positive"),
        (dict(phases=(Phase(FEET, 0.1), Phase((), 0.0), Phase(FEET, 0.1))), r"^phases\[1\].duration: 0.0: expected a positive"),
        (dict(phases=(Phase(FEET, 0.1), Phase((), 0.01), Phase(FEET, 0.1))), r"^phases\[1\].duration: 0.01: shorter than one knot \(timestep 0.05 s\); expected at least 0.05 s$"),
        (dict(phases=(Phase(FEET, 0.1), Phase((), 0.03), Phase(FEET, 0.1))), r"^phases\[1\].duration: 0.03: shorter than one knot \(timestep 0.05 s\); expected at least 0.05 s$"),
        (dict(phases=(Phase("FL_foot", 0.1),)), r"^phases\[0\].contacts: 'FL_foot': expected a list of contact names"),
        # accepted: a blank name named the folder runs/ _se3; a repeated contact, likely a slip for another
        (dict(name=" "), r"^name: ' ': expected a non-empty string$"),
        (dict(name="jump "), r"^name: 'jump ': expected a name without leading or trailing spaces"),
        (dict(phases=(Phase(("FL_foot", "FL_foot"), 0.1),)), r"^phases\[0\].contacts: .*'FL_foot' given more than once; expected each contact once$"),
        # a duration between knots was rounded to the nearest knot (0.12 s flew 0.1 s)
        (dict(phases=(Phase(FEET, 0.1), Phase((), 0.12), Phase(FEET, 0.1))), r"^phases\[1\].duration: 0.12: not a whole number of timesteps \(0.05 s\); expected a multiple such as 0.1 or 0.15 s$"),
        (dict(friction=-0.5), r"^friction: -0.5: expected a positive"),
        (dict(friction="high"), r"^friction: 'high': expected a positive"),
        (dict(max_iter=-3), r"^max_iter: -3: expected a positive whole number"),
        (dict(max_iter="lots"), r"^max_iter: 'lots': expected a positive whole number"),
        (dict(phases=(Phase((), 0.1), Phase(FEET, 0.1))), r"^phases\[0\].contacts: \[\]: expected the task to start in contact"),
        (dict(flip_axis=(0.0, 0.0, 0.0), flip_turns=-1), r"^flip_axis: \[0.0, 0.0, 0.0\]: expected a list of 3 numbers, not all zero$"),
        (dict(flip_axis=(0.0, 1.0, 0.0)), r"^flip_turns: None: expected the signed number of turns"),
        (dict(flip_turns=1), r"^flip_turns: 1: expected no flip_turns without a flip_axis"),
        (dict(target_translation=(1.0, 0.0)), r"^target_translation: \[1.0, 0.0\]: expected a list of 3 numbers$"),
        (dict(warm_start_joints=(JointRule((7,), (("FL_calf_joint", -1.0),)),)), r"^warm_start_joints\[0\].phases: \[7\]: expected a non-empty list of phase indices in 0..2"),
        # two rules setting one joint in one phase: the later one won without a word
        (
            dict(warm_start_joints=(JointRule((0, 1), (("FL_calf_joint", -1.0),)), JointRule((1,), (("FL_thigh_joint", 0.5), ("FL_calf_joint", -2.0))))),
            r"^warm_start_joints\[1\].joints.FL_calf_joint: -2.0: also set in phase 1 by warm_start_joints\[0\]; expected each joint set by one rule per phase$",
        ),
    ],
)
def test_bad_tasks_fail_when_built(changes, match):
    # robot-independent checks: building the Task is enough, no robot model is loaded
    with pytest.raises(TaskError, match=match):
        small_task(**changes)


def test_joint_rules_may_share_a_phase_or_a_joint():
    rules = (JointRule((0,), (("FL_calf_joint", -1.0),)), JointRule((1,), (("FL_calf_joint", -2.0),)), JointRule((0, 1), (("FL_thigh_joint", 0.5),)))
    assert small_task(warm_start_joints=rules).warm_start_joints == rules


@pytest.mark.parametrize(
    "changes, match",
    [
        (dict(phases=(Phase(("FL_foot", "left_paw"), 0.1), Phase(FEET, 0.1))), r"^phases\[0\].contacts: 'left_paw': expected a contact of robot 'go2': one of \['FL_foot'"),
        (dict(target_joints=(0.0,) * 11), r"^target_joints: 11 values: expected 12"),
        (dict(target_joints=(0.0, 0.7, -1.5) * 3 + (0.0, 0.7, 5.0)), r"^target_joints\[11\] \(RR_calf_joint\): 5.0: outside the joint limits"),
        (dict(warm_start_joints=(JointRule((1,), (("FL_knee", 0.0),)),)), r"^warm_start_joints\[0\].joints: 'FL_knee': unknown joint"),
        (dict(warm_start_joints=(JointRule((1,), (("FL_calf_joint", 0.5),)),)), r"^warm_start_joints\[0\].joints.FL_calf_joint: 0.5: outside the joint limits"),
    ],
)
def test_bad_tasks_for_the_robot_raise_actionable_errors(go2, changes, match):
    task = small_task(**changes)
    with pytest.raises(TaskError, match=match):
        task.validate(go2)


def test_task_built_in_python_is_normalized_and_hashable():
    t = Task(name="hop", robot="go2", timestep=1, phases=[Phase(list(FEET), 1)], target_translation=[1, 0, 0], max_iter=np.int64(5))
    assert t.phases == (Phase(FEET, 1.0),) and t.target_translation == (1.0, 0.0, 0.0)
    assert isinstance(t.timestep, float) and type(t.max_iter) is int
    assert t.content_hash() == small_task().replace(phases=(Phase(FEET, 1.0),), timestep=1.0, target_translation=(1.0, 0.0, 0.0), max_iter=5).content_hash()
    assert hash(t) == hash(t.replace())
    assert t.content_hash() != t.replace(friction=0.8).content_hash()
    assert t.content_hash() == t.replace(description="other words").content_hash()


_GOOD = """name = "x"
robot = "go2"
timestep = 0.05
[target]
translation = [0.1, 0.0, 0.0]
[costs]
configuration = 0.0
[[phases]]
contacts = ["FL_foot", "FR_foot", "RL_foot", "RR_foot"]
duration = 0.2
[[phases]]
contacts = []
duration = 0.1
[[phases]]
contacts = ["FL_foot", "FR_foot", "RL_foot", "RR_foot"]
duration = 0.2
[[warm_start_rules]]
axis = [0.0, 1.0, 0.0]
angle = 0.5
phases = [1]
"""


@pytest.mark.parametrize(
    "old, new, match",
    [
        ("[costs]\nconfiguration", "[costs]\nconfigration", r"costs.configration: unknown key: did you mean 'configuration'\? expected one of \['configuration', 'acceleration'\]"),
        ("translation =", "translaton =", r"target.translaton: unknown key: did you mean 'translation'\?"),
        ("duration = 0.1", "duration = 0.1\nforce = 3", r"phases\[1\].force: unknown key"),
        ("angle = 0.5", "angel = 0.5", r"warm_start_rules\[0\].angel: unknown key"),
        ("angle = 0.5\n", "", r"warm_start_rules\[0\].angle: missing: expected a rotation angle"),
        ("axis = [0.0, 1.0, 0.0]\n", "", r"warm_start_rules\[0\].axis: missing"),
        ("phases = [1]\n", "", r"warm_start_rules\[0\].phases: missing"),
        # a ramp over [0, 2] ramped through phase 1 as well
        ("phases = [1]\n", "phases = [0, 2]\n", r"warm_start_rules\[0\].phases: \[0, 2\]: a ramp spans consecutive phases; expected every index from 0 to 2"),
        ('robot = "go2"', 'robot = "go2"\nfriction = "high"', r"friction: 'high': expected a positive friction coefficient"),
        ('robot = "go2"', 'robot = "go2"\nmax_iter = "lots"', r"max_iter: 'lots': expected a positive whole number"),
        ('robot = "go2"', 'robot = "go2"\nmax_iter = -1', r"max_iter: -1: expected"),
        ('robot = "go2"', 'robot = "go2"\nmax_iter = 2.5', r"max_iter: 2.5: expected"),
        ('robot = "go2"', 'robot = "go2"\nflip_axis = [0, 0, 0]\nflip_turns = -1', r"flip_axis: \[0, 0, 0\]: expected a list of 3 numbers, not all zero"),
        ("contacts = []", 'contacts = "FL_foot"', r"phases\[1\].contacts: 'FL_foot': expected a list of contact names"),
        ("timestep = 0.05", "timestep = 0", r"timestep: 0: expected a positive number of seconds"),
        ("timestep = 0.05", 'timestep = "fast"', r"timestep: 'fast': expected a positive number"),
        ("duration = 0.1", "duration = 0", r"phases\[1\].duration: 0: expected a positive"),
        ("duration = 0.1", "duration = 0.33", r"phases\[1\].duration: 0.33: not a whole number of timesteps \(0.05 s\); expected a multiple such as 0.3 or 0.35 s"),
        ("[target]\n", "[target]\nrotation_rpy = 3\n", r"target.rotation_rpy: 3: expected a list of 3 numbers"),
        ('robot = "go2"', 'robot = "spot"', r"robot: 'spot': expected one of"),
        ('name = "x"', 'name = "../../escaped"', r"name: '../../escaped': expected a plain name for the run folders \(e.g. my_jump\)"),
        ('robot = "go2"', 'robot = "go2"\nspeed = 3', r"speed: unknown key: expected one of \["),  # (it said "unknown field" at the top level)
        # integers past float's range (TOML reads any size), and a name too long for a folder:
        # an OverflowError and an OSError ("File name too long") traceback before
        ('robot = "go2"', 'robot = "go2"\nfriction = 1' + "0" * 400, r"friction: 10{400}: expected a positive friction coefficient"),
        ("angle = 0.5", "angle = 1" + "0" * 400, r"warm_start_rules\[0\].angle: 10{400}: expected"),
        ('name = "x"', 'name = "' + "a" * 201 + '"', r"name: 'a{201}': expected a name of at most 200 bytes \(it names the run folders\)"),
        # an angle past half a turn is a smaller one's attitude: [0, 0, 2 pi] (a spin meant)
        # solved as a plain hop, 90 (degrees meant) as 116.6 degrees
        ("[target]\n", "[target]\nrotation_rpy = [0.0, 0.0, 6.283185307179586]\n", r"target.rotation_rpy: \[0.0, 0.0, 6.283185307179586\]: expected angles \(rad\) within \[-pi, pi\]: .* whole turns on the way are flip_axis and flip_turns"),
        ("[target]\n", "[target]\nrotation_rpy = [0.0, 90.0, 0.0]\n", r"target.rotation_rpy: \[0.0, 90.0, 0.0\]: expected angles \(rad\) within \[-pi, pi\]"),
        # half a turn with an upright target can never end as its success check expects
        ('robot = "go2"', 'robot = "go2"\nflip_axis = [0, 1, 0]\nflip_turns = 0.5', r"flip_turns: 0.5: expected a whole number of turns: the target's attitude is the standing one"),
    ],
)
def test_task_file_errors_name_file_field_value_and_expectation(tmp_path, old, new, match):
    path = tmp_path / "mine.toml"
    assert old in _GOOD
    path.write_text(_GOOD.replace(old, new, 1))
    with pytest.raises(TaskError, match=match) as e:
        tasks.load(str(path))
    assert str(e.value).startswith(f"{path}: ") and "\n" not in str(e.value)


@pytest.mark.parametrize(
    "old, new, match",
    [
        ('contacts = []', 'contacts = ["FL_foot", "left_paw"]', r"phases\[1\].contacts: 'left_paw': expected a contact of robot 'go2'"),
        ("[target]\n", "[target]\njoints = [0.0, 0.7, -1.5, 0.0, 0.7, -1.5, 0.0, 0.7, -1.5, 0.0, 0.7, 5.0]\n", r"target.joints\[11\] \(RR_calf_joint\): 5.0: outside the joint limits"),
    ],
)
def test_robot_checks_of_a_task_file_name_the_file_and_its_keys(go2, tmp_path, old, new, match):
    """validate() of a task loaded from a file: the error named neither the file nor the TOML
    key (``target_joints[11]``, a Python name), as a solve from Python reported it."""
    path = tmp_path / "mine.toml"
    path.write_text(_GOOD.replace(old, new, 1))
    task = tasks.load(str(path))
    with pytest.raises(TaskError, match=f"^{path}: {match}") as e:
        task.validate(go2)
    assert e.value.source == str(path) and "\n" not in str(e.value)
    assert task == tasks.from_dict(tomllib.loads(path.read_text())) and task.content_hash() == task.replace().content_hash()


def test_the_module_docstring_gives_every_key():
    """The README sends users to the module docstring for "the whole format": it left out
    force_limit_factor, terrain_height, description and target.joints, which files accept."""
    doc = tasks.__doc__
    keys = [k for k in tasks._TOP_KEYS if k != "warm_start"] + [k for table in ("target", "costs", "phases", "warm_start_rules", "warm_start_joints") for k in tasks._TABLE_KEYS[table]]
    missing = [k for k in keys if f"{k} =" not in doc and f"[{k}]" not in doc]
    assert not missing


def test_phases_must_be_an_array_of_tables():
    with pytest.raises(TaskError, match=r"^<dict>: phases: 3: expected an array of tables \[\[phases\]\]"):
        tasks.from_dict({"name": "x", "robot": "go2", "timestep": 0.05, "phases": 3})


def test_warm_start_is_the_former_name_of_warm_start_rules(tmp_path):
    """The old key of task files and the old constructor keyword still work, with a warning."""
    from jtraj.task import Profile, RotationRule

    rule = RotationRule(Profile.RAMP, (0.0, 1.0, 0.0), 0.5, (1,))
    new = small_task(warm_start_rules=(rule,))
    with pytest.warns(DeprecationWarning, match="warm_start_rules"):
        old = small_task(warm_start=(rule,))
    assert old == new and old.content_hash() == new.content_hash() and old.warm_start_rules == (rule,)
    with pytest.warns(DeprecationWarning, match="Task.warm_start is deprecated"):
        assert new.warm_start == (rule,)
    with pytest.raises(TaskError, match="expected only warm_start_rules"):
        small_task(warm_start_rules=(rule,), warm_start=(rule,))
    path = tmp_path / "old.toml"
    path.write_text(_GOOD.replace("[[warm_start_rules]]", "[[warm_start]]"))
    with pytest.warns(DeprecationWarning, match=r"\[\[warm_start\]\] in a task file"):
        from_old_file = tasks.load(str(path))
    path.write_text(_GOOD)
    assert from_old_file == tasks.load(str(path)) and from_old_file.warm_start_rules[0].angle == 0.5
    # an error in such a file names its key as the file writes it (it said warm_start_rules[0])
    path.write_text(_GOOD.replace("[[warm_start_rules]]", "[[warm_start]]").replace("axis = [0.0, 1.0, 0.0]", "axis = [0.0, 0.0, 0.0]"))
    with pytest.warns(DeprecationWarning), pytest.raises(TaskError, match=r": warm_start\[0\].axis: \[0.0, 0.0, 0.0\]: expected a list of 3 numbers, not all zero$"):
        tasks.load(str(path))
    path.write_text(_GOOD + _GOOD[_GOOD.index("[[warm_start_rules]]") :].replace("[[warm_start_rules]]", "[[warm_start]]"))
    with pytest.raises(TaskError, match=r"expected only \[\[warm_start_rules\]\]"):
        tasks.load(str(path))


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
    with pytest.raises(TaskError, match="does not exist"):
        tasks.load(str(tmp_path / "missing.toml"))
    (tmp_path / "dir.toml").mkdir()  # was "does not exist"
    with pytest.raises(TaskError, match=r"^task file: '.*dir.toml': is a folder; expected a .toml task file$"):
        tasks.load(str(tmp_path / "dir.toml"))
    # a description written in Latin-1 ended in a UnicodeDecodeError from inside tomllib
    path.write_bytes(path.read_bytes() + 'description = "d\xe9part"\n'.encode("latin-1"))
    with pytest.raises(TaskError, match=r"^task file: '.*mine.toml': not UTF-8 text \(invalid continuation byte at byte \d+\); expected a TOML file in UTF-8$"):
        tasks.load(str(path))
    with pytest.raises(TaskError, match=r"^task: 'moonwalk': unknown task"):
        tasks.load("moonwalk")


def test_retarget_changes_the_robot_and_nothing_else():
    walk = tasks.load("walk")
    full = tasks.retarget(walk, {"talos": "talos_full"})
    assert full.robot == "talos_full" and full.validate() is full
    assert dataclasses.replace(full, robot="talos") == walk
    assert full.content_hash() != walk.content_hash()  # runs on either model keep their own keys
    assert tasks.retarget(walk, {"go2": "talos"}) is walk
    with pytest.raises(tasks.TaskError, match="expected a contact of robot 'go2'"):
        tasks.retarget(walk, {"talos": "go2"}).validate()


@pytest.mark.parametrize("bench", ["solve", "hessians", "mu_oracle", "unit_norm"])
def test_benchmarks_refuse_an_unknown_task_when_parsing(bench, capsys):
    """The benchmarks' task arguments go through `jtraj.task.task_argument`: an unknown task is
    argparse's one-line error (exit 2), before a peer runs or anything compiles."""
    from conftest import bench_module

    with pytest.raises(SystemExit) as exit:
        bench_module(bench).main(["moonwalk"])
    assert exit.value.code == 2
    assert "argument task" in (err := capsys.readouterr().err) and "'moonwalk': unknown task; expected one of ['backflip'" in err
    assert tasks.task_argument("big_jump") == "big_jump"


@pytest.mark.parametrize(
    "old, new, match",
    [
        # the count was infinite, and round() raised OverflowError from inside the loader
        ("timestep = 0.05", "timestep = 5e-324", r"phases\[0\].duration: 0.2: inf knots at the timestep 4.94066e-324 s; expected at most 100000 knots in a task \(a longer timestep or a shorter phase\)$"),
        # 4 million knots (1e-7 s: 23 million for big_jump, which ran out of memory)
        ("timestep = 0.05", "timestep = 1e-7", r"phases\[0\].duration: 0.2: 2e\+06 knots at the timestep 1e-07 s; expected at most 100000 knots"),
        # accepted, then schedule() raised OverflowError
        ("duration = 0.1", "duration = 1e300", r"phases\[1\].duration: 1e\+300: 2e\+301 knots at the timestep 0.05 s; expected at most 100000 knots"),
        # every phase under the cap, the task over it: 40000 + 20000 + 40000 intervals
        ("timestep = 0.05", "timestep = 5e-6", r"timestep: 5e-06: 100001 knots over the phases' 0.5 s; expected at most 100000 knots in a task \(a longer timestep or shorter phases\)$"),
    ],
)
def test_knot_counts_over_the_cap_are_refused_when_loaded(tmp_path, old, new, match):
    path = tmp_path / "mine.toml"
    path.write_text(_GOOD.replace(old, new, 1))
    with pytest.raises(TaskError, match=rf"^{re.escape(str(path))}: {match}") as e:
        tasks.load(str(path))
    assert "\n" not in str(e.value)


def test_the_knot_cap_is_on_the_task_s_knots():
    with pytest.raises(TaskError, match=r"^phases\[0\].duration: 100000.0: 100001 knots at the timestep 1 s; expected at most 100000 knots"):
        small_task(timestep=1.0, phases=(Phase(FEET, 100_000.0),))
    with pytest.raises(TaskError, match=r"^timestep: 1.0: 100001 knots over the phases' 100000 s; expected at most 100000 knots"):
        small_task(timestep=1.0, phases=(Phase(FEET, 50_000.0), Phase(FEET, 50_000.0)))
    assert small_task(timestep=1.0, phases=(Phase(FEET, 99_999.0),)).n_knots == tasks.MAX_KNOTS == 100_000
    assert max(tasks.load(name).n_knots for name in tasks.available()) < tasks.MAX_KNOTS


def test_max_iter_is_bounded_by_ipopt_s_limit(tmp_path):
    # 2**63 - 1 loaded, then failed inside Ipopt's option check with a traceback
    with pytest.raises(TaskError, match=r"^max_iter: 2147483648: expected a positive whole number of iterations, at most 2147483647 \(Ipopt's limit\)$"):
        small_task(max_iter=2**31)
    assert small_task(max_iter=2**31 - 1).max_iter == tasks.MAX_ITER == 2**31 - 1
    path = tmp_path / "mine.toml"
    path.write_text(_GOOD.replace('robot = "go2"', 'robot = "go2"\nmax_iter = 9223372036854775807', 1))
    with pytest.raises(TaskError, match=rf"^{re.escape(str(path))}: max_iter: 9223372036854775807: expected a positive whole number of iterations, at most 2147483647"):
        tasks.load(str(path))


@pytest.mark.parametrize("axis", [(1e-200, 0.0, 0.0), (1e200, 1e200, 0.0), (0.0, 3e150, 4e150), (0.0, 9e-151, 0.0)])
def test_axes_whose_length_underflows_or_overflows_are_refused(tmp_path, axis):
    # they were accepted: the warm start's axis came out NaN ([1e-200, 0, 0]) or zero, and so did
    # the flip check's (jtraj.success divides by np.linalg.norm)
    shown = re.escape(repr(list(axis)))
    expected = r"expected an axis of length between 1e-150 and 1e150, e.g. \[1, 0, 0\] \(its length does not matter, only its direction\)$"
    with pytest.raises(TaskError, match=rf"^flip_axis: {shown}: {expected}"):
        small_task(flip_axis=axis, flip_turns=1)
    path = tmp_path / "mine.toml"
    path.write_text(_GOOD.replace("axis = [0.0, 1.0, 0.0]", f"axis = [{', '.join(map(repr, axis))}]", 1))
    with pytest.raises(TaskError, match=rf"^{re.escape(str(path))}: warm_start_rules\[0\].axis: {shown}: {expected}"):
        tasks.load(str(path))


def test_short_and_long_axes_within_range_give_unit_warm_start_axes():
    for axis in ((0.0, 1e-150, 0.0), (0.0, 3e149, 4e149)):
        rule = tasks.RotationRule(tasks.Profile.RAMP, axis, 1.0, (1,))
        ((unit, _),) = small_task(warm_start_rules=(rule,)).warm_start_angles()
        np.testing.assert_allclose(unit, np.asarray(axis) / np.hypot(axis[1], axis[2]), rtol=1e-15)


def test_a_task_error_survives_a_worker_process():
    """A TaskError raised in a worker of a sweep is pickled back to the parent: it was rebuilt
    from its one-line message alone, which __init__ does not take (a TypeError, which the
    process pool reports as a lost worker)."""
    import pickle

    error = TaskError("phases[0].contacts", tasks._Raw("['left_hand']"), "expected the lowest points", "mine.toml")
    back = pickle.loads(pickle.dumps(error))
    assert type(back) is TaskError and str(back) == str(error) == "mine.toml: phases[0].contacts: ['left_hand']: expected the lowest points"
    assert (back.field, back.value, back.expected, back.source) == (error.field, error.value, error.expected, error.source)


def test_a_retargeted_task_file_keeps_its_file_for_its_errors(tmp_path):
    """`--robot talos=talos_full` moved a task file to another model and lost its file name:
    the errors found later (its fixed knots) named no file."""
    path = tmp_path / "mine.toml"
    path.write_text((importlib.resources.files("jtraj.tasks") / "big_jump.toml").read_text())
    task = tasks.load(str(path))
    moved = tasks.retarget(task, {"talos": "talos_full"})
    assert moved.robot == "talos_full" and moved._source == task._source == str(path)
    assert tasks.retarget(task, {"go2": "g1"}) is task


def test_a_tasks_own_errors_name_its_file_and_toml_keys(tmp_path):
    """`Task.error`: the transcription's errors about a task name its file as `validate`'s do
    (one helper, where the transcription had two copies of it)."""
    path = tmp_path / "mine.toml"
    path.write_text(
        'name = "mine"\nrobot = "go2"\ntimestep = 0.05\n'
        '[[phases]]\ncontacts = ["FL_foot", "FR_foot", "RL_foot", "RR_foot"]\nduration = 0.2\n'
    )
    error = tasks.load(str(path)).error("target_joints[3]", 1.5, "expected a value in the joint's limits")
    assert isinstance(error, TaskError)
    assert error.source == str(path)
    assert str(error) == f"{path}: target.joints[3]: 1.5: expected a value in the joint's limits"
    built = dataclasses.replace(tasks.load("big_jump"))  # not from a file: no source
    assert built.error("timestep", 0.0, "expected > 0").source is None


def test_rules_given_in_python_as_a_user_would_write_them():
    """A profile given as "ramp" was refused as "expected 'ramp' or 'hold'", and one rule (or
    None) in place of the tuple raised "object is not iterable"."""
    from jtraj.task import Profile, RotationRule

    rule = RotationRule("ramp", (0.0, 1.0, 0.0), 0.5, (1,))  # type: ignore[arg-type]
    assert small_task(warm_start_rules=(rule,)).warm_start_rules[0].profile is Profile.RAMP
    for field, value in (("warm_start_rules", rule), ("warm_start_rules", None), ("warm_start_joints", None)):
        with pytest.raises(TaskError, match=rf"^{field}: .*: expected a list of \w+ \(empty: none\)$"):
            small_task(**{field: value})
    with pytest.raises(TaskError, match=r"warm_start_rules\[0\].profile: 'spin': expected 'ramp' or 'hold'"):
        small_task(warm_start_rules=(RotationRule("spin", (0.0, 1.0, 0.0), 0.5, (1,)),))  # type: ignore[arg-type]


def test_half_a_turn_as_typed_is_accepted():
    """The range check of target.rotation_rpy refused 3.1416 and float32's pi, both half a
    turn as people write it."""
    for yaw in (3.1416, float(np.float32(np.pi)), -math.pi):
        assert small_task(target_rotation_rpy=(0.0, 0.0, yaw)).target_rotation_rpy[2] == yaw
    with pytest.raises(TaskError, match=r"expected angles \(rad\) within \[-pi, pi\]"):
        small_task(target_rotation_rpy=(0.0, 0.0, 3.15))



def test_the_module_docstrings_toml_example_loads(tmp_path):
    """The README calls jtraj.task's docstring the whole format; its example named phases 1 and
    2 of a one-phase task and held a placeholder that is no TOML (a review)."""
    import jtraj.task as task_lib
    from jtraj import robot as robot_lib

    doc = task_lib.__doc__
    block = doc[doc.index("TOML form") :].split("::\n\n", 1)[1].split("\n\n", 1)[0]
    text = "\n".join(line[4:] for line in block.splitlines())
    (tmp_path / "example.toml").write_text(text)
    loaded = task_lib.from_file(tmp_path / "example.toml")
    loaded.validate(robot_lib.load(loaded.robot))
    assert (loaded.name, len(loaded.phases), loaded.flip_turns) == ("my_flip", 3, -1)


def test_a_task_file_with_an_upper_case_extension_is_a_file(tmp_path):
    """TINY.TOML was refused as an unknown built-in task, though it is a task file."""
    import importlib.resources

    from jtraj import task as task_lib

    text = (importlib.resources.files("jtraj.tasks") / "big_jump.toml").read_text()
    (tmp_path / "JUMP.TOML").write_text(text)
    assert task_lib.load(str(tmp_path / "JUMP.TOML")).name == "big_jump"
    (tmp_path / "jump").write_text(text)
    with pytest.raises(task_lib.TaskError, match=r"a file of that name exists: give its path with the \.toml extension"):
        task_lib.load(str(tmp_path / "jump"))
