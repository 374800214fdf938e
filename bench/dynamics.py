"""Inverse dynamics and its Jacobians over one Talos trajectory: jtraj versus Pinocchio.

Run: ``python bench/dynamics.py [--knots 66] [--repeats 30] [--robot talos] [--out DIR]``

For K knots with random states (q, v, a, contact forces) it times, median over repeats:
  - tau at all knots: jtraj (jit + vmap) vs Pinocchio (rnea with external forces, Python loop);
  - the full Jacobian of tau w.r.t. every knot variable (q, v, a, forces), with tau: jtraj's
    batched analytical derivatives vs Pinocchio's computeRNEADerivatives (which computes tau
    too) + contact frame Jacobians (Python loop over knots, same states);
  - for comparison, jax.jacfwd through MJX's pipeline and through jtraj's own RNEA.
Compile times are the first call's wall time. Pinocchio's external forces are built in the
joint frames before timing (which only favours Pinocchio). Before any timing is reported, the
last knot's tau, dtau/dv, M and J_c are checked against Pinocchio's (`AGREEMENT_TOL`) and
dtau/dq against central differences of Pinocchio's tau with the forces fixed in the world
(`DQ_TOL`; Pinocchio's analytical dtau/dq holds them fixed in the joint frames instead). The autodiff baselines are the
median of fewer calls (a third of ``--repeats``, at least 3; jacfwd through MJX: 3), which the
table says. ``--out DIR`` writes ``DIR/dynamics.json``, ``DIR/dynamics.md`` and
``DIR/provenance.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

try:  # the peer: main() says so when it is missing (--help works without it)
    import pinocchio as pin
except ImportError:
    pin = None

import jtraj  # noqa: F401  (float64)
from jtraj import dynamics
from jtraj import robot as robot_lib
from jtraj.parameterization import PARAMETERIZATIONS

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/_args.py, also when the tests load this file from its path
from _args import add_out, add_param  # noqa: E402


def timed(fn, repeats):
    """(first-call seconds, median seconds over repeats) of fn(), blocking on the result."""
    t0 = time.perf_counter()
    jax.block_until_ready(fn())
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return first, float(np.median(times))


def batched(fn):
    """jit(vmap(fn)) over knots for fn(robot, param, q, v, a, forces)."""
    return jax.jit(jax.vmap(fn, in_axes=(None, None, 0, 0, 0, 0)), static_argnums=(0, 1))


def row(label, ours, theirs=None, note="", compile_s=None, repeats=None) -> dict:
    """Print one line of the table: jtraj's time, Pinocchio's and jtraj's over Pinocchio's
    (below 1: jtraj is faster); return it as a record (seconds) for `table`."""
    line = f"{label:44s}{ours * 1e3:10.3f}ms"
    if theirs is not None:
        line += f"{theirs * 1e3:10.3f}ms{ours / theirs:19.2f}"
    print(line + note)
    return dict(label=label, jtraj_s=ours, pinocchio_s=theirs, compile_s=compile_s, repeats=repeats)


def table(rows: list[dict], note: str) -> str:
    """Markdown: one line per `row` record, times in milliseconds, and ``note``."""
    from jtraj.tables import markdown_table

    def ms(t):
        return "" if t is None else f"{t * 1e3:.3f}"

    return markdown_table(
        ("", "jtraj (ms)", "Pinocchio (ms)", "jtraj / Pinocchio", "jtraj compile (s)", "median of"),
        [
            (r["label"], ms(r["jtraj_s"]), ms(r["pinocchio_s"]), "" if r["pinocchio_s"] is None else f"{r['jtraj_s'] / r['pinocchio_s']:.2f}",
             "" if r["compile_s"] is None else f"{r['compile_s']:.2f}", r["repeats"])
            for r in rows
        ],
        note,
    )


def pinocchio_model(robot):
    return robot_lib.to_pinocchio(robot)


def pinocchio_jacobians(model, data, frames, qs, vs, as_, fexts) -> list:
    """Per knot, what jtraj's batched derivatives return: tau, dtau/dq, dtau/dv, dtau/da and the
    contact frames' Jacobians (their 3 translation rows). computeRNEADerivatives computes tau
    (``data.tau``) and the joint placements and Jacobians that getFrameJacobian reads: an rnea
    before it (as this benchmark once timed) did the same pass twice and slowed Pinocchio's side.
    The derivative matrices are ``data``'s own, which the next knot overwrites (not copied:
    the timed work is the computation)."""
    out = []
    for q, v, a, fext in zip(qs, vs, as_, fexts):
        dq, dv, da = pin.computeRNEADerivatives(model, data, q, v, a, fext)
        Jc = [pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)[:3] for fid in frames]
        out.append((data.tau.copy(), dq, dv, da, Jc))
    return out


def pinocchio_state(model, q_index, perm, param, q, v, a) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pinocchio's (q, v, a) of one knot of jtraj's (``q`` in the chart ``param``, then the
    joints; ``v``, ``a`` in jtraj's order): the free flyer's (xyz, quaternion xyzw), the joints
    at ``q_index``, the velocities put at ``perm`` (jtraj's index to Pinocchio's)."""
    T = param.to_pose(jnp.asarray(q[: param.nq]))
    qp = np.zeros(model.nq)
    qp[:3] = np.asarray(T.translation())
    w, x, y, z = np.asarray(T.rotation().wxyz)
    qp[3:7] = [x, y, z, w]
    qp[q_index] = np.asarray(q[param.nq :])
    vp, ap = np.zeros(model.nv), np.zeros(model.nv)
    vp[perm], ap[perm] = np.asarray(v), np.asarray(a)
    return qp, vp, ap


