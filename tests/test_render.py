"""Rendering and plots of a solution, on a Go2 motion made up (no solve): a base that turns
half a back-flip at a constant body twist while the feet push off, then flies."""

import dataclasses
import json
import xml.etree.ElementTree as ET

import mujoco
import numpy as np
import pytest
from jaxlie import SE3

from jtraj import robot as robots
from jtraj.cli import main
from jtraj.io import FileFormatError
from jtraj.plots import plot_comparison, plot_directory, plot_solution
from jtraj.render import NotDrawable, RenderOptions, interpolate, keyframe_strip, keyframe_times, render, write_image, write_video
from jtraj.result import Outcome, Result
from jtraj.solvers import Stats
from jtraj.solvers import Status as SolverStatus
from jtraj.transcription import Trajectory

W, H = 160, 120
SMALL = RenderOptions(width=W, height=H, fps=12, shadows=False)
TWIST = np.array([0.6, 0.0, 0.8, 0.0, -2 * np.pi, 0.0])  # body frame: forward, up, pitching back


def _result(n_knots=11, duration=0.5) -> Result:
    """Go2 with the base at ``T_0 Exp(t V)`` (so SE(3) interpolation is exact), the feet in
    contact for the first three knots."""
    go2 = robots.load("go2")
    t = np.linspace(0.0, duration, n_knots)
    T0 = go2.base_pose_standing
    poses = SE3(np.stack([(T0 @ SE3.exp(TWIST * tk)).wxyz_xyz for tk in t]))
    xyz_wxyz = np.concatenate([np.asarray(poses.translation()), np.asarray(poses.rotation().wxyz)], axis=1)
    P = go2.ncontact
    forces = np.zeros((n_knots, P, 3))
    forces[:3, :, 2] = go2.total_mass * go2.gravity / P
    forces[:3, :, 0] = [[10.0], [0.0], [-5.0]]
    contact_positions = np.zeros((n_knots, P, 3))
    contact_positions[:, :, :2] = [[0.19, 0.14], [0.19, -0.14], [-0.19, 0.14], [-0.19, -0.14]]
    traj = Trajectory(
        t=t, base_xyz_wxyz=xyz_wxyz, q_base=xyz_wxyz, q_joints=np.tile(go2.q_joints_standing, (n_knots, 1)),
        v=np.zeros((n_knots, go2.nv)), a=np.zeros((n_knots, go2.nv)), tau=np.zeros((n_knots, go2.nv)),
        forces=forces, contact_positions=contact_positions, in_contact=np.arange(n_knots)[:, None].repeat(P, 1) < 3,
        contact_names=go2.contact_names,
    )
    return Result(
        problem="made_up_flip", model="go2", variant="se3", solver="ipopt", status=Outcome.SOLVED, solver_status=SolverStatus.SOLVED,
        status_msg="", stats=Stats(), metrics={"turns": -0.5}, cost=0.0, constraint_violation=0.0, violation_by_group={},
        time_compile=0.0, n_variables=0, n_constraints=0, options={},
        history=[{"iter": 0, "inf_pr": 1.0, "inf_du": 1.0}, {"iter": 1, "inf_pr": 1e-9, "inf_du": 1e-7}], trajectory=traj,
    )


@pytest.fixture(scope="module")
def result():
    return _result()


@pytest.fixture(scope="module")
def frames(result):
    return render(result, SMALL)


def test_interpolation_follows_the_constant_twist_and_hits_the_knots(result):
    traj = result.trajectory
    times = np.array([0.0, 0.013, 0.21, 0.333, 0.5])
    f = interpolate(traj, times)
    T0 = robots.load("go2").base_pose_standing
    for tk, qpos in zip(times, f.qpos):
        expected = T0 @ SE3.exp(TWIST * tk)
        np.testing.assert_allclose(qpos[:3], expected.translation(), atol=1e-9)
        np.testing.assert_allclose(abs(qpos[3:7] @ np.asarray(expected.rotation().wxyz)), 1.0, atol=1e-9)
    # joints: linearly between their knots (joints that move from knot to knot, so that a wrong
    # weight or knot index shows)
    moving = dataclasses.replace(traj, q_joints=traj.q_joints + 0.1 * np.sin(np.arange(traj.q_joints.size)).reshape(traj.q_joints.shape))
    np.testing.assert_allclose(interpolate(moving, moving.t).qpos[:, 7:], moving.q_joints, atol=1e-12)
    between = interpolate(moving, [0.3 * moving.t[1] + 0.7 * moving.t[2], 0.9 * moving.t[4] + 0.1 * moving.t[5]]).qpos[:, 7:]
    np.testing.assert_allclose(between[0], 0.3 * moving.q_joints[1] + 0.7 * moving.q_joints[2], atol=1e-12)
    np.testing.assert_allclose(between[1], 0.9 * moving.q_joints[4] + 0.1 * moving.q_joints[5], atol=1e-12)
    # forces are interpolated linearly, contact flags taken from the nearest knot
    half = interpolate(traj, [0.5 * (traj.t[2] + traj.t[3])])
    np.testing.assert_allclose(half.forces[0], 0.5 * (traj.forces[2] + traj.forces[3]))
    # knot 2 is in stance and knot 3 in flight: a quarter of the way takes knot 2's flags, three quarters knot 3's
    near = interpolate(traj, [0.75 * traj.t[2] + 0.25 * traj.t[3], 0.25 * traj.t[2] + 0.75 * traj.t[3]])
    assert traj.in_contact[2].all() and not traj.in_contact[3].any()
    assert near.in_contact[0].all() and not near.in_contact[1].any()


def _first_knots(result: Result, n: int) -> Result:
    """``result`` cut to its first ``n`` knots."""
    traj = result.trajectory
    per_knot = ("t", "base_xyz_wxyz", "q_base", "q_joints", "v", "a", "tau", "forces", "contact_positions", "in_contact")
    return dataclasses.replace(result, trajectory=dataclasses.replace(traj, **{k: np.asarray(getattr(traj, k))[:n] for k in per_knot}))


