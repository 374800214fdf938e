"""jtraj: JAX-native, differentiable trajectory optimization for legged and humanoid robots."""

import os as _os
import sys as _sys

# Single-threaded OpenBLAS unless the user says otherwise (set before jax/scipy load it). The
# LAPACK kernels jax calls on the CPU are small (one knot's blocks); OpenBLAS's threads only
# contend for the cores: measured on a loaded 2-core machine, a 66 x 66 triangular solve took
# 90 ms with its default threads and 0.12 ms with one.
_os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax as _jax  # noqa: E402

# MuJoCo picks its OpenGL backend when imported: without a display, software EGL (Mesa's
# llvmpipe) lets jtraj.render draw offscreen, or OSMesa; where neither loads, none (drawing
# then says what to install; EGL set without its library broke `import mujoco` itself). An
# explicit MUJOCO_GL is left alone.
if _sys.platform.startswith("linux") and not _os.environ.get("DISPLAY") and not _os.environ.get("WAYLAND_DISPLAY") and "MUJOCO_GL" not in _os.environ:
    from jtraj import _gl

    _gl.chosen = _os.environ["MUJOCO_GL"] = _gl.headless_backend()

# All numerics in float64: interior-point solves and Lie-group series need the digits.
_jax.config.update("jax_enable_x64", True)

# One JAX CPU device per core (before JAX starts its backends): a vmapped jtraj solve on the
# CPU splits its batch over them in one program. Measured on 2 cores, big_jump's 10 noisy
# replicates vmapped: 11.4 to 13.1 s on two devices, 17.8 s on one (docs/measurements.md,
# `results/replicates_cpu_split/`).
from jtraj import config as _config  # noqa: E402

try:
    _config.split_cpu()
except ValueError as _error:  # a bad JTRAJ_CPU_DEVICES
    # The command line imports this package before its main() can catch anything: every
    # command, --help too, ended in a traceback. It gets the one line of any bad input and
    # exit status 2 (jtraj.cli.EXIT_BAD_INPUT); `import jtraj` from Python still raises.
    if _config._runs_the_command_line():
        print(f"jtraj: {_error}", file=_sys.stderr)
        raise SystemExit(2) from None
    raise
del _config  # jtraj.config stays; help(jtraj) listed the alias as a submodule of its own

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

_LAZY = {"solve": ("jtraj.solver", "solve"), "Result": ("jtraj.result", "Result"), "load_task": ("jtraj.task", "load"), "load_robot": ("jtraj.robot", "load"), "TaskParams": ("jtraj.transcription", "TaskParams"), "differentiable": ("jtraj.differentiate", "differentiable"), "OptimalMotion": ("jtraj.differentiate", "OptimalMotion")}


def _submodules() -> frozenset[str]:
    """The names of the package's modules and subpackages (from its folder, nothing imported)."""
    import pkgutil

    return frozenset(info.name for info in pkgutil.iter_modules(__path__))


def __getattr__(name: str):
    """The names imported on first use (solve, Result, load_task, load_robot, TaskParams,
    differentiable, OptimalMotion, render): they pull in MuJoCo and the robots. The package's
    submodules too (``jtraj.solvers``, ``jtraj.task``...): they were an AttributeError after
    ``import jtraj`` until something else had imported them."""
    import importlib

    if name in _LAZY:
        module, attr = _LAZY[name]
        return getattr(importlib.import_module(module), attr)
    if not name.startswith("_") and name in _submodules():  # jtraj.render too, callable as its render()
        return importlib.import_module(f"jtraj.{name}")
    raise AttributeError(f"module 'jtraj' has no attribute {name!r}")


def __dir__() -> list[str]:
    """The module's names and the lazily imported ones, for dir(jtraj), completion and help."""
    return sorted(set(globals()) | set(__all__))

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
    "solve",
    "Result",
    "load_task",
    "load_robot",
    "TaskParams",
    "differentiable",
    "OptimalMotion",
    "render",
]
