"""Implicit derivatives of small NLPs against central differences of re-solved problems."""

import dataclasses

import cyipopt
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jtraj  # noqa: F401  (float64)
from jtraj.implicit import implicit_solution
from jtraj.sensitivity import DenseNLP, active_set, kkt_system


def ipopt_forward(nlp: DenseNLP, x0, **options):
    """Solve ``nlp`` at theta with Ipopt (tight tolerance, exact Hessian; ``options`` replace
    the defaults): (x, lam)."""

    def forward(theta):
        xl, xu, gl, gu = (np.asarray(b, float) for b in nlp.bounds(theta))

        class Callbacks:
            def objective(self, x):
                return float(nlp.objective(x, theta))

            def gradient(self, x):
                return np.asarray(nlp.gradient(x, theta))

            def constraints(self, x):
                return np.asarray(nlp.constraints(x, theta))

            def jacobian(self, x):
                return np.asarray(nlp.jacobian(x, theta))

            def jacobianstructure(self):
                return nlp.jac_rows, nlp.jac_cols

            def hessian(self, x, lam, obj_factor):
                return np.asarray(nlp.hessian(x, lam, obj_factor, theta))

            def hessianstructure(self):
                return nlp.hess_rows, nlp.hess_cols

        problem = cyipopt.Problem(n=nlp.n, m=nlp.m, problem_obj=Callbacks(), lb=xl, ub=xu, cl=gl, cu=gu)
        for k, v in dict(dict(tol=1e-12, print_level=0, sb="yes", mu_strategy="monotone"), **options).items():
            problem.add_option(k, v)
        x, info = problem.solve(np.clip(x0, xl, xu))
        assert info["status"] == 0, info["status_msg"]
        return x, info["mult_g"]

    return forward


def central_fd(fn, theta, eps=1e-6):
    theta = np.asarray(theta, float)
    cols = []
    for i in range(theta.size):
        d = np.zeros_like(theta)
        d[i] = eps
        cols.append((fn(theta + d) - fn(theta - d)) / (2 * eps))
    return np.stack(cols, axis=-1)


def equality_qp():
    Q = np.array([[3.0, 1.0, 0.0], [1.0, 2.0, 0.5], [0.0, 0.5, 1.5]])
    a = np.array([1.0, -1.0, 2.0])
    f = lambda x, th: 0.5 * x @ Q @ x - th[:3] @ x
    g = lambda x, th: jnp.array([a @ x])
    bounds = lambda th: (np.full(3, -np.inf), np.full(3, np.inf), th[3:4], th[3:4])
    return DenseNLP(f, g, bounds, 3, 1), np.array([0.3, -0.2, 0.5, 0.7]), np.zeros(3)


def inequality_qp():
    # x0 + x1 <= 1 active (the target p lies beyond it), x2 >= theta_4 active, x3 fixed at theta_5
    f = lambda x, th: 0.5 * jnp.sum((x - th[:4]) ** 2) + 0.1 * x[0] * x[2]
    g = lambda x, th: jnp.array([x[0] + x[1], x[1] - x[2]])
    bounds = lambda th: (
        jnp.array([-jnp.inf, -jnp.inf, th[4], th[5]]),
        jnp.array([jnp.inf, jnp.inf, jnp.inf, th[5]]),
        jnp.array([-jnp.inf, -5.0]),
        jnp.array([1.0, 5.0]),
    )
    return DenseNLP(f, g, bounds, 4, 2), np.array([1.0, 0.8, -1.0, 0.4, 0.2, -0.3]), np.zeros(4)


def nonlinear():
    # a circle equality with a parametric radius, an active nonlinear inequality whose shape
    # depends on theta, and a theta-dependent objective
    f = lambda x, th: (x[0] - th[0]) ** 2 + (x[1] - 1.0) ** 2 + 0.3 * jnp.exp(x[2]) + jnp.sin(th[1] * x[0] * x[1])
    g = lambda x, th: jnp.array([x[0] ** 2 + x[1] ** 2 + x[2] ** 2, x[0] - th[3] * x[1] ** 2])
    bounds = lambda th: (jnp.full(3, -jnp.inf), jnp.full(3, jnp.inf), jnp.array([th[2], -jnp.inf]), jnp.array([th[2], 0.0]))
    return DenseNLP(f, g, bounds, 3, 2), np.array([2.0, 0.7, 1.5, 0.8]), np.array([0.5, 0.5, 0.5])


