"""Experiments on a small Go2 task: vmapped noisy warm starts, the robustness study's files,
the Table IV writer, and the plots."""

import dataclasses
import inspect
import io
import json
import os
import re
import signal
import subprocess
import sys
import time
import types
import zlib
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest
from test_transcription import HOP

import jtraj.experiments as experiments
from jtraj.executors import WorkerLostError
from jtraj.experiments import RUN_KEY, RUNS_FILE, chart_noisy_warm_starts, compare, noisy_warm_starts, read_runs, robustness, run_key
from jtraj.plots import plot_convergence, plot_result
from jtraj.result import Outcome, Result
from jtraj.solvers import Status
from jtraj.success import FEASIBILITY_TOL


def test_noisy_warm_starts_are_vmapped_draws():
    x0 = np.arange(6.0)
    draws = noisy_warm_starts(x0, [1e-6, 0.5], replicates=400, seed=3)
    assert draws.shape == (2, 400, 6)
    dev = draws - x0
    np.testing.assert_allclose(dev[0].std(), 1e-6, rtol=0.1)
    np.testing.assert_allclose(dev[1].std(), 0.5, rtol=0.1)
    assert abs(dev[1].mean()) < 0.05
    # replicates differ, and a seed reproduces them
    assert not np.allclose(dev[1, 0], dev[1, 1])
    np.testing.assert_array_equal(draws, noisy_warm_starts(x0, [1e-6, 0.5], replicates=400, seed=3))


def _an_earlier_commands_record(folder):
    """A complete provenance.json of another command in ``folder``, as a reused folder has."""
    (folder / "provenance.json").write_text(json.dumps({"command": "jtraj robustness --replicates 7", "complete": True}))


def _this_calls_record(folder, function):
    """Called from Python, the sweeps wrote no provenance.json and left an earlier command's
    complete record beside their own tables; now it is this call's, the earlier one kept."""
    record = json.loads((folder / "provenance.json").read_text())
    assert record["complete"] is True and record["call"]["function"] == f"jtraj.experiments.{function}"
    assert [r["command"] for r in record["earlier"]] == ["jtraj robustness --replicates 7"]
    return record["call"]


def test_robustness_study_writes_tables_and_figure(tmp_path):
    _an_earlier_commands_record(tmp_path)
    runs = robustness([HOP], ["se3"], sigmas=[1e-6, 1e-2], replicates=2, out=tmp_path, progress=None)
    call = _this_calls_record(tmp_path, "robustness")
    # what decides the runs: the command of a Python call is the process's (a script's name, a
    # notebook kernel's launcher), and the folder kept neither the seed nor the replicates
    assert call["tasks"] == [{"name": "test_hop", "task_hash": HOP.content_hash()}] and call["params"] == ["se3"]
    assert (call["sigmas"], call["replicates"], call["seed"], call["solver"], call["variables"]) == ([1e-6, 1e-2], 2, 0, "ipopt", "paper")
    assert call["ipopt_options"] == {} and call["variables_hash"] == runs[0]["variables_hash"]
    assert len(runs) == 4
    summary = json.loads((tmp_path / "table_iii.json").read_text())
    assert [(r["sigma"], r["runs"]) for r in summary] == [(1e-6, 2), (1e-2, 2)]
    assert all(r["converged_rate"] == 1.0 and r["task_success_rate"] == 1.0 for r in summary)
    assert "| test_hop | se3 | 100% / 100% | 100% / 100% |" in (tmp_path / "table_iii.md").read_text()
    assert (tmp_path / "fig2.png").stat().st_size > 1000


def test_a_resumed_study_says_which_runs_other_code_solved(tmp_path, monkeypatch):
    """A study resumed after a change of code mixed two commits' runs in one table without a
    word, and no run said which code solved it. Each run records its source, and resuming runs
    of another commit (or of none recorded) says so."""
    import io as stdio

    first = {"commit": "a" * 40, "dirty": False}
    monkeypatch.setattr(experiments, "_code_source", lambda: first)
    runs = robustness([HOP], ["se3"], sigmas=[1e-3], replicates=1, seed=5, out=tmp_path, progress=None)
    assert runs[0]["source"] == first
    # and the device that solved it (a Ray worker's can differ from the caller's)
    import jax

    assert runs[0]["device"] == {"backend": jax.default_backend(), "devices": len(jax.devices()), "device_kind": jax.devices()[0].device_kind}
    said = stdio.StringIO()
    robustness([HOP], ["se3"], sigmas=[1e-3], replicates=1, seed=5, out=tmp_path, progress=said)
    assert "resuming: 1 of this call's 1 runs" in said.getvalue() and "note:" not in said.getvalue()  # the same commit
    monkeypatch.setattr(experiments, "_code_source", lambda: {"commit": "b" * 40, "dirty": True})
    said = stdio.StringIO()
    robustness([HOP], ["se3"], sigmas=[1e-3], replicates=1, seed=5, out=tmp_path, progress=said)
    assert f"note: 1 of the resumed runs were solved by other code ({'a' * 7}) than this call's ({'b' * 7} with changes), or code that may differ; their rows are kept" in said.getvalue()


def test_robustness_resumes_a_stopped_study(tmp_path):
    first = robustness([HOP], ["se3"], sigmas=[1e-3], replicates=1, seed=5, out=tmp_path, progress=None)
    more = robustness([HOP], ["se3"], sigmas=[1e-3], replicates=2, seed=5, out=tmp_path, progress=None)
    # the first run is kept as it was (same timing record), only replicate 1 is new
    assert [r["replicate"] for r in more] == [0, 1]
    assert more[0] == first[0]
    # a complete study solves nothing and still writes its tables
    (tmp_path / "table_iii.md").unlink()
    assert robustness([HOP], ["se3"], sigmas=[1e-3], replicates=2, seed=5, out=tmp_path, progress=None) == more
    assert "| test_hop | se3 | 100% / 100% |" in (tmp_path / "table_iii.md").read_text()
    # layout= (the former name of variables=) warns and names the same runs
    with pytest.warns(DeprecationWarning, match="layout="):
        assert robustness([HOP], ["se3"], sigmas=[1e-3], replicates=2, seed=5, out=tmp_path, progress=None, layout="paper") == more
    # another seed is another study: nothing is reused
    other = robustness([HOP], ["se3"], sigmas=[1e-3], replicates=1, seed=6, out=tmp_path, progress=None)
    assert len(other) == 1 and other[0]["seed"] == 6 and other[0]["time_s"] != first[0]["time_s"]
    # ... and the runs of seed 5 are still in the file
    assert {r["seed"] for r in read_runs(tmp_path / RUNS_FILE)} == {5, 6}


def test_robustness_does_not_resume_runs_whose_variables_changed_content(tmp_path, monkeypatch, capsys):
    """A run is keyed by what its variables were, not only their name: when "paper" comes to
    mean other options (as its Euler warm start once did), or a row does not say (a file
    written before jtraj recorded it), the run is solved again rather than taken as done."""
    import dataclasses

    from jtraj import solver as jsolver
    from jtraj.experiments import variables_hash

    kw = dict(sigmas=[1e-3], replicates=1, seed=11, out=tmp_path)
    first = robustness([HOP], ["se3"], progress=None, **kw)
    assert first[0]["variables_hash"] == variables_hash("paper") == variables_hash(jsolver.PAPER_VARIABLES)
    assert robustness([HOP], ["se3"], progress=None, **kw) == first  # resumed as it was
    # the same name with other content: another run
    changed = dataclasses.replace(jsolver.VARIABLES["paper"], warm_start_euler="matrix")
    assert variables_hash(changed) != variables_hash("paper")
    monkeypatch.setitem(jsolver.VARIABLES, "paper", changed)
    again = robustness([HOP], ["se3"], progress=None, **kw)
    assert again[0]["layout"] == "paper" and again[0]["variables_hash"] == variables_hash(changed)
    assert again[0]["time_s"] != first[0]["time_s"] and len(read_runs(tmp_path / RUNS_FILE)) == 2
    monkeypatch.undo()
    # a row without the content (an earlier version's) is kept in the file but not resumed
    old = {k: v for k, v in first[0].items() if k != "variables_hash"}
    (tmp_path / RUNS_FILE).write_text(json.dumps(old) + "\n")
    capsys.readouterr()
    redone = robustness([HOP], ["se3"], progress=sys.stdout, **kw)
    assert "1 runs in" in capsys.readouterr().out and redone[0]["variables_hash"] == variables_hash("paper")
    assert redone[0]["time_s"] != first[0]["time_s"] and len(read_runs(tmp_path / RUNS_FILE)) == 2


def test_robustness_keys_changed_variables_by_their_label(tmp_path):
    """A study with a TranscriptionOptions records it as its nearest named variables plus the
    changed fields, and those runs are not the named variables' runs."""
    from jtraj.solver import variables_label, with_changes

    rows_variables = with_changes("paper", {"force_limits": "rows"})
    assert variables_label(rows_variables) == "paper+force_limits=rows"
    assert variables_label(with_changes("paper", {"force_limits": "bounds"})) == "paper"
    runs = robustness([HOP], ["se3"], sigmas=[1e-3], replicates=1, variables=rows_variables, out=tmp_path, progress=None)
    assert [r["layout"] for r in runs] == ["paper+force_limits=rows"] and runs[0]["converged"]
    # the same study again reuses the run; the paper variables' study solves its own
    assert robustness([HOP], ["se3"], sigmas=[1e-3], replicates=1, variables=rows_variables, out=tmp_path, progress=None) == runs
    paper = robustness([HOP], ["se3"], sigmas=[1e-3], replicates=1, out=tmp_path, progress=None)
    assert paper[0]["layout"] == "paper" and len(read_runs(tmp_path / RUNS_FILE)) == 2


@pytest.mark.parametrize(
    ("exact_hessian", "options", "label"),
    [
        (False, None, "limited-memory"),
        (True, None, "exact"),
        # the solver options were not looked at: these runs were keyed "limited-memory"
        (False, {"hessian_approximation": "exact"}, "exact"),
        (False, {"hessian_approximation": "EXACT"}, "exact"),
        (False, {"hessian": "exact"}, "exact"),
        (False, {"hessian": "bfgs"}, "bfgs"),
        (False, {"hessian": "lbfgs", "tol": 1e-4}, "limited-memory"),
    ],
)
def test_robustness_keys_runs_by_the_hessian_they_solve_with(exact_hessian, options, label):
    from jtraj.experiments import _group_key

    assert _group_key(HOP, "se3", "paper", exact_hessian, options, 0, "jtraj")["hessian"] == label


@pytest.mark.parametrize("sigma", [-0.1, float("nan"), float("inf")])
def test_robustness_refuses_a_noise_level_that_is_no_standard_deviation(sigma, tmp_path):
    with pytest.raises(ValueError, match=r"robustness: sigma=.*: expected noise levels \(standard deviations\) >= 0"):
        robustness([HOP], ["se3"], sigmas=[0.1, sigma], replicates=1, out=tmp_path / "study", progress=False)
    assert not (tmp_path / "study").exists()  # refused before anything is written or solved


def test_noise_of_a_run_does_not_depend_on_the_other_runs():
    x0 = np.zeros(5)
    a = noisy_warm_starts(x0, [1e-3, 0.1], replicates=2, seed=4)
    b = noisy_warm_starts(x0, [0.5, 0.1, 1e-3], replicates=3, seed=4)
    np.testing.assert_array_equal(a[1], b[1, :2])  # sigma 0.1, replicates 0 and 1
    np.testing.assert_array_equal(a[0], b[2, :2])
    np.testing.assert_array_equal(b[1, 2], noisy_warm_starts(x0, [0.1], replicates=[2], seed=4)[0, 0])
    assert not np.allclose(a[1, 0] / 0.1, a[0, 0] / 1e-3)  # levels are not one draw rescaled


