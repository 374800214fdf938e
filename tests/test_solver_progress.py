"""What `jtraj.solve` prints for a solve (progress=a stream), on the transcription tests' Go2
hop; a backend object stands in for a solver where the test needs a given outcome."""

import io

import numpy as np
import pytest
from test_transcription import HOP

from jtraj import solve, solvers
from jtraj.solvers.base import bind, invalid_problem

WHY = "inconsistent bounds: g_lower[3]=1.0 > g_upper[3]=0.0 (1 such g bound(s))"


class Refusing(solvers.IpoptSolver):
    """Refuses every problem as `invalid_problem` does for inconsistent bounds."""

    def solve(self, nlp, x0, theta=None, options=None, callback=None):
        return invalid_problem(bind(nlp, theta), np.asarray(x0, float), WHY, nlp.m, nlp, callback)


def test_an_invalid_problem_prints_the_bound_at_fault():
    """The lines after the summary gave the status's general message ("inconsistent bounds or
    too few degrees of freedom") and not the solver's own, which names the bound."""
    stream = io.StringIO()
    result = solve(HOP, solver=Refusing(), progress=stream, keep_trajectory=False)
    assert result.solver_status is solvers.Status.INVALID_PROBLEM and result.status_msg == WHY
    lines = stream.getvalue().splitlines()
    stopped = lines.index(f"  ipopt stopped: invalid_problem ({solvers.Status.INVALID_PROBLEM.message})")
    assert lines[stopped + 1] == f"  {WHY}"


def test_the_largest_violations_put_a_nan_group_first_and_keep_the_order(monkeypatch):
    """A group with a NaN row (``violation_by_group`` passes NaN through) left the sort's order to
    the dict's: a group at 0 came first and a larger one was dropped."""
    from jtraj.nlp import KnotNLP

    groups = {"bounds": 0.0, "dynamics": float("nan"), "friction": 3.0, "contact": 7.0}
    monkeypatch.setattr(KnotNLP, "violation_by_group", lambda self, x, theta=None: dict(groups))
    stream = io.StringIO()
    solve(HOP, solver=Refusing(), progress=stream, keep_trajectory=False)
    assert "  largest violations: dynamics nan, contact 7.00e+00, friction 3.00e+00" in stream.getvalue().splitlines()


def test_printed_progress_says_when_it_builds_a_tasks_nlp(monkeypatch):
    """A task's first solve built and compiled its NLP (tens of seconds on a whole-body task)
    before its first line; a line says so now, and only where the NLP is not built yet."""
    import dataclasses

    import jtraj.solver

    class Built(Exception):
        pass

    stream = io.StringIO()

    def stop(*args, **kwargs):
        raise Built

    monkeypatch.setattr(jtraj.solver, "prepare", stop)
    fresh = dataclasses.replace(HOP, name="hop_not_built_yet")
    with pytest.raises(Built):
        solve(fresh, progress=stream)
    assert stream.getvalue() == "jtraj: building hop_not_built_yet's NLP (SE(3) tangent, compact variables) and compiling its functions ...\n"
    monkeypatch.setattr(jtraj.solver, "_is_prepared", lambda *a: True)
    stream = io.StringIO()
    with pytest.raises(Built):
        solve(fresh, progress=stream)
    assert stream.getvalue() == ""
    monkeypatch.undo()
    # a task solved before is built: no line (HOP, solved by the tests above in this process)
    jtraj.solver.prepare(HOP)
    assert jtraj.solver._is_prepared(HOP, "se3", "compact")