def lower_row_upper_bound():
    # a nonlinear row active at its (parametric) lower bound, where the multiplier is negative
    # and its curvature enters the Hessian with that sign, and a variable at its parametric
    # upper bound (the other problems hold rows at upper bounds and variables at lower ones)
    f = lambda x, th: jnp.sum((x[:2] - th[:2]) ** 2) + (x[2] - 3.0) ** 2 + x[0] * x[2]
    g = lambda x, th: jnp.array([x[0] ** 2 + x[1] ** 2])
    bounds = lambda th: (jnp.full(3, -jnp.inf), jnp.array([jnp.inf, jnp.inf, th[3]]), jnp.array([th[2]]), jnp.array([jnp.inf]))
    return DenseNLP(f, g, bounds, 3, 1), np.array([0.3, 0.2, 1.0, 1.5]), np.array([1.0, 1.0, 0.0])


PROBLEMS = {"equality_qp": equality_qp, "inequality_qp": inequality_qp, "nonlinear": nonlinear, "lower_row_upper_bound": lower_row_upper_bound}


@pytest.mark.parametrize("name", sorted(PROBLEMS))
def test_jacobian_matches_resolved_differences(name):
    nlp, theta, x0 = PROBLEMS[name]()
    forward = ipopt_forward(nlp, x0)
    solve = implicit_solution(nlp, forward)
    sol = solve(jnp.asarray(theta))
    assert not bool(sol.degenerate)
    J = np.asarray(jax.jacobian(lambda th: solve(th).x)(jnp.asarray(theta)))
    J_fd = central_fd(lambda th: forward(th)[0], theta)
    np.testing.assert_allclose(J, J_fd, rtol=1e-6, atol=1e-7)


def test_active_set_of_the_inequality_problem():
    nlp, theta, x0 = inequality_qp()
    x, lam = ipopt_forward(nlp, x0)(theta)
    a = kkt_system(nlp, x, lam, theta).active
    np.testing.assert_array_equal(a.row_active, [True, False])
    np.testing.assert_array_equal(a.at_bound, [False, False, True, True])
    assert not a.degenerate
    np.testing.assert_allclose(x[2:], theta[4:], atol=1e-9)  # driven by its bounds


def test_active_set_of_the_lower_row_upper_bound_problem():
    nlp, theta, x0 = lower_row_upper_bound()
    x, lam = ipopt_forward(nlp, x0)(theta)
    a = kkt_system(nlp, x, lam, theta).active
    assert lam[0] < 0  # Ipopt's sign at a lower bound
    np.testing.assert_array_equal(a.row_active, [True])
    np.testing.assert_array_equal(a.row_upper, [False])
    np.testing.assert_array_equal(a.at_bound, [False, False, True])
    np.testing.assert_array_equal(a.at_upper, [False, False, True])


def test_grad_vjp_jvp_agree_and_compose_with_jit():
    nlp, theta, x0 = nonlinear()
    solve = implicit_solution(nlp, ipopt_forward(nlp, x0))
    w = jnp.array([1.0, -2.0, 0.5])

    def loss(th):
        s = solve(th)
        return jnp.sum(w * s.x) + jnp.sum(s.x**2) * th[0]

    th = jnp.asarray(theta)
    g = jax.grad(loss)(th)
    g_jit = jax.jit(jax.grad(loss))(th)
    np.testing.assert_allclose(g_jit, g, rtol=1e-12)
    J = jax.jacobian(lambda t: solve(t).x)(th)
    v = jnp.array([0.3, -1.0, 0.2, 0.5])
    _, x_dot = jax.jvp(lambda t: solve(t).x, (th,), (v,))
    np.testing.assert_allclose(x_dot, J @ v, rtol=1e-10, atol=1e-12)
    _, pullback = jax.vjp(lambda t: solve(t).x, th)
    np.testing.assert_allclose(pullback(w)[0], w @ J, rtol=1e-10, atol=1e-12)
    g_fd = central_fd(lambda t: float(loss(jnp.asarray(t))), theta)
    np.testing.assert_allclose(g, g_fd, rtol=1e-6)


