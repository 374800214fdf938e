"""Experiments on a small Go2 task: vmapped noisy warm starts, the robustness study's files,
the Table IV writer, and the plots."""

import json

import numpy as np

from jtraj.experiments import compare, noisy_warm_starts, robustness
from jtraj.plots import plot_convergence, plot_result
from jtraj.result import Result
from test_transcription import HOP


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


def test_robustness_study_writes_tables_and_figure(tmp_path):
    runs = robustness([HOP], ["se3"], sigmas=[1e-6, 1e-2], replicates=2, out=tmp_path, progress=None)
    assert len(runs) == 4
    summary = json.loads((tmp_path / "table_iii.json").read_text())
    assert [(r["sigma"], r["runs"]) for r in summary] == [(1e-6, 2), (1e-2, 2)]
    assert all(r["success_rate"] == 1.0 for r in summary)
    assert "| test_hop | se3 | 100% | 100% |" in (tmp_path / "table_iii.md").read_text()
    assert (tmp_path / "fig2.png").stat().st_size > 1000


def test_robustness_resumes_a_stopped_study(tmp_path):
    first = robustness([HOP], ["se3"], sigmas=[1e-3], replicates=1, seed=5, out=tmp_path, progress=None)
    more = robustness([HOP], ["se3"], sigmas=[1e-3], replicates=2, seed=5, out=tmp_path, progress=None)
    # the first run is kept as it was (same timing record), only replicate 1 is new
    assert [r["replicate"] for r in more] == [0, 1]
    assert more[0] == first[0]
    # a complete study solves nothing and still writes its tables
    (tmp_path / "table_iii.md").unlink()
    assert robustness([HOP], ["se3"], sigmas=[1e-3], replicates=2, seed=5, out=tmp_path, progress=None) == more
    assert "| test_hop | se3 | 100% |" in (tmp_path / "table_iii.md").read_text()
    # another seed is another study: nothing is reused
    other = robustness([HOP], ["se3"], sigmas=[1e-3], replicates=1, seed=6, out=tmp_path, progress=None)
    assert len(other) == 1 and other[0]["seed"] == 6 and other[0]["time_s"] != first[0]["time_s"]


def test_robustness_with_worker_processes_matches_in_process(tmp_path):
    kw = dict(sigmas=[1e-2], replicates=1, seed=2, progress=None, resume=False)
    serial = robustness([HOP], ["se3", "euler"], out=tmp_path / "a", **kw)
    parallel = robustness([HOP], ["se3", "euler"], out=tmp_path / "b", workers=2, **kw)
    key = lambda r: r["parameterization"]
    for a, b in zip(sorted(serial, key=key), sorted(parallel, key=key)):
        assert (a["parameterization"], a["status"], a["iterations"]) == (b["parameterization"], b["status"], b["iterations"])
        np.testing.assert_allclose(a["cost"], b["cost"], rtol=1e-6)


def test_compare_writes_table_iv_and_plots(tmp_path):
    rows = compare([HOP], ["se3"], out=tmp_path, progress=None)
    assert rows[0]["task"] == "test_hop" and rows[0]["converged"]
    assert "| test_hop | se3 | solved |" in (tmp_path / "table_iv.md").read_text()
    result = Result.load(tmp_path / "test_hop_se3")
    assert plot_result(result, tmp_path / "t.png").stat().st_size > 1000
    assert plot_convergence(result, tmp_path / "c.png").stat().st_size > 1000
