"""SO(3) and SE(3) calculus on top of jaxlie.

jaxlie provides the groups themselves (storage `SO3.wxyz`, `SE3.wxyz_xyz`), `exp`,
composition (`@`), `inverse`, the action on points (`T @ p`) and the adjoint; `log` is computed
here (jaxlie's SO(3) log has a wrong derivative within 2e-10 rad of angle pi).
This module adds what jaxlie does not have, in the notation of Sola et al., "A micro Lie
theory for state estimation in robotics" (arXiv:1812.01537):

- the right and left Jacobians and their inverses for SO(3) and SE(3), as closed forms,
- the plus and minus operators  ``T (+) xi = T Exp(xi)``  and
  ``T2 (-) T1 = Log(T1^-1 T2)``.

Tangent vectors of SE(3) are ordered translation first, ``xi = (rho, theta)``, the same as
jaxlie's and Pinocchio's motion vectors (linear, angular).

Every function is pure JAX, works on batches through leading axes or `jax.vmap`, and is
free of NaN in values and gradients at the identity and at rotation angle pi.
"""

from __future__ import annotations

from typing import TypeVar

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike
from jaxlie import SE3, SO3

__all__ = [
    "SE3",
    "SO3",
    "skew",
    "exp",
    "log",
    "compose",
    "inverse",
    "act",
    "adjoint",
    "plus",
    "minus",
    "right_jacobian",
    "left_jacobian",
    "right_jacobian_inv",
    "left_jacobian_inv",
    "accumulated_rotation",
    "rotation_steps",
]

Group = TypeVar("Group", SO3, SE3)

# Below this angle the closed forms lose digits to cancellation; series are used instead.
# The series below are exact to ~1e-17 for angles under the threshold.
_SMALL_ANGLE = 0.05


def skew(v: jax.Array) -> jax.Array:
    """Skew-symmetric matrix ``[v]x`` with ``[v]x w = v x w``; shape (..., 3) -> (..., 3, 3)."""
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    zero = jnp.zeros_like(x)
    return jnp.stack(
        [
            jnp.stack([zero, -z, y], axis=-1),
            jnp.stack([z, zero, -x], axis=-1),
            jnp.stack([-y, x, zero], axis=-1),
        ],
        axis=-2,
    )


def _tangent(group: type, tangent: ArrayLike) -> jax.Array:
    """``tangent`` as a float array whose last axis is the group's tangent size (ValueError
    otherwise: a wrong size would be read past its end, which JAX clamps silently)."""
    tangent = jnp.asarray(tangent)
    dim = getattr(group, "tangent_dim", None)
    if dim is not None and (tangent.ndim == 0 or tangent.shape[-1] != dim):
        raise ValueError(f"a {group.__name__} tangent must have {dim} entries on its last axis, got shape {tangent.shape}")
    if not jnp.issubdtype(tangent.dtype, jnp.floating):
        tangent = tangent.astype(float)
    return tangent


def exp(group: type[Group], tangent: jax.Array) -> Group:
    """Exponential map ``Exp: R^3 -> SO(3)`` or ``R^6 -> SE(3)``.

    SO(3) is jaxlie's. SE(3) is computed here as ``(Exp(theta), J_l(theta) rho)``:
    jaxlie 1.5.0's ``SE3.exp`` uses the rotation matrix in place of ``J_l`` for angles
    below 1e-5, which is wrong to first order (translation off by ``theta x rho / 2``, and
    its derivative at the identity off by a factor 2).
    """
    tangent = _tangent(group, tangent)
    if group is SE3:
        rho, theta = tangent[..., :3], tangent[..., 3:]
        translation = jnp.einsum("...ij,...j->...i", _so3_left_jacobian(theta), rho)
        return SE3.from_rotation_and_translation(SO3.exp(theta), translation)  # type: ignore[return-value]  # Group is SE3 here
    return group.exp(tangent)


