"""Quaternion calculus of "Planning with Attitude" (Jackson, Tracy and Manchester, RA-L 2021).

Quaternions are plain arrays ``q = [q_s, q_v]`` (scalar first, "wxyz", Hamilton product),
the convention of the paper, of MuJoCo and of jaxlie's ``SO3.wxyz``. Equation numbers refer
to that paper. Functions take one quaternion (shape (4,)) unless a
docstring says otherwise; use `jax.vmap` for batches.

Three printed equations of the paper carry slips that this module does not copy; the
functions here equal the autodiff expressions stated in their docstrings, and the tests
check exactly those expressions:

- eq. 15: the second-order term of the Cayley map is ``-|phi|^2 / 2 q``, so the Hessian
  correction is ``G^T (d2h/dq2) G - (dh/dq q) I3`` (printed with ``+``);
- eq. 41: the gradient of ``1 - |q_g^T q|`` is ``-sign(q_g^T q) q_g^T G(q)`` (printed
  without the minus). Eq. 42 as printed is right;
- eq. 38: the Cayley map's inverse has the Jacobian ``[-q_v / q_s^2, I3 / q_s]``; as printed,
  ``-1/q_s^2 [q_v, -(1/q_s) I3]``, its vector block would be ``I3 / q_s^3``
  (`cayley_inv_jacobian`; a review's check against ``jax.jacfwd``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jtraj.lie import skew
from jtraj.numbers import shaped

__all__ = [
    "H",
    "T",
    "L",
    "R",
    "multiply",
    "conjugate",
    "rotation_matrix",
    "rotate",
    "attitude_jacobian",
    "cayley",
    "cayley_inv",
    "cayley_inv_jacobian",
    "multiplicative_update",
    "jacobian_correction",
    "hessian_correction",
    "quaternion_jacobian_correction",
    "error_state_jacobian",
    "geodesic_cost",
    "geodesic_cost_gradient",
    "geodesic_cost_hessian",
]

#: ``H = [0; I3]`` (eq. 8): embeds a 3-vector as a pure quaternion, ``r^ = H r``.
H = jnp.vstack([jnp.zeros((1, 3)), jnp.eye(3)])

#: ``T = diag(1, -1, -1, -1)`` (eq. 5): conjugation, ``q* = T q``.
T = jnp.diag(jnp.array([1.0, -1.0, -1.0, -1.0]))


def L(q: jax.Array) -> jax.Array:
    """Left-multiplication matrix (eq. 2): ``q (x) p = L(q) p``; (4,) -> (4, 4)."""
    q = shaped(q, (4,), "q (a quaternion)")
    s, v = q[0], q[1:]
    top = jnp.concatenate([s[None], -v])[None, :]
    bottom = jnp.concatenate([v[:, None], s * jnp.eye(3) + skew(v)], axis=1)
    return jnp.concatenate([top, bottom], axis=0)


def R(q: jax.Array) -> jax.Array:
    """Right-multiplication matrix (eq. 3): ``p (x) q = R(q) p``; (4,) -> (4, 4)."""
    q = shaped(q, (4,), "q (a quaternion)")
    s, v = q[0], q[1:]
    top = jnp.concatenate([s[None], -v])[None, :]
    bottom = jnp.concatenate([v[:, None], s * jnp.eye(3) - skew(v)], axis=1)
    return jnp.concatenate([top, bottom], axis=0)


def multiply(q1: jax.Array, q2: jax.Array) -> jax.Array:
    """Hamilton product ``q1 (x) q2 = L(q1) q2`` (eq. 1)."""
    return L(q1) @ shaped(q2, (4,), "q2 (a quaternion)")


def conjugate(q: jax.Array) -> jax.Array:
    """``q* = T q``, the inverse of a unit quaternion (eq. 5)."""
    return T @ shaped(q, (4,), "q (a quaternion)")


def rotation_matrix(q: jax.Array) -> jax.Array:
    """``A(q) = H^T L(q) R(q)^T H`` (eq. 9): body-to-world rotation of a unit quaternion."""
    return H.T @ L(q) @ R(q).T @ H


def rotate(q: jax.Array, r: jax.Array) -> jax.Array:
    """``A(q) r``, the rotation of the 3-vector r."""
    return rotation_matrix(q) @ shaped(r, (3,), "r (a 3-vector)")


def attitude_jacobian(q: jax.Array) -> jax.Array:
    """Attitude Jacobian ``G(q) = L(q) H`` (eq. 14); (4,) -> (4, 3).

    Equals ``jax.jacfwd(lambda phi: L(q) @ cayley(phi))(zeros(3))``.
    """
    return L(q) @ H


def cayley(phi: jax.Array) -> jax.Array:
    """Cayley map (eq. 11): Rodrigues parameters to a unit quaternion, ``[1; phi] / sqrt(1+|phi|^2)``."""
    phi = shaped(phi, (3,), "phi (Rodrigues parameters)")
    return jnp.concatenate([jnp.ones(1, phi.dtype), phi]) / jnp.sqrt(1.0 + phi @ phi)


def cayley_inv(q: jax.Array) -> jax.Array:
    """Inverse Cayley map (eq. 12): ``q_v / q_s``; singular at rotation angle pi (q_s = 0)."""
    q = shaped(q, (4,), "q (a quaternion)")
    return q[1:] / q[0]


def cayley_inv_jacobian(q: jax.Array) -> jax.Array:
    """``D(q) = d cayley_inv / dq = [-q_v / q_s^2, I3 / q_s]`` (eq. 38 as corrected in the
    module docstring); (4,) -> (3, 4)."""
    q = shaped(q, (4,), "q (a quaternion)")
    s = q[0]
    return jnp.concatenate([-q[1:, None] / s**2, jnp.eye(3) / s], axis=1)


def multiplicative_update(q: jax.Array, phi: jax.Array) -> jax.Array:
    """The multiplicative step ``q (x) cayley(phi) = L(q) cayley(phi)`` (Algorithm 2, line 5)."""
    return L(q) @ cayley(phi)


def jacobian_correction(dh_dq: jax.Array, q: jax.Array) -> jax.Array:
    """Jacobian of ``h(q)`` with respect to a rotation, ``dh/dq G(q)`` (eq. 14).

    ``dh_dq`` has shape (p, 4) (or (4,) for scalar h). Equals
    ``jax.jacfwd(lambda phi: h(L(q) @ cayley(phi)))(zeros(3))``.
    """
    return dh_dq @ attitude_jacobian(q)


def hessian_correction(d2h_dq2: jax.Array, dh_dq: jax.Array, q: jax.Array) -> jax.Array:
    """Hessian of scalar ``h(q)`` with respect to a rotation (eq. 15, sign corrected).

    ``G^T (d2h/dq2) G - (dh/dq . q) I3``; equals
    ``jax.hessian(lambda phi: h(L(q) @ cayley(phi)))(zeros(3))``.
    """
    G = attitude_jacobian(q)
    return G.T @ d2h_dq2 @ G - (dh_dq @ q) * jnp.eye(3)


def quaternion_jacobian_correction(df_dq: jax.Array, q: jax.Array, q_out: jax.Array) -> jax.Array:
    """Jacobian of a quaternion-valued ``q' = f(q)`` in error coordinates (eq. 18).

    ``G(q')^T (df/dq) G(q)``, with ``q' = f(q)``; equals
    ``jax.jacfwd(lambda phi: cayley_inv(L(q').T @ f(L(q) @ cayley(phi))))(zeros(3))``.
    """
    return attitude_jacobian(q_out).T @ df_dq @ attitude_jacobian(q)


def error_state_jacobian(x: jax.Array) -> jax.Array:
    """Error-state Jacobian ``E(x)`` (eq. 25) of a rigid-body state ``x = [r, q, rest]``.

    Shape (nx,) -> (nx, nx - 1): ``blockdiag(I3, G(q), I)``, so that ``E^T (df/dx) E`` is a
    Jacobian in the error state ``[dr, phi, d rest]``; for ``x = [r, q, v, omega]`` (13,) ->
    (13, 12). (It was (13, 12) for every state, also a 23-state spacecraft's.)
    """
    x = jnp.asarray(x)
    if x.ndim != 1 or x.shape[0] < 7:
        raise ValueError(f"x (a state [r, q, ...]) must have shape (nx,) with nx >= 7, got {x.shape} (one at a time: use jax.vmap for batches)")
    nx = x.shape[0]
    q = x[3:7]
    E = jnp.zeros((nx, nx - 1), x.dtype if jnp.issubdtype(x.dtype, jnp.floating) else float)
    E = E.at[0:3, 0:3].set(jnp.eye(3))
    E = E.at[3:7, 3:6].set(attitude_jacobian(q))
    E = E.at[7:, 6:].set(jnp.eye(nx - 7))
    return E


def geodesic_cost(q: jax.Array, q_goal: jax.Array) -> jax.Array:
    """Geodesic attitude cost ``1 - |q_g^T q|`` (eq. 40), invariant under ``q -> -q``."""
    q, q_goal = shaped(q, (4,), "q (a quaternion)"), shaped(q_goal, (4,), "q_goal (a quaternion)")
    return 1.0 - jnp.abs(q_goal @ q)


def geodesic_cost_gradient(q: jax.Array, q_goal: jax.Array) -> jax.Array:
    """Gradient of eq. 40 with respect to a rotation: ``-sign(q_g^T q) q_g^T G(q)`` (eq. 41).

    Equals ``jax.grad(lambda phi: geodesic_cost(L(q) @ cayley(phi), q_goal))(zeros(3))``,
    also at ``q_g^T q = 0`` (q half a turn from the goal, the cost's maximum), where the
    sign is taken as +1 as JAX's derivative of ``abs`` takes it: ``sign(0) = 0`` would give a
    zero gradient there, a stationary point for a gradient method at the worst attitude.
    """
    q, q_goal = shaped(q, (4,), "q (a quaternion)"), shaped(q_goal, (4,), "q_goal (a quaternion)")
    sign = jnp.where(q_goal @ q >= 0, 1.0, -1.0)
    return -sign * (q_goal @ attitude_jacobian(q))


def geodesic_cost_hessian(q: jax.Array, q_goal: jax.Array) -> jax.Array:
    """Hessian of eq. 40 with respect to a rotation: ``sign(q_g^T q) (q_g^T q) I3`` (eq. 42).

    Equals ``jax.hessian(lambda phi: geodesic_cost(L(q) @ cayley(phi), q_goal))(zeros(3))``.
    """
    q, q_goal = shaped(q, (4,), "q (a quaternion)"), shaped(q_goal, (4,), "q_goal (a quaternion)")
    return jnp.abs(q_goal @ q) * jnp.eye(3)
