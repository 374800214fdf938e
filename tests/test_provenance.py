"""provenance.json of the sweeps (`jtraj.provenance.begin_run` / `end_run`): written when a run
starts, marked complete when it ends, earlier records of the folder kept."""

import json
import re
import subprocess
from pathlib import Path

import pytest

from jtraj import provenance as prov


def test_a_run_is_marked_incomplete_until_it_ends_and_keeps_the_folders_earlier_records(tmp_path):
    out = tmp_path / "study"
    first = prov.begin_run(out, ["jtraj", "robustness", "--tasks", "walk"])
    on_disk = json.loads((out / "provenance.json").read_text())
    assert on_disk["complete"] is False and on_disk["command"] == "jtraj robustness --tasks walk"
    assert "earlier" not in on_disk and first == on_disk
    prov.end_run(out, first)
    done = json.loads((out / "provenance.json").read_text())
    assert done["complete"] is True and re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", done["date_end_utc"])
    # a second run into the folder (a resume) and a third that stops: both earlier records kept, oldest first
    second = prov.begin_run(out, ["jtraj", "robustness", "--tasks", "walk,big_jump"])
    prov.end_run(out, second)
    prov.begin_run(out, ["jtraj", "robustness", "--tasks", "walk,big_jump", "--sigmas", "0.5"])
    last = json.loads((out / "provenance.json").read_text())
    assert last["complete"] is False and last["command"].endswith("--sigmas 0.5")
    assert [(e["command"], e["complete"]) for e in last["earlier"]] == [("jtraj robustness --tasks walk", True), ("jtraj robustness --tasks walk,big_jump", True)]
    assert all("earlier" not in e for e in last["earlier"])
    # an unreadable record is replaced, not kept
    (out / "provenance.json").write_text("{trunc")
    assert "earlier" not in prov.begin_run(out, ["jtraj", "compare"])


def test_provenance_names_jaxs_devices_and_the_checkout():
    record = prov.provenance(["jtraj", "compare"])
    assert record["jax"]["backend"] in ("cpu", "gpu", "tpu") and record["jax"]["devices"] >= 1
    root = Path(prov.__file__).resolve().parent.parent
    if not (root / ".git").exists():
        assert "source" not in record  # an installed copy: no commit to name
        return
    head = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
    assert record["source"]["commit"] == head and isinstance(record["source"]["dirty"], bool)


def test_source_is_none_outside_a_checkout(monkeypatch, tmp_path):
    fake = tmp_path / "site-packages" / "jtraj" / "provenance.py"
    fake.parent.mkdir(parents=True)
    monkeypatch.setattr(prov, "__file__", str(fake))
    assert prov.source() is None
    (tmp_path / "site-packages" / ".git").mkdir()  # a .git that git cannot read: still None, no error
    monkeypatch.setenv("GIT_DIR", str(tmp_path / "nowhere"))
    assert prov.source() is None


def test_dirty_names_a_changed_file_and_an_untracked_one_the_run_loads(monkeypatch, tmp_path):
    """A checkout is dirty when a tracked file of the code changed or when a task, robot or
    module file the run loads is not tracked (``git status --untracked-files=no`` called a tree
    with a new tasks/*.toml clean, though the commit cannot give that task); files git ignores,
    untracked files elsewhere, and tracked files outside the code (a sweep's own outputs in a
    tracked results folder) do not count."""
    def git(*args):
        subprocess.run(["git", "-C", str(tmp_path), *args], capture_output=True, check=True)

    for name, text in (("jtraj/provenance.py", ""), ("tasks/walk.toml", "a"), (".gitignore", "runs/\n"), ("results/t/provenance.json", "{}"), ("bench/solve.py", "")):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    git("init", "-q")
    git("add", ".")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-m", "x")
    monkeypatch.setattr(prov, "__file__", str(tmp_path / "jtraj" / "provenance.py"))
    monkeypatch.delenv("GIT_DIR", raising=False)
    clean = prov.source()
    assert clean is not None and clean["dirty"] is False and "untracked" not in clean
    (tmp_path / "runs").mkdir()
    (tmp_path / "runs" / "result.json").write_text("{}")  # ignored
    (tmp_path / "notes.md").write_text("")  # not loaded by a run
    # a sweep written into a tracked results folder rewrites its own files
    (tmp_path / "results" / "t" / "provenance.json").write_text('{"a": 1}')
    assert prov.source()["dirty"] is False
    (tmp_path / "bench" / "solve.py").write_text("changed")
    assert prov.source() == {"commit": clean["commit"], "dirty": True}
    git("checkout", "--", "bench/solve.py")
    (tmp_path / "tasks" / "my_jump.toml").write_text("b")
    assert prov.source() == {"commit": clean["commit"], "dirty": True, "untracked": ["tasks/my_jump.toml"]}
    (tmp_path / "tasks" / "my_jump.toml").unlink()
    (tmp_path / "tasks" / "walk.toml").write_text("changed")
    assert prov.source() == {"commit": clean["commit"], "dirty": True}