def test_a_single_knot_is_drawn_as_it_stands(result):
    one = _first_knots(result, 1)
    f = interpolate(one.trajectory, [0.0, 0.3])
    # the one pose at every time (was NaN: the interval to the next knot was divided by zero)
    np.testing.assert_allclose(f.qpos, np.tile(np.concatenate([one.trajectory.base_xyz_wxyz[0], one.trajectory.q_joints[0]]), (2, 1)), atol=1e-12)
    np.testing.assert_allclose(f.forces, one.trajectory.forces[[0, 0]])
    assert f.in_contact.all()
    video = render(one, SMALL)
    assert len(video) == 2 and all(image.std() > 10 for image in video)  # NaN poses drew black images
    assert keyframe_strip(one, 2, options=SMALL).std() > 10


def test_video_frames_have_the_size_are_not_blank_and_move(frames, result):
    duration = result.trajectory.t[-1]
    assert frames.shape == (round(duration * SMALL.fps) + 1, H, W, 3) and frames.dtype == np.uint8
    for image in frames:
        assert image.std() > 10  # sky, ground and robot, not a flat color
    assert np.abs(frames[0].astype(int) - frames[-1].astype(int)).mean() > 5


def test_speed_sets_the_number_of_frames(result):
    import jtraj

    # jtraj.render is the module and, called, its render()
    # a 0.5 s motion at a quarter of real time lasts 2 s: 8 frame intervals at 4 frames per second
    slow = jtraj.render(result, SMALL, speed=0.25, fps=4, label=False)
    assert len(slow) == round(0.5 / 0.25 * 4) + 1 and slow.shape[1:] == (H, W, 3)


def test_flight_is_marked_and_forces_are_drawn(result, frames):
    # the orange bar along the top marks flight (knots 3 and later), not the stance frames
    top = frames[:, 0, :, :].astype(int)
    orange = (top[:, :, 0] > 200) & (top[:, :, 2] < 80)
    flying = ~interpolate(result.trajectory, np.linspace(0, 0.5, len(frames))).in_contact.any(axis=1)
    assert np.all(orange.mean(axis=1)[flying] > 0.9) and np.all(orange.mean(axis=1)[~flying] < 0.1)
    # the force arrows are the only yellow (R, G high, B low) things in the first frame
    no_forces = render(result, SMALL, forces=False, label=False, fps=2)[0].astype(int)
    with_forces = render(result, SMALL, label=False, fps=2)[0].astype(int)
    yellow = lambda im: np.sum((im[..., 0] > 180) & (im[..., 1] > 120) & (im[..., 2] < 60))
    assert yellow(with_forces) > 20 and yellow(no_forces) == 0


def test_keyframe_strips(result):
    n = 4
    side = keyframe_strip(result, n, options=SMALL)
    assert side.shape == (H, n * W + 2 * (n - 1), 3)
    panels = [side[:, i * (W + 2) : i * (W + 2) + W] for i in range(n)]
    assert all(p.std() > 10 for p in panels)
    assert np.abs(panels[0].astype(int) - panels[-1].astype(int)).mean() > 5
    overlay = keyframe_strip(result, n, layout="overlay", options=SMALL)
    assert overlay.shape == (H, W, 3) and overlay.std() > 10
    with pytest.raises(ValueError, match="layout"):
        keyframe_strip(result, n, layout="grid", options=SMALL)
    # numpy's own TypeError about linspace's num, and a bool taken for 1 keyframe, before
    for bad in (2.5, True, 1):
        with pytest.raises(ValueError, match=rf"a strip needs a whole number of at least 2 keyframes, got n={bad!r}"):
            keyframe_strip(result, bad, options=SMALL)


def test_the_overlay_draws_the_earlier_keyframes_too(result, monkeypatch):
    """The overlay's earlier keyframes are copies added to the last one's scene: the strip
    test's ``std() > 10`` held with none of them drawn (one pose on sky and ground)."""
    import jtraj.render as render_module

    draw, calls = render_module._Painter.draw, []

    def spy(self, *args, **kwargs):
        image = draw(self, *args, **kwargs)
        calls.append((image, draw(self, *args, **{**kwargs, "extra_poses": ()})))  # the last keyframe alone
        return image

    monkeypatch.setattr(render_module._Painter, "draw", spy)
    overlay = keyframe_strip(result, 4, layout="overlay", options=SMALL, forces=False)
    ((image, alone),) = calls
    assert np.array_equal(overlay, image)
    changed = np.abs(image.astype(int) - alone.astype(int)).max(axis=-1) > 30
    assert changed.mean() > 0.01, changed.mean()


def test_keyframes_spread_along_the_motion_not_the_clock():
    traj = _result().trajectory
    # the base stands still for the first half, then moves: keyframes gather in the second half
    still = traj.base_xyz_wxyz.copy()
    still[:6] = still[0]
    times = keyframe_times(Trajectory(**{**traj.__dict__, "base_xyz_wxyz": still}), 5)
    assert times[0] == traj.t[0] and times[-1] == traj.t[-1]
    assert np.all(np.diff(times) > 0) and np.all(times[1:-1] > traj.t[5])
    # a base that never moves: even times
    frozen = np.tile(traj.base_xyz_wxyz[:1], (len(traj.t), 1))
    np.testing.assert_allclose(keyframe_times(Trajectory(**{**traj.__dict__, "base_xyz_wxyz": frozen}), 3), [0.0, 0.25, 0.5])


@pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")  # reading back the MP4 runs ffmpeg
def test_video_files(frames, tmp_path):
    import imageio_ffmpeg

    mp4 = write_video(frames, tmp_path / "m.mp4", fps=12)
    reader = imageio_ffmpeg.read_frames(str(mp4))
    meta = next(reader)
    assert tuple(meta["size"]) == (W, H) and sum(1 for _ in reader) == len(frames)
    from PIL import Image

    gif = Image.open(write_video(frames, tmp_path / "m.gif", fps=12))
    assert gif.size == (W, H) and gif.n_frames == len(frames)
    assert Image.open(write_image(frames[0], tmp_path / "f.png")).size == (W, H)
    with pytest.raises(ValueError, match=r"mp4 or \.gif"):
        write_video(frames, tmp_path / "m.avi")
    # written beside the target and renamed into place: no partial file is left behind
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.png", "m.gif", "m.mp4"]


