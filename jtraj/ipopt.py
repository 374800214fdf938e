"""The boundary to Ipopt (through cyipopt): the only module that converts to numpy per call.

`solve_nlp` hands a `jtraj.nlp.KnotNLP` to Ipopt, counts evaluations, times the callbacks
(derivative and function evaluation in JAX) apart from Ipopt's own work, and prints live
progress.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from typing import Any, TextIO

import jax.numpy as jnp
import numpy as np

from jtraj.nlp import KnotNLP

__all__ = ["DEFAULT_OPTIONS", "IpoptOutcome", "solve_nlp"]

#: Solver settings of the comparative study's public code (REFERENCE.md).
DEFAULT_OPTIONS: dict[str, Any] = {
    "tol": 1e-3,
    "max_iter": 200,
    "hessian_approximation": "limited-memory",
    "nlp_scaling_method": "none",
    "linear_solver": "mumps",
    "max_wall_time": 600.0,
    "print_level": 0,
    "sb": "yes",  # no Ipopt banner
}


@dataclasses.dataclass
class IpoptOutcome:
    """What Ipopt returned, with evaluation counts and a time split (seconds)."""

    x: np.ndarray
    status: int
    status_msg: str
    iterations: int
    objective: float
    constraint_violation: float
    obj_evals: int
    grad_evals: int
    con_evals: int
    jac_evals: int
    hess_evals: int
    time_total: float
    time_callbacks: float
    time_ipopt: float
    mult_g: np.ndarray
    history: list[dict[str, float]]
    violation_by_group: dict[str, float]

    @property
    def converged(self) -> bool:
        # 0: solve succeeded, 1: solved to acceptable level
        return self.status in (0, 1)


class _Callbacks:
    def __init__(self, nlp: KnotNLP, exact_hessian: bool, progress: TextIO | None, every: int):
        self.nlp = nlp
        self.counts = dict(obj=0, grad=0, con=0, jac=0, hess=0)
        self.t_callbacks = 0.0
        self.progress = progress
        self.every = every
        self.history: list[dict[str, float]] = []
        self.iterations = 0
        if exact_hessian:
            self.hessianstructure = lambda: (nlp.hess_rows, nlp.hess_cols)
            self.hessian = self._hessian

    def _timed(self, key, fn, *args):
        t = time.perf_counter()
        out = np.asarray(fn(*args))
        self.t_callbacks += time.perf_counter() - t
        self.counts[key] += 1
        return out

    def objective(self, x):
        return float(self._timed("obj", self.nlp.objective, jnp.asarray(x)))

    def gradient(self, x):
        return self._timed("grad", self.nlp.gradient, jnp.asarray(x))

    def constraints(self, x):
        return self._timed("con", self.nlp.constraints, jnp.asarray(x))

    def jacobian(self, x):
        return self._timed("jac", self.nlp.jacobian, jnp.asarray(x))

    def jacobianstructure(self):
        return self.nlp.jac_rows, self.nlp.jac_cols

    def _hessian(self, x, lagrange, obj_factor):
        return self._timed("hess", self.nlp.hessian, jnp.asarray(x), jnp.asarray(lagrange), float(obj_factor))

    def intermediate(self, alg_mod, iter_count, obj_value, inf_pr, inf_du, mu, d_norm, regularization_size, alpha_du, alpha_pr, ls_trials):
        self.iterations = int(iter_count)
        self.history.append(dict(iter=int(iter_count), objective=float(obj_value), inf_pr=float(inf_pr), inf_du=float(inf_du), mu=float(mu), alpha_pr=float(alpha_pr)))
        if self.progress is not None and (iter_count % self.every == 0):
            if iter_count == 0:
                print(f"{'iter':>5} {'objective':>14} {'inf_pr':>10} {'inf_du':>10} {'lg(mu)':>7} {'alpha_pr':>9}", file=self.progress)
            lgmu = np.log10(mu) if mu > 0 else -np.inf
            print(f"{iter_count:5d} {obj_value:14.6e} {inf_pr:10.3e} {inf_du:10.3e} {lgmu:7.2f} {alpha_pr:9.2e}", file=self.progress, flush=True)
        return True


def solve_nlp(
    nlp: KnotNLP,
    x0: np.ndarray,
    options: dict[str, Any] | None = None,
    exact_hessian: bool = False,
    progress: TextIO | None = sys.stdout,
    progress_every: int = 1,
) -> IpoptOutcome:
    """Solve ``nlp`` from ``x0`` with Ipopt.

    ``options`` override `DEFAULT_OPTIONS` (any Ipopt option name is accepted; Ipopt rejects
    unknown ones). ``exact_hessian=True`` passes the Hessian of the Lagrangian from JAX and
    sets ``hessian_approximation=exact``.
    """
    import cyipopt

    opts = dict(DEFAULT_OPTIONS)
    if exact_hessian:
        opts["hessian_approximation"] = "exact"
        nlp.build_hessian()
    opts.update(options or {})
    if opts.get("hessian_approximation") == "exact" and not exact_hessian:
        nlp.build_hessian()
        exact_hessian = True

    cb = _Callbacks(nlp, exact_hessian, progress, progress_every)
    problem = cyipopt.Problem(
        n=nlp.n,
        m=nlp.m,
        problem_obj=cb,
        lb=nlp.x_lower,
        ub=nlp.x_upper,
        cl=nlp.g_lower,
        cu=nlp.g_upper,
    )
    for key, value in opts.items():
        if isinstance(value, bool):
            value = "yes" if value else "no"
        try:
            problem.add_option(key, value)
        except TypeError as e:  # cyipopt raises TypeError for unknown options / bad values
            raise ValueError(f"Ipopt rejected option {key}={value!r}: {e}") from None
    x0 = np.clip(np.asarray(x0, float), nlp.x_lower, nlp.x_upper)
    t0 = time.perf_counter()
    x, info = problem.solve(x0)
    total = time.perf_counter() - t0
    violation = nlp.violation(x)
    return IpoptOutcome(
        x=x,
        status=int(info["status"]),
        status_msg=info["status_msg"].decode() if isinstance(info["status_msg"], bytes) else str(info["status_msg"]),
        iterations=cb.iterations,
        objective=float(info["obj_val"]),
        constraint_violation=violation,
        obj_evals=cb.counts["obj"],
        grad_evals=cb.counts["grad"],
        con_evals=cb.counts["con"],
        jac_evals=cb.counts["jac"],
        hess_evals=cb.counts["hess"],
        time_total=total,
        time_callbacks=cb.t_callbacks,
        time_ipopt=total - cb.t_callbacks,
        mult_g=np.asarray(info["mult_g"]),
        history=cb.history,
        violation_by_group=nlp.violation_by_group(x),
    )
