"""Figures of a solution (jtraj.plots), on the made-up Go2 motion of test_render (no solve, no
OpenGL)."""

import dataclasses
import json

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pytest
from test_render import _result

from jtraj import robot as robots
from jtraj.plots import plot_comparison, plot_convergence, plot_result, plot_solution


@pytest.fixture(scope="module")
def result():
    return _result()


def test_figures_leave_pyplot_alone(result, tmp_path):
    # a notebook's backend and its open figures: jtraj's figures must not switch the one
    # (matplotlib.use closes every figure and stops inline display) nor join the others
    backend = matplotlib.get_backend()
    plt.switch_backend("svg")
    try:
        mine = plt.figure()
        result.save(tmp_path / "made_up_flip_se3")
        (tmp_path / "table_iv.json").write_text(json.dumps([{"task": "made_up_flip", "parameterization": "se3", "status": "solved", "iterations": 0}]))
        figures = [plot_solution(result), plot_result(result, tmp_path / "r.png"), plot_convergence(result, tmp_path / "c.png"), plot_comparison(tmp_path)]
        assert matplotlib.get_backend() == "svg"
        assert plt.get_fignums() == [mine.number]
        assert len(figures[0].axes) == 6 and (tmp_path / "r.png").stat().st_size > 10_000
    finally:
        plt.close("all")
        plt.switch_backend(backend)


def test_torque_panel_with_nan_torques(result):
    go2 = robots.load("go2")
    tau = np.zeros_like(result.trajectory.tau)
    tau[:, 6 + 4] = go2.tau_max[4]  # the fifth joint at its limit ...
    tau[5, 6 + 4] = np.nan  # ... but NaN at one knot
    tau[:, 6 + 1] = 0.5 * go2.tau_max[1]
    with_nan = dataclasses.replace(result, trajectory=dataclasses.replace(result.trajectory, tau=tau))
    torque_panel = plot_solution(with_nan).axes[3]
    assert torque_panel.get_title() == f"highest: {go2.joint_names[4]} (1.00)"
    # a solve stopped by a numerical error: every torque NaN is drawn, not a ValueError
    all_nan = dataclasses.replace(result, trajectory=dataclasses.replace(result.trajectory, tau=np.full_like(tau, np.nan)))
    assert plot_solution(all_nan).axes[3].get_title() == "joint torques are NaN"


def test_comparison_keeps_its_legend_and_labels_when_the_first_column_is_blank(result, tmp_path):
    # the table's first parameterization saved no trajectory: its column is blank, the next is drawn
    result.save(tmp_path / "made_up_flip_euler")
    rows = [{"task": "made_up_flip", "parameterization": p, "status": "solved", "iterations": 0} for p in ("se3", "euler")]
    (tmp_path / "table_iv.json").write_text(json.dumps(rows))
    fig = plot_comparison(tmp_path)
    (blank_top, drawn_top), (blank_bottom, drawn_bottom) = np.reshape(fig.axes, (2, 2))
    assert blank_top.get_title() == "made_up_flip [se3]: no trajectory"
    assert [t.get_text() for t in drawn_top.get_legend().get_texts()] == ["x", "y", "z"]
    assert drawn_bottom.get_legend() is not None
    assert (blank_top.get_ylabel(), blank_bottom.get_ylabel()) == ("base position (m)", "rotation (deg)")


def test_a_single_knot_is_marked(result):
    from test_render import _first_knots

    one = _first_knots(result, 1)
    for fig in (plot_solution(one), plot_result(one, None)):
        curves = [line for ax in fig.axes for line in ax.get_lines() if len(line.get_xdata()) == 1]
        assert curves and all(line.get_marker() == "o" for line in curves)  # a line of one point is invisible


def test_convergence_ticks_whole_iterations(result):
    # two iterations (0 and 1): matplotlib's default ticks were 0, 0.2, ..., 1
    ax = plot_convergence(result, None).axes[0]
    ticks = [t for t in ax.get_xticks() if ax.get_xlim()[0] <= t <= ax.get_xlim()[1]]
    assert ticks and all(float(t).is_integer() for t in ticks), ticks


