"""Euler angles on the flips from four warm starts, in one run: which part of the warm start
decides whether Euler fails (the paper's Table IV and III) or converges to a plain jump.

The study's flip scripts write the warm start with ``rpy2rep(q, [0, theta, 0])`` on the
flight's nodes only, theta ramping 0 -> -2 pi, and leave the other nodes at the standing pose.
For the SE(3) chart (its public code) that goes through a rotation matrix and its log; the
paper's Euler code is not public. The warm starts solved here, Euler chart, study's variables,
Ipopt with the study's settings:

- ``matrix``: roll, pitch and yaw extracted from each knot's rotation matrix, pitch kept
  `jtraj.euler.GIMBAL_MARGIN` from +-pi/2 (``warm_start_euler="matrix"``): the coordinates jump
  by pi (back-flip: roll and yaw) or 2 pi (side-flip: roll) mid-flight.
- ``angles``: the ramp written into the coordinates as it is, the knots after it back at the
  standing pose, as the scripts leave them (``warm_start_euler="angles"``, the study's
  variables' default): the coordinates ramp to -2 pi and jump back at landing, and the
  back-flip's pitch sits at -pi/2 and -3 pi/2 on two knots, where the rate matrix W is
  singular.
- ``angles-nudged``: ``angles`` with those two pitches moved by the gimbal margin (W finite).
- ``angles-held``: the ramp's final angle kept after it (``Task.warm_start_angles()``'s
  default), so the jump of 2 pi sits at the last knot, whose bounds hold the target (0).

::

    python bench/euler_warm_start.py [TASK ...] [--variants matrix,angles,...] [--out DIR]

``--out DIR`` writes ``DIR/euler_warm_start.json`` (one record per solve),
``DIR/euler_warm_start.md`` and ``DIR/provenance.json``. Times include no compile.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/_args.py, also when the tests load this file from its path
from _args import add_out, add_tasks, refuse_repeats  # noqa: E402

VARIANTS = ("matrix", "angles", "angles-nudged", "angles-held")


def warm_start(task: str, variant: str):
    """The study's variables for ``variant`` and the warm start (n_knots, nz) to solve from."""
    from jtraj import euler
    from jtraj.solver import prepare, transcription_options

    options = dataclasses.replace(transcription_options("paper"), warm_start_euler="matrix" if variant == "matrix" else "angles")
    tr = prepare(task, "euler", options).transcription
    Z = tr.warm_start()
    pitch = tr.layout.slice("q").start + 4
    if variant == "angles-nudged":
        at_lock = np.abs(np.mod(Z[:, pitch] + np.pi / 2, np.pi)) < 1e-9
        Z[at_lock, pitch] += euler.GIMBAL_MARGIN
    elif variant == "angles-held":
        base = tr.layout.slice("q").start + 3
        for (axis, held), (_, standing) in zip(tr.task.warm_start_angles(), tr.task.warm_start_angles(after_ramp="standing")):
            i = int(np.flatnonzero(np.abs(axis) > 1e-12)[0])
            Z[:, base + i] += np.sign(axis[i]) * (held - standing)
    return options, Z


def run(task: str, variant: str) -> dict:
    """One solve; its record."""
    import jtraj

    options, Z = warm_start(task, variant)
    res = jtraj.solve(task, "euler", variables=options, warm_start=Z, progress=None, keep_trajectory=False)
    return dict(
        task=task, warm_start=variant, status=res.status.value, iterations=res.iterations, obj_evals=res.stats.obj_evals,
        cost=res.cost, constraint_violation=res.constraint_violation, turns=res.turns, time_s=round(res.time_s, 2),
    )


def table(records: list[dict]) -> str:
    """Markdown, one row per solve, in the order solved."""
    lines = ["| task | warm start | status | iterations | obj evals | cost | violation | turns |", "|---|---|---|---|---|---|---|---|"]
    for r in records:
        turns = "" if r["turns"] is None else f"{r['turns']:+.2f}"
        lines.append(f"| {r['task']} | {r['warm_start']} | {r['status']} | {r['iterations']} | {r['obj_evals']} | {r['cost']:.3g} | {r['constraint_violation']:.1e} | {turns} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_tasks(ap, ["backflip", "sideflip"])
    ap.add_argument("--variants", default=",".join(VARIANTS), help=f"comma-separated, of: {', '.join(VARIANTS)}")
    add_out(ap, "euler_warm_start")
    a = ap.parse_args(argv)
    variants = [v.strip() for v in a.variants.split(",") if v.strip()]
    if not variants or any(v not in VARIANTS for v in variants):
        ap.error(f"--variants: expected some of {', '.join(VARIANTS)}, got {a.variants!r}")
    refuse_repeats(ap, "--variants", variants, "variant")
    records = []
    for task in a.tasks:
        for variant in variants:
            records.append(run(task, variant))
            r = records[-1]
            print(f"{task} euler, {variant}: {r['status']}, {r['iterations']} iterations, violation {r['constraint_violation']:.1e}, {r['time_s']:.1f} s", flush=True)
    text = table(records)
    print(text, end="")
    if a.out:
        from jtraj.provenance import write_results

        write_results(a.out, "euler_warm_start", records, text, "bench/euler_warm_start.py", argv)
        print(f"wrote {a.out}/euler_warm_start.json, euler_warm_start.md, provenance.json")


if __name__ == "__main__":
    main()
