"""Benchmark tasks side by side with the comparative study's public code, in one invocation:
time to solution, time per Ipopt iteration and its split into JAX evaluation (functions and
derivatives) and Ipopt's own work, for jtraj's variants, and the public code's time and
iterations measured in the same run (never remembered figures: machines differ from day to
day). The table has no compile column: the JSON records ``compile_s``, the time to build the
NLP of the first variant's variables (``compile_variables``), once per task.

    python bench/solve.py big_jump [sideflip ...] [--param se3] [--variants paper,compact,lean]
        [--ipopt NAME=VALUE ...] [--jtraj NAME=VALUE ...] [--peer PATH | --no-peer] [--repeat N]
        [--robot talos=talos_full] [--code-costs] [--out DIR]

The public code solves its own problem: Talos is its ``talos_full_v2`` (3 kg heavier than the
built-in tasks' ``talos``, example-robot-data's ``talos_reduced``, with stronger arms and
torso), and its walk and back-flip scripts weigh the costs otherwise than the paper's Table II.
``--robot talos=talos_full`` solves jtraj's side on the code's Talos (`robots/talos_full.toml`)
and ``--code-costs`` with the code's weights (``bench/side_by_side.py``'s ``CODE_COSTS``), so
that both sides solve the same problem; the task cell names them, and the JSON records them.
The Go2 and G1 are the same robots on both sides.

Variants (Ipopt with the study's settings: L-BFGS Hessian, tol 1e-3, MUMPS; or jtraj's solver):
    paper    the study's variables per knot (q, v, a, f, c)
    compact  jtraj's default: contact positions substituted by forward kinematics (q, v, a, f)
    lean     accelerations substituted too (q, v, f)
    exact    the paper's variables with the exact Hessian of the Lagrangian from JAX
    jtraj    the compact variables with jtraj's own interior point (solver="jtraj", tol 1e-3);
             its time is the whole jitted solve (the "Ipopt own" column then holds it all);
             ``--jtraj NAME=VALUE`` sets its options (`jtraj.solvers.IpmOptions`; e.g.
             ``constr_viol_tol=1e-6``), shown in its row's variant cell

``--ipopt NAME=VALUE`` adds an Ipopt option to the Ipopt variants; ``print_level`` (3 here) may
be raised, not lowered, and ``print_timing_statistics`` stays yes: the linear solver's time is
read from the timing table Ipopt prints.

``--peer`` is the path of a runner, run as ``PEER TASK``, that runs the public code on one task
and prints one JSON line with at least ``iterations`` and ``time_s`` (its wall time around
Ipopt's solve, model building excluded); the default is ``../shared/peers/run-se3-trajopt``
beside the repository when it exists. It runs before jtraj's variants, one after the other (never concurrently), and the
ratio column is its time over each variant's time to solution (compile excluded; none where
the variant did not solve the task, its status instead). A public-code run stopped by a limit
(Ipopt status -1, -4 or -5: iterations, CPU or wall time) gives a lower bound (">= "); one that
failed otherwise (e.g. 2, infeasible; -2, restoration failed) gives no ratio, its status
instead. Without a peer the table has no ratio column.

``--repeat N`` measures each side N times, alternating (the public code, then jtraj's variants,
N rounds), and reports the median of each with its range (N odd: the median is one of the runs,
whose other columns the row shows): on a shared virtual machine one run
of either can be off by a third (big_jump's jtraj solve took 2.02 s and then 1.52 s in runs
minutes apart, and 1.22 s in the session before), and the ratio of two single runs inherits both errors. The iterations of every repeat
should agree (both sides are deterministic on one machine); where they do not, the table
shows each repeat's, and stderr says so. ``--out DIR`` writes ``DIR/speed.json`` (every raw record)
and ``DIR/speed.md`` (the table) and ``DIR/provenance.json`` (command, date, machine, versions),
again after each task, with ``"complete": false`` until the last task's rows are written.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from jtraj import io as jio
from jtraj.cli import InputError, _check_ipopt, _check_robots  # the command line's parsing and checks
from jtraj.provenance import write_results
from jtraj.solver import prepare, solve

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/_args.py, also when the tests load this file from its path
from _args import DEFAULT_PEER, add_out, add_param, add_tasks, refuse_repeats, results_record  # noqa: E402

VARIANTS = {
    "paper": dict(variables="paper", exact_hessian=False),
    "lean": dict(variables="lean", exact_hessian=False),
    "exact": dict(variables="paper", exact_hessian=True),
    "compact": dict(variables="compact", exact_hessian=False),
    "jtraj": dict(variables="compact", exact_hessian=False, solver="jtraj"),
}

#: Ipopt's statuses of a run stopped by a limit, not failed: -1 Maximum_Iterations_Exceeded,
#: -4 Maximum_CpuTime_Exceeded, -5 Maximum_WallTime_Exceeded (its time is a lower bound)
STOPPED_BY_LIMIT = (-1, -4, -5)


def linear_solver_time(text: str) -> float | None:
    """The linear solver's wall time (``StdAugSystemSolverMultiSolve``) in the timing table
    Ipopt prints (``print_timing_statistics``), in seconds; None where the table has no such line."""
    m = re.search(r"StdAugSystemSolverMultiSolve\.*:\s+([\d.]+) \(sys:\s+[\d.]+ wall:\s+([\d.]+)\)", text)
    return float(m.group(2)) if m else None


def run_peer(peer: str, task: str) -> dict:
    """Run the public code on ``task``; its JSON line (iterations, time_s, status, ...), or a
    one-line SystemExit naming the peer and what it printed."""
    proc = subprocess.run([peer, task], capture_output=True, text=True)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode != 0 or not lines:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise SystemExit(f"bench/solve.py: peer {peer} {task} failed (exit {proc.returncode}): {' | '.join(tail)}")
    try:
        rec = json.loads(lines[-1])
    except json.JSONDecodeError:
        rec = None
    if not isinstance(rec, dict) or not all(isinstance(rec.get(k), (int, float)) for k in ("iterations", "time_s")):
        raise SystemExit(f"bench/solve.py: peer {peer} {task} printed {lines[-1][:200]!r}; expected a JSON object with numbers iterations and time_s")
    return rec


def problem(task: str, robots: dict[str, str], code_costs: bool) -> Any:
    """The task jtraj solves: the built-in ``task``, or with ``robots`` or ``code_costs`` the
    Task object `side_by_side.jtraj_task` makes (on the mapped robot, with the code's costs)."""
    if not robots and not code_costs:
        return task
    from side_by_side import jtraj_task

    return jtraj_task(task, robots, code_costs)


def problem_label(task: str, robots: dict[str, str], code_costs: bool) -> str:
    """The table's task cell: the name, and the robot model and costs where they are not the
    built-in task's (the code's costs differ on the walk and the back-flip only)."""
    from side_by_side import CODE_COSTS

    from jtraj.task import load

    notes = []
    if robots:  # (a record of no mapping needs no task: the name alone)
        robot = load(task).robot
        notes += [robots[robot]] if robot in robots else []
    notes += ["code's costs"] if code_costs and task in CODE_COSTS else []
    return task + (f" ({', '.join(notes)})" if notes else "")


def run_variant(task: Any, param: str, variant: str, extra: dict, extra_jtraj: dict) -> dict:
    v = VARIANTS[variant]
    if v.get("solver") == "jtraj":
        return run_jtraj(task, param, variant, v, extra_jtraj)
    opts = {"print_timing_statistics": "yes", "print_level": 3} | extra  # main() refused values that hide the timing table
    # Ipopt prints its timing table on the C side: capture it from file descriptor 1
    with tempfile.TemporaryFile(mode="w+") as tmp:
        sys.stdout.flush()
        saved = os.dup(1)
        os.dup2(tmp.fileno(), 1)
        try:
            r = solve(task, param, variables=v["variables"], exact_hessian=v["exact_hessian"], ipopt_options=opts, progress=io.StringIO())
        finally:
            sys.stdout.flush()
            os.dup2(saved, 1)
            os.close(saved)
        tmp.seek(0)
        time_linear_solver = linear_solver_time(tmp.read())
    return _record(variant, r, time_linear_solver)


def _record(variant: str, r, time_linear_solver: float | None) -> dict:
    """One variant's row of the benchmark from its `jtraj.Result`."""
    return dict(
        variant=variant,
        status=r.status.value,
        success=r.success,
        iterations=r.iterations,
        time_s=r.time_s,
        time_derivatives=r.time_derivatives,
        time_ipopt=r.time_solver,
        time_linear_solver=time_linear_solver,
        cost=r.cost,
        constraint_violation=r.constraint_violation,
    )


def run_jtraj(task: Any, param: str, variant: str, v: dict, options: dict) -> dict:
    """jtraj's own interior point (compiled before its clock starts; no Ipopt timing table),
    with ``options`` over its defaults."""
    t0 = time.perf_counter()
    r = solve(task, param, variables=v["variables"], solver="jtraj", options=dict(options), progress=io.StringIO())
    total = time.perf_counter() - t0
    print(f"{getattr(task, 'name', task)} [{variant}]: solver program compiled and run in {total:.1f} s", flush=True)
    return _record(variant, r, None) | {"options": dict(options)}


def _median_of(runs: list[dict], what: str) -> dict:
    """The run of median ``time_s`` (the lower middle one for an even count, which main()
    refuses: the table's other columns are that run's) with every run's
    time in ``times_s``. Repeats that took different iterations (they should not: both sides
    are deterministic on one machine) are kept, said on stderr and shown in the table."""
    order = sorted(runs, key=lambda r: r["time_s"])
    its = [r["iterations"] for r in runs]
    if len(set(its)) > 1:
        print(f"bench/solve.py: {what}: the repeats took different iterations {its}; the table shows each", file=sys.stderr, flush=True)
    return dict(order[(len(order) - 1) // 2], times_s=[r["time_s"] for r in runs], iterations_all=its)


def _iterations_cell(rec: dict) -> str:
    """Iterations, or each repeat's where they differ."""
    its = rec.get("iterations_all") or [rec["iterations"]]
    return str(rec["iterations"]) if len(set(its)) == 1 else "/".join(map(str, its))


def _time_cell(rec: dict) -> str:
    """A time, with the range of its repeats when there were several."""
    times = rec.get("times_s") or [rec["time_s"]]
    return f"{rec['time_s']:.2f}" + (f" ({min(times):.2f}-{max(times):.2f})" if len(times) > 1 else "")


def _label(v: dict) -> str:
    """A row's variant cell: its name, and the solver options given on the command line."""
    opts = v.get("options") or {}
    return v["variant"] + "".join(f", {k}={val}" for k, val in opts.items())


def markdown(records: list[dict]) -> str:
    with_peer = any(r.get("peer") for r in records)
    head = "| task | variant | status | iterations | cost | violation | time (s) | s/iter | JAX eval (s) | Ipopt own (s) |"
    head += " peer iterations | peer cost | peer violation | peer time (s) | peer / jtraj |" if with_peer else ""
    lines = [head, "|" + "---|" * head.count(" | ") + "---|"]
    for rec in records:
        peer = rec.get("peer")
        for v in rec["variants"]:
            row = (
                f"| {problem_label(rec['task'], rec.get('robots') or {}, bool(rec.get('code_costs')))} | {_label(v)} | {v['status']} | {_iterations_cell(v)} | {v['cost']:.4g} | {v['constraint_violation']:.1e} "
                f"| {_time_cell(v)} | {v['time_s'] / max(v['iterations'], 1):.3f} "
                f"| {v['time_derivatives']:.2f} | {v['time_ipopt']:.2f} |"
            )
            if with_peer and peer:
                # a run stopped by a limit (`STOPPED_BY_LIMIT`; the public code stops at its own
                # 600 s wall-time limit, Ipopt status -5): its time is then a lower bound, and so
                # is the ratio. Any other status but 0 and 1 (2 infeasible, -2 restoration
                # failed, 4 diverging, ...) is a failed run: no time to solution, no ratio.
                # (a runner owes only iterations and time_s: without a status, nothing is claimed)
                status = peer.get("status")
                done = status is None or status in (0, 1)
                stopped = status in STOPPED_BY_LIMIT
                bound = ">= " if stopped else ""
                note = " (no status)" if status is None else "" if done else f" (stopped, Ipopt status {status})" if stopped else f" (failed, Ipopt status {status})"
                cost = f"{peer['obj']:.4g}" if peer.get("obj") is not None else ""
                viol = f"{peer['cons']:.1e}" if peer.get("cons") is not None else ""
                # a variant that did not solve the task has no time to solution to compare
                if not v.get("success", True):
                    ratio = f"none (jtraj {v['status']})"
                elif not (done or stopped):
                    ratio = f"none (peer status {status})"
                else:
                    ratio = f"{bound}{peer['time_s'] / v['time_s']:.1f}x"
                row += f" {_iterations_cell(peer)}{note} | {cost} | {viol} | {bound}{_time_cell(peer)} | {ratio} |"
            elif with_peer:
                row += " | | | | |"
            lines.append(row)
    loads = [x for r in records for x in (r.get("machine", {}).get("load_1min"), r.get("load_1min_after")) if x is not None]
    if loads:
        cpus = records[0].get("machine", {}).get("cpus")
        order = " (the public code and jtraj ran one after the other)" if with_peer else ""
        lines.append(f"\nMachine: {cpus} CPUs, 1-minute load average {min(loads):.1f} to {max(loads):.1f} during these runs{order}.")
    repeats = max((len(x.get("times_s") or [0]) for r in records for x in [*r["variants"], r.get("peer") or {}]), default=1)
    if repeats > 1:
        alternating = ", alternating the public code and jtraj" if with_peer else ""
        lines.append(f"\nTimes: the median of {repeats} runs{alternating}, their range in brackets; the ratio is of the medians.")
    if with_peer:
        lines.append("\nCost and violation: jtraj's objective and largest violation of a constraint or bound (unscaled); the peer's are the final objective and constraint violation in its Ipopt log (Ipopt's scaled values).")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_tasks(ap)
    add_param(ap)
    ap.add_argument("--variants", default="paper,compact,lean")
    ap.add_argument("--ipopt", action="append", default=[], metavar="NAME=VALUE", help="extra Ipopt option for every Ipopt variant")
    ap.add_argument("--jtraj", action="append", default=[], metavar="NAME=VALUE", help="option of jtraj's solver for the jtraj variant (e.g. constr_viol_tol=1e-6)")
    ap.add_argument("--peer", default=str(DEFAULT_PEER) if DEFAULT_PEER.exists() else None, help=f"path of the runner of the public code, run as PEER TASK (default {DEFAULT_PEER} when it exists)")
    ap.add_argument("--no-peer", action="store_true", help="do not run the public code")
    ap.add_argument("--repeat", type=int, default=1, metavar="N", help="measure each side N times (N odd), alternating, and report medians (default 1)")
    ap.add_argument("--robot", action="append", default=[], metavar="ROBOT=OTHER", help="jtraj solves the tasks on ROBOT with the model OTHER (talos=talos_full: the public code's Talos)")
    ap.add_argument("--code-costs", action="store_true", help="jtraj uses the cost weights of the public code's task scripts where they differ from the paper's Table II")
    # checked as it is parsed: a file there failed in write_results after every solve
    add_out(ap, "speed")
    ap.add_argument("--table-only", action="store_true", help="rewrite DIR/speed.md from DIR/speed.json, solve nothing")
    args = ap.parse_args(argv)
    if args.table_only:
        if not args.out:
            ap.error("--table-only needs --out DIR")
        path = Path(args.out) / "speed.json"
        not_records = f"--table-only: {path}: not the records bench/solve.py writes (a list of one object per task, with its variants)"
        try:
            records = jio.read_json(path)
        except jio.FileFormatError as e:  # missing, empty, not JSON
            ap.error(f"--table-only: {e}")
        if not isinstance(records, list) or not all(isinstance(r, dict) for r in records):
            ap.error(not_records)
        try:
            text = markdown(records)
        except (KeyError, TypeError, AttributeError, ValueError, IndexError) as e:  # records of another shape
            ap.error(f"{not_records}: {type(e).__name__}: {e}")
        jio.write_text(Path(args.out) / "speed.md", text)
        return
    if not args.tasks:
        ap.error("give at least one task")
    if args.repeat < 1 or args.repeat % 2 == 0:
        ap.error(f"--repeat: {args.repeat}: expected an odd count (at least 1), so that the median is one of the runs")
    variants = [v for v in args.variants.split(",") if v]
    if not variants:
        ap.error(f"--variants: {args.variants!r}: expected some of {sorted(VARIANTS)}")
    for v in variants:
        if v not in VARIANTS:
            ap.error(f"--variants: {v!r}: expected some of {sorted(VARIANTS)}")
    refuse_repeats(ap, "--variants", variants, "variant")  # each would run twice a round and be tabled twice
    try:  # the command line's own parsing and checks of solver options
        extra = _check_ipopt(args.ipopt, "ipopt")
        extra_jtraj = _check_ipopt(args.jtraj, "jtraj", field="--jtraj")
    except ValueError as err:  # InputError, or Ipopt's catalog's IpoptOptionError
        ap.error(str(err))
    # the timing table is printed at print_level 3 (J_SUMMARY) and up, and only when asked for
    if extra.get("print_timing_statistics", "yes") != "yes":
        ap.error(f"--ipopt print_timing_statistics={extra['print_timing_statistics']}: expected yes (the default here): the linear solver's time is read from Ipopt's timing statistics")
    if extra.get("print_level", 3) < 3:
        ap.error(f"--ipopt print_level={extra['print_level']}: expected 3 or more (the default here is 3): Ipopt prints its timing statistics from level 3")
    try:
        robots = _check_robots(args.robot)
    except InputError as err:
        ap.error(str(err))
    peer = None if args.no_peer else args.peer
    if peer is not None and args.param != "se3":  # its ratio would be of two parameterizations
        ap.error(f"--param {args.param}: the public code solves with the SE(3) tangent only; pass --param se3, or --no-peer for jtraj's rows alone")
    if peer is not None and not (os.path.isfile(peer) and os.access(peer, os.X_OK)):
        ap.error(f"--peer: {peer!r}: expected the path of an executable runner (run as PEER TASK)")
    if peer is None and not args.no_peer:
        print(f"bench/solve.py: no peer: the paper's public code is not at {DEFAULT_PEER}; the table has jtraj's rows only (pass --peer PATH to compare, --no-peer to silence this)", file=sys.stderr, flush=True)
    records = []
    for t, task in enumerate(args.tasks):
        solved = problem(task, robots, args.code_costs)
        rec = dict(
            task=task, robots=robots, code_costs=args.code_costs, param=args.param,
            machine=dict(cpus=os.cpu_count(), load_1min=os.getloadavg()[0], platform=platform.platform()), peer=None, variants=[],
        )
        peer_runs: list[dict] = []
        runs: dict[str, list[dict]] = {name: [] for name in variants}
        for i in range(args.repeat):
            if peer:
                peer_runs.append(run_peer(peer, task))
                print(f"{task}: public code: {peer_runs[-1]['iterations']} iterations, {peer_runs[-1]['time_s']:.2f} s", flush=True)
            if i == 0:
                # the first variant's NLP (the default variables' was compiled whatever the
                # variants, for nothing with --variants paper, and recorded as the compile)
                first = VARIANTS[variants[0]]["variables"]
                t0 = time.perf_counter()
                prep = prepare(solved, args.param, first)
                rec["compile_s"], rec["compile_variables"] = time.perf_counter() - t0, first
                print(f"{task} [{args.param}, {first} variables]: {prep.nlp.n} variables, {prep.nlp.m} constraints; compile {rec['compile_s']:.1f} s", flush=True)
            for name in variants:
                runs[name].append(run_variant(solved, args.param, name, extra, extra_jtraj))
                if args.repeat > 1:
                    print(f"{task} [{name}]: run {i + 1} of {args.repeat}: {runs[name][-1]['iterations']} iterations, {runs[name][-1]['time_s']:.2f} s", flush=True)
        if peer_runs:
            rec["peer"] = _median_of(peer_runs, f"{task}: the public code")
        rec["variants"] = [_median_of(runs[name], f"{task} [{name}]") for name in variants]
        rec["load_1min_after"] = os.getloadavg()[0]
        records.append(rec)
        print(markdown([rec]), flush=True)
        if args.out:
            write_results(args.out, "speed", records, markdown(records), "bench/solve.py", record=results_record("bench/solve.py", argv, complete=t == len(args.tasks) - 1))


if __name__ == "__main__":
    main()