def test_flight_shading_stays_within_the_motion(result):
    # the made-up motion ends in flight: the last band stretched the time axis half a step past 0.5 s
    t = result.trajectory.t
    for fig in (plot_result(result, None), plot_solution(result)):
        for ax in fig.axes:
            assert (ax.dataLim.x0, ax.dataLim.x1) == pytest.approx((t[0], t[-1]), abs=1e-12)


def test_friction_panel_uses_the_friction_solved_at(result):
    """A solve at another friction (theta) records it in options["theta"]; the friction panel
    used the built-in task's (or 0.9) whatever the solve's friction was."""
    assert plot_solution(result).axes[5].get_ylabel() == "max(|f_x|, |f_y|) / (mu f_z), mu = 0.9"
    at_half = dataclasses.replace(result, options={**result.options, "theta": {"friction": 0.5}})
    assert plot_solution(at_half).axes[5].get_ylabel() == "max(|f_x|, |f_y|) / (mu f_z), mu = 0.5"
    assert plot_solution(at_half, friction=0.3).axes[5].get_ylabel() == "max(|f_x|, |f_y|) / (mu f_z), mu = 0.3"


def test_friction_panel_measures_the_pyramid_the_nlp_enforces(result):
    """The NLP keeps touching points in the 4-facet pyramid ``|f_x|, |f_y| <= mu f_z``
    (`jtraj.transcription.friction_stage`); the panel measured the circular cone ``|f_t| /
    (mu f_z)``, which put a feasible force at the pyramid's corner at sqrt(2), over the dashed
    limit."""
    from jtraj import plots

    mu = 0.5
    forces = np.array(result.trajectory.forces)
    fz = forces[:3, :, 2:3]
    forces[:3, :, :2] = mu * fz * np.array([1.0, -1.0])  # the pyramid's corner: both facets active
    corner = dataclasses.replace(result, options={"theta": {"friction": mu}}, trajectory=dataclasses.replace(result.trajectory, forces=forces))
    panel = plot_solution(corner).axes[5]
    drawn = np.concatenate([line.get_ydata() for line in panel.get_lines() if line.get_label() in corner.trajectory.contact_names])
    np.testing.assert_allclose(np.nanmax(drawn), 1.0)
    assert "pyramid" in panel.get_title()
    # the former name, which measured the circular cone, still answers, with a warning
    with pytest.warns(DeprecationWarning, match="friction_cone_ratio is deprecated: it is now called jtraj.plots.friction_pyramid_ratio"):
        assert plots.friction_cone_ratio is plots.friction_pyramid_ratio


def test_weight_line_is_the_weight_of_the_masses_solved_at(result):
    """A solve at other body masses (theta) records them in options["theta"]; the weight line
    was the model's mass whatever the solve's masses were. The world body (first) is left out,
    as `jtraj.transcription.robot_mass` does."""
    from jtraj.dynamics import model_masses

    go2 = robots.load("go2")

    def weight_line(r):
        (line,) = [line for line in plot_solution(r).axes[4].get_lines() if line.get_label() == "weight"]
        return line.get_ydata()[0]

    assert weight_line(result) == pytest.approx(go2.total_mass * go2.gravity)
    masses = 1.5 * model_masses(go2)
    masses[0] = 100.0  # the world body's entry: not the robot's weight
    heavier = dataclasses.replace(result, options={"theta": {"friction": 0.9, "body_masses": masses.tolist()}})
    assert weight_line(heavier) == pytest.approx(1.5 * go2.total_mass * go2.gravity)


def test_friction_of_a_result_without_theta_is_its_builtin_tasks(monkeypatch):
    """A result without a recorded theta (older files) takes a built-in task's friction; a name
    that is no built-in task gives none (the panel's 0.9), and a built-in task that fails to
    load says so instead of passing for an unknown name."""
    from jtraj import plots
    from jtraj import task as tasks

    assert plots._task_friction("big_jump") == tasks.load("big_jump").friction
    assert plots._task_friction("my_own_hop") is None

    def broken(name):
        raise tasks.TaskError("phases[0].duration", -1.0, "a positive duration")

    monkeypatch.setattr(tasks, "load", broken)
    with pytest.raises(tasks.TaskError, match="a positive duration"):
        plots._task_friction("big_jump")


