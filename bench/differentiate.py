"""Cost of one backward pass through the solver against one solve (`jtraj.differentiable`),
with each forward solver side by side in one run.

    python bench/differentiate.py [--solvers ipopt,jtraj] [--knots-scale 1] [--repeat 3] [--batch 4] [--out DIR]

On a Go2 hop (the task of tests/test_differentiable.py), for each solver of ``--solvers`` (its
forward-solve defaults, `jtraj.differentiate.forward_options`: tol 1e-10 and the exact
Hessian), after compiling everything once:
- solve, cold: from the task's warm start;
- solve, warm: re-solving from the solution (what an optax loop or a finite difference does),
  through ``jax.jit(f)``;
- sensitivity system: active set, assembly of K and its sparse LU (host, once per solve; the
  assembly runs in the forward pass, so the warm solve above includes it, the LU in the first
  backward pass);
- backward: ``jax.jit(jax.grad(loss))`` minus the warm solve it contains (the sparse LU of K,
  the transposed triangular solve and the JAX vector-Jacobian products of the residual and the
  motion). The table gives the iterations of both warm solves: the difference stands for the
  backward pass only where they agree;
- a batch: the gradient at ``--batch`` frictions (0.8 to 1.2 times the task's), through
  ``jax.vmap`` against one after another, every member from the solution at the task's theta.
  Under ``jax.vmap`` on a CPU the forward solves of jtraj's solver run side by side in threads
  (`jtraj.differentiate`), Ipopt's one after another.

Each figure is the fastest of ``--repeat`` runs; the solvers' gradients of the loss are printed
and must agree, as must a batch's vmapped and one-by-one gradients. ``--out DIR`` writes them
with the run's provenance (command, date, machine, versions): ``DIR/differentiate.json``,
``DIR/differentiate.md`` and ``DIR/provenance.json``.
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


SOLVER_NAMES = {"ipopt": "Ipopt", "jtraj": "jtraj's solver"}


def table(rec: dict) -> str:
    """Markdown: one row per figure of the record `main` measures, in milliseconds, and one
    pair of columns (ms, iterations) per solver."""
    from jtraj.tables import markdown_table

    names = list(rec["solvers"])
    header = [""]
    for name in names:
        header += [f"{SOLVER_NAMES.get(name, name)} ms", "iterations"]
    figures = [
        ("solve, cold (from the task's warm start)", lambda r: f"{r['cold_ms']:.1f}", "cold_iterations"),
        ("solve, warm (re-solve from the solution)", lambda r: f"{r['warm_ms']:.1f}", "warm_iterations"),
        ("sensitivity system (active set, K, sparse LU)", lambda r: f"{r['system_ms']:.1f}", None),
        ("backward pass (grad minus its warm solve)", lambda r: f"{r['grad_ms'] - r['warm_ms']:.1f}", None),
        ("grad of a loss through the solver, total", lambda r: f"{r['grad_ms']:.1f}", "grad_iterations"),
    ]
    if all("batch_ms" in rec["solvers"][name] for name in names):
        batch = rec["solvers"][names[0]]["batch"]
        figures += [
            (f"grad at {batch} frictions, jax.vmap", lambda r: f"{r['batch_ms']:.1f}", None),
            (f"grad at {batch} frictions, one after another", lambda r: f"{r['sequential_ms']:.1f}", None),
        ]
    rows = []
    for label, ms, its in figures:
        row: list[object] = [label]
        for name in names:
            r = rec["solvers"][name]
            row += [ms(r), r[its] if its else ""]
        rows.append(tuple(row))
    note = f"Go2 hop, {rec['knots']} knots: n = {rec['n']} variables, m = {rec['m']} constraints; the fastest of {rec['repeat']} runs, compile excluded."
    return markdown_table(tuple(header), rows, note)


def measure(task: Task, solver: str, repeat: int, batch: int = 4) -> tuple[dict, object]:
    """One solver's figures (ms, iterations) and its gradient of the loss at the task's theta."""
    f = differentiable(task, solver=solver)
    theta = f.theta
    name = SOLVER_NAMES.get(solver, solver)

    def loss(th):
        m = f(th)
        return m.cost + jnp.max(jnp.abs(m.tau[:, 6:]))

    solve = jax.jit(lambda th: f(th).cost)
    grad = jax.jit(jax.grad(loss))
    gradient = jax.block_until_ready(grad(theta))  # compile both, solve once
    jax.block_until_ready(solve(theta))

    def cold():
        f.warm_start_from(None)
        return solve(theta)

    t_cold = best_of(cold, repeat)
    cold_iterations = f.last_solution.stats.iterations
    print(f"{name}: solve, cold (from the task's warm start): {t_cold * 1e3:8.1f} ms ({cold_iterations} iterations)", flush=True)
    jax.block_until_ready(solve(theta))
    t_warm = best_of(lambda: solve(theta), repeat)
    warm_iterations = f.last_solution.stats.iterations
    print(f"{name}: solve, warm (re-solve from the solution): {t_warm * 1e3:8.1f} ms ({warm_iterations} iterations)", flush=True)
    x, lam = f.last_solution.x, f.last_solution.mult_g

    def system():
        s = kkt_system(f.nlp, x, lam, theta)
        # a backward pass's right-hand side: a cotangent of x, none of the multipliers
        s.solve(np.concatenate([np.ones(f.nlp.n), np.zeros(f.nlp.m)]), transpose=True)
        return s.matrix.nnz

    t_system = best_of(system, repeat)
    print(f"{name}: sensitivity system (active set, K, sparse LU): {t_system * 1e3:8.1f} ms (K in the forward pass, LU in the backward)", flush=True)
    t_grad = best_of(lambda: grad(theta), repeat)
    # the warm solve inside grad: the backward pass below is the difference only where both
    # warm solves took the same iterations
    grad_iterations = f.last_solution.stats.iterations
    print(f"{name}: backward pass (grad minus its warm solve): {(t_grad - t_warm) * 1e3:8.1f} ms")
    print(f"{name}: grad of a loss through the solver, total: {t_grad * 1e3:8.1f} ms ({grad_iterations} iterations in its warm solve)", flush=True)
    # a batch of frictions: jax.vmap of the gradient against the members one after another,
    # every member from the solution at the task's theta
    frictions = jnp.asarray(theta.friction) * jnp.linspace(0.8, 1.2, batch)

    def at(friction):
        return loss(theta.replace(friction=friction))

    batched = jax.jit(jax.vmap(jax.grad(at)))
    single = jax.jit(jax.grad(at))
    x_star = np.asarray(f.last_solution.x)

    def run_batched():
        f.warm_start_from(x_star)
        return batched(frictions)

    def run_sequential():
        out = []
        for fr in frictions:
            f.warm_start_from(x_star)
            out.append(single(fr))
        return out

    g_batch = jax.block_until_ready(run_batched())  # compile both
    g_single = jax.block_until_ready(run_sequential())
    t_batch = best_of(run_batched, repeat)
    t_seq = best_of(run_sequential, repeat)
    gradients_agree(np.asarray(g_batch), np.asarray(g_single), "the vmapped and the one-by-one gradients")
    print(f"{name}: grad at {batch} frictions, vmapped {t_batch * 1e3:8.1f} ms, one after another {t_seq * 1e3:8.1f} ms, speedup {t_seq / t_batch:.2f}", flush=True)
    rec = dict(
        cold_ms=t_cold * 1e3, cold_iterations=cold_iterations, warm_ms=t_warm * 1e3, warm_iterations=warm_iterations,
        system_ms=t_system * 1e3, grad_ms=t_grad * 1e3, grad_iterations=grad_iterations,
        batch=batch, batch_ms=t_batch * 1e3, sequential_ms=t_seq * 1e3,
        n=f.nlp.n, m=f.nlp.m, knots=f.transcription.N + 1,
    )
    return rec, gradient


def gradients_agree(a, b, what: str = "the solvers' gradients", rtol: float = 1e-5) -> float:
    """Largest difference of two gradients (pytrees), relative to the largest entry of ``b``;
    raises SystemExit naming ``what`` differs when it exceeds ``rtol`` (a backward pass of a
    wrong solution is no measurement)."""
    la = np.concatenate([np.ravel(np.asarray(v, float)) for v in jax.tree.leaves(a)])
    lb = np.concatenate([np.ravel(np.asarray(v, float)) for v in jax.tree.leaves(b)])
    diff = float(np.max(np.abs(la - lb)) / max(np.max(np.abs(lb)), 1e-300))
    if not diff <= rtol:
        raise SystemExit(f"bench/differentiate.py: {what} differ by {diff:.1e} of the largest entry (more than {rtol:g})")
    return diff


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--solvers", default="ipopt,jtraj", help="comma-separated forward solvers, measured one after the other (default ipopt,jtraj)")
    ap.add_argument("--knots-scale", type=int, default=1, help="divide the timestep by this (more knots)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--batch", type=int, default=4, help="frictions of the batched gradient (jax.vmap against one after another)")
    add_out(ap, "differentiate")
    args = ap.parse_args(argv)
    if args.knots_scale < 1:
        ap.error(f"--knots-scale: {args.knots_scale}: expected an integer >= 1 (the timestep is divided by it)")
    if args.repeat < 1:
        ap.error(f"--repeat: {args.repeat}: expected an integer >= 1")
    if args.batch < 2:
        ap.error(f"--batch: {args.batch}: expected an integer >= 2")
    from jtraj import solvers

    names = [s.strip() for s in args.solvers.split(",") if s.strip()]
    unknown = [s for s in names if s not in solvers.SOLVERS]
    if not names or unknown or len(set(names)) != len(names):
        ap.error(f"--solvers: {args.solvers!r}: expected distinct names of {', '.join(solvers.SOLVERS)}")
    task = hop(args.knots_scale)
    records, gradients = {}, {}
    for name in names:
        records[name], gradients[name] = measure(task, name, args.repeat, args.batch)
    first = records[names[0]]
    print(f"Go2 hop, {first['knots']} knots: n = {first['n']} variables, m = {first['m']} constraints")
    for name in names[1:]:
        diff = gradients_agree(gradients[name], gradients[names[0]])
        print(f"gradients of the loss, {name} against {names[0]}: largest difference {diff:.1e} of the largest entry")
    rec = dict(
        task="go2 hop", knots=first["knots"], n=first["n"], m=first["m"], repeat=args.repeat, knots_scale=args.knots_scale,
        solvers={name: {k: v for k, v in r.items() if k not in ("n", "m", "knots")} for name, r in records.items()},
    )
    print(table(rec))
    if args.out:
        from jtraj.provenance import write_results

        write_results(args.out, "differentiate", rec, table(rec), "bench/differentiate.py", argv)
        print(f"wrote {args.out}/differentiate.json, differentiate.md, provenance.json")


if __name__ == "__main__":
    main()
