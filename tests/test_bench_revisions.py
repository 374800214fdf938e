"""bench/revisions.py: its table, and its refusal of a process that imported the wrong jtraj."""

import pytest
from conftest import bench_module


@pytest.fixture(scope="module")
def revisions():
    return bench_module("revisions")


def test_table_gives_each_revision_its_fastest_solve_and_the_ratio(revisions):
    records = [
        dict(task="walk", label="aaa", iterations=16, cost=0.0, times=[9.0, 8.0, 8.5]),
        dict(task="walk", label="bbb", iterations=16, cost=0.0, times=[6.5, 6.4, 7.0]),
        dict(task="sideflip", label="aaa", iterations=33, cost=0.5, times=[3.3]),
        dict(task="sideflip", label="bbb", iterations=32, cost=0.25, times=[3.0]),
    ]
    lines = revisions.table(records, ("aaa", "bbb")).splitlines()
    assert lines[0].startswith("| task | iterations (aaa / bbb) |")
    assert len(lines) == 4
    assert lines[2] == "| walk | 16 / 16 | 0 / 0 | 8.00 | 6.40 | 0.500 | 0.400 | 1.25x |"
    assert lines[3] == "| sideflip | 33 / 32 | 0.5 / 0.25 | 3.30 | 3.00 | 0.100 | 0.094 | 1.10x |"


def test_table_shows_a_failed_solve_and_gives_it_no_ratio(revisions):
    """The records hold each solve's status, the table left it out: a revision whose solve
    stopped at its iteration limit sooner got a ratio, read as a speed-up of the solver."""
    records = [
        dict(task="walk", label="aaa", iterations=16, cost=0.0, times=[8.0], status="solved"),
        dict(task="walk", label="bbb", iterations=50, cost=0.0, times=[4.0], status="not_converged"),
    ]
    lines = revisions.table(records, ("aaa", "bbb")).splitlines()
    assert lines[2] == "| walk | 16 / 50 (not_converged) | 0 / 0 | 8.00 | 4.00 | 0.500 | 0.080 | none |"

def test_a_process_that_imports_jtraj_from_elsewhere_is_refused(revisions, tmp_path):
    """A tree without jtraj: the child imports the installed one, says so and stops before
    solving anything."""
    with pytest.raises(RuntimeError, match="not from"):
        revisions.run_child(tmp_path, "no_such_task", "se3", "compact", 1)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["no-such-revision"], "rev: 'no-such-revision': not a commit of this repository"),
        (["HEAD:README.md"], "rev: 'HEAD:README.md': not a commit of this repository"),  # a file, not a commit
        (["-x"], "rev: '-x': not a commit"),  # not taken for an option of git
        (["HEAD", "walk", "bogus"], "argument tasks: "),
        (["HEAD", "walk", "walk"], "tasks: 'walk' given 2 times; expected each task once"),
        (["HEAD", "--param", "bogus"], "argument --param: invalid choice: 'bogus'"),
        (["HEAD", "--variables", "bogus"], "argument --variables: invalid choice: 'bogus'"),
        (["HEAD", "--repeats", "0"], "--repeats: 0: expected an integer >= 1"),
        (["HEAD", "--repeats", "x"], "argument --repeats: invalid int value: 'x'"),
        (["HEAD", "--out", "README.md"], "--out: 'README.md': is a file; expected a folder"),
    ],
)
def test_bad_arguments_are_refused_before_any_work(revisions, monkeypatch, capsys, argv, message):
    """Unknown revisions, tasks, parameterizations and variables, and bad numbers and output
    folders were found by the child processes after the worktree was made (or not at all: a
    file as --out failed after every solve); they are argparse's one-line error, exit 2."""
    from conftest import refused

    def no_work(*args, **kwargs):
        raise AssertionError("did work after a bad input")

    monkeypatch.setattr(revisions, "run_child", no_work)
    monkeypatch.setattr(revisions.tempfile, "TemporaryDirectory", no_work)
    monkeypatch.chdir(revisions.REPO)
    if argv[0] == "-x":
        argv = ["--", *argv]
    refused(revisions.main, argv, capsys, message)


