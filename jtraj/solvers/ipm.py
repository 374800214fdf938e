"""jtraj's own solver: a primal-dual interior-point method of Ipopt's family, in JAX.

The NLP is a `jtraj.nlp.KnotNLP` seen knot by knot (`jtraj.solvers.stage.StageView`)::

    min f(Z)   s.t.  c_lower <= C(Z) <= c_upper,   x_lower <= Z <= x_upper,

Z (K, n), C (K, m) with row k reading knots k and k+1. As in Ipopt (Wächter & Biegler, Math.
Prog. 106, 2006): inequality rows get slacks ``C - s = 0`` with the row bounds on s; the
barrier subproblems ``min f - mu sum log(bound distances)`` are solved inexactly by primal-dual
Newton steps, ``mu`` set afresh each iteration by Ipopt's adaptive rule (or falling
monotonically, ``mu <- max(min(tol, compl_inf_tol)/(kappa_eps + 1), min(kappa_mu mu,
mu^theta_mu))`` once the barrier error is below ``kappa_eps mu``); steps keep a fraction ``tau = max(0.99,
1 - mu)`` of the distance to the bounds; the bound multipliers stay within ``kappa_sigma``
of their central values. Fixed variables (equal bounds) are removed from the step; their bound
multipliers are reported at the end as Ipopt's are (`IpmResult`).

Differences from Ipopt, and why:
- Newton step: the block-tridiagonal factorization of `jtraj.solvers.kkt` (linear in the knots,
  small dense blocks; inertia correction by ``delta_w`` when the condensed matrix is not
  positive definite, on the variables' block and, as Ipopt's, the inequality slacks' (before
  2026-12-07 on the variables' only: on a concave box with the exact Hessian 18 and 13
  iterations where Ipopt takes 13 and 9); a dual regularization ``delta_c mu^(1/4)`` on every row, which is Ipopt's
  perturbation for a dependent Jacobian and is needed here: the corner-point contacts make the
  equality rows dependent, 12 per stance knot on Talos), instead of a general sparse LDL^T.
- Hessian: by default Ipopt's limited-memory BFGS of the Lagrangian (``sigma I`` minus a
  rank-12 term in compact form, Byrd, Nocedal and Schnabel 1994), whose low-rank term the
  Newton solve handles by Sherman-Morrison-Woodbury around the block factorization of the
  rest, so the matrix stays block tridiagonal. The exact Hessian per element (the 2n x 2n block
  of the knot-k terms on (z_k, z_{k+1})) is an option. On the six tasks with the default barrier
  rule it took fewer iterations on big_jump (10 against 11) and the side-flip (19 against 33),
  as many on hopscotch, more on the walk (23 against 16), and it missed the back-flip (a motion
  of -0.85 turn) and the handstand (200 iterations). It also costs 11 to 18 times as much per
  iteration and compiles far longer (`results/hessians/`, the README). A damped (Powell) BFGS
  per element (partitioned quasi-Newton, Griewank and Toint) is another; it converges on small
  problems but not on the whole-body tasks (big_jump: multipliers grow to 1e7 and the dual
  infeasibility stalls near 1e4): its unexplored directions keep the identity's curvature.
- Barrier: Ipopt's adaptive strategy (its default with a quasi-Newton Hessian, and what the
  study's Ipopt runs therefore use) with Ipopt's defaults: the quality-function oracle and the
  obj-constr-filter rule for leaving the free mode. The G1 back-flip needs both: with the LOQO
  oracle and the KKT-error rule jtraj's solver stopped at 200 iterations, and Ipopt itself,
  given those two options, converges in 45 iterations to a motion of -0.95 turn (not a flip)
  where its defaults find the flip in 19. The LOQO oracle, the KKT-error rule and the
  monotone strategy are options; the KKT-error rule measures progress by the scaled
  optimality error (max-norm) where Ipopt's uses averaged squared residuals. On big_jump the monotone strategy's fixed mu = 0.1 let the
  fraction-to-the-boundary rule cut every step to 1e-3..1e-2.
  As Ipopt's, the adaptive strategy's first factorization is at mu = 1 (not ``mu_init``),
  ``mu_max`` is ``mu_max_fact`` times the initial average complementarity, and the
  limited-memory BFGS forgets its memory after ``lbfgs_max_skipping`` skipped pairs in a row:
  with the first two, the iterates on a noisy Talos walk agreed with Ipopt's to the printed
  digits up to iteration 12, where Ipopt reset its L-BFGS (without them they parted at the
  first), and with the reset three noisy walks took Ipopt's iteration counts, 31, 23 and 50
  (docs/measurements.md).
- Globalization: Ipopt's filter line search with its second-order corrections (``max_soc``;
  the factorization of the direction is kept in the loop state, so a correction costs one KKT
  solve; it runs in a loop that a vmapped batch enters only when one of its members corrects),
  without a feasibility restoration phase: a failed line search takes its last (tiny) step and
  the solve stops after several in a row. A trial point
  costs the objective and constraints only; the Jacobian is evaluated at accepted points. As
  in Ipopt, the filter is emptied whenever mu changes and at every free-mode iteration of the
  adaptive strategy; a step for which the switching and Armijo conditions hold leaves it as
  it is, whichever test accepted the step (step A-7); a filter entry rejects only a point
  worse in both measures; the acceptance tests allow Ipopt's rounding margin (10 eps of the
  reference value); and the inertia correction starts from the last positive ``delta_w``,
  remembered through iterations that needed none (Algorithm IC).
- Not implemented from Ipopt (its defaults in brackets): the damping of one-sided bounds in
  the barrier function (``kappa_d`` 1e-5), least-squares initial multipliers (y starts at 0),
  Ipopt's least-squares multiplier update at nearly feasible iterates (``recalc_y``, on by
  default with its limited-memory Hessian, at violations below ``recalc_y_feas_tol`` 1e-6:
  jtraj's y follows the Newton step only, and its iteration counts are Ipopt's with
  ``recalc_y=no``: on a pendulum swing-up at tol 1e-8, 17, 21, 16 and 15 iterations from four
  starts, where Ipopt's default takes 15, 19, 15 and 12, a review's measurement; on the
  study's tasks Ipopt's own runs do not change with ``recalc_y=no``: `jtraj solve` of the
  side-flip, big_jump and the back-flip took 41, 11 and 119 iterations to the same cost and
  violation either way, 2026-12-07: its augmented system there is singular, the corner-point
  contacts' rows being dependent, or the violation never below the threshold), the relaxation of bounds
  (``bound_relax_factor`` 1e-8), the watchdog procedure, tiny-step detection, and
  ``obj_max_inc``. Smaller differences: a solved barrier problem lowers mu at
  most 4 times in one iteration (Ipopt's monotone loop has no bound, and its adaptive
  strategy's fixed mode lowers it once); the filter holds 64 entries in a ring and keeps
  dominated ones; with ``adaptive_mu_globalization="kkt-error"`` the fixed mode returns to
  the free mode only at an iteration that lowers mu with progress in the KKT error (Ipopt's
  returns at the first with that progress); ``delta_w_max`` is the paper's
  1e40 (Ipopt's default 1e20). In the adaptive strategy's fixed mode tau is ``max(tau_min,
  1 - mu)`` of the new mu at every iteration (Ipopt sets it when the mode changes or mu is
  lowered, from the old mu; they differ below mu = 1e-2, in tau's third decimal or beyond).
  The inertia correction tries ``delta_w = 0`` first at every iteration (Ipopt skips that
  trial once three iterations in a row needed a correction, its degenerate-Hessian rule; with
  the default L-BFGS Hessian the matrix is positive definite anyway) and makes at most 40
  trials (Ipopt has no count; its sequence reaches ``delta_w_max`` in about 35). Iterative
  refinement stops at the first step that does not lower the residual and hands that step
  on: Ipopt then raises the perturbation when the residual ratio is still above 1e-5
  (``residual_ratio_singular``), which is not done here (on 40 random ill-conditioned systems
  one ended at a ratio of 1.5e-5; on the tests' problems at tol 1e-15 none above 1e-6).
- Everything is one `jax.jit` program (`lax.while_loop`); `jax.vmap` of `IPM.solve` over
  initial guesses (and parameters theta) is one program too. On an accelerator it is
  vectorized: the replicates step together, and a converged replicate's state no longer
  changes (the batched while loop only updates unfinished members). On a CPU, where a
  vectorized batch is slower than its members one after another (`_members_apart_on_cpu`
  says why), its batching rule splits the batch over JAX's CPU devices (one per core, set by
  ``import jtraj``), each running its share one member after another in the same program
  (`IpmOptions.cpu_batch`); `JtrajSolver.solve_batch` by default runs the one-problem
  program on every core instead, which balances uneven members better.

State: `bench/solve.py TASK --variants compact,jtraj` measures it on the six tasks (the
README quotes the run). Ipopt stays the default.

Convergence (Ipopt's test at the comparative study's settings): the scaled optimality error
``max(dual_inf / s_d, constr_viol, compl / s_c) <= tol`` with Ipopt's ``s_d, s_c`` (s_max =
100), and unscaled ``constr_viol <= 1e-4``, ``dual_inf <= 1``, ``compl <= 1e-4``.
"""

from __future__ import annotations

import dataclasses
import enum
import threading
import time
import warnings
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jtraj.config import cpu_count
from jtraj.nlp import KnotNLP
from jtraj.solvers import kkt
from jtraj.solvers.base import (
    AbstractCallback,
    AbstractOptions,
    AbstractSolver,
    InvalidOptionError,
    Iteration,
    PrintProgress,
    Solution,
    Stats,
    Status,
    _positive,
    bind,
    guess_shapes,
    initial_guess,
    invalid_problem,
    max_violation,
)
from jtraj.solvers.stage import StageView

__all__ = ["IpmOptions", "IpmStatus", "IpmResult", "IPM", "JtrajSolver"]


#: the largest integer of the compiled program's counters (int32)
_INT32_MAX = 2**31 - 1


class IpmStatus(enum.IntEnum):
    """Termination of the interior-point loop (int codes, so they live in JAX arrays)."""

    RUNNING = 0
    CONVERGED = 1
    MAX_ITER = 2
    LINE_SEARCH_FAILED = 3  # several line searches in a row found no acceptable step
    NUMERICAL_ERROR = 4  # NaN or Inf in the iterate, its function values or derivatives (the Hessian too)
    INERTIA_FAILED = 5  # no delta_w up to delta_w_max gave a positive-definite Newton matrix

    @property
    def shared(self) -> Status:
        """The status of the shared enumeration (`jtraj.solvers.Status`) this termination is
        reported as, e.g. CONVERGED -> ``Status.SOLVED``."""
        return _STATUS[self]


class _Tolerances(NamedTuple):
    """`IpmOptions.RUNTIME_FIELDS` as arrays, an input of the compiled solve."""

    tol: Any
    constr_viol_tol: Any
    dual_inf_tol: Any
    compl_inf_tol: Any
    feasibility_polish_tol: Any
    feasibility_polish_iter: Any



#: Ipopt's options that `IpmOptions` has under another name (the fields' docstrings)
IPOPT_NAMES = {
    "hessian_approximation": "hessian",
    "limited_memory_max_history": "lbfgs_memory",
    "limited_memory_init_val": "lbfgs_init_val",
    "limited_memory_init_val_min": "lbfgs_init_min",
    "limited_memory_init_val_max": "lbfgs_init_max",
    "limited_memory_max_skipping": "lbfgs_max_skipping",
    "max_refinement_steps": "refine_steps",
    "min_refinement_steps": "min_refine_steps",
    "eta_phi": "armijo",
}


