"""The contract every NLP solver backend of jtraj fulfils, and what it returns.

A backend is one class: ``solve(nlp, x0, theta, options, callback) -> Solution``.

- ``nlp`` is a `jtraj.nlp.KnotNLP` (or, for Ipopt, anything with the same functions:
  ``objective``, ``gradient``, ``constraints``, ``jacobian`` in COO order, ``hessian`` after
  ``build_hessian()``, their sparsity ``jac_rows/jac_cols/hess_rows/hess_cols`` and the bounds;
  jtraj's own solver works on a KnotNLP's knot structure and refuses another with TypeError).
- ``theta`` is the NLP's parameter pytree; the backend passes it to every function unchanged
  (None for an NLP whose numbers are all constants).
- ``options`` is the backend's own typed options object (`AbstractOptions`): keyword-only,
  validated when it is built, so a wrong option fails before anything compiles or runs.
- ``callback`` receives the start, every iteration and the end (`AbstractCallback`); progress
  printing is one such callback (`PrintProgress`), resolved when the solve starts, so that it
  writes to the ``sys.stdout`` of that moment (pytest's and a notebook's capture included).

Every backend maps its own return codes to the one `Status` enumeration, whose members carry a
message saying what happened and what to try.
"""

from __future__ import annotations

import abc
import dataclasses
import difflib
import enum
import sys
import time
from collections.abc import Callable
from typing import Any, ClassVar, TextIO

import numpy as np

__all__ = [
    "MessageEnum",
    "Status",
    "Stats",
    "Iteration",
    "Solution",
    "AbstractOptions",
    "InvalidOptionError",
    "AbstractCallback",
    "PrintProgress",
    "CallbackList",
    "Progress",
    "resolve_progress",
    "AbstractSolver",
    "max_violation",
    "EvaluationTimer",
    "BoundNLP",
    "bind",
    "guess_shapes",
    "initial_guess",
    "invalid_problem",
    "RecordIterates",
]


class MessageEnum(enum.Enum):
    """An enumeration whose members are ``(value, message)``: ``member.value`` is the short
    name written to files, ``member.message`` says what it means and what to try."""

    message: str

    def __new__(cls, value: str, message: str) -> MessageEnum:
        member = object.__new__(cls)
        member._value_ = value
        member.message = message
        return member


class Status(MessageEnum):
    """How a solve ended, one enumeration for every backend. ``status.message`` explains it."""

    SOLVED = ("solved", "converged to the requested tolerances")
    ACCEPTABLE = ("acceptable", "converged only to the acceptable tolerances (acceptable_tol and friends), not to tol")
    FEASIBLE_POINT = ("feasible_point", "stopped at a feasible point, as asked (a feasibility problem)")
    MAX_ITER = ("max_iter", "the iteration limit was reached; raise max_iter or improve the warm start")
    MAX_WALL_TIME = ("max_wall_time", "the wall-clock limit was reached; raise max_wall_time")
    MAX_CPU_TIME = ("max_cpu_time", "the CPU-time limit was reached; raise max_cpu_time")
    INFEASIBLE = ("infeasible", "the solver found the constraints locally infeasible; check bounds and targets")
    DIVERGING = ("diverging", "the iterates diverged (an unbounded objective or badly scaled problem)")
    SEARCH_DIRECTION_TOO_SMALL = ("search_direction_too_small", "the search direction became too small to make progress; the tolerance may be too tight")
    RESTORATION_FAILED = ("restoration_failed", "the feasibility restoration phase failed (Ipopt), or the filter line search failed several times in a row (jtraj's solver, which has no restoration phase); try another warm start or scaling")
    STEP_COMPUTATION_FAILED = ("step_computation_failed", "no step could be computed: a singular or ill-conditioned KKT system, or (Ipopt) a line search that found no acceptable step at an almost feasible point, where Ipopt does not fall back on restoration")
    NUMERICAL_ERROR = ("numerical_error", "a function returned NaN or Inf; check the model near the iterate")
    USER_STOP = ("user_stop", "a callback asked the solver to stop")
    INVALID_OPTION = ("invalid_option", "the solver rejected an option; see the message for which")
    INVALID_PROBLEM = ("invalid_problem", "the problem is ill-posed (too few degrees of freedom or inconsistent bounds)")
    OUT_OF_MEMORY = ("out_of_memory", "the solver ran out of memory")
    INTERNAL_ERROR = ("internal_error", "the solver failed internally")

    @property
    def converged(self) -> bool:
        """SOLVED or ACCEPTABLE: the solver returned a point it considers a solution."""
        return self in (Status.SOLVED, Status.ACCEPTABLE)


