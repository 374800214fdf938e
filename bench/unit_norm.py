"""The quaternion charts with and without a unit-norm row, on the paper's tasks, in one run.

The comparative study's quaternion implementation normalizes rho wherever it is used (its
footnote 2) and keeps no norm constraint; so does jtraj by default. Whether rho's norm is then
a free direction of the NLP depends on the chart's rows (`jtraj.parameterization`):

- Quaternion #1 and #2: the integration rows fix every interior knot's rho, norm included
  (``rho + 1/2 L(rho) H omega h`` has norm ``sqrt(1 + |omega h / 2|^2)``; the manifold step
  has norm 1). A row ``|rho|^2 = 1`` would contradict the first (forcing omega = 0) and repeat
  the second, so neither gets one here.
- Quaternion #3: its difference rows are six (``Exp(q2) (-) Exp(q1)``) for seven coordinates,
  so rho's norm at each knot is left free: a direction along which no row and no cost changes.

This benchmark solves each task with Quaternion #3 as the study does and with
``unit_norm=True`` (the row ``|rho|^2 - 1 = 0`` at every knot whose coordinates are not fixed
by bounds), the study's variables, Ipopt with the study's settings (``--params`` quat1 and
quat2 are refused: for the reason above, they get no unit-norm row)::

    python bench/unit_norm.py [TASK ...] [--params quat3] [--solver ipopt] [--out DIR]

``--out DIR`` writes ``DIR/unit_norm.json`` (one record per solve), ``DIR/unit_norm.md`` and
``DIR/provenance.json``. Times include no compile.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from jtraj.experiments import ALL_TASKS

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/_args.py, also when the tests load this file from its path
from _args import add_out, add_tasks, refuse_repeats  # noqa: E402


def run(task: str, param: str, unit_norm: bool, solver: str) -> dict:
    """One solve from the task's warm start; its record."""
    import jtraj
    from jtraj import parameterization

    chart = dataclasses.replace(parameterization.get(param), unit_norm=unit_norm)
    res = jtraj.solve(task, chart, variables="paper", solver=solver, progress=None, keep_trajectory=False)
    return dict(
        task=task, parameterization=param, unit_norm=unit_norm, solver=solver, status=res.status.value, iterations=res.iterations,
        cost=res.cost, constraint_violation=res.constraint_violation, turns=res.turns, time_s=round(res.time_s, 2),
    )


def table(records: list[dict]) -> str:
    """Markdown, one row per solve, in the order solved."""
    lines = ["| task | parameterization | norm row | status | iterations | cost | violation | turns | time (s) |", "|---|---|---|---|---|---|---|---|---|"]
    for r in records:
        turns = "" if r["turns"] is None else f"{r['turns']:+.2f}"
        lines.append(
            f"| {r['task']} | {r['parameterization']} | {'yes' if r['unit_norm'] else 'no'} | {r['status']} | {r['iterations']} | {r['cost']:.3g} | "
            f"{r['constraint_violation']:.1e} | {turns} | {r['time_s']:.1f} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_tasks(ap, ALL_TASKS)
    ap.add_argument("--params", default="quat3", help="comma-separated quaternion charts: quat3 (quat1 and quat2 get no unit-norm row: their integration rows fix rho's norm)")
    ap.add_argument("--solver", default="ipopt", choices=("ipopt", "jtraj"))
    add_out(ap, "unit_norm")
    a = ap.parse_args(argv)
    params = [p for p in a.params.split(",") if p]
    if not params or any(p not in ("quat1", "quat2", "quat3") for p in params):
        ap.error(f"--params: expected quaternion charts (quat1, quat2, quat3), got {a.params!r}")
    # quat1 and quat2 were solved with unit_norm=True too, which the docstring says they do not get
    why = {"quat1": "would contradict them (forcing omega = 0)", "quat2": "would repeat them (the manifold step has norm 1)"}
    for p in params:
        if p in why:
            ap.error(f"--params: {p!r}: its integration rows fix rho's norm at every interior knot, so a unit-norm row {why[p]}; expected quat3")
    refuse_repeats(ap, "--params", params, "chart")
    records = []
    for task in a.tasks:
        for param in params:
            for unit_norm in (False, True):
                records.append(run(task, param, unit_norm, a.solver))
                r = records[-1]
                print(f"{task} {param} unit_norm={unit_norm}: {r['status']}, {r['iterations']} iterations, violation {r['constraint_violation']:.1e}, {r['time_s']:.1f} s", flush=True)
    text = table(records)
    print(text, end="")
    if a.out:
        from jtraj.provenance import write_results

        write_results(a.out, "unit_norm", records, text, "bench/unit_norm.py", argv)
        print(f"wrote {a.out}/unit_norm.json, unit_norm.md, provenance.json")


if __name__ == "__main__":
    main()
