"""Rigid-body models of "Planning with Attitude" (`jtraj.attitude.models`): RK4 order and the
norm drift it documents, conservation laws, equilibria, the flat-plate coefficients,
error-state round trips, autodiff against finite differences and vmap against a loop."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import central_difference, random_unit_vectors

from jtraj import quaternion as Q
from jtraj.attitude import models as M

MODELS = {
    "rigid_body": M.RigidBody(),
    "quadrotor": M.Quadrotor(),
    "airplane": M.Airplane(),
    "spacecraft": M.FlexibleSpacecraft(),
}


def random_state(model, rng):
    q = random_unit_vectors(rng, 1, 4)[0]
    r, v, w = rng.normal(size=3), rng.normal(size=3) + np.r_[5.0, 0, 0], rng.normal(size=3)
    x = np.concatenate([r, q, v, w])
    if isinstance(model, M.FlexibleSpacecraft):
        w = 0.3 * rng.normal(size=3)
        x = np.concatenate([r, q, v, w, 0.1 * rng.normal(size=6), rng.normal(size=4)])
    assert x.shape == (model.nx,)
    return jnp.asarray(x)


def random_control(model, rng):
    scale = {"RigidBody": 0.5, "Quadrotor": 1.2, "Airplane": 0.2, "FlexibleSpacecraft": 0.3}
    return jnp.asarray(rng.normal(size=model.nu) * scale[type(model).__name__])


def rollout(f, x, u, h, steps):
    step = jax.jit(lambda x: M.rk4(f, x, u, h))
    xs = [x]
    for _ in range(steps):
        xs.append(step(xs[-1]))
    return jnp.stack(xs)


def max_drift(values):
    values = np.asarray(values)
    return np.max(np.abs(values - values[0]))


@pytest.mark.parametrize("name", list(MODELS))
def test_dimensions(name, rng):
    model = MODELS[name]
    x, u = random_state(model, rng), random_control(model, rng)
    assert u.shape == (model.nu,)
    assert model.dynamics(x, u).shape == (model.nx,)
    # one input short or too many, a state short: JAX clamps an index past the end (a rigid
    # body given 4 inputs took the fourth as all three torques), now refused by name
    kind = type(model).__name__
    for bad_u in (u[:-1], jnp.concatenate([u, u[:1]])):
        with pytest.raises(ValueError, match=rf"^{kind} input u must have shape \({model.nu},\), got \({bad_u.shape[0]},\)$"):
            model.dynamics(x, bad_u)
    with pytest.raises(ValueError, match=rf"^{kind} state x must have shape \({model.nx},\), got \({model.nx - 1},\)$"):
        model.dynamics(x[:-1], u)


def test_rk4_quaternion_norm_error_is_fifth_order(rng):
    """|q| is invariant in continuous time; one RK4 step breaks it by O(h^5)."""
    body = M.RigidBody(inertia=(1.0, 2.0, 2.5))
    x = random_state(body, rng).at[10:13].set(jnp.array([1.0, 2.0, -1.5]))
    u = jnp.zeros(6)
    errors = []
    for h in (0.1, 0.05, 0.025):
        x1 = M.rk4(body.dynamics, x, u, h)
        errors.append(abs(float(jnp.linalg.norm(x1[3:7])) - 1.0))
    slopes = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(slopes > 4.5), (errors, slopes)
    xs = rollout(body.dynamics, x, u, 0.01, 100)
    assert max_drift(np.linalg.norm(xs[:, 3:7], axis=1)) < 1e-9


def test_rk4_norm_shrink_for_constant_rate_matches_docstring():
    """rk4's docstring: for constant omega |q| shrinks by about (|omega| h / 2)^6 / 144 per step."""
    body = M.RigidBody(inertia=(2.0, 2.0, 2.0))  # spherical: omega stays constant
    omega = jnp.array([0.5, -1.0, 2.0])
    x = jnp.concatenate([jnp.zeros(3), jnp.array([1.0, 0, 0, 0]), jnp.zeros(3), omega])
    for h in (0.2, 0.1):
        shrink = 1.0 - float(jnp.linalg.norm(M.rk4(body.dynamics, x, jnp.zeros(6), h)[3:7]))
        theta = float(jnp.linalg.norm(omega)) * h / 2
        np.testing.assert_allclose(shrink, theta**6 / 144, rtol=0.05)