@dataclasses.dataclass(frozen=True)
class Stats:
    """Work of one solve. Times in seconds: ``time_total = time_evaluations + time_solver``,
    where ``time_evaluations`` is spent in the NLP's (JAX) functions and ``time_solver`` in the
    backend's own work (linear algebra, line search, ...). Compilation is not included."""

    iterations: int = 0
    obj_evals: int = 0
    grad_evals: int = 0
    con_evals: int = 0
    jac_evals: int = 0
    hess_evals: int = 0
    time_total: float = 0.0
    time_evaluations: float = 0.0

    @property
    def time_solver(self) -> float:
        return self.time_total - self.time_evaluations


@dataclasses.dataclass(frozen=True)
class Iteration:
    """One iteration as a backend reports it: objective, primal and dual infeasibility, barrier
    parameter ``mu`` (0 for methods without one) and primal step length ``alpha_pr``."""

    iter: int
    objective: float
    inf_pr: float
    inf_du: float
    mu: float = 0.0
    alpha_pr: float = 0.0

    def as_dict(self) -> dict[str, float]:
        return dataclasses.asdict(self)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Solution:
    """What every backend returns.

    Attributes:
        x: (n,) primal solution (the last iterate when not converged).
        status: the `Status`; ``message`` is the backend's own wording of it.
        objective: f(x).
        constraint_violation: max violation of the constraint rows and variable bounds at x.
        mult_g: (m,) multipliers of the constraints g(x).
        mult_x_lower, mult_x_upper: (n,) multipliers of the lower and upper variable bounds.
        stats: iteration and evaluation counts and the time split.
        history: one `Iteration` per iteration, in order.
        time_compile: seconds the backend spent compiling for this solve, outside the timed
            solve: jtraj's solver its program, the first time it meets an NLP, options and
            parameter shapes; Ipopt with ``hessian="exact"`` the NLP's exact Hessian, built and
            called once the first time it meets the NLP (else 0: its other callbacks are
            compiled with the NLP). Not in ``stats``' times.
    """

    x: np.ndarray
    status: Status
    message: str
    objective: float
    constraint_violation: float
    mult_g: np.ndarray
    mult_x_lower: np.ndarray
    mult_x_upper: np.ndarray
    stats: Stats
    history: tuple[Iteration, ...] = ()
    time_compile: float = 0.0

    @property
    def converged(self) -> bool:
        return self.status.converged


class InvalidOptionError(ValueError):
    """A solver option with a wrong name, type or value; the message says how to fix it."""


