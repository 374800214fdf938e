"""What counts as a number in an argument check, and the length of a user's vector.

Python's ``bool`` is an ``int``, so ``isinstance(True, int)`` holds; every check of a user's
count, size, rate or angle refuses it, and takes numpy's scalars as Python's.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["is_real", "is_whole", "is_seed", "unit_and_length", "shaped"]


def is_real(value: Any) -> bool:
    """A Python or numpy integer or float (not a bool); it may still be NaN or infinite."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


def is_whole(value: Any) -> bool:
    """A Python or numpy integer (not a bool)."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def is_seed(value: Any) -> bool:
    """A whole number that JAX's ``PRNGKey`` takes: 64 bits, below 2**63 in magnitude (a larger
    one raises OverflowError where the noise is drawn, after the NLP has compiled)."""
    return is_whole(value) and -(2**63) <= value < 2**63


def unit_and_length(vector: Any) -> tuple[np.ndarray, float]:
    """``vector / |vector|`` and ``|vector|`` of finite numbers, both computed from the vector
    scaled by its largest component, so that the squares neither overflow ([1e200, 1e200, 0]:
    an infinite length unscaled) nor underflow ([1e-200, 0, 0]: 0); ``(vector, 0.0)`` for a
    zero vector."""
    a = np.asarray(vector, float)
    scale = float(np.max(np.abs(a))) if a.size else 0.0
    if scale == 0.0:
        return a, 0.0
    a = a / scale
    norm = float(np.linalg.norm(a))
    return a / norm, scale * norm


def shaped(value: Any, shape: tuple[int, ...], what: str) -> Any:
    """``value`` as a JAX float array of exactly ``shape`` (one quaternion, one 3-vector...),
    else a ValueError naming ``what``: the quaternion and Euler-angle functions index their
    arguments (``q[0]``, ``rpy[2]``), and JAX clamps an index past the end without a word (a
    2-vector of angles gave a rotation with yaw = pitch). Shapes are static under ``jit``,
    so the check costs nothing there; batches go through ``jax.vmap``."""
    import jax.numpy as jnp

    array = jnp.asarray(value)
    if array.shape != shape:
        batch = " (one at a time: use jax.vmap for batches)" if array.ndim > len(shape) and array.shape[-len(shape) :] == shape else ""
        raise ValueError(f"{what} must have shape {shape}, got {array.shape}{batch}")
    return array if jnp.issubdtype(array.dtype, jnp.floating) else array.astype(float)
