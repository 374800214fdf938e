"""bench/profile_solve.py: each record has its solve's status, and the table shows a solve that
did not succeed, with the committed table's rows as they were."""

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import bench_module

from jtraj.solvers.ipm import IpmStatus

RESULTS = Path(__file__).resolve().parents[1] / "results" / "profile_solve"


@pytest.fixture(scope="module")
def profile_solve():
    return bench_module("profile_solve")


def _record(profile_solve, **fields):
    phases = {p: 0.125 for p in profile_solve.PHASES}
    return dict(task="big_jump", knots=47, n=156, iterations=12, wall_s=1.45, thread_ms_per_iteration=125.0, share=phases) | fields


def test_the_committed_table_is_what_its_records_render(profile_solve):
    """The committed records (written before the status was recorded) render as committed."""
    records = json.loads((RESULTS / "profile_solve.json").read_text())
    assert profile_solve.table(records) == (RESULTS / "profile_solve.md").read_text()


def test_a_solve_that_did_not_succeed_shows_its_status(profile_solve):
    """The records had no status: a solve that stopped at its iteration limit was tabled as
    one that converged, its phases' shares read as a converged solve's."""
    lines = profile_solve.table([_record(profile_solve, status="solved"), _record(profile_solve, task="walk", iterations=50, status="max_iter")]).splitlines()
    assert lines[2].startswith("| big_jump | 47 x 156 | 12 | 1.45 | 125 | 12 % |")
    assert lines[3].startswith("| walk | 47 x 156 | 50 (max_iter) | 1.45 | 125 | 12 % |")


#: every termination of the interior point and the status jtraj's solve reports for it (the
#: comments of `IpmStatus` and `jtraj.solvers.Status`): a loop still running when it stopped is
#: an internal error, a line search failing repeatedly the solver's restoration failure, no
#: regularization giving the right inertia a step that could not be computed
SHARED_STATUS = {
    IpmStatus.RUNNING: "internal_error",
    IpmStatus.CONVERGED: "solved",
    IpmStatus.MAX_ITER: "max_iter",
    IpmStatus.LINE_SEARCH_FAILED: "restoration_failed",
    IpmStatus.NUMERICAL_ERROR: "numerical_error",
    IpmStatus.INERTIA_FAILED: "step_computation_failed",
}


def test_every_ipm_status_has_its_expected_status():
    assert set(SHARED_STATUS) == set(IpmStatus)  # a new termination needs its row here


@pytest.mark.parametrize("ipm", list(IpmStatus), ids=lambda s: s.name)
def test_the_status_is_the_one_jtraj_solve_gives(profile_solve, ipm):
    """The compiled program's IpmStatus code (a JAX scalar) as `jtraj.solvers.Status`'s value,
    as every other benchmark records ``Result.status.value``."""
    assert profile_solve.status_of(SimpleNamespace(status=np.int32(int(ipm)))) == SHARED_STATUS[ipm]