def test_comparison_cells_without_a_trajectory_or_of_another_solver(result, tmp_path):
    """A cell whose result.json was saved without a trajectory beside an older trajectory.npz
    (Result.load drops that one) ended jtraj plot in AttributeError on None; a cell saved by
    another solver with the table's status and iterations was drawn as the table's."""
    import dataclasses

    result.save(tmp_path / "made_up_flip_se3")
    dataclasses.replace(result, trajectory=None).save(tmp_path / "made_up_flip_euler")
    (tmp_path / "made_up_flip_euler" / "trajectory.npz").write_bytes((tmp_path / "made_up_flip_se3" / "trajectory.npz").read_bytes())
    rows = [{"task": "made_up_flip", "parameterization": p, "status": result.status.value, "iterations": result.iterations, "solver": s} for p, s in (("se3", "jtraj"), ("euler", result.solver))]
    (tmp_path / "table_iv.json").write_text(json.dumps(rows))
    fig = plot_comparison(tmp_path)
    (se3_top, euler_top), _ = np.reshape(fig.axes, (2, 2))
    assert result.solver != "jtraj" and se3_top.get_title() == "made_up_flip [se3]: saved run is not the table's"
    assert euler_top.get_title() == "made_up_flip [euler]: no trajectory"


def test_a_result_naming_another_robot_is_refused_in_one_line(result, tmp_path, capsys):
    """A result.json whose model was edited to another robot passes the files' checksum (it
    covers the trajectory); `jtraj plot` ended in an IndexError and `jtraj render` in a
    broadcast error, each a traceback. Both now name the array and what the robot wants."""
    from jtraj.cli import main
    from jtraj.io import FileFormatError

    other = dataclasses.replace(result, model="g1")
    knots, joints = np.shape(result.trajectory.q_joints)
    g1 = robots.load("g1")
    assert g1.nj != joints
    with pytest.raises(FileFormatError, match=rf"does not fit the robot 'g1' its result names: q_joints has shape \({knots}, {joints}\), the robot wants \(knots, {g1.nj}\)"):
        plot_solution(other)
    other.save(tmp_path / "run")
    for argv in (["plot", str(tmp_path / "run"), "--out", str(tmp_path / "p")], ["render", str(tmp_path / "run"), "--strip", str(tmp_path / "k.png"), "--keyframes", "2"]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"jtraj {argv[0]}: DIR:") and "does not fit the robot 'g1'" in err and err.count("\n") == 1, err
    assert not (tmp_path / "k.png").exists() and not (tmp_path / "p" / "solution.png").exists()


def test_a_compare_folder_without_trajectories_is_refused(result, tmp_path, capsys):
    """`jtraj plot` of a folder written by `jtraj compare --no-trajectories` (results/table_iv)
    wrote comparison.png with every panel blank and exited 0; with one cell saved it draws."""
    from jtraj.cli import main
    from jtraj.io import FileFormatError

    rows = [{"task": "made_up_flip", "parameterization": p, "status": result.status.value, "iterations": result.iterations, "solver": result.solver} for p in ("se3", "euler")]
    (tmp_path / "table_iv.json").write_text(json.dumps(rows))
    with pytest.raises(FileFormatError, match=r"table_iv.json: none of its 2 runs has a saved trajectory to draw"):
        plot_comparison(tmp_path)
    assert main(["plot", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("jtraj plot: DIR:") and "none of its 2 runs" in err and err.count("\n") == 1, err
    assert not (tmp_path / "comparison.png").exists()
    result.save(tmp_path / "made_up_flip_se3")
    fig = plot_comparison(tmp_path)
    assert fig.axes[0].get_title().startswith("made_up_flip [se3]: ") and fig.axes[1].get_title() == "made_up_flip [euler]: no trajectory"
