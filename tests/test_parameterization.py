"""The five floating-base parameterizations behind one contract (Table I)."""

import jax
import jax.numpy as jnp
import numpy as np
import pinocchio  # a test dependency, the independent oracle of the manifold step
import pytest

from jtraj import euler, lie
from jtraj.lie import SE3, SO3
from jtraj.parameterization import (
    PARAMETERIZATIONS,
    Quaternion1,
    Quaternion3,
    body_twist_to_qvel,
    get,
    qvel_to_body_twist,
)

PARAMS = list(PARAMETERIZATIONS.values())
IDS = list(PARAMETERIZATIONS)


def random_pose(rng, max_angle=2.5):
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = rng.uniform(0.0, max_angle)
    # Euler's chart needs |pitch| < pi/2: draw rpy directly instead for everyone
    rpy = rng.uniform([-3.0, -1.4, -3.0], [3.0, 1.4, 3.0])
    R = SO3.from_rpy_radians(*rpy) if rng.uniform() < 0.5 else SO3.exp(jnp.asarray(axis * angle))
    return SE3.from_rotation_and_translation(R, jnp.asarray(rng.normal(size=3)))


def random_twist(rng):
    return jnp.asarray(rng.normal(size=6))


def stepped_by_pinocchio(T, V, h):
    """T Exp(V h) (body twist V = (v, omega)) by Pinocchio's ``exp6``, not by `jtraj.lie`."""
    M = pinocchio.SE3(np.asarray(T.rotation().as_matrix()), np.asarray(T.translation()))
    M = M * pinocchio.exp6(pinocchio.Motion(np.asarray(V) * h))
    return SE3.from_rotation_and_translation(SO3.from_matrix(jnp.asarray(M.rotation)), jnp.asarray(M.translation))


def assert_same_pose(T1, T2, atol=1e-12):
    np.testing.assert_allclose(T1.as_matrix(), T2.as_matrix(), atol=atol)


@pytest.mark.parametrize("param", PARAMS, ids=IDS)
def test_contract_sizes(param, rng):
    q = param.from_pose(random_pose(rng))
    assert q.shape == (param.nq,)
    assert param.difference(q, q).shape == (param.ndiff,)
    np.testing.assert_allclose(param.difference(q, q), 0.0, atol=1e-14)
    assert param.constraint(q).shape == (param.ncon,)
    assert param.integrate(q, random_twist(rng), 0.05).shape == (param.nq,)


@pytest.mark.parametrize("param", PARAMS, ids=IDS)
def test_pose_round_trips(param, rng):
    for _ in range(10):
        T = random_pose(rng)
        q = param.from_pose(T)
        assert_same_pose(param.to_pose(q), T)
        np.testing.assert_allclose(param.from_pose(param.to_pose(q)), q, atol=1e-11)
        qpos = param.to_qpos(q)
        assert qpos.shape == (7,)
        np.testing.assert_allclose(jnp.linalg.norm(qpos[3:]), 1.0, atol=1e-14)
        assert_same_pose(param.to_pose(param.from_qpos(qpos)), T)


@pytest.mark.parametrize("param", PARAMS, ids=IDS)
def test_numpy_coordinates_are_taken_as_jax_ones(param, rng):
    """Every chart's methods take numpy arrays, as the SE(3) and Euler ones always did."""
    q = np.asarray(param.from_pose(random_pose(rng)))
    w = np.asarray(random_twist(rng))
    assert type(q) is np.ndarray
    np.testing.assert_array_equal(param.to_qpos(q), param.to_qpos(jnp.asarray(q)))
    assert_same_pose(param.to_pose(q), param.to_pose(jnp.asarray(q)), atol=0)
    np.testing.assert_array_equal(param.integrate(q, w, 0.05), param.integrate(jnp.asarray(q), jnp.asarray(w), 0.05))


