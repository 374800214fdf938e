"""Figures of a solved trajectory: matplotlib Figures built without pyplot (no screen needed,
a notebook's own figures and backend left alone), written to files or returned."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jtraj import io as jio
from jtraj.lie import accumulated_rotation
from jtraj.result import Result, stale_trajectory_note

__all__ = ["plot_result", "plot_convergence", "plot_solution", "plot_comparison", "plot_directory", "friction_pyramid_ratio"]


def _figure(**kwargs):
    """A matplotlib Figure built without pyplot: it needs no display, and neither switches the
    backend of a notebook nor closes or shows its other figures."""
    from matplotlib.figure import Figure

    return Figure(**kwargs)


def plot_result(result: Result, path: str | Path) -> Path:
    """Base position, base rotation (about the world axes, accumulated from the first knot),
    vertical contact forces and joint torques against time, flight phases shaded grey. Returns
    the path (the figure when ``path`` is None)."""
    t = _trajectory(result)
    fig = _figure(figsize=(11, 6.5))
    axes = fig.subplots(2, 2, sharex=True)
    touching = t.in_contact.any(axis=1)
    for ax in axes.ravel():
        _flight_shading(ax, t.t, touching)
    _base_pose_panels(axes[0, 0], axes[0, 1], t)
    ax = axes[1, 0]
    fz = t.forces[:, :, 2]
    for j, name in enumerate(t.contact_names):
        ax.plot(t.t, fz[:, j], lw=0.8, label=name if len(t.contact_names) <= 8 else None)
    ax.set_ylabel("contact force z (N)")
    ax.set_xlabel("time (s)")
    if len(t.contact_names) <= 8:
        ax.legend(fontsize=6, ncol=2)
    ax = axes[1, 1]
    ax.plot(t.t, t.tau[:, 6:], lw=0.6)
    ax.set_ylabel("joint torques (N m)")
    ax.set_xlabel("time (s)")
    turns = "" if result.turns is None else f", {result.turns:+.2f} turns"
    fig.suptitle(f"{result.task} on {result.robot}, {result.parameterization}: {result.status.value}, {result.iterations} iterations{turns} (grey: flight)")
    fig.tight_layout()
    return _finish(fig, path)


def plot_convergence(result: Result, path: str | Path) -> Path:
    """Primal and dual infeasibility against the solver's iterations."""
    from matplotlib.ticker import MaxNLocator

    h = result.history
    fig = _figure(figsize=(5, 3.5))
    ax = fig.subplots()
    it = [r["iter"] for r in h]
    ax.semilogy(it, [r["inf_pr"] for r in h], label="primal infeasibility")
    ax.semilogy(it, [r["inf_du"] for r in h], label="dual infeasibility")
    ax.set_xlabel(f"{result.solver} iteration")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # no iteration 0.5 on a short solve
    ax.legend()
    ax.set_title(f"{result.task} [{result.parameterization}]")
    fig.tight_layout()
    return _finish(fig, path)


def _base_pose_panels(ax_position, ax_rotation, t) -> None:
    """Base position (m) and base rotation about the world axes (deg, accumulated)."""
    for i, name in enumerate("xyz"):
        ax_position.plot(t.t, t.base_xyz_wxyz[:, i], label=name)
    ax_position.set_ylabel("base position (m)")
    ax_position.legend(fontsize=8)
    angles = np.asarray(accumulated_rotation(t.base_xyz_wxyz[:, 3:7]))
    for i, name in enumerate(("about x", "about y", "about z")):
        ax_rotation.plot(t.t, np.degrees(angles[:, i]), label=name)
    ax_rotation.set_ylabel("base rotation (deg, accumulated)")
    ax_rotation.legend(fontsize=8)


def _flight_shading(ax, t, touching) -> None:
    """Grey bands over the knots where no contact point touches the ground (half a step either
    side, within the motion's span: a flight at the end does not stretch the time axis)."""
    dt = t[1] - t[0] if len(t) > 1 else 0.0
    for k in np.flatnonzero(~touching):
        ax.axvspan(max(t[k] - 0.5 * dt, t[0]), min(t[k] + 0.5 * dt, t[-1]), color="0.9", lw=0)


def _task_friction(task_name: str) -> float | None:
    """The friction coefficient of a built-in task, None when ``task_name`` is not one."""
    from jtraj import task as tasks

    if task_name not in tasks.available():  # a task built in Python or from a file
        return None
    return float(tasks.load(task_name).friction)  # a built-in task that fails to load says why


