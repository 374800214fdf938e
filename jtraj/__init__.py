"""jtraj: JAX-native, differentiable trajectory optimization for legged and humanoid robots."""

import jax as _jax

# All numerics in float64: interior-point solves and Lie-group series need the digits.
_jax.config.update("jax_enable_x64", True)

from jtraj import euler, lie, parameterization, quaternion  # noqa: E402
from jtraj.parameterization import (  # noqa: E402
    PARAMETERIZATIONS,
    AbstractParameterization,
    EulerRPY,
    Quaternion1,
    Quaternion2,
    Quaternion3,
    SE3Tangent,
)

__version__ = "0.1.0"

__all__ = [
    "euler",
    "lie",
    "parameterization",
    "quaternion",
    "PARAMETERIZATIONS",
    "AbstractParameterization",
    "EulerRPY",
    "Quaternion1",
    "Quaternion2",
    "Quaternion3",
    "SE3Tangent",
]
