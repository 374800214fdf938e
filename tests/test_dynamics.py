"""Inverse dynamics and contact kinematics against MuJoCo C, Pinocchio and MJX; the analytical
Jacobians against jax.jacfwd; physical laws (free fall, Newton) and the convention details.

Inputs are a few random states per robot; compiled functions are module-level and shared.
"""

import copy
import functools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pinocchio as pin
import pytest

from jtraj import dynamics, lie
from jtraj import robot as robot_lib
from jtraj.parameterization import PARAMETERIZATIONS

ROBOTS = ("talos", "g1", "go2")
NSTATES = 2
QUAT1 = PARAMETERIZATIONS["quat1"]


@functools.partial(jax.jit, static_argnums=(0, 1))
def _evaluate(robot, param, Q, V, A, F):
    """Everything the oracles compare, for a batch of states (one compile per robot/chart)."""

    def one(q, v, a, f):
        M, dtau_df = dynamics.acceleration_force_jacobians(robot, param, q)
        return dict(
            tau=dynamics.inverse_dynamics(robot, param, q, v, a, f),
            points=dynamics.contact_positions(robot, param, q),
            Jc=dynamics.contact_jacobians(robot, param, q),
            M=dynamics.mass_matrix(robot, param, q),
            M_direct=M,
            dtau_df=dtau_df,
            qpos_qvel_qacc=dynamics.to_mujoco(robot, param, q, v, a),
        )

    return jax.vmap(one)(Q, V, A, F)


_jacfwd = jax.jit(
    jax.vmap(jax.jacfwd(dynamics.inverse_dynamics, argnums=(2, 3, 4, 5)), in_axes=(None, None, 0, 0, 0, 0)),
    static_argnums=(0, 1),
)
_points_jacfwd = jax.jit(
    jax.vmap(jax.jacfwd(dynamics.contact_positions, argnums=2), in_axes=(None, None, 0)),
    static_argnums=(0, 1),
)
_points_jacobians = jax.jit(
    jax.vmap(dynamics.contact_position_jacobians, in_axes=(None, None, 0)), static_argnums=(0, 1)
)
_mjx = jax.jit(
    jax.vmap(dynamics.inverse_dynamics_mjx, in_axes=(None, None, 0, 0, 0, 0)), static_argnums=(0, 1)
)
_tau = jax.jit(dynamics.inverse_dynamics, static_argnums=(0, 1))


def random_states(robot, param, n, seed=0, quaternion_scale=1.0, standing=False):
    """n random states: base anywhere with any orientation, joints inside their limits;
    with ``standing``, the first is the standing pose at rest."""
    rng = np.random.default_rng(seed)
    Q, V, A, F = [], [], [], []
    for _ in range(n):
        T = lie.exp(lie.SE3, jnp.asarray(rng.normal(size=6) * np.array([1, 1, 1, 1.5, 1.5, 1.5])))
        q_base = np.array(param.from_pose(T))
        if param.nq == 7:  # quaternion charts normalize wherever they use rho
            q_base[3:] *= quaternion_scale
        q_joints = rng.uniform(robot.q_lower.clip(-2, 2), robot.q_upper.clip(-2, 2))
        Q.append(np.concatenate([q_base, q_joints]))
        V.append(rng.normal(size=robot.nv))
        A.append(rng.normal(size=robot.nv))
        F.append(rng.normal(scale=50.0, size=(robot.ncontact, 3)))
    if standing:  # the warm start: identity rotation (series branches of the charts), at rest
        q_base = np.asarray(param.from_pose(robot.base_pose_standing))
        Q[0] = np.concatenate([q_base, robot.q_joints_standing])
        V[0], A[0] = np.zeros(robot.nv), np.zeros(robot.nv)
        F[0] = np.tile([0.0, 0.0, robot.total_mass * robot.gravity / robot.ncontact], (robot.ncontact, 1))
    return tuple(jnp.asarray(np.stack(x)) for x in (Q, V, A, F))


def rel_err(x, ref):
    x, ref = np.asarray(x), np.asarray(ref)
    return np.abs(x - ref).max() / max(np.abs(ref).max(), 1e-300)


@pytest.fixture(scope="module", params=ROBOTS)
def robot(request):
    return robot_lib.load(request.param)


