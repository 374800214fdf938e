"""bench/differentiate.py: its table, written with the run's provenance by ``--out``."""

from conftest import bench_module


def test_table_gives_each_figure_and_the_backward_pass():
    rec = dict(task="go2 hop", knots=9, n=594, m=638, repeat=3, knots_scale=1, cold_ms=815.0, cold_iterations=15, warm_ms=624.0, warm_iterations=12, system_ms=61.0, grad_ms=942.0)
    lines = bench_module("differentiate").table(rec).splitlines()
    assert lines[0] == "|  | ms | Ipopt iterations |"
    assert lines[2] == "| solve, cold (Ipopt from the task's warm start) | 815.0 | 15 |"
    assert lines[3] == "| solve, warm (re-solve from the solution) | 624.0 | 12 |"
    assert lines[5] == "| backward pass (grad minus its warm solve) | 318.0 |  |"  # grad less the warm solve
    assert lines[6] == "| grad of a loss through the solver, total | 942.0 |  |"
    assert lines[-1] == "Go2 hop, 9 knots: n = 594 variables, m = 638 constraints; the fastest of 3 runs, compile excluded."
