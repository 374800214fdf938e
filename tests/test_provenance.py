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
    """A checkout is dirty when a tracked file changed or when a task, robot or module file the
    run loads is not tracked (``git status --untracked-files=no`` called a tree with a new
    tasks/*.toml clean, though the commit cannot give that task); files git ignores, and
    untracked files elsewhere, do not count."""
    def git(*args):
        subprocess.run(["git", "-C", str(tmp_path), *args], capture_output=True, check=True)

    for name, text in (("jtraj/provenance.py", ""), ("tasks/walk.toml", "a"), (".gitignore", "runs/\n")):
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
    assert prov.source()["dirty"] is False
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
