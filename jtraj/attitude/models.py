"""Rigid-body models of "Planning with Attitude" (Section II-B, eq. 10), in pure JAX.

Every model is a small frozen dataclass (hashable, so it can be a static argument of `jax.jit`)
with its parameters as fields, ``nx`` / ``nu`` dimensions and ``dynamics(x, u) -> x_dot`` for
ONE state; `jax.vmap` it over knots. The state starts with the rigid-body block

    x = [r (3), q (4), v (3), omega (3)]     (`POS`, `QUAT`, `VEL`, `OMEGA` slices)

- ``r``: position of the centre of mass in the world frame (m); world z is up, gravity -z.
- ``q``: body-to-world attitude ``q_world_body``, scalar first (wxyz), Hamilton product.
- ``v``: velocity of the centre of mass in the WORLD frame (m/s), so ``r_dot = v``.
- ``omega``: angular velocity in the BODY frame (rad/s), so ``q_dot = 1/2 L(q) H omega``.

and `FlexibleSpacecraft` appends modal coordinates and wheel momenta. Eq. 10 is evaluated as
written: the quaternion is NOT renormalized inside the dynamics (the exact flow keeps
``|q| = 1``; an integrator only approximately, see `rk4`).

`rk4` is the explicit 4th-order Runge-Kutta step used for every discretization.
`error_state` / `retract_error_state` are the 12-dimensional (``nx - 1``) error state of eq. 25
with Rodrigues parameters (``cayley_inv(L(q_ref)^T q)``) for the attitude.

Units are SI (m, kg, s, N, N m, rad) unless a docstring says otherwise.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from typing import ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jtraj import quaternion as quat
from jtraj.constants import GRAVITY
from jtraj.numbers import shaped

__all__ = [
    "POS",
    "QUAT",
    "VEL",
    "OMEGA",
    "rk4",
    "rigid_body_dynamics",
    "rigid_state",
    "error_state",
    "retract_error_state",
    "quat_about_axis",
    "RigidBody",
    "Quadrotor",
    "Airplane",
    "AirplaneTrim",
    "Surface",
    "FlexibleSpacecraft",
]

POS = slice(0, 3)
QUAT = slice(3, 7)
VEL = slice(7, 10)
OMEGA = slice(10, 13)

Dynamics = Callable[[jax.Array, jax.Array], jax.Array]


def rk4(f: Dynamics, x: jax.Array, u: jax.Array, h: float | jax.Array) -> jax.Array:
    """One explicit 4th-order Runge-Kutta step of ``x_dot = f(x, u)`` with u held constant.

    ``h`` is the step (s) and may be traced. On the quaternion the step is accurate to
    O(h^5) per step but does not keep ``|q| = 1`` exactly: for a constant angular velocity the
    norm shrinks by about ``(|omega| h / 2)^6 / 144`` per step.
    """
    k1 = f(x, u)
    k2 = f(x + 0.5 * h * k1, u)
    k3 = f(x + 0.5 * h * k2, u)
    k4 = f(x + h * k3, u)
    return x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def rigid_body_dynamics(x: jax.Array, force_world: jax.Array, torque_body: jax.Array, mass: float, inertia: jax.Array) -> jax.Array:
    """Eq. 10 for ``x = [r, q, v, omega]`` (13,): force in the world frame (N), torque about
    the centre of mass in the body frame (N m), ``inertia`` (3, 3) in the body frame (kg m^2).

    Returns ``[v, 1/2 L(q) H omega, F / m, J^-1 (tau - omega x J omega)]``.
    """
    q, v, w = x[QUAT], x[VEL], x[OMEGA]
    q_dot = 0.5 * quat.L(q) @ quat.H @ w
    w_dot = jnp.linalg.solve(inertia, torque_body - jnp.cross(w, inertia @ w))
    return jnp.concatenate([v, q_dot, force_world / mass, w_dot])


def rigid_state(r=(0.0, 0.0, 0.0), q=(1.0, 0.0, 0.0, 0.0), v=(0.0, 0.0, 0.0), omega=(0.0, 0.0, 0.0)) -> np.ndarray:
    """``[r, q, v, omega]`` (13,) as a numpy array (host-side helper for problem setup)."""
    return np.concatenate([np.asarray(r, float), np.asarray(q, float), np.asarray(v, float), np.asarray(omega, float)])


def quat_about_axis(axis, angle: float) -> np.ndarray:
    """Unit quaternion (wxyz, numpy) of a rotation by ``angle`` (rad) about ``axis`` (normalized
    here). Angles beyond pi give the quaternion on the continuous branch from the identity:
    ``angle = 2 pi`` gives ``[-1, 0, 0, 0]``."""
    a = np.asarray(axis, float)
    n = np.linalg.norm(a) if a.shape == (3,) else 0.0
    if not (np.isfinite(n) and n > 0.0):
        raise ValueError(f"quat_about_axis: axis must be a finite nonzero 3-vector, got {axis!r}")
    a = a / n
    return np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * a])


def error_state(x: jax.Array, x_ref: jax.Array) -> jax.Array:
    """Error state of eq. 25, ``x (-) x_ref``: (nx,) -> (nx - 1,).

    ``[r - r_ref, cayley_inv(L(q_ref)^T q), (rest of x) - (rest of x_ref)]``. The attitude part
    is the Rodrigues parameter of the rotation from ``q_ref`` to ``q``; it is invariant under
    ``q -> -q`` and singular only when that rotation is pi. Its Jacobian with respect to x at
    ``x = x_ref`` is ``E(x_ref)^T`` (`jtraj.quaternion.error_state_jacobian`) for unit q.
    """
    q, q_ref = x[QUAT], x_ref[QUAT]
    phi = quat.cayley_inv(quat.L(q_ref).T @ q)
    return jnp.concatenate([x[POS] - x_ref[POS], phi, x[7:] - x_ref[7:]])


def retract_error_state(x_ref: jax.Array, dx: jax.Array) -> jax.Array:
    """Inverse of `error_state`: ``x_ref (+) dx`` with ``q = L(q_ref) cayley(phi)``."""
    q = quat.multiplicative_update(x_ref[QUAT], dx[3:6])
    return jnp.concatenate([x_ref[POS] + dx[0:3], q, x_ref[7:] + dx[6:]])


# ----------------------------------------------------------------------------------------
# Models


def _state_and_input(model, x: jax.Array, u: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``x`` (nx,) and ``u`` (nu,) of ``model``, else a ValueError naming them: the models index
    their inputs, and JAX clamps an index past the end without a word (a rigid body given 4
    inputs took the fourth as all three torques)."""
    return shaped(x, (model.nx,), f"{type(model).__name__} state x"), shaped(u, (model.nu,), f"{type(model).__name__} input u")


