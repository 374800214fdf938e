"""bench/dynamics.py: Pinocchio's side of the Jacobian benchmark does the work once."""

import numpy as np
import pinocchio as pin
from conftest import bench_module

from jtraj import robot as robot_lib


def _states(model, K: int):
    rng = np.random.default_rng(0)
    qs, vs, as_, fexts = [], [], [], []
    for _ in range(K):
        q = pin.neutral(model)
        q[:3] = rng.normal(size=3)
        quat = rng.normal(size=4)
        q[3:7] = quat / np.linalg.norm(quat)
        q[7:] += rng.uniform(-0.3, 0.3, model.nq - 7)
        qs.append(q)
        vs.append(rng.normal(size=model.nv))
        as_.append(rng.normal(size=model.nv))
        fexts.append([pin.Force(rng.normal(size=6)) for _ in range(model.njoints)])
    return qs, vs, as_, fexts


def test_pinocchio_jacobians_run_no_separate_rnea(monkeypatch):
    """The timed Pinocchio Jacobians called rnea before computeRNEADerivatives, which computes
    tau and the Jacobians getFrameJacobian reads itself: one inverse dynamics pass per knot too
    many on Pinocchio's side of the ratio. Same figures without it, tau included."""
    bench = bench_module("dynamics")
    model, frames, _, _ = robot_lib.to_pinocchio(robot_lib.load("go2"))
    qs, vs, as_, fexts = _states(model, 2)
    ref, data = [], model.createData()
    for q, v, a, fext in zip(qs, vs, as_, fexts):
        tau = pin.rnea(model, data, q, v, a, fext).copy()
        d = [np.array(m) for m in pin.computeRNEADerivatives(model, data, q, v, a, fext)]
        ref.append((tau, *d, [pin.getFrameJacobian(model, data, f, pin.LOCAL_WORLD_ALIGNED)[:3].copy() for f in frames]))

    def no_rnea(*args, **kwargs):
        raise AssertionError("rnea timed beside computeRNEADerivatives")

    monkeypatch.setattr(bench.pin, "rnea", no_rnea)
    held = model.createData()  # the derivatives returned are views of its memory: kept alive
    out = bench.pinocchio_jacobians(model, held, frames, qs, vs, as_, fexts)
    assert len(out) == 2
    for (tau, *_), (rtau, *_) in zip(out, ref):
        np.testing.assert_allclose(tau, rtau, rtol=0, atol=1e-12)
    # the derivatives are Pinocchio's own matrices, which the next knot overwrites: the last's
    (_, dq, dv, da, Jc), (_, rdq, rdv, rda, rJc) = out[-1], ref[-1]
    for x, y in ((dq, rdq), (dv, rdv), (da, rda), *zip(Jc, rJc)):
        np.testing.assert_allclose(np.asarray(x), y, rtol=0, atol=1e-12)


def test_table_says_each_row_median_count(capsys):
    """The printed header said 'median of --repeats' for every row, the autodiff baselines are
    medians of fewer calls; ``--out``'s table gives each row's count, and no ratio without a peer."""
    bench = bench_module("dynamics")
    rows = [
        bench.row("tau at all knots", 0.002, 0.001, compile_s=0.5, repeats=30),
        bench.row("jax.jacfwd through jtraj RNEA", 0.004, compile_s=2.0, repeats=10),
    ]
    assert "tau at all knots" in capsys.readouterr().out
    lines = bench.table(rows, "note").splitlines()
    assert lines[0] == "|  | jtraj (ms) | Pinocchio (ms) | jtraj / Pinocchio | jtraj compile (s) | median of |"
    assert lines[2] == "| tau at all knots | 2.000 | 1.000 | 2.00 | 0.50 | 30 |"
    assert lines[3] == "| jax.jacfwd through jtraj RNEA | 4.000 |  |  | 2.00 | 10 |"
    assert lines[-1] == "note"


def test_a_disagreement_with_pinocchio_stops_the_benchmark():
    """The cross-check with Pinocchio was printed and never enforced: wrong derivatives would
    have been timed against Pinocchio's. Above the tolerance, or NaN, the run stops."""
    import pytest

    bench = bench_module("dynamics")
    bench.refuse_disagreement(4.4e-16)  # the Go2's, measured
    for err in (1e-6, float("nan")):
        with pytest.raises(SystemExit, match="tau and Jacobians differ by"):
            bench.refuse_disagreement(err)
    bench.refuse_disagreement(3.3e-10, bench.DQ_TOL, "dtau/dq")  # the Go2's, measured
    with pytest.raises(SystemExit, match=r"dtau/dq differ by 1\.0e-05"):
        bench.refuse_disagreement(1e-5, bench.DQ_TOL, "dtau/dq")


