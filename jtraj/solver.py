"""``jtraj.solve(task, parameterization, **options) -> Result``."""

from __future__ import annotations

import contextlib
import dataclasses
import math
import re
import threading
import time
import types
from collections.abc import Mapping
from typing import Any

import jax.numpy as jnp
import numpy as np

from jtraj import config, solvers
from jtraj import io as jio
from jtraj import parameterization as params
from jtraj import robot as robots
from jtraj import task as tasks
from jtraj.deprecation import renamed_argument, warn_renamed
from jtraj.nlp import KnotNLP
from jtraj.numbers import is_seed, is_whole
from jtraj.registry import lookup
from jtraj.result import Outcome, Result, folder_in_the_way
from jtraj.solvers.base import guess_shapes, initial_guess
from jtraj.success import FEASIBILITY_TOL
from jtraj.success import evaluate as check_motion
from jtraj.transcription import COMPACT_VARIABLES, LEAN_VARIABLES, PAPER_VARIABLES, TaskParams, Transcription, TranscriptionOptions

#: The named choices of variables per knot (``variables=`` of `solve`, ``--variables``).
VARIABLES = {"paper": PAPER_VARIABLES, "compact": COMPACT_VARIABLES, "lean": LEAN_VARIABLES}


def transcription_options(variables: str | TranscriptionOptions) -> TranscriptionOptions:
    """The `TranscriptionOptions` a ``variables=`` argument names (a `VARIABLES` key or an
    options object)."""
    if isinstance(variables, TranscriptionOptions):
        return variables
    return lookup(VARIABLES, variables, "variables", hint=" or a TranscriptionOptions")


def variables_label(variables: str | TranscriptionOptions) -> str:
    """A name for ``variables`` in tables and run keys: a `VARIABLES` key as it is, an options
    object by the key it equals, else by the nearest key and the fields that differ from it
    (``"paper+force_limits=rows+contact_height=row"``)."""
    if isinstance(variables, str):
        transcription_options(variables)  # an unknown name fails here, with the known ones
        return variables
    options = transcription_options(variables)

    def changes(base: TranscriptionOptions) -> list[str]:
        return [f"{f.name}={getattr(options, f.name)}" for f in dataclasses.fields(options) if getattr(options, f.name) != getattr(base, f.name)]

    name = min(VARIABLES, key=lambda key: len(changes(VARIABLES[key])))
    return "+".join([name, *changes(VARIABLES[name])])


def with_changes(variables: str | TranscriptionOptions, changes: dict[str, str] | None) -> str | TranscriptionOptions:
    """``variables`` with fields of its `TranscriptionOptions` replaced (``changes``: field name
    to value, the values of the string fields); no changes: ``variables`` as it is. Raises
    ValueError for a field that is not a string field, and the options' own checks."""
    if not changes:
        return variables
    options = transcription_options(variables)
    settable = {f.name for f in dataclasses.fields(options) if f.type in (str, "str")}
    unknown = sorted(set(changes) - settable)
    if unknown:
        raise ValueError(f"{unknown}: not a field of the variables that can be set; expected some of {sorted(settable)}")
    fields: dict[str, Any] = dict(changes)
    try:
        return dataclasses.replace(options, **fields)
    except ValueError as e:
        # "it needs contact_variables=True": a field no change can set; which variables have it
        needed = re.search(r"it needs (\w+)=True", str(e))
        having = [name for name, o in VARIABLES.items() if needed and getattr(o, needed.group(1), False)]
        if not having:
            raise
        raise ValueError(f"{e} (as the variables {' and '.join(map(repr, having))} have: variables={having[0]!r}, --variables {having[0]})") from None


def __getattr__(name: str) -> Any:
    if name == "LAYOUTS":  # its former name
        warn_renamed("jtraj.solver.LAYOUTS", "jtraj.solver.VARIABLES")
        return VARIABLES
    raise AttributeError(f"module 'jtraj.solver' has no attribute {name!r}")