def joint_forces(model, data, frames, qp, f_world) -> list:
    """Pinocchio's external forces, one per joint in its frame, of the world-frame forces
    ``f_world`` (one row of 3 per contact frame) applied at the contact frames' origins at
    configuration ``qp`` (jtraj's contact forces). Leaves ``data``'s placements at ``qp``."""
    pin.framesForwardKinematics(model, data, qp)
    fext = [pin.Force.Zero() for _ in range(model.njoints)]
    for c, fid in enumerate(frames):
        joint = model.frames[fid].parentJoint
        p = data.oMf[fid].translation
        fext[joint] += data.oMi[joint].actInv(pin.Force(f_world[c], np.cross(p, f_world[c])))
    return fext


#: the step of `tau_dq_differences`
FD_STEP = 1e-6


def tau_dq_differences(model, data, frames, qp, vp, ap, f_world, perm, h: float = FD_STEP) -> np.ndarray:
    """dtau/dq by central differences of Pinocchio's rnea, the contact forces ``f_world`` fixed
    in the world and applied where the contact frames are at each perturbed configuration
    (`joint_forces`). Column i is along Pinocchio's tangent direction ``perm[i]``
    (``pin.integrate``: the base's twist in its own frame, then the joints), rows and columns in
    jtraj's order of velocities (``perm``: jtraj's index to Pinocchio's)."""
    nv = model.nv
    out = np.empty((nv, nv))
    for i in range(nv):
        step = np.zeros(nv)
        step[perm[i]] = h
        taus = []
        for sign in (1.0, -1.0):
            q = pin.integrate(model, qp, sign * step)
            taus.append(pin.rnea(model, data, q, vp, ap, joint_forces(model, data, frames, q, f_world)).copy())
        out[:, i] = ((taus[0] - taus[1]) / (2 * h))[perm]
    return out


