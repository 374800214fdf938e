"""The five floating-base parameterizations of the comparative study (Table I).

Every parameterization maps its base coordinates ``q`` (length `nq`) to a pose
``T_world_base`` in SE(3) and back, steps the pose with the body twist (semi-implicit Euler
position step), and measures the difference of two configurations. Downstream code uses the
methods of `AbstractParameterization`, with three exceptions that read a chart's ``name``
(the study's warm starts, as the paper describes them per chart): with the study's variables
the warm start of ``"euler"`` adds the task's rotation rules to its roll, pitch and yaw
coordinates (`jtraj.transcription.TranscriptionOptions.warm_start_euler`), the charts named
``"quat..."`` take ``warm_start_quaternions="matrix"``, and the noise study's poses converted
into a ``"quat..."`` chart keep the sign of its warm start's quaternions. A chart of one's own
under another name gets none of these.

Generalized velocity (the same for all parameterizations): the body twist
``V_b = (v_body, omega_body)`` of the base, linear velocity of the base origin and angular
velocity, both expressed in the base frame (Pinocchio's free-flyer convention), followed by
the joint rates. MuJoCo/MJX's free joint uses ``qvel = (v_world, omega_body)`` instead, with
``v_world = R_world_base v_body``: see `body_twist_to_qvel` and `qvel_to_body_twist`.

All methods take one configuration (no batch axes); use `jax.vmap` for batches.
"""

from __future__ import annotations

import abc
import dataclasses
import functools
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
from jaxlie import SE3, SO3

from jtraj import euler, lie
from jtraj import quaternion as quat
from jtraj.registry import lookup

__all__ = [
    "AbstractParameterization",
    "SE3Tangent",
    "Quaternion1",
    "Quaternion2",
    "Quaternion3",
    "EulerRPY",
    "PARAMETERIZATIONS",
    "QUATERNION_FLOOR",
    "get",
    "body_twist_to_qvel",
    "qvel_to_body_twist",
]


class AbstractParameterization(abc.ABC):
    """Contract of a floating-base parameterization.

    Class attributes:
        name: short name used on the command line (``se3``, ``quat1``, ...).
        label: the row of Table I.
        nq: number of base coordinates.
        ndiff: length of `difference`'s output.
        ncon: length of `constraint`'s output (0 when the chart needs none).
    """

    name: ClassVar[str]
    label: ClassVar[str]
    nq: ClassVar[int]
    ndiff: ClassVar[int]

    def __init_subclass__(cls, **kwargs: Any) -> None:
        # Every chart's methods check their coordinates (`_coordinates`) before its own code
        # runs: a wrong size would otherwise be indexed past its end, which JAX clamps silently.
        super().__init_subclass__(**kwargs)
        for method, checked in _CHECKED_ARGUMENTS.items():
            if method in cls.__dict__:
                setattr(cls, method, _with_checked_arguments(cls.__dict__[method], checked))

    def _coordinates(self, value: Any, what: str, size: int | None = None) -> jax.Array:
        """``value`` as a float array of shape (``size``,) (default ``nq``)."""
        size = self.nq if size is None else size
        value = jnp.asarray(value)
        if value.ndim == 0 or value.shape[-1] != size:
            raise ValueError(f"{type(self).__name__}: {what} must have {size} entries on its last axis ({self.label}), got shape {value.shape}")
        if value.ndim != 1:
            # the charts index single configurations (q[3:7]): a batch would be sliced along
            # its first axis and fail deep inside with a shape error naming neither
            raise ValueError(f"{type(self).__name__}: {what} must be one configuration of shape ({size},), got shape {value.shape}; use jax.vmap for batches")
        return value if jnp.issubdtype(value.dtype, jnp.floating) else value.astype(float)

    @property
    def ncon(self) -> int:
        return 0

    @abc.abstractmethod
    def to_pose(self, q: jax.Array) -> SE3:
        """Base pose ``T_world_base`` of coordinates ``q``."""

    @abc.abstractmethod
    def from_pose(self, T_world_base: SE3) -> jax.Array:
        """Coordinates of a pose (one representative where the chart has several)."""

    @abc.abstractmethod
    def integrate(self, q: jax.Array, V_b: jax.Array, h: jax.Array | float) -> jax.Array:
        """Position step of semi-implicit Euler (Table I, 'Elementary Integration').

        ``V_b`` is the body twist (6,), h the timestep in seconds.
        """

    @abc.abstractmethod
    def difference(self, q1: jax.Array, q2: jax.Array) -> jax.Array:
        """Difference 'q2 - q1' of Table I, shape (ndiff,)."""

    def constraint(self, q: jax.Array) -> jax.Array:
        """Equality constraints the chart needs, ``c(q) = 0``; shape (ncon,)."""
        return jnp.zeros((0,), q.dtype)

    def to_qpos(self, q: jax.Array) -> jax.Array:
        """MJX free-joint coordinates ``xyz_wxyz`` (7,), unit quaternion."""
        T = self.to_pose(q)
        return jnp.concatenate([T.translation(), T.rotation().wxyz])

    def from_qpos(self, qpos: jax.Array) -> jax.Array:
        """Inverse of `to_qpos` (the quaternion is normalized first; a zero one, which gave NaN
        coordinates, is the identity, as the quaternion charts' `to_qpos` read theirs)."""
        qpos = self._coordinates(qpos, "qpos (xyz_wxyz)", 7)
        wxyz = qpos[3:7]
        zero = jnp.all(wxyz == 0.0)  # (one branch: no NaN derivative from the other)
        wxyz = jnp.where(zero, jnp.array([1.0, 0.0, 0.0, 0.0]), wxyz)
        wxyz = wxyz / jnp.linalg.norm(wxyz)
        return self.from_pose(SE3.from_rotation_and_translation(SO3(wxyz), qpos[:3]))

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"