__all__ = ["solve", "prepare", "Prepared", "release_compiled", "release_compiled_if_crowded", "VARIABLES", "transcription_options", "variables_label", "with_changes", "solver_options", "evaluate", "memory_maps", "compile_callbacks"]


class Prepared:
    """A transcription with its compiled NLP, reusable across solves (noise replicates...)."""

    def __init__(self, transcription: Transcription, nlp: KnotNLP, time_compile: float):
        self.transcription = transcription
        self.nlp = nlp
        self.time_compile = time_compile


_CACHE: dict[tuple, Prepared] = {}
#: guards `_CACHE` and `_BUILDING` (a key's lock while a thread builds its NLP)
_CACHE_LOCK = threading.Lock()
_BUILDING: dict[tuple, threading.Lock] = {}


def _is_prepared(task: tasks.Task | str, parameterization: str | params.AbstractParameterization, variables) -> bool:
    """Whether `prepare` holds the NLP of this key already (False for a task that does not load:
    `prepare` raises its error)."""
    try:
        key = (tasks.load(task), params.get(parameterization), transcription_options(variables))
    except Exception:
        return False
    with _CACHE_LOCK:
        return key in _CACHE


def release_compiled() -> None:
    """Forget every NLP that `prepare` keeps (with each, the solver programs compiled for it) and
    JAX's in-memory caches of compiled functions, so that their memory is freed; the next solve
    compiles again (from the persistent compilation cache where it holds the programs)."""
    import gc

    import jax

    from jtraj.solvers import ipopt

    # under the lock: a thread between `prepare`'s test of a key and its read of it got a
    # KeyError from a clear in another thread (a solve's `release_compiled_if_crowded`)
    with _CACHE_LOCK:
        _CACHE.clear()
    ipopt.forget_hessians()  # (their programs go with JAX's caches)
    jax.clear_caches()
    gc.collect()


def memory_maps() -> tuple[int, int] | None:
    """(memory maps this process holds, the kernel's limit ``vm.max_map_count``), or None where
    the system does not tell (not Linux)."""
    try:
        with open("/proc/self/maps", "rb") as f:
            held = sum(1 for _ in f)
        with open("/proc/sys/vm/max_map_count") as f:
            return held, int(f.read())
    except (OSError, ValueError):
        return None


def release_compiled_if_crowded(share: float = 0.5) -> bool:
    """`release_compiled` when this process holds more than ``share`` of the kernel's limit of
    memory maps; returns whether it did. Each compiled XLA executable holds memory maps (measured
    on big_jump: about 3,300 for its NLP's functions, 6,300 with jtraj's solver program), and a
    process past the limit (65,530 by default on Linux) fails in LLVM ("Cannot allocate memory")
    and crashes: a sweep kept in one process met it at its 12th group, a benchmark of 18
    programs at its 9th. `prepare` calls this before it builds a new NLP."""
    maps = memory_maps()
    if maps is None or maps[0] <= share * maps[1]:
        return False
    release_compiled()
    return True


def prepare(
    task: tasks.Task | str,
    parameterization: str | params.AbstractParameterization = "se3",
    variables: str | TranscriptionOptions = "compact",
    *,
    layout: str | TranscriptionOptions | None = None,
) -> Prepared:
    """Build (once per task, parameterization and variables per knot) the transcription and
    compile its NLP. ``variables`` as in `solve`; ``layout`` is its deprecated former name.

    The task is part of the key field by field: a task with another value of a parameter (or
    ``max_iter``, ``description``) is another NLP, built and compiled again. To reuse the
    compiled NLP, pass the parameter as ``theta`` (`solve`'s) and the iteration limit as a
    solver option. Threads that ask for the same key at once build it once."""
    variables = renamed_argument(variables, layout, "variables", "layout", "compact")
    task = tasks.load(task)
    param = params.get(parameterization)
    options = transcription_options(variables)
    key = (task, param, options)
    with _CACHE_LOCK:
        if (hit := _CACHE.get(key)) is not None:
            return hit
        building = _BUILDING.setdefault(key, threading.Lock())
    with building:  # two threads missed the cache: the second waits for the first's build
        with _CACHE_LOCK:
            hit = _CACHE.get(key)
        if hit is not None:
            return hit
        prep = _build(key, task, param, options)
        # (only once built: after a failed build, the threads that retry still take turns)
        with _CACHE_LOCK:
            _BUILDING.pop(key, None)
        return prep


