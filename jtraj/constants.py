"""Physical constants shared by the legged-robot and the rigid-body code (SI units)."""

__all__ = ["GRAVITY"]

#: Gravitational acceleration (m/s^2), along -z of the world frame; the value both papers use.
GRAVITY = 9.81
