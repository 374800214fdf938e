"""Where one solve of jtraj's own interior point spends its time, by phase, from a profile of
its compiled program: what a change to the solver can win, measured instead of guessed.

    python bench/profile_solve.py [TASK ...] [--param se3] [--variables paper] [--out DIR]

For each task: the program is compiled (`jtraj.solvers.JtrajSolver`'s, for the task's warm
start) and run once, then run again under ``jax.profiler.trace``. The trace's XLA operations
(each the time the CPU's worker threads spent in it, nested operations subtracted) are mapped
to the ``jax.named_scope`` they were traced under, through the compiled program's HLO
metadata, and summed by phase:

- ``factor``: the block Cholesky factorizations (`jtraj.solvers.kkt.factor`), inertia
  corrections' retries included;
- ``block solves``: the forward and backward sweeps of the first solve of each Newton system
  (`kkt.solve_factored`, the L-BFGS columns' included);
- ``refinement``: iterative refinement (`kkt.solve`'s loop: its sweeps and KKT products);
- ``condensed blocks``: ``J^T D^-1 J`` (`kkt._product_blocks`);
- ``derivatives``: the objective's gradient and the Jacobian at accepted points;
- ``values``: objective and constraints at trial points (the line search);
- ``mu oracle``: the quality function's golden section;
- ``other``: the rest (the state's vector algebra, the filter, L-BFGS updates, the loop).

The program is compiled afresh (``JTRAJ_NO_CACHE=1``, set here): JAX's persistent cache keys a
program without its metadata, so a program cached before a scope moved would be attributed by
the old names. Times are thread time, which on this 2-core machine exceeds the wall time where XLA runs two
operations at once, and the profiler adds some; the shares are what to read. Each record has
the solve's ``status`` (`jtraj.solvers.Status`'s value); the table shows it beside the
iterations of a solve that did not succeed. ``--out DIR`` writes ``DIR/profile_solve.json``,
``DIR/profile_solve.md`` and ``DIR/provenance.json``.
"""

from __future__ import annotations

import argparse
import collections
import glob
import os
import re
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/_args.py, also when the tests load this file from its path
from _args import add_out, add_param, add_tasks, add_variables  # noqa: E402

os.environ["JTRAJ_NO_CACHE"] = "1"  # before jtraj is imported (see the docstring)

PHASES = ("factor", "block solves", "refinement", "condensed blocks", "derivatives", "values", "mu oracle", "other")
# (scope in the op's name stack, phase), first match wins: refinement holds sweeps of its own
_SCOPES = (
    ("kkt_refine", "refinement"),
    ("kkt_sweeps", "block solves"),
    ("kkt_factor", "factor"),
    ("kkt_condensed", "condensed blocks"),
    ("nlp_derivatives", "derivatives"),
    ("nlp_hessian", "derivatives"),
    ("nlp_values", "values"),
    ("ipm_mu_oracle", "mu oracle"),
)


def phase_of(op_name: str | None) -> str:
    """The phase of an HLO operation from its ``op_name`` metadata (None: other)."""
    for scope, phase in _SCOPES:
        if op_name and scope in op_name:
            return phase
    return "other"


def exclusive_times(xplane: str) -> collections.Counter:
    """Nanoseconds per trace event name on XLA's CPU worker threads, children subtracted."""
    from jax.profiler import ProfileData

    excl: collections.Counter = collections.Counter()
    for plane in ProfileData.from_file(xplane).planes:
        for line in plane.lines:
            if "XLAEigen" not in line.name:
                continue
            stack: list[list] = []
            for start, end, name in sorted(((e.start_ns, e.start_ns + e.duration_ns, e.name) for e in line.events), key=lambda e: (e[0], -e[1])):
                while stack and stack[-1][1] <= start:
                    stack.pop()
                if stack:
                    excl[stack[-1][2]] -= end - start
                excl[name] += end - start
                stack.append([start, end, name])
    return excl