def test_the_checkout_itself_is_refused_as_the_earlier_revision(revisions, monkeypatch, capsys):
    """HEAD on a checkout without changes gave both columns one label, and the table took both
    from the first revision's solves: 1.00x whatever was measured. A checkout whose only
    change is an untracked file a run loads counts as changed (`jtraj.provenance.source`)."""
    from conftest import refused

    def no_work(*args, **kwargs):
        raise AssertionError("did work after a bad input")

    monkeypatch.setattr(revisions, "run_child", no_work)
    monkeypatch.setattr(revisions.tempfile, "TemporaryDirectory", no_work)
    def clean(root):  # the benchmark's own checkout, whichever jtraj this process imported
        assert root == revisions.REPO
        return {"commit": "c", "dirty": False}

    monkeypatch.setattr("jtraj.provenance.source", clean)
    refused(revisions.main, ["HEAD", "walk"], capsys, "rev: 'HEAD': the checkout itself (")


def test_a_task_file_is_given_to_both_trees_by_its_absolute_path(revisions, monkeypatch, tmp_path, capsys):
    """Each child runs in its tree (the earlier revision's is a temporary worktree): a task file
    named relative to where the benchmark was started was looked for inside that tree."""
    from importlib.resources import files

    (tmp_path / "mine.toml").write_text(files("jtraj.tasks").joinpath("walk.toml").read_text())
    monkeypatch.chdir(tmp_path)
    real_run = revisions.subprocess.run
    seen = []

    def run(cmd, *args, **kwargs):  # no worktree: the children are faked
        return revisions.subprocess.CompletedProcess(cmd, 0, "", "") if "worktree" in cmd else real_run(cmd, *args, **kwargs)

    def child(tree, task, param, variables, repeats):
        seen.append(task)
        return dict(task=task, iterations=10, status="solved", cost=1.0, times=[1.0])

    monkeypatch.setattr(revisions.subprocess, "run", run)
    monkeypatch.setattr(revisions, "run_child", child)
    monkeypatch.setattr("jtraj.provenance.source", lambda root=None: {"commit": "c", "dirty": True})  # HEAD against the changes
    assert revisions.main(["HEAD", "mine.toml", "--repeats", "1"]) == 0
    assert seen == [str(tmp_path / "mine.toml")] * 2
    assert "| mine.toml | 10 / 10 |" in capsys.readouterr().out