@dataclasses.dataclass(frozen=True, kw_only=True)
class AbstractOptions:
    """Base of the backends' option objects: frozen, keyword-only, checked at construction
    (subclasses add their checks in ``__check__``, raising `InvalidOptionError`)."""

    #: what the options are for, in error messages
    solver_name: ClassVar[str] = "solver"

    def __post_init__(self) -> None:
        self.__check__()

    def __check__(self) -> None:
        return None

    @classmethod
    def from_dict(cls, values: dict[str, Any] | None) -> AbstractOptions:
        """Options from a plain mapping (command line, JSON); unknown names raise."""
        values = dict(values or {})
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - names)
        if unknown:
            # the nearest names first: the list of every option (about 50 of jtraj's) hid the typo
            close = [f"{name!r} for {near[0]!r}" for name in unknown if isinstance(name, str) and (near := difflib.get_close_matches(name, names, n=1))]
            hint = f" (did you mean {', '.join(close)}?)" if close else ""
            hint += cls._other_solvers_options(unknown)
            raise InvalidOptionError(f"unknown {cls.solver_name} option(s) {unknown}{hint}; expected one of {sorted(names)}")
        return cls(**values)

    @classmethod
    def _other_solvers_options(cls, unknown: list) -> str:
        """What to add to the error of options ``unknown`` that another solver takes (Ipopt's
        linear_solver given to jtraj's solver was refused with the list of jtraj's options)."""
        return ""

    def replace(self, **changes: Any) -> AbstractOptions:
        return dataclasses.replace(self, **changes)

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def _positive(options: AbstractOptions, *names: str, allow_none: bool = False) -> None:
    for name in names:
        value = getattr(options, name)
        if value is None and allow_none:
            continue
        # numpy's scalars too (np.float32, np.int64 from an array of settings): they are numbers
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)) or not value > 0:
            raise InvalidOptionError(f"{options.solver_name} option {name}={value!r}: expected a positive number")


class AbstractCallback:
    """Hooks a solver calls: ``on_start`` once, ``on_iteration`` after every iteration (return
    False to stop the solve with `Status.USER_STOP`; jtraj's own solver reports its iterations
    after its compiled loop has ended, so it cannot stop there and warns), ``on_end`` with the
    `Solution`.

    A callback whose ``wants_iterates`` is True also gets ``on_iterate(it, x)`` with the
    iterate's variables (unscaled, length ``nlp.n``) before ``on_iteration``. Ipopt provides
    them (cyipopt's ``get_current_iterate``); jtraj's own solver runs as one compiled program
    and refuses such a callback."""

    wants_iterates: bool = False

    def on_start(self, nlp: Any) -> None:
        return None

    def on_iterate(self, it: Iteration, x: np.ndarray) -> None:
        return None

    def on_iteration(self, it: Iteration) -> bool | None:
        return None

    def on_end(self, solution: Solution) -> None:
        return None


class PrintProgress(AbstractCallback):
    """One line per ``every`` iterations (iter, objective, inf_pr, inf_du, lg(mu), alpha_pr).

    ``stream=None`` writes to ``sys.stdout`` as it is when the solve runs, not when this module
    was imported (pytest and notebooks replace it)."""

    def __init__(self, stream: TextIO | None = None, every: int = 1):
        if not isinstance(every, int) or every < 1:
            raise ValueError(f"progress every={every!r}: expected an integer >= 1")
        self.stream = stream
        self.every = every

    def _out(self) -> TextIO:
        return self.stream if self.stream is not None else sys.stdout

    def on_iteration(self, it: Iteration) -> None:
        if it.iter % self.every:
            return
        out = self._out()
        if it.iter == 0:
            print(f"{'iter':>5} {'objective':>14} {'inf_pr':>10} {'inf_du':>10} {'lg(mu)':>7} {'alpha_pr':>9}", file=out)
        lgmu = np.log10(it.mu) if it.mu > 0 else -np.inf
        print(f"{it.iter:5d} {it.objective:14.6e} {it.inf_pr:10.3e} {it.inf_du:10.3e} {lgmu:7.2f} {it.alpha_pr:9.2e}", file=out, flush=True)

    def write(self, text: str) -> None:
        """A free line (headers and summaries of the caller) on the same stream."""
        print(text, file=self._out(), flush=True)


