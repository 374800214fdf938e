"""Time jtraj's own solver at another revision of this repository and at the working tree, in
one run: what a change to the solver is worth, measured on the same machine under the same
load, never against remembered figures.

    python bench/revisions.py REV [TASK ...] [--param se3] [--variables compact]
        [--repeats 3] [--out DIR]

``REV`` (for example ``HEAD~1``) is checked out into a temporary git worktree, removed at the
end. Every (task, revision) pair runs in its own process whose ``PYTHONPATH`` puts that tree's
``jtraj`` first; the process checks the file it imported ``jtraj`` from, and the benchmark
refuses a result that came from the wrong tree. The two revisions alternate task by task, the
earlier revision first. Each process compiles, then solves the task's warm start ``--repeats``
times (`jtraj.solve(..., solver="jtraj")`; each solve's time is the jitted solve alone, as
``stats.time_total``), and the table gives the fastest. Iterations, status and cost are printed
beside the times, so a change that alters the iterates shows. ``--out DIR`` writes
``DIR/revisions.json`` (every record), ``DIR/revisions.md`` (the table) and
``DIR/provenance.json``; where a process fails, the records measured before it (provenance
``"complete": false``), and the benchmark stops with one line naming the failure. Default
tasks: walk big_jump backflip sideflip.

A record's ``time_compile`` is the first solve's `Result.time_compile`: building the NLP and
compiling the solver's program, in seconds (short where the persistent compilation cache held them;
`jtraj.solve` counts the solver's program since this was written; the records in
``results/solver_coupled_factor`` are older and count the NLP alone).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/_args.py, also when the tests load this file from its path
from _args import add_out, add_param, add_tasks, add_variables  # noqa: E402

REPO = Path(__file__).resolve().parents[1]

CHILD = """
import json, sys
from pathlib import Path
import jtraj
if Path(jtraj.__file__).resolve().parent.parent != Path.cwd().resolve():
    sys.exit(f"jtraj imported from {jtraj.__file__}, not from {Path.cwd()}")
task, param, variables, repeats = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
runs = [jtraj.solve(task, param, variables=variables, solver="jtraj", progress=False, keep_trajectory=False) for _ in range(repeats + 1)]
r = runs[-1]
print("REVISIONS " + json.dumps(dict(
    jtraj=jtraj.__file__, task=task, iterations=r.stats.iterations, status=r.status.value,
    cost=r.cost, violation=r.constraint_violation, time_compile=runs[0].time_compile,
    times=[x.stats.time_total for x in runs[1:]],
)))
"""


def run_child(tree: Path, task: str, param: str, variables: str, repeats: int) -> dict:
    """One process solving ``task`` with the jtraj of ``tree``; its record (RuntimeError, one
    line with the last lines of its stderr, where it fails)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tree), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep))
    proc = subprocess.run([sys.executable, "-c", CHILD, task, param, variables, str(repeats)], env=env, capture_output=True, text=True, cwd=tree)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("REVISIONS ")]
    if proc.returncode != 0 or not lines:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise RuntimeError(f"{task} at {tree}: exit {proc.returncode}: {' | '.join(tail)}")
    record = json.loads(lines[-1][len("REVISIONS ") :])
    if Path(record["jtraj"]).resolve().parent.parent != tree.resolve():
        raise RuntimeError(f"{task}: the child imported jtraj from {record['jtraj']}, not from {tree}")
    return record