@dataclasses.dataclass(frozen=True, kw_only=True)
class IpmOptions(AbstractOptions):
    """Options of the interior-point method (names and defaults follow Ipopt's options).

    Attributes:
        tol: scaled optimality error for convergence (the study's Ipopt setting, 1e-3).
        max_iter: iteration limit.
        constr_viol_tol, dual_inf_tol, compl_inf_tol: unscaled limits at convergence.
        hessian: Ipopt's ``hessian_approximation``: ``"lbfgs"`` (default: Ipopt's
            ``limited-memory`` BFGS, a scaled identity plus a low-rank term, solved by
            Sherman-Morrison-Woodbury around the block factorization), ``"exact"`` (the
            Lagrangian's Hessian from JAX, per element) or ``"bfgs"``
            (partitioned damped BFGS; does not converge on the whole-body tasks).
        mu_strategy: ``"adaptive"`` (default, as Ipopt's default with a quasi-Newton Hessian)
            or ``"monotone"`` (Fiacco-McCormick).
        mu_oracle: how the adaptive strategy's free mode picks mu: ``"loqo"`` (``sigma
            avg(d z)`` from the iterate's centrality) or ``"quality-function"`` (default, as
            Ipopt's: the affine-scaling and centering steps are solved with the same
            factorization, and ``sigma`` minimizes a linear model of the next iterate's
            squared KKT residuals, found by golden section in [sigma_min, sigma_max];
            Nocedal, Wächter and Waltz 2009). ``sigma_min``, ``sigma_max``,
            ``quality_function_max_section_steps`` and ``quality_function_section_sigma_tol``
            are Ipopt's options of that oracle.
        adaptive_mu_globalization: when the adaptive strategy falls back to the monotone mode
            (Ipopt's option of that name): ``"obj-constr-filter"`` (default, as Ipopt's: free
            mode lasts while each iterate improves the objective or the constraint violation
            on every earlier free-mode iterate, by a margin) or ``"kkt-error"`` (while the KKT
            error falls). Measured on the G1 back-flip from the compact warm start with the
            quality-function oracle: obj-constr-filter converges in 19 iterations to a flip of
            cost 0.640, as Ipopt does (0.640 in 19; `results/hessians/`), kkt-error stops at
            200 iterations.
        mu_min, mu_max, mu_max_fact, adaptive_mu_kkterror_red_fact,
            adaptive_mu_monotone_init_factor, filter_margin_fact, filter_max_margin: Ipopt's
            constants of the adaptive strategy. ``mu_max=None`` (default) is, as in Ipopt when
            the option is not given, ``mu_max_fact`` times the initial point's average
            complementarity; ``mu_min=None`` (default) is, as in Ipopt when the option is not
            given, ``min(1e-11, tol / 2, compl_inf_tol / 2)`` (`mu_min_value`; 1e-11 for every
            tolerance above 2e-11). A problem without bounds on its free variables and without
            inequality rows keeps mu at ``mu_min`` and tau at ``tau_min``, as Ipopt's adaptive
            update does (there is no complementarity to take it from).
        mu_init, kappa_eps, kappa_mu, theta_mu, tau_min, kappa_sigma, s_max: Ipopt's barrier
            and safeguard constants. ``mu_init`` is the monotone strategy's first barrier
            parameter; the adaptive strategy starts, as Ipopt's, from mu = 1, which with the
            quality-function oracle only sets the first factorization's dual regularization
            ``delta_c mu^(1/4)`` (the LOQO oracle replaces it before the first factorization).
        bound_push, bound_frac: how far the initial point is pushed inside its bounds.
        delta_c, delta_c_mu_scaled: dual regularization of every row. Scaled (default):
            ``delta_c mu^(1/4)`` and part of the system, as Ipopt's perturbation for a
            dependent Jacobian (the whole-body tasks' corner-point contacts make the equality
            rows dependent: 12 per stance knot on Talos). Otherwise a fixed value removed by
            iterative refinement.
        delta_c_min: a floor under the scaled ``delta_c mu^(1/4)`` (default 0: none). With mu at
            ``mu_min`` the scaled value is 1.8e-11, the condensed matrix weighs the equality rows
            by its inverse, and its Cholesky needs ``delta_w`` about every other iteration
            (measured on the tests' Go2 hop at tol 1e-8: 86 to 117 iterations against Ipopt's
            20 to 38; with ``delta_c_min=1e-9`` 21 to 31, docs/measurements.md). Not the
            default: at the study's tol 1e-3 the floor takes the back-flip from 29 iterations
            to 102 (`results/delta_c_variants/`). With the exact Hessian a floor of 1e-9 is
            too low: on the Go2 hop of tests/test_differentiable.py at tol 1e-10 the
            factorization needed ``delta_w`` (about 1e-6) at every iteration once mu reached
            ``mu_min``, 211 iterations against Ipopt's 15; 1e-7 took 15
            (`jtraj.differentiate.JTRAJ_OPTIONS`, docs/measurements.md).
        refine_steps, min_refine_steps, residual_ratio_max: iterative refinement of each KKT
            solve (Ipopt's ``max_refinement_steps``, ``min_refinement_steps`` and
            ``residual_ratio_max``): it stops once the residual ratio is at most
            ``residual_ratio_max``, when a step does not lower the residual, or after
            ``refine_steps`` steps; ``residual_ratio_max=0`` takes ``refine_steps`` every time.
            The default 1e-6 is looser than Ipopt's 1e-10 and a decade below its
            ``residual_ratio_singular`` (1e-5, the ratio at which Ipopt deems a solve wrong):
            measured on the six tasks (``bench/options.py``, docs/measurements.md), 1e-10 took
            the same iterations (the handstand one fewer) and made the solves 1.04x to 1.22x as
            long. The step counts differ from Ipopt's (10 and 1); they have not been
            measured apart from the ratio.
        max_line_search: trial points of the line search per iteration: the full step and
            the halvings after it, that is ``max_line_search - 1`` halvings (0 and 1 both try
            the full step alone); second-order corrections are counted apart (``max_soc``).
        max_soc, kappa_soc: Ipopt's second-order corrections: when the first trial point of an
            iteration is rejected and raised the constraint violation, up to ``max_soc``
            corrected steps (the same factorization, the constraint rows' right-hand side
            replaced by the accumulated ``c_soc = alpha c_soc + c(trial)``) are tried, while each
            lowers the violation by the factor ``kappa_soc``; then backtracking resumes along
            the original direction. ``max_soc=0`` turns them off.
        armijo: the filter line search's sufficient-decrease constant, Ipopt's ``eta_phi``
            (default 1e-8, Ipopt's). Until 2026-12-06 the field was ignored and
            its default read 1e-4, so options recorded before then (results/) list 1e-4 for
            solves that used 1e-8.
        max_line_search_failures: consecutive failed line searches before giving up.
        bfgs_init: initial element Hessian scale of the BFGS approximation.
        bfgs_scaling: rescale each element's initial matrix by its first curvature pair.
        lbfgs_memory, lbfgs_init_val, lbfgs_init_min, lbfgs_init_max: Ipopt's
            ``limited_memory_max_history`` and ``limited_memory_init_val(_min, _max)``.
        lbfgs_max_skipping: Ipopt's ``limited_memory_max_skipping``: after this many
            successive pairs skipped for want of curvature, the next iteration forgets the
            memory and restarts from ``lbfgs_init_val`` times the identity (on the whole-body
            tasks' first iterations almost every pair is skipped, and Ipopt restarts every
            third iteration).
        feasibility_polish_tol, feasibility_polish_iter: once an iterate passes the
            convergence test with a constraint violation above ``feasibility_polish_tol``
            (default 1e-6; None: off), up to ``feasibility_polish_iter`` more iterations are
            taken, whether or not each passes the convergence test; in each, an iterate whose
            violation is above the tolerance steps onto the constraints' linearization (the
            Newton step without its dual residual, multipliers kept: `IPM._projection`), one
            within it takes its Newton step. The solve returns the first converged iterate
            whose violation is within the tolerance, else the converged iterate of least
            violation seen (always a converged one: a polishing iteration that fails its line
            search or reaches ``max_iter`` ends the polish with it). Ipopt has no such step;
            the convergence test itself is Ipopt's. (Newton steps alone, before the projection:
            the Go2 side-flip went from 1.2e-6 at convergence to 5.8e-11, but the SE(3)
            back-flip traded feasibility for its objective at mu_min, from 5.5e-6 to 9.2e-5.)
        cpu_batch: how ``jax.vmap`` of the solve runs on a CPU: ``"sequential"`` (default:
            the batch split in contiguous shares over JAX's CPU devices, one per core, each
            share ``lax.map`` of the one-problem solve, each member to its own last iteration,
            with its results) or ``"vectorized"`` (as on an accelerator, which always
            vectorizes: the members step together, a converged member's updates masked).
            Measured on big_jump's noisy replicates, the sequential batch on one device was
            2.7x faster than the vectorized one on this 2-core CPU, and two devices took it
            from 19.2 to 12.4 s (`_members_apart_on_cpu`).

    The tolerances of the convergence test and of the polish (`RUNTIME_FIELDS`) are inputs of
    the compiled program: options that differ only in them share one program (`IPM`), as do
    options that differ in ``cpu_batch`` alone (it chooses how a vmap of that program is
    batched). Whether the polish is on (``feasibility_polish_tol`` None or not) and every other
    option are compiled in.
    """

    #: the options passed to the compiled program as values (a change does not recompile)
    RUNTIME_FIELDS: ClassVar[tuple[str, ...]] = _Tolerances._fields

    #: the valid ranges of the options that follow Ipopt's: (lower, lower open, upper, upper
    #: open, Ipopt's name), as the bundled Ipopt lists them (a test compares them with
    #: `jtraj.solvers.ipopt_catalog`), except kappa_sigma: below 1 Ipopt skips the safeguard,
    #: whose interval this solver would invert
    RANGES: ClassVar[dict[str, tuple[float, bool, float, bool, str]]] = {
        "bound_push": (0.0, True, np.inf, True, "bound_push"),
        "bound_frac": (0.0, True, 0.5, False, "bound_frac"),
        "mu_min": (0.0, True, np.inf, True, "mu_min"),
        "mu_max_fact": (0.0, True, np.inf, True, "mu_max_fact"),
        "kappa_eps": (0.0, True, np.inf, True, "barrier_tol_factor"),
        "kappa_mu": (0.0, True, 1.0, True, "mu_linear_decrease_factor"),
        "theta_mu": (1.0, True, 2.0, True, "mu_superlinear_decrease_power"),
        "tau_min": (0.0, True, 1.0, True, "tau_min"),
        "kappa_sigma": (1.0, False, np.inf, True, "kappa_sigma"),
        "s_max": (0.0, True, np.inf, True, "s_max"),
        "armijo": (0.0, True, 0.5, True, "eta_phi"),
        "kappa_soc": (0.0, True, np.inf, True, "kappa_soc"),
        "sigma_min": (0.0, False, np.inf, True, "sigma_min"),
        "sigma_max": (0.0, True, np.inf, True, "sigma_max"),
        "lbfgs_init_val": (0.0, True, np.inf, True, "limited_memory_init_val"),
        "lbfgs_init_min": (0.0, True, np.inf, True, "limited_memory_init_val_min"),
        "lbfgs_init_max": (0.0, True, np.inf, True, "limited_memory_init_val_max"),
        "filter_margin_fact": (0.0, True, 1.0, True, "filter_margin_fact"),
        "filter_max_margin": (0.0, True, np.inf, True, "filter_max_margin"),
        "adaptive_mu_kkterror_red_fact": (0.0, True, 1.0, True, "adaptive_mu_kkterror_red_fact"),
        "adaptive_mu_monotone_init_factor": (0.0, True, np.inf, True, "adaptive_mu_monotone_init_factor"),
        "quality_function_section_sigma_tol": (0.0, False, 1.0, True, "quality_function_section_sigma_tol"),
    }

    tol: float = 1e-3
    max_iter: int = 200
    constr_viol_tol: float = 1e-4
    dual_inf_tol: float = 1.0
    compl_inf_tol: float = 1e-4
    hessian: str = "lbfgs"
    mu_strategy: str = "adaptive"
    mu_oracle: str = "quality-function"
    adaptive_mu_globalization: str = "obj-constr-filter"
    filter_margin_fact: float = 1e-5
    filter_max_margin: float = 1.0
    mu_init: float = 0.1
    kappa_eps: float = 10.0
    kappa_mu: float = 0.2
    theta_mu: float = 1.5
    tau_min: float = 0.99
    kappa_sigma: float = 1e10
    s_max: float = 100.0
    bound_push: float = 1e-2
    bound_frac: float = 1e-2
    delta_c: float = 1e-8
    delta_c_mu_scaled: bool = True
    delta_c_min: float = 0.0
    refine_steps: int = 3
    min_refine_steps: int = 0
    residual_ratio_max: float = 1e-6
    max_line_search: int = 30
    max_soc: int = 4
    kappa_soc: float = 0.99
    armijo: float = 1e-8
    max_line_search_failures: int = 5
    bfgs_init: float = 1.0
    bfgs_scaling: bool = True
    lbfgs_memory: int = 6
    lbfgs_init_val: float = 1.0
    lbfgs_init_min: float = 1e-8
    lbfgs_init_max: float = 1e8
    lbfgs_max_skipping: int = 2
    mu_min: float | None = None
    mu_max: float | None = None
    mu_max_fact: float = 1e3
    sigma_min: float = 1e-6
    sigma_max: float = 1e2
    quality_function_max_section_steps: int = 8
    quality_function_section_sigma_tol: float = 1e-2
    adaptive_mu_kkterror_red_fact: float = 0.9999
    adaptive_mu_monotone_init_factor: float = 0.8
    feasibility_polish_tol: float | None = 1e-6
    feasibility_polish_iter: int = 5
    cpu_batch: str = "sequential"

    solver_name: ClassVar[str] = "jtraj"

    @classmethod
    def _other_solvers_options(cls, unknown: list) -> str:
        from jtraj.solvers.ipopt_catalog import catalog

        ipopt = [name for name in unknown if isinstance(name, str) and name in catalog()]
        # Ipopt's options that this solver takes under another name (the fields' docstrings):
        # the hint names the field rather than only sending the user to Ipopt
        ours = [f"{name!r} is this solver's {IPOPT_NAMES[name]!r}" for name in ipopt if name in IPOPT_NAMES]
        others = [name for name in ipopt if name not in IPOPT_NAMES]
        hints = ours + ([f"{', '.join(map(repr, others))} {'is an option' if len(others) == 1 else 'are options'} of Ipopt: solver='ipopt', --solver ipopt"] if others else [])
        return f" ({'; '.join(hints)})" if hints else ""

    def __check__(self) -> None:
        if self.hessian not in ("lbfgs", "exact", "bfgs"):
            raise InvalidOptionError(f"jtraj option hessian={self.hessian!r}: expected 'lbfgs', 'exact' or 'bfgs'")
        if self.mu_strategy not in ("adaptive", "monotone"):
            raise InvalidOptionError(f"jtraj option mu_strategy={self.mu_strategy!r}: expected 'adaptive' or 'monotone'")
        if self.mu_oracle not in ("loqo", "quality-function"):
            raise InvalidOptionError(f"jtraj option mu_oracle={self.mu_oracle!r}: expected 'loqo' or 'quality-function'")
        if self.cpu_batch not in ("sequential", "vectorized"):
            raise InvalidOptionError(f"jtraj option cpu_batch={self.cpu_batch!r}: expected 'sequential' or 'vectorized'")
        if self.adaptive_mu_globalization not in ("obj-constr-filter", "kkt-error"):
            raise InvalidOptionError(f"jtraj option adaptive_mu_globalization={self.adaptive_mu_globalization!r}: expected 'obj-constr-filter' or 'kkt-error'")
        # every field by the type of its default: a string from the command line ("false",
        # "1e-3" unparsed) must not reach the solver as a truthy or untraceable value
        for field in dataclasses.fields(self):
            value, default = getattr(self, field.name), field.default
            if isinstance(default, bool):
                if not isinstance(value, (bool, np.bool_)):
                    raise InvalidOptionError(f"jtraj option {field.name}={value!r}: expected true or false")
            elif isinstance(default, int):
                if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 0:
                    raise InvalidOptionError(f"jtraj option {field.name}={value!r}: expected an integer >= 0")
                if value > _INT32_MAX:  # the program counts in int32
                    raise InvalidOptionError(f"jtraj option {field.name}={value!r}: expected an integer in [0, {_INT32_MAX}]")
            elif value is None and "None" in str(field.type):
                continue
            elif (isinstance(default, float) or (default is None and "float" in str(field.type))) and (isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)) or not np.isfinite(value)):
                raise InvalidOptionError(f"jtraj option {field.name}={value!r}: expected a finite number")
        _positive(self, "tol", "constr_viol_tol", "dual_inf_tol", "compl_inf_tol", "mu_init", "delta_c")
        for name in ("delta_c_min", "residual_ratio_max"):
            if not getattr(self, name) >= 0:
                raise InvalidOptionError(f"jtraj option {name}={getattr(self, name)!r}: expected a number >= 0")
        _positive(self, "mu_max", "feasibility_polish_tol", allow_none=True)
        for name, (lo, lo_open, hi, hi_open, _) in self.RANGES.items():
            value = getattr(self, name)
            if value is None:  # mu_min: Ipopt's rule when not given
                continue
            if (value <= lo if lo_open else value < lo) or (value >= hi if hi_open else value > hi):
                interval = f"{'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
                raise InvalidOptionError(f"jtraj option {name}={value!r}: expected a number in {interval}")
        for low, high in (("sigma_min", "sigma_max"), ("lbfgs_init_min", "lbfgs_init_max")):
            if getattr(self, low) > getattr(self, high):
                raise InvalidOptionError(f"jtraj option {low}={getattr(self, low)!r}: expected at most {high}={getattr(self, high)!r}")
        if self.max_line_search_failures < 1:
            raise InvalidOptionError(f"jtraj option max_line_search_failures={self.max_line_search_failures!r}: expected an integer >= 1")
        if self.lbfgs_max_skipping < 1:  # Ipopt's limited_memory_max_skipping is >= 1; 0 reset the memory every iteration
            raise InvalidOptionError(f"jtraj option lbfgs_max_skipping={self.lbfgs_max_skipping!r}: expected an integer >= 1 (Ipopt's limited_memory_max_skipping)")
        if self.delta_c_min > 0.0 and not self.delta_c_mu_scaled:
            raise InvalidOptionError(f"jtraj option delta_c_min={self.delta_c_min!r}: a floor under the scaled delta_c mu^(1/4), which delta_c_mu_scaled=false does not use")
        if self.min_refine_steps > self.refine_steps:
            raise InvalidOptionError(f"jtraj option min_refine_steps={self.min_refine_steps!r}: expected at most refine_steps={self.refine_steps!r}")
        per_iteration = self.max_line_search + 1 + self.max_soc
        if (self.max_iter + 1) * per_iteration > _INT32_MAX:  # IPM._max_passes, an int32 loop bound
            raise InvalidOptionError(
                f"jtraj option max_iter={self.max_iter!r}: expected at most {_INT32_MAX // per_iteration - 1} with max_line_search={self.max_line_search} "
                f"and max_soc={self.max_soc} (the solver bounds its evaluations, (max_iter + 1) (max_line_search + 1 + max_soc), in a 32-bit integer)"
            )
        # every number as the Python type of its field's default, as IpoptOptions does: an int (1
        # for 1.0) or a numpy scalar (np.float32) reached the loop's state as int64 or float32,
        # whose trace failed, and, equal and hashing alike, keyed the same program as 1.0
        for field in dataclasses.fields(self):
            value, default = getattr(self, field.name), field.default
            if isinstance(default, bool):
                object.__setattr__(self, field.name, bool(value))
            elif isinstance(default, int):
                object.__setattr__(self, field.name, int(value))
            elif value is not None and (isinstance(default, float) or (default is None and "float" in str(field.type))):
                object.__setattr__(self, field.name, float(value))

    def mu_min_value(self) -> float:
        """``mu_min``, or where it is not given Ipopt's rule at these tolerances."""
        return self.mu_min if self.mu_min is not None else float(_ipopt_mu_min(self.tol, self.compl_inf_tol, np))

    def compiled_part(self) -> "IpmOptions":
        """These options with the `RUNTIME_FIELDS` at fixed values (the polish kept on or off)
        and ``cpu_batch`` at its default (it chooses only how a vmap of the program is
        batched: the one-problem program is the same, and was compiled again): the key of the
        program."""
        polish = None if self.feasibility_polish_tol is None else 1.0
        return dataclasses.replace(self, tol=1.0, constr_viol_tol=1.0, dual_inf_tol=1.0, compl_inf_tol=1.0, feasibility_polish_tol=polish, feasibility_polish_iter=1, cpu_batch="sequential")

    def runtime_part(self) -> _Tolerances:
        """The `RUNTIME_FIELDS` as the program's input (the polish tolerance +inf when off)."""
        polish = np.inf if self.feasibility_polish_tol is None else self.feasibility_polish_tol
        f = np.float64
        return _Tolerances(f(self.tol), f(self.constr_viol_tol), f(self.dual_inf_tol), f(self.compl_inf_tol), f(polish), np.int32(self.feasibility_polish_iter))