class CallbackList(AbstractCallback):
    """Several callbacks; the solve stops when any of them asks to."""

    def __init__(self, callbacks: list[AbstractCallback]):
        self.callbacks = list(callbacks)
        self.wants_iterates = any(c.wants_iterates for c in self.callbacks)

    def on_start(self, nlp: Any) -> None:
        for c in self.callbacks:
            c.on_start(nlp)

    def on_iterate(self, it: Iteration, x: np.ndarray) -> None:
        for c in self.callbacks:
            if c.wants_iterates:
                c.on_iterate(it, x)

    def on_iteration(self, it: Iteration) -> bool:
        return all([c.on_iteration(it) is not False for c in self.callbacks])

    def on_end(self, solution: Solution) -> None:
        for c in self.callbacks:
            c.on_end(solution)


class RecordIterates(AbstractCallback):
    """Keeps every iterate of an Ipopt solve: ``iterates`` (one array of the NLP's variables per
    iteration, the starting point first) and ``iterations`` (their `Iteration` records)."""

    wants_iterates = True

    def __init__(self) -> None:
        self.iterates: list[np.ndarray] = []
        self.iterations: list[Iteration] = []

    def on_start(self, nlp: Any) -> None:
        self.iterates, self.iterations = [], []

    def on_iterate(self, it: Iteration, x: np.ndarray) -> None:
        self.iterates.append(np.array(x, float))
        self.iterations.append(it)


#: What a ``progress=`` argument accepts: True (print to the current sys.stdout), False or None
#: (quiet), a text stream, or a callback object.
Progress = bool | TextIO | AbstractCallback | None


def resolve_progress(progress: Progress, every: int = 1) -> AbstractCallback | None:
    """The callback a ``progress=`` argument stands for (None: quiet)."""
    if progress is None or progress is False:
        return None
    if progress is True:
        return PrintProgress(None, every)
    if isinstance(progress, AbstractCallback):
        return progress
    if hasattr(progress, "write"):
        return PrintProgress(progress, every)
    raise TypeError(f"progress={progress!r}: expected True, False/None, a text stream or an AbstractCallback")


def max_violation(g: np.ndarray, g_lower: np.ndarray, g_upper: np.ndarray, x: np.ndarray, x_lower: np.ndarray, x_upper: np.ndarray) -> float:
    """Max violation of ``g_lower <= g <= g_upper`` and ``x_lower <= x <= x_upper``."""
    viol = np.maximum(np.maximum(g_lower - g, g - g_upper), 0.0)
    bviol = np.maximum(np.maximum(x_lower - x, x - x_upper), 0.0)
    # np.max, not Python's max: max(0.0, nan) is 0.0, which reported a NaN x within its bounds
    return float(np.max([viol.max(initial=0.0), bviol.max(initial=0.0)]))


class EvaluationTimer:
    """Counts and times the calls of the NLP's functions (host conversion included)."""

    def __init__(self) -> None:
        self.counts = dict(obj=0, grad=0, con=0, jac=0, hess=0)
        self.seconds = 0.0

    def call(self, key: str, fn: Callable[..., Any], *args: Any) -> np.ndarray:
        t = time.perf_counter()
        out = np.asarray(fn(*args))
        self.seconds += time.perf_counter() - t
        self.counts[key] += 1
        return out

    def stats(self, iterations: int, time_total: float) -> Stats:
        c = self.counts
        return Stats(iterations, c["obj"], c["grad"], c["con"], c["jac"], c["hess"], time_total, self.seconds)


