"""Wahba's problem (paper Section IV): SVD reference against an independent oracle, the
convergence behaviour of Algorithms 1 and 2 and of the multiplicative Newton method,
jit-once and vmap-vs-loop checks, and the output files."""

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jtraj import quaternion as Q
from jtraj.attitude import wahba as W

TRIALS = 16
ITERATIONS = 11
FLOOR = 1e-12  # well above the ~4e-16 double-precision floor of the SVD reference


@pytest.fixture(scope="module")
def result():
    return W.run_wahba(trials=TRIALS, iterations=ITERATIONS, seed=0)


@pytest.fixture(scope="module")
def problems():
    keys = jax.random.split(jax.random.PRNGKey(7), 4)
    return [W.generate_problem(k) for k in keys]


def test_problem_instance_matches_the_description(problems):
    for p in problems:
        assert p.v_world.shape == (20, 3) and p.v_body.shape == (20, 3)
        np.testing.assert_allclose(np.linalg.norm(p.v_world, axis=1), 1.0, atol=1e-14)
        np.testing.assert_allclose(np.linalg.norm(p.v_body, axis=1), 1.0, atol=1e-14)
        q_svd = W.solve_svd(p)
        # the initial guess is exactly 10 degrees from the SVD solution
        assert abs(W.angle_error(p.q_world_body_init, q_svd) - math.radians(10.0)) < 1e-13
        # noise: each measurement is a few degrees (Rayleigh, scale 5 deg) off the truth
        A = np.asarray(Q.rotation_matrix(p.q_world_body_true))
        cosines = np.sum(np.asarray(p.v_world) * (np.asarray(p.v_body) @ A.T), axis=1)
        angles = np.degrees(np.arccos(np.clip(cosines, -1, 1)))
        assert 1.0 < np.mean(angles) < 15.0 and np.max(angles) < 30.0
        # and the estimate lies between the truth and the noise level
        assert W.angle_error(q_svd, p.q_world_body_true) < math.radians(5.0)


def test_svd_solution_is_about_two_degrees_from_the_truth():
    """The module docstring's number (it said 1 degree): 5 degrees of noise per axis over 20
    vectors leave 5 / sqrt(2 * 20 / 3) = 1.37 degrees per axis, a mean angle of about 2.2."""
    keys = jax.random.split(jax.random.PRNGKey(0), 100)
    error = jax.jit(jax.vmap(lambda k: (lambda p: W.angle_error(W.solve_svd(p), p.q_world_body_true))(W.generate_problem(k))))
    mean_deg = float(np.degrees(np.mean(error(keys))))
    assert 2.0 < mean_deg < 2.6, mean_deg
    assert "about 2 degrees from the true attitude" in " ".join(W.__doc__.split())


def test_svd_solution_matches_scipy_align_vectors(problems):
    for p in problems:
        # scipy minimizes sum |a_i - R b_i|^2, the same loss with a = v_world, b = v_body
        rot, _ = Rotation.align_vectors(np.asarray(p.v_world), np.asarray(p.v_body))
        x, y, z, w = rot.as_quat()
        assert W.angle_error(W.solve_svd(p), jnp.array([w, x, y, z])) < 1e-12


def test_svd_solution_is_a_minimizer(problems, rng):
    for p in problems:
        q_svd = W.solve_svd(p)
        best = float(W.wahba_loss(q_svd, p))
        for scale in (1e-5, 1e-3, 1e-1, 1.0, 3.0):
            phis = rng.normal(size=(50, 3)) * scale
            losses = jax.vmap(lambda phi: W.wahba_loss(Q.multiplicative_update(q_svd, phi), p))(jnp.asarray(phis))
            assert np.all(np.asarray(losses) >= best - 1e-13), scale
        # first-order condition in the tangent space
        grad = Q.jacobian_correction(jax.grad(W.wahba_loss)(q_svd, p), q_svd)
        assert np.max(np.abs(grad)) < 1e-13


