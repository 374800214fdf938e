"""Robot definitions: loading, the declared data, and agreement with Pinocchio and MuJoCo."""

import dataclasses
import importlib.resources
import tomllib
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin
import pytest
from conftest import mujoco_contact_positions

from jtraj import robot as robot_lib

ROBOTS = ("talos", "talos_full", "g1", "go2")
EXPECTED = {  # name: (joints, nv, contact groups and their sizes)
    "talos": (30, 36, {"left_foot": 4, "right_foot": 4, "left_hand": 1, "right_hand": 1}),
    "talos_full": (30, 36, {"left_foot": 4, "right_foot": 4, "left_hand": 1, "right_hand": 1}),
    "g1": (29, 35, {"left_foot": 4, "right_foot": 4, "left_hand": 1, "right_hand": 1}),
    "go2": (12, 18, {"FL_foot": 1, "FR_foot": 1, "RL_foot": 1, "RR_foot": 1}),
}


def pinocchio_model(robot):
    """Pinocchio model from the same URDF, locked joints removed at 0, one frame per contact."""
    model, frames, _, _ = robot_lib.to_pinocchio(robot)
    return model, frames


def pinocchio_q(model, robot, xyz_wxyz, q_joints):
    q = np.zeros(model.nq)
    q[:3] = xyz_wxyz[:3]
    w, x, y, z = xyz_wxyz[3:7]
    q[3:7] = [x, y, z, w]
    for name, value in zip(robot.joint_names, q_joints):
        q[model.joints[model.getJointId(name)].idx_q] = value
    return q


@pytest.fixture(scope="module", params=ROBOTS)
def robot(request):
    return robot_lib.load(request.param)


def test_available_lists_the_four_robot_models():
    """The three robots, Talos in two models: exactly the ones the tests below check."""
    assert sorted(robot_lib.available()) == sorted(ROBOTS)


def test_sizes_and_groups(robot):
    nj, nv, groups = EXPECTED[robot.name]
    assert robot.nj == robot.nq_joints == nj
    assert robot.nv == nv == robot.mj_model.nv == robot.mjx_model.nv
    assert robot.mj_model.nq == 7 + nj
    assert len(set(robot.joint_names)) == nj
    assert not set(robot.locked_joints) & set(robot.joint_names)
    assert {g: len(idx) for g, idx in robot.contact_groups.items()} == groups
    for idx in robot.contact_groups.values():
        assert all(0 <= i < robot.ncontact for i in idx)
    assert robot.contact_offsets.shape == (robot.ncontact, 3)
    assert robot.contact_body_ids.shape == (robot.ncontact,)
    assert robot.gravity == pytest.approx(9.81)


def test_joint_order_is_mujoco_qpos_order(robot):
    m = robot.mj_model
    for k, name in enumerate(robot.joint_names):
        j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)
        assert m.jnt_qposadr[j] == 7 + k
        assert m.jnt_dofadr[j] == 6 + k


def test_talos_grippers_locked():
    talos = robot_lib.load("talos")
    assert set(talos.locked_joints) == {"gripper_left_joint", "gripper_right_joint"}
    assert "gripper_left_joint" not in talos.joint_names


def test_talos_full_is_the_study_codes_talos():
    """talos_full: talos_full_v2's links, joints and masses (the study's code's Talos), the
    seven joints of each gripper locked; the same joints, standing pose and contacts as talos,
    whose talos_reduced model is lighter and has far weaker arms."""
    full, reduced = robot_lib.load("talos_full"), robot_lib.load("talos")
    assert full.urdf_path.name == "talos_full_v2.urdf"
    assert len(full.locked_joints) == 14 and all(j.startswith("gripper_") for j in full.locked_joints)
    assert full.joint_names == reduced.joint_names
    np.testing.assert_array_equal(full.q_joints_standing, reduced.q_joints_standing)
    assert full.contact_names == reduced.contact_names

    # the mass of every link of each URDF, read here independently of the loader (locked
    # joints and fused links keep their masses): 93.336 kg in talos_full_v2.urdf, 90.272 kg in
    # talos_reduced.urdf (example-robot-data's files; robots/talos_full.toml: "3.1 kg lighter")
    def urdf_mass(path):
        links = ET.parse(path).getroot().findall("link")
        return sum(float(link.find("inertial/mass").get("value")) for link in links if link.find("inertial") is not None)

    assert reduced.urdf_path.name == "talos_reduced.urdf"
    assert full.total_mass == pytest.approx(urdf_mass(full.urdf_path)) == pytest.approx(93.336, abs=1e-3)
    assert reduced.total_mass == pytest.approx(urdf_mass(reduced.urdf_path)) == pytest.approx(90.272, abs=1e-3)
    tau = dict(zip(full.joint_names, full.tau_max))
    tau_reduced = dict(zip(reduced.joint_names, reduced.tau_max))
    assert (tau["arm_left_5_joint"], tau_reduced["arm_left_5_joint"]) == (20.0, 3.0)
    assert (tau["torso_1_joint"], tau_reduced["torso_1_joint"]) == (200.0, 78.0)


