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
