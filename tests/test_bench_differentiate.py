"""bench/differentiate.py: its table, one pair of columns per solver, and its gradient check (its refusals: tests/test_bench_args.py)."""

from types import SimpleNamespace

import numpy as np
import pytest
from conftest import bench_module


def test_table_gives_each_figure_and_the_backward_pass_per_solver():
    ipopt = dict(cold_ms=815.0, cold_iterations=15, warm_ms=624.0, warm_iterations=12, system_ms=61.0, grad_ms=942.0, grad_iterations=12, batch=4, batch_ms=3000.0, sequential_ms=3100.0)
    jt = dict(cold_ms=300.0, cold_iterations=16, warm_ms=120.0, warm_iterations=3, system_ms=60.0, grad_ms=290.5, grad_iterations=3, batch=4, batch_ms=700.0, sequential_ms=1200.0)
    rec = dict(task="go2 hop", knots=9, n=594, m=638, repeat=3, knots_scale=1, solvers={"ipopt": ipopt, "jtraj": jt})
    lines = bench_module("differentiate").table(rec).splitlines()
    assert lines[0] == "|  | Ipopt ms | iterations | jtraj's solver ms | iterations |"
    assert lines[2] == "| solve, cold (from the task's warm start) | 815.0 | 15 | 300.0 | 16 |"
    assert lines[3] == "| solve, warm (re-solve from the solution) | 624.0 | 12 | 120.0 | 3 |"
    assert lines[5] == "| backward pass (grad minus its warm solve) | 318.0 |  | 170.5 |  |"  # grad less the warm solve
    assert lines[6] == "| grad of a loss through the solver, total | 942.0 | 12 | 290.5 | 3 |"
    assert lines[7] == "| grad at 4 frictions, jax.vmap | 3000.0 |  | 700.0 |  |"
    assert lines[8] == "| grad at 4 frictions, one after another | 3100.0 |  | 1200.0 |  |"
    # a record without the batch (an earlier run) has no batch rows
    for r in (ipopt, jt):
        del r["batch_ms"]
    assert "frictions" not in bench_module("differentiate").table(rec)
    assert lines[-1] == "Go2 hop, 9 knots: n = 594 variables, m = 638 constraints; the fastest of 3 runs, compile excluded."


def test_gradients_that_differ_stop_the_benchmark():
    bench = bench_module("differentiate")
    a = {"x": np.array([1.0, -2.0]), "y": np.array(0.5)}
    assert bench.gradients_agree(a, {"x": np.array([1.0, -2.0 + 1e-7]), "y": np.array(0.5)}) == pytest.approx(5e-8)
    with pytest.raises(SystemExit, match=r"gradients differ by 5\.0e-02"):
        bench.gradients_agree(a, {"x": np.array([1.0, -2.0]), "y": np.array(0.6)})


def test_main_stops_when_the_solvers_gradients_differ(monkeypatch, tmp_path):
    """The test above calls the check alone: main() itself, given two solvers whose gradients
    differ, must stop before it writes its results."""
    bench = bench_module("differentiate")
    record = {"knots": 9, "n": 594, "m": 638}
    grads = {"ipopt": {"friction": np.array(1.0)}, "jtraj": {"friction": np.array(1.1)}}
    monkeypatch.setattr(bench, "measure", lambda task, name, repeat, batch: (dict(record), grads[name]))
    monkeypatch.setattr(bench, "hop", lambda scale: None)
    out = tmp_path / "o"
    with pytest.raises(SystemExit, match=r"gradients differ by"):
        bench.main(["--solvers", "ipopt,jtraj", "--out", str(out)])
    assert not out.exists()


class _Theta:
    def __init__(self, friction=1.0):
        self.friction = friction

    def replace(self, friction):
        return _Theta(friction)


class _Differentiable:
    """A stand-in for `jtraj.differentiable` of the hop: the loss's gradient is the friction."""

    def __init__(self, task, solver):
        self.theta = _Theta()
        self.last_solution = SimpleNamespace(stats=SimpleNamespace(iterations=7), x=np.zeros(3), mult_g=np.zeros(2))
        self.nlp = SimpleNamespace(n=3, m=2)
        self.transcription = SimpleNamespace(N=4)

    def __call__(self, theta):
        return SimpleNamespace(cost=float(np.sum(theta.friction)), tau=np.zeros((5, 8)))

    def warm_start_from(self, x):
        pass


@pytest.mark.parametrize("vmapped_off_by", [0.0, 0.5])
def test_a_batch_whose_vmapped_gradients_differ_says_so(monkeypatch, vmapped_off_by):
    """Where the vmapped and the one-by-one gradients of a batch disagreed, the benchmark said
    "the solvers' gradients differ" (one solver's, against itself). Fakes for JAX's transforms
    and the solver: no compile, no solve."""
    import jax

    bench = bench_module("differentiate")

    def vmap(fn):  # the batch's gradients, off by ``vmapped_off_by`` against the members one by one
        return lambda xs: np.array([fn(x) for x in xs]) + vmapped_off_by

    fake_jax = SimpleNamespace(jit=lambda fn: fn, grad=lambda fn: fn, vmap=vmap, block_until_ready=lambda x: x, tree=jax.tree)
    monkeypatch.setattr(bench, "jax", fake_jax)
    monkeypatch.setattr(bench, "jnp", np)
    monkeypatch.setattr(bench, "differentiable", _Differentiable)
    monkeypatch.setattr(bench, "kkt_system", lambda *a: SimpleNamespace(solve=lambda *a, **k: None, matrix=SimpleNamespace(nnz=1)))
    if vmapped_off_by:
        with pytest.raises(SystemExit) as exc:
            bench.measure(bench.hop(1), "jtraj", repeat=1, batch=2)
        assert str(exc.value.code).startswith("bench/differentiate.py: the vmapped and the one-by-one gradients differ by ")
    else:
        rec, gradient = bench.measure(bench.hop(1), "jtraj", repeat=1, batch=2)
        assert rec["batch"] == 2 and rec["knots"] == 5 and gradient == 1.0