def test_main_stops_when_its_derivatives_disagree_with_pinocchio(monkeypatch, tmp_path, capsys):
    """The test above calls the check alone: main() itself, with tau off by 1 %, must stop
    before it times or writes anything (the check was once printed and never enforced)."""
    import pytest

    bench = bench_module("dynamics")
    real = bench.dynamics.batched_inverse_dynamics_derivatives

    def off(*args):
        r = real(*args)
        return r._replace(tau=r.tau * 1.01)

    monkeypatch.setattr(bench.dynamics, "batched_inverse_dynamics_derivatives", off)
    monkeypatch.setattr(bench, "timed", lambda fn, repeats: (0.0, 1e-3))  # nothing timed
    out = tmp_path / "o"
    with pytest.raises(SystemExit, match="tau and Jacobians differ by"):
        bench.main(["--robot", "go2", "--knots", "1", "--repeats", "1", "--skip-mjx", "--out", str(out)])
    assert "agreement with Pinocchio" in capsys.readouterr().out
    assert not out.exists() or not any(out.iterdir())


def test_dtau_dq_is_checked_against_pinocchio_with_world_forces():
    """bench/dynamics.py cross-checked tau, dtau/dv, M and J_c with Pinocchio but not dtau/dq,
    half of the timed Jacobian. Pinocchio's analytical dtau/dq holds the external forces fixed
    in the joint frames, jtraj's holds them fixed in the world at the moving contact points, so
    the benchmark checks it against central differences of Pinocchio's tau with jtraj's forces:
    they agree with jtraj's derivative in a non-trivial chart, and Pinocchio's own dtau/dq,
    which leaves out the forces' moving points, is far outside the tolerance."""
    import jax.numpy as jnp

    from jtraj import dynamics, lie
    from jtraj.parameterization import PARAMETERIZATIONS

    bench = bench_module("dynamics")
    robot, param = robot_lib.load("go2"), PARAMETERIZATIONS["euler"]
    model, frames, q_index, v_index = robot_lib.to_pinocchio(robot)
    perm = np.concatenate([np.arange(6), v_index])
    rng = np.random.default_rng(3)
    T = lie.exp(lie.SE3, jnp.asarray(rng.normal(scale=0.5, size=6)))
    q = np.concatenate([np.asarray(param.from_pose(T)), robot.q_joints_standing + rng.uniform(-0.3, 0.3, robot.nj)])
    v, a = rng.normal(size=robot.nv), rng.normal(size=robot.nv)
    f = rng.normal(scale=50.0, size=(robot.ncontact, 3))
    ours = dynamics.batched_inverse_dynamics_derivatives(robot, param, *(jnp.asarray(x)[None] for x in (q, v, a, f)))

    qp, vp, ap = bench.pinocchio_state(model, q_index, perm, param, q, v, a)
    data = model.createData()
    fd = bench.tau_dq_differences(model, data, frames, qp, vp, ap, f, perm)
    mapped = np.asarray(ours.dq[0]) @ bench.chart_tangent(param, q[: param.nq], robot.nj)
    assert np.abs(mapped - fd).max() / np.abs(fd).max() < bench.DQ_TOL
    joint_fixed = pin.computeRNEADerivatives(model, data, qp, vp, ap, bench.joint_forces(model, data, frames, qp, f))[0]
    assert np.abs(joint_fixed[np.ix_(perm, perm)] - fd).max() / np.abs(fd).max() > 1e3 * bench.DQ_TOL


def test_main_checks_dtau_dq_before_it_reports(capsys, monkeypatch):
    """main() runs the dtau/dq check on the knot it cross-checks, and a disagreement in dtau/dq
    alone stops it before any timing (the helpers above are checked on their own)."""
    import pytest

    bench = bench_module("dynamics")
    argv = ["--robot", "go2", "--knots", "2", "--repeats", "1", "--skip-mjx"]
    bench.main(argv)
    out = capsys.readouterr().out
    err = float(out.split("dtau/dq against central differences of Pinocchio's tau (step 1e-06), max relative error: ")[1].split()[0])
    assert err < bench.DQ_TOL and "tau at all knots" in out
    differences = bench.tau_dq_differences
    monkeypatch.setattr(bench, "tau_dq_differences", lambda *a, **k: differences(*a, **k) * 1.001)
    with pytest.raises(SystemExit, match=r"dtau/dq differ by 1\.0e-03"):
        bench.main(argv)
    assert "tau at all knots" not in capsys.readouterr().out