def test_noise_drawn_in_another_chart_gives_the_same_noisy_poses():
    """``noise_chart``: a quaternion chart given SE(3)'s draws starts from SE(3)'s noisy poses
    (same base poses knot by knot, every other variable the same numbers), its own chart's
    name is its own draws, and a name that is not a chart is refused."""
    from jtraj import robot as robots
    from jtraj.parameterization import get
    from jtraj.transcription import PAPER_VARIABLES, Transcription

    go2 = robots.load("go2")
    se3, quat = (Transcription(go2, HOP, get(p), PAPER_VARIABLES) for p in ("se3", "quat1"))
    src = noisy_warm_starts(se3.warm_start(), [0.3], [0, 4], seed=2)[0]
    got = chart_noisy_warm_starts(quat, "se3", [0.3], [0, 4], seed=2)[0]
    assert got.shape == (2, *quat.warm_start().shape)
    # a given source transcription (reused across charts by the study's check) draws the same
    np.testing.assert_array_equal(chart_noisy_warm_starts(quat, "se3", [0.3], [0, 4], seed=2, source=se3)[0], got)
    with pytest.raises(ValueError, match="source is a quat1 transcription"):
        chart_noisy_warm_starts(se3, "euler", [0.3], 1, source=quat)
    qa, qb = se3.layout.slice("q"), quat.layout.slice("q")
    pose = lambda tr, x: np.stack([tr.param.to_pose(jnp.asarray(k[: tr.param.nq])).as_matrix() for k in x[:, tr.layout.slice("q")]])
    for a, b in zip(src, got):
        np.testing.assert_allclose(pose(quat, b), pose(se3, a), atol=1e-12)
        np.testing.assert_array_equal(b[:, qb][:, quat.param.nq :], a[:, qa][:, se3.param.nq :])  # joint angles
        for name, _ in quat.layout.slots:
            if name != "q":
                np.testing.assert_array_equal(b[:, quat.layout.slice(name)], a[:, se3.layout.slice(name)])
    # the noise turned the poses: the quaternion chart's own draws are other poses
    own = chart_noisy_warm_starts(quat, None, [0.3], [0, 4], seed=2)[0]
    np.testing.assert_array_equal(own, chart_noisy_warm_starts(quat, "quat1", [0.3], [0, 4], seed=2)[0])
    np.testing.assert_array_equal(own, noisy_warm_starts(quat.warm_start(), [0.3], [0, 4], seed=2)[0])
    assert not np.allclose(pose(quat, own[0]), pose(se3, src[0]), atol=1e-3)
    with pytest.raises(ValueError, match="noise_chart='quat4'"):
        chart_noisy_warm_starts(quat, "quat4", [0.3], 1)


def test_noise_of_a_turning_warm_start_in_another_chart():
    """A warm start that turns the base once: written from SE(3)'s poses, a quaternion chart's
    keeps each knot's sign of rho along the turn (noise-free, its own warm start); the Euler
    chart's, whose angles wind through the turn as the study's scripts write them, cannot be
    written from poses, and is refused (`check_noise_chart` too, before anything compiles)."""
    import dataclasses

    from jtraj import robot as robots
    from jtraj.experiments import NoiseChartError, check_noise_chart
    from jtraj.parameterization import get
    from jtraj.task import Phase, Profile, RotationRule
    from jtraj.transcription import PAPER_VARIABLES, Transcription

    turn = dataclasses.replace(
        HOP, phases=(HOP.phases[0], Phase((), 0.4), HOP.phases[2]), warm_start_rules=(RotationRule(Profile.RAMP, (0.0, 1.0, 0.0), -2 * np.pi, (1,)),)
    )
    go2 = robots.load("go2")
    quat = Transcription(go2, turn, get("quat1"), PAPER_VARIABLES)
    clean = chart_noisy_warm_starts(quat, "se3", [0.0], 1)[0, 0]
    np.testing.assert_allclose(clean, quat.warm_start(), atol=1e-9)
    rho = clean[:, quat.layout.slice("q")][:, 3:7]
    assert (rho[:, 0] < 0).any()  # the turn passes rho through -rho's half
    with pytest.raises(NoiseChartError, match="not the euler warm start"):
        chart_noisy_warm_starts(Transcription(go2, turn, get("euler"), PAPER_VARIABLES), "se3", [0.1], 1)
    with pytest.raises(NoiseChartError, match="not the euler warm start"):
        check_noise_chart([turn], ["quat1", "euler"], "paper", "se3")
    check_noise_chart([turn], ["quat1", "se3"], "paper", "se3")  # the chart itself is not checked


def test_robustness_keys_runs_by_the_chart_of_their_noise(tmp_path, monkeypatch):
    """Euler runs with SE(3)'s noise are other runs than with Euler's own (their rows say so and
    the table names the chart); the chart's own name is its own noise, resumed as such."""
    kw = dict(sigmas=[1e-3], replicates=1, seed=3, out=tmp_path, progress=None)
    [own] = robustness([HOP], ["euler"], **kw)
    [other] = robustness([HOP], ["euler"], noise_chart="se3", **kw)
    assert own["noise_chart"] is None and other["noise_chart"] == "se3" and other["time_s"] != own["time_s"]
    assert other["converged"] and other["constraint_violation"] < FEASIBILITY_TOL
    assert "coordinates of SE(3)" in (tmp_path / "table_iii.md").read_text()
    assert len(read_runs(tmp_path / RUNS_FILE)) == 2
    assert robustness([HOP], ["euler"], noise_chart="euler", **kw) == [own]  # resumed, not solved
    assert "coordinates of" not in (tmp_path / "table_iii.md").read_text()
    assert robustness([HOP], ["euler"], noise_chart="se3", **kw) == [other]
    with pytest.raises(ValueError, match="noise_chart='xyz'"):
        robustness([HOP], ["euler"], noise_chart="xyz", **kw)
    # one run of the study solved again alone, with its trajectory
    from jtraj import solve

    again = solve(HOP, "euler", variables="paper", noise=1e-3, seed=3, replicate=0, noise_chart="se3", progress=None)
    assert again.iterations == other["iterations"] and again.trajectory is not None
    np.testing.assert_allclose(again.cost, other["cost"], rtol=1e-9, atol=1e-12)
    # a solve that stops short says why, after its summary
    stream = io.StringIO()
    short = solve(HOP, "euler", variables="paper", options={"max_iter": 1}, progress=stream, keep_trajectory=False)
    assert not short.converged and short.solver_status is Status.MAX_ITER
    summary, why = stream.getvalue().splitlines()[-3:-1]
    assert summary == short.summary()
    assert why == f"  ipopt stopped: max_iter ({Status.MAX_ITER.message})"
    # and a converged solve whose motion fails the task check says what the check found
    import jtraj.solver
    from jtraj.success import TaskCheck

    monkeypatch.setattr(jtraj.solver, "check_motion", lambda *a: TaskCheck(False, None, 0.9, None, "the base turns 0.90 turns in all"))
    stream = io.StringIO()
    failed = solve(HOP, "euler", variables="paper", progress=stream, keep_trajectory=False)
    assert failed.converged and failed.status.value == "converged_but_task_failed"
    assert stream.getvalue().splitlines()[-1] == "  task check failed: the base turns 0.90 turns in all"
    monkeypatch.undo()
    with pytest.raises(ValueError, match="without warm_start= and theta="):
        solve(HOP, "euler", variables="paper", noise=1e-3, replicate=0, theta={"friction": 0.5}, progress=None)
    with pytest.raises(ValueError, match="needs replicate="):
        solve(HOP, "euler", variables="paper", noise=1e-3, noise_chart="se3", progress=None)


def test_summary_keeps_solvers_and_noise_charts_apart(tmp_path, monkeypatch):
    """One runs file can hold a cell's runs with two solvers and two noise charts (their keys
    differ): the summary, the table and the figure keep them apart and say which is which;
    a file of one setting keeps the plain parameterization."""
    from jtraj.experiments import _table_iii_markdown, plot_iterations, setting_label, summarize_robustness

    def run(solver, chart, converged, iterations):
        return dict(task="walk", parameterization="quat1", sigma=0.5, solver=solver, noise_chart=chart, converged=converged, constraint_violation=1e-9, success=converged, iterations=iterations)

    runs = [run("ipopt", None, True, 30), run("ipopt", None, False, 50), run("ipopt", "se3", True, 20), run("ipopt", "se3", True, 24), run("jtraj", "se3", False, 50)]
    summary = summarize_robustness(runs)
    got = {(r["solver"], r["noise_chart"]): (r["runs"], r["converged_rate"], r["iterations_median"]) for r in summary}
    assert got == {("ipopt", None): (2, 0.5, 30.0), ("ipopt", "se3"): (2, 1.0, 22.0), ("jtraj", "se3"): (1, 0.0, None)}
    assert [setting_label(r, summary) for r in summary] == ["quat1 (ipopt, noise in own chart)", "quat1 (ipopt, noise in se3)", "quat1 (jtraj, noise in se3)"]
    table = _table_iii_markdown(summary, [0.5])
    assert "| walk | quat1 (ipopt, noise in own chart) | 50% / 50% |" in table and "| walk | quat1 (ipopt, noise in se3) | 100% / 100% |" in table
    import jtraj.experiments as experiments
    from jtraj.parameterization import PARAMETERIZATIONS

    figures = []
    save = experiments.jio.save_figure

    def keep_and_save(fig, path, **kwargs):
        figures.append(fig)
        return save(fig, path, **kwargs)

    monkeypatch.setattr(experiments.jio, "save_figure", keep_and_save)
    plot_iterations(runs, tmp_path / "fig2.png")
    assert (tmp_path / "fig2.png").stat().st_size > 0 and len(figures) == 1
    (ax,) = figures[0].axes
    name = PARAMETERIZATIONS["quat1"].label
    # one line per setting with a converged run (jtraj's has none: named in the panel, and in the
    # legend, which lists every setting); medians 30 and 22 at sigma 0.5
    assert [t.get_text() for t in ax.get_legend().get_texts()] == [f"{name} (ipopt, noise in own chart)", f"{name} (ipopt, noise in se3)", f"{name} (jtraj, noise in se3)"]
    assert [tuple(line.get_ydata()) for line in ax.get_lines()] == [(30.0,), (22.0,)]
    # the own-chart median is of 1 of its 2 runs, and says so beside its point
    assert [t.get_text() for t in ax.texts] == ["1/2", f"{name} (jtraj, noise in se3): no converged run"]
    one = summarize_robustness(runs[:2])
    assert len(one) == 1 and setting_label(one[0], one) == "quat1" and "| walk | quat1 | 50% / 50% |" in _table_iii_markdown(one, [0.5])
    old = [{k: v for k, v in r.items() if k not in ("solver", "noise_chart")} for r in runs[:2]]  # rows of earlier files
    assert [(r["solver"], r["noise_chart"]) for r in summarize_robustness(old)] == [("ipopt", None)]


def test_table_iii_refuses_a_cell_whose_runs_come_from_different_settings():
    """A runs.jsonl keeps the runs of earlier settings beside a study's (another seed, options,
    Hessian...); Table III of the file's rows counted them in one cell, over a mixed
    denominator. A field an earlier file did not record matches any value."""
    from jtraj.experiments import summarize_robustness, table_iii

    def run(seed, converged, **more):
        return dict(task="walk", parameterization="se3", sigma=0.1, converged=converged, constraint_violation=1e-9, success=converged, iterations=20, seed=seed, **more)

    with pytest.raises(ValueError, match=r"^Table III: the runs of walk / se3 at sigma 0.1 differ in seed \(0, 7\); expected one setting's runs per cell"):
        table_iii([run(0, True), run(7, False)])
    with pytest.raises(ValueError, match=r"differ in options_hash \(a, b\)"):
        summarize_robustness([run(0, True, options_hash="a"), run(0, True, options_hash="b")])
    (row,) = summarize_robustness([run(0, True, robot_hash="r1"), run(0, False)])  # the second's robot not recorded
    assert row["runs"] == 2 and row["converged_rate"] == 0.5
    # but one replicate twice is two settings' runs: a study resumed beside runs written before
    # the hashes were recorded solved them again, and the cell counted both (20 runs of 10)
    with pytest.raises(ValueError, match=r"^Table III: the runs of walk / se3 at sigma 0.1 hold replicate\(s\) \[0\] more than once"):
        summarize_robustness([run(0, True, replicate=0, variables_hash="v1"), run(0, False, replicate=0), run(0, True, replicate=1, variables_hash="v1")])
    # and names the public way to select one setting's runs (the message said "select them
    # first", and the only selection was private)
    from jtraj.experiments import select_runs

    mixed = [run(0, True), run(7, False), run(0, False, solver="jtraj")]
    with pytest.raises(ValueError, match=r"select_runs\(runs, seed=7\), the setting of the last run"):
        table_iii(mixed[:2])
    assert select_runs(mixed, seed=0) == [mixed[0], mixed[2]]
    assert select_runs(mixed, seed=0, solver="ipopt") == [mixed[0]]  # (a row without a solver is an Ipopt run)
    assert "| walk | se3 |" in table_iii(select_runs(mixed, seed=7))
    with pytest.raises(ValueError, match=r"^select_runs: sede: not a field of a run; expected some of task_hash"):
        select_runs(mixed, sede=0)