def test_load_is_cached_and_frozen():
    talos = robot_lib.load("talos")
    assert robot_lib.load("talos") is talos
    with pytest.raises(dataclasses.FrozenInstanceError):
        talos.name = "other"
    with pytest.raises(ValueError, match="read-only"):
        talos.q_joints_standing[0] = 1.0


def test_pure_rigid_body_model(robot):
    m = robot.mj_model
    assert np.all(m.dof_damping == 0) and np.all(m.dof_armature == 0) and np.all(m.dof_frictionloss == 0)
    assert m.ngeom == 0  # geometry stripped for dynamics
    assert m.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE


def test_limits_agree_with_mujoco_and_urdf(robot):
    m = robot.mj_model
    ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n) for n in robot.joint_names]
    ranges = m.jnt_range[ids]
    np.testing.assert_allclose(robot.q_lower, ranges[:, 0])
    np.testing.assert_allclose(robot.q_upper, ranges[:, 1])
    assert np.all(robot.q_lower < robot.q_upper)
    assert np.all(np.isfinite(robot.v_max)) and np.all(robot.v_max > 0)
    assert np.all(np.isfinite(robot.tau_max)) and np.all(robot.tau_max > 0)
    # velocity limits come from the URDF (MuJoCo drops them)
    urdf = ET.parse(robot.urdf_path).getroot()
    by_name = {j.get("name"): j for j in urdf.findall("joint")}
    for k, name in enumerate(robot.joint_names):
        limit = by_name[name].find("limit")
        assert robot.v_max[k] == float(limit.get("velocity"))
        assert robot.tau_max[k] == float(limit.get("effort"))


def test_go2_effort_limits():
    go2 = robot_lib.load("go2")
    for name, effort in zip(go2.joint_names, go2.tau_max):
        expected = 45.43 if "calf" in name else 23.7
        assert effort == pytest.approx(expected), name


#: How far (m) from the ground the standing pose's lowest foot point may be: the study's base
#: heights have 4 or 5 decimals (G1's 0.6756 puts its soles 0.073 mm below the ground).
STANDING_HEIGHT_TOLERANCE = 1e-4


def _assert_stands_on_its_feet(robot):
    """What the standing base height means: with the standing joint angles, the lowest of the
    robot's contact points is a foot point (a point of a ``*foot*`` contact group) at z = 0, the
    ground, by MuJoCo's forward kinematics."""
    z = mujoco_contact_positions(robot, robot.qpos_standing)[:, 2]
    feet = sorted(i for g, idx in robot.contact_groups.items() if "foot" in g for i in idx)
    assert feet and int(np.argmin(z)) in feet, (robot.name, z)
    assert abs(z.min()) < STANDING_HEIGHT_TOLERANCE, (robot.name, robot.contact_names[int(np.argmin(z))], z.min())


