"""The benchmarks that rewrite their results folder after each task (bench/solve.py,
hessians.py, options.py, fatrop.py): a run stopped part-way left a folder that looked finished.
Their provenance.json says ``"complete": false`` while tasks remain, true after the last one.
Fakes stand for every solve; each second task's fake reads what the first task left."""

import json
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import bench_module

from jtraj.result import Outcome


def _record(argv=None):
    """A provenance record without git or the JAX devices."""
    return {"command": " ".join(argv), "date_utc": "2026-01-01T00:00:00Z"}


def _prep():
    tr = SimpleNamespace(resolve_theta=lambda theta: None, warm_start=lambda theta=None: np.zeros((2, 3)), task=SimpleNamespace(max_iter=50))
    return SimpleNamespace(transcription=tr, nlp=SimpleNamespace(n=6, m=4))


def _solve_fakes(mod, seen):
    """bench/solve.py: `prepare` and `run_variant`."""

    def variant(task, param, name, extra, extra_jtraj):
        seen(task)
        return dict(variant=name, status="solved", success=True, iterations=3, time_s=1.0, time_derivatives=0.1, time_ipopt=0.9, time_linear_solver=None, cost=0.0, constraint_violation=0.0)

    return {"prepare": lambda *a, **k: SimpleNamespace(nlp=SimpleNamespace(n=6, m=4)), "run_variant": variant}


def _hessians_fakes(mod, seen):
    def run(tasks, hessians, param, variables):
        seen(tasks[0])
        return [dict(task=tasks[0], hessian=h, status="solved", iterations=3, cost=0.0, constraint_violation=0.0, turns=None, time_s=1.0, time_compile_s=2.0) for h in hessians]

    return {"run": run}


def _options_fakes(mod, seen):
    def solve(task, param, **kwargs):
        seen(task)
        return SimpleNamespace(time_compile=2.0, time_s=1.0, iterations=3, status=Outcome.SOLVED, cost=0.0, constraint_violation=0.0)

    real = mod.measure
    return {"measure": lambda task, variants, rounds, param, variables: real(task, variants, rounds, param, variables, solve=solve)}


def _fatrop_fakes(mod, seen):
    form = SimpleNamespace(N=1, nx=[2, 2], nu=[1, 1], ng=[1, 1], nlp=SimpleNamespace(n=6, m=4), dropped={})

    def fatrop(form, x0, theta, tol, max_iter, print_level, hessian):
        return dict(solver="fatrop", status="0", success=True, iterations=3, time_s=1.0, time_derivatives=0.5, time_solver=0.5, cost=0.0, constraint_violation=0.0, x=None)

    def prepare(task, param):
        seen(task)
        return _prep()

    return {"prepare": prepare, "stage_form": lambda nlp: form, "drop_dependent": lambda form, x0, theta, rtol: form, "solve_fatrop": fatrop}


#: script, its results' name, its command line before the tasks and --out, and its fakes
SCRIPTS = [
    ("solve", "speed", ["--no-peer", "--variants", "jtraj"], _solve_fakes),
    ("hessians", "hessians", ["--hessians", "lbfgs"], _hessians_fakes),
    ("options", "options", ["--variant", "default", "--rounds", "1"], _options_fakes),
    ("fatrop", "fatrop", ["--no-ipopt"], _fatrop_fakes),
]


@pytest.mark.parametrize(("script", "name", "options", "fakes"), SCRIPTS, ids=[s[0] for s in SCRIPTS])
def test_the_provenance_says_whether_every_task_was_done(monkeypatch, capsys, tmp_path, script, name, options, fakes):
    if script == "fatrop":
        pytest.importorskip("casadi")
    import jtraj.provenance

    mod = bench_module(script)
    out = tmp_path / "out"
    left: list[tuple[str, bool, list[str]]] = []  # (task, its folder's provenance "complete", the tasks its json holds)

    def seen(task):
        # what a run stopped now (before this task's files) would leave
        if (out / "provenance.json").exists():
            records = json.loads((out / f"{name}.json").read_text())
            left.append((task, json.loads((out / "provenance.json").read_text())["complete"], sorted({r["task"] for r in records})))

    for attr, fake in fakes(mod, seen).items():
        monkeypatch.setattr(mod, attr, fake)
    monkeypatch.setattr(jtraj.provenance, "provenance", _record)
    argv = ["walk", "big_jump", *options, "--out", str(out)]
    mod.main(argv)
    assert left and {task for task, _, _ in left} == {"big_jump"}
    assert all(not complete and tasks == ["walk"] for _, complete, tasks in left)
    prov = json.loads((out / "provenance.json").read_text())
    assert prov["complete"] is True
    assert prov["command"] == " ".join(["python", f"bench/{script}.py", *argv])
    assert sorted({r["task"] for r in json.loads((out / f"{name}.json").read_text())}) == ["big_jump", "walk"]


@pytest.mark.parametrize(("script", "name", "options", "fakes"), SCRIPTS, ids=[s[0] for s in SCRIPTS])
def test_one_task_is_complete_at_once(monkeypatch, capsys, tmp_path, script, name, options, fakes):
    if script == "fatrop":
        pytest.importorskip("casadi")
    import jtraj.provenance

    mod = bench_module(script)
    for attr, fake in fakes(mod, lambda task: None).items():
        monkeypatch.setattr(mod, attr, fake)
    monkeypatch.setattr(jtraj.provenance, "provenance", _record)
    mod.main(["walk", *options, "--out", str(tmp_path)])
    assert json.loads((tmp_path / "provenance.json").read_text())["complete"] is True
    # and the results file holds the task's record, with what its fake solve returned
    records = json.loads((tmp_path / f"{name}.json").read_text())
    assert [r["task"] for r in records] == ["walk"]  # one solve: one variant, Hessian or solver
    assert ITERATIONS[script](records[0]) == 3


#: where each script's record keeps its solve's iterations (3 in every fake above)
ITERATIONS = {
    "solve": lambda r: r["variants"][0]["iterations"],
    "hessians": lambda r: r["iterations"],
    "options": lambda r: r["iterations"][0],
    "fatrop": lambda r: r["solvers"][0]["iterations"],
}
