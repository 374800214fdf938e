"""bench/side_by_side.py with fake runners of the paper's code (shell scripts in tmp_path) and
no jtraj solve: a failed solve is an error row that the next run retries, and the exit status
says so; bad runner output and bad arguments stop with one line before anything is solved."""

import json
from pathlib import Path

import pytest
from conftest import bench_module, fake_peer, refused


@pytest.fixture(scope="module")
def sbs():
    return bench_module("side_by_side")


def _no_solve(*args, **kwargs):
    raise AssertionError("solved after a bad input")


def _rows(out: Path) -> list[dict]:
    return json.loads((out / "side_by_side.json").read_text())


def test_a_failed_peer_solve_is_retried_and_exits_nonzero(sbs, monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(sbs, "run_jtraj", _no_solve)
    out = tmp_path / "out"
    argv = ["--tasks", "walk,big_jump", "--variables", "", "--out", str(out)]
    # the runner fails on walk only
    flaky = fake_peer(tmp_path, 'if [ "$1" = walk ]; then echo boom >&2; exit 3; fi\necho \'{"status": 0, "iterations": 11, "time_s": 2.0}\'')
    with pytest.raises(SystemExit) as exc:
        sbs.main([*argv, "--peer", str(flaky)])
    assert exc.value.code == "bench/side_by_side.py: 1 solve(s) failed, their rows say error in " + f"{out / 'side_by_side.json'}; run again to retry them: paper on walk (sigma 0, seed 0)"
    assert "paper on walk (sigma 0, seed 0) failed: boom" in capsys.readouterr().err
    assert [(r["task"], r["status"]) for r in _rows(out)] == [("walk", "error"), ("big_jump", 0)]
    # the next run, the same runner fixed, solves walk again (big_jump is done), and its row
    # replaces the error row in place
    ok = fake_peer(tmp_path, 'echo "$1" >> "$(dirname "$0")/calls"\necho \'{"status": 0, "iterations": 14, "time_s": 1.0}\'')  # (the same path)
    sbs.main([*argv, "--peer", str(ok)])
    calls = (tmp_path / "calls").read_text().split()
    assert calls == ["walk"]
    assert [(r["task"], r["status"], r["iterations"]) for r in _rows(out)] == [("walk", 0, 14), ("big_jump", 0, 11)]
    assert {r["runner"] for r in _rows(out)} == {str(ok)}  # (big_jump's row kept: the same runner)
    assert "| walk | 0 | 14 | 14 |" in (out / "side_by_side.md").read_text()


def test_the_paper_codes_rows_of_another_runner_are_solved_again(sbs, monkeypatch, tmp_path):
    """The rows of the paper's code were resumed whatever runner made them: a run with another
    ``--peer`` (a changed copy of the code) kept the first runner's iterations under its name."""
    monkeypatch.setattr(sbs, "run_jtraj", _no_solve)
    out = tmp_path / "out"
    argv = ["--tasks", "walk", "--variables", "", "--out", str(out)]
    first = fake_peer(tmp_path, 'echo \'{"status": 0, "iterations": 11, "time_s": 2.0}\'', name="first")
    sbs.main([*argv, "--peer", str(first)])
    assert [(r["iterations"], r["runner"]) for r in _rows(out)] == [(11, str(first))]
    sbs.main([*argv, "--peer", str(first)])  # the same runner: resumed, not solved again
    assert len(_rows(out)) == 1
    other = fake_peer(tmp_path, 'echo \'{"status": 0, "iterations": 17, "time_s": 2.0}\'', name="other")
    sbs.main([*argv, "--peer", str(other)])
    assert [(r["iterations"], r["runner"]) for r in _rows(out)] == [(17, str(other))]


def test_a_jtraj_solve_that_raises_is_an_error_row_and_the_others_run(sbs, monkeypatch, tmp_path, capsys):
    """A jtraj solve that raised ended the whole run in a traceback, where a failed solve of
    the paper's code is an error row that the next run retries."""
    solved = []

    def run_jtraj(task, variables, sigma, seed, *args):
        solved.append(task)
        if task == "walk":
            raise FloatingPointError("NaN in the warm start")
        return dict(code=f"jtraj {variables}", task=task, sigma=sigma, seed=seed, status="solved", converged=True, iterations=12)

    monkeypatch.setattr(sbs, "run_jtraj", run_jtraj)
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exc:
        sbs.main(["--tasks", "walk,big_jump", "--variables", "paper", "--peer", "", "--out", str(out)])
    assert "1 solve(s) failed" in str(exc.value.code) and "jtraj paper on walk (sigma 0, seed 0)" in str(exc.value.code)
    assert "failed: FloatingPointError: NaN in the warm start" in capsys.readouterr().err
    assert solved == ["walk", "big_jump"]
    assert [(r["code"], r["task"], r["status"]) for r in _rows(out)] == [("jtraj paper", "walk", "error"), ("jtraj paper", "big_jump", "solved")]


@pytest.mark.parametrize(("body", "printed"), [("echo '{not json'", "'{not json'"), ("echo hello", "'hello'"), ("echo '{\"foo\": 1}'", "'{\"foo\": 1}'"), ("true", "''")])
def test_unparsable_peer_output_stops_with_one_line(sbs, tmp_path, body, printed):
    peer = fake_peer(tmp_path, body)
    with pytest.raises(SystemExit) as exc:
        sbs.run_peer(peer, "walk", 0.0, 0)
    assert exc.value.code == f"bench/side_by_side.py: the paper code's runner {peer} walk printed {printed}; expected a JSON line with status and iterations"


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--variables", "paper,bogus"], "--variables: 'bogus': unknown variables; expected some of paper, compact, lean"),
        (["--tasks", "walk,bogus"], "--tasks: 'bogus': unknown task; expected some of walk, hopscotch"),
        (["--robot", "talos"], "--robot: 'talos': expected ROBOT=OTHER"),
        (["--robot", "talos=nobody"], "unknown robot 'nobody'"),
        (["--set", "force_limits"], "--set: 'force_limits': expected FIELD=VALUE"),
        # checked against every variables name, not only the first
        (["--variables", "paper,lean", "--set", "contact_height=row"], "it needs contact_variables=True (as the variables 'paper' have: variables='paper', --variables paper) (with --variables lean)"),
        (["--sigma", "0.5", "--seeds", "a,b"], "argument --seeds: 'a,b': expected comma-separated seeds >= 0"),
        (["--sigma", "0.5", "--seeds", "-1"], "argument --seeds: '-1': expected comma-separated seeds >= 0"),
        (["--sigma", "-1"], "argument --sigma: '-1': expected a noise level (standard deviation) >= 0"),
        (["--sigma", "nan"], "argument --sigma: 'nan': expected a noise level"),
        # seeds without noise solved seed 0 alone, without a word
        (["--seeds", "1,2,3"], "--seeds: 1,2,3: seeds of the noise draws; expected --sigma > 0 with them"),
        # a file: FileExistsError's traceback from mkdir
        (["--out", "README.md"], "argument --out: 'README.md': is a file; expected a folder"),
    ],
)
def test_bad_arguments_are_refused_before_any_solve(sbs, monkeypatch, tmp_path, capsys, argv, message):
    for name in ("run_peer", "run_peer_checked", "run_jtraj", "peer_iterates"):
        monkeypatch.setattr(sbs, name, _no_solve)
    peer = fake_peer(tmp_path, "exit 1")
    refused(sbs.main, ["--peer", str(peer), "--out", str(tmp_path / "out"), *argv], capsys, message)
    assert not (tmp_path / "out" / "side_by_side.json").exists()


