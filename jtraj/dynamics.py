"""Rigid-body inverse dynamics, contact kinematics and their derivatives, in pure JAX.

Every function takes ONE configuration (no knot axis) unless its name says otherwise; use
`jax.vmap` for batches. The robot and the parameterization are static (hashable) arguments.

Conventions (Pinocchio's free flyer):
    q = [q_base (param.nq coordinates of the parameterization), q_joints (nj)]
    v = [V_b (6): linear then angular velocity of the base, both in the base frame,
         joint rates (nj)]
    a = dv/dt (the body-frame spatial acceleration of the base, then joint accelerations)
    forces (ncontact, 3): world-frame forces applied at the robot's contact points
    tau = M(q) a + b(q, v) - sum_j J_j(q)^T f_j, shape (nv,) with nv = 6 + nj;
          tau[:6] is the base wrench in the base frame (force then torque, N and N m),
          tau[6:] the joint torques (N m).

The algorithm is the recursive Newton-Euler algorithm written in world ("absolute")
coordinates, as Pinocchio's derivative algorithms are: spatial vectors are expressed in the
world frame at the world origin, ordered (linear, angular). Only forward kinematics is
recursive (one batched op per tree depth level); velocities, accelerations and composite
forces are sums over ancestors or subtrees, computed as products with constant 0/1 tree
matrices. The same quantities give
the analytical derivatives of tau with respect to q and v (the world-frame formulation of
Carpentier & Mansard, RSS 2018, derived here for this layout): each column k of dtau/dq is a
rigid motion of the subtree of dof k (which leaves J_i^T F_i unchanged where both move) plus
the change of the velocities and accelerations it induces, so both Jacobians come out as a
handful of dense products instead of forward-mode autodiff through the recursion.

The model arrays are read from ``robot.mjx_model`` once per robot and baked in as constants,
except the body masses: every function that uses inertias takes an optional ``masses``
(nbody,) in kg, one per MuJoCo body (``robot.mj_model.body_mass`` order, the world body 0
first), a traced array (so a change does not recompile and derivatives with respect to it
exist). A body of mass ``m`` keeps the model's centre of mass and scales its rotational
inertia by ``m / m_model`` (the link's shape and density distribution are kept: the
spatial inertia of the body is the model's times ``m / m_model``). ``masses=None`` is the
model's masses.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from jaxlie import SO3

from jtraj.deprecation import warn_renamed
from jtraj.lie import skew as _skew
from jtraj.parameterization import AbstractParameterization, body_twist_to_qvel
from jtraj.robot import Robot, mjx  # jtraj.robot imports MJX quietly

__all__ = [
    "inverse_dynamics",
    "inverse_dynamics_mjx",
    "contact_positions",
    "contact_jacobians",
    "contact_position_jacobians",
    "mass_matrix",
    "acceleration_force_jacobians",
    "inverse_dynamics_derivatives",
    "batched_inverse_dynamics_derivatives",
    "InverseDynamicsJacobians",
    "model_masses",
    "to_mujoco",
    "tau_from_mujoco",
]


# ----------------------------------------------------------------------------------------
# Static tree structure, computed once per robot on the host.


@dataclasses.dataclass(frozen=True, eq=False)
class _Tree:
    nbody: int  # including the world body 0
    nj: int
    nv: int
    parent: np.ndarray  # (nbody,)
    levels: tuple[np.ndarray, ...]  # body ids at depth 2, 3, ... (depth 1 = the base)
    level_parent_slot: tuple[np.ndarray, ...]  # position of each level's parents in the level above
    level_order: np.ndarray  # (nbody,) position of each body in the concatenated levels
    base: int  # body id of the floating base
    R_parent_body: np.ndarray  # (nbody, 3, 3) body frame in parent frame at q = 0
    p_parent_body: np.ndarray  # (nbody, 3)
    hinge_axis: np.ndarray  # (nbody, 3) in the body frame, 0 where the body has no hinge
    hinge_anchor: np.ndarray  # (nbody, 3) in the body frame
    hinge_q: np.ndarray  # (nbody,) index into q_joints, or nj (a padding zero) if none
    hinge_q0: np.ndarray  # (nbody,) MuJoCo qpos0 of the hinge
    joint_body: np.ndarray  # (nj,) body of each joint
    dof_body: np.ndarray  # (nv,)
    dof_parent: np.ndarray  # (nv,) parent body of the dof's body
    mass: np.ndarray  # (nbody,)
    com_body: np.ndarray  # (nbody, 3) centre of mass in the body frame
    inertia_body: np.ndarray  # (nbody, 3, 3) rotational inertia about the com, body axes
    ancestor_dofs: np.ndarray  # (nbody, nv): 1 where the dof moves the body
    subtree: np.ndarray  # (nbody, nbody): [a, b] = 1 if b is in the subtree of a
    lower: np.ndarray  # (nv, nv) bool: body(k) is an ancestor of body(i) or the same
    upper: np.ndarray  # (nv, nv) bool: body(k) is a strict descendant of body(i)
    contact_body: np.ndarray  # (ncontact,)
    contact_offset: np.ndarray  # (ncontact, 3)
    contact_incidence: np.ndarray  # (nbody, ncontact)
    contact_dofs: np.ndarray  # (ncontact, nv): 1 where the dof moves the contact point
    gravity: np.ndarray  # (3,) world gravity vector


def model_masses(robot: Robot) -> np.ndarray:
    """The model's body masses (nbody,) in kg, world body first: the default ``masses``."""
    return np.array(_tree(robot).mass)