def test_bad_frames_and_file_names_are_refused(frames, tmp_path):
    with pytest.raises(ValueError, match=r"float64 in \[0.0, 1.0\]; expected uint8 pixels"):
        write_video(frames / 255.0, tmp_path / "f.mp4")  # would be written black
    with pytest.raises(ValueError, match=r"frames of shape \(120, 160, 3\); expected \(T, H, W, 3\) RGB; for one image use write_image"):
        write_video(frames[0], tmp_path / "one.mp4")
    for fps in (0, -10, float("nan")):
        with pytest.raises(ValueError, match="fps must be a finite number > 0"):
            write_video(frames, tmp_path / "f.gif", fps=fps)
    with pytest.raises(ValueError, match=r"expected a \.png, \.jpg or \.jpeg file name"):
        write_image(frames[0], tmp_path / "f.bmp")
    with pytest.raises(ValueError, match=r"image of shape \(120, 160\); expected \(H, W, 3\)"):
        write_image(frames[0, :, :, 0], tmp_path / "f.png")
    assert not list(tmp_path.iterdir())
    # integer pixels in 0-255 of another dtype are written as they are
    write_image(frames[0].astype(np.int64), tmp_path / "i.png")
    from PIL import Image

    np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "i.png").convert("RGB")), frames[0])


@pytest.mark.parametrize(
    "change, match",
    [
        ({"width": 40.5}, "width must be a whole number of pixels"),
        ({"height": True}, "height must be a whole number of pixels"),
        ({"fps": 0}, "fps must be a finite number > 0"),
        ({"speed": float("nan")}, "speed must be a finite number > 0"),
        ({"distance": -1.0}, "distance must be a finite number > 0"),
        ({"elevation": float("inf")}, "elevation must be a finite number of degrees"),
    ],
)
def test_render_options_refuse_impossible_values(change, match):
    with pytest.raises(ValueError, match=match):
        RenderOptions(**change)


def test_render_names_what_it_was_given_instead_of_a_result(result):
    from jtraj.render import _render_options

    with pytest.raises(TypeError, match="not its trajectory"):
        render(result.trajectory)
    with pytest.raises(ValueError, match="render_benchmark"):
        render(dataclasses.replace(result, problem="quadflip", trajectory=object()))
    # options as a mapping of RenderOptions' fields, keyword arguments over them
    assert _render_options({"width": 32, "height": 24}, {"height": 20}) == RenderOptions(width=32, height=20)
    assert _render_options(SMALL, {"fps": 5}) == dataclasses.replace(SMALL, fps=5)
    with pytest.raises(TypeError, match="options must be a RenderOptions"):
        render(result, 320)
    # a trajectory with NaN poses (a solver stopped by a numerical error) loads but is not drawn
    poses = np.array(result.trajectory.base_xyz_wxyz)
    poses[7:, 3] = np.nan
    broken = dataclasses.replace(result, trajectory=dataclasses.replace(result.trajectory, base_xyz_wxyz=poses))
    with pytest.raises(NotDrawable, match=r"the base pose is NaN or infinite at 4 knot\(s\), the first at knot 7 \(the solver's status: solved\)"):
        render(broken)
    # NaN joint angles were drawn as a robot without those limbs
    joints = np.array(result.trajectory.q_joints)
    joints[4, 2] = np.nan
    broken = dataclasses.replace(result, trajectory=dataclasses.replace(result.trajectory, q_joints=joints))
    with pytest.raises(NotDrawable, match=r"the joint angles are NaN or infinite at 1 knot\(s\), the first at knot 4"):
        keyframe_strip(broken, options=SMALL)
    # a zero quaternion was normalized to NaN, and the camera, following the base over the whole
    # motion, turned every frame black
    poses = np.array(result.trajectory.base_xyz_wxyz)
    poses[5, 3:7] = 0.0
    broken = dataclasses.replace(result, trajectory=dataclasses.replace(result.trajectory, base_xyz_wxyz=poses))
    with pytest.raises(NotDrawable, match=r"^the base orientation is a zero quaternion at 1 knot\(s\), the first at knot 5 \(the solver's status: solved\); nothing to draw there$"):
        render(broken, SMALL)


def test_nan_forces_are_refused_before_drawing_where_forces_are_drawn(result, monkeypatch):
    import jtraj.render as jrender

    # finite poses, non-finite forces (in stance, knots 1 and 2): drawn as arrows to NaN before
    forces = np.array(result.trajectory.forces)
    forces[1, 0, 2] = np.nan
    forces[2, 3, 0] = np.inf
    broken = dataclasses.replace(result, trajectory=dataclasses.replace(result.trajectory, forces=forces))
    match = r"the contact forces are NaN or infinite at 2 knot\(s\), the first at knot 1 \(the solver's status: solved; RenderOptions\(forces=False\), or jtraj render --no-forces, draws the motion without them\); nothing to draw there"
    with monkeypatch.context() as m:
        m.setattr(jrender._Painter, "for_result", lambda *a, **k: pytest.fail("opened a renderer before checking the forces"))
        with pytest.raises(NotDrawable, match=match):
            render(broken, SMALL)
        for layout in ("side", "overlay"):
            with pytest.raises(NotDrawable, match=match):
                keyframe_strip(broken, 2, layout=layout, options=SMALL)
    # without the arrows the motion is drawn, and is the motion with finite forces drawn without them
    video = render(broken, SMALL, forces=False, label=False, fps=2)
    np.testing.assert_array_equal(video, render(result, SMALL, forces=False, label=False, fps=2))


def test_render_command_draws_without_forces_on_request(result, tmp_path, capsys):
    """`jtraj render` refuses non-finite forces in one line, as a bad DIR, and ``--no-forces``
    draws the motion without them."""
    forces = np.array(result.trajectory.forces)
    forces[1, 0, 2] = np.nan
    dataclasses.replace(result, trajectory=dataclasses.replace(result.trajectory, forces=forces)).save(tmp_path / "run")
    size = ["--width", str(W), "--height", str(H), "--fps", "2", "--no-shadows"]
    assert main(["render", str(tmp_path / "run"), "--strip", str(tmp_path / "k.png"), "--keyframes", "2", *size]) == 2
    err = capsys.readouterr().err
    assert err.startswith("jtraj render: DIR:") and "the contact forces are NaN or infinite at 1 knot(s)" in err and err.count("\n") == 1
    assert not (tmp_path / "k.png").exists()
    assert main(["render", str(tmp_path / "run"), "--strip", str(tmp_path / "k.png"), "--keyframes", "2", "--no-forces", *size]) == 0
    assert (tmp_path / "k.png").stat().st_size > 1000