class AbstractSolver(abc.ABC):
    """A solver backend. Subclasses set ``name`` (the registry key) and ``Options`` (their
    `AbstractOptions` subclass, whose defaults are used when ``options`` is None)."""

    name: ClassVar[str]
    Options: ClassVar[type[AbstractOptions]]
    #: whether the callback's ``on_iterate`` gets the iterates (a callback that wants them,
    #: `RecordIterates`, is refused otherwise)
    reports_iterates: ClassVar[bool] = True

    def options(self, options: AbstractOptions | dict[str, Any] | None = None, **overrides: Any) -> AbstractOptions:
        """The options object from None (defaults), a mapping or an options object, with
        ``overrides`` applied; wrong types and names raise `InvalidOptionError`."""
        if options is None:
            opts = self.Options()
        elif isinstance(options, AbstractOptions):
            if not isinstance(options, self.Options):
                raise InvalidOptionError(f"solver {self.name!r} takes {self.Options.__name__}, got {type(options).__name__}")
            opts = options
        elif isinstance(options, dict):
            opts = self.Options.from_dict(options)
        else:
            raise InvalidOptionError(f"options={options!r}: expected None, a dict or {self.Options.__name__}")
        return opts.replace(**overrides) if overrides else opts

    @abc.abstractmethod
    def solve(
        self,
        nlp: Any,
        x0: np.ndarray,
        theta: Any = None,
        options: AbstractOptions | dict[str, Any] | None = None,
        callback: AbstractCallback | None = None,
    ) -> Solution:
        """Solve ``nlp`` with parameters ``theta`` (None: ``nlp.theta``) from the primal guess
        ``x0`` (n,) or (n_knots, nz) (clipped into the variable bounds; another shape, or a NaN
        or infinite entry, is a ValueError, `initial_guess`). A NaN bound is a ValueError; a
        lower bound above its upper one returns `Status.INVALID_PROBLEM` naming it, before
        anything compiles."""


@dataclasses.dataclass(frozen=True)
class BoundNLP:
    """An NLP's functions of the primal vector alone, with its parameters ``theta`` fixed, and
    its bounds at that ``theta``: what a backend iterates on."""

    objective: Callable[[Any], Any]
    gradient: Callable[[Any], Any]
    constraints: Callable[[Any], Any]
    jacobian: Callable[[Any], Any]
    hessian: Callable[[Any, Any, float], Any]
    x_lower: np.ndarray
    x_upper: np.ndarray
    g_lower: np.ndarray
    g_upper: np.ndarray
    #: ``locate("x" | "g", i)``: where variable or row i sits in the NLP (`KnotNLP.locate`:
    #: knot and slot, or group, knot and row), named beside a refused bound; None: indices only
    locate: Callable[[str, int], str] | None = None

    def where(self, kind: str, i: int) -> str:
        """`` (at ...)``, the place of entry ``i`` of ``kind`` ("x" or "g") by ``locate``, or
        nothing without one."""
        return f" (at {self.locate(kind, i)})" if self.locate is not None else ""

    def inconsistent(self) -> str | None:
        """What is wrong when a lower bound exceeds its upper one, or is +inf (or an upper one
        -inf), the first such bound (variables before constraint rows, with its place where
        the NLP tells it), else None: Ipopt's INVALID_PROBLEM."""
        for name, lower, upper in (("x", self.x_lower, self.x_upper), ("g", self.g_lower, self.g_upper)):
            # a lower bound of +inf (or an upper one of -inf) is met by nothing: jtraj's solver
            # reported such a row solved, Ipopt a numerical error
            bad = np.flatnonzero((lower > upper) | (lower == np.inf) | (upper == -np.inf))
            if bad.size:
                i = int(bad[0])
                relation = ">" if lower[i] > upper[i] else "and"
                return (
                    f"inconsistent bounds: {name}_lower[{i}]={float(lower[i])!r} {relation} {name}_upper[{i}]={float(upper[i])!r}"
                    f"{self.where(name, i)} ({bad.size} such {name} bound(s))"
                )
        return None


def _checked(f: BoundNLP) -> BoundNLP:
    """``f``, unless a bound is NaN (a solver would silently drop that bound): ValueError
    naming the first one."""
    for name in ("x_lower", "x_upper", "g_lower", "g_upper"):
        bad = np.flatnonzero(np.isnan(getattr(f, name)))
        if bad.size:
            i = int(bad[0])
            raise ValueError(f"the NLP's bound {name}[{i}]{f.where(name[0], i)} is NaN ({bad.size} NaN entries of {name}); check theta and the bounds' functions")
    return f