def _quat_to_mat(wxyz: np.ndarray) -> np.ndarray:
    m = np.zeros(9)
    mujoco.mju_quat2Mat(m, np.asarray(wxyz, dtype=np.float64))
    return m.reshape(3, 3)


@functools.lru_cache(maxsize=None)
def _tree(robot: Robot) -> _Tree:
    m = robot.mjx_model
    parent = np.asarray(m.body_parentid)
    nbody = parent.shape[0]
    jnt_type = np.asarray(m.jnt_type)
    jnt_body = np.asarray(m.jnt_bodyid)
    jnt_qposadr = np.asarray(m.jnt_qposadr)
    if jnt_type[0] != mujoco.mjtJoint.mjJNT_FREE:
        raise ValueError(f"robot {robot.name!r}: expected a free joint first")
    base = int(jnt_body[0])
    nj = robot.nj
    nv = 6 + nj

    depth = np.zeros(nbody, dtype=int)
    for b in range(1, nbody):
        if parent[b] >= b:
            raise ValueError(f"robot {robot.name!r}: bodies are not in topological order")
        depth[b] = depth[parent[b]] + 1
    if np.any(depth[1:] < 1) or np.sum(depth == 1) != 1 or depth[base] != 1:
        raise ValueError(f"robot {robot.name!r}: expected a single floating root body")
    levels = tuple(np.flatnonzero(depth == d) for d in range(2, depth.max() + 1))
    previous = [np.array([0]), np.array([base])] + list(levels)
    level_parent_slot = tuple(
        np.searchsorted(previous[i + 1], parent[level]) for i, level in enumerate(levels)
    )
    level_order = np.argsort(np.concatenate(previous))

    R_parent_body = np.stack([_quat_to_mat(q) for q in np.asarray(m.body_quat)])
    p_parent_body = np.asarray(m.body_pos, dtype=np.float64)
    hinge_axis = np.zeros((nbody, 3))
    hinge_anchor = np.zeros((nbody, 3))
    hinge_q = np.full(nbody, nj)
    hinge_q0 = np.zeros(nbody)
    joint_body = np.zeros(nj, dtype=int)
    qpos0 = np.asarray(m.qpos0)
    for j in range(1, jnt_type.shape[0]):
        b = jnt_body[j]
        if hinge_q[b] != nj:
            raise ValueError(f"robot {robot.name!r}: body {b} has more than one joint")
        k = jnt_qposadr[j] - 7
        hinge_axis[b] = np.asarray(m.jnt_axis)[j]
        hinge_anchor[b] = np.asarray(m.jnt_pos)[j]
        hinge_q[b] = k
        hinge_q0[b] = qpos0[jnt_qposadr[j]]
        joint_body[k] = b
    dof_body = np.concatenate([np.full(6, base), joint_body])
    dof_parent = parent[dof_body]

    inertia_body = np.stack(
        [
            _quat_to_mat(q) @ np.diag(d) @ _quat_to_mat(q).T
            for q, d in zip(np.asarray(m.body_iquat), np.asarray(m.body_inertia))
        ]
    )

    ancestors = np.zeros((nbody, nbody), dtype=bool)  # [b, a]: a is an ancestor of b or b
    for b in range(1, nbody):
        ancestors[b] = ancestors[parent[b]]
        ancestors[b, b] = True
    subtree = ancestors.T.astype(np.float64)
    ancestor_dofs = ancestors[:, dof_body].astype(np.float64)
    lower = ancestors[dof_body][:, dof_body]
    upper = ancestors[dof_body][:, dof_body].T & (dof_body[:, None] != dof_body[None, :])

    contact_body = robot.contact_body_ids
    contact_incidence = np.zeros((nbody, robot.ncontact))
    contact_incidence[contact_body, np.arange(robot.ncontact)] = 1.0
    return _Tree(
        nbody=nbody,
        nj=nj,
        nv=nv,
        parent=parent,
        levels=levels,
        level_parent_slot=level_parent_slot,
        level_order=level_order,
        base=base,
        R_parent_body=R_parent_body,
        p_parent_body=p_parent_body,
        hinge_axis=hinge_axis,
        hinge_anchor=hinge_anchor,
        hinge_q=hinge_q,
        hinge_q0=hinge_q0,
        joint_body=joint_body,
        dof_body=dof_body,
        dof_parent=dof_parent,
        mass=np.asarray(m.body_mass, dtype=np.float64),
        com_body=np.asarray(m.body_ipos, dtype=np.float64),
        inertia_body=inertia_body,
        ancestor_dofs=ancestor_dofs,
        subtree=subtree,
        lower=lower,
        upper=upper,
        contact_body=contact_body,
        contact_offset=robot.contact_offsets,
        contact_incidence=contact_incidence,
        contact_dofs=ancestor_dofs[contact_body],
        gravity=np.asarray(m.opt.gravity, dtype=np.float64),
    )


