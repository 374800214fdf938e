"""MuJoCo's OpenGL backend where there is no display, chosen by ``import jtraj`` before MuJoCo
is imported (MuJoCo reads ``MUJOCO_GL`` once, then).

EGL (Mesa's llvmpipe, or a GPU's driver) draws offscreen without a display; OSMesa too. Where
neither library loads, MuJoCo's ``MUJOCO_GL=egl`` made ``import mujoco`` itself fail (PyOpenGL
raised AttributeError), and with it every command that loads a robot, drawing or not; jtraj
then sets ``disable``, so only drawing fails, with a `jtraj.render.RenderError` saying what to
install.
"""

from __future__ import annotations

import ctypes
from collections.abc import Callable

__all__ = ["chosen", "headless_backend"]

#: what `headless_backend` chose in this process (None: MUJOCO_GL was set, or a display is there)
chosen: str | None = None


def _loads(name: str) -> bool:
    """Whether ``lib<name>`` loads as PyOpenGL loads it on Linux: ``lib<name>.so``, then
    ``.so.9`` down to ``.so.0``."""
    for filename in (f"lib{name}.so", *(f"lib{name}.so.{i}" for i in range(9, -1, -1))):
        try:
            ctypes.CDLL(filename)
            return True
        except OSError:
            continue
    return False


def headless_backend(loads: Callable[[str], bool] = _loads) -> str:
    """``"egl"`` where libEGL and an OpenGL library (libOpenGL or libGL) load, else
    ``"osmesa"`` where libOSMesa loads, else ``"disable"`` (MuJoCo without OpenGL)."""
    if loads("EGL") and (loads("OpenGL") or loads("GL")):
        return "egl"
    if loads("OSMesa"):
        return "osmesa"
    return "disable"