def test_table_iii_counts_a_converged_run_only_when_it_is_feasible():
    """The paper's Table III success is "converged to a feasible point": a run the solver calls
    converged with a violation at or over `FEASIBILITY_TOL` is not counted, nor are its
    iterations."""
    from jtraj.experiments import _table_iii_markdown, summarize_robustness
    from jtraj.success import FEASIBILITY_TOL

    def run(violation, iterations):
        return dict(task="walk", parameterization="se3", sigma=0.1, converged=True, constraint_violation=violation, success=True, iterations=iterations)

    runs = [run(1e-9, 20), run(0.5 * FEASIBILITY_TOL, 30), run(FEASIBILITY_TOL, 40), run(2 * FEASIBILITY_TOL, 50)]
    (row,) = summarize_robustness(runs)
    assert (row["converged_rate"], row["task_success_rate"], row["iterations_median"]) == (0.5, 0.5, 25.0)
    assert "| walk | se3 | 50% / 50% |" in _table_iii_markdown([row], [0.1])
    (row,) = summarize_robustness([run(2 * FEASIBILITY_TOL, 50)])
    assert (row["converged_rate"], row["iterations_median"]) == (0.0, None)


def test_table_iii_never_rounds_a_failure_away():
    """Whole percent read 399 of 400 as "100%" and 1 of 400 as "0%": a cell with one failed run,
    or one jump counted as a flip, showed the same two rates."""
    from jtraj.experiments import _table_iii_markdown, summarize_robustness

    def cell(done: list[bool]) -> str:
        runs = [dict(task="walk", parameterization="se3", sigma=0.1, converged=True, constraint_violation=1e-9, success=ok, iterations=20) for ok in done]
        return next(line for line in _table_iii_markdown(summarize_robustness(runs), [0.1]).splitlines() if line.startswith("| walk"))

    assert cell([True] * 399 + [False]) == "| walk | se3 | 100% / >99% |"
    assert cell([False] * 399 + [True]) == "| walk | se3 | 100% / <1% |"
    assert cell([True] * 7 + [False] * 3) == "| walk | se3 | 100% / 70% |"
    assert cell([True] * 199 + [False]) == "| walk | se3 | 100% / >99% |"  # 99.5 % rounds to 100 %
    assert cell([True] * 399 + [False] * 401).endswith("/ 50% |")  # 49.875 %: not at the ends


def test_fig2_gives_each_setting_one_colour_in_every_panel(tmp_path, monkeypatch):
    """Fig. 2: a setting keeps its colour and marker across tasks even where another setting has
    no converged run (the colours used to follow each panel's own cycle); one legend lists every
    setting (here all three are drawn on the walk); sigma 0 is drawn (a symmetric log axis), not
    dropped off a log axis."""
    import jtraj.experiments as experiments
    from jtraj.experiments import plot_iterations

    def run(task, p, sigma, converged, iterations):
        return dict(task=task, parameterization=p, sigma=sigma, converged=converged, constraint_violation=1e-9, success=converged, iterations=iterations)

    runs = [run("walk", p, s, True, 20 + i) for i, p in enumerate(("se3", "quat1", "euler")) for s in (0.0, 0.1)]
    runs += [run("backflip", "se3", s, True, 30) for s in (0.0, 0.1)] + [run("backflip", "quat1", s, False, 200) for s in (0.0, 0.1)]
    runs += [run("backflip", "euler", s, True, 40) for s in (0.0, 0.1)]
    figures = []
    save = experiments.jio.save_figure
    monkeypatch.setattr(experiments.jio, "save_figure", lambda fig, path, **k: (figures.append(fig), save(fig, path, **k))[1])
    plot_iterations(runs, tmp_path / "fig2.png")
    walk, backflip = figures[0].axes[:2]
    colour = {line.get_label(): (line.get_color(), line.get_marker()) for line in walk.get_lines()}
    assert len(set(colour.values())) == 3
    for line in backflip.get_lines():  # Euler's line on the back-flip is Euler's colour, not Quaternion #1's
        assert (line.get_color(), line.get_marker()) == colour[line.get_label()]
    assert [line.get_label() for line in backflip.get_lines()] == [walk.get_lines()[0].get_label(), walk.get_lines()[2].get_label()]
    assert [t.get_text() for t in walk.get_legend().get_texts()] == list(colour) and backflip.get_legend() is None
    assert walk.get_xscale() == "symlog" and list(walk.get_lines()[0].get_xdata()) == [0.0, 0.1]


def test_fig2_shows_failed_settings_and_noise_levels(tmp_path, monkeypatch):
    """Fig. 2 drew a setting with no converged run in a panel nowhere (not even in the legend),
    and bridged a noise level where none converged with its line and band, as if it had data:
    the line now breaks there (NaN) and the band with it, and the failed setting is named in the
    panel in its own colour and in the legend with its colour and marker."""
    import matplotlib.colors as mcolors

    import jtraj.experiments as experiments
    from jtraj.experiments import plot_iterations
    from jtraj.parameterization import PARAMETERIZATIONS

    sigmas = (1e-6, 1e-3, 0.1, 0.5)

    def run(task, p, sigma, converged, r):
        return dict(task=task, parameterization=p, sigma=sigma, replicate=r, converged=converged, constraint_violation=1e-9 if converged else 1.0, success=converged, iterations=50 + r)

    # the walk: both converge everywhere; the back-flip: se3 not at sigma 0.1, quat1 nowhere
    runs = [run("walk", p, s, True, r) for p in ("se3", "quat1") for s in sigmas for r in range(3)]
    runs += [run("backflip", "se3", s, s != 0.1, r) for s in sigmas for r in range(3)] + [run("backflip", "quat1", s, False, r) for s in sigmas for r in range(3)]
    figures = []
    save = experiments.jio.save_figure
    monkeypatch.setattr(experiments.jio, "save_figure", lambda fig, path, **k: (figures.append(fig), save(fig, path, **k))[1])
    plot_iterations(runs, tmp_path / "fig2.png")
    walk, backflip = figures[0].axes
    se3, quat1 = PARAMETERIZATIONS["se3"].label, PARAMETERIZATIONS["quat1"].label
    (line,) = backflip.get_lines()
    assert line.get_label() == se3 and list(line.get_xdata()) == list(sigmas)
    assert np.isnan(line.get_ydata()).tolist() == [False, False, True, False]
    (band,) = backflip.collections
    assert len(band.get_paths()) == 2  # 1e-6 to 1e-3, and 0.5 alone: nothing across 0.1
    colour = {line.get_label(): (line.get_color(), line.get_marker()) for line in walk.get_lines()}
    (note,) = backflip.texts
    assert note.get_text() == f"{quat1}: no converged run" and mcolors.same_color(note.get_color(), colour[quat1][0])
    legend = walk.get_legend()
    assert [t.get_text() for t in legend.get_texts()] == [se3, quat1] and backflip.get_legend() is None
    assert [(h.get_color(), h.get_marker()) for h in legend.legend_handles] == [colour[se3], colour[quat1]]
    assert not walk.texts


def test_fig2_says_how_many_runs_each_median_holds(tmp_path, monkeypatch):
    """Fig. 2's medians are of the converged runs alone, and nothing said how many: a point of
    one converged run in ten looked like one of ten (the Euler back-flip's line fell from 148 to
    103 iterations on 2 of 10 runs). Such points are labelled, and the axis says whose runs."""
    import jtraj.experiments as experiments
    from jtraj.experiments import plot_iterations

    def run(sigma, converged, r):
        return dict(task="walk", parameterization="se3", sigma=sigma, replicate=r, converged=converged, constraint_violation=1e-9 if converged else 1.0, success=converged, iterations=20 + r)

    runs = [run(1e-3, True, r) for r in range(3)] + [run(0.1, r == 0, r) for r in range(3)] + [run(0.5, False, r) for r in range(3)]
    figures = []
    save = experiments.jio.save_figure
    monkeypatch.setattr(experiments.jio, "save_figure", lambda fig, path, **k: (figures.append(fig), save(fig, path, **k))[1])
    plot_iterations(runs, tmp_path / "fig2.png")
    (ax,) = figures[0].axes
    assert [(t.get_text(), t.xy) for t in ax.texts] == [("1/3", (0.1, 20.0))]  # not at 1e-3 (3/3), none where none converged
    assert ax.get_ylabel() == "iterations to convergence\n(converged runs)"


def test_fig2_axis_holds_every_noise_level(tmp_path, monkeypatch):
    """A largest sigma where no setting converged was off the axis (it was autoscaled from the
    converged medians alone): the figure showed no sign of that noise level."""
    import jtraj.experiments as experiments
    from jtraj.experiments import plot_iterations

    def run(p, sigma, converged, r):
        return dict(task="hop", parameterization=p, sigma=sigma, replicate=r, converged=converged, constraint_violation=1e-9 if converged else 1.0, success=converged, iterations=12 + r)

    runs = [run(p, s, s < 0.5, r) for p in ("se3", "quat1") for s in (1e-3, 0.5) for r in range(2)]
    runs += [dict(run("se3", 0.5, False, 0), task="walk")]  # a panel with no converged run at all
    figures = []
    save = experiments.jio.save_figure
    monkeypatch.setattr(experiments.jio, "save_figure", lambda fig, path, **k: (figures.append(fig), save(fig, path, **k))[1])
    plot_iterations(runs, tmp_path / "fig2.png")
    axes = {ax.get_title(): ax for ax in figures[0].axes}
    for ax, sigmas in ((axes["hop"], (1e-3, 0.5)), (axes["walk"], (0.5,))):
        lo, hi = ax.get_xlim()
        assert all(lo < s < hi for s in sigmas), (ax.get_title(), lo, hi)
    assert axes["walk"].get_ylim()[0] >= 0.0 and axes["hop"].get_ylim()[0] > 0.0  # no negative iterations


#: the result fields of a run that the tables read (`read_runs` sets aside rows without them)
_RESULT = {"converged": True, "constraint_violation": 0.0, "success": True, "iterations": 12}


def test_corrupt_runs_file_is_moved_aside(tmp_path, capsys):
    path = tmp_path / RUNS_FILE
    good = {"task_hash": "h", "parameterization": "se3", "layout": "paper", "hessian": "limited-memory", "options_hash": "o", "seed": 0, "sigma": 0.1, "replicate": 0, "task": "t"} | _RESULT
    path.write_text(json.dumps(good) + "\n" + json.dumps(good | {"replicate": 0, "cost": 2.0}) + "\n" + '{"task_hash": "h", "param')
    runs = read_runs(path, repair=True)  # the warning goes to the sys.stderr of the call (capsys's here)
    assert runs == [good]  # the duplicate key is read once, the torn line dropped
    assert "line(s) [3] did not parse" in capsys.readouterr().err
    assert (tmp_path / f"{RUNS_FILE}.corrupt-1").read_text().endswith('"param')
    assert read_runs(path, repair=True) == [good] and not (tmp_path / f"{RUNS_FILE}.corrupt-2").exists()