@dataclasses.dataclass(frozen=True)
class RigidBody:
    """A free rigid body: ``u = [force_world (3) N, torque_body (3) N m]``, no gravity.

    The torque-free case (``u = 0``) conserves kinetic energy and the world-frame angular
    momentum ``A(q) J omega``; the tests use it as the plain check of eq. 10 and `rk4`.
    """

    mass: float = 1.0
    inertia: tuple[float, float, float] = (1.0, 2.0, 3.0)  # principal moments (kg m^2)

    nx: ClassVar[int] = 13
    nu: ClassVar[int] = 6

    def dynamics(self, x: jax.Array, u: jax.Array) -> jax.Array:
        x, u = _state_and_input(self, x, u)
        return rigid_body_dynamics(x, u[:3], u[3:], self.mass, jnp.diag(jnp.asarray(self.inertia)))

    def energy(self, x: jax.Array) -> jax.Array:
        w = x[OMEGA]
        return 0.5 * w @ (jnp.asarray(self.inertia) * w) + 0.5 * self.mass * x[VEL] @ x[VEL]

    def angular_momentum_world(self, x: jax.Array) -> jax.Array:
        return quat.rotate(x[QUAT], jnp.asarray(self.inertia) * x[OMEGA])


@dataclasses.dataclass(frozen=True)
class Quadrotor:
    """Quadrotor of the paper's flip benchmark, "+" configuration.

    Inputs ``u`` (4,): one command per rotor; rotor i pushes ``kf u_i`` (N) along body +z and
    exerts the reaction torque ``+-km u_i`` (N m) about body z. With ``kf = 1`` N the command
    is the rotor thrust in newtons; hover is ``u_i = m g / (4 kf)`` = 1.226. Rotors 1..4 sit
    at ``arm`` on body +x, +y, -x, -y; rotors 1 and 3 spin so that their reaction torque is
    ``+km u``, rotors 2 and 4 ``-km u``. No rotor dynamics, no drag, no thrust limits (the
    commands may go negative; bound them in the problem if wanted).

    Parameters (the attitude paper's public benchmark code): mass 0.5 kg, J = diag(0.0023, 0.0023, 0.004) kg m^2,
    arm 0.175 m, kf 1.0 N per unit command, km 0.0245 N m per unit command, g = 9.81 m/s^2.
    """

    mass: float = 0.5
    inertia: tuple[float, float, float] = (0.0023, 0.0023, 0.004)
    arm: float = 0.175
    kf: float = 1.0
    km: float = 0.0245
    gravity: float = GRAVITY

    nx: ClassVar[int] = 13
    nu: ClassVar[int] = 4

    def wrench(self, u: jax.Array) -> tuple[jax.Array, jax.Array]:
        """(thrust along body z (N), torque in the body frame (3,) N m) of the commands u."""
        u = shaped(u, (self.nu,), "Quadrotor input u")
        thrust = self.kf * u
        torque = jnp.stack(
            [
                self.arm * (thrust[1] - thrust[3]),
                self.arm * (thrust[2] - thrust[0]),
                self.km * (u[0] - u[1] + u[2] - u[3]),
            ]
        )
        return jnp.sum(thrust), torque

    def dynamics(self, x: jax.Array, u: jax.Array) -> jax.Array:
        x, u = _state_and_input(self, x, u)
        thrust, torque = self.wrench(u)
        f_world = quat.rotate(x[QUAT], jnp.stack([0.0, 0.0, thrust])) + jnp.array([0.0, 0.0, -self.mass * self.gravity])
        return rigid_body_dynamics(x, f_world, torque, self.mass, jnp.diag(jnp.asarray(self.inertia)))

    def hover_control(self) -> np.ndarray:
        """Commands (4,) that hold any level attitude at rest: ``m g / (4 kf)`` each."""
        return np.full(4, self.mass * self.gravity / (4 * self.kf))


