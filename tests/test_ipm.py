"""jtraj's own interior-point solver on small knot problems and on a small Go2 hop."""

import dataclasses
import io

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jtraj import solvers
from jtraj.nlp import ConstraintGroup, CostGroup, Dep, KnotNLP, Layout
from jtraj.solvers.ipm import IPM, IpmOptions, IpmStatus

K = 16
H_STEP = 0.25
U_MAX = 0.6
V_MAX = 0.35


def double_integrator(speed_lower=None, speed_upper=None, theta=None) -> KnotNLP:
    """Move a unit mass from p=0 to p=1 at rest in (K-1) h seconds with least effort,
    |u| <= U_MAX (a variable bound) and v <= V_MAX (an inequality row): both become active.
    ``speed_lower``/``speed_upper`` replace the speed row's bounds (arrays, or functions of
    ``theta``, the NLP's parameters)."""
    layout = Layout((("p", 1), ("v", 1), ("u", 1)))
    pairs = np.arange(K - 1)

    def step(theta, data, p, v, u, p1, v1):
        return jnp.concatenate([p1 - p - H_STEP * v1, v1 - v - H_STEP * u])

    groups = [
        ConstraintGroup("dynamics", (Dep("p"), Dep("v"), Dep("u"), Dep("p", 1), Dep("v", 1)), step, pairs,
                        np.zeros((K - 1, 2)), np.zeros((K - 1, 2)), np.ones((K - 1, 2), bool)),
        ConstraintGroup("speed", (Dep("v"),), lambda theta, data, v: v, np.arange(K),
                        np.full((K, 1), -np.inf) if speed_lower is None else speed_lower,
                        np.full((K, 1), V_MAX) if speed_upper is None else speed_upper, np.ones((K, 1), bool)),
    ]
    costs = [CostGroup("effort", (Dep("u"),), lambda theta, data, u: 0.5 * jnp.sum(u**2), np.arange(K))]
    lower = np.tile([-np.inf, -np.inf, -U_MAX], (K, 1))
    upper = np.tile([np.inf, np.inf, U_MAX], (K, 1))
    lower[0] = upper[0] = [0.0, 0.0, 0.0]
    lower[-1, :2] = upper[-1, :2] = [1.0, 0.0]
    lower[-1, 2] = upper[-1, 2] = 0.0
    return KnotNLP(layout, K, costs, groups, lower, upper, theta=theta)


@pytest.fixture(scope="module")
def toy():
    nlp = double_integrator()
    return nlp, IPM(nlp, IpmOptions(tol=1e-8, compl_inf_tol=1e-8, constr_viol_tol=1e-8, max_iter=100))


def test_active_bound_and_inequality(toy):
    nlp, ipm = toy
    r = ipm.solve(jnp.zeros((K, 3)), None)
    assert int(r.status) == IpmStatus.CONVERGED
    x = np.asarray(r.x)
    assert nlp.violation(x.reshape(-1)) < 1e-7
    assert abs(x[:, 2].max() - U_MAX) < 1e-6 and abs(x[:, 1].max() - V_MAX) < 1e-6  # both active
    ref = solvers.get("ipopt").solve(nlp, np.zeros(nlp.n), None, {"tol": 1e-10, "hessian": "exact"})
    assert ref.converged
    np.testing.assert_allclose(float(r.objective), ref.objective, rtol=1e-6)
    np.testing.assert_allclose(x.reshape(-1), ref.x, atol=1e-4)


def test_nlp_error_takes_the_rows_violation_not_the_slacks_lag(toy):
    """Convergence is judged by Ipopt's NLP error, whose primal part is how far c(x) lies
    outside its bounds (its curr_nlp_constraint_violation), not by how far the slacks lag
    c(x) (c - s, the barrier problem's residual). A point whose speed rows are inside their
    bounds but whose slacks lag by 0.1 was held back as if it violated them by 0.1."""
    _, ipm = toy
    p, st = ipm._start(jnp.zeros((K, 3)), None)
    ineq = np.asarray(p.ineq)
    assert ineq.any()
    lagging = st._replace(s=jnp.where(p.ineq, st.c - 0.1, st.s))
    _, _, barrier_primal, _ = ipm._error(p, lagging, 0.0)
    _, _, nlp_primal, _ = ipm._error(p, lagging, 0.0, nlp=True)
    assert float(barrier_primal) >= 0.1 - 1e-12

    def rows_violation(c):  # max over the rows of how far c lies outside [cl, cu], by numpy
        cl, cu, c = np.asarray(p.cl), np.asarray(p.cu), np.asarray(c)
        rows = np.asarray(p.eq | p.ineq)
        with np.errstate(invalid="ignore"):
            return float(np.max(np.where(rows, np.maximum(np.maximum(cl - c, c - cu), 0.0), 0.0)))

    # the slacks' lag does not count: the start's rows' violation, with or without it
    assert float(nlp_primal) == pytest.approx(rows_violation(st.c))
    assert float(nlp_primal) == pytest.approx(float(ipm._error(p, st, 0.0, nlp=True)[2]))
    # a row of c(x) outside its bounds does count, by how far it is outside
    row = int(np.flatnonzero(ineq & np.isfinite(np.asarray(p.cu)))[0])
    outside = lagging._replace(c=lagging.c.at[row].set(p.cu[row] + 7.0))
    _, _, nlp_outside, _ = ipm._error(p, outside, 0.0, nlp=True)
    assert rows_violation(outside.c) == pytest.approx(7.0) and float(nlp_outside) == pytest.approx(7.0)


def test_free_mode_empties_the_filter_every_iteration(toy):
    """Ipopt's adaptive barrier update resets the line search on every free-mode iteration,
    whether or not the oracle's mu changed (clipped to mu_min it does not): the filter held 1
    and 2 entries at the toy's last free-mode iterations, at mu_min."""
    _, ipm = toy
    p, st = ipm._start(jnp.zeros((K, 3)), None)
    step = jax.jit(lambda st, passes: ipm._iteration(p, st, passes, None))
    passes = jnp.zeros((2,), jnp.int32)
    free_iterations = 0
    for _ in range(100):
        st, passes = step(st, passes)
        if bool(st.free_mode):
            free_iterations += 1
            assert int(st.n_filter) == 0, (int(st.it), int(st.n_filter), float(st.mu))
        if int(st.status) != IpmStatus.RUNNING:
            break
    assert int(st.status) == IpmStatus.CONVERGED and free_iterations > 5
    assert float(st.mu) == pytest.approx(ipm.options.mu_min_value())  # the oracle's mu was clipped


def test_filter_is_left_alone_after_a_switching_and_armijo_step(toy):
    """Wachter & Biegler's step A-7 (Ipopt's FilterLSAcceptor::UpdateForNextIteration): the
    filter is augmented after a step unless the switching condition and the Armijo condition
    both held, whether or not the step was judged as an f-type step (theta <= theta_min). With
    theta_min set to 0 every step is judged by the filter's tests, and a switching and Armijo
    step must still leave the filter as it is (regression: it was augmented unless theta <=
    theta_min). The monotone strategy keeps the filter between barrier problems."""
    nlp, ipm = toy
    mono = IPM(nlp, dataclasses.replace(ipm.options, mu_strategy="monotone"))
    p, st = mono._start(jnp.zeros((K, 3)), None)
    step = jax.jit(lambda st, passes: mono._iteration(p, st, passes, None))
    measures = jax.jit(lambda x, s, f, c, mu: mono._measures(p, x, s, f, c, mu))
    passes = jnp.zeros((2,), jnp.int32)
    checked = {True: 0, False: 0}  # steps checked, by whether switching and Armijo held
    for _ in range(100):
        if not bool(st.first):
            pre = st._replace(theta_min=jnp.zeros_like(st.theta_min))
            post, _ = step(pre, passes)
            reset = float(post.mu) != float(pre.mu) or int(post.status) != IpmStatus.RUNNING
            if not reset:
                alpha, slope, theta0, phi0 = float(post.alpha), float(pre.slope), float(pre.theta0), float(pre.phi0)
                _, phi = measures(post.x, post.s, post.f, post.c, pre.mu)
                switching = slope < 0 and alpha * (-slope) ** IPM.S_PHI > IPM.DELTA * theta0**IPM.S_THETA
                armijo = float(phi) - phi0 <= mono.options.armijo * alpha * slope + IPM.ROUNDING * abs(phi0)
                added = int(post.n_filter) - int(pre.n_filter)
                assert added == (0 if switching and armijo else 1), (int(post.it), switching, armijo, added)
                checked[switching and armijo] += 1
        st, passes = step(st, passes)
        if int(st.status) != IpmStatus.RUNNING:
            break
    assert int(st.status) == IpmStatus.CONVERGED
    assert checked[True] >= 2 and checked[False] >= 2, checked


