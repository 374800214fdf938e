"""Benchmarks of "Planning with Attitude" (`jtraj.attitude`): the two formulations' contract,
the problem definitions, short-horizon solves of every benchmark in both formulations (N = 21
knots), including an active keep-out cone in the satellite slew, and that the package stands
without MuJoCo."""

import functools
import json
import math
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jtraj.attitude as B
from jtraj import quaternion as Q
from jtraj.attitude import models as M
from jtraj.attitude.cli import main_attitude
from jtraj.lie import accumulated_rotation
from jtraj.result import Result

SHORT = {"quadflip": {}, "barrelroll": {}, "satellite": {"tf": 25.0}}  # tf: 1.25 s steps keep RK4 stable
N_SHORT = 21


@functools.cache
def solve(name, variant, ipopt_options=(), **kwargs):
    kw = {**SHORT[name], **kwargs}
    return B.solve_benchmark(name, variant, n_knots=N_SHORT, progress=False, options=dict(ipopt_options), **kw)


def random_quaternion(rng):
    q = rng.normal(size=4)
    return jnp.asarray(q / np.linalg.norm(q))


# ---------------------------------------------------------------------------------------- contract


def test_formulation_dimensions():
    naive, att = B.FORMULATIONS["naive"], B.FORMULATIONS["attitude"]
    assert (naive.defect_dim(13), att.defect_dim(13), att.defect_dim(23)) == (13, 12, 22)
    assert (naive.target_dim, att.target_dim) == (4, 3)
    assert att.unit_norm and not naive.unit_norm


def test_attitude_defect_ignores_sign_and_scale_of_the_quaternion(rng):
    att = B.FORMULATIONS["attitude"]
    model = M.Quadrotor()
    x = jnp.asarray(M.rigid_state(r=(0.1, 0.2, 1.0), q=random_quaternion(rng), v=(1.0, 0.0, 0.5), omega=(3.0, -1.0, 2.0)))
    x_pred = M.rk4(model.dynamics, x, jnp.asarray(model.hover_control()) + 0.3, 0.05)
    # RK4 leaves |q| slightly off 1; the error-state defect only sees the rotation
    scales = (-1.0, 2.5, -0.4, 1.0 / float(jnp.linalg.norm(x_pred[3:7])))
    for x_next in (x_pred.at[3:7].multiply(c) for c in scales):
        np.testing.assert_allclose(att.defect(x_next, x_pred), 0.0, atol=1e-15)
    # and sees a rotation, whatever the sign and scale of the quaternion that carries it
    phi = jnp.array([0.02, -0.01, 0.03])
    turned = x_pred.at[3:7].set(Q.multiplicative_update(x_pred[3:7] / jnp.linalg.norm(x_pred[3:7]), phi))
    for c in scales[:3]:
        d = np.asarray(att.defect(turned.at[3:7].multiply(c), x_pred))
        np.testing.assert_allclose(np.linalg.norm(d), np.linalg.norm(phi), rtol=0.05)
    # while the naive defect sees the sign flip as a distance of 2
    naive = B.FORMULATIONS["naive"]
    assert float(jnp.linalg.norm(naive.defect(x_pred.at[3:7].multiply(-1.0), x_pred))) > 1.9


def test_attitude_target_and_cost_use_the_rotation_only(rng):
    att, naive = B.FORMULATIONS["attitude"], B.FORMULATIONS["naive"]
    q_ref = random_quaternion(rng)
    np.testing.assert_allclose(att.attitude_error(-q_ref, q_ref), 0.0, atol=1e-15)
    np.testing.assert_allclose(att.attitude_error(Q.multiplicative_update(q_ref, jnp.array([0.1, -0.2, 0.3])), q_ref), [0.1, -0.2, 0.3], atol=1e-14)
    assert float(jnp.max(jnp.abs(naive.attitude_error(-q_ref, q_ref)))) > 0.1
    # the geodesic cost differentiated by JAX and corrected by G(q) is eq. 41 (sign-corrected)
    q = random_quaternion(rng)
    g = jax.grad(att.attitude_cost)(q, q_ref) @ Q.attitude_jacobian(q)
    np.testing.assert_allclose(g, Q.geodesic_cost_gradient(q, q_ref), atol=1e-14)
    # same weights on the sphere: 1/2 |q - q_ref|^2 = 1 - q_ref . q for unit q (near q_ref)
    q_near = Q.multiplicative_update(q_ref, jnp.array([0.1, 0.2, -0.1]))
    np.testing.assert_allclose(naive.attitude_cost(q_near, q_ref), att.attitude_cost(q_near, q_ref), atol=1e-15)