def profile(task: str, param: str, variables: str) -> dict:
    """Profile one solve of ``task`` from its warm start; its record."""
    import jax
    import jax.numpy as jnp

    from jtraj import solvers
    from jtraj.solver import prepare

    prep = prepare(task, param, variables)
    tr, nlp = prep.transcription, prep.nlp
    theta = tr.resolve_theta(None)
    backend = solvers.get("jtraj")
    ipm = backend.ipm(nlp, backend.options({"max_iter": tr.task.max_iter}))
    x0 = jnp.asarray(tr.warm_start(theta).reshape(ipm.view.K, ipm.view.n))
    compiled = ipm.program.lower(x0, theta, ipm.tolerances).compile()
    op_names = dict(re.findall(r"%([\w.\-]+) = [^\n]*?op_name=\"([^\"]+)\"", compiled.as_text()))
    jax.block_until_ready(compiled(x0, theta, ipm.tolerances))  # warm
    t0 = time.perf_counter()
    r = jax.block_until_ready(compiled(x0, theta, ipm.tolerances))
    wall = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as d:
        jax.profiler.start_trace(d)
        jax.block_until_ready(compiled(x0, theta, ipm.tolerances))
        jax.profiler.stop_trace()
        (xplane,) = glob.glob(f"{d}/**/*.xplane.pb", recursive=True)
        excl = exclusive_times(xplane)
    by_phase = collections.Counter({p: 0 for p in PHASES})
    for name, ns in excl.items():
        if name in op_names:
            by_phase[phase_of(op_names[name])] += ns
        elif name != "ThunkExecutor::Execute":
            by_phase["other"] += ns
    total = sum(by_phase.values())
    if by_phase["other"] == total:
        raise RuntimeError(f"{task}: no profiled operation carries a phase's scope; was the program compiled from this tree?")
    iterations = int(r.iterations)
    return dict(
        task=task, parameterization=param, variables=variables, status=status_of(r), iterations=iterations, wall_s=round(wall, 3),
        knots=ipm.view.K, n=ipm.view.n, m=ipm.view.m, thread_ms={p: round(by_phase[p] / 1e6, 1) for p in PHASES},
        share={p: round(by_phase[p] / total, 4) for p in PHASES}, thread_ms_per_iteration=round(total / 1e6 / max(iterations, 1), 1),
    )


def status_of(r) -> str:
    """How the profiled solve ended, as `jtraj.solve` says it (`jtraj.solvers.Status`'s value,
    e.g. ``solved`` or ``max_iter``), from the compiled program's `IpmResult`."""
    from jtraj.solvers.ipm import IpmStatus

    return IpmStatus(int(r.status)).shared.value


def table(records: list[dict]) -> str:
    """Markdown: one row per task, the phases' shares of the profiled thread time; a solve that
    did not succeed has its status beside its iterations (records written before the status
    was recorded have none: their rows are as they were)."""
    head = "| task | knots x n | iterations | solve (s) | thread ms / iteration | " + " | ".join(PHASES) + " |"
    lines = [head, "|" + "---|" * (5 + len(PHASES))]
    for r in records:
        shares = " | ".join(f"{100 * r['share'][p]:.0f} %" for p in PHASES)
        status = r.get("status", "solved")
        iterations = f"{r['iterations']}" + ("" if status == "solved" else f" ({status})")
        lines.append(f"| {r['task']} | {r['knots']} x {r['n']} | {iterations} | {r['wall_s']:.2f} | {r['thread_ms_per_iteration']:.0f} | {shares} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_tasks(ap, ["walk", "big_jump", "backflip", "sideflip"])
    add_param(ap)
    add_variables(ap, "paper", help="the variables per knot (default: the study's, as the robustness study solves)")
    add_out(ap, "profile_solve")
    a = ap.parse_args(argv)
    records = []
    for task in a.tasks:
        records.append(profile(task, a.param, a.variables))
        r = records[-1]
        print(f"{task}: {r['status']}, {r['iterations']} iterations in {r['wall_s']:.2f} s; " + ", ".join(f"{p} {100 * r['share'][p]:.0f} %" for p in PHASES), flush=True)
    text = table(records)
    print(text, end="")
    if a.out:
        from jtraj.provenance import write_results

        write_results(a.out, "profile_solve", records, text, "bench/profile_solve.py", argv)
        print(f"wrote {a.out}/profile_solve.json, profile_solve.md, provenance.json")


if __name__ == "__main__":
    main()
