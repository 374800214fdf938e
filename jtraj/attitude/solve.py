"""Solving the attitude benchmarks: any backend of `jtraj.solvers`, one `jtraj.result.Result`
per solve, and the comparison table of every benchmark in both formulations.

Ipopt settings (`IPOPT_OPTIONS`): exact Hessian of the Lagrangian from JAX (the paper's
ALTRO is a second-order method too), ``constr_viol_tol = 1e-5`` (the paper's constraint
tolerance) also as the *acceptable* violation, so that a returned "converged" solution always
satisfies the constraints to 1e-5; ``tol = 1e-6`` on Ipopt's scaled KKT error, and
``acceptable_tol = 1e-4``: a solve that ends at Ipopt's acceptable level counts as converged
(`jtraj.result.Result.converged`), its KKT error then at most 1e-4; Ipopt's default
gradient-based NLP scaling; MUMPS; 1000 iterations and 1800 s of wall time at most.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp

from jtraj import config, solvers
from jtraj.attitude import benchmarks, formulations
from jtraj.attitude.benchmarks import PAPER_ITERATIONS, Benchmark
from jtraj.attitude.formulations import AbstractFormulation
from jtraj.attitude.transcription import build_nlp, decode, warm_start
from jtraj.result import Result
from jtraj.solvers import AbstractOptions, AbstractSolver, IpoptOptions, IpoptSolver
from jtraj.tables import markdown_table, write_table

__all__ = ["IPOPT_OPTIONS", "CONSTRAINT_TOLERANCE", "solve_benchmark", "compare_benchmarks", "result_directory"]

#: Ipopt options of every benchmark solve (see the module docstring).
IPOPT_OPTIONS = IpoptOptions(
    tol=1e-6,
    constr_viol_tol=1e-5,
    acceptable_constr_viol_tol=1e-5,
    acceptable_tol=1e-4,
    max_iter=1000,
    hessian="exact",
    nlp_scaling_method="gradient-based",
    linear_solver="mumps",
    max_wall_time=1800.0,
)

#: The paper's constraint tolerance: a converged solve must satisfy the constraints to it.
CONSTRAINT_TOLERANCE = 1e-5


def _options(backend: AbstractSolver, options: AbstractOptions | dict[str, Any] | None) -> AbstractOptions:
    """The benchmarks' settings of ``backend`` (`IPOPT_OPTIONS` for Ipopt) with ``options``
    over them (an options object replaces them)."""
    if isinstance(options, AbstractOptions):
        return backend.options(options)
    if isinstance(backend, IpoptSolver):
        return IPOPT_OPTIONS.merge(options)
    return backend.options(options)


def result_directory(out: str | Path, result: Result) -> Path:
    """Where a benchmark result is saved under ``out``: ``out/{benchmark}_{variant}``."""
    return Path(out) / f"{result.problem}_{result.variant}"


def solve_benchmark(
    name: str | Benchmark,
    variant: str | AbstractFormulation = "attitude",
    out: str | Path | None = None,
    n_knots: int | None = None,
    progress: solvers.Progress = True,
    options: AbstractOptions | dict[str, Any] | None = None,
    solver: str | AbstractSolver = "ipopt",
    **benchmark_kwargs: Any,
) -> Result:
    """Solve a benchmark (a name of `jtraj.attitude.benchmarks.BENCHMARKS` or a `Benchmark`)
    in one formulation.

    ``n_knots`` (and any ``benchmark_kwargs``, e.g. ``tf``) go to the benchmark's factory
    (with a built `Benchmark` they raise ValueError);
    ``options`` (a dict of option names or the solver's options object) go over
    `IPOPT_OPTIONS` for Ipopt. JAX functions are compiled before the solver starts, so
    ``time_s`` is the solve alone. With ``out``, saves into `result_directory`.
    ``progress``: True prints every 10th iteration to the current sys.stdout, False is quiet,
    a stream or a `jtraj.solvers.AbstractCallback` receives them.
    """
    config.enable_compilation_cache()
    fm = formulations.get(variant)
    bench = benchmarks.get(name, n_knots, **benchmark_kwargs)
    backend = solvers.get(solver)
    opts = _options(backend, options)
    t0 = time.perf_counter()
    nlp = build_nlp(bench, fm)
    z0 = warm_start(bench, nlp)
    x0 = jnp.asarray(z0)
    nlp.build_hessian()
    for fn in (nlp.objective, nlp.gradient, nlp.constraints, nlp.jacobian):
        jax.block_until_ready(fn(x0, nlp.theta))
    jax.block_until_ready(nlp.hessian(x0, jnp.ones(nlp.m), 1.0, nlp.theta))
    time_compile = time.perf_counter() - t0
    solution = backend.solve(nlp, z0, None, opts, solvers.resolve_progress(progress, 10))
    trajectory = decode(bench, solution.x)
    metrics, task_ok = bench.metrics(trajectory.X, trajectory.U)
    result = Result.from_solution(
        solution,
        feasibility_tol=CONSTRAINT_TOLERANCE,
        task_ok=task_ok,
        violation_by_group=nlp.violation_by_group(solution.x),
        problem=bench.name,
        variant=fm.name,
        model=type(bench.model).__name__,
        solver=backend.name,
        time_compile=time_compile,
        metrics={"n_knots": bench.n_knots, "tf": bench.tf, **metrics},
        n_variables=nlp.n,
        nnz_jacobian=nlp.nnz_jac,
        options={"solver": backend.name, **opts.as_dict()},
        trajectory=trajectory,
    )
    if out is not None:
        result.save(result_directory(out, result))
    return result


def compare_benchmarks(
    out_dir: str | Path,
    names: tuple[str, ...] = ("barrelroll", "quadflip", "satellite"),
    variants: tuple[str, ...] = ("naive", "attitude"),
    n_knots: int | None = None,
    progress: solvers.Progress = False,
    solver: str = "ipopt",
) -> list[dict[str, Any]]:
    """Solve every benchmark in every variant; write ``out_dir``/table.json and table.md
    (iterations, time, violation, status next to the paper's iterations) and each result's
    folder; prints each summary and the table (``jtraj attitude all``)."""
    rows = []
    for name in names:
        for variant in variants:
            r = solve_benchmark(name, variant, out=out_dir, n_knots=n_knots, progress=progress, solver=solver)
            rows.append(
                {
                    "benchmark": name,
                    "variant": variant,
                    "status": r.status.value,
                    "iterations": r.iterations,
                    "time_s": r.time_s,
                    "time_compile_s": r.time_compile,
                    "constraint_violation": r.constraint_violation,
                    "objective": r.cost,
                    "paper_iterations": PAPER_ITERATIONS[name][{"naive": 0, "attitude": 1}[variant]],
                    **{k: v for k, v in r.metrics.items() if isinstance(v, (int, float))},
                }
            )
            print(r.summary(), flush=True)
    header = ("benchmark", "variant", "status", "iterations", "paper (ALTRO)", "time (s)", "violation")
    table = markdown_table(
        header,
        ((r["benchmark"], r["variant"], r["status"], r["iterations"], r["paper_iterations"], f"{r['time_s']:.2f}", f"{r['constraint_violation']:.1e}") for r in rows),
    )
    write_table(out_dir, "table", rows, table)
    print(table, end="")
    return rows
