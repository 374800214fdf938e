"""Iterations of the study's public code and of jtraj on the same tasks, one after the other.

    python bench/side_by_side.py --out results/side_by_side [--tasks walk,big_jump,...]
        [--variables paper] [--peer ../shared/peers/run-se3-trajopt] [--sigma 0.5 --seeds 0,1,2]
        [--robot talos=talos_full] [--code-costs] [--set FIELD=VALUE ...]

For every task (and noise draw): the paper's code (SE(3) tangent, its own settings, through its
runner script, which prints one JSON line), then ``jtraj.solve(task, "se3", variables=...)`` for
each choice of variables. Iterations are what is compared: on a shared machine the times are noisy. Writes
``DIR/side_by_side.json`` (one row per solve), ``DIR/side_by_side.md`` (the table the README
quotes) and ``DIR/provenance.json``. Rows already in the JSON are kept (resume), except the
solves that failed (rows with status ``error``) and the paper code's rows of another runner
or other sources (each names its runner's path, ``runner``, and a noisy flip's the sources it
ran, ``peer_src``; a row without them is from before the fields): they run again, and the new
row replaces the old. The exit status is nonzero when a solve failed.

The noise of the paper's runner is numpy's ``default_rng(seed)`` on its own variable vector,
jtraj's is ``numpy default_rng(seed)`` on jtraj's: same distribution, not the same draws (the
two codes order and size their variables differently). A noisy draw of a flip runs the code
through a driver (`PEER_DRIVER`, the code itself unchanged, its runner's noise) that keeps its
iterates, so that jtraj's task check (`jtraj.success`) reads the code's last one as it reads
jtraj's: the cell then counts the converged draws that did the task ("task done").

``--robot talos=talos_full`` solves jtraj's side on the study's Talos model (`robots/talos_full.toml`)
and ``--code-costs`` with the cost weights of the code's task scripts where they differ from the
paper's Table II (`CODE_COSTS`); both show in the jtraj column's name, as do ``--set``'s
changes to the variables (``--set force_limits=rows --set contact_height=row``: the code's rows).
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import dataclasses
import functools
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

import jtraj
from jtraj import io, success
from jtraj.cli import InputError, _check_names, _check_robots, _load_valid_task
from jtraj.provenance import FolderInUseError, begin_run, end_run, holding
from jtraj.provenance import source as provenance_source
from jtraj.solver import VARIABLES, with_changes
from jtraj.task import Task, TaskError, available, retarget
from jtraj.task import load as load_task

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/_args.py, also when the tests load this file from its path
from _args import DEFAULT_PEER, add_out, add_peer_options  # noqa: E402

#: Iterations of the SE(3) tangent parameterization in the paper's Table IV.
PAPER_TABLE_IV = {"walk": 14, "hopscotch": 10, "big_jump": 11, "handstand": 88, "backflip": 28, "sideflip": 29}
TASKS = ("walk", "hopscotch", "big_jump", "handstand", "backflip", "sideflip")
#: Cost weights of the public code's task scripts that differ from the paper's Table II:
#: ``walk.py`` adds a configuration cost of 1e-6 (Table II: none), ``humanoid_flip.py`` weighs
#: the back-flip's configuration cost 1e-6 (Table II: 1e-9).
CODE_COSTS = {"walk": {"configuration_weight": 1e-6}, "backflip": {"configuration_weight": 1e-6}}


@functools.cache
def builtin_task(name: str) -> Task:
    """The built-in task ``name`` (a frozen dataclass), parsed once: the table's cells and the
    peer's checks look up its flip axis and turns row by row."""
    return load_task(name)


def peer_sources(runner: Path | str) -> Path:
    """The public code's sources, where its runner keeps them: ``se3_trajopt/src`` beside the
    runner script (`--peer-src`'s default, from the runner the command names)."""
    return Path(os.path.abspath(runner)).parent / "se3_trajopt" / "src"  # beside the path, as the runner looks (links not followed)


