"""Robot models: a URDF from example-robot-data, loaded into MuJoCo and MJX, plus the data a
task needs (contact points and groups, standing pose, limits), declared in ``robots/*.toml``.

`load` reads ``robots/<name>.toml`` (installed as package data ``jtraj.robots``), finds the URDF
inside the installed ``example-robot-data`` distribution, and builds a frozen `Robot`:

- the URDF is parsed with ``xml.etree``; ``<visual>``/``<collision>`` are stripped (dynamics
  never depends on meshes), the locked joints become ``fixed``, and MuJoCo's compiler is told to
  fuse static bodies and keep the inertias as written (``balanceinertia="false"``);
- a free joint is added to the root body; damping, armature and friction loss are zeroed, so
  the model is pure rigid-body dynamics;
- contact points are declared on URDF links; a link that MuJoCo fused into its parent is
  resolved to the surviving ancestor body by composing the URDF fixed-joint origins, so every
  contact point is expressed in a body MuJoCo keeps.

Joint order everywhere is MuJoCo's ``qpos`` order (`Robot.joint_names`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import difflib
import functools
import hashlib
import importlib.metadata
import importlib.resources
import io
import json
import os
import pathlib
import re
import shutil
import tempfile
import tomllib
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

import mujoco
import numpy as np
from jaxlie import SE3, SO3

from jtraj import euler
from jtraj.constants import GRAVITY
from jtraj.numbers import is_real, is_whole, unit_and_length

# MJX prints "Failed to import warp" (its optional GPU backend) on import: keep the command line
# clean and pass on anything else it prints.
with contextlib.redirect_stdout(io.StringIO()) as _mjx_import_output:
    from mujoco import mjx
for _line in _mjx_import_output.getvalue().splitlines():
    if "warp" not in _line:
        print(_line)

__all__ = [
    "Robot",
    "ContactPoint",
    "RobotLoadError",
    "available",
    "load",
    "load_file",
    "load_render_model",
    "render_spec",
    "compile_render_spec",
    "mesh_cache_dir",
    "robots_data_dir",
    "GRAVITY",
    "to_pinocchio",
]

_FREE_JOINT_NAME = "floating_base"
# Mesh formats MuJoCo can read; Collada (.dae) is converted for rendering, others are skipped.
_MUJOCO_MESH_SUFFIXES = (".stl", ".obj", ".msh")


class RobotLoadError(ValueError):
    """A robot definition or model that cannot be loaded; the message names the file."""


@dataclasses.dataclass(frozen=True)
class ContactPoint:
    """One contact point.

    Attributes:
        name: unique name within the robot.
        link: URDF link the point was declared on.
        offset_link: position of the point in the link frame (m).
        body: MuJoCo body that carries the point (``link`` or its surviving ancestor).
        body_id: MuJoCo body id.
        offset_body: position of the point in the body frame (m).
    """

    name: str
    link: str
    offset_link: tuple[float, float, float]
    body: str
    body_id: int
    offset_body: tuple[float, float, float]


@dataclasses.dataclass(frozen=True, eq=False)
class Robot:
    """A floating-base robot: MuJoCo/MJX models and the task-facing data.

    Instances are immutable and hashed by identity, so they can be static arguments of
    `jax.jit`. Arrays are read-only numpy arrays. Joint-indexed arrays have length `nj` in
    MuJoCo ``qpos`` order (`joint_names`).

    Attributes:
        name: robot name (the TOML file's stem).
        source: the TOML file it was built from.
        urdf_path: the URDF inside example-robot-data.
        mj_model: MuJoCo model (free joint first, then the `nj` hinge joints).
        mjx_model: the same model on device (`mujoco.mjx.put_model`).
        joint_names: actuated joint names.
        locked_joints: URDF joints turned fixed (at 0).
        contacts: the contact points, in declaration order.
        contact_groups: group name -> tuple of indices into `contacts`.
        q_joints_standing: standing joint positions (rad), shape (nj,).
        base_xyz_wxyz_standing: standing base pose, position (m) then unit quaternion.
        q_lower, q_upper: joint position limits (rad) from the URDF (+-inf if unlimited).
        v_max: joint velocity limits (rad/s) from the URDF (inf if absent).
        tau_max: joint effort limits (N m) from the URDF (inf if absent).
        total_mass: sum of the body masses (kg).
        gravity: magnitude of gravity (m/s^2), along -z.
    """

    name: str
    source: pathlib.Path
    urdf_path: pathlib.Path
    mj_model: mujoco.MjModel
    mjx_model: Any
    joint_names: tuple[str, ...]
    locked_joints: tuple[str, ...]
    contacts: tuple[ContactPoint, ...]
    contact_groups: Mapping[str, tuple[int, ...]]
    q_joints_standing: np.ndarray
    base_xyz_wxyz_standing: np.ndarray
    q_lower: np.ndarray
    q_upper: np.ndarray
    v_max: np.ndarray
    tau_max: np.ndarray
    total_mass: float
    gravity: float = GRAVITY

    @property
    def nj(self) -> int:
        """Number of actuated joints."""
        return len(self.joint_names)

    @property
    def nq_joints(self) -> int:
        """Alias of `nj`: joint coordinates in ``q`` after the base coordinates."""
        return self.nj

    @property
    def nv(self) -> int:
        """Generalized velocity size, ``6 + nj`` (body twist then joint rates)."""
        return 6 + self.nj

    @property
    def ncontact(self) -> int:
        return len(self.contacts)

    @property
    def contact_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.contacts)

    @property
    def contact_body_ids(self) -> np.ndarray:
        """MuJoCo body id of each contact point, shape (ncontact,)."""
        return _readonly(np.array([c.body_id for c in self.contacts], dtype=np.int64))

    @property
    def contact_offsets(self) -> np.ndarray:
        """Contact point positions in their body frames (m), shape (ncontact, 3)."""
        return _readonly(np.array([c.offset_body for c in self.contacts], dtype=np.float64).reshape(-1, 3))

    @property
    def base_pose_standing(self) -> SE3:
        """Standing base pose ``T_world_base``."""
        xyz_wxyz = self.base_xyz_wxyz_standing
        return SE3.from_rotation_and_translation(SO3(xyz_wxyz[3:]), xyz_wxyz[:3])

    @property
    def qpos_standing(self) -> np.ndarray:
        """MuJoCo ``qpos`` of the standing pose, shape (7 + nj,)."""
        return _readonly(np.concatenate([self.base_xyz_wxyz_standing, self.q_joints_standing]))

    def contact_index(self, name: str) -> int:
        """Index of the contact point ``name`` in `contacts`."""
        names = self.contact_names
        if name not in names:
            choices = ", ".join(names)
            raise KeyError(f"robot {self.name!r} has no contact point {name!r}; expected one of: {choices}")
        return names.index(name)

    def group(self, name: str) -> tuple[int, ...]:
        """Contact point indices of the group ``name``."""
        if name not in self.contact_groups:
            choices = ", ".join(self.contact_groups)
            raise KeyError(f"robot {self.name!r} has no contact group {name!r}; expected one of: {choices}")
        return self.contact_groups[name]

    def joints_outside_limits(self, q_joints: Any) -> np.ndarray:
        """Indices of the joints whose positions in ``q_joints`` (nj,) (rad) lie outside
        [`q_lower`, `q_upper`], in joint order (empty when all are within)."""
        q = np.asarray(q_joints, float)
        return np.flatnonzero((q < self.q_lower) | (q > self.q_upper))

    def content_hash(self) -> str:
        """A hex digest of everything of this robot that a problem reads: the compiled MuJoCo
        model (MuJoCo's binary MJB: bodies, masses, inertias, joints), the contact points and
        groups, the standing pose and the limits. Equal for equal robots, whatever file or
        example-robot-data folder they came from; a sweep's runs record it, so an edited robot
        file is not taken for the one they were solved on."""
        mjb = np.zeros(mujoco.mj_sizeModel(self.mj_model), np.uint8)
        mujoco.mj_saveModel(self.mj_model, None, mjb)
        data = dict(
            joint_names=self.joint_names,
            locked_joints=self.locked_joints,
            contacts=[(c.name, c.body_id, list(c.offset_body)) for c in self.contacts],
            contact_groups={k: list(v) for k, v in self.contact_groups.items()},
            standing=[*self.base_xyz_wxyz_standing.tolist(), *self.q_joints_standing.tolist()],
            limits=[a.tolist() for a in (self.q_lower, self.q_upper, self.v_max, self.tau_max)],
            gravity=self.gravity,
        )
        digest = hashlib.sha256(mjb.tobytes())
        digest.update(json.dumps(data, sort_keys=True).encode())
        return digest.hexdigest()[:16]

    def __repr__(self) -> str:
        return (
            f"Robot({self.name!r}, nj={self.nj}, nv={self.nv}, ncontact={self.ncontact}, "
            f"groups={list(self.contact_groups)}, mass={self.total_mass:.3f} kg)"
        )


# ----------------------------------------------------------------------------------------
# Locating files


ROBOT_DATA_ENV = "JTRAJ_ROBOT_DATA"


def robots_data_dir() -> pathlib.Path:
    """The ``robots`` folder of the installed example-robot-data distribution.

    The environment variable ``JTRAJ_ROBOT_DATA``, when set, names another folder laid out the
    same way (for a machine where only the few URDF files are copied, not the distribution).
    """
    override = os.environ.get(ROBOT_DATA_ENV)
    if override:
        folder = pathlib.Path(override).expanduser()
        if not folder.is_dir():
            raise RobotLoadError(f"{ROBOT_DATA_ENV}={override!r} is not a folder")
        return folder
    try:
        files = importlib.metadata.files("example-robot-data")
    except importlib.metadata.PackageNotFoundError:
        raise RobotLoadError(
            "the example-robot-data distribution is not installed; install it with "
            "`pip install example-robot-data`"
        ) from None
    marker = ("share", "example-robot-data", "robots")
    for f in files or ():
        parts = f.parts
        for i in range(len(parts) - len(marker)):
            if parts[i : i + len(marker)] == marker:
                return pathlib.Path(f.locate()).parents[len(parts) - i - len(marker) - 1]
    raise RobotLoadError(
        "example-robot-data is installed but holds no share/example-robot-data/robots folder"
    )


def available() -> tuple[str, ...]:
    """Names of the robots defined in the package data ``jtraj.robots``."""
    folder = importlib.resources.files("jtraj.robots")
    return tuple(sorted(p.name[: -len(".toml")] for p in folder.iterdir() if p.name.endswith(".toml")))


def load(name: str) -> Robot:
    """The robot ``name`` (`available()`: ``talos``, ``talos_full``, ``g1``, ``go2``), from ``robots/<name>.toml``.

    Cached: a second call returns the same object (so jitted functions do not recompile).
    """
    # checked before the cache, which cannot hash a list
    if isinstance(name, os.PathLike) or (isinstance(name, str) and (name.endswith(".toml") or "/" in name)):
        raise RobotLoadError(
            f"unknown robot {name!r}; expected one of: {', '.join(available())} (with the editable install, a robot file saved in the checkout's robots/ folder is the robot of its stem; jtraj.robot.load_file reads one)"
        )
    if not isinstance(name, str):
        raise RobotLoadError(f"unknown robot {name!r}; expected one of: {', '.join(available())} (a robot's name, a string)")
    return _load_named(name)


@functools.lru_cache(maxsize=None)
def _load_named(name: str) -> Robot:
    resource = importlib.resources.files("jtraj.robots") / f"{name}.toml"
    if not resource.is_file():
        raise RobotLoadError(f"unknown robot {name!r}; expected one of: {', '.join(available())}")
    with importlib.resources.as_file(resource) as path:
        robot = load_file(path)
    if robot.name != name:
        # found by its file's name, as tasks and --robot name it, and a run records the robot's
        # name to draw it again: a copy of go2.toml saved as my_go2.toml was solved as my_go2
        # and recorded, plotted and rendered as go2
        raise RobotLoadError(f"{name}.toml: name = {robot.name!r}, but the robot is found as {name!r} (its file's name): leave 'name' out, or write name = {name!r}")
    return robot


def load_file(path: str | pathlib.Path) -> Robot:
    """A robot from a TOML definition file (see ``robots/talos.toml`` for the format).

    Keys: ``name``; ``urdf`` (relative to example-robot-data's robots folder, or absolute);
    ``locked_joints`` (fixed at 0); ``expected_joints`` (a check); ``[standing]`` with
    ``base_xyz``, ``base_wxyz`` and a ``[standing.joints]`` table (others 0); ``[[contact]]``
    entries with ``name``, ``link`` and ``offset`` (m, link frame); ``[groups]`` mapping a
    group name to contact names.

    ``extends = "talos"`` starts from another robot file in the same folder (``talos.toml``,
    which may extend another in turn) and applies this file on top: tables (``[standing]``,
    ``[standing.joints]``, ``[groups]``) are merged key by key at every depth, and any other
    value (a string, number or array, the ``[[contact]]`` list included) replaces the
    parent's whole. ``name`` is not inherited: it defaults to this file's stem, and a file in
    jtraj's ``robots`` folder, found by its stem (`load`), must not give another (a run records
    the name to draw the robot again). A ``[[contact]]`` without ``offset`` is at its link's
    origin.
    ``robots/talos_full.toml`` is an example.
    """
    path = pathlib.Path(path)
    return _build(_read_config(path), path)


def _read_toml(path: pathlib.Path) -> dict[str, Any]:
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except (OSError, tomllib.TOMLDecodeError) as err:
        raise RobotLoadError(f"{path}: cannot read robot definition: {err}") from err


def _read_config(path: pathlib.Path, chain: tuple[pathlib.Path, ...] = ()) -> dict[str, Any]:
    """The robot file at ``path`` with its ``extends`` chain resolved (see `load_file`).

    ``chain`` holds the files that extend this one, child first, to report cycles.
    """
    config = _read_toml(path)
    # each file's own keys, against its own path: checked after the merge, a parent's unknown
    # key was reported as the child file's
    _check_keys(config, "", path)
    if isinstance(config.get("standing"), Mapping):
        _check_keys(config["standing"], "standing.", path)
    for entry in config.get("contact", []) if isinstance(config.get("contact"), list) else []:
        _check_keys(entry, "contact[].", path)
    if "extends" not in config:
        return config
    parent = config.pop("extends")
    if not isinstance(parent, str) or not parent or "/" in parent or "\\" in parent or parent.endswith(".toml"):
        raise RobotLoadError(
            f"{path}: 'extends' must name another robot file in the same folder by its stem "
            f"(e.g. \"talos\" for talos.toml), got {parent!r}"
        )
    parent_path = path.parent / f"{parent}.toml"
    chain = (*chain, path)
    if parent_path.resolve() in {p.resolve() for p in chain}:
        cycle = " -> ".join(p.name for p in (*chain, parent_path))
        raise RobotLoadError(f"{path}: extends = {parent!r} makes a cycle: {cycle}")
    if not parent_path.is_file():
        siblings = sorted(p.stem for p in path.parent.glob("*.toml") if p.resolve() != path.resolve())
        raise RobotLoadError(
            f"{path}: extends = {parent!r}, but there is no robot file {parent_path}; "
            f"expected one of: {', '.join(siblings) or '(no other .toml file in that folder)'}"
        )
    base = _read_config(parent_path, chain)
    base.pop("name", None)  # a robot's name is its own (see load_file)
    return _merge(base, config)


def _merge(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict[str, Any]:
    """``override`` on top of ``base``: tables merged key by key at every depth, other values
    replaced whole; keys keep the parent's order, new keys come after."""
    merged = dict(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = _merge(merged[key], value)
        else:
            merged[key] = value
    return merged


# ----------------------------------------------------------------------------------------
# URDF handling


def _floats(text: str | None, n: int, default: float = 0.0) -> np.ndarray:
    if text is None:
        return np.full(n, default)
    values = np.array([float(x) for x in text.split()])
    if values.shape != (n,) or not np.all(np.isfinite(values)):
        raise ValueError(f"expected {n} finite numbers, got {text!r}")
    return values


def _origin(element: ET.Element) -> tuple[np.ndarray, np.ndarray]:
    """(R, p) of an element's ``<origin>``, identity when absent."""
    origin = element.find("origin")
    if origin is None:
        return np.eye(3), np.zeros(3)
    # URDF's rpy is R = Rz(yaw) Ry(pitch) Rx(roll), the convention of jtraj.euler
    R = np.asarray(euler.rotation_matrix(np.asarray(_floats(origin.get("rpy"), 3))))
    return R, _floats(origin.get("xyz"), 3)


@dataclasses.dataclass(frozen=True)
class _Urdf:
    path: pathlib.Path
    root: ET.Element
    links: tuple[str, ...]
    joints: Mapping[str, ET.Element]  # by name
    parent_joint: Mapping[str, ET.Element]  # child link -> joint


def _parse_urdf(path: pathlib.Path, source: pathlib.Path) -> _Urdf:
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as err:
        raise RobotLoadError(f"{source}: cannot parse URDF {path}: {err}") from err
    if root.tag != "robot":
        raise RobotLoadError(f"{source}: {path} is not a URDF (root element <{root.tag}>, expected <robot>)")
    links = tuple(link.get("name") for link in root.findall("link"))
    joints = {j.get("name"): j for j in root.findall("joint")}
    for name, joint in joints.items():
        for end in ("parent", "child"):
            element = joint.find(end)
            if element is None or not element.get("link"):
                raise RobotLoadError(f"{source}: joint {name!r} of {path} has no <{end} link=\"...\"/>")
    parent_joint = {j.find("child").get("link"): j for j in joints.values()}
    return _Urdf(path, root, links, joints, parent_joint)


def _mujoco_urdf_string(
    urdf: _Urdf,
    locked: tuple[str, ...],
    *,
    keep_geometry: bool,
    mesh_root: pathlib.Path | None = None,
) -> str:
    """The URDF text handed to MuJoCo: locked joints fixed, geometry stripped or resolved."""
    root = ET.fromstring(ET.tostring(urdf.root))  # a copy
    for joint in root.findall("joint"):
        if joint.get("name") in locked:
            joint.set("type", "fixed")
            for tag in ("limit", "mimic", "dynamics", "calibration", "safety_controller"):
                for child in joint.findall(tag):
                    joint.remove(child)
        elif joint.find("mimic") is not None:
            # MuJoCo ignores <mimic>; the joint stays independent.
            joint.remove(joint.find("mimic"))
    for link in root.findall("link"):
        for tag in ("visual", "collision"):
            for geom in link.findall(tag):
                position = list(link).index(geom)
                link.remove(geom)
                if keep_geometry:
                    for i, part in enumerate(_resolve_meshes(geom, mesh_root)):
                        link.insert(position + i, part)
    # Gazebo/transmission extras are noise to MuJoCo.
    for child in list(root):
        if child.tag not in ("link", "joint", "material"):
            root.remove(child)
    compiler = ET.SubElement(ET.SubElement(root, "mujoco"), "compiler")
    compiler.set("discardvisual", "false" if keep_geometry else "true")
    compiler.set("fusestatic", "true")
    compiler.set("balanceinertia", "false")
    compiler.set("strippath", "false")
    return ET.tostring(root, encoding="unicode")


def _resolve_meshes(geom: ET.Element, mesh_root: pathlib.Path | None) -> list[ET.Element]:
    """``geom`` (a ``<visual>`` or ``<collision>``) with its mesh file names pointed at files
    MuJoCo reads: empty when a mesh cannot be loaded; one element per colored part when a
    Collada mesh was converted (see `_collada_parts`)."""
    meshes = list(geom.iter("mesh"))
    for mesh in meshes:
        # talos_full_v2.urdf writes most of its meshes "package:///example-robot-data/...":
        # read as any other package URL (they were dropped, and the study's Talos was drawn as
        # its feet alone)
        filename = re.sub(r"^package:/+", "package://", mesh.get("filename", ""))
        prefix = "package://example-robot-data/robots/"
        if filename.startswith(prefix) and mesh_root is not None:
            path = mesh_root / filename[len(prefix) :]
        elif filename.startswith("package://"):
            return []
        else:
            path = pathlib.Path(filename)
        if not path.is_file():
            return []
        if path.suffix.lower() == ".dae" and len(meshes) == 1:
            return _collada_geoms(geom, mesh, path)
        if path.suffix.lower() not in _MUJOCO_MESH_SUFFIXES:
            return []
        mesh.set("filename", str(path))
    return [geom]


def _collada_geoms(geom: ET.Element, mesh: ET.Element, path: pathlib.Path) -> list[ET.Element]:
    """One copy of ``geom`` per part of the Collada file ``path``, each pointing at that
    part's OBJ file and colored with the part's material."""
    parts = _collada_parts(path)
    out = []
    for i, (part_path, rgba) in enumerate(parts):
        mesh.set("filename", str(part_path))
        copy = ET.fromstring(ET.tostring(geom))
        for material in copy.findall("material"):
            copy.remove(material)
        material = ET.SubElement(copy, "material", name=f"{path.stem}_{i}_{rgba[0]:02x}{rgba[1]:02x}{rgba[2]:02x}")
        ET.SubElement(material, "color", rgba=" ".join(f"{c / 255:.3f}" for c in rgba))
        out.append(copy)
    return out


def mesh_cache_dir() -> pathlib.Path:
    """Where converted meshes are kept: ``$JTRAJ_MESH_CACHE`` or ``~/.cache/jtraj/meshes``."""
    if os.environ.get("JTRAJ_MESH_CACHE"):
        return pathlib.Path(os.environ["JTRAJ_MESH_CACHE"]).expanduser()  # as JTRAJ_CACHE_DIR: "~/x" made a folder named "~"
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return pathlib.Path(base) / "jtraj" / "meshes"


@functools.lru_cache(maxsize=None)
def _collada_parts(path: pathlib.Path) -> tuple[tuple[pathlib.Path, tuple[int, int, int, int]], ...]:
    """The parts of a Collada (.dae) mesh as OBJ files MuJoCo reads, with their RGBA (0-255).

    MuJoCo cannot read Collada; trimesh (with pycollada) converts it, once per file: the OBJ
    files are cached under `mesh_cache_dir`, keyed by the source's path, size and time stamp.
    Without trimesh the mesh is skipped (returns no parts) with a warning naming the extra.
    """
    stat = path.stat()
    key = hashlib.sha1(f"{path.resolve()}:{stat.st_size}:{stat.st_mtime_ns}".encode()).hexdigest()[:16]
    folder = mesh_cache_dir() / f"{path.stem}-{key}"
    index = folder / "parts.json"
    if index.is_file():
        entries = json.loads(index.read_text())
        return tuple((folder / e["file"], tuple(e["rgba"])) for e in entries)
    try:
        import trimesh
    except ImportError:
        warnings.warn(
            f"{path.name}: Collada meshes need trimesh and pycollada to be drawn "
            "(`pip install 'jtraj[render]'`); drawing this link without its visual mesh",
            stacklevel=2,
        )
        return ()
    try:
        # Each geometry of the scene, with the scene graph's transforms applied.
        geometries = trimesh.load(str(path), force="scene").dump()
    except Exception as err:  # trimesh raises a variety of parser errors
        raise RobotLoadError(f"cannot convert Collada mesh {path} with trimesh: {err}") from err
    # Write into a temporary folder, then rename: concurrent loads never see half a cache entry.
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = pathlib.Path(tempfile.mkdtemp(dir=folder.parent, prefix=f".{path.stem}-"))
    entries = []
    for i, g in enumerate(geometries):
        if len(g.faces) == 0:
            continue
        material = getattr(g.visual, "material", None)
        rgba = getattr(material, "main_color", None)
        if rgba is None:
            rgba = np.asarray(g.visual.main_color) if hasattr(g.visual, "main_color") else (200, 200, 200, 255)
        # MuJoCo names meshes after their file stem: the stems must be unique across files.
        name = f"{path.stem}_{key[:6]}_part{i}.obj"
        # Geometry only: MuJoCo takes the color from the URDF material written beside it.
        trimesh.Trimesh(vertices=g.vertices, faces=g.faces, process=False).export(tmp / name)
        entries.append({"file": name, "rgba": [int(c) for c in rgba]})
    (tmp / "parts.json").write_text(json.dumps(entries))
    try:
        tmp.rename(folder)
    except OSError:  # another process finished first: use its copy
        shutil.rmtree(tmp, ignore_errors=True)
    return tuple((folder / e["file"], tuple(e["rgba"])) for e in entries)


def _spec(text: str, source: pathlib.Path, urdf_path: pathlib.Path) -> mujoco.MjSpec:
    """The URDF text as a MuJoCo spec, with the free joint added to the root body."""
    try:
        spec = mujoco.MjSpec.from_string(text)
    except ValueError as err:  # MuJoCo raises ValueError on parse and compile errors
        raise RobotLoadError(f"{source}: MuJoCo could not load URDF {urdf_path}: {err}") from err
    root_body = spec.worldbody.first_body()
    if root_body is None:
        raise RobotLoadError(f"{source}: MuJoCo could not load URDF {urdf_path}: the model has no body")
    free = root_body.add_freejoint()
    free.name = _FREE_JOINT_NAME
    return spec


def _compile(text: str, source: pathlib.Path, urdf_path: pathlib.Path) -> mujoco.MjModel:
    spec = _spec(text, source, urdf_path)
    try:
        return spec.compile()
    except ValueError as err:
        raise RobotLoadError(f"{source}: MuJoCo could not load URDF {urdf_path}: {err}") from err


def _link_in_body(
    urdf: _Urdf,
    locked: tuple[str, ...],
    model: mujoco.MjModel,
    link: str,
    source: pathlib.Path,
    what: str,
) -> tuple[int, np.ndarray, np.ndarray]:
    """(body id, R_body_link, p_body_link) of a URDF link: the link itself if MuJoCo kept it
    as a body, else its closest ancestor through fixed joints."""
    if link not in urdf.links:
        raise RobotLoadError(
            f"{source}: {what} is on link {link!r}, which is not a link of {urdf.path}; "
            f"expected one of: {', '.join(urdf.links)}"
        )
    R, p = np.eye(3), np.zeros(3)
    current = link
    while True:
        body_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, current)
        if body_id >= 0:
            return body_id, R, p
        joint = urdf.parent_joint.get(current)
        if joint is None or (joint.get("type") != "fixed" and joint.get("name") not in locked):
            raise RobotLoadError(f"{source}: link {current!r} has no MuJoCo body and no fixed parent joint")
        try:
            R_j, p_j = _origin(joint)
        except ValueError as err:
            raise RobotLoadError(f"{source}: <origin> of joint {joint.get('name')!r} of {urdf.path}: {err}") from err
        # T_parent_link = T_joint-origin T_current_link
        R, p = R_j @ R, R_j @ p + p_j
        current = joint.find("parent").get("link")


def _limits(urdf: _Urdf, joint_names: tuple[str, ...]) -> tuple[np.ndarray, ...]:
    lower, upper, velocity, effort = (np.empty(len(joint_names)) for _ in range(4))
    for i, name in enumerate(joint_names):
        joint = urdf.joints[name]
        limit = joint.find("limit")
        continuous = joint.get("type") == "continuous"

        def get(key, default, limit=limit):
            return float(limit.get(key)) if limit is not None and limit.get(key) is not None else default

        lower[i] = -np.inf if continuous else get("lower", -np.inf)
        upper[i] = np.inf if continuous else get("upper", np.inf)
        velocity[i] = get("velocity", np.inf)
        effort[i] = get("effort", np.inf)
    return lower, upper, velocity, effort


def _readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


# ----------------------------------------------------------------------------------------
# Building a Robot


def _require(config: Mapping, key: str, kind: type, source: pathlib.Path, where: str = ""):
    if key not in config:
        raise RobotLoadError(f"{source}: missing key {where}{key!r}")
    value = config[key]
    if not isinstance(value, kind):
        raise RobotLoadError(f"{source}: {where}{key!r} must be a {kind.__name__}, got {value!r}")
    return value


def _vector(value: Any, n: int, source: pathlib.Path, what: str) -> np.ndarray:
    """``value`` as ``n`` floats; each element a number (np.asarray took true as 1.0 and "1" as 1.0)."""
    items = list(value) if isinstance(value, (list, tuple, np.ndarray)) else None
    if items is None or len(items) != n or not all(is_real(x) and np.isfinite(x) for x in items):
        raise RobotLoadError(f"{source}: {what} must be {n} finite numbers, got {value!r}")
    return np.array(items, dtype=np.float64)


#: The keys a robot file may have, at its top level and in its tables.
_KEYS = {
    "": ("name", "extends", "urdf", "locked_joints", "expected_joints", "standing", "contact", "groups"),
    "standing.": ("base_xyz", "base_wxyz", "joints"),
    "contact[].": ("name", "link", "offset"),
}


def _check_keys(table: Any, where: str, source: pathlib.Path) -> None:
    allowed = _KEYS[where]
    if not isinstance(table, Mapping):
        raise RobotLoadError(f"{source}: {where.rstrip('.') or 'the file'} must be a table, got {table!r}")
    for key in table:
        if key not in allowed:
            close = difflib.get_close_matches(key, allowed, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise RobotLoadError(f"{source}: unknown key {where}{key!r}{hint} (expected {', '.join(where + k for k in allowed)})")


def _strings(value: Any, source: pathlib.Path, what: str) -> tuple[str, ...]:
    """A list of names (a lone string is refused: it would be read letter by letter)."""
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
        raise RobotLoadError(f"{source}: {what} must be a list of names, got {value!r}")
    return tuple(value)


def _build(config: Mapping, source: pathlib.Path) -> Robot:
    _check_keys(config, "", source)
    name = config.get("name", source.stem)
    if not isinstance(name, str) or not name:
        raise RobotLoadError(f"{source}: 'name' must be a nonempty string, got {name!r}")
    urdf_rel = _require(config, "urdf", str, source)
    urdf_path = robots_data_dir() / urdf_rel
    if not urdf_path.is_file():
        raise RobotLoadError(
            f"{source}: URDF {urdf_rel!r} not found; expected a path relative to {robots_data_dir()} "
            f"(e.g. 'talos_data/robots/talos_reduced.urdf')"
        )
    urdf = _parse_urdf(urdf_path, source)

    locked = _strings(config.get("locked_joints", []), source, "'locked_joints'")
    for joint in locked:
        if joint not in urdf.joints:
            raise RobotLoadError(
                f"{source}: locked joint {joint!r} is not a joint of {urdf_path}; "
                f"expected one of: {', '.join(urdf.joints)}"
            )
    return _assemble(config, source, name, urdf_path, urdf, locked)


def _assemble(config, source, name, urdf_path, urdf, locked) -> Robot:
    model = _compile(_mujoco_urdf_string(urdf, locked, keep_geometry=False), source, urdf_path)
    # The formulation is pure rigid-body dynamics.
    model.dof_damping[:] = 0.0
    model.dof_armature[:] = 0.0
    model.dof_frictionloss[:] = 0.0
    model.jnt_stiffness[:] = 0.0
    # MuJoCo warns of a NaN in the URDF on stdout and loads it
    for field in ("body_pos", "body_quat", "body_ipos", "body_iquat", "body_mass", "body_inertia", "jnt_pos", "jnt_axis", "qpos0"):
        if not np.all(np.isfinite(getattr(model, field))):
            raise RobotLoadError(f"{source}: {urdf_path} has a number that is not finite (NaN or inf) in MuJoCo's {field}")

    free = mujoco.mjtJoint.mjJNT_FREE
    hinge = mujoco.mjtJoint.mjJNT_HINGE
    if model.njnt < 1 or model.jnt_type[0] != free:
        raise RobotLoadError(f"{source}: expected the free joint first in the MuJoCo model of {urdf_path}")
    joint_names = []
    for j in range(1, model.njnt):
        jname = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j)
        if model.jnt_type[j] != hinge:
            kind = mujoco.mjtJoint(model.jnt_type[j]).name
            raise RobotLoadError(
                f"{source}: joint {jname!r} of {urdf_path} has MuJoCo type {kind}; "
                "only revolute joints are supported"
            )
        joint_names.append(jname)
    joint_names = tuple(joint_names)

    expected_nj = config.get("expected_joints")
    if expected_nj is not None and (not is_whole(expected_nj) or expected_nj < 0):
        raise RobotLoadError(f"{source}: 'expected_joints' must be a whole number >= 0, got {expected_nj!r}")
    if expected_nj is not None and expected_nj != len(joint_names):
        raise RobotLoadError(
            f"{source}: {urdf_path} with locked joints {list(locked)} has {len(joint_names)} joints, "
            f"expected {expected_nj}"
        )

    # Contact points.
    contacts: list[ContactPoint] = []
    entries = config.get("contact", [])
    if not isinstance(entries, list):
        raise RobotLoadError(f"{source}: 'contact' must be an array of tables ([[contact]]), got {entries!r}")
    for i, entry in enumerate(entries):
        where = f"contact[{i}]."
        _check_keys(entry, "contact[].", source)
        cname = _require(entry, "name", str, source, where)
        link = _require(entry, "link", str, source, where)
        offset = _vector(entry.get("offset", [0.0, 0.0, 0.0]), 3, source, f"{where}offset")
        if not cname.strip():
            raise RobotLoadError(f"{source}: {where}name is empty; expected the contact point's name (groups and messages use it)")
        if cname in (c.name for c in contacts):
            raise RobotLoadError(f"{source}: duplicate contact point name {cname!r}")
        body_id, R_bl, p_bl = _link_in_body(urdf, locked, model, link, source, f"contact point {cname!r}")
        offset_body = R_bl @ offset + p_bl
        contacts.append(
            ContactPoint(
                name=cname,
                link=link,
                offset_link=tuple(float(x) for x in offset),
                body=mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, body_id),
                body_id=int(body_id),
                offset_body=tuple(float(x) for x in offset_body),
            )
        )
    contact_names = [c.name for c in contacts]
    groups: dict[str, tuple[int, ...]] = {}
    group_table = config.get("groups", {})
    if not isinstance(group_table, Mapping):
        raise RobotLoadError(f"{source}: 'groups' must be a table of contact-point lists, got {group_table!r}")
    for gname, members in group_table.items():
        indices = []
        for member in _strings(members, source, f"group {gname!r}"):
            if member not in contact_names:
                raise RobotLoadError(
                    f"{source}: group {gname!r} names contact point {member!r}, which is not declared; "
                    f"expected one of: {', '.join(contact_names)}"
                )
            if contact_names.index(member) in indices:
                raise RobotLoadError(f"{source}: group {gname!r} names contact point {member!r} twice; expected each point once")
            indices.append(contact_names.index(member))
        # a phase touching with an empty group passed the task's "starts in contact" check
        # with no point on the ground
        if not indices:
            raise RobotLoadError(f"{source}: group {gname!r} names no contact point; expected one or more of: {', '.join(contact_names)}")
        groups[gname] = tuple(indices)

    # Standing pose.
    standing = config.get("standing", {})
    _check_keys(standing, "standing.", source)
    base_xyz = _vector(standing.get("base_xyz", [0.0, 0.0, 0.0]), 3, source, "standing.base_xyz")
    base_wxyz = _vector(standing.get("base_wxyz", [1.0, 0.0, 0.0, 0.0]), 4, source, "standing.base_wxyz")
    # its norm computed scaled: [1e200, 1e200, 0, 0] had the norm inf, and normalized to zeros
    unit, norm = unit_and_length(base_wxyz)
    if not 1e-6 < norm < np.inf:
        raise RobotLoadError(f"{source}: standing.base_wxyz must be a nonzero quaternion (w, x, y, z) of finite norm, got {base_wxyz.tolist()}")
    base_wxyz = unit
    q_standing = np.zeros(len(joint_names))
    joints_table = standing.get("joints", {})
    if not isinstance(joints_table, Mapping):
        raise RobotLoadError(f"{source}: standing.joints must be a table of joint angles, got {joints_table!r}")
    for jname, value in joints_table.items():
        if jname not in joint_names:
            raise RobotLoadError(
                f"{source}: standing.joints names {jname!r}, which is not an actuated joint; "
                f"expected one of: {', '.join(joint_names)}"
            )
        if not is_real(value) or not np.isfinite(value):
            raise RobotLoadError(f"{source}: standing.joints.{jname} must be a finite number (rad), got {value!r}")
        q_standing[joint_names.index(jname)] = float(value)

    lower, upper, velocity, effort = _limits(urdf, joint_names)
    for j, jname in enumerate(joint_names):
        # NaN fails these comparisons too: every bound of the NLP is built from them
        if not lower[j] <= upper[j]:
            raise RobotLoadError(f"{source}: joint {jname!r} of {urdf_path} has limit lower={lower[j]:g} above upper={upper[j]:g}")
        if not (velocity[j] >= 0 and effort[j] >= 0):
            raise RobotLoadError(
                f"{source}: joint {jname!r} of {urdf_path} has limit velocity={velocity[j]:g}, effort={effort[j]:g}; both must be >= 0"
            )
        # every task fixes its first knot at the standing joints and keeps all knots within the
        # limits: such a robot could solve nothing (a joint the file does not state stands at 0)
        if not lower[j] <= q_standing[j] <= upper[j]:
            said = f"standing.joints.{jname} = {q_standing[j]:g}" if jname in joints_table else f"standing joint {jname!r} (not in standing.joints: 0)"
            raise RobotLoadError(f"{source}: {said} is outside its limits [{lower[j]:g}, {upper[j]:g}] rad in {urdf_path}")
    return Robot(
        name=name,
        source=source,
        urdf_path=urdf_path,
        mj_model=model,
        mjx_model=mjx.put_model(model),
        joint_names=joint_names,
        locked_joints=locked,
        contacts=tuple(contacts),
        contact_groups=MappingProxyType(groups),
        q_joints_standing=_readonly(q_standing),
        base_xyz_wxyz_standing=_readonly(np.concatenate([base_xyz, base_wxyz])),
        q_lower=_readonly(lower),
        q_upper=_readonly(upper),
        v_max=_readonly(velocity),
        tau_max=_readonly(effort),
        total_mass=float(np.sum(model.body_mass)),
        gravity=float(-model.opt.gravity[2]),
    )


def render_spec(robot: Robot) -> mujoco.MjSpec:
    """The MuJoCo spec of `load_render_model`, for callers that add scenery (a floor, lights,
    textures) before compiling it with `compile_render_spec`."""
    urdf = _parse_urdf(robot.urdf_path, robot.source)
    text = _mujoco_urdf_string(urdf, robot.locked_joints, keep_geometry=True, mesh_root=robots_data_dir())
    return _spec(text, robot.source, robot.urdf_path)


def compile_render_spec(robot: Robot, spec: mujoco.MjSpec) -> mujoco.MjModel:
    """Compiles a `render_spec` (possibly with scenery added) and checks that the robot's
    ``qpos`` layout is unchanged."""
    try:
        model = spec.compile()
    except ValueError as err:
        raise RobotLoadError(f"{robot.source}: MuJoCo could not compile the render model of {robot.urdf_path}: {err}") from err
    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, mujoco.mj_id2name(robot.mj_model, mujoco.mjtObj.mjOBJ_BODY, 1))
    if model.nq != robot.mj_model.nq or body != 1 or model.jnt_type[0] != mujoco.mjtJoint.mjJNT_FREE:
        raise RobotLoadError(
            f"{robot.source}: render model of {robot.urdf_path} has nq={model.nq} and its root body at id {body}, "
            f"expected nq={robot.mj_model.nq} with the robot's root body first"
        )
    return model


