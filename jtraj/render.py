"""Pictures of a solution: videos and keyframe strips drawn with MuJoCo's offscreen renderer.

``jtraj.render(result)`` returns the frames of a video (numpy, ``(T, H, W, 3)`` uint8) at real
time (or ``speed`` times it); `keyframe_strip` returns one image of keyframes spread along the
motion, side by side or overlaid (the paper's Fig. 1); `write_video` / `write_image` save them,
`render_directory` does both for a folder written by ``jtraj solve`` (``jtraj render DIR``).

Between knots the base pose is interpolated on SE(3) (``T_k Exp(s Log(T_k^-1 T_k+1))``) and
the joints linearly. The scene has a checker ground, contact forces drawn as arrows (a force
equal to the robot's weight, at the body masses it was solved at, twice as long as the base's
standing height), a label that marks the flight phases, and a camera that follows the base.

Headless machines: MuJoCo picks its OpenGL backend when it is imported, from ``MUJOCO_GL``.
``import jtraj`` sets ``MUJOCO_GL=egl`` when the variable is unset and there is no display, so
Mesa's software EGL (llvmpipe) draws without a GPU; ``MUJOCO_GL=osmesa`` works too where
libOSMesa is installed (jtraj takes it where libEGL does not load, and ``disable`` where
neither does: `jtraj._gl`). Writing MP4 needs ``imageio-ffmpeg`` (the ``render`` extra); GIF and
PNG are written with Pillow (a matplotlib dependency).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import sys
import threading
import types
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from jtraj import io as jio
from jtraj.numbers import is_real, is_whole

if TYPE_CHECKING:
    import mujoco

    from jtraj.result import Result
    from jtraj.transcription import Trajectory

__all__ = [
    "RenderOptions",
    "MAX_FRAMES",
    "TooManyFrames",
    "auto_azimuth",
    "RenderError",
    "render",
    "keyframe_strip",
    "keyframe_times",
    "interpolate",
    "write_video",
    "write_image",
    "show",
    "render_directory",
    "render_rigid_body",
    "render_benchmark",
    "rigid_body_model",
    "NotDrawable",
    "add_scenery",
    "Frames",
]


class RenderError(RuntimeError):
    """Rendering is not possible here; the message says what to install or set."""


#: the most video frames `render` draws: they are held in memory until written (at 640 x 480,
#: 0.9 MB each, and as much again while stacked); two minutes at 30 frames per second
MAX_FRAMES = 3600


class TooManyFrames(ValueError):
    """A video of more than `MAX_FRAMES` frames (a slow ``speed`` or a high ``fps``)."""


class NotDrawable(ValueError):
    """The result (or the folder it was loaded from) holds no legged robot's motion that can be
    drawn: no trajectory, a rigid-body benchmark's, NaN base poses or joint angles, or NaN
    contact forces where forces are drawn (`RenderOptions.forces`); the message says which.
    `render_rigid_body` raises it for a NaN path."""


@dataclasses.dataclass(frozen=True, kw_only=True)
class RenderOptions:
    """How a motion is drawn.

    Attributes:
        width, height: image size (pixels).
        fps: video frame rate (frames per second of video).
        speed: playback speed; 1 is real time, 0.25 four times slower.
        distance: camera distance to the base (m); None: from the robot's standing height and
            the motion's extent.
        azimuth, elevation: camera angles (degrees, MuJoCo's convention); azimuth 90 looks
            along +y, so motions in the x-z plane (back-flips) are seen from the side, and 180
            along -x (side-flips about x). None (the default azimuth): chosen from the motion
            (`auto_azimuth`): along the axis of a flip, else from the side of the base's travel.
        forces: draw contact forces as arrows.
        force_length: arrow length (m) of a force equal to the robot's weight; None: twice
            the standing base height (so the share of the weight on one foot clears the leg).
        label: write the time and "flight" (when no contact point touches) on each image.
        shadows: cast shadows (several times slower with software OpenGL).
    """

    width: int = 640
    height: int = 480
    fps: float = 30.0
    speed: float = 1.0
    distance: float | None = None
    azimuth: float | None = None
    elevation: float = -15.0
    forces: bool = True
    force_length: float | None = None
    label: bool = True
    shadows: bool = True

    def __post_init__(self):
        for name in ("width", "height"):
            v = getattr(self, name)
            if not is_whole(v):
                raise ValueError(f"{name} must be a whole number of pixels, got {v!r}")
        if self.width < 16 or self.height < 16:
            raise ValueError(f"image size must be at least 16x16 pixels, got {self.width}x{self.height}")
        for name in ("fps", "speed", "distance", "force_length"):
            v = getattr(self, name)
            if v is None and name in ("distance", "force_length"):
                continue
            if not is_real(v) or not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
        for name in ("azimuth", "elevation"):
            v = getattr(self, name)
            if v is None and name == "azimuth":
                continue
            if not is_real(v) or not math.isfinite(v):
                raise ValueError(f"{name} must be a finite number of degrees, got {v!r}")


# ----------------------------------------------------------------------------------------
# OpenGL backend


def _gl_setting() -> str:
    """``MUJOCO_GL`` as the messages give it, and the backend MuJoCo loaded where that is
    another: MuJoCo reads the variable once, when mujoco is first imported."""
    from mujoco import gl_context

    env = os.environ.get("MUJOCO_GL")
    context = getattr(gl_context, "GLContext", None)
    loaded = None if context is None else context.__module__.rpartition(".")[2]  # mujoco.egl, mujoco.osmesa, mujoco.glfw
    if loaded is not None and (env or "").strip().lower() in ("egl", "osmesa", "glfw") and loaded != env.strip().lower():
        return (
            f"MuJoCo's {loaded} backend (mujoco was imported before MUJOCO_GL was set to {env!r}, and reads it only then: "
            "import jtraj before mujoco, or set MUJOCO_GL before starting Python)"
        )
    return f"MUJOCO_GL={env!r}"


def _mujoco():
    """MuJoCo with an OpenGL context usable here, or a RenderError that says what to do."""
    import mujoco
    from mujoco import gl_context

    if getattr(gl_context, "GLContext", None) is None:
        from jtraj import _gl

        why = "; jtraj found neither libEGL with libOpenGL or libGL nor libOSMesa to load" if _gl.chosen == "disable" and os.environ.get("MUJOCO_GL") == "disable" else ""
        raise RenderError(
            f"MuJoCo has no OpenGL backend ({_gl_setting()}{why}); on a machine without "
            "display set MUJOCO_GL=egl (Mesa's libEGL: apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri libopengl0) or "
            "MUJOCO_GL=osmesa (apt-get install libosmesa6) before importing mujoco"
        )
    return mujoco


#: held while a renderer is made from a model whose offscreen size `_renderer` changed
_SIZING = threading.Lock()


def _renderer(model, width: int, height: int):
    """An offscreen renderer of ``width`` x ``height`` pixels. The model is shared (`scene_model`
    is cached): its offscreen size is set for this renderer's framebuffer and put back after,
    so one large (or failed) request does not size every later renderer's framebuffer. The three
    steps hold `_SIZING`, so that renderers made in several threads at once each get their own
    size (without it, one thread's put-back could land between another's set and its renderer,
    which then failed for want of framebuffer, and left the model at the other's size)."""
    with _SIZING:
        return _sized_renderer(model, width, height)


def _sized_renderer(model, width: int, height: int):
    mujoco = _mujoco()
    saved = int(model.vis.global_.offwidth), int(model.vis.global_.offheight)
    model.vis.global_.offwidth, model.vis.global_.offheight = width, height
    try:
        return mujoco.Renderer(model, height=height, width=width)
    except Exception as err:  # the GL backends raise their own error types
        if "framebuffer" in str(err).lower():  # the context opened; this size did not fit
            raise RenderError(
                f"MuJoCo could not make an offscreen framebuffer of {width}x{height} pixels with {_gl_setting()}: {err}; "
                "expected a size this OpenGL can allocate: draw smaller images (width, height)"
            ) from err
        raise RenderError(
            f"MuJoCo could not open an offscreen OpenGL context with {_gl_setting()}: {err}. "
            "Without display or GPU use MUJOCO_GL=egl with Mesa (apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri libopengl0) or "
            "MUJOCO_GL=osmesa (apt-get install libosmesa6)"
        ) from err
    finally:
        model.vis.global_.offwidth, model.vis.global_.offheight = saved


# ----------------------------------------------------------------------------------------
# Scene


def add_scenery(spec: mujoco.MjSpec, *, checker_size: float = 0.5, ground: bool = True, ground_height: float = 0.0) -> None:
    """Adds a checker ground plane (squares of ``checker_size`` m, at height ``ground_height``
    m; none if not ``ground``), a sky and a light that casts shadows to a MuJoCo spec."""
    mujoco = _mujoco()
    spec.add_texture(
        name="jtraj_sky", type=mujoco.mjtTexture.mjTEXTURE_SKYBOX, builtin=mujoco.mjtBuiltin.mjBUILTIN_GRADIENT,
        rgb1=[0.55, 0.7, 0.88], rgb2=[0.95, 0.96, 0.98], width=256, height=256,
    )
    spec.add_texture(
        name="jtraj_checker", type=mujoco.mjtTexture.mjTEXTURE_2D, builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
        rgb1=[0.82, 0.84, 0.86], rgb2=[0.64, 0.67, 0.7], width=256, height=256,
    )
    material = spec.add_material(name="jtraj_ground", texrepeat=[1.0 / (2 * checker_size)] * 2, texuniform=True)
    material.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "jtraj_checker"
    # A plane of size 0 is drawn to the horizon.
    if ground:
        spec.worldbody.add_geom(
            name="jtraj_ground", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05], pos=[0.0, 0.0, ground_height], material="jtraj_ground",
            contype=0, conaffinity=0, group=2,
        )
    spec.worldbody.add_light(
        name="jtraj_sun", type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL, pos=[0, 0, 6], dir=[0.3, 0.2, -1],
        diffuse=[0.6, 0.6, 0.6], specular=[0.1, 0.1, 0.1], castshadow=True,
    )
    spec.visual.headlight.ambient = [0.45, 0.45, 0.45]
    spec.visual.headlight.diffuse = [0.4, 0.4, 0.4]
    spec.visual.quality.shadowsize = 2048
    spec.visual.map.znear = 0.01


@functools.lru_cache(maxsize=None)
def scene_model(robot_name: str, ground_height: float = 0.0) -> mujoco.MjModel:
    """The robot's render model (`jtraj.robot.load_render_model`) on a checker ground at
    ``ground_height`` m (the task's ``terrain_height``, where its feet touch).

    Collision meshes of bodies that also have visual meshes are hidden (group 3) so each body
    is drawn once; a body with only collision meshes shows those.
    """
    from jtraj import robot as robots

    _mujoco()
    robot = robots.load(robot_name)
    spec = robots.render_spec(robot)
    add_scenery(spec, ground_height=ground_height)
    model = robots.compile_render_spec(robot, spec)
    visual_bodies = set(model.geom_bodyid[model.geom_group == 1])
    for g in range(model.ngeom):
        if model.geom_group[g] == 0 and model.geom_bodyid[g] in visual_bodies:
            model.geom_group[g] = 3
    return model


def _options(mujoco):
    option = mujoco.MjvOption()
    option.geomgroup[:] = 0
    option.geomgroup[0:3] = 1
    return option


# ----------------------------------------------------------------------------------------
# Interpolation


@dataclasses.dataclass(frozen=True)
class Frames:
    """A trajectory resampled at given times (arrays have the time axis first).

    Attributes:
        t: times (s), shape (T,).
        qpos: MuJoCo ``qpos`` (base xyz, base wxyz, joints), shape (T, 7 + nj).
        forces: contact forces (N, world frame), shape (T, P, 3).
        contact_positions: contact points (m, world frame), shape (T, P, 3).
        in_contact: contact flags of the nearest knot, shape (T, P).
    """

    t: np.ndarray
    qpos: np.ndarray
    forces: np.ndarray
    contact_positions: np.ndarray
    in_contact: np.ndarray


def _interpolate_poses(t: np.ndarray, xyz: np.ndarray, wxyz: np.ndarray, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Poses (T, 7) ``[xyz, wxyz]`` at ``times`` (clipped to the knots ``t``), moving at a
    constant body twist between knots: ``T_k Exp(s Log(T_k^-1 T_k+1))``; also the knot ``k``
    (T,) before each time, the knot ``k1`` (T,) after it and the fraction ``s`` (T,) of the
    interval."""
    from jaxlie import SE3

    times = np.clip(np.asarray(times, float), t[0], t[-1])
    k = np.clip(np.searchsorted(t, times, side="right") - 1, 0, max(len(t) - 2, 0))
    k1 = np.minimum(k + 1, len(t) - 1)  # a single knot is its own next one
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(t[k1] > t[k], (times - t[k]) / (t[k1] - t[k]), 0.0)
    wxyz = wxyz / np.linalg.norm(wxyz, axis=1, keepdims=True)
    T = np.concatenate([wxyz, xyz], axis=1)  # jaxlie stores wxyz_xyz
    Ta, Tb = SE3(T[k]), SE3(T[k1])
    pose = np.asarray((Ta @ SE3.exp((Ta.inverse() @ Tb).log() * s[:, None])).wxyz_xyz)
    return np.concatenate([pose[:, 4:], pose[:, :4]], axis=1), k, k1, s


def interpolate(trajectory: Trajectory, times: np.ndarray) -> Frames:
    """The trajectory at ``times`` (s, clipped to its span): base pose on SE(3)
    (``T_k Exp(s Log(T_k^-1 T_k+1))``, constant body twist between knots), joints, forces and
    contact points linearly, contact flags from the nearest knot."""
    t = np.asarray(trajectory.t, float)
    xyz_wxyz = np.asarray(trajectory.base_xyz_wxyz, float)
    base, k, k1, s = _interpolate_poses(t, xyz_wxyz[:, :3], xyz_wxyz[:, 3:7], times)
    times = np.clip(np.asarray(times, float), t[0], t[-1])

    def lerp(a):
        a = np.asarray(a, float)
        w = s.reshape((-1,) + (1,) * (a.ndim - 1))
        return (1 - w) * a[k] + w * a[k1]

    qpos = np.concatenate([base, lerp(trajectory.q_joints)], axis=1)
    nearest = np.where(s < 0.5, k, k1)
    return Frames(
        t=times,
        qpos=qpos,
        forces=lerp(trajectory.forces),
        contact_positions=lerp(trajectory.contact_positions),
        in_contact=np.asarray(trajectory.in_contact, bool)[nearest],
    )


# ----------------------------------------------------------------------------------------
# Drawing


class _Painter:
    """One model, one offscreen renderer; draws a pose (with forces, a path) from a camera.

    ``scale`` (m) sizes the arrows: a force equal to ``weight`` (N) is ``2 scale`` long
    unless `RenderOptions.force_length` says otherwise.
    """

    def __init__(self, model, options: RenderOptions, *, weight: float = 1.0, scale: float = 1.0):
        self.mujoco = _mujoco()
        self.model = model
        self.data = self.mujoco.MjData(self.model)
        self.options = options
        self.renderer = _renderer(self.model, options.width, options.height)
        self.vopt = _options(self.mujoco)
        self.renderer.scene.flags[self.mujoco.mjtRndFlag.mjRND_SHADOW] = options.shadows
        self.weight = weight
        self.force_length = options.force_length if options.force_length is not None else 2.0 * scale
        self.arrow_width = 0.04 * scale

    @classmethod
    def for_result(cls, result: Result, options: RenderOptions) -> _Painter:
        """The painter of ``result``'s robot on its task's ground (``terrain_height`` in the
        result's options; 0 for results saved before it was recorded), its arrows scaled by
        the weight of the body masses solved at (`jtraj.plots._weight`), which the forces
        carried, not the model's."""
        from jtraj.plots import _weight, result_robot

        if options.azimuth is None:
            options = dataclasses.replace(options, azimuth=auto_azimuth(result.trajectory.base_xyz_wxyz))
        robot_name = result.robot
        robot = result_robot(result)
        ground = float(result.options.get("terrain_height", 0.0) or 0.0)
        painter = cls(scene_model(robot_name, ground), options, weight=_weight(result, robot), scale=float(robot.base_xyz_wxyz_standing[2]))
        painter.robot = robot
        return painter

    def close(self):
        self.renderer.close()

    def camera(self, lookat: np.ndarray, distance: float):
        cam = self.mujoco.MjvCamera()
        cam.type = self.mujoco.mjtCamera.mjCAMERA_FREE
        cam.lookat[:] = lookat
        cam.distance = distance
        cam.azimuth = self.options.azimuth
        cam.elevation = self.options.elevation
        return cam

    def pose(self, qpos: np.ndarray, data=None):
        data = self.data if data is None else data
        data.qpos[:] = qpos
        self.mujoco.mj_kinematics(self.model, data)
        return data

    def draw(self, qpos, forces, points, in_contact, camera, extra_poses: Sequence[np.ndarray] = (), path: np.ndarray | None = None) -> np.ndarray:
        """The image of ``qpos`` (plus copies at ``extra_poses``), force arrows at ``points``
        where ``in_contact``, and ``path`` (M, 3) as a line."""
        mj = self.mujoco
        self.renderer.update_scene(self.pose(qpos), camera=camera, scene_option=self.vopt)
        scene = self.renderer.scene
        for q in extra_poses:
            # More copies of the body in the same scene: MuJoCo sorts them by depth.
            mj.mjv_addGeoms(self.model, self.pose(q, mj.MjData(self.model)), self.vopt, mj.MjvPerturb(), mj.mjtCatBit.mjCAT_DYNAMIC, scene)
        if self.options.forces and forces is not None:
            self._arrows(scene, forces, points, in_contact)
        if path is not None:
            self._line(scene, path)
        return self.renderer.render().copy()

    def draw_frames(self, frames: Frames, lookat: np.ndarray, distance: float) -> list[np.ndarray]:
        """One image per time of ``frames``, the camera at ``lookat[i]``, labelled if asked."""
        images = []
        for i in range(len(frames.t)):
            image = self.draw(frames.qpos[i], frames.forces[i], frames.contact_positions[i], frames.in_contact[i], self.camera(lookat[i], distance))
            if self.options.label:
                image = _label(image, f"t = {frames.t[i]:.2f} s", not frames.in_contact[i].any())
            images.append(image)
        return images

    def _line(self, scene, path):
        mj = self.mujoco
        for a, b in zip(path[:-1], path[1:]):
            if scene.ngeom >= scene.maxgeom:
                break
            geom = scene.geoms[scene.ngeom]
            mj.mjv_initGeom(geom, mj.mjtGeom.mjGEOM_LINE, np.zeros(3), np.zeros(3), np.eye(3).ravel(), np.array([0.1, 0.3, 0.8, 1.0], np.float32))
            mj.mjv_connector(geom, mj.mjtGeom.mjGEOM_LINE, 3.0, a, b)  # width in pixels
            scene.ngeom += 1

    def _arrows(self, scene, forces, points, in_contact):
        mj = self.mujoco
        for f, p, on in zip(forces, points, in_contact):
            length = self.force_length * np.linalg.norm(f) / self.weight
            if not on or length < 1e-3 or scene.ngeom >= scene.maxgeom:
                continue
            geom = scene.geoms[scene.ngeom]
            mj.mjv_initGeom(geom, mj.mjtGeom.mjGEOM_ARROW, np.zeros(3), np.zeros(3), np.eye(3).ravel(), np.array([1.0, 0.75, 0.0, 1.0], np.float32))
            mj.mjv_connector(geom, mj.mjtGeom.mjGEOM_ARROW, self.arrow_width, p, p + f / np.linalg.norm(f) * length)
            scene.ngeom += 1


def _label(image: np.ndarray, text: str, flight: bool) -> np.ndarray:
    from PIL import Image, ImageDraw

    img = Image.fromarray(image)
    draw = ImageDraw.Draw(img)
    size = max(10, image.shape[0] // 18)
    try:
        from PIL import ImageFont

        font = ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1 has one bitmap size
        font = None
    draw.text((4, 2), text, fill=(20, 20, 20), font=font)
    if flight:
        # An orange bar along the top marks the flight phases.
        draw.rectangle([0, 0, image.shape[1] - 1, max(2, image.shape[0] // 60)], fill=(235, 120, 20))
        draw.text((image.shape[1] - 6 - draw.textlength("flight", font=font), 2), "flight", fill=(200, 80, 0), font=font)
    return np.asarray(img)


def _side_by_side(images: Sequence[np.ndarray]) -> np.ndarray:
    """Images of one height in a row, 2 white pixels apart."""
    gap = np.full((images[0].shape[0], 2, 3), 255, np.uint8)
    row = [part for image in images for part in (image, gap)][:-1]
    return np.concatenate(row, axis=1)


def _as_result(result) -> Result:
    from jtraj.result import Result, result_folder, stale_trajectory_note

    if isinstance(result, (str, Path)):
        folder = result_folder(result)
        result = Result.load(folder)
        if result.trajectory is None and (stale := stale_trajectory_note(folder)):
            raise NotDrawable(f"{folder / 'result.json'}: saved without a trajectory, nothing to draw{stale}")
    elif not isinstance(result, Result):
        raise TypeError(f"render takes a Result or the folder `jtraj solve` wrote, got a {type(result).__name__} (pass the Result itself, not its trajectory)")
    if result.trajectory is None:
        raise NotDrawable("the result has no trajectory to draw (solve with keep_trajectory=True or load a folder with trajectory.npz)")
    if not hasattr(result.trajectory, "base_xyz_wxyz"):
        raise NotDrawable(f"{result.problem!r} is not a legged robot's motion (its trajectory is a {type(result.trajectory).__name__}); draw a rigid-body benchmark with jtraj.render.render_benchmark, or its folder with jtraj render")
    status = f" (the solver's status: {result.solver_status.value})"
    _refuse_non_finite("the base pose is", status, result.trajectory.base_xyz_wxyz)
    _refuse_zero_quaternions("the base orientation", status, np.asarray(result.trajectory.base_xyz_wxyz)[:, 3:7])
    # MuJoCo draws NaN joint angles as missing limbs, without a word
    _refuse_non_finite("the joint angles are", status, result.trajectory.q_joints)
    return result


def _refuse_non_finite(what: str, note: str, *per_knot: Any) -> None:
    """NotDrawable, saying how many knots and which first, where a knot of ``per_knot``
    (arrays with the knots first) holds a NaN or an infinity; ``what`` names them, ``note``
    follows the knots in the message."""
    bad = np.zeros(len(per_knot[0]), bool)
    for values in per_knot:
        values = np.asarray(values)
        bad |= ~np.all(np.isfinite(values), axis=tuple(range(1, values.ndim)))
    if bad.any():
        raise NotDrawable(f"{what} NaN or infinite at {int(bad.sum())} knot(s), the first at knot {int(np.argmax(bad))}{note}; nothing to draw there")


def _refuse_zero_quaternions(what: str, note: str, wxyz: Any) -> None:
    """NotDrawable where a knot's quaternion (N, 4) is zero, which no rotation is: normalized
    for drawing, it was NaN, and the camera, which follows the base over the whole motion,
    turned every frame black without a word."""
    bad = np.linalg.norm(np.asarray(wxyz, float), axis=-1) < 1e-9
    if bad.any():
        raise NotDrawable(f"{what} is a zero quaternion at {int(bad.sum())} knot(s), the first at knot {int(np.argmax(bad))}{note}; nothing to draw there")


def _check_forces(result: Result, options: RenderOptions) -> None:
    """Where forces are drawn, NaN or infinite ones (with finite poses) are refused before
    anything is drawn: they were drawn as arrows to NaN, and spread to the frames on either
    side of their knot, as forces are interpolated."""
    if options.forces:
        note = f" (the solver's status: {result.solver_status.value}; RenderOptions(forces=False), or jtraj render --no-forces, draws the motion without them)"
        _refuse_non_finite("the contact forces are", note, result.trajectory.forces)


def _render_options(options: RenderOptions | Mapping[str, Any] | None, kwargs: dict[str, Any]) -> RenderOptions:
    """``options`` (None: the defaults; a mapping: their changes) with ``kwargs`` over it."""
    if options is None or isinstance(options, Mapping):
        return RenderOptions(**{**(options or {}), **kwargs})
    if not isinstance(options, RenderOptions):
        raise TypeError(f"options must be a RenderOptions or a mapping of its fields, got {type(options).__name__}")
    return dataclasses.replace(options, **kwargs)


#: the base's net horizontal travel (m) from which `auto_azimuth` turns the camera to its side
TRAVEL_FOR_CAMERA = 0.05


def auto_azimuth(base_xyz_wxyz: np.ndarray, min_travel: float = TRAVEL_FOR_CAMERA) -> float:
    """The camera azimuth (degrees) that shows a base motion (``(N, 7)`` poses, xyz and wxyz)
    from its side:

    - a flip (the accumulated rotation, `jtraj.success.rotation_vector`, a quarter turn or more,
      mostly about a horizontal axis): along that axis, so the flip turns in the image's plane;
      of the two views along it, the one with its azimuth in (0, 180] (a back-flip about y: 90;
      a side-flip about x: 180, looking along -x, where +y is to the right);
    - otherwise, where the base travels ``min_travel`` metres or more horizontally: from the side
      of the travel, which goes to the right of the image (+x: 90, +y: 180);
    - otherwise 90 (looking along +y)."""
    from jtraj.success import rotation_vector

    poses = np.asarray(base_xyz_wxyz, float)
    a, _ = rotation_vector(poses)
    horizontal = float(np.linalg.norm(a[:2]))
    if np.all(np.isfinite(a)) and np.linalg.norm(a) >= math.pi / 2 and horizontal > abs(a[2]):
        azimuth = math.degrees(math.atan2(a[1], a[0]))  # the camera looks along (cos az, sin az)
        return azimuth + 180.0 if azimuth <= 0.0 else azimuth
    travel = poses[-1, :2] - poses[0, :2]
    if np.all(np.isfinite(travel)) and np.linalg.norm(travel) >= min_travel:
        # the image's right is (sin az, -cos az) for MuJoCo's camera
        return math.degrees(math.atan2(travel[0], -travel[1])) % 360.0
    return 90.0


def _check_frames(duration: float, options: RenderOptions) -> int:
    """The frame count of ``duration`` seconds of motion at ``options``' speed and rate; a
    `TooManyFrames` above `MAX_FRAMES`, before anything is drawn (the frames of --speed 0.01
    filled the memory)."""
    n = max(2, int(round(duration / options.speed * options.fps)) + 1)
    if n > MAX_FRAMES:
        raise TooManyFrames(
            f"render: {duration:g} s of motion at speed {options.speed:g} and {options.fps:g} fps is {n} frames; expected at most {MAX_FRAMES} (they are held in memory until written): "
            "a larger speed or a lower fps"
        )
    return n


def _follow(frames: Frames, robot) -> tuple[np.ndarray, float]:
    """Camera targets (T, 3) that follow the base in x and y at a steady height, and a
    distance that keeps the robot and its vertical excursion in view."""
    base = frames.qpos[:, :3]
    height = float(robot.base_xyz_wxyz_standing[2])
    z = 0.5 * (base[:, 2].min() + base[:, 2].max())
    lookat = np.column_stack([base[:, 0], base[:, 1], np.full(len(base), z)])
    distance = 3.2 * height + 1.2 * float(np.ptp(base[:, 2]))
    return lookat, distance


def render(result: Result | str | Path, options: RenderOptions | Mapping[str, Any] | None = None, **kwargs) -> np.ndarray:
    """Video frames of a solved motion, shape (T, height, width, 3), uint8.

    ``result`` is a `jtraj.result.Result` with a trajectory or a folder written by
    ``jtraj solve``; ``options`` a `RenderOptions` or a mapping of its fields (keyword
    arguments override them, e.g. ``render(r, width=320, height=240, speed=0.5)``). Frames are
    spread evenly from the first knot to the last, about ``speed / fps`` seconds of motion apart
    (the whole number of intervals nearest to the duration at that spacing).
    """
    options = _render_options(options, kwargs)
    result = _as_result(result)
    _check_forces(result, options)
    traj = result.trajectory
    duration = float(traj.t[-1] - traj.t[0])
    n = _check_frames(duration, options)
    frames = interpolate(traj, np.linspace(traj.t[0], traj.t[-1], n))
    painter = _Painter.for_result(result, options)
    try:
        lookat, distance = _follow(frames, painter.robot)
        distance = options.distance or distance
        return np.stack(painter.draw_frames(frames, lookat, distance))
    finally:
        painter.close()


def keyframe_times(trajectory: Trajectory, n: int, length: float = 1.0) -> np.ndarray:
    """``n`` times (s) evenly spread along the base's motion, first and last knot included.

    The motion between knots is ``|Log(T_k^-1 T_k+1)|`` with the rotation counted as the arc
    it sweeps at ``length`` m from the base (e.g. the standing height), so turning and moving
    both count; a motion that does not move the base falls back to even times.
    """
    from jaxlie import SE3

    xyz_wxyz = np.asarray(trajectory.base_xyz_wxyz, float)
    T = SE3(np.concatenate([xyz_wxyz[:, 3:7], xyz_wxyz[:, :3]], axis=1))
    twist = np.asarray((SE3(T.wxyz_xyz[:-1]).inverse() @ SE3(T.wxyz_xyz[1:])).log())
    step = np.linalg.norm(twist[:, :3], axis=1) + length * np.linalg.norm(twist[:, 3:], axis=1)
    t = np.asarray(trajectory.t, float)
    if not np.sum(step) > 0:
        return np.linspace(t[0], t[-1], n)
    travelled = np.concatenate([[0.0], np.cumsum(step)])
    times = np.interp(np.linspace(0.0, travelled[-1], n), travelled, t)
    times[[0, -1]] = t[[0, -1]]  # np.interp picks any knot of a still stretch at the ends
    return times


def _check_strip(n: Any, layout: str, spacing: str) -> None:
    """`keyframe_strip`'s own arguments, checked before anything is drawn."""
    if layout not in ("side", "overlay"):
        raise ValueError(f"layout must be 'side' or 'overlay', got {layout!r}")
    if spacing not in ("motion", "time"):
        raise ValueError(f"spacing must be 'motion' or 'time', got {spacing!r}")
    if not is_whole(n) or n < 2:
        raise ValueError(f"a strip needs a whole number of at least 2 keyframes, got n={n!r}")


def keyframe_strip(
    result: Result | str | Path,
    n: int = 6,
    *,
    layout: str = "side",
    spacing: str = "motion",
    options: RenderOptions | None = None,
    **kwargs,
) -> np.ndarray:
    """One image of ``n`` keyframes from the first knot to the last, shape (H, W, 3) uint8.

    ``spacing="motion"`` spreads them evenly along the base's motion (`keyframe_times`: a
    flip gets most keyframes, standing still few); ``spacing="time"`` evenly in time.

    ``layout="side"``: one panel per keyframe (``options.width`` x ``options.height`` each),
    the camera following the base, side by side. ``layout="overlay"``: every keyframe drawn in
    one scene from a fixed camera that frames the whole path (the paper's Fig. 1).
    """
    _check_strip(n, layout, spacing)
    options = _render_options(options, kwargs)
    result = _as_result(result)
    _check_forces(result, options)
    traj = result.trajectory
    if spacing == "motion":
        from jtraj import robot as robots

        times = keyframe_times(traj, n, length=float(robots.load(result.robot).base_xyz_wxyz_standing[2]))
    else:
        times = np.linspace(traj.t[0], traj.t[-1], n)
    frames = interpolate(traj, times)
    painter = _Painter.for_result(result, options)
    try:
        lookat, distance = _follow(frames, painter.robot)
        distance = options.distance or distance
        if layout == "overlay":
            base = frames.qpos[:, :3]
            center = 0.5 * (base.min(axis=0) + base.max(axis=0))
            center[2] = lookat[0, 2]
            span = float(np.max(np.ptp(base[:, :2], axis=0)))
            cam = painter.camera(center, options.distance or distance + 1.2 * span)
            return painter.draw(
                frames.qpos[-1],
                frames.forces.reshape(-1, 3),
                frames.contact_positions.reshape(-1, 3),
                frames.in_contact.reshape(-1),
                cam,
                extra_poses=list(frames.qpos[:-1]),
            )
        return _side_by_side(painter.draw_frames(frames, lookat, distance))
    finally:
        painter.close()


# ----------------------------------------------------------------------------------------
# Rigid bodies (the attitude benchmarks)

#: Simple bodies for the attitude benchmarks, by benchmark name.
BENCHMARK_SHAPES = {"quadflip": "quadrotor", "barrelroll": "airplane", "satellite": "satellite"}


def rigid_body_model(shape: str, size: float = 1.0) -> mujoco.MjModel:
    """A free body drawn as a simple ``shape`` about ``size`` m across, on the checker ground
    (``quadrotor``, ``airplane``) or in an empty sky (``satellite``); body x forward, z up.

    quadrotor: two crossed arms and four rotors (the front two red); airplane: fuselage along
    +x, wing, tail plane and fin; satellite: a bus, two solar panels along y and an instrument
    pointing along +z.
    """
    if shape not in ("quadrotor", "airplane", "satellite"):
        raise ValueError(f"shape must be 'quadrotor', 'airplane' or 'satellite', got {shape!r}")
    mujoco = _mujoco()
    spec = mujoco.MjSpec()
    add_scenery(spec, checker_size=max(0.5, size), ground=shape != "satellite")
    if shape == "satellite":
        spec.visual.headlight.ambient = [0.5, 0.5, 0.5]
    body = spec.worldbody.add_body(name="body")
    body.add_freejoint()
    box, cyl, capsule = mujoco.mjtGeom.mjGEOM_BOX, mujoco.mjtGeom.mjGEOM_CYLINDER, mujoco.mjtGeom.mjGEOM_CAPSULE
    grey, dark, red, blue, gold = [0.75, 0.77, 0.8, 1], [0.25, 0.27, 0.3, 1], [0.85, 0.2, 0.15, 1], [0.15, 0.25, 0.6, 1], [0.85, 0.7, 0.3, 1]
    s = 0.5 * size
    if shape == "quadrotor":
        body.add_geom(type=box, size=[0.2 * s, 0.2 * s, 0.06 * s], rgba=dark)
        for angle in (45.0, -45.0):
            body.add_geom(type=box, size=[s, 0.04 * s, 0.025 * s], euler=[0, 0, angle], rgba=grey)
        for x in (1, -1):
            for y in (1, -1):
                pos = [x * s / np.sqrt(2), y * s / np.sqrt(2), 0.06 * s]
                body.add_geom(type=cyl, size=[0.3 * s, 0.01 * s, 0], pos=pos, rgba=red if x > 0 else dark)
    elif shape == "airplane":
        body.add_geom(type=capsule, fromto=[-s, 0, 0, s, 0, 0], size=[0.08 * s, 0, 0], rgba=grey)
        body.add_geom(type=box, size=[0.18 * s, s, 0.015 * s], pos=[0.1 * s, 0, 0], rgba=blue)
        body.add_geom(type=box, size=[0.1 * s, 0.35 * s, 0.012 * s], pos=[-0.9 * s, 0, 0], rgba=blue)
        body.add_geom(type=box, size=[0.12 * s, 0.012 * s, 0.2 * s], pos=[-0.9 * s, 0, 0.2 * s], rgba=red)
    else:
        body.add_geom(type=box, size=[0.3 * s, 0.3 * s, 0.3 * s], rgba=gold)
        for y in (1, -1):
            body.add_geom(type=box, size=[0.25 * s, 0.35 * s, 0.01 * s], pos=[0, y * 0.68 * s, 0], rgba=blue)
        body.add_geom(type=cyl, size=[0.08 * s, 0.12 * s, 0], pos=[0, 0, 0.42 * s], rgba=dark)
    return spec.compile()


def render_rigid_body(
    t: np.ndarray,
    xyz: np.ndarray,
    wxyz: np.ndarray,
    shape: str,
    *,
    strip: int | None = None,
    options: RenderOptions | None = None,
    **kwargs,
) -> np.ndarray:
    """A rigid body moving along its path: video frames (T, H, W, 3) with the camera following
    the body, or with ``strip=n`` one image of ``n`` copies along the path from a fixed camera
    (side by side for the satellite, which turns in place). The path is drawn as a blue line.

    ``t`` (N,) knot times (s), ``xyz`` (N, 3) positions (m), ``wxyz`` (N, 4) attitudes.
    """
    if strip is not None and (not is_whole(strip) or strip < 1):
        raise ValueError(f"strip must be a whole number of keyframes >= 1, got {strip!r}")
    options = _render_options(options, kwargs)
    t, xyz, wxyz = (np.asarray(a, float) for a in (t, xyz, wxyz))
    # (a knot more in t than in xyz was an IndexError inside the interpolation)
    if t.ndim != 1 or len(t) < 1 or xyz.shape != (len(t), 3) or wxyz.shape != (len(t), 4):
        raise ValueError(f"render_rigid_body: t {t.shape}, xyz {xyz.shape} and wxyz {wxyz.shape}: expected (N,), (N, 3) and (N, 4), N >= 1 knots")
    # MuJoCo would refuse the body's NaN size ("nan size in geom")
    _refuse_non_finite("the body's position or attitude is", "", xyz, wxyz)
    _refuse_zero_quaternions("the body's attitude", "", wxyz)
    extent = float(np.max(np.ptp(xyz, axis=0)))
    size = 1.0 if extent < 1e-6 else float(np.clip(0.2 * extent, 0.3, 2.0))
    if options.azimuth is None:
        # seen from the side of its travel (an explicit azimuth=90 was taken for the default
        # and replaced by this too)
        options = dataclasses.replace(options, azimuth=auto_azimuth(np.column_stack([xyz[[0, -1]], wxyz[[0, 0]]]), min_travel=1e-6))
    # the path as flown between knots (constant twist), not straight chords
    n = _check_frames(float(t[-1] - t[0]), options) if strip is None else 0  # the video's frames
    path = _interpolate_poses(t, xyz, wxyz, np.linspace(t[0], t[-1], min(2000, 8 * len(t))))[0][:, :3] if extent > 1e-6 else None
    painter = _Painter(rigid_body_model(shape, size), options, scale=size)  # (its GL context is closed below)
    try:
        if strip is not None:
            times = np.linspace(t[0], t[-1], strip)
            qpos = _interpolate_poses(t, xyz, wxyz, times)[0]
            if path is None:  # turning in place: one panel per keyframe
                panels = []
                for q, tk in zip(qpos, times):
                    image = painter.draw(q, None, None, None, painter.camera(q[:3], options.distance or 2.2 * size))
                    panels.append(_label(image, f"t = {tk:.3g} s", False) if options.label else image)
                return _side_by_side(panels)
            center = 0.5 * (xyz.min(axis=0) + xyz.max(axis=0))
            cam = painter.camera(center, options.distance or 1.1 * extent + 2 * size)
            return painter.draw(qpos[-1], None, None, None, cam, extra_poses=list(qpos[:-1]), path=path)
        times = np.linspace(t[0], t[-1], n)
        qpos = _interpolate_poses(t, xyz, wxyz, times)[0]
        images = []
        for q, tk in zip(qpos, times):
            image = painter.draw(q, None, None, None, painter.camera(q[:3], options.distance or 4 * size), path=path)
            images.append(_label(image, f"t = {tk:.3g} s", False) if options.label else image)
        return np.stack(images)
    finally:
        painter.close()


def render_benchmark(result, out_dir: str | Path, *, options: RenderOptions | None = None, keyframes: int = 8) -> list[Path]:
    """``jtraj attitude ... --render``: ``motion.mp4`` and ``keyframes.png`` in ``out_dir`` (the
    result's folder) of an attitude benchmark `jtraj.result.Result` (its ``problem`` and its
    trajectory's ``t`` and states ``X``, whose first 7 columns are position and wxyz attitude).
    Without imageio-ffmpeg, which writes the .mp4, a RenderError comes before anything is drawn."""
    shape = BENCHMARK_SHAPES.get(result.problem)
    if shape is None:
        raise ValueError(f"no body to draw for benchmark {result.problem!r}; expected one of: {', '.join(BENCHMARK_SHAPES)}")
    _check_video_writer(Path(out_dir) / "motion.mp4")  # before the frames are drawn
    options = options or RenderOptions()
    return _draw_benchmark(result, Path(out_dir) / "motion.mp4", Path(out_dir) / "keyframes.png", keyframes, options)


def _is_benchmark(result: Result) -> bool:
    """Whether ``result`` is an attitude benchmark's that `_draw_benchmark` can draw."""
    return result.problem in BENCHMARK_SHAPES and result.trajectory is not None and hasattr(result.trajectory, "X")


def _draw_benchmark(result: Result, out: Path | None, strip: Path | None, keyframes: int, options: RenderOptions) -> list[Path]:
    """The video ``out`` and/or the keyframe strip ``strip`` of an attitude benchmark's result
    (`render_benchmark`, and `render_directory` for its folder)."""
    shape = BENCHMARK_SHAPES[result.problem]
    t, X = np.asarray(result.trajectory.t), np.asarray(result.trajectory.X)
    written = []
    if out is not None:
        # the satellite slews for minutes: show it faster than real time
        speed = options.speed * (10.0 if t[-1] - t[0] > 30 else 1.0)
        video = render_rigid_body(t, X[:, :3], X[:, 3:7], shape, options=dataclasses.replace(options, speed=speed))
        written.append(write_video(video, out, fps=options.fps))
    if strip is not None:
        strip_options = dataclasses.replace(options, width=min(options.width, 320) if shape == "satellite" else options.width)
        written.append(write_image(render_rigid_body(t, X[:, :3], X[:, 3:7], shape, strip=keyframes, options=strip_options), strip))
    return written


# ----------------------------------------------------------------------------------------
# Files

#: The file names `write_video` writes, by suffix (`render_directory` checks ``out`` against them first).
_VIDEO_SUFFIXES = (".gif", ".mp4")
#: Pillow's format for each file name `write_image` writes, by suffix (`render_directory` checks ``strip`` against them first).
_IMAGE_FORMATS = {".png": "PNG", ".jpg": "JPEG", ".jpeg": "JPEG"}


def _pixels(array: Any, ndim: int, what: str) -> np.ndarray:
    """``array`` as uint8 pixels of ``ndim`` dimensions, the last RGB; ValueError otherwise
    (floats are refused rather than cast: images in [0, 1] would come out black)."""
    a = np.asarray(array)
    shape = "(T, H, W, 3)" if ndim == 4 else "(H, W, 3)"
    if a.ndim != ndim or a.shape[-1] != 3 or 0 in a.shape:
        hint = "; for one image use write_image" if ndim == 4 and a.ndim == 3 else ""
        raise ValueError(f"{what} of shape {a.shape}; expected {shape} RGB{hint}")
    if a.dtype != np.uint8:
        if a.dtype.kind not in "iu" or a.min() < 0 or a.max() > 255:
            raise ValueError(f"{what} are {a.dtype} in [{a.min()}, {a.max()}]; expected uint8 pixels 0-255 (from [0, 1] floats: (x * 255).round().astype(np.uint8))")
        a = a.astype(np.uint8)
    return a


def write_video(frames: np.ndarray, path: str | Path, fps: float = 30.0) -> Path:
    """Writes frames (T, H, W, 3) uint8 as ``.mp4`` (H.264 through imageio-ffmpeg; an odd
    width or height loses its last pixel column or row) or ``.gif`` (frame delays in whole
    hundredths of a second, real time on average; above 50 fps viewers may slow it down)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in _VIDEO_SUFFIXES:
        raise ValueError(f"{path}: expected a .mp4 or .gif file name")
    if not is_real(fps) or not (math.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a finite number > 0, got {fps!r}")
    frames = _pixels(frames, 4, "frames")
    path.parent.mkdir(parents=True, exist_ok=True)
    # written beside the target and renamed into place: a killed render leaves no half video
    final, path = path, path.with_name(f".{path.stem}.{os.getpid()}.partial{suffix}")
    try:
        _encode_video(frames, path, suffix, fps)
        os.replace(path, final)
    finally:
        path.unlink(missing_ok=True)
    return final


def _imageio_ffmpeg() -> types.ModuleType:
    """imageio-ffmpeg, which writes .mp4, with its ffmpeg program found, or a RenderError that
    says how to install them."""
    try:
        import imageio_ffmpeg
    except ImportError:
        raise RenderError("writing .mp4 needs imageio-ffmpeg: pip install 'jtraj[render]' (or write a .gif)") from None
    # the program too: imageio-ffmpeg's wheel without a binary looks for one on the system, and
    # its RuntimeError came as a traceback once every frame was drawn
    try:
        imageio_ffmpeg.get_ffmpeg_exe()
    except RuntimeError as e:
        raise RenderError(f"writing .mp4 needs the ffmpeg program, which imageio-ffmpeg did not find ({e}): install ffmpeg, or imageio-ffmpeg's wheel for this platform, which brings one (or write a .gif)") from None
    return imageio_ffmpeg


def _check_video_writer(path: str | Path) -> None:
    """The writer that `write_video` needs for ``path``'s suffix, checked before the frames are
    drawn (it was found missing only when they were written, minutes later): a RenderError for
    an .mp4 without imageio-ffmpeg. A .gif needs Pillow, which matplotlib brings."""
    if Path(path).suffix.lower() == ".mp4":
        _imageio_ffmpeg()


def _encode_video(frames: np.ndarray, path: Path, suffix: str, fps: float) -> None:
    if suffix == ".gif":
        from PIL import Image

        images = [Image.fromarray(f) for f in frames]
        # GIF delays are whole hundredths of a second: each frame ends at its time rounded to
        # one, so that the video keeps real time on average (33 ms per frame at 30 fps was
        # stored as 30 ms, 11 % fast)
        ends = np.round(np.arange(1, len(images) + 1) * 100.0 / fps).astype(int)
        durations = (10 * np.diff(ends, prepend=0)).tolist()
        images[0].save(path, save_all=True, append_images=images[1:], duration=durations, loop=0)
    elif suffix == ".mp4":
        imageio_ffmpeg = _imageio_ffmpeg()
        # H.264 in yuv420p wants even sizes.
        h, w = frames.shape[1] // 2 * 2, frames.shape[2] // 2 * 2
        writer = imageio_ffmpeg.write_frames(str(path), (w, h), fps=fps, codec="libx264", pix_fmt_out="yuv420p", quality=7, macro_block_size=1)
        with warnings.catch_warnings():
            # JAX warns on any fork; this one is subprocess's fork-exec of ffmpeg, which is safe.
            warnings.filterwarnings("ignore", message="os.fork", category=RuntimeWarning)
            writer.send(None)
        for f in frames:
            writer.send(np.ascontiguousarray(f[:h, :w]))
        writer.close()


def show(frames: np.ndarray, fps: float = 30.0, **kwargs) -> None:
    """Shows a video (T, H, W, 3) or an image (H, W, 3) inline in a notebook with mediapy.

    mediapy encodes videos with ``ffmpeg``; when none is on the PATH it is pointed at the
    binary that imageio-ffmpeg ships (both in the ``render`` extra).
    """
    try:
        import mediapy
    except ImportError:
        raise RenderError("showing frames inline needs mediapy: pip install 'jtraj[render]'") from None
    frames = np.asarray(frames)
    if frames.ndim == 3:
        mediapy.show_image(frames, **kwargs)
        return
    import shutil

    if shutil.which("ffmpeg") is None:
        try:
            import imageio_ffmpeg
        except ImportError:
            raise RenderError("showing a video inline needs ffmpeg, which is not on the PATH: pip install 'jtraj[render]' (imageio-ffmpeg ships one)") from None

        mediapy.set_ffmpeg(imageio_ffmpeg.get_ffmpeg_exe())
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="os.fork", category=RuntimeWarning)  # see write_video
        mediapy.show_video(frames, fps=fps, **kwargs)


def write_image(image: np.ndarray, path: str | Path) -> Path:
    """Writes an (H, W, 3) uint8 image (PNG or JPEG, from the file name)."""
    from PIL import Image

    path = Path(path)
    fmt = _IMAGE_FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise ValueError(f"{path}: expected a .png, .jpg or .jpeg file name")
    image = _pixels(image, 3, "image")
    path.parent.mkdir(parents=True, exist_ok=True)
    with jio.atomic_open(path, "wb") as f:
        Image.fromarray(image).save(f, format=fmt, optimize=True)
    return path


def render_directory(
    directory: str | Path,
    out: str | Path | None = None,
    strip: str | Path | None = None,
    *,
    keyframes: int = 6,
    layout: str = "side",
    spacing: str = "motion",
    options: RenderOptions | None = None,
) -> list[Path]:
    """``jtraj render``: the video (``out``) and/or the keyframe strip (``strip``) of the
    solution in ``directory`` (its ``result.json`` and ``trajectory.npz``), a robot's or an
    attitude benchmark's (`render_benchmark`'s drawing); returns the paths.
    The strip's panels are ``options``' size capped at 480 x 480 pixels each (a 640 x 480
    video gets 480 x 480 panels). A path that is a folder, and an .mp4 without its writer
    (imageio-ffmpeg: a RenderError), are refused before anything is drawn."""
    # what would fail after minutes of drawing, checked first
    if out is None and strip is None:
        raise ValueError("nothing to write: give out (a .mp4 or .gif file) and/or strip (a .png or .jpg file)")
    if out is not None and Path(out).suffix.lower() not in _VIDEO_SUFFIXES:
        raise ValueError(f"{out}: expected a .mp4 or .gif file name")
    if out is not None:
        _check_video_writer(out)
    if strip is not None:
        if Path(strip).suffix.lower() not in _IMAGE_FORMATS:
            raise ValueError(f"{strip}: expected a .png, .jpg or .jpeg file name")
        _check_strip(keyframes, layout, spacing)
    for path in (out, strip):
        if path is not None and Path(path).is_dir():
            raise ValueError(f"{path}: is a folder; expected the name of a file to write")
    directory = Path(directory)
    if not (directory / "trajectory.npz").is_file():
        raise FileNotFoundError(f"{directory}: no trajectory.npz (expected a folder written by `jtraj solve`)")
    options = options or RenderOptions()
    from jtraj.result import Result, result_folder

    if _is_benchmark(benchmark := Result.load(result_folder(directory))):
        # a folder of `jtraj attitude` (it was refused, pointing to render_benchmark): its body
        # along its path; the strip's layout and spacing are the robots'
        return _draw_benchmark(benchmark, None if out is None else Path(out), None if strip is None else Path(strip), keyframes, options)
    result = _as_result(directory)
    written = []
    if out is not None:
        written.append(write_video(render(result, options), out, fps=options.fps))
    if strip is not None:
        strip_options = dataclasses.replace(options, width=min(options.width, 480), height=min(options.height, 480))
        written.append(write_image(keyframe_strip(result, keyframes, layout=layout, spacing=spacing, options=strip_options), strip))
    return written


class _CallableModule(types.ModuleType):
    """``jtraj.render`` is this module and, called, its `render` function."""

    def __call__(self, *args, **kwargs):
        return render(*args, **kwargs)


sys.modules[__name__].__class__ = _CallableModule