@pytest.mark.parametrize("kind", ["missing", "not executable"])
def test_a_peer_that_cannot_run_is_refused(sbs, monkeypatch, tmp_path, capsys, kind):
    for name in ("run_peer", "run_peer_checked", "run_jtraj"):
        monkeypatch.setattr(sbs, name, _no_solve)
    peer = tmp_path / "nothing" if kind == "missing" else fake_peer(tmp_path, "exit 0", executable=False)
    refused(sbs.main, ["--peer", str(peer), "--out", str(tmp_path / "out")], capsys, f"--peer: '{peer}': expected the path of the paper code's executable runner")



def test_a_folder_another_run_holds_is_refused(sbs, monkeypatch, tmp_path, capsys):
    """Two runs into one folder read the same rows and each wrote its own over the other's."""
    import fcntl
    import os

    for name in ("run_peer", "run_peer_checked", "run_jtraj", "peer_iterates"):
        monkeypatch.setattr(sbs, name, _no_solve)
    out = tmp_path / "out"
    out.mkdir()
    fd = os.open(out, os.O_RDONLY)  # another open description: as another process's hold
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        refused(sbs.main, ["--peer", str(fake_peer(tmp_path, "exit 1")), "--out", str(out)], capsys, f"--out: {out} is in use by another run")
    finally:
        os.close(fd)
    assert not any(out.iterdir())