def log(element: SO3 | SE3) -> jax.Array:
    """Logarithm map ``Log: SO(3) -> R^3`` or ``SE(3) -> R^6``, the inverse of `exp`
    for rotation angles below pi, with its derivatives also there and at pi.

    The SO(3) part is computed here (`_so3_log`): jaxlie 1.5.0's ``SO3.log`` returns
    ``pi v / |v|`` where ``|w| < 1e-10``, which does not depend on w, so its derivative along
    the rotation's own axis was 0 instead of 1 within about 2e-10 rad of pi (a review's
    finding: the flip and handstand warm starts put knots at exactly pi, where the SE(3)
    tangent chart's dynamics rows had a Jacobian of rank 5 in place of 6)."""
    if isinstance(element, SE3):
        theta = _so3_log(element.rotation().wxyz)
        rho = jnp.einsum("...ij,...j->...i", _so3_left_jacobian_inv(theta), element.translation())
        return jnp.concatenate([rho, theta], axis=-1)
    return _so3_log(element.wxyz)


def _so3_log(wxyz: jax.Array) -> jax.Array:
    """``Log`` of unit quaternions (..., 4) wxyz: ``2 atan2(|v|, w) v / |v|`` on the shorter
    way round (``w >= 0``: q and -q are one rotation), smooth up to and at angle pi (atan2
    has no special case at ``w = 0``), and its Taylor series ``(2 / w - 2 |v|^2 / (3 w^3)) v``
    where ``|v|^2`` is below jaxlie's threshold for the dtype (1e-10 in float64)."""
    w, v = wxyz[..., 0], wxyz[..., 1:]
    flip = jnp.where(w < 0, -1.0, 1.0).astype(wxyz.dtype)
    w, v = w * flip, v * flip[..., None]
    n2 = jnp.sum(v * v, axis=-1)
    small = n2 < (1e-10 if wxyz.dtype == jnp.float64 else 1e-5)
    n = jnp.sqrt(jnp.where(small, 1.0, n2))  # (one branch each: no NaN in the other's derivative)
    w_small = jnp.where(small, w, 1.0)
    scale = jnp.where(small, 2.0 / w_small - (2.0 / 3.0) * n2 / w_small**3, 2.0 * jnp.arctan2(n, w) / n)
    return scale[..., None] * v


def compose(a: Group, b: Group) -> Group:
    """Group composition ``a b``."""
    return a @ b


def inverse(element: Group) -> Group:
    """Group inverse."""
    return element.inverse()


def act(element: SO3 | SE3, point: jax.Array) -> jax.Array:
    """Action on a point of R^3: ``R p`` or ``R p + t``."""
    return element @ point


def adjoint(element: SO3 | SE3) -> jax.Array:
    """Adjoint matrix, ``Ad_T xi = Log(T Exp(xi) T^-1)`` to first order (jaxlie)."""
    return element.adjoint()


def plus(element: Group, tangent: jax.Array) -> Group:
    """Right plus: ``T (+) xi = T Exp(xi)`` (Sola eq. 25)."""
    return element @ exp(type(element), tangent)


def minus(element2: Group, element1: Group) -> jax.Array:
    """Right minus: ``T2 (-) T1 = Log(T1^-1 T2)`` (Sola eq. 26)."""
    return log(element1.inverse() @ element2)


# ----------------------------------------------------------------------------------------
# Scalar coefficient functions of the rotation angle, safe at 0 (series) and at pi.


