"""Why `JtrajSolver.solve_batch` runs members one after another on a CPU: one block sweep of the
KKT solve, vectorized over a batch (`jax.vmap`) against the same members one after another
(`lax.map`), in the same run.

    python bench/vmap_cpu.py [--members 4] [--knots 47] [--sizes 32,132] [--repeats 50] [--out DIR]

The sweep is the shape of `jtraj.solvers.kkt.solve_factored`'s: a `lax.scan` over the knots of
an n x n block times a vector, repeated. At n = 132 (Talos, big_jump) one member's blocks are
K n^2 doubles (6.5 MB); several members' do not fit in the cache together, and the vectorized
batch streams them all from memory on every sweep. Prints one line per size:
``n=N: one X ms, one after another Y ms, vmapped Z ms, vmapped / one after another R`` (each
time the mean of 3 calls after one that compiles). ``--out DIR`` writes ``DIR/vmap_cpu.json``,
``DIR/vmap_cpu.md`` and ``DIR/provenance.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/_args.py, also when the tests load this file from its path
from _args import add_out  # noqa: E402

jax.config.update("jax_enable_x64", True)


def sweeps(blocks: jax.Array, b: jax.Array, repeats: int) -> jax.Array:
    """``repeats`` forward sweeps over the knots: y_k = tanh(L_k (b_k + y_{k-1}))."""

    def one(_, y):
        def step(prev, inp):
            L_k, b_k = inp
            out = jnp.tanh(L_k @ (b_k + prev))
            return out, out

        return jax.lax.scan(step, y[0], (blocks, b + y))[1]

    return jax.lax.fori_loop(0, repeats, one, b)


def timed(fn, *args, reps: int = 3) -> float:
    jax.block_until_ready(fn(*args))  # compile
    t0 = time.perf_counter()
    for _ in range(reps):
        jax.block_until_ready(fn(*args))
    return (time.perf_counter() - t0) / reps


def sizes(text: str) -> list[int]:
    """argparse ``type=`` of ``--sizes``: comma-separated block sizes >= 1."""
    try:
        out = [int(s) for s in text.split(",")]
    except ValueError:
        out = []
    if not out or min(out) < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: expected comma-separated block sizes >= 1, e.g. 32,132")
    return out


def table(records: list[dict], note: str) -> str:
    """Markdown: one row per block size, times in milliseconds, and ``note``."""
    from jtraj.tables import markdown_table

    return markdown_table(
        ("n", "one (ms)", "one after another (ms)", "vmapped (ms)", "vmapped / one after another"),
        [(r["n"], f"{r['one_ms']:.1f}", f"{r['mapped_ms']:.1f}", f"{r['vmapped_ms']:.1f}", f"{r['vmapped_ms'] / r['mapped_ms']:.2f}") for r in records],
        note,
    )


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--members", type=int, default=4)
    ap.add_argument("--knots", type=int, default=47)
    ap.add_argument("--sizes", type=sizes, default="32,132")
    ap.add_argument("--repeats", type=int, default=50)
    add_out(ap, "vmap_cpu")
    args = ap.parse_args(argv)
    for name in ("members", "knots", "repeats"):
        if getattr(args, name) < 1:
            ap.error(f"--{name}: {getattr(args, name)}: expected an integer >= 1")
    rng = np.random.default_rng(0)
    head = f"JAX {jax.__version__} on {jax.devices()[0].platform}; {args.members} members, {args.knots} knots, {args.repeats} sweeps"
    print(head, flush=True)
    records = []
    for n in args.sizes:
        L = jnp.asarray(0.01 * rng.standard_normal((args.members, args.knots, n, n)))
        b = jnp.asarray(rng.standard_normal((args.members, args.knots, n)))
        run = lambda L, b: sweeps(L, b, args.repeats)  # noqa: E731
        one = timed(jax.jit(run), L[0], b[0])
        mapped = timed(jax.jit(lambda L, b, run=run: jax.lax.map(lambda a: run(*a), (L, b))), L, b)
        vmapped = timed(jax.jit(jax.vmap(run)), L, b)
        print(f"n={n}: one {one * 1e3:.1f} ms, one after another {mapped * 1e3:.1f} ms, vmapped {vmapped * 1e3:.1f} ms, vmapped / one after another {vmapped / mapped:.2f}", flush=True)
        records.append(dict(n=n, members=args.members, knots=args.knots, sweeps=args.repeats, one_ms=one * 1e3, mapped_ms=mapped * 1e3, vmapped_ms=vmapped * 1e3))
    if args.out:
        from jtraj.provenance import write_results

        write_results(args.out, "vmap_cpu", records, table(records, head + "; each time the mean of 3 calls after one that compiles."), "bench/vmap_cpu.py", argv)


if __name__ == "__main__":
    main()
