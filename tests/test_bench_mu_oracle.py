"""bench/mu_oracle.py solves with the task's iteration limit, as `jtraj.solve` does (IpmOptions'
own default is 200; the walk's limit is 50), with each barrier rule's options."""

from types import SimpleNamespace

from conftest import bench_module

from jtraj import solver as solver_module
from jtraj import solvers


def test_each_rule_is_solved_with_the_tasks_max_iter(monkeypatch, capsys):
    mod = bench_module("mu_oracle")
    seen = []

    class FakeSolver:
        def solve(self, nlp, x0, theta, options):
            seen.append(options)
            return SimpleNamespace(status=SimpleNamespace(value="solved"), stats=SimpleNamespace(time_total=1.0, iterations=10, obj_evals=12))

    real = solvers.get("jtraj")
    fake = FakeSolver()
    fake.options = real.options  # solver_options builds the real options object
    prep = SimpleNamespace(transcription=SimpleNamespace(task=SimpleNamespace(max_iter=50), warm_start=lambda: None), nlp=SimpleNamespace(theta=None))
    monkeypatch.setattr(solver_module, "prepare", lambda task, param: prep)
    monkeypatch.setattr(solvers, "get", lambda name: fake)
    mod.main(["walk", "--repeat", "1"])
    assert [o.max_iter for o in seen] == [50, 50]
    assert [(o.mu_oracle, o.adaptive_mu_globalization) for o in seen][1] == ("loqo", "kkt-error")
    assert seen[0].mu_oracle != "loqo"
    assert capsys.readouterr().out.count("walk ") == 2


def test_out_writes_every_solve_with_provenance(monkeypatch, tmp_path):
    """The figures were only printed: no results with the run's provenance."""
    import json

    mod = bench_module("mu_oracle")
    times = iter([2.0, 3.0, 2.5, 3.5])

    class FakeSolver:
        def solve(self, nlp, x0, theta, options):
            return SimpleNamespace(status=SimpleNamespace(value="solved"), stats=SimpleNamespace(time_total=next(times), iterations=10, obj_evals=20))

    fake = FakeSolver()
    fake.options = solvers.get("jtraj").options
    prep = SimpleNamespace(transcription=SimpleNamespace(task=SimpleNamespace(max_iter=50), warm_start=lambda: None), nlp=SimpleNamespace(theta=None))
    monkeypatch.setattr(solver_module, "prepare", lambda task, param: prep)
    monkeypatch.setattr(solvers, "get", lambda name: fake)
    out = tmp_path / "out"
    mod.main(["walk", "--repeat", "2", "--out", str(out)])
    records = json.loads((out / "mu_oracle.json").read_text())
    assert [(r["repeat"], r["time_s"]) for r in records] == [(1, 2.0), (1, 3.0), (2, 2.5), (2, 3.5)]
    assert records[1]["rule"] == "loqo + kkt-error"
    lines = (out / "mu_oracle.md").read_text().splitlines()
    assert lines[3] == "| walk | loqo + kkt-error | 1 | solved | 10 | 3.00 | 0.300 | 20 | 0.150 |"
    assert "mu_oracle.py walk --repeat 2" in json.loads((out / "provenance.json").read_text())["command"]
