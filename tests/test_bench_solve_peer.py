"""bench/solve.py says so when it runs without the paper's code beside it (a clone elsewhere),
instead of printing a table without the peer's column and no word why."""

import json
import re
from pathlib import Path
from types import SimpleNamespace

import pytest
from conftest import bench_module, fake_peer, refused


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


def _no_solve(*args, **kwargs):
    raise AssertionError("solved, compiled or ran the peer after a bad input")


def _run(variant: str, time_s: float, iterations: int = 11) -> dict:
    return dict(variant=variant, status="solved", success=True, iterations=iterations, time_s=time_s, time_derivatives=0.0, time_ipopt=time_s, time_linear_solver=None, cost=0.0, constraint_violation=1e-9)


def test_repeats_alternate_and_report_the_medians(monkeypatch, capsys, tmp_path):
    """``--repeat 3``: the public code and jtraj take turns, each side's time is its median
    (the table shows the range), and the ratio is of the medians, not of single runs."""
    solve = bench_module("solve")
    calls: list[str] = []
    peer_times = iter([14.0, 11.0, 20.0])
    jtraj_times = iter([2.0, 1.0, 1.2])

    def peer_run(peer, task):
        calls.append("peer")
        return dict(iterations=11, time_s=next(peer_times), status=0, obj=0.0, cons=1e-6)

    def fake_variant(task, param, name, extra, extra_jtraj):
        calls.append(name)
        return _run(name, next(jtraj_times))

    class _Prep:
        class nlp:
            n, m = 10, 5

    monkeypatch.setattr(solve, "run_peer", peer_run)
    monkeypatch.setattr(solve, "run_variant", fake_variant)
    monkeypatch.setattr(solve, "prepare", lambda *a, **k: _Prep)
    peer = fake_peer(tmp_path, "exit 1")  # main() checks that it is an executable file; peer_run runs instead
    solve.main(["big_jump", "--variants", "jtraj", "--peer", str(peer), "--repeat", "3", "--out", str(tmp_path / "out")])
    assert calls == ["peer", "jtraj"] * 3
    records = json.loads((tmp_path / "out" / "speed.json").read_text())
    assert records[0]["peer"]["time_s"] == 14.0 and records[0]["peer"]["times_s"] == [14.0, 11.0, 20.0]
    assert records[0]["variants"][0]["time_s"] == 1.2
    table = (tmp_path / "out" / "speed.md").read_text()
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


@pytest.mark.parametrize(
    ("output", "expected"),
    [
        ("echo '{not json'", "printed '{not json'; expected a JSON object with numbers iterations and time_s"),
        ("echo '{\"foo\": 1}'", "printed '{\"foo\": 1}'; expected a JSON object"),
        ("echo '{\"iterations\": 5}'", "expected a JSON object with numbers iterations and time_s"),
        ("echo hello", "failed (exit 0): hello"),
        ("echo boom >&2; exit 3", "failed (exit 3): boom"),
    ],
)
def test_a_peer_that_prints_no_record_stops_with_one_line(tmp_path, output, expected):
    """Bad output of the runner: one line naming it, the task and what it printed, no traceback
    (SystemExit's message is printed as it is, exit status 1)."""
    solve = bench_module("solve")
    peer = fake_peer(tmp_path, output)
    with pytest.raises(SystemExit) as exc:
        solve.run_peer(str(peer), "big_jump")
    message = str(exc.value.code)
    assert message.startswith(f"bench/solve.py: peer {peer} big_jump ") and expected in message
    assert "\n" not in message


def test_a_peer_record_is_returned(tmp_path):
    solve = bench_module("solve")
    peer = fake_peer(tmp_path, 'echo "log line"; echo \'{"iterations": 5, "time_s": 1.5, "status": 0}\'')
    assert solve.run_peer(str(peer), "big_jump") == {"iterations": 5, "time_s": 1.5, "status": 0}


def test_bad_peer_output_stops_before_jtraj_solves(monkeypatch, tmp_path):
    solve = bench_module("solve")
    for name in ("prepare", "solve", "run_variant"):
        monkeypatch.setattr(solve, name, _no_solve)
    peer = fake_peer(tmp_path, "echo '{not json'")
    with pytest.raises(SystemExit, match=re.escape("printed '{not json'")):
        solve.main(["big_jump", "--variants", "jtraj", "--peer", str(peer)])


def _outcome():
    from jtraj.result import Outcome

    return SimpleNamespace(status=Outcome.SOLVED, success=True, iterations=3, time_s=1.0, time_derivatives=0.1, time_solver=0.9, cost=0.0, constraint_violation=0.0)