def test_reading_a_runs_file_does_not_change_it(tmp_path, capsys):
    """read_runs, the public reader (the robustness notebook's), replaced a file with a torn
    line by its good lines: read while a study appended to it, the line being written and
    every run appended before the replacement were lost from the study's file. Only the
    sweeps, which hold their folder, repair it (``repair=True``)."""
    path = tmp_path / RUNS_FILE
    good = {"task_hash": "h", "parameterization": "se3", "layout": "paper", "hessian": "limited-memory", "options_hash": "o", "seed": 0, "sigma": 0.1, "replicate": 0, "task": "t"} | _RESULT
    being_written = json.dumps(good)[:-1] + "\n" + json.dumps(good | {"replicate": 1})[:40]
    path.write_text(json.dumps(good) + "\n" + being_written)
    before = path.read_bytes()
    assert read_runs(path) == [good]
    assert "line(s) [2, 3] did not parse; its 1 good runs read, the file left as it is" in capsys.readouterr().err
    assert path.read_bytes() == before and not list(tmp_path.glob("*.corrupt-*"))
    with path.open("a") as f:  # the study finishes its line: nothing of it was lost
        f.write(json.dumps(good | {"replicate": 1})[40:] + "\n")
    assert read_runs(path) == [good, good | {"replicate": 1}]  # (its torn line 2 skipped)
    assert "line(s) [2] did not parse" in capsys.readouterr().err


_SWEEP = """
import sys
sys.path.insert(0, {tests!r})
from test_transcription import HOP
from jtraj.experiments import robustness
robustness([HOP], ["se3"], sigmas=[1e-3, 1e-2], replicates=2, seed=7, out={out!r}, progress=None)
"""


def _table(out):
    return (Path(out) / "table_iii.md").read_text(), json.loads((Path(out) / "table_iii.json").read_text())


def test_sweep_killed_midway_resumes_without_losing_or_repeating_runs(tmp_path):
    kw = dict(sigmas=[1e-3, 1e-2], replicates=2, seed=7, progress=None)
    whole = robustness([HOP], ["se3"], out=tmp_path / "whole", **kw)  # compiles; fills the cache
    out = tmp_path / "killed"
    runs_path = out / RUNS_FILE
    # the killed process must not share the compilation cache: JAX writes an entry in place,
    # and a kill in the middle of that write would leave a torn executable for later tests
    env = {**os.environ, "JTRAJ_NO_CACHE": "1"}
    proc = subprocess.Popen([sys.executable, "-c", _SWEEP.format(tests=str(Path(__file__).parent), out=str(out))], env=env)
    try:
        deadline = time.time() + 300
        while time.time() < deadline and proc.poll() is None:
            if runs_path.exists() and runs_path.read_bytes().count(b"\n") >= 1:
                break
            time.sleep(0.02)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait()
    at_kill = read_runs(runs_path)
    assert 1 <= len(at_kill) < 4, "the kill should land in the middle of the sweep"
    resumed = robustness([HOP], ["se3"], out=out, **kw)
    keys = [run_key(r) for r in resumed]
    assert len(keys) == len(set(keys)) == 4
    assert {run_key(r) for r in at_kill} <= set(keys)
    assert [run_key(r) for r in resumed] == [run_key(r) for r in whole]
    assert _table(out) == _table(tmp_path / "whole")
    lines = runs_path.read_text().splitlines()
    assert len(lines) == 4  # each run written once


def test_robustness_with_worker_processes_matches_in_process(tmp_path):
    kw = dict(sigmas=[1e-2], replicates=1, seed=2, progress=None, resume=False)
    serial = robustness([HOP], ["se3", "euler"], out=tmp_path / "a", **kw)
    parallel = robustness([HOP], ["se3", "euler"], out=tmp_path / "b", workers=2, **kw)
    key = lambda r: r["parameterization"]
    assert len(serial) == len(parallel) == 2
    for a, b in zip(sorted(serial, key=key), sorted(parallel, key=key)):
        assert (a["parameterization"], a["status"], a["iterations"]) == (b["parameterization"], b["status"], b["iterations"])
        np.testing.assert_allclose(a["cost"], b["cost"], rtol=1e-6)


def test_compare_writes_table_iv_and_plots(tmp_path, capsys):
    _an_earlier_commands_record(tmp_path)
    rows = compare([HOP], ["se3"], out=tmp_path)
    call = _this_calls_record(tmp_path, "compare")
    assert (call["tasks"], call["params"], call["solver"], call["variables"]) == ([{"name": "test_hop", "task_hash": HOP.content_hash()}], ["se3"], "ipopt", "paper")
    assert rows[0]["task"] == "test_hop" and rows[0]["converged"]
    # the default progress prints to the sys.stdout of the call (capsys's), not of the import
    assert "jtraj: test_hop on go2" in capsys.readouterr().out
    # the robot of each row (a task retargeted with --robot is solved on another)
    assert rows[0]["robot"] == "go2" and "| test_hop | go2 | se3 | solved |" in (tmp_path / "table_iv.md").read_text()
    result = Result.load(tmp_path / "test_hop_se3")
    assert json.loads((tmp_path / "test_hop_se3" / "provenance.json").read_text())["call"]["task"] == "test_hop"
    assert plot_result(result, tmp_path / "t.png").stat().st_size > 1000
    assert plot_convergence(result, tmp_path / "c.png").stat().st_size > 1000


def test_vmapped_draw_uses_the_key_of_each_run():
    import jax

    from jtraj.experiments import noise_key

    x0 = np.ones(4)
    draw = noisy_warm_starts(x0, [0.25], replicates=[3], seed=9)[0, 0]
    np.testing.assert_allclose(draw, x0 + 0.25 * np.asarray(jax.random.normal(noise_key(9, 0.25, 3), (4,))), rtol=1e-15)


# the study with jtraj's interior point: one vmapped solve per sigma, compiled once per module
JTRAJ_STUDY = dict(sigmas=[1e-3], replicates=3, seed=1, progress=None, solver="jtraj")


@pytest.fixture(scope="module")
def jtraj_study(tmp_path_factory):
    out = tmp_path_factory.mktemp("jtraj_study")
    return out, robustness([HOP], ["se3"], out=out, **JTRAJ_STUDY)


def test_jtraj_robustness_rows_record_the_batched_solve(jtraj_study):
    out, runs = jtraj_study
    assert [r["replicate"] for r in runs] == [0, 1, 2]
    assert {(r["solver"], r["batch"]) for r in runs} == {("jtraj", 3)}
    assert all(r["solver_status"] == "solved" and r["converged"] and r["constraint_violation"] < FEASIBILITY_TOL for r in runs)
    # one call's time, shared by its replicates
    assert len({r["time_s"] for r in runs}) == 1 and runs[0]["time_s"] > 0
    table = (out / "table_iii.md").read_text()
    assert "| test_hop | se3 | 100% / 100% |" in table and "success of the solver (jtraj)" in table


def test_ipopt_and_jtraj_runs_share_a_file_without_colliding(jtraj_study, tmp_path):
    out, runs = jtraj_study
    (tmp_path / RUNS_FILE).write_text((out / RUNS_FILE).read_text())
    ipopt = robustness([HOP], ["se3"], out=tmp_path, **(JTRAJ_STUDY | {"solver": "ipopt", "replicates": 1}))
    assert len(ipopt) == 1 and ipopt[0]["solver"] == "ipopt" and ipopt[0]["batch"] == 1
    assert set(ipopt[0]) == set(runs[0])  # the same fields
    i = RUN_KEY.index("solver")
    a, b = run_key(ipopt[0]), run_key(runs[0])
    assert a[:i] + a[i + 1 :] == b[:i] + b[i + 1 :] and a[i] != b[i]  # only the solver differs
    assert len(read_runs(tmp_path / RUNS_FILE)) == 4


def test_jtraj_batched_rows_equal_one_by_one_solves(jtraj_study):
    from jtraj import solve
    from jtraj.solver import prepare
    from jtraj.solvers import JtrajSolver

    _, runs = jtraj_study
    x0 = prepare(HOP, "se3", "paper").transcription.warm_start()
    starts = noisy_warm_starts(x0, JTRAJ_STUDY["sigmas"], JTRAJ_STUDY["replicates"], JTRAJ_STUDY["seed"])[0]
    assert len(runs) == len(starts) > 0  # zip below must not compare nothing
    for row, start in zip(runs, starts):
        one = solve(HOP, "se3", variables="paper", solver="jtraj", warm_start=start, progress=None, keep_trajectory=False)
        assert (one.solver_status.value, one.status.value, one.success) == (row["solver_status"], row["status"], row["success"])
        if JtrajSolver.default_strategy() == "threads":
            # on a CPU the batch runs each member in `solve`'s own program: the same iterations
            assert one.iterations == row["iterations"] and one.cost == row["cost"]
        else:
            # the vmapped program rounds differently (its history agrees to ~1e-12 for the first
            # iterations, then a line-search or golden-section comparison of nearly equal values
            # can differ and the iterates part: measured 16 against 14 iterations), so the
            # outcome is compared, and the counts to within a few iterations
            assert abs(one.iterations - row["iterations"]) <= 4


def test_jtraj_robustness_resumes_only_the_missing_replicates(jtraj_study, tmp_path, monkeypatch):
    from jtraj.solvers import JtrajSolver

    out, runs = jtraj_study
    lines = (out / RUNS_FILE).read_text().splitlines()
    # a complete study solves nothing
    monkeypatch.setattr(JtrajSolver, "solve_batch", lambda *a, **k: pytest.fail("a finished run was solved again"))
    assert robustness([HOP], ["se3"], out=out, **JTRAJ_STUDY) == runs
    monkeypatch.undo()
    # a study stopped after two replicates solves only the third (in the same compiled program;
    # a vmapped one is padded to the study's batch), with the same result as in the full batch
    (tmp_path / RUNS_FILE).write_text("\n".join(line for line in lines if json.loads(line)["replicate"] != 1) + "\n")
    solved = []
    original = JtrajSolver.solve_batch
    monkeypatch.setattr(JtrajSolver, "solve_batch", lambda self, nlp, x0s, *a, **k: solved.append(len(x0s)) or original(self, nlp, x0s, *a, **k))
    resumed = robustness([HOP], ["se3"], out=tmp_path, **JTRAJ_STUDY)
    assert solved == [1]
    assert [r["replicate"] for r in resumed] == [0, 1, 2] and resumed[1]["batch"] == 1
    assert (resumed[1]["iterations"], resumed[1]["solver_status"]) == (runs[1]["iterations"], runs[1]["solver_status"])
    assert resumed[0] == runs[0] and resumed[2] == runs[2]  # read back, not solved again


def test_jtraj_robustness_progress_counts_the_tables_converged_runs(jtraj_study, tmp_path, monkeypatch):
    """The batch's progress line counted the solver's own success, so a run converged to a
    violation over FEASIBILITY_TOL read as converged there and as failed in Table III."""
    original, seen = experiments.evaluate, []

    def first_infeasible(*args, **kwargs):
        res = original(*args, **kwargs)
        if not seen:
            res.constraint_violation = 10 * FEASIBILITY_TOL
        seen.append(res)
        return res

    monkeypatch.setattr(experiments, "evaluate", first_infeasible)
    stream = io.StringIO()
    runs = robustness([HOP], ["se3"], out=tmp_path, **(JTRAJ_STUDY | {"progress": stream}))
    assert all(r.converged for r in seen) and len(seen) == 3  # the solver's success, all three
    assert [experiments._converged(r) for r in runs] == [False, True, True]
    assert "jtraj: 2/3 converged" in stream.getvalue()


def test_rows_without_a_solver_are_ipopt_runs(tmp_path):
    old = {"task_hash": "h", "parameterization": "se3", "layout": "paper", "hessian": "limited-memory", "options_hash": "o", "seed": 0, "sigma": 0.1, "replicate": 0, "task": "t"} | _RESULT
    (tmp_path / RUNS_FILE).write_text(json.dumps(old) + "\n" + json.dumps(old | {"solver": "jtraj"}) + "\n")
    runs = read_runs(tmp_path / RUNS_FILE)
    assert len(runs) == 2  # the two solvers' runs do not collide
    assert run_key(runs[0]) == run_key(old | {"solver": "ipopt"}) != run_key(runs[1])


