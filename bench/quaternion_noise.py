"""Do the study's quaternion cells fail for the chart, or for the size of the noise on the pose?

The comparative study's footnote 2 says its quaternion implementation "always normalize[s] the
quaternions". jtraj normalizes rho wherever the NLP uses it, and its noise study adds
``sigma * N(0, 1)`` to every entry of the warm start, rho's four included, so a noisy knot's rho
has a norm of about 1.4 at sigma 0.5. This benchmark solves the same draws with jtraj's
solver (``--solver ipopt``: Ipopt, one by one, as Table III), as the study draws them (`jtraj.experiments.noisy_warm_starts`, seed 0): ``raw`` (the
study's warm starts) and ``unit`` (each knot's rho divided by its norm after the noise), and
prints and writes how many converge and do the task. A mode named after another chart gives
this chart that chart's own draws (the same seed; `jtraj.experiments.chart_noisy_warm_starts`,
which `jtraj robustness --noise-chart` uses too): ``se3`` puts the noise on ``xi`` in place
of ``(p, rho)`` and writes each knot's noisy pose ``Exp(xi)`` as ``(p, rho)``, every other
variable as the SE(3) draw has it. The two charts then start from the same poses, and only the
chart differs (``--params se3 --modes raw,quat1`` is the converse). Noise of sigma on rho's
four entries turns a pose much further than noise of sigma on xi's three rotation entries;
each mode's row gives the mean angle between the noisy and the noise-free base orientation
over the interior knots::

    python bench/quaternion_noise.py [--task walk] [--params quat1,quat2] [--sigma 0.5]
        [--draws 20] [--first 0] [--modes raw,unit,se3] [--max-iter 200] [--variables paper]
        [--solver jtraj|ipopt] [--out DIR]

``--out DIR`` writes ``DIR/quaternion_noise.json`` (one record per solve), ``DIR/quaternion_noise.md`` and
``DIR/provenance.json``. A walk with a quaternion at sigma 0.5 takes 10 to 60 s per draw on
two cores.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/_args.py, also when the tests load this file from its path
from _args import add_out, add_variables, refuse_repeats  # noqa: E402

#: raw: the chart's own draws; unit: a quaternion chart's draws with each rho normalized; any
#: other parameterization's name: that chart's draws (same seed), its noisy poses written in
#: this chart
MODES = ("raw", "unit", "se3", "quat1", "quat2", "euler")


def unit_quaternions(starts: np.ndarray, q: slice) -> np.ndarray:
    """``starts`` (..., n_knots, nz) with each knot's rho (``q``'s coordinates 3:7) divided by
    its norm; a copy, every other entry unchanged."""
    out = np.array(starts, float)
    rho = out[..., q][..., 3:7]
    out[..., q.start + 3 : q.start + 7] = rho / np.linalg.norm(rho, axis=-1, keepdims=True)
    return out


def rotation_noise(tr, starts: np.ndarray, clean: np.ndarray) -> np.ndarray:
    """Angle (rad) between each start's and the noise-free warm start's base orientation, at
    the interior knots: (n_starts, n_knots - 2)."""
    import jax

    q = tr.layout.slice("q")
    nb = tr.param.nq

    def angle(qn, qc):
        Rn, Rc = tr.param.to_pose(qn).rotation(), tr.param.to_pose(qc).rotation()
        return jax.numpy.linalg.norm((Rc.inverse() @ Rn).log())

    fn = jax.jit(jax.vmap(jax.vmap(angle), in_axes=(0, None)))
    return np.asarray(fn(starts[:, 1:-1, q.start : q.start + nb], clean[1:-1, q.start : q.start + nb]))


def check_modes(task: str, params: list[str], variables: str, modes: tuple[str, ...]) -> None:
    """ValueError, before anything compiles, where `run` cannot solve a (parameterization, mode)
    pair: the cheap checks of every pair first, then those that build each chart's warm start
    (about 3 s a transcription, against minutes of solves)."""
    from jtraj.experiments import check_noise_chart
    from jtraj.parameterization import PARAMETERIZATIONS
    from jtraj.robot import load as load_robot
    from jtraj.solver import transcription_options
    from jtraj.task import load as load_task
    from jtraj.transcription import Transcription

    for param in params:
        if param in modes:
            raise ValueError(f"--modes: {param}: with --params {param} it is mode raw (the chart's own draws); leave one out")
        if "unit" in modes and not param.startswith("quat"):
            raise ValueError(f"--modes: unit: needs quaternion charts; --params has {param}")
    if "unit" in modes:
        t = load_task(task)
        robot, options = load_robot(t.robot), transcription_options(variables)
        for param in params:
            tr = Transcription(robot, t, PARAMETERIZATIONS[param], options)
            rho = tr.warm_start()[:, tr.layout.slice("q")][:, 3:7]
            if not np.allclose(np.linalg.norm(rho, axis=1), 1.0):
                raise ValueError(f"--modes: unit: needs a quaternion chart whose warm start's q[3:7] are unit quaternions; {param}'s are not")
    for chart in (m for m in modes if m in PARAMETERIZATIONS):
        try:
            check_noise_chart([task], params, variables, chart)
        except ValueError as e:  # NoiseChartError
            raise ValueError(f"--modes: {chart}: {e}") from None


def run(task: str, param: str, sigma: float, draws: int, max_iter: int, variables: str, modes: tuple[str, ...] = MODES, first: int = 0, solver: str = "jtraj") -> list[dict]:
    """Each mode's solves of draws ``first .. first + draws - 1`` with ``solver`` (jtraj's: one
    batched call per mode; Ipopt: one by one, as the study); one record per solve."""
    import time

    from jtraj import solvers
    from jtraj.experiments import chart_noisy_warm_starts, noisy_warm_starts
    from jtraj.solver import evaluate, prepare, solve

    prep = prepare(task, param, variables)
    tr, nlp = prep.transcription, prep.nlp
    x0 = tr.warm_start()
    q = tr.layout.slice("q")
    # main() checked these pairs (`check_modes`) before anything compiled; kept for direct calls
    if "unit" in modes and not (tr.param.name.startswith("quat") and np.allclose(np.linalg.norm(x0[:, q][:, 3:7], axis=1), 1.0)):
        raise SystemExit(f"{param}: mode unit needs a quaternion chart whose warm start's q[3:7] are unit quaternions")
    if param in modes:
        raise SystemExit(f"{param}: mode {param} is mode raw")
    reps = range(first, first + draws)
    noisy = np.asarray(noisy_warm_starts(x0, [sigma], reps, 0)[0])
    backend = solvers.get("jtraj")
    theta = tr.resolve_theta(None)
    opts = backend.options({"max_iter": max_iter})
    records = []
    for mode in modes:
        if mode == "raw":
            starts = noisy
        elif mode == "unit":
            starts = unit_quaternions(noisy, q)
        else:
            try:
                starts = chart_noisy_warm_starts(tr, mode, [sigma], reps, 0)[0]
            except ValueError as e:
                raise SystemExit(f"mode {mode}: {e}") from None
        angles = rotation_noise(tr, starts, x0)
        if solver == "jtraj":
            solutions, total, compile_time = backend.solve_batch(nlp, starts, theta, opts)
            results = [evaluate(tr, sol, tr.decode(sol.x, theta), 0.0, {}, nlp.nnz_jac, None, theta, backend.name) for sol in solutions]
        else:
            t0, compile_time = time.perf_counter(), 0.0
            results = [solve(task, param, variables=variables, solver=solver, warm_start=start, ipopt_options={"max_iter": max_iter}, progress=None, keep_trajectory=False) for start in starts]
            total = time.perf_counter() - t0
        for r, res in zip(reps, results):
            i = r - first
            records.append(dict(task=task, parameterization=param, mode=mode, sigma=sigma, replicate=r, solver=solver, status=res.status.value, converged=res.converged, success=res.success, iterations=res.iterations, constraint_violation=res.constraint_violation, rotation_noise_mean=float(angles[i].mean()), rotation_noise_over_half_pi=float((angles[i] > np.pi / 2).mean())))
        done = [x for x in records if x["mode"] == mode]
        print(f"{task} {param} {mode}: {sum(x['converged'] for x in done)}/{draws} converged, {sum(x['success'] for x in done)} did the task, base rotated {angles.mean():.2f} rad on average by the noise ({total:.0f} s, compile {compile_time:.0f} s)", flush=True)
    return records


def table(records: list[dict]) -> str:
    """Markdown: per (parameterization, mode), converged and task-done counts, the converged
    runs' median iterations and, where recorded, how far the noise turned the base."""
    angles = all("rotation_noise_mean" in r for r in records)
    # tables of the first run (modes raw and unit, no angles recorded) keep their header
    head = "| parameterization | warm start (mode) |" if angles else "| parameterization | warm start's rho |"
    head += " converged | did the task | iterations of the converged (median) |"
    lines = [head + (" base rotated by the noise (rad, mean) | knots turned > 90 deg |" if angles else ""), "|---|---|---|---|---|" + ("---|---|" if angles else "")]
    for param in dict.fromkeys(r["parameterization"] for r in records):
        for mode in dict.fromkeys(r["mode"] for r in records):
            rows = [r for r in records if r["parameterization"] == param and r["mode"] == mode]
            if not rows:
                continue
            its = [r["iterations"] for r in rows if r["converged"]]
            # an even count's median is a half-integer: "12.5", not "12" (f"{12.5:.0f}" rounds half to even)
            median = f"{np.median(its):g}" if its else "-"
            line = f"| {param} | {mode} | {sum(r['converged'] for r in rows)} / {len(rows)} | {sum(r['success'] for r in rows)} / {len(rows)} | {median} |"
            if angles:
                line += f" {np.mean([r['rotation_noise_mean'] for r in rows]):.2f} | {100 * np.mean([r['rotation_noise_over_half_pi'] for r in rows]):.1f} % |"
            lines.append(line)
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    from jtraj.cli import InputError, _check_params
    from jtraj.task import task_argument

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="walk", type=task_argument)
    ap.add_argument("--params", default="quat1,quat2", help="comma-separated parameterizations")
    ap.add_argument("--sigma", type=float, default=0.5)
    ap.add_argument("--draws", type=int, default=20)
    ap.add_argument("--first", type=int, default=0, help="first draw (replicate number)")
    ap.add_argument("--modes", default="raw,unit,se3", help=f"warm starts to solve, of {','.join(MODES)}")
    ap.add_argument("--max-iter", type=int, default=200)
    add_variables(ap, "paper")
    ap.add_argument("--solver", default="jtraj", choices=("jtraj", "ipopt"), help="jtraj's (batched) or Ipopt (one by one, as Table III)")
    add_out(ap, "quaternion_noise")
    a = ap.parse_args(argv)
    try:
        params = _check_params("--params", a.params)
    except InputError as e:
        ap.error(str(e))
    if not (math.isfinite(a.sigma) and a.sigma >= 0):
        ap.error(f"--sigma: {a.sigma}: expected a noise level (standard deviation) >= 0")
    for name, least in (("draws", 1), ("first", 0), ("max_iter", 1)):
        if getattr(a, name) < least:
            ap.error(f"--{name.replace('_', '-')}: {getattr(a, name)}: expected an integer >= {least}")
    modes = tuple(a.modes.split(","))
    if not modes or set(modes) - set(MODES):
        ap.error(f"--modes {a.modes}: expected modes of {','.join(MODES)}")
    refuse_repeats(ap, "--modes", modes, "mode")
    try:  # every (parameterization, mode) pair, before the first solve
        check_modes(a.task, params, a.variables, modes)
    except ValueError as e:
        ap.error(str(e))
    records = []
    for param in params:
        records += run(a.task, param, a.sigma, a.draws, a.max_iter, a.variables, modes, a.first, a.solver)
    text = table(records)
    print(text, end="")
    if a.out is not None:
        from jtraj.provenance import write_results

        write_results(a.out, "quaternion_noise", records, text, "bench/quaternion_noise.py", argv)
        print(f"wrote {a.out}/quaternion_noise.json, quaternion_noise.md, provenance.json")


if __name__ == "__main__":
    main()