def test_out_is_written_as_the_other_benchmarks_results_with_the_provenance_written_once(revisions, monkeypatch, tmp_path, capsys):
    """``--out DIR`` wrote revisions.json with json.dumps (a solve's NaN cost as NaN, not JSON)
    and provenance.json twice: once by write_provenance, then again with the revisions added.
    Now: strict JSON, and one provenance record, naming both revisions, written once."""
    import math
    import pathlib

    from jtraj import io

    real_run = revisions.subprocess.run

    def run(cmd, *args, **kwargs):  # no worktree: the children are faked
        return revisions.subprocess.CompletedProcess(cmd, 0, "", "") if "worktree" in cmd else real_run(cmd, *args, **kwargs)

    def child(tree, task, param, variables, repeats):
        return dict(task=task, iterations=10, status="solved" if tree == revisions.REPO else "numerical_error", cost=1.0 if tree == revisions.REPO else math.nan, times=[1.0])

    written: list[str] = []
    real_write_text, real_path_write_text = io.write_text, pathlib.Path.write_text
    monkeypatch.setattr(io, "write_text", lambda path, text: written.append(pathlib.Path(path).name) or real_write_text(path, text))
    monkeypatch.setattr(pathlib.Path, "write_text", lambda self, *a, **k: written.append(self.name) or real_path_write_text(self, *a, **k))
    monkeypatch.setattr(revisions.subprocess, "run", run)
    monkeypatch.setattr(revisions, "run_child", child)
    monkeypatch.setattr("jtraj.provenance.source", lambda root=None: {"commit": "c", "dirty": True})
    out = tmp_path / "out"
    assert revisions.main(["HEAD", "walk", "--repeats", "1", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert sorted(written) == ["provenance.json", "revisions.json", "revisions.md"]
    records = io.read_json(out / "revisions.json")  # strict JSON: the NaN is null
    assert [(r["task"], r["cost"]) for r in records] == [("walk", None), ("walk", 1.0)]
    prov = io.read_json(out / "provenance.json")
    assert prov["command"] == f"python bench/revisions.py HEAD walk --repeats 1 --out {out}"
    assert prov["revisions"] == {"earlier": records[0]["label"], "later": records[1]["label"]}
    md = (out / "revisions.md").read_text()
    assert md.startswith("| task | iterations (") and md in printed
    assert sorted(p.name for p in out.iterdir()) == ["provenance.json", "revisions.json", "revisions.md"]  # no temporary file left


def test_a_failed_process_keeps_the_records_measured_before_it(revisions, monkeypatch, tmp_path, capsys):
    """One failed child raised RuntimeError with a traceback, and every record measured before
    it was lost (the files were written at the end): now they are written, marked incomplete,
    the table holds the tasks both revisions solved, and the benchmark stops with one line."""
    from jtraj import io

    real_run = revisions.subprocess.run
    removed = []

    def run(cmd, *args, **kwargs):  # no worktree: the children are faked
        if "worktree" in cmd:
            removed.append("remove" in cmd)
            return revisions.subprocess.CompletedProcess(cmd, 0, "", "")
        return real_run(cmd, *args, **kwargs)

    calls = []

    def child(tree, task, param, variables, repeats):
        calls.append(task)
        if len(calls) == 4:  # the later revision of the second task
            raise RuntimeError(f"{task} at {tree}: exit 1: MemoryError")
        return dict(task=task, iterations=10, status="solved", cost=1.0, times=[1.0])

    monkeypatch.setattr(revisions.subprocess, "run", run)
    monkeypatch.setattr(revisions, "run_child", child)
    monkeypatch.setattr("jtraj.provenance.source", lambda root=None: {"commit": "c", "dirty": True})
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exc:
        revisions.main(["HEAD", "walk", "big_jump", "backflip", "--repeats", "1", "--out", str(out)])
    message = str(exc.value.code)
    assert message == f"bench/revisions.py: big_jump at {revisions.REPO}: exit 1: MemoryError; {out}/revisions.json holds the 3 records measured before it"
    assert calls == ["walk", "walk", "big_jump", "big_jump"] and removed == [False, True]  # stopped there; the worktree removed
    prov = io.read_json(out / "provenance.json")
    earlier, later = prov["revisions"]["earlier"], prov["revisions"]["later"]
    assert [(r["task"], r["label"]) for r in io.read_json(out / "revisions.json")] == [("walk", earlier), ("walk", later), ("big_jump", earlier)]
    assert prov["complete"] is False
    rows = [line for line in (out / "revisions.md").read_text().splitlines() if line.startswith("| ")]
    assert [row.split(" | ")[0] for row in rows] == ["| task", "| walk"]  # big_jump has one revision's record: no row


def test_a_failed_first_process_writes_nothing(revisions, monkeypatch, tmp_path):
    real_run = revisions.subprocess.run

    def run(cmd, *args, **kwargs):
        return revisions.subprocess.CompletedProcess(cmd, 0, "", "") if "worktree" in cmd else real_run(cmd, *args, **kwargs)

    def child(tree, task, param, variables, repeats):
        raise RuntimeError(f"{task} at {tree}: exit 1: boom")

    monkeypatch.setattr(revisions.subprocess, "run", run)
    monkeypatch.setattr(revisions, "run_child", child)
    monkeypatch.setattr("jtraj.provenance.source", lambda root=None: {"commit": "c", "dirty": True})
    with pytest.raises(SystemExit, match=r"^bench/revisions\.py: walk at .*: exit 1: boom$"):
        revisions.main(["HEAD", "walk", "--out", str(tmp_path / "out")])
    assert not (tmp_path / "out").exists()
