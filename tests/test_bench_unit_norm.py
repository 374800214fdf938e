"""bench/unit_norm.py: its table and its checks of the arguments (the solves are the benchmark's)."""

import pytest
from conftest import bench_module, refused


@pytest.fixture(scope="module")
def un():
    return bench_module("unit_norm")


def test_table_has_one_row_per_solve(un):
    records = [
        dict(task="big_jump", parameterization="quat3", unit_norm=False, status="not_converged", iterations=200, cost=0.0, constraint_violation=40.0, turns=None, time_s=53.71),
        dict(task="sideflip", parameterization="quat3", unit_norm=True, status="solved", iterations=31, cost=0.0, constraint_violation=5.9e-8, turns=-1.0, time_s=9.14),
    ]
    lines = un.table(records).splitlines()
    assert lines[0].startswith("| task | parameterization | norm row |") and len(lines) == 4
    assert lines[2] == "| big_jump | quat3 | no | not_converged | 200 | 0 | 4.0e+01 |  | 53.7 |"
    assert lines[3] == "| sideflip | quat3 | yes | solved | 31 | 0 | 5.9e-08 | -1.00 | 9.1 |"


@pytest.mark.parametrize("params", ["se3", "quat3,euler", ""])
def test_only_quaternion_charts_are_accepted(un, params, capsys):
    # argparse's usage line names --params too: the message (its error line) is the bench's own
    refused(un.main, ["big_jump", "--params", params], capsys, f"--params: expected quaternion charts (quat1, quat2, quat3), got {params!r}")