#: Ipopt's settings of the weak-activity tests: the tests' tight monotone solve, and
#: jtraj.differentiate's tol 1e-10 with Ipopt's adaptive default, which ends a weakly active
#: pair at a slack and multiplier of about 4e-6 (above weak_tol: it went unflagged)
WEAK_SETTINGS = {"tol 1e-12": {}, "tol 1e-10": {"tol": 1e-10, "mu_strategy": "adaptive"}}


@pytest.mark.parametrize("setting", list(WEAK_SETTINGS))
def test_weakly_active_constraint_is_flagged_and_one_sided(setting):
    # min (x - theta)^2 s.t. x <= 0 at theta = 0: the bound is reached with a zero multiplier
    nlp = DenseNLP(
        lambda x, th: (x[0] - th[0]) ** 2,
        lambda x, th: x[:1],
        lambda th: (np.full(1, -np.inf), np.full(1, np.inf), np.array([-np.inf]), np.array([0.0])),
        1, 1,
    )
    forward = ipopt_forward(nlp, np.array([-1.0]), **WEAK_SETTINGS[setting])
    solve = implicit_solution(nlp, forward)
    assert bool(solve(jnp.zeros(1)).degenerate)
    d = float(jax.grad(lambda t: solve(t).x[0])(jnp.zeros(1))[0])
    eps = 1e-2  # (the interior point stops about sqrt(mu) inside the bound)
    left = (forward(np.zeros(1))[0][0] - forward(np.array([-eps]))[0][0]) / eps
    right = (forward(np.array([eps]))[0][0] - forward(np.zeros(1))[0][0]) / eps
    assert abs(left - 1.0) < 1e-3 and abs(right) < 1e-3  # the two one-sided derivatives differ
    assert abs(d - 1.0) < 1e-8  # treated as inactive: the side where it is slack
    assert not bool(solve(jnp.array([-0.5])).degenerate)


@pytest.mark.parametrize("setting", list(WEAK_SETTINGS))
def test_weakly_active_bound_is_flagged_and_one_sided(setting):
    """The same for a variable bound, x0 >= 0 at theta0 = 0 (its multiplier comes from
    stationarity; it was flagged at neither setting and held at the bound, derivative 0)."""
    nlp = DenseNLP(
        lambda x, th: jnp.sum((x - th) ** 2),
        lambda x, th: jnp.array([x[0] - x[1]]),
        lambda th: (jnp.zeros(2), jnp.full(2, jnp.inf), jnp.array([-10.0]), jnp.array([10.0])),
        2, 1,
    )
    solve = implicit_solution(nlp, ipopt_forward(nlp, np.ones(2), **WEAK_SETTINGS[setting]))
    theta = jnp.array([0.0, 1.0])
    assert bool(solve(theta).degenerate)
    np.testing.assert_allclose(np.asarray(jax.jacobian(lambda t: solve(t).x)(theta)), np.eye(2), atol=1e-8)  # the slack side
    strict = jnp.array([-1.0, 1.0])  # strictly active: held at the bound, not degenerate
    assert not bool(solve(strict).degenerate)
    np.testing.assert_allclose(np.asarray(jax.jacobian(lambda t: solve(t).x)(strict)), np.diag([0.0, 1.0]), atol=1e-8)


def test_an_inconsistent_tangent_is_refused_at_any_size():
    """Two equal rows x0 + x1 = theta0 and = theta1: a tangent that moves them apart has no
    solution, whatever its size (one of size 1e-6 passed the residual test, whose floor was an
    absolute 1e-6, and came back as a derivative); a consistent one is a derivative."""
    from jtraj.sensitivity import SingularKKTError

    nlp = DenseNLP(
        lambda x, th: jnp.sum(x**2),
        lambda x, th: jnp.array([x[0] + x[1], x[0] + x[1]]),
        lambda th: (jnp.full(2, -jnp.inf), jnp.full(2, jnp.inf), th, th),
        2, 2,
    )
    theta = np.array([1.0, 1.0])
    x, lam = ipopt_forward(nlp, np.zeros(2))(theta)
    system = kkt_system(nlp, x, lam, theta)
    n = nlp.n
    for size in (1.0, 1e-6, 1e-9):  # the rows' right-hand sides moved apart
        with pytest.raises(SingularKKTError, match="could not be solved"):
            system.solve(np.r_[np.zeros(n), size, 0.0])
    for size in (1.0, 1e-6):  # moved together: x moves by half of it along (1, 1)
        np.testing.assert_allclose(system.solve(np.r_[np.zeros(n), size, size])[:n], [size / 2, size / 2], rtol=1e-8)


