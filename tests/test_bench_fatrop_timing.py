"""bench/fatrop.py's "JAX eval" column: the time of the callbacks' whole bodies (JAX and the
host's work on the values: reordering, the multipliers mapped to the rows, casadi.DM), as its
docstring says; it held the JAX calls alone, and the host's work counted as FATROP's own.
A fake two-variable stage NLP: no compile, no solve."""

import time
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import bench_module

casadi = pytest.importorskip("casadi")


def _evaluator(F):
    rows, cols = np.array([0, 1, 1]), np.array([0, 0, 1])
    nlp = SimpleNamespace(
        n=2, m=2, jac_rows=rows, jac_cols=cols, hess_rows=rows, hess_cols=cols, build_hessian=lambda: None,
        objective=lambda x, theta: float(x @ x), constraints=lambda x, theta: np.asarray(x), gradient=lambda x, theta: 2 * np.asarray(x),
        jacobian=lambda x, theta: np.ones(3), hessian=lambda x, lam, obj_factor, theta: np.array([2.0, 0.0, 2.0]),
    )
    return F._Evaluator(SimpleNamespace(nlp=nlp, perm=np.array([1, 0])), theta=None)


def test_jax_eval_holds_the_host_work_of_the_callbacks(monkeypatch):
    F = bench_module("fatrop")
    ev = _evaluator(F)
    oracle = F._callback_class()(ev)
    hess = oracle.get_factory("nlp_hess_l", ["x", "p", "lam:f", "lam:g"], ["hess:gamma:x:x"], {}, {})
    real_lam = ev._lam

    def slow_lam(lam):  # the host's reordering of the multipliers, made slow
        time.sleep(0.2)
        return real_lam(lam)

    monkeypatch.setattr(ev, "_lam", slow_lam)
    ev.seconds = 0.0
    H = hess(casadi.DM([1.0, 2.0]), casadi.DM(0, 1), casadi.DM(1.0), casadi.DM([0.5, -0.5]))
    np.testing.assert_array_equal(np.asarray(H.full()), [[2.0, 0.0], [0.0, 2.0]])
    assert ev.seconds >= 0.2
    assert ev.counts == {"hess": 1}
    # the NLP's own callback (f, g) too
    ev.seconds = 0.0
    f, g = oracle(casadi.DM([1.0, 2.0]), casadi.DM(0, 1))
    assert float(f) == 5.0 and np.asarray(g).ravel().tolist() == [2.0, 1.0]
    assert ev.seconds > 0 and ev.counts == {"hess": 1, "f": 1, "g": 1}
