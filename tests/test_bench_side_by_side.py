"""bench/side_by_side.py with fake runners of the paper's code (shell scripts in tmp_path) and
no jtraj solve: a failed solve is an error row that the next run retries, and the exit status
says so; bad runner output stops with one line."""

import json
from pathlib import Path

import pytest
from conftest import bench_module


@pytest.fixture(scope="module")
def sbs():
    return bench_module("side_by_side")


def _peer(folder: Path, body: str, name: str = "peer", executable: bool = True) -> Path:
    path = folder / name
    path.write_text(f"#!/bin/sh\n{body}\n")
    path.chmod(0o755 if executable else 0o644)
    return path


def _no_solve(*args, **kwargs):
    raise AssertionError("solved after a bad input")


def _rows(out: Path) -> list[dict]:
    return json.loads((out / "side_by_side.json").read_text())


def test_a_failed_peer_solve_is_retried_and_exits_nonzero(sbs, monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(sbs, "run_jtraj", _no_solve)
    out = tmp_path / "out"
    argv = ["--tasks", "walk,big_jump", "--variables", "", "--out", str(out)]
    # the runner fails on walk only
    flaky = _peer(tmp_path, 'if [ "$1" = walk ]; then echo boom >&2; exit 3; fi\necho \'{"status": 0, "iterations": 11, "time_s": 2.0}\'')
    with pytest.raises(SystemExit) as exc:
        sbs.main([*argv, "--peer", str(flaky)])
    assert exc.value.code == "bench/side_by_side.py: 1 solve(s) failed, their rows say error in " + f"{out / 'side_by_side.json'}; run again to retry them: paper on walk (sigma 0, seed 0)"
    assert "paper on walk (sigma 0, seed 0) failed: boom" in capsys.readouterr().err
    assert [(r["task"], r["status"]) for r in _rows(out)] == [("walk", "error"), ("big_jump", 0)]
    # the next run solves walk again (big_jump is done), and its row replaces the error row in place
    ok = _peer(tmp_path, 'echo "$1" >> "$(dirname "$0")/calls"\necho \'{"status": 0, "iterations": 14, "time_s": 1.0}\'', name="ok")
    sbs.main([*argv, "--peer", str(ok)])
    calls = (tmp_path / "calls").read_text().split()
    assert calls == ["walk"]
    assert [(r["task"], r["status"], r["iterations"]) for r in _rows(out)] == [("walk", 0, 14), ("big_jump", 0, 11)]
    assert "| walk | 0 | 14 | 14 |" in (out / "side_by_side.md").read_text()


@pytest.mark.parametrize(("body", "printed"), [("echo '{not json'", "'{not json'"), ("echo hello", "'hello'"), ("echo '{\"foo\": 1}'", "'{\"foo\": 1}'"), ("true", "''")])
def test_unparsable_peer_output_stops_with_one_line(sbs, tmp_path, body, printed):
    peer = _peer(tmp_path, body)
    with pytest.raises(SystemExit) as exc:
        sbs.run_peer(peer, "walk", 0.0, 0)
    assert exc.value.code == f"bench/side_by_side.py: the paper code's runner {peer} walk printed {printed}; expected a JSON line with status and iterations"

