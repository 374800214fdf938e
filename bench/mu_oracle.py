"""jtraj's interior point with its two barrier rules on one task, in one process: iterations,
time, and time per pass (an NLP evaluation: an iteration or a backtracking step).

    python bench/mu_oracle.py [TASK] [--param se3] [--repeat 2] [--out DIR]

The rules: the default (Ipopt's: quality-function oracle, obj-constr-filter) and the former one
(LOQO oracle, KKT-error). Each is solved ``--repeat`` times from the task's warm start with the
compact variables and the task's iteration limit (as ``jtraj.solve`` sets it), alternating, so a change in the machine's load shows as a change between
repeats; compile is excluded (one program per rule, compiled before the first solve).
``--out DIR`` writes ``DIR/mu_oracle.json`` (one record per solve), ``DIR/mu_oracle.md`` and
``DIR/provenance.json``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/_args.py, also when the tests load this file from its path
from _args import add_out, add_param  # noqa: E402

RULES = {
    "quality-function + obj-constr-filter (default)": {},
    "loqo + kkt-error": {"mu_oracle": "loqo", "adaptive_mu_globalization": "kkt-error"},
}


def table(records: list[dict]) -> str:
    """Markdown, one row per solve, in the order solved (the rules taking turns)."""
    from jtraj.tables import markdown_table

    return markdown_table(
        ("task", "rule", "repeat", "status", "iterations", "time (s)", "s/iter", "passes", "s/pass"),
        [
            (r["task"], r["rule"], r["repeat"], r["status"], r["iterations"], f"{r['time_s']:.2f}", f"{r['time_s'] / max(r['iterations'], 1):.3f}", r["passes"], f"{r['time_s'] / max(r['passes'], 1):.3f}")
            for r in records
        ],
        "A pass is an NLP evaluation: an iteration or a backtracking step. Compile excluded.",
    )


def main(argv: list[str] | None = None) -> None:
    from jtraj.task import task_argument  # jtraj after the module's own settings

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("task", nargs="?", type=task_argument, default="big_jump")
    add_param(ap)
    ap.add_argument("--repeat", type=int, default=2)
    add_out(ap, "mu_oracle")
    args = ap.parse_args(argv)
    if args.repeat < 1:
        ap.error(f"--repeat: {args.repeat}: expected an integer >= 1")

    from jtraj import solvers
    from jtraj.solver import prepare, solver_options

    prep = prepare(args.task, args.param)
    x0 = prep.transcription.warm_start()
    solver = solvers.get("jtraj")
    max_iter = prep.transcription.task.max_iter  # IpmOptions' own default (200) is not the task's (walk: 50)
    options = {name: solver_options(solver, rule, None, False, max_iter) for name, rule in RULES.items()}
    records = []
    for k in range(args.repeat):
        for name, opts in options.items():
            sol = solver.solve(prep.nlp, x0, prep.nlp.theta, opts)
            t, its, passes = sol.stats.time_total, sol.stats.iterations, sol.stats.obj_evals
            records.append(dict(task=args.task, param=args.param, rule=name, repeat=k + 1, status=sol.status.value, iterations=its, time_s=t, passes=passes))
            print(f"{args.task} {name:48s} {sol.status.value:14s} {its:4d} it {t:7.2f} s  {t / max(its, 1):.3f} s/it  {passes} passes  {t / max(passes, 1):.3f} s/pass", flush=True)
    if args.out:
        from jtraj.provenance import write_results

        write_results(args.out, "mu_oracle", records, table(records), "bench/mu_oracle.py", argv)


if __name__ == "__main__":
    main()