#: The contract's methods whose leading arguments are checked, by their names in the contract:
#: (argument, what it is, size), size None for the chart's own ``nq``.
_CHECKED_ARGUMENTS: dict[str, tuple[tuple[str, str, int | None], ...]] = {
    "to_pose": (("q", "q", None),),
    "integrate": (("q", "q", None), ("V_b", "V_b (body twist)", 6)),
    "difference": (("q1", "q1", None), ("q2", "q2", None)),
    "constraint": (("q", "q", None),),
}


def _with_checked_arguments(method: Any, checked: tuple[tuple[str, str, int | None], ...]) -> Any:
    @functools.wraps(method)
    def wrapped(self, *args, **kwargs):
        args = tuple(self._coordinates(a, *checked[i][1:]) if i < len(checked) else a for i, a in enumerate(args))
        for name, what, size in checked[len(args):]:
            if name in kwargs:
                kwargs[name] = self._coordinates(kwargs[name], what, size)
        return method(self, *args, **kwargs)

    return wrapped


# the base class's own methods, which charts without a constraint (SE(3) tangent, Euler)
# inherit: `__init_subclass__` wraps only what a chart defines
for _method in ("constraint",):
    setattr(AbstractParameterization, _method, _with_checked_arguments(getattr(AbstractParameterization, _method), _CHECKED_ARGUMENTS[_method]))


#: Smallest quaternion norm the charts divide by. Noise on a warm start (or a wild iterate)
#: can drive rho to zero, where rho / |rho| and its derivatives are NaN; below the floor the
#: quaternion is first moved by ``QUATERNION_FLOOR`` along its scalar part (away from zero, so
#: its norm stays >= the floor), which keeps values and derivatives finite (derivatives of
#: size ~1 / floor) and leaves every quaternion of norm >= the floor untouched.
QUATERNION_FLOOR = 1e-6


def _unit(rho: jax.Array) -> jax.Array:
    rho = jnp.asarray(rho)
    sq = rho @ rho
    small = sq < QUATERNION_FLOOR**2
    # one branch only: where() would pass NaN gradients of the untaken rho / |rho| at zero
    away = jnp.where(rho[0] >= 0, 1.0, -1.0) * QUATERNION_FLOOR
    safe = jnp.where(small, rho.at[0].add(away), rho)
    return safe / jnp.sqrt(safe @ safe)


def _pose_from_xyz_wxyz(q: jax.Array) -> SE3:
    # The quaternion variables are not kept at unit norm by the transcription; as in the
    # paper's code they are normalized wherever they are used.
    return SE3.from_rotation_and_translation(SO3(_unit(q[3:7])), q[:3])


def _xyz_wxyz_from_pose(T: SE3) -> jax.Array:
    return jnp.concatenate([T.translation(), T.rotation().wxyz])


