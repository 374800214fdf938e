"""Quaternion calculus of "Planning with Attitude": identities, and every correction
formula against the autodiff expression it claims to equal."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import central_difference
from jaxlie import SO3

from jtraj import quaternion as Q

Z3 = jnp.zeros(3)


def random_quaternions(rng, n):
    q = rng.normal(size=(n, 4))
    return [jnp.asarray(x / np.linalg.norm(x)) for x in q]


def test_multiplication_matrices(rng):
    q1, q2 = random_quaternions(rng, 2)
    np.testing.assert_allclose(Q.L(q1) @ q2, Q.R(q2) @ q1, atol=1e-15)  # eq. 1
    np.testing.assert_allclose(Q.multiply(q1, q2), (SO3(q1) @ SO3(q2)).wxyz, atol=1e-15)
    np.testing.assert_allclose(Q.L(Q.T @ q1), Q.L(q1).T, atol=1e-15)  # eq. 6
    np.testing.assert_allclose(Q.L(q1).T @ Q.L(q1), np.eye(4), atol=1e-15)
    np.testing.assert_allclose(Q.R(Q.T @ q1), Q.R(q1).T, atol=1e-15)  # eq. 7
    np.testing.assert_allclose(Q.multiply(q1, Q.conjugate(q1)), [1, 0, 0, 0], atol=1e-15)


def test_rotation_matrix_matches_jaxlie(rng):
    for q in random_quaternions(rng, 5):
        np.testing.assert_allclose(Q.rotation_matrix(q), SO3(q).as_matrix(), atol=1e-14)
        r = jnp.asarray(rng.normal(size=3))
        # q (x) r^ (x) q* = A(q) r  (eq. 9)
        np.testing.assert_allclose(Q.multiply(Q.multiply(q, Q.H @ r), Q.conjugate(q))[1:], Q.rotate(q, r), atol=1e-14)


def test_cayley_round_trip_and_identity():
    phi = jnp.array([0.3, -0.2, 0.5])
    q = Q.cayley(phi)
    assert abs(jnp.linalg.norm(q) - 1) < 1e-15
    np.testing.assert_allclose(Q.cayley_inv(q), phi, atol=1e-15)
    np.testing.assert_allclose(Q.cayley(Z3), [1, 0, 0, 0])
    # gradients finite at the identity
    g = jax.jacfwd(lambda p: Q.cayley_inv(Q.cayley(p)))(Z3)
    np.testing.assert_allclose(g, np.eye(3), atol=1e-15)


def test_attitude_jacobian_is_derivative_of_cayley_step(rng):
    for q in random_quaternions(rng, 3):
        J = jax.jacfwd(lambda p: Q.L(q) @ Q.cayley(p))(Z3)
        np.testing.assert_allclose(Q.attitude_jacobian(q), J, atol=1e-14)
        np.testing.assert_allclose(Q.attitude_jacobian(q), central_difference(lambda p: np.asarray(Q.multiplicative_update(q, jnp.asarray(p))), np.zeros(3)), atol=1e-9)


def _h(q):
    """A nonlinear vector function of a quaternion."""
    return jnp.array([q[0] * q[1] - q[2] ** 2, jnp.sin(q[3]) + q[0] ** 3, q @ jnp.array([1.0, 2.0, -1.0, 0.5])])


def _hs(q):
    return jnp.sin(q[0] + 2 * q[1]) * q[3] + q[2] ** 2 * q[1]


def test_eq14_jacobian_correction(rng):
    for q in random_quaternions(rng, 3):
        expected = jax.jacfwd(lambda p: _h(Q.L(q) @ Q.cayley(p)))(Z3)
        np.testing.assert_allclose(Q.jacobian_correction(jax.jacfwd(_h)(q), q), expected, atol=1e-13)


def test_eq15_hessian_correction(rng):
    for q in random_quaternions(rng, 3):
        expected = jax.hessian(lambda p: _hs(Q.L(q) @ Q.cayley(p)))(Z3)
        got = Q.hessian_correction(jax.hessian(_hs)(q), jax.grad(_hs)(q), q)
        np.testing.assert_allclose(got, expected, atol=1e-13)


def test_regression_eq15_sign():
    """The paper prints eq. 15 with '+ I3 (dh/dq q)'; the Cayley map's second-order term
    makes it '-'. A linear h exposes the sign: its Hessian is only that term."""
    q = jnp.array([0.8, 0.2, -0.4, 0.4]) / jnp.linalg.norm(jnp.array([0.8, 0.2, -0.4, 0.4]))
    c = jnp.array([1.0, -2.0, 0.5, 3.0])
    expected = jax.hessian(lambda p: c @ (Q.L(q) @ Q.cayley(p)))(Z3)
    np.testing.assert_allclose(expected, -(c @ q) * np.eye(3), atol=1e-14)
    np.testing.assert_allclose(Q.hessian_correction(jnp.zeros((4, 4)), c, q), expected, atol=1e-14)


def test_eq18_quaternion_jacobian_correction(rng):
    qa, qb = random_quaternions(rng, 2)

    def f(q):  # a quaternion-valued function: left and right multiplication
        return Q.multiply(qa, Q.multiply(q, qb))

    for q in random_quaternions(rng, 3):
        q_out = f(q)
        expected = jax.jacfwd(lambda p: Q.cayley_inv(Q.L(q_out).T @ f(Q.L(q) @ Q.cayley(p))))(Z3)
        got = Q.quaternion_jacobian_correction(jax.jacfwd(f)(q), q, q_out)
        np.testing.assert_allclose(got, expected, atol=1e-13)


def test_cayley_inv_jacobian_eq38(rng):
    for q in random_quaternions(rng, 3):
        np.testing.assert_allclose(Q.cayley_inv_jacobian(q), jax.jacfwd(Q.cayley_inv)(q), atol=1e-13)


def test_error_state_jacobian_eq25(rng):
    q = random_quaternions(rng, 1)[0]
    x = jnp.concatenate([jnp.asarray(rng.normal(size=3)), q, jnp.asarray(rng.normal(size=6))])

    def retract(dx):
        return jnp.concatenate([x[:3] + dx[:3], Q.L(q) @ Q.cayley(dx[3:6]), x[7:] + dx[6:]])

    E = Q.error_state_jacobian(x)
    assert E.shape == (13, 12)
    np.testing.assert_allclose(E, jax.jacfwd(retract)(jnp.zeros(12)), atol=1e-14)


def test_error_state_jacobian_of_a_longer_state_is_that_of_its_error_state(rng):
    """The 23-state spacecraft's E(x) was (13, 12), not E(x_ref)^T of its error state's
    Jacobian, (22, 23), as `jtraj.attitude.models.error_state` says it is."""
    from jtraj.attitude.models import error_state

    q = random_quaternions(rng, 1)[0]
    x = jnp.concatenate([jnp.asarray(rng.normal(size=3)), q, jnp.asarray(rng.normal(size=16))])
    E = Q.error_state_jacobian(x)
    assert E.shape == (23, 22)
    np.testing.assert_allclose(E.T, jax.jacfwd(lambda y: error_state(y, x))(x), atol=1e-13)
    with pytest.raises(ValueError, match=r"x \(a state \[r, q, ...\]\) must have shape \(nx,\) with nx >= 7, got \(5,\)"):
        Q.error_state_jacobian(jnp.zeros(5))


@pytest.mark.parametrize(
    "call, message",
    [
        # each of these read past the end of a short argument (JAX clamps) or ignored a long one
        (lambda: Q.cayley_inv(jnp.ones(3)), r"q \(a quaternion\) must have shape \(4,\), got \(3,\)$"),
        (lambda: Q.cayley(jnp.ones(4)), r"phi \(Rodrigues parameters\) must have shape \(3,\), got \(4,\)$"),
        (lambda: Q.geodesic_cost(jnp.ones(3), jnp.ones(3)), r"q \(a quaternion\) must have shape \(4,\), got \(3,\)$"),
        (lambda: Q.geodesic_cost_gradient(jnp.ones(4), jnp.ones(3)), r"q_goal \(a quaternion\) must have shape \(4,\)"),
        (lambda: Q.rotate(jnp.ones(4), jnp.ones(4)), r"r \(a 3-vector\) must have shape \(3,\), got \(4,\)$"),
        (lambda: Q.multiply(jnp.ones(4), jnp.ones(5)), r"q2 \(a quaternion\) must have shape \(4,\)"),
        (lambda: Q.L(jnp.ones((2, 4))), r"q \(a quaternion\) must have shape \(4,\), got \(2, 4\) \(one at a time: use jax.vmap for batches\)$"),
        (lambda: Q.cayley_inv_jacobian(jnp.ones(5)), r"q \(a quaternion\) must have shape \(4,\)"),
    ],
)
def test_arguments_of_the_wrong_shape_are_refused(call, message):
    with pytest.raises(ValueError, match=message):
        call()


@pytest.mark.parametrize("flip", [1.0, -1.0])
def test_geodesic_cost_eq40_42(rng, flip):
    q, qg = random_quaternions(rng, 2)
    q = flip * q  # double cover: the cost is invariant, the formulas must follow the sign

    def cost(p):
        return Q.geodesic_cost(Q.L(q) @ Q.cayley(p), qg)

    np.testing.assert_allclose(Q.geodesic_cost(q, qg), Q.geodesic_cost(-q, qg), atol=1e-15)
    np.testing.assert_allclose(Q.geodesic_cost_gradient(q, qg), jax.grad(cost)(Z3), atol=1e-14)
    np.testing.assert_allclose(Q.geodesic_cost_hessian(q, qg), jax.hessian(cost)(Z3), atol=1e-14)


def test_regression_eq41_sign():
    """eq. 41 is printed without the minus sign; a step along -gradient must lower the cost."""
    qg = jnp.array([1.0, 0.0, 0.0, 0.0])
    q = Q.cayley(jnp.array([0.2, 0.0, 0.0]))
    g = Q.geodesic_cost_gradient(q, qg)
    assert Q.geodesic_cost(Q.multiplicative_update(q, -1e-3 * g), qg) < Q.geodesic_cost(q, qg)


#: the module's functions with arguments of each kind: "q" a unit quaternion, "v" a 3-vector,
#: "x" a 13-state (r, q, v, omega), "g" a 1 x 4 row (dh/dq), "h" a 4 x 4 matrix (d2h/dq2)
JIT_VMAP = [
    ("L", "q"), ("R", "q"), ("multiply", "qq"), ("conjugate", "q"), ("rotation_matrix", "q"), ("rotate", "qv"),
    ("attitude_jacobian", "q"), ("cayley", "v"), ("cayley_inv", "q"), ("cayley_inv_jacobian", "q"),
    ("multiplicative_update", "qv"), ("jacobian_correction", "gq"), ("hessian_correction", "hgq"),
    ("quaternion_jacobian_correction", "hqq"), ("error_state_jacobian", "x"), ("geodesic_cost", "qq"),
    ("geodesic_cost_gradient", "qq"), ("geodesic_cost_hessian", "qq"),
]


@pytest.mark.parametrize(("name", "kinds"), JIT_VMAP, ids=[f[0] for f in JIT_VMAP])
def test_functions_jit_and_vmap(rng, name, kinds):
    """``jax.jit(jax.vmap(f))`` over a batch equals ``f`` member by member."""
    B = 4

    def draw(kind):
        if kind == "q":
            return jnp.stack(random_quaternions(rng, B))
        if kind == "x":
            return jnp.concatenate([rng.normal(size=(B, 3)), jnp.stack(random_quaternions(rng, B)), rng.normal(size=(B, 6))], axis=1)
        return jnp.asarray(rng.normal(size={"v": (B, 3), "g": (B, 1, 4), "h": (B, 4, 4)}[kind]))

    f = getattr(Q, name)
    args = [draw(k) for k in kinds]
    batched = jax.jit(jax.vmap(f))(*args)
    for i in range(B):
        np.testing.assert_allclose(batched[i], f(*(a[i] for a in args)), rtol=1e-12, atol=1e-14)


def test_regression_eq41_gradient_half_a_turn_from_the_goal():
    """Regression: at q_g^T q = 0 (the identity and a goal half a turn away, the cost's
    maximum) eq. 41 with sign(0) = 0 gave a zero gradient, where JAX's gradient (which the
    docstring says it equals) is a unit vector. (A check that a step against it lowers the cost
    could not fail there: every step from the maximum does.)"""
    q = jnp.array([1.0, 0.0, 0.0, 0.0])
    for qg in (jnp.array([0.0, 1.0, 0.0, 0.0]), jnp.array([0.0, 0.0, 0.6, -0.8])):
        g = Q.geodesic_cost_gradient(q, qg)
        np.testing.assert_allclose(g, jax.grad(lambda p: Q.geodesic_cost(Q.L(q) @ Q.cayley(p), qg))(Z3), atol=1e-15)
        np.testing.assert_allclose(np.linalg.norm(g), 1.0, atol=1e-15)
