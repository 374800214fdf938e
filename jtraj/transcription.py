"""Inverse-dynamics direct transcription (paper eqs. 11-18) for any floating-base parameterization.

Variables of knot k (one `Layout` for all knots; the NLP fixes by bounds what a knot does not
use, and Ipopt removes fixed variables):

    q  (param.nq + nj)   base coordinates in the parameterization's chart, joint positions
    v  (nv)              body twist of the base and joint rates
    a  (nv)              its time derivative
    f  (3 P)             world-frame forces at the task's P contact points (0 when not touching)
    c  (3 P)             contact positions (0 when not touching)

Constraint groups, each written for ONE knot and vmapped (rows of inactive contacts dropped):

    dynamics      tau(q, v, a, f): base rows = 0, joint rows within the effort limits
    integration   v' = v + a h;  param.difference(param.integrate(q_b, V_b', h), q_b') = 0;
                  q_j' = q_j + qd_j' h                    (semi-implicit Euler, Table I)
    contact       FK_j(q) = c_j for touching points; c_z is the terrain height (a bound)
    stationary    (c_j')_xy = (c_j)_xy while a point keeps touching
    clearance     FK_j(q)_z >= terrain height for points in the air
    friction      4-facet pyramid |f_x|, |f_y| <= mu f_z (f_z >= 0 and |f_i| <= 1.5 m g are bounds)
    force_rate    |f_j' - f_j| <= max_delta_force per component (tasks that set it)
    chart         the parameterization's own constraint (e.g. unit quaternion norm), if any

Costs: 1/2 w_q |q_j - q_j,standing|^2 and 1/2 w_a |a_j|^2 per knot. Boundary conditions are
bounds: knot 0 at the standing pose at rest, the last knot at the target pose at rest, a = 0.

Nothing here imports cyipopt; `build_nlp` returns a `jtraj.nlp.KnotNLP`.
"""

from __future__ import annotations

import dataclasses
from functools import cached_property

import jax
import jax.numpy as jnp
import numpy as np
from jaxlie import SE3, SO3

from jtraj import dynamics, lie
from jtraj.nlp import ConstraintGroup, CostGroup, Dep, KnotNLP, Layout
from jtraj.parameterization import AbstractParameterization
from jtraj.task import Task

__all__ = ["Transcription", "TranscriptionOptions", "PAPER_LAYOUT", "COMPACT_LAYOUT", "LEAN_LAYOUT", "Trajectory"]

GRAVITY = 9.81


@dataclasses.dataclass(frozen=True)
class TranscriptionOptions:
    """Variable layout.

    Attributes:
        contact_variables: keep the contact positions c_{j,k} as variables with
            ``FK_j(q_k) = c_{j,k}`` (the paper). False substitutes ``FK_j(q_k)``: the contact
            rows become ``FK_j(q_k)_z = terrain`` and stationarity ``FK_j(q_{k+1})_xy =
            FK_j(q_k)_xy``.
        acceleration_variables: keep a_k as variables with ``v_{k+1} = v_k + a_k h`` (the
            paper). False substitutes ``a_k = (v_{k+1} - v_k) / h`` (and a_N = 0).
    Both substitutions eliminate equality constraints exactly: the feasible trajectories are
    the same, the NLP is smaller.
    """

    contact_variables: bool = True
    acceleration_variables: bool = True


#: The study's variable layout (q, v, a, f, c at every knot).
PAPER_LAYOUT = TranscriptionOptions()
#: Contact positions substituted by forward kinematics: (q, v, a, f) at every knot.
COMPACT_LAYOUT = TranscriptionOptions(contact_variables=False, acceleration_variables=True)
#: Contact positions and accelerations substituted: (q, v, f) at every knot.
LEAN_LAYOUT = TranscriptionOptions(contact_variables=False, acceleration_variables=False)