class IpmResult(NamedTuple):
    """Outcome of `IPM.solve` (arrays; a leading batch axis under vmap).

    Attributes:
        x: (K, n) primal solution.
        y: (K, m) constraint multipliers in the stage layout (Ipopt's sign convention:
            ``grad f + J^T y - z_L + z_U = 0``).
        z_lower, z_upper: (K, n) bound multipliers; on fixed variables (equal bounds, not in
            the step) those that make the stationarity hold there, as Ipopt reports them:
            ``r = grad f + J^T y``, ``z_lower = max(r, 0)``, ``z_upper = max(-r, 0)``.
        status: `IpmStatus` code.
        iterations, objective, constr_viol (unscaled, original bounds), dual_inf, compl,
        error (scaled optimality error), mu, passes (evaluations of the objective and
        constraints: the initial point and every line-search trial), derivative_passes
        (evaluations of the gradient and Jacobian, and of the Hessian with ``hessian="exact"``:
        one at the initial point and one at each accepted point).
        history: (max_iter + 1, 5) per iteration: objective, constr_viol, dual_inf, log10 mu,
            primal step size (NaN after the last iteration). The mu of row k is the barrier
            parameter chosen at iterate k for the step that leaves it; Ipopt's iteration k
            reports the one of the step that led to iterate k, so the same barrier path shows
            one row later in Ipopt's history (row 0: Ipopt's initial mu, here the first step's).
    """

    x: jax.Array
    y: jax.Array
    z_lower: jax.Array
    z_upper: jax.Array
    status: jax.Array
    iterations: jax.Array
    objective: jax.Array
    constr_viol: jax.Array
    dual_inf: jax.Array
    compl: jax.Array
    error: jax.Array
    mu: jax.Array
    passes: jax.Array
    derivative_passes: jax.Array
    history: jax.Array


class _Problem(NamedTuple):
    """Bounds and masks, fixed for one solve."""

    xl: jax.Array
    xu: jax.Array
    cl: jax.Array
    cu: jax.Array
    free: jax.Array  # (K, n) bool
    has_xl: jax.Array
    has_xu: jax.Array
    eq: jax.Array  # (K, m) bool active equality rows
    ineq: jax.Array  # active inequality rows with at least one finite bound
    has_sl: jax.Array
    has_su: jax.Array
    tols: _Tolerances  # the run-time options (`IpmOptions.RUNTIME_FIELDS`)


class _State(NamedTuple):
    """The loop's carry. Each pass of the loop evaluates the NLP once, at the trial point
    ``x + alpha dx``: accepted, it becomes the iterate and the next direction is computed;
    rejected, alpha is halved (so the program holds one copy of the NLP's functions)."""

    # iterate and its first-order data
    x: jax.Array
    s: jax.Array
    y: jax.Array
    zl: jax.Array
    zu: jax.Array
    vl: jax.Array
    vu: jax.Array
    f: jax.Array
    c: jax.Array
    grad: jax.Array
    J: jax.Array  # (nnz,) the constraint Jacobian's nonzeros (`kkt.JacobianPattern`)
    # direction from the iterate, and the line search along it
    dx: jax.Array
    ds: jax.Array
    dy: jax.Array
    dzl: jax.Array
    dzu: jax.Array
    dvl: jax.Array
    dvu: jax.Array
    alpha: jax.Array
    alpha_dual: jax.Array
    trials: jax.Array
    phi0: jax.Array
    theta0: jax.Array
    slope: jax.Array
    # filter and barrier
    filter: jax.Array  # (F, 2) (theta, phi) pairs, +inf where empty
    n_filter: jax.Array
    theta_min: jax.Array
    theta_max: jax.Array
    mu: jax.Array
    tau: jax.Array  # fraction to the boundary for the next direction
    mu_max: jax.Array
    free_mode: jax.Array  # adaptive strategy: mu from the LOQO rule (True) or monotone (False)
    refs: jax.Array  # (4,) KKT errors of the last accepted free-mode iterates
    mu_filter: jax.Array  # (F, 2) (objective, violation) of free-mode iterates, +inf where empty
    H: jax.Array  # (K, 2n, 2n) with hessian="bfgs" (its state) or "exact" (of the current direction), else empty
    scaled: jax.Array  # (K,) bool: the element's BFGS matrix got its initial scaling
    S: jax.Array  # (l, K, n) limited-memory BFGS steps, oldest first
    Y: jax.Array  # (l, K, n) ... and Lagrangian gradient differences
    used: jax.Array  # (l,) bool
    lsigma: jax.Array  # scaled identity of the limited-memory matrix
    lskip: jax.Array  # successive limited-memory updates skipped
    # the Newton matrix of the current direction, kept for second-order corrections
    fac_diag: jax.Array  # (K, n, n) block Cholesky factor
    fac_sub: jax.Array
    delta_c: jax.Array
    delta_w: jax.Array  # of the current direction's factorization (0 when none was needed)
    delta_w_last: jax.Array  # the last positive delta_w of any factorization (Algorithm IC's)
    # bookkeeping
    first: jax.Array
    it: jax.Array
    status: jax.Array
    ls_fail: jax.Array
    history: jax.Array


#: Ipopt's mu_min when the option is not given (its catalog's default)
_MU_MIN = 1e-11


def _ipopt_mu_min(tol, compl_inf_tol, xp):
    """Ipopt's adaptive update's mu_min when the option is not given: its default, or half the
    tighter of ``tol`` and ``compl_inf_tol`` where that is smaller (measured with the bundled
    Ipopt: at tol 1e-13 its mu reaches 5e-14)."""
    return xp.minimum(_MU_MIN, 0.5 * xp.minimum(tol, compl_inf_tol))


def _safe(num, den, mask):
    return jnp.where(mask, num / jnp.where(mask, den, 1.0), 0.0)


def _members_apart_on_cpu(solve: Any, vectorize_on_cpu: bool = False) -> Any:
    """``solve(x0, theta, tols)`` whose batching rule, on a CPU, runs the members apart
    (`IpmOptions.cpu_batch`; ``vectorize_on_cpu``: vectorize there too).

    Under ``jax.vmap`` the vectorized solve steps its members together: every member runs the
    slowest member's iterations (masked), every batched loop (line search, inertia correction)
    runs to its longest member's trials, and XLA's CPU code runs the Riccati sweeps' small
    products several times slower vectorized than member after member (``bench/vmap_cpu.py``).
    On a CPU the batch is instead ``lax.map`` of the unbatched solve: the members one after
    another in the same program, each stopping at its own last iteration, with the results of
    the one-problem program; with several CPU devices (`jtraj.config.split_cpu`, one per core)
    the batch is split over them (`_split_over_devices`), and each runs its share so. Elsewhere
    (GPU) the batch is vectorized. `lax.platform_dependent` picks one per platform when the
    program is lowered, so one ``jax.vmap(ipm.solve)`` serves both.

    Measured (`bench/replicates.py --strategies vmap,threads,vectorized`, big_jump, 10
    replicates at sigma 0.1, 2-core CPU, one run): the vectorized batch took 84.1 s, this
    31.5 s. Two lanes of members side by side in the program (two ``lax.map``s, which XLA's
    CPU runtime may run on two threads) took 33.9 s and compiled in 109 s, against 31.4 s and
    81 s for one lane. Split over two CPU devices instead (2026-12-01, a faster day of the same
    machine, ``--no-ipopt``): 12.41 s against 19.15 s on one device, ten one-problem solves
    17.8-19.1 s; the shares were 131 and 159 iterations, so the split cannot beat 159/290 of
    one lane."""
    batchable = jax.custom_batching.custom_vmap(solve)

    @batchable.def_vmap
    def rule(axis_size, in_batched, *args):
        in_axes = tuple(jax.tree.map(lambda b: 0 if b else None, in_batched))

        def vectorized(*args):
            return jax.vmap(solve, in_axes=in_axes)(*args)

        def one_after_another(*args):
            flat, tree = jax.tree.flatten(args)
            batched = jax.tree.leaves(in_batched)

            def member(leaves):
                it = iter(leaves)
                return solve(*jax.tree.unflatten(tree, [next(it) if b else a for a, b in zip(flat, batched)]))

            return lax.map(member, [a for a, b in zip(flat, batched) if b])

        if vectorize_on_cpu:
            out = vectorized(*args)
        elif len(devices := _batch_devices()) > 1:
            out = _split_over_devices(one_after_another, devices, axis_size, args, in_batched)
        else:
            out = lax.platform_dependent(*args, cpu=one_after_another, default=vectorized)
        return out, jax.tree.map(lambda _: True, out)

    return batchable


def _batch_devices() -> list:
    """The devices a vmapped solve splits its batch over: JAX's CPU devices when it computes on
    the CPU (`jtraj.config.split_cpu`: one per core), else none (an accelerator vectorizes)."""
    return jax.local_devices(backend="cpu") if jax.default_backend() == "cpu" else []


def _split_over_devices(batch: Any, devices: list, size: int, args: tuple, in_batched: tuple) -> Any:
    """``batch(*args)`` (batched along axis 0 where ``in_batched``) with the batch split in
    contiguous shares over ``devices`` (`jax.shard_map`; no more devices than members): each
    device runs ``batch`` of its share, all at once, so the one program computes on every CPU
    device (`jtraj.config.split_cpu`: one per core). A batch that does not divide is padded
    with copies of its first member, whose results are dropped."""
    from jax.sharding import Mesh, PartitionSpec

    devices = devices[: min(len(devices), size)]
    count = len(devices)
    pad = -size % count
    in_batched = tuple(in_batched)
    spec = jax.tree.map(lambda b: PartitionSpec("batch") if b else PartitionSpec(), in_batched)

    def padded(a, b):
        return jnp.concatenate([a, jnp.repeat(a[:1], pad, axis=0)]) if b and pad else a

    args = jax.tree.map(padded, args, in_batched)
    mesh = Mesh(np.asarray(devices), ("batch",))
    # each device's share is its own problem: no collectives, and no check of the loops'
    # carries for values that vary over the mesh (every carry does)
    out = jax.shard_map(batch, mesh=mesh, in_specs=spec, out_specs=PartitionSpec("batch"), check_vma=False)(*args)
    return jax.tree.map(lambda a: a[:size], out) if pad else out


def _require_knot_nlp(nlp: Any, caller: str) -> None:
    """TypeError unless ``nlp`` is a `jtraj.nlp.KnotNLP`: this solver works on its knot
    structure (`StageView`'s blocks, the NLP's ``solver_programs``), which an NLP with only the
    functions Ipopt takes lacks (it failed with a bare AttributeError)."""
    if not isinstance(nlp, KnotNLP):
        raise TypeError(
            f"{caller}: nlp of type {type(nlp).__name__}: expected a jtraj.nlp.KnotNLP (jtraj's solver works on its knot structure; "
            "solver='ipopt' takes any NLP with the documented functions)"
        )


#: guards the shared IPMs of an NLP (`IPM.__init__`)
_SHARED_LOCK = threading.Lock()


