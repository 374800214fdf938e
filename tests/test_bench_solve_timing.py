"""bench/solve.py's timed region: what is compiled before the clock of a variant starts."""

from types import SimpleNamespace

import numpy as np
import pytest
from conftest import bench_module


def _outcome():
    from jtraj.result import Outcome

    return SimpleNamespace(status=Outcome.SOLVED, success=True, iterations=3, time_s=1.0, time_derivatives=0.1, time_solver=0.9, cost=0.0, constraint_violation=0.0)


class _FakeNLP:
    m = 3
    theta = "nlp theta"

    def __init__(self, events: list):
        self.events = events

    def build_hessian(self):
        self.events.append("build_hessian")

    def hessian(self, x, lam, obj_factor, theta):
        self.events.append(("hessian", np.asarray(x).shape, np.asarray(lam).shape, obj_factor, theta))
        return np.zeros(2)


class _FakeTranscription:
    def resolve_theta(self, theta):
        assert theta is None
        return "resolved theta"

    def warm_start(self, theta=None):
        assert theta == "resolved theta"
        return np.zeros((2, 2))


@pytest.mark.parametrize(("variant", "compiled"), [("exact", True), ("paper", False), ("lean", False)])
def test_the_exact_hessian_is_compiled_before_the_timed_solve(monkeypatch, variant, compiled):
    """The exact variant's Hessian was first called inside Ipopt's timed solve: `prepare`
    compiles the objective, gradient, constraints and Jacobian, not the Hessian, so its compile
    counted as solve time. It is now built and evaluated once, at the warm start and the theta
    the solve uses, before `solve` runs (and only for the variant that uses it)."""
    bench = bench_module("solve")
    events: list = []
    prepared: list = []

    def fake_prepare(task, param, variables="compact"):
        prepared.append((task, param, variables))
        return type("Prep", (), {"nlp": _FakeNLP(events), "transcription": _FakeTranscription()})()

    def fake_solve(task, param, **kwargs):
        events.append("solve")
        assert kwargs["exact_hessian"] == (variant == "exact")
        return _outcome()

    monkeypatch.setattr(bench, "prepare", fake_prepare)
    monkeypatch.setattr(bench, "solve", fake_solve)
    bench.run_variant("big_jump", "se3", variant, {}, {})
    if compiled:
        assert prepared == [("big_jump", "se3", "paper")]
        assert events == ["build_hessian", ("hessian", (4,), (3,), 1.0, "resolved theta"), "solve"]
    else:
        assert events == ["solve"]


@pytest.mark.parametrize(("variants", "variables"), [("paper", "paper"), ("lean,paper", "lean"), ("jtraj", "compact"), ("exact", "paper")])
def test_the_nlp_compiled_first_is_the_first_variants(monkeypatch, tmp_path, variants, variables):
    """main() compiled the default (compact) variables' NLP before the variants, whichever they
    were: with --variants paper, a compile for nothing, recorded as the task's compile_s."""
    import json

    bench = bench_module("solve")
    prepared: list = []

    def fake_prepare(task, param, variables="compact"):
        prepared.append(variables)
        return type("Prep", (), {"nlp": type("NLP", (), {"n": 10, "m": 5})})()

    def fake_variant(task, param, name, extra, extra_jtraj):
        return dict(variant=name, status="solved", success=True, iterations=3, time_s=1.0, time_derivatives=0.0, time_ipopt=1.0, time_linear_solver=None, cost=0.0, constraint_violation=0.0)

    monkeypatch.setattr(bench, "prepare", fake_prepare)
    monkeypatch.setattr(bench, "run_variant", fake_variant)
    bench.main(["big_jump", "--variants", variants, "--no-peer", "--out", str(tmp_path)])
    assert prepared == [variables]
    assert json.loads((tmp_path / "speed.json").read_text())[0]["compile_variables"] == variables