def test_prepare_releases_compiled_programs_near_the_memory_map_limit(monkeypatch):
    """Before it builds a new NLP, `prepare` frees what earlier ones compiled once the process
    holds more than half of the kernel's memory-map limit (a robustness study in one process
    met the limit at its 12th group and crashed in LLVM), and keeps them below that; a cached
    NLP needs nothing new."""
    from jtraj import solver

    class Released(Exception):
        pass

    def release():
        raise Released  # stops prepare before it builds anything

    held = solver.prepare(HOP, "se3", "paper")  # in the cache from here on
    # only that one: another test on this worker may have prepared HOP with quat2 already
    monkeypatch.setattr(solver, "_CACHE", {k: v for k, v in solver._CACHE.items() if v is held})
    monkeypatch.setattr(solver, "release_compiled", release)
    monkeypatch.setattr(solver, "memory_maps", lambda: (40000, 65530))
    assert solver.prepare(HOP, "se3", "paper") is held  # cached: no release
    with pytest.raises(Released):
        solver.prepare(HOP, "quat2", "paper")  # a new NLP, in a crowded process
    with pytest.raises(Released):
        solver.release_compiled_if_crowded()
    monkeypatch.setattr(solver, "memory_maps", lambda: (1000, 65530))
    assert solver.release_compiled_if_crowded() is False
    monkeypatch.setattr(solver, "memory_maps", lambda: None)  # a system that does not tell
    assert solver.release_compiled_if_crowded() is False


def test_release_compiled_forgets_prepared_nlps_and_jax_caches():
    import jax
    import jax.numpy as jnp

    from jtraj import solver

    held = solver.memory_maps()
    assert held is None or 0 < held[0] < held[1]
    f = jax.jit(lambda x: jnp.sin(x) + 1.0)
    f(jnp.ones(3))
    assert f._cache_size() == 1
    saved = dict(solver._CACHE)
    try:
        solver._CACHE[("a key",)] = object()
        solver.release_compiled()
        assert solver._CACHE == {} and f._cache_size() == 0
    finally:
        solver._CACHE.update(saved)  # the other tests' prepared NLPs (their programs compile again)


@pytest.mark.filterwarnings("error::UserWarning")  # Fig. 2 without a converged run draws no empty legend
def test_a_stopped_replicates_progress_line_says_why(tmp_path):
    stream = io.StringIO()
    robustness([HOP], ["euler"], sigmas=[1e-3], replicates=1, seed=3, out=tmp_path, progress=stream, ipopt_options={"max_iter": 1})
    [line] = [ln for ln in stream.getvalue().splitlines() if "#0:" in ln]
    assert line.endswith("  (ipopt: max_iter)") and "not_converged" in line
    assert (tmp_path / "fig2.png").stat().st_size > 0


def test_a_failed_cells_progress_line_says_why():
    from jtraj.experiments import _why

    row = {"status": "solved", "solver": "ipopt", "solver_status": "solved", "task_check": None}
    assert _why(row) == ""
    assert _why({**row, "status": "converged_but_task_failed", "task_check": "+0.00 turns about the flip axis; expected -1 +- 0.25"}) == "  (task check: +0.00 turns about the flip axis; expected -1 +- 0.25)"
    assert _why({**row, "status": "not_converged", "converged": False, "solver_status": "step_computation_failed"}) == "  (ipopt: step_computation_failed)"
    infeasible = {**row, "status": "not_converged", "converged": True, "constraint_violation": 0.02}
    assert _why(infeasible) == f"  (ipopt converged, but to a violation of 2.0e-02, over the feasibility tolerance {FEASIBILITY_TOL:g})"


# The sweeps' bookkeeping without compiles or solves: `fake_solves` replaces prepare, the noisy
# warm starts and solve in jtraj.experiments (in this process only: worker processes import the
# real ones), and `_StoppingExecutor` stands for worker processes that end partway.


def _fake_result(task, p):
    """What `jtraj.solve` returns, with the fields the sweeps' rows take."""
    loaded = experiments.load_task(task)
    name = loaded.name
    it = 10 + zlib.crc32(f"{name}{p}".encode()) % 20
    return types.SimpleNamespace(
        task=name, robot=loaded.robot, parameterization=p, solver="ipopt", status=Outcome.SOLVED, solver_status=Status.SOLVED, converged=True, success=True, turns=None, iterations=it,
        obj_evals=it + 1, grad_evals=it, con_evals=it, jac_evals=it, cost=1.0, constraint_violation=1e-9, time_s=0.01, time_compile=0.0, metrics={},
    )


@pytest.fixture
def fake_solves(monkeypatch):
    """The (task, parameterization, out) of every solve of a sweep, each answered at once."""
    solved = []

    def solve(task, p, out=None, **kwargs):
        solved.append((task, p, out))
        return _fake_result(task, p)

    monkeypatch.setattr(experiments, "prepare", lambda task, p, variables: types.SimpleNamespace(transcription=None, time_compile=0.0))
    monkeypatch.setattr(experiments, "chart_noisy_warm_starts", lambda tr, chart, levels, numbers, seed=0, source=None: np.zeros((len(levels), len(numbers), 1)))
    monkeypatch.setattr(experiments, "solve", solve)
    return solved


class _StoppingExecutor:
    """Runs the first ``finished`` groups in this process, then raises `WorkerLostError` (``lost``)
    or ends; ``closed`` says whether the caller closed the generator (what stops real workers)."""

    def __init__(self, finished: int, lost: bool = True):
        self.finished, self.lost, self.closed = finished, lost, False

    def map(self, fn, arg_list):
        try:
            for i in range(self.finished):
                yield i, fn(*arg_list[i])
            if self.lost:
                raise WorkerLostError("a worker process ended without finishing its group")
        finally:
            self.closed = True

    def stream(self, fn, arg_list):
        try:
            for i in range(self.finished):
                for item in fn(*arg_list[i]):
                    yield i, item
            if self.lost:
                raise WorkerLostError("a worker process ended without finishing its group")
        finally:
            self.closed = True


def test_compare_keeps_the_finished_cells_when_a_worker_is_lost(tmp_path, monkeypatch, fake_solves):
    executor = _StoppingExecutor(2)
    monkeypatch.setattr(experiments, "executor_for", lambda *args: executor)
    with pytest.raises(WorkerLostError, match=r"ended without finishing its group; .*table_iv.json holds the 2 of 3 cells finished before it$"):
        compare(["walk"], ["se3", "quat1", "euler"], out=tmp_path, progress=None, save_trajectories=False, workers=2)
    assert [r["parameterization"] for r in json.loads((tmp_path / "table_iv.json").read_text())] == ["se3", "quat1"]
    assert executor.closed