def table(records: list[dict], labels: tuple[str, str]) -> str:
    """The Markdown table: per task, both revisions' iterations, cost and fastest time; a solve
    that did not succeed has its status beside its iterations, and no ratio (its time is not a
    time to solution)."""

    def status(r: dict) -> str:
        return "" if r.get("status", "solved") == "solved" else f" ({r['status']})"

    a, b = labels
    rows = [
        f"| task | iterations ({a} / {b}) | cost ({a} / {b}) | fastest solve {a} (s) | fastest solve {b} (s) | s/iter {a} | s/iter {b} | {a} / {b} |",
        "|---|---|---|---|---|---|---|---|",
    ]
    tasks = list(dict.fromkeys(r["task"] for r in records))
    for t in tasks:
        ra = next(r for r in records if r["task"] == t and r["label"] == a)
        rb = next(r for r in records if r["task"] == t and r["label"] == b)
        ta, tb = min(ra["times"]), min(rb["times"])
        ratio = f"{ta / tb:.2f}x" if not status(ra) + status(rb) else "none"
        rows.append(
            f"| {t} | {ra['iterations']}{status(ra)} / {rb['iterations']}{status(rb)} | {ra['cost']:.4g} / {rb['cost']:.4g} | {ta:.2f} | {tb:.2f} | "
            f"{ta / max(ra['iterations'], 1):.3f} | {tb / max(rb['iterations'], 1):.3f} | {ratio} |"
        )
    return "\n".join(rows) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("rev", help="the earlier revision (git rev, e.g. HEAD~1)")
    add_tasks(ap, ["walk", "big_jump", "backflip", "sideflip"])
    add_param(ap)
    add_variables(ap, "compact")
    ap.add_argument("--repeats", type=int, default=3, help="timed solves per task and revision (after one that compiles)")
    add_out(ap, "revisions")
    args = ap.parse_args(argv)
    # every argument before the worktree and the first compile
    if args.repeats < 1:
        ap.error(f"--repeats: {args.repeats}: expected an integer >= 1")
    # a commit (not a tree or file, e.g. HEAD:README.md), and never read as one of git's options
    sha = subprocess.run(["git", "rev-parse", "--verify", "--quiet", "--short", f"{args.rev}^{{commit}}"], cwd=REPO, capture_output=True, text=True)
    if sha.returncode != 0:
        ap.error(f"rev: {args.rev!r}: not a commit of this repository; expected a git revision such as HEAD~1 or a commit hash")
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True).stdout.strip()
    # changed as provenance counts it: a tracked file, or an untracked one a run loads
    from jtraj.provenance import source

    dirty = bool((source(REPO) or {}).get("dirty"))
    labels = (sha.stdout.strip(), head + ("+changes" if dirty else ""))
    if labels[0] == labels[1]:  # the table's columns are found by label: both would be one run's
        ap.error(f"rev: {args.rev!r}: the checkout itself ({head}, no changes); expected an earlier revision, or changes in the checkout")
    records: list[dict] = []
    failure = None
    with tempfile.TemporaryDirectory(prefix="jtraj-rev-") as tmp:
        tree = Path(tmp) / "tree"
        subprocess.run(["git", "worktree", "add", "--detach", str(tree), sha.stdout.strip()], cwd=REPO, check=True, capture_output=True)
        try:
            for task in args.tasks:
                for label, where in zip(labels, (tree, REPO)):
                    # a task file by its absolute path: each child runs in its own tree
                    rec = run_child(where, str(Path(task).resolve()) if task.endswith(".toml") else task, args.param, args.variables, args.repeats)
                    rec["task"], rec["label"] = task, label
                    records.append(rec)
                    print(f"{task:10s} {label:14s} {rec['iterations']:4d} it  {rec['status']:26s} cost {rec['cost']:.4g}  fastest {min(rec['times']):.2f} s  (all: {', '.join(f'{t:.2f}' for t in rec['times'])})", flush=True)
        except RuntimeError as e:  # a failed process: keep the records measured before it
            failure = e
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=REPO, capture_output=True)
    if failure is not None and not records:
        raise SystemExit(f"bench/revisions.py: {failure}")
    md = table(records[: len(records) // 2 * 2], labels)  # the tasks both revisions solved
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    note = f"\nMachine: {os.cpu_count()} CPUs, 1-minute load average {load:.1f} at the end; {args.param}, {args.variables} variables, jtraj's solver, the fastest of {args.repeats} solves (compile excluded), one process per task and revision.\n"
    print()
    print(md + note)
    if args.out:
        from jtraj.provenance import provenance, write_results

        # strict JSON, each file written atomically, with the two revisions in the provenance:
        # its record is built with them and written once
        record = provenance(["python", "bench/revisions.py", *(argv if argv is not None else sys.argv[1:])])
        record["revisions"] = {"earlier": labels[0], "later": labels[1]}
        record["complete"] = failure is None
        write_results(args.out, "revisions", records, md + note, "bench/revisions.py", record=record)
    if failure is not None:
        kept = f"; {args.out}/revisions.json holds the {len(records)} records measured before it" if args.out else ""
        raise SystemExit(f"bench/revisions.py: {failure}{kept}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