def test_cores_are_the_ones_this_process_may_use(monkeypatch):
    """``machine.cores`` is the process's CPU affinity (``taskset -c 0`` recorded the machine's
    2)."""
    monkeypatch.setattr(prov.os, "sched_getaffinity", lambda pid: {0}, raising=False)
    assert prov.provenance(["jtraj", "compare"])["machine"]["cores"] == 1


@pytest.mark.parametrize("argv", [["jtraj", "compare"], ["python", "bench/solve.py", "walk"]])
def test_command_keeps_its_program(argv):
    assert prov.provenance(argv)["command"] == " ".join(argv)


def test_an_empty_command_line_is_recorded_as_empty():
    # argv=[] (no program name, as an embedding host may give) raised IndexError
    assert prov.provenance([])["command"] == ""


def test_gits_own_variables_do_not_point_the_record_at_another_repository(monkeypatch, tmp_path):
    """GIT_DIR (set in git hooks and some shells) made source() record another repository's
    HEAD, and GIT_INDEX_FILE called a clean checkout dirty."""
    def git(folder, *args):
        return subprocess.run(["git", "-C", str(folder), *args], capture_output=True, text=True, check=True).stdout.strip()

    for folder, text in ((tmp_path / "ours", "a"), (tmp_path / "other", "b")):
        (folder / "jtraj").mkdir(parents=True)
        (folder / "jtraj" / "provenance.py").write_text(text)
        git(folder, "init", "-q")
        git(folder, "add", ".")
        git(folder, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-m", text)
    ours = git(tmp_path / "ours", "rev-parse", "HEAD")
    monkeypatch.setattr(prov, "__file__", str(tmp_path / "ours" / "jtraj" / "provenance.py"))
    monkeypatch.setenv("GIT_DIR", str(tmp_path / "other" / ".git"))
    monkeypatch.setenv("GIT_INDEX_FILE", str(tmp_path / "no-index"))
    assert prov.source() == {"commit": ours, "dirty": False}


HOLDER = """
import sys
from jtraj.provenance import recording
with recording(sys.argv[1], ["jtraj", "robustness", "--tasks", "walk"]):
    print("holding", flush=True)
    sys.stdin.read()  # until the test closes our stdin
"""


@pytest.fixture
def held_by_another_process(tmp_path):
    """tmp_path/study, held by a run in another Python process until the test ends."""
    import sys

    out = tmp_path / "study"
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(out)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline() == "holding\n"
        yield out
    finally:
        assert holder.stdin is not None
        holder.stdin.close()
        holder.wait(timeout=60)


def _flock_free(folder: Path) -> bool:
    """Whether another open description of ``folder`` (as another process has) can lock it now."""
    import fcntl
    import os

    fd = os.open(folder, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return True
    except BlockingIOError:
        return False
    finally:
        os.close(fd)


def test_a_folder_another_process_is_running_in_is_refused_naming_that_run(held_by_another_process):
    """Two runs in one folder appended to one runs.jsonl, solved the same runs twice and
    overwrote each other's tables and provenance.json; the second now stops before writing."""
    out = held_by_another_process
    before = (out / "provenance.json").read_text()
    refusal = rf"^{re.escape(str(out))} is in use by another run \(jtraj robustness --tasks walk, begun \d{{4}}-.*Z\): wait for it to end, or write to another folder$"
    with pytest.raises(prov.FolderInUseError, match=refusal):
        with prov.recording(out, ["jtraj", "robustness", "--tasks", "big_jump"]):
            pytest.fail("the block ran")
    assert re.match(refusal, prov.in_use(out) or "")
    assert (out / "provenance.json").read_text() == before


def test_a_record_left_by_a_run_that_ended_names_no_one(tmp_path):
    """The refusal named the command of an unfinished record, also one a killed run left."""
    import fcntl
    import os

    out = tmp_path / "study"
    out.mkdir()
    (out / "provenance.json").write_text(json.dumps({"command": "jtraj robustness (killed last week)", "date_utc": "2026-11-30T00:00:00Z", "complete": False, "pid": 2**22 + 1}))
    fd = os.open(out, os.O_RDONLY)  # another open description: as another process's hold
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        assert prov.in_use(out) == f"{out} is in use by another run: wait for it to end, or write to another folder"
    finally:
        os.close(fd)
    assert prov.in_use(out) is None


def test_the_sweeps_and_the_command_line_refuse_it_before_touching_the_folder(held_by_another_process, capsys):
    from jtraj import cli, experiments

    out = held_by_another_process
    (out / "runs.jsonl").write_text("")
    (out / "table_iv.md").write_text("the other run's table\n")
    with pytest.raises(prov.FolderInUseError):  # (before it moved the other run's runs aside)
        experiments.robustness(["big_jump"], ["se3"], [0.1], replicates=1, out=out, resume=False, progress=None)
    with pytest.raises(prov.FolderInUseError):  # (before it removed the other run's table)
        experiments.compare(["big_jump"], ["se3"], out=out, progress=None)
    assert sorted(p.name for p in out.iterdir()) == ["provenance.json", "runs.jsonl", "table_iv.md"]
    code = cli.main(["robustness", "--tasks", "big_jump", "--params", "se3", "--sigmas", "0.1", "--replicates", "1", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == cli.EXIT_BAD_INPUT and err.startswith(f"jtraj robustness: {out} is in use by another run (jtraj robustness --tasks walk") and err.count("\n") == 1
    # a compare cell's folder in use: refused before the first cell is solved
    assert experiments.cell_folder_problem(out.parent, ["study"], ["x"]) is None  # (no such cell folder)
    (out.parent / "walk_se3").symlink_to(out)  # the cell folder walk_se3 is the held one
    assert (experiments.cell_folder_problem(out.parent, ["walk"], ["se3"]) or "").startswith(f"{out.parent / 'walk_se3'} is in use by another run")


def test_a_run_holds_its_folder_until_the_last_block_of_its_process_ends(tmp_path):
    out = tmp_path / "study"
    with prov.recording(out, ["jtraj", "compare"]) as record:
        assert not _flock_free(out) and prov.in_use(out) is None  # (this process's own)
        # a solve's or a sweep's with record_run inside: its end leaves the folder held
        with prov.recording(out, ["jtraj", "solve"]) as inner:
            prov.end_run(out, inner)
        assert not _flock_free(out)
        prov.end_run(out, record)
    assert _flock_free(out)
    with pytest.raises(RuntimeError, match="a fault mid-run"):
        with prov.recording(out, ["jtraj", "solve"]):
            assert not _flock_free(out)
            raise RuntimeError("a fault mid-run")
    assert _flock_free(out) and json.loads((out / "provenance.json").read_text())["complete"] is False
    # two threads' blocks: let go when the second ends
    import threading

    entered, leave = threading.Barrier(2), threading.Event()

    def thread():
        with prov.holding(out):
            entered.wait()
            leave.wait(30)

    t = threading.Thread(target=thread)
    t.start()
    with prov.holding(out):
        entered.wait()
    assert not _flock_free(out)
    leave.set()
    t.join()
    assert _flock_free(out)
    # a folder a block made and its run left empty is removed (a solve refused after the hold)
    with pytest.raises(ValueError):
        with prov.holding(tmp_path / "new"):
            raise ValueError
    assert not (tmp_path / "new").exists()


def test_a_made_folder_stays_while_another_block_holds_it(tmp_path):
    """Thread A made the folder, B held it too; A's end removed it (empty) while B held it, and
    another process could lock the folder made again in its place."""
    import threading

    out = tmp_path / "a" / "new"
    entered, b_in, a_done = threading.Event(), threading.Event(), threading.Event()

    def a():
        with prov.holding(out):
            entered.set()
            b_in.wait(30)
        a_done.set()

    t = threading.Thread(target=a)
    t.start()
    entered.wait(30)
    with prov.holding(out):
        b_in.set()
        a_done.wait(30)
        assert out.is_dir() and not _flock_free(out)
    t.join()
    # the last one out removes what the first made, parents too, where empty
    assert not (tmp_path / "a").exists()


def test_a_block_that_locked_nothing_does_not_end_another_blocks_hold(tmp_path, monkeypatch):
    """A block whose lock failed without an error (no descriptor left) still let go as it
    ended, and ended the hold of a block that took the folder meanwhile."""
    import os
    import threading

    out = tmp_path / "study"
    real_open = os.open
    failed = []

    def open_failing_once(path, flags, *args):
        if not failed:
            failed.append(path)
            raise OSError(24, "Too many open files")
        return real_open(path, flags, *args)

    monkeypatch.setattr(prov.os, "open", open_failing_once)
    x_in, y_in, x_done = threading.Event(), threading.Event(), threading.Event()

    def x():
        with prov.holding(out):  # locks nothing
            x_in.set()
            y_in.wait(30)
        x_done.set()

    t = threading.Thread(target=x)
    t.start()
    x_in.wait(30)
    with prov.holding(out):  # takes the lock
        y_in.set()
        x_done.wait(30)
        assert failed and not _flock_free(out)  # x's end left it held
    t.join()
    assert _flock_free(out)


def test_the_holder_is_named_while_its_process_lives(tmp_path, monkeypatch):
    """Another user's live process (os.kill says EPERM) was taken for dead; a record that is
    not an object crashed the refusal."""
    import os

    out = tmp_path / "study"
    out.mkdir()
    record = {"command": "jtraj robustness", "date_utc": "2026-12-07T00:00:00Z", "complete": False, "pid": os.getpid() + 1}
    (out / "provenance.json").write_text(json.dumps(record))

    def not_yours(pid, signal):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(prov.os, "kill", not_yours)
    assert prov._in_use_message(out) == f"{out} is in use by another run (jtraj robustness, begun 2026-12-07T00:00:00Z): wait for it to end, or write to another folder"
    (out / "provenance.json").write_text("[1, 2]")
    assert prov._in_use_message(out) == f"{out} is in use by another run: wait for it to end, or write to another folder"