def test_standing_pose_values():
    # the legs' angles and base heights are the study's public code's standing poses (its
    # Talos, G1 and Go2 wrappers set q[2] = 1.0274, 0.6756 and 0.31131): the robots' files must
    # keep them, since the warm starts and Table IV's tasks start from these poses
    talos = robot_lib.load("talos")
    q = dict(zip(talos.joint_names, talos.q_joints_standing))
    for side in ("left", "right"):
        hip, knee, ankle = (q[f"leg_{side}_{i}_joint"] for i in (3, 4, 5))
        assert (hip, knee, ankle) == (-0.4, 0.8, -0.4)
    assert talos.base_xyz_wxyz_standing.tolist() == [0.0, 0.0, 1.0274, 1.0, 0.0, 0.0, 0.0]
    _assert_stands_on_its_feet(talos)
    # arms as in talos.srdf's half_sitting (read independently here)
    srdf = robot_lib.robots_data_dir() / "talos_data" / "srdf" / "talos.srdf"
    state = next(s for s in ET.parse(srdf).getroot().iter("group_state") if s.get("name") == "half_sitting")
    joints = [j for j in state.iter("joint") if j.get("name").startswith("arm_")]
    arms = {j.get("name"): float(j.get("value")) for j in joints}
    assert len(arms) == 14
    for name, value in arms.items():
        assert q[name] == value, name

    g1 = robot_lib.load("g1")
    q = dict(zip(g1.joint_names, g1.q_joints_standing))
    for side in ("left", "right"):
        hip, knee, ankle = (q[f"{side}_{j}_joint"] for j in ("hip_pitch", "knee", "ankle_pitch"))
        assert (hip, knee, ankle) == (-0.6, 1.2, -0.6)
    assert g1.base_xyz_wxyz_standing[2] == 0.6756
    _assert_stands_on_its_feet(g1)

    go2 = robot_lib.load("go2")
    q = dict(zip(go2.joint_names, go2.q_joints_standing))
    for leg in ("FL", "FR", "RL", "RR"):
        assert (q[f"{leg}_hip_joint"], q[f"{leg}_thigh_joint"], q[f"{leg}_calf_joint"]) == (0.0, 0.7, -1.5)
    assert go2.base_xyz_wxyz_standing[2] == 0.31131
    _assert_stands_on_its_feet(go2)


def test_fused_links_resolve_to_surviving_bodies():
    talos = robot_lib.load("talos")
    hand = talos.contacts[talos.contact_index("left_hand")]
    assert hand.link == "gripper_left_inner_single_link" and hand.body == "arm_left_7_link"
    assert mujoco.mj_name2id(talos.mj_model, mujoco.mjtObj.mjOBJ_BODY, hand.link) == -1
    g1 = robot_lib.load("g1")
    hand = g1.contacts[g1.contact_index("right_hand")]
    assert hand.link == "right_rubber_hand" and hand.body == "right_wrist_yaw_link"


def test_total_mass_and_standing_contacts_match_pinocchio(robot):
    model, frames = pinocchio_model(robot)
    data = model.createData()
    assert robot.total_mass == pytest.approx(pin.computeTotalMass(model), rel=1e-12)

    # standing pose: contact points agree in 3-D, and the feet touch the ground
    q = pinocchio_q(model, robot, robot.base_xyz_wxyz_standing, robot.q_joints_standing)
    pin.framesForwardKinematics(model, data, q)
    p_pin = np.stack([data.oMf[f].translation for f in frames])
    p_mj = mujoco_contact_positions(robot, robot.qpos_standing)
    np.testing.assert_allclose(p_mj, p_pin, atol=1e-12)
    feet = [i for g, idx in robot.contact_groups.items() if "foot" in g for i in idx]
    heights = p_mj[feet, 2]
    print(f"\n{robot.name} standing contact heights (m): " + ", ".join(
        f"{robot.contacts[i].name} {p_mj[i, 2]:+.6f}" for i in range(robot.ncontact)))
    assert np.all(np.abs(heights) < 2e-4), heights


def test_contact_positions_match_pinocchio_at_random_pose(robot):
    rng = np.random.default_rng(7)
    model, frames = pinocchio_model(robot)
    data = model.createData()
    wxyz = rng.normal(size=4)
    xyz_wxyz = np.concatenate([rng.normal(size=3), wxyz / np.linalg.norm(wxyz)])
    q_joints = rng.uniform(robot.q_lower.clip(-2, 2), robot.q_upper.clip(-2, 2))
    pin.framesForwardKinematics(model, data, pinocchio_q(model, robot, xyz_wxyz, q_joints))
    p_pin = np.stack([data.oMf[f].translation for f in frames])
    p_mj = mujoco_contact_positions(robot, np.concatenate([xyz_wxyz, q_joints]))
    np.testing.assert_allclose(p_mj, p_pin, atol=1e-12)