def test_an_nlp_without_rows_is_differentiated():
    """An NLP with variable bounds only (m = 0): its derivative failed reshaping the empty
    multipliers to (-1, 0)."""
    nlp = DenseNLP(
        lambda x, th: jnp.sum((x - th) ** 2),
        lambda x, th: jnp.zeros(0),
        lambda th: (jnp.array([0.0, -jnp.inf]), jnp.full(2, jnp.inf), jnp.zeros(0), jnp.zeros(0)),
        2, 0,
    )
    solve = implicit_solution(nlp, ipopt_forward(nlp, np.ones(2)))
    J = jax.jacobian(lambda t: solve(t).x)(jnp.array([-1.0, 0.5]))  # x0 held at its bound
    np.testing.assert_allclose(np.asarray(J), np.diag([0.0, 1.0]), atol=1e-8)


def test_second_derivatives_are_refused_in_words():
    """Derivatives are first order only; asking for more says so (regression: JAX's own
    "Pure callbacks do not support JVP. Please use `jax.custom_jvp`", which jtraj already uses)."""
    from jtraj.implicit import SecondOrderError

    nlp, theta, x0 = nonlinear()
    solve = implicit_solution(nlp, ipopt_forward(nlp, x0))
    th = jnp.asarray(theta)
    for second in (
        lambda: jax.hessian(lambda t: solve(t).x.sum())(th),
        lambda: jax.jit(jax.hessian(lambda t: solve(t).x.sum()))(th),
        lambda: jax.grad(lambda t: jax.jvp(lambda u: solve(u).x.sum(), (t,), (jnp.ones(4),))[1])(th),
    ):
        with pytest.raises(SecondOrderError, match="first order only"):
            second()


def test_bad_options_are_refused_when_built():
    """implicit_solution checks weak_tol and cache_size (regression: cache_size=-1 raised a
    bare KeyError at the first solve, weak_tol=-1 or NaN was taken without a word)."""
    nlp, theta, x0 = nonlinear()
    forward = ipopt_forward(nlp, x0)
    for kwargs, match in [
        ({"weak_tol": -1.0}, r"weak_tol must be a number in \[0, 1\)"),
        ({"weak_tol": float("nan")}, r"weak_tol must be a number in \[0, 1\)"),
        ({"cache_size": -1}, "cache_size must be an integer >= 0"),
        ({"cache_size": 2.5}, "cache_size must be an integer >= 0"),
    ]:
        with pytest.raises(ValueError, match=match):
            implicit_solution(nlp, forward, **kwargs)
    # nothing kept is allowed: every pass rebuilds its system from the solution
    J0 = jax.jacobian(lambda th: implicit_solution(nlp, forward, cache_size=0)(th).x)(jnp.asarray(theta))
    J = jax.jacobian(lambda th: implicit_solution(nlp, forward)(th).x)(jnp.asarray(theta))
    np.testing.assert_allclose(J0, J, rtol=1e-12, atol=1e-14)


