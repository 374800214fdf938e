"""bench/replicates.py with a fake solver: ``--out F.json`` is one JSON file written atomically
with the run's provenance, an output that cannot be written is refused before any solve, and
the last line (README and scripts read it) is unchanged."""

import json
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import bench_module


def _fake_run(monkeypatch, mod, replicates: int = 2):
    sol = SimpleNamespace(converged=True, x=None, status=SimpleNamespace(value="solved"), stats=SimpleNamespace(iterations=7, time_total=3.0))
    backend = SimpleNamespace(name="jtraj", options=lambda merged: merged, solve_batch=lambda nlp, starts, theta, strategy, options: ([sol] * len(starts), 1.0, 5.0))
    tr = SimpleNamespace(resolve_theta=lambda theta: None, warm_start=lambda: np.zeros((3, 4)), decode=lambda x, theta: SimpleNamespace(base_xyz_wxyz=None), task=SimpleNamespace(max_iter=50, flip_axis=None, flip_turns=0))
    nlp = SimpleNamespace(violation=lambda x, theta: 0.0)
    monkeypatch.setattr(mod, "prepare", lambda task, param: SimpleNamespace(transcription=tr, nlp=nlp))
    monkeypatch.setattr(mod.solvers, "get", lambda name: backend)
    monkeypatch.setattr(mod, "noisy_warm_starts", lambda x0, sigmas, n, seed: np.zeros((1, n, *x0.shape)))
    monkeypatch.setattr(mod, "check_motion", lambda *a: SimpleNamespace(ok=True))
    ipopt = SimpleNamespace(time_s=10.0, iterations=11, constraint_violation=1e-9, success=True, status=SimpleNamespace(value="solved"))
    monkeypatch.setattr(mod, "solve", lambda *a, **k: ipopt)


def test_out_is_written_as_the_other_benchmarks_results(monkeypatch, capsys, tmp_path):
    """``--out DIR/F.json``: F.json with the run's provenance inside (as before), and, as
    `jtraj.provenance.write_results` writes every other benchmark's, DIR/F.md and DIR/provenance.json."""
    mod = bench_module("replicates")
    _fake_run(monkeypatch, mod)
    out = tmp_path / "replicates.json"
    mod.main(["--replicates", "2", "--strategies", "vmap", "--out", str(out)])
    assert capsys.readouterr().out.splitlines()[-1] == "replicates: vmapped 1.00 s, sequential 20.00 s, speedup 20.00 (sequential: Ipopt)"
    report = json.loads(out.read_text())
    assert (report["vmapped_s"], report["ipopt_sequential_s"], report["speedup"]) == (1.0, 20.0, {"vmap": 20.0})
    command = f"python bench/replicates.py --replicates 2 --strategies vmap --out {out}"
    assert report["provenance"]["command"] == command
    assert json.loads((tmp_path / "provenance.json").read_text())["command"] == command
    table = (tmp_path / "replicates.md").read_text().splitlines()
    assert table[0] == "| strategy | batch | compile (s) | solve (s) | per replicate (s) | converged | iterations (mean / max) |"
    assert table[2] == "| vmap | 2 | 5.0 | 1.00 | 0.500 | 2/2 | 7.0 / 7 |"
    assert table[-1] == "replicates: vmapped 1.00 s, sequential 20.00 s, speedup 20.00 (sequential: Ipopt)"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["provenance.json", "replicates.json", "replicates.md"]  # no temporary file left


@pytest.mark.parametrize("kind", ["folder", "unwritable", "not json"])
def test_an_out_that_cannot_be_written_is_refused_before_any_solve(monkeypatch, capsys, tmp_path, kind):
    mod = bench_module("replicates")

    def no_work(*args, **kwargs):
        raise AssertionError("solved before refusing --out")

    monkeypatch.setattr(mod, "prepare", no_work)
    out = {"folder": str(tmp_path), "unwritable": "/proc/no/replicates.json", "not json": str(tmp_path / "replicates.txt")}[kind]
    with pytest.raises(SystemExit) as exc:
        mod.main(["--out", out])
    assert exc.value.code == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert f"--out: '{out}': " in last
    assert {"folder": "is a folder; expected the path of a JSON file", "unwritable": "cannot create a file in", "not json": "expected the path of a JSON file, F.json"}[kind] in last


def test_the_provenance_record_is_built_once(monkeypatch, tmp_path):
    """F.json's provenance and provenance.json were two records, built one after the other
    (their dates could differ, and git ran twice for the source): one record now, in both."""
    import jtraj.provenance

    mod = bench_module("replicates")
    _fake_run(monkeypatch, mod)
    built: list[list[str]] = []

    def record(argv=None):
        built.append(argv)
        return {"command": " ".join(argv), "record": len(built)}

    monkeypatch.setattr(mod, "provenance", record)
    monkeypatch.setattr(jtraj.provenance, "provenance", record)
    out = tmp_path / "runs" / "replicates.json"  # a folder to create
    mod.main(["--replicates", "2", "--strategies", "vmap", "--out", str(out)])
    assert len(built) == 1
    assert json.loads(out.read_text())["provenance"] == json.loads((out.parent / "provenance.json").read_text()) == {"command": f"python bench/replicates.py --replicates 2 --strategies vmap --out {out}", "record": 1}
    assert sorted(p.name for p in out.parent.iterdir()) == ["provenance.json", "replicates.json", "replicates.md"]


@pytest.mark.parametrize("failed", ["jtraj", "ipopt"])
def test_no_speedup_where_a_replicate_failed(monkeypatch, capsys, tmp_path, failed):
    """A replicate that failed on either side (a solve stopped at its iteration limit) made the
    speedup one of different work, printed all the same: the line gives the counts instead."""
    mod = bench_module("replicates")
    _fake_run(monkeypatch, mod)
    if failed == "jtraj":
        sols = [SimpleNamespace(converged=ok, x=None, status=SimpleNamespace(value="solved" if ok else "not_converged"), stats=SimpleNamespace(iterations=7, time_total=3.0)) for ok in (True, False)]
        monkeypatch.setattr(mod.solvers, "get", lambda name: SimpleNamespace(name="jtraj", options=lambda merged: merged, solve_batch=lambda nlp, starts, theta, strategy, options: (sols[: len(starts)], 1.0, 5.0)))
    else:
        runs = iter([True, False])
        monkeypatch.setattr(mod, "solve", lambda *a, **k: SimpleNamespace(time_s=10.0, iterations=11, constraint_violation=1e-9, success=next(runs), status=SimpleNamespace(value="solved")))
    out = tmp_path / "replicates.json"
    mod.main(["--replicates", "2", "--strategies", "vmap", "--out", str(out)])
    counts = "jtraj 1/2 converged, Ipopt 2/2" if failed == "jtraj" else "jtraj 2/2 converged, Ipopt 1/2"
    assert capsys.readouterr().out.splitlines()[-1] == f"replicates: vmapped 1.00 s, sequential 20.00 s, speedup none ({counts}) (sequential: Ipopt)"
    assert json.loads(out.read_text())["speedup"] == {}
