"""jtraj's interior point with each of its Hessians on the study's tasks, in one run: Ipopt's
limited-memory BFGS (the default), a damped BFGS update of each element's block (a
structure-preserving quasi-Newton) and the exact Hessian of the Lagrangian from JAX.

    python bench/hessians.py [TASK ...] [--param se3] [--hessians lbfgs,bfgs,exact]
                             [--variables compact] [--out DIR]

Each (task, Hessian) is solved once from the task's warm start by ``jtraj.solve(...,
solver="jtraj", options={"hessian": ...})`` with the study's other settings (tol 1e-3, the
task's iteration limit), one after the other in this process; the time is the solve alone
(its program is compiled before the clock starts, and that compile is printed and kept as
``time_compile_s``; a task's first solve in the process also carries the build of its NLP,
`jtraj.solve`'s ``time_compile``, so the first Hessian's is the larger). Prints one row per solve; ``--out`` writes ``DIR/hessians.json``,
``DIR/hessians.md`` and ``DIR/provenance.json``, again after each task (``"complete": false``
until the last). Default tasks: the six of the study.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jtraj
from jtraj.experiments import ALL_TASKS
from jtraj.provenance import write_results
from jtraj.solvers.ipm import IpmOptions
from jtraj.tables import markdown_table

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/_args.py, also when the tests load this file from its path
from _args import add_out, add_param, add_tasks, add_variables, refuse_repeats, results_record  # noqa: E402

HESSIANS = ("lbfgs", "bfgs", "exact")


def run(tasks: list[str], hessians: list[str], param: str, variables: str) -> list[dict]:
    rows = []
    for task in tasks:
        for hessian in hessians:
            res = jtraj.solve(task, param, variables=variables, solver="jtraj", options={"hessian": hessian}, progress=None, keep_trajectory=False)
            row = dict(
                task=task, hessian=hessian, status=res.status.value, iterations=res.iterations, cost=res.cost,
                constraint_violation=res.constraint_violation, turns=res.turns, time_s=round(res.time_s, 3), time_compile_s=round(res.time_compile, 1),
            )
            print(f"{task:10s} {hessian:6s} {row['status']:26s} {row['iterations']:4d} it  cost {row['cost']:.4g}  viol {row['constraint_violation']:.1e}  "
                  f"{row['time_s']:7.2f} s  (compiled in {row['time_compile_s']:.0f} s)", flush=True)
            rows.append(row)
    return rows


def table(rows: list[dict]) -> str:
    header = ("task", "Hessian", "status", "iterations", "cost", "max violation", "turns", "time (s)", "s/iter")
    return markdown_table(header, (
        (r["task"], r["hessian"], r["status"], r["iterations"], f"{r['cost']:.4g}", f"{r['constraint_violation']:.1e}",
         "" if r["turns"] is None else f"{r['turns']:+.2f}", f"{r['time_s']:.2f}", f"{r['time_s'] / max(r['iterations'], 1):.3f}")
        for r in rows
    ))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_tasks(ap, ALL_TASKS)
    add_param(ap)
    ap.add_argument("--hessians", default=",".join(HESSIANS), help=f"comma-separated, some of {','.join(HESSIANS)}")
    add_variables(ap, "compact")
    add_out(ap, "hessians")
    args = ap.parse_args(argv)
    hessians = [h for h in args.hessians.split(",") if h]
    if not hessians:
        ap.error(f"--hessians: {args.hessians!r}: expected some of {','.join(HESSIANS)}")
    refuse_repeats(ap, "--hessians", hessians, "Hessian")
    for h in hessians:
        try:
            IpmOptions(hessian=h)  # an unknown name fails here, with the option's own message
        except ValueError as e:  # InvalidOptionError
            ap.error(f"--hessians: {e}")
    rows: list[dict] = []
    for t, task in enumerate(args.tasks):  # the files after each task: a long run keeps what it solved
        rows += run([task], hessians, args.param, args.variables)
        if args.out:
            write_results(args.out, "hessians", rows, table(rows), "bench/hessians.py", record=results_record("bench/hessians.py", argv, complete=t == len(args.tasks) - 1))


if __name__ == "__main__":
    main()