@pytest.mark.parametrize(("extra", "expected"), [({}, 3), ({"print_level": 5}, 5)])
def test_ipopt_options_may_raise_the_print_level(monkeypatch, extra, expected):
    """``--ipopt print_level=5`` was a TypeError (a keyword given twice); the user's level wins
    over the default 3 (the timing table is printed from 3 up)."""
    solve = bench_module("solve")
    seen: dict = {}

    def fake_solve(task, param, **kwargs):
        seen.update(kwargs["ipopt_options"])
        return _outcome()

    monkeypatch.setattr(solve, "solve", fake_solve)
    rec = solve.run_variant("big_jump", "se3", "paper", extra, {})
    assert seen == {"print_timing_statistics": "yes", "print_level": expected}
    assert rec["variant"] == "paper" and rec["iterations"] == 3


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--ipopt", "print_timing_statistics=no"], "--ipopt print_timing_statistics=no: expected yes"),
        (["--ipopt", "print_level=2"], "--ipopt print_level=2: expected 3 or more"),
        (["--param", "bogus"], "argument --param: invalid choice: 'bogus'"),
        (["--repeat", "2"], "--repeat: 2: expected an odd count (at least 1), so that the median is one of the runs"),
        (["--repeat", "0"], "--repeat: 0: expected an odd count"),
        # the peer solves with SE(3): its ratio to another parameterization's solve was printed as a speed-up
        (["--param", "euler"], "--param euler: the public code solves with the SE(3) tangent only"),
        # each run twice a round: the median of an even count, and every row printed twice
        (["--variants", "paper,paper"], "--variants: 'paper' given 2 times; expected each variant once"),
        (["--variants", "jtraj,compact,jtraj"], "--variants: 'jtraj' given 2 times; expected each variant once"),
        # an IndexError at variants[0], after the peer's first run
        (["--variants", ","], "--variants: ',': expected some of ['compact', 'exact', 'jtraj', 'lean', 'paper']"),
        (["--variants", ""], "--variants: '': expected some of"),
    ],
)
def test_bad_options_are_refused_before_any_work(monkeypatch, capsys, tmp_path, argv, message):
    solve = bench_module("solve")
    for name in ("prepare", "solve", "run_variant", "run_peer"):
        monkeypatch.setattr(solve, name, _no_solve)
    peer = fake_peer(tmp_path, "exit 1")
    refused(solve.main, ["big_jump", "--peer", str(peer), *argv], capsys, message)


@pytest.mark.parametrize("kind", ["missing", "not executable", "folder"])
def test_a_peer_that_cannot_run_is_refused_before_any_work(monkeypatch, capsys, tmp_path, kind):
    solve = bench_module("solve")
    for name in ("prepare", "solve", "run_variant", "run_peer"):
        monkeypatch.setattr(solve, name, _no_solve)
    peer = {"missing": tmp_path / "nothing", "not executable": fake_peer(tmp_path, "exit 0", executable=False), "folder": tmp_path}[kind]
    refused(solve.main, ["big_jump", "--peer", str(peer)], capsys, f"--peer: '{peer}': expected the path of an executable runner (run as PEER TASK)")


def test_no_ratio_where_the_variant_did_not_solve():
    """A variant that stopped (here at its iteration limit in 5 s) has no time to solution: its
    row gave 'peer / jtraj 2.0x' beside the peer's 10 s solve, as if jtraj were twice as fast."""
    solve = bench_module("solve")
    stopped = dict(_run("paper", 5.0, iterations=200), status="not_converged", success=False)
    peer = dict(iterations=11, time_s=10.0, status=0, obj=1.0, cons=1e-6)
    table = solve.markdown([dict(task="big_jump", peer=peer, variants=[stopped, _run("compact", 2.0)])])
    rows = [line for line in table.splitlines() if line.startswith("| big_jump |")]
    assert rows[0].endswith("| 10.00 | none (jtraj not_converged) |") and "2.0x" not in rows[0]
    assert rows[1].endswith("| 10.00 | 5.0x |")


