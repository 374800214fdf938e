"""Euler angles (eqs. 5-6)."""

import jax
import jax.numpy as jnp
import numpy as np
from jaxlie import SO3

from jtraj import euler, lie


def test_rotation_matrix_convention(rng):
    for _ in range(5):
        rpy = jnp.asarray(rng.uniform(-1.4, 1.4, size=3))
        Rm = euler.rotation_matrix(rpy)
        expected = SO3.from_z_radians(rpy[2]) @ SO3.from_y_radians(rpy[1]) @ SO3.from_x_radians(rpy[0])
        np.testing.assert_allclose(Rm, expected.as_matrix(), atol=1e-14)
        np.testing.assert_allclose(euler.from_rotation_matrix(Rm), rpy, atol=1e-12)


def test_rate_matrix_maps_body_rate_to_angle_rates(rng):
    """d/dt rpy(R Exp(omega t)) at t=0 equals W(rpy) omega (eq. 6)."""
    for _ in range(5):
        rpy = jnp.asarray(rng.uniform(-1.2, 1.2, size=3))
        omega = jnp.asarray(rng.normal(size=3))
        Rm = euler.rotation_matrix(rpy)
        path = lambda t: euler.from_rotation_matrix(Rm @ lie.exp(SO3, omega * t).as_matrix())
        np.testing.assert_allclose(jax.jacfwd(path)(0.0), euler.rate_matrix(rpy) @ omega, atol=1e-12)


def test_regression_from_rotation_matrix_at_gimbal_lock_keeps_the_rotation():
    """At pitch +-pi/2 the entries that give roll and yaw are rounding noise when the matrix
    does not come from `rotation_matrix` (here a turn about y by Exp): roll and yaw came out
    unrelated, a pose 0.25 rad from the input for yaw 0.5, and the Euler chart's `from_pose`
    (documented to move such a pose by the gimbal margin only) inherited it."""
    from jtraj.parameterization import get

    chart = get("euler")
    for pitch in (-np.pi / 2, np.pi / 2, -3 * np.pi / 2):
        for roll, yaw in ((0.0, 0.5), (0.3, -2.0), (-1.1, 2.9)):
            R = SO3.from_z_radians(yaw) @ lie.exp(SO3, jnp.array([0.0, pitch, 0.0])) @ SO3.from_x_radians(roll)
            rpy = euler.from_rotation_matrix(R.as_matrix())
            np.testing.assert_allclose(euler.rotation_matrix(rpy), R.as_matrix(), atol=1e-12)
            T = lie.SE3.from_rotation_and_translation(R, jnp.zeros(3))
            moved = float(jnp.linalg.norm(lie.minus(chart.to_pose(chart.from_pose(T)), T)))
            assert moved <= euler.GIMBAL_MARGIN * (1 + 1e-9), (pitch, roll, yaw, moved)


def test_angles_of_the_wrong_shape_are_refused():
    """A 2-vector of angles gave a rotation with yaw = pitch (JAX clamps the index past its
    end); integer angles are taken as floats."""
    import pytest

    for f in (euler.rotation_matrix, euler.rate_matrix, euler.away_from_gimbal_lock):
        with pytest.raises(ValueError, match=r"rpy \(roll, pitch, yaw\) must have shape \(3,\), got \(2,\)$"):
            f(jnp.array([0.1, 0.2]))
    with pytest.raises(ValueError, match=r"Rm \(a rotation matrix\) must have shape \(3, 3\), got \(2, 2\)$"):
        euler.from_rotation_matrix(jnp.eye(2))
    np.testing.assert_allclose(euler.rotation_matrix(np.array([0, 0, 0])), np.eye(3))


def test_from_rotation_matrix_is_exact_near_the_lock_and_differentiable_at_it():
    """Just outside the old lock threshold (cos pitch 1e-6 to 1e-4) the two arctan2 of entries of
    size cos(pitch) lost up to six digits (6e-10 in the round trip's matrix); exactly at the
    lock the Jacobians had NaN columns (arctan2(0, 0), sqrt(0))."""
    rng = np.random.default_rng(3)
    # a rotation matrix as a pose gives it (from a quaternion: its entries are not those
    # rotation_matrix computes, which the two arctan2 read back exactly)
    for distance in (1e-7, 1e-6, 1e-5, 1e-4, 1e-3):
        for sign in (1.0, -1.0):
            for roll, yaw in rng.uniform(-np.pi, np.pi, (50, 2)):
                R = SO3.from_rpy_radians(roll, sign * (np.pi / 2 - distance), yaw).as_matrix()
                np.testing.assert_allclose(euler.rotation_matrix(euler.from_rotation_matrix(R)), R, atol=2e-15)
    for R in (SO3.from_y_radians(np.pi / 2).as_matrix(), SO3.from_y_radians(-np.pi / 2).as_matrix()):
        R = jnp.round(R)  # exactly at the lock: R[2, 1] = R[2, 2] = R[1, 0] = R[0, 0] = 0
        for jacobian in (jax.jacfwd, jax.jacrev):
            assert np.all(np.isfinite(np.asarray(jacobian(euler.from_rotation_matrix)(R))))
