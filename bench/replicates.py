"""Noise replicates in one vmapped solve of jtraj's interior point against the same replicates
solved one after another with Ipopt, in the same run.

    python bench/replicates.py [--task big_jump] [--param se3] [--sigma 0.1] [--replicates 10]

Both solvers start from the same noisy warm starts (`jtraj.experiments.noisy_warm_starts`).
Compilation is excluded from both times: the vmapped program is compiled ahead of time
(``lower().compile()``), and Ipopt's NLP functions are compiled by ``prepare``. Prints one line
per replicate (status, iterations, violation, task success) and, last,
``replicates: vmapped X s, sequential Y s, speedup Z``.
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

from jtraj.experiments import noisy_warm_starts
from jtraj.solver import prepare, solve
from jtraj.solvers.ipm import IPM, IpmOptions, IpmStatus
from jtraj.success import FEASIBILITY_TOL
from jtraj.success import evaluate as check_motion


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="big_jump")
    ap.add_argument("--param", default="se3")
    ap.add_argument("--sigma", type=float, default=0.1)
    ap.add_argument("--replicates", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    prep = prepare(args.task, args.param)
    tr, nlp = prep.transcription, prep.nlp
    starts = noisy_warm_starts(tr.warm_start(), [args.sigma], args.replicates, args.seed)[0]
    ipm = IPM(nlp, IpmOptions(max_iter=tr.task.max_iter))
    batched = jax.jit(jax.vmap(ipm.solve, in_axes=(0, None)))
    t = time.perf_counter()
    compiled = batched.lower(jnp.asarray(starts), nlp.theta).compile()
    print(f"jtraj vmapped program compiled in {time.perf_counter() - t:.1f} s", flush=True)
    t = time.perf_counter()
    r = jax.block_until_ready(compiled(jnp.asarray(starts), nlp.theta))
    t_vmapped = time.perf_counter() - t

    t_sequential = 0.0
    for i in range(args.replicates):
        x = np.asarray(r.x[i]).reshape(-1)
        traj = tr.decode(x)
        viol = nlp.violation(x, nlp.theta)
        ok_j = int(r.status[i]) == IpmStatus.CONVERGED and viol < FEASIBILITY_TOL and check_motion(traj.base_xyz_wxyz, tr.task.flip_axis, tr.task.flip_turns).ok
        res = solve(args.task, args.param, warm_start=starts[i], progress=None, keep_trajectory=False)
        t_sequential += res.time_s
        print(
            f"#{i}: jtraj {IpmStatus(int(r.status[i])).name.lower():18s} {int(r.iterations[i]):4d} it viol {viol:.1e} success {ok_j} | "
            f"ipopt {res.status.value:26s} {res.iterations:4d} it viol {res.constraint_violation:.1e} {res.time_s:6.2f} s success {res.success}",
            flush=True,
        )
    print(f"replicates: vmapped {t_vmapped:.2f} s, sequential {t_sequential:.2f} s, speedup {t_sequential / t_vmapped:.2f}")


if __name__ == "__main__":
    main()