@pytest.mark.parametrize(
    ("status", "cells"),
    [
        (0, "| 11 | 1 | 1.0e-06 | 10.00 | 5.0x |"),
        (-5, "| 11 (stopped, Ipopt status -5) | 1 | 1.0e-06 | >= 10.00 | >= 5.0x |"),
        (None, "| 11 (no status) | 1 | 1.0e-06 | 10.00 | 5.0x |"),
    ],
)
def test_a_peer_without_a_status_is_not_called_stopped(status, cells):
    """The runner's record needs only iterations and time_s; one without a status was shown as
    '(stopped, Ipopt status None)' with its time and the ratio as lower bounds."""
    solve = bench_module("solve")
    peer = dict(iterations=11, time_s=10.0, obj=1.0, cons=1e-6) | ({} if status is None else {"status": status})
    table = solve.markdown([dict(task="big_jump", peer=peer, variants=[_run("compact", 2.0)])])
    row = next(line for line in table.splitlines() if line.startswith("| big_jump |"))
    assert row.endswith(cells), row


@pytest.mark.parametrize(
    ("status", "cells"),
    [
        # stopped by a limit (iterations, CPU time, wall time): the time and the ratio are lower bounds
        (-1, "| 11 (stopped, Ipopt status -1) | 1 | 1.0e-06 | >= 10.00 | >= 5.0x |"),
        (-4, "| 11 (stopped, Ipopt status -4) | 1 | 1.0e-06 | >= 10.00 | >= 5.0x |"),
        # failed: no time to solution, no ratio (these were '>= 5.0x', as if stopped by a limit)
        (2, "| 11 (failed, Ipopt status 2) | 1 | 1.0e-06 | 10.00 | none (peer status 2) |"),
        (-2, "| 11 (failed, Ipopt status -2) | 1 | 1.0e-06 | 10.00 | none (peer status -2) |"),
        (4, "| 11 (failed, Ipopt status 4) | 1 | 1.0e-06 | 10.00 | none (peer status 4) |"),
        (1, "| 11 | 1 | 1.0e-06 | 10.00 | 5.0x |"),  # solved to acceptable level
    ],
)
def test_only_a_peer_stopped_by_a_limit_is_a_lower_bound(status, cells):
    solve = bench_module("solve")
    peer = dict(iterations=11, time_s=10.0, obj=1.0, cons=1e-6, status=status)
    table = solve.markdown([dict(task="big_jump", peer=peer, variants=[_run("compact", 2.0)])])
    row = next(line for line in table.splitlines() if line.startswith("| big_jump |"))
    assert row.endswith(cells), row


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (None, "speed.json: file does not exist"),
        ("", "speed.json: file is empty; expected JSON"),
        ("{not json", "speed.json: not valid JSON"),
        ("{}", "speed.json: not the records bench/solve.py writes"),
        ("[1, 2]", "speed.json: not the records bench/solve.py writes"),
        ('[{"task": "big_jump"}]', "speed.json: not the records bench/solve.py writes (a list of one object per task, with its variants): KeyError: 'variants'"),
        ('[{"task": "big_jump", "variants": [{"variant": "paper"}]}]', "speed.json: not the records bench/solve.py writes"),
        ('[{"task": "big_jump", "variants": 3}]', "speed.json: not the records bench/solve.py writes"),
    ],
)
def test_table_only_refuses_a_missing_or_malformed_speed_json(monkeypatch, capsys, tmp_path, content, expected):
    """``--table-only`` read DIR/speed.json with a traceback (FileFormatError, or KeyError and
    TypeError for records of another shape): argparse's one-line error now, no speed.md written."""
    solve = bench_module("solve")
    for name in ("prepare", "solve", "run_variant", "run_peer"):
        monkeypatch.setattr(solve, name, _no_solve)
    if content is not None:
        (tmp_path / "speed.json").write_text(content)
    refused(solve.main, ["--table-only", "--out", str(tmp_path)], capsys, f"--table-only: {tmp_path}/{expected}")
    assert not (tmp_path / "speed.md").exists()


def test_table_only_rewrites_the_table_of_good_records(monkeypatch, tmp_path):
    solve = bench_module("solve")
    records = [dict(task="big_jump", peer=None, variants=[_run("compact", 2.0)])]
    (tmp_path / "speed.json").write_text(json.dumps(records))
    solve.main(["--table-only", "--out", str(tmp_path)])
    assert (tmp_path / "speed.md").read_text() == solve.markdown(records)


def test_the_docstring_promises_no_compile_column():
    """Its second line promised 'compile time' beside the table's columns; the table has none
    (the JSON's compile_s is the first variant's NLP build)."""
    solve = bench_module("solve")
    assert "compile time" not in solve.__doc__.split("\n\n")[0]
    assert "compile_s" in solve.__doc__ and "compile" not in solve.markdown([dict(task="t", peer=None, variants=[_run("compact", 2.0)])]).splitlines()[0]