# ----------------------------------------------------------------------------------------
# Spatial algebra, world frame, (linear, angular) ordering.


# Position of entry (a, b) of a symmetric 6x6 matrix in its packed upper triangle.
_SYM6 = np.zeros((6, 6), dtype=int)
_SYM6[np.triu_indices(6)] = np.arange(21)
_SYM6 = np.maximum(_SYM6, _SYM6.T)


def _motion_cross(m1: jax.Array, m2: jax.Array) -> jax.Array:
    """``m1 x m2`` for motion vectors along the last axis (6,)."""
    v1, w1, v2, w2 = m1[..., :3], m1[..., 3:], m2[..., :3], m2[..., 3:]
    return jnp.concatenate([jnp.cross(w1, v2) + jnp.cross(v1, w2), jnp.cross(w1, w2)], axis=-1)


def _force_cross(m: jax.Array, f: jax.Array) -> jax.Array:
    """``m x* f`` (motion acting on force) along the last axis."""
    v, w, fl, n = m[..., :3], m[..., 3:], f[..., :3], f[..., 3:]
    return jnp.concatenate([jnp.cross(w, fl), jnp.cross(w, n) + jnp.cross(v, fl)], axis=-1)


def _fbar(f: jax.Array) -> jax.Array:
    """6x6 matrix with ``x x* f == -fbar(f) x`` (antisymmetric)."""
    Fl, N = _skew(f[..., :3]), _skew(f[..., 3:])
    Z = jnp.zeros_like(Fl)
    return jnp.concatenate([jnp.concatenate([Z, Fl], -1), jnp.concatenate([Fl, N], -1)], -2)


def _matvec(A: jax.Array, x: jax.Array) -> jax.Array:
    """``A x`` over leading axes. Written as an unrolled sum of products: XLA:CPU runs many
    tiny batched dot products (and small reductions) far slower than elementwise code."""
    out = A[..., :, 0] * x[..., None, 0]
    for k in range(1, A.shape[-1]):
        out = out + A[..., :, k] * x[..., None, k]
    return out


def _matmul(A: jax.Array, B: jax.Array) -> jax.Array:
    """``A B`` for small matrices over leading axes, unrolled (see `_matvec`)."""
    out = A[..., :, 0, None] * B[..., None, 0, :]
    for k in range(1, A.shape[-1]):
        out = out + A[..., :, k, None] * B[..., None, k, :]
    return out


def _rotation_about(axis: jax.Array, angle: jax.Array) -> jax.Array:
    """Rodrigues: rotation by ``angle`` about unit ``axis``, batched:
    ``cos 1 + sin [a] + (1 - cos) a a^T``."""
    s, c = jnp.sin(angle)[..., None, None], jnp.cos(angle)[..., None, None]
    return c * jnp.eye(3) + s * _skew(axis) + (1.0 - c) * (axis[..., :, None] * axis[..., None, :])


# ----------------------------------------------------------------------------------------
# Kinematics


class _Kinematics(NamedTuple):
    R: jax.Array  # (nbody, 3, 3) world orientation of each body
    p: jax.Array  # (nbody, 3) world position of each body origin
    J: jax.Array  # (6, nv) world-frame motion subspace of each dof


def _array(value: jax.Array) -> jax.Array:
    """``value`` (an array or a list, as the public functions take it) as a JAX float array:
    reading ``.shape`` of a list was an AttributeError."""
    a = jnp.asarray(value)
    return a if jnp.issubdtype(a.dtype, jnp.floating) else a.astype(float)


def _split(robot: Robot, param: AbstractParameterization, q: jax.Array) -> tuple[jax.Array, jax.Array]:
    expected = param.nq + robot.nj
    q = _array(q)
    if q.shape != (expected,):
        raise ValueError(
            f"q has shape {q.shape}; expected ({expected},) = {param.nq} base coordinates of "
            f"{param!r} + {robot.nj} joints of {robot.name!r}"
        )
    return q[: param.nq], q[param.nq :]