def check_peer_paths(ap: argparse.ArgumentParser, args: argparse.Namespace, runner: Path | str, remedy: str) -> None:
    """The public code's paths (`add_peer_options`), checked before anything runs: its
    environment's Python must exist (``remedy`` says what else the user can do) and its
    sources (``--peer-src``, default beside ``runner``) must hold its task scripts. Both are
    made absolute in ``args``: the code runs in a folder of its own."""
    if not args.peer_python.exists():
        ap.error(f"--peer-python: '{args.peer_python}' does not exist: run the public code's runner once (it creates its environment), {remedy}")
    args.peer_src = Path(os.path.abspath(args.peer_src or peer_sources(runner)))
    args.peer_python = Path(os.path.abspath(args.peer_python))
    if not (args.peer_src / "examples" / "agile_exps").is_dir():
        ap.error(f"--peer-src: '{args.peer_src}' does not hold the public code's examples/agile_exps: pass the folder of its sources")


#: The environment the public code's runner creates on first use.
DEFAULT_PEER_PYTHON = Path(os.environ.get("SE3_TRAJOPT_VENV", Path(tempfile.gettempdir()) / "se3-trajopt-venv")) / "bin" / "python"
#: The public code's script of each task (as its runner maps them).
PEER_SCRIPTS = {"big_jump": "humanoid_jump", "backflip": "humanoid_flip", "sideflip": "quad_sideflip", "walk": "walk", "hopscotch": "hopscotch", "handstand": "handstand"}

# Run inside the public code's environment: argv = script, output .npz. Records cyipopt's
# current iterate at every iteration of the code's own `intermediate` callback, and the base
# pose of every knot (its SE(3)-tangent q[:6] through pinocchio's exp6, quaternion wxyz).
PEER_DRIVER = r"""
import runpy, sys
script, out = sys.argv[1], sys.argv[2]
sys.argv = [script]  # the code parses the command line when its modules are imported
import numpy as np
import cyipopt
import pinocchio as pin
from nltrajopt.trajectory_optimization import NLTrajOpt

held, xs, stats, nodes = {}, [], [], []

class Problem(cyipopt.Problem):
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        held["problem"] = self

cyipopt.Problem = Problem
code_intermediate = NLTrajOpt.intermediate

def intermediate(self, alg_mod, iter_count, obj_value, inf_pr, inf_du, mu, d_norm, reg, alpha_du, alpha_pr, ls):
    xs.append(np.array(held["problem"].get_current_iterate(scaled=False)["x"]))
    stats.append([iter_count, obj_value, inf_pr, inf_du, mu, alpha_pr])
    nodes[:] = [(n.q_id.start, n.q_id.stop) for n in self.nodes]
    return code_intermediate(self, alg_mod, iter_count, obj_value, inf_pr, inf_du, mu, d_norm, reg, alpha_du, alpha_pr, ls)

NLTrajOpt.intermediate = intermediate
runpy.run_path(script, run_name="__main__")
base = []
for x in xs:
    poses = []
    for a, b in nodes:
        T = pin.exp6(pin.Motion(x[a:a + 6]))
        q = pin.Quaternion(T.rotation)
        poses.append(np.r_[T.translation, q.w, q.x, q.y, q.z])
    base.append(poses)
np.savez(out, stats=np.array(stats), base=np.array(base))
"""


class PeerError(RuntimeError):
    """The public code failed (`peer_iterates`): its message says how, in the code's words."""


def peer_iterates(task: str, peer_src: Path, peer_python: Path = DEFAULT_PEER_PYTHON, sigma: float = 0.0, seed: int = 0) -> dict:
    """The public code's solve of ``task`` through `PEER_DRIVER`, with its runner's noise on
    the warm start (``sigma``, ``seed``; the code reads them from the environment as its
    runner sets them). Returns ``stats`` (iterations, 6), ``base`` (iterations, knots, 7) and
    ``peerstats``, the code's own line of Ipopt statistics (iterations, time, status); a
    `PeerError` where the code failed or printed no such line."""
    if not peer_python.exists():
        raise FileNotFoundError(f"{peer_python} does not exist: run the public code's runner once (it creates its environment), or pass --peer-python")
    script = peer_src / "examples" / "agile_exps" / f"{PEER_SCRIPTS[task]}.py"
    env = os.environ | {"PYTHONPATH": str(peer_src), "SE3_TRAJOPT_NOISE_SIGMA": repr(float(sigma)), "SE3_TRAJOPT_NOISE_SEED": str(int(seed))}
    with tempfile.TemporaryDirectory() as work:
        out = Path(work) / "iterates.npz"
        driver = Path(work) / "driver.py"
        driver.write_text(PEER_DRIVER)
        run = subprocess.run([str(peer_python), str(driver), str(script), str(out)], cwd=work, env=env, capture_output=True, text=True)
        if run.returncode != 0:
            raise PeerError(f"the public code failed on {task}: {run.stderr[-800:]}")
        line = next((line for line in run.stdout.splitlines() if line.startswith("PEERSTATS")), None)
        if line is None:
            raise PeerError(f"the public code printed no PEERSTATS line on {task}: {run.stdout[-800:]}")
        d = np.load(out)
        return dict(stats=d["stats"], base=d["base"], peerstats=ast.literal_eval(line[len("PEERSTATS") :].strip()))


