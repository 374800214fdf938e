"""Roll-pitch-yaw Euler angles, as in the comparative study (eqs. 5-6).

``rpy = (phi, theta, psi)`` are roll, pitch and yaw in radians, with
``R(rpy) = Rz(psi) Ry(theta) Rx(phi)`` the body-to-world rotation. The chart is singular at
``theta = +-pi/2`` (gimbal lock), where `rate_matrix` is undefined.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jtraj.numbers import shaped

__all__ = ["GIMBAL_MARGIN", "rotation_matrix", "from_rotation_matrix", "rate_matrix", "away_from_gimbal_lock"]

#: Smallest distance (rad) of a pitch from +-pi/2 that `away_from_gimbal_lock` allows: there
#: |W| <= 1 / sin(margin) ~ 1e3 instead of ~1e16 at the singularity in floating point.
GIMBAL_MARGIN = 1e-3


def _rx(a: jax.Array) -> jax.Array:
    c, s = jnp.cos(a), jnp.sin(a)
    return jnp.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _ry(a: jax.Array) -> jax.Array:
    c, s = jnp.cos(a), jnp.sin(a)
    return jnp.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rz(a: jax.Array) -> jax.Array:
    c, s = jnp.cos(a), jnp.sin(a)
    return jnp.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_matrix(rpy: jax.Array) -> jax.Array:
    """``Rz(psi) Ry(theta) Rx(phi)`` (eq. 5); (3,) -> (3, 3)."""
    rpy = shaped(rpy, (3,), "rpy (roll, pitch, yaw)")
    return _rz(rpy[2]) @ _ry(rpy[1]) @ _rx(rpy[0])


#: Below this cos(pitch) `from_rotation_matrix` takes the yaw from the roll (see there): the two
#: arctan2 of entries of size cos(pitch) lose a factor of about 1 / cos(pitch) to rounding (the
#: round trip of a rotation matrix from a quaternion: 3.5e-10 at cos 1e-6, where the threshold
#: was, 5e-14 just above 1e-2), the yaw from the roll stays within 1e-15 at any pitch. Above
#: it the result is the one it was (the study's runs' warm starts rarely come this close).
_LOCK_COS = 1e-2


def from_rotation_matrix(Rm: jax.Array) -> jax.Array:
    """Inverse of `rotation_matrix` with pitch in [-pi/2, pi/2]; (3, 3) -> (3,).

    At gimbal lock only yaw - roll (pitch pi/2) or yaw + roll (pitch -pi/2) is determined:
    there the roll is read as elsewhere and the yaw is computed from it, so that
    ``rotation_matrix(from_rotation_matrix(Rm)) == Rm`` holds at the lock too.
    """
    Rm = shaped(Rm, (3, 3), "Rm (a rotation matrix)")
    # exactly at the lock Rm[2, 1] = Rm[2, 2] = 0: arctan2(0, 0) and sqrt(0) have NaN
    # derivatives, and the roll there is any (0, as arctan2 gives); one branch only, as in
    # jtraj.lie, so that the untaken one passes no NaN
    sq = Rm[2, 1] ** 2 + Rm[2, 2] ** 2
    away = sq > 0.0
    roll = jnp.where(away, jnp.arctan2(jnp.where(away, Rm[2, 1], 0.0), jnp.where(away, Rm[2, 2], 1.0)), 0.0)
    cos_pitch = jnp.where(away, jnp.sqrt(jnp.where(away, sq, 1.0)), 0.0)
    pitch = jnp.arctan2(-Rm[2, 0], cos_pitch)
    lock = cos_pitch < _LOCK_COS
    # (at the lock Rm[1, 0] = Rm[0, 0] = 0 too: that arctan2 is not taken there, one branch)
    yaw = jnp.arctan2(jnp.where(lock, 0.0, Rm[1, 0]), jnp.where(lock, 1.0, Rm[0, 0]))
    # Near the lock Rm[2, 1], Rm[2, 2], Rm[1, 0] and Rm[0, 0] are all ~cos(pitch): at the lock
    # they are rounding noise, and the two arctan2 give a roll and a yaw that do not belong
    # together (a pose off by up to pi). Column 1 of Rm Rx(roll)^T = Rz(yaw) Ry(pitch) is
    # (-sin yaw, cos yaw, 0) for any pitch, which gives the yaw that goes with the roll.
    sr, cr = jnp.sin(roll), jnp.cos(roll)
    yaw_from_roll = jnp.arctan2(Rm[0, 2] * sr - Rm[0, 1] * cr, Rm[1, 1] * cr - Rm[1, 2] * sr)
    yaw = jnp.where(lock, yaw_from_roll, yaw)
    return jnp.stack([roll, pitch, yaw])


def rate_matrix(rpy: jax.Array) -> jax.Array:
    """``W(theta)`` of eq. 6, mapping the body angular velocity to ``d rpy / dt``; (3,) -> (3, 3)."""
    rpy = shaped(rpy, (3,), "rpy (roll, pitch, yaw)")
    phi, theta = rpy[0], rpy[1]
    sp, cp = jnp.sin(phi), jnp.cos(phi)
    tt, ct = jnp.tan(theta), jnp.cos(theta)
    return jnp.array(
        [
            [1.0, sp * tt, cp * tt],
            [0.0, cp, -sp],
            [0.0, sp / ct, cp / ct],
        ]
    )


def away_from_gimbal_lock(rpy: jax.Array, margin: float = GIMBAL_MARGIN) -> jax.Array:
    """``rpy`` with the pitch (in [-pi/2, pi/2], as `from_rotation_matrix` returns it) clipped
    to [-pi/2 + margin, pi/2 - margin]; a rotation at most ``margin`` rad away."""
    rpy = shaped(rpy, (3,), "rpy (roll, pitch, yaw)")
    half = jnp.pi / 2 - margin
    return rpy.at[1].set(jnp.clip(rpy[1], -half, half))
