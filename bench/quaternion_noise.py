"""Does renormalizing the noisy quaternions of a warm start change the study's quaternion cells?

The comparative study's footnote 2 says its quaternion implementation "always normalize[s] the
quaternions". jtraj normalizes rho wherever the NLP uses it, and its noise study adds
``sigma * N(0, 1)`` to every entry of the warm start, rho's four included, so a noisy knot's rho
has a norm of about 1.4 at sigma 0.5. This benchmark solves the same draws twice with jtraj's
solver, as the study draws them (`jtraj.experiments.noisy_warm_starts`, seed 0): ``raw`` (the
study's warm starts) and ``unit`` (each knot's rho divided by its norm after the noise), and
prints and writes how many converge and do the task::

    python bench/quaternion_noise.py [--task walk] [--params quat1,quat2] [--sigma 0.5]
        [--draws 20] [--max-iter 200] [--variables paper] [--out DIR]

``--out DIR`` writes ``DIR/quaternion_noise.json`` (one record per solve), ``DIR/quaternion_noise.md`` and
``DIR/provenance.json``. A walk with a quaternion at sigma 0.5 takes 10 to 60 s per draw on
two cores.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

MODES = ("raw", "unit")


def unit_quaternions(starts: np.ndarray, q: slice) -> np.ndarray:
    """``starts`` (..., n_knots, nz) with each knot's rho (``q``'s coordinates 3:7) divided by
    its norm; a copy, every other entry unchanged."""
    out = np.array(starts, float)
    rho = out[..., q][..., 3:7]
    out[..., q.start + 3 : q.start + 7] = rho / np.linalg.norm(rho, axis=-1, keepdims=True)
    return out


def run(task: str, param: str, sigma: float, draws: int, max_iter: int, variables: str) -> list[dict]:
    """Both modes' solves of ``draws`` draws; one record per solve."""
    from jtraj import solvers
    from jtraj.experiments import noisy_warm_starts
    from jtraj.solver import evaluate, prepare

    prep = prepare(task, param, variables)
    tr, nlp = prep.transcription, prep.nlp
    if not tr.param.name.startswith("quat"):
        raise SystemExit(f"{param}: not a quaternion parameterization")
    x0 = tr.warm_start()
    q = tr.layout.slice("q")
    if not np.allclose(np.linalg.norm(x0[:, q][:, 3:7], axis=1), 1.0):
        raise SystemExit(f"{param}: the warm start's q[3:7] is not a unit quaternion")
    noisy = np.asarray(noisy_warm_starts(x0, [sigma], draws, 0)[0])
    backend = solvers.get("jtraj")
    theta = tr.resolve_theta(None)
    opts = backend.options({"max_iter": max_iter})
    records = []
    for mode in MODES:
        starts = noisy if mode == "raw" else unit_quaternions(noisy, q)
        solutions, total, compile_time = backend.solve_batch(nlp, starts, theta, opts)
        for r, sol in enumerate(solutions):
            res = evaluate(tr, sol, tr.decode(sol.x, theta), 0.0, {}, nlp.nnz_jac, None, theta, backend.name)
            records.append(dict(task=task, parameterization=param, mode=mode, sigma=sigma, replicate=r, status=res.status.value, converged=res.converged, success=res.success, iterations=res.iterations, constraint_violation=res.constraint_violation))
        done = [x for x in records if x["mode"] == mode]
        print(f"{task} {param} {mode}: {sum(x['converged'] for x in done)}/{draws} converged, {sum(x['success'] for x in done)} did the task ({total:.0f} s, compile {compile_time:.0f} s)", flush=True)
    return records


def table(records: list[dict]) -> str:
    """Markdown: per (parameterization, mode), converged and task-done counts, and the draws on
    which the two modes end differently."""
    lines = ["| parameterization | warm start's rho | converged | did the task | iterations of the converged (median) |", "|---|---|---|---|---|"]
    for param in dict.fromkeys(r["parameterization"] for r in records):
        for mode in MODES:
            rows = [r for r in records if r["parameterization"] == param and r["mode"] == mode]
            its = [r["iterations"] for r in rows if r["converged"]]
            median = f"{np.median(its):.0f}" if its else "-"
            lines.append(f"| {param} | {mode} | {sum(r['converged'] for r in rows)} / {len(rows)} | {sum(r['success'] for r in rows)} / {len(rows)} | {median} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="walk")
    ap.add_argument("--params", default="quat1,quat2")
    ap.add_argument("--sigma", type=float, default=0.5)
    ap.add_argument("--draws", type=int, default=20)
    ap.add_argument("--max-iter", type=int, default=200)
    ap.add_argument("--variables", default="paper")
    ap.add_argument("--out", type=Path)
    a = ap.parse_args(argv)
    records = []
    for param in a.params.split(","):
        records += run(a.task, param, a.sigma, a.draws, a.max_iter, a.variables)
    text = table(records)
    print(text, end="")
    if a.out is not None:
        from jtraj.provenance import write_results

        write_results(a.out, "quaternion_noise", records, text, "bench/quaternion_noise.py", argv)
        print(f"wrote {a.out}/quaternion_noise.json, quaternion_noise.md, provenance.json")


if __name__ == "__main__":
    main()