@dataclasses.dataclass(frozen=True)
class SE3Tangent(AbstractParameterization):
    """``q = xi`` in R^6, ``T = Exp(xi)`` (the study's proposal).

    integrate: ``Log(Exp(xi) Exp(V h))``; difference: ``Log(Exp(xi1)^-1 Exp(xi2))``.
    The two are inverse maps: ``difference(xi, integrate(xi, V, h)) == V h`` for rotation
    angles below pi. Any xi whose rotation angle is not a nonzero multiple of 2 pi is a valid
    coordinate (angles beyond pi included); at 2 pi k, k != 0, Exp's Jacobian loses rank: a
    pose turned a whole number of times with a translation off its axis has no coordinates
    there, and near it the translation's grow without bound, so a warm start winding through
    a full turn meets a singular point. `integrate` and `from_pose` return the principal
    logarithm (angle at most pi).
    """

    name: ClassVar[str] = "se3"
    label: ClassVar[str] = "SE(3) tangent"
    nq: ClassVar[int] = 6
    ndiff: ClassVar[int] = 6

    def to_pose(self, q):
        return lie.exp(SE3, q)

    def from_pose(self, T_world_base):
        return lie.log(T_world_base)

    def integrate(self, q, V_b, h):
        return lie.log(lie.plus(lie.exp(SE3, q), V_b * h))

    def difference(self, q1, q2):
        return lie.minus(lie.exp(SE3, q2), lie.exp(SE3, q1))


@dataclasses.dataclass(frozen=True)
class _QuaternionBase(AbstractParameterization):
    """``q = (p, rho)``: position and a quaternion ``rho = (s, nu)`` (wxyz), 7 coordinates.

    ``unit_norm=True`` adds the constraint ``|rho|^2 - 1 = 0``; by default (as in the
    study) no norm constraint is kept and rho is normalized wherever it is used.
    """

    nq: ClassVar[int] = 7
    unit_norm: bool = False

    @property
    def ncon(self) -> int:
        return 1 if self.unit_norm else 0

    def constraint(self, q):
        if self.unit_norm:
            return jnp.atleast_1d(q[3:7] @ q[3:7] - 1.0)
        return jnp.zeros((0,), q.dtype)

    def to_pose(self, q):
        return _pose_from_xyz_wxyz(q)

    def from_pose(self, T_world_base):
        return _xyz_wxyz_from_pose(T_world_base)

    def _manifold_integrate(self, q, V_b, h):
        # Log_q(Exp_q(p, rho) (+) V h)
        return _xyz_wxyz_from_pose(lie.plus(_pose_from_xyz_wxyz(q), V_b * h))

    def _vector_difference(self, q1, q2):
        return q2 - q1


@dataclasses.dataclass(frozen=True)
class Quaternion1(_QuaternionBase):
    """Quaternion #1: vector integration and vector differences.

    integrate: ``p + R(rho) v h``, ``rho + 1/2 L(rho) H omega h`` (rho normalized first);
    difference: ``(p2 - p1, rho2 - rho1)``. Not inverse maps; the documented relation is
    ``difference(q, integrate(q, V, h)) == (R(rho) v h, 1/2 L(rho) H omega h)`` for a unit
    rho (for another norm the step starts from rho / |rho|, so the difference also holds
    ``rho / |rho| - rho``), and the step agrees with ``Exp_q(q) Exp(V h)`` to first order in h.
    """

    name: ClassVar[str] = "quat1"
    label: ClassVar[str] = "Quaternion #1"
    ndiff: ClassVar[int] = 7

    def integrate(self, q, V_b, h):
        rho = _unit(q[3:7])
        p_dot = quat.rotation_matrix(rho) @ V_b[:3]
        rho_dot = 0.5 * quat.L(rho) @ quat.H @ V_b[3:]
        return jnp.concatenate([q[:3] + p_dot * h, rho + rho_dot * h])

    def difference(self, q1, q2):
        return self._vector_difference(q1, q2)


@dataclasses.dataclass(frozen=True)
class Quaternion2(_QuaternionBase):
    """Quaternion #2: manifold integration, vector differences.

    integrate: ``Log_q(Exp_q(p, rho) Exp(V h))``; difference: ``(p2 - p1, rho2 - rho1)``.
    Relation: ``to_pose(integrate(q, V, h)) == to_pose(q) Exp(V h)``.
    """

    name: ClassVar[str] = "quat2"
    label: ClassVar[str] = "Quaternion #2"
    ndiff: ClassVar[int] = 7

    def integrate(self, q, V_b, h):
        return self._manifold_integrate(q, V_b, h)

    def difference(self, q1, q2):
        return self._vector_difference(q1, q2)


