"""The block-tridiagonal factor (`jtraj.solvers.kkt.factor`) with its diagonal blocks factored
by one LAPACK call each against in halves (`kkt.SPLIT_ABOVE`), on random blocks of the tasks'
shapes, in one process, the two programs taking turns.

    python bench/factor_split.py [--shapes 47x156x96,121x78x48] [--rounds 15] [--out DIR]

A shape is ``KxNxC``: K knots of n x n blocks whose off-diagonal blocks have C coupled columns
(the defaults: big_jump's block size with the study's variables, 47 x 156, with the 96 coupled
columns of its compact variables; the side-flip's shape with the study's variables, 121 x 78;
`results/factor_split_tasks/` has each task's own shapes). Each round
times each program five times, the order alternating; the table gives the fastest, the first quartile and the median
of all its timings, and the largest difference between the two factors: the larger of that of
their diagonal blocks and that of their off-diagonal blocks (``sub``), each relative to the
largest entry of those blocks. ``--out DIR`` writes ``DIR/factor_split.json``,
``factor_split.md`` and ``provenance.json``.

Why: OpenBLAS's Cholesky (``dpotrf``) of these small blocks ran at 3 to 5 GFLOP/s on this
project's 2-core machines, a matrix product of the same size at about 30 (measured in scratch
runs; see docs/measurements.md). The halves move part of the work into matrix products.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jtraj.provenance import write_results
from jtraj.solvers import kkt

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/_args.py, also when the tests load this file from its path
from _args import add_out  # noqa: E402

jax.config.update("jax_enable_x64", True)

NO_SPLIT = 10**9


def blocks(K: int, n: int, c: int, seed: int = 0) -> tuple[jax.Array, jax.Array, np.ndarray]:
    """A random positive definite block-tridiagonal matrix's (diag, upper on ``c`` columns)."""
    rng = np.random.default_rng(seed)
    G = rng.standard_normal((K, n, n)) / np.sqrt(n)
    diag = G @ np.swapaxes(G, 1, 2) + 4.0 * np.eye(n)
    cols = np.sort(rng.choice(n, c, replace=False)).astype(np.int32)
    upper = 0.1 * rng.standard_normal((K, n, c))
    return jnp.asarray(diag), jnp.asarray(upper), cols


def program(split_above: int, cols: np.ndarray, diag: jax.Array, upper: jax.Array):
    """The factor compiled for ``diag``, ``upper``, traced with ``kkt.SPLIT_ABOVE = split_above``."""
    saved = kkt.SPLIT_ABOVE
    kkt.SPLIT_ABOVE = split_above
    try:
        return jax.jit(lambda d, u: kkt.factor(d, u, cols)).lower(diag, upper).compile()
    finally:
        kkt.SPLIT_ABOVE = saved


def measure(K: int, n: int, c: int, rounds: int) -> dict:
    diag, upper, cols = blocks(K, n, c)
    progs = {"one call": program(NO_SPLIT, cols, diag, upper), "halves": program(kkt.SPLIT_ABOVE, cols, diag, upper)}
    outs = {k: jax.block_until_ready(p(diag, upper)) for k, p in progs.items()}
    assert all(bool(o[1]) for o in outs.values()), "the random matrix should factor"
    # both parts of the factor: the diagonal blocks and the off-diagonal ones (``sub``)
    diff = max(_relative_difference(getattr(outs["halves"][0], part), getattr(outs["one call"][0], part)) for part in ("diag", "sub"))
    times: dict[str, list[float]] = {k: [] for k in progs}
    for i in range(rounds):
        # the order alternates (ABBA...): the second program of a round ran faster than the
        # first in a trial with two identical programs
        for k, p in list(progs.items())[:: 1 if i % 2 == 0 else -1]:
            for _ in range(5):
                t = time.perf_counter()
                jax.block_until_ready(p(diag, upper))
                times[k].append(time.perf_counter() - t)
    stats = {k: dict(min_ms=1e3 * min(v), p25_ms=1e3 * float(np.percentile(v, 25)), median_ms=1e3 * float(np.median(v))) for k, v in times.items()}
    return dict(K=K, n=n, c=c, split_above=kkt.SPLIT_ABOVE, backend=jax.default_backend(), rounds=rounds, max_rel_diff=diff, stats=stats)


def _relative_difference(a, ref) -> float:
    """Largest entry of ``|a - ref|`` relative to the largest of ``|ref|`` (absolute where ``ref`` is 0)."""
    a, ref = np.asarray(a), np.asarray(ref)
    return float(np.max(np.abs(a - ref)) / (np.max(np.abs(ref)) or 1.0))


def table(records: list[dict]) -> str:
    lines = [
        "| knots x n (coupled) | split | one call: fastest / p25 / median (ms) | halves: fastest / p25 / median (ms) | one call / halves (median) | largest difference |",
        "|---|---|---|---|---|---|",
    ]
    for r in records:
        a, b = r["stats"]["one call"], r["stats"]["halves"]
        split = "yes" if r["n"] > r["split_above"] else f"no (n <= {r['split_above']})"
        if r.get("backend", "cpu") != "cpu":
            split = f"no ({r['backend']})"
        lines.append(
            f"| {r['K']} x {r['n']} ({r['c']}) | {split} | {a['min_ms']:.1f} / {a['p25_ms']:.1f} / {a['median_ms']:.1f} "
            f"| {b['min_ms']:.1f} / {b['p25_ms']:.1f} / {b['median_ms']:.1f} | {a['median_ms'] / b['median_ms']:.2f}x | {r['max_rel_diff']:.1e} |"
        )
    return "\n".join(lines) + "\n"


def shapes(text: str) -> list[tuple[int, int, int]]:
    """argparse ``type=`` of ``--shapes``: comma-separated ``KxNxC``, K and N at least 1, C
    coupled columns of the N (1 <= C <= N)."""
    out = []
    for item in text.split(","):
        try:
            K, n, c = (int(x) for x in item.split("x"))
        except ValueError:
            raise argparse.ArgumentTypeError(f"{item!r}: expected KxNxC (knots, block size, coupled columns), e.g. 47x156x96") from None
        if K < 1 or not 1 <= c <= n:
            raise argparse.ArgumentTypeError(f"{item!r}: expected K >= 1 knots and 1 <= C <= N coupled columns of the N x N blocks")
        out.append((K, n, c))
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shapes", type=shapes, default="47x156x96,121x78x48", help="KxNxC,... (knots, block size, coupled columns)")
    ap.add_argument("--rounds", type=int, default=15)
    add_out(ap, "factor_split")
    args = ap.parse_args(argv)
    if args.rounds < 1:
        ap.error(f"--rounds: {args.rounds}: expected an integer >= 1")
    records = []
    for K, n, c in args.shapes:
        records.append(measure(K, n, c, args.rounds))
        print(table(records[-1:]).splitlines()[-1], flush=True)
    md = table(records)
    print(md)
    if args.out:
        write_results(args.out, "factor_split", records, md, "bench/factor_split.py", argv)


if __name__ == "__main__":
    main()