def guess_shapes(nlp: Any) -> list[tuple[int, ...]]:
    """The shapes an initial guess of ``nlp`` may take: (n,) and, for a knot NLP, (n_knots, nz)."""
    n = int(nlp.n)
    shapes: list[tuple[int, ...]] = [(n,)]
    knots, nz = getattr(nlp, "n_knots", None), getattr(nlp, "nz", None)
    if isinstance(knots, int) and isinstance(nz, int) and knots * nz == n:
        shapes.append((knots, nz))
    return shapes


def initial_guess(nlp: Any, x0: Any, name: str = "x0") -> np.ndarray:
    """``x0`` as the (n,) vector of ``nlp``'s variables, from one of `guess_shapes`, before
    anything compiles: something that is not an array of numbers (a `jtraj.result.Result`, a
    trajectory) raises TypeError, any other shape (a scalar or one value would be broadcast by
    the clip into the bounds) and a NaN or infinite entry (the solve compiled, then ended in a
    numerical error with a NaN cost) raise ValueError, each naming ``name`` (and the first bad
    entry, with its knot and slot where the NLP tells them: ``nlp.locate``)."""
    shapes = guess_shapes(nlp)
    expected = f"{' or '.join(str(s) for s in shapes)} (the NLP's {nlp.n} variables)"
    import jax

    if isinstance(x0, jax.core.Tracer):  # JAX's own error says it: the solvers run on the host
        np.asarray(x0, float)
    try:
        x = np.asarray(x0, float)
    except (TypeError, ValueError):  # float() of a Result, a ragged list, a word
        raise TypeError(
            f"{name} of type {type(x0).__name__}: expected an array of numbers of shape {expected}; "
            "a Result or its trajectory holds no such array (jtraj.transcription.Transcription.warm_start gives a task's own start)"
        ) from None
    if x.shape not in shapes:
        raise ValueError(f"{name} of shape {x.shape}: expected {expected}")
    bad = np.flatnonzero(~np.isfinite(x.reshape(-1)))
    if bad.size:
        i = int(bad[0])
        index = ", ".join(str(int(k)) for k in np.unravel_index(i, x.shape))
        if callable(getattr(nlp, "locate", None)):
            where = f" (at {nlp.locate('x', i)})"
        elif x.ndim == 2:
            where = f" (at knot {i // x.shape[1]}, column {i % x.shape[1]})"
        else:
            where = ""
        raise ValueError(
            f"{name}[{index}]{where} is {float(x.reshape(-1)[i])!r} ({bad.size} NaN or infinite entries of {name}): "
            "an initial guess must be finite (a solve from it ends in a numerical error)"
        )
    return x.reshape(-1)


def invalid_problem(f: BoundNLP, x0: np.ndarray, message: str, m: int, nlp: Any = None, callback: AbstractCallback | None = None) -> Solution:
    """The `Solution` of a problem refused before its solve (`Status.INVALID_PROBLEM`, as
    Ipopt returns it): ``x0`` (n,) as it was given, nothing evaluated. A ``callback`` gets its
    start (with ``nlp``) and this end, as after a solve."""
    n = len(x0)
    solution = Solution(
        x=np.asarray(x0, float),
        status=Status.INVALID_PROBLEM,
        message=message,
        objective=float("nan"),
        constraint_violation=float("nan"),
        mult_g=np.zeros(m),
        mult_x_lower=np.zeros(n),
        mult_x_upper=np.zeros(n),
        stats=Stats(),
    )
    if callback is not None:
        callback.on_start(nlp)
        callback.on_end(solution)
    return solution