def test_render_model_has_meshes_and_same_layout():
    go2 = robot_lib.load("go2")
    render = robot_lib.load_render_model(go2)
    assert render.ngeom > 0 and render.nmesh > 0
    assert (render.nbody, render.nq, render.nv) == (go2.mj_model.nbody, go2.mj_model.nq, go2.mj_model.nv)


# ----------------------------------------------------------------------------------------
# Errors a user can act on


def _talos_config():
    return tomllib.loads((importlib.resources.files("jtraj.robots") / "talos.toml").read_text())


def _write_toml(path, config):
    """Minimal TOML writer for the robot format (tomllib only reads)."""

    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return f'"{v}"'
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(v)

    def is_table_array(v):
        return isinstance(v, list) and len(v) > 0 and isinstance(v[0], dict)

    lines = [f"{k} = {value(v)}" for k, v in config.items() if not (isinstance(v, dict) or is_table_array(v))]
    for key, v in config.items():
        if isinstance(v, dict):
            lines.append(f"[{key}]")
            lines += [f"{k2} = {value(v2)}" for k2, v2 in v.items() if not isinstance(v2, dict)]
            for k2, v2 in v.items():
                if isinstance(v2, dict):
                    lines.append(f"[{key}.{k2}]")
                    lines += [f"{k3} = {value(v3)}" for k3, v3 in v2.items()]
        elif is_table_array(v):
            for entry in v:
                lines.append(f"[[{key}]]")
                lines += [f"{k2} = {value(v2)}" for k2, v2 in entry.items()]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_toml_writer_round_trips(tmp_path):
    config = _talos_config()
    path = _write_toml(tmp_path / "copy.toml", config)
    assert tomllib.loads(path.read_text()) == config  # every table and value, as written
    robot = robot_lib.load_file(path)
    assert robot.joint_names == robot_lib.load("talos").joint_names
    assert robot.contact_names == robot_lib.load("talos").contact_names


def test_contact_on_missing_link_names_the_link(tmp_path):
    config = _talos_config()
    config["contact"][0]["link"] = "leg_left_7_link"
    path = _write_toml(tmp_path / "bad_link.toml", config)
    with pytest.raises(robot_lib.RobotLoadError) as err:
        robot_lib.load_file(path)
    message = str(err.value)
    assert "leg_left_7_link" in message and "bad_link.toml" in message
    assert "leg_left_6_link" in message  # lists the valid names


def test_unknown_robot_lists_choices():
    with pytest.raises(robot_lib.RobotLoadError, match="talos"):
        robot_lib.load("atlas")
    for path in (Path("robots/go2.toml"), "robots/go2.toml", "go2.toml"):
        with pytest.raises(robot_lib.RobotLoadError, match=r"with the editable install, a robot file saved in the checkout's robots/ folder is the robot of its stem; jtraj\.robot\.load_file reads one"):
            robot_lib.load(path)
    # a list (a name in a list by mistake) reached the cache, which raised TypeError: unhashable
    with pytest.raises(robot_lib.RobotLoadError, match=r"unknown robot \['go2'\]; .*a robot's name, a string"):
        robot_lib.load(["go2"])


