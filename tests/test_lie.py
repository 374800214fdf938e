"""SO(3)/SE(3): round trips, group axioms, closed-form Jacobians against autodiff, finite
differences and Pinocchio, and NaN-freedom at the identity and at angle pi."""

import jax
import jax.numpy as jnp
import numpy as np
import pinocchio  # a test dependency: a missing pinocchio is an error, not a skip
import pytest
from conftest import central_difference, random_unit_vectors
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from jtraj import lie
from jtraj.lie import SE3, SO3

GROUPS = [(SO3, 3), (SE3, 6)]
E = lie.exp
Lg = lie.log
ids = ["SO3", "SE3"]


def tangents(rng, group_dim, n, angle):
    """n tangent vectors whose rotation part has the given angle."""
    axes = random_unit_vectors(rng, n)
    if group_dim == 3:
        return axes * angle
    return np.concatenate([rng.normal(size=(n, 3)), axes * angle], axis=1)


ANGLES = {"random": None, "near_identity": 1e-7, "small": 0.049, "medium": 1.3, "near_pi": np.pi - 1e-6}


def sample(rng, dim, kind, n=16):
    if ANGLES[kind] is None:
        # random angles in (0, pi): Log returns the principal branch only
        return tangents(rng, dim, n, rng.uniform(0.0, np.pi - 1e-3, size=(n, 1)))
    return tangents(rng, dim, n, ANGLES[kind])


@pytest.mark.parametrize("group,dim", GROUPS, ids=ids)
@pytest.mark.parametrize("kind", list(ANGLES))
def test_exp_log_round_trip(group, dim, kind, rng):
    xi = jnp.asarray(sample(rng, dim, kind))
    # batched through jaxlie's leading axes
    back = Lg(E(group, xi))
    np.testing.assert_allclose(back, xi, atol=1e-9 if kind != "near_pi" else 1e-6)
    # and log(exp) as group elements
    T = E(group, xi)
    np.testing.assert_allclose(E(group, Lg(T)).as_matrix(), T.as_matrix(), atol=1e-12)


@pytest.mark.parametrize("group,dim", GROUPS, ids=ids)
@pytest.mark.parametrize("batch", [(), (5,), (2, 3)])
def test_batch_shapes(group, dim, batch, rng):
    xi = jnp.asarray(rng.normal(size=batch + (dim,)))
    T = E(group, xi)
    assert Lg(T).shape == batch + (dim,)
    assert lie.right_jacobian(group, xi).shape == batch + (dim, dim)
    assert lie.left_jacobian_inv(group, xi).shape == batch + (dim, dim)
    assert Lg(lie.plus(T, xi)).shape == batch + (dim,)
    assert lie.minus(T, T).shape == batch + (dim,)
    # batched == vmapped
    if batch:
        flat = xi.reshape(-1, dim)
        J_v = jax.vmap(lambda x: lie.right_jacobian(group, x))(flat)
        np.testing.assert_allclose(lie.right_jacobian(group, xi).reshape(-1, dim, dim), J_v, atol=1e-14)


