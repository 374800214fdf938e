"""Cost of one backward pass through the solver against one solve (`jtraj.differentiable`).

    python bench/differentiate.py [--knots-scale 1] [--repeat 3] [--out DIR]

On a Go2 hop (the task of tests/test_differentiable.py), after compiling everything once:
- solve, cold: Ipopt from the task's warm start;
- solve, warm: Ipopt re-solving from the solution (what an optax loop or a finite
  difference does), through ``jax.jit(f)``;
- sensitivity system: active set, assembly of K and its sparse LU (host, once per solve; the
  assembly runs in the forward pass, so the warm solve above includes it, the LU in the first
  backward pass);
- backward: ``jax.jit(jax.grad(loss))`` minus the warm solve it contains (the sparse LU of K,
  the transposed triangular solve and the JAX vector-Jacobian products of the residual and the
  motion).

Each figure is the fastest of ``--repeat`` runs. ``--out DIR`` writes them with the run's
provenance (command, date, machine, versions): ``DIR/differentiate.json``,
``DIR/differentiate.md`` and ``DIR/provenance.json`` (the figures depend on the machine and its
load: none are kept here).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import jtraj  # noqa: F401  (float64)
from jtraj.differentiate import differentiable
from jtraj.sensitivity import kkt_system
from jtraj.task import Phase, Task

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/_args.py, also when the tests load this file from its path
from _args import add_out  # noqa: E402

FEET = ("FL_foot", "FR_foot", "RL_foot", "RR_foot")


def hop(scale: int) -> Task:
    return Task(
        name="hop", robot="go2", timestep=0.05 / scale,
        phases=(Phase(FEET, 0.15), Phase((), 0.1), Phase(FEET, 0.15)),
        target_translation=(0.1, 0.0, 0.0), configuration_weight=1.0, acceleration_weight=1e-3,
    )


def best_of(fn, repeat):
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t)
    return min(times)


def table(rec: dict) -> str:
    """Markdown: one row per figure of the record `main` measures, in milliseconds."""
    from jtraj.tables import markdown_table

    rows = [
        ("solve, cold (Ipopt from the task's warm start)", f"{rec['cold_ms']:.1f}", rec["cold_iterations"]),
        ("solve, warm (re-solve from the solution)", f"{rec['warm_ms']:.1f}", rec["warm_iterations"]),
        ("sensitivity system (active set, K, sparse LU)", f"{rec['system_ms']:.1f}", ""),
        ("backward pass (grad minus its warm solve)", f"{rec['grad_ms'] - rec['warm_ms']:.1f}", ""),
        ("grad of a loss through the solver, total", f"{rec['grad_ms']:.1f}", ""),
    ]
    note = f"Go2 hop, {rec['knots']} knots: n = {rec['n']} variables, m = {rec['m']} constraints; the fastest of {rec['repeat']} runs, compile excluded."
    return markdown_table(("", "ms", "Ipopt iterations"), rows, note)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--knots-scale", type=int, default=1, help="divide the timestep by this (more knots)")
    ap.add_argument("--repeat", type=int, default=3)
    add_out(ap, "differentiate")
    args = ap.parse_args(argv)
    if args.knots_scale < 1:
        ap.error(f"--knots-scale: {args.knots_scale}: expected an integer >= 1 (the timestep is divided by it)")
    if args.repeat < 1:
        ap.error(f"--repeat: {args.repeat}: expected an integer >= 1")
    f = differentiable(hop(args.knots_scale))
    theta = f.theta

    def loss(th):
        m = f(th)
        return m.cost + jnp.max(jnp.abs(m.tau[:, 6:]))

    solve = jax.jit(lambda th: f(th).cost)
    grad = jax.jit(jax.grad(loss))
    jax.block_until_ready(grad(theta))  # compile both, solve once
    jax.block_until_ready(solve(theta))

    def cold():
        f.warm_start_from(None)
        return solve(theta)

    print(f"Go2 hop, {f.transcription.N + 1} knots: n = {f.nlp.n} variables, m = {f.nlp.m} constraints", flush=True)
    t_cold = best_of(cold, args.repeat)
    cold_iterations = f.last_solution.stats.iterations
    print(f"solve, cold (Ipopt from the task's warm start): {t_cold * 1e3:8.1f} ms ({cold_iterations} iterations)", flush=True)
    jax.block_until_ready(solve(theta))
    t_warm = best_of(lambda: solve(theta), args.repeat)
    warm_iterations = f.last_solution.stats.iterations
    print(f"solve, warm (re-solve from the solution):       {t_warm * 1e3:8.1f} ms ({warm_iterations} iterations)", flush=True)
    x, lam = f.last_solution.x, f.last_solution.mult_g

    def system():
        s = kkt_system(f.nlp, x, lam, theta)
        # a backward pass's right-hand side: a cotangent of x, none of the multipliers
        s.solve(np.concatenate([np.ones(f.nlp.n), np.zeros(f.nlp.m)]), transpose=True)
        return s.matrix.nnz

    t_system = best_of(system, args.repeat)
    print(f"sensitivity system (active set, K, sparse LU):  {t_system * 1e3:8.1f} ms (K in the forward pass, LU in the backward)", flush=True)
    t_grad = best_of(lambda: grad(theta), args.repeat)
    print(f"backward pass (grad minus its warm solve):      {(t_grad - t_warm) * 1e3:8.1f} ms")
    print(f"grad of a loss through the solver, total:       {t_grad * 1e3:8.1f} ms")
    if args.out:
        from jtraj.provenance import write_results

        rec = dict(
            task="go2 hop", knots=f.transcription.N + 1, n=f.nlp.n, m=f.nlp.m, repeat=args.repeat, knots_scale=args.knots_scale,
            cold_ms=t_cold * 1e3, cold_iterations=cold_iterations, warm_ms=t_warm * 1e3, warm_iterations=warm_iterations,
            system_ms=t_system * 1e3, grad_ms=t_grad * 1e3,
        )
        write_results(args.out, "differentiate", rec, table(rec), "bench/differentiate.py", argv)
        print(f"wrote {args.out}/differentiate.json, differentiate.md, provenance.json")


if __name__ == "__main__":
    main()