@pytest.fixture(scope="module")
def evaluated(robot):
    """States (quat1 chart, quaternions not unit norm) and all quantities at them."""
    states = random_states(robot, QUAT1, NSTATES, seed=1, quaternion_scale=1.7)
    return states, jax.tree.map(np.asarray, _evaluate(robot, QUAT1, *states))


# ----------------------------------------------------------------------------------------
# MuJoCo C


def _rotation(qpos):
    R = np.zeros(9)
    mujoco.mju_quat2Mat(R, qpos[3:7] / np.linalg.norm(qpos[3:7]))
    return R.reshape(3, 3)


def test_matches_mujoco_c(robot, evaluated):
    (_, _, _, F), out = evaluated
    m = robot.mj_model
    d = mujoco.MjData(m)
    for k in range(NSTATES):
        qpos, qvel, qacc = (np.asarray(x[k]) for x in out["qpos_qvel_qacc"])
        d.qpos[:], d.qvel[:], d.qacc[:] = qpos, qvel, qacc
        mujoco.mj_inverse(m, d)
        qfrc = d.qfrc_inverse.copy()
        jacs = []
        for c in range(robot.ncontact):
            jacp = np.zeros((3, m.nv))
            mujoco.mj_jac(m, d, jacp, None, out["points"][k, c], robot.contact_body_ids[c])
            jacs.append(jacp)
            qfrc -= jacp.T @ np.asarray(F[k, c])
        # qvel = P V with P = diag(R, 1): tau = P^T qfrc, M = P^T M_mj P, J = J_mj P
        P = np.eye(m.nv)
        P[:3, :3] = _rotation(qpos)
        M_mj = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, M_mj)
        assert rel_err(out["tau"][k], P.T @ qfrc) < 1e-10
        assert rel_err(out["M"][k], P.T @ M_mj @ P) < 1e-10
        assert rel_err(out["Jc"][k], np.stack(jacs) @ P) < 1e-10
        b = robot.contact_body_ids
        points = d.xpos[b] + np.einsum("cij,cj->ci", d.xmat[b].reshape(-1, 3, 3), robot.contact_offsets)
        np.testing.assert_allclose(out["points"][k], points, atol=1e-12)


# ----------------------------------------------------------------------------------------
# Pinocchio


def _pinocchio(robot):
    model, frames, q_index, v_index = robot_lib.to_pinocchio(robot)
    v_perm = np.concatenate([np.arange(6), v_index])  # ours -> Pinocchio
    return model, frames, q_index, v_perm


def _pin_q(model, q_index, q_quat1):
    """Pinocchio configuration of a quat1 configuration (xyz, wxyz not unit, joints)."""
    q = np.zeros(model.nq)
    q[:3] = q_quat1[:3]
    w, x, y, z = q_quat1[3:7] / np.linalg.norm(q_quat1[3:7])
    q[3:7] = [x, y, z, w]
    q[q_index] = q_quat1[7:]
    return q


def test_matches_pinocchio(robot, evaluated):
    (Q, V, A, F), out = evaluated
    model, frames, q_index, perm = _pinocchio(robot)
    data = model.createData()
    for k in range(NSTATES):
        q = _pin_q(model, q_index, np.asarray(Q[k]))
        v, a = np.zeros(model.nv), np.zeros(model.nv)
        v[perm], a[perm] = V[k], A[k]
        pin.framesForwardKinematics(model, data, q)
        pin.computeJointJacobians(model, data, q)
        Jc = np.stack([pin.getFrameJacobian(model, data, f, pin.LOCAL_WORLD_ALIGNED)[:3] for f in frames])
        points = np.stack([data.oMf[f].translation for f in frames])
        tau = pin.rnea(model, data, q, v, a) - np.einsum("cij,ci->j", Jc, np.asarray(F[k]))
        M = pin.crba(model, data, q)
        M = np.triu(M) + np.triu(M, 1).T
        assert rel_err(out["tau"][k], tau[perm]) < 1e-10
        assert rel_err(out["M"][k], M[np.ix_(perm, perm)]) < 1e-10
        assert rel_err(out["Jc"][k], Jc[:, :, perm]) < 1e-10
        np.testing.assert_allclose(out["points"][k], points, atol=1e-12)