def test_armijo_test_allows_ipopts_rounding_margin(toy):
    """Ipopt's acceptance tests compare with ``Compare_le``: ``lhs - rhs <= 10 eps |reference|``
    (`IPM._le`). Take a step whose first trial was accepted by the Armijo test (theta_min set
    to +inf, so every switching step is judged by it alone) and move phi0 so that the trial
    misses the Armijo test by 3 eps of |phi0|: the step is still accepted, at the same trial
    point, and a solver without the margin (``ROUNDING = 0``) rejects it. At 30 eps both
    reject it. The Armijo constant is the option ``armijo`` (Ipopt's eta_phi): a decrease
    that the default 1e-8 accepts, ``armijo=0.4`` rejects."""
    nlp, ipm = toy

    class Strict(IPM):
        ROUNDING = 0.0

    strict = Strict(nlp, ipm.options)
    demanding = IPM(nlp, dataclasses.replace(ipm.options, armijo=0.4))  # Ipopt's eta_phi, default 1e-8
    p, st = ipm._start(jnp.zeros((K, 3)), None)
    step = jax.jit(lambda st, passes: ipm._iteration(p, st, passes, None))
    step_strict = jax.jit(lambda st, passes: strict._iteration(p, st, passes, None))
    step_demanding = jax.jit(lambda st, passes: demanding._iteration(p, st, passes, None))
    measures = jax.jit(lambda x, s, f, c, mu: ipm._measures(p, x, s, f, c, mu))
    passes = jnp.zeros((2,), jnp.int32)
    checked = 0
    for _ in range(100):
        if not bool(st.first):
            pre = st._replace(theta_min=jnp.full_like(st.theta_min, jnp.inf))
            post, _ = step(pre, passes)
            alpha, slope, theta0 = float(pre.alpha), float(pre.slope), float(pre.theta0)
            switching = slope < 0 and alpha * (-slope) ** IPM.S_PHI > IPM.DELTA * theta0**IPM.S_THETA
            if switching and int(post.trials) == 0 and float(post.alpha) == alpha and int(post.status) == IpmStatus.RUNNING:
                _, phi = measures(post.x, post.s, post.f, post.c, pre.mu)
                base = float(phi) - ipm.options.armijo * alpha * slope  # phi0 at which Armijo holds with equality
                same = lambda s: bool(jnp.array_equal(s.x, post.x))  # noqa: E731  the first trial point taken
                for miss, margin_accepts in ((3.0, True), (30.0, False)):
                    moved = pre._replace(phi0=jnp.asarray(base - miss * np.finfo(np.float64).eps * abs(base)))
                    with_margin, _ = step(moved, passes)
                    without, _ = step_strict(moved, passes)
                    assert same(with_margin) == margin_accepts, (int(post.it), miss)
                    assert not same(without), (int(post.it), miss)
                # a decrease of half what armijo=0.4 asks for passes the default's test, not its
                moved = pre._replace(phi0=jnp.asarray(float(phi) - 0.5 * 0.4 * alpha * slope))
                assert same(step(moved, passes)[0]) and not same(step_demanding(moved, passes)[0])
                checked += 1
        st, passes = step(st, passes)
        if int(st.status) != IpmStatus.RUNNING or checked >= 3:
            break
    assert checked >= 3


def test_monotone_barrier_strategy_reaches_the_same_solution(toy):
    """The default barrier update is Ipopt's adaptive one; the monotone (Fiacco-McCormick)
    update is an option and must find the same optimum."""
    nlp, ipm = toy
    adaptive = ipm.solve(jnp.zeros((K, 3)), None)
    mono = IPM(nlp, dataclasses.replace(ipm.options, mu_strategy="monotone")).solve(jnp.zeros((K, 3)), None)
    assert int(mono.status) == IpmStatus.CONVERGED and int(adaptive.status) == IpmStatus.CONVERGED
    np.testing.assert_allclose(float(mono.objective), float(adaptive.objective), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(mono.x), np.asarray(adaptive.x), atol=1e-4)
    mus = np.asarray(mono.history)[: int(mono.iterations) + 1, 3]
    assert np.all(np.diff(mus) <= 0)  # monotone: log10 mu never rises
    with pytest.raises(solvers.InvalidOptionError, match="mu_strategy"):
        IpmOptions(mu_strategy="probing")


def test_objective_constraint_filter_globalization(toy):
    """Ipopt's obj-constr-filter rule for leaving the free barrier mode: an iterate that
    improves neither the objective nor the violation on an earlier free-mode iterate sends the
    barrier to the monotone mode at 0.8 times the average complementarity; an improving one
    stays free and joins the filter, dropping the entries it dominates. The solve reaches the
    same optimum as with the KKT-error rule (an option)."""
    nlp, ipm = toy
    filt = ipm
    assert filt.options.adaptive_mu_globalization == "obj-constr-filter"  # Ipopt's default
    r = filt.solve(jnp.zeros((K, 3)), None)
    ref = IPM(nlp, dataclasses.replace(ipm.options, adaptive_mu_globalization="kkt-error")).solve(jnp.zeros((K, 3)), None)
    assert int(r.status) == IpmStatus.CONVERGED
    np.testing.assert_allclose(float(r.objective), float(ref.objective), rtol=1e-6)

    p, st = filt._start(jnp.zeros((K, 3)), None)
    st = st._replace(f=jnp.asarray(2.0), c=jnp.zeros_like(st.c) + 0.01)
    theta = float(filt._infeasibility_l1(p, st.c, st.s))
    avg = float(filt._complementarity(p, st)[0])
    worse = st._replace(mu_filter=st.mu_filter.at[0].set(jnp.array([1.0, 0.5 * theta])))
    mu, free, _, _, kept = filt._update_mu(p, worse, jnp.asarray(False), jnp.asarray(1.0))
    assert not bool(free) and np.isclose(float(mu), 0.8 * avg) and np.array_equal(np.asarray(kept), np.asarray(worse.mu_filter))
    better = st._replace(mu_filter=st.mu_filter.at[0].set(jnp.array([3.0, 2.0 * theta])).at[1].set(jnp.array([1.0, 3.0 * theta])))
    mu, free, _, _, kept = filt._update_mu(p, better, jnp.asarray(False), jnp.asarray(1.0))
    kept = np.asarray(kept)
    assert bool(free)
    assert [2.0, theta] in kept.tolist() and [3.0, 2.0 * theta] not in kept.tolist()  # dominated entry dropped
    assert [1.0, 3.0 * theta] in kept.tolist()
    with pytest.raises(solvers.InvalidOptionError, match="adaptive_mu_globalization"):
        IpmOptions(adaptive_mu_globalization="never")


def test_quality_function_and_loqo_oracles_reach_the_same_solution(toy):
    """The default mu oracle is Ipopt's (the quality function over the affine-scaling and
    centering steps); the LOQO rule is an option: the same optimum, another barrier path."""
    nlp, ipm = toy
    qf = ipm
    assert qf.options.mu_oracle == "quality-function"
    r = qf.solve(jnp.zeros((K, 3)), None)
    ref = IPM(nlp, dataclasses.replace(ipm.options, mu_oracle="loqo")).solve(jnp.zeros((K, 3)), None)
    assert int(ref.status) == IpmStatus.CONVERGED
    assert int(r.status) == IpmStatus.CONVERGED
    np.testing.assert_allclose(float(r.objective), float(ref.objective), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(r.x), np.asarray(ref.x), atol=1e-4)
    mu_qf = np.asarray(r.history)[1 : int(r.iterations) + 1, 3]
    mu_loqo = np.asarray(ref.history)[1 : int(ref.iterations) + 1, 3]
    assert len(mu_qf) != len(mu_loqo) or not np.allclose(mu_qf, mu_loqo)
    # the first direction: mu = sigma avg(d z) with sigma in [sigma_min, sigma_max]
    p, st = qf._start(jnp.zeros((K, 3)), None)
    st, _ = qf._iteration(p, st, jnp.zeros((2,), jnp.int32), None)  # (values, derivatives) so far
    avg = float(qf._complementarity(p, st)[0])
    assert bool(st.free_mode) and qf.options.sigma_min * avg <= float(st.mu) <= qf.options.sigma_max * avg
    with pytest.raises(solvers.InvalidOptionError, match="mu_oracle"):
        IpmOptions(mu_oracle="probing")


def test_vmap_equals_one_by_one_and_no_recompile(toy, monkeypatch):
    """On a CPU the vmapped program splits its batch over the CPU devices (two in the tests,
    conftest), each running its share one member after another (``cpu_batch="sequential"``,
    `lax.map` of the one-problem solve); three members on two devices are padded to four.
    Each member's result is the one-problem program's, and so it is on one CPU device (the
    program of a machine with one core). (The vectorized batch of an accelerator: the next
    test.)"""
    from jtraj.solvers import ipm as ipm_module

    _nlp, ipm = toy
    assert ipm.options.cpu_batch == "sequential"
    assert len(ipm_module._batch_devices()) == 2
    x0s = 0.3 * np.random.default_rng(0).standard_normal((3, K, 3))
    batched = jax.jit(jax.vmap(ipm.solve, in_axes=(0, None)))(jnp.asarray(x0s), None)
    assert len(batched.x.sharding.device_set) == 2  # one program on both devices
    # a fresh NLP, so that its program is traced again, with one CPU device
    monkeypatch.setattr(ipm_module, "_batch_devices", lambda: jax.local_devices(backend="cpu")[:1])
    alone = IPM(double_integrator(), ipm.options)
    one_device = jax.jit(jax.vmap(alone.solve, in_axes=(0, None)))(jnp.asarray(x0s), None)
    assert len(one_device.x.sharding.device_set) == 1
    for i, x0 in enumerate(x0s):
        one = ipm.solve(jnp.asarray(x0), None)
        for batch in (batched, one_device):
            assert int(one.iterations) == int(batch.iterations[i])
            assert int(one.passes) == int(batch.passes[i])
            # (measured: equal to the last bit; the map's body is compiled apart from the
            # one-problem program, so rounding may differ)
            np.testing.assert_allclose(np.asarray(batch.x[i]), np.asarray(one.x), rtol=0, atol=1e-12)
    assert ipm.program._cache_size() == 1  # new initial guesses did not recompile