@dataclasses.dataclass
class Trajectory:
    """A decoded trajectory; arrays have the knot axis first."""

    t: np.ndarray  # (K,) s
    base_xyz_wxyz: np.ndarray  # (K, 7) base pose, MJX free-joint convention
    q_base: np.ndarray  # (K, param.nq) base coordinates in the parameterization's chart
    q_joints: np.ndarray  # (K, nj) rad
    v: np.ndarray  # (K, nv) body twist + joint rates
    a: np.ndarray  # (K, nv)
    tau: np.ndarray  # (K, nv) generalized forces from inverse dynamics (base rows ~ 0)
    forces: np.ndarray  # (K, P, 3) N, world frame
    contact_positions: np.ndarray  # (K, P, 3) m, forward kinematics of the contact points
    in_contact: np.ndarray  # (K, P) bool
    contact_names: tuple[str, ...]


class Transcription:
    """The transcription of ``task`` for ``robot`` in parameterization ``param``."""

    def __init__(self, robot, task: Task, param: AbstractParameterization, options: TranscriptionOptions = COMPACT_LAYOUT):
        task.validate(robot)
        self.options = options
        self.robot = robot
        self.task = task
        self.param = param
        self.schedule = task.schedule(robot)
        self.points = np.asarray(self.schedule.points, int)
        self.P = len(self.points)
        self.nj = robot.nj
        self.nv = robot.nv
        self.nq = param.nq + robot.nj
        self.N = self.schedule.n_knots - 1
        self.h = float(task.timestep)
        slots = [("q", self.nq), ("v", self.nv)]
        if options.acceleration_variables:
            slots.append(("a", self.nv))
        slots.append(("f", 3 * self.P))
        if options.contact_variables:
            slots.append(("c", 3 * self.P))
        self.layout = Layout(tuple(slots))
        self.contact_names = tuple(robot.contact_names[i] for i in self.points)

    # -------------------------------------------------------------------- host-side helpers
    # Poses on the host are numpy xyz_wxyz arrays and every JAX computation here is jitted
    # and batched over knots: evaluated op by op, each primitive would compile on its own
    # (measured: 235 compilations, half a minute, for the warm start of big_jump).
    @cached_property
    def _host(self):
        param = self.param

        def coords(xyz_wxyz, qj):
            """Configuration q of base poses (K, 7) and joint positions (K, nj)."""
            T = SE3.from_rotation_and_translation(SO3(xyz_wxyz[..., 3:]), xyz_wxyz[..., :3])
            return jnp.concatenate([jax.vmap(param.from_pose)(T), qj], axis=-1)

        def rotate(axis_angle, wxyz):
            """Rotations Exp(axis_angle) R about world axes, batched."""
            return jax.vmap(lambda w, R: (lie.exp(SO3, w) @ SO3(R)).wxyz)(axis_angle, wxyz)

        return dict(coords=jax.jit(coords), rotate=jax.jit(rotate), fk=jax.jit(jax.vmap(self._fk)))

    @cached_property
    def initial_xyz_wxyz(self) -> np.ndarray:
        """Standing base pose, lowered/raised so the first phase's contact points touch the terrain."""
        robot = self.robot
        xyz_wxyz = np.array(robot.base_xyz_wxyz_standing, float)
        q = self._host["coords"](xyz_wxyz[None], np.asarray(robot.q_joints_standing)[None])
        p = np.asarray(self._host["fk"](q))[0]
        touching = self.schedule.in_contact[0]
        spread = float(np.ptp(p[touching, 2]))
        if spread > 5e-3:
            raise ValueError(
                f"the standing pose of {robot.name!r} does not put the contact points of phase 0 on flat "
                f"ground (heights differ by {spread * 1000:.1f} mm)"
            )
        xyz_wxyz[2] -= float(np.mean(p[touching, 2])) - self.task.terrain_height
        return xyz_wxyz

    @cached_property
    def target_xyz_wxyz(self) -> np.ndarray:
        """Target base pose: the task's displacement and rotation applied to the initial pose."""
        T0 = self.initial_xyz_wxyz
        rpy = np.asarray(self.task.target_rotation_rpy, float)
        # rotate by Rz(yaw) Ry(pitch) Rx(roll), composed about world axes
        wxyz = T0[3:][None]
        for axis, angle in ((0, rpy[0]), (1, rpy[1]), (2, rpy[2])):
            aa = np.zeros((1, 3))
            aa[0, axis] = angle
            wxyz = self._host["rotate"](aa, wxyz)
        return np.concatenate([T0[:3] + np.asarray(self.task.target_translation), np.asarray(wxyz)[0]])

    @property
    def initial_pose(self) -> SE3:
        x = self.initial_xyz_wxyz
        return SE3.from_rotation_and_translation(SO3(jnp.asarray(x[3:])), jnp.asarray(x[:3]))

    @property
    def target_pose(self) -> SE3:
        x = self.target_xyz_wxyz
        return SE3.from_rotation_and_translation(SO3(jnp.asarray(x[3:])), jnp.asarray(x[:3]))

    @cached_property
    def q_joints_target(self) -> np.ndarray:
        if self.task.target_joints is not None:
            return np.asarray(self.task.target_joints, float)
        return np.asarray(self.robot.q_joints_standing, float)

    # -------------------------------------------------------------------- functions of one knot
    # Jitted so that the groups which call them (and vmap / jacfwd of those) reuse one traced
    # jaxpr: tracing the unrolled kinematic tree costs about a second each time.
    def _forces_all(self, f: jax.Array) -> jax.Array:
        F = jnp.zeros((len(self.robot.contact_names), 3), f.dtype)
        return F.at[self.points].set(f.reshape(self.P, 3))

    @cached_property
    def _tau(self):
        return jax.jit(lambda q, v, a, f: dynamics.inverse_dynamics(self.robot, self.param, q, v, a, self._forces_all(f)))

    @cached_property
    def _fk(self):
        return jax.jit(lambda q: dynamics.contact_positions(self.robot, self.param, q)[self.points])

    # -------------------------------------------------------------------- the NLP
    def build_nlp(self) -> KnotNLP:
        robot, task, param = self.robot, self.task, self.param
        n_knots, N, P, nj, nv = self.N + 1, self.N, self.P, self.nj, self.nv
        nqb = param.nq
        h = self.h
        contact = self.schedule.in_contact  # (K, P)
        knots = np.arange(n_knots)
        pairs = np.arange(N)
        groups: list[ConstraintGroup] = []

        # dynamics ------------------------------------------------------------
        effort = np.asarray(robot.tau_max, float)
        lo = np.concatenate([np.zeros(6), -effort])
        hi = np.concatenate([np.zeros(6), effort])

        points = self.points
        ncp = len(robot.contact_names)
        acc_vars = self.options.acceleration_variables

        def derivatives(Q, V, A, Fv):
            # analytical RNEA derivatives; d tau / d a = M and d tau / d f = -J^T need no autodiff
            K = Q.shape[0]
            F = jnp.zeros((K, ncp, 3), Q.dtype).at[:, points].set(Fv.reshape(K, P, 3))
            d = dynamics.inverse_dynamics_jacobians(robot, param, Q, V, A, F)
            df = d.df.reshape(K, nv, ncp, 3)[:, :, points, :].reshape(K, nv, 3 * P)
            return d, df

        if acc_vars:

            def dyn(data, q, v, a, f):
                return self._tau(q, v, a, f)

            def dyn_jac(data, Q, V, A, Fv):
                d, df = derivatives(Q, V, A, Fv)
                return jnp.concatenate([d.dq, d.dv, d.da, df], axis=-1)

            groups.append(
                ConstraintGroup(
                    "dynamics", (Dep("q"), Dep("v"), Dep("a"), Dep("f")), dyn, knots,
                    np.tile(lo, (n_knots, 1)), np.tile(hi, (n_knots, 1)), np.ones((n_knots, nv), bool),
                    batched_jacobian=dyn_jac,
                )
            )
        else:
            # a_k = (v_{k+1} - v_k) / h at k < N; a_N = 0 (the final knot is at rest)
            def dyn_pair(data, q, v, f, v1):
                return self._tau(q, v, (v1 - v) / h, f)

            def dyn_pair_jac(data, Q, V, Fv, V1):
                d, df = derivatives(Q, V, (V1 - V) / h, Fv)
                return jnp.concatenate([d.dq, d.dv - d.da / h, df, d.da / h], axis=-1)

            def dyn_last(data, q, v, f):
                return self._tau(q, v, jnp.zeros_like(v), f)

            def dyn_last_jac(data, Q, V, Fv):
                d, df = derivatives(Q, V, jnp.zeros_like(V), Fv)
                return jnp.concatenate([d.dq, d.dv, df], axis=-1)

            groups.append(
                ConstraintGroup(
                    "dynamics", (Dep("q"), Dep("v"), Dep("f"), Dep("v", 1)), dyn_pair, pairs,
                    np.tile(lo, (N, 1)), np.tile(hi, (N, 1)), np.ones((N, nv), bool),
                    batched_jacobian=dyn_pair_jac,
                )
            )
            groups.append(
                ConstraintGroup(
                    "dynamics", (Dep("q"), Dep("v"), Dep("f")), dyn_last, np.array([N]),
                    lo[None], hi[None], np.ones((1, nv), bool), batched_jacobian=dyn_last_jac,
                )
            )

        # integration -----------------------------------------------------------
        def position_step(hk, q, q1, v1):
            r_base = param.difference(param.integrate(q[:nqb], v1[:6], hk), q1[:nqb])
            r_j = q1[nqb:] - q[nqb:] - v1[6:] * hk
            return jnp.concatenate([r_base, r_j])

        if acc_vars:

            def integ(hk, q, v, a, q1, v1):
                return jnp.concatenate([v1 - v - a * hk, position_step(hk, q, q1, v1)])

            deps = (Dep("q"), Dep("v"), Dep("a"), Dep("q", 1), Dep("v", 1))
            n_int = nv + param.ndiff + nj
        else:

            def integ(hk, q, q1, v1):
                return position_step(hk, q, q1, v1)

            deps = (Dep("q"), Dep("q", 1), Dep("v", 1))
            n_int = param.ndiff + nj
        groups.append(
            ConstraintGroup(
                "integration", deps, integ, pairs,
                np.zeros((N, n_int)), np.zeros((N, n_int)), np.ones((N, n_int), bool),
                data=jnp.full((N,), h),
            )
        )

        if P:
            both = contact[:-1] & contact[1:]
            if self.options.contact_variables:
                # contact kinematics FK = c; c_z is the terrain height (a bound) ----------
                groups.append(
                    ConstraintGroup(
                        "contact", (Dep("q"), Dep("c")), lambda data, q, c: (self._fk(q) - c.reshape(P, 3)).reshape(-1), knots,
                        np.zeros((n_knots, 3 * P)), np.zeros((n_knots, 3 * P)), np.repeat(contact, 3, axis=1),
                    )
                )
                # stationarity: x, y of a touching point stay put ---------------------
                groups.append(
                    ConstraintGroup(
                        "stationary", (Dep("c"), Dep("c", 1)),
                        lambda data, c, c1: (c1.reshape(P, 3)[:, :2] - c.reshape(P, 3)[:, :2]).reshape(-1), pairs,
                        np.zeros((N, 2 * P)), np.zeros((N, 2 * P)), np.repeat(both, 2, axis=1),
                    )
                )
            else:
                groups.append(
                    ConstraintGroup(
                        "contact", (Dep("q"),), lambda data, q: self._fk(q)[:, 2], knots,
                        np.full((n_knots, P), task.terrain_height), np.full((n_knots, P), task.terrain_height), contact,
                    )
                )
                groups.append(
                    ConstraintGroup(
                        "stationary", (Dep("q"), Dep("q", 1)),
                        lambda data, q, q1: (self._fk(q1)[:, :2] - self._fk(q)[:, :2]).reshape(-1), pairs,
                        np.zeros((N, 2 * P)), np.zeros((N, 2 * P)), np.repeat(both, 2, axis=1),
                    )
                )
            # swing points above the terrain ----------------------------------------
            groups.append(
                ConstraintGroup(
                    "clearance", (Dep("q"),), lambda data, q: self._fk(q)[:, 2], knots,
                    np.full((n_knots, P), task.terrain_height), np.full((n_knots, P), np.inf), ~contact,
                )
            )
            # friction pyramid -------------------------------------------------------
            mu = task.friction

            def friction(data, f):
                f = f.reshape(P, 3)
                fx, fy, fz = f[:, 0], f[:, 1], f[:, 2]
                return jnp.stack([mu * fz - fx, mu * fz + fx, mu * fz - fy, mu * fz + fy], axis=1).reshape(-1)

            groups.append(
                ConstraintGroup(
                    "friction", (Dep("f"),), friction, knots,
                    np.zeros((n_knots, 4 * P)), np.full((n_knots, 4 * P), np.inf), np.repeat(contact, 4, axis=1),
                )
            )
            if task.max_delta_force is not None:
                d = float(task.max_delta_force)
                groups.append(
                    ConstraintGroup(
                        "force_rate", (Dep("f"), Dep("f", 1)), lambda data, f, f1: f1 - f, pairs,
                        np.full((N, 3 * P), -d), np.full((N, 3 * P), d), np.repeat(both, 3, axis=1),
                    )
                )
        if param.ncon:
            groups.append(
                ConstraintGroup(
                    "chart", (Dep("q"),), lambda data, q: param.constraint(q[:nqb]), knots,
                    np.zeros((n_knots, param.ncon)), np.zeros((n_knots, param.ncon)), np.ones((n_knots, param.ncon), bool),
                )
            )

        # costs ---------------------------------------------------------------------
        costs = []
        q_ref = jnp.asarray(robot.q_joints_standing, float)
        if task.configuration_weight > 0:
            w = task.configuration_weight
            costs.append(CostGroup("configuration", (Dep("q"),), lambda data, q: 0.5 * w * jnp.sum((q[nqb:] - q_ref) ** 2), knots))
        if task.acceleration_weight > 0:
            w = task.acceleration_weight
            if acc_vars:
                costs.append(CostGroup("acceleration", (Dep("a"),), lambda data, a: 0.5 * w * jnp.sum(a[6:] ** 2), knots))
            else:  # a_N = 0 adds nothing
                costs.append(CostGroup("acceleration", (Dep("v"), Dep("v", 1)), lambda data, v, v1: 0.5 * w * jnp.sum(((v1 - v)[6:] / h) ** 2), pairs))

        lower, upper = self.bounds()
        return KnotNLP(self.layout, n_knots, costs, groups, lower, upper)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Variable bounds (n_knots, nz): limits, contacts, boundary conditions."""
        robot, task, param, L = self.robot, self.task, self.param, self.layout
        n_knots, P, nqb = self.N + 1, self.P, param.nq
        lower = np.full((n_knots, L.nz), -np.inf)
        upper = np.full((n_knots, L.nz), np.inf)
        sq, sv, sf = L.slice("q"), L.slice("v"), L.slice("f")
        # joint position and velocity limits
        lower[:, sq.start + nqb : sq.stop] = robot.q_lower
        upper[:, sq.start + nqb : sq.stop] = robot.q_upper
        lower[:, sv.start + 6 : sv.stop] = -np.asarray(robot.v_max)
        upper[:, sv.start + 6 : sv.stop] = np.asarray(robot.v_max)
        # forces: touching points f_z in [0, F], |f_x|, |f_y| <= F; others 0
        F = task.force_limit_factor * robot.total_mass * GRAVITY
        contact = self.schedule.in_contact
        fl = np.where(contact[:, :, None], np.array([-F, -F, 0.0]), 0.0).reshape(n_knots, 3 * P)
        fu = np.where(contact[:, :, None], np.array([F, F, F]), 0.0).reshape(n_knots, 3 * P)
        lower[:, sf], upper[:, sf] = fl, fu
        if self.options.contact_variables:
            # contact positions: touching points on the terrain (z fixed), others unused (0)
            cz = task.terrain_height
            sc = L.slice("c")
            lower[:, sc] = np.where(contact[:, :, None], np.array([-np.inf, -np.inf, cz]), 0.0).reshape(n_knots, 3 * P)
            upper[:, sc] = np.where(contact[:, :, None], np.array([np.inf, np.inf, cz]), 0.0).reshape(n_knots, 3 * P)
        # boundary conditions
        q0, qN = np.asarray(
            self._host["coords"](
                np.stack([self.initial_xyz_wxyz, self.target_xyz_wxyz]),
                np.stack([robot.q_joints_standing, self.q_joints_target]),
            )
        )
        for k, q in ((0, q0), (n_knots - 1, qN)):
            lower[k, sq] = upper[k, sq] = q
            lower[k, sv] = upper[k, sv] = 0.0
        if self.options.acceleration_variables:
            lower[-1, L.slice("a")] = upper[-1, L.slice("a")] = 0.0
        return lower, upper

    # -------------------------------------------------------------------- warm start
    def warm_start(self) -> np.ndarray:
        """The paper's non-informative warm start (plus the task's rotation rules): every knot
        at the standing pose at rest, the weight shared among the touching points."""
        robot, L = self.robot, self.layout
        n_knots, P = self.N + 1, self.P
        host = self._host
        poses = np.tile(self.initial_xyz_wxyz, (n_knots, 1))
        for axis, angles in self.task.warm_start_angles():
            poses[:, 3:] = np.asarray(host["rotate"](axis[None] * angles[:, None], poses[:, 3:]))
        qj = np.tile(np.asarray(robot.q_joints_standing, float), (n_knots, 1))
        placed = np.zeros(n_knots, bool)
        for rule in self.task.warm_start_joints:
            knots = np.isin(self.schedule.phase_of_knot, rule.phases)
            for joint, value in rule.joints:
                qj[knots, robot.joint_names.index(joint)] = value
            placed |= knots & rule.place_on_terrain
        contact = self.schedule.in_contact
        q = np.asarray(host["coords"](poses, qj))
        if placed.any():
            # rest the touching points of the placed knots on the terrain (vertical shift)
            fk = np.asarray(host["fk"](q))
            for k in np.flatnonzero(placed & contact.any(axis=1)):
                poses[k, 2] -= float(np.mean(fk[k, contact[k], 2])) - self.task.terrain_height
            q = np.asarray(host["coords"](poses, qj))
        Z = np.zeros((n_knots, L.nz))
        Z[:, L.slice("q")] = q
        n_touch = contact.sum(axis=1)
        f = np.zeros((n_knots, P, 3))
        f[:, :, 2] = np.where(contact, robot.total_mass * GRAVITY / np.maximum(n_touch, 1)[:, None], 0.0)
        Z[:, L.slice("f")] = f.reshape(n_knots, -1)
        if self.options.contact_variables:
            c = np.array(host["fk"](q))
            c[:, :, 2] = self.task.terrain_height
            Z[:, L.slice("c")] = np.where(contact[:, :, None], c, 0.0).reshape(n_knots, -1)
        return Z

    # -------------------------------------------------------------------- decoding
    @cached_property
    def _decode_arrays(self):
        @jax.jit
        def arrays(q, v, a, f):
            tau = jax.vmap(self._tau)(q, v, a, f)
            fk = jax.vmap(self._fk)(q)
            qpos = jax.vmap(self.param.to_qpos)(q[:, : self.param.nq])
            return tau, fk, qpos

        return arrays

    def decode(self, x: np.ndarray) -> Trajectory:
        L, param = self.layout, self.param
        Z = jnp.asarray(np.asarray(x).reshape(self.N + 1, L.nz))
        s = L.split(Z)
        q, v, f = s["q"], s["v"], s["f"]
        if self.options.acceleration_variables:
            a = s["a"]
        else:
            a = jnp.concatenate([(v[1:] - v[:-1]) / self.h, jnp.zeros_like(v[:1])])
        tau, fk, qpos = self._decode_arrays(q, v, a, f)
        return Trajectory(
            t=np.arange(self.N + 1) * self.h,
            base_xyz_wxyz=np.asarray(qpos),
            q_base=np.asarray(q[:, : param.nq]),
            q_joints=np.asarray(q[:, param.nq :]),
            v=np.asarray(v),
            a=np.asarray(a),
            tau=np.asarray(tau),
            forces=np.asarray(f).reshape(-1, self.P, 3),
            contact_positions=np.asarray(fk),
            in_contact=self.schedule.in_contact.copy(),
            contact_names=self.contact_names,
        )