def _check_theta_shapes(nlp: Any, theta: Any) -> None:
    """ValueError naming the first parameter of ``theta`` whose shape differs from that of the
    NLP's own ``nlp.theta`` (same structure); a batch of parameters, one per member of a
    `solve_batch`, failed inside the NLP's bound functions with JAX's broadcasting error.
    TypeError where the structure differs (another type, other fields), naming the type
    expected. An NLP without ``theta`` is not checked."""
    import jax

    own = getattr(nlp, "theta", None)
    if own is None or theta is own:
        return
    given = jax.tree_util.tree_flatten_with_path(theta)[0]
    ref = jax.tree_util.tree_flatten_with_path(own)[0]
    # the leaves' paths, not the tree types: a list for the NLP's tuple is the same theta
    if [path for path, _ in given] != [path for path, _ in ref]:
        # (a dict of overrides, as jtraj.solve takes, failed inside the bound functions with
        # AttributeError)
        transcription = sys.modules.get("jtraj.transcription")
        hint = (
            "; a mapping of overrides ({'friction': 0.5}) becomes one by jtraj.transcription.Transcription.resolve_theta"
            if transcription is not None and isinstance(own, transcription.TaskParams)
            else ""
        )
        raise TypeError(
            f"theta of type {type(theta).__name__} does not have the structure of the NLP's own theta: expected a {type(own).__name__} "
            f"with the same fields (nlp.theta, or None for it){hint}"
        )
    for (path, a), (_, b) in zip(given, ref):
        if np.shape(a) != np.shape(b):
            raise ValueError(
                f"theta{jax.tree_util.keystr(path)} has shape {np.shape(a)}, the NLP's own theta {np.shape(b)}: a solve is at one theta "
                "(solve_batch's members share it); solve each theta by its own call"
            )


def bind(nlp: Any, theta: Any = None) -> BoundNLP:
    """Fix ``theta`` in ``nlp``'s functions. An NLP with parameters has ``bounds(theta)`` and
    functions of ``(x, theta)``; one without takes x alone (``theta`` must then be None).
    ``theta=None`` means the NLP's own default parameters ``nlp.theta`` where it has them; a
    parameter of another shape than in ``nlp.theta`` (a batch of them) raises ValueError, a
    theta of another structure (a dict where ``nlp.theta`` is a `TaskParams`) TypeError.
    A NaN bound raises ValueError (bounds where lower > upper are `BoundNLP.inconsistent`)."""
    if callable(getattr(nlp, "bounds", None)):
        if theta is None:
            theta = getattr(nlp, "theta", None)
        _check_theta_shapes(nlp, theta)
        x_lower, x_upper, g_lower, g_upper = (np.asarray(b, float) for b in nlp.bounds(theta))
        return _checked(BoundNLP(
            objective=lambda x: nlp.objective(x, theta),
            gradient=lambda x: nlp.gradient(x, theta),
            constraints=lambda x: nlp.constraints(x, theta),
            jacobian=lambda x: nlp.jacobian(x, theta),
            hessian=lambda x, lam, obj_factor: nlp.hessian(x, lam, obj_factor, theta),
            x_lower=x_lower,
            x_upper=x_upper,
            g_lower=g_lower,
            g_upper=g_upper,
            locate=nlp.locate if callable(getattr(nlp, "locate", None)) else None,
        ))
    if theta is not None:
        raise TypeError(f"{type(nlp).__name__} takes no parameters theta; pass theta=None")
    return _checked(BoundNLP(
        objective=lambda x: nlp.objective(x),
        gradient=lambda x: nlp.gradient(x),
        constraints=lambda x: nlp.constraints(x),
        jacobian=lambda x: nlp.jacobian(x),
        hessian=lambda x, lam, obj_factor: nlp.hessian(x, lam, obj_factor),
        x_lower=np.asarray(nlp.x_lower, float),
        x_upper=np.asarray(nlp.x_upper, float),
        g_lower=np.asarray(nlp.g_lower, float),
        g_upper=np.asarray(nlp.g_upper, float),
        locate=nlp.locate if callable(getattr(nlp, "locate", None)) else None,
    ))
