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


@pytest.mark.parametrize("argv", [["jtraj", "compare"], ["python", "bench/solve.py", "walk"]])
def test_command_keeps_its_program(argv):
    assert prov.provenance(argv)["command"] == " ".join(argv)


def test_an_empty_command_line_is_recorded_as_empty():
    # argv=[] (no program name, as an embedding host may give) raised IndexError
    assert prov.provenance([])["command"] == ""