def chart_tangent(param, q_base, nj: int) -> np.ndarray:
    """(param.nq + nj, 6 + nj): the derivative of the coordinates of ``q (+) delta`` at delta = 0,
    the base moved by ``T Exp(delta_base)`` (Pinocchio's integrate, to first order) and the
    joints by ``delta_joints``; jtraj's dtau/dq times it is dtau along Pinocchio's tangent."""
    T = param.to_pose(jnp.asarray(q_base))
    base = jax.jacfwd(lambda d: param.from_pose(T @ jtraj.lie.exp(jtraj.lie.SE3, d)))(jnp.zeros(6))
    out = np.zeros((param.nq + nj, 6 + nj))
    out[: param.nq, :6] = np.asarray(base)
    out[param.nq :, 6:] = np.eye(nj)
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="talos", choices=robot_lib.available())
    parser.add_argument("--knots", type=int, default=66)
    parser.add_argument("--repeats", type=int, default=30)
    add_param(parser, "quat1")
    parser.add_argument("--skip-mjx", action="store_true", help="skip the slow jacfwd-through-MJX baseline")
    add_out(parser, "dynamics")
    args = parser.parse_args(argv)
    for name in ("knots", "repeats"):
        if getattr(args, name) < 1:
            parser.error(f"--{name}: {getattr(args, name)}: expected an integer >= 1")
    if pin is None:  # a traceback at import, before: jtraj's columns alone would be no comparison
        parser.error("Pinocchio, the peer of this benchmark, is not installed: pip install pin==4.1.0 (in jtraj's [bench] extra)")

    robot = robot_lib.load(args.robot)
    param = PARAMETERIZATIONS[args.param]
    K, nv, nc = args.knots, robot.nv, robot.ncontact
    rng = np.random.default_rng(0)

    # Random states around the standing pose.
    T0 = robot.base_pose_standing
    xi = rng.normal(scale=0.3, size=(K, 6))
    poses = [T0 @ jtraj.lie.exp(jtraj.lie.SE3, jnp.asarray(x)) for x in xi]
    Qb = np.stack([np.asarray(param.from_pose(T)) for T in poses])
    Qj = robot.q_joints_standing + rng.uniform(-0.5, 0.5, size=(K, robot.nj))
    Q = jnp.asarray(np.concatenate([Qb, Qj], axis=1))
    V = jnp.asarray(rng.normal(size=(K, nv)))
    A = jnp.asarray(rng.normal(size=(K, nv)))
    F = jnp.asarray(rng.normal(scale=100.0, size=(K, nc, 3)))

    print(f"robot {robot.name}: nq = {param.nq}+{robot.nj}, nv = {nv}, {nc} contact points, {K} knots, "
          f"parameterization {param.name}, jax {jax.__version__} on {jax.devices()[0].platform}, "
          f"median of {args.repeats}")

    # --- jtraj
    tau_batch = batched(dynamics.inverse_dynamics)
    c_tau, t_tau = timed(lambda: tau_batch(robot, param, Q, V, A, F), args.repeats)
    c_jac, t_jac = timed(lambda: dynamics.batched_inverse_dynamics_derivatives(robot, param, Q, V, A, F), args.repeats)
    ours = dynamics.batched_inverse_dynamics_derivatives(robot, param, Q, V, A, F)

    # --- Pinocchio, same states
    model, frames, q_index, v_index = pinocchio_model(robot)
    data = model.createData()
    perm = np.concatenate([np.arange(6), v_index])
    qs, vs, as_, fexts = [], [], [], []
    for k in range(K):
        qp, vp, ap = pinocchio_state(model, q_index, perm, param, Q[k], V[k], A[k])
        qs.append(qp), vs.append(vp), as_.append(ap), fexts.append(joint_forces(model, data, frames, qp, np.asarray(F[k])))

    def pin_tau():
        return [pin.rnea(model, data, qs[k], vs[k], as_[k], fexts[k]).copy() for k in range(K)]

    def pin_jac():
        return pinocchio_jacobians(model, data, frames, qs, vs, as_, fexts)

    _, p_tau = timed(pin_tau, args.repeats)
    _, p_jac = timed(pin_jac, args.repeats)

    # Cross-check on the last knot: tau, dv, da, df agree with Pinocchio, each difference
    # relative to the largest entry of Pinocchio's (df = -J_c^T)
    taus = pin_tau()
    _, _, dv_p, da_p, Jc_p = pin_jac()[-1]
    da_p = np.triu(da_p) + np.triu(da_p, 1).T
    err = max(
        np.abs(np.asarray(ours.tau[-1]) - taus[-1][perm]).max() / np.abs(taus[-1]).max(),
        np.abs(np.asarray(ours.dv[-1]) - dv_p[np.ix_(perm, perm)]).max() / np.abs(dv_p).max(),
        np.abs(np.asarray(ours.da[-1]) - da_p[np.ix_(perm, perm)]).max() / np.abs(da_p).max(),
        np.abs(np.asarray(ours.df[-1]) + np.concatenate(Jc_p)[:, perm].T).max() / np.abs(np.concatenate(Jc_p)).max(),
    )
    print(f"agreement with Pinocchio (tau, dtau/dv, M, J_c), max relative error: {err:.1e}")
    refuse_disagreement(err)
    # dtau/dq: Pinocchio's analytical one holds its external forces fixed in the joint frames,
    # jtraj's holds them fixed in the world at the moving contact points; so central
    # differences of Pinocchio's tau with jtraj's forces, along Pinocchio's tangent
    dq_fd = tau_dq_differences(model, data, frames, qs[-1], vs[-1], as_[-1], np.asarray(F[-1]), perm)
    dq_ours = np.asarray(ours.dq[-1]) @ chart_tangent(param, Q[-1, : param.nq], robot.nj)
    err_dq = np.abs(dq_ours - dq_fd).max() / np.abs(dq_fd).max()
    print(f"dtau/dq against central differences of Pinocchio's tau (step {FD_STEP:g}), max relative error: {err_dq:.1e}")
    refuse_disagreement(err_dq, DQ_TOL, "dtau/dq")

    print()
    print(f"{'':44s}{'jtraj':>12s}{'Pinocchio':>12s}{'jtraj / Pinocchio':>19s}")
    rows = [
        row("tau at all knots", t_tau, p_tau, compile_s=c_tau, repeats=args.repeats),
        row("Jacobian of tau w.r.t. (q, v, a, f)", t_jac, p_jac, compile_s=c_jac, repeats=args.repeats),
    ]
    print(f"jtraj compile: tau {c_tau:.2f} s, Jacobians {c_jac:.2f} s")

    # --- autodiff baselines
    print()
    fewer = max(3, args.repeats // 3)
    own_fwd = batched(jax.jacfwd(dynamics.inverse_dynamics, argnums=(2, 3, 4, 5)))
    c_own, t_own = timed(lambda: own_fwd(robot, param, Q, V, A, F), fewer)
    rows.append(row("jax.jacfwd through jtraj RNEA", t_own, note=f"  (compile {c_own:.2f} s)", compile_s=c_own, repeats=fewer))
    if not args.skip_mjx:
        mjx_tau = batched(dynamics.inverse_dynamics_mjx)
        c_mt, t_mt = timed(lambda: mjx_tau(robot, param, Q, V, A, F), fewer)
        mjx_fwd = batched(jax.jacfwd(dynamics.inverse_dynamics_mjx, argnums=(2, 3, 4, 5)))
        c_mj, t_mj = timed(lambda: mjx_fwd(robot, param, Q, V, A, F), 3)
        rows.append(row("tau through MJX (vmap)", t_mt, note=f"  (compile {c_mt:.2f} s)", compile_s=c_mt, repeats=fewer))
        rows.append(row("jax.jacfwd through MJX (vmap)", t_mj, note=f"  (compile {c_mj:.2f} s)", compile_s=c_mj, repeats=3))
    if args.out:
        from jtraj.provenance import write_results

        note = (f"{robot.name}, {K} knots, parameterization {param.name}, jax {jax.__version__} on {jax.devices()[0].platform}, "
                f"pinocchio {pin.__version__}; agreement with Pinocchio (tau, dtau/dv, M, J_c), max relative error {err:.1e}; "
                f"dtau/dq against central differences of Pinocchio's tau, {err_dq:.1e}.")
        rec = dict(robot=robot.name, knots=K, parameterization=param.name, agreement=err, agreement_dq=err_dq, rows=rows)
        write_results(args.out, "dynamics", rec, table(rows, note), "bench/dynamics.py", argv)
        print(f"wrote {args.out}/dynamics.json, dynamics.md, provenance.json")


#: the largest relative difference from Pinocchio's tau and Jacobians at which the timings are
#: reported (measured: 4.4e-16 on the Go2, 66 knots): above it the two sides do not compute the
#: same thing, and their times are not a comparison
AGREEMENT_TOL = 1e-8

#: the same for dtau/dq against `tau_dq_differences`, whose central differences carry rounding
#: of about 1e-16 |tau| / FD_STEP
DQ_TOL = 1e-6


def refuse_disagreement(err: float, tol: float = AGREEMENT_TOL, what: str = "tau and Jacobians") -> None:
    """Stop (SystemExit, one line) where jtraj's dynamics and Pinocchio's disagree by more than
    ``tol`` (or the error is NaN): the check was printed and the timings reported anyway."""
    if not err <= tol:
        raise SystemExit(f"bench/dynamics.py: jtraj's and Pinocchio's {what} differ by {err:.1e} (relative), more than {tol:g}; no timings reported")


if __name__ == "__main__":
    main()