def test_torque_free_rigid_body_conserves_energy_and_world_momentum(rng):
    body = M.RigidBody(inertia=(1.0, 2.0, 3.0))
    x = random_state(body, rng).at[10:13].set(jnp.array([0.3, 2.0, 0.4]))  # near the unstable axis
    xs = rollout(body.dynamics, x, jnp.zeros(6), 0.005, 400)
    energy = jax.vmap(body.energy)(xs)
    assert max_drift(energy) / energy[0] < 1e-8
    assert max_drift(jax.vmap(body.angular_momentum_world)(xs)) < 1e-8
    assert max_drift(xs[:, 10:13]) > 0.1  # the body rates do move: the check is not vacuous


@pytest.mark.parametrize("yaw", [0.0, 1.0, -2.5])
def test_quadrotor_hover_is_an_equilibrium(yaw):
    quad = M.Quadrotor()
    q = jnp.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])
    x = jnp.concatenate([jnp.array([0.3, -1.0, 1.0]), q, jnp.zeros(6)])
    u = jnp.asarray(quad.hover_control())
    np.testing.assert_allclose(u, 0.5 * 9.81 / 4, rtol=1e-15)
    np.testing.assert_allclose(quad.dynamics(x, u), 0.0, atol=1e-14)


def test_quadrotor_wrench_takes_one_command_per_rotor():
    with pytest.raises(ValueError, match=r"^Quadrotor input u must have shape \(4,\), got \(3,\)$"):
        M.Quadrotor().wrench(jnp.array([1.0, 2.0, 3.0]))


def test_quadrotor_motor_torques():
    quad = M.Quadrotor()
    x = jnp.concatenate([jnp.zeros(3), jnp.array([1.0, 0, 0, 0]), jnp.zeros(6)])
    hover = jnp.asarray(quad.hover_control())
    d = 0.1
    J = np.array(quad.inertia)
    # rotor 2 sits on +y: more thrust there rolls about +x and yaws by -km d
    w_dot = quad.dynamics(x, hover.at[1].add(d))[10:13]
    np.testing.assert_allclose(w_dot, np.array([0.175 * d, 0.0, -0.0245 * d]) / J, rtol=1e-12)
    # rotor 1 sits on +x: pitches about -y, yaws by +km d
    w_dot = quad.dynamics(x, hover.at[0].add(d))[10:13]
    np.testing.assert_allclose(w_dot, np.array([0.0, -0.175 * d, 0.0245 * d]) / J, rtol=1e-12)
    # thrust acts along body z: rolled 90 degrees about x, it pushes along world -y
    q_roll = jnp.array([math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0])
    v_dot = quad.dynamics(x.at[3:7].set(q_roll), hover)[7:10]
    np.testing.assert_allclose(v_dot, [0.0, -9.81, -9.81], atol=1e-14)


def test_quat_about_axis():
    np.testing.assert_allclose(M.quat_about_axis((0.0, 0.0, 2.0), math.pi / 2), [math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)], atol=1e-16)
    np.testing.assert_allclose(M.quat_about_axis((1.0, 0.0, 0.0), 2 * math.pi), [-1.0, 0.0, 0.0, 0.0], atol=1e-15)  # continuous branch
    # regression: a zero axis gave NaNs, a 2-vector a 3-element "quaternion", both silently
    for axis in ((0.0, 0.0, 0.0), (1.0, 0.0), (1.0, np.nan, 0.0)):
        with pytest.raises(ValueError, match="quat_about_axis: axis must be a finite nonzero 3-vector"):
            M.quat_about_axis(axis, 1.0)


def test_flat_plate_coefficients():
    """One plate, no fuselage: C_L = 2 sin a cos a and C_D = 2 sin^2 a at every angle."""
    S, rho, V = 0.3, 1.225, 4.0
    plate = M.Surface(S, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, -1.0, 0.0), 2, 1.0)
    plane = M.Airplane(surfaces=(plate,), fuselage_drag_area=0.0)
    identity = jnp.array([1.0, 0.0, 0.0, 0.0])
    qS = 0.5 * rho * V**2 * S
    for alpha in np.radians([-30.0, 0.0, 5.0, 20.0, 60.0, 90.0]):
        v = V * jnp.array([math.cos(alpha), 0.0, -math.sin(alpha)])  # air hits the plate from below
        F, tau = plane.aero_wrench(identity, v, jnp.zeros(3), jnp.zeros(4))
        lift = F @ jnp.array([math.sin(alpha), 0.0, math.cos(alpha)])
        drag = -F @ (v / V)
        np.testing.assert_allclose(lift / qS, 2 * math.sin(alpha) * math.cos(alpha), atol=1e-9)
        np.testing.assert_allclose(drag / qS, 2 * math.sin(alpha) ** 2, atol=1e-9)
        np.testing.assert_allclose(tau, 0.0, atol=1e-15)  # force through the centre of mass
    # a deflection rotates the plate: +delta_e gives the same force as a higher angle of attack
    F1, _ = plane.aero_wrench(identity, jnp.array([V, 0.0, 0.0]), jnp.zeros(3), jnp.array([0.0, 0.0, 0.1, 0.0]))
    v_alpha = V * jnp.array([math.cos(0.1), 0.0, -math.sin(0.1)])
    F2, _ = plane.aero_wrench(identity, v_alpha, jnp.zeros(3), jnp.zeros(4))
    np.testing.assert_allclose(jnp.linalg.norm(F1), jnp.linalg.norm(F2), rtol=1e-12)
    assert F1[2] > 0