def test_vmap_keeps_members_line_searches_apart():
    """The vectorized batch (an accelerator's; ``cpu_batch="vectorized"`` on a CPU): a
    pendulum swing-up (nonlinear dynamics) from far-off starts: one member's line search
    backtracks many times, the others' never; the batched line search (its own while loop, run
    to the longest member's) gives every member its own trials, iterates and evaluations, and
    a member that has converged is frozen while the others go on."""
    layout = Layout((("p", 1), ("v", 1), ("u", 1)))

    def step(theta, data, p, v, u, p1, v1):
        return jnp.concatenate([p1 - p - H_STEP * v1, v1 - v - H_STEP * (u - 2.0 * jnp.sin(p1))])

    groups = [ConstraintGroup("dynamics", (Dep("p"), Dep("v"), Dep("u"), Dep("p", 1), Dep("v", 1)), step, np.arange(K - 1),
                              np.zeros((K - 1, 2)), np.zeros((K - 1, 2)), np.ones((K - 1, 2), bool))]
    costs = [CostGroup("effort", (Dep("u"),), lambda theta, data, u: 0.5 * jnp.sum(u**2), np.arange(K))]
    lower, upper = np.tile([-np.inf, -np.inf, -2.0], (K, 1)), np.tile([np.inf, np.inf, 2.0], (K, 1))
    lower[0] = upper[0] = 0.0
    lower[-1, :2] = upper[-1, :2] = [np.pi, 0.0]
    # Ipopt's refinement ratio 1e-10, not the default 1e-6: from the third start the path is
    # chaotic (measured one by one: 64 iterations at 1e-10, 135 at 1e-8 and at 1e-6; over 30
    # such starts, medians 40 and 41), and this test is about the batch, not the step's accuracy
    ipm = IPM(KnotNLP(layout, K, costs, groups, lower, upper), IpmOptions(max_iter=100, cpu_batch="vectorized", residual_ratio_max=1e-10))
    x0s = 30.0 * np.random.default_rng(0).standard_normal((3, K, 3))
    batched = jax.jit(jax.vmap(ipm.solve, in_axes=(0, None)))(jnp.asarray(x0s), None)
    backtracks = []
    for i, x0 in enumerate(x0s):
        one = ipm.solve(jnp.asarray(x0), None)
        assert int(one.status) == int(batched.status[i]) == IpmStatus.CONVERGED
        # (batched and one-by-one arithmetic round differently, and 90 iterations of a
        # nonlinear problem amplify that: counts agree to a few percent, the optimum closely;
        # the two runs stop at different iterates of the tol-1e-3 test, whose controls near
        # their bound differ by about 1e-4). Measured under the tests' XLA flags: 33 and 34
        # iterations (batched, alone) before the factor finished its blocks in its knot step,
        # 36 and 32 after it (34 and 34 under XLA's default flags), with the objectives equal
        # to 1.3e-8 and the iterates to 7e-5; the counts are held to 15 %.
        assert abs(int(one.iterations) - int(batched.iterations[i])) <= 0.15 * int(one.iterations)
        assert abs(int(one.passes) - int(batched.passes[i])) <= 0.15 * int(one.passes)
        np.testing.assert_allclose(float(batched.objective[i]), float(one.objective), rtol=1e-6)
        np.testing.assert_allclose(np.asarray(batched.x[i]), np.asarray(one.x), atol=3e-4)
        backtracks.append(int(batched.passes[i]) - int(batched.iterations[i]))
        # derivatives come only at accepted points: the initial point and one per iteration
        assert int(batched.derivative_passes[i]) == int(batched.iterations[i]) + 1
    assert max(backtracks) > 10 and min(backtracks) == 1  # (the first evaluation is not an iteration)
    assert len({int(i) for i in batched.iterations}) > 1  # each member stopped at its own iteration


def _concave_box():
    """max |z|^2 per knot in the box |z_i| <= 1, |z_1 + z_2| <= 1.5 (3 knots of z in R^2; the
    exact Hessian is -I) and its asymmetric start (0.05, 0.02): (nlp, z0)."""
    nk = 3
    costs = [CostGroup("concave", (Dep("z"),), lambda theta, data, z: -0.5 * jnp.sum(z**2), np.arange(nk))]
    groups = [ConstraintGroup("sum", (Dep("z"),), lambda theta, data, z: z[:1] + z[1:], np.arange(nk),
                              np.full((nk, 1), -1.5), np.full((nk, 1), 1.5), np.ones((nk, 1), bool))]
    nlp = KnotNLP(Layout((("z", 2),)), nk, costs, groups, -np.ones((nk, 2)), np.ones((nk, 2)))
    return nlp, jnp.tile(jnp.array([0.05, 0.02]), (nk, 1))


def test_the_direction_at_a_converged_iterate_is_corrected_for_the_polish():
    """The feasibility polish goes on from a converged iterate with the direction computed
    there; cutting the inertia correction for every member that was not RUNNING (meant for the
    vmapped batch's members stopped before) left that direction uncorrected: a NaN step where
    the Newton matrix needs delta_w > 0 (measured on the side-flip: 32 iterations ending at a
    violation of 1.0e-6 instead of 33 at 5.8e-11)."""
    nlp, z0 = _concave_box()
    ipm = IPM(nlp, IpmOptions(hessian="exact", tol=0.1, compl_inf_tol=1.0, dual_inf_tol=10.0, max_iter=100, feasibility_polish_tol=None))
    p, st = ipm._start(z0, None)
    step = jax.jit(lambda st, passes: ipm._iteration(p, st, passes, None))
    passes = jnp.zeros((2,), jnp.int32)
    for _ in range(5):
        st, passes = step(st, passes)
        if int(st.status) != IpmStatus.RUNNING:
            break
    # converged after one iteration (the loose test), where the concave cost needs a correction
    assert int(st.status) == IpmStatus.CONVERGED and int(st.it) == 1
    assert float(st.delta_w) > 0.0 and bool(jnp.all(jnp.isfinite(st.dx))), (float(st.delta_w), st.dx)


def test_a_stopped_member_of_a_vmapped_batch_makes_no_inertia_correction(monkeypatch):
    """Under vmap a member that has stopped still runs the batch's iteration (its results are
    masked): one whose matrix holds a NaN (a log of a negative point) failed every trial of the
    inertia correction, about 24 factorizations, in each of the other members' iterations."""
    from jtraj.solvers import kkt

    calls: list[int] = []
    real = kkt.factor

    def counting(*args, **kwargs):
        fac, ok = real(*args, **kwargs)
        jax.debug.callback(lambda ok: calls.append(1), ok)  # once per member and factorization
        return fac, ok

    monkeypatch.setattr(kkt, "factor", counting)
    n = 4
    layout = Layout((("p", 1), ("u", 1)))
    costs = [CostGroup("c", (Dep("p"), Dep("u")), lambda th, d, p, u: 0.5 * jnp.sum((p - 2.0) ** 2) + 0.5 * jnp.sum(u**2), np.arange(n))]
    groups = [
        ConstraintGroup("log", (Dep("p"),), lambda th, d, p: jnp.log(p), np.arange(n), np.full((n, 1), -10.0), np.full((n, 1), np.inf), np.ones((n, 1), bool)),
        ConstraintGroup("step", (Dep("p"), Dep("u"), Dep("p", 1)), lambda th, d, p, u, p1: p1 - p - u, np.arange(n - 1), np.zeros((n - 1, 1)), np.zeros((n - 1, 1)), np.ones((n - 1, 1), bool)),
    ]
    ipm = IPM(KnotNLP(layout, n, costs, groups, np.full((n, 2), -np.inf), np.full((n, 2), np.inf)), IpmOptions(max_iter=40, cpu_batch="vectorized"))
    good = jnp.ones((n, 2))
    run = jax.jit(jax.vmap(ipm.solve))
    counts = []
    for batch in (jnp.stack([good, good]), jnp.stack([good, good.at[:, 0].set(-1.0)])):
        calls.clear()
        r = jax.block_until_ready(run(batch))
        counts.append(len(calls))
    assert [IpmStatus(int(s)) for s in r.status] == [IpmStatus.CONVERGED, IpmStatus.NUMERICAL_ERROR]
    assert int(r.iterations[0]) >= 2  # the batch iterated after the second member stopped
    # the stopped member's corrections no longer come with every later iteration of the batch:
    # at most those of the iterations up to its stop (measured: 8 and 54; 192 before)
    assert counts[1] <= counts[0] + 2 * kkt.InertiaOptions().max_attempts, counts