# ---------------------------------------------------------------------------------------- definitions


def test_quadrotor_flip_definition():
    b = B.quadrotor_flip()
    assert (b.n_knots, b.tf, b.h) == (101, 5.0, 0.05)
    knots = [t.knot for t in b.targets]
    assert knots == [19, 44, 50, 54, 74, 100]  # the paper code's 1-based knots 20, 45, 51, 55, 75
    rolls = [math.degrees(2 * math.atan2(t.q[1], t.q[0])) % 360 for t in b.targets]
    np.testing.assert_allclose(rolls[1:5], [90, 180, 270, 0], atol=1e-9)
    np.testing.assert_allclose(b.targets[-1].q, [-1, 0, 0, 0], atol=1e-15)  # 360 degrees, continuous branch
    np.testing.assert_allclose(b.x_lower[0, :3], [0, -1, 1])
    np.testing.assert_allclose(b.x_lower[-1, :3], [0, 1, 1])  # 2 m along +y
    assert np.all(b.x_lower[:, 2] >= 0.0)  # floor
    # warm start turns a full revolution about x
    turns = np.asarray(accumulated_rotation(b.x_init[:, 3:7]))[-1] / (2 * np.pi)
    np.testing.assert_allclose(turns, [1, 0, 0], atol=1e-12)
    # shorter horizons keep the waypoint times
    short = B.quadrotor_flip(N_SHORT)
    np.testing.assert_allclose([short.t[t.knot] for t in short.targets], [b.t[t.knot] for t in b.targets], atol=0.13)


def test_barrel_roll_definition():
    b = B.barrel_roll()
    plane = b.model
    assert (b.n_knots, b.tf) == (101, 1.25)
    x0 = b.x_lower[0]
    np.testing.assert_allclose(x0[:3], [-3, 0, 1.5])
    np.testing.assert_allclose(x0[7:10], [5, 0, 0])
    np.testing.assert_allclose(plane.dynamics(jnp.asarray(x0), jnp.asarray(b.u_init[0]))[7:], 0.0, atol=1e-10)  # trimmed
    q_goal = jnp.asarray(b.targets[0].q)
    A = np.asarray(Q.rotation_matrix(q_goal))
    assert A[2, 2] < -0.9  # body z points down: upside down
    np.testing.assert_allclose(A[:, 0], np.asarray(Q.rotation_matrix(jnp.asarray(x0[3:7])))[:, 0], atol=1e-14)  # same nose direction
    # the guess rolls into the goal; the pure trim rollout sits exactly pi from it (Cayley singular)
    np.testing.assert_allclose(jnp.abs(jnp.asarray(b.x_init[-1, 3:7]) @ q_goal), 1.0, atol=1e-14)
    trim_only = B.barrel_roll(roll_guess=False)
    assert abs(float(jnp.asarray(trim_only.x_init[-1, 3:7]) @ q_goal)) < 1e-12


def test_barrel_roll_check_wants_a_half_roll_either_way():
    """The inverted goal alone was the check: a path that rolls 540 degrees met it and passed.
    The guess's roll about the body x axis (one axis: exactly 180, -180 and 540 degrees)."""
    b = B.barrel_roll(21)
    q_trim = b.x_lower[0, 3:7]
    for turn, ok in ((np.pi, True), (-np.pi, True), (3 * np.pi, False)):
        X = b.x_init.copy()
        rolls = np.stack([M.quat_about_axis((1.0, 0.0, 0.0), turn * s) for s in np.linspace(0.0, 1.0, 21)])
        X[:, 3:7] = rolls @ np.asarray(Q.L(jnp.asarray(q_trim))).T
        metrics, passed = b.metrics(X, np.zeros((20, 4)))
        assert max(metrics["target_errors_deg"].values()) < 1e-6  # the goal is met each time
        assert metrics["roll_deg"] == pytest.approx(np.degrees(turn), abs=1e-6) and passed is ok