def _check_before_the_build(task, parameterization, variables, theta, warm_start) -> None:
    """`solve`'s checks of a given theta's values (`Transcription.resolve_theta`,
    `Transcription.check_boundaries`) and a given warm start's shape, on the transcription of
    the prepared NLP where there is one, else on one made for them (no NLP built)."""
    task, param, options = tasks.load(task), params.get(parameterization), transcription_options(variables)
    with _CACHE_LOCK:
        hit = _CACHE.get((task, param, options))
    tr = hit.transcription if hit is not None else Transcription(robots.load(task.robot), task, param, options)
    if theta is not None:
        tr.check_boundaries(tr.resolve_theta(theta))
    if warm_start is not None:
        knots, nz = tr.N + 1, tr.layout.nz
        shape = types.SimpleNamespace(n=knots * nz, n_knots=knots, nz=nz)
        try:
            fits = np.shape(np.asarray(warm_start, float)) in guess_shapes(shape)
        except (TypeError, ValueError):
            fits = False
        if not fits:  # (its entries are checked with the NLP, which names their slots)
            initial_guess(shape, warm_start, "warm_start")


def _build(key: tuple, task: tasks.Task, param: params.AbstractParameterization, options: TranscriptionOptions) -> Prepared:
    # about to compile a new NLP (and, for jtraj's solver, its program): a process that went
    # through many of them (a sweep, a benchmark, a notebook) frees the earlier ones first
    release_compiled_if_crowded()
    config.enable_compilation_cache()
    t0 = time.perf_counter()
    robot = robots.load(task.robot)
    tr = Transcription(robot, task, param, options)
    nlp = tr.build_nlp()
    compile_callbacks(tr, nlp)
    prep = Prepared(tr, nlp, time.perf_counter() - t0)
    with _CACHE_LOCK:
        _CACHE[key] = prep
    return prep


def _check_theta_form(theta: Any) -> None:
    """`solve`'s ``theta`` checked for its form and names before the NLP is built (its values
    need the task's shapes: `Transcription.resolve_theta`); the messages are resolve_theta's
    and `TaskParams.replace`'s."""
    if theta is None or isinstance(theta, TaskParams):
        return
    if not isinstance(theta, Mapping):
        raise TypeError(f"theta must be None, a mapping of parameter overrides or a TaskParams, got {type(theta).__name__}")
    names = [f.name for f in dataclasses.fields(TaskParams)]
    for name in theta:
        if name not in names:
            raise ValueError(f"unknown task parameter {name!r}; expected one of {names}")


def compile_callbacks(tr: Transcription, nlp: KnotNLP) -> None:
    """Compile the NLP functions Ipopt calls, for the current default device, by calling each
    once on the warm start (so that a timed solve does not include compiling them)."""
    x = jnp.asarray(tr.warm_start().reshape(-1))
    for fn in (nlp.objective, nlp.gradient, nlp.constraints, nlp.jacobian):
        np.asarray(fn(x, nlp.theta))


