"""The ``jtraj attitude`` command: one benchmark (solve, print, save its folder and figure) or
all of them (`jtraj.attitude.solve.compare_benchmarks`)."""

from __future__ import annotations

from pathlib import Path

from jtraj.attitude import benchmarks
from jtraj.attitude.benchmarks import BENCHMARKS, PAPER_ITERATIONS
from jtraj.attitude.solve import compare_benchmarks, result_directory, solve_benchmark
from jtraj.result import Outcome, Result

__all__ = ["main_attitude", "main"]

PLOT_FILE = "plot.png"


def main_attitude(bench: str, variant: str = "attitude", out_dir: str | Path | None = None, n_knots: int | None = None, solver: str = "ipopt") -> Result:
    """``jtraj attitude BENCH``: solve with live progress, print iterations, time, constraint
    violation and the benchmark's key numbers, save ``OUT/BENCH_VARIANT/`` (result.json,
    trajectory.npz, plot.png)."""
    out = Path(out_dir) if out_dir is not None else Path("runs") / "attitude"
    result = solve_benchmark(bench, variant, out=out, n_knots=n_knots, progress=True, solver=solver)
    folder = result_directory(out, result)
    result.plot(folder / PLOT_FILE)
    print(result.summary())
    for key in ("min_sun_angle_deg", "roll_turns", "roll_deg", "max_quaternion_norm_error"):
        if key in result.metrics:
            print(f"  {key}: {result.metrics[key]:.6g}")
    paper = PAPER_ITERATIONS.get(result.problem)
    if paper is not None:
        print(f"  paper (ALTRO) iterations naive/modified: {paper[0]}/{paper[1]}")
    print(f"wrote {folder}/result.json, trajectory.npz, {PLOT_FILE}")
    return result


def main(bench: str, variant: str, out_dir: str | Path, n_knots: int | None = None, solver: str = "ipopt", render: bool = False) -> int:
    """Exit status of ``jtraj attitude``, as ``jtraj solve``'s: 0 when every solve did the task,
    3 when every solve converged but one does not do it, 4 when one did not converge (2 stays a
    bad input's). With ``render``, one benchmark's motion is also drawn
    (`jtraj.render.render_benchmark`, which needs MuJoCo) into its folder."""
    from jtraj.cli import EXIT_NOT_CONVERGED, EXIT_TASK_FAILED, InputError

    # a knot count a benchmark refuses (too few, two quadflip waypoints on one knot, a satellite
    # step too long for RK4) is a bad input: one line and exit 2 before anything is solved
    if n_knots is not None:
        for name in BENCHMARKS if bench == "all" else (bench,):
            try:
                benchmarks.get(name, n_knots)
            except ValueError as e:
                raise InputError("--knots", n_knots, str(e)) from None
    if bench == "all":
        rows = compare_benchmarks(out_dir, n_knots=n_knots, solver=solver)
        statuses = {r["status"] for r in rows}
    else:
        result = main_attitude(bench, variant, out_dir, n_knots=n_knots, solver=solver)
        statuses = {result.status.value}
    code = 0 if statuses <= {Outcome.SOLVED.value} else EXIT_NOT_CONVERGED if Outcome.NOT_CONVERGED.value in statuses else EXIT_TASK_FAILED
    if bench != "all" and render:
        from jtraj.cli import _render_after_solve
        from jtraj.render import render_benchmark

        folder = result_directory(out_dir, result)
        if not _render_after_solve("attitude", lambda: render_benchmark(result, folder), str(folder)):
            return code or 1
    return code