def test_angle_error_resolves_tiny_angles():
    # references whose product with dq is exact in floating point: the error is the function's
    # own, and relative (an acos of the scalar part would give 0 below about 1e-8)
    for q in (jnp.array([1.0, 0.0, 0.0, 0.0]), jnp.array([0.0, 1.0, 0.0, 0.0]), jnp.array([0.0, 0.0, 0.0, -1.0])):
        for angle in (1e-15, 1e-12, 1e-6, 0.5, 3.0):
            dq = jnp.array([math.cos(angle / 2), math.sin(angle / 2), 0.0, 0.0])
            assert abs(float(W.angle_error(Q.multiply(q, dq), q)) - angle) <= 1e-15 * angle
    # a generic reference: rounding the product to O(1) numbers costs ~1e-16 absolute
    q = jnp.array([0.3, -0.5, 0.1, 0.8])
    q = q / jnp.linalg.norm(q)
    for angle in (1e-6, 0.5, 3.0):
        dq = jnp.array([math.cos(angle / 2), math.sin(angle / 2), 0.0, 0.0])
        assert abs(float(W.angle_error(Q.multiply(q, dq), q)) - angle) <= 1e-15 + 1e-13 * angle
    assert W.angle_error(-q, q) == 0.0  # double cover


def test_multiplicative_gauss_newton_reaches_machine_precision(result):
    e = result.multiplicative
    np.testing.assert_allclose(e[:, 0], math.radians(10.0), rtol=1e-12)
    assert np.median(e[:, -1]) < 1e-10
    assert np.max(e[:, -1]) < 1e-13
    # monotone decrease down to the floor
    above = e[:, :-1] > FLOOR
    assert np.all(e[:, 1:][above] < e[:, :-1][above])


def test_multiplicative_gauss_newton_converges_at_the_predicted_linear_rate(problems):
    """Gauss-Newton with a nonzero residual at the solution is linear, with rate
    rho(I - (J^T J)^-1 H) (H the exact Hessian); the observed error ratios converge to it."""
    solve = jax.jit(W.multiplicative_gauss_newton, static_argnums=1)
    for p in problems:
        q_svd = W.solve_svd(p)
        iterates = solve(p, 12)
        e = np.asarray(jax.vmap(W.angle_error, in_axes=(0, None))(iterates, q_svd))
        res = lambda q: W.wahba_residual(q, p)  # noqa: E731
        J = Q.jacobian_correction(jax.jacfwd(res)(q_svd), q_svd)
        loss = lambda q: 0.5 * W.wahba_loss(q, p)  # noqa: E731
        H = Q.hessian_correction(jax.hessian(loss)(q_svd), jax.grad(loss)(q_svd), q_svd)
        rho = np.max(np.abs(np.linalg.eigvals(np.eye(3) - np.linalg.solve(J.T @ J, H))))
        assert 1e-3 < rho < 0.2  # linear, fast: the noise is small
        ratios = e[1:] / e[:-1]
        asymptotic = ratios[(e[:-1] < 1e-5) & (e[1:] > FLOOR)]
        assert len(asymptotic) >= 2
        np.testing.assert_allclose(asymptotic[-1], rho, rtol=0.05)
        assert np.all(ratios[e[1:] > FLOOR] < 1.5 * rho)


def test_multiplicative_newton_is_quadratic(result):
    e = result.newton
    ok = (e[:, :-1] > FLOOR) & (e[:, 1:] > FLOOR)
    constant = e[:, 1:][ok] / e[:, :-1][ok] ** 2
    assert len(constant) >= TRIALS  # at least one step per trial above the floor
    assert np.max(constant) < 1.0  # e_{k+1} <= C e_k^2
    # while Gauss-Newton's e_{k+1} / e_k^2 grows without bound: it is not quadratic
    g = result.multiplicative
    ok = (g[:, :-1] > FLOOR) & (g[:, 1:] > FLOOR)
    assert np.max(g[:, 1:][ok] / g[:, :-1][ok] ** 2) > 1e3
    assert np.median(e[:, 3]) < 1e-13


def test_projected_gauss_newton_stalls(result):
    p, m = result.projected, result.multiplicative
    assert np.median(p[:, -1]) > 1e-5
    assert np.median(p[:, -1]) > 1e8 * np.median(m[:, -1])
    # it is a true stall (a fixed point), not slow convergence
    np.testing.assert_allclose(p[:, -1], p[:, -2], rtol=1e-6)
    assert np.min(p[:, -1]) > 1e-7


def test_projected_with_homogeneous_rotation_does_not_stall(result):
    """With eq. 9's A(q) (homogeneous in q) the projected fixed point is the minimizer."""
    assert np.median(result.projected_homogeneous[:, -1]) < 1e-10


def test_stall_point_is_a_fixed_point_but_not_stationary(problems):
    p = problems[0]
    iterates = W.projected_gauss_newton(p, 15)
    q_stall = iterates[-1]
    np.testing.assert_allclose(iterates[-2], q_stall, atol=1e-14)
    grad = Q.jacobian_correction(jax.grad(W.wahba_loss)(q_stall, p), q_stall)
    assert np.max(np.abs(grad)) > 1e-6


