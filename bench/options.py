"""jtraj's interior point under several option sets on the study's tasks, in one process, the
option sets taking turns: what an option is worth, measured on the same machine under the same
load (on a shared virtual machine two runs minutes apart differ by a third, so figures from
separate runs cannot tell a 20 % change from the machine's drift).

    python bench/options.py [TASK ...] --variant NAME=OPTION:VALUE[,OPTION:VALUE...] [...]
                            [--rounds 3] [--param se3] [--variables compact] [--out DIR]

Each ``--variant`` names a set of `jtraj.solvers.IpmOptions` fields (``--variant
loose=residual_ratio_max:1e-6``; a bare ``--variant default`` has none, and is the baseline
when given first). The first variant is the baseline of the ratio column. Per task, every
variant is first solved once to compile its program (kept as ``time_compile_s``; the first
variant's also carries the build of the task's NLP, `jtraj.solve`'s ``time_compile``), then each is
timed ``--rounds`` times in ABBA order (a round's order reversed every other round, so neither
side always runs first). Each solve starts from the task's warm start, so a variant's repeats
take the same iterations; a record keeps each repeat's iterations, and the table shows them
all where they differ.

The table gives each variant's status, iterations, cost and largest violation (of its last
repeat), the median time with its range, and the baseline's median over the variant's.
``--out`` writes ``DIR/options.json``, ``DIR/options.md`` and ``DIR/provenance.json``, again after
each task (``"complete": false`` until the last). Default tasks: the six of the study.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jtraj
from jtraj.cli import InputError, _check_ipopt  # the command line's NAME=VALUE parsing and checks
from jtraj.experiments import ALL_TASKS
from jtraj.provenance import write_results
from jtraj.tables import markdown_table

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/_args.py, also when the tests load this file from its path
from _args import add_out, add_param, add_tasks, add_variables, results_record  # noqa: E402


def parse_variant(text: str) -> tuple[str, dict[str, Any]]:
    """``NAME=OPTION:VALUE,...`` (or a bare ``NAME``) -> (name, options), parsed and checked as
    the command line's ``--ipopt OPTION=VALUE`` items of ``--solver jtraj`` are."""
    name, _, spec = text.partition("=")
    items = [item for item in spec.split(",") if item]
    if not name:
        raise InputError("--variant", text, "expected NAME=OPTION:VALUE[,OPTION:VALUE...]")
    for item in items:
        if ":" not in item:
            raise InputError("--variant", text, f"{item!r} is not OPTION:VALUE")
    return name, _check_ipopt([item.replace(":", "=", 1) for item in items], "jtraj", field="--variant")


def measure(task: str, variants: list[tuple[str, dict[str, Any]]], rounds: int, param: str = "se3", variables: str = "compact", solve: Callable[..., Any] | None = None) -> list[dict]:
    """One record per variant: the compile solve, then ``rounds`` (at least 1) timed solves in
    ABBA order."""
    if rounds < 1:
        raise ValueError(f"rounds={rounds}: expected at least 1")
    solve = solve or jtraj.solve

    def once(options: dict[str, Any]) -> Any:
        return solve(task, param, variables=variables, solver="jtraj", options=options, progress=None, keep_trajectory=False)

    records = {name: dict(task=task, variant=name, options=options, times_s=[], iterations=[]) for name, options in variants}
    for name, options in variants:
        records[name]["time_compile_s"] = round(once(options).time_compile, 1)
    for k in range(rounds):
        for name, options in variants if k % 2 == 0 else variants[::-1]:
            res, rec = once(options), records[name]
            rec["times_s"].append(round(res.time_s, 4))
            rec["iterations"].append(res.iterations)
            rec.update(status=res.status.value, cost=res.cost, constraint_violation=res.constraint_violation)
    out = [records[name] for name, _ in variants]
    for rec in out:
        rec["median_s"] = statistics.median(rec["times_s"])
        rec["speedup"] = statistics.median(out[0]["times_s"]) / rec["median_s"]
        print(f"{task:10s} {rec['variant']:12s} {rec['status']:26s} it {'/'.join(map(str, sorted(set(rec['iterations']))))}  "
              f"cost {rec['cost']:.6g}  viol {rec['constraint_violation']:.1e}  median {rec['median_s']:.3f} s  {rec['times_s']}", flush=True)
    return out


def table(records: list[dict]) -> str:
    def options(r: dict) -> str:
        return ", ".join(f"{k}={v}" for k, v in r["options"].items()) or "(defaults)"

    def iterations(r: dict) -> str:
        return "/".join(str(i) for i in r["iterations"]) if len(set(r["iterations"])) > 1 else str(r["iterations"][0])

    def ratio(r: dict) -> str:
        # a solve that did not do the task has no time to solution to compare (a stop at the
        # iteration limit read as the variant being so much slower)
        baseline = next(b for b in records if b["task"] == r["task"])
        failed = [x for x in (r, baseline) if x["status"] != "solved"]
        return f"{r['speedup']:.2f}x" if not failed else f"none ({'baseline ' if failed[0] is baseline and r is not baseline else ''}{failed[0]['status']})"

    header = ("task", "variant", "options", "status", "iterations", "cost", "max violation", "median time (s)", "range (s)", "baseline / variant")
    return markdown_table(header, (
        (r["task"], r["variant"], options(r), r["status"], iterations(r), f"{r['cost']:.6g}", f"{r['constraint_violation']:.1e}", f"{r['median_s']:.3f}",
         f"{min(r['times_s']):.3f}-{max(r['times_s']):.3f}", ratio(r))
        for r in records
    ), note="Each variant's solves alternate with the others' in one process (ABBA); the ratio is of the medians, the first variant the baseline; none where either did not solve the task.")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_tasks(ap, ALL_TASKS)
    ap.add_argument("--variant", action="append", required=True, help="NAME=OPTION:VALUE[,OPTION:VALUE...] (repeatable; the first is the baseline)")
    ap.add_argument("--rounds", type=int, default=3)
    add_param(ap)
    add_variables(ap, "compact")
    add_out(ap, "options")
    args = ap.parse_args(argv)
    if args.rounds < 1:
        ap.error("--rounds must be at least 1")
    try:
        variants = [parse_variant(v) for v in args.variant]
    except InputError as exc:
        ap.error(str(exc))
    if len({name for name, _ in variants}) != len(variants):
        ap.error("--variant names must differ")
    rows: list[dict] = []
    for t, task in enumerate(args.tasks):  # the files after each task: a long run keeps what it measured
        rows += measure(task, variants, args.rounds, args.param, args.variables)
        if args.out:
            write_results(args.out, "options", rows, table(rows), "bench/options.py", record=results_record("bench/options.py", argv, complete=t == len(args.tasks) - 1))


if __name__ == "__main__":
    main()