@pytest.mark.parametrize(
    "edit, fragment",
    [
        (lambda c: c.update(locked_joints=["gripper_joint"]), "gripper_joint"),
        (lambda c: c["groups"].update(left_foot=["left_foot_toe"]), "left_foot_toe"),
        (lambda c: c["standing"]["joints"].update(knee=0.3), "knee"),
        (lambda c: c.update(urdf="talos_data/robots/no_such.urdf"), "no_such.urdf"),
        (lambda c: c.update(expected_joints=32), "expected 32"),
        (lambda c: c["contact"][0].update(offset=[0.0, 1.0]), "offset"),
        # misspelt keys and tables are refused, not ignored
        (lambda c: c.update(locked_joint=["arm_left_7_joint"]), "unknown key 'locked_joint'; did you mean 'locked_joints'?"),
        (lambda c: c.update(extend="talos"), "unknown key 'extend'; did you mean 'extends'?"),
        (lambda c: c["standing"].update(joint=c["standing"].pop("joints")), "unknown key standing.'joint'; did you mean 'joints'?"),
        (lambda c: c["contact"][0].update(ofset=[0.0, 0.0, 0.0]), "unknown key contact[].'ofset'; did you mean 'offset'?"),
        # values of the wrong kind name themselves
        (lambda c: c["standing"].update(base_wxyz=[0.0, 0.0, 0.0, 0.0]), "standing.base_wxyz must be a nonzero quaternion"),
        (lambda c: c.update(expected_joints="32"), "'expected_joints' must be a whole number >= 0, got '32'"),
        (lambda c: c.update(locked_joints="gripper_left_joint"), "'locked_joints' must be a list of names, got 'gripper_left_joint'"),
        (lambda c: c["groups"].update(left_foot="left_sole"), "group 'left_foot' must be a list of names"),
        (lambda c: c["standing"]["joints"].update(leg_left_4_joint="0.7x"), "standing.joints.leg_left_4_joint must be a finite number (rad), got '0.7x'"),
        # booleans and strings were read as numbers (true as 1.0, "1" as 1.0), as standing.joints does not
        (lambda c: c["contact"][0].update(offset=[True, False, True]), "contact[0].offset must be 3 finite numbers, got [True, False, True]"),
        (lambda c: c["contact"][0].update(offset=["0", "0", "-0.1"]), "contact[0].offset must be 3 finite numbers, got ['0', '0', '-0.1']"),
        (lambda c: c["standing"].update(base_xyz=[False, False, True]), "standing.base_xyz must be 3 finite numbers, got [False, False, True]"),
        (lambda c: c["standing"].update(base_wxyz=[True, False, False, False]), "standing.base_wxyz must be 4 finite numbers, got [True, False, False, False]"),
        # a standing pose outside the joint limits: loaded, and every solve on it refused later
        # by a message that named theta, not the file
        (lambda c: c["standing"]["joints"].update(leg_left_4_joint=-0.5), "standing.joints.leg_left_4_joint = -0.5 is outside its limits [0, "),
        # an empty group let a phase "touch" with no point on the ground; a point named twice
        # or a nameless point
        (lambda c: c["groups"].update(left_foot=[]), "group 'left_foot' names no contact point; expected one or more of: "),
        (lambda c: c["groups"].update(left_foot=["left_foot_front_left", "left_foot_front_left"]), "group 'left_foot' names contact point 'left_foot_front_left' twice"),
        (lambda c: c["contact"][0].update(name=""), "contact[0].name is empty"),
        # a norm past the largest float: normalized to zeros
        (lambda c: c["standing"].update(base_wxyz=[1.5e308, 1.5e308, 0.0, 0.0]), "standing.base_wxyz must be a nonzero quaternion (w, x, y, z) of finite norm, got [1.5e+308, 1.5e+308, 0.0, 0.0]"),
    ],
)
def test_invalid_definitions_raise_with_the_offending_value(tmp_path, edit, fragment):
    config = _talos_config()
    edit(config)
    path = _write_toml(tmp_path / "bad.toml", config)
    with pytest.raises(robot_lib.RobotLoadError, match=r"bad\.toml") as err:
        robot_lib.load_file(path)
    assert fragment in str(err.value)


def test_a_huge_standing_quaternion_is_normalized_without_overflow(tmp_path):
    # its norm overflowed to inf, and the standing attitude became [0, 0, 0, 0]
    config = _talos_config()
    config["standing"]["base_wxyz"] = [1e200, 0.0, 1e200, 0.0]
    robot = robot_lib.load_file(_write_toml(tmp_path / "huge.toml", config))
    np.testing.assert_allclose(robot.base_xyz_wxyz_standing[3:], [np.sqrt(0.5), 0.0, np.sqrt(0.5), 0.0], rtol=1e-15)


def test_model_that_mujoco_cannot_load_names_the_file(tmp_path):
    # A moving body without mass is rejected by MuJoCo's compiler.
    urdf = tmp_path / "massless.urdf"
    urdf.write_text(
        """<robot name="massless">
  <link name="base"><inertial><mass value="1"/>
    <inertia ixx="1" iyy="1" izz="1" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="arm"/>
  <joint name="hinge" type="revolute"><parent link="base"/><child link="arm"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
</robot>
"""
    )
    path = _write_toml(tmp_path / "massless.toml", {"name": "massless", "urdf": str(urdf)})
    with pytest.raises(robot_lib.RobotLoadError) as err:
        robot_lib.load_file(path)
    assert "massless.toml" in str(err.value) and "massless.urdf" in str(err.value)


