"""Optimal motions as differentiable functions of the task's parameters.

``f = jtraj.differentiable(task)`` returns ``f(theta) -> OptimalMotion``: a JAX function of
the parameter pytree ``theta`` (`jtraj.transcription.TaskParams`: target, timestep, friction,
force bounds, cost weights, link masses, standing pose) whose value is the solution of the
task at theta (any `jtraj.solvers` backend, Ipopt by default, through `jax.pure_callback`;
warm-started from the previous solution; `forward_options` gives Ipopt and jtraj's solver
tight defaults) and whose derivatives come from the implicit function theorem at that solution (`jtraj.implicit`,
`jtraj.sensitivity`). ``jax.grad``, ``jax.jacobian``, ``jax.jvp`` and ``jax.vjp`` work through
it, and so does ``jax.jit`` around the user's own loss.

Everything in `OptimalMotion` (base poses, joints, velocities, accelerations, torques, contact
forces, cost) is a JAX function of the solution x and of theta, so its derivative is the chain
rule through ``dx/dtheta`` plus its direct dependence on theta (a torque depends on the link
masses directly, too).

What is differentiated and what is not:
- the contact schedule (which feet touch at which knot) and the knot count are fixed; the
  timestep is a parameter (the phase durations scale with it);
- the active set (which torque limits, friction facets, force bounds and clearance rows are
  at their bounds) is held fixed: the derivative is that of the solution while the active
  set does not change, and it is exact there;
- at a degenerate solution (a limit reached with a zero multiplier: strict complementarity
  fails) the solution is only one-sidedly differentiable; the weakly active limits are
  treated as inactive, and ``OptimalMotion.degenerate`` is True. The value is then the
  derivative of the problem without those limits: a one-sided derivative only where its
  tangent keeps every one of them satisfied, which it need not (on a Go2 hop with 6 weakly
  active friction rows, the tangent along ``max_delta_force`` broke some for a step up and
  others for a step down, and dx differed from both one-sided differences by 0.64);
- the standing pose and the target place the fixed first and last knots, whose contact points
  must stay on the terrain (`jtraj.solve` refuses a theta that lifts them, and so does
  ``f``). A direction of theta that moves such a point (one standing joint alone, a target
  height) leaves the problem infeasible on both sides, so it has no derivative: ``jax.jvp``
  along it fails with a `jtraj.sensitivity.SingularKKTError` naming the entries of theta
  without one (it comes as JAX's runtime error, ``jax.errors.JaxRuntimeError``, whose message
  ends with it: the sensitivity solve is a host callback of a compiled program, eager
  ``jax.jvp`` too), and a gradient's entries along them are arbitrary numbers, which
  ``jax.grad`` says with a `jtraj.sensitivity.NotDifferentiableWarning` naming them (on the Go2 hop of the
  README: the target's height, roll and pitch, the standing base's tilt and the standing
  joint angles); its other entries are exact. Directions that keep the points on the
  terrain (a target in the ground's plane, a yaw) are differentiable;
- derivatives are first order (no Hessians through the solver).

A unique solution is needed for derivatives to exist: with four feet on the ground the
contact forces are not determined by the task's costs alone (internal forces), so the NLP
here adds a small force regularization ``1/2 force_weight |f / (m g)|^2`` per knot, and the
task must have positive configuration and acceleration weights.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
import warnings
from collections.abc import Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jtraj import config, solvers
from jtraj import parameterization as params
from jtraj import robot as robots
from jtraj import task as tasks
from jtraj.deprecation import renamed_argument
from jtraj.implicit import implicit_solution
from jtraj.nlp import CostGroup, Dep, KnotNLP
from jtraj.numbers import is_real
from jtraj.sensitivity import check_weak_tol
from jtraj.solver import transcription_options
from jtraj.transcription import COMPACT_VARIABLES, CONSTRAINT_STAGES, GRAVITY, TaskParams, Transcription, TranscriptionOptions, cost_terms

__all__ = ["OptimalMotion", "DifferentiableTask", "differentiable", "SolveError", "IPOPT_OPTIONS", "JTRAJ_OPTIONS", "forward_options", "motion"]

#: Ipopt settings of the forward solve: tight (the derivatives are those of the exact
#: solution) with the exact Hessian, which the sensitivity system needs anyway.
IPOPT_OPTIONS: dict[str, Any] = {"tol": 1e-10, "constr_viol_tol": 1e-10, "hessian": "exact", "max_iter": 500}

#: jtraj's solver's settings of the forward solve: Ipopt's above, and a floor of 1e-7 under
#: the dual regularization ``delta_c mu^(1/4)`` (`jtraj.solvers.IpmOptions.delta_c_min`).
#: Without it the regularization falls to 1.8e-11 at ``mu_min``, the condensed Newton matrix
#: weighs the equality rows by its inverse, and its Cholesky fails in rounding at every
#: iteration from there on; the inertia correction's ``delta_w`` (about 1e-6) then swamps the
#: force regularization's curvature (4e-8 on the Go2) and the steps creep. Measured on
#: the Go2 hop of tests/test_differentiable.py (2026-12-06): with floors 1e-9, 1e-8, 1e-7, 1e-6
#: and 1e-5 the solve took 211, 38, 15, 15 and 18 iterations, Ipopt 15; without one it stopped
#: at the 500-iteration limit (docs/measurements.md).
JTRAJ_OPTIONS: dict[str, Any] = {**IPOPT_OPTIONS, "delta_c_min": 1e-7}

#: the forward solve's defaults by backend name (`forward_options`)
_FORWARD_OPTIONS: dict[str, dict[str, Any]] = {"ipopt": IPOPT_OPTIONS, "jtraj": JTRAJ_OPTIONS}


class SolveError(RuntimeError):
    """The forward solve did not converge; the derivatives would be meaningless."""


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class OptimalMotion:
    """The optimal motion at theta (a pytree; K knots, P contact points of the task).

    Attributes:
        t: (K,) s.
        base_xyz_wxyz: (K, 7) base pose, MJX free-joint convention (world frame).
        q_base: (K, nq_base) base coordinates in the parameterization's chart.
        q_joints: (K, nj) rad.
        v: (K, nv) body twist of the base (v_body, omega_body) and joint rates.
        a: (K, nv) its time derivative.
        tau: (K, nv) generalized forces from inverse dynamics (N, N m; base rows ~ 0).
        forces: (K, P, 3) contact forces, world frame (N).
        cost: () the NLP's objective at the solution.
        degenerate: () bool: strict complementarity fails, derivatives are one-sided.
        x: (n,) the NLP's solution vector; lam: (m,) its constraint multipliers, 0 on the rows
            the derivatives hold inactive (`jtraj.implicit.ImplicitSolution.lam`).
    """

    t: jax.Array
    base_xyz_wxyz: jax.Array
    q_base: jax.Array
    q_joints: jax.Array
    v: jax.Array
    a: jax.Array
    tau: jax.Array
    forces: jax.Array
    cost: jax.Array
    degenerate: jax.Array
    x: jax.Array
    lam: jax.Array


class DifferentiableTask:
    """The callable that `differentiable` returns: ``f(theta) -> OptimalMotion``.

    Attributes:
        transcription: the task's `jtraj.transcription.Transcription`.
        nlp: its NLP (with the force regularization).
        theta: the task's default parameters (`TaskParams`); change fields with
            ``f.theta.replace(friction=0.5)``.
        options: the forward solve's options (`forward_options`). Assigned an options object,
            a dict or None, it takes them as `differentiable`'s ``options`` does (for Ipopt a
            dict over `IPOPT_OPTIONS`), checked, from the next call on.
        last_solution: the backend's `jtraj.solvers.Solution` of the latest forward solve.
    """

    def __init__(self, tr: Transcription, nlp: KnotNLP, backend: solvers.AbstractSolver, options: solvers.AbstractOptions, weak_tol: float, say: Any = None):
        self.transcription = tr
        self.nlp = nlp
        self.theta = tr.default_theta()
        self.backend = backend
        self.options = options
        self.last_solution: solvers.Solution | None = None
        self._x_warm: np.ndarray | None = None

        def prepare(theta):
            theta = jax.tree_util.tree_map(jnp.asarray, theta)
            # differentiable() checks the task's weights; theta can set them too (here they are
            # values, also under jax.jit): without them the optimum is not unique and the
            # derivatives came back wrong without a word (a zero acceleration weight on the
            # Go2 hop: d cost / d target x 0.025 against 0.037 by re-solving)
            _check_weights(tr.task.name, float(theta.configuration_weight), float(theta.acceleration_weight), "theta sets")
            # as jtraj.solve refuses it (here values, also under jax.jit): a standing pose or a
            # target off the terrain ran the solver to an infeasible stop
            tr.check_boundaries(theta)
            x0 = tr.warm_start(theta).reshape(-1) if self._x_warm is None else self._x_warm
            return theta, x0

        def checked(sol, member=""):
            if not sol.status.converged:
                own = f" ({sol.message})" if sol.message and sol.message != sol.status.message else ""
                raise SolveError(
                    f"{tr.task.name}: {backend.name} did not converge at this theta{member} ({sol.status.value}: {sol.status.message}{own}; "
                    f"{sol.stats.iterations} iterations, violation {sol.constraint_violation:.1e})"
                )
            if sol.status is not solvers.Status.SOLVED:
                # Ipopt's acceptable level allows a violation and a complementarity of 1e-2 by
                # default: the active set read off such a point, and the derivatives, may be wrong
                warnings.warn(
                    f"{tr.task.name}: {backend.name} stopped at an approximate solution{member} ({sol.status.value}: {sol.status.message}; "
                    f"violation {sol.constraint_violation:.1e}): the derivatives are those of this point and may be wrong "
                    f"(Ipopt: acceptable_iter=0 solves on to tol; a warnings filter 'error' refuses such points)",
                    RuntimeWarning,
                    stacklevel=3,
                )
            return sol.x, sol.mult_g

        first = [True]  # the first forward solve compiles the NLP's functions: said when `say` is given

        def first_said(run, started: str, ended):
            """``run()``, and on the first forward call (with `say`) ``started`` before it and
            ``ended(its result, seconds)`` after."""
            if say is None or not first[0]:
                return run()
            say(f"jtraj.differentiable: {tr.task.name}: {started}")
            t0 = time.perf_counter()
            out = run()
            first[0] = False
            say(f"jtraj.differentiable: {tr.task.name}: {ended(out, time.perf_counter() - t0)}")
            return out

        def forward(theta):
            theta, x0 = prepare(theta)
            sol = first_said(
                lambda: backend.solve(nlp, x0, theta, self.options),
                f"first forward solve with {backend.name} (compiles the NLP's functions, once)",
                lambda sol, seconds: f"{sol.status.value} in {sol.stats.iterations} iterations, {seconds:.1f} s",
            )
            self.last_solution = sol
            out = checked(sol)
            self._x_warm = sol.x
            return out

        def forward_many(thetas):
            # a batch (jax.vmap over theta): every member from the same warm start, side by side
            # where the backend runs as compiled JAX (`_side_by_side`), else one after another
            prepared = [prepare(theta) for theta in thetas]
            opts = self.options
            solve = lambda job: backend.solve(nlp, job[1], job[0], opts)  # noqa: E731

            def solve_all():
                if _side_by_side(backend) and len(prepared) > 1:
                    from concurrent.futures import ThreadPoolExecutor

                    from jtraj.config import cpu_count

                    # the first to need the program compiles it; the others wait for it
                    with ThreadPoolExecutor(min(len(prepared), cpu_count())) as pool:  # the process's cores
                        return list(pool.map(solve, prepared))
                return [solve(job) for job in prepared]

            solutions = first_said(
                solve_all,
                f"first forward solves, {len(prepared)} with {backend.name} (compile the NLP's functions, once)",
                lambda solutions, seconds: f"{len(solutions)} solves in {seconds:.1f} s",
            )
            outs = []
            for i, sol in enumerate(solutions):  # a loop, not a comprehension: checked's stacklevel
                self.last_solution = sol  # the failed member, if one fails
                outs.append(checked(sol, f" (member {i} of a batch of {len(solutions)})"))
            self._x_warm = solutions[-1].x
            return outs

        first_derivative = None if say is None else f"jtraj.differentiable: {tr.task.name}: first derivative (compiles the implicit function theorem's tangent and the KKT system's functions, once)"
        self._solution = implicit_solution(nlp, forward, weak_tol=weak_tol, forward_many=forward_many, say=say, first_derivative=first_derivative)

    @property
    def options(self) -> solvers.AbstractOptions:
        return self._options

    @options.setter
    def options(self, options: solvers.AbstractOptions | dict[str, Any] | None) -> None:
        # a dict went to the backend as it was: the backend's defaults (jtraj's Ipopt options: tol 1e-3, L-BFGS) replaced
        # the tight IPOPT_OPTIONS that differentiable() merges a dict over
        self._options = forward_options(self.backend, options)

    def warm_start_from(self, x: np.ndarray | None) -> None:
        """Warm-start the next forward solve from ``x`` (None: the task's warm start): the
        NLP's variables, (n,) or (knots, variables per knot), finite."""
        if x is None:
            self._x_warm = None
            return
        x = np.asarray(x, float)
        if x.size != self.nlp.n or x.shape not in ((self.nlp.n,), (self.transcription.N + 1, self.transcription.layout.nz)):
            raise ValueError(f"warm start of shape {x.shape}; expected ({self.nlp.n},) or ({self.transcription.N + 1}, {self.transcription.layout.nz}), the NLP's variables")
        if not np.all(np.isfinite(x)):
            raise ValueError("warm start has NaN or infinite entries")
        self._x_warm = x.reshape(-1)

    def __call__(self, theta: TaskParams | dict[str, Any] | None = None) -> OptimalMotion:
        """The optimal motion at ``theta``: a `TaskParams`, a mapping of overrides of ``self.theta``'s
        fields (``{"friction": 0.6}``) or None (``self.theta``). Values are checked as
        `jtraj.solve` checks them (shapes always; values unless traced; the fixed first and
        last knots on the terrain, `Transcription.check_boundaries`, as the forward solve
        starts, also under ``jax.jit``), and the cost weights must stay > 0 (`differentiable`;
        a ValueError). Raises `SolveError`
        when the forward solve does not converge (inside ``jax.jit`` or ``jax.vmap``, where the
        solve is a host callback, that comes as JAX's runtime error,
        ``jax.errors.JaxRuntimeError``, whose message ends with the SolveError's; so does a
        `jtraj.sensitivity.NotAKKTPointError`), and warns (RuntimeWarning)
        when it converged only to the acceptable level (`jtraj.solvers.Status.ACCEPTABLE`)."""
        theta = self.transcription.resolve_theta(self.theta if theta is None else theta, base=self.theta)
        sol = self._solution(theta)
        return motion(self.transcription, self.nlp, sol.x, theta, sol.lam, sol.degenerate)


def motion(tr: Transcription, nlp: KnotNLP, x: jax.Array, theta: TaskParams, lam: jax.Array, degenerate: jax.Array) -> OptimalMotion:
    """`OptimalMotion` of a solution vector x at theta (JAX; differentiable in x and theta)."""
    L, param = tr.layout, tr.param
    Z = x.reshape(tr.N + 1, L.nz)
    s = L.split(Z)
    q, v, f = s["q"], s["v"], s["f"]
    if "a" in s:
        a = s["a"]
    else:
        a = jnp.concatenate([(v[1:] - v[:-1]) / theta.timestep, jnp.zeros_like(v[:1])])
    tau = jax.vmap(tr._tau, in_axes=(0, 0, 0, 0, None))(q, v, a, f, theta.body_masses)
    qpos = jax.vmap(param.to_qpos)(q[:, : param.nq])
    return OptimalMotion(
        t=jnp.arange(tr.N + 1) * theta.timestep,
        base_xyz_wxyz=qpos,
        q_base=q[:, : param.nq],
        q_joints=q[:, param.nq :],
        v=v,
        a=a,
        tau=tau,
        forces=f.reshape(tr.N + 1, tr.P, 3),
        cost=nlp.objective(x, theta),
        degenerate=degenerate,
        x=x,
        lam=lam,
    )


def _side_by_side(backend: solvers.AbstractSolver) -> bool:
    """Whether a batch's forward solves may run side by side in threads: jtraj's solver (one
    compiled JAX program per NLP, which releases the GIL while it runs) on a CPU-only JAX; not
    Ipopt (its callbacks hold the GIL, and MUMPS is not known to be thread-safe), and not on an
    accelerator, where the callback's thread keeps JAX's default device on the CPU
    (`jtraj.implicit`) and the workers, which do not inherit that setting, would dispatch to
    the accelerator from inside the running computation."""
    return backend.name == "jtraj" and jax.default_backend() == "cpu"


def _check_weights(name: str, configuration_weight: float, acceleration_weight: float, source: str) -> None:
    """Refuse cost weights without which the optimum is not unique (``source`` says who set
    them: the task or theta)."""
    if not (configuration_weight > 0 and acceleration_weight > 0):
        raise ValueError(
            f"{name}: {source} configuration_weight={configuration_weight} and acceleration_weight={acceleration_weight}; "
            "differentiable tasks need configuration_weight > 0 and acceleration_weight > 0 for a unique optimum"
        )


def differentiable(
    task: tasks.Task | str,
    parameterization: str | params.AbstractParameterization = "se3",
    *,
    solver: str | solvers.AbstractSolver = "ipopt",
    options: solvers.AbstractOptions | dict[str, Any] | None = None,
    variables: str | TranscriptionOptions = COMPACT_VARIABLES,
    force_weight: float = 1e-3,
    weak_tol: float = 1e-6,
    layout: str | TranscriptionOptions | None = None,
    progress: bool = True,
) -> DifferentiableTask:
    """``f(theta) -> OptimalMotion``, the task's optimal motion as a differentiable function.

    Args:
        task: a task name, ``.toml`` path or `jtraj.task.Task`; it needs positive
            ``configuration_weight`` and ``acceleration_weight`` (a unique optimum).
        parameterization: the floating-base parameterization (``"se3"`` default).
        variables: the variables per knot, a name of `jtraj.solver.VARIABLES` or a
            `jtraj.transcription.TranscriptionOptions` (default compact).
        force_weight: weight of the force regularization ``1/2 w |f / (m g)|^2`` per knot
            and contact point (makes internal contact forces unique); ``m`` is the robot
            model's mass, a constant: theta's ``body_masses`` do not rescale this term.
        solver: a `jtraj.solvers.SOLVERS` name or a solver object, for the forward solve.
        options: its options. A dict is merged over the forward solve's defaults (None:
            those alone), `IPOPT_OPTIONS` for Ipopt (tol 1e-10 and the exact Hessian) and
            `JTRAJ_OPTIONS` for jtraj's solver (the same, and a floor under its dual
            regularization), so ``{"max_iter": 50}`` keeps the tight tolerance; an options
            object is used as given. The task's own ``max_iter`` (the study's limit, 50 to
            200) is not used: the tight tolerance takes more, and the defaults allow 500. Other backends: their defaults and the dict's changes.
            jtraj's solver's own defaults are loose for derivatives: it stops at tol 1e-3
            (measured on the Go2 hop of tests/test_differentiable.py: d take-off velocity /
            d trunk mass -1.42992e-3 against Ipopt's -1.43133e-3, which central differences
            confirm); with `JTRAJ_OPTIONS` it gives Ipopt's -1.431328e-3 in 15 iterations.
        weak_tol: tolerance of the weak-activity (degeneracy) test, relative to the largest
            multiplier (see `jtraj.sensitivity.active_set`).
        layout: the former name of ``variables`` (deprecated: warns).
        progress: True (default) says on stderr, one line each, what compiles before it does:
            the exact Hessian here, the NLP's functions at the first forward solve, and the
            tangent's program and the KKT system's functions at the first derivative (each
            about a minute for a small Go2 hop on a 2-core CPU without the compilation cache);
            False: silent.

    Returns:
        a `DifferentiableTask`: call it with a `TaskParams` (``f.theta`` is the task's).
    """
    variables = renamed_argument(variables, layout, "variables", "layout", COMPACT_VARIABLES)
    if not is_real(force_weight) or not (math.isfinite(force_weight) and force_weight > 0):
        raise ValueError(f"force_weight must be a finite number > 0 (it makes the contact forces unique), got {force_weight!r}")
    check_weak_tol(weak_tol)
    if not isinstance(progress, (bool, np.bool_)):
        raise ValueError(f"progress={progress!r}: expected True or False")
    say = _say if progress else None
    backend = solvers.get(solver)  # unknown names and options fail here, before building anything
    opts = forward_options(backend, options)
    # a bad parameterization or variables name was refused only after the task and the robot
    # were loaded
    param, transcription = params.get(parameterization), transcription_options(variables)
    config.enable_compilation_cache()
    task = tasks.load(task)
    _check_weights(task.name, task.configuration_weight, task.acceleration_weight, "the task sets")
    robot = robots.load(task.robot)
    tr = Transcription(robot, task, param, transcription)
    groups = [g for stage in CONSTRAINT_STAGES for g in stage(tr)]
    weight = force_weight / (robot.total_mass * GRAVITY) ** 2
    costs = cost_terms(tr) + [CostGroup("force", (Dep("f"),), lambda theta, data, f: 0.5 * weight * jnp.sum(f**2), np.arange(tr.N + 1))]
    nlp = KnotNLP(
        tr.layout, tr.N + 1, costs, groups,
        lambda theta: tr.bounds(theta)[0], lambda theta: tr.bounds(theta)[1],
        theta=tr.default_theta(), structure=tr.structure,
    )
    if say is not None:
        say(f"jtraj.differentiable: {task.name} on {robot.name} with {param.label}: {nlp.n} variables, {nlp.m} constraints; compiling the exact Hessian (once)")
    t0 = time.perf_counter()
    nlp.build_hessian()
    if say is not None:
        say(f"jtraj.differentiable: {task.name}: the exact Hessian built in {time.perf_counter() - t0:.1f} s")
    return DifferentiableTask(tr, nlp, backend, opts, weak_tol, say)


def _say(text: str) -> None:
    """`differentiable`'s progress line, on stderr."""
    print(text, file=sys.stderr, flush=True)


def forward_options(backend: solvers.AbstractSolver, options: solvers.AbstractOptions | dict[str, Any] | None) -> solvers.AbstractOptions:
    """The forward solve's options: a dict (or None) over `IPOPT_OPTIONS` for Ipopt and over
    `JTRAJ_OPTIONS` for jtraj's solver, an options object as given; other backends:
    ``backend.options(options)``."""
    defaults = _FORWARD_OPTIONS.get(backend.name)
    if defaults is not None and (options is None or isinstance(options, Mapping)):
        options = {**defaults, **(options or {})}
    return backend.options(options)