def solve(
    task: tasks.Task | str,
    parameterization: str | params.AbstractParameterization = "se3",
    *,
    variables: str | TranscriptionOptions = "compact",
    solver: str | solvers.AbstractSolver = "ipopt",
    options: solvers.AbstractOptions | dict[str, Any] | None = None,
    exact_hessian: bool = False,
    ipopt_options: dict[str, Any] | None = None,
    warm_start: np.ndarray | None = None,
    noise: float = 0.0,
    seed: int = 0,
    replicate: int | None = None,
    noise_chart: str | None = None,
    progress: solvers.Progress = True,
    progress_every: int = 1,
    out: str | None = None,
    keep_trajectory: bool = True,
    theta: TaskParams | dict[str, Any] | None = None,
    layout: str | TranscriptionOptions | None = None,
    command: list[str] | None = None,
) -> Result:
    """Solve a task with one of `jtraj.solvers.SOLVERS` (Ipopt by default).

    Args:
        task: a built-in task name (``"big_jump"``), a ``.toml`` path or a `jtraj.task.Task`.
        parameterization: ``"se3"`` (default), ``"quat1"``, ``"quat2"``, ``"quat3"``, ``"euler"``
            or a parameterization object.
        variables: variables per knot (`VARIABLES`, or a `TranscriptionOptions`):
            ``"compact"`` (default; q, v, a, f: contact positions substituted by forward
            kinematics), ``"paper"`` (q, v, a, f, c as the study) or ``"lean"`` (q, v, f:
            accelerations substituted too). ``bench/solve.py TASK`` times them against the study's public code in one
            run (speed depends on the machine and its load: no figures here).
        solver: a name of `jtraj.solvers.SOLVERS` (``"ipopt"``) or a solver object.
        options: the solver's options object (e.g. `jtraj.solvers.IpoptOptions`) or a dict of
            option names (for Ipopt, any Ipopt option); the task's ``max_iter`` is the
            default iteration limit of a dict.
        exact_hessian: use the exact Hessian of the Lagrangian from JAX instead of L-BFGS.
        ipopt_options: a dict of Ipopt options, the same as ``options`` (kept for scripts).
        warm_start: (n_knots, nz) initial guess, in this parameterization's coordinates and
            these variables (an array carries no chart: one made for another parameterization
            of the same size, e.g. se3 and euler, is taken as it is); default the task's warm
            start (`Transcription.warm_start` at ``theta``: its standing pose and masses).
        noise: standard deviation of zero-mean Gaussian noise added to the warm start.
        seed: seed of that noise (numpy's ``default_rng(seed)``, as the study's public code
            draws it, unless ``replicate`` is given).
        replicate: draw the noise as `jtraj.experiments.robustness` draws replicate
            ``replicate`` of ``seed`` at sigma ``noise``, so that one run of a noise study can
            be solved again alone, with its trajectory (`jtraj.experiments.noise_key`).
        noise_chart: with ``replicate``, draw that noise in this parameterization's
            coordinates and start from its noisy poses (`jtraj.experiments.chart_noisy_warm_starts`,
            the study's ``noise_chart``); None: the solved chart's own.
        progress: True (default) prints a line per ``progress_every`` iterations to the
            ``sys.stdout`` of the moment (and a line before building a task's NLP the first
            time); a text stream prints there; False or None is quiet; a
            `jtraj.solvers.AbstractCallback` receives the iterations instead. Ipopt's lines come
            as it iterates; jtraj's solver runs as one compiled program, and its lines come
            when it returns.
        progress_every: print every this many iterations (default 1: each); printed progress
            only (a callback given as ``progress`` receives every iteration, and is refused
            with another value).
        out: directory to write ``result.json`` and ``trajectory.npz`` into: a folder (or none
            yet) this user can write in, checked before the compile (as ``jtraj solve --out``).
            The result's ``options["warm_start"]`` records how the start was made: ``given``
            (a ``warm_start`` array), ``noise``, ``seed`` (None where no noise was drawn:
            ``noise=0`` without ``replicate``), ``replicate`` and ``noise_chart``.
            The folder's ``provenance.json`` (`jtraj.provenance.begin_run`: date, machine,
            versions, source commit) is written once the NLP is built, before the solve (and before
            the compile of jtraj's solver program), marked complete once the result is saved; it names this call (``"call"``) and ``command``.
            The folder is held from before the build to the end (`jtraj.provenance.holding`):
            another process's run in it raises `jtraj.provenance.FolderInUseError` first.
        keep_trajectory: attach the solution's `jtraj.transcription.Trajectory` to the result (default
            True); False keeps only the figures of the solve (the sweeps' setting), and
            ``out`` then writes no ``trajectory.npz``.
        theta: the task's parameters (`jtraj.transcription.TaskParams`), or a dict
            overriding some of them (``{"friction": 0.5, "timestep": 0.04}``); other values
            of theta reuse the compiled NLP. A standing pose or target that puts the fixed
            first or last knot off the terrain its phases stand on is refused before the
            solver runs (`Transcription.check_boundaries`).
        layout: the former name of ``variables`` (deprecated: warns).
        command: the command line ``out``'s ``provenance.json`` records (``jtraj solve``
            passes its own); default this process's (``sys.argv``).
    """
    variables = renamed_argument(variables, layout, "variables", "layout", "compact")
    # the arguments that need no model, checked before anything compiles
    # a number: one of numpy's or JAX's scalars too, not a bool (noise=True was sigma 1)
    kind = np.asarray(noise).dtype
    if isinstance(noise, (bool, np.bool_)) or np.ndim(noise) != 0 or not (np.issubdtype(kind, np.integer) or np.issubdtype(kind, np.floating)):
        raise ValueError(f"solve: noise={noise!r}: expected a standard deviation >= 0")
    noise = float(noise)
    if not (math.isfinite(noise) and noise >= 0):
        raise ValueError(f"solve: noise={noise!r}: expected a standard deviation >= 0")
    for name, flag in (("exact_hessian", exact_hessian), ("keep_trajectory", keep_trajectory)):
        if not isinstance(flag, (bool, np.bool_)):  # exact_hessian="false" chose the exact Hessian
            raise ValueError(f"solve: {name}={flag!r}: expected True or False")
    # a string was joined letter by letter into provenance.json's command
    if command is not None and (isinstance(command, str) or not all(isinstance(a, str) for a in command)):
        raise ValueError(f"solve: command={command!r}: expected a list of strings (shlex.split(text) splits a command line)")
    # replicate=1.5 drew replicate 1 and replicate=-1 one no study has (numbers are cast to
    # uint32); a negative seed of numpy's noise failed in default_rng after the NLP was built
    # and 2**32 drew replicate 0's noise while the result recorded 2**32 (JAX folds 32 bits in)
    if replicate is not None and (not is_whole(replicate) or not 0 <= replicate < 2**32):
        raise ValueError(f"solve: replicate={replicate!r}: expected a replicate number >= 0 and below 2**32 (jtraj.experiments.robustness numbers them from 0)")
    if (noise or replicate is not None) and not is_whole(seed):
        raise ValueError(f"solve: seed={seed!r}: expected an integer")
    if replicate is not None and not is_seed(seed):  # the study's draws: JAX's PRNGKey, after the compile
        raise ValueError(f"solve: seed={seed!r}: expected a 64-bit integer (below 2**63 in magnitude)")
    if noise and replicate is None and seed < 0:
        raise ValueError(f"solve: seed={seed!r}: expected a seed >= 0 for numpy's default_rng, which draws this noise (replicate= draws with JAX, which takes any)")
    if out is not None and (problem := jio.output_folder_problem(out) or folder_in_the_way(out)) is not None:  # (not after the solve)
        raise ValueError(f"solve: out={out!r}: {problem}")
    # how the start is drawn, and theta's form and names (its values need the task's shapes)
    if replicate is not None and (warm_start is not None or theta is not None):
        raise ValueError("solve: replicate= solves a run of the noise study, from the task's own warm start at its own theta; give it without warm_start= and theta=")
    if noise_chart is not None and replicate is None:
        raise ValueError("solve: noise_chart= needs replicate= (the study's draws)")
    if noise_chart is not None and noise_chart not in params.PARAMETERIZATIONS:
        raise ValueError(f"solve: noise_chart={noise_chart!r}: expected one of {', '.join(params.PARAMETERIZATIONS)} or None")
    _check_theta_form(theta)
    backend = solvers.get(solver)
    # with the task's own iteration limit (a file's, read without building anything): jtraj's
    # solver refuses a limit its 32-bit loop bound cannot hold, and with 0 here that came after
    # the NLP's build and compile
    loaded = tasks.load(task)  # (read once here: the checks below and the build message use it)
    solver_options(backend, options, ipopt_options, exact_hessian, loaded.max_iter)
    if not is_whole(progress_every) or progress_every < 1:  # (numpy's integers too; not True)
        raise ValueError(f"solve: progress_every={progress_every!r}: expected an integer >= 1")
    progress_every = int(progress_every)
    if progress_every != 1 and isinstance(progress, solvers.AbstractCallback):  # it was ignored
        raise ValueError(f"solve: progress_every={progress_every} with a callback: the callback receives every iteration; progress_every sets how often printed progress prints")
    callback = solvers.resolve_progress(progress, progress_every)
    if callback is not None and callback.wants_iterates and not backend.reports_iterates:
        raise ValueError(f"solve: progress={progress!r} records the iterates, which solver={backend.name!r} does not report: record them with solver='ipopt'")
    if noise_chart is not None:  # a chart that cannot take the noisy poses: refused before the compile
        from jtraj.experiments import check_noise_chart

        check_noise_chart([task], [params.get(parameterization).name], variables, noise_chart)
    # held from here (`jtraj.provenance.holding`), however the solve ends: another process's run
    # in it is refused before the build
    held = contextlib.ExitStack()
    if out is not None:
        from jtraj.provenance import holding

        held.enter_context(holding(out))
    with held:
        if theta is not None or warm_start is not None:
            # their values and shape, on the transcription alone (seconds at most), before the NLP
            # is built and compiled (tens of seconds on a whole-body task)
            _check_before_the_build(task, parameterization, variables, theta, warm_start)
        if isinstance(callback, solvers.PrintProgress) and not _is_prepared(loaded, parameterization, variables):
            # tens of seconds on a whole-body task, which printed nothing until the NLP was built
            # (named by the task's name, also where a file's path was given)
            callback.write(f"jtraj: building {loaded.name}'s NLP ({params.get(parameterization).label}, {variables_label(variables)} variables) and compiling its functions ...")
        prep = prepare(task, parameterization, variables)
        tr, nlp = prep.transcription, prep.nlp
        theta_given = theta is not None
        theta = tr.resolve_theta(theta)
        if theta_given:
            tr.check_boundaries(theta)  # a standing pose or target that no solver could meet
        # a given warm start as one of the NLP's guess shapes, named in the error: flattened first, a
        # transposed (nz, n_knots) guess had the right size and was solved from scrambled knots
        x0 = tr.warm_start(theta) if warm_start is None else initial_guess(nlp, warm_start, "warm_start")
        if replicate is not None:
            from jtraj.experiments import chart_noisy_warm_starts

            x0 = chart_noisy_warm_starts(tr, noise_chart, [noise], [replicate], seed)[0, 0]
        elif noise:
            x0 = x0 + noise * np.random.default_rng(seed).standard_normal(x0.shape)
        with _CACHE_LOCK:  # (two threads' solves both reported it)
            compile_time, prep.time_compile = prep.time_compile, 0.0  # counted once per process (by the first solve that gets this far)
        run = None
        if out is not None:  # the inputs are good: unfinished from here until the result is saved
            from jtraj.provenance import begin_run

            call = {"function": "jtraj.solve", "task": tr.task.name, "parameterization": tr.param.name, "solver": backend.name, "variables": dataclasses.asdict(tr.options), "theta_given": theta_given}
            run = begin_run(out, command, {"call": call})
        opts = solver_options(backend, options, ipopt_options, exact_hessian, tr.task.max_iter)
        say = callback.write if isinstance(callback, solvers.PrintProgress) else None
        if say is not None:
            say(
                f"jtraj: {tr.task.name} on {tr.robot.name} with {tr.param.label}: {nlp.n} variables, "
                f"{nlp.m} constraints, {nlp.nnz_jac} Jacobian nonzeros, {tr.N + 1} knots"
                + (f" (compiled in {compile_time:.1f} s)" if compile_time else "")
            )
        solution = backend.solve(nlp, x0.reshape(-1), theta, opts, callback)
        compile_time += solution.time_compile  # the backend's own program (jtraj's solver)
        traj = tr.decode(solution.x, theta)
        # how the start was drawn (a seed that is not whole drew nothing: noise needs a whole one)
        start = {"given": warm_start is not None, "noise": float(noise), "seed": int(seed) if is_whole(seed) and (noise or replicate is not None) else None, "replicate": None if replicate is None else int(replicate), "noise_chart": noise_chart}
        settings = {"solver": backend.name, **opts.as_dict(), "layout": dataclasses.asdict(tr.options), "warm_start": start, "terrain_height": float(tr.task.terrain_height)}
        result = evaluate(tr, solution, traj, compile_time, settings, nlp.nnz_jac, nlp.violation_by_group(solution.x, theta), theta, backend.name)
        if not keep_trajectory:
            result.trajectory = None
        if say is not None:
            say(result.summary())
            if result.status is Outcome.TASK_FAILED:
                say(f"  task check failed: {result.metrics['task_check']}")
            elif result.status is Outcome.NOT_CONVERGED:
                if result.converged:
                    say(f"  {backend.name} converged, but to a violation of {result.constraint_violation:.2e}, over the feasibility tolerance {FEASIBILITY_TOL:g}")
                else:
                    say(f"  {backend.name} stopped: {result.solver_status.value} ({result.solver_status.message})")
                    if result.solver_status is solvers.Status.INVALID_PROBLEM:  # the bound at fault is in the solver's own message
                        say(f"  {result.status_msg}")
                # NaN first (a group with a NaN row is the worst), then largest; NaN keys left
                # the sort's order to the dict's, and it could name a group at 0
                worst = sorted(result.violation_by_group.items(), key=lambda kv: (not math.isnan(kv[1]), -kv[1]))[:3]
                say("  largest violations: " + ", ".join(f"{k} {v:.2e}" for k, v in worst))
        if out is not None:
            from jtraj.provenance import end_run

            result.save(out)
            assert run is not None
            run.pop("earlier", None)  # the saved result replaced the earlier solve's
            end_run(out, run)
    return result