def test_derivatives_match_pinocchio_rnea_derivatives():
    """dtau/dq, dtau/dv, dtau/da against Pinocchio's analytical RNEA derivatives (no
    contact forces: Pinocchio's external forces are fixed in the joint frames, ours in the
    world). dtau/dq is compared along the tangent: q(delta) = Pinocchio's integrate."""
    robot = robot_lib.load("talos")
    model, _, q_index, perm = _pinocchio(robot)
    data = model.createData()
    Q, V, A, F = random_states(robot, QUAT1, 1, seed=5)
    F = jnp.zeros_like(F)
    jac = dynamics.batched_inverse_dynamics_derivatives(robot, QUAT1, Q, V, A, F)
    q = _pin_q(model, q_index, np.asarray(Q[0]))
    v, a = np.zeros(model.nv), np.zeros(model.nv)
    v[perm], a[perm] = V[0], A[0]
    dq, dv, da = pin.computeRNEADerivatives(model, data, q, v, a)
    da = np.triu(da) + np.triu(da, 1).T
    # coordinates of q (+) delta for the quat1 chart (xyz, wxyz), first order in delta:
    # d xyz = R d_lin, d wxyz = 1/2 wxyz * (0, d_ang)
    wxyz = np.asarray(Q[0, 3:7])
    w, x, y, z = wxyz / np.linalg.norm(wxyz)
    R = pin.Quaternion(w, x, y, z).toRotationMatrix()
    L = np.array([[-x, -y, -z], [w, -z, y], [z, w, -x], [-y, x, w]])  # d wxyz / d omega_body * 2
    dcoords = np.zeros((robot.nj + 7, robot.nv))
    dcoords[:3, :3] = R
    dcoords[3:7, 3:6] = 0.5 * L * np.linalg.norm(wxyz)
    dcoords[7:, 6:] = np.eye(robot.nj)
    assert rel_err(np.asarray(jac.dq[0]) @ dcoords, dq[np.ix_(perm, perm)]) < 1e-10
    assert rel_err(jac.dv[0], dv[np.ix_(perm, perm)]) < 1e-10
    assert rel_err(jac.da[0], da[np.ix_(perm, perm)]) < 1e-10


# ----------------------------------------------------------------------------------------
# MJX's pipeline


@pytest.mark.parametrize("name", ["go2", "talos"])
def test_mjx_reference_matches(name):
    robot = robot_lib.load(name)
    states = random_states(robot, QUAT1, NSTATES, seed=2)
    out = _evaluate(robot, QUAT1, *states)
    assert rel_err(_mjx(robot, QUAT1, *states), out["tau"]) < 1e-10


# ----------------------------------------------------------------------------------------
# Analytical Jacobians == jax.jacfwd


@pytest.mark.parametrize(
    "name, chart",
    [("talos", "se3"), ("talos", "quat1"), ("go2", "euler"), ("go2", "quat3")],
)
def test_jacobians_equal_jacfwd(name, chart):
    robot = robot_lib.load(name)
    param = PARAMETERIZATIONS[chart]
    Q, V, A, F = random_states(robot, param, NSTATES, seed=3, quaternion_scale=0.8, standing=True)
    fast = dynamics.batched_inverse_dynamics_derivatives(robot, param, Q, V, A, F)
    for x in fast:
        assert np.all(np.isfinite(x))
    dq, dv, da, df = _jacfwd(robot, param, Q, V, A, F)
    K, nv = Q.shape[0], robot.nv
    assert fast.dq.shape == (K, nv, param.nq + robot.nj)
    assert fast.df.shape == (K, nv, 3 * robot.ncontact)
    assert rel_err(fast.dq, dq) < 1e-10
    assert rel_err(fast.dv, dv) < 1e-10
    assert rel_err(fast.da, da) < 1e-10
    assert rel_err(fast.df, df.reshape(K, nv, -1)) < 1e-10
    assert rel_err(_points_jacobians(robot, param, Q), _points_jacfwd(robot, param, Q)) < 1e-12
    # tau comes with the Jacobians, equal to the per-knot function's
    assert rel_err(fast.tau[-1], _tau(robot, param, Q[-1], V[-1], A[-1], F[-1])) < 1e-12


