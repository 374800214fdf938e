"""The knot-structured sparse NLP: assembled Jacobian and Hessian equal dense autodiff, and
Ipopt solves a small pendulum swing-up through it without recompiling; parameters theta
(gravity, a weight, a bound) change values without recompiling and vmap."""

import io
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jtraj.nlp import ConstraintGroup, CostGroup, Dep, KnotNLP, Layout
from jtraj.solvers import InvalidOptionError, IpoptOptions, IpoptSolver, PrintProgress, Status

H = 0.1
N = 21  # knots
#: the pendulum's parameters: gravity, the effort weight and the speed bound of the band rows
#: (float64 arrays: a weakly typed Python scalar would be another jit signature)
THETA = {name: jnp.asarray(value, dtype=jnp.float64) for name, value in {"g": 9.81, "w": 0.5, "band": 30.0}.items()}


def pendulum_nlp(traces=None):
    layout = Layout((("x", 2), ("u", 1)))

    def dyn(params, data, x, u, x_next):
        if traces is not None:
            traces.append(1)
        theta, omega = x
        omega_next = omega + data * (u[0] - params["g"] * jnp.sin(theta))
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
        fn=lambda params, data, x: jnp.array([x[1] ** 2 + 0.1 * jnp.cos(x[0]), x[0] * x[1]]),
        knots=np.arange(N),
        lower=np.full((N, 2), -np.inf),
        upper=lambda params: params["band"],
        active=np.tile(np.array([True, False]), (N, 1)) | (np.arange(N) % 3 == 0)[:, None],
    )
    effort = CostGroup(name="effort", deps=(Dep("u"), Dep("x")), fn=lambda params, data, u, x: params["w"] * u[0] ** 2 + 1e-3 * x[1] ** 4, knots=np.arange(N))
    lower = np.full((N, 3), -np.inf)
    upper = np.full((N, 3), np.inf)
    lower[:, 2], upper[:, 2] = -15.0, 15.0
    lower[0, :2] = upper[0, :2] = [0.0, 0.0]
    lower[-1, :2] = upper[-1, :2] = [np.pi, 0.0]
    return KnotNLP(layout, N, [effort], [dynamics, band], lower, upper, theta=THETA)


@pytest.fixture(scope="module")
def nlp():
    return pendulum_nlp()


def test_sparse_jacobian_equals_dense_autodiff(nlp):
    x = jnp.asarray(np.random.default_rng(0).normal(size=nlp.n))
    dense = jax.jacfwd(nlp._constraints_py)(x, THETA)
    np.testing.assert_allclose(nlp.dense_jacobian(x), dense, atol=1e-12)
    # structure is sparse: dynamics rows touch two knots only
    assert nlp.nnz_jac < 0.2 * nlp.m * nlp.n


def test_dropped_rows_and_bounds(nlp):
    summary = nlp.row_groups_summary()
    assert summary["dynamics"] == 2 * (N - 1)
    assert summary["band"] == N + len(range(0, N, 3))
    assert nlp.g_lower.shape == nlp.g_upper.shape == (nlp.m,)
    # the band's upper bound is a function of theta; inactive rows are dropped at any theta
    x_lower, _, _, g_upper = nlp.bounds({**THETA, "band": THETA["band"] * 0 + 7.0})
    band = nlp.row_group == "band"
    np.testing.assert_array_equal(np.asarray(g_upper)[band], 7.0)
    np.testing.assert_array_equal(np.asarray(g_upper)[~band], 0.0)
    np.testing.assert_array_equal(np.asarray(x_lower), nlp.x_lower)
    np.testing.assert_array_equal(nlp.g_upper[band], 30.0)


def test_hessian_equals_dense_autodiff(nlp):
    nlp.build_hessian()
    rng = np.random.default_rng(1)
    x = jnp.asarray(rng.normal(size=nlp.n))
    lam = jnp.asarray(rng.normal(size=nlp.m))
    lagrangian = lambda x: 0.7 * nlp._objective_py(x, THETA) + lam @ nlp._constraints_py(x, THETA)
    dense = np.tril(np.asarray(jax.hessian(lagrangian)(x)))
    got = np.zeros((nlp.n, nlp.n))
    np.add.at(got, (nlp.hess_rows, nlp.hess_cols), np.asarray(nlp.hessian(x, lam, 0.7, THETA)))
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


