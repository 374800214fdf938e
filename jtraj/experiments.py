"""The comparative study's experiments: Table IV (every task with every parameterization) and the
noise-robustness study (Table III, Fig. 2).

Warm starts of the robustness study are drawn for all replicates and noise levels at once with
`jax.vmap` over PRNG keys; each replicate is then an independent Ipopt solve of the same
compiled NLP (one compile per task and parameterization). Results are written as JSON and
Markdown tables and a figure.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TextIO

import jax
import jax.numpy as jnp
import numpy as np

from jtraj.parameterization import PARAMETERIZATIONS
from jtraj.task import Task, load as load_task
from jtraj.solver import prepare, solve

__all__ = ["compare", "robustness", "noisy_warm_starts", "TABLE_IV_PAPER_SE3"]

#: Iterations of the SE(3) tangent parameterization in the paper's Table IV.
TABLE_IV_PAPER_SE3 = {"walk": 14, "hopscotch": 10, "big_jump": 11, "handstand": 88, "backflip": 28, "sideflip": 29}
ALL_TASKS = ("walk", "hopscotch", "big_jump", "handstand", "backflip", "sideflip")
ROBUSTNESS_TASKS = ("walk", "big_jump", "backflip", "sideflip")
ROBUSTNESS_PARAMS = ("euler", "quat1", "quat2", "se3")
SIGMAS = (1e-6, 1e-3, 0.1, 0.5)

_ROW_KEYS = ("task", "parameterization", "status", "converged", "success", "turns", "iterations", "obj_evals", "grad_evals", "con_evals", "jac_evals", "cost", "constraint_violation", "time_s", "time_compile")


def _row(result) -> dict:
    row = {k: getattr(result, k) for k in _ROW_KEYS}
    row["status"] = result.status.value
    return row


def compare(
    tasks: Sequence[str | Task] = ALL_TASKS,
    params: Sequence[str] = tuple(PARAMETERIZATIONS),
    out: str | Path = "runs/table_iv",
    layout: str = "paper",
    exact_hessian: bool = False,
    progress: TextIO | None = sys.stdout,
    save_trajectories: bool = True,
) -> list[dict]:
    """Table IV: solve every task with every parameterization; write table_iv.{json,md}."""
    out = Path(out)
    rows = []
    for task in tasks:
        name = task if isinstance(task, str) else task.name
        for p in params:
            r = solve(task, p, layout=layout, exact_hessian=exact_hessian, progress=progress, progress_every=10, out=out / f"{name}_{p}" if save_trajectories else None)
            rows.append(_row(r))
            _write_table_iv(rows, out)
    return rows


def _write_table_iv(rows: list[dict], out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "table_iv.json").write_text(json.dumps(rows, indent=2))
    lines = [
        "| task | parameterization | status | iterations (paper, SE(3)) | obj evals | jac evals | cost | violation | turns | time (s) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        paper = TABLE_IV_PAPER_SE3.get(r["task"]) if r["parameterization"] == "se3" else None
        turns = "" if r["turns"] is None else f"{r['turns']:+.2f}"
        lines.append(
            f"| {r['task']} | {r['parameterization']} | {r['status']} | {r['iterations']}"
            + (f" ({paper})" if paper else "")
            + f" | {r['obj_evals']} | {r['jac_evals']} | {r['cost']:.3g} | {r['constraint_violation']:.1e} | {turns} | {r['time_s']:.1f} |"
        )
    (out / "table_iv.md").write_text("\n".join(lines) + "\n")


def noisy_warm_starts(x0: np.ndarray, sigmas: Sequence[float], replicates: int, seed: int = 0) -> np.ndarray:
    """Warm starts plus zero-mean Gaussian noise, (len(sigmas), replicates, *x0.shape), drawn
    with one vmapped call over PRNG keys."""
    keys = jax.random.split(jax.random.PRNGKey(seed), len(sigmas) * replicates).reshape(len(sigmas), replicates, -1)
    base = jnp.asarray(x0)

    def one(key, sigma):
        return base + sigma * jax.random.normal(key, base.shape, base.dtype)

    draw = jax.vmap(jax.vmap(one, in_axes=(0, None)), in_axes=(0, 0))
    return np.asarray(draw(keys, jnp.asarray(sigmas, base.dtype)))


def _robustness_group(task, p, sigmas, replicates, seed, layout, exact_hessian, done, progress=None, on_sigma=None) -> list[dict]:
    """One (task, parameterization) of the study: one compile, then every noisy replicate not in
    ``done``. ``on_sigma(rows)`` is called after each noise level (checkpoints)."""
    prep = prepare(task, p, layout)
    name = prep.transcription.task.name
    starts = noisy_warm_starts(prep.transcription.warm_start(), sigmas, replicates, seed)
    rows = []
    for si, sigma in enumerate(sigmas):
        new = []
        for r in range(replicates):
            if (name, p, float(sigma), r) in done:
                continue
            res = solve(task, p, layout=layout, warm_start=starts[si, r], exact_hessian=exact_hessian, progress=None, keep_trajectory=False)
            new.append(_row(res) | {"sigma": float(sigma), "replicate": r, "seed": seed, "layout": layout})
            if progress is not None:
                print(f"{name:10s} {p:6s} sigma={sigma:<7g} #{r}: {res.status.value:26s} {res.iterations:4d} it  {res.time_s:6.1f} s", file=progress, flush=True)
        rows += new
        if on_sigma is not None:
            on_sigma(new)
    return rows


def _robustness_group_in_worker(*args, verbose: bool) -> list[dict]:
    # a stream does not cross processes: a worker prints to its own stdout
    return _robustness_group(*args, progress=sys.stdout if verbose else None)


def robustness(
    tasks: Sequence[str | Task] = ROBUSTNESS_TASKS,
    params: Sequence[str] = ROBUSTNESS_PARAMS,
    sigmas: Sequence[float] = SIGMAS,
    replicates: int = 10,
    seed: int = 0,
    out: str | Path = "runs/robustness",
    layout: str = "paper",
    exact_hessian: bool = False,
    progress: TextIO | None = sys.stdout,
    workers: int = 1,
    resume: bool = True,
) -> list[dict]:
    """Table III and Fig. 2: success rate and iterations under warm-start noise.

    Success follows the paper's Table III: the solve converged to a feasible point; rows
    also count how many of those converged without doing the task (e.g. no flip: the
    paper's asterisk).

    ``workers > 1`` solves (task, parameterization) groups in that many processes. With
    ``resume`` (default), runs already in ``out/runs.json`` with the same seed and layout are
    kept and not solved again, so a stopped study goes on where it ended.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    runs: list[dict] = []
    if resume and (out / "runs.json").exists():
        old = json.loads((out / "runs.json").read_text())
        runs = [r for r in old if r.get("seed") == seed and r.get("layout") == layout]
        if progress is not None and runs:
            print(f"resuming: {len(runs)} runs already in {out / 'runs.json'}", file=progress, flush=True)
    done = {(r["task"], r["parameterization"], r["sigma"], r["replicate"]) for r in runs}
    groups = [(task, p) for task in tasks for p in params]

    def checkpoint(rows: list[dict]) -> None:
        runs.extend(rows)
        (out / "runs.json").write_text(json.dumps(runs, indent=2))

    def write_tables() -> None:
        # after every (task, parameterization): a long study can be stopped
        summary = summarize_robustness(runs)
        (out / "table_iii.json").write_text(json.dumps(summary, indent=2))
        (out / "table_iii.md").write_text(_table_iii_markdown(summary, sigmas))

    def complete(task, p) -> bool:
        name = load_task(task).name
        return all((name, p, float(s), r) in done for s in sigmas for r in range(replicates))

    # groups already complete are not compiled again
    args = [(task, p, tuple(sigmas), replicates, seed, layout, exact_hessian, done) for task, p in groups if not complete(task, p)]
    if workers <= 1:
        for a in args:
            _robustness_group(*a, progress=progress, on_sigma=checkpoint)
            write_tables()
    else:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor, as_completed

        # JAX is not fork-safe: workers start fresh interpreters
        with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn")) as pool:
            futures = [pool.submit(_robustness_group_in_worker, *a, verbose=progress is not None) for a in args]
            for f in as_completed(futures):
                checkpoint(f.result())
                write_tables()
    if not runs:
        raise ValueError("robustness: no runs (empty tasks, parameterizations or sigmas)")
    if not args:
        write_tables()  # every run was already there: the tables all the same
    plot_iterations(runs, out / "fig2.png")
    return runs


def summarize_robustness(runs: list[dict]) -> list[dict]:
    # the paper's order: tasks as in Table III, parameterizations as in Table I, then others
    task_rank = {t: i for i, t in enumerate(("walk", "big_jump", "backflip", "sideflip", "hopscotch", "handstand"))}
    param_rank = {p: i for i, p in enumerate(PARAMETERIZATIONS)}
    keys = sorted(
        {(r["task"], r["parameterization"], r["sigma"]) for r in runs},
        key=lambda k: (task_rank.get(k[0], len(task_rank)), k[0], param_rank.get(k[1], len(param_rank)), k[1], k[2]),
    )
    rows = []
    for task, p, sigma in keys:
        sel = [r for r in runs if (r["task"], r["parameterization"], r["sigma"]) == (task, p, sigma)]
        conv = [r for r in sel if r["converged"]]
        its = np.array([r["iterations"] for r in conv]) if conv else np.array([])
        rows.append(
            dict(
                task=task,
                parameterization=p,
                sigma=sigma,
                runs=len(sel),
                success_rate=len(conv) / len(sel),
                task_success_rate=sum(r["success"] for r in sel) / len(sel),
                converged_without_task=sum(1 for r in conv if not r["success"]),
                iterations_median=float(np.median(its)) if its.size else None,
                iterations_p25=float(np.percentile(its, 25)) if its.size else None,
                iterations_p75=float(np.percentile(its, 75)) if its.size else None,
            )
        )
    return rows


def _table_iii_markdown(summary: list[dict], sigmas: Sequence[float]) -> str:
    lines = ["| task | parameterization | " + " | ".join(f"sigma={s:g}" for s in sigmas) + " |", "|---|---|" + "---|" * len(sigmas)]
    for task in dict.fromkeys(r["task"] for r in summary):
        for p in dict.fromkeys(r["parameterization"] for r in summary if r["task"] == task):
            cells = []
            for s in sigmas:
                match = [r for r in summary if r["task"] == task and r["parameterization"] == p and r["sigma"] == s]
                if not match:
                    cells.append("")
                    continue
                r = match[0]
                star = "*" if r["converged_without_task"] else ""
                cells.append(f"{100 * r['success_rate']:.0f}%{star}")
            lines.append(f"| {task} | {p} | " + " | ".join(cells) + " |")
    lines.append("\n\\* some runs converged without doing the task (e.g. a jump instead of a flip).")
    return "\n".join(lines) + "\n"


def plot_iterations(runs: list[dict], path: str | Path) -> None:
    """Fig. 2: iterations to convergence against noise (median, 25-75th percentiles)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    summary = summarize_robustness(runs)
    tasks = list(dict.fromkeys(r["task"] for r in summary))
    fig, axes = plt.subplots(1, len(tasks), figsize=(4 * len(tasks), 3.4), squeeze=False)
    for ax, task in zip(axes[0], tasks):
        for p in dict.fromkeys(r["parameterization"] for r in summary if r["task"] == task):
            rows = [r for r in summary if r["task"] == task and r["parameterization"] == p and r["iterations_median"] is not None]
            if not rows:
                continue
            s = np.array([r["sigma"] for r in rows])
            med = np.array([r["iterations_median"] for r in rows])
            ax.plot(s, med, marker="o", label=PARAMETERIZATIONS[p].label)
            ax.fill_between(s, [r["iterations_p25"] for r in rows], [r["iterations_p75"] for r in rows], alpha=0.2)
        ax.set_xscale("log")
        ax.set_title(task)
        ax.set_xlabel("warm-start noise sigma")
        ax.set_ylabel("iterations to convergence")
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