def test_direct_jacobians_are_mass_matrix_and_contact_jacobians(robot, evaluated):
    """acceleration_force_jacobians shares its helpers with mass_matrix and contact_jacobians,
    so it is checked against autodiff of the inverse dynamics (M and -J_c^T by definition, in
    the column order of ``forces.reshape(-1)``), which the mass-matrix oracles (MuJoCo, pin)
    do not cover."""
    states, out = evaluated
    _, _, da, df = _jacfwd(robot, QUAT1, *states)
    K = da.shape[0]
    assert rel_err(out["M_direct"], da) < 1e-10
    assert rel_err(out["dtau_df"], np.asarray(df).reshape(K, robot.nv, -1)) < 1e-10
    for M in out["M_direct"]:
        np.testing.assert_allclose(M, M.T, atol=1e-12 * np.abs(M).max())
        assert np.linalg.eigvalsh(M).min() > 0


def test_jacobians_do_not_recompile():
    robot = robot_lib.load("go2")
    param = PARAMETERIZATIONS["quat3"]
    states = random_states(robot, param, NSTATES, seed=3, quaternion_scale=0.8)
    dynamics.batched_inverse_dynamics_derivatives(robot, param, *states)
    before = dynamics.batched_inverse_dynamics_derivatives._cache_size()
    states = random_states(robot, param, NSTATES, seed=4)
    dynamics.batched_inverse_dynamics_derivatives(robot, param, *states)
    assert dynamics.batched_inverse_dynamics_derivatives._cache_size() == before


def test_former_name_of_the_batched_derivatives_warns():
    with pytest.warns(DeprecationWarning, match="inverse_dynamics_jacobians is deprecated"):
        assert dynamics.inverse_dynamics_jacobians is dynamics.batched_inverse_dynamics_derivatives


def test_body_masses_match_mujoco_with_the_same_masses():
    """``masses`` scales each body (mass and rotational inertia) like a MuJoCo model with
    those masses and inertias scaled alike; the model's masses give the default exactly."""
    robot = robot_lib.load("go2")
    Q, V, A, F = random_states(robot, QUAT1, 1, seed=8, quaternion_scale=1.3)
    q, v, a, f = Q[0], V[0], A[0], F[0]
    m0 = dynamics.model_masses(robot)
    assert m0.shape == (robot.mj_model.nbody,) and abs(m0.sum() - robot.total_mass) < 1e-12
    tau_masses = jax.jit(dynamics.inverse_dynamics, static_argnums=(0, 1))
    np.testing.assert_array_equal(tau_masses(robot, QUAT1, q, v, a, f, jnp.asarray(m0)), _tau(robot, QUAT1, q, v, a, f))
    scale = np.random.default_rng(9).uniform(0.5, 2.0, m0.shape)
    model = copy.deepcopy(robot.mj_model)
    model.body_mass[:] = m0 * scale
    model.body_inertia[:] = robot.mj_model.body_inertia * scale[:, None]
    d = mujoco.MjData(model)
    qpos, qvel, qacc = (np.asarray(x) for x in dynamics.to_mujoco(robot, QUAT1, q, v, a))
    d.qpos[:], d.qvel[:], d.qacc[:] = qpos, qvel, qacc
    mujoco.mj_inverse(model, d)
    qfrc = d.qfrc_inverse.copy()
    points = np.asarray(dynamics.contact_positions(robot, QUAT1, q))
    for c in range(robot.ncontact):
        jacp = np.zeros((3, model.nv))
        mujoco.mj_jac(model, d, jacp, None, points[c], robot.contact_body_ids[c])
        qfrc -= jacp.T @ np.asarray(f[c])
    tau = tau_masses(robot, QUAT1, q, v, a, f, jnp.asarray(m0 * scale))
    assert rel_err(tau, dynamics.tau_from_mujoco(qpos, qfrc)) < 1e-10
    assert rel_err(tau, _tau(robot, QUAT1, q, v, a, f)) > 1e-3  # the masses did change tau