@pytest.mark.parametrize("param", PARAMS, ids=IDS)
def test_integration_is_first_order_exact_on_the_manifold(param, rng):
    """Every row of Table I integrates the body twist: to_pose(integrate(q, V, h)) equals
    to_pose(q) Exp(V h) (Pinocchio's) up to O(h^2)."""
    T = random_pose(rng)
    q = param.from_pose(T)
    V = random_twist(rng)
    errors = []
    for h in (1e-2, 5e-3):
        stepped = param.to_pose(param.integrate(q, V, h))
        errors.append(np.linalg.norm(lie.minus(stepped, stepped_by_pinocchio(T, V, h))))
    assert errors[0] < 1e-2
    if param.name == "quat2":  # its step is the manifold's own, T Exp(V h), not an approximation
        assert errors[0] < 1e-12 and errors[1] < 1e-12, errors
    # second order: halving h divides the error by ~4 (or it is exact)
    assert errors[1] <= errors[0] / 3.0 or errors[0] < 1e-12


def _documented_difference(param, q, V, h):
    """difference(q, integrate(q, V, h)) as documented for each row of Table I."""
    T = param.to_pose(q)
    Rm = T.rotation().as_matrix()
    if param.name in ("se3", "quat3"):  # inverse maps
        return V * h
    if param.name in ("quat1", "euler"):
        # an explicit Euler step of the coordinates' kinematics: h times their rate along the
        # flow t -> T Exp(V t) at t = 0, here by autodiff of the chart (not the code's L, H or
        # Euler-rate matrix); the translation's rate is R v
        _, rate = jax.jvp(lambda t: param.from_pose(lie.plus(T, V * t)), (jnp.zeros(()),), (jnp.ones(()),))
        np.testing.assert_allclose(rate[:3], Rm @ V[:3], atol=1e-12)
        return rate * h
    if param.name == "quat2":  # manifold step (Pinocchio's), vector difference
        stepped = param.from_pose(stepped_by_pinocchio(T, V, h))
        # the step moves the quaternion continuously: of the two for the rotation, the one near q's
        sign = jnp.sign(jnp.dot(stepped[3:], q[3:]))
        return jnp.concatenate([stepped[:3], sign * stepped[3:]]) - q
    raise AssertionError(param.name)


@pytest.mark.parametrize("param", PARAMS, ids=IDS)
def test_integrate_and_difference_follow_table_1(param, rng):
    for _ in range(5):
        q = param.from_pose(random_pose(rng))
        V = random_twist(rng)
        h = 0.05
        q_next = param.integrate(q, V, h)
        np.testing.assert_allclose(param.difference(q, q_next), _documented_difference(param, q, V, h), atol=1e-12)


@pytest.mark.parametrize("param", PARAMS, ids=IDS)
def test_jit_compiles_once_and_vmap_equals_loop(param, rng):
    traces = []

    def step(q, V):
        traces.append(1)
        q_next = param.integrate(q, V, 0.05)
        return q_next, param.difference(q, q_next), param.to_qpos(q_next)

    jitted = jax.jit(step)
    qs = jnp.stack([param.from_pose(random_pose(rng)) for _ in range(4)])
    Vs = jnp.stack([random_twist(rng) for _ in range(4)])
    loop = [jitted(qs[i], Vs[i]) for i in range(4)]
    assert len(traces) == 1
    batched = jax.vmap(step)(qs, Vs)
    for i in range(4):
        for got, want in zip(batched, loop[i]):
            np.testing.assert_allclose(got[i], want, atol=1e-13)


@pytest.mark.parametrize("param", PARAMS, ids=IDS)
def test_derivatives_finite_at_identity(param):
    q = param.from_pose(SE3.identity())
    V = jnp.array([0.1, -0.2, 0.3, 0.0, 0.0, 0.0])

    def f(q, V):
        return jnp.concatenate([param.difference(q, param.integrate(q, V, 0.05)), param.to_qpos(q)])

    for J in jax.jacfwd(f, argnums=(0, 1))(q, V):
        assert np.all(np.isfinite(J))