@pytest.mark.parametrize("robot_name", robots.available())
def test_every_body_with_a_mesh_visual_is_drawn(robot_name):
    """talos_full's URDF writes its meshes "package:///example-robot-data/...", which were
    dropped: the study's Talos was drawn as its feet alone (3 bodies with visuals of 31)."""
    robot = robots.load(robot_name)
    model = robots.load_render_model(robot)
    visual_bodies = set(model.geom_bodyid[model.geom_group == 1])
    # every link with a mesh visual in the URDF gets it, on its body or, for a link MuJoCo fused
    # into its parent through a fixed joint (the feet), on the parent's
    urdf = ET.parse(robot.urdf_path).getroot()
    parent = {j.find("child").get("link"): (j.find("parent").get("link"), j.get("type")) for j in urdf.findall("joint")}
    want = set()
    for link in urdf.findall("link"):
        if link.find("visual/geometry/mesh") is None:
            continue
        name = link.get("name")
        while (body := mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)) < 0:
            name, kind = parent[name]
            assert kind == "fixed" or robot_name != "go2", f"{link.get('name')} has no body"  # the Talos models lock joints too
        want.add(body)
    assert visual_bodies == want and len(want) > 10
    if robot_name != "go2":
        return
    assert len(visual_bodies) == 13  # base, 4 x (hip, thigh, calf with its foot)
    # the Collada parts converted keep their colors: the base has more than one
    base_colors = {tuple(c) for c in model.geom_rgba[(model.geom_bodyid == 1) & (model.geom_group == 1)].round(2)}
    assert len(base_colors) > 1


def test_friction_pyramid_ratio():
    from jtraj.plots import friction_pyramid_ratio

    # the pyramid's corner |f_x| = |f_y| = mu f_z is on it (the circular cone's ratio was sqrt(2))
    f = np.array([[3.0, -3.0, 6.0], [3.0, 4.0, 10.0], [0.0, 0.0, 5.0], [1.0, 0.0, 0.0]])
    np.testing.assert_allclose(friction_pyramid_ratio(f, 0.5)[:3], [1.0, 0.8, 0.0])
    assert np.isnan(friction_pyramid_ratio(f, 0.5)[3])  # no contact


def test_plots_are_written(result, tmp_path):
    assert plot_solution(result, tmp_path / "s.png").stat().st_size > 10_000
    fig = result.plot()
    assert len(fig.axes) == 6 and "made_up_flip" in fig._suptitle.get_text()
    # a solution folder
    result.save(tmp_path / "run")
    paths = plot_directory(tmp_path / "run")
    assert [p.name for p in paths] == ["solution.png", "convergence.png"] and all(p.stat().st_size > 5000 for p in paths)
    # a comparison folder: runs named TASK_PARAM beside table_iv.json
    compare = tmp_path / "compare"
    for param in ("se3", "euler"):
        result.save(compare / f"made_up_flip_{param}")
    rows = [{"task": "made_up_flip", "parameterization": p, "status": result.status.value, "iterations": result.iterations} for p in ("se3", "euler", "quat1")]
    (compare / "table_iv.json").write_text(json.dumps(rows))
    fig = plot_comparison(compare)
    assert fig.axes[0].get_title().startswith("made_up_flip [se3]: solved")
    assert "no trajectory" in fig.axes[2].get_title()
    assert [p.name for p in plot_directory(compare)] == ["comparison.png"]
    with pytest.raises(FileNotFoundError, match=r"table_iv\.json"):
        plot_directory(tmp_path / "nothing")
    # a folder left by an earlier run (the table's row took other iterations) and an unreadable
    # one are left blank with a title saying so; the other cells are still drawn
    rows[1]["iterations"] = result.iterations + 16
    (compare / "table_iv.json").write_text(json.dumps(rows))
    (compare / "made_up_flip_quat1").mkdir()
    (compare / "made_up_flip_quat1" / "trajectory.npz").write_bytes(b"torn")
    fig = plot_comparison(compare)
    assert fig.axes[0].get_title().startswith("made_up_flip [se3]: solved")
    assert fig.axes[1].get_title() == "made_up_flip [euler]: saved run is not the table's"
    assert fig.axes[2].get_title() == "made_up_flip [quat1]: unreadable result"
    # a damaged table is a FileFormatError naming it (`jtraj plot` prints it in one line, exit 2)
    for text in ("[{\"task\": \"made_up_fl", "[]", '[{"task": "walk"}]', '{"task": "walk"}'):
        (compare / "table_iv.json").write_text(text)
        with pytest.raises(FileFormatError, match=r"table_iv\.json"):
            plot_comparison(compare)


def test_render_and_plot_commands(result, tmp_path, capsys):
    result.save(tmp_path)
    size = ["--width", str(W), "--height", str(H), "--fps", "6", "--no-shadows"]
    assert main(["render", str(tmp_path), "--out", str(tmp_path / "m.gif"), "--strip", str(tmp_path / "k.png"), "--keyframes", "3", *size]) == 0
    assert (tmp_path / "m.gif").stat().st_size > 1000 and (tmp_path / "k.png").stat().st_size > 1000
    assert main(["plot", str(tmp_path)]) == 0
    assert "solution.png" in capsys.readouterr().out
    capsys.readouterr()
    assert main(["render", str(tmp_path / "empty"), "--out", str(tmp_path / "x.gif")]) == 2
    assert "jtraj render: DIR:" in capsys.readouterr().err
    assert main(["render", str(tmp_path), "--out", str(tmp_path / "x.avi")]) == 2
    assert "--out" in capsys.readouterr().err
    assert main(["plot", str(tmp_path / "empty")]) == 2