class IPM:
    """The interior-point solver for one `KnotNLP` (its shapes are static; bounds, initial
    guess, parameters theta and the tolerances are inputs, so new values do not recompile).

    ``IPM(nlp, options).solve(x0, theta)`` runs the jitted program ``ipm.program(x0, theta,
    tolerances)``; ``jax.vmap(ipm.solve)`` batches it. IPMs of one NLP whose options differ
    only in `IpmOptions.RUNTIME_FIELDS` and ``cpu_batch`` share one program (and its
    compilations; ``cpu_batch`` picks its batching rule under vmap).
    """

    def __init__(self, nlp, options: IpmOptions | None = None):
        self.options = options or IpmOptions()
        self.tolerances = self.options.runtime_part()
        # {options' compiled part: the IPM that traces the program}, kept on the NLP, so that
        # the programs go with it (measured: a registry keyed weakly by the NLP, whose IPMs
        # refer back to it, kept every sweep group's NLP and programs, about 6,300 memory maps
        # per big_jump group, until a process met Linux's default limit of 65,530 and crashed
        # in LLVM)
        _require_knot_nlp(nlp, "IPM")
        key = ("ipm", self.options.compiled_part())
        shared = nlp.solver_programs
        # one owner per key also when solves start side by side in threads (a vmapped
        # `jtraj.differentiable`): each thread's IPM had its own compiled programs, so each
        # compiled the program again
        with _SHARED_LOCK:
            owner = shared.get(key)
            if owner is None:
                # this IPM traces the program; its options' run-time fields are never read there
                self.view = StageView(nlp)
                if self.options.hessian == "exact":
                    self.view.prepare_hessian()
                # the one program, under either batching rule of `IpmOptions.cpu_batch`
                self.programs = {batch: jax.jit(_members_apart_on_cpu(self._solve, batch == "vectorized")) for batch in ("sequential", "vectorized")}
                self.compiled: dict[str, Any] = {}  # ahead-of-time compiled programs (`JtrajSolver`)
                shared[key] = owner = self
            else:
                self.view, self.programs, self.compiled = owner.view, owner.programs, owner.compiled
        self.program = self.programs[self.options.cpu_batch]
        self._registry = (shared, key, owner)

    def forget_if_uncompiled(self) -> None:
        """Take this IPM's program off its NLP when it has compiled nothing (`JtrajSolver`
        calls it when lowering or compiling the program raised): kept, it stood for every later
        IPM of the NLP whose options compare equal, so one failed compile failed them all."""
        shared, key, owner = self._registry
        with _SHARED_LOCK:
            if not owner.compiled and shared.get(key) is owner:
                del shared[key]

    def solve(self, x0: jax.Array, theta: Any = None) -> IpmResult:
        """Solve from x0 (K, n) at theta (the jitted program with this IPM's tolerances)."""
        return self.program(x0, theta, self.tolerances)

    # ------------------------------------------------------------------ pieces
    def _problem(self, theta, tols: _Tolerances) -> _Problem:
        view = self.view
        xl, xu, cl, cu = view.bounds(theta)
        free = ~(xl == xu)
        has_xl = free & jnp.isfinite(xl)
        has_xu = free & jnp.isfinite(xu)
        active = jnp.asarray(view.active)
        eq = active & (cl == cu)
        has_sl = active & ~eq & jnp.isfinite(cl)
        has_su = active & ~eq & jnp.isfinite(cu)
        ineq = has_sl | has_su
        return _Problem(xl, xu, cl, cu, free, has_xl, has_xu, eq, ineq, has_sl, has_su, tols)

    @staticmethod
    def _push(v, lo, hi, has_lo, has_hi, push, frac):
        """Ipopt's initial-point rule: move v at least a little inside [lo, hi]."""
        width = jnp.where(has_lo & has_hi, hi - lo, jnp.inf)
        lo_f = jnp.where(has_lo, lo, 0.0)
        hi_f = jnp.where(has_hi, hi, 0.0)
        p_lo = jnp.minimum(push * jnp.maximum(1.0, jnp.abs(lo_f)), frac * width)
        p_hi = jnp.minimum(push * jnp.maximum(1.0, jnp.abs(hi_f)), frac * width)
        v = jnp.where(has_lo, jnp.maximum(v, lo_f + p_lo), v)
        return jnp.where(has_hi, jnp.minimum(v, hi_f - p_hi), v)

    def _residuals(self, p: _Problem, st: _State, mu):
        """Dual infeasibility, primal infeasibility (C - t) and complementarities at st."""
        jty = kkt._apply_JT(st.J, None, st.y, self.view.pattern)
        r_x = jnp.where(p.free, st.grad + jty - st.zl + st.zu, 0.0)
        r_s = jnp.where(p.ineq, -st.y - st.vl + st.vu, 0.0)
        t = jnp.where(p.eq, p.cl, st.s)
        r_c = jnp.where(p.eq | p.ineq, st.c - t, 0.0)
        cl_x = jnp.where(p.has_xl, (st.x - p.xl) * st.zl - mu, 0.0)
        cu_x = jnp.where(p.has_xu, (p.xu - st.x) * st.zu - mu, 0.0)
        cl_s = jnp.where(p.has_sl, (st.s - p.cl) * st.vl - mu, 0.0)
        cu_s = jnp.where(p.has_su, (p.cu - st.s) * st.vu - mu, 0.0)
        return r_x, r_s, r_c, (cl_x, cu_x, cl_s, cu_s)

    def _error(self, p: _Problem, st: _State, mu, nlp: bool = False):
        """(scaled error, dual_inf, primal_inf, compl) as in Ipopt's optimality test.

        ``nlp=True`` (the NLP's error, mu = 0): the primal part is the violation of the rows'
        bounds by c(x), as Ipopt's ``curr_nlp_error`` (its ``curr_nlp_constraint_violation``);
        otherwise (a barrier problem's error) it is the residual ``c - s`` of the slacks' rows,
        as its ``curr_barrier_error``. The two differ where c(x) is inside its bounds but the
        slack has not caught up."""
        o = self.options
        r_x, r_s, r_c, compl = self._residuals(p, st, mu)
        dual_inf = jnp.maximum(jnp.max(jnp.abs(r_x)), jnp.max(jnp.abs(r_s)))
        primal_inf = self._constr_viol(p, st.c) if nlp else jnp.max(jnp.abs(r_c))
        compl_inf = jnp.max(jnp.stack([jnp.max(jnp.abs(c)) for c in compl]))
        n_rows = jnp.sum(p.eq | p.ineq)
        z_sum = sum(jnp.sum(jnp.abs(jnp.where(mask, z, 0.0))) for z, mask in ((st.zl, p.has_xl), (st.zu, p.has_xu), (st.vl, p.has_sl), (st.vu, p.has_su)))
        n_bounds = jnp.sum(p.has_xl) + jnp.sum(p.has_xu) + jnp.sum(p.has_sl) + jnp.sum(p.has_su)
        y_sum = jnp.sum(jnp.abs(jnp.where(p.eq | p.ineq, st.y, 0.0)))
        s_d = jnp.maximum(o.s_max, (y_sum + z_sum) / jnp.maximum(n_rows + n_bounds, 1)) / o.s_max
        s_c = jnp.maximum(o.s_max, z_sum / jnp.maximum(n_bounds, 1)) / o.s_max
        err = jnp.maximum(jnp.maximum(dual_inf / s_d, primal_inf), compl_inf / s_c)
        return err, dual_inf, primal_inf, compl_inf

    def _constr_viol(self, p: _Problem, c):
        """Unscaled violation of the original row bounds (Ipopt's constr_viol)."""
        active = p.eq | p.ineq
        v = jnp.maximum(jnp.maximum(jnp.where(active, p.cl - c, 0.0), jnp.where(active, c - p.cu, 0.0)), 0.0)
        return jnp.max(jnp.where(active, v, 0.0))

    def _barrier(self, p: _Problem, x, s, mu):
        def logs(v, b, mask, sign):
            return jnp.sum(jnp.where(mask, jnp.log(jnp.where(mask, sign * (v - b), 1.0)), 0.0))

        return -mu * (logs(x, p.xl, p.has_xl, 1.0) + logs(x, p.xu, p.has_xu, -1.0) + logs(s, p.cl, p.has_sl, 1.0) + logs(s, p.cu, p.has_su, -1.0))

    def _infeasibility_l1(self, p: _Problem, c, s):
        t = jnp.where(p.eq, p.cl, s)
        return jnp.sum(jnp.where(p.eq | p.ineq, jnp.abs(c - t), 0.0))

    @staticmethod
    def _max_step(v, dv, lo, hi, has_lo, has_hi, tau):
        """Largest alpha in (0, 1] with v + alpha dv keeping a fraction tau of the distances."""
        a_lo = jnp.where(has_lo & (dv < 0), -tau * (v - lo) / jnp.where(dv < 0, dv, -1.0), jnp.inf)
        a_hi = jnp.where(has_hi & (dv > 0), tau * (hi - v) / jnp.where(dv > 0, dv, 1.0), jnp.inf)
        return jnp.minimum(1.0, jnp.minimum(jnp.min(a_lo), jnp.min(a_hi)))

    @staticmethod
    def _max_dual_step(z, dz, mask, tau):
        a = jnp.where(mask & (dz < 0), -tau * z / jnp.where(dz < 0, dz, -1.0), jnp.inf)
        return jnp.minimum(1.0, jnp.min(a))

    def _step_bounds(self, p: _Problem, st: _State, step, tau):
        """(primal, dual) fraction-to-the-boundary step lengths of ``step`` = (dx, ds, dy, dzl,
        dzu, dvl, dvu) from the iterate ``st``."""
        dx, ds, _, dzl, dzu, dvl, dvu = step
        a_primal = jnp.minimum(self._max_step(st.x, dx, p.xl, p.xu, p.has_xl, p.has_xu, tau), self._max_step(st.s, ds, p.cl, p.cu, p.has_sl, p.has_su, tau))
        a_dual = jnp.min(jnp.stack([self._max_dual_step(z, dz, mk, tau) for z, dz, mk in ((st.zl, dzl, p.has_xl), (st.zu, dzu, p.has_xu), (st.vl, dvl, p.has_sl), (st.vu, dvu, p.has_su))]))
        return a_primal, a_dual

    def _element_grad(self, grad, A, B, y):
        """(K, 2n) gradient of each element's Lagrangian terms: the cost's gradient at knot k
        (costs are assigned to the knot they are differentiated by) and y_k . C_k."""
        return jnp.concatenate([grad + jnp.einsum("kmn,km->kn", A, y), jnp.einsum("kmn,km->kn", B, y)], axis=1)

    def _bfgs(self, H, scaled, s_el, y_el):
        """Damped BFGS update of each element Hessian (Powell: s^T y >= 0.2 s^T H s keeps H
        positive definite); elements whose step is (numerically) zero are unchanged.

        An element's first usable pair (s^T y > 0) first replaces its initial identity by
        ``(y^T y / s^T y) I`` (Nocedal and Wright, eq. 6.20), so every direction starts at the
        element's measured curvature rather than at 1: the whole-body problems' Lagrangian
        curvature is many orders of magnitude away from 1. Returns (H, scaled)."""

        def one(Hk, done, sk, yk):
            sy0 = sk @ yk
            usable = (sy0 > 1e-12 * jnp.sqrt((sk @ sk) * (yk @ yk))) & (sy0 > 0)
            gamma = jnp.clip((yk @ yk) / jnp.where(usable, sy0, 1.0), 1e-8, 1e8)
            rescale = usable & ~done
            Hk = jnp.where(rescale, gamma * jnp.eye(Hk.shape[0], dtype=Hk.dtype), Hk)
            Hs = Hk @ sk
            sHs = sk @ Hs
            sy = sk @ yk
            theta = jnp.where(sy >= 0.2 * sHs, 1.0, 0.8 * sHs / jnp.where(sHs - sy != 0, sHs - sy, 1.0))
            r = theta * yk + (1.0 - theta) * Hs
            sr = sk @ r
            ok = (sHs > 1e-14 * (1.0 + jnp.sum(jnp.abs(Hk)))) & (sr > 0) & jnp.isfinite(sr)
            Hn = Hk - jnp.outer(Hs, Hs) / jnp.where(ok, sHs, 1.0) + jnp.outer(r, r) / jnp.where(ok, sr, 1.0)
            return jnp.where(ok, 0.5 * (Hn + Hn.T), Hk), done | rescale

        if not self.options.bfgs_scaling:
            scaled = jnp.ones_like(scaled)
        return jax.vmap(one)(H, scaled, s_el, y_el)

    # ------------------------------------------------------------------ the solve
    def _start(self, x0: jax.Array, theta: Any = None, tols: _Tolerances | None = None) -> tuple[_Problem, _State]:
        """The problem's bounds and masks, and the loop's first state (its first pass
        evaluates x0); ``tols`` None: this IPM's own."""
        tols = self.tolerances if tols is None else tols
        o = self.options
        view = self.view
        K, n, m = view.K, view.n, view.m
        l = o.lbfgs_memory if o.hessian == "lbfgs" else 1  # noqa: E741
        p = self._problem(theta, tols)
        Z = jnp.asarray(x0, jnp.float64).reshape(K, n)
        Z = jnp.where(p.free, Z, jnp.where(jnp.isfinite(p.xl), p.xl, Z))
        Z = self._push(Z, p.xl, p.xu, p.has_xl, p.has_xu, o.bound_push, o.bound_frac)
        zx, zc = jnp.zeros((K, n)), jnp.zeros((K, m))
        ones_x, ones_c = jnp.ones((K, n)), jnp.ones((K, m))
        zero = jnp.zeros(())
        # the factor's off-diagonal rows: all n, or the coupled columns (`kkt.factor`)
        coupled = kkt.coupled_columns(view.pattern, block_hessian=o.hessian != "lbfgs")
        st = _State(
            x=Z, s=zc, y=zc,
            zl=jnp.where(p.has_xl, ones_x, 0.0), zu=jnp.where(p.has_xu, ones_x, 0.0),
            vl=jnp.where(p.has_sl, ones_c, 0.0), vu=jnp.where(p.has_su, ones_c, 0.0),
            f=zero, c=zc, grad=zx, J=jnp.zeros((view.pattern.nnz,)),
            dx=zx, ds=zc, dy=zc, dzl=zx, dzu=zx, dvl=zc, dvu=zc,
            alpha=zero, alpha_dual=zero, trials=jnp.zeros((), jnp.int32), phi0=zero, theta0=zero, slope=zero,
            filter=jnp.full((self.FILTER_SIZE, 2), jnp.inf), n_filter=jnp.zeros((), jnp.int32),
            theta_min=zero, theta_max=zero, mu=jnp.asarray(o.mu_init if o.mu_strategy == "monotone" else 1.0, jnp.float64), tau=jnp.asarray(o.tau_min, jnp.float64),
            mu_max=jnp.asarray(np.inf if o.mu_max is None else o.mu_max, jnp.float64),
            free_mode=jnp.asarray(o.mu_strategy == "adaptive"), refs=jnp.full((4,), jnp.inf),
            mu_filter=jnp.full((self.FILTER_SIZE, 2), jnp.inf),
            # element Hessians are state only for the partitioned BFGS (the others rebuild them)
            H=jnp.broadcast_to(o.bfgs_init * jnp.eye(2 * n), (K, 2 * n, 2 * n)) if o.hessian == "bfgs" else jnp.zeros((K, 2 * n, 2 * n)) if o.hessian == "exact" else jnp.zeros((0,)), scaled=jnp.zeros((K,), bool), delta_w=zero, delta_w_last=zero,
            S=jnp.zeros((l, K, n)), Y=jnp.zeros((l, K, n)), used=jnp.zeros((l,), bool), lsigma=jnp.asarray(o.lbfgs_init_val, jnp.float64),
            lskip=jnp.zeros((), jnp.int32),
            fac_diag=jnp.zeros((K, n, n)), fac_sub=jnp.zeros((K, n if coupled is None else coupled.size, n)), delta_c=zero,
            first=jnp.asarray(True), it=jnp.zeros((), jnp.int32),
            status=jnp.asarray(int(IpmStatus.RUNNING), jnp.int32), ls_fail=jnp.zeros((), jnp.int32),
            history=jnp.full((o.max_iter + 1, 5), jnp.nan),
        )
        return p, st

    def _finish(self, p: _Problem, st: _State, passes: jax.Array) -> IpmResult:
        """The result of the state; ``passes`` is the (values, derivatives) evaluation count."""
        err, dual_inf, constr_viol, compl = self._error(p, st, 0.0, nlp=True)
        # fixed variables have no bound multipliers in the loop (they leave the step); reported,
        # as Ipopt's (fixed_variable_treatment=make_parameter), are those that close the
        # stationarity there: grad f + J^T y = z_L - z_U, the one of the sign it needs
        r = st.grad + kkt._apply_JT(st.J, None, st.y, self.view.pattern)
        zl = jnp.where(p.free, st.zl, jnp.maximum(r, 0.0))
        zu = jnp.where(p.free, st.zu, jnp.maximum(-r, 0.0))
        return IpmResult(
            x=st.x, y=st.y, z_lower=zl, z_upper=zu, status=st.status, iterations=st.it,
            objective=st.f, constr_viol=constr_viol, dual_inf=dual_inf, compl=compl,
            error=err, mu=st.mu, passes=passes[0], derivative_passes=passes[1], history=st.history,
        )

    def _solve(self, x0: jax.Array, theta: Any, tols: _Tolerances) -> IpmResult:
        p, st = self._start(x0, theta, tols)

        def cond(carry):
            st, passes = carry
            return (st.status == int(IpmStatus.RUNNING)) & (passes[0] < self._max_passes)

        o = self.options
        # evaluations so far: (objective and constraints, their derivatives)
        none = jnp.zeros((2,), jnp.int32)
        if o.feasibility_polish_tol is None:

            def body(carry):
                st, passes = carry
                return self._iteration(p, st, passes, theta)

            st, passes = lax.while_loop(cond, body, (st, none))
            return self._finish(p, st, passes)

        # feasibility polish (IpmOptions.feasibility_polish_tol): from the first converged
        # iterate above the tolerance, up to feasibility_polish_iter more iterations are taken,
        # whether or not each passes the convergence test, and the converged iterate of least
        # violation seen is kept aside
        converged, running = int(IpmStatus.CONVERGED), int(IpmStatus.RUNNING)
        pick = lambda flag, a, b: jax.tree.map(lambda u, v: jnp.where(flag, u, v), a, b)  # noqa: E731

        def polish_body(carry):
            st, passes, saved, polishing, start = carry
            # while polishing, an iterate above the tolerance steps onto the constraints
            # (`_projection`) instead of along its Newton direction
            # (a loop run once or not at all, as the second-order corrections': under vmap only
            # when some member projects)
            project = polishing & (self._constr_viol(p, st.c) > p.tols.feasibility_polish_tol)
            st = lax.while_loop(lambda c: c[0], lambda c: (jnp.asarray(False), self._projection(p, c[1])), (project, st))[1]
            # no projection to take (the factorization at a converged iterate is not checked by
            # the inertia correction's status): the polish ends, the kept iterate handed back
            unusable = project & ~(jnp.all(jnp.isfinite(st.dx)) & jnp.all(jnp.isfinite(st.ds)))
            st = st._replace(status=jnp.where(unusable, int(IpmStatus.NUMERICAL_ERROR), st.status).astype(jnp.int32))
            # (a projection's trial is not corrected by a second-order correction, a Newton step)
            new, passes = self._iteration(p, st, passes, theta, correct=~project)
            ok = new.status == converged
            viol = self._constr_viol(p, new.c)
            loose = ok & (viol > p.tols.feasibility_polish_tol)
            start = jnp.where(loose & ~polishing, new.it, start)
            saved = pick(ok & (~polishing | (viol < self._constr_viol(p, saved.c))), new, saved)
            polishing = polishing | loose
            # go on from a loose converged iterate or one that fails the test; a failure (line
            # search, max_iter) or the polish's last iteration hands back the iterate kept aside,
            # and a converged iterate within the tolerance ends it
            more = polishing & (loose | (new.status == running)) & (new.it - start < p.tols.feasibility_polish_iter) & (new.it < o.max_iter)
            new = pick(polishing & ~more & ~(ok & ~loose), saved, new)
            return new._replace(status=jnp.where(more, running, new.status).astype(jnp.int32)), passes, saved, polishing, start

        st, passes, saved, polishing, _ = lax.while_loop(
            lambda carry: cond(carry[:2]), polish_body, (st, none, st, jnp.asarray(False), jnp.zeros((), jnp.int32))
        )
        # polished to the limit without reaching the tolerance: the converged iterate of lower
        # violation (the loop also ends, RUNNING, when the evaluation bound is reached)
        back = polishing & ((st.status != converged) | (self._constr_viol(p, saved.c) < self._constr_viol(p, st.c)))
        return self._finish(p, pick(back, saved, st), passes)

    @property
    def _max_passes(self) -> int:
        """Bound on evaluations of the objective and constraints: every iteration's full line
        search."""
        return (self.options.max_iter + 1) * (self.options.max_line_search + 1 + self.options.max_soc)

    FILTER_SIZE = 64
    # Ipopt's filter line-search constants (Wächter & Biegler 2006, section 2.3 and Table 1)
    GAMMA_THETA, GAMMA_PHI, DELTA, S_THETA, S_PHI = 1e-5, 1e-8, 1.0, 1.1, 2.3  # eta_phi: IpmOptions.armijo
    ROUNDING = 10.0 * float(np.finfo(np.float64).eps)  # Ipopt's Compare_le tolerance, relative

    @classmethod
    def _le(cls, lhs, rhs, ref):
        """``lhs <= rhs`` up to a rounding error of 10 eps of the reference value ``ref``, as
        Ipopt's acceptance tests compare (its ``Compare_le``)."""
        return lhs - rhs <= cls.ROUNDING * jnp.abs(ref)

    def _measures(self, p: _Problem, x, s, f, c, mu):
        """(theta, phi): l1 infeasibility and barrier objective."""
        return self._infeasibility_l1(p, c, s), f + self._barrier(p, x, s, mu)

    def _iteration(self, p: _Problem, st: _State, passes: jax.Array, theta, correct: jax.Array | bool = True) -> tuple[_State, jax.Array]:
        """One iteration: the line search (values only at each trial point), then the
        derivatives at the accepted point and the next direction (`_advance`). ``correct``
        False: no second-order corrections (the polish's projections).

        Only an accepted point needs the Jacobian, so a rejected trial costs one evaluation of
        the objective and constraints. Under ``vmap`` the line search is its own loop, so the
        derivatives and the Newton step run once per iteration for the whole batch, not once per
        trial of its slowest member (a batched ``cond`` computes both branches). ``passes``
        counts the evaluations so far, (objective and constraints, their derivatives)."""
        o = self.options
        K, m = self.view.K, self.view.m
        zero = jnp.zeros(())
        false = jnp.asarray(False)
        # the loop carries what a trial changes (step length, trial count, status, a second-order
        # correction's step), not the state
        step0 = (st.dx, st.ds, st.dy, st.dzl, st.dzu, st.dvl, st.dvu)
        r_c0 = jnp.where(p.eq, st.c - p.cl, jnp.where(p.ineq, st.c - st.s, 0.0))
        soc0 = (false, false, jnp.zeros((), jnp.int32), jnp.zeros((K, m)), zero, step0, zero, zero)
        init = (st.alpha, st.trials, st.status, st.x, st.s, zero, jnp.zeros((K, m)), zero, false, false, false, passes, soc0)

        def trial_cond(ls):
            status, done, passes = ls[2], ls[8], ls[11]
            return (~done) & (status == int(IpmStatus.RUNNING)) & (passes[0] < self._max_passes)

        def trial_body(ls):
            alpha, trials, status, *_, passes, soc = ls
            in_soc, _, soc_k, c_soc, th_old, soc_step, a_soc, ad_soc = soc
            # the trial point: along the direction, or a second-order correction's step
            xt = st.x + jnp.where(in_soc, a_soc * soc_step[0], alpha * st.dx)
            s_t = st.s + jnp.where(in_soc, a_soc * soc_step[1], alpha * st.ds)
            ft, ct = self.view.values(xt, theta)
            # the first pass only evaluates the initial point; its slacks start inside their bounds
            s_first = jnp.where(p.ineq, self._push(ct, p.cl, p.cu, p.has_sl, p.has_su, o.bound_push, o.bound_frac), 0.0)
            s_t = jnp.where(st.first, s_first, s_t)
            th_t, ph_t = self._measures(p, xt, s_t, ft, ct, st.mu)
            finite = jnp.isfinite(th_t) & jnp.isfinite(ph_t)
            # a correction is judged with the first trial's alpha (Ipopt's alpha_primal_test)
            switching = (st.slope < 0) & (alpha * (-st.slope) ** self.S_PHI > self.DELTA * st.theta0 ** self.S_THETA)
            armijo = self._le(ph_t - st.phi0, o.armijo * alpha * st.slope, st.phi0)
            f_type = switching & (st.theta0 <= st.theta_min)
            sufficient = jnp.where(
                f_type, armijo,
                self._le(th_t, (1.0 - self.GAMMA_THETA) * st.theta0, st.theta0) | self._le(ph_t - st.phi0, -self.GAMMA_PHI * st.theta0, st.phi0),
            )
            # a filter entry rejects a point no better than it in both measures (Ipopt's
            # Filter::Acceptable: acceptable where one measure is at most the entry's)
            in_filter = jnp.any((th_t > st.filter[:, 0]) & (ph_t > st.filter[:, 1]))
            accept = finite & (th_t <= st.theta_max) & sufficient & ~in_filter
            # second-order corrections: after a rejected first trial that raised the violation,
            # then while each correction lowers it by kappa_soc (Wachter & Biegler, A-5.5 to 5.10)
            rejected = finite & ~accept & ~st.first
            start = rejected & ~in_soc & (trials == 0) & (o.max_soc > 0) & correct & (th_t >= st.theta0)
            more = rejected & in_soc & (soc_k < o.max_soc) & (th_t <= o.kappa_soc * th_old)
            do_soc = start | more
            r_t = jnp.where(p.eq, ct - p.cl, jnp.where(p.ineq, ct - s_t, 0.0))
            c_new = jnp.where(start, alpha * r_c0, a_soc * c_soc) + r_t
            # a loop run once or not at all rather than a `cond`: under ``vmap`` a batched `cond`
            # computes both branches, so every trial of every member would pay the correction's
            # KKT solve; the loop runs only when some member corrects
            _, soc_step, a_soc, ad_soc = lax.while_loop(
                lambda c: c[0], lambda c: (jnp.asarray(False), *self._soc_step(p, st, c_new)), (do_soc, soc_step, a_soc, ad_soc)
            )
            soc = (do_soc, in_soc, jnp.where(do_soc, soc_k + 1, soc_k).astype(jnp.int32), jnp.where(do_soc, c_new, c_soc), jnp.where(do_soc, th_t, th_old), soc_step, a_soc, ad_soc)
            give_up = finite & ~accept & ~do_soc & (trials + 1 >= o.max_line_search)
            advance = st.first | accept | give_up
            # a rejected trial halves the step (a non-finite one at the last trial stops the solve)
            status = jnp.where(advance | finite | (trials + 1 < o.max_line_search), status, int(IpmStatus.NUMERICAL_ERROR)).astype(jnp.int32)
            back = ~advance & ~do_soc
            alpha = jnp.where(back, 0.5 * alpha, alpha)
            trials = jnp.where(back, trials + 1, trials).astype(jnp.int32)
            # the filter is left as it is after a step where the switching condition and the
            # Armijo condition both hold, whichever test accepted it (Wächter & Biegler 2006,
            # step A-7; Ipopt's FilterLSAcceptor::UpdateForNextIteration): theta_min only picks
            # the test
            return (alpha, trials, status, xt, s_t, ft, ct, th_t, advance, switching & armijo, give_up & ~st.first, passes.at[0].add(1), soc)

        alpha, trials, status, xt, s_t, ft, ct, th_t, done, f_step, failed, passes, soc = lax.while_loop(trial_cond, trial_body, init)
        # the accepted point came from a correction: its step is the one taken (primal length
        # of the correction, y along it, bound multipliers by its own fraction to the boundary)
        taken = done & soc[1]
        pick = lambda a, b: jnp.where(taken, a, b)  # noqa: E731
        dx, ds, dy, dzl, dzu, dvl, dvu = jax.tree.map(pick, soc[5], step0)
        st = st._replace(
            alpha=pick(soc[6], alpha), alpha_dual=pick(soc[7], st.alpha_dual), trials=trials, status=status,
            dx=dx, ds=ds, dy=dy, dzl=dzl, dzu=dzu, dvl=dvl, dvu=dvu,
        )

        def accepted(st):
            gt, Jt = self.view.derivatives(xt, theta)
            return self._advance(p, st, (xt, s_t, ft, ct, gt, Jt, th_t), f_step, failed, theta)

        return lax.cond(done, accepted, lambda st: st, st), passes.at[1].add(done.astype(jnp.int32))

    def _advance(self, p: _Problem, st: _State, trial, f_step, failed, theta) -> _State:
        """Accept the trial point: update multipliers, Hessian, filter, barrier; test
        convergence; compute the next direction."""
        o = self.options
        xt, s_t, ft, ct, gt, Jt, th_t = trial
        first = st.first
        alpha, a_dual = st.alpha, st.alpha_dual
        mu = st.mu
        y = st.y + alpha * st.dy
        zl, zu = st.zl + a_dual * st.dzl, st.zu + a_dual * st.dzu
        vl, vu = st.vl + a_dual * st.dvl, st.vu + a_dual * st.dvu
        pattern = self.view.pattern
        Jt = jnp.where((p.eq | p.ineq).reshape(-1)[pattern.rows], Jt, 0.0)
        # the derivatives must be finite in the free variables only: a fixed variable leaves the
        # step (as with Ipopt's make_parameter), and a NaN or Inf in its column or gradient entry
        # (a norm's derivative at 0 on a fixed knot) is kept from the Newton system (`_newton_system`)
        derivs_finite = jnp.all(jnp.isfinite(jnp.where(p.free, gt, 0.0))) & jnp.all(jnp.isfinite(jnp.where(pattern.free_columns(p.free), Jt, 0.0)))
        H = st.H
        if o.hessian == "bfgs":
            # partitioned BFGS: element gradient differences at the new multipliers
            step = jnp.where(p.free, xt - st.x, 0.0)
            nxt = lambda a: jnp.concatenate([a[1:], jnp.zeros_like(a[:1])], axis=0)  # noqa: E731
            s_el = jnp.concatenate([step, nxt(step)], axis=1)
            free2 = jnp.concatenate([p.free, nxt(p.free)], axis=1)
            y_el = jnp.where(free2, self._element_grad(gt, *pattern.dense(Jt), y) - self._element_grad(st.grad, *pattern.dense(st.J), y), 0.0)
            H_new, scaled = self._bfgs(H, st.scaled, s_el, y_el)
            H = jnp.where(first, H, H_new)
            scaled = jnp.where(first, st.scaled, scaled)
        else:
            scaled = st.scaled
        lbfgs = (st.S, st.Y, st.used, st.lsigma, st.lskip)
        if o.hessian == "lbfgs":
            # Ipopt's limited-memory BFGS of the Lagrangian: pairs (x+ - x, grad L(x+, y+) -
            # grad L(x, y+)) on the free variables, skipped without enough curvature (s^T y <=
            # sqrt(eps) |s| |y|) or for a step of (numerically) zero, and the scaled identity
            # sigma = s^T y / s^T s of the newest pair ("scalar1"). As Ipopt's, after
            # lbfgs_max_skipping successive skips the memory is reset and the pair dropped.
            step = jnp.where(p.free, xt - st.x, 0.0)
            diff = jnp.where(p.free, gt + kkt._apply_JT(Jt, None, y, pattern) - st.grad - kkt._apply_JT(st.J, None, y, pattern), 0.0)
            sy, ss, yy = jnp.sum(step * diff), jnp.sum(step * step), jnp.sum(diff * diff)
            eps = jnp.finfo(step.dtype).eps
            reset = (~first) & (st.lskip >= o.lbfgs_max_skipping)
            update = (~first) & ~reset
            keep = update & (jnp.max(jnp.abs(step)) >= 100.0 * eps) & (sy > jnp.sqrt(eps) * jnp.sqrt(ss * yy))
            push = lambda hist, new, empty: jnp.where(reset, empty, jnp.where(keep, jnp.concatenate([hist[1:], new[None]], axis=0), hist))  # noqa: E731
            lsigma = jnp.where(keep, jnp.clip(sy / jnp.where(keep, ss, 1.0), o.lbfgs_init_min, o.lbfgs_init_max), jnp.where(reset, o.lbfgs_init_val, st.lsigma))
            lskip = jnp.where(update & ~keep, st.lskip + 1, 0).astype(jnp.int32)
            lbfgs = (push(st.S, step, jnp.zeros_like(st.S)), push(st.Y, diff, jnp.zeros_like(st.Y)), push(st.used, jnp.asarray(True), jnp.zeros_like(st.used)), lsigma, lskip)

        # the bound multipliers kept within kappa_sigma of mu / distance, as Ipopt's
        # `correct_bound_multiplier` when it accepts a trial point (not at the initial point):
        # in the adaptive strategy's free mode with the trial point's average complementarity
        # (at most 1e3) as mu, else the barrier parameter. (Clamped at the initial point too, and
        # with the step's mu, a run with kappa_sigma = 10 took 25 iterations where Ipopt takes 17.)
        trial_compl = self._complementarity(p, st._replace(x=xt, s=s_t, zl=zl, zu=zu, vl=vl, vu=vu))[0]
        mu_clamp = jnp.where(st.free_mode, jnp.minimum(trial_compl, 1e3), mu)

        def clamp(z, dist, mask):
            dist = jnp.where(mask, dist, 1.0)
            clamped = jnp.clip(z, mu_clamp / (o.kappa_sigma * dist), o.kappa_sigma * mu_clamp / dist)
            return jnp.where(mask, jnp.where(first, z, clamped), 0.0)

        zl = clamp(zl, xt - p.xl, p.has_xl)
        zu = clamp(zu, p.xu - xt, p.has_xu)
        vl = clamp(vl, s_t - p.cl, p.has_sl)
        vu = clamp(vu, p.cu - s_t, p.has_su)
        # filter: a step that was not an Armijo step on phi adds the old point's envelope
        add = (~first) & (~f_step)
        entry = jnp.stack([(1.0 - self.GAMMA_THETA) * st.theta0, st.phi0 - self.GAMMA_PHI * st.theta0])
        filt = jnp.where(add, st.filter.at[st.n_filter % self.FILTER_SIZE].set(entry), st.filter)
        n_filter = st.n_filter + add.astype(jnp.int32)
        theta_min = jnp.where(first, 1e-4 * jnp.maximum(1.0, th_t), st.theta_min)
        theta_max = jnp.where(first, 1e4 * jnp.maximum(1.0, th_t), st.theta_max)
        it = st.it + (~first).astype(jnp.int32)
        new = st._replace(
            x=xt, s=s_t, y=y, zl=zl, zu=zu, vl=vl, vu=vu, f=ft, c=ct, grad=gt, J=Jt, H=H, scaled=scaled,
            S=lbfgs[0], Y=lbfgs[1], used=lbfgs[2], lsigma=lbfgs[3], lskip=lbfgs[4],
            filter=filt, n_filter=n_filter, theta_min=theta_min, theta_max=theta_max,
            first=jnp.asarray(False), it=it, trials=jnp.zeros((), jnp.int32),
            ls_fail=jnp.where(failed, st.ls_fail + 1, 0).astype(jnp.int32),
        )

        # convergence error (at mu = 0, so the barrier update below does not change it)
        # (the NLP error's primal part is the rows' violation, the convergence test's too)
        err, dual_inf, viol, compl = self._error(p, new, 0.0, nlp=True)
        mu_new, free_mode, refs, mu_max, mu_filter = self._update_mu(p, new, first, err)
        # Ipopt's fraction to the boundary, with either oracle: from the NLP error in free mode,
        # from mu otherwise (the LOQO oracle's free mode took 1 - mu: 15 iterations on HS071
        # where Ipopt takes 10, and 10 with this rule)
        tau = jnp.where(free_mode, jnp.maximum(o.tau_min, 1.0 - err), jnp.maximum(o.tau_min, 1.0 - mu_new))
        if o.mu_oracle == "quality-function":
            # in free mode `_direction` chooses mu, and the factorization before it sees the
            # previous one (as Ipopt's regularization does)
            mu_new = jnp.where(free_mode & (o.mu_strategy == "adaptive"), mu, mu_new)
        if o.mu_strategy == "adaptive":
            # as Ipopt's adaptive update: without bounds there is no complementarity to choose
            # mu from (its average is 0, and so would be mu_max and mu): mu_min and tau_min
            none = self._n_bounds(p) == 0
            mu_new, tau, free_mode = jnp.where(none, self._mu_min(p), mu_new), jnp.where(none, o.tau_min, tau), free_mode & ~none
        new = new._replace(mu=mu_new, tau=tau, free_mode=free_mode, refs=refs, mu_max=mu_max, mu_filter=mu_filter)
        # convergence and limits at the new iterate
        t = p.tols
        # the objective too: the optimality error never reads f, so a NaN f (a log of a negative
        # number with a finite gradient) went on into the barrier function, or, at a stationary
        # start, was reported converged with objective NaN (Ipopt: an invalid number)
        finite = jnp.isfinite(err) & jnp.all(jnp.isfinite(xt)) & jnp.isfinite(ft) & derivs_finite
        converged = (err <= t.tol) & (viol <= t.constr_viol_tol) & (dual_inf <= t.dual_inf_tol) & (compl <= t.compl_inf_tol) & finite
        status = jnp.where(
            converged, int(IpmStatus.CONVERGED),
            jnp.where(~finite, int(IpmStatus.NUMERICAL_ERROR),
            jnp.where(new.ls_fail >= o.max_line_search_failures, int(IpmStatus.LINE_SEARCH_FAILED),
            jnp.where(it >= o.max_iter, int(IpmStatus.MAX_ITER), int(IpmStatus.RUNNING)))))
        # (the inertia correction is cut only for a member that had stopped before this
        # iteration, a vmapped batch's: one that stops here may still take this direction, as
        # the feasibility polish does from a converged iterate)
        new = self._direction(p, new._replace(status=status.astype(jnp.int32)), theta, active=st.status == int(IpmStatus.RUNNING))  # sets mu with the quality function
        # a new barrier problem, every free-mode iteration (only the adaptive strategy has
        # one; Ipopt's AdaptiveMuUpdate resets the line search there even when mu comes out the
        # same, e.g. at mu_min), or a failed line search empties the filter
        reset = (new.mu != mu) | failed | new.free_mode
        history = st.history.at[it].set(jnp.stack([ft, viol, dual_inf, jnp.log10(new.mu), jnp.where(first, jnp.nan, alpha)]))
        return new._replace(
            history=history,
            filter=jnp.where(reset, jnp.full_like(filt, jnp.inf), filt),
            n_filter=jnp.where(reset, 0, n_filter).astype(jnp.int32),
        )

    def _mu_min(self, p: _Problem):
        """``mu_min``, or Ipopt's rule at the run's tolerances where it is not given."""
        o = self.options
        return o.mu_min if o.mu_min is not None else _ipopt_mu_min(p.tols.tol, p.tols.compl_inf_tol, jnp)

    @staticmethod
    def _n_bounds(p: _Problem):
        """The number of finite bounds on free variables and inequality rows' slacks."""
        return sum(jnp.sum(mask) for mask in (p.has_xl, p.has_xu, p.has_sl, p.has_su))

    def _complementarity(self, p: _Problem, st: _State):
        """(average, smallest) product of bound distance and multiplier over all bounds."""
        pairs = ((st.x - p.xl, st.zl, p.has_xl), (p.xu - st.x, st.zu, p.has_xu), (st.s - p.cl, st.vl, p.has_sl), (p.cu - st.s, st.vu, p.has_su))
        total = sum(jnp.sum(jnp.where(mask, d * z, 0.0)) for d, z, mask in pairs)
        smallest = jnp.min(jnp.stack([jnp.min(jnp.where(mask, d * z, jnp.inf)) for d, z, mask in pairs]))
        count = self._n_bounds(p)
        return total / jnp.maximum(count, 1), jnp.where(count > 0, smallest, 0.0)

    def _update_mu(self, p: _Problem, st: _State, first, err):
        """The barrier parameter for the next direction.

        Monotone (Fiacco-McCormick, Ipopt's ``mu_strategy=monotone``): mu falls by
        ``min(kappa_mu mu, mu^theta_mu)`` while the barrier problem's error is below
        ``kappa_eps mu``. Adaptive (Ipopt's default when the Hessian is quasi-Newton; Nocedal,
        Wächter and Waltz, 2009): in free mode mu is chosen afresh each iteration, by the
        quality function (``mu_oracle="quality-function"``: chosen in `_direction`, which has the
        Newton steps it needs) or by the LOQO rule
        (Vanderbei and Shanno; ``mu_oracle="loqo"``) ``mu = sigma avg(d z)``, ``sigma = 0.1
        min(0.05 (1 - xi) / xi, 2)^3``, ``xi = min(d z) / avg(d z)``, in [mu_min, mu_max]. Free mode lasts while the iterate makes progress;
        otherwise the monotone mode takes over from ``mu = 0.8 avg(d z)``. Progress, by
        ``adaptive_mu_globalization``: with ``obj-constr-filter`` (Ipopt's default), the
        objective or the l1 constraint violation, each plus a margin ``1e-5 min(1, err)``, is
        no larger than that of every earlier free-mode iterate (a filter of those pairs,
        dominated ones dropped), and the fixed mode hands back as soon as an iterate makes
        progress again; with ``kkt-error``, the KKT error is below ``kappa`` times the largest
        of the last four accepted errors, and the fixed mode hands back once a solved barrier
        problem shows that progress. ``err`` is the iterate's KKT error at mu = 0. Returns
        (mu, free_mode, refs, mu_max, mu_filter).
        """
        o = self.options
        mu = st.mu
        mu_floor = jnp.minimum(p.tols.tol, p.tols.compl_inf_tol) / (o.kappa_eps + 1.0)

        def mu_body(_, mu):
            err_mu = self._error(p, st, mu)[0]
            smaller = jnp.maximum(mu_floor, jnp.minimum(o.kappa_mu * mu, mu ** o.theta_mu))
            return jnp.where(err_mu <= o.kappa_eps * mu, smaller, mu)

        mu_mono = lax.fori_loop(0, 4, mu_body, mu)
        if o.mu_strategy == "monotone":
            return mu_mono, st.free_mode, st.refs, st.mu_max, st.mu_filter
        avg, smallest = self._complementarity(p, st)
        mu_max = jnp.where(first, o.mu_max_fact * avg, st.mu_max) if o.mu_max is None else st.mu_max
        xi = smallest / jnp.maximum(avg, 1e-300)
        sigma = 0.1 * jnp.minimum(0.05 * (1.0 - xi) / jnp.maximum(xi, 1e-300), 2.0) ** 3
        mu_min = self._mu_min(p)
        mu_loqo = jnp.clip(sigma * avg, mu_min, mu_max)
        mu_filter = st.mu_filter
        if o.adaptive_mu_globalization == "kkt-error":
            progress = err <= o.adaptive_mu_kkterror_red_fact * jnp.max(st.refs)
            # free mode continues on progress; fixed mode returns to it when a barrier problem
            # was solved (mu decreased) with progress
            free = jnp.where(st.free_mode, progress, (mu_mono < mu) & progress)
        else:
            point = jnp.stack([st.f, self._infeasibility_l1(p, st.c, st.s)])
            margin = o.filter_margin_fact * jnp.minimum(o.filter_max_margin, err)
            progress = jnp.all(jnp.any(point + margin <= st.mu_filter, axis=1))
            free = progress
            # an accepted point joins the filter, and the entries it dominates leave it
            kept = jnp.where(jnp.all(point[None] <= st.mu_filter, axis=1)[:, None], jnp.inf, st.mu_filter)
            slot = jnp.argmax(jnp.isinf(kept[:, 0]))  # a free slot (the first, when all are full)
            mu_filter = jnp.where(free, kept.at[slot].set(point), st.mu_filter)
        to_fixed = st.free_mode & ~free
        mu_fixed = jnp.where(to_fixed, jnp.clip(o.adaptive_mu_monotone_init_factor * avg, mu_min, mu_max), mu_mono)
        refs = jnp.where(free, jnp.roll(st.refs, 1).at[0].set(err), st.refs)
        return jnp.where(free, mu_loqo, mu_fixed), free, refs, mu_max, mu_filter

    @staticmethod
    def _lbfgs_low_rank(st: _State) -> kkt.LowRank:
        """The limited-memory BFGS matrix ``sigma I - W^T M^-1 W`` in compact form (Byrd,
        Nocedal and Schnabel 1994): ``W = [sigma S; Y]``, ``M = [[sigma S^T S, L], [L^T, -D]]``
        with ``L`` the strictly lower part of ``S^T Y`` and ``D`` its diagonal (pairs oldest
        first). Unused slots hold zero vectors and identity rows of M."""
        S, Y, used, sig = st.S, st.Y, st.used, st.lsigma
        SS = jnp.einsum("ikn,jkn->ij", S, S)
        SY = jnp.einsum("ikn,jkn->ij", S, Y)
        L = jnp.tril(SY, -1)
        unused = jnp.diag(jnp.where(used, 0.0, 1.0))
        M = jnp.block([[sig * SS + unused, L], [L.T, -jnp.diag(jnp.where(used, jnp.diag(SY), 1.0))]])
        return kkt.LowRank(W=jnp.concatenate([sig * S, Y], axis=0), M=M)

    def _direction(self, p: _Problem, st: _State, theta, active: jax.Array | bool = True) -> _State:
        """Newton direction at the iterate for the barrier parameter, its step bounds, and the
        line search's reference values.

        Every piece of the primal-dual Newton step is affine in mu, so it is solved for two
        right-hand sides with one factorization: the affine-scaling step (mu = 0) and the step
        at mu = avg(d z); the step for any mu is their combination (Ipopt's quality-function
        oracle does the same). With ``mu_oracle="quality-function"`` in free mode, mu is chosen
        here (`_quality_function_mu`); otherwise it is ``st.mu``."""
        o = self.options
        view = self.view
        x = st.x
        # with L-BFGS the Hessian is sigma I plus the low-rank term: no block part
        H = None if o.hessian == "lbfgs" else view.hessian(x, st.y, 1.0, theta) if o.hessian == "exact" else st.H
        if o.hessian == "exact":
            # a fixed variable's rows and columns removed (with where: a NaN there must not count)
            free2 = jnp.concatenate([p.free, jnp.concatenate([p.free[1:], jnp.zeros_like(p.free[:1])], axis=0)], axis=1)
            H = jnp.where(free2[:, :, None] & free2[:, None, :], H, 0.0)
        system, low_rank, r_c, right_hand_side, full_step, barrier_gradients = self._newton_system(p, st, H)
        # Ipopt's dual regularization, shrinking with mu (its kappa_c = 1/4)
        delta_c = o.delta_c * st.mu ** 0.25 if o.delta_c_mu_scaled else jnp.asarray(o.delta_c, jnp.float64)
        if o.delta_c_mu_scaled and o.delta_c_min > 0.0:
            delta_c = jnp.maximum(delta_c, o.delta_c_min)
        # the correction starts from the last positive delta_w, kept through the iterations
        # that needed none (Wächter & Biegler 2006, Algorithm IC; Ipopt's perturbation handler)
        # (``active`` False, a member of a vmapped batch that had stopped: no correction, its
        # step is not taken)
        fac, delta_w, ok = kkt.factor_with_correction(system, delta_c, st.delta_w_last, active=active)
        avg = jnp.maximum(self._complementarity(p, st)[0], 1e-300)
        rx, rc = jax.tree.map(lambda a, b: jnp.stack([a, b]), right_hand_side(0.0, r_c, delta_w), right_hand_side(avg, r_c, delta_w))
        # both right-hand sides at once: their first block solves share the sweeps with the
        # low-rank columns' (`kkt.solve`)
        dxs, dys = kkt.solve(system, fac, delta_w, delta_c, rx, rc, o.refine_steps, remove_delta_c=not o.delta_c_mu_scaled, low_rank=low_rank, residual_ratio_max=o.residual_ratio_max, min_refine_steps=o.min_refine_steps)
        affine = full_step(0.0, dxs[0], dys[0], delta_w)
        centering = jax.tree.map(lambda a, b: a - b, full_step(avg, dxs[1], dys[1], delta_w), affine)  # per unit sigma
        mu = st.mu
        if o.mu_strategy == "adaptive" and o.mu_oracle == "quality-function":
            with jax.named_scope("ipm_mu_oracle"):
                mu = jnp.where(st.free_mode, self._quality_function_mu(p, st, affine, centering, avg), mu)
        scale = jnp.where(self._n_bounds(p) > 0, mu / avg, 0.0)  # no bounds: no centering
        step = jax.tree.map(lambda a, c: a + scale * c, affine, centering)
        dx, ds, dy, dzl, dzu, dvl, dvu = step
        a_max, a_dual = self._step_bounds(p, st, step, st.tau)
        theta0, phi0 = self._measures(p, x, st.s, st.f, st.c, mu)
        grad_bar_x, grad_bar_s = barrier_gradients(mu)
        slope = jnp.sum(grad_bar_x * dx) + jnp.sum(grad_bar_s * ds)
        status = st.status
        if H is not None:
            # a NaN or Inf Hessian fails every delta_w: a function's NaN, not a matrix to correct
            status = jnp.where((status == int(IpmStatus.RUNNING)) & ~jnp.all(jnp.isfinite(H)), int(IpmStatus.NUMERICAL_ERROR), status)
        status = jnp.where((status == int(IpmStatus.RUNNING)) & ~ok, int(IpmStatus.INERTIA_FAILED), status)
        return st._replace(
            dx=dx, ds=ds, dy=dy, dzl=dzl, dzu=dzu, dvl=dvl, dvu=dvu, alpha=a_max, alpha_dual=a_dual, mu=mu,
            phi0=phi0, theta0=theta0, slope=slope, delta_w=jnp.where(ok, delta_w, st.delta_w), status=status.astype(jnp.int32),
            delta_w_last=jnp.where(ok & (delta_w > 0.0), delta_w, st.delta_w_last),
            fac_diag=fac.diag, fac_sub=fac.sub, delta_c=delta_c,
            H=H if o.hessian == "exact" else st.H,
        )

    def _newton_maps(self, p: _Problem, st: _State):
        """The pieces of the primal-dual Newton step at the iterate ``st`` that do not need the
        factorization: the bound terms of the matrix (sigma_x (K, n), d0 (K, m)), the
        constraint residual r_c, and maps ``right_hand_side(mu, r_c)`` (the
        condensed system's right-hand sides), ``full_step(mu, dx, dy)`` (slack and bound
        multiplier steps from dx, dy) and ``barrier_gradients(mu)``. Every piece is affine in
        mu; second-order corrections replace r_c."""
        x, s = st.x, st.s
        dxl = jnp.where(p.has_xl, x - p.xl, 1.0)
        dxu = jnp.where(p.has_xu, p.xu - x, 1.0)
        dsl = jnp.where(p.has_sl, s - p.cl, 1.0)
        dsu = jnp.where(p.has_su, p.cu - s, 1.0)
        sigma_x = _safe(st.zl, dxl, p.has_xl) + _safe(st.zu, dxu, p.has_xu)
        sigma_s = _safe(st.vl, dsl, p.has_sl) + _safe(st.vu, dsu, p.has_su)
        t = jnp.where(p.eq, p.cl, s)
        r_c = jnp.where(p.eq | p.ineq, st.c - t, 0.0)
        sig_s = jnp.where(p.ineq, sigma_s, 1.0)
        d0 = jnp.where(p.ineq, 1.0 / sig_s, jnp.where(p.eq, 0.0, 1.0))

        def barrier_gradients(mu):
            # the bound multipliers replaced by mu / distance
            gx = jnp.where(p.free, st.grad - _safe(mu, dxl, p.has_xl) + _safe(mu, dxu, p.has_xu), 0.0)
            gs = jnp.where(p.ineq, -_safe(mu, dsl, p.has_sl) + _safe(mu, dsu, p.has_su), 0.0)
            return gx, gs

        # with the inertia correction's delta_w the slacks' block is sigma_s + delta_w, as in
        # Ipopt (`kkt.KKTSystem.slack`): the two maps take the delta_w of the factorization
        def right_hand_side(mu, r_c, delta_w=0.0):
            gx, gs = barrier_gradients(mu)
            rhat_x = jnp.where(p.free, gx + kkt._apply_JT(st.J, None, st.y, self.view.pattern), 0.0)
            rhat_s = jnp.where(p.ineq, gs - st.y, 0.0)
            # slacks eliminated: ds = (dy - rhat_s) / (sigma_s + delta_w) on inequality rows
            return -rhat_x, -jnp.where(p.ineq, r_c + rhat_s / (sig_s + delta_w), r_c)

        def full_step(mu, dx, dy, delta_w=0.0):
            rhat_s = jnp.where(p.ineq, barrier_gradients(mu)[1] - st.y, 0.0)
            ds = jnp.where(p.ineq, (dy - rhat_s) / (sig_s + delta_w), 0.0)
            dzl = jnp.where(p.has_xl, (mu - st.zl * dxl - st.zl * dx) / dxl, 0.0)
            dzu = jnp.where(p.has_xu, (mu - st.zu * dxu + st.zu * dx) / dxu, 0.0)
            dvl = jnp.where(p.has_sl, (mu - st.vl * dsl - st.vl * ds) / dsl, 0.0)
            dvu = jnp.where(p.has_su, (mu - st.vu * dsu + st.vu * ds) / dsu, 0.0)
            return dx, ds, dy, dzl, dzu, dvl, dvu

        return sigma_x, d0, r_c, right_hand_side, full_step, barrier_gradients

    def _newton_system(self, p: _Problem, st: _State, H):
        """The Newton matrix at the iterate ``st`` with block Hessian ``H`` (None with L-BFGS):
        its `kkt.KKTSystem` (L-BFGS's sigma on the diagonal), the limited-memory low-rank term
        (None otherwise), and `_newton_maps`'s r_c, right_hand_side, full_step and
        barrier_gradients."""
        sigma_x, d0, r_c, right_hand_side, full_step, barrier_gradients = self._newton_maps(p, st)
        low_rank = None
        if self.options.hessian == "lbfgs":
            sigma_x = sigma_x + jnp.where(p.free, st.lsigma, 0.0)
            low_rank = self._lbfgs_low_rank(st)
        # a fixed variable's column removed with where: the KKT solve masks by products with 0
        J = jnp.where(self.view.pattern.free_columns(p.free), st.J, 0.0)
        system = kkt.KKTSystem(H=H, sigma=sigma_x, A=J, B=None, d0=d0, free=p.free, pattern=self.view.pattern, slack=p.ineq)
        return system, low_rank, r_c, right_hand_side, full_step, barrier_gradients

    def _factored(self, p: _Problem, st: _State):
        """The Newton system at an iterate whose direction was computed there, so the state holds
        its factorization: (system, r_c, right_hand_side, full_step, ``solve(rx, rc) -> (dx,
        dy)`` with that factorization), for the steps that reuse it (second-order corrections,
        the polish's projection)."""
        o = self.options
        system, low_rank, r_c, right_hand_side, full_step, _ = self._newton_system(p, st, st.H if o.hessian in ("exact", "bfgs") else None)

        def solve(rx, rc):
            return kkt.solve(system, kkt.BlockFactor(st.fac_diag, st.fac_sub), st.delta_w, st.delta_c, rx, rc, o.refine_steps, remove_delta_c=not o.delta_c_mu_scaled, low_rank=low_rank, residual_ratio_max=o.residual_ratio_max, min_refine_steps=o.min_refine_steps)

        return system, r_c, right_hand_side, full_step, solve

    def _soc_step(self, p: _Problem, st: _State, c_soc):
        """Ipopt's second-order correction: the Newton step at the iterate for its barrier
        parameter with the factorization of the current direction, the constraint residual
        replaced by ``c_soc``. Returns (step, primal and dual fraction-to-the-boundary
        lengths)."""
        _, _, right_hand_side, full_step, solve = self._factored(p, st)
        dx, dy = solve(*right_hand_side(st.mu, c_soc, st.delta_w))
        step = full_step(st.mu, dx, dy, st.delta_w)
        a_p, a_d = self._step_bounds(p, st, step, st.tau)
        return step, a_p, a_d

    def _projection(self, p: _Problem, st: _State) -> _State:
        """The feasibility polish's direction at the iterate: the step of least
        ``(W + Sigma)``-norm onto the linearized constraints, ``[W + Sigma, J^T; J, -D] (dx,
        dy) = (0, -r_c)`` with the factorization of the iterate's Newton direction (the
        Newton step with its dual residual left out; D holds the inequality rows' slack terms
        and the dual regularization delta_c, so the rows are met to within about delta_c |dy|,
        as by a Newton step), the slacks following the rows (``J dx - ds = -r_c``) and every
        multiplier kept. Its line search is the filter's h-type test (slope 0: never an Armijo
        step on the barrier objective: a trial is taken for enough lower infeasibility, or
        for enough lower barrier objective), without second-order corrections.

        After a loose convergence test at mu near ``mu_min`` a Newton iteration goes on trading
        feasibility for the objective: measured on the SE(3) back-flip, the violation went
        5.5e-6, 9.2e-5, 7.0e-6, 9.9e-5 over the four iterations after it."""
        system, r_c, _, _, solve = self._factored(p, st)
        dx, dy = solve(jnp.zeros_like(st.x), -r_c)
        dx = jnp.where(p.free, dx, 0.0)
        ds = jnp.where(p.ineq, kkt.perturbed_d0(system, st.delta_w) * dy, 0.0)
        keep = jax.tree.map(jnp.zeros_like, (st.dy, st.dzl, st.dzu, st.dvl, st.dvu))
        a_max, a_dual = self._step_bounds(p, st, (dx, ds, *keep), st.tau)
        return st._replace(dx=dx, ds=ds, dy=keep[0], dzl=keep[1], dzu=keep[2], dvl=keep[3], dvu=keep[4], alpha=a_max, alpha_dual=a_dual, slope=jnp.zeros_like(st.slope))

    def _quality_function_mu(self, p: _Problem, st: _State, affine, centering, avg):
        """Ipopt's quality-function oracle: mu = sigma avg(d z), with sigma minimizing the
        squared KKT residuals predicted after the step ``affine + sigma centering`` (each
        cut by the fraction to the boundary): ``(1 - a_dual)^2 |grad L|^2 / n_dual + (1 -
        a_primal)^2 |c - s|^2 / n_rows + |(d + a_primal dd) (z + a_dual dz)|^2 / n_bounds``.
        The search follows Ipopt's: the slope at sigma = 1 decides between [1, sigma_max] and
        [sigma_min, 0.99], then golden section in sigma (at most
        ``quality_function_max_section_steps`` sections, relative tolerance
        ``quality_function_section_sigma_tol``), the interval's outer end kept if it is better."""
        o = self.options
        tau = st.tau
        r_x, r_s, r_c, _ = self._residuals(p, st, 0.0)
        n_dual = jnp.maximum(jnp.sum(p.free) + jnp.sum(p.ineq), 1)
        n_pri = jnp.maximum(jnp.sum(p.eq | p.ineq), 1)
        n_comp = jnp.maximum(jnp.sum(p.has_xl) + jnp.sum(p.has_xu) + jnp.sum(p.has_sl) + jnp.sum(p.has_su), 1)
        dual_sq = (jnp.sum(r_x**2) + jnp.sum(r_s**2)) / n_dual
        primal_sq = jnp.sum(r_c**2) / n_pri
        x, s = st.x, st.s

        def quality(sigma):
            step = jax.tree.map(lambda a, c: a + sigma * c, affine, centering)
            dx, ds, _, dzl, dzu, dvl, dvu = step
            a_p, a_d = self._step_bounds(p, st, step, tau)
            pairs = ((x - p.xl, dx, st.zl, dzl, p.has_xl), (p.xu - x, -dx, st.zu, dzu, p.has_xu), (s - p.cl, ds, st.vl, dvl, p.has_sl), (p.cu - s, -ds, st.vu, dvu, p.has_su))
            compl = sum(jnp.sum(jnp.where(mask, ((d + a_p * dd) * (z + a_d * dz)) ** 2, 0.0)) for d, dd, z, dz, mask in pairs) / n_comp
            return (1.0 - a_d) ** 2 * dual_sq + (1.0 - a_p) ** 2 * primal_sq + compl

        gfac = (3.0 - np.sqrt(5.0)) / 2.0
        tol = o.quality_function_section_sigma_tol

        def golden(lo, up):
            """Golden section on [lo, up]; returns the best of the last inner points and the
            interval's end that the search never moved (evaluated)."""
            m1, m2 = lo + gfac * (up - lo), lo + (1.0 - gfac) * (up - lo)
            q1, q2 = quality(m1), quality(m2)

            def section(_, c):
                lo, m1, m2, up, q1, q2 = c
                go = (up - lo) >= tol * up
                left = q1 > q2  # the minimum is right of m1
                n_lo, n_up = jnp.where(left, m1, lo), jnp.where(left, up, m2)
                n_m1 = jnp.where(left, m2, n_lo + gfac * (n_up - n_lo))
                n_m2 = jnp.where(left, n_lo + (1.0 - gfac) * (n_up - n_lo), m1)
                q_new = quality(jnp.where(left, n_m2, n_m1))
                n_q1, n_q2 = jnp.where(left, q2, q_new), jnp.where(left, q_new, q1)
                new = (n_lo, n_m1, n_m2, n_up, n_q1, n_q2)
                return jax.tree.map(lambda a, b: jnp.where(go, a, b), new, c)

            lo_e, m1, m2, up_e, q1, q2 = lax.fori_loop(0, o.quality_function_max_section_steps, section, (lo, m1, m2, up, q1, q2))
            best, q_best = jnp.where(q1 < q2, m1, m2), jnp.minimum(q1, q2)
            return best, q_best, lo_e, up_e

        sigma_1minus = 1.0 - max(1e-4, tol)
        q_1, q_1minus = quality(1.0), quality(sigma_1minus)
        larger = q_1minus > q_1  # the quality falls beyond sigma = 1
        up_big = jnp.minimum(o.sigma_max, st.mu_max / avg)
        mu_min = self._mu_min(p)
        lo_small = jnp.maximum(o.sigma_min, mu_min / avg)
        up_small = jnp.minimum(jnp.maximum(lo_small, sigma_1minus), st.mu_max / avg)
        lo, up = jnp.where(larger, 1.0, lo_small), jnp.where(larger, up_big, up_small)
        best, q_best, lo_e, up_e = golden(lo, jnp.maximum(up, lo))
        # as Ipopt: an end of the interval the search never moved from (the upper one first)
        # is taken if it is better than the best inner point
        end = jnp.where(up_e == up, up, lo)
        sigma = jnp.where(((up_e == up) | (lo_e == lo)) & (quality(end) < q_best), end, best)
        sigma = jnp.where(lo >= up, jnp.where(larger, up, lo), sigma)  # empty interval: its end
        return jnp.clip(sigma * avg, mu_min, st.mu_max)


