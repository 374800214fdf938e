"""bench/solve.py: what is compiled before the variants (the exact Hessian is compiled before the clock by the Ipopt backend itself: tests/test_solvers.py)."""

import pytest
from conftest import bench_module


def _fake_solves(monkeypatch, bench) -> list[tuple]:
    """bench/solve.py's prepare and run_variant answered at once; returns the list of their
    calls, ``("prepare", task, variables)`` and ``("variant", task, name)``."""
    calls: list[tuple] = []

    def fake_prepare(task, param, variables="compact"):
        calls.append(("prepare", task, variables))
        return type("Prep", (), {"nlp": type("NLP", (), {"n": 10, "m": 5})})()

    def fake_variant(task, param, name, extra, extra_jtraj):
        calls.append(("variant", task, name))
        return dict(variant=name, status="solved", success=True, iterations=3, time_s=1.0, time_derivatives=0.0, time_ipopt=1.0, time_linear_solver=None, cost=0.0, constraint_violation=0.0)

    monkeypatch.setattr(bench, "prepare", fake_prepare)
    monkeypatch.setattr(bench, "run_variant", fake_variant)
    return calls


@pytest.mark.parametrize(("variants", "variables"), [("paper", "paper"), ("lean,paper", "lean"), ("jtraj", "compact"), ("exact", "paper")])
def test_the_nlp_compiled_first_is_the_first_variants(monkeypatch, tmp_path, variants, variables):
    """main() compiled the default (compact) variables' NLP before the variants, whichever they
    were: with --variants paper, a compile for nothing, recorded as the task's compile_s."""
    import json

    bench = bench_module("solve")
    calls = _fake_solves(monkeypatch, bench)
    bench.main(["big_jump", "--variants", variants, "--no-peer", "--out", str(tmp_path)])
    assert [c[2] for c in calls if c[0] == "prepare"] == [variables]
    assert json.loads((tmp_path / "speed.json").read_text())[0]["compile_variables"] == variables


def test_the_linear_solvers_time_is_read_from_ipopts_timing_table():
    """speed.json's time_linear_solver is the wall time (not the CPU time) of Ipopt's
    StdAugSystemSolverMultiSolve line, None where Ipopt printed no timing table."""
    bench = bench_module("solve")
    table = (
        "OverallAlgorithm....................:      0.005 (sys:      0.000 wall:      0.009)\n"
        " StdAugSystemSolverMultiSolve.......:      0.002 (sys:      0.000 wall:      0.003)\n"
        " LinearSystemBackSolve..............:      0.004 (sys:      0.000 wall:      0.005)\n"
    )
    assert bench.linear_solver_time(table) == 0.003
    assert bench.linear_solver_time("EXIT: Optimal Solution Found.\n") is None


def test_robot_and_code_costs_reach_the_solved_problem_and_the_table(monkeypatch, tmp_path):
    """The public code solves Talos as its talos_full_v2 with its own walk and back-flip costs:
    ``--robot talos=talos_full --code-costs`` gives jtraj's side that problem (the table's task
    cell and the JSON say so); bench/solve.py had neither, and compared big_jump on another Talos."""
    import json

    bench = bench_module("solve")
    calls = _fake_solves(monkeypatch, bench)
    bench.main(["walk", "sideflip", "--variants", "jtraj", "--no-peer", "--robot", "talos=talos_full", "--code-costs", "--out", str(tmp_path)])
    walk, _, sideflip, _ = [task for _, task, _ in calls]  # each task's prepare, then its variant
    assert walk.robot == "talos_full" and walk.configuration_weight == 1e-6  # the code's walk.py weight
    assert sideflip.robot == "go2"  # not on Talos: its own robot
    records = json.loads((tmp_path / "speed.json").read_text())
    assert records[0]["robots"] == {"talos": "talos_full"} and records[0]["code_costs"] is True
    table = (tmp_path / "speed.md").read_text()
    # the side-flip's costs are the code's without a change: its cell says nothing
    assert "| walk (talos_full, code's costs) | jtraj |" in table and "| sideflip | jtraj |" in table
    bench.main(["big_jump", "--variants", "jtraj", "--no-peer"])
    assert calls[-1][1] == "big_jump"  # without them: the built-in task, by name