def test_attitude_bodies_along_their_paths(tmp_path, monkeypatch):
    from types import SimpleNamespace

    from jtraj.render import render_benchmark, render_rigid_body

    # a quadrotor rolling once about x while it climbs and comes back down along y
    t = np.linspace(0.0, 1.0, 9)
    angle = np.linspace(0.0, 2 * np.pi, 9)
    xyz = np.column_stack([np.zeros(9), np.linspace(0.0, 2.0, 9), 1.0 + np.sin(angle / 2)])
    wxyz = np.column_stack([np.cos(angle / 2), np.sin(angle / 2), np.zeros(9), np.zeros(9)])
    frames = render_rigid_body(t, xyz, wxyz, "quadrotor", options=SMALL, fps=4)
    assert frames.shape == (5, H, W, 3) and all(f.std() > 10 for f in frames)
    strip = render_rigid_body(t, xyz, wxyz, "quadrotor", strip=4, options=SMALL)
    assert strip.shape == (H, W, 3)
    # the path is drawn: blue pixels (the line) only where a path is given
    blue = lambda im: np.sum((im[..., 2].astype(int) - im[..., 0] > 100) & (im[..., 1] < 150))
    assert blue(strip) > 20
    # a satellite turns in place: one panel per keyframe, no ground, and no path is drawn (the
    # line's calls are counted: its blue solar panels made a colour count of the image unsure)
    import jtraj.render as jrender

    lines = []
    original = jrender._Painter._line
    monkeypatch.setattr(jrender._Painter, "_line", lambda self, scene, path: lines.append(len(path)) or original(self, scene, path))
    still = render_rigid_body(t, np.zeros((9, 3)), wxyz, "satellite", strip=3, options=SMALL)
    assert still.shape == (H, 3 * W + 4, 3)
    assert lines == []
    render_rigid_body(t, xyz, wxyz, "quadrotor", strip=2, options=SMALL)
    assert len(lines) == 1 and lines[0] > 2  # the quadrotor's path, as the spy sees it
    monkeypatch.undo()
    trajectory = SimpleNamespace(t=t, X=np.concatenate([xyz, wxyz, np.zeros((9, 6))], axis=1))
    result = SimpleNamespace(problem="quadflip", variant="attitude", trajectory=trajectory)
    paths = render_benchmark(result, tmp_path, options=dataclasses.replace(SMALL, fps=4), keyframes=3)
    assert [p.name for p in paths] == ["motion.mp4", "keyframes.png"]
    assert all(p.stat().st_size > 1000 for p in paths)
    with pytest.raises(ValueError, match="shape must be"):
        render_rigid_body(t, xyz, wxyz, "blimp", options=SMALL)
    for bad in (0, 2.0):  # an IndexError on no keyframes, numpy's TypeError on a float count
        with pytest.raises(ValueError, match=rf"strip must be a whole number of keyframes >= 1, got {bad!r}"):
            render_rigid_body(t, xyz, wxyz, "quadrotor", strip=bad, options=SMALL)
    # a solve that diverged: NaN states (MuJoCo refused the body's NaN size: "nan size in geom")
    xyz[6:, 2] = np.nan
    with pytest.raises(NotDrawable, match=r"the body's position or attitude is NaN or infinite at 3 knot\(s\), the first at knot 6"):
        render_rigid_body(t, xyz, wxyz, "quadrotor", options=SMALL)



def test_rigid_body_paths_are_checked_before_a_renderer_opens(monkeypatch):
    """Knots of different counts were an IndexError inside the interpolation, after the
    renderer had opened (and was left open); a zero quaternion drew black frames."""
    import jtraj.render as jrender

    monkeypatch.setattr(jrender, "_Painter", lambda *a, **k: pytest.fail("opened a renderer before checking the path"))
    t, xyz, wxyz = np.linspace(0.0, 1.0, 5), np.zeros((5, 3)), np.tile([1.0, 0.0, 0.0, 0.0], (5, 1))
    for args in ((t, xyz[:4], wxyz), (t, xyz, wxyz[:, :3]), (t[:, None], xyz, wxyz), (t[:0], xyz[:0], wxyz[:0])):
        with pytest.raises(ValueError, match=r"^render_rigid_body: t \(\d*,?.*\), xyz .* and wxyz .*: expected \(N,\), \(N, 3\) and \(N, 4\), N >= 1 knots$"):
            jrender.render_rigid_body(*args, "quadrotor", options=SMALL)
    wxyz[2] = 0.0
    with pytest.raises(NotDrawable, match=r"^the body's attitude is a zero quaternion at 1 knot\(s\), the first at knot 2; nothing to draw there$"):
        jrender.render_rigid_body(t, xyz, wxyz, "quadrotor", options=SMALL)


def test_no_context_names_the_backend_mujoco_loaded(monkeypatch):
    from mujoco import gl_context

    from jtraj.render import RenderError, _renderer

    def no_context(*args, **kwargs):
        raise RuntimeError("no OpenGL context")

    monkeypatch.setattr(mujoco, "Renderer", no_context)
    monkeypatch.setenv("MUJOCO_GL", "egl")
    model = mujoco.MjModel.from_xml_string("<mujoco/>")
    # mujoco imported before jtraj set MUJOCO_GL=egl: it loaded GLFW, which the variable no longer says
    monkeypatch.setattr(gl_context, "GLContext", type("GLContext", (), {"__module__": "mujoco.glfw"}))
    with pytest.raises(RenderError, match=r"with MuJoCo's glfw backend \(mujoco was imported before MUJOCO_GL was set to 'egl'.*import jtraj before mujoco"):
        _renderer(model, 32, 32)
    monkeypatch.setattr(gl_context, "GLContext", type("GLContext", (), {"__module__": "mujoco.egl"}))
    with pytest.raises(RenderError, match=r"with MUJOCO_GL='egl': no OpenGL context\. Without display"):
        _renderer(model, 32, 32)


def test_gif_keeps_real_time(tmp_path):
    from PIL import Image

    # one second at 30 fps: GIF delays are whole hundredths, 33 ms was stored as 30 ms (0.9 s in all)
    frames = np.random.default_rng(0).integers(0, 256, (30, 16, 16, 3), dtype=np.uint8)
    gif = Image.open(write_video(frames, tmp_path / "m.gif", fps=30))
    durations = []
    for i in range(gif.n_frames):
        gif.seek(i)
        durations.append(gif.info["duration"])
    assert len(durations) == 30 and sum(durations) == 1000 and set(durations) <= {30, 40}