def _kinematics(robot: Robot, param: AbstractParameterization, q: jax.Array) -> _Kinematics:
    tree = _tree(robot)
    q = _array(q)  # a list, as the public functions take it: its dtype is read below
    q_base, q_joints = _split(robot, param, q)
    T = param.to_pose(q_base)
    R_base, p_base = T.rotation().as_matrix(), T.translation()

    # Local transforms of every body (parent frame), one batched op.
    angle = jnp.concatenate([q_joints, jnp.zeros((1,), q.dtype)])[tree.hinge_q] - tree.hinge_q0
    R_hinge = _rotation_about(jnp.asarray(tree.hinge_axis), angle)
    R_loc = _matmul(jnp.asarray(tree.R_parent_body), R_hinge)
    # off-centre hinge: the anchor stays fixed
    anchor = jnp.asarray(tree.hinge_anchor)
    shift = anchor - _matvec(R_hinge, anchor)
    p_loc = jnp.asarray(tree.p_parent_body) + _matvec(jnp.asarray(tree.R_parent_body), shift)

    # Depth by depth, each level one batched composition with its parents (in the previous
    # level); the levels are put back in body order with one gather at the end.
    Rs = [jnp.eye(3, dtype=q.dtype)[None], R_base[None]]
    ps = [jnp.zeros((1, 3), q.dtype), p_base[None]]
    for level, parent_slot in zip(tree.levels, tree.level_parent_slot):
        R_par, p_par = Rs[-1][parent_slot], ps[-1][parent_slot]
        Rs.append(_matmul(R_par, R_loc[level]))
        ps.append(p_par + _matvec(R_par, p_loc[level]))
    R = jnp.concatenate(Rs)[tree.level_order]
    p = jnp.concatenate(ps)[tree.level_order]

    # Motion subspace, world frame at the world origin.
    # Base: J = Ad_T maps the body twist to the world spatial velocity.
    Z = jnp.zeros((3, 3), q.dtype)
    J_base = jnp.concatenate(
        [jnp.concatenate([R_base, _matmul(_skew(p_base), R_base)], 1), jnp.concatenate([Z, R_base], 1)], 0
    )
    jb = tree.joint_body
    omega = _matvec(R[jb], jnp.asarray(tree.hinge_axis[jb]))
    anchor_world = p[jb] + _matvec(R[jb], jnp.asarray(tree.hinge_anchor[jb]))
    J_joints = jnp.concatenate([jnp.cross(anchor_world, omega), omega], axis=-1).T
    return _Kinematics(R, p, jnp.concatenate([J_base, J_joints], axis=1))


def _contact_points(tree: _Tree, kin: _Kinematics) -> jax.Array:
    b = tree.contact_body
    return kin.p[b] + _matvec(kin.R[b], jnp.asarray(tree.contact_offset))


def _point_jacobians(tree: _Tree, kin: _Kinematics, points: jax.Array) -> jax.Array:
    # velocity of a point p: v_o + w x p = J_lin - p x J_ang
    J_lin, J_ang = kin.J[:3], kin.J[3:]
    Jp = J_lin.T[None] + jnp.cross(J_ang.T[None], points[:, None, :])  # (ncontact, nv, 3)
    return jnp.swapaxes(Jp, -1, -2) * jnp.asarray(tree.contact_dofs)[:, None, :]


def contact_positions(robot: Robot, param: AbstractParameterization, q: jax.Array) -> jax.Array:
    """World positions of all contact points (m), shape (ncontact, 3)."""
    tree = _tree(robot)
    return _contact_points(tree, _kinematics(robot, param, q))


def contact_jacobians(robot: Robot, param: AbstractParameterization, q: jax.Array) -> jax.Array:
    """World-frame point Jacobians, shape (ncontact, 3, nv): ``d p_c/dt = J_c v`` with ``v``
    the body-twist generalized velocity (Pinocchio's LOCAL_WORLD_ALIGNED linear rows)."""
    tree = _tree(robot)
    kin = _kinematics(robot, param, q)
    return _point_jacobians(tree, kin, _contact_points(tree, kin))


def contact_position_jacobians(robot: Robot, param: AbstractParameterization, q: jax.Array) -> jax.Array:
    """Jacobians of `contact_positions` with respect to the coordinates ``q``, shape
    (ncontact, 3, param.nq + nj); equal to ``jax.jacfwd(contact_positions, argnums=2)``."""
    tree = _tree(robot)
    kin = _kinematics(robot, param, q)
    Jc = _point_jacobians(tree, kin, _contact_points(tree, kin))
    J_base = _matmul(Jc[..., :6], _local_base_jacobian(param, _split(robot, param, q)[0]))
    return jnp.concatenate([J_base, Jc[..., 6:]], axis=-1)


class _Inertia(NamedTuple):
    """Spatial inertias about the world origin in 10 numbers each (linear in the body data,
    so subtree sums are sums of the parameters): mass m, first moment h = m c, rotational
    inertia Io about the origin; the 6x6 matrix is [[m 1, -[h]], [[h], Io]]."""

    m: jax.Array  # (...,)
    h: jax.Array  # (..., 3)
    Io: jax.Array  # (..., 3, 3)

    def pack(self) -> jax.Array:
        return jnp.concatenate([self.m[..., None], self.h, self.Io.reshape(*self.m.shape, 9)], axis=-1)

    @staticmethod
    def unpack(x: jax.Array) -> "_Inertia":
        return _Inertia(x[..., 0], x[..., 1:4], x[..., 4:13].reshape(*x.shape[:-1], 3, 3))

    def apply(self, x: jax.Array) -> jax.Array:
        """``I x``: momentum (a force) of the motion x (..., 6)."""
        v, w = x[..., :3], x[..., 3:]
        lin = self.m[..., None] * v - jnp.cross(self.h, w)
        ang = jnp.cross(self.h, v) + _matvec(self.Io, w)
        return jnp.concatenate([lin, ang], axis=-1)

    def matrix(self) -> jax.Array:
        H = _skew(self.h)
        top = jnp.concatenate([self.m[..., None, None] * jnp.eye(3), -H], -1)
        return jnp.concatenate([top, jnp.concatenate([H, self.Io], -1)], -2)