def test_evaluation_time_is_what_the_evaluations_took(monkeypatch):
    # replaces `time_evaluations < time_total`, true by construction: here every constraint
    # evaluation takes at least `delay`, which the split must attribute to evaluations
    nlp = pendulum_nlp([])
    x0 = np.zeros((N, 3))
    x0[:, 0] = np.linspace(0, np.pi, N)
    delay = 0.01
    fast = nlp.constraints

    def slow(*args):
        time.sleep(delay)
        return fast(*args)

    monkeypatch.setattr(nlp, "constraints", slow)
    out = IpoptSolver().solve(nlp, x0.ravel(), None, IpoptOptions(tol=1e-8, max_iter=300))
    s = out.stats
    assert out.converged and s.con_evals > 3
    assert s.time_evaluations >= delay * s.con_evals


def test_unknown_ipopt_option_is_reported(nlp):
    with pytest.raises(InvalidOptionError, match="not_an_option"):
        IpoptSolver().solve(nlp, np.zeros(nlp.n), None, {"not_an_option": 1})


def test_zero_weight_keeps_hessian_structure():
    """A cost scaled by a parameter that is 0 by default keeps its Hessian entries: the
    structure is probed at perturbed parameters, and the values follow theta."""
    zero = {**THETA, "w": THETA["w"] * 0.0}
    layout = Layout((("x", 2), ("u", 1)))
    cost = CostGroup("effort", (Dep("u"),), lambda params, data, u: params["w"] * u[0] ** 2, np.arange(N))
    nlp = KnotNLP(layout, N, [cost], [], np.full((N, 3), -1.0), np.full((N, 3), 1.0), theta=zero)
    nlp.build_hessian()
    assert nlp.nnz_hess == N  # d^2/du^2 at every knot
    x = jnp.asarray(np.random.default_rng(2).normal(size=nlp.n))
    np.testing.assert_allclose(nlp.hessian(x, jnp.zeros(0), 1.0, zero), 0.0)
    np.testing.assert_allclose(nlp.hessian(x, jnp.zeros(0), 1.0, THETA), 2 * 0.5)


def test_changing_theta_does_not_recompile_and_vmaps(nlp):
    """New parameter values reuse the compiled functions; vmap over theta equals a loop."""
    rng = np.random.default_rng(3)
    x = jnp.asarray(rng.normal(size=nlp.n))
    for fn in (nlp.objective, nlp.gradient, nlp.constraints):
        fn(x, THETA)
    nlp.jacobian(x, THETA)
    nlp.bounds(THETA)
    fns = {"objective": nlp.objective, "gradient": nlp.gradient, "constraints": nlp.constraints, "blocks": nlp._all_blocks, "bounds": nlp.bounds}
    sizes = {name: fn._cache_size() for name, fn in fns.items()}
    thetas = [{k: v * s for k, v in THETA.items()} for s in (0.5, 1.5, 2.0)]
    loop = {name: [] for name in ("objective", "constraints", "jacobian", "gradient")}
    for theta in thetas:
        loop["objective"].append(nlp.objective(x, theta))
        loop["gradient"].append(nlp.gradient(x, theta))
        loop["constraints"].append(nlp.constraints(x, theta))
        loop["jacobian"].append(nlp.jacobian(x, theta))
        nlp.bounds(theta)
    assert {name: fn._cache_size() for name, fn in fns.items()} == sizes, "a new theta recompiled"
    # the values do depend on theta (gravity enters the dynamics rows)
    assert not np.allclose(loop["constraints"][0], loop["constraints"][1])
    stacked = jax.tree.map(lambda *v: jnp.stack(v), *thetas)
    for name in loop:
        batched = jax.vmap(getattr(nlp, name), in_axes=(None, 0))(x, stacked)
        np.testing.assert_allclose(batched, np.stack(loop[name]), rtol=1e-13, atol=1e-13)
    # and the Jacobian in theta of the constraints exists (differentiation through parameters)
    dg_dg = jax.jacfwd(lambda g: nlp.constraints(x, {**THETA, "g": g}))(THETA["g"])
    fd = (nlp.constraints(x, {**THETA, "g": THETA["g"] + 1e-6}) - nlp.constraints(x, {**THETA, "g": THETA["g"] - 1e-6})) / 2e-6
    np.testing.assert_allclose(dg_dg, fd, atol=1e-7)