def test_a_system_built_again_holds_the_active_set_of_its_solution(monkeypatch):
    """A system no longer cached was built again from the solution's multipliers, which are
    zeroed off its active set: found again from them the active set was another (here x1's
    bound, multiplier 7e-4, read as weakly active beside x0's bound multiplier, 1000 once the
    dropped duplicate row's -500 was zeroed, 500 before), and the derivative wrong without a
    word (2/3 for 1). A batch one larger than the cache built every
    member's system again. min 1000 x0 + (x1 - th0)^2/2 + (x2 - x1)^2/2 + x2^2/2, x0 >= 0 as a
    bound and as a row, x1 <= 1 + th1 active: dx1/dth1 = 1, dx2/dth1 = 1/2."""
    import jtraj.implicit as implicit

    nlp = DenseNLP(
        lambda x, th: 1000.0 * x[0] + 0.5 * (x[1] - th[0]) ** 2 + 0.5 * (x[2] - x[1]) ** 2 + 0.5 * x[2] ** 2,
        lambda x, th: x[:1],
        lambda th: (jnp.array([0.0, -jnp.inf, -jnp.inf]), jnp.array([jnp.inf, 1.0 + th[1], jnp.inf]), jnp.zeros(1), jnp.full(1, jnp.inf)),
        3, 1,
    )
    forward = ipopt_forward(nlp, np.array([1.0, 0.0, 0.0]), tol=1e-10, mu_strategy="adaptive")
    theta = jnp.array([1.5007, 0.0])
    x, lam = forward(np.asarray(theta))
    held = kkt_system(nlp, x, lam, np.asarray(theta)).active
    assert held.dropped_rows[0] and held.at_bound[1]  # the case: a dropped row whose multiplier is large, x1 held
    # found again from the zeroed multipliers: x1's bound weakly active, not held
    again = kkt_system(nlp, x, np.where(held.row_active, lam, 0.0), np.asarray(theta)).active
    assert not again.at_bound[1] and again.weak_bounds[1]
    for size in (16, 0):
        J = np.asarray(jax.jacobian(lambda th: implicit_solution(nlp, forward, cache_size=size)(th).x)(theta))
        np.testing.assert_allclose(J[1:, 1], [1.0, 0.5], atol=1e-6)
    built = []
    real = implicit.kkt_system
    monkeypatch.setattr(implicit, "kkt_system", lambda *a, **k: built.append(k.get("active")) or real(*a, **k))
    solve = implicit_solution(nlp, forward, cache_size=4, forward_many=lambda thetas: [forward(t) for t in thetas])
    J = np.asarray(jax.vmap(jax.jacobian(lambda th: solve(th).x))(jnp.tile(theta, (5, 1))))
    np.testing.assert_allclose(J[:, 1, 1], 1.0, atol=1e-6)
    # 5 in the forward pass; the backward pass builds again only the one the cache no longer held
    assert len(built) == 6 and built[:5] == [None] * 5 and built[5] is not None


def test_a_forward_returning_garbage_is_refused_in_words():
    """A forward that returns wrong shapes or NaN is named (regression: a broadcast error deep
    in the active set; NaN came back as the solution, and under a gradient as "not
    differentiable")."""
    nlp, theta, _ = nonlinear()
    for x, lam, match in [
        (np.zeros(4), np.zeros(2), r"x of shape \(4,\) and lam of shape \(2,\); expected \(3,\) and \(2,\)"),
        (np.zeros(3), np.zeros(3), r"lam of shape \(3,\); expected \(3,\) and \(2,\)"),
        (np.array([np.nan, 0.0, 0.0]), np.zeros(2), "NaN or infinite x or lam"),
    ]:
        solve = implicit_solution(nlp, lambda th, x=x, lam=lam: (x, lam))
        with pytest.raises(ValueError, match=match):
            solve(jnp.asarray(theta))


def test_kkt_system_and_active_set_check_their_point():
    """kkt_system and active_set, public, name a bad point or weak_tol (regression: a wrong
    shape failed inside JAX with "dot_general requires contracting dimensions to have the same
    shape", a NaN x or a weak_tol of -1 or NaN gave a system without a word)."""
    nlp, theta, x0 = equality_qp()
    x, lam = ipopt_forward(nlp, x0)(theta)
    for build in (kkt_system, active_set):
        for args, kwargs, match in [
            ((x[:2], lam), {}, r"x of shape \(2,\) and lam of shape \(1,\); expected \(3,\) and \(1,\)"),
            ((x, np.zeros(3)), {}, r"lam of shape \(3,\); expected \(3,\) and \(1,\)"),
            ((np.array([np.nan, 0.0, 0.0]), lam), {}, "NaN or infinite entries"),
            ((x, lam), {"weak_tol": -1.0}, r"weak_tol must be a number in \[0, 1\)"),
            ((x, lam), {"weak_tol": float("nan")}, r"weak_tol must be a number in \[0, 1\)"),
        ]:
            with pytest.raises(ValueError, match=match):
                build(nlp, *args, theta, **kwargs)
    assert kkt_system(nlp, x, lam, theta).active.row_active.tolist() == [True]


