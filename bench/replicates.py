"""Noise replicates in one vmapped solve of jtraj's interior point against the same replicates
solved one after another with Ipopt, in the same run.

    python bench/replicates.py [--task big_jump] [--param se3] [--sigma 0.1] [--replicates 10]
                               [--strategies vmap,threads] [--batches 10,100] [--jtraj-sequential]
                               [--no-ipopt] [--out F.json]

Both solvers start from the same noisy warm starts (`jtraj.experiments.noisy_warm_starts`), and
jtraj's batch goes through `JtrajSolver.solve_batch`, as `jtraj robustness --solver jtraj` does.
Compilation is excluded from every time: the programs are compiled ahead of time (the compile
time is printed on its own line), and Ipopt's NLP functions are compiled by ``prepare``.

- ``--strategies``: `solve_batch`'s ways to solve the batch, each timed: ``vmap`` (one vmapped
  program: on an accelerator the members step together, on a CPU it splits them over the CPU
  devices, one per core, each running its share one member after another,
  `IpmOptions.cpu_batch`), ``threads`` (the one-problem program, one member per CPU
  core at a time; what `solve_batch` does on a CPU) and ``vectorized`` (``vmap`` with
  ``cpu_batch="vectorized"``: the members in lockstep on a CPU too, as before 2026-11-28). The
  last line is the first strategy's; with several, one line per strategy, the first's last.

- ``--batches``: further batch sizes to time (more noisy starts from the same seed), to see how
  a vmapped solve scales; on a CPU it is about linear, on a GPU it should not be.
- ``--jtraj-sequential``: also time jtraj's solver one replicate at a time (one compiled
  program), which separates what vmap buys from what the solver buys.
- ``--no-ipopt``: skip Ipopt (a machine without cyipopt); the last line then compares with
  jtraj one at a time.

On a GPU, jtraj's programs run on the GPU and Ipopt's NLP functions on the same machine's CPU
(``jax.default_device``), where a solver that calls them one point at a time belongs.

Prints the JAX device, one line per replicate (status, iterations, violation, task success) and,
last, ``replicates: vmapped X s, sequential Y s, speedup Z (sequential: Ipopt)`` (``jtraj one
at a time`` with ``--no-ipopt``; one such line per ``--strategies`` entry, the first one's last;
``speedup none (jtraj K/N converged, Ipopt J/N)`` where a replicate failed on either side:
the times are then of different work); ``--out DIR/F.json`` writes every
figure as JSON (atomically, strict JSON), with the run's provenance (command, date, machine,
versions) under ``provenance``, and, as `jtraj.provenance.write_results` writes the other
benchmarks' results, beside it ``DIR/F.md`` (the batches' table and the last lines) and
``DIR/provenance.json``, the same record (the results/replicates_* folders hold these files).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import math
import os
import platform
import sys
from pathlib import Path

import jax
import numpy as np

from jtraj import solvers
from jtraj.cli import InputError, _check_out
from jtraj.config import cpu_count
from jtraj.experiments import noisy_warm_starts
from jtraj.numbers import is_seed
from jtraj.provenance import provenance, write_results
from jtraj.solver import compile_callbacks, prepare, solve, solver_options
from jtraj.success import FEASIBILITY_TOL
from jtraj.success import evaluate as check_motion
from jtraj.tables import markdown_table
from jtraj.task import task_argument

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/_args.py, also when the tests load this file from its path
from _args import add_param, refuse_repeats  # noqa: E402


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="big_jump", type=task_argument)
    add_param(ap)
    ap.add_argument("--sigma", type=float, default=0.1)
    ap.add_argument("--replicates", type=int, default=10)
    ap.add_argument("--strategies", default="vmap,threads", help="comma-separated ways to time: vmap, threads (solve_batch's strategies), vectorized (vmap with cpu_batch='vectorized')")
    ap.add_argument("--batches", default="", help="comma-separated further batch sizes to time, e.g. 100,1000")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jtraj-sequential", action="store_true", help="also time jtraj's solver one replicate at a time")
    ap.add_argument("--no-ipopt", action="store_true", help="skip the sequential Ipopt solves")
    ap.add_argument("--out", help="write the figures to this JSON file, F.json (with F.md and provenance.json beside it)")
    args = ap.parse_args(argv)
    try:
        batches = [int(b) for b in args.batches.split(",") if b.strip()]
    except ValueError:
        ap.error(f"--batches: {args.batches!r}: expected comma-separated batch sizes >= 1, e.g. 100,1000")
    if not (math.isfinite(args.sigma) and args.sigma >= 0):
        ap.error(f"--sigma: {args.sigma}: expected a noise level (standard deviation) >= 0")
    strategies = [s.strip() for s in args.strategies.split(",") if s.strip()]
    from jtraj.solvers.ipm import JtrajSolver

    known = (*JtrajSolver.STRATEGIES, "vectorized")
    if not strategies or any(s not in known for s in strategies):
        ap.error(f"--strategies takes some of {', '.join(known)}")
    refuse_repeats(ap, "--strategies", strategies, "strategy")  # each would be timed and tabled twice
    if args.replicates < 1 or any(b < 1 for b in batches):
        ap.error("--replicates and --batches take positive whole numbers")
    if not is_seed(args.seed):  # JAX's PRNGKey raised OverflowError after the compile
        ap.error(f"--seed: {args.seed}: expected a 64-bit integer (below 2**63 in magnitude)")
    if args.out is not None:  # a file that can be written, before minutes of solves
        try:
            if os.path.isdir(args.out):
                raise InputError("--out", args.out, "is a folder; expected the path of a JSON file")
            if not args.out.endswith(".json") or os.path.basename(args.out) == ".json":
                raise InputError("--out", args.out, "expected the path of a JSON file, F.json (F.md and provenance.json are written beside it)")
            _check_out(os.path.dirname(os.path.abspath(args.out)), shown=args.out)
        except InputError as e:
            ap.error(str(e))
    if args.no_ipopt:
        args.jtraj_sequential = True  # something to compare with

    device = jax.devices()[0]
    print(f"JAX {jax.__version__} on {device.platform} ({device.device_kind}, {jax.local_device_count(device.platform)} devices); {platform.node()}", flush=True)
    prep = prepare(args.task, args.param)
    tr, nlp = prep.transcription, prep.nlp
    theta = tr.resolve_theta(None)
    backend = solvers.get("jtraj")
    opts = solver_options(backend, None, None, False, tr.task.max_iter)
    largest = max([args.replicates, *batches])
    starts = noisy_warm_starts(tr.warm_start(), [args.sigma], largest, args.seed)[0]
    report: dict = {
        "task": args.task, "parameterization": args.param, "sigma": args.sigma, "replicates": args.replicates,
        "jax": jax.__version__, "device": f"{device.platform} {device.device_kind}", "devices": jax.local_device_count(device.platform), "cpus": cpu_count(), "batches": [],
    }

    label = {"vmap": "vmapped", "threads": f"threads ({min(args.replicates, cpu_count())} at a time)", "vectorized": "vmapped (vectorized)"}
    timed: dict[str, float] = {}
    solved: dict[str, int] = {}  # each strategy's converged members of the compared batch
    for strategy in strategies:
        for k, size in enumerate([args.replicates, *batches]):
            how = dict(strategy="vmap", options=dataclasses.replace(opts, cpu_batch="vectorized")) if strategy == "vectorized" else dict(strategy=strategy, options=opts)
            sols, total, compile_time = backend.solve_batch(nlp, starts[:size], theta, **how)  # type: ignore[attr-defined]
            converged = sum(s.converged for s in sols)
            its = [s.stats.iterations for s in sols]
            print(
                f"jtraj {strategy} batch of {size}: compiled in {compile_time:.1f} s, solved in {total:.2f} s "
                f"({total / size:.3f} s per replicate), {converged}/{size} converged, iterations {min(its)}-{max(its)}",
                flush=True,
            )
            report["batches"].append({"strategy": strategy, "size": size, "compile_s": compile_time, "solve_s": total, "converged": converged, "iterations_max": max(its), "iterations_mean": float(np.mean(its))})
            if k == 0:  # the replicates compared with Ipopt
                timed[strategy] = total
                solved[strategy] = converged
                if strategy == strategies[0]:
                    batch = sols

    t_jtraj_seq = 0.0
    seq: list = [None] * args.replicates
    if args.jtraj_sequential:
        for i in range(args.replicates):
            seq[i] = backend.solve(nlp, starts[i], theta, opts)
            t_jtraj_seq += seq[i].stats.time_total
        report["jtraj_sequential_s"] = t_jtraj_seq

    # Ipopt calls the NLP's functions one point at a time: on the CPU, also on a GPU machine,
    # where `prepare` compiled them for the GPU; compile them for the CPU before timing
    on_cpu = contextlib.nullcontext() if device.platform == "cpu" else jax.default_device(jax.devices("cpu")[0])
    if not args.no_ipopt and device.platform != "cpu":
        with on_cpu:
            compile_callbacks(tr, nlp)
    t_ipopt = 0.0
    ipopt_solved = 0
    rows = []
    for i, sol in enumerate(batch):
        traj = tr.decode(sol.x, theta)
        viol = nlp.violation(sol.x, theta)
        ok = sol.converged and viol < FEASIBILITY_TOL and check_motion(traj.base_xyz_wxyz, tr.task.flip_axis, tr.task.flip_turns).ok
        line = f"#{i}: jtraj {sol.status.value:26s} {sol.stats.iterations:4d} it viol {viol:.1e} success {ok}"
        row = {"replicate": i, "jtraj": {"status": sol.status.value, "iterations": sol.stats.iterations, "violation": viol, "success": bool(ok)}}
        if seq[i] is not None:
            line += f" | one at a time {seq[i].stats.iterations:4d} it {seq[i].stats.time_total:6.2f} s"
        if not args.no_ipopt:
            with on_cpu:
                res = solve(args.task, args.param, warm_start=starts[i], progress=None, keep_trajectory=False)
            t_ipopt += res.time_s
            ipopt_solved += bool(res.success)
            line += f" | ipopt {res.status.value:26s} {res.iterations:4d} it viol {res.constraint_violation:.1e} {res.time_s:6.2f} s success {res.success}"
            row["ipopt"] = {"status": res.status.value, "iterations": res.iterations, "violation": res.constraint_violation, "time_s": res.time_s, "success": bool(res.success)}
        rows.append(row)
        print(line, flush=True)
    report["rows"] = rows
    if "vmap" in timed:
        report["vmapped_s"] = timed["vmap"]
    if "threads" in timed:
        report["threads_s"] = timed["threads"]
    if "vectorized" in timed:
        report["vectorized_s"] = timed["vectorized"]
    if args.jtraj_sequential:
        print(f"jtraj one at a time: {t_jtraj_seq:.2f} s; " + ", ".join(f"{label[s]} {t:.2f} s, speedup {t_jtraj_seq / t:.2f}" for s, t in timed.items()), flush=True)
    sequential = t_jtraj_seq if args.no_ipopt else t_ipopt
    if not args.no_ipopt:
        report["ipopt_sequential_s"] = t_ipopt
    against = "jtraj one at a time" if args.no_ipopt else "Ipopt"
    n = args.replicates
    # the sequential side's solved replicates: Ipopt's successes, or jtraj's one at a time
    sequential_solved = sum(bool(r is not None and r.converged) for r in seq) if args.no_ipopt else ipopt_solved
    report["solved"] = {**solved, "sequential": sequential_solved}

    def speedup(s: str) -> str:
        # a replicate that failed on either side (stopped at the iteration limit, say) makes the
        # two times those of different work: no ratio, the counts instead
        if solved[s] == n and sequential_solved == n:
            return f"{sequential / timed[s]:.2f}"
        return f"none (jtraj {solved[s]}/{n} converged, {against} {sequential_solved}/{n})"

    report["speedup"] = {s: sequential / t for s, t in timed.items() if solved[s] == n and sequential_solved == n}
    # the first strategy's line last (vmap's, by default: the line)
    last = [f"replicates: {label[s]} {timed[s]:.2f} s, sequential {sequential:.2f} s, speedup {speedup(s)} (sequential: {against})" for s in reversed(strategies)]
    if args.out:
        # one provenance record, held by F.json and written as provenance.json
        out = Path(args.out)
        report["provenance"] = provenance(["python", "bench/replicates.py", *(sys.argv[1:] if argv is None else argv)])
        write_results(out.parent, out.stem, report, markdown(report, last), "bench/replicates.py", record=report["provenance"])
    for line in last:
        print(line)


def markdown(report: dict, last: list[str]) -> str:
    """The table of F.md: every timed batch, then the printed last lines."""
    header = ("strategy", "batch", "compile (s)", "solve (s)", "per replicate (s)", "converged", "iterations (mean / max)")
    rows = [(b["strategy"], b["size"], f"{b['compile_s']:.1f}", f"{b['solve_s']:.2f}", f"{b['solve_s'] / b['size']:.3f}", f"{b['converged']}/{b['size']}", f"{b['iterations_mean']:.1f} / {b['iterations_max']}") for b in report["batches"]]
    note = f"{report['task']}, {report['parameterization']}, sigma {report['sigma']:g}, {report['replicates']} replicates on {report['device']} ({report['devices']} devices, {report['cpus']} CPUs).\n\n" + "\n".join(last)
    return markdown_table(header, rows, note)


if __name__ == "__main__":
    main()