def test_compare_removes_the_figure_of_the_table_it_replaces(tmp_path, monkeypatch, fake_solves):
    """jtraj plot OUT's comparison.png of an earlier table stayed beside the new table_iv.json,
    showing parameterizations the new table does not hold."""
    (tmp_path / "comparison.png").write_bytes(b"the earlier table's")
    (tmp_path / "notes.txt").write_text("mine")
    compare(["walk"], ["euler"], out=tmp_path, progress=None, save_trajectories=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt", "provenance.json", "table_iv.json", "table_iv.md"]
    (tmp_path / "table_iv.md").unlink()
    (tmp_path / "table_iv.md").mkdir()  # refused before the first solve, not after the last
    with pytest.raises(ValueError, match=r"^compare: .*table_iv.md is a folder; expected room for the file table_iv.md$"):
        compare(["walk"], ["se3"], out=tmp_path, progress=None, save_trajectories=False)
    assert [p for _, p, _ in fake_solves] == ["euler"]


def test_compare_keeps_a_cell_whose_progress_line_failed(tmp_path, monkeypatch, fake_solves):
    """A cell that arrives as the progress stream breaks (a Ctrl-C that ended the `tee` of
    `jtraj compare | tee log`) is in the table: it was finished."""

    class Broken(io.StringIO):
        def write(self, text):
            if "\n" in self.getvalue():  # the second line
                raise BrokenPipeError("[Errno 32] Broken pipe")
            return super().write(text)

    executor = _StoppingExecutor(2, lost=False)
    monkeypatch.setattr(experiments, "executor_for", lambda *args: executor)
    with pytest.raises(BrokenPipeError) as e:
        compare(["walk"], ["se3", "quat1", "euler"], out=tmp_path, progress=Broken(), save_trajectories=False, workers=2)
    assert [r["parameterization"] for r in json.loads((tmp_path / "table_iv.json").read_text())] == ["se3", "quat1"]
    assert e.value.__notes__ == [f"{tmp_path / 'table_iv.json'} holds the 2 of 3 cells finished before it"]  # for the command line
    assert executor.closed


@pytest.mark.parametrize("executor", ["local", "ray"])
@pytest.mark.parametrize("resume", [True, False])
def test_robustness_says_where_the_runs_are_when_a_worker_is_lost(tmp_path, monkeypatch, fake_solves, executor, resume):
    """A lost worker's message says where the finished runs are and how to resume them, with
    either executor (a lost Ray worker's was not extended); without resume the same call would
    move them aside again: it says to resume (it said the same call again resumes)."""
    stopping = _StoppingExecutor(1)
    monkeypatch.setattr(experiments, "executor_for", lambda *args: stopping)
    again = "the same call again resumes from them" if resume else "the same call with resume=True (jtraj robustness without --no-resume) resumes from them"
    with pytest.raises(WorkerLostError, match=r"ended without finishing its group; the runs finished before it are kept in .*runs.jsonl, and " + re.escape(again) + "$"):
        robustness(["walk"], ["se3", "euler"], sigmas=[0.1], replicates=2, out=tmp_path, progress=None, resume=resume, executor=executor, workers=2 if executor == "local" else 1)
    assert len(read_runs(tmp_path / RUNS_FILE)) == 2 and stopping.closed


@pytest.mark.parametrize("sweep", ["compare", "robustness"])
def test_sweeps_hand_the_ray_gpus_to_the_executor_and_record_them(tmp_path, monkeypatch, fake_solves, sweep):
    """``ray_gpus`` reaches the Ray executor (Ray hides the GPUs from a task that reserves none)
    and the call's provenance."""
    made = []

    def executor_for(*args):
        made.append(args)
        return _StoppingExecutor(1, lost=False)

    monkeypatch.setattr(experiments, "executor_for", executor_for)
    if sweep == "compare":
        compare(["walk"], ["se3"], out=tmp_path, progress=None, save_trajectories=False, executor="ray", ray_gpus=0.5)
    else:
        robustness(["walk"], ["se3"], sigmas=[0.1], replicates=1, out=tmp_path, progress=None, executor="ray", ray_gpus=0.5)
    assert made and all(args[0] == "ray" and args[3] == 0.5 for args in made)
    assert json.loads((tmp_path / "provenance.json").read_text())["call"]["ray_gpus"] == 0.5


class _OtherMujocoExecutor(_StoppingExecutor):
    """Runs every group in this process as a worker whose MuJoCo compiles the robot to another
    model would: its `Robot.content_hash` (the runs' ``robot_hash``) differs from the caller's."""

    def __init__(self, monkeypatch):
        super().__init__(finished=0, lost=False)
        self.monkeypatch = monkeypatch

    def _as_worker(self, fn, args):
        with self.monkeypatch.context() as m:
            m.setattr(experiments, "_robot_hash", lambda name: "0123456789abcdef")
            return list(fn(*args)) if inspect.isgeneratorfunction(fn) else fn(*args)

    def map(self, fn, arg_list):
        for i, args in enumerate(arg_list):
            yield i, self._as_worker(fn, args)

    def stream(self, fn, arg_list):
        for i, args in enumerate(arg_list):
            for item in self._as_worker(fn, args):
                yield i, item


@pytest.mark.parametrize("executor", ["local", "ray"])
def test_robustness_refuses_a_worker_that_keys_runs_otherwise(tmp_path, monkeypatch, fake_solves, executor):
    """A worker (a Ray node with another MuJoCo) that keys its group's runs otherwise than the
    calling process is refused before it solves, naming the field: its rows were written under
    its keys, left out of the table without a word, and solved again by every resume."""
    monkeypatch.setattr(experiments, "executor_for", lambda *args: _OtherMujocoExecutor(monkeypatch))
    with pytest.raises(experiments.KeyMismatchError, match=r"^walk se3: this worker keys the group's runs otherwise than the process that called the sweep \(robot_hash '0123456789abcdef' here, '[0-9a-f]{16}' there\)"):
        robustness(["walk"], ["se3", "euler"], sigmas=[0.1], replicates=2, out=tmp_path, progress=None, executor=executor, workers=2 if executor == "local" else 1)
    assert fake_solves == [] and read_runs(tmp_path / RUNS_FILE) == []


@pytest.mark.parametrize("stop", [RuntimeError("boom"), KeyboardInterrupt()])
def test_robustness_on_ray_keeps_each_run_as_it_comes(tmp_path, monkeypatch, fake_solves, stop):
    """With the Ray executor each run's row comes back as it is solved (a streaming task), is
    appended to runs.jsonl and its progress line printed here: a group that fails, or an
    interrupt, keeps the runs solved before it. Rows came only when a group ended (a failing
    group's, or an interrupted one's, were lost, though the interrupt said they were kept), and
    nothing was printed."""
    from test_executors import _fake_ray

    monkeypatch.setitem(sys.modules, "ray", _fake_ray({}))
    solve = experiments.solve

    def stops_at_the_third(task, p, **kwargs):
        if len(fake_solves) == 2:
            raise stop
        return solve(task, p, **kwargs)

    monkeypatch.setattr(experiments, "solve", stops_at_the_third)
    stream = io.StringIO()
    with pytest.raises(type(stop)):
        robustness(["walk"], ["se3"], sigmas=[0.1], replicates=3, out=tmp_path, progress=stream, executor="ray")
    assert [r["replicate"] for r in read_runs(tmp_path / RUNS_FILE)] == [0, 1]
    it = _fake_result("walk", "se3").iterations
    assert stream.getvalue().splitlines() == [f"walk       se3    sigma=0.1     #{r}: {'solved':26s} {it:4d} it     0.0 s" for r in (0, 1)]


def test_robustness_keys_runs_by_the_names_of_solver_and_parameterization_objects(tmp_path, fake_solves):
    """A solver or parameterization object (or class) keyed the runs by the object while rows
    record the name: nothing was found again (no resume) and the call returned none of its
    runs. Each stands for its name; an unknown name is refused before anything is solved."""
    from jtraj.parameterization import PARAMETERIZATIONS
    from jtraj.solvers import IpoptSolver

    kw = dict(sigmas=[0.1], replicates=2, out=tmp_path, progress=None)
    first = robustness(["walk"], [PARAMETERIZATIONS["se3"]], solver=IpoptSolver, **kw)
    assert [(r["parameterization"], r["solver"], r["replicate"]) for r in first] == [("se3", "ipopt", 0), ("se3", "ipopt", 1)] and len(fake_solves) == 2
    assert robustness(["walk"], ["se3"], solver=IpoptSolver(), **kw) == first and len(fake_solves) == 2  # resumed
    with pytest.raises(ValueError, match=r"^robustness: params: 'quat9': unknown parameterization; expected some of se3, quat1, quat2, quat3, euler$"):
        robustness(["walk"], ["se3", "quat9"], **(kw | {"out": tmp_path / "other"}))
    with pytest.raises(ValueError, match=r"^robustness: params: 'se3' given 2 times; expected each parameterization once$"):
        robustness(["walk"], ["se3", PARAMETERIZATIONS["se3"]], **(kw | {"out": tmp_path / "other"}))
    assert len(fake_solves) == 2 and not (tmp_path / "other").exists()


def test_a_kill_while_a_damaged_runs_file_is_rewritten_keeps_it(tmp_path, monkeypatch, fake_solves):
    """read_runs moved a damaged runs.jsonl aside, then wrote its good lines back: a kill in
    between left no runs.jsonl, and the next call solved every run again. It copies the file
    aside and replaces it whole."""
    kw = dict(sigmas=[0.1], replicates=2, out=tmp_path, progress=None)
    robustness(["walk"], ["se3"], **kw)
    path = tmp_path / RUNS_FILE
    damaged = path.read_text() + '{"torn": \n'
    path.write_text(damaged)
    write_text = experiments.jio.write_text

    def killed(target, text):
        if Path(target) == path:
            raise KeyboardInterrupt  # the process killed as it writes the good lines back
        return write_text(target, text)

    monkeypatch.setattr(experiments.jio, "write_text", killed)
    with pytest.raises(KeyboardInterrupt):
        read_runs(path, io.StringIO(), repair=True)
    assert path.read_text() == damaged and (tmp_path / f"{RUNS_FILE}.corrupt-1").read_text() == damaged
    monkeypatch.setattr(experiments.jio, "write_text", write_text)
    fake_solves.clear()
    assert len(robustness(["walk"], ["se3"], **kw)) == 2 and not fake_solves  # nothing solved again


def test_compare_gives_each_cell_its_loaded_task_and_an_absolute_folder(tmp_path, monkeypatch, fake_solves):
    """A Ray worker runs in a folder of its own (a cluster started elsewhere): a relative task
    path and a relative out were resolved there (another file or none; cell folders outside
    OUT). Each cell gets its task as loaded by the sweep and its folder as an absolute path;
    a parameterization object stands for its name."""
    from importlib.resources import files

    from jtraj.parameterization import PARAMETERIZATIONS
    from jtraj.task import Task

    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "mywalk.toml").write_text(files("jtraj.tasks").joinpath("walk.toml").read_text())
    elsewhere = tmp_path / "worker"
    elsewhere.mkdir()

    class Elsewhere:
        """Runs each cell in the folder ``elsewhere``, as a Ray worker runs in its own."""

        def map(self, fn, arg_list):
            for i, args in enumerate(arg_list):
                here = os.getcwd()
                os.chdir(elsewhere)
                try:
                    result = fn(*args)
                finally:
                    os.chdir(here)
                yield i, result

    monkeypatch.setattr(experiments, "executor_for", lambda *args: Elsewhere())
    rows = compare(["mine/mywalk.toml"], [PARAMETERIZATIONS["se3"]], out="table", progress=None, executor="ray")
    assert [(r["task"], r["parameterization"]) for r in rows] == [("walk", "se3")]
    [(task, p, folder)] = fake_solves
    assert isinstance(task, Task) and (task.name, p, folder) == ("walk", "se3", str(tmp_path / "table" / "walk_se3"))
    assert (tmp_path / "table" / "table_iv.json").exists() and not list(elsewhere.iterdir())


def test_robustness_checkpoint_table_holds_every_group_so_far(tmp_path, monkeypatch, fake_solves):
    """The Table III written after each group of a sequential study has all groups solved so
    far (it had the last group's only), so a study that stops leaves the table of its groups."""
    solve = experiments.solve

    def fail_on_euler(task, p, **kwargs):
        if p == "euler":
            raise RuntimeError("boom")
        return solve(task, p, **kwargs)

    monkeypatch.setattr(experiments, "solve", fail_on_euler)
    with pytest.raises(RuntimeError, match="boom"):
        robustness(["walk", "big_jump"], ["se3", "quat1", "euler"], sigmas=[0.1], replicates=1, out=tmp_path, progress=None)
    table = (tmp_path / "table_iii.md").read_text()
    assert "| walk | se3 | 100% / 100% |" in table and "| walk | quat1 | 100% / 100% |" in table
    assert [(r["task"], r["parameterization"]) for r in json.loads((tmp_path / "table_iii.json").read_text())] == [("walk", "se3"), ("walk", "quat1")]


def test_robustness_resumes_a_runs_file_without_a_final_newline(tmp_path, fake_solves, capsys):
    """A runs file whose valid last line has no newline (joined with "\\n".join) keeps that
    run, and the next run is appended on a line of its own (it was glued onto that line,
    and both runs set aside as a corrupt line)."""
    kw = dict(sigmas=[0.1], out=tmp_path, progress=None)
    robustness(["walk"], ["se3"], replicates=2, **kw)
    path = tmp_path / RUNS_FILE
    path.write_text(path.read_text().rstrip("\n"))
    assert len(read_runs(path)) == 2
    runs = robustness(["walk"], ["se3"], replicates=3, **kw)
    assert [r["replicate"] for r in runs] == [0, 1, 2] and len(read_runs(path)) == 3
    assert len(fake_solves) == 3 and not list(tmp_path.glob("*.corrupt-*")) and "warning" not in capsys.readouterr().err


def test_compare_names_the_cells_of_task_files_after_their_tasks(tmp_path, fake_solves):
    """A task given as a .toml path: its cell's folder is OUT/{task name}_{parameterization},
    where its rows and `jtraj plot` look (it was OUT/{the path as given}_..., outside OUT for
    an absolute path)."""
    from importlib.resources import files

    task_file = tmp_path / "elsewhere" / "mywalk.toml"
    task_file.parent.mkdir()
    task_file.write_text(files("jtraj.tasks").joinpath("walk.toml").read_text())
    out = tmp_path / "out"
    rows = compare([str(task_file), "big_jump"], ["se3"], out=out, progress=None)
    assert [(r["task"], r["parameterization"]) for r in rows] == [("walk", "se3"), ("big_jump", "se3")]
    assert [folder for _, _, folder in fake_solves] == [str(out / "walk_se3"), str(out / "big_jump_se3")]


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(sigmas=[0.1, 1e-1, 0.5]), "robustness: sigmas: 0.1 given 2 times; expected each noise level once"),
        (dict(params=["se3", "euler", "se3"]), "robustness: params: 'se3' given 2 times; expected each parameterization once"),
        (dict(tasks=["walk", "big_jump", "walk"]), "robustness: tasks: 'walk' given 2 times; expected each task once"),
    ],
)
def test_robustness_refuses_repeated_settings(tmp_path, fake_solves, kwargs, message):
    """A repeated noise level (0.1 and 1e-1), parameterization or task was solved, counted and
    tabled twice (duplicate columns); it is refused before anything is written or solved."""
    kw = dict(tasks=["walk"], params=["se3"], sigmas=[0.1], replicates=1, out=tmp_path / "study", progress=None) | kwargs
    with pytest.raises(ValueError, match=f"^{message}$"):
        robustness(**kw)
    assert not fake_solves and not (tmp_path / "study").exists()


def test_compare_refuses_repeated_tasks_and_parameterizations(tmp_path, fake_solves):
    from importlib.resources import files

    task_file = tmp_path / "mywalk.toml"
    task_file.write_text(files("jtraj.tasks").joinpath("walk.toml").read_text())
    with pytest.raises(ValueError, match=r"^compare: tasks: 'walk' and '.*mywalk.toml' are the same task \('walk'\); expected each task once$"):
        compare(["walk", str(task_file)], ["se3"], out=tmp_path / "out", progress=None)
    with pytest.raises(ValueError, match=r"^compare: params: 'se3' given 2 times; expected each parameterization once$"):
        compare(["walk"], ["se3", "se3"], out=tmp_path / "out", progress=None)
    assert not fake_solves and not (tmp_path / "out").exists()