def _body_inertias(tree: _Tree, masses: jax.Array | None) -> tuple[jax.Array, jax.Array]:
    """Body masses (nbody,) and rotational inertias about the com in body axes (nbody, 3, 3):
    the model's, or for ``masses`` the model's inertias scaled by ``masses / model mass``."""
    if masses is None:
        return jnp.asarray(tree.mass), jnp.asarray(tree.inertia_body)
    masses = jnp.asarray(masses)
    if masses.shape != tree.mass.shape:
        raise ValueError(f"masses must have shape {tree.mass.shape} (one per MuJoCo body, world first), got {masses.shape}")
    positive = tree.mass > 0
    # massless bodies (the world) keep their (zero) inertia; m / m_model is exactly 1 at the
    # model's masses, so the default masses give the constants' results bit for bit
    scale = jnp.where(positive, masses / np.where(positive, tree.mass, 1.0), 1.0)
    return masses, scale[:, None, None] * jnp.asarray(tree.inertia_body)


def _spatial_inertias(tree: _Tree, kin: _Kinematics, masses: jax.Array | None = None) -> _Inertia:
    """World-frame spatial inertia of each body about the world origin."""
    m, inertia_body = _body_inertias(tree, masses)
    c = kin.p + _matvec(kin.R, jnp.asarray(tree.com_body))
    Ic = _matmul(_matmul(kin.R, inertia_body), jnp.swapaxes(kin.R, -1, -2))
    # Io = Ic - m [c][c] = Ic + m (|c|^2 1 - c c^T)
    cc = jnp.sum(c * c, axis=-1)[..., None, None] * jnp.eye(3) - c[..., :, None] * c[..., None, :]
    return _Inertia(m, m[:, None] * c, Ic + m[:, None, None] * cc)


# ----------------------------------------------------------------------------------------
# Inverse dynamics


class _Rnea(NamedTuple):
    kin: _Kinematics
    I: _Inertia  # body spatial inertias
    ov: jax.Array  # (nbody, 6) body spatial velocities
    oa: jax.Array  # (nbody, 6) body spatial accelerations minus gravity
    h: jax.Array  # (nbody, 6) body momenta
    f_net: jax.Array  # (nbody, 6) body force minus external contact forces
    points: jax.Array  # (ncontact, 3)
    tau: jax.Array  # (nv,)
    forces: jax.Array  # (ncontact, 3), the argument as an array