def test_se3_tangent_difference_is_blind_to_full_turns(rng):
    """A warm start may wind xi past pi (flips); the difference must not see the 2 pi."""
    se3 = get("se3")
    xi = jnp.array([0.1, 0.2, 0.3, 0.0, 0.5, 0.0])
    # the same pose one turn further: theta' = theta (1 + 2 pi / |theta|), rho' keeps
    # the translation J_l(theta) rho
    theta_wound = xi[3:] * (1 + 2 * np.pi / 0.5)
    rho_wound = lie.left_jacobian_inv(SO3, theta_wound) @ lie.left_jacobian(SO3, xi[3:]) @ xi[:3]
    wound = jnp.concatenate([rho_wound, theta_wound])
    assert_same_pose(se3.to_pose(wound), se3.to_pose(xi))
    np.testing.assert_allclose(se3.difference(xi, wound), 0.0, atol=1e-12)
    np.testing.assert_allclose(se3.integrate(wound, jnp.zeros(6), 0.1), xi, atol=1e-12)


def test_quaternion_sign_and_norm_are_ignored_by_the_pose():
    q = jnp.array([0.1, 0.2, 0.3, 0.6, 0.0, 0.8, 0.0])
    for p in (Quaternion1(), Quaternion3()):
        assert_same_pose(p.to_pose(q), p.to_pose(q.at[3:].multiply(-2.5)))


def test_unit_norm_option():
    q = jnp.array([0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0])
    assert Quaternion3().ncon == 0
    p = Quaternion3(unit_norm=True)
    assert p.ncon == 1
    np.testing.assert_allclose(p.constraint(q), [3.0])


def test_unknown_name_lists_choices():
    with pytest.raises(ValueError, match=r"expected one of \['euler', 'quat1', 'quat2', 'quat3', 'se3'\]"):
        get("quaternion")


def test_velocity_conversion_to_mjx(rng):
    T = random_pose(rng)
    V = random_twist(rng)
    qvel = body_twist_to_qvel(T, V)
    np.testing.assert_allclose(qvel[:3], T.rotation().as_matrix() @ V[:3], atol=1e-14)
    np.testing.assert_allclose(qvel[3:], V[3:])
    np.testing.assert_allclose(qvel_to_body_twist(T, qvel), V, atol=1e-14)


QUATS = [p for p in PARAMS if p.nq == 7]


@pytest.mark.parametrize("param", QUATS, ids=[p.name for p in QUATS])
@pytest.mark.parametrize("rho", [[0.0, 0.0, 0.0, 0.0], [1e-12, 0.0, 0.0, 0.0], [-3e-7, 0.0, 2e-7, 0.0], [0.0, 1e-9, -1e-9, 0.0]], ids=["zero", "tiny_w", "below_floor", "tiny_v"])
def test_quaternion_charts_finite_near_zero_norm(param, rho):
    """Regression: noise drove rho to zero, where rho / |rho| gave NaN values and Jacobians."""
    q = jnp.concatenate([jnp.array([0.1, 0.2, 0.3]), jnp.asarray(rho)])
    q_other = jnp.array([0.1, 0.2, 0.3, 0.9, 0.1, 0.0, 0.1])
    V = jnp.array([0.1, -0.2, 0.3, 0.4, -0.5, 0.6])

    def f(q):
        return jnp.concatenate([param.integrate(q, V, 0.05), param.difference(q, q_other), param.difference(q_other, q), param.to_qpos(q)])

    assert np.all(np.isfinite(f(q)))
    for J in (jax.jacfwd(f)(q), jax.jacrev(f)(q)):
        assert np.all(np.isfinite(J))
    # the pose is still a rotation
    np.testing.assert_allclose(np.linalg.norm(param.to_qpos(q)[3:]), 1.0, atol=1e-12)


def test_quaternion_floor_leaves_normal_quaternions_exact():
    from jtraj.parameterization import QUATERNION_FLOOR, _unit

    for rho in ([0.6, 0.0, 0.8, 0.0], [2 * QUATERNION_FLOOR, 0.0, 0.0, 0.0], [0.0, -QUATERNION_FLOOR, 0.0, 0.0]):
        rho = jnp.asarray(rho)
        np.testing.assert_array_equal(_unit(rho), rho / jnp.linalg.norm(rho))


