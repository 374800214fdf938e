"""bench/solve.py says so when it runs without the paper's code beside it (a clone elsewhere),
instead of printing a table without the peer's column and no word why."""

import json
from pathlib import Path

import pytest
from conftest import bench_module


class _Stop(Exception):
    pass


def _stop(*args, **kwargs):
    raise _Stop


@pytest.mark.parametrize(("argv", "warned"), [([], True), (["--no-peer"], False)])
def test_a_missing_default_peer_is_announced(monkeypatch, capsys, argv, warned):
    solve = bench_module("solve")
    missing = Path("/nonexistent/shared/peers/run-se3-trajopt")
    monkeypatch.setattr(solve, "DEFAULT_PEER", missing)
    monkeypatch.setattr(solve, "prepare", _stop)  # stop before any compile
    with pytest.raises(_Stop):
        solve.main(["big_jump", "--variants", "jtraj", *argv])
    err = capsys.readouterr().err
    assert (f"no peer: the paper's public code is not at {missing}" in err) == warned


def _run(variant: str, time_s: float, iterations: int = 11) -> dict:
    return dict(variant=variant, status="solved", success=True, iterations=iterations, time_s=time_s, time_derivatives=0.0, time_ipopt=time_s, time_linear_solver=None, cost=0.0, constraint_violation=1e-9)


def test_repeats_alternate_and_report_the_medians(monkeypatch, capsys, tmp_path):
    """``--repeat 3``: the public code and jtraj take turns, each side's time is its median
    (the table shows the range), and the ratio is of the medians, not of single runs."""
    solve = bench_module("solve")
    calls: list[str] = []
    peer_times = iter([14.0, 11.0, 20.0])
    jtraj_times = iter([2.0, 1.0, 1.2])

    def fake_peer(peer, task):
        calls.append("peer")
        return dict(iterations=11, time_s=next(peer_times), status=0, obj=0.0, cons=1e-6)

    def fake_variant(task, param, name, extra, extra_jtraj):
        calls.append(name)
        return _run(name, next(jtraj_times))

    class _Prep:
        class nlp:
            n, m = 10, 5

    monkeypatch.setattr(solve, "run_peer", fake_peer)
    monkeypatch.setattr(solve, "run_variant", fake_variant)
    monkeypatch.setattr(solve, "prepare", lambda *a, **k: _Prep)
    solve.main(["big_jump", "--variants", "jtraj", "--peer", "fake", "--repeat", "3", "--out", str(tmp_path)])
    assert calls == ["peer", "jtraj"] * 3
    records = json.loads((tmp_path / "speed.json").read_text())
    assert records[0]["peer"]["time_s"] == 14.0 and records[0]["peer"]["times_s"] == [14.0, 11.0, 20.0]
    assert records[0]["variants"][0]["time_s"] == 1.2
    table = (tmp_path / "speed.md").read_text()
    assert "| 1.20 (1.00-2.00) |" in table and "| 14.00 (11.00-20.00) |" in table
    assert "| 11.7x |" in table  # 14.0 / 1.2
    assert "the median of 3 runs" in table


def test_repeats_that_disagree_on_iterations_are_shown(capsys):
    solve = bench_module("solve")
    assert solve._median_of([_run("jtraj", 1.0), _run("jtraj", 3.0), _run("jtraj", 2.0)], "x")["time_s"] == 2.0
    assert solve._median_of([_run("jtraj", 1.0), _run("jtraj", 3.0)], "x")["time_s"] == 1.0
    assert capsys.readouterr().err == ""
    rec = solve._median_of([_run("jtraj", 1.0), _run("jtraj", 1.5, iterations=12), _run("jtraj", 2.0)], "big_jump [jtraj]")
    assert "big_jump [jtraj]: the repeats took different iterations [11, 12, 11]" in capsys.readouterr().err
    assert solve._iterations_cell(rec) == "11/12/11" and rec["iterations"] == 12
    assert solve._iterations_cell(_run("jtraj", 1.0)) == "11"