def test_show_without_ffmpeg_says_what_to_install(monkeypatch):
    import shutil
    import sys

    from jtraj.render import RenderError, show

    monkeypatch.setattr(shutil, "which", lambda name: None)
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # not installed
    with pytest.raises(RenderError, match=r"needs ffmpeg, which is not on the PATH: pip install 'jtraj\[render\]'"):
        show(np.zeros((2, 16, 16, 3), np.uint8))


def test_render_directory_checks_its_arguments_before_drawing(result, tmp_path, monkeypatch):
    import jtraj.render as jrender

    result.save(tmp_path)
    (tmp_path / "v.gif").mkdir()
    (tmp_path / "s.png").mkdir()
    # a bad file name or strip argument was found after the video was drawn (minutes), and
    # neither file asked for was no error at all
    monkeypatch.setattr(jrender, "render", lambda *a, **k: pytest.fail("drew the video before checking the arguments"))
    monkeypatch.setattr(jrender, "keyframe_strip", lambda *a, **k: pytest.fail("drew the strip before checking the arguments"))
    for kwargs, match in (
        ({}, r"nothing to write: give out"),
        ({"out": tmp_path / "m.avi"}, r"m\.avi: expected a \.mp4 or \.gif file name"),
        ({"out": tmp_path / "m.gif", "strip": tmp_path / "k.bmp"}, r"k\.bmp: expected a \.png, \.jpg or \.jpeg file name"),
        ({"out": tmp_path / "m.gif", "strip": tmp_path / "k.png", "layout": "grid"}, "layout must be 'side' or 'overlay'"),
        ({"out": tmp_path / "m.gif", "strip": tmp_path / "k.png", "spacing": "even"}, "spacing must be 'motion' or 'time'"),
        ({"out": tmp_path / "m.gif", "strip": tmp_path / "k.png", "keyframes": 1}, "at least 2 keyframes"),
        # a folder failed in the write, after the drawing
        ({"out": tmp_path / "v.gif"}, r"v\.gif: is a folder; expected the name of a file to write"),
        ({"out": tmp_path / "m.gif", "strip": tmp_path / "s.png"}, r"s\.png: is a folder; expected the name of a file to write"),
    ):
        with pytest.raises(ValueError, match=match):
            jrender.render_directory(tmp_path, **kwargs)
    assert not (tmp_path / "m.gif").exists()


def test_the_ground_is_drawn_at_the_tasks_terrain_height(result, monkeypatch):
    """The ground plane is at the height the task's feet touch (``terrain_height``, which a
    result records in its options); it was drawn at z = 0 whatever the task said. A result saved
    before the height was recorded is drawn on z = 0."""
    import jtraj.render as render_module

    ground = render_module.scene_model("go2", 0.3)
    plane = mujoco.mj_name2id(ground, mujoco.mjtObj.mjOBJ_GEOM, "jtraj_ground")
    assert ground.geom_pos[plane][2] == pytest.approx(0.3)
    assert render_module.scene_model("go2").geom_pos[plane][2] == 0.0
    asked = []
    real = render_module.scene_model
    monkeypatch.setattr(render_module, "scene_model", lambda name, height=0.0: (asked.append((name, height)), real(name, height))[1])
    render(dataclasses.replace(result, options={"terrain_height": 0.3}), SMALL, fps=2, label=False)
    render(result, SMALL, fps=2, label=False)
    assert asked == [("go2", 0.3), ("go2", 0.0)]