@pytest.fixture(scope="module")
def trims():
    plane = M.Airplane()
    return {speed: plane.trim(speed) for speed in (5.0, 7.0)}


@pytest.mark.parametrize("speed", [5.0, 7.0])
def test_airplane_trim_is_an_equilibrium(speed, trims):
    plane = M.Airplane()
    trim = trims[speed]
    x, u = jnp.asarray(trim.x), jnp.asarray(trim.u)
    x_dot = plane.dynamics(x, u)
    np.testing.assert_allclose(x_dot[0:3], [speed, 0.0, 0.0], atol=1e-14)
    np.testing.assert_allclose(x_dot[3:], 0.0, atol=1e-10)
    np.testing.assert_allclose(jnp.linalg.norm(x[3:7]), 1.0, atol=1e-15)
    assert 0.0 < trim.angle_of_attack < math.radians(30)
    assert 0.0 < float(u[0]) < 0.5 * plane.mass * 9.81  # thrust well below weight
    assert abs(float(u[2])) < math.radians(30)
    # an RK4 rollout from trim stays in trim (the unstable spiral mode is not excited)
    xs = rollout(plane.dynamics, x, u, 0.01, 50)
    np.testing.assert_allclose(xs[-1, 7:], x[7:], atol=1e-8)
    np.testing.assert_allclose(xs[-1, 0], 0.5 * speed, atol=1e-8)


def test_airplane_trim_angle_falls_with_speed(trims):
    assert trims[7.0].angle_of_attack < trims[5.0].angle_of_attack


def test_pyramid_wheels_are_isotropic():
    B = np.asarray(M.FlexibleSpacecraft().wheel_axes).T
    np.testing.assert_allclose(np.linalg.norm(B, axis=0), 1.0, atol=1e-15)
    np.testing.assert_allclose(B @ B.T, 4.0 / 3.0 * np.eye(3), atol=1e-15)


def _conservation_drift(craft, x, u, h, seconds):
    xs = rollout(craft.dynamics, x, u, h, int(round(seconds / h)))
    return xs, max_drift(jax.vmap(craft.energy)(xs)), max_drift(jax.vmap(craft.angular_momentum_world)(xs))


def test_spacecraft_without_input_or_damping_conserves_energy_and_momentum(rng):
    """Energy and world momentum are conserved by the flow (u = 0, zero damping), also with
    spinning wheels; RK4 breaks them only by its O(h^4) global error."""
    craft = M.FlexibleSpacecraft(modal_damping=(0.0, 0.0, 0.0))
    x = random_state(craft, rng)
    assert np.all(np.abs(x[19:23]) > 0.0)
    xs, e1, h1 = _conservation_drift(craft, x, jnp.zeros(4), 0.1, 10.0)
    _, e2, h2 = _conservation_drift(craft, x, jnp.zeros(4), 0.05, 10.0)
    assert e1 < 1e-5 and h1 < 1e-5
    assert e1 / e2 > 10 and h1 / h2 > 10  # fourth order: 16 expected
    assert max_drift(xs[:, 13:16]) > 1e-2  # the modes move


def test_spacecraft_wheel_torques_are_internal(rng):
    craft = M.FlexibleSpacecraft()  # with damping and input
    x = random_state(craft, rng)
    u = jnp.array([0.5, -0.3, 0.2, -0.5])
    xs, _, h1 = _conservation_drift(craft, x, u, 0.1, 10.0)
    _, _, h2 = _conservation_drift(craft, x, u, 0.05, 10.0)
    assert h1 < 1e-5 and h1 / h2 > 10
    np.testing.assert_allclose(xs[-1, 19:23], x[19:23] + 10.0 * u, atol=1e-11)  # h_w_dot = u
    np.testing.assert_allclose(xs[-1, 7:10], x[7:10], atol=1e-15)  # no force: v constant