class Surface(NamedTuple):
    """A flat plate of the airplane: ``area`` (m^2), centre of pressure ``position`` (body, m),
    unit ``normal`` at zero deflection (body), ``hinge`` axis (body) about which a deflection
    rotates the whole plate, and the input index (1 aileron, 2 elevator, 3 rudder) times
    ``sign`` that deflects it (rad)."""

    area: float
    position: tuple[float, float, float]
    normal: tuple[float, float, float]
    hinge: tuple[float, float, float]
    control: int
    sign: float


class AirplaneTrim(NamedTuple):
    """Steady level flight: state (13,), inputs (4,), angle of attack (rad), residual norm."""

    x: np.ndarray
    u: np.ndarray
    angle_of_attack: float
    residual: float


def _default_surfaces() -> tuple[Surface, ...]:
    # Wing split into two half-wings (full-span all-moving ailerons, deflected oppositely),
    # an all-moving horizontal tail (elevator) and an all-moving fin (rudder).
    return (
        Surface(0.05, (-0.01, 0.14, 0.0), (0.0, 0.0, 1.0), (0.0, -1.0, 0.0), 1, 1.0),  # left wing
        Surface(0.05, (-0.01, -0.14, 0.0), (0.0, 0.0, 1.0), (0.0, -1.0, 0.0), 1, -1.0),  # right wing
        Surface(0.02, (-0.30, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, -1.0, 0.0), 2, 1.0),  # horizontal tail
        Surface(0.012, (-0.30, 0.0, 0.05), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), 3, 1.0),  # fin
    )