def test_solve_trials_compiles_once():
    keys_a = jax.random.split(jax.random.PRNGKey(1), 2)
    keys_b = jax.random.split(jax.random.PRNGKey(2), 2)
    before = W.solve_trials._cache_size()
    a = W.solve_trials(keys_a, iterations=3, n_vectors=6, noise_std=0.05, init_offset=0.1)
    after_first = W.solve_trials._cache_size()
    b = W.solve_trials(keys_b, iterations=3, n_vectors=6, noise_std=0.02, init_offset=0.2)
    assert after_first == before + 1
    assert W.solve_trials._cache_size() == after_first  # new keys and noise: no retrace
    assert not np.allclose(a.multiplicative, b.multiplicative)


def test_vmap_equals_loop():
    keys = jax.random.split(jax.random.PRNGKey(3), 3)
    kwargs = dict(iterations=3, n_vectors=6, noise_std=0.05, init_offset=0.1)
    batched = W.solve_trials(keys, **kwargs)
    one = jax.jit(W.solve_trial, static_argnames=("iterations", "n_vectors"))
    for i in range(3):
        single = one(keys[i], **kwargs)
        for name in W.WahbaErrors._fields:
            np.testing.assert_allclose(getattr(batched, name)[i], getattr(single, name), rtol=1e-10, atol=1e-15)


def test_convergence_order_estimates():
    e = 0.1 ** (2.0 ** np.arange(5))  # 1e-1, 1e-2, 1e-4, 1e-8, 1e-16
    assert abs(W.convergence_order(e[None])[0] - 2.0) < 1e-12
    lin = 0.1 * 0.03 ** np.arange(8)
    assert abs(W.convergence_order(lin[None])[0] - 1.0) < 1e-12
    stalled = np.array([0.1, 1e-2, 5e-3, 5e-3, 5e-3])
    assert np.isnan(W.convergence_order(stalled[None])[0])


def test_outputs_written(result, tmp_path):
    summary = W.write_wahba_data(result, tmp_path / "w.npz", tmp_path / "w.json")
    data = np.load(tmp_path / "w.npz")
    np.testing.assert_array_equal(data["multiplicative"], result.multiplicative)
    assert data["projected"].shape == (TRIALS, ITERATIONS + 1)
    loaded = json.loads((tmp_path / "w.json").read_text())
    assert loaded == json.loads(json.dumps(summary))
    m = loaded["methods"]
    assert abs(m["multiplicative"]["median_order_estimate"] - 1.0) < 0.2
    assert m["newton"]["median_order_estimate"] > 1.8
    assert m["projected"]["median_order_estimate"] is None and m["projected"]["median_order_note"] == "stalled"
    assert m["newton"]["median_order_note"] is None
    W.plot_wahba(result, tmp_path / "w.png")
    assert (tmp_path / "w.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_main_wahba_writes_the_three_files(tmp_path, capsys):
    W.main_wahba(tmp_path, trials=2, iterations=3)
    for name in ("wahba.npz", "wahba.json", "wahba.png"):
        assert (tmp_path / name).stat().st_size > 0
    assert "multiplicative" in capsys.readouterr().out


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"trials": 0}, "trials must be an integer >= 1, got 0"),
        ({"iterations": 2.5}, "iterations must be an integer >= 1, got 2.5"),
        ({"n_vectors": 1}, "n_vectors must be an integer >= 2, got 1"),
        ({"noise_std_deg": float("nan")}, "noise_std_deg must be a finite number >= 0"),
        ({"init_offset_deg": -10.0}, "init_offset_deg must be a finite number >= 0"),
    ],
)
def test_bad_arguments_are_rejected(kwargs, match):
    with pytest.raises(ValueError, match=match):
        W.run_wahba(**kwargs)


def test_one_vector_is_not_a_wahba_problem():
    with pytest.raises(ValueError, match="n_vectors must be an integer >= 2"):
        W.generate_problem(jax.random.PRNGKey(0), n_vectors=1)


def test_a_run_too_short_for_an_order_does_not_say_stalled(tmp_path, capsys):
    """One iteration gives two errors per trial, too few for an order estimate; the summary
    said every method had stalled."""
    summary = W.main_wahba(tmp_path, trials=1, iterations=1)
    out = capsys.readouterr().out
    assert "stalled" not in out and out.count("order n/a (fewer than three errors above 1e-13)") == len(summary["methods"])
    assert {m["median_order_note"] for m in summary["methods"].values()} == {"fewer than three errors above 1e-13"}