class _Interrupt(KeyboardInterrupt):
    pass


def test_a_stopped_run_leaves_its_own_unfinished_provenance(sbs, monkeypatch, tmp_path):
    """Rows are written after each solve, the provenance only at the end: a run stopped after
    its first solve left its new row beside the provenance (command, date) of the run before."""
    out = tmp_path / "out"
    peer = fake_peer(tmp_path, 'echo \'{"status": 0, "iterations": 11, "time_s": 2.0}\'')
    sbs.main(["--tasks", "walk", "--variables", "", "--peer", str(peer), "--out", str(out)])
    first = json.loads((out / "provenance.json").read_text())
    assert first["complete"] is True and first["command"].endswith("--tasks walk --variables '' --peer " + f"{peer} --out {out}")

    def interrupted(*args, **kwargs):
        raise _Interrupt

    monkeypatch.setattr(sbs, "run_jtraj", interrupted)
    with pytest.raises(_Interrupt):  # big_jump's peer row is written, then its jtraj solve is stopped
        sbs.main(["--tasks", "big_jump,walk", "--variables", "paper", "--peer", str(peer), "--out", str(out)])
    assert [(r["code"], r["task"]) for r in _rows(out)] == [("paper", "walk"), ("paper", "big_jump")]
    prov = json.loads((out / "provenance.json").read_text())
    assert prov["complete"] is False and "--tasks big_jump,walk" in prov["command"]
    assert prov["earlier"] == [first]


@pytest.mark.parametrize(
    ("python", "error"),
    [
        # the code failed: the row holds its stderr, after what failed
        ("echo boom >&2; exit 1", "the public code failed on backflip: boom\n"),
        # the driver wrote no iterates: numpy's error, named
        ("echo \"PEERSTATS {'status': 0, 'iter': 3, 'time': 1.0}\"", "FileNotFoundError: "),
    ],
)
def test_a_failed_checked_peer_solve_is_an_error_row(sbs, monkeypatch, tmp_path, capsys, python, error):
    """A noisy flip runs the paper's code through the driver (run_peer_checked): a run that
    failed is an error row that the next run retries, whatever failed, as run_peer's."""
    monkeypatch.setattr(sbs, "run_jtraj", _no_solve)
    out = tmp_path / "out"
    peer = fake_peer(tmp_path, "exit 1")  # not run: the driver runs the code
    peer_python = fake_peer(tmp_path, python, name="python")
    src = tmp_path / "src"
    (src / "examples" / "agile_exps").mkdir(parents=True)
    argv = ["--tasks", "backflip", "--variables", "", "--sigma", "0.5", "--peer", str(peer), "--peer-src", str(src), "--peer-python", str(peer_python), "--out", str(out)]
    with pytest.raises(SystemExit) as exc:
        sbs.main(argv)
    assert str(exc.value.code).endswith("run again to retry them: paper on backflip (sigma 0.5, seed 0)")
    (row,) = _rows(out)
    assert (row["code"], row["task"], row["status"], row["iterations"]) == ("paper", "backflip", "error", None)
    if error.endswith("\n"):
        assert row["error"] == error
    else:
        assert row["error"].startswith(error)
    assert "bench/side_by_side.py: paper on backflip (sigma 0.5, seed 0) failed: " in capsys.readouterr().err


