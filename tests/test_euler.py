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