# ----------------------------------------------------------------------------------------
# extends: a robot file on top of another


def test_extends_merges_tables_and_replaces_other_values(tmp_path):
    """Tables merge key by key at every depth; strings, numbers and arrays (``[[contact]]``
    included) replace the parent's; ``name`` is not inherited; chains resolve in order."""
    (tmp_path / "base.toml").write_text(
        'name = "base"\nurdf = "a.urdf"\nlocked_joints = ["j1", "j2"]\nexpected_joints = 3\n'
        "[standing]\nbase_xyz = [0.0, 0.0, 1.0]\n[standing.joints]\nknee = 0.8\nhip = -0.4\n"
        '[[contact]]\nname = "c1"\nlink = "l1"\n[[contact]]\nname = "c2"\nlink = "l2"\n'
        '[groups]\nfoot = ["c1", "c2"]\nhand = ["c2"]\n'
    )
    (tmp_path / "middle.toml").write_text(
        'extends = "base"\nurdf = "b.urdf"\nlocked_joints = ["j3"]\n'
        "[standing.joints]\nknee = 0.9\nankle = 0.1\n"
        '[[contact]]\nname = "c3"\nlink = "l3"\n[groups]\nfoot = ["c3"]\n'
    )
    (tmp_path / "child.toml").write_text('extends = "middle"\nexpected_joints = 4\n[standing]\nbase_wxyz = [0.0, 0.0, 0.0, 1.0]\n')
    config = robot_lib._read_config(tmp_path / "child.toml")
    assert config == {
        "urdf": "b.urdf",
        "locked_joints": ["j3"],
        "expected_joints": 4,
        "standing": {"base_xyz": [0.0, 0.0, 1.0], "joints": {"knee": 0.9, "hip": -0.4, "ankle": 0.1}, "base_wxyz": [0.0, 0.0, 0.0, 1.0]},
        "contact": [{"name": "c3", "link": "l3"}],
        "groups": {"foot": ["c3"], "hand": ["c2"]},
    }
    assert robot_lib._read_config(tmp_path / "base.toml")["name"] == "base"  # a file without extends is as written


def test_extends_overrides_a_loaded_robot(tmp_path):
    """A file extending a copy of talos.toml loads as talos with its own changes on top."""
    talos = robot_lib.load("talos")
    (tmp_path / "parent.toml").write_text((importlib.resources.files("jtraj.robots") / "talos.toml").read_text())
    (tmp_path / "kneel.toml").write_text(
        'extends = "parent"\n[standing]\nbase_xyz = [0.0, 0.0, 0.9]\n[standing.joints]\nleg_left_4_joint = 1.2\n'
        '[groups]\nfeet = ["left_foot_front_left", "right_foot_front_left"]\n'
    )
    robot = robot_lib.load_file(tmp_path / "kneel.toml")
    assert robot.name == "kneel"  # the file's stem, not the parent's name
    assert (robot.joint_names, robot.locked_joints, robot.contact_names) == (talos.joint_names, talos.locked_joints, talos.contact_names)
    expected = talos.q_joints_standing.copy()
    expected[talos.joint_names.index("leg_left_4_joint")] = 1.2
    np.testing.assert_array_equal(robot.q_joints_standing, expected)
    assert robot.base_xyz_wxyz_standing.tolist() == [0.0, 0.0, 0.9, 1.0, 0.0, 0.0, 0.0]
    assert dict(robot.contact_groups) == {**talos.contact_groups, "feet": (0, 4)}


def test_talos_full_extends_talos():
    """talos_full.toml states only what differs from talos.toml: its URDF and locked joints."""
    folder = importlib.resources.files("jtraj.robots")
    with importlib.resources.as_file(folder / "talos_full.toml") as full, importlib.resources.as_file(folder / "talos.toml") as reduced:
        assert tomllib.loads(full.read_text())["extends"] == "talos"
        merged, parent = robot_lib._read_config(full), robot_lib._read_config(reduced)
    assert {k for k in merged.keys() | parent.keys() if merged.get(k) != parent.get(k)} == {"name", "urdf", "locked_joints"}