def _angle(theta_vec: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Returns (theta^2, a safe theta for the closed forms, small-angle mask)."""
    theta_sq = jnp.sum(jnp.square(theta_vec), axis=-1)
    small = theta_sq < _SMALL_ANGLE**2
    # The closed-form branch is evaluated with a harmless value where it is not used, so
    # that neither it nor its gradient produces NaN (the jnp.where gradient trap).
    theta_safe = jnp.sqrt(jnp.where(small, 1.0, theta_sq))
    return theta_sq, theta_safe, small


def _coefficients_a_b(theta_vec: jax.Array) -> tuple[jax.Array, jax.Array]:
    """a = (1 - cos t) / t^2 and b = (t - sin t) / t^3."""
    t2, t, small = _angle(theta_vec)
    a = jnp.where(
        small,
        0.5 - t2 / 24.0 + t2**2 / 720.0 - t2**3 / 40320.0,
        (1.0 - jnp.cos(t)) / t**2,
    )
    b = jnp.where(
        small,
        1.0 / 6.0 - t2 / 120.0 + t2**2 / 5040.0 - t2**3 / 362880.0,
        (t - jnp.sin(t)) / t**3,
    )
    return a, b


def _coefficient_c(theta_vec: jax.Array) -> jax.Array:
    """c = 1/t^2 - (1 + cos t) / (2 t sin t) = 1/t^2 - cot(t/2) / (2 t).

    Written with cot(t/2) so that it is finite at t = pi (it blows up only at 2 pi, where
    the inverse Jacobians are genuinely singular).
    """
    t2, t, small = _angle(theta_vec)
    half = 0.5 * t
    return jnp.where(
        small,
        1.0 / 12.0 + t2 / 720.0 + t2**2 / 30240.0 + t2**3 / 1209600.0,
        1.0 / t**2 - jnp.cos(half) / (2.0 * t * jnp.sin(half)),
    )


def _so3_left_jacobian(theta_vec: jax.Array) -> jax.Array:
    a, b = _coefficients_a_b(theta_vec)
    K = skew(theta_vec)
    return jnp.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K)


def _so3_left_jacobian_inv(theta_vec: jax.Array) -> jax.Array:
    c = _coefficient_c(theta_vec)
    K = skew(theta_vec)
    return jnp.eye(3) - 0.5 * K + c[..., None, None] * (K @ K)


def _se3_q_left(rho: jax.Array, theta_vec: jax.Array) -> jax.Array:
    """The coupling block Q(rho, theta) of the SE(3) left Jacobian (Barfoot eq. 7.86)."""
    t2, t, small = _angle(theta_vec)
    a, b = _coefficients_a_b(theta_vec)
    # d = (t^2/2 + cos t - 1) / t^4 = (1/2 - a) / t^2
    d = jnp.where(
        small,
        1.0 / 24.0 - t2 / 720.0 + t2**2 / 40320.0 - t2**3 / 3628800.0,
        (0.5 - a) / t**2,
    )
    # e = 1/2 (d + 3 (t - sin t - t^3/6) / t^5) = 1/2 (d + 3 (b - 1/6) / t^2)
    e = jnp.where(
        small,
        1.0 / 120.0 - t2 / 2520.0 + t2**2 / 120960.0 - t2**3 / 9979200.0,
        0.5 * (d + 3.0 * (b - 1.0 / 6.0) / t**2),
    )
    P = skew(theta_vec)
    R = skew(rho)
    PR = P @ R
    RP = R @ P
    PRP = PR @ P
    return (
        0.5 * R
        + b[..., None, None] * (PR + RP + PRP)
        + d[..., None, None] * (P @ PR + RP @ P - 3.0 * PRP)
        + e[..., None, None] * (PRP @ P + P @ PRP)
    )


def _se3_left_jacobian(xi: jax.Array) -> jax.Array:
    rho, theta_vec = xi[..., :3], xi[..., 3:]
    J = _so3_left_jacobian(theta_vec)
    Q = _se3_q_left(rho, theta_vec)
    zero = jnp.zeros_like(J)
    top = jnp.concatenate([J, Q], axis=-1)
    bottom = jnp.concatenate([zero, J], axis=-1)
    return jnp.concatenate([top, bottom], axis=-2)


def _se3_left_jacobian_inv(xi: jax.Array) -> jax.Array:
    rho, theta_vec = xi[..., :3], xi[..., 3:]
    Jinv = _so3_left_jacobian_inv(theta_vec)
    Q = _se3_q_left(rho, theta_vec)
    zero = jnp.zeros_like(Jinv)
    top = jnp.concatenate([Jinv, -Jinv @ Q @ Jinv], axis=-1)
    bottom = jnp.concatenate([zero, Jinv], axis=-1)
    return jnp.concatenate([top, bottom], axis=-2)


_LEFT = {SO3: _so3_left_jacobian, SE3: _se3_left_jacobian}
_LEFT_INV = {SO3: _so3_left_jacobian_inv, SE3: _se3_left_jacobian_inv}


def _check_group(group: type) -> None:
    if group not in _LEFT:
        raise TypeError(f"expected jaxlie.SO3 or jaxlie.SE3, got {group!r}")


def left_jacobian(group: type[SO3] | type[SE3], tangent: jax.Array) -> jax.Array:
    """Left Jacobian ``J_l(xi)``: ``Exp(xi + d) = Exp(J_l d) Exp(xi)`` to first order.

    Equals ``jax.jacfwd(lambda d: log(exp(G, xi + d) @ exp(G, xi).inverse()))(0)``.
    Shape (..., n) -> (..., n, n) with n = 3 (SO3) or 6 (SE3).
    """
    _check_group(group)
    return _LEFT[group](_tangent(group, tangent))


def right_jacobian(group: type[SO3] | type[SE3], tangent: jax.Array) -> jax.Array:
    """Right Jacobian ``J_r(xi) = J_l(-xi)``: ``Exp(xi + d) = Exp(xi) Exp(J_r d)``.

    Equals ``jax.jacfwd(lambda d: log(exp(G, xi).inverse() @ exp(G, xi + d)))(0)``; for SE3
    it is Pinocchio's ``Jexp6``.
    """
    _check_group(group)
    tangent = _tangent(group, tangent)
    return _LEFT[group](-tangent)


def left_jacobian_inv(group: type[SO3] | type[SE3], tangent: jax.Array) -> jax.Array:
    """Inverse of the left Jacobian, finite for rotation angles below 2 pi."""
    _check_group(group)
    tangent = _tangent(group, tangent)
    return _LEFT_INV[group](tangent)


def right_jacobian_inv(group: type[SO3] | type[SE3], tangent: jax.Array) -> jax.Array:
    """Inverse of the right Jacobian: ``Log(Exp(xi) Exp(d)) = xi + J_r^-1(xi) d``.

    Equals ``jax.jacfwd(lambda d: log(exp(G, xi) @ exp(G, d)))(0)`` for rotation angles up to
    pi, and jaxlie's ``SO3.exp(xi).jlog()`` below pi (jaxlie's ``SE3.jlog`` is off at small
    angles: 1.2e-6 at 1e-5 rad, a review's measurement).
    """
    _check_group(group)
    tangent = _tangent(group, tangent)
    return _LEFT_INV[group](-tangent)


def accumulated_rotation(wxyz: ArrayLike, frame: str = "world") -> jax.Array:
    """Rotation accumulated along a sequence of attitudes (rad): (N, 4) wxyz -> (N, 3).

    Sums the increments ``Log(R_{k+1} R_k^T)`` (world frame, default) or ``Log(R_k^T R_{k+1})``
    (``frame="body"``), starting from zero, so that a full flip about a fixed axis reads as the
    axis times 2 pi where ``Log`` of the end attitude alone would read 0. Each step must stay
    below pi for its direction to be seen. Inputs need not be unit quaternions (they are
    normalized first); `rotation_steps` says what they must be.
    """
    steps = rotation_steps(wxyz, frame)
    return jnp.concatenate([jnp.zeros((1, 3), steps.dtype), jnp.cumsum(steps, axis=0)])


def rotation_steps(wxyz: ArrayLike, frame: str = "world") -> jax.Array:
    """The increments of `accumulated_rotation`: (N, 4) wxyz -> (N - 1, 3) rad,
    ``Log(R_{k+1} R_k^T)`` (``"world"``) or ``Log(R_k^T R_{k+1})`` (``"body"``).

    One sequence (N, 4), N >= 1, not a batch of them (unlike the rest of this module). A zero
    quaternion, which is no attitude, gives NaN steps on either side of it (the callers, e.g.
    `jtraj.success`, read NaN as no motion to check)."""
    if frame not in ("world", "body"):
        raise ValueError(f"frame must be 'world' or 'body', got {frame!r}")
    q = jnp.asarray(wxyz)
    if q.ndim != 2 or q.shape[0] < 1 or q.shape[1] != 4:  # (they failed deep in jaxlie or numpy)
        raise ValueError(f"wxyz must be a sequence of quaternions of shape (N, 4), N >= 1, got {q.shape}")
    q = q / jnp.linalg.norm(q, axis=-1, keepdims=True)
    a, b = SO3(q[1:]), SO3(q[:-1])
    return log(a @ b.inverse()) if frame == "world" else log(b.inverse() @ a)