def friction_pyramid_ratio(forces: np.ndarray, friction: float) -> np.ndarray:
    """``max(|f_x|, |f_y|) / (mu f_z)`` of world-frame contact forces (..., 3) on flat ground:
    at most 1 inside the 4-facet friction pyramid ``|f_x|, |f_y| <= mu f_z`` that the NLP
    enforces (`jtraj.transcription.friction_stage`, on the same world-frame forces); NaN where
    ``f_z`` is not positive (no contact). The circular cone's ``|f_t| / (mu f_z)`` put a
    feasible force at the pyramid's corner at sqrt(2), over the limit."""
    forces = np.asarray(forces, float)
    tangential = np.max(np.abs(forces[..., :2]), axis=-1)
    fz = forces[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(fz > 1e-9, tangential / (friction * fz), np.nan)


def __getattr__(name: str):
    if name == "friction_cone_ratio":  # its former name, when it measured the circular cone the NLP does not enforce
        from jtraj.deprecation import warn_renamed

        warn_renamed("jtraj.plots.friction_cone_ratio", "jtraj.plots.friction_pyramid_ratio (max(|f_x|, |f_y|) / (mu f_z), the NLP's pyramid)")
        return friction_pyramid_ratio
    raise AttributeError(f"module 'jtraj.plots' has no attribute {name!r}")


def _weight(result: Result, robot) -> float:
    """The weight (N) of the robot that ``result`` was solved for: its body masses as solved at
    (``options["theta"]["body_masses"]``, recorded by `jtraj.solve`; the world body's, first,
    left out as `jtraj.transcription.robot_mass` does); the robot model's total mass where
    they are not recorded (results saved before) or do not sum to a positive mass."""
    masses = (result.options.get("theta") or {}).get("body_masses")
    if masses is not None:
        from jtraj.transcription import robot_mass

        mass = float(robot_mass(np.asarray(masses, float)))
        if np.isfinite(mass) and mass > 0:
            return mass * robot.gravity
    return robot.total_mass * robot.gravity


def plot_solution(result: Result, path: str | Path | None = None, *, friction: float | None = None):
    """Six panels against time, contact phases shaded (grey: flight): base position; base
    rotation (world-axis angles, accumulated, deg); joint angles and joint torques as fractions
    of their limits (0..1 is the range for angles, joints without limits left out;
    |tau| / tau_max <= 1 for torques); vertical contact forces (N) against the robot's weight
    at the body masses it was solved at (`_weight`); and the use of the friction pyramid the NLP
    enforces, ``max(|f_x|, |f_y|) / (mu f_z)`` (<= 1 inside it, `friction_pyramid_ratio`).

    ``friction`` (mu) defaults to the friction the result was solved at (its
    ``options["theta"]``, recorded by `jtraj.solve`), else the built-in task's of the result's
    task name (0.9, said in the panel's title, for another task). Returns the figure, or writes
    it to ``path`` and returns the path.
    """

    t = _trajectory(result)
    robot = result_robot(result)
    if friction is None:
        friction = (result.options.get("theta") or {}).get("friction")
    mu = friction if friction is not None else _task_friction(result.task)
    mu_note = "" if friction is not None or mu is not None else " (mu = 0.9 assumed: not a built-in task)"
    mu = 0.9 if mu is None else mu
    touching = t.in_contact.any(axis=1)
    fig = _figure(figsize=(12, 9))
    axes = fig.subplots(3, 2, sharex=True)
    for ax in axes.ravel():
        _flight_shading(ax, t.t, touching)

    _base_pose_panels(axes[0, 0], axes[0, 1], t)

    ax = axes[1, 0]
    span = robot.q_upper - robot.q_lower
    bounded = np.isfinite(span)
    ax.plot(t.t, (t.q_joints[:, bounded] - robot.q_lower[bounded]) / span[bounded], lw=0.7)
    for limit in (0.0, 1.0):
        ax.axhline(limit, color="k", ls="--", lw=0.8)
    ax.set_ylabel("joint angle (fraction of range)")

    ax = axes[1, 1]
    ratio = np.abs(t.tau[:, 6:]) / robot.tau_max
    ax.plot(t.t, ratio, lw=0.7)
    ax.axhline(1.0, color="k", ls="--", lw=0.8)
    ax.set_ylabel("|joint torque| / limit")
    if np.isnan(ratio).all():  # a solve stopped by a numerical error
        ax.set_title("joint torques are NaN", fontsize=8)
    else:
        peak = np.where(np.isnan(ratio), -np.inf, ratio).max(axis=0)  # a NaN knot leaves its joint's other knots in
        worst = int(np.argmax(peak))
        ax.set_title(f"highest: {robot.joint_names[worst]} ({peak[worst]:.2f})", fontsize=8)

    labels = t.contact_names if len(t.contact_names) <= 8 else [None] * len(t.contact_names)
    ax = axes[2, 0]
    for j, name in enumerate(labels):
        ax.plot(t.t, t.forces[:, j, 2], lw=0.8, label=name)
    ax.axhline(_weight(result, robot), color="k", ls=":", lw=0.8, label="weight")
    ax.set_ylabel("contact force z (N)")
    ax.set_xlabel("time (s)")
    ax.legend(fontsize=6, ncol=2)

    ax = axes[2, 1]
    pyramid = friction_pyramid_ratio(t.forces, mu)
    for j, name in enumerate(labels):
        ax.plot(t.t, pyramid[:, j], lw=0.8, label=name)
    ax.axhline(1.0, color="k", ls="--", lw=0.8)
    ax.set_ylabel(f"max(|f_x|, |f_y|) / (mu f_z), mu = {mu:g}")
    ax.set_xlabel("time (s)")
    ax.set_title(f"the NLP's friction pyramid |f_x|, |f_y| <= mu f_z{mu_note}", fontsize=8)

    turns = "" if result.turns is None else f", {result.turns:+.2f} turns"
    fig.suptitle(
        f"{result.task} on {result.robot}, {result.parameterization}: {result.status.value}, "
        f"{result.iterations} iterations{turns} (grey: flight; dashed: limits)"
    )
    fig.tight_layout()
    return _finish(fig, path)


def _trajectory(result: Result):
    if result.trajectory is None:
        raise ValueError("the result has no trajectory (solve(..., keep_trajectory=True))")
    return result.trajectory


def result_robot(result: Result):
    """The robot ``result`` names (`jtraj.robot.load`), checked against its trajectory's
    widths: a result.json whose model was edited to another robot passes the files' checksum
    (which covers the trajectory only), and drawing or plotting it failed deep inside with a
    broadcast or index error. `jtraj.io.FileFormatError` (a ValueError) says which array and
    what the robot wants."""
    from jtraj import robot as robots

    robot = robots.load(result.robot)
    t = _trajectory(result)
    for name, width in (("q_joints", robot.nj), ("v", robot.nv)):
        shape = np.asarray(getattr(t, name, None)).shape
        if len(shape) != 2 or shape[1] != width:
            raise jio.FileFormatError(
                f"{result.problem!r}'s trajectory does not fit the robot {result.robot!r} its result names: {name} has shape {shape}, "
                f"the robot wants (knots, {width}) (a result.json whose model names another robot than the one solved?)"
            )
    return robot


def _finish(fig, path):
    for ax in fig.axes:
        for line in ax.get_lines():
            if len(line.get_xdata()) == 1 and line.get_marker() in ("None", "", None):
                line.set_marker("o")  # a trajectory of one knot: a line through one point draws nothing
    if path is None:
        return fig
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    jio.save_figure(fig, path, dpi=110)
    return path


def plot_comparison(directory: str | Path, path: str | Path | None = None):
    """The motions of a ``jtraj compare`` folder side by side: one column per
    parameterization, two rows per task (base position; accumulated base rotation), titled
    with each run's outcome and iterations. Runs without a saved trajectory, with an unreadable
    one, or with one that is not the table's run (a folder left by an earlier run: other outcome
    or iterations) are left blank, their title saying which; where no cell has a trajectory
    (``jtraj compare --no-trajectories``) it raises `jtraj.io.FileFormatError`. Returns the figure, or writes it to
    ``path`` and returns the path. A table_iv.json that is not a list of rows with ``task`` and
    ``parameterization`` raises `jtraj.io.FileFormatError` naming it."""
    directory = Path(directory)
    table = directory / "table_iv.json"
    if not table.is_file():
        raise FileNotFoundError(f"{directory}: no table_iv.json (expected a folder written by `jtraj compare`)")
    rows = jio.read_json(table)
    if not (isinstance(rows, list) and rows and all(isinstance(r, dict) and isinstance(r.get("task"), str) and isinstance(r.get("parameterization"), str) for r in rows)):
        raise jio.FileFormatError(f"{table}: expected a non-empty list of Table IV rows, each with a task and a parameterization (as `jtraj compare` writes)")
    by_cell = {(r["task"], r["parameterization"]): r for r in rows}
    tasks = list(dict.fromkeys(r["task"] for r in rows))
    params = list(dict.fromkeys(r["parameterization"] for r in rows))
    fig = _figure(figsize=(3.2 * len(params), 2.3 * 2 * len(tasks)))
    axes = fig.subplots(2 * len(tasks), len(params), squeeze=False, sharex="row")
    legend = True  # on the first cell drawn, which a blank first column does not hold
    missing = 0  # cells without a trajectory
    for i, task in enumerate(tasks):
        for j, param in enumerate(params):
            top, bottom = axes[2 * i, j], axes[2 * i + 1, j]
            if j == 0:
                top.set_ylabel("base position (m)", fontsize=8)
                bottom.set_ylabel("rotation (deg)", fontsize=8)
            run = directory / f"{task}_{param}"
            row = by_cell.get((task, param))
            if row is None or not (run / "trajectory.npz").is_file():
                top.set_title(f"{task} [{param}]: no trajectory", fontsize=8)
                missing += 1
                continue
            try:
                result = Result.load(run)
            except jio.FileFormatError:
                top.set_title(f"{task} [{param}]: unreadable result", fontsize=8)
                continue
            # (the solver too: a cell of another solver with the same status and iterations was drawn)
            if (result.status.value, result.iterations, result.solver) != (row.get("status"), row.get("iterations"), row.get("solver", result.solver)):
                top.set_title(f"{task} [{param}]: saved run is not the table's", fontsize=8)
                continue
            t = result.trajectory
            if t is None:  # result.json saved without one beside an older trajectory.npz (load drops it)
                top.set_title(f"{task} [{param}]: no trajectory", fontsize=8)
                missing += 1
                continue
            touching = t.in_contact.any(axis=1)
            for ax in (top, bottom):
                _flight_shading(ax, t.t, touching)
            for k, name in enumerate("xyz"):
                top.plot(t.t, t.base_xyz_wxyz[:, k], lw=0.9, label=name)
            angles = np.degrees(np.asarray(accumulated_rotation(t.base_xyz_wxyz[:, 3:7])))
            for k, name in enumerate(("x", "y", "z")):
                bottom.plot(t.t, angles[:, k], lw=0.9, label=f"about {name}")
            top.set_title(f"{task} [{param}]: {result.status.value}, {result.iterations} it", fontsize=8)
            bottom.set_xlabel("time (s)", fontsize=8)
            if legend:
                top.legend(fontsize=6)
                bottom.legend(fontsize=6)
                legend = False
    if missing == len(tasks) * len(params):  # a figure of blank panels only, written as if it were one
        raise jio.FileFormatError(
            f"{table}: none of its {len(rows)} runs has a saved trajectory to draw "
            "(each cell's folder TASK_PARAM beside it; `jtraj compare --no-trajectories` writes only the tables)"
        )
    fig.suptitle("one column per parameterization (grey: flight)")
    fig.tight_layout()
    return _finish(fig, path)


def plot_directory(directory: str | Path, out: str | Path | None = None) -> list[Path]:
    """``jtraj plot DIR``: for a solution folder (``result.json`` + ``trajectory.npz``),
    ``solution.png`` (`jtraj.result.Result.plot`: `plot_solution`, or an attitude benchmark's
    own figure) and ``convergence.png``; for a ``jtraj compare`` folder
    (``table_iv.json``), ``comparison.png`` (`plot_comparison`). Written into ``out``
    (default ``directory``); returns the paths. A ``result.json`` saved without a trajectory
    raises `jtraj.io.FileFormatError` (``jtraj plot``: one line, exit status 2), which says
    when the ``trajectory.npz`` beside it is an earlier solve's."""
    directory = Path(directory)
    out = Path(out) if out is not None else directory
    if (directory / "table_iv.json").is_file():
        return [plot_comparison(directory, out / "comparison.png")]
    if not (directory / "result.json").is_file():
        raise FileNotFoundError(f"{directory}: neither result.json (a `jtraj solve` folder) nor table_iv.json (a `jtraj compare` folder)")
    result = Result.load(directory)
    if result.trajectory is None:
        raise jio.FileFormatError(f"{directory / 'result.json'}: saved without a trajectory, nothing to plot against time{stale_trajectory_note(directory)}")
    # Result.plot: the whole-body figure, or an attitude benchmark's own
    solution = out / "solution.png"
    result.plot(solution)
    return [solution, plot_convergence(result, out / "convergence.png")]