@pytest.mark.parametrize(
    "files, start, fragments",
    [
        ({"a": 'extends = "b"', "b": 'extends = "a"'}, "a", ["b.toml", "'a'", "cycle", "a.toml -> b.toml -> a.toml"]),
        ({"a": 'extends = "a"'}, "a", ["a.toml", "cycle", "a.toml -> a.toml"]),
        ({"a": 'extends = "nowhere"', "other": ""}, "a", ["a.toml", "'nowhere'", "nowhere.toml", "expected one of: other"]),
        ({"a": 'extends = "../talos"'}, "a", ["a.toml", "'../talos'", "same folder"]),
        ({"a": "extends = 3"}, "a", ["a.toml", "3", "same folder"]),
    ],
)
def test_extends_cycles_and_missing_parents_raise(tmp_path, files, start, fragments):
    for stem, text in files.items():
        (tmp_path / f"{stem}.toml").write_text(f'urdf = "x.urdf"\n{text}\n')
    with pytest.raises(ValueError) as err:  # RobotLoadError, before any URDF is read
        robot_lib.load_file(tmp_path / f"{start}.toml")
    assert isinstance(err.value, robot_lib.RobotLoadError)
    for fragment in fragments:
        assert fragment in str(err.value), str(err.value)


def test_robot_data_folder_from_the_environment(tmp_path, monkeypatch):
    """JTRAJ_ROBOT_DATA names a folder laid out as example-robot-data's ``robots`` folder (a
    machine with only the URDFs copied); a robot file's relative ``urdf`` resolves in it."""
    installed = robot_lib.robots_data_dir()
    rel = "go2_description/urdf/go2.urdf"
    (tmp_path / rel).parent.mkdir(parents=True)
    (tmp_path / rel).write_bytes((installed / rel).read_bytes())
    monkeypatch.setenv(robot_lib.ROBOT_DATA_ENV, str(tmp_path))
    assert robot_lib.robots_data_dir() == tmp_path
    with importlib.resources.as_file(importlib.resources.files("jtraj.robots") / "go2.toml") as path:
        go2 = robot_lib.load_file(path)
    assert go2.nj == 12 and go2.ncontact == 4
    (tmp_path / rel).unlink()  # read from there, not from the installed distribution
    with importlib.resources.as_file(importlib.resources.files("jtraj.robots") / "go2.toml") as path:
        with pytest.raises(robot_lib.RobotLoadError, match="not found"):
            robot_lib.load_file(path)
    monkeypatch.setenv(robot_lib.ROBOT_DATA_ENV, str(tmp_path / "missing"))
    with pytest.raises(robot_lib.RobotLoadError, match="JTRAJ_ROBOT_DATA"):
        robot_lib.robots_data_dir()


# ----------------------------------------------------------------------------------------
# URDF files that cannot make a robot


_TINY_INERTIAL = '<inertial><mass value="1"/><inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" iyz="0"/></inertial>'
#: a base, an arm on a hinge and a foot link fused into the arm (a contact point on the foot)
_TINY_URDF = f"""<robot name="tiny">
  <link name="base">{_TINY_INERTIAL}</link>
  <link name="arm">{_TINY_INERTIAL}</link>
  <link name="foot"/>
  <joint name="hinge" type="revolute"><parent link="base"/><child link="arm"/><axis xyz="0 1 0"/>
    <limit lower="-1" upper="1" effort="5" velocity="2"/></joint>
  <joint name="ankle" type="fixed"><parent link="arm"/><child link="foot"/><origin xyz="0 0 -0.1"/></joint>
</robot>
"""


def _tiny_robot_file(folder, urdf_text):
    (folder / "tiny.urdf").write_text(urdf_text)
    return _write_toml(folder / "tiny.toml", {"urdf": str(folder / "tiny.urdf"), "contact": [{"name": "toe", "link": "foot"}]})


def test_tiny_urdf_loads(tmp_path):
    """The URDF the cases below break loads as written."""
    robot = robot_lib.load_file(_tiny_robot_file(tmp_path, _TINY_URDF))
    assert robot.joint_names == ("hinge",) and robot.contact_names == ("toe",)
    np.testing.assert_allclose(robot.contact_offsets, [[0.0, 0.0, -0.1]])


