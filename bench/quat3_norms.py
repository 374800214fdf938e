"""Where Quaternion #3's free direction goes: the norm of rho at every Ipopt iterate.

Quaternion #3 (manifold integration and differences, no norm row) leaves the norm of each
interior knot's rho free: every row and cost normalizes rho, so none changes along it
(`bench/unit_norm.py`). Nothing in the NLP then holds the norm, and a step that rotates a
knot moves it: a step d orthogonal to rho takes the norm to ``sqrt(|rho|^2 + |d|^2)``. As the
norm grows, the rows' derivatives along rho shrink as 1 / |rho| and their curvature as
1 / |rho|^2, so the limited-memory Hessian and the Jacobian the solver sees grow badly scaled;
as it falls, they blow up. This benchmark records every iterate of Ipopt (the study's
settings, its variables) on each task with Quaternion #3, with and without the unit-norm row,
and reports the norms of the interior knots' rho beside Ipopt's own figures::

    python bench/quat3_norms.py [TASK ...] [--no-norm-row-only] [--out DIR]

``--out DIR`` writes ``DIR/quat3_norms.json`` (per solve: the result and, per iteration,
Ipopt's figures and the smallest and largest norm), ``DIR/quat3_norms.md`` (one row per
solve) and ``DIR/provenance.json``. Times include no compile.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

from jtraj.experiments import ALL_TASKS

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/_args.py, also when the tests load this file from its path
from _args import add_out, refuse_repeats  # noqa: E402


def norms_of(tr, x: np.ndarray) -> np.ndarray:
    """The norms of rho at the interior knots of the iterate ``x`` (the end knots' are fixed
    by bounds)."""
    Z = np.asarray(x).reshape(tr.N + 1, tr.layout.nz)
    q = np.asarray(tr.layout.split(Z)["q"])
    return np.linalg.norm(q[1:-1, 3:7], axis=1)


def run(task: str, unit_norm: bool) -> dict:
    """One solve of ``task`` with Quaternion #3 from the task's warm start, every iterate kept."""
    import jtraj
    from jtraj import parameterization, solvers

    chart = dataclasses.replace(parameterization.get("quat3"), unit_norm=unit_norm)
    rec = solvers.RecordIterates()
    res = jtraj.solve(task, chart, variables="paper", progress=rec, keep_trajectory=False)
    tr = jtraj.solver.prepare(task, chart, "paper").transcription
    norms = np.array([norms_of(tr, x) for x in rec.iterates])
    iters = [
        dict(
            iter=int(it.iter), objective=float(it.objective), inf_pr=float(it.inf_pr), inf_du=float(it.inf_du), mu=float(it.mu),
            alpha_pr=float(it.alpha_pr), norm_min=float(n.min()), norm_max=float(n.max()),
        )
        for it, n in zip(rec.iterations, norms)
    ]
    above = np.nonzero(norms.max(axis=1) > 2.0)[0]
    return dict(
        task=task, unit_norm=unit_norm, status=res.status.value, iterations=res.iterations, cost=res.cost,
        constraint_violation=res.constraint_violation, turns=res.turns, time_s=round(res.time_s, 2),
        norm_start=[float(norms[0].min()), float(norms[0].max())], norm_end=[float(norms[-1].min()), float(norms[-1].max())],
        norm_range=[float(norms.min()), float(norms.max())],
        first_iter_above_2=None if above.size == 0 else int(iters[above[0]]["iter"]),
        iterates=iters,
    )


def table(records: list[dict]) -> str:
    """Markdown, one row per solve."""
    lines = [
        "| task | norm row | status | iterations | violation | norms at the start | at the end | over all iterates | first iterate with a norm > 2 |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in records:
        rng = lambda v: f"{v[0]:.3g} to {v[1]:.3g}"  # noqa: E731
        first = "" if r["first_iter_above_2"] is None else str(r["first_iter_above_2"])
        lines.append(
            f"| {r['task']} | {'yes' if r['unit_norm'] else 'no'} | {r['status']} | {r['iterations']} | {r['constraint_violation']:.1e} | "
            f"{rng(r['norm_start'])} | {rng(r['norm_end'])} | {rng(r['norm_range'])} | {first} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("tasks", nargs="*", default=list(ALL_TASKS))
    ap.add_argument("--no-norm-row-only", action="store_true", help="solve only without the unit-norm row (the study's Quaternion #3)")
    add_out(ap, "quat3_norms")
    a = ap.parse_args(argv)
    bad = [t for t in a.tasks if t not in ALL_TASKS]
    if bad:
        ap.error(f"unknown task(s) {bad}; expected some of {list(ALL_TASKS)}")
    refuse_repeats(ap, "tasks", a.tasks, "task")
    records = []
    for task in a.tasks:
        for unit_norm in (False,) if a.no_norm_row_only else (False, True):
            r = run(task, unit_norm)
            records.append(r)
            print(
                f"{task} unit_norm={unit_norm}: {r['status']}, {r['iterations']} iterations, violation {r['constraint_violation']:.1e}, "
                f"|rho| {r['norm_end'][0]:.3g} to {r['norm_end'][1]:.3g} at the end ({r['norm_range'][0]:.3g} to {r['norm_range'][1]:.3g} over all), {r['time_s']:.1f} s",
                flush=True,
            )
    text = table(records)
    print(text, end="")
    if a.out:
        from jtraj.provenance import write_results

        write_results(a.out, "quat3_norms", records, text, "bench/quat3_norms.py", argv)
        print(f"wrote {a.out}/quat3_norms.json, quat3_norms.md, provenance.json")


if __name__ == "__main__":
    main()