def test_satellite_definition_and_keep_out_geometry():
    b = B.satellite_slew()
    assert (b.n_knots, b.tf, b.h) == (401, 100.0, 0.25)
    q0 = jnp.asarray(b.x_lower[0, 3:7])
    np.testing.assert_allclose(2 * math.acos(float(q0[0])), math.radians(150), atol=1e-14)
    np.testing.assert_allclose(q0[1:] / jnp.linalg.norm(q0[1:]), np.array([1, 2, 3]) / math.sqrt(14), atol=1e-14)
    assert np.all(b.u_upper[:-1] == 0.5) and np.all(b.u_lower[:-1] == -0.5)
    ko = b.keep_out
    np.testing.assert_allclose(np.linalg.norm(ko.camera_body), 1.0, atol=1e-15)
    cam, sun = jnp.asarray(ko.camera_body), jnp.asarray(ko.sun_world)
    # start and goal are outside the 40 degree cone, the constant-axis slew between them is not
    path = np.stack([np.asarray(Q.multiply(q0, jnp.asarray(M.quat_about_axis((1, 2, 3), -math.radians(150) * s)))) for s in np.linspace(0, 1, 101)])
    angles = np.degrees(jax.vmap(lambda q: M.FlexibleSpacecraft.sun_angle(q, cam, sun))(jnp.asarray(path)))
    assert angles[0] > 40 and angles[-1] > 40 and angles.min() < 36


@pytest.mark.parametrize("n_knots", [16, 20, 24])
def test_quadrotor_flip_refuses_waypoints_on_one_knot(n_knots):
    """Regression: at these counts the scaled knots of two waypoints (roll 180 and 270 degrees)
    coincided, two contradictory hard attitude targets on one knot, an infeasible problem."""
    with pytest.raises(ValueError, match=f"benchmark quadflip: n_knots={n_knots} puts two attitude waypoints on one knot"):
        B.quadrotor_flip(n_knots)
    for ok in (n_knots - 1, n_knots + 1):
        knots = [t.knot for t in B.quadrotor_flip(ok).targets]
        assert len(set(knots)) == len(knots)


def test_bad_requests_are_reported():
    with pytest.raises(ValueError, match=r"unknown benchmark 'loop'.*barrelroll"):
        B.solve_benchmark("loop", "attitude")
    with pytest.raises(ValueError, match=r"unknown variant 'euler'.*attitude"):
        B.solve_benchmark("quadflip", "euler")
    with pytest.raises(ValueError, match="n_knots"):
        B.quadrotor_flip(n_knots=3)
    for tf in (-1.0, 0.0, float("nan")):
        with pytest.raises(ValueError, match="benchmark quadflip: tf must be a finite number > 0"):
            B.quadrotor_flip(tf=tf)
    with pytest.raises(ValueError, match="benchmark barrelroll: speed must be a finite number > 0"):
        B.barrel_roll(speed=float("inf"))
    with pytest.raises(ValueError, match="too long"):
        B.satellite_slew(n_knots=21)  # 5 s steps cannot resolve the 0.3 Hz mode
    # regression: a negative angle became the cone of its absolute value, 200 a cone about -sun
    for angle in (-10.0, 180.0, 200.0, float("nan"), "40"):
        with pytest.raises(ValueError, match=r"benchmark satellite: keep_out_deg must be None or a number of degrees in \[0, 180\)"):
            B.satellite_slew(keep_out_deg=angle)
    assert B.satellite_slew(keep_out_deg=0.0).keep_out.angle_deg == 0.0


def test_a_built_benchmark_refuses_factory_arguments():
    """Regression: solve_benchmark(a built Benchmark, n_knots=21, tf=...) solved the benchmark as
    built (101 knots), silently ignoring the arguments its docstring sends to the factory."""
    built = B.quadrotor_flip()
    assert B.benchmarks.get(built) is built
    with pytest.raises(ValueError, match=r"benchmark quadflip: \{'n_knots': 21, 'tf': 4.0\} cannot change a built benchmark"):
        B.benchmarks.get(built, 21, tf=4.0)
    with pytest.raises(ValueError, match=r"benchmark quadflip: \{'n_knots': 21\} cannot change a built benchmark"):
        B.solve_benchmark(built, n_knots=21, progress=False)
    with pytest.raises(ValueError, match=r"benchmark quadflip: \{'tf': 4.0\} cannot change a built benchmark"):
        B.solve_benchmark(built, tf=4.0, progress=False)