def test_negative_curvature_goes_through_inertia_correction():
    """max |z|^2 in a box: the exact Hessian is -I, so the Newton matrix has the wrong inertia
    where the barrier's curvature is smaller than 1; uncorrected, Newton would jump to the
    stationary point z = 0 (a maximum of the cost). With delta_w the method walks out to a
    vertex (an asymmetric start, so that it does not stop at the saddle (0.75, 0.75) either)."""
    nlp, z0 = _concave_box()
    ipm = IPM(nlp, IpmOptions(hessian="exact", tol=1e-6, max_iter=100))
    # iteration by iteration: once the barrier's curvature no longer outweighs -I, the Newton
    # matrices need delta_w > 0 (measured 2026-12-04: from the second iteration to the eleventh)
    p, st = ipm._start(z0, None)
    step = jax.jit(lambda st, passes: ipm._iteration(p, st, passes, None))
    delta_w, last = [], []
    passes = jnp.zeros((2,), jnp.int32)  # (values, derivatives) evaluated so far
    for _ in range(100):
        st, passes = step(st, passes)
        delta_w.append(float(st.delta_w))
        last.append(float(st.delta_w_last))
        if int(st.status) != IpmStatus.RUNNING:
            break
    assert int(st.status) == IpmStatus.CONVERGED and max(delta_w) > 0.0, delta_w
    # the next correction starts from the last positive delta_w, remembered through the
    # iterations that needed none (Algorithm IC; it was forgotten there and every correction
    # began again at delta_w_first): here the last iterations need none and keep it
    assert delta_w[-1] == 0.0 and last[-1] > 0.0
    for i in range(len(delta_w)):
        used = [w for w in delta_w[: i + 1] if w > 0.0]
        assert last[i] == (used[-1] if used else 0.0), (i, delta_w, last)
    r = ipm.solve(z0, None)
    assert int(r.status) == IpmStatus.CONVERGED
    x = np.asarray(r.x)
    # local minimizers are vertices of {|z_i| <= 1, |z_1 + z_2| <= 1.5}: (1, -1)-like with cost
    # -1 or (1, 0.5)-like with cost -0.625 per knot; the stationary point z = 0 costs 0
    assert float(r.objective) <= -0.625 * z0.shape[0] + 1e-6
    assert np.all(np.max(np.abs(x), axis=1) > 1.0 - 1e-5)
    assert nlp.violation(x.reshape(-1)) < 1e-8


@pytest.mark.slow
def test_converges_on_small_go2_hop():
    """The interior point, through `jtraj.solve`, on the transcription tests' Go2 hop with the
    study's variables. That is the program the jtraj robustness tests run (tests/
    test_experiments.py), so the two files compile it once between them: the second finds it
    in the persistent compilation cache."""
    from test_transcription import HOP

    from jtraj import solve
    from jtraj.solver import prepare

    result = solve(HOP, "se3", variables="paper", solver="jtraj", progress=None)
    assert result.solver_status is solvers.Status.SOLVED and result.converged, result.status_msg
    assert 5 < result.stats.iterations < HOP.max_iter
    # the largest violation of the NLP's rows and bounds at the solver's x (unscaled; measured
    # 2.3e-5 in the dynamics rows, as Ipopt's solution; the study's constr_viol_tol is 1e-4)
    assert result.constraint_violation < 1e-4
    assert set(result.violation_by_group) == set(prepare(HOP, "se3", "paper").nlp.row_groups_summary()) | {"bounds"}


@pytest.mark.parametrize("param", ["quat1", "quat2", "quat3", "euler"])
def test_converges_on_small_go2_hop_with_the_other_parameterizations(param):
    """The same hop with each other floating-base chart (SE(3) is the test above): the
    interior point converges at the study's settings and does the hop, and it reaches the
    minimum Ipopt reaches. The hop's optimal cost is about 0, so at the study's tol 1e-3 each
    solver stops at a small cost (up to a few 1e-3) set by where it stops, which moves with the CPU's
    rounding (measured 2026-12-07 on an AMD EPYC with AVX-512, Quaternion #1, #2, #3, Euler:
    jtraj 4.1e-7, 5.3e-5, 8.7e-4, 1.7e-4, Ipopt 2.6e-3, 1.6e-4, 9.2e-6, 7.1e-4; an earlier
    session's CPU gave jtraj 1.3e-5 on Quaternion #3, and a bound of Ipopt's cost plus 1e-4
    failed here; on an AMD EPYC without AVX-512 on the same day, XLA's AVX2 code, jtraj ended
    Quaternion #3 at 3.7e-3, identically before and after 2026-12-07's fixed-column change,
    where a bound of 1e-3 failed; Ipopt 9.1e-6). At tol 1e-3 the cost is bounded by 1e-2 only;
    the minima are compared at tol 1e-8 (jtraj with the floor
    ``delta_c_min=1e-9`` such tolerances want): both reach 1e-11 to 1e-13 (measured: jtraj
    1.7e-11, 1.1e-11, 7.6e-13, 1.4e-11; Ipopt 2.2e-12, 8.7e-12, 3.4e-13, 1.3e-12). Each chart
    is a program of its own (a compile per case)."""
    from test_transcription import HOP

    from jtraj import solve

    ours = solve(HOP, param, variables="paper", solver="jtraj", progress=None, keep_trajectory=False)
    ipopt = solve(HOP, param, variables="paper", progress=None, keep_trajectory=False)
    assert ours.solver_status is solvers.Status.SOLVED and ours.success, ours.status_msg
    assert ipopt.success, ipopt.status_msg
    assert ours.constraint_violation < 1e-4 and ours.cost < 1e-2, (ours.constraint_violation, ours.cost)
    tight = solve(HOP, param, variables="paper", solver="jtraj", options={"tol": 1e-8, "delta_c_min": 1e-9}, progress=None, keep_trajectory=False)
    ipopt_tight = solve(HOP, param, variables="paper", options={"tol": 1e-8}, progress=None, keep_trajectory=False)
    assert tight.solver_status is solvers.Status.SOLVED and tight.success and ipopt_tight.solver_status is solvers.Status.SOLVED
    assert tight.constraint_violation < 1e-8 and tight.cost <= ipopt_tight.cost + 1e-9, (tight.cost, ipopt_tight.cost)


def test_dual_regularization_floor_keeps_the_tight_tail_at_ipopts_pace():
    """At tol 1e-8, mu reaches mu_min and the scaled ``delta_c mu^(1/4)`` (1.8e-11) makes the
    condensed matrix so ill-conditioned that its Cholesky needs ``delta_w`` about every other
    iteration (measured 2026-12-06: 115 iterations on this hop against Ipopt's 28). A floor of
    1e-9 keeps the tail at Ipopt's pace (measured 28)."""
    from test_transcription import HOP

    from jtraj import solve

    tight = dict(tol=1e-8, constr_viol_tol=1e-8, compl_inf_tol=1e-8, dual_inf_tol=1e-6)
    ours = solve(HOP, "se3", variables="paper", solver="jtraj", progress=None, keep_trajectory=False, ipopt_options=tight | {"delta_c_min": 1e-9})
    ipopt = solve(HOP, "se3", variables="paper", progress=None, keep_trajectory=False, ipopt_options=tight)
    assert ours.solver_status is solvers.Status.SOLVED and ipopt.solver_status is solvers.Status.SOLVED
    assert ours.constraint_violation < 1e-8
    assert ours.iterations <= 1.5 * ipopt.iterations, (ours.iterations, ipopt.iterations)
    with pytest.raises(solvers.InvalidOptionError, match="delta_c_min"):
        solvers.get("jtraj").options({"delta_c_min": -1.0})


def test_registered_backend_returns_the_shared_solution(toy):
    nlp, _ = toy
    backend = solvers.get("jtraj")
    opts = backend.options({"tol": 1e-8, "compl_inf_tol": 1e-8, "constr_viol_tol": 1e-8, "max_iter": 100})
    sol = backend.solve(nlp, np.zeros(nlp.n), None, opts)
    assert sol.status is solvers.Status.SOLVED and sol.converged
    assert sol.constraint_violation < 1e-7 and sol.stats.iterations == len(sol.history) - 1
    # values at the initial point and every trial, derivatives at the initial point and every
    # accepted one (a converged solve accepts one point per iteration)
    st = sol.stats
    assert st.grad_evals == st.jac_evals == st.iterations + 1 and st.obj_evals == st.con_evals >= st.grad_evals
    assert st.hess_evals == 0  # L-BFGS, the default
    assert sol.mult_g.shape == (nlp.m,)
    # the multipliers satisfy stationarity: grad f + J^T y - z_L + z_U = 0 on the free variables
    r = np.asarray(nlp.gradient(sol.x, None)) + nlp.dense_jacobian(sol.x).T @ sol.mult_g - sol.mult_x_lower + sol.mult_x_upper
    free = nlp.x_lower < nlp.x_upper
    assert np.abs(r[free]).max() < 1e-6
    with pytest.raises(solvers.InvalidOptionError, match="hessian"):
        backend.options({"hessian": "newton"})


def test_solve_reports_its_program_compile_once(toy):
    """The first solve of an (NLP, options) pair compiles the solver's program and says how long
    it took (`Solution.time_compile`, outside ``stats.time_total``); the next reuses it."""
    nlp, _ = toy
    backend = solvers.get("jtraj")
    opts = backend.options({"tol": 1e-7, "max_iter": 99})  # options no other test compiles
    texts = [io.StringIO(), io.StringIO()]
    first = backend.solve(nlp, np.zeros(nlp.n), None, opts, solvers.PrintProgress(texts[0]))
    again = backend.solve(nlp, np.zeros(nlp.n), None, opts, solvers.PrintProgress(texts[1]))
    assert first.time_compile > 0 and again.time_compile == 0.0
    # a printing callback hears of the compile before it starts, and not of a reused program
    assert texts[0].getvalue().startswith("jtraj solver: compiling its program")
    assert "compiling" not in texts[1].getvalue() and " iter " in texts[1].getvalue()
    assert first.stats.iterations == again.stats.iterations and first.converged