def run_peer_checked(task: str, sigma: float, seed: int, peer_src: Path, peer_python: Path = DEFAULT_PEER_PYTHON) -> dict:
    """One solve of the paper's code through `peer_iterates`, its last iterate's base motion
    put through jtraj's task check (`jtraj.success`): the row `run_peer` gives, with ``turns``,
    ``off_axis_share`` and ``task_ok``; where the code failed, `peer_iterates`'s `PeerError`,
    which main() makes an ``error`` row (`_error_text`), as it does any solve that raised."""
    problem = builtin_task(task)
    d = peer_iterates(task, peer_src, peer_python, sigma, seed)
    check = success.evaluate(d["base"][-1], problem.flip_axis, problem.flip_turns)
    st = d["peerstats"]
    return dict(
        code="paper",
        task=task,
        sigma=sigma,
        seed=seed,
        status=int(st["status"]),
        converged=int(st["status"]) in (0, 1),
        iterations=int(st["iter"]),
        cost=float(d["stats"][-1][1]),
        time_s=round(float(st["time"]), 3),
        turns=check.turns,
        off_axis_share=check.off_axis_share,
        task_ok=bool(check.ok),
    )


def _error_text(e: Exception) -> str:
    """The ``error`` of the row of a solve that raised ``e``, its last 500 characters: the
    public code's failure in its words (`PeerError`), anything else after its type's name."""
    return (str(e) if isinstance(e, PeerError) else f"{type(e).__name__}: {e}")[-500:]


def _error_row(task: str, sigma: float, seed: int, error: str, code: str = "paper") -> dict:
    """The row of a failed solve of the paper's code, or of a jtraj solve that raised (``code``
    its column); not done: a later run solves it again."""
    return dict(code=code, task=task, sigma=sigma, seed=seed, status="error", converged=False, iterations=None, error=error)


def run_peer(peer: Path, task: str, sigma: float, seed: int) -> dict:
    """One solve of the paper's code: its runner's JSON line as a row; an ``error`` row where
    the runner failed, and a one-line SystemExit where its last line is not its JSON record."""
    if not peer.exists():
        raise FileNotFoundError(f"the paper code's runner {peer} does not exist: pass --peer PATH, or --peer '' to skip it")
    cmd = [str(peer), task] + (["--sigma", repr(sigma), "--seed", str(seed)] if sigma else [])
    out = subprocess.run(cmd, capture_output=True, text=True)
    if out.returncode != 0:
        return _error_row(task, sigma, seed, out.stderr[-500:])
    last = (out.stdout.strip().splitlines() or [""])[-1]
    try:
        d = json.loads(last)
        status, iterations = int(d["status"]), int(d["iterations"])
    except (ValueError, KeyError, TypeError):  # not JSON (a ValueError), not an object, no such key, not a number
        raise SystemExit(f"bench/side_by_side.py: the paper code's runner {peer} {task} printed {last[:200]!r}; expected a JSON line with status and iterations") from None
    # Ipopt's status 0 (solved) and 1 (solved to acceptable level) count as converged
    return dict(code="paper", task=task, sigma=sigma, seed=seed, status=status, converged=status in (0, 1), iterations=iterations, cost=d.get("obj"), time_s=d.get("time_s"))