def test_a_right_hand_side_of_the_wrong_size_is_named():
    # scipy's "b is of incompatible size" did not say which size the system has
    nlp, theta, x0 = equality_qp()
    x, lam = ipopt_forward(nlp, x0)(theta)
    system = kkt_system(nlp, x, lam, theta)
    for rhs in (np.ones(3), np.ones((2, 5)), np.ones((1, 2, 4))):
        with pytest.raises(ValueError, match=r"expected \(4,\) or \(batch, 4\)"):
            system.solve(rhs)
    assert system.solve(np.ones((2, 4))).shape == (2, 4)


def test_vmap_hands_the_whole_batch_to_forward_many():
    """With ``forward_many``, ``jax.vmap`` over theta (nested too) solves the batch in one host
    call, and values and gradients equal those of the one-at-a-time solution."""
    nlp, theta, x0 = nonlinear()
    forward = ipopt_forward(nlp, x0)
    calls = []

    def forward_many(thetas):
        calls.append(len(thetas))
        return [forward(th) for th in thetas]

    one = implicit_solution(nlp, forward)
    many = implicit_solution(nlp, forward, forward_many=forward_many)
    w = jnp.array([1.0, -2.0, 0.5])
    thetas = jnp.asarray(theta) + jnp.array([[0.0, 0.0, 0.0, 0.0], [0.1, -0.05, 0.1, 0.0], [-0.1, 0.05, 0.2, 0.1]])

    def loss(solve):
        return lambda th: jnp.sum(w * solve(th).x) + th[1] * jnp.sum(solve(th).x ** 2)

    np.testing.assert_allclose(jax.vmap(lambda th: many(th).x)(thetas), jax.vmap(lambda th: one(th).x)(thetas), rtol=1e-10, atol=1e-12)
    assert calls == [3]
    np.testing.assert_allclose(jax.vmap(jax.grad(loss(many)))(thetas), jax.vmap(jax.grad(loss(one)))(thetas), rtol=1e-8, atol=1e-10)
    # two vmaps: a (2, 3) batch, the outer one over a second parameter set
    outer = jnp.stack([thetas, thetas + 0.01])
    calls.clear()
    xs = jax.vmap(jax.vmap(lambda th: many(th).x))(outer)
    assert calls == [6] and xs.shape == (2, 3, 3)
    np.testing.assert_allclose(xs[1, 2], one(outer[1, 2]).x, rtol=1e-10, atol=1e-12)
    # a forward_many that loses a member is named
    bad = implicit_solution(nlp, forward, forward_many=lambda ths: [forward(th) for th in ths[:-1]])
    with pytest.raises(Exception, match="forward_many returned 2 solutions for 3 parameter sets"):
        jax.block_until_ready(jax.vmap(lambda th: bad(th).x)(thetas))


def _capped_qp() -> DenseNLP:
    """``min (x - theta)^2 / 2  s.t.  x <= 1`` (a row): at theta = 2, x = 1, lam = 1 and
    dx/dtheta = 0."""
    return DenseNLP(
        lambda x, th: 0.5 * jnp.sum((x - th) ** 2),
        lambda x, th: x,
        lambda th: (jnp.full(1, -jnp.inf), jnp.full(1, jnp.inf), jnp.full(1, -jnp.inf), jnp.ones(1)),
        1, 1,
    )