def test_jacobians_with_masses_equal_jacfwd():
    """The analytical Jacobians at other masses, and d tau / d masses exists (autodiff)."""
    robot = robot_lib.load("go2")
    param = PARAMETERIZATIONS["se3"]
    Q, V, A, F = random_states(robot, param, NSTATES, seed=10)
    masses = jnp.asarray(dynamics.model_masses(robot) * np.random.default_rng(11).uniform(0.5, 2.0, robot.mj_model.nbody))
    fast = dynamics.batched_inverse_dynamics_derivatives(robot, param, Q, V, A, F, masses)
    jac = jax.jit(
        jax.vmap(jax.jacfwd(dynamics.inverse_dynamics, argnums=(2, 3, 4, 5, 6)), in_axes=(None, None, 0, 0, 0, 0, None)),
        static_argnums=(0, 1),
    )
    dq, dv, da, df, dm = jac(robot, param, Q, V, A, F, masses)
    assert rel_err(fast.dq, dq) < 1e-10
    assert rel_err(fast.dv, dv) < 1e-10
    assert rel_err(fast.da, da) < 1e-10
    assert rel_err(fast.df, df.reshape(*fast.df.shape)) < 1e-10
    # tau without contact forces is linear and homogeneous in the masses: tau = dtau/dm m
    @jax.jit
    def free(Q, V, A, masses):
        def tau(q, v, a, m):
            return dynamics.inverse_dynamics(robot, param, q, v, a, jnp.zeros((robot.ncontact, 3)), m)

        per_knot = jax.vmap(lambda q, v, a: (tau(q, v, a, masses), jax.jacfwd(tau, argnums=3)(q, v, a, masses)))
        return per_knot(Q, V, A)

    tau_free, dm_free = free(Q, V, A, masses)
    assert rel_err(jnp.einsum("kvb,b->kv", dm_free, masses), tau_free) < 1e-10
    assert dm.shape == (NSTATES, robot.nv, robot.mj_model.nbody)


# ----------------------------------------------------------------------------------------
# Physics and conventions


def test_free_fall_needs_no_force(robot):
    """Every body falling with gravity, at rest: tau = 0 (v = 0, base accel = R^T g)."""
    (Q, V, A, F) = random_states(robot, QUAT1, NSTATES, seed=6)
    R = jax.vmap(lambda q: QUAT1.to_pose(q[:7]).rotation().as_matrix())(Q)
    g = jnp.array([0.0, 0.0, -robot.gravity])
    A = jnp.zeros_like(A).at[:, :3].set(jnp.einsum("kji,j->ki", R, g))
    out = _evaluate(robot, QUAT1, Q, jnp.zeros_like(V), A, jnp.zeros_like(F))
    assert np.abs(out["tau"]).max() < 1e-10 * robot.total_mass * robot.gravity


def test_base_force_obeys_newton(robot):
    """At rest (v = a = 0) the base force is m g minus the contact forces, in the world."""
    (Q, V, A, F) = random_states(robot, QUAT1, NSTATES, seed=7)
    out = _evaluate(robot, QUAT1, Q, jnp.zeros_like(V), jnp.zeros_like(A), F)
    R = np.stack([np.asarray(QUAT1.to_pose(q[:7]).rotation().as_matrix()) for q in Q])
    f_world = np.einsum("kij,kj->ki", R, out["tau"][:, :3])
    expected = np.array([0.0, 0.0, robot.total_mass * robot.gravity]) - np.asarray(F).sum(axis=1)
    np.testing.assert_allclose(f_world, expected, atol=1e-9 * np.abs(expected).max())


def test_quaternion_scale_is_invisible(robot, evaluated):
    """quat1 normalizes rho: tau does not change when rho is scaled, and dtau/dq along rho is 0."""
    (Q, V, A, F), out = evaluated
    Q2 = Q.at[:, 3:7].multiply(0.3)
    out2 = _evaluate(robot, QUAT1, Q2, V, A, F)
    assert rel_err(out2["tau"], out["tau"]) < 1e-12
    if robot.name == "go2":  # cheapest compile for the Jacobian
        jac = dynamics.batched_inverse_dynamics_derivatives(robot, QUAT1, Q, V, A, F)
        radial = jnp.einsum("kij,kj->ki", jac.dq[:, :, 3:7], Q[:, 3:7])
        assert np.abs(radial).max() < 1e-10 * np.abs(jac.dq).max()


def test_wrong_shapes_raise_with_expected_shape():
    robot = robot_lib.load("go2")
    q = jnp.zeros(7 + robot.nj)
    v = jnp.zeros(robot.nv)
    f = jnp.zeros((robot.ncontact, 3))
    with pytest.raises(ValueError, match=r"expected \(18,\)"):
        dynamics.inverse_dynamics(robot, PARAMETERIZATIONS["se3"], q, v, v, f)
    with pytest.raises(ValueError, match=r"\(4, 3\)"):
        dynamics.inverse_dynamics(robot, QUAT1, q, v, v, f[:2])