#: IpmStatus -> the shared enumeration
_STATUS = {
    IpmStatus.RUNNING: Status.INTERNAL_ERROR,
    IpmStatus.CONVERGED: Status.SOLVED,
    IpmStatus.MAX_ITER: Status.MAX_ITER,
    IpmStatus.LINE_SEARCH_FAILED: Status.RESTORATION_FAILED,
    IpmStatus.NUMERICAL_ERROR: Status.NUMERICAL_ERROR,
    IpmStatus.INERTIA_FAILED: Status.STEP_COMPUTATION_FAILED,
}
_MESSAGES = {
    # the loop also ends, still RUNNING, at its bound on evaluations (`IPM._max_passes`), which
    # every iteration's full line search stays within: the message was the bare name 'RUNNING'
    IpmStatus.RUNNING: "the solver's loop ended at its bound on evaluations, (max_iter + 1) (max_line_search + 1 + max_soc), before any termination test (an internal error)",
    IpmStatus.CONVERGED: "converged (Ipopt's optimality test)",
    IpmStatus.MAX_ITER: "iteration limit reached",
    IpmStatus.LINE_SEARCH_FAILED: "the filter line search failed several times in a row (this solver has no restoration phase)",
    IpmStatus.NUMERICAL_ERROR: "NaN or Inf in the iterate or in the functions' values or derivatives there (the Hessian's too)",
    IpmStatus.INERTIA_FAILED: "no regularization delta_w up to delta_w_max made the Newton matrix positive definite (Ipopt would turn to its restoration phase; this solver has none)",
}