def test_compare_checks_every_cell_folder_before_the_first_solve(tmp_path, fake_solves, capsys):
    """A cell folder that could not take its result failed in that cell's solve, with a
    traceback, after the cells before it were solved; the command line now refuses it in one
    line, and without trajectories no cell folder is written, so none is checked."""
    from jtraj import cli

    out = tmp_path / "out"
    out.mkdir()
    (out / "walk_quat1").write_text("a file where the cell's folder goes")
    (out / "walk_se3").mkdir()
    (out / "walk_se3" / "result.json").mkdir()
    for params, cell, problem in ((["se3", "quat1"], "walk_se3", "result.json is a folder; expected room for the file result.json"), (["quat1"], "walk_quat1", "is a file; expected a folder")):
        with pytest.raises(ValueError, match=rf"^compare: out={re.escape(repr(str(out)))}: the cell folder {re.escape(str(out / cell))}: .*{re.escape(problem)}"):
            compare(["walk"], params, out=out, progress=None)
        code = cli.main(["compare", "--tasks", "walk", "--params", ",".join(params), "--out", str(out)])
        err = capsys.readouterr().err
        assert code == cli.EXIT_BAD_INPUT and err.startswith(f"jtraj compare: --out: {str(out)!r}: the cell folder {out / cell}") and err.count("\n") == 1
    assert not fake_solves and sorted(p.name for p in out.iterdir()) == ["walk_quat1", "walk_se3"]
    compare(["walk"], ["quat1"], out=out, progress=None, save_trajectories=False)
    assert len(fake_solves) == 1


def test_one_group_with_workers_prints_to_the_given_stream(tmp_path, fake_solves, capsys):
    """With workers=2 and one group, the local executor solved it in this process, whose stdout
    took the run lines in place of the stream given as progress."""
    stream = io.StringIO()
    robustness(["walk"], ["se3"], sigmas=[0.1], replicates=2, out=tmp_path, progress=stream, workers=2)
    assert len(fake_solves) == 2 and capsys.readouterr().out == ""
    assert sum(line.startswith("walk") for line in stream.getvalue().splitlines()) == 2, stream.getvalue()


def test_rows_that_are_not_runs_are_set_aside_with_the_torn_lines(tmp_path, fake_solves, capsys):
    """Lines that parse but are not runs (not an object, a row without a key field or without a
    field the tables read) are reported in the torn lines' warning and set aside with them, so
    their runs are solved again: a row without 'success' crashed Table III with a KeyError,
    rows without a key field were dropped without a word, and the counts included them."""
    kw = dict(sigmas=[0.1], replicates=3, seed=4, out=tmp_path)
    robustness(["walk"], ["se3"], progress=None, **kw)
    path = tmp_path / RUNS_FILE
    lines = path.read_text().splitlines()
    no_key = {k: v for k, v in json.loads(lines[0]).items() if k != "task_hash"}
    no_success = {k: v for k, v in json.loads(lines[1]).items() if k != "success"}
    other_seed = json.loads(lines[2]) | {"seed": 5}
    text = [lines[0], "", "[1, 2]", json.dumps(no_key), json.dumps(no_success), lines[2], json.dumps(other_seed), lines[2][:40]]
    path.write_text("\n".join(text))
    fake_solves.clear()
    capsys.readouterr()
    stream = io.StringIO()
    runs = robustness(["walk"], ["se3"], progress=stream, **kw)
    warning, resuming = stream.getvalue().splitlines()[:2]
    assert warning == (
        f"warning: {path}: line(s) [8] did not parse and line(s) [3, 4, 5] are not runs (line 3: a JSON list, not an object; line 4: no 'task_hash'; "
        f"line 5: no 'success'); the file was copied to {path}.corrupt-1 and its 3 good runs kept"
    )
    assert resuming == f"resuming: 2 of this call's 3 runs already in {path}; its 1 runs of other settings are kept"
    assert [r["replicate"] for r in runs] == [0, 1, 2] and [p for _, p, _ in fake_solves] == ["se3"]  # replicate 1 solved again
    assert (tmp_path / f"{RUNS_FILE}.corrupt-1").read_text() == "\n".join(text)
    assert len(path.read_text().splitlines()) == 4 and len(read_runs(path)) == 4


def test_the_resume_note_tells_other_settings_from_other_noise_levels(tmp_path, fake_solves, monkeypatch):
    """The resume note counted runs of this call's settings at other noise levels or replicates
    as runs of other settings, and a call whose settings matched none of the file's runs (a
    forgotten --seed) solved the whole study again without saying why."""
    # one clean commit for every call (a checkout with changes adds the other-code note)
    monkeypatch.setattr(experiments, "_code_source", lambda: {"commit": "a" * 40, "dirty": False})
    path = tmp_path / RUNS_FILE
    robustness(["walk"], ["se3"], sigmas=[0.1, 0.5], replicates=2, seed=4, out=tmp_path, progress=None)
    robustness(["walk"], ["se3"], sigmas=[0.1], replicates=1, seed=5, out=tmp_path, progress=None)
    stream = io.StringIO()
    robustness(["walk"], ["se3"], sigmas=[0.1], replicates=2, seed=4, out=tmp_path, progress=stream)
    lines = stream.getvalue().splitlines()
    assert lines[0] == f"resuming: 2 of this call's 2 runs already in {path}; its 1 runs of other settings and 2 runs of these settings at other noise levels or replicates are kept"
    assert not any(line.startswith("note:") for line in lines)
    fake_solves.clear()
    stream = io.StringIO()
    robustness(["walk"], ["se3"], sigmas=[0.1], replicates=1, seed=6, out=tmp_path, progress=stream)
    lines = stream.getvalue().splitlines()
    assert lines[0] == f"resuming: 0 of this call's 1 runs already in {path}; its 5 runs of other settings are kept"
    assert lines[1] == "note: none of them is this call's: the file's runs of these tasks and parameterizations differ in seed (--seed)"
    assert len(fake_solves) == 1


def test_rows_with_values_of_another_kind_are_set_aside_with_the_torn_lines(tmp_path, fake_solves):
    """Rows whose fields are there but of another kind than the sweeps write are set aside as
    rows that are not runs, and their runs solved again: a list for sigma made the run's key
    unhashable (a TypeError in read_runs), and a string violation of a run of this call crashed
    Table III. A row of an earlier file (no solver, variables or robot content, a NaN violation
    written as null) is still a run."""
    kw = dict(sigmas=[0.1], replicates=3, seed=4, out=tmp_path)
    robustness(["walk"], ["se3"], progress=None, **kw)
    path = tmp_path / RUNS_FILE
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    earlier = {k: v for k, v in rows[2].items() if k not in ("solver", "variables_hash", "noise_chart", "robot_hash")} | {"constraint_violation": None}
    text = [rows[0] | {"sigma": [0.1]}, rows[1] | {"constraint_violation": "abc"}, rows[2], rows[2] | {"seed": "5", "iterations": True}, earlier]
    path.write_text("".join(json.dumps(r) + "\n" for r in text))
    fake_solves.clear()
    stream = io.StringIO()
    runs = robustness(["walk"], ["se3"], progress=stream, **kw)
    warning, note, resuming = stream.getvalue().splitlines()[:3]
    assert warning == (
        f"warning: {path}: line(s) [1, 2, 4] are not runs (line 1: 'sigma' is an array (expected a number); line 2: 'constraint_violation' is a string (expected a number or null); "
        f"line 4: 'seed' is a string (expected an integer), 'iterations' is true (expected an integer)); the file was copied to {path}.corrupt-1 and its 2 good runs kept"
    )
    assert note.startswith("note: 1 runs in ") and resuming == f"resuming: 1 of this call's 3 runs already in {path}"
    assert [r["replicate"] for r in runs] == [0, 1, 2] and len(fake_solves) == 2  # replicates 0 and 1 solved again
    assert runs[2] == rows[2] and earlier in read_runs(path) and len(read_runs(path)) == 4


def test_a_runs_file_that_cannot_be_read_is_refused_before_anything_is_solved(tmp_path, fake_solves, monkeypatch, capsys):
    """OUT/runs.jsonl a folder ended jtraj robustness in an IsADirectoryError traceback (exit
    status 1); a file it cannot read (here an I/O error) in an OSError one. Each is now one
    line naming the file, exit status 2, before the study compiles or writes anything."""
    from jtraj.cli import EXIT_BAD_INPUT, main
    from jtraj.io import FileFormatError

    out = tmp_path / "rob"
    runs = out / RUNS_FILE
    runs.mkdir(parents=True)
    expected = "expected a JSON-lines file of runs (or none, to start the study)"
    argv = ["robustness", "--tasks", "walk", "--params", "se3", "--sigmas", "0.1", "--replicates", "1", "--out", str(out)]
    for extra in ([], ["--no-resume"]):
        assert main(argv + extra) == EXIT_BAD_INPUT
        assert capsys.readouterr().err == f"jtraj robustness: {runs}: is a folder; {expected}\n"
        assert not (out / "provenance.json").exists()  # checked with the command line's inputs
    with pytest.raises(FileFormatError, match=f"^{runs}: is a folder; "):
        robustness(["walk"], ["se3"], [0.1], replicates=1, out=out, progress=None)
    assert runs.is_dir() and not list(runs.iterdir()) and not (out / "table_iii.json").exists()
    runs.rmdir()
    runs.write_text("")

    def unreadable(*args, **kwargs):
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(experiments.jio, "open", unreadable, raising=False)
    assert main(argv) == EXIT_BAD_INPUT
    assert capsys.readouterr().err == f"jtraj robustness: {runs}: cannot be read (the system says: Input/output error); {expected}\n"
    assert not fake_solves and not (out / "table_iii.json").exists() and runs.read_text() == ""


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(executor="dask"), "executor='dask': expected one of local, ray"),
        (dict(workers=0), "workers=0: expected an integer >= 1"),
        (dict(workers=2.5), "workers=2.5: expected an integer >= 1"),
        (dict(ray_address="auto"), "ray_address='auto': needs executor='ray' (the local executor does not use a cluster)"),
        (dict(executor="ray", workers=2), "workers=2: is for executor='local'; with executor='ray' each group is a Ray task and the cluster runs as many at once as it has CPUs"),
    ],
)
def test_an_unknown_executor_is_refused_before_the_runs_file_is_touched(tmp_path, fake_solves, monkeypatch, kwargs, message):
    """robustness(resume=False) moved runs.jsonl aside, then found the executor unknown;
    workers=0 solved in this process as if 1 had been given; and an option of the other
    executor (ray_address with the local one, workers with Ray), which the command line
    refuses, was ignored without a word."""
    monkeypatch.setitem(sys.modules, "ray", None)  # no Ray instance started, whatever happens
    study = tmp_path / "study"
    study.mkdir()
    (study / "runs.jsonl").write_text("{}\n")
    with pytest.raises(ValueError, match=f"^robustness: {re.escape(message)}$"):
        robustness(["walk"], ["se3"], [0.1], replicates=1, out=study, progress=None, resume=False, **kwargs)
    with pytest.raises(ValueError, match=f"^compare: {re.escape(message)}$"):
        compare(["walk"], ["se3"], out=tmp_path / "table", progress=None, **kwargs)
    assert sorted(p.name for p in study.iterdir()) == ["runs.jsonl"] and not fake_solves and not (tmp_path / "table").exists()


def test_fig2_leaves_pyplot_alone(tmp_path):
    """plot_iterations (called by the robustness notebook) must not switch a notebook's backend
    (matplotlib.use closes every open figure and stops inline display) nor leave a figure in
    pyplot's list."""
    import matplotlib
    import matplotlib.pyplot as plt

    from jtraj.experiments import plot_iterations

    runs = [dict(task="walk", parameterization="se3", sigma=s, converged=True, constraint_violation=1e-9, success=True, iterations=20) for s in (0.1, 0.5)]
    backend = matplotlib.get_backend()
    plt.switch_backend("svg")
    try:
        mine = plt.figure()
        plot_iterations(runs, tmp_path / "fig2.png")
        assert matplotlib.get_backend() == "svg"
        assert plt.get_fignums() == [mine.number]
        assert (tmp_path / "fig2.png").stat().st_size > 1_000
    finally:
        plt.close("all")
        plt.switch_backend(backend)