@pytest.mark.parametrize(
    "argv, message",
    [
        (["quadflip", "--knots", "5"], "--knots: 5: benchmark quadflip: n_knots must be an integer >= 11"),
        (["quadflip", "--knots", "20"], "--knots: 20: benchmark quadflip: n_knots=20 puts two attitude waypoints on one knot"),
        (["all", "--knots", "30"], "--knots: 30: satellite: step 3.45 s is too long"),
    ],
)
def test_cli_refuses_a_knot_count_in_one_line(argv, message, tmp_path, capsys):
    """Regression: a knot count the benchmark refuses ended ``jtraj attitude`` in a traceback
    (for ``all``, after solving the benchmarks before the satellite); it is a bad input."""
    from jtraj.cli import EXIT_BAD_INPUT
    from jtraj.cli import main as jtraj_main

    assert jtraj_main(["attitude", *argv, "--out", str(tmp_path)]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert err.startswith(f"jtraj attitude: {message}") and err.count("\n") == 1, err
    assert not any(tmp_path.iterdir())  # nothing was solved or written


def test_cli_main_blames_knots_only_when_given(tmp_path):
    """Without --knots, an error of the benchmark is not reported as '--knots: None: ...'."""
    from jtraj.attitude.cli import main as attitude_main
    from jtraj.cli import InputError

    with pytest.raises(ValueError, match="unknown benchmark 'loop'") as err:
        attitude_main("loop", "attitude", tmp_path)
    assert not isinstance(err.value, InputError), err.value


# ---------------------------------------------------------------------------------------- solves


@pytest.mark.slow
@pytest.mark.parametrize("variant", ["naive", "attitude"])
def test_quadrotor_flip_short(variant):
    r = solve("quadflip", variant)
    assert r.success, r.summary()
    assert r.constraint_violation < 1e-5
    assert abs(r.metrics["roll_turns"] - 1.0) < 0.05  # a real flip
    assert max(r.metrics["target_errors_deg"].values()) < 1e-3
    assert r.metrics["min_altitude_m"] > -1e-6
    np.testing.assert_allclose(r.trajectory.X[-1, :3], [0, 1, 1], atol=1e-9)
    if variant == "attitude":
        assert r.metrics["max_quaternion_norm_error"] < 1e-8


@pytest.mark.slow
def test_naive_quaternions_drift_off_the_sphere():
    """The naive defect carries RK4's norm error; the attitude formulation's unit-norm rows
    remove it."""
    naive, att = solve("quadflip", "naive"), solve("quadflip", "attitude")
    assert naive.metrics["max_quaternion_norm_error"] > 1e3 * att.metrics["max_quaternion_norm_error"]


@pytest.mark.slow
def test_barrel_roll_short():
    r = solve("barrelroll", "attitude")
    assert r.success, r.summary()
    A = np.asarray(Q.rotation_matrix(jnp.asarray(r.trajectory.X[-1, 3:7])))
    assert A[2, 2] < -0.9  # ends upside down
    assert abs(r.metrics["roll_deg"]) > 90
    np.testing.assert_allclose(r.trajectory.X[-1, :3], [3, 0, 1.5], atol=1e-9)
    assert np.all(r.trajectory.U[:, 0] >= -1e-8) and np.all(np.abs(r.trajectory.U[:, 1:]) <= math.radians(60) + 1e-8)


@pytest.mark.slow
def test_barrel_roll_naive_is_much_slower():
    """The naive barrel roll converges only after hundreds of iterations (365 at N = 21, none
    within 1000 at N = 101, measured when this test was written). The attitude formulation must
    converge; the naive one, given three times the attitude formulation's iterations, must
    not (a cap that both hit would prove nothing, so the budget follows the measured count)."""
    att = solve("barrelroll", "attitude")
    assert att.converged and att.success, att.summary()
    budget = 3 * att.iterations
    naive = solve("barrelroll", "naive", ipopt_options=(("max_iter", budget),))
    assert not naive.converged, f"the naive barrel roll converged within {budget} iterations: {naive.summary()}"


@pytest.mark.slow
def test_naive_constraint_jacobian_is_rank_deficient():
    """Why the naive formulation struggles: its 4-row attitude targets plus the additive
    defects constrain the quaternion norm, which the inputs barely move (only through RK4's
    O(h^5) norm error), so the constraint Jacobian loses rank (LICQ fails). The attitude
    formulation's Jacobian at the same point is well conditioned."""
    r = solve("quadflip", "attitude")
    bench = B.quadrotor_flip(N_SHORT)
    z = jnp.asarray(np.concatenate([r.trajectory.X, np.vstack([r.trajectory.U, bench.u_lower[-1:]])], axis=1).reshape(-1))
    sigma_min = {}
    for variant in ("naive", "attitude"):
        nlp = B.build_nlp(bench, B.FORMULATIONS[variant])
        J = nlp.dense_jacobian(z)[:, nlp.x_lower < nlp.x_upper]  # fixed variables are not variables
        sigma_min[variant] = np.linalg.svd(J, compute_uv=False)[-1]
    assert sigma_min["naive"] < 1e-8
    assert sigma_min["attitude"] > 1e-3


@pytest.mark.slow
@pytest.mark.parametrize("variant", ["naive", "attitude"])
def test_satellite_keep_out_is_active_and_satisfied(variant):
    r = solve("satellite", variant)
    assert r.success, r.summary()
    margin = r.metrics["min_sun_angle_deg"] - 40.0
    assert -1e-3 < margin < 1e-2  # satisfied (to the 1e-5 tolerance on the cosine) and touching
    assert r.metrics["max_abs_torque"] <= 0.5 + 1e-8
    assert r.metrics["target_errors_deg"]["goal@20"] < 1e-6


@pytest.mark.slow
def test_satellite_without_keep_out_crosses_the_cone():
    free = solve("satellite", "attitude", keep_out_deg=None)
    assert free.success, free.summary()
    assert free.metrics["min_sun_angle_deg"] < 39.0
    assert "keep_out" not in free.violation_by_group
    # the constraint costs something
    assert solve("satellite", "attitude").cost > free.cost


@pytest.mark.slow
def test_result_files_and_figure(tmp_path):
    r = solve("satellite", "attitude")
    folder = r.save(tmp_path / "satellite")
    data = json.loads((folder / "result.json").read_text())
    assert data["status"] == "solved" and data["iterations"] == r.iterations and data["solver_status"] == "solved"
    assert data["constraint_violation"] == r.constraint_violation
    with np.load(folder / "trajectory.npz") as z:
        np.testing.assert_array_equal(z["X"], r.trajectory.X)
        assert z["U"].shape == (N_SHORT - 1, 4) and z["t"][-1] == 25.0
    back = Result.load(folder)
    np.testing.assert_array_equal(back.trajectory.U, r.trajectory.U)
    assert back.metrics == json.loads(json.dumps(r.metrics))
    for name in ("quadflip", "barrelroll", "satellite"):
        # with a path, the path (as Result.plot and jtraj.plots.plot_solution); without, the figure
        assert B.plot_benchmark(solve(name, "attitude"), tmp_path / f"{name}.png") == tmp_path / f"{name}.png"
        assert (tmp_path / f"{name}.png").read_bytes()[:4] == b"\x89PNG"
        assert B.plot_benchmark(solve(name, "attitude")).axes


@pytest.mark.slow
def test_main_attitude_prints_and_saves(tmp_path, capsys):
    r = main_attitude("quadflip", "attitude", tmp_path, n_knots=N_SHORT)
    out = capsys.readouterr().out
    assert "iterations" in out and "violation" in out and "inf_pr" in out
    for name in ("result.json", "trajectory.npz", "plot.png"):
        assert (tmp_path / "quadflip_attitude" / name).stat().st_size > 0
    # deterministic: the same problem gives the same iterations as the cached solve
    assert r.iterations == solve("quadflip", "attitude").iterations
    np.testing.assert_allclose(r.trajectory.X, solve("quadflip", "attitude").trajectory.X, atol=1e-12)


def test_importing_attitude_loads_no_mujoco_robot_or_transcription():
    code = "import sys, jtraj.attitude; print(sorted(m for m in ('mujoco', 'mujoco.mjx', 'jtraj.robot', 'jtraj.dynamics', 'jtraj.transcription') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_every_benchmark_has_its_own_check_and_figure():
    assert set(B.BENCHMARKS) == set(SHORT) == {"quadflip", "barrelroll", "satellite"}  # the paper's three
    for name, cls in B.BENCHMARKS.items():
        assert cls.name == name
        for method in ("build", "task_metrics", "plot_curve"):
            assert method in vars(cls), (name, method)  # its own, not dispatched on its name
