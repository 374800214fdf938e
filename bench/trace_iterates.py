"""Where the study's public code and jtraj part: the base motion at every Ipopt iterate.

    python bench/trace_iterates.py backflip [--variables paper] [--code-costs]
        [--set FIELD=VALUE ...] [--robot g1=OTHER] [--peer-src DIR] [--peer-python PATH] [--no-peer] [--out DIR]

Both codes run Ipopt with the study's settings from the same warm start. At every iteration
the iterate's base poses are decoded and checked as the task check does (`jtraj.success`):
the accumulated rotation about the task's flip axis (turns), the whole rotation (total turns)
and the share of it off the flip axis, beside Ipopt's objective, primal and dual
infeasibility, barrier parameter and step. The public code runs in its own environment (the
one its runner ``run-se3-trajopt`` creates on first use; ``--peer-python``), with a driver
that records cyipopt's current iterate in the code's ``intermediate`` callback and decodes
its SE(3)-tangent base variables with pinocchio's ``exp6``; the code itself is not changed.
jtraj records its iterates with `jtraj.solvers.RecordIterates`.

Writes ``OUT/iterates.json`` (per iteration: the Ipopt figures and the task-check values, no
trajectories), ``OUT/iterates.md`` (the two tables) and ``OUT/provenance.json``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import jtraj
from jtraj import solvers, success
from jtraj.cli import InputError, _check_robots, _load_valid_task
from jtraj.provenance import write_results
from jtraj.solver import with_changes
from jtraj.task import TaskError

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from _args import DEFAULT_PEER, add_out, add_peer_options, add_variables  # noqa: E402
from side_by_side import (  # noqa: E402  (the same task variants and the same driver of the public code)
    CODE_COSTS,
    DEFAULT_PEER_PYTHON,
    PEER_SCRIPTS,
    check_peer_paths,
    jtraj_label,
    jtraj_task,
    parse_changes,
    peer_iterates,
)


def rows_of(stats: np.ndarray, base: np.ndarray, flip_axis, flip_turns) -> list[dict]:
    """One row per iterate: Ipopt's figures and the task check of its base motion."""
    rows = []
    for (it, obj, inf_pr, inf_du, mu, alpha_pr), b in zip(stats, base):
        check = success.evaluate(b, flip_axis, flip_turns)
        rows.append(
            dict(
                iter=int(it),
                objective=float(obj),
                inf_pr=float(inf_pr),
                inf_du=float(inf_du),
                mu=float(mu),
                alpha_pr=float(alpha_pr),
                turns=check.turns,
                total_turns=check.total_turns,
                off_axis_share=check.off_axis_share,
                base_z_max=float(np.max(b[:, 2])),
            )
        )
    return rows


def run_peer(task: str, peer_src: Path, peer_python: Path, flip_axis, flip_turns) -> dict:
    d = peer_iterates(task, peer_src, peer_python)
    return dict(code="paper's code", knots=int(d["base"].shape[1]), rows=rows_of(d["stats"], d["base"], flip_axis, flip_turns))


def run_jtraj(task_name: str, variables: str, robots: dict[str, str], code_costs: bool, changes: dict[str, str] | None = None) -> dict:
    """jtraj's run; ``changes`` replace fields of the named variables' `TranscriptionOptions`."""
    task = jtraj_task(task_name, robots, code_costs)
    options = with_changes(variables, changes)
    rec = solvers.RecordIterates()
    res = jtraj.solve(task, "se3", variables=options, progress=rec, keep_trajectory=False)
    tr = jtraj.solver.prepare(task, "se3", options).transcription
    theta = tr.resolve_theta(None)
    base = np.array([tr.decode(x, theta).base_xyz_wxyz for x in rec.iterates])
    stats = np.array([[it.iter, it.objective, it.inf_pr, it.inf_du, it.mu, it.alpha_pr] for it in rec.iterations])
    label = jtraj_label(variables, robots, code_costs, changes)
    return dict(code=label, knots=int(base.shape[1]), status=res.status.value, rows=rows_of(stats, base, task.flip_axis, task.flip_turns))


def render(runs: list[dict]) -> str:
    out = []
    for run in runs:
        out += [
            f"**{run['code']}** ({run['knots']} knots)",
            "",
            "| iter | objective | inf_pr | inf_du | lg(mu) | alpha_pr | turns | total turns | off-axis share | max base z |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        for r in run["rows"]:
            turns = "" if r["turns"] is None else f"{r['turns']:.3f}"
            share = "" if r["off_axis_share"] is None else f"{r['off_axis_share']:.3f}"
            out.append(
                f"| {r['iter']} | {r['objective']:.4g} | {r['inf_pr']:.2e} | {r['inf_du']:.2e} | {np.log10(r['mu']):.2f} | {r['alpha_pr']:.2e} | {turns} | {r['total_turns']:.3f} | {share} | {r['base_z_max']:.3f} |"
            )
        out.append("")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("task", choices=sorted(PEER_SCRIPTS))
    add_variables(ap, "paper")
    ap.add_argument("--code-costs", action="store_true", help=f"jtraj with the cost weights of the code's scripts ({CODE_COSTS})")
    add_peer_options(ap, DEFAULT_PEER_PYTHON, f"the folder se3_trajopt/src beside the runner, {DEFAULT_PEER}")
    ap.add_argument("--no-peer", action="store_true")
    add_out(ap, "iterates")
    args = ap.parse_args(argv)
    # every input is checked before the public code or jtraj solves
    try:
        robots = _check_robots(args.robot)
        if robots:
            _load_valid_task(args.task, robots, all_used=True)  # the task on the other robot passes its checks
    except (InputError, TaskError) as e:
        ap.error(str(e))
    changes = parse_changes(ap, args.set, args.variables)
    if not args.no_peer:
        check_peer_paths(ap, args, DEFAULT_PEER, "pass --peer-python, or --no-peer")
    task = jtraj_task(args.task, robots, args.code_costs)
    runs = []
    if not args.no_peer:
        try:
            runs.append(run_peer(args.task, args.peer_src, args.peer_python, task.flip_axis, task.flip_turns))
        except RuntimeError as e:
            raise SystemExit(f"bench/trace_iterates.py: {e}") from None
    runs.append(run_jtraj(args.task, args.variables, robots, args.code_costs, changes))
    text = render(runs)
    print(text)
    if args.out:
        write_results(args.out, "iterates", {"task": args.task, "runs": runs}, text, "bench/trace_iterates.py", argv)


if __name__ == "__main__":
    main()