def load_render_model(robot: Robot) -> mujoco.MjModel:
    """A MuJoCo model of ``robot`` with the meshes it can load, for rendering.

    Same bodies and joints as ``robot.mj_model`` (same ``qpos`` layout); visual and collision
    geometry whose mesh files exist in a format MuJoCo reads are kept, Collada (.dae) visuals
    are converted to OBJ once and cached (`mesh_cache_dir`; needs trimesh and pycollada, the
    ``render`` extra), the rest is skipped. URDF visuals are geom group 1, collisions group 0.
    Dynamics never uses this model.
    """
    model = compile_render_spec(robot, render_spec(robot))
    if model.nbody != robot.mj_model.nbody:
        raise RobotLoadError(
            f"{robot.source}: render model of {robot.urdf_path} has {model.nbody} bodies, expected {robot.mj_model.nbody}"
        )
    return model


def to_pinocchio(robot: Robot):
    """The same robot as a Pinocchio model, for oracles and benchmarks (needs ``pin``).

    Built from the same URDF with a free-flyer root, the locked joints removed at 0, and one
    operational frame per contact point (in declaration order). Returns
    ``(model, frame_ids, q_index, v_index)``: the Pinocchio ``q`` / ``v`` index of each of
    ``robot.joint_names``.
    """
    import pinocchio as pin

    full = pin.buildModelFromUrdf(str(robot.urdf_path), pin.JointModelFreeFlyer())
    locked = [full.getJointId(n) for n in robot.locked_joints]
    model = pin.buildReducedModel(full, locked, pin.neutral(full)) if locked else full
    frames = []
    for c in robot.contacts:
        link_frame = model.getFrameId(c.link)
        placement = model.frames[link_frame].placement * pin.SE3(np.eye(3), np.array(c.offset_link))
        parent_joint = model.frames[link_frame].parentJoint
        frame = pin.Frame(f"contact_{c.name}", parent_joint, link_frame, placement, pin.FrameType.OP_FRAME)
        frames.append(model.addFrame(frame))
    joints = [model.joints[model.getJointId(n)] for n in robot.joint_names]
    q_index = np.array([j.idx_q for j in joints])
    v_index = np.array([j.idx_v for j in joints])
    return model, frames, q_index, v_index
