"""Benchmark one task: compile time, time to solution, time per Ipopt iteration and its split
into JAX evaluation (functions and derivatives) and Ipopt's own work, side by side with the
paper's public implementation (figures of REFERENCE.md / issue, same kind of machine) and
with jtraj's paper-faithful settings in the same run.

    python bench/solve.py big_jump [--param se3] [--variants paper,compact,lean]

Variants (all with the study's Ipopt settings: L-BFGS Hessian, tol 1e-3, MUMPS):
    paper    the study's variables per knot (q, v, a, f, c)
    compact  jtraj's default: contact positions substituted by forward kinematics (q, v, a, f)
    lean     accelerations substituted too (q, v, f)
    exact    the paper layout with the exact Hessian of the Lagrangian from JAX
"""

from __future__ import annotations

import argparse
import io
import re
import time

from jtraj.solver import prepare, solve

#: Time to solution (s) and iterations of the paper's public implementation on a 2-core
#: machine of this kind (issue #4), compile excluded.
PAPER = {"big_jump": (12.7, 11), "walk": (46.7, 12), "hopscotch": (21.6, 10), "handstand": (103.0, 89), "backflip": (33.9, 28), "sideflip": (33.1, 29)}

VARIANTS = {
    "paper": dict(layout="paper", exact_hessian=False, ipopt_options={}),
    "lean": dict(layout="lean", exact_hessian=False, ipopt_options={}),
    "exact": dict(layout="paper", exact_hessian=True, ipopt_options={}),
    "compact": dict(layout="compact", exact_hessian=False, ipopt_options={}),
}


def ipopt_timing(text: str) -> dict[str, float]:
    out = {}
    for key in ("OverallAlgorithm", "Function Evaluations", "LinearSystemFactorization", "LinearSystemBackSolve", "StdAugSystemSolverMultiSolve"):
        m = re.search(rf"{re.escape(key)}\.*:\s+([\d.]+) \(sys:\s+[\d.]+ wall:\s+([\d.]+)\)", text)
        if m:
            out[key] = float(m.group(2))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("task")
    ap.add_argument("--param", default="se3")
    ap.add_argument("--variants", default="paper,compact,lean")
    ap.add_argument("--ipopt", action="append", default=[], metavar="NAME=VALUE", help="extra Ipopt option for every variant")
    args = ap.parse_args()
    extra = {}
    for item in args.ipopt:
        k, v = item.split("=", 1)
        extra[k] = int(v) if v.isdigit() else (float(v) if v.replace(".", "", 1).replace("e-", "", 1).isdigit() else v)

    t0 = time.perf_counter()
    prep = prepare(args.task, args.param)
    compile_s = time.perf_counter() - t0
    print(f"{args.task} [{args.param}]: {prep.nlp.n} variables, {prep.nlp.m} constraints, {prep.nlp.nnz_jac} Jacobian nonzeros")
    print(f"compile (transcription, sparsity probes, first call of every callback): {compile_s:.1f} s")
    paper_s, paper_it = PAPER.get(args.task, (float("nan"), 0))
    header = f"{'variant':<8} {'status':<10} {'iters':>5} {'time (s)':>9} {'s/iter':>7} {'JAX eval':>9} {'Ipopt own':>9} {'  of which linear solver':>24} {'paper/jtraj':>11}"
    print(header)
    print(f"{'paper':<8} {'(public code)':<10} {paper_it:5d} {paper_s:9.2f} {paper_s / max(paper_it, 1):7.3f} {'':>9} {'':>9} {'':>24} {1.0:11.2f}")
    for name in args.variants.split(","):
        v = VARIANTS[name]
        opts = dict(v["ipopt_options"], print_timing_statistics="yes", print_level=3, **extra)
        # Ipopt prints its timing table on the C side: capture it from file descriptor 1
        import os
        import sys
        import tempfile

        with tempfile.TemporaryFile(mode="w+") as tmp:
            sys.stdout.flush()
            saved = os.dup(1)
            os.dup2(tmp.fileno(), 1)
            try:
                r = solve(args.task, args.param, layout=v["layout"], exact_hessian=v["exact_hessian"], ipopt_options=opts, progress=io.StringIO())
            finally:
                sys.stdout.flush()
                os.dup2(saved, 1)
                os.close(saved)
            tmp.seek(0)
            timing = ipopt_timing(tmp.read())
        linsolve = timing.get("StdAugSystemSolverMultiSolve", float("nan"))
        print(
            f"{name:<8} {('ok' if r.success else r.status.value)[:10]:<10} {r.iterations:5d} {r.time_s:9.2f} {r.time_s / max(r.iterations, 1):7.3f} "
            f"{r.time_derivatives:9.2f} {r.time_ipopt:9.2f} {linsolve:24.2f} {paper_s / r.time_s:11.2f}"
        )


if __name__ == "__main__":
    main()