@pytest.mark.parametrize("group,dim", GROUPS, ids=ids)
def test_group_axioms(group, dim, rng):
    a, b, c = (E(group, jnp.asarray(rng.normal(size=dim))) for _ in range(3))
    I = group.identity()
    np.testing.assert_allclose(((a @ b) @ c).as_matrix(), (a @ (b @ c)).as_matrix(), atol=1e-12)
    np.testing.assert_allclose((a @ I).as_matrix(), a.as_matrix(), atol=1e-14)
    np.testing.assert_allclose((I @ a).as_matrix(), a.as_matrix(), atol=1e-14)
    np.testing.assert_allclose((a @ a.inverse()).as_matrix(), np.eye(dim // 3 * 0 + (3 if dim == 3 else 4)), atol=1e-12)
    np.testing.assert_allclose(lie.compose(a, b).as_matrix(), a.as_matrix() @ b.as_matrix(), atol=1e-12)
    np.testing.assert_allclose(lie.inverse(a).as_matrix(), np.linalg.inv(a.as_matrix()), atol=1e-12)
    p = jnp.asarray(rng.normal(size=3))
    np.testing.assert_allclose(lie.act(a @ b, p), lie.act(a, lie.act(b, p)), atol=1e-12)
    # plus / minus are inverse operations
    xi = jnp.asarray(0.5 * rng.normal(size=dim))
    np.testing.assert_allclose(lie.minus(lie.plus(a, xi), a), xi, atol=1e-12)
    np.testing.assert_allclose(lie.plus(a, lie.minus(b, a)).as_matrix(), b.as_matrix(), atol=1e-12)
    # adjoint: T Exp(xi) T^-1 = Exp(Ad_T xi)
    lhs = (a @ E(group, xi) @ a.inverse()).as_matrix()
    rhs = E(group, lie.adjoint(a) @ xi).as_matrix()
    np.testing.assert_allclose(lhs, rhs, atol=1e-12)


def _autodiff_jacobians(group, dim, xi):
    z = jnp.zeros(dim)
    Jr = jax.jacfwd(lambda d: Lg(E(group, xi).inverse() @ E(group, xi + d)))(z)
    Jl = jax.jacfwd(lambda d: Lg(E(group, xi + d) @ E(group, xi).inverse()))(z)
    Jr_inv = jax.jacfwd(lambda d: Lg(E(group, xi) @ E(group, d)))(z)
    Jl_inv = jax.jacfwd(lambda d: Lg(E(group, d) @ E(group, xi)))(z)
    return Jr, Jl, Jr_inv, Jl_inv


@pytest.mark.parametrize("group,dim", GROUPS, ids=ids)
@pytest.mark.parametrize("kind", ["random", "near_identity", "small", "medium"])
def test_jacobians_equal_autodiff(group, dim, kind, rng):
    for xi in sample(rng, dim, kind, n=6):
        xi = jnp.asarray(xi)
        Jr, Jl, Jr_inv, Jl_inv = _autodiff_jacobians(group, dim, xi)
        np.testing.assert_allclose(lie.right_jacobian(group, xi), Jr, atol=1e-10)
        np.testing.assert_allclose(lie.left_jacobian(group, xi), Jl, atol=1e-10)
        np.testing.assert_allclose(lie.right_jacobian_inv(group, xi), Jr_inv, atol=1e-9)
        np.testing.assert_allclose(lie.left_jacobian_inv(group, xi), Jl_inv, atol=1e-9)
        np.testing.assert_allclose(lie.right_jacobian(group, xi) @ lie.right_jacobian_inv(group, xi), np.eye(dim), atol=1e-10)


@pytest.mark.parametrize("group,dim", GROUPS, ids=ids)
def test_jacobians_equal_finite_differences(group, dim, rng):
    xi = rng.normal(size=dim)
    T = E(group, jnp.asarray(xi))
    Jr_fd = central_difference(lambda d: np.asarray(Lg(T.inverse() @ E(group, jnp.asarray(xi + d)))), np.zeros(dim))
    np.testing.assert_allclose(lie.right_jacobian(group, jnp.asarray(xi)), Jr_fd, atol=1e-8)
    Jl_fd = central_difference(lambda d: np.asarray(Lg(E(group, jnp.asarray(xi + d)) @ T.inverse())), np.zeros(dim))
    np.testing.assert_allclose(lie.left_jacobian(group, jnp.asarray(xi)), Jl_fd, atol=1e-8)


def test_regression_jaxlie_se3_exp_near_identity(rng):
    """jaxlie 1.5.0's SE3.exp uses R in place of J_l(theta) below 1e-5 rad: the translation
    is off by theta x rho / 2 and d Exp / d theta at the identity by a factor 2. lie.exp
    must not inherit that."""
    xi = jnp.array([0.5, 1.4, -0.2, 1e-7, 3e-8, -2e-8])
    np.testing.assert_allclose(Lg(E(SE3, xi)), xi, atol=1e-15)
    dt_dtheta = jax.jacfwd(lambda x: E(SE3, x).translation())(jnp.zeros(6).at[:3].set(xi[:3]))[:, 3:]
    np.testing.assert_allclose(dt_dtheta, -0.5 * np.asarray(lie.skew(xi[:3])), atol=1e-14)


def test_right_jacobian_inverse_matches_jaxlie_jlog(rng):
    for _ in range(5):
        xi = jnp.asarray(rng.normal(size=6))
        np.testing.assert_allclose(lie.right_jacobian_inv(SE3, xi), E(SE3, xi).jlog(), atol=1e-9)


@pytest.mark.parametrize("group,dim", GROUPS, ids=ids)
@pytest.mark.parametrize("angle", [0.0, 1e-12, np.pi - 1e-11, np.pi])
def test_the_derivative_of_log_is_the_inverse_right_jacobian_up_to_pi(group, dim, angle):
    """jaxlie's SO(3) log is pi v / |v| where |w| < 1e-10: its derivative along the rotation's
    axis was 0, not 1, within 2e-10 rad of pi, where the flip and handstand warm starts put
    knots (the SE(3) chart's dynamics rows had rank 5 there in place of 6)."""
    axis = jnp.array([0.3, -0.5, 0.81]) / jnp.linalg.norm(jnp.array([0.3, -0.5, 0.81]))
    for a in (axis, jnp.array([0.0, 1.0, 0.0])):  # (the warm starts' own: a turn about y)
        xi = a * angle if dim == 3 else jnp.concatenate([jnp.array([0.1, 0.2, -0.3]), a * angle])
        J = jax.jacfwd(lambda d: lie.log(E(group, xi) @ E(group, d)))(jnp.zeros(dim))
        # at pi, log may give either of the two tangents of the rotation (rounding picks the
        # quaternion's sign): the Jacobian is that tangent's
        np.testing.assert_allclose(J, lie.right_jacobian_inv(group, lie.log(E(group, xi))), atol=1e-9)
        assert np.linalg.matrix_rank(np.asarray(J)) == dim


@pytest.mark.parametrize("group,dim", GROUPS, ids=ids)
@pytest.mark.parametrize("angle", [0.0, 1e-9, np.pi, np.pi - 1e-9])
def test_no_nan_at_identity_and_pi(group, dim, angle):
    axis = jnp.array([0.3, -0.5, 0.81]) / jnp.linalg.norm(jnp.array([0.3, -0.5, 0.81]))
    xi = axis * angle if dim == 3 else jnp.concatenate([jnp.array([0.1, 0.2, -0.3]), axis * angle])

    def scalar(x):
        T = E(group, x)
        return (
            jnp.sum(Lg(T))
            + jnp.sum(lie.right_jacobian(group, x))
            + jnp.sum(lie.left_jacobian(group, x))
            + jnp.sum(lie.right_jacobian_inv(group, x))
            + jnp.sum(lie.left_jacobian_inv(group, x))
            + jnp.sum(lie.minus(lie.plus(T, x), T))
        )

    value, grad = jax.value_and_grad(scalar)(xi)
    assert np.isfinite(value)
    assert np.all(np.isfinite(grad))
    fwd = jax.jacfwd(lambda x: Lg(E(group, x)))(xi)
    assert np.all(np.isfinite(fwd))


def test_regression_se3_q_block_fourth_coefficient_sign(rng):
    """Bug found while writing lie.py: the fourth term of Barfoot's Q(rho, theta) was coded
    as 1/2 (d - 3 (b - 1/6) / t^2); the right sign is +. Small angles hid it (error grew
    with the angle), so check a large one against autodiff."""
    xi = jnp.array([0.4, -1.0, 0.7, 0.3, 2.2, -1.5])
    Jr = _autodiff_jacobians(SE3, 6, xi)[0]
    np.testing.assert_allclose(lie.right_jacobian(SE3, xi), Jr, atol=1e-10)


@settings(max_examples=40, deadline=None)
@given(arrays(np.float64, 6, elements=st.floats(-3.0, 3.0)))
def test_property_log_exp_round_trip(xi):
    """Hypothesis: Log(Exp(xi)) == xi whenever the rotation angle is below pi."""
    xi = np.asarray(xi)
    if np.linalg.norm(xi[3:]) > np.pi - 1e-3:
        xi[3:] *= (np.pi - 1e-3) / np.linalg.norm(xi[3:])
    np.testing.assert_allclose(_jit_roundtrip(jnp.asarray(xi)), xi, atol=1e-8)


_jit_roundtrip = jax.jit(lambda x: Lg(E(SE3, x)))


class TestPinocchioOracle:
    pin = pinocchio

    def test_exp6_log6_jexp6(self, rng):
        pin = self.pin
        for _ in range(20):
            xi = rng.normal(size=6)
            M = pin.exp6(xi)
            T = E(SE3, jnp.asarray(xi))
            np.testing.assert_allclose(T.rotation().as_matrix(), M.rotation, atol=1e-12)
            np.testing.assert_allclose(T.translation(), M.translation, atol=1e-12)
            np.testing.assert_allclose(Lg(T), pin.log6(M).vector, atol=1e-10)
            np.testing.assert_allclose(lie.right_jacobian(SE3, jnp.asarray(xi)), pin.Jexp6(pin.Motion(xi)), atol=1e-10)
            np.testing.assert_allclose(lie.right_jacobian_inv(SE3, Lg(T)), pin.Jlog6(M), atol=1e-9)


def test_accumulated_rotation_counts_full_turns():
    """A back-flip about +y reads -2 pi about y (Log of the end attitude alone reads 0); the
    body-frame sum of a roll about the body x axis of a pitched body stays on body x."""
    angles = np.linspace(0, -2 * np.pi, 41)
    wxyz = jnp.stack([SO3.from_y_radians(a).wxyz for a in angles])
    np.testing.assert_allclose(lie.accumulated_rotation(wxyz)[-1], [0.0, -2 * np.pi, 0.0], atol=1e-9)
    np.testing.assert_allclose(lie.accumulated_rotation(2.0 * wxyz)[-1], [0.0, -2 * np.pi, 0.0], atol=1e-9)  # not unit
    pitch = SO3.from_y_radians(0.3)
    rolled = jnp.stack([(pitch @ SO3.from_x_radians(a)).wxyz for a in np.linspace(0, np.pi, 21)])
    np.testing.assert_allclose(lie.accumulated_rotation(rolled, "body")[-1], [np.pi, 0.0, 0.0], atol=1e-9)
    assert abs(float(lie.accumulated_rotation(rolled)[-1, 0]) - np.pi * np.cos(0.3)) < 1e-9
    with pytest.raises(ValueError, match="frame"):
        lie.accumulated_rotation(wxyz, "space")


def test_tangents_of_the_wrong_size_are_refused_and_integers_taken_as_floats():
    for fn in (lambda t: lie.exp(lie.SE3, t), lambda t: lie.left_jacobian(lie.SE3, t), lambda t: lie.right_jacobian_inv(lie.SE3, t)):
        with pytest.raises(ValueError, match=r"a SE3 tangent must have 6 entries on its last axis, got shape \(3,\)"):
            fn(jnp.zeros(3))
    with pytest.raises(ValueError, match=r"a SO3 tangent must have 3 entries on its last axis, got shape \(6,\)"):
        lie.exp(lie.SO3, jnp.zeros(6))
    np.testing.assert_array_equal(lie.exp(lie.SE3, np.array([0, 0, 1, 0, 0, 0])).translation(), [0.0, 0.0, 1.0])


def test_rotation_steps_take_one_sequence_of_attitudes():
    """A single quaternion, a batch of sequences or 3-vectors failed deep in jaxlie or numpy.
    A zero quaternion gives NaN steps beside it, which the success check reads as no motion."""
    from jtraj.lie import accumulated_rotation, rotation_steps

    for bad in (jnp.array([1.0, 0.0, 0.0, 0.0]), jnp.zeros((2, 5, 4)), jnp.zeros((5, 3)), jnp.zeros((0, 4))):
        with pytest.raises(ValueError, match=r"^wxyz must be a sequence of quaternions of shape \(N, 4\), N >= 1, got "):
            rotation_steps(bad)
    steps = np.asarray(rotation_steps(jnp.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]])))
    assert np.all(np.isnan(steps[:2])) and np.all(steps[2] == 0.0)
    half_turn = jnp.array([[1.0, 0.0, 0.0, 0.0], [np.cos(0.5), np.sin(0.5), 0.0, 0.0]])
    np.testing.assert_allclose(jax.jit(accumulated_rotation)(half_turn), [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], atol=1e-12)