def test_spacecraft_energy_rate(rng):
    """dE/dt = -omega^T A_w u - eta_dot^T C eta_dot along the flow (chain rule via jvp)."""
    craft = M.FlexibleSpacecraft(modal_damping=(0.02, 0.05, 0.01))
    x, u = random_state(craft, rng), jnp.array([0.1, -0.2, 0.3, 0.05])
    _, rate = jax.jvp(craft.energy, (x,), (craft.dynamics(x, u),))
    m = craft.matrices()
    expected = -x[10:13] @ m["A_w"] @ u - x[16:19] @ m["C"] @ x[16:19]
    np.testing.assert_allclose(rate, expected, rtol=1e-12, atol=1e-14)


def test_spacecraft_reduced_inertia_is_positive_definite():
    m = M.FlexibleSpacecraft().matrices()
    assert np.linalg.eigvalsh(np.asarray(m["J"] - m["delta"].T @ m["delta"])).min() > 0.1


def test_sun_angle():
    cam = np.array([0.360, -0.930, 0.079])
    cam = cam / np.linalg.norm(cam)
    sun = np.array([1.0, 0.0, 0.0])
    identity = jnp.array([1.0, 0.0, 0.0, 0.0])
    angle = M.FlexibleSpacecraft.sun_angle(identity, jnp.asarray(cam), jnp.asarray(sun))
    np.testing.assert_allclose(angle, math.acos(cam[0]), atol=1e-15)  # 69 degrees at the identity (the goal)
    for target_deg in (0.0, 40.0, 120.0):
        target = np.array([math.cos(math.radians(target_deg)), math.sin(math.radians(target_deg)), 0.0])
        axis = np.cross(cam, target)
        half = 0.5 * math.atan2(np.linalg.norm(axis), cam @ target)
        q = jnp.asarray(np.r_[math.cos(half), math.sin(half) * axis / np.linalg.norm(axis)])
        np.testing.assert_allclose(Q.rotate(q, jnp.asarray(cam)), target, atol=1e-14)
        angle = M.FlexibleSpacecraft.sun_angle(q, jnp.asarray(cam), jnp.asarray(sun))
        np.testing.assert_allclose(angle, math.radians(target_deg), atol=1e-7)


@pytest.mark.parametrize("name", list(MODELS))
def test_error_state_round_trip_and_jacobian(name, rng):
    model = MODELS[name]
    x_ref = random_state(model, rng)
    dx = jnp.asarray(rng.normal(size=model.nx - 1) * 0.3)
    x = M.retract_error_state(x_ref, dx)
    np.testing.assert_allclose(jnp.linalg.norm(x[3:7]), 1.0, atol=1e-15)
    np.testing.assert_allclose(M.error_state(x, x_ref), dx, atol=1e-13)
    np.testing.assert_allclose(M.error_state(x.at[3:7].multiply(-1.0), x_ref), dx, atol=1e-13)  # double cover
    # d error_state / dx at x_ref is E(x_ref)^T (eq. 25), extended by identities
    Jx = jax.jacfwd(M.error_state)(x_ref, x_ref)
    E = np.zeros((model.nx, model.nx - 1))
    E[0:3, 0:3] = np.eye(3)
    E[3:7, 3:6] = Q.attitude_jacobian(x_ref[3:7])
    E[7:, 6:] = np.eye(model.nx - 7)
    np.testing.assert_allclose(Jx, E.T, atol=1e-14)


@pytest.mark.parametrize("name", list(MODELS))
def test_rk4_jacobian_matches_central_differences(name, rng):
    model = MODELS[name]
    x, u = random_state(model, rng), random_control(model, rng)
    step = jax.jit(lambda x, u: M.rk4(model.dynamics, x, u, 0.02))
    Jx, Ju = jax.jit(jax.jacfwd(step, argnums=(0, 1)))(x, u)
    Jx_fd = central_difference(lambda x_: step(jnp.asarray(x_), u), np.asarray(x))
    Ju_fd = central_difference(lambda u_: step(x, jnp.asarray(u_)), np.asarray(u))
    np.testing.assert_allclose(Jx, Jx_fd, atol=1e-7, rtol=1e-6)
    np.testing.assert_allclose(Ju, Ju_fd, atol=1e-7, rtol=1e-6)


@pytest.mark.parametrize("name", list(MODELS))
def test_vmap_equals_loop(name, rng):
    model = MODELS[name]
    xs = jnp.stack([random_state(model, rng) for _ in range(4)])
    us = jnp.stack([random_control(model, rng) for _ in range(4)])
    batched = jax.jit(jax.vmap(lambda x, u: M.rk4(model.dynamics, x, u, 0.01)))(xs, us)
    for i in range(4):
        np.testing.assert_allclose(batched[i], M.rk4(model.dynamics, xs[i], us[i], 0.01), rtol=1e-13, atol=1e-15)
