"""bench/quat3_norms.py: the norms it reads from an iterate, its table, its checks of the
arguments (the solves are the benchmark's)."""

from types import SimpleNamespace

import numpy as np
import pytest
from conftest import bench_module, refused


@pytest.fixture(scope="module")
def qn():
    return bench_module("quat3_norms")


def test_norms_are_those_of_the_interior_knots_rho(qn):
    # 4 knots of 9 variables each; q is the first 7 (position, then rho)
    Z = np.zeros((4, 9))
    Z[:, 3:7] = [[9.0, 0, 0, 0], [0, 3.0, 4.0, 0], [0.5, 0, 0, 0], [0, 0, 0, 7.0]]
    tr = SimpleNamespace(N=3, layout=SimpleNamespace(nz=9, split=lambda Z: {"q": Z[:, :7]}))
    np.testing.assert_allclose(qn.norms_of(tr, Z.ravel()), [5.0, 0.5])  # the end knots' 9 and 7 are left out


def test_table_has_one_row_per_solve(qn):
    base = dict(task="walk", iterations=50, constraint_violation=190.0, norm_start=[1.0, 1.0])
    records = [
        base | dict(unit_norm=False, status="not_converged", norm_end=[0.0333, 1.0], norm_range=[0.0283, 1.2], first_iter_above_2=None),
        base | dict(unit_norm=True, status="solved", iterations=18, constraint_violation=5.6e-12, norm_end=[1.0, 1.0], norm_range=[1.0, 2.5], first_iter_above_2=7),
    ]
    lines = qn.table(records).splitlines()
    assert len(lines) == 4 and lines[0].startswith("| task | norm row | status |")
    assert lines[2] == "| walk | no | not_converged | 50 | 1.9e+02 | 1 to 1 | 0.0333 to 1 | 0.0283 to 1.2 |  |"
    assert lines[3] == "| walk | yes | solved | 18 | 5.6e-12 | 1 to 1 | 1 to 1 | 1 to 2.5 | 7 |"


def test_unknown_tasks_are_refused(qn, capsys):
    refused(qn.main, ["big_jump", "moonwalk"], capsys, "unknown task(s) ['moonwalk']; expected some of [")