@pytest.mark.parametrize(
    ("x", "lam", "said"),
    [
        # stopped early: stationarity fails, |x - theta| / max(1, |grad f|) (it gave dx/dtheta = 1)
        (0.5, 0.0, "dual 1"),
        (1.0, -1.0, "dual 2"),  # the row's multiplier of the wrong sign (and stationarity)
        (1.2, 0.8, "infeasibility 0.2, complementarity 0.16"),  # over the row's bound
        (0.5, 1.5, "complementarity 0.5"),  # a multiplier on a row that is slack (0.5 * 1.5 / 1.5)
    ],
)
def test_a_point_that_is_not_a_kkt_point_is_refused(x, lam, said):
    """Only shapes and finiteness were checked: the derivatives of a forward that returned an
    unconverged point came back as those of a solution (dx/dtheta = 1 where it is 0)."""
    from jtraj.sensitivity import NotAKKTPointError, kkt_errors

    nlp, theta = _capped_qp(), jnp.array([2.0])
    good = implicit_solution(nlp, lambda th: (np.array([1.0]), np.array([1.0])))
    np.testing.assert_allclose(np.asarray(jax.jacobian(lambda th: good(th).x)(theta)), [[0.0]], atol=1e-12)
    assert max(kkt_errors(nlp, np.array([1.0]), np.array([1.0]), theta).values()) == 0.0
    bad = implicit_solution(nlp, lambda th: (np.array([x]), np.array([lam])))
    with pytest.raises(NotAKKTPointError, match=rf"not a KKT point of the NLP at this theta: {said} \(kkt_tol=0.0001\); its implicit derivatives would be of no solution"):
        bad(theta)
    with pytest.raises(NotAKKTPointError):
        kkt_system(nlp, np.array([x]), np.array([lam]), theta)
    # kkt_tol=None: not checked, as before (the caller's own responsibility)
    assert implicit_solution(nlp, lambda th: (np.array([x]), np.array([lam])), kkt_tol=None)(theta).x.shape == (1,)
    for tol in (0.0, -1.0, float("nan"), "1e-4"):
        with pytest.raises(ValueError, match="kkt_tol must be a number > 0 or None"):
            implicit_solution(nlp, lambda th: (np.array([1.0]), np.array([1.0])), kkt_tol=tol)


def test_bounds_of_1e19_are_infinite_to_the_kkt_check():
    """Ipopt's convention: a bound of 1e19 or beyond is none. Counted as finite, the exact
    solution of ``min (x - theta)^2 / 2`` with x in [-1e19, 1e19] had a complementarity of
    1e7 (its stationarity residual times the slack) and was refused."""
    from jtraj.sensitivity import kkt_errors

    nlp = DenseNLP(
        lambda x, th: 0.5 * jnp.sum((x - th) ** 2),
        lambda x, th: jnp.zeros(0),
        lambda th: (jnp.full(1, -1e19), jnp.full(1, 1e19), jnp.zeros(0), jnp.zeros(0)),
        1, 0,
    )
    theta = jnp.array([2.0])
    errors = kkt_errors(nlp, np.array([2.0 + 1e-12]), np.zeros(0), theta)
    assert max(errors.values()) < 1e-11, errors
    assert kkt_system(nlp, np.array([2.0 + 1e-12]), np.zeros(0), theta).active.at_bound.tolist() == [False]


def test_kkt_system_evaluates_the_point_once():
    """The KKT check and the active set each evaluated the rows, the Jacobian and the gradient
    at the same point: twice each per `kkt_system`. Same active set and matrix."""
    nlp, theta = _capped_qp(), jnp.array([2.0])
    calls = {"constraints": 0, "jacobian": 0, "gradient": 0}

    def counted(name):
        fn = getattr(nlp, name)

        def call(*args):
            calls[name] += 1
            return fn(*args)

        return call

    class Counted:
        def __getattr__(self, attr):
            return counted(attr) if attr in calls else getattr(nlp, attr)

    system = kkt_system(Counted(), np.array([1.0]), np.array([1.0]), theta)
    assert calls == {"constraints": 1, "jacobian": 1, "gradient": 1}
    plain = kkt_system(nlp, np.array([1.0]), np.array([1.0]), theta)
    for field in dataclasses.fields(plain.active):
        assert np.array_equal(getattr(system.active, field.name), getattr(plain.active, field.name)), field.name
    np.testing.assert_array_equal(system.solve(np.ones(2)), plain.solve(np.ones(2)))
    assert system.active.row_active.tolist() == [True]


