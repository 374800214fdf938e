"""Where a cold start's time goes with jtraj's solver: building the NLP (its structure probe and
Ipopt's callbacks compile here), compiling the solver's program, and the solve, under XLA flag
settings given on the command line.

    python bench/compile.py [TASK ...] [--param se3] [--variables paper]
        [--flags="|--xla_llvm_disable_expensive_passes=true"] [--repeats 3] [--out DIR]

Each (task, flags) pair runs in a fresh process with ``JTRAJ_NO_CACHE=1`` (no persistent
compilation cache) and ``XLA_FLAGS`` set to one of ``--flags``' settings (separated by ``|``;
an empty one is none; write ``--flags=...``, since the settings start with dashes): `jtraj.solver.prepare`, then
`jtraj.solve(..., solver="jtraj")` once (its ``time_compile`` less prepare's is the program's
compile) and ``--repeats`` more times (the table gives the fastest solve). ``--out DIR``
writes ``DIR/compile.json``, ``DIR/compile.md`` and ``DIR/provenance.json``; where a process
fails, the records measured before it (provenance ``"complete": false``), and the benchmark
stops with one line naming the failure. Default: big_jump,
no flags. Run it on an otherwise idle machine: compiles are single-threaded and slow down under
load.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/_args.py, also when the tests load this file from its path
from _args import add_out, add_param, add_tasks, add_variables, results_record  # noqa: E402

CHILD = """
import json, sys
import jtraj
from jtraj.solver import prepare
task, param, variables, repeats = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
build = prepare(task, param, variables).time_compile  # counted once, in the first solve's too
kw = dict(variables=variables, solver="jtraj", progress=False, keep_trajectory=False)
first = jtraj.solve(task, param, **kw)
runs = [jtraj.solve(task, param, **kw) for _ in range(repeats)]
print("COMPILE " + json.dumps(dict(
    task=task, build=build, program=first.time_compile - build, iterations=first.iterations,
    status=first.status.value, times=[r.time_s for r in runs],
)))
"""


def run_child(task: str, param: str, variables: str, flags: str, repeats: int) -> dict:
    """One fresh process; its record, with the flags it ran under (RuntimeError, one line with
    the last lines of its stderr, where it fails)."""
    env = dict(os.environ, JTRAJ_NO_CACHE="1", XLA_FLAGS=flags)
    proc = subprocess.run([sys.executable, "-c", CHILD, task, param, variables, str(repeats)], env=env, capture_output=True, text=True)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("COMPILE ")]
    if proc.returncode != 0 or not lines:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise RuntimeError(f"{task} with XLA_FLAGS={flags!r}: exit {proc.returncode}: {' | '.join(tail)}")
    return json.loads(lines[-1][len("COMPILE ") :]) | dict(flags=flags, param=param, variables=variables)


def table(records: list[dict]) -> str:
    """Markdown: one row per record, times in seconds; a solve that did not succeed has its
    status beside its iterations."""
    lines = ["| task | XLA_FLAGS | build the NLP (s) | compile the solver (s) | solve (s, fastest) | iterations |", "|---|---|---|---|---|---|"]
    for r in records:
        flags = f"`{r['flags']}`" if r["flags"] else "(none)"
        status = "" if r.get("status", "solved") == "solved" else f" ({r['status']})"
        lines.append(f"| {r['task']} | {flags} | {r['build']:.1f} | {r['program']:.1f} | {min(r['times']):.2f} | {r['iterations']}{status} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_tasks(ap, ["big_jump"])
    add_param(ap)
    add_variables(ap, "paper")
    ap.add_argument("--flags", default="", help="XLA_FLAGS settings separated by '|', one process each (empty: none)")
    ap.add_argument("--repeats", type=int, default=3)
    add_out(ap, "compile")
    a = ap.parse_args(argv)
    if a.repeats < 1:
        ap.error(f"--repeats: {a.repeats}: expected an integer >= 1 (the table gives the fastest of them)")
    records: list[dict] = []
    failure = None
    try:
        for task in a.tasks:
            for flags in a.flags.split("|"):
                records.append(run_child(task, a.param, a.variables, flags, a.repeats))
                r = records[-1]
                print(f"{task} XLA_FLAGS={flags!r}: build {r['build']:.1f} s, program {r['program']:.1f} s, solve {min(r['times']):.2f} s", flush=True)
    except RuntimeError as e:  # a failed process: keep the records measured before it
        failure = e
    text = table(records)
    if records:
        print(text, end="")
    if a.out is not None and records:
        from jtraj.provenance import write_results

        write_results(a.out, "compile", records, text, "bench/compile.py", record=results_record("bench/compile.py", argv, complete=failure is None))
        print(f"wrote {a.out}/compile.json, compile.md, provenance.json")
    if failure is not None:
        kept = f"; {a.out}/compile.json holds the {len(records)} records measured before it" if a.out is not None and records else ""
        raise SystemExit(f"bench/compile.py: {failure}{kept}")


if __name__ == "__main__":
    main()