#: a tolerance at or below this is "tight" for `_status_message`'s hint
_TIGHT_TOL = 1e-6


def _status_message(code: IpmStatus, opts: IpmOptions, mu: float) -> str:
    """The status's message; at the iteration limit of a tight solve (``tol`` <= 1e-6) whose
    mu sat at ``mu_min`` without a floor under the dual regularization, with the remedy
    measured for that tail (`IpmOptions.delta_c_min`)."""
    message = _MESSAGES.get(code, code.name)
    mu_min = opts.mu_min_value()
    if code is IpmStatus.MAX_ITER and opts.tol <= _TIGHT_TOL and opts.delta_c_mu_scaled and opts.delta_c_min == 0.0 and mu <= mu_min * (1.0 + 1e-12):
        floor = "1e-7" if opts.hessian == "exact" else "1e-9"
        message += (
            f"; mu sat at mu_min, where the dual regularization delta_c mu^(1/4) is {opts.delta_c * mu_min**0.25:.1e} and the "
            f"Newton matrix's factorization needs inertia corrections in rounding: at tight tolerances set delta_c_min={floor} "
            "(docs/measurements.md)"
        )
    return message


#: serializes `JtrajSolver._program`'s compiles (compiles run one at a time)
_COMPILE_LOCK = threading.Lock()