@pytest.mark.parametrize(
    "old, new, fragment",
    [
        # jtraj reads the joint tree itself before MuJoCo does: an AttributeError on None
        ('<child link="foot"/>', "", "joint 'ankle' of"),
        ('<child link="arm"/>', '<child/>', "joint 'hinge' of"),
        # limits the NLP's bounds are made of: lower above upper made the joint's bounds empty,
        # a negative effort or velocity the torque and rate bounds
        ('lower="-1" upper="1"', 'lower="1" upper="-1"', "tiny.urdf has limit lower=1 above upper=-1"),
        ('effort="5"', 'effort="-5"', "tiny.urdf has limit velocity=2, effort=-5; both must be >= 0"),
        ('velocity="2"', 'velocity="-2"', "velocity=-2, effort=5; both must be >= 0"),
        # NaN loaded (MuJoCo only prints a warning): a NaN contact offset or body position
        ('xyz="0 0 -0.1"', 'xyz="0 0 nan"', "<origin> of joint 'ankle' of"),
        ('<axis xyz="0 1 0"/>', '<origin xyz="0 nan 0"/><axis xyz="0 1 0"/>', "not finite (NaN or inf) in MuJoCo's body_pos"),
        ('<inertial><mass value="1"/>', '<inertial><origin xyz="inf 0 0"/><mass value="1"/>', "not finite (NaN or inf) in MuJoCo's body_ipos"),
    ],
)
def test_urdf_defects_raise_naming_the_files(tmp_path, monkeypatch, old, new, fragment):
    # MuJoCo's parser writes its warning about a NaN in the XML to MUJOCO_LOG.TXT in the
    # working directory; keep it out of the checkout
    monkeypatch.chdir(tmp_path)
    assert old in _TINY_URDF
    path = _tiny_robot_file(tmp_path, _TINY_URDF.replace(old, new, 1))
    with pytest.raises(robot_lib.RobotLoadError) as err:
        robot_lib.load_file(path)
    message = str(err.value)
    assert "tiny.toml" in message and "tiny.urdf" in message and fragment in message, message


def test_a_robot_file_in_the_robots_folder_is_named_by_its_file(tmp_path, monkeypatch):
    """A copy of go2.toml saved as my_go2.toml (its ``name = "go2"`` left in) was solved as the
    robot my_go2 but named go2: runs recorded go2, and plots and renders drew go2. Found by its
    file's name, a robot file must not give another (a path's file may: load_file)."""
    folder = importlib.resources.files("jtraj.robots")
    text = (folder / "go2.toml").read_text()
    (tmp_path / "my_go2.toml").write_text(text)
    (tmp_path / "my_go2b.toml").write_text(text.replace('name = "go2"', 'name = "my_go2b"'))
    files = importlib.resources.files
    monkeypatch.setattr(importlib.resources, "files", lambda package: tmp_path if package == "jtraj.robots" else files(package))
    with pytest.raises(robot_lib.RobotLoadError, match=r"^my_go2.toml: name = 'go2', but the robot is found as 'my_go2' \(its file's name\): leave 'name' out, or write name = 'my_go2'$"):
        robot_lib.load("my_go2")
    assert robot_lib.load("my_go2b").name == "my_go2b"
    assert robot_lib.load_file(tmp_path / "my_go2.toml").name == "go2"  # a path's file keeps its name


def test_an_unknown_key_of_a_parent_file_is_the_parents(tmp_path):
    """With ``extends``, a key the parent file got wrong was reported as the child's."""
    talos = (importlib.resources.files("jtraj.robots") / "talos.toml").read_text()
    (tmp_path / "parent.toml").write_text(talos.replace('name = "talos"', 'name = "parent"\nstandng = 1'))
    (tmp_path / "child.toml").write_text('extends = "parent"\n')
    with pytest.raises(robot_lib.RobotLoadError, match=r"parent\.toml: unknown key 'standng'; did you mean 'standing'\?"):
        robot_lib.load_file(tmp_path / "child.toml")


def test_the_mesh_cache_variable_expands_the_home_folder(monkeypatch, tmp_path):
    """``JTRAJ_MESH_CACHE="~/meshes"`` (quoted in a shell, or from a .env file) made a folder
    named "~" in the working directory, where JTRAJ_CACHE_DIR and JTRAJ_ROBOT_DATA expand it."""
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.setenv("JTRAJ_MESH_CACHE", "~/meshes")
    assert robot_lib.mesh_cache_dir() == tmp_path / "meshes"
