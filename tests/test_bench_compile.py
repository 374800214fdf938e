"""bench/compile.py: its table."""

from conftest import bench_module


def test_table_gives_the_fastest_solve_and_names_the_flags():
    records = [
        dict(task="big_jump", flags="", build=36.04, program=42.26, times=[1.7, 1.65, 1.66], iterations=12),
        dict(task="big_jump", flags="--xla_backend_optimization_level=0", build=25.1, program=34.7, times=[6.2, 5.72], iterations=12),
    ]
    lines = bench_module("compile").table(records).splitlines()
    assert lines[0].startswith("| task | XLA_FLAGS |")
    assert lines[2] == "| big_jump | (none) | 36.0 | 42.3 | 1.65 | 12 |"
    assert lines[3] == "| big_jump | `--xla_backend_optimization_level=0` | 25.1 | 34.7 | 5.72 | 12 |"


def test_table_shows_the_status_of_a_solve_that_failed():
    """The child records each solve's status, the table left it out: a solve that stopped at its
    iteration limit showed its time and iterations as a solved one's."""
    records = [
        dict(task="big_jump", flags="", build=36.0, program=42.3, times=[1.7], iterations=12, status="solved"),
        dict(task="sideflip", flags="", build=20.0, program=30.0, times=[9.5], iterations=200, status="not_converged"),
    ]
    lines = bench_module("compile").table(records).splitlines()
    assert lines[2].endswith("| 1.70 | 12 |")
    assert lines[3].endswith("| 9.50 | 200 (not_converged) |")