@pytest.mark.parametrize("replicates", [2.5, 0, True, "3"])
def test_a_replicate_count_that_is_not_a_whole_number_is_refused_before_the_folder_is_touched(tmp_path, fake_solves, replicates):
    """replicates=2.5 passed, removed the folder's earlier tables, wrote an unfinished
    provenance.json, then failed at the first draw."""
    study = tmp_path / "study"
    study.mkdir()
    (study / "table_iii.md").write_text("an earlier study's table\n")
    with pytest.raises(ValueError, match=rf"^robustness: replicates={re.escape(repr(replicates))}: expected an integer >= 1$"):
        robustness(["walk"], ["se3"], [0.1], replicates=replicates, out=study, progress=None)
    assert sorted(p.name for p in study.iterdir()) == ["table_iii.md"] and not fake_solves
    # a numpy count is a count (it was taken for a list of replicate numbers, and failed)
    np.testing.assert_array_equal(noisy_warm_starts(np.zeros(2), [0.1], np.int64(3), seed=1), noisy_warm_starts(np.zeros(2), [0.1], 3, seed=1))


@pytest.mark.parametrize("seed", [2**63, -(2**63) - 1, 1.5, True])
def test_a_seed_jax_cannot_take_is_refused_before_any_solve(tmp_path, fake_solves, seed):
    """robustness(seed=2**63) raised OverflowError from JAX's PRNGKey after the first compile."""
    with pytest.raises(ValueError, match=r"^robustness: seed=.*: expected a 64-bit integer"):
        robustness(["walk"], ["se3"], [0.1], replicates=1, out=tmp_path / "study", seed=seed, progress=None)
    assert not fake_solves and not (tmp_path / "study").exists()



def test_robustness_does_not_resume_runs_of_a_robot_that_changed(tmp_path, fake_solves, monkeypatch, capsys):
    """A run is keyed by its robot's content, not only the task's robot name: after a robot
    file changes (its masses, contacts, limits), the runs solved on the old one are kept in the
    file but solved again; a row that does not say (an earlier version's) is not resumed."""
    from jtraj import robot as robot_lib
    from jtraj import task as task_lib

    robot = robot_lib.load(task_lib.load("big_jump").robot)
    assert robot.content_hash() == robot_lib.load_file(robot.source).content_hash()  # loaded again, the same robot
    wider = dataclasses.replace(robot, q_upper=np.asarray(robot.q_upper) + 0.1)
    assert wider.content_hash() != robot.content_hash()
    kw = dict(sigmas=[1e-3], replicates=1, seed=3, out=tmp_path, progress=None)
    first = robustness(["big_jump"], ["se3"], **kw)
    assert first[0]["robot_hash"] == robot.content_hash() and len(fake_solves) == 1
    assert robustness(["big_jump"], ["se3"], **kw) == first and len(fake_solves) == 1  # resumed
    original = experiments._robot_hash
    monkeypatch.setattr(experiments, "_robot_hash", lambda name: wider.content_hash())
    again = robustness(["big_jump"], ["se3"], **kw)
    assert len(fake_solves) == 2 and again[0]["robot_hash"] == wider.content_hash()
    assert len(read_runs(tmp_path / RUNS_FILE)) == 2
    monkeypatch.setattr(experiments, "_robot_hash", original)
    old = {k: v for k, v in first[0].items() if k != "robot_hash"}
    (tmp_path / RUNS_FILE).write_text(json.dumps(old) + "\n")
    redone = robustness(["big_jump"], ["se3"], **(kw | {"progress": sys.stdout}))
    assert "1 runs in" in capsys.readouterr().out and len(fake_solves) == 3 and redone[0]["robot_hash"] == robot.content_hash()


def test_no_resume_keeps_every_earlier_runs_file(tmp_path, fake_solves):
    """resume=False moved runs.jsonl to runs.jsonl.previous, replacing the one an earlier
    resume=False had moved there: the second call lost the first study's runs."""
    kw = dict(sigmas=[1e-3], replicates=1, out=tmp_path, progress=None, resume=False)
    robustness(["big_jump"], ["se3"], seed=1, **kw)
    first = (tmp_path / RUNS_FILE).read_text()
    robustness(["big_jump"], ["se3"], seed=2, **kw)
    second = (tmp_path / RUNS_FILE).read_text()
    stream = io.StringIO()
    robustness(["big_jump"], ["se3"], seed=3, **(kw | {"progress": stream}))
    # the progress says where the earlier runs went
    assert f"not resuming: the earlier runs of {tmp_path / RUNS_FILE} are kept in {tmp_path / RUNS_FILE}.previous-2\n" in stream.getvalue()
    assert (tmp_path / f"{RUNS_FILE}.previous-1").read_text() == first
    assert (tmp_path / f"{RUNS_FILE}.previous-2").read_text() == second
    assert [json.loads(line)["seed"] for line in (tmp_path / RUNS_FILE).read_text().splitlines()] == [3]


def test_table_iii_of_runs_with_and_without_iterations():
    """The public Table III of a runs file: the table robustness writes, and with iterations
    each cell's median of the converged runs ('-' where none converged)."""
    from jtraj.experiments import table_iii

    def run(sigma, replicate, converged, iterations, p="se3"):
        return dict(task="walk", parameterization=p, sigma=sigma, replicate=replicate, converged=converged, constraint_violation=1e-9, success=converged, iterations=iterations)

    runs = [run(0.5, 0, False, 50), run(0.1, 0, True, 12), run(0.1, 1, True, 16), run(0.5, 1, False, 50), run(0.1, 0, True, 20, "euler"), run(0.1, 1, True, 21, "euler")]
    plain = [line for line in table_iii(runs).splitlines() if line.startswith("|")]
    assert plain == ["| task | parameterization | sigma=0.1 | sigma=0.5 |", "|---|---|---|---|", "| walk | se3 | 100% / 100% | 0% / 0% |", "| walk | euler | 100% / 100% |  |"]
    counted = table_iii(runs, iterations=True)
    # a half median as it is (":.0f" rounded halves to even: 20.5 read "20", 49.5 "50")
    assert "| walk | se3 | 100% / 100% (14) | 0% / 0% (-) |" in counted and "| walk | euler | 100% / 100% (20.5) |  |" in counted
    assert "median iterations of the converged runs" in counted and "median iterations" not in table_iii(runs)


def test_table_iii_names_the_solvers_and_noise_charts_as_robustness_writes_them(tmp_path):
    """table_iii and robustness's table_iii.md each worked out the heading's solvers and noise
    charts from the runs; one place does it now, and both tables say the same. Rows of earlier
    files (no solver, no chart) count as Ipopt's in their own charts."""
    from jtraj.experiments import _write_robustness_outputs, table_iii

    def run(solver, chart):
        row = dict(task="walk", parameterization="quat1", sigma=0.5, replicate=0, converged=True, constraint_violation=1e-9, success=True, iterations=20, solver=solver, noise_chart=chart)
        return {k: v for k, v in row.items() if v is not None}

    runs = [run("jtraj", "se3"), run("ipopt", "euler"), run(None, None)]
    _write_robustness_outputs(runs, [0.5], tmp_path, figure=False)
    written = (tmp_path / "table_iii.md").read_text()
    assert table_iii(runs) == written
    assert "success of the solver (ipopt, jtraj)" in written and "coordinates of Euler" in written and "and SE(3)" in written, written
    plain = table_iii(runs[2:])
    assert "success of the solver (ipopt)" in plain and "coordinates of" not in plain

@pytest.mark.parametrize("finished", [0, 1])
def test_compare_interrupted_says_how_many_cells_its_table_holds(tmp_path, fake_solves, monkeypatch, finished):
    """Ctrl-C in compare: the command line said table_iv.json holds the cells finished before
    it, even when none had and the file was an earlier run's table."""
    (tmp_path / "table_iv.json").write_text("[]")  # an earlier run's
    solve = experiments.solve

    def interrupted_after(task, p, **kwargs):
        if len(fake_solves) == finished:
            raise KeyboardInterrupt
        return solve(task, p, **kwargs)

    monkeypatch.setattr(experiments, "solve", interrupted_after)
    with pytest.raises(KeyboardInterrupt) as e:
        compare(["big_jump"], ["se3", "euler"], out=tmp_path, progress=None)
    said = f"{tmp_path / 'table_iv.json'} holds the 1 of 2 cells finished before it" if finished else "none of the 2 cells had finished"
    assert str(e.value) == said
    # the earlier run's table is not left to read as this call's (it was, with none finished)
    assert (tmp_path / "table_iv.json").exists() == bool(finished) and (tmp_path / "table_iv.md").exists() == bool(finished)


def test_robustness_removes_an_earlier_calls_tables_before_it_solves(tmp_path, monkeypatch):
    """An interrupt before the first checkpoint left an earlier call's table_iii.* in OUT, and
    fig2.png (written at the end only) stayed an earlier call's until the end: both read as
    this call's. A folder in the place of one failed after all the solves."""
    from jtraj.experiments import robustness

    for name in ("table_iii.json", "table_iii.md", "fig2.png"):
        (tmp_path / name).write_text("an earlier call's")
    (tmp_path / "notes.txt").write_text("mine")
    groups = []

    def interrupted(*args, **kwargs):
        groups.append(args[:2])
        raise KeyboardInterrupt

    monkeypatch.setattr(experiments, "_robustness_group", interrupted)
    with pytest.raises(KeyboardInterrupt):
        robustness([HOP], ["se3"], [0.1], replicates=2, out=tmp_path, progress=None)
    assert len(groups) == 1 and sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt", "provenance.json"]
    assert json.loads((tmp_path / "provenance.json").read_text())["complete"] is False  # this call's, unfinished
    (tmp_path / "fig2.png").mkdir()
    with pytest.raises(ValueError, match=r"^robustness: .*fig2.png is a folder; expected room for the file fig2.png$"):
        robustness([HOP], ["se3"], [0.1], replicates=2, out=tmp_path, progress=None)
    assert len(groups) == 1  # refused before the first group


def test_a_noise_chart_check_that_passed_is_not_built_again(monkeypatch):
    """jtraj robustness --noise-chart checks the chart before it writes OUT, and robustness()
    checks it again: the second check built every transcription again (seconds per pair)."""
    from jtraj.experiments import check_noise_chart

    calls = []
    monkeypatch.setattr(experiments, "chart_noisy_warm_starts", lambda tr, chart, *a, **k: calls.append(tr.param.name))
    monkeypatch.setattr(experiments, "_NOISE_CHARTS_PASSED", set())
    check_noise_chart([HOP], ["se3", "quat1", "euler"], "paper", "se3")
    assert calls == ["quat1", "euler"]
    check_noise_chart([HOP], ["se3", "quat1", "euler", "quat2"], "paper", "se3")
    assert calls == ["quat1", "euler", "quat2"]  # only the pair not checked before
    check_noise_chart([HOP], ["quat1"], "compact", "se3")  # other variables: another check
    assert calls[-1] == "quat1" and len(calls) == 4


@pytest.mark.parametrize("solver", ["jtraj", "ipopt"])
def test_one_setting_spelled_two_ways_keys_the_same_runs(solver):
    """``--ipopt mu_init=1`` and ``=1.0`` are one setting: a real option's whole number keyed
    the runs apart, and a study resumed with the other spelling solved every run again. An
    integer option's value, and a different value, still key apart."""
    from jtraj.experiments import _group_key

    def key(options):
        return _group_key(HOP, "se3", "paper", False, options, 0, solver)["options_hash"]

    assert key({"mu_init": 1}) == key({"mu_init": 1.0}) == key({"mu_init": np.int64(1)})
    assert key({"mu_init": 1}) != key({"mu_init": 2.0}) and key({"mu_init": 1}) != key(None)
    assert key({"max_iter": 50}) != key({"max_iter": 60})
    assert key({"mu_max": 1}) == key({"mu_max": 1.0})  # jtraj's typed float | None, Ipopt's real


def test_a_study_refused_in_its_folder_leaves_no_empty_folder_behind(tmp_path):
    """`robustness` made OUT itself before `holding` held it, so `holding` did not count it as a
    folder it made, and an error inside (here: no noise levels) left an empty OUT behind."""
    out = tmp_path / "new" / "study"
    with pytest.raises(ValueError, match=r"robustness: no runs \(empty tasks, parameterizations or sigmas\)"):
        robustness([HOP], ["se3"], sigmas=[], out=out, progress=None)
    assert not (tmp_path / "new").exists()