def test_the_code_sources_are_found_beside_the_runner_and_checked(sbs, monkeypatch, tmp_path, capsys):
    """A noisy flip runs the public code's sources: by default those beside the runner that
    --peer names (se3_trajopt/src), and a folder without its task scripts is refused before
    anything runs."""
    monkeypatch.setattr(sbs, "run_jtraj", _no_solve)
    monkeypatch.setattr(sbs, "run_peer_checked", _no_solve)
    peer = fake_peer(tmp_path, "exit 1")
    peer_python = fake_peer(tmp_path, "exit 1", name="python")
    assert sbs.peer_sources(peer) == tmp_path / "se3_trajopt" / "src"
    argv = ["--tasks", "backflip", "--variables", "", "--sigma", "0.5", "--peer", str(peer), "--peer-python", str(peer_python), "--out", str(tmp_path / "out")]
    refused(sbs.main, argv, capsys, f"--peer-src: '{tmp_path / 'se3_trajopt' / 'src'}' does not hold the public code's examples/agile_exps")
    refused(sbs.main, [*argv, "--peer-src", str(tmp_path)], capsys, f"--peer-src: '{tmp_path}' does not hold the public code's examples/agile_exps")
    assert not (tmp_path / "out").exists()


def test_relative_code_paths_reach_the_code_as_absolute_ones(sbs, monkeypatch, tmp_path):
    """The public code runs in a temporary folder of its own: relative --peer-src and
    --peer-python are made absolute before it starts (they passed the checks, then the code
    could not find its script)."""
    monkeypatch.setattr(sbs, "run_jtraj", _no_solve)
    seen = []

    def record(task, sigma, seed, peer_src, peer_python):
        seen.append((peer_src, peer_python))
        raise RuntimeError("recorded")

    monkeypatch.setattr(sbs, "run_peer_checked", record)
    (tmp_path / "src" / "examples" / "agile_exps").mkdir(parents=True)
    peer = fake_peer(tmp_path, "exit 1")
    fake_peer(tmp_path, "exit 1", name="python")
    monkeypatch.chdir(tmp_path)
    argv = ["--tasks", "backflip", "--variables", "", "--sigma", "0.5", "--peer", str(peer), "--peer-src", "src", "--peer-python", "python", "--out", "out"]
    with pytest.raises(SystemExit):
        sbs.main(argv)
    assert seen == [(tmp_path / "src", tmp_path / "python")]


def test_jtraj_rows_of_other_code_are_solved_again(sbs, monkeypatch, tmp_path):
    """A jtraj row was resumed whatever commit solved it (rows kept none), so a run re-solved
    only the peer and tabled it beside old jtraj iterations under this run's provenance. A row
    is resumed only when this commit, from a clean checkout, solved it."""
    solved = []

    def run_jtraj(task, variables, sigma, seed, *args):
        solved.append(task)
        return dict(code=f"jtraj {variables}", task=task, sigma=sigma, seed=seed, status="solved", converged=True, iterations=12)

    monkeypatch.setattr(sbs, "run_jtraj", run_jtraj)
    out = tmp_path / "out"
    argv = ["--tasks", "walk", "--variables", "paper", "--peer", "", "--out", str(out)]
    clean = {"commit": "a" * 40, "dirty": False}
    monkeypatch.setattr(sbs, "provenance_source", lambda: clean)
    sbs.main(argv)
    assert solved == ["walk"] and _rows(out)[0]["source"] == clean
    sbs.main(argv)  # the same clean commit: resumed
    assert solved == ["walk"]
    for other in ({"commit": "b" * 40, "dirty": False}, {"commit": "b" * 40, "dirty": True}, None):
        monkeypatch.setattr(sbs, "provenance_source", lambda other=other: other)
        sbs.main(argv)  # another commit, a changed checkout, no checkout: solved again
    assert solved == ["walk"] * 4 and len(_rows(out)) == 1 and _rows(out)[0]["source"] is None
    rows = _rows(out)
    del rows[0]["source"]  # a row from before rows kept it
    (out / "side_by_side.json").write_text(json.dumps(rows))
    monkeypatch.setattr(sbs, "provenance_source", lambda: clean)
    sbs.main(argv)
    assert solved == ["walk"] * 5