@dataclasses.dataclass(frozen=True)
class Airplane:
    """A small aerobatic airplane built from flat plates (body axes x forward, y left, z up).

    Inputs ``u`` (4,): ``[thrust (N, along body +x through the centre of mass), aileron,
    elevator, rudder (rad)]``. Each `Surface` is an all-moving flat plate; a deflection rotates
    its normal about the surface's hinge axis by ``sign * u[control]``:

    - ailerons: the two half-wings, left one by ``+delta_a``, right one by ``-delta_a``
      (leading edge up), so ``delta_a > 0`` rolls right wing down (+x roll);
    - elevator: ``delta_e > 0`` raises the tail's leading edge, more tail lift, nose down;
    - rudder: ``delta_r > 0`` pushes the tail toward +y, nose toward -y (right).

    Aerodynamics (documented choices, not wind-tunnel data): every plate feels only a normal
    force, the flat-plate model ``C_N = 2 sin(a)`` (Hoerner), i.e. ``C_L = 2 sin a cos a`` and
    ``C_D = 2 sin^2 a`` at every angle of attack ``a`` (post-stall included, which is what an
    aerobatic maneuver needs), evaluated with the local air velocity of the plate,
    ``v_p = A(q)^T v + omega x p`` (still air), giving ``F = -rho S |v_p| (n . v_p) n`` at the
    plate's centre of pressure; this yields the roll, pitch and yaw damping. The fuselage adds
    parasitic drag ``-1/2 rho CdS |v| v``. No downwash, no propwash, no propeller torque.

    Parameters: mass 0.075 kg and J = diag(4.89e-4, 6.38e-4, 7.95e-4) kg m^2 (paper); air
    density 1.225 kg/m^3; wing 0.1 m^2 (two 0.05 m^2 halves, centres of pressure 0.14 m
    out and 1 cm behind the centre of mass), tail 0.02 m^2 and fin 0.012 m^2 at 0.30 m behind,
    fuselage drag area CdS = 0.002 m^2 (choices sized for a ~0.56 m span foam model flying at
    5 m/s: trim angle of attack about 13 degrees, see `trim`).
    """

    mass: float = 0.075
    inertia: tuple[float, float, float] = (4.89e-4, 6.38e-4, 7.95e-4)
    gravity: float = GRAVITY
    air_density: float = 1.225
    surfaces: tuple[Surface, ...] = dataclasses.field(default_factory=_default_surfaces)
    fuselage_drag_area: float = 0.002

    nx: ClassVar[int] = 13
    nu: ClassVar[int] = 4

    def aero_wrench(self, q: jax.Array, v_world: jax.Array, omega: jax.Array, u: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Aerodynamic force and torque about the centre of mass, both in the body frame."""
        # All plates at once (arrays over surfaces): a small graph, so derivatives compile fast.
        S = jnp.asarray([s.area for s in self.surfaces])
        P = jnp.asarray([s.position for s in self.surfaces])
        N0 = jnp.asarray([s.normal for s in self.surfaces])
        A = jnp.asarray([s.hinge for s in self.surfaces])
        deflection = jnp.asarray([s.sign for s in self.surfaces]) * u[np.array([s.control for s in self.surfaces])]
        c, s_ = jnp.cos(deflection)[:, None], jnp.sin(deflection)[:, None]
        n = N0 * c + jnp.cross(A, N0) * s_ + A * jnp.sum(A * N0, axis=1, keepdims=True) * (1.0 - c)
        v_body = quat.rotation_matrix(q).T @ v_world
        vp = v_body + jnp.cross(omega, P)
        speed = jnp.sqrt(jnp.sum(vp * vp, axis=1) + _AIRSPEED_FLOOR**2)
        f = (-self.air_density * S * speed * jnp.sum(n * vp, axis=1))[:, None] * n
        force = jnp.sum(f, axis=0) - 0.5 * self.air_density * self.fuselage_drag_area * _smooth_norm(v_body) * v_body
        torque = jnp.sum(jnp.cross(P, f), axis=0)
        return force, torque

    def dynamics(self, x: jax.Array, u: jax.Array) -> jax.Array:
        x, u = _state_and_input(self, x, u)
        q = x[QUAT]
        f_aero, tau = self.aero_wrench(q, x[VEL], x[OMEGA], u)
        f_body = f_aero + jnp.stack([u[0], 0.0, 0.0])
        f_world = quat.rotate(q, f_body) + jnp.array([0.0, 0.0, -self.mass * self.gravity])
        return rigid_body_dynamics(x, f_world, tau, self.mass, jnp.diag(jnp.asarray(self.inertia)))

    def trim(self, speed: float = 5.0, position=(0.0, 0.0, 0.0), iterations: int = 30) -> AirplaneTrim:
        """Steady, wings-level flight along world +x at ``speed`` (m/s).

        Unknowns: pitch angle (= angle of attack, the flight path is level), thrust and
        elevator, with aileron = rudder = 0 and omega = 0; equations: zero world x and z
        acceleration and zero pitch acceleration (the other three vanish by symmetry). Solved
        by Newton's method with JAX derivatives; raises ValueError if it does not converge.
        """
        trim = _solve_trim(self, float(speed), tuple(float(p) for p in position), int(iterations))
        return AirplaneTrim(trim.x.copy(), trim.u.copy(), trim.angle_of_attack, trim.residual)


@functools.lru_cache(maxsize=16)
def _solve_trim(plane: Airplane, speed: float, position: tuple[float, ...], iterations: int) -> AirplaneTrim:
    # cached: the benchmark factories and tests ask for the same trim repeatedly
    def state(z):
        theta = z[0]
        # nose up by theta: rotation by -theta about body y (x forward, z up)
        q = jnp.stack([jnp.cos(theta / 2), 0.0 * theta, -jnp.sin(theta / 2), 0.0 * theta])
        return jnp.concatenate([jnp.asarray(position, float), q, jnp.array([speed, 0.0, 0.0]), jnp.zeros(3)])

    def controls(z):
        return jnp.stack([z[1], 0.0 * z[1], z[2], 0.0 * z[1]])

    def residual(z):
        xd = plane.dynamics(state(z), controls(z))
        return jnp.stack([xd[7], xd[9], xd[11]])

    res_jac = jax.jit(lambda z: (residual(z), jax.jacfwd(residual)(z)))
    z = jnp.array([0.2, 0.1, 0.0])
    for _ in range(iterations):
        r, J = res_jac(z)
        z = z - jnp.linalg.solve(J, r)
        if float(jnp.max(jnp.abs(r))) < 1e-13:
            break
    r = float(jnp.max(jnp.abs(res_jac(z)[0])))
    if not r < 1e-10:
        raise ValueError(f"no level-flight trim found at {speed} m/s (residual {r:.2e}); try a speed nearer 5 m/s")
    return AirplaneTrim(np.asarray(state(z)), np.asarray(controls(z)), float(z[0]), r)


# |v| is evaluated as sqrt(|v|^2 + floor^2) so that derivatives stay finite at zero airspeed.
_AIRSPEED_FLOOR = 1e-6  # m/s


def _smooth_norm(v: jax.Array) -> jax.Array:
    return jnp.sqrt(v @ v + _AIRSPEED_FLOOR**2)


def _pyramid_axes(elevation_deg: float) -> tuple[tuple[float, float, float], ...]:
    # Spin axes at 45, 135, 225, 315 degrees of azimuth about body z, tilted elevation_deg
    # out of the xy plane.
    b = math.radians(elevation_deg)
    return tuple((math.cos(b) * math.cos(a), math.cos(b) * math.sin(a), math.sin(b)) for a in (math.pi / 4 + k * math.pi / 2 for k in range(4)))


@dataclasses.dataclass(frozen=True)
class FlexibleSpacecraft:
    """Spacecraft with flexible appendages and four reaction wheels: the truncated hybrid
    coordinate model (Likins) with three flexible modes.

    State (23,): ``[r, q, v, omega (13), eta (3), eta_dot (3), h_w (4)]``; the rigid block is
    the one of every model (no forces act, so r and v only drift), ``eta`` the modal
    coordinates (units sqrt(kg) m), ``h_w`` the wheel spin momenta relative to the body
    (N m s). Inputs ``u`` (4,): motor torques on the wheels (N m), bounded by 0.5 in the slew.

    Equations (body frame; ``H`` the total angular momentum about the centre of mass)::

        H        = J omega + delta^T eta_dot + A_w h_w
        H_dot    = -omega x H                      (no external torque)
        h_w_dot  = u
        eta_ddot = -delta omega_dot - C eta_dot - K eta,   C = 2 zeta Omega, K = Omega^2

    so ``(J - delta^T delta) omega_dot = -omega x H - A_w u + delta^T (C eta_dot + K eta)``.
    Wheel torques are internal: the world-frame momentum ``A(q) H`` is conserved exactly by the
    continuous dynamics whatever u is.

    Parameters: J = diag(1, 2, 3) kg m^2 (paper; hub plus locked wheels and appendages).
    Documented choices for the rest: modal frequencies 0.1, 0.2, 0.3 Hz and damping ratio
    0.005 (typical of large solar arrays); coupling ``delta`` (3 modes x 3 axes, sqrt(kg) m)
    below, so that the appendages carry 10-22 % of the inertia about each axis
    (``J - delta^T delta`` stays well positive definite); four wheels in a pyramid about body
    z at 35.26 degrees elevation (``cos^2 = 2/3``), the arrangement whose torque envelope is
    isotropic (``A_w A_w^T = 4/3 I``).
    """

    inertia: tuple[float, float, float] = (1.0, 2.0, 3.0)
    modal_frequencies_hz: tuple[float, float, float] = (0.1, 0.2, 0.3)
    modal_damping: tuple[float, float, float] = (0.005, 0.005, 0.005)
    coupling: tuple[tuple[float, float, float], ...] = (
        (0.30, 0.00, 0.05),
        (0.00, 0.60, 0.10),
        (0.10, 0.00, 0.80),
    )
    wheel_axes: tuple[tuple[float, float, float], ...] = _pyramid_axes(math.degrees(math.asin(1 / math.sqrt(3))))
    torque_limit: float = 0.5

    nx: ClassVar[int] = 23
    nu: ClassVar[int] = 4
    ETA: ClassVar[slice] = slice(13, 16)
    ETA_DOT: ClassVar[slice] = slice(16, 19)
    WHEELS: ClassVar[slice] = slice(19, 23)

    def matrices(self) -> dict[str, jax.Array]:
        """J, delta (3, 3), A_w (3, 4), C, K (3, 3) as arrays."""
        w = 2 * jnp.pi * jnp.asarray(self.modal_frequencies_hz)
        return {
            "J": jnp.diag(jnp.asarray(self.inertia)),
            "delta": jnp.asarray(self.coupling),
            "A_w": jnp.asarray(self.wheel_axes).T,
            "C": jnp.diag(2 * jnp.asarray(self.modal_damping) * w),
            "K": jnp.diag(w**2),
        }

    def angular_momentum_body(self, x: jax.Array) -> jax.Array:
        m = self.matrices()
        return m["J"] @ x[OMEGA] + m["delta"].T @ x[self.ETA_DOT] + m["A_w"] @ x[self.WHEELS]

    def angular_momentum_world(self, x: jax.Array) -> jax.Array:
        return quat.rotate(x[QUAT], self.angular_momentum_body(x))

    def energy(self, x: jax.Array) -> jax.Array:
        """Kinetic plus elastic energy of hub and appendages (wheel spin energy excluded):
        ``1/2 w^T J w + w^T delta^T eta_dot + 1/2 |eta_dot|^2 + 1/2 eta^T K eta``. Along the flow
        its rate is ``-w^T A_w u - eta_dot^T C eta_dot`` (the wheels' gyroscopic torque does no
        work), so it is conserved for u = 0 without damping, spinning wheels included."""
        m = self.matrices()
        w, eta, eta_dot = x[OMEGA], x[self.ETA], x[self.ETA_DOT]
        return 0.5 * w @ m["J"] @ w + w @ m["delta"].T @ eta_dot + 0.5 * eta_dot @ eta_dot + 0.5 * eta @ m["K"] @ eta

    def dynamics(self, x: jax.Array, u: jax.Array) -> jax.Array:
        x, u = _state_and_input(self, x, u)
        m = self.matrices()
        q, w = x[QUAT], x[OMEGA]
        eta, eta_dot = x[self.ETA], x[self.ETA_DOT]
        H = self.angular_momentum_body(x)
        elastic = m["C"] @ eta_dot + m["K"] @ eta
        w_dot = jnp.linalg.solve(m["J"] - m["delta"].T @ m["delta"], -jnp.cross(w, H) - m["A_w"] @ u + m["delta"].T @ elastic)
        eta_ddot = -m["delta"] @ w_dot - elastic
        q_dot = 0.5 * quat.L(q) @ quat.H @ w
        return jnp.concatenate([x[VEL], q_dot, jnp.zeros(3, x.dtype), w_dot, eta_dot, eta_ddot, u])

    @staticmethod
    def sun_angle(q: jax.Array, camera_body: jax.Array, sun_world: jax.Array) -> jax.Array:
        """Angle (rad) between the camera axis ``A(q) c`` and the sun direction (both unit)."""
        return jnp.arccos(jnp.clip(sun_world @ quat.rotate(q, camera_body), -1.0, 1.0))
