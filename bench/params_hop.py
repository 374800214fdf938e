"""jtraj's interior point and Ipopt on a small Go2 hop with each of the five floating-base
parameterizations, in one run.

    python bench/params_hop.py [--params se3,quat1,quat2,quat3,euler] [--out DIR]

The hop (Go2, 0.05 s knots, stance 0.15 s, flight 0.1 s, stance 0.15 s, 0.1 m forward) is
the one ``tests/test_ipm.py`` solved before 1ca32f0, solved from the task's warm start with the
compact variables by ``jtraj.solve(..., solver="jtraj")`` and by Ipopt with the study's
settings. CI now solves a smaller hop (``tests/test_transcription.py``'s ``HOP``, the study's
variables) with all five parameterizations (``test_converges_on_small_go2_hop`` and
``test_converges_on_small_go2_hop_with_the_other_parameterizations``); this benchmark's rows
are measured only here. Prints one row per
(parameterization, solver): status, iterations, cost, largest constraint violation, solve time
(compile excluded; the JSON's ``time_compile_s`` is `jtraj.solve`'s ``time_compile``, which
for a parameterization's first solve also holds the build of its NLP); ``--out`` writes
``DIR/params_hop.json``, ``DIR/params_hop.md`` and
``DIR/provenance.json``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jtraj
from jtraj.cli import InputError, _check_params
from jtraj.provenance import write_results
from jtraj.task import Phase, Task

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/_args.py, also when the tests load this file from its path
from _args import add_out  # noqa: E402

FEET = ("FL_foot", "FR_foot", "RL_foot", "RR_foot")
HOP = Task(name="hop", robot="go2", timestep=0.05, phases=(Phase(FEET, 0.15), Phase((), 0.1), Phase(FEET, 0.15)), target_translation=(0.1, 0.0, 0.0))


def run(params: list[str]) -> list[dict]:
    rows = []
    for p in params:
        for solver in ("jtraj", "ipopt"):
            res = jtraj.solve(HOP, p, solver=solver, progress=None, keep_trajectory=False)
            row = dict(parameterization=p, solver=solver, status=res.status.value, iterations=res.iterations, cost=res.cost, constraint_violation=res.constraint_violation, time_s=round(res.time_s, 3), time_compile_s=round(res.time_compile, 1))
            print(f"{p:6s} {solver:6s} {row['status']:16s} {row['iterations']:4d} it  cost {row['cost']:.3g}  viol {row['constraint_violation']:.1e}  {row['time_s']:.2f} s", flush=True)
            rows.append(row)
    return rows


def render(rows: list[dict]) -> str:
    lines = ["| parameterization | solver | status | iterations | cost | max violation | time (s) |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['parameterization']} | {r['solver']} | {r['status']} | {r['iterations']} | {r['cost']:.3g} | {r['constraint_violation']:.1e} | {r['time_s']:.2f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--params", default="se3,quat1,quat2,quat3,euler")
    add_out(ap, "params_hop")
    args = ap.parse_args(argv)
    try:
        params = _check_params("--params", args.params)
    except InputError as e:
        ap.error(str(e))
    rows = run(params)
    if args.out:
        write_results(args.out, "params_hop", rows, render(rows), "bench/params_hop.py", argv)


if __name__ == "__main__":
    main()
