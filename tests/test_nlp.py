"""The knot-structured sparse NLP: assembled Jacobian and Hessian equal dense autodiff, and
Ipopt solves a small pendulum swing-up through it without recompiling."""

import io

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jtraj.solvers import InvalidOptionError, IpoptOptions, IpoptSolver, PrintProgress, Status
from jtraj.nlp import ConstraintGroup, CostGroup, Dep, KnotNLP, Layout

H = 0.1
N = 21  # knots


def pendulum_nlp(traces=None):
    layout = Layout((("x", 2), ("u", 1)))

    def dyn(data, x, u, x_next):
        if traces is not None:
            traces.append(1)
        theta, omega = x
        omega_next = omega + data * (u[0] - 9.81 * jnp.sin(theta))
        return jnp.stack([x_next[0] - theta - data * x_next[1], x_next[1] - omega_next])

    K = N - 1
    dynamics = ConstraintGroup(
        name="dynamics",
        deps=(Dep("x"), Dep("u"), Dep("x", 1)),
        fn=dyn,
        knots=np.arange(K),
        lower=np.zeros((K, 2)),
        upper=np.zeros((K, 2)),
        active=np.ones((K, 2), bool),
        data=jnp.full((K,), H),
    )
    # a nonlinear inequality at some knots only: |omega| bounded by a cosine-shaped band
    band = ConstraintGroup(
        name="band",
        deps=(Dep("x"),),
        fn=lambda data, x: jnp.array([x[1] ** 2 + 0.1 * jnp.cos(x[0]), x[0] * x[1]]),
        knots=np.arange(N),
        lower=np.full((N, 2), -np.inf),
        upper=np.full((N, 2), 30.0),
        active=np.tile(np.array([True, False]), (N, 1)) | (np.arange(N) % 3 == 0)[:, None],
    )
    effort = CostGroup(name="effort", deps=(Dep("u"), Dep("x")), fn=lambda data, u, x: 0.5 * u[0] ** 2 + 1e-3 * x[1] ** 4, knots=np.arange(N))
    lower = np.full((N, 3), -np.inf)
    upper = np.full((N, 3), np.inf)
    lower[:, 2], upper[:, 2] = -15.0, 15.0
    lower[0, :2] = upper[0, :2] = [0.0, 0.0]
    lower[-1, :2] = upper[-1, :2] = [np.pi, 0.0]
    return KnotNLP(layout, N, [effort], [dynamics, band], lower, upper)


@pytest.fixture(scope="module")
def nlp():
    return pendulum_nlp()


def test_sparse_jacobian_equals_dense_autodiff(nlp):
    x = jnp.asarray(np.random.default_rng(0).normal(size=nlp.n))
    dense = jax.jacfwd(nlp._constraints_py)(x)
    np.testing.assert_allclose(nlp.dense_jacobian(x), dense, atol=1e-12)
    # structure is sparse: dynamics rows touch two knots only
    assert nlp.nnz_jac < 0.2 * nlp.m * nlp.n


def test_dropped_rows_and_bounds(nlp):
    summary = nlp.row_groups_summary()
    assert summary["dynamics"] == 2 * (N - 1)
    assert summary["band"] == N + len(range(0, N, 3))
    assert nlp.g_lower.shape == nlp.g_upper.shape == (nlp.m,)


def test_hessian_equals_dense_autodiff(nlp):
    nlp.build_hessian()
    rng = np.random.default_rng(1)
    x = jnp.asarray(rng.normal(size=nlp.n))
    lam = jnp.asarray(rng.normal(size=nlp.m))
    lagrangian = lambda x: 0.7 * nlp._objective_py(x) + lam @ nlp._constraints_py(x)
    dense = np.tril(np.asarray(jax.hessian(lagrangian)(x)))
    got = np.zeros((nlp.n, nlp.n))
    np.add.at(got, (nlp.hess_rows, nlp.hess_cols), np.asarray(nlp.hessian(x, lam, 0.7)))
    assert np.all(nlp.hess_rows >= nlp.hess_cols)
    np.testing.assert_allclose(got, dense, atol=1e-11)


@pytest.mark.parametrize("exact", [False, True], ids=["lbfgs", "exact"])
def test_ipopt_solves_swing_up_without_recompiling(exact):
    traces = []
    nlp = pendulum_nlp(traces)
    x0 = np.zeros((N, 3))
    x0[:, 0] = np.linspace(0, np.pi, N)
    log = io.StringIO()
    traces_before = len(traces)
    options = IpoptOptions(tol=1e-8, max_iter=300, hessian="exact" if exact else "lbfgs")
    out = IpoptSolver().solve(nlp, x0.ravel(), None, options, PrintProgress(log))
    assert out.converged and out.status is Status.SOLVED, out.message
    assert out.constraint_violation < 1e-7
    Z = out.x.reshape(N, 3)
    assert abs(Z[-1, 0] - np.pi) < 1e-9
    # the dynamics function is traced once for the Jacobian blocks (at construction) and
    # once for the constraint values (first call); iterations and a second solve add none
    assert out.stats.iterations > 3
    assert len(traces) - traces_before <= (2 if exact else 1)  # + the Hessian blocks, built on first use
    traces_after_first = len(traces)
    out2 = IpoptSolver().solve(nlp, (x0 + 0.01).ravel(), None, options)
    assert out2.converged
    assert len(traces) == traces_after_first, "a second solve recompiled the NLP functions"
    assert "inf_pr" in log.getvalue()
    assert out.stats.jac_evals >= out.stats.iterations
    assert out.stats.time_evaluations < out.stats.time_total


def test_unknown_ipopt_option_is_reported(nlp):
    with pytest.raises(InvalidOptionError, match="not_an_option"):
        IpoptSolver().solve(nlp, np.zeros(nlp.n), None, {"not_an_option": 1})