def solver_options(
    backend: solvers.AbstractSolver,
    options: solvers.AbstractOptions | dict[str, Any] | None,
    ipopt_options: dict[str, Any] | None,
    exact_hessian: bool,
    max_iter: int,
) -> solvers.AbstractOptions:
    """The backend's options object: a given object as it is; otherwise the task's iteration
    limit, then the dicts, then ``exact_hessian`` (a dict's Hessian option that asks for another
    Hessian is a ValueError: one of the two would be ignored)."""
    if isinstance(options, solvers.AbstractOptions):
        if ipopt_options:
            raise ValueError("pass the solver options either as an options object or as ipopt_options, not both")
        if exact_hessian:
            # the object's own choice of another Hessian than its default was replaced without
            # a word (a dict's is refused below)
            chosen = getattr(options, "hessian", None)
            fields = {f.name: f.default for f in dataclasses.fields(options)} if dataclasses.is_dataclass(options) else {}
            if chosen is not None and str(chosen).lower() not in ("exact", str(fields.get("hessian", "")).lower()):
                raise ValueError(f"solve: {type(options).__name__}(hessian={chosen!r}) with exact_hessian=True: expected hessian='exact' (or the default) or exact_hessian=False")
            return backend.options(options, hessian="exact")
        return backend.options(options)
    for name, given in (("options", options), ("ipopt_options", ipopt_options)):
        if given is not None and not isinstance(given, Mapping):  # ('str' object is not a mapping)
            said = f"{type(given).__name__} goes in options=" if isinstance(given, solvers.AbstractOptions) else "expected None, a dict" + (" or an options object" if name == "options" else "")
            raise solvers.InvalidOptionError(f"solve: {name}={given!r}: {said}")
    if options and ipopt_options:
        # both dicts: ipopt_options won where they disagreed, without a word
        clash = sorted(k for k in set(options) & set(ipopt_options) if options[k] != ipopt_options[k])
        if clash:
            said = ", ".join(f"{k}={options[k]!r} and {ipopt_options[k]!r}" for k in clash)
            raise ValueError(f"solve: options and ipopt_options disagree on {said}: expected each option once (they are the same thing)")
    merged: dict[str, Any] = {"max_iter": max_iter, **(options or {}), **(ipopt_options or {})}
    if exact_hessian:
        if conflict := _hessian_conflict(merged):
            raise ValueError(f"solve: {conflict[0]}={conflict[1]!r} with exact_hessian=True: expected {conflict[0]}='exact' or exact_hessian=False")
        merged.pop("hessian_approximation", None)
        merged["hessian"] = "exact"
    return backend.options(merged)