def test_solve_batch_equals_solve_and_padding_keeps_the_members(toy):
    """`JtrajSolver.solve_batch` with ``strategy="vmap"``: one vmapped call; each member has the
    counts and status of `solve` from the same guess (the toy rounds alike: the solutions agree
    too), and a batch padded to a larger program gives its members the same results as the
    full batch. With ``"threads"`` (the CPU's default) each member is `solve`'s own program, so
    its solution is `solve`'s to the bit."""
    nlp, _ = toy
    backend = solvers.get("jtraj")
    opts = backend.options({"tol": 1e-8, "compl_inf_tol": 1e-8, "constr_viol_tol": 1e-8, "max_iter": 100})
    x0s = 0.3 * np.random.default_rng(1).standard_normal((3, nlp.n))
    batch, total, _ = backend.solve_batch(nlp, x0s, None, opts, strategy="vmap")
    threaded, t_threads, _ = backend.solve_batch(nlp, x0s, None, opts, strategy="threads", threads=2)
    assert backend.default_strategy() == ("threads" if jax.default_backend() == "cpu" else "vmap")
    assert len(batch) == 3 and total > 0 and all(s.stats.time_total == total / 3 for s in batch)
    assert len(threaded) == 3 and all(s.stats.time_total == t_threads / 3 for s in threaded)
    for x0, member, own in zip(x0s, batch, threaded):
        one = backend.solve(nlp, x0, None, opts)
        assert (member.status, member.stats.iterations) == (one.status, one.stats.iterations) and member.converged
        np.testing.assert_allclose(member.x, one.x, atol=1e-9)
        assert (own.status, own.stats.iterations) == (one.status, one.stats.iterations)
        np.testing.assert_array_equal(own.x, one.x)
    padded, _, compile_time = backend.solve_batch(nlp, x0s[2:], None, opts, batch_size=3, strategy="vmap")
    assert compile_time == 0.0  # the batch-of-3 program is reused
    assert padded[0].stats.iterations == batch[2].stats.iterations
    np.testing.assert_array_equal(padded[0].x, batch[2].x)
    with pytest.raises(ValueError, match="4 initial guesses for a batch of 3"):
        backend.solve_batch(nlp, np.zeros((4, nlp.n)), None, opts, batch_size=3)
    with pytest.raises(ValueError, match="unknown strategy 'pmap'"):
        backend.solve_batch(nlp, x0s, None, opts, strategy="pmap")
    with pytest.raises(ValueError, match="threads=0"):
        backend.solve_batch(nlp, x0s, None, opts, strategy="threads", threads=0)