def test_the_first_derivative_is_announced_once():
    """`jtraj.differentiable`'s first derivative compiled for about a minute without a word:
    ``say`` is told ``first_derivative`` once, as the first derivative is taken."""
    nlp = DenseNLP(
        lambda x, th: jnp.sum((x - th) ** 2),
        lambda x, th: jnp.zeros(0),
        lambda th: (jnp.array([0.0, -jnp.inf]), jnp.full(2, jnp.inf), jnp.zeros(0), jnp.zeros(0)),
        2, 0,
    )
    said = []
    solve = implicit_solution(nlp, ipopt_forward(nlp, np.ones(2)), say=said.append, first_derivative="first derivative")
    solve(jnp.array([-1.0, 0.5]))
    assert said == []  # a forward solve alone compiles no derivative
    for _ in range(2):
        J = jax.jacobian(lambda t: solve(t).x)(jnp.array([-1.0, 0.5]))
    np.testing.assert_allclose(np.asarray(J), np.diag([0.0, 1.0]), atol=1e-8)
    assert said == ["first derivative"]


def _duplicated_row():
    """One equality row written twice, with right-hand sides theta[0] and theta[1] (equal at
    the point): dependent active rows, so only directions that keep them equal have a
    derivative; x = (t, t) / 2 along those."""
    nlp = DenseNLP(
        lambda x, th: jnp.sum(x**2),
        lambda x, th: jnp.array([x[0] + x[1], x[0] + x[1]]),
        lambda th: (jnp.full(2, -jnp.inf), jnp.full(2, jnp.inf), th, th),
        2, 2,
    )
    return nlp, implicit_solution(nlp, ipopt_forward(nlp, np.zeros(2))), jnp.array([1.0, 1.0])


def test_a_gradient_along_entries_without_a_derivative_warns_and_names_them():
    """jax.grad returned a number for every entry of theta, also where the solution has no
    derivative (jax.jvp raised there): which of the transposed system's solutions the LU picked
    set them. It now warns, naming those entries; the exact combinations stay exact."""
    from jtraj.sensitivity import NotDifferentiableWarning, SingularKKTError

    _, solve, th = _duplicated_row()
    with pytest.warns(NotDifferentiableWarning, match=r"theta\[0\], theta\[1\] of theta have no derivative at this solution"):
        g = jax.block_until_ready(jax.grad(lambda t: solve(t).x[0])(th))  # (warned from JAX's callback: within the block)
    assert float(g.sum()) == pytest.approx(0.5, abs=1e-8)  # along (1, 1): the derivative, 1/2
    np.testing.assert_allclose(jax.jvp(lambda t: solve(t).x, (th,), (jnp.ones(2),))[1], [0.5, 0.5], atol=1e-8)
    # (raised in JAX's callback: a JaxRuntimeError, or a ValueError with the test suite's XLA
    # flags, whose message ends with the SingularKKTError's)
    raised = (SingularKKTError, jax.errors.JaxRuntimeError, ValueError)
    with pytest.raises(raised, match=r"inconsistent: the solution has no derivative along it here; the entries of theta without a derivative here: theta\[0\], theta\[1\]"):
        jax.jvp(lambda t: solve(t).x, (th,), (jnp.array([1.0, 0.0]),))
    # the multipliers of the two rows are not unique: their derivative is refused, saying so
    with pytest.raises(raised, match=r"reaches multipliers \(lam\) of linearly dependent active rows"):
        jax.grad(lambda t: solve(t).lam[0])(th)


def test_left_null_space_is_exact_and_empty_where_rows_are_independent():
    import warnings

    from jtraj.sensitivity import undifferentiable_parameters

    nlp, _, th = _duplicated_row()
    x, lam = ipopt_forward(nlp, np.zeros(2))(np.asarray(th))
    system = kkt_system(nlp, x, lam, np.asarray(th))
    U = system.left_null_space()
    assert U.shape == (4, 1) and np.abs(system.matrix.T @ U).max() < 1e-12 and np.linalg.norm(U) == pytest.approx(1.0)
    assert undifferentiable_parameters(nlp, system, x, lam, np.asarray(th)) == ["theta[0]", "theta[1]"]
    nlp, theta, x0 = nonlinear()
    x, lam = ipopt_forward(nlp, x0)(theta)
    system = kkt_system(nlp, x, lam, theta)
    assert system.left_null_space().shape == (5, 0) and undifferentiable_parameters(nlp, system, x, lam, theta) == []
    solve = implicit_solution(nlp, ipopt_forward(nlp, x0))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning where every entry has its derivative
        jax.grad(lambda t: solve(t).x.sum())(jnp.asarray(theta))