def jtraj_task(name: str, robots: dict[str, str], code_costs: bool) -> Task:
    """The task jtraj solves: the built-in one, on the robot ``robots`` maps its robot to, with
    the code's cost weights if ``code_costs``."""
    task = retarget(builtin_task(name), robots)
    return dataclasses.replace(task, **CODE_COSTS.get(name, {})) if code_costs else task


def jtraj_label(variables: str, robots: dict[str, str], code_costs: bool, changes: dict[str, str] | None = None) -> str:
    """The jtraj column: ``jtraj paper``, ``jtraj paper, talos_full, code's costs``, then the
    ``--set`` changes (``..., force_limits=rows``)."""
    return ", ".join([f"jtraj {variables}", *robots.values(), *(["code's costs"] if code_costs else []), *(f"{k}={v}" for k, v in (changes or {}).items())])


def parse_changes(ap: argparse.ArgumentParser, items: list[str], variables: str | list[str]) -> dict[str, str]:
    """``--set FIELD=VALUE`` items as a dict, checked against the options of ``variables`` (a
    name or several: each must take the changes; a parser error otherwise)."""
    changes = {}
    for item in items:
        field, sep, value = item.partition("=")
        if not sep or not field or not value:
            ap.error(f"--set: {item!r}: expected FIELD=VALUE, e.g. force_limits=rows")
        changes[field] = value
    for name in [variables] if isinstance(variables, str) else variables:
        try:
            with_changes(name, changes)
        except ValueError as e:
            ap.error(f"--set: {e}" + (f" (with --variables {name})" if not isinstance(variables, str) else ""))
    return changes


def seed_list(text: str) -> list[int]:
    """argparse ``type=`` of ``--seeds``: comma-separated seeds >= 0."""
    try:
        seeds = [int(s) for s in text.split(",")]
    except ValueError:
        seeds = []
    if not seeds or min(seeds) < 0:
        raise argparse.ArgumentTypeError(f"{text!r}: expected comma-separated seeds >= 0, e.g. 0,1,2")
    return seeds


def noise_level(text: str) -> float:
    """argparse ``type=`` of ``--sigma``: a finite standard deviation >= 0."""
    try:
        sigma = float(text)
    except ValueError:
        sigma = math.nan
    if not (math.isfinite(sigma) and sigma >= 0):
        raise argparse.ArgumentTypeError(f"{text!r}: expected a noise level (standard deviation) >= 0")
    return sigma


def run_jtraj(task: str, variables: str, sigma: float, seed: int, robots: dict[str, str] | None = None, code_costs: bool = False, changes: dict[str, str] | None = None) -> dict:
    """jtraj's solve; ``changes`` replace fields of the named variables' `TranscriptionOptions`
    (e.g. ``force_limits="rows"``) and show in the column's name."""
    problem = jtraj_task(task, robots or {}, code_costs)
    options = with_changes(variables, changes)
    r = jtraj.solve(problem, "se3", variables=options, noise=sigma, seed=seed, progress=None)
    check = success.evaluate(r.trajectory.base_xyz_wxyz, problem.flip_axis, problem.flip_turns)
    return dict(
        code=jtraj_label(variables, robots or {}, code_costs, changes),
        robot=problem.robot,
        configuration_weight=problem.configuration_weight,
        task=task,
        sigma=sigma,
        seed=seed,
        status=r.status.value,
        converged=bool(r.converged),
        iterations=int(r.iterations),
        cost=float(r.cost),
        time_s=round(float(r.time_s), 3),
        turns=r.turns,
        off_axis_share=check.off_axis_share,
        task_ok=bool(check.ok),
    )


def _turned(row: dict) -> bool:
    """The row's motion turns its task's number of turns about the flip axis (within
    `jtraj.success.TURN_TOLERANCE`), however much of its rotation is off that axis."""
    return abs(row["turns"] - builtin_task(row["task"]).flip_turns) <= success.TURN_TOLERANCE