@pytest.mark.parametrize("pitch", [np.pi / 2, -np.pi / 2, np.pi / 2 - 1e-9])
def test_euler_from_pose_keeps_off_gimbal_lock(pitch):
    """Regression: a flip's warm start passing pitch -pi/2 at a knot gave |W| ~ 1e16."""
    p = get("euler")
    T = SE3.from_rotation_and_translation(SO3.from_rpy_radians(0.0, pitch, 0.0), jnp.zeros(3))
    q = p.from_pose(T)
    assert np.pi / 2 - abs(float(q[4])) >= euler.GIMBAL_MARGIN * (1 - 1e-9)
    W = euler.rate_matrix(q[3:6])
    assert np.abs(W).max() < 1.01 / np.sin(euler.GIMBAL_MARGIN)
    # the pose moved by at most the margin
    err = lie.minus(p.to_pose(q), T)
    assert float(jnp.linalg.norm(err[3:])) <= euler.GIMBAL_MARGIN * (1 + 1e-9)
    V = jnp.array([0.1, -0.2, 0.3, 0.4, -0.5, 0.6])
    # d(W omega h)/d pitch ~ |omega| h / sin(margin)^2: large, but ~1e31 at the lock itself
    bound = 2 * float(jnp.linalg.norm(V[3:])) * 0.05 / np.sin(euler.GIMBAL_MARGIN) ** 2
    for J in jax.jacfwd(lambda q, V: p.integrate(q, V, 0.05), argnums=(0, 1))(q, V):
        assert np.all(np.isfinite(J)) and np.abs(J).max() < bound


def test_euler_integration_near_gimbal_lock_follows_table_1():
    """Within the margin of pitch +-pi/2 the Table I relation still holds exactly, and the
    first-order step still matches the manifold step for small h (W is large, not wrong)."""
    p = get("euler")
    V = jnp.array([0.1, -0.2, 0.3, 0.0, 0.02, 0.0])
    for pitch in (np.pi / 2 - 2 * euler.GIMBAL_MARGIN, -np.pi / 2 + 2 * euler.GIMBAL_MARGIN):
        q = jnp.array([0.0, 0.0, 0.0, 0.3, pitch, -0.2])
        h = 1e-5
        rpy = q[3:6]
        np.testing.assert_allclose(p.difference(q, p.integrate(q, V, h)), jnp.concatenate([euler.rotation_matrix(rpy) @ V[:3], euler.rate_matrix(rpy) @ V[3:]]) * h, rtol=1e-9, atol=1e-15)
        step = lie.minus(p.to_pose(p.integrate(q, V, h)), lie.plus(p.to_pose(q), V * h))
        assert float(jnp.linalg.norm(step)) < 1e-7


def test_euler_warm_start_of_the_backflip_avoids_gimbal_lock():
    from jtraj import task as tasks

    (axis, angles), = tasks.load("backflip").warm_start_angles()
    assert np.any(np.isclose(angles, -np.pi / 2)) and np.any(np.isclose(angles, -3 * np.pi / 2))  # the ramp passes the lock
    p = get("euler")
    poses = jax.vmap(lambda a: SE3.from_rotation_and_translation(SO3.exp(jnp.asarray(axis) * a), jnp.zeros(3)))(jnp.asarray(angles))
    q = jax.vmap(p.from_pose)(poses)
    W = jax.vmap(euler.rate_matrix)(q[:, 3:6])
    assert np.all(np.isfinite(W)) and np.abs(W).max() < 1.01 / np.sin(euler.GIMBAL_MARGIN)


