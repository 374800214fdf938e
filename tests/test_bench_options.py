"""bench/options.py with a fake solve: the variants alternate ABBA after one compile solve each,
the table's ratio is of the medians, and bad variants are refused with the option's message."""

from types import SimpleNamespace

import pytest
from conftest import bench_module, refused

from jtraj.cli import InputError
from jtraj.result import Outcome


def fake_solver(times):
    calls = []

    def solve(task, param, *, variables, solver, options, progress, keep_trajectory):
        assert (solver, progress, keep_trajectory) == ("jtraj", None, False)
        name = options.get("residual_ratio_max", "base")
        calls.append(name)
        return SimpleNamespace(time_compile=2.0, time_s=times[name].pop(0), iterations=11, status=Outcome.SOLVED, cost=0.5, constraint_violation=1e-9)

    return solve, calls


def test_variants_alternate_and_ratio_is_of_medians():
    bench = bench_module("options")
    variants = [bench.parse_variant("default"), bench.parse_variant("loose=residual_ratio_max:1e-6")]
    assert variants == [("default", {}), ("loose", {"residual_ratio_max": 1e-6})]
    # per variant: the compile solve, then three timed ones
    solve, calls = fake_solver({"base": [9.0, 1.0, 3.0, 2.0], 1e-6: [9.0, 1.0, 0.5, 4.0]})
    recs = bench.measure("big_jump", variants, rounds=3, solve=solve)
    assert calls == ["base", 1e-6, "base", 1e-6, 1e-6, "base", "base", 1e-6]
    assert [r["times_s"] for r in recs] == [[1.0, 3.0, 2.0], [1.0, 0.5, 4.0]]
    assert [r["median_s"] for r in recs] == [2.0, 1.0]
    assert [r["speedup"] for r in recs] == [1.0, 2.0]
    assert recs[0]["time_compile_s"] == 2.0
    lines = bench.table(recs).splitlines()
    assert lines[2] == "| big_jump | default | (defaults) | solved | 11 | 0.5 | 1.0e-09 | 2.000 | 1.000-3.000 | 1.00x |"
    assert lines[3] == "| big_jump | loose | residual_ratio_max=1e-06 | solved | 11 | 0.5 | 1.0e-09 | 1.000 | 0.500-4.000 | 2.00x |"


def test_parse_variant_values_and_errors(capsys):
    bench = bench_module("options")
    assert bench.parse_variant("a=refine_steps:0,feasibility_polish_tol:none,delta_c_mu_scaled:false") == (
        "a", {"refine_steps": 0, "feasibility_polish_tol": None, "delta_c_mu_scaled": False})
    with pytest.raises(InputError, match="no_such_option"):
        bench.parse_variant("a=no_such_option:1")
    with pytest.raises(ValueError, match="residual_ratio_max"):
        bench.parse_variant("a=residual_ratio_max:-1")
    with pytest.raises(ValueError, match="OPTION:VALUE"):
        bench.parse_variant("a=refine_steps")
    capsys.readouterr()
    refused(bench.main, ["big_jump", "--variant", "a", "--variant", "a"], capsys, "--variant names must differ")


def test_no_ratio_where_either_solve_did_not_do_the_task():
    """A variant stopped at the iteration limit got a ratio (0.11x in results/delta_c_variants/
    fixed/), read as that variant being so much slower to a solution it never reached."""
    bench = bench_module("options")

    def row(task, variant, status, speedup):
        return dict(task=task, variant=variant, options={}, status=status, iterations=[200], cost=0.0, constraint_violation=1e-9, median_s=1.0, times_s=[1.0], speedup=speedup)

    recs = [row("a", "default", "solved", 1.0), row("a", "v", "not_converged", 0.11), row("b", "default", "converged_but_task_failed", 1.0), row("b", "v", "solved", 2.0)]
    ratios = [line.rsplit("|", 2)[1].strip() for line in bench.table(recs).splitlines()[2:6]]
    assert ratios == ["1.00x", "none (not_converged)", "none (converged_but_task_failed)", "none (baseline converged_but_task_failed)"]
