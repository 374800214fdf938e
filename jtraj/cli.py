"""Command line: ``jtraj <command>``; ``jtraj --help`` lists the commands."""

from __future__ import annotations

import argparse
import sys


def _cmd_params(args: argparse.Namespace) -> int:
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jtraj import lie
    from jtraj.lie import SE3, SO3
    from jtraj.parameterization import PARAMETERIZATIONS

    key = jax.random.PRNGKey(args.seed)
    k1, k2, k3 = jax.random.split(key, 3)
    T = SE3.from_rotation_and_translation(SO3.sample_uniform(k1), jax.random.normal(k2, (3,)))
    V = jax.random.normal(k3, (6,))
    h = 0.05
    print(f"random pose: xyz_wxyz = {np.round(np.concatenate([T.translation(), T.rotation().wxyz]), 4)}")
    print(f"{'name':<7} {'Table I row':<20} {'nq':>3} {'ndiff':>5}  {'pose round trip':>15}  {'step error vs Exp(Vh)':>21}")
    ok = True
    for name, p in PARAMETERIZATIONS.items():
        q = p.from_pose(T)
        roundtrip = float(jnp.max(jnp.abs(p.to_pose(q).as_matrix() - T.as_matrix())))
        step = float(jnp.linalg.norm(lie.minus(p.to_pose(p.integrate(q, V, h)), lie.plus(T, V * h))))
        ok &= roundtrip < 1e-9
        print(f"{name:<7} {p.label:<20} {p.nq:>3} {p.ndiff:>5}  {roundtrip:>15.2e}  {step:>21.2e}")
    return 0 if ok else 1


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="jtraj", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("params", help="list the floating-base parameterizations and check them on a random pose")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=_cmd_params)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