def test_mujoco_conversions_check_shapes():
    """to_mujoco and the MJX reference check v, a and the forces as inverse_dynamics does;
    to_mujoco returned a qvel of 6 entries for a v of 6, and the MJX reference ended in
    errors from inside MuJoCo and einsum."""
    robot = robot_lib.load("go2")
    q = jnp.zeros(7 + robot.nj).at[3].set(1.0)
    v = jnp.zeros(robot.nv)
    f = jnp.zeros((robot.ncontact, 3))
    with pytest.raises(ValueError, match=r"v and a must have shape \(18,\), got \(6,\) and \(18,\)"):
        dynamics.to_mujoco(robot, QUAT1, q, v[:6], v)
    with pytest.raises(ValueError, match=r"v and a must have shape \(18,\), got \(18,\) and \(17,\)"):
        dynamics.inverse_dynamics_mjx(robot, QUAT1, q, v, v[:17], f)
    with pytest.raises(ValueError, match=r"forces must have shape \(4, 3\) .*, got \(2, 3\)"):
        dynamics.inverse_dynamics_mjx(robot, QUAT1, q, v, v, f[:2])
    qpos, qvel, qacc = dynamics.to_mujoco(robot, QUAT1, q, v, v)
    assert qpos.shape == (7 + robot.nj,) and qvel.shape == qacc.shape == (robot.nv,)


def test_lists_are_taken_as_arrays():
    """The public functions take lists, as JAX's own do (the shape checks read ``.shape``
    first: contact_positions(robot, param, [0.0] * 18) was an AttributeError); integers
    become floats."""
    robot = robot_lib.load("go2")
    se3 = PARAMETERIZATIONS["se3"]
    rng = np.random.default_rng(3)
    q, v, a = (0.1 * rng.standard_normal(n) for n in (6 + robot.nj, robot.nv, robot.nv))
    forces = [[0, 0, 40]] * robot.ncontact  # integers
    as_arrays = (jnp.asarray(q), jnp.asarray(v), jnp.asarray(a), jnp.asarray(forces, float))
    as_lists = (q.tolist(), v.tolist(), a.tolist(), forces)
    for fn, n_args in (
        (dynamics.contact_positions, 1),
        (dynamics.inverse_dynamics, 4),
        (dynamics.inverse_dynamics_derivatives, 4),  # reads the forces again after inverse dynamics
        (dynamics.to_mujoco, 3),
    ):
        got, expected = fn(robot, se3, *as_lists[:n_args]), fn(robot, se3, *as_arrays[:n_args])
        jax.tree.map(np.testing.assert_array_equal, got, expected)


def test_robot_without_contact_points(tmp_path):
    """A robot file may declare no contact point: its contact arrays are (0, 3) and (0,), and
    inverse dynamics takes forces of shape (0, 3). The offsets came back as (0,), and every
    function of this module failed with an IndexError."""
    import importlib.resources
    import re

    text = (importlib.resources.files("jtraj.robots") / "go2.toml").read_text()
    path = tmp_path / "go2_no_contacts.toml"
    path.write_text(re.sub(r"\[\[contact\]\].*", "", text, flags=re.S))  # the contacts and groups go
    robot = robot_lib.load_file(path)
    assert robot.ncontact == 0 and robot.contact_offsets.shape == (0, 3) and robot.contact_body_ids.shape == (0,)
    q = jnp.concatenate([jnp.array([0.0, 0.0, 0.3, 1.0, 0.0, 0.0, 0.0]), jnp.asarray(robot.q_joints_standing)])
    v = jnp.zeros(robot.nv)
    tau = dynamics.inverse_dynamics(robot, QUAT1, q, v, v, jnp.zeros((0, 3)))
    np.testing.assert_allclose(tau[:3], [0.0, 0.0, robot.total_mass * robot.gravity], rtol=1e-12)  # at rest: m g
    assert dynamics.contact_positions(robot, QUAT1, q).shape == (0, 3)
    assert dynamics.contact_jacobians(robot, QUAT1, q).shape == (0, 3, robot.nv)