def _cell(rows: list[dict]) -> str:
    """'12' for one converged solve, '50, limit' when it stopped, 'k/n converged, median m' for draws."""
    if not rows:
        return ""
    if len(rows) == 1:
        r = rows[0]
        if r["iterations"] is None:
            return "error"
        if not r["converged"]:
            return f"{r['iterations']}, not conv."
        # jtraj's own check: converged, but no flip (or no landing at the target)
        return f"{r['iterations']}, task failed" if r.get("status") == "converged_but_task_failed" else f"{r['iterations']}"
    conv = sorted(r["iterations"] for r in rows if r["converged"])
    med = f", median {statistics.median(conv):g}" if conv else ""
    # rows with the task check of their last iterate (the flips' draws): how many converged and did the task
    done = ""
    if all("task_ok" in r for r in rows):
        done = f", {sum(bool(r['converged'] and r['task_ok']) for r in rows)} task done"
        if all(r.get("turns") is not None for r in rows):  # a flip: also count the somersaults whatever their twist
            done += f" ({sum(bool(r['converged'] and _turned(r)) for r in rows)} turned)"
    return f"{len(conv)}/{len(rows)} conv.{done}{med}"


def render(rows: list[dict]) -> str:
    """The Markdown table of ``rows``: one line per (task, sigma), one column per code."""
    codes = sorted(dict.fromkeys(r["code"] for r in rows), key=lambda c: c != "paper")  # the paper's code first
    keys = list(dict.fromkeys((r["task"], r["sigma"]) for r in rows))
    lines = ["| task | sigma | paper's Table IV | " + " | ".join("paper's code" if c == "paper" else c for c in codes) + " |", "|---|---|---|" + "---|" * len(codes)]
    for task, sigma in keys:
        cells = [_cell([r for r in rows if (r["task"], r["sigma"], r["code"]) == (task, sigma, c)]) for c in codes]
        paper = str(PAPER_TABLE_IV.get(task, "")) if sigma == 0 else ""
        lines.append(f"| {task} | {sigma:g} | {paper} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tasks", default=",".join(TASKS), help=f"comma-separated built-in tasks (with a peer: some of {','.join(TASKS)})")
    ap.add_argument("--variables", "--layouts", dest="variables", default="paper", help="comma-separated jtraj.solver.VARIABLES names ('' for none; --layouts: the former name)")
    ap.add_argument("--sigma", type=noise_level, default=0.0)
    ap.add_argument("--seeds", type=seed_list, default="0", help="comma-separated seeds of the noise draws (with --sigma > 0)")
    ap.add_argument("--peer", default=str(DEFAULT_PEER), help="path of the paper code's runner script, run as PEER TASK [--sigma S --seed N] ('' to skip it)")
    add_peer_options(ap, DEFAULT_PEER_PYTHON, "the folder se3_trajopt/src beside --peer")
    ap.add_argument("--code-costs", action="store_true", help="jtraj uses the cost weights of the code's task scripts (CODE_COSTS) where they differ from Table II")
    add_out(ap, "side_by_side", default="results/side_by_side")
    args = ap.parse_args(argv)
    # every input is checked before anything is solved
    if args.peer and not (os.path.isfile(args.peer) and os.access(args.peer, os.X_OK)):
        ap.error(f"--peer: {args.peer!r}: expected the path of the paper code's executable runner, or --peer '' to skip it")
    if not args.sigma and args.seeds != [0]:  # without noise one solve is made, seed 0's
        ap.error(f"--seeds: {','.join(map(str, args.seeds))}: seeds of the noise draws; expected --sigma > 0 with them")
    names = [v for v in args.variables.split(",") if v]
    try:
        robots = _check_robots(args.robot)
        tasks = _check_names("--tasks", args.tasks, list(TASKS) if args.peer else available(), "tasks")
        for name in names:
            if name not in VARIABLES:
                raise InputError("--variables", name, f"unknown variables; expected some of {', '.join(VARIABLES)} (comma-separated; '' for none)")
        for task in tasks if robots else []:  # the task on the other robot passes its checks
            _load_valid_task(task, robots)
    except (InputError, TaskError) as e:
        ap.error(str(e))
    changes = parse_changes(ap, args.set, names or "paper")
    if args.peer and args.sigma and any(builtin_task(t).flip_axis is not None for t in tasks):  # noisy flips run the code's sources
        check_peer_paths(ap, args, args.peer, "or pass --peer-python")
    out = Path(args.out)
    # held while it runs (`jtraj.provenance.holding`): two runs into one folder read the same
    # rows and each wrote its own over the other's
    held = contextlib.ExitStack()
    try:
        held.enter_context(holding(out))
    except FolderInUseError as e:
        ap.error(f"--out: {e}")
    with held:
        out.mkdir(parents=True, exist_ok=True)
        path = out / "side_by_side.json"
        try:
            rows = io.read_json(path) if path.exists() else []
        except io.FileFormatError as e:
            ap.error(f"--out: {e}")
        # provenance.json says from the start that a run is writing this folder: a run stopped
        # half-way (Ctrl-C, a crash) left its rows beside the provenance of the run before it
        record = begin_run(out, ["python", "bench/side_by_side.py", *(sys.argv[1:] if argv is None else argv)])
        # a failed solve (an error row) is not done, nor is the paper code's row of another runner
        # (`--peer`): it runs again, and its new row replaces the old
        runner = os.path.abspath(args.peer) if args.peer else None

        def peer_fields(task: str) -> dict:
            """What a paper code's row of ``task`` names of the code that solved it."""
            checked = args.sigma and builtin_task(task).flip_axis is not None
            return dict(runner=runner, **({"peer_src": str(args.peer_src)} if checked else {}))

        # ... nor is a jtraj row of other code: it was reused whatever commit solved it (rows kept
        # no commit), and the table, stamped with this run's provenance, set old iterations beside
        # a new peer run. One solved by this commit, from a clean checkout, is done.
        here = provenance_source()
        ours = here if here is not None and not here.get("dirty") else None

        def resumable(r: dict) -> bool:
            if r["task"] not in tasks or r.get("status") == "error":
                return False
            if r["code"] == "paper":
                return all(r.get(k) == v for k, v in peer_fields(r["task"]).items())
            return ours is not None and r.get("source") == ours

        done = {(r["code"], r["task"], r["sigma"], r["seed"]) for r in rows if resumable(r)}
        failed: list[str] = []
        seeds = args.seeds if args.sigma else [0]
        for task in tasks:
            for seed in seeds:
                # a flip's draw goes through the driver, whose last iterate the task check reads
                peer = (
                    (lambda task=task, seed=seed: run_peer_checked(task, args.sigma, seed, args.peer_src, args.peer_python))
                    if args.sigma and builtin_task(task).flip_axis is not None
                    else (lambda task=task, seed=seed: run_peer(Path(args.peer), task, args.sigma, seed))
                )
                jobs = ([("paper", peer)] if args.peer else []) + [
                    (jtraj_label(lay, robots, args.code_costs, changes), lambda lay=lay, task=task, seed=seed: run_jtraj(task, lay, args.sigma, seed, robots, args.code_costs, changes))
                    for lay in args.variables.split(",")
                    if lay
                ]
                for code, job in jobs:
                    key = (code, task, args.sigma, seed)
                    if key in done:
                        continue
                    try:
                        row = job()
                    except Exception as e:  # a solve that raised (jtraj's, or the public code's through its driver): an error row; the other solves still run
                        row = _error_row(task, args.sigma, seed, _error_text(e), code)
                    if code == "paper":
                        row.update(peer_fields(task))
                    else:
                        row["source"] = here  # the commit (and whether the checkout differed) that solved it
                    print(json.dumps(row), flush=True)
                    old = [i for i, r in enumerate(rows) if (r["code"], r["task"], r["sigma"], r["seed"]) == key]  # a failed one
                    if old:
                        rows[old[0]] = row
                    else:
                        rows.append(row)
                    if row["status"] == "error":
                        failed.append(f"{code} on {task} (sigma {args.sigma:g}, seed {seed})")
                        print(f"bench/side_by_side.py: {failed[-1]} failed: {(row['error'].strip().splitlines() or [''])[-1]}", file=sys.stderr, flush=True)
                    io.write_json(path, rows)
                    io.write_text(out / "side_by_side.md", render(rows))
        io.write_text(out / "side_by_side.md", render(rows))
        end_run(out, record)
    if failed:
        raise SystemExit(f"bench/side_by_side.py: {len(failed)} solve(s) failed, their rows say error in {path}; run again to retry them: {'; '.join(failed)}")


if __name__ == "__main__":
    main()
