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