def test_a_result_saved_without_a_trajectory_beside_an_earlier_one(result, tmp_path, capsys):
    """A result saved without a trajectory (result.json's digest null) beside an earlier solve's
    trajectory.npz, which `Result.load` leaves out: `jtraj plot` ended in a FileNotFoundError's
    traceback saying "result.json without trajectory.npz" with the file there, and `jtraj render`
    said to load a folder with trajectory.npz. Both say which file is whose, in one line (exit 2)."""
    import shutil

    result.save(tmp_path / "full")
    dataclasses.replace(result, trajectory=None).save(tmp_path / "run")
    shutil.copy(tmp_path / "full" / "trajectory.npz", tmp_path / "run" / "trajectory.npz")
    said = r"saved without a trajectory, nothing to (plot against time|draw); the trajectory\.npz beside it is an earlier solve's"
    with pytest.raises(FileFormatError, match=rf"run/result\.json: {said}"):
        plot_directory(tmp_path / "run")
    with pytest.raises(NotDrawable, match=rf"run/result\.json: {said}"):
        render(tmp_path / "run", SMALL)
    capsys.readouterr()
    assert main(["plot", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("jtraj plot: DIR:") and "earlier solve's" in err and err.count("\n") == 1
    assert main(["render", str(tmp_path / "run"), "--strip", str(tmp_path / "k.png")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("jtraj render: DIR:") and "earlier solve's" in err and err.count("\n") == 1
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == ["result.json", "trajectory.npz"]
    # without the earlier file, no word of one
    (tmp_path / "run" / "trajectory.npz").unlink()
    with pytest.raises(FileFormatError, match=r"saved without a trajectory, nothing to plot against time$"):
        plot_directory(tmp_path / "run")


def test_mp4_without_its_writer_is_refused_before_anything_is_drawn(result, tmp_path, monkeypatch):
    """Without imageio-ffmpeg, an .mp4 failed only when it was written, after every frame was
    drawn (minutes), and the keyframe strip asked for with it was not written at all."""
    import sys
    from types import SimpleNamespace

    import jtraj.render as jrender

    result.save(tmp_path / "run")
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # not installed
    monkeypatch.setattr(jrender._Painter, "draw", lambda *a, **k: pytest.fail("drew a frame before checking the video writer"))
    said = r"writing \.mp4 needs imageio-ffmpeg: pip install 'jtraj\[render\]' \(or write a \.gif\)"
    with pytest.raises(jrender.RenderError, match=said):
        jrender.render_directory(tmp_path / "run", tmp_path / "m.mp4", tmp_path / "k.png", options=SMALL)
    # jtraj render: the same line, exit status 1 (as without OpenGL)
    with pytest.raises(SystemExit, match=rf"^jtraj render: {said}$"):
        main(["render", str(tmp_path / "run"), "--out", str(tmp_path / "m.mp4"), "--strip", str(tmp_path / "k.png"), "--width", str(W), "--height", str(H)])
    # jtraj attitude --render's motion.mp4
    t = np.linspace(0.0, 1.0, 3)
    X = np.concatenate([np.zeros((3, 3)), np.tile([1.0, 0.0, 0.0, 0.0], (3, 1)), np.zeros((3, 6))], axis=1)
    quadflip = SimpleNamespace(problem="quadflip", variant="attitude", trajectory=SimpleNamespace(t=t, X=X))
    with pytest.raises(jrender.RenderError, match=said):
        jrender.render_benchmark(quadflip, tmp_path / "att", options=SMALL)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
    jrender._check_video_writer(tmp_path / "m.gif")  # Pillow writes GIF
    # jtraj solve --render and jtraj attitude --render: before the solve
    import jtraj.attitude.cli
    import jtraj.solver

    monkeypatch.setattr(jtraj.solver, "solve", lambda *a, **k: pytest.fail("solved before checking the video writer"))
    monkeypatch.setattr(jtraj.attitude.cli, "main", lambda *a, **k: pytest.fail("solved before checking the video writer"))
    for argv in (["solve", "big_jump", "--out", str(tmp_path / "s"), "--render"], ["attitude", "quadflip", "--out", str(tmp_path / "a"), "--render"]):
        with pytest.raises(SystemExit, match=rf"^jtraj {argv[0]}: --render: {said}; nothing was solved$"):
            main(argv)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_force_arrows_are_scaled_by_the_weight_of_the_masses_solved_at(result):
    """A force equal to the robot's weight is drawn 2 standing heights long: the weight of the
    body masses the solve used (options["theta"]), not the model's, whose forces they carried."""
    from jtraj.dynamics import model_masses
    from jtraj.render import _Painter

    go2 = robots.load("go2")
    heavier = dataclasses.replace(result, options={"theta": {"friction": 0.9, "body_masses": (1.5 * model_masses(go2)).tolist()}})
    for r, scale in ((result, 1.0), (heavier, 1.5)):
        painter = _Painter.for_result(r, SMALL)
        try:
            assert painter.weight == pytest.approx(scale * go2.total_mass * go2.gravity)
        finally:
            painter.close()


def test_an_image_too_large_for_opengl_leaves_later_renders_alone():
    """The shared (cached) scene model's offscreen size was raised for each renderer and never
    lowered: after one request larger than OpenGL allows, every later render of that robot in
    the process failed too, with advice to install Mesa."""
    from jtraj.render import RenderError, render, scene_model

    r = _result()
    model = scene_model("go2")
    size = int(model.vis.global_.offwidth), int(model.vis.global_.offheight)
    with pytest.raises(RenderError, match=r"offscreen framebuffer of 262144x16 pixels .*draw smaller images"):
        render(r, width=262144, height=16, fps=2, shadows=False)
    assert (int(model.vis.global_.offwidth), int(model.vis.global_.offheight)) == size
    frames = render(r, width=160, height=120, fps=2, shadows=False)
    assert frames.shape == (2, 120, 160, 3) and frames.std() > 10


def test_renderers_made_in_threads_each_get_their_size(monkeypatch):
    """`_renderer` sets the shared model's offscreen size, makes the renderer and puts the size
    back. Two threads doing it at once interleaved: one's put-back could land between the
    other's set and its renderer, which then saw the wrong size (a failed framebuffer), and
    the model kept the other thread's size. Each renderer here sees its own size throughout,
    and the model ends at its own."""
    import threading
    import time
    import types

    from jtraj import render as render_mod

    model = mujoco.MjModel.from_xml_string("<mujoco/>")
    size = int(model.vis.global_.offwidth), int(model.vis.global_.offheight)
    seen = []

    class Renderer:  # stands in for mujoco.Renderer: reads the model's size twice, a while apart
        def __init__(self, m, height, width):
            first = int(m.vis.global_.offwidth), int(m.vis.global_.offheight)
            time.sleep(0.05)
            seen.append(((width, height), first, (int(m.vis.global_.offwidth), int(m.vis.global_.offheight))))

    monkeypatch.setattr(render_mod, "_mujoco", lambda: types.SimpleNamespace(Renderer=Renderer))
    threads = [threading.Thread(target=render_mod._renderer, args=(model, 100 + 10 * i, 80 + 10 * i)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(seen) == 4
    for asked, first, later in seen:
        assert first == asked and later == asked
    assert (int(model.vis.global_.offwidth), int(model.vis.global_.offheight)) == size


def _poses_about(axis, turns, travel=(0.0, 0.0), n=41):
    """(n, 7) base poses turning ``turns`` about ``axis`` while moving by ``travel`` (x, y)."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    angle = np.linspace(0.0, 2 * np.pi * turns, n)
    xyz = np.column_stack([np.linspace(0.0, travel[0], n), np.linspace(0.0, travel[1], n), np.full(n, 0.3)])
    wxyz = np.column_stack([np.cos(angle / 2), np.sin(angle / 2)[:, None] * axis])
    return np.concatenate([xyz, wxyz], axis=1)


@pytest.mark.parametrize(
    "axis, turns, travel, azimuth",
    [
        ([0, 1, 0], -1, (-0.5, 0.0), 90.0),  # the back-flip: along y, as the fixed default did
        ([1, 0, 0], -1, (0.0, 0.3), 180.0),  # the side-flip: along x (90 saw it edge-on)
        ([-1, 0, 0], 1, (0.0, 0.3), 180.0),  # the same flip, its axis written the other way
        ([0, 0, 1], 0, (2.0, 0.0), 90.0),  # a walk along +x: from its side, going right
        ([0, 0, 1], 0, (0.0, 1.0), 180.0),  # along +y
        ([0, 0, 1], 0, (-1.0, 0.0), 270.0),  # along -x
        ([0, 0, 1], 1, (0.0, 0.0), 90.0),  # a spin about the vertical, in place
        ([0, 0, 1], 0, (0.01, 0.02), 90.0),  # a drift under TRAVEL_FOR_CAMERA
    ],
)
def test_the_default_camera_looks_along_a_flips_axis_or_from_the_side_of_the_travel(axis, turns, travel, azimuth):
    """The camera's azimuth was 90 (looking along +y) for every legged motion: the side-flip,
    about x, turned towards and away from the viewer, and its keyframes overlaid on top of each
    other."""
    from jtraj.render import auto_azimuth

    assert auto_azimuth(_poses_about(axis, turns, travel)) == pytest.approx(azimuth)


def test_a_side_flip_is_drawn_along_its_axis_and_an_explicit_azimuth_is_kept(result, monkeypatch):
    """`keyframe_strip` and `render` choose the azimuth from the motion unless one is given;
    `render_rigid_body` took an explicit azimuth=90 for the default and replaced it."""
    import jtraj.render as jrender

    seen = []
    original = jrender._Painter.camera
    monkeypatch.setattr(jrender._Painter, "camera", lambda self, *a: seen.append(self.options.azimuth) or original(self, *a))
    traj = result.trajectory
    # the made-up half back-flip turned about x instead (a side-flip's axis): w, x, y, z -> w, y, ...
    turned = traj.base_xyz_wxyz.copy()
    turned[:, 4], turned[:, 5] = traj.base_xyz_wxyz[:, 5], traj.base_xyz_wxyz[:, 4]
    side = dataclasses.replace(result, trajectory=dataclasses.replace(traj, base_xyz_wxyz=turned, q_base=turned))
    keyframe_strip(side, 2, options=SMALL)
    assert set(seen) == {180.0}
    seen.clear()
    keyframe_strip(result, 2, options=SMALL)  # the back-flip: 90, as before
    assert set(seen) == {90.0}
    seen.clear()
    keyframe_strip(side, 2, options=dataclasses.replace(SMALL, azimuth=90.0))
    assert set(seen) == {90.0}
    seen.clear()
    t = np.linspace(0.0, 1.0, 5)
    xyz = np.column_stack([np.zeros(5), np.linspace(0.0, 2.0, 5), np.ones(5)])
    wxyz = np.tile([1.0, 0.0, 0.0, 0.0], (5, 1))
    jrender.render_rigid_body(t, xyz, wxyz, "quadrotor", strip=2, options=dataclasses.replace(SMALL, azimuth=90.0))
    assert set(seen) == {90.0}
    seen.clear()
    jrender.render_rigid_body(t, xyz, wxyz, "quadrotor", strip=2, options=SMALL)  # from the side of its travel along +y
    assert set(seen) == {180.0}


def test_render_command_takes_the_camera(result, tmp_path):
    """`jtraj render` had no camera options: a motion the default view showed edge-on could be
    turned only from Python."""
    from jtraj.cli import _render_options, build_parser

    args = build_parser().parse_args(["render", str(tmp_path), "--strip", "k.png", "--azimuth", "0", "--elevation", "-30", "--distance", "4"])
    options = _render_options(args)
    assert (options.azimuth, options.elevation, options.distance) == (0.0, -30.0, 4.0)
    default = _render_options(build_parser().parse_args(["render", str(tmp_path), "--strip", "k.png"]))
    assert (default.azimuth, default.elevation, default.distance) == (None, RenderOptions.elevation, None)
    result.save(tmp_path / "run")
    for flag, value in (("--azimuth", "nan"), ("--distance", "0")):
        assert main(["render", str(tmp_path / "run"), "--strip", str(tmp_path / "k.png"), flag, value]) == 2
    assert not (tmp_path / "k.png").exists()


def test_an_mp4_without_the_ffmpeg_program_is_refused_before_drawing(result, tmp_path, monkeypatch):
    """imageio-ffmpeg without an ffmpeg program (its wheel without a binary, none on the system)
    passed the check, and its RuntimeError came as a traceback once every frame was drawn."""
    import imageio_ffmpeg

    import jtraj.render as jrender

    def missing():
        raise RuntimeError("No ffmpeg exe could be found. Install ffmpeg on your system, or set the IMAGEIO_FFMPEG_EXE environment variable.")

    monkeypatch.setattr(imageio_ffmpeg, "get_ffmpeg_exe", missing)
    monkeypatch.setattr(jrender, "render", lambda *a, **k: pytest.fail("drew the video before checking its writer"))
    result.save(tmp_path)
    with pytest.raises(jrender.RenderError, match=r"writing \.mp4 needs the ffmpeg program, which imageio-ffmpeg did not find \(No ffmpeg exe"):
        jrender.render_directory(tmp_path, tmp_path / "m.mp4")
    assert not (tmp_path / "m.mp4").exists()


def test_a_video_of_too_many_frames_is_refused_before_drawing(result, tmp_path, monkeypatch, capsys):
    """The frames are held in memory until written: --speed 0.01 on a few seconds of motion was
    gigabytes, and the process was killed after a long draw without a word."""
    import jtraj.render as jrender

    monkeypatch.setattr(jrender._Painter, "for_result", lambda *a, **k: pytest.fail("opened a renderer for too many frames"))
    duration = float(result.trajectory.t[-1] - result.trajectory.t[0])
    speed = duration * SMALL.fps / jrender.MAX_FRAMES  # one frame more than allowed
    with pytest.raises(jrender.TooManyFrames, match=rf"is {jrender.MAX_FRAMES + 1} frames; expected at most {jrender.MAX_FRAMES}"):
        render(result, SMALL, speed=speed)
    # a rigid body's video too (`jtraj render` of an attitude folder, `jtraj attitude --render`)
    monkeypatch.setattr(jrender, "_Painter", lambda *a, **k: pytest.fail("opened a renderer for too many frames"))
    t = np.linspace(0.0, 1.0, 5)
    with pytest.raises(jrender.TooManyFrames, match=r"1 s of motion at speed 1e-06"):
        jrender.render_rigid_body(t, np.zeros((5, 3)), np.tile([1.0, 0.0, 0.0, 0.0], (5, 1)), "quadrotor", options=SMALL, speed=1e-6)
    monkeypatch.undo()
    result.save(tmp_path / "run")
    assert main(["render", str(tmp_path / "run"), "--out", str(tmp_path / "m.gif"), "--speed", "1e-4"]) == 2
    err = capsys.readouterr().err
    assert "jtraj render: --speed, --fps: 0.0001, 30: 0.5 s of motion at speed 0.0001 and 30 fps is 150001 frames" in err
    assert not (tmp_path / "m.gif").exists()