@pytest.mark.parametrize("param", PARAMS, ids=IDS)
def test_wrong_sizes_are_refused_by_name(param):
    """A coordinate vector of another chart's size is refused, not read past its end (which
    JAX would clamp silently); integer coordinates are taken as floats."""
    with pytest.raises(ValueError, match=rf"{type(param).__name__}: q must have {param.nq} entries on its last axis"):
        param.to_qpos(jnp.zeros(3))
    with pytest.raises(ValueError, match=r"V_b \(body twist\) must have 6 entries"):
        param.integrate(param.from_pose(SE3.identity()), jnp.zeros(3), 0.1)
    with pytest.raises(ValueError, match="q2 must have"):
        param.difference(param.from_pose(SE3.identity()), jnp.zeros(param.nq + 1))
    with pytest.raises(ValueError, match=r"qpos \(xyz_wxyz\) must have 7 entries"):
        param.from_qpos(jnp.zeros(6))
    # also by the charts without a constraint, which inherit the base class's (it gave (0,)
    # for any size, and a list was an AttributeError)
    with pytest.raises(ValueError, match=rf"{type(param).__name__}: q must have {param.nq} entries on its last axis"):
        param.constraint(jnp.zeros(3))
    assert param.constraint(np.asarray(param.from_pose(SE3.identity())).tolist()).shape == (param.ncon,)
    # arguments given by name are checked too
    with pytest.raises(ValueError, match="q must have"):
        param.to_pose(q=jnp.zeros(3))
    with pytest.raises(ValueError, match=r"V_b \(body twist\) must have 6 entries"):
        param.integrate(param.from_pose(SE3.identity()), V_b=jnp.zeros(3), h=0.1)
    q = np.asarray(param.from_pose(SE3.identity())).round().astype(int)
    np.testing.assert_allclose(param.to_qpos(q), [0, 0, 0, 1, 0, 0, 0], atol=1e-15)


@pytest.mark.parametrize("param", PARAMS, ids=IDS)
def test_regression_batches_are_refused_with_a_pointer_to_vmap(param):
    """Regression: the contract is one configuration, but a (K, nq) batch passed the size
    check (last axis) and then failed inside with JAX shape errors ("dot_general requires
    contracting dimensions...", a bare AssertionError for the Euler chart) naming neither
    the argument nor jax.vmap."""
    qs = jnp.stack([param.from_pose(SE3.identity())] * 3)
    for call in (lambda: param.to_qpos(qs), lambda: param.integrate(qs, jnp.zeros((3, 6)), 0.1), lambda: param.difference(qs, qs)):
        with pytest.raises(ValueError, match=r"must be one configuration of shape .*use jax.vmap for batches"):
            call()
    with pytest.raises(ValueError, match=r"qpos \(xyz_wxyz\) must be one configuration of shape \(7,\)"):
        param.from_qpos(jnp.zeros((3, 7)).at[:, 3].set(1.0))
    np.testing.assert_allclose(jax.vmap(param.to_qpos)(qs), np.tile([0.0, 0, 0, 1, 0, 0, 0], (3, 1)), atol=1e-15)


def test_se3_tangent_is_singular_at_a_whole_turn():
    """The docstring said any xi was a valid coordinate, winding through full turns: at a
    rotation angle of 2 pi Exp's Jacobian loses rank (translation off the axis cannot be
    written), while half a radian past it the chart is regular again."""
    se3 = get("se3")

    def smallest_singular_value(angle):
        xi = jnp.array([0.3, 0.0, 0.2, 0.0, angle, 0.0])
        J = jax.jacfwd(lambda x: se3.to_pose(x).parameters())(xi)  # (7, 6): wxyz_xyz
        return float(np.linalg.svd(np.asarray(J), compute_uv=False)[-1])

    assert smallest_singular_value(2 * np.pi) < 1e-12
    assert smallest_singular_value(2 * np.pi + 0.5) > 1e-2 and smallest_singular_value(1.5 * np.pi) > 1e-2


def test_a_zero_quaternion_in_qpos_is_the_identity_not_nan():
    """from_qpos divided by the quaternion's norm: a zero one gave NaN coordinates (and NaN
    derivatives), where the quaternion charts' to_qpos read a zero quaternion as the identity."""
    for name in PARAMETERIZATIONS:
        p = get(name)
        qpos = jnp.array([0.1, 0.2, 0.3, 0.0, 0.0, 0.0, 0.0])
        q = p.from_qpos(qpos)
        np.testing.assert_allclose(p.to_qpos(q), [0.1, 0.2, 0.3, 1.0, 0.0, 0.0, 0.0], atol=1e-12)
        assert np.all(np.isfinite(np.asarray(jax.jacfwd(p.from_qpos)(qpos)))), name
        # a tiny quaternion keeps its direction (no floor)
        tiny = jnp.array([0.0, 0.0, 0.0, 0.0, 1e-9, 0.0, 0.0])
        np.testing.assert_allclose(np.abs(p.to_qpos(p.from_qpos(tiny))[3:]), [0.0, 1.0, 0.0, 0.0], atol=1e-9)