def _check_rates(robot: Robot, v: jax.Array, a: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(v, a)`` as JAX float arrays (`_array`), checked for shape."""
    nv = robot.nv
    v, a = _array(v), _array(a)
    if v.shape != (nv,) or a.shape != (nv,):
        raise ValueError(f"v and a must have shape ({nv},), got {v.shape} and {a.shape}")
    return v, a


def _check_forces(robot: Robot, forces: jax.Array) -> jax.Array:
    """``forces`` as a JAX float array (`_array`), checked for shape."""
    nc = robot.ncontact
    forces = _array(forces)
    if forces.shape != (nc, 3):
        raise ValueError(
            f"forces must have shape ({nc}, 3) (all contact points of {robot.name!r}), got {forces.shape}"
        )
    return forces


def _rnea(robot, param, q, v, a, forces, masses=None) -> _Rnea:
    tree = _tree(robot)
    v, a = _check_rates(robot, v, a)
    forces = _check_forces(robot, forces)
    kin = _kinematics(robot, param, q)
    anc = jnp.asarray(tree.ancestor_dofs)
    Jt = kin.J.T  # (nv, 6)
    ov = anc @ (Jt * v[:, None])  # (nbody, 6): sum over the dofs above each body
    Jdot_t = _motion_cross(ov[tree.dof_body], Jt)  # (nv, 6)
    minus_g = jnp.concatenate([-jnp.asarray(tree.gravity), jnp.zeros(3)])
    oa = minus_g + anc @ (Jt * a[:, None] + Jdot_t * v[:, None])
    I = _spatial_inertias(tree, kin, masses)
    h = I.apply(ov)
    f = I.apply(oa) + _force_cross(ov, h)
    points = _contact_points(tree, kin)
    f_ext = jnp.concatenate([forces, jnp.cross(points, forces)], axis=-1)  # (nc, 6)
    f_net = f - jnp.asarray(tree.contact_incidence) @ f_ext
    F = jnp.asarray(tree.subtree) @ f_net  # composite forces
    tau = jnp.sum(Jt * F[tree.dof_body], axis=-1)
    return _Rnea(kin, I, ov, oa, h, f_net, points, tau, forces)


def inverse_dynamics(
    robot: Robot,
    param: AbstractParameterization,
    q: jax.Array,
    v: jax.Array,
    a: jax.Array,
    forces: jax.Array,
    masses: jax.Array | None = None,
) -> jax.Array:
    """``tau = M(q) a + b(q, v) - sum_j J_j(q)^T f_j``, shape (nv,).

    Args:
        q: (param.nq + nj,) base coordinates then joint positions (rad).
        v: (nv,) body twist of the base (m/s, rad/s, base frame) then joint rates.
        a: (nv,) time derivative of ``v``.
        forces: (ncontact, 3) world-frame forces (N) at all contact points of the robot
            (zeros for inactive ones).
        masses: (nbody,) body masses (kg), default the model's (see the module docstring).

    Returns:
        tau (nv,): base wrench in the base frame (N, N m), then joint torques (N m); equal
        to Pinocchio's ``rnea`` with the external forces.
    """
    return _rnea(robot, param, q, v, a, forces, masses).tau


def mass_matrix(robot: Robot, param: AbstractParameterization, q: jax.Array, masses: jax.Array | None = None) -> jax.Array:
    """Joint-space inertia matrix ``M(q)`` (nv, nv), body-twist convention for the base;
    ``masses`` (nbody,) as in `inverse_dynamics`."""
    tree = _tree(robot)
    kin = _kinematics(robot, param, q)
    return _mass_matrix(tree, kin, _spatial_inertias(tree, kin, masses))


def _mass_matrix(tree: _Tree, kin: _Kinematics, I: _Inertia) -> jax.Array:
    # M[i, k] = J_i^T Ic J_k with Ic the composite inertia of the deeper of the two dofs.
    Ic = _Inertia.unpack((jnp.asarray(tree.subtree) @ I.pack())[tree.dof_body])
    P = Ic.apply(kin.J.T)  # rows J_i^T Ic_i (Ic symmetric), (nv, 6)
    PJ = P @ kin.J
    return jnp.where(tree.lower, PJ, jnp.where(tree.upper, PJ.T, 0.0))


def acceleration_force_jacobians(
    robot: Robot, param: AbstractParameterization, q: jax.Array, masses: jax.Array | None = None
) -> tuple[jax.Array, jax.Array]:
    """``(dtau/da, dtau/dforces)`` without autodiff: ``M(q)`` (nv, nv) and ``-J_c^T``
    (nv, ncontact * 3), the force columns ordered contact point major, xyz minor (the order
    of ``forces.reshape(-1)``)."""
    tree = _tree(robot)
    kin = _kinematics(robot, param, q)
    M = _mass_matrix(tree, kin, _spatial_inertias(tree, kin, masses))
    Jc = _point_jacobians(tree, kin, _contact_points(tree, kin))
    return M, -Jc.reshape(-1, tree.nv).T


# ----------------------------------------------------------------------------------------
# Derivatives


class InverseDynamicsJacobians(NamedTuple):
    """``tau`` and its Jacobians (a pytree). Shapes for one knot; the batched function adds a
    leading knot axis.

    Attributes:
        tau: (nv,)
        dq: (nv, param.nq + nj), with respect to the coordinates ``q``
        dv: (nv, nv)
        da: (nv, nv), equal to ``M(q)``
        df: (nv, ncontact * 3), equal to ``-J_c(q)^T`` (contact major, xyz minor)
    """

    tau: jax.Array
    dq: jax.Array
    dv: jax.Array
    da: jax.Array
    df: jax.Array


def _local_base_jacobian(param: AbstractParameterization, q_base: jax.Array) -> jax.Array:
    """``d xi / d q_base`` (6, param.nq) with ``T(q + dq) = T(q) Exp(xi)`` to first order."""
    T = param.to_pose(q_base).as_matrix()
    dT = jax.jacfwd(lambda x: param.to_pose(x).as_matrix())(q_base)  # (4, 4, nq)
    R = T[:3, :3]
    d_rho = _matmul(R.T, dT[:3, 3, :])
    W = _matmul(R.T, jnp.moveaxis(dT[:3, :3, :], -1, 0))  # (nq, 3, 3): R^T dR, skew
    d_theta = 0.5 * jnp.stack([W[:, 2, 1] - W[:, 1, 2], W[:, 0, 2] - W[:, 2, 0], W[:, 1, 0] - W[:, 0, 1]])
    return jnp.concatenate([d_rho, d_theta], axis=0)


def inverse_dynamics_derivatives(
    robot: Robot,
    param: AbstractParameterization,
    q: jax.Array,
    v: jax.Array,
    a: jax.Array,
    forces: jax.Array,
    masses: jax.Array | None = None,
) -> InverseDynamicsJacobians:
    """`inverse_dynamics` and its Jacobians for one knot, analytically.

    Equals ``jax.jacfwd(inverse_dynamics, argnums=(2, 3, 4, 5))`` (forces flattened), at a
    fraction of the cost. Shapes in `InverseDynamicsJacobians`.

    Derivation, in the world frame (``J_k`` motion vector of dof k, ``l(k)`` the parent body
    of its body, ``ov``/``oa`` body velocities/accelerations with gravity, ``Ic``/``Bc``/
    ``Ec``/``F`` subtree sums of inertias, velocity operators B, contact operators E and
    forces; ``tau_i = J_i . F_i``):

    - moving ``q_k`` moves the subtree of dof k rigidly by the twist ``J_k``, changes its
      velocities by ``w_k = ov_l(k) x J_k`` and accelerations by
      ``alpha_k = oa_l(k) x J_k + ov_l(k) x w_k``; contact forces keep their world direction.
      For k above i or on the same body, ``J_i . F_i`` is invariant under the rigid motion:
      ``dtau_i/dq_k = J_i . (Ic_i alpha_k + Bc_i w_k + Ec_i J_k)``; for k below i,
      ``dtau_i/dq_k = J_i . (J_k x* F_k + Ic_k alpha_k + Bc_k w_k + Ec_k J_k)``.
    - ``d oa_b/dv_k = c_k + J_k x ov_b`` with ``c_k = (ov_body(k) + ov_l(k)) x J_k``:
      ``dtau_i/dv_k = J_i . (Ic c_k + Bc J_k)`` taken at the deeper of i and k.
    - The base columns come out in the local tangent (``T Exp(xi)``) and are mapped to the
      chart's coordinates with ``d xi / d q_base``.
    """
    tree = _tree(robot)
    nv = tree.nv
    r = _rnea(robot, param, q, v, a, forces, masses)
    J = r.kin.J  # (6, nv)
    Jt = J.T  # (nv, 6): rows are the dofs' world motion vectors
    db, dp = tree.dof_body, tree.dof_parent

    # B: change of a body's force when the velocities change (beyond a rigid motion),
    #   B x = I (x cross ov) + x cross* (I ov) + ov cross* (I x) = (X + X^T) - fbar(h),
    # X = (ov cross*) I; a symmetric part plus an antisymmetric one linear in the momentum h.
    # X's columns are ov cross* (columns of I): cross products, not 6x6 products.
    Imat = r.I.matrix()
    X = jnp.swapaxes(_force_cross(r.ov[:, None, :], jnp.swapaxes(Imat, -1, -2)), -1, -2)
    S = X + jnp.swapaxes(X, -1, -2)
    iu = np.triu_indices(6)
    # Subtree sums of inertias (10 parameters), forces, momenta and S (21 entries): one product.
    stacked = jnp.concatenate([r.I.pack(), r.f_net, r.h, S[:, iu[0], iu[1]]], axis=-1)
    composite = (jnp.asarray(tree.subtree) @ stacked)[db]  # (nv, 46)
    Ic = _Inertia.unpack(composite[:, :13])
    Fc = composite[:, 13:19]
    Bc = composite[:, 25:][:, _SYM6] - _fbar(composite[:, 19:25])  # (nv, 6, 6)
    # E: a contact force keeps its world direction while its point moves with the body:
    #   E = [[0, -[F]], [0, -N]] with F = sum f_c and N = sum [p_c][f_c] over the subtree.
    N_c = _matmul(_skew(r.points), _skew(r.forces))
    csum = jnp.asarray(tree.contact_dofs).T @ jnp.concatenate([r.forces, N_c.reshape(-1, 9)], axis=-1)
    F_sub, N_sub = csum[:, :3], csum[:, 3:].reshape(nv, 3, 3)

    ov_par, oa_par, ov_own = r.ov[dp], r.oa[dp], r.ov[db]
    w = _motion_cross(ov_par, Jt)  # velocity change of the subtree per unit dof motion
    alpha = _motion_cross(oa_par, Jt) + _motion_cross(ov_par, w)  # acceleration change
    c = _motion_cross(ov_own + ov_par, Jt)  # d(acceleration)/d(rate) of the dof
    J_lin, J_ang = Jt[:, :3], Jt[:, 3:]
    E_J = jnp.concatenate([jnp.cross(J_ang, F_sub), -_matvec(N_sub, J_ang)], axis=-1)  # Ec_k J_k
    E_row = jnp.concatenate(  # J_i^T Ec_i
        [jnp.zeros_like(J_lin), jnp.cross(F_sub, J_lin) - _matvec(jnp.swapaxes(N_sub, -1, -2), J_ang)],
        axis=-1,
    )
    P = Ic.apply(Jt)  # rows J_i^T Ic_i
    Q = _matvec(jnp.swapaxes(Bc, -1, -2), Jt)  # rows J_i^T Bc_i

    # dof k an ancestor of dof i (or the same body): the rigid motion of the subtree leaves
    # J_i^T F_i unchanged, only the induced velocity/acceleration changes count.
    Z = jnp.zeros((6, nv), J.dtype)
    lhs = jnp.concatenate([P, Q, E_row], axis=1)  # (nv, 18)
    rhs = jnp.concatenate(
        [
            jnp.concatenate([alpha.T, c.T, J], axis=1),
            jnp.concatenate([w.T, J, Z], axis=1),
            jnp.concatenate([J, Z, Z], axis=1),
        ],
        axis=0,
    )  # (18, 3 nv)
    low = lhs @ rhs
    low_q, low_v, PJ = low[:, :nv], low[:, nv : 2 * nv], low[:, 2 * nv :]
    # dof k a strict descendant of dof i: J_i is fixed, F_i changes by the subtree's change.
    G_q = _force_cross(Jt, Fc) + Ic.apply(alpha) + _matvec(Bc, w) + E_J
    G_v = Ic.apply(c) + _matvec(Bc, Jt)
    up = Jt @ jnp.concatenate([G_q.T, G_v.T], axis=1)
    up_q, up_v = up[:, :nv], up[:, nv:]

    dtau_dx = jnp.where(tree.lower, low_q, jnp.where(tree.upper, up_q, 0.0))
    dtau_dv = jnp.where(tree.lower, low_v, jnp.where(tree.upper, up_v, 0.0))
    M = jnp.where(tree.lower, PJ, jnp.where(tree.upper, PJ.T, 0.0))
    Jc = _point_jacobians(tree, r.kin, r.points)
    dtau_df = -Jc.reshape(-1, nv).T

    q_base = _split(robot, param, q)[0]
    dtau_dbase = _matmul(dtau_dx[:, :6], _local_base_jacobian(param, q_base))
    dtau_dq = jnp.concatenate([dtau_dbase, dtau_dx[:, 6:]], axis=1)
    return InverseDynamicsJacobians(r.tau, dtau_dq, dtau_dv, M, dtau_df)


@functools.partial(jax.jit, static_argnums=(0, 1))
def batched_inverse_dynamics_derivatives(
    robot: Robot,
    param: AbstractParameterization,
    Q: jax.Array,
    V: jax.Array,
    A: jax.Array,
    F: jax.Array,
    masses: jax.Array | None = None,
) -> InverseDynamicsJacobians:
    """`inverse_dynamics_derivatives` for a batch of knots (leading axis K), jitted.

    Args: Q (K, param.nq + nj), V (K, nv), A (K, nv), F (K, ncontact, 3); masses (nbody,)
    shared by the knots (default the model's).
    Returns: tau (K, nv), dq (K, nv, param.nq + nj), dv (K, nv, nv), da = M (K, nv, nv),
    df (K, nv, ncontact * 3).
    """
    per_knot = jax.vmap(inverse_dynamics_derivatives, in_axes=(None, None, 0, 0, 0, 0, None))
    return per_knot(robot, param, Q, V, A, F, masses)


def __getattr__(name: str):
    if name == "inverse_dynamics_jacobians":  # its former name, which did not say it is batched
        warn_renamed("jtraj.dynamics.inverse_dynamics_jacobians", "jtraj.dynamics.batched_inverse_dynamics_derivatives")
        return batched_inverse_dynamics_derivatives
    raise AttributeError(f"module 'jtraj.dynamics' has no attribute {name!r}")


# ----------------------------------------------------------------------------------------
# MuJoCo conventions and the MJX reference


def to_mujoco(
    robot: Robot, param: AbstractParameterization, q: jax.Array, v: jax.Array, a: jax.Array
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """MuJoCo ``(qpos, qvel, qacc)`` of a state in this module's convention.

    The free joint's ``qvel = (R v_body, omega_body)``; differentiating,
    ``qacc = (R (a_lin + omega x v_body), a_ang)``.
    """
    q_base, q_joints = _split(robot, param, q)
    v, a = _check_rates(robot, v, a)
    T = param.to_pose(q_base)
    R = T.rotation().as_matrix()
    qpos = jnp.concatenate([param.to_qpos(q_base), q_joints])
    qvel = jnp.concatenate([body_twist_to_qvel(T, v[:6]), v[6:]])
    acc_lin = R @ (a[:3] + jnp.cross(v[3:6], v[:3]))
    qacc = jnp.concatenate([acc_lin, a[3:]])
    return qpos, qvel, qacc


def tau_from_mujoco(qpos: jax.Array, qfrc: jax.Array) -> jax.Array:
    """Generalized force in this module's convention from a MuJoCo one.

    MuJoCo's free-joint force is (world force, body torque); the body-twist convention wants
    (body force, body torque): ``tau = P^T qfrc`` with ``qvel = P V``, ``P = diag(R, I)``.
    """
    R = SO3(qpos[3:7] / jnp.linalg.norm(qpos[3:7])).as_matrix()
    return jnp.concatenate([R.T @ qfrc[:3], qfrc[3:]])


def inverse_dynamics_mjx(
    robot: Robot,
    param: AbstractParameterization,
    q: jax.Array,
    v: jax.Array,
    a: jax.Array,
    forces: jax.Array,
) -> jax.Array:
    """`inverse_dynamics` through MJX's own pipeline (kinematics, com_pos, com_vel, rne with
    accelerations, point Jacobians), with the conventions converted. A reference and the
    benchmark's baseline; slower to differentiate."""
    m = robot.mjx_model
    v, a = _check_rates(robot, v, a)
    forces = _check_forces(robot, forces)
    qpos, qvel, qacc = to_mujoco(robot, param, q, v, a)
    d = mjx.make_data(m).replace(qpos=qpos, qvel=qvel, qacc=qacc)
    d = mjx.kinematics(m, d)
    d = mjx.com_pos(m, d)
    d = mjx.com_vel(m, d)
    d = mjx.rne(m, d, flg_acc=True)
    body = robot.contact_body_ids
    points = d.xpos[body] + _matvec(d.xmat[body], jnp.asarray(robot.contact_offsets))
    jacp = jax.vmap(lambda p, b: mjx.jac(m, d, p, b)[0])(points, jnp.asarray(body))  # (nc, nv, 3)
    qfrc = d.qfrc_bias - jnp.einsum("cvi,ci->v", jacp, forces)
    return tau_from_mujoco(qpos, qfrc)