def test_lbfgs_iterates_follow_ipopt_with_skipped_pairs():
    """On a cost concave in z0 and convex in z1 some curvature pairs have s^T y < 0: Ipopt's
    limited-memory BFGS skips them, and after two in a row forgets its memory and drops the
    third pair (limited_memory_max_skipping=2). With the same rule and the adaptive strategy's
    start (mu = 1 for the first factorization, mu_max from the initial complementarity),
    jtraj's solver takes Ipopt's steps: the same iteration count and, iteration by iteration,
    the same barrier parameter and step length (without the reset it takes 9 iterations where
    Ipopt takes 10)."""
    layout = Layout((("z", 2),))
    nk = 3
    costs = [CostGroup("saddle", (Dep("z"),), lambda theta, data, z: -0.5 * z[0] ** 2 + 2.0 * z[1] ** 2 + 0.1 * z[0] - 0.3 * z[1], np.arange(nk))]
    groups = [ConstraintGroup("sum", (Dep("z"),), lambda theta, data, z: z[:1] + 2.0 * z[1:], np.arange(nk),
                              np.full((nk, 1), -1.5), np.full((nk, 1), 1.5), np.ones((nk, 1), bool))]
    nlp = KnotNLP(layout, nk, costs, groups, -np.ones((nk, 2)), np.ones((nk, 2)))
    x0 = np.tile([0.05, 0.02], nk)
    tol = {"tol": 1e-8, "max_iter": 60}
    ipopt = solvers.get("ipopt")
    ref = ipopt.solve(nlp, x0, None, ipopt.options({**tol, "constr_viol_tol": 1e-8, "acceptable_iter": 0, "print_level": 0}))
    ours = solvers.get("jtraj")
    sol = ours.solve(nlp, x0, None, ours.options({**tol, "constr_viol_tol": 1e-8, "compl_inf_tol": 1e-8}))
    assert ref.converged and sol.converged
    assert sol.stats.iterations == ref.stats.iterations > 5
    # Ipopt reports the mu of the step that led to an iterate, jtraj the mu of the next step;
    # the last two steps are taken at the smallest mu either allows (not compared)
    np.testing.assert_allclose([h.mu for h in sol.history[:-3]], [h.mu for h in ref.history[1:-2]], rtol=1e-6)
    np.testing.assert_allclose([h.alpha_pr for h in sol.history[:-2]], [h.alpha_pr for h in ref.history[:-2]], rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(sol.x, ref.x, atol=1e-6)


def test_bound_multiplier_safeguard_is_ipopts():
    """The bound multipliers are kept within kappa_sigma of mu / distance as Ipopt keeps them
    when it accepts a trial point: not at the initial point, and in the adaptive strategy's
    free mode with the trial point's average complementarity as mu. jtraj clamped the initial
    point too, with the step's mu: at kappa_sigma = 10 on HS015 it took 14 iterations where
    Ipopt takes 11 (Ipopt with the differences the solver documents set alike)."""
    layout = Layout((("x", 2),))
    costs = [CostGroup("hs015", (Dep("x"),), lambda theta, data, x: 100.0 * (x[1] - x[0] ** 2) ** 2 + (1.0 - x[0]) ** 2, np.arange(1))]
    groups = [ConstraintGroup("rows", (Dep("x"),), lambda theta, data, x: jnp.stack([x[0] * x[1], x[0] + x[1] ** 2]), np.arange(1),
                              np.array([[1.0, 0.0]]), np.full((1, 2), np.inf), np.ones((1, 2), bool))]
    nlp = KnotNLP(layout, 1, costs, groups, np.full((1, 2), -np.inf), np.array([[0.5, np.inf]]))
    x0 = np.array([-2.0, 1.0])
    ipopt, ours = solvers.get("ipopt"), solvers.get("jtraj")
    common = {"tol": 1e-8, "constr_viol_tol": 1e-8, "max_iter": 200, "kappa_sigma": 10.0}
    # Ipopt without its least-squares multipliers and bound relaxation, which jtraj's solver lacks
    ref = ipopt.solve(nlp, x0, None, ipopt.options({**common, "acceptable_iter": 0, "print_level": 0, "recalc_y": "no", "constr_mult_init_max": 0.0, "bound_relax_factor": 0.0, "kappa_d": 0.0}))
    sol = ours.solve(nlp, x0, None, ours.options({**common, "compl_inf_tol": 1e-8}))
    assert ref.converged and sol.converged
    assert sol.stats.iterations == ref.stats.iterations == 11
    np.testing.assert_allclose(sol.x, ref.x, atol=1e-6)


@pytest.mark.parametrize(("mu_strategy", "iterations"), [("monotone", 13), ("adaptive", 9)])
def test_inertia_correction_perturbs_the_slacks_as_ipopt(mu_strategy, iterations):
    """On the concave box (exact Hessian -I: the inertia correction works every iteration) the
    inequality rows' slacks get delta_w too, as Ipopt's: jtraj's solver takes Ipopt's
    iterations (13 monotone, 9 adaptive; it took 18 and 13 when only the variables' block was
    perturbed, and Ipopt's own iterates are the same whether the box's row has a slack of its
    own or an explicit slack variable). Ipopt with the differences the solver documents set
    alike."""
    nlp, z0 = _concave_box()
    ipopt, ours = solvers.get("ipopt"), solvers.get("jtraj")
    common = {"tol": 1e-8, "constr_viol_tol": 1e-8, "max_iter": 80, "hessian": "exact", "mu_strategy": mu_strategy}
    ref = ipopt.solve(nlp, np.asarray(z0).ravel(), None, ipopt.options({**common, "acceptable_iter": 0, "print_level": 0, "recalc_y": "no", "constr_mult_init_max": 0.0, "bound_relax_factor": 0.0, "kappa_d": 0.0}))
    sol = ours.solve(nlp, np.asarray(z0).ravel(), None, ours.options({**common, "compl_inf_tol": 1e-8}))
    assert ref.converged and sol.converged
    assert sol.stats.iterations == ref.stats.iterations == iterations
    np.testing.assert_allclose(sol.objective, ref.objective, rtol=1e-8)


def test_second_order_corrections_let_the_full_step_through():
    """The Maratos example (Nocedal and Wright, eq. 15.34): min 2 (x^2 + y^2 - 1) - x on the unit
    circle, from a point on the circle where the full Newton step raises both the objective and
    the violation, so the filter rejects it. With second-order corrections (max_soc=4, Ipopt's
    default) the corrected full step is accepted, as Ipopt accepts it, and the solve takes fewer
    iterations; without them the first step is halved."""
    layout = Layout((("p", 2),))
    nk = 2
    costs = [CostGroup("maratos", (Dep("p"),), lambda theta, data, p: 2.0 * (p[0] ** 2 + p[1] ** 2 - 1.0) - p[0], np.arange(nk))]
    groups = [ConstraintGroup("circle", (Dep("p"),), lambda theta, data, p: (p[0] ** 2 + p[1] ** 2)[None], np.arange(nk),
                              np.ones((nk, 1)), np.ones((nk, 1)), np.ones((nk, 1), bool))]
    nlp = KnotNLP(layout, nk, costs, groups, np.tile([-2.0, -np.inf], (nk, 1)), np.tile([2.0, np.inf], (nk, 1)))
    x0 = np.tile([np.cos(0.3), np.sin(0.3)], nk)
    ipopt, ours = solvers.get("ipopt"), solvers.get("jtraj")
    runs = {}
    for max_soc in (0, 4):
        common = {"tol": 1e-8, "max_iter": 60, "constr_viol_tol": 1e-8, "max_soc": max_soc}
        ref = ipopt.solve(nlp, x0, None, ipopt.options({**common, "acceptable_iter": 0, "print_level": 0}))
        sol = ours.solve(nlp, x0, None, ours.options({**common, "compl_inf_tol": 1e-8}))
        assert ref.converged and sol.converged
        np.testing.assert_allclose(sol.x.reshape(nk, 2), np.tile([1.0, 0.0], (nk, 1)), atol=1e-6)
        # the first step: halved without corrections, full with them, in both solvers
        assert sol.history[1].alpha_pr == ref.history[1].alpha_pr == (0.5 if max_soc == 0 else 1.0)
        runs[max_soc] = sol.stats.iterations
    assert runs[4] < runs[0]


def test_feasibility_polish_after_a_loose_convergence_test():
    """Converged at a loose violation limit, the solve goes on while the violation is above
    feasibility_polish_tol (at most feasibility_polish_iter iterations, never past max_iter),
    returns a converged iterate whatever happens, and does the same under vmap (vectorized, as
    on an accelerator: the polishing member's updates masked apart from the others')."""
    nlp = double_integrator()
    loose = IpmOptions(tol=1e-2, constr_viol_tol=1e-2, compl_inf_tol=1e-2, max_iter=100, feasibility_polish_tol=None, cpu_batch="vectorized")
    x0 = jnp.zeros((K, 3))
    plain = IPM(nlp, loose).solve(x0, None)
    n, v = int(plain.iterations), float(plain.constr_viol)
    assert int(plain.status) == IpmStatus.CONVERGED and 1e-12 < v < 1e-2
    history = np.asarray(plain.history)[: n + 1]

    ipm = IPM(nlp, dataclasses.replace(loose, feasibility_polish_tol=v / 10))  # compiled once, used again under vmap below
    polished = ipm.solve(x0, None)
    assert int(polished.status) == IpmStatus.CONVERGED
    assert int(polished.iterations) > n and float(polished.constr_viol) <= v / 10
    np.testing.assert_array_equal(np.asarray(polished.history)[: n + 1], history)  # the same run up to there
    assert nlp.violation(np.asarray(polished.x).reshape(-1)) <= v / 10 * (1 + 1e-9)

    # an unreachable tolerance: exactly feasibility_polish_iter more iterations, the lower violation kept
    capping = IPM(nlp, dataclasses.replace(loose, feasibility_polish_tol=1e-300, feasibility_polish_iter=2))
    capped = capping.solve(x0, None)
    assert int(capped.status) == IpmStatus.CONVERGED and int(capped.iterations) == n + 2
    assert float(capped.constr_viol) <= v
    # the tolerances are inputs of the program: the two IPMs ran one program, compiled once;
    # turning the polish off (None) or another iteration limit is another program
    assert capping.program is ipm.program and ipm.program._cache_size() == 1
    assert IPM(nlp, loose).program is not ipm.program
    assert IPM(nlp, dataclasses.replace(loose, feasibility_polish_tol=v / 10, max_iter=99)).program is not ipm.program

    # the polish steps onto the constraints (`IPM._projection`), which are linear here: one
    # step from 3.7e-9 at iteration 4 lands on them to rounding (measured 5.9e-14) and passes
    # the test, the multipliers kept (Newton iterations, the polish before, failed the test at
    # iteration 5 and reached 5.7e-10 at 6)
    early = dataclasses.replace(loose, tol=0.05, compl_inf_tol=1.0)
    first = IPM(nlp, early).solve(x0, None)
    assert int(first.iterations) == 4 and 1e-9 < float(first.constr_viol) < 1e-8
    went_on = IPM(nlp, dataclasses.replace(early, feasibility_polish_tol=1e-12)).solve(x0, None)
    assert int(went_on.status) == IpmStatus.CONVERGED and int(went_on.iterations) == 5
    assert float(went_on.constr_viol) <= 1e-12 and nlp.violation(np.asarray(went_on.x).reshape(-1)) <= 1e-12
    np.testing.assert_array_equal(np.asarray(went_on.y), np.asarray(first.y))
    assert abs(float(went_on.objective) - float(first.objective)) < 1e-6
    np.testing.assert_array_equal(np.asarray(went_on.history)[:5], np.asarray(first.history)[:5])

    # the polish's rules where a polishing iteration fails the convergence test, with Newton
    # steps in place of the projection (the polish before it; an IPM subclass needs an NLP of
    # its own, since IPMs of one NLP and options share their compiled program): iteration 5
    # fails the test (the dual infeasibility jumps from 0.016 to 0.31), the polish goes on and
    # iteration 6 passes within the tolerance (5.7e-10)...
    class NewtonPolish(IPM):
        def _projection(self, p, st):
            return st

    newton = dataclasses.replace(early, feasibility_polish_tol=1e-9)
    went_on = NewtonPolish(double_integrator(), newton).solve(x0, None)
    assert int(went_on.status) == IpmStatus.CONVERGED and int(went_on.iterations) == 6
    assert float(went_on.constr_viol) <= 1e-9
    # ... and with one polishing iteration, the one that fails the test, iteration 4 comes back
    # after one more evaluation
    handed_back = NewtonPolish(double_integrator(), dataclasses.replace(newton, feasibility_polish_iter=1)).solve(x0, None)
    assert int(handed_back.status) == IpmStatus.CONVERGED and int(handed_back.iterations) == 4
    assert int(handed_back.passes) > int(first.passes)
    np.testing.assert_array_equal(np.asarray(handed_back.x), np.asarray(first.x))

    # a projection that cannot be taken (a factorization that failed at the converged iterate,
    # which no status reports there) ends the polish at once with the converged iterate, not
    # after a line search of non-finite trials (30 evaluations)
    class NoProjection(IPM):
        def _projection(self, p, st):
            return st._replace(dx=jnp.full_like(st.dx, jnp.nan))

    unusable = NoProjection(double_integrator(), newton).solve(x0, None)
    assert int(unusable.status) == IpmStatus.CONVERGED and int(unusable.iterations) == 4
    assert int(unusable.passes) == int(first.passes)
    np.testing.assert_array_equal(np.asarray(unusable.x), np.asarray(first.x))

    # converged at the iteration limit: nothing to polish with
    at_limit = IPM(nlp, dataclasses.replace(loose, feasibility_polish_tol=1e-300, max_iter=n)).solve(x0, None)
    assert int(at_limit.status) == IpmStatus.CONVERGED and int(at_limit.iterations) == n
    assert float(at_limit.constr_viol) == v

    starts = jnp.stack([x0, x0.at[1:-1, 0].set(0.5)])
    batched = jax.jit(jax.vmap(ipm.solve, in_axes=(0, None)))(starts, None)
    for i in range(2):
        one = ipm.solve(starts[i], None)
        assert int(batched.iterations[i]) == int(one.iterations) and int(batched.status[i]) == int(one.status)
        np.testing.assert_allclose(np.asarray(batched.x[i]), np.asarray(one.x), atol=1e-8)
    with pytest.raises(solvers.InvalidOptionError, match="feasibility_polish_tol"):
        IpmOptions(feasibility_polish_tol=0.0)
    # fields are checked by the type of their default: booleans, finite numbers
    with pytest.raises(solvers.InvalidOptionError, match="bfgs_scaling=1: expected true or false"):
        IpmOptions(bfgs_scaling=1)
    with pytest.raises(solvers.InvalidOptionError, match="kappa_soc=nan: expected a finite number"):
        IpmOptions(kappa_soc=float("nan"))
    with pytest.raises(solvers.InvalidOptionError, match="armijo=True: expected a finite number"):
        IpmOptions(armijo=True)


def test_every_termination_has_a_shared_status():
    """`IpmStatus.shared`: how each end of the loop is reported in the shared enumeration (the
    benchmarks' records use it)."""
    from jtraj.solvers.ipm import _STATUS

    assert IpmStatus.CONVERGED.shared is solvers.Status.SOLVED
    assert IpmStatus.MAX_ITER.shared is solvers.Status.MAX_ITER
    # every termination has its entry (a missing one raised KeyError only when it occurred)
    assert set(_STATUS) == set(IpmStatus)
    assert all(isinstance(s.shared, solvers.Status) for s in IpmStatus)


def test_a_failed_inertia_correction_is_not_reported_as_nan(monkeypatch):
    """When no delta_w up to delta_w_max gives the Newton matrix the right inertia, the solve
    ends as a failed step computation with its own message; it ended as NUMERICAL_ERROR, which
    the shared status describes as a function returning NaN or Inf."""
    from jtraj.solvers import kkt

    # an NLP of its own: its compiled programs, kept on the NLP, must not serve other tests
    nlp = double_integrator()
    real = kkt.factor_with_correction

    def never(system, delta_c, delta_w_last, options=kkt.InertiaOptions(), active=True):
        fac, delta_w, _ = real(system, delta_c, delta_w_last, options, active)
        return fac, delta_w, jnp.asarray(False)

    monkeypatch.setattr(kkt, "factor_with_correction", never)
    r = IPM(nlp, IpmOptions(tol=1e-8, max_iter=20)).solve(jnp.zeros((K, 3)), None)
    assert int(r.status) == IpmStatus.INERTIA_FAILED
    assert IpmStatus.INERTIA_FAILED.shared is solvers.Status.STEP_COMPUTATION_FAILED
    sol = solvers.get("jtraj").solve(nlp, np.zeros(nlp.n), None, {"tol": 1e-8, "max_iter": 20})
    assert sol.status is solvers.Status.STEP_COMPUTATION_FAILED and "delta_w" in sol.message, sol.message


def test_ipms_made_side_by_side_share_one_program():
    """IPMs of one NLP and options made in several threads at once (the forward solves of a
    vmapped `jtraj.differentiable`) share one owner's compiled programs (regression: each
    thread's IPM had its own, and each compiled the program again, one after another)."""
    from concurrent.futures import ThreadPoolExecutor

    nlp = double_integrator()
    options = IpmOptions(tol=1e-6)
    with ThreadPoolExecutor(4) as pool:
        ipms = list(pool.map(lambda _: IPM(nlp, options), range(4)))
    assert len({id(ipm.compiled) for ipm in ipms}) == 1 and len({id(ipm.view) for ipm in ipms}) == 1
    assert len(nlp.solver_programs) == 1


def test_a_tight_solve_at_its_limit_warns_with_the_floor_to_set():
    """A tight solve (tol 1e-15) that reaches its iteration limit with mu at mu_min and no floor
    under delta_c says which delta_c_min to set, in its message and in a RuntimeWarning; with
    the floor set it does not. (With mu_min not given it is Ipopt's tol / 2, and the same
    solve converges in 15 iterations, Ipopt's 16; given as 1e-11 it stops at the limit.)"""
    import warnings

    nlp = double_integrator()
    tight = {"tol": 1e-15, "constr_viol_tol": 1e-15, "compl_inf_tol": 1e-15, "max_iter": 20}
    backend = solvers.get("jtraj")
    assert backend.solve(nlp, np.zeros(nlp.n), None, tight).converged
    tight["mu_min"] = 1e-11
    with pytest.warns(RuntimeWarning, match="set delta_c_min=1e-9"):
        sol = backend.solve(nlp, np.zeros(nlp.n), None, tight)
    assert sol.status is solvers.Status.MAX_ITER and "delta_c_min=1e-9" in sol.message
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        floored = backend.solve(nlp, np.zeros(nlp.n), None, {**tight, "delta_c_min": 1e-9})
    assert "delta_c_min" not in floored.message


def fixed_ends_double_integrator() -> KnotNLP:
    """The double integrator without any bound on a free variable and without inequality rows:
    fixed end points, the dynamics rows and the effort cost."""
    layout = Layout((("p", 1), ("v", 1), ("u", 1)))

    def step(theta, data, p, v, u, p1, v1):
        return jnp.concatenate([p1 - p - H_STEP * v1, v1 - v - H_STEP * u])

    groups = [ConstraintGroup("dynamics", (Dep("p"), Dep("v"), Dep("u"), Dep("p", 1), Dep("v", 1)), step, np.arange(K - 1),
                              np.zeros((K - 1, 2)), np.zeros((K - 1, 2)), np.ones((K - 1, 2), bool))]
    costs = [CostGroup("effort", (Dep("u"),), lambda theta, data, u: 0.5 * jnp.sum(u**2), np.arange(K))]
    lower, upper = np.full((K, 3), -np.inf), np.full((K, 3), np.inf)
    lower[0] = upper[0] = 0.0
    lower[-1] = upper[-1] = [1.0, 0.0, 0.0]
    return KnotNLP(layout, K, costs, groups, lower, upper)


@pytest.mark.parametrize("oracle", ["quality-function", "loqo"])
def test_a_problem_without_bounds_keeps_mu_at_mu_min(oracle):
    """Regression: without bounds the average complementarity is 0, so mu_max and then mu were
    0, the dual regularization delta_c mu^(1/4) vanished, and every factorization failed
    (step_computation_failed at the first iteration, where Ipopt solves it). As Ipopt's
    adaptive update, mu stays at mu_min."""
    nlp = fixed_ends_double_integrator()
    ours = solvers.get("jtraj").solve(nlp, np.zeros(nlp.n), None, {"mu_oracle": oracle, "tol": 1e-8})
    ref = solvers.get("ipopt").solve(nlp, np.zeros(nlp.n), None, {"tol": 1e-10})
    assert ours.converged and ref.converged, (ours.status, ours.message)
    assert {it.mu for it in ours.history[1:]} == {IpmOptions(tol=1e-8).mu_min_value()}
    np.testing.assert_allclose(ours.x, ref.x, atol=1e-6)
    assert ours.stats.iterations <= ref.stats.iterations + 2


def test_mu_min_follows_ipopts_rule_when_not_given(toy):
    """Ipopt's mu_min, when not given, is min(1e-11, tol / 2, compl_inf_tol / 2): at tol 1e-13
    its mu reaches 5e-14 on the toy, and so does this solver's; a given mu_min is kept."""
    assert IpmOptions().mu_min_value() == 1e-11 and IpmOptions(tol=1e-13, compl_inf_tol=1e-12).mu_min_value() == 5e-14
    assert IpmOptions(tol=1e-13, mu_min=1e-9).mu_min_value() == 1e-9
    nlp, _ = toy
    tight = {"tol": 1e-13, "constr_viol_tol": 1e-13, "compl_inf_tol": 1e-13, "max_iter": 100}
    ours = solvers.get("jtraj").solve(nlp, np.zeros(nlp.n), None, tight)
    ref = solvers.get("ipopt").solve(nlp, np.zeros(nlp.n), None, tight)
    assert ours.converged and ref.converged
    assert min(it.mu for it in ref.history) == 5e-14
    assert min(it.mu for it in ours.history) == pytest.approx(5e-14, rel=1e-9)  # (sigma avg at its lower end)
    assert ours.stats.iterations <= ref.stats.iterations + 2  # 18 with mu_min 1e-11, Ipopt 13


def test_the_cpu_batching_rule_does_not_compile_the_one_problem_program_again():
    """cpu_batch chooses how a vmap of the program is batched on a CPU; it keyed the program,
    so a solve with cpu_batch="vectorized" compiled the same one-problem program again."""
    nlp = double_integrator()  # its own NLP: the first solve compiles its program
    backend = solvers.get("jtraj")
    first = backend.solve(nlp, np.zeros(nlp.n))
    other = backend.solve(nlp, np.zeros(nlp.n), None, {"cpu_batch": "vectorized"})
    assert first.time_compile > 0 and other.time_compile == 0.0 and len(nlp.solver_programs) == 1
    np.testing.assert_array_equal(first.x, other.x)
    # each batching rule has its own batch program (the vectorized one steps its members together)
    x0s = np.zeros((2, nlp.n))
    for batch in ("sequential", "vectorized"):
        sols, _, compile_time = backend.solve_batch(nlp, x0s, None, {"cpu_batch": batch}, strategy="vmap")
        assert compile_time > 0 and all(s.converged for s in sols)


def test_whole_numbers_for_real_options_solve_and_leave_the_defaults_working():
    """An int (1 for 1.0) for a real option reached the loop's state as int64 and the trace
    failed ('cond branches must have equal output types'); as 1 == 1.0, those options keyed
    the defaults' program, registered before its compile failed, and every later solve of
    the NLP, the defaults' included, failed the same way. Options are stored as their
    fields' types, so both solves share one program."""
    nlp = double_integrator()  # its own NLP: the first solve compiles its program
    backend = solvers.get("jtraj")
    ints = backend.solve(nlp, np.zeros(nlp.n), None, {"lbfgs_init_val": 1, "s_max": 100, "max_iter": np.int64(200)})  # the defaults
    assert ints.converged and ints.time_compile > 0
    default = backend.solve(nlp, np.zeros(nlp.n))
    assert default.converged and default.time_compile == 0.0  # the same program
    assert default.stats.iterations == ints.stats.iterations
    np.testing.assert_array_equal(default.x, ints.x)
    # the other options the state is built from, and numpy's float32: traced and run
    options = {"mu_strategy": "monotone", "mu_init": 1, "delta_c": 1, "delta_c_mu_scaled": False, "tau_min": np.float32(0.99), "mu_max": 1000, "max_iter": 5}
    ran = backend.solve(nlp, np.zeros(nlp.n), None, options)
    assert ran.status is solvers.Status.MAX_ITER and ran.stats.iterations == 5


def test_a_program_whose_compile_failed_is_not_kept_for_the_nlp(monkeypatch):
    """The NLP kept the IPM of a program whose trace or compile raised, so its next solves with
    the same options reused that failing program instead of tracing their own."""
    nlp = double_integrator()
    real = IPM._solve

    def failing(self, x0, theta, tols):
        raise RuntimeError("the trace failed")

    monkeypatch.setattr(IPM, "_solve", failing)
    with pytest.raises(RuntimeError, match="the trace failed"):
        solvers.get("jtraj").solve(nlp, np.zeros(nlp.n))
    assert not nlp.solver_programs
    monkeypatch.setattr(IPM, "_solve", real)
    assert solvers.get("jtraj").solve(nlp, np.zeros(nlp.n)).converged


def test_fixed_variables_get_ipopts_bound_multipliers(toy):
    """The fixed variables (the first and last knots) are out of the step and had zero bound
    multipliers, so grad f + J^T y - z_L + z_U was 4 there; they are, as Ipopt reports them
    (fixed_variable_treatment=make_parameter), max(r, 0) and max(-r, 0) of r = grad f + J^T y."""
    nlp, _ = toy
    tight = {"tol": 1e-8, "compl_inf_tol": 1e-8, "constr_viol_tol": 1e-8, "max_iter": 100}  # the toy's program
    ours = solvers.get("jtraj").solve(nlp, np.zeros(nlp.n), None, tight)
    ref = solvers.get("ipopt").solve(nlp, np.zeros(nlp.n), None, {"tol": 1e-10, "hessian": "exact"})
    assert ours.converged and ref.converged
    fixed = nlp.x_lower == nlp.x_upper
    assert fixed.sum() == 6
    r = np.asarray(nlp.gradient(ours.x, None)) + nlp.dense_jacobian(ours.x).T @ ours.mult_g - ours.mult_x_lower + ours.mult_x_upper
    assert np.abs(r).max() < 1e-6  # on every variable, fixed ones included
    assert np.abs(ours.mult_x_upper[fixed]).max() > 1.0  # they carry multipliers
    assert (ours.mult_x_lower >= 0).all() and (ours.mult_x_upper >= 0).all() and not (ours.mult_x_lower * ours.mult_x_upper)[fixed].any()
    np.testing.assert_allclose(ours.mult_x_lower[fixed], ref.mult_x_lower[fixed], atol=1e-4)
    np.testing.assert_allclose(ours.mult_x_upper[fixed], ref.mult_x_upper[fixed], atol=1e-4)


def test_a_nan_exact_hessian_is_a_numerical_error():
    """A cost whose Hessian is infinite at the start (|u|^1.5 at u = 0): every delta_w failed,
    and the solve was reported as a failed step computation (no delta_w made the matrix
    positive definite) instead of a function's NaN or Inf, as a NaN gradient is."""
    layout = Layout((("p", 1), ("v", 1), ("u", 1)))

    def step(theta, data, p, v, u, p1, v1):
        return jnp.concatenate([p1 - p - H_STEP * v1, v1 - v - H_STEP * u])

    groups = [ConstraintGroup("dynamics", (Dep("p"), Dep("v"), Dep("u"), Dep("p", 1), Dep("v", 1)), step, np.arange(K - 1),
                              np.zeros((K - 1, 2)), np.zeros((K - 1, 2)), np.ones((K - 1, 2), bool))]
    costs = [CostGroup("effort", (Dep("u"),), lambda theta, data, u: 0.5 * jnp.sum(u**2) + jnp.sum(jnp.abs(u) ** 1.5), np.arange(K))]
    lower, upper = np.tile([-np.inf, -np.inf, -U_MAX], (K, 1)), np.tile([np.inf, np.inf, U_MAX], (K, 1))
    lower[0] = upper[0] = 0.0
    lower[-1] = upper[-1] = [1.0, 0.0, 0.0]
    nlp = KnotNLP(layout, K, costs, groups, lower, upper)
    sol = solvers.get("jtraj").solve(nlp, np.zeros(nlp.n), None, {"hessian": "exact", "max_iter": 20})
    assert sol.status is solvers.Status.NUMERICAL_ERROR and sol.stats.iterations == 0, (sol.status, sol.message)
    assert "NaN or Inf" in sol.message and "Hessian" in sol.message


def test_a_nan_objective_is_a_numerical_error():
    """The convergence test never reads the objective: a start where f is NaN (a log of a
    negative number) but the gradient is zero was reported SOLVED with objective NaN, and one
    with a finite gradient went on with a NaN barrier function. Ipopt: an invalid number."""
    layout = Layout((("z", 2),))
    costs = [CostGroup("c", (Dep("z"),), lambda theta, data, z: (z[0] + 0.51) ** 2 + 0.01 * jnp.log(z[0]) + (z[1] - 0.5) ** 2, np.arange(2))]
    nlp = KnotNLP(layout, 2, costs, [], np.full((2, 2), -np.inf), np.full((2, 2), np.inf))
    x0 = np.tile([-0.5, 0.5], 2)
    assert np.isnan(float(nlp.objective(x0, None))) and np.abs(np.asarray(nlp.gradient(x0, None))).max() < 1e-12
    sol = solvers.get("jtraj").solve(nlp, x0, None, {"tol": 1e-8})
    assert sol.status is solvers.Status.NUMERICAL_ERROR and not sol.converged and sol.stats.iterations == 0, (sol.status, sol.objective)


def test_loqo_oracle_takes_ipopts_fraction_to_the_boundary():
    """With the LOQO oracle the free mode's fraction to the boundary was 1 - mu, Ipopt's is
    1 - (NLP error) with every oracle: on HS071 (here on two knots) 15 iterations where Ipopt
    takes 10. With Ipopt's rule the runs take the same barrier parameters."""
    layout = Layout((("x", 4),))
    cost = [CostGroup("hs071", (Dep("x"),), lambda theta, data, x: x[0] * x[3] * (x[0] + x[1] + x[2]) + x[2], np.arange(2))]
    rows = [ConstraintGroup("rows", (Dep("x"),), lambda theta, data, x: jnp.stack([jnp.prod(x), jnp.sum(x**2)]), np.arange(2),
                            np.tile([25.0, 40.0], (2, 1)), np.tile([np.inf, 40.0], (2, 1)), np.ones((2, 2), bool))]
    nlp = KnotNLP(layout, 2, cost, rows, np.ones((2, 4)), np.full((2, 4), 5.0))
    x0 = np.tile([1.0, 5.0, 5.0, 1.0], 2)
    tight = {"tol": 1e-8, "constr_viol_tol": 1e-8, "compl_inf_tol": 1e-8, "mu_oracle": "loqo"}
    ours = solvers.get("jtraj").solve(nlp, x0, None, tight)
    ref = solvers.get("ipopt").solve(nlp, x0, None, tight | {"mu_strategy": "adaptive", "hessian_approximation": "limited-memory", "acceptable_iter": 0})
    assert ours.converged and ref.converged and abs(ours.objective - ref.objective) < 1e-6
    assert ours.stats.iterations == ref.stats.iterations, ([h.mu for h in ours.history], [h.mu for h in ref.history])
    # (Ipopt's row k shows the mu of iteration k's step, this solver's the mu chosen after it)
    np.testing.assert_allclose([h.mu for h in ours.history[:-1]], [h.mu for h in ref.history[1:]], rtol=1e-3)


def test_a_nan_derivative_of_a_fixed_variable_is_removed_and_a_free_ones_is_a_numerical_error():
    """A row |u| <= U_MAX written with a norm, whose derivative is NaN at u = 0. With u fixed
    to 0 at both ends, the NaN lies only in fixed variables' columns, which Ipopt removes
    (make_parameter) and solves in 11 iterations; jtraj's solver masked them by multiplying by 0
    (NaN * 0 = NaN), failed every delta_w and stopped at iteration 0 as a failed step
    computation. From u = 0 everywhere the NaN is in free columns: an invalid number in a
    derivative (NUMERICAL_ERROR, as for a NaN Hessian), not a failed inertia correction."""
    layout = Layout((("p", 1), ("v", 1), ("u", 1)))

    def step(theta, data, p, v, u, p1, v1):
        return jnp.concatenate([p1 - p - H_STEP * v1, v1 - v - H_STEP * u])

    groups = [
        ConstraintGroup("dynamics", (Dep("p"), Dep("v"), Dep("u"), Dep("p", 1), Dep("v", 1)), step, np.arange(K - 1),
                        np.zeros((K - 1, 2)), np.zeros((K - 1, 2)), np.ones((K - 1, 2), bool)),
        ConstraintGroup("unorm", (Dep("u"),), lambda theta, data, u: jnp.linalg.norm(u)[None], np.arange(K),
                        np.full((K, 1), -np.inf), np.full((K, 1), U_MAX), np.ones((K, 1), bool)),
    ]
    costs = [CostGroup("effort", (Dep("u"),), lambda theta, data, u: 0.5 * jnp.sum(u**2), np.arange(K))]
    lower, upper = np.full((K, 3), -np.inf), np.full((K, 3), np.inf)
    lower[0] = upper[0] = 0.0
    lower[-1] = upper[-1] = [1.0, 0.0, 0.0]
    nlp = KnotNLP(layout, K, costs, groups, lower, upper)
    x0 = np.tile([0.5, 0.1, 0.1], (K, 1))
    x0[0], x0[-1] = lower[0], lower[-1]
    J = np.asarray(nlp.jacobian(x0.reshape(-1), None))
    assert not np.isfinite(J).all()  # the fixed u's entries
    jt = solvers.get("jtraj")
    sol = jt.solve(nlp, x0.reshape(-1), None, {"tol": 1e-8, "max_iter": 50})
    ref = solvers.get("ipopt").solve(nlp, x0.reshape(-1), None, {"tol": 1e-8, "max_iter": 50})
    assert ref.converged and sol.status is solvers.Status.SOLVED, (sol.status, sol.message)
    np.testing.assert_allclose(sol.objective, ref.objective, rtol=1e-6)
    x0[:, 2] = 0.0
    bad = jt.solve(nlp, x0.reshape(-1), None, {"tol": 1e-8, "max_iter": 50})
    assert bad.status is solvers.Status.NUMERICAL_ERROR and bad.stats.iterations == 0, (bad.status, bad.message)