class JtrajSolver(AbstractSolver):
    """jtraj's own interior-point solver (`IPM`) as a backend of `jtraj.solvers.SOLVERS`.

    It takes a `jtraj.nlp.KnotNLP` only: the Newton step works on the knot structure (rows
    reading knots k and k+1, `StageView`), which an NLP with the backends' functions alone
    does not have (Ipopt takes one; here it is a TypeError).

    One compiled program per NLP and options (kept while the NLP lives; options that differ
    only in the tolerances, `IpmOptions.RUNTIME_FIELDS`, share it), compiled before the
    clock starts: later solves with other initial guesses or parameters do not compile again,
    and ``stats.time_total`` is the solve alone. The solve runs inside one
    `jax.jit` call, so the callback receives the iterations after it ends, and the time is
    not split between evaluations and the solver's own work (``time_evaluations`` is 0).
    For batches, `solve_batch` runs one vmapped program over several initial guesses, or, on a
    CPU, the one-problem program on every core (see there).
    """

    name: ClassVar[str] = "jtraj"
    Options: ClassVar[type[AbstractOptions]] = IpmOptions
    reports_iterates: ClassVar[bool] = False  # one compiled program: no intermediate iterates

    @staticmethod
    def ipm(nlp: Any, options: IpmOptions) -> IPM:
        """The `IPM` of ``nlp`` with ``options`` (its program is shared, see `IPM`)."""
        return IPM(nlp, options)

    def solve(self, nlp: Any, x0: np.ndarray, theta: Any = None, options: AbstractOptions | dict[str, Any] | None = None, callback: AbstractCallback | None = None) -> Solution:
        """As `AbstractSolver.solve`, for a `jtraj.nlp.KnotNLP` only (another NLP, one with the
        functions alone, is a TypeError: the solver works on its knot structure)."""
        _require_knot_nlp(nlp, "jtraj's solver")
        if callback is not None and callback.wants_iterates and not self.reports_iterates:
            raise ValueError("jtraj's solver runs as one compiled program and reports no intermediate iterates: record them with solver='ipopt'")
        opts = self.options(options)
        x0 = initial_guess(nlp, x0)
        if theta is None:  # the NLP's own parameters (`bind`), also for the program's key below
            theta = getattr(nlp, "theta", None)
        f = bind(nlp, theta)
        problem = f.inconsistent()
        if problem is not None:  # as Ipopt returns it, before anything compiles
            return invalid_problem(f, x0, problem, len(f.g_lower), nlp, callback)
        ipm = self.ipm(nlp, opts)
        if callback is not None:
            callback.on_start(nlp)
        view = ipm.view
        x0 = np.clip(x0, f.x_lower, f.x_upper).reshape(view.K, view.n)
        # compile ahead (once per NLP, options and parameter shapes), so that the time below is
        # the solve's alone; a printing callback says so first (about a minute on a whole-body
        # task without the compilation cache)
        say = callback.write if isinstance(callback, PrintProgress) else None
        program, compile_time = self._program(ipm, "", ipm.program, jnp.asarray(x0), theta, say)
        t0 = time.perf_counter()
        r = jax.block_until_ready(program(jnp.asarray(x0), theta, ipm.tolerances))
        solution = self._solution(ipm, f, r, opts, time.perf_counter() - t0, callback)
        solution = dataclasses.replace(solution, time_compile=compile_time)
        if callback is not None:
            callback.on_end(solution)
        return solution

    #: ways to solve a batch (`solve_batch`)
    STRATEGIES: ClassVar[tuple[str, ...]] = ("vmap", "threads")

    @staticmethod
    def default_strategy() -> str:
        """``"threads"`` when JAX computes on the CPU, ``"vmap"`` on an accelerator."""
        return "threads" if jax.default_backend() == "cpu" else "vmap"

    def solve_batch(
        self,
        nlp: Any,
        x0s: np.ndarray,
        theta: Any = None,
        options: AbstractOptions | dict[str, Any] | None = None,
        batch_size: int | None = None,
        strategy: str | None = None,
        threads: int | None = None,
    ) -> tuple[list[Solution], float, float]:
        """Solve from several initial guesses at once (``nlp`` a `jtraj.nlp.KnotNLP`, as for
        `solve`).

        ``x0s``: (B, nlp.n) or (B, K, n) initial guesses, clipped to the variable bounds as in
        `solve`. With ``strategy="threads"`` member i is ``solve(nlp, x0s[i], ...)`` bit for bit
        (the same compiled program). The vmapped program is compiled apart from it, and its
        rounding differs: on a convex problem its members end as their one-by-one solves (the
        iterates agree to rounding), but on a nonconvex one the differences can grow along the
        iterations, and a member can take other iterations or end with another status, which
        can also depend on the other members of its batch (a review's measurement on tests'
        pendulum swing-up, 8 starts of 30 N(0, 1): 4 of 8 members took other iterations on a
        CPU's sequential batch, and on the vectorized one a member stopped at the iteration
        limit where its one-by-one solve converged in 66). ``theta`` is one set of parameters, shared by every
        member (None: ``nlp.theta``); a theta with a batch axis is refused (`bind`).

        ``strategy``:
        - ``"vmap"``: one call of the vmapped `IPM` program. On an accelerator its members
          step together, and the batch runs until its slowest member is done (the others'
          updates are masked); on a CPU the program splits them over the CPU devices (one per
          core), each running its share one member after another (`IpmOptions.cpu_batch`).
          ``batch_size`` (>= B; default B): the batch the program is compiled for; a shorter
          batch is padded with copies of its first guess, so that batches of different
          lengths (a resumed study's missing replicates) reuse one program.
        - ``"threads"``: the one-problem program of `solve`, each member on its own, ``threads``
          at a time (default: the cores this process may run on, `jtraj.config.cpu_count`;
          JAX releases the GIL while a program runs). On a
          CPU this balances uneven members better: each core takes the next member when it
          is done (big_jump's 10 noisy replicates on 2 cores, one run of `bench/replicates.py`
          on 2026-12-01: 10.03 s, against 10.77 s for the vmapped program split over two CPU
          devices, whose fixed shares held 131 and 159 of the 290 iterations).
          ``batch_size`` is ignored.
        - None (default): `default_strategy` (``"threads"`` on a CPU, ``"vmap"`` otherwise).

        Returns the B solutions, the wall seconds of the batch (compiling excluded; each
        solution's ``stats.time_total`` is that time divided by B) and the seconds spent
        compiling in this call (0 when the program was compiled before).
        """
        _require_knot_nlp(nlp, "jtraj's solver")
        strategy = strategy or self.default_strategy()
        if strategy not in self.STRATEGIES:
            raise ValueError(f"solve_batch: unknown strategy {strategy!r}; expected one of {', '.join(self.STRATEGIES)}")
        # whole counts (threads=1.5 ran, batch_size=2.5 failed in numpy, batch_size=0 read "1
        # initial guesses for a batch of 0; expected 1 to 0")
        whole = lambda v: not isinstance(v, (bool, np.bool_)) and isinstance(v, (int, np.integer)) and v >= 1  # noqa: E731
        if threads is not None and not whole(threads):
            raise ValueError(f"solve_batch: threads={threads!r}; expected a positive count or None (the CPU count)")
        if batch_size is not None and not whole(batch_size):
            raise ValueError(f"solve_batch: batch_size={batch_size!r}; expected a positive count (the batch the program is compiled for) or None (the number of guesses)")
        opts = self.options(options)
        x0s = np.asarray(x0s, float)
        n = int(nlp.n)
        shapes = guess_shapes(nlp)
        if x0s.ndim < 2 or len(x0s) < 1 or x0s.shape[1:] not in shapes:
            raise ValueError(f"solve_batch: x0s of shape {x0s.shape}: expected B >= 1 initial guesses, of shape " + " or ".join("(B, " + ", ".join(map(str, shape)) + ")" for shape in shapes))
        x0s = x0s.reshape(len(x0s), n)
        count = len(x0s)
        size = count if batch_size is None else batch_size
        if not 1 <= count <= size:
            raise ValueError(f"solve_batch: {count} initial guesses for a batch of {size}; expected 1 to {size}")
        if theta is None:  # the NLP's own parameters (`bind`), also for the program's key below
            theta = getattr(nlp, "theta", None)
        f = bind(nlp, theta)
        problem = f.inconsistent()
        if problem is not None:  # as Ipopt returns it, before anything compiles
            return [invalid_problem(f, x0, problem, len(f.g_lower)) for x0 in x0s], 0.0, 0.0
        ipm = self.ipm(nlp, opts)
        view = ipm.view
        x0s = np.clip(x0s, f.x_lower, f.x_upper).reshape(count, view.K, view.n)
        if strategy == "threads":
            return self._solve_threads(ipm, f, x0s, theta, opts, threads)
        padded = jnp.asarray(np.concatenate([x0s, np.repeat(x0s[:1], size - count, axis=0)]))
        program, compile_time = self._program(ipm, f"vmap {size} {opts.cpu_batch} ", jax.jit(jax.vmap(ipm.program, in_axes=(0, None, None))), padded, theta)
        t0 = time.perf_counter()
        rs = jax.block_until_ready(program(padded, theta, ipm.tolerances))
        total = time.perf_counter() - t0
        members = [jax.tree.map(lambda a, i=i: a[i], rs) for i in range(count)]
        return [self._solution(ipm, f, r, opts, total / count) for r in members], total, compile_time

    def _solve_threads(self, ipm: IPM, f: Any, x0s: np.ndarray, theta: Any, opts: IpmOptions, threads: int | None) -> tuple[list[Solution], float, float]:
        """`solve_batch`'s ``"threads"`` strategy (x0s already clipped, (B, K, n))."""
        from concurrent.futures import ThreadPoolExecutor

        count = len(x0s)
        threads = min(count, threads or cpu_count())  # the cores this process may use (its affinity)
        program, compile_time = self._program(ipm, "", ipm.program, jnp.asarray(x0s[0]), theta)
        run = lambda x0: jax.block_until_ready(program(jnp.asarray(x0), theta, ipm.tolerances))  # noqa: E731
        t0 = time.perf_counter()
        with ThreadPoolExecutor(threads) as pool:
            rs = list(pool.map(run, x0s))
        total = time.perf_counter() - t0
        return [self._solution(ipm, f, r, opts, total / count) for r in rs], total, compile_time

    @staticmethod
    def _program(ipm: IPM, kind: str, jitted: Any, x0: jax.Array, theta: Any, say: Any = None) -> tuple[Any, float]:
        """``jitted(x0, theta, tolerances)`` compiled ahead of time for these argument shapes, once
        per (NLP, options but the run-time ones, kind, parameter shapes); returns it and the
        seconds spent compiling in this call. ``say(text)``, if given, is told before and after
        a compile."""
        key = kind + str(jax.tree.map(lambda a: (np.shape(a), jnp.result_type(a)), theta))
        if key in ipm.compiled:
            return ipm.compiled[key], 0.0
        # one compile at a time: solves started side by side in threads (a vmapped
        # `jtraj.differentiable`) wait for the first one's program instead of each compiling it
        with _COMPILE_LOCK:
            if key in ipm.compiled:
                return ipm.compiled[key], 0.0
            if say is not None:
                say(f"jtraj solver: compiling its {kind}program (once per NLP and options other than the tolerances)")
            t0 = time.perf_counter()
            try:
                ipm.compiled[key] = jitted.lower(x0, theta, ipm.tolerances).compile()
            except BaseException:
                ipm.forget_if_uncompiled()  # the NLP's next solve traces its own program
                raise
            seconds = time.perf_counter() - t0
        if say is not None:
            say(f"jtraj solver: compiled in {seconds:.1f} s")
        return ipm.compiled[key], seconds

    @staticmethod
    def _solution(ipm: IPM, f: Any, r: IpmResult, opts: IpmOptions, total: float, callback: AbstractCallback | None = None) -> Solution:
        """The shared `Solution` of one (unbatched) `IpmResult`, solved in ``total`` seconds;
        ``callback`` receives its iterations."""
        view = ipm.view
        code = IpmStatus(int(r.status))
        x = np.asarray(r.x).reshape(-1)
        iterations = int(r.iterations)
        history = tuple(
            Iteration(iter=i, objective=float(h[0]), inf_pr=float(h[1]), inf_du=float(h[2]), mu=float(10.0 ** h[3]), alpha_pr=0.0 if np.isnan(h[4]) else float(h[4]))
            for i, h in enumerate(np.asarray(r.history)[: iterations + 1])
        )
        if callback is not None:
            for it in history:
                if callback.on_iteration(it) is False:
                    # the iterations are replayed after the compiled loop has ended: too late to stop
                    warnings.warn(
                        f"jtraj's solver cannot stop at a callback's request (iteration {it.iter}): it reports its iterations after its compiled loop "
                        "has run to its own end; stop it by its options (max_iter, tol) or use solver='ipopt'",
                        RuntimeWarning,
                        stacklevel=2,
                    )
                    break
        g = np.asarray(f.constraints(jnp.asarray(x)))
        values, derivatives = int(r.passes), int(r.derivative_passes)
        message = _status_message(code, opts, float(r.mu))
        if message != _MESSAGES.get(code, code.name):  # the tight tail's remedy: said where it shows
            warnings.warn(f"jtraj's solver: {message}", RuntimeWarning, stacklevel=3)
        return Solution(
            x=x,
            status=code.shared,
            message=message,
            objective=float(r.objective),
            constraint_violation=max_violation(g, f.g_lower, f.g_upper, x, f.x_lower, f.x_upper),
            mult_g=np.asarray(view.from_stage_rows(r.y)),
            mult_x_lower=np.asarray(r.z_lower).reshape(-1),
            mult_x_upper=np.asarray(r.z_upper).reshape(-1),
            stats=Stats(iterations, values, derivatives, values, derivatives, derivatives if opts.hessian == "exact" else 0, total, 0.0),
            history=history,
        )