@dataclasses.dataclass(frozen=True)
class Quaternion3(_QuaternionBase):
    """Quaternion #3: manifold integration and manifold differences.

    integrate: ``Log_q(Exp_q(p, rho) Exp(V h))``; difference:
    ``Exp_q(p2, rho2) (-) Exp_q(p1, rho1)`` in R^6. Inverse maps:
    ``difference(q, integrate(q, V, h)) == V h``. With 7 coordinates and 6 difference rows,
    the norm of rho is left free unless ``unit_norm=True``.
    """

    name: ClassVar[str] = "quat3"
    label: ClassVar[str] = "Quaternion #3"
    ndiff: ClassVar[int] = 6

    def integrate(self, q, V_b, h):
        return self._manifold_integrate(q, V_b, h)

    def difference(self, q1, q2):
        return lie.minus(_pose_from_xyz_wxyz(q2), _pose_from_xyz_wxyz(q1))


@dataclasses.dataclass(frozen=True)
class EulerRPY(AbstractParameterization):
    """``q = (p, rpy)``, ``R = Rz(psi) Ry(theta) Rx(phi)`` (6 coordinates).

    integrate: ``p + R v h``, ``rpy + W(rpy) omega h`` (eq. 6); difference:
    ``(p2 - p1, rpy2 - rpy1)``. Relation: ``difference(q, integrate(q, V, h)) ==
    (R v h, W omega h)``. Singular at pitch +-pi/2.
    """

    name: ClassVar[str] = "euler"
    label: ClassVar[str] = "Euler angles (RPY)"
    nq: ClassVar[int] = 6
    ndiff: ClassVar[int] = 6

    def to_pose(self, q):
        # jaxlie's from_rpy_radians is Rz(yaw) Ry(pitch) Rx(roll), the convention of eq. 5.
        rotation = SO3.from_rpy_radians(roll=q[3], pitch=q[4], yaw=q[5])
        return SE3.from_rotation_and_translation(rotation, q[:3])

    def from_pose(self, T_world_base):
        """Coordinates with pitch in [-pi/2 + m, pi/2 - m], m = `euler.GIMBAL_MARGIN`: at
        gimbal lock W(theta) is infinite (|W| ~ 1e16 at pitch = pi/2 in floating point), so a
        pose there or within m of it (e.g. a flip's warm start passing pitch -pi/2 at a knot)
        gets its pitch clipped to m rad short of the lock; every other pose round-trips
        exactly."""
        rpy = euler.from_rotation_matrix(T_world_base.rotation().as_matrix())
        return jnp.concatenate([T_world_base.translation(), euler.away_from_gimbal_lock(rpy)])

    def integrate(self, q, V_b, h):
        rpy = q[3:6]
        p_dot = euler.rotation_matrix(rpy) @ V_b[:3]
        rpy_dot = euler.rate_matrix(rpy) @ V_b[3:]
        return jnp.concatenate([q[:3] + p_dot * h, rpy + rpy_dot * h])

    def difference(self, q1, q2):
        return q2 - q1


#: One instance of each row of Table I, by command-line name.
PARAMETERIZATIONS: dict[str, AbstractParameterization] = {
    p.name: p for p in (SE3Tangent(), Quaternion1(), Quaternion2(), Quaternion3(), EulerRPY())
}


def get(name: str | AbstractParameterization) -> AbstractParameterization:
    """The parameterization called ``name`` (``se3``, ``quat1``, ``quat2``, ``quat3``, ``euler``)."""
    if isinstance(name, AbstractParameterization):
        return name
    return lookup(PARAMETERIZATIONS, name, "parameterization")


def body_twist_to_qvel(T_world_base: SE3, V_b: jax.Array) -> jax.Array:
    """MJX free-joint ``qvel = (R v_body, omega_body)`` from the body twist ``V_b`` (6,)."""
    Rm = T_world_base.rotation().as_matrix()
    return jnp.concatenate([Rm @ V_b[:3], V_b[3:]])


def qvel_to_body_twist(T_world_base: SE3, qvel: jax.Array) -> jax.Array:
    """Body twist ``(R^T v_world, omega_body)`` from MJX free-joint ``qvel`` (6,)."""
    Rm = T_world_base.rotation().as_matrix()
    return jnp.concatenate([Rm.T @ qvel[:3], qvel[3:6]])