def _hessian_conflict(options: dict[str, Any]) -> tuple[str, Any] | None:
    """The option of ``options`` that asks for another Hessian than the exact one (Ipopt's
    ``hessian_approximation``, the backends' ``hessian``), as (name, value); None if none does."""
    for key in ("hessian_approximation", "hessian"):
        # Ipopt takes its strings in any case ("EXACT"), as `IpoptOptions.from_dict` does
        if key in options and not (isinstance(options[key], str) and options[key].lower() == "exact"):
            return key, options[key]
    return None


def evaluate(tr: Transcription, solution: solvers.Solution, traj, compile_time: float, options: dict[str, Any], nnz_jacobian: int = 0, violation_by_group: dict[str, float] | None = None, theta: TaskParams | None = None, solver: str = "ipopt") -> Result:
    """Task-success check (`jtraj.success`): converged, feasible to `FEASIBILITY_TOL`, and the
    base motion does the task (a flip with the expected sign, count and axis; no unplanned
    somersault otherwise). The final position error is reported but not tested: the variable
    bounds fix the final pose, so it cannot fail."""
    task = tr.task
    target = tr.target_xyz_wxyz[:3] if theta is None else tr.target_xyz_wxyz_of(theta)[:3]
    check = check_motion(traj.base_xyz_wxyz, task.flip_axis, task.flip_turns)
    metrics: dict[str, Any] = {"final_position_error": float(np.linalg.norm(traj.base_xyz_wxyz[-1, :3] - target)), "turns": check.turns, "task_check": check.reason}
    if theta is not None:  # the parameters solved at (a plot's friction pyramid and weight read theta's friction and masses)
        options = {**options, "theta": {f.name: np.asarray(getattr(theta, f.name), float).tolist() for f in dataclasses.fields(theta)}}
    return Result.from_solution(
        solution,
        feasibility_tol=FEASIBILITY_TOL,
        task_ok=check.ok,
        violation_by_group=violation_by_group or {},
        problem=task.name,
        variant=tr.param.name,
        model=tr.robot.name,
        solver=solver,
        time_compile=compile_time,
        metrics=metrics,
        n_variables=tr.layout.nz * (tr.N + 1),
        nnz_jacobian=nnz_jacobian,
        options=dict(options),
        trajectory=traj,
    )
