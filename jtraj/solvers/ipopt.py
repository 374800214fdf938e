"""Ipopt (through cyipopt) as a jtraj solver backend: the only module that imports cyipopt.

`IpoptSolver.solve` hands a knot NLP to Ipopt, counts and times the evaluations of its (JAX)
functions apart from Ipopt's own work, reports every iteration to the callback, and maps
Ipopt's return code to `jtraj.solvers.Status`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import threading
import time
import weakref
from typing import Any, ClassVar

import jax.numpy as jnp
import numpy as np

from jtraj.solvers.base import (
    AbstractCallback,
    AbstractOptions,
    AbstractSolver,
    BoundNLP,
    EvaluationTimer,
    InvalidOptionError,
    Iteration,
    Solution,
    Status,
    _positive,
    bind,
    initial_guess,
    invalid_problem,
    max_violation,
)

__all__ = ["IpoptOptions", "IpoptSolver", "IPOPT_STATUS"]

#: Ipopt's ApplicationReturnStatus codes (IpReturnCodes_inc.h) and what they mean here.
IPOPT_STATUS: dict[int, Status] = {
    0: Status.SOLVED,
    1: Status.ACCEPTABLE,
    2: Status.INFEASIBLE,
    3: Status.SEARCH_DIRECTION_TOO_SMALL,
    4: Status.DIVERGING,
    5: Status.USER_STOP,
    6: Status.FEASIBLE_POINT,
    -1: Status.MAX_ITER,
    -2: Status.RESTORATION_FAILED,
    -3: Status.STEP_COMPUTATION_FAILED,
    -4: Status.MAX_CPU_TIME,
    -5: Status.MAX_WALL_TIME,
    -10: Status.INVALID_PROBLEM,
    -11: Status.INVALID_PROBLEM,
    -12: Status.INVALID_OPTION,
    -13: Status.NUMERICAL_ERROR,
    -100: Status.INTERNAL_ERROR,
    -101: Status.INTERNAL_ERROR,
    -102: Status.OUT_OF_MEMORY,
    -199: Status.INTERNAL_ERROR,
}

#: Linear solvers Ipopt can be built with (MUMPS is the one in the wheel).
LINEAR_SOLVERS = ("mumps", "ma27", "ma57", "ma77", "ma86", "ma97", "pardiso", "pardisomkl", "spral", "wsmp")
#: the largest value of Ipopt's integer options (a C int)
INT_MAX = 2**31 - 1
#: (Ipopt's "user-scaling" takes scaling factors from the problem, and jtraj gives none: it
#: was accepted and solved as "none")
SCALING_METHODS = ("none", "gradient-based", "equilibration-based")
HESSIANS = {"lbfgs": "limited-memory", "exact": "exact"}


@dataclasses.dataclass(frozen=True, kw_only=True)
class IpoptOptions(AbstractOptions):
    """Ipopt settings. Defaults are those of the comparative study's public code (tolerance
    1e-3, 200 iterations, L-BFGS Hessian, no NLP scaling, MUMPS).

    Attributes:
        tol: Ipopt's ``tol`` on the scaled KKT error.
        max_iter: iteration limit.
        max_wall_time: wall-clock limit (s).
        hessian: ``"lbfgs"`` (limited-memory quasi-Newton) or ``"exact"`` (the NLP's exact
            Hessian of the Lagrangian, built on first use).
        linear_solver: Ipopt's ``linear_solver`` (one of `LINEAR_SOLVERS`).
        nlp_scaling_method: Ipopt's ``nlp_scaling_method``.
        acceptable_tol, constr_viol_tol, acceptable_constr_viol_tol: Ipopt's options of those
            names; None leaves Ipopt's default.
        extra: any other Ipopt option by its Ipopt name (booleans become "yes"/"no"), checked
            when the options are built against the bundled Ipopt's own option list (names,
            types, ranges; `jtraj.solvers.ipopt_catalog`).
    """

    solver_name: ClassVar[str] = "Ipopt"

    tol: float = 1e-3
    max_iter: int = 200
    max_wall_time: float = 600.0
    hessian: str = "lbfgs"
    linear_solver: str = "mumps"
    nlp_scaling_method: str = "none"
    acceptable_tol: float | None = None
    constr_viol_tol: float | None = None
    acceptable_constr_viol_tol: float | None = None
    extra: dict[str, Any] = dataclasses.field(default_factory=dict)

    def __check__(self) -> None:
        for name in ("tol", "max_wall_time", "acceptable_tol", "constr_viol_tol", "acceptable_constr_viol_tol"):
            value = getattr(self, name)
            if isinstance(value, (int, np.integer, np.floating)) and not isinstance(value, bool):
                object.__setattr__(self, name, float(value))  # Ipopt's real options take 1 (and numpy's scalars) as well as 1.0
        _positive(self, "tol", "max_wall_time")
        _positive(self, "acceptable_tol", "constr_viol_tol", "acceptable_constr_viol_tol", allow_none=True)
        if isinstance(self.max_iter, bool) or not isinstance(self.max_iter, (int, np.integer)) or self.max_iter < 0:
            raise InvalidOptionError(f"Ipopt option max_iter={self.max_iter!r}: expected an integer >= 0")
        if self.max_iter > INT_MAX:  # Ipopt's integer options are C ints (cyipopt: OverflowError at the solve)
            raise InvalidOptionError(f"Ipopt option max_iter={self.max_iter!r}: expected an integer in [0, {INT_MAX}]")
        if not isinstance(self.hessian, str) or self.hessian not in HESSIANS:  # a list: TypeError 'unhashable type'
            raise InvalidOptionError(f"Ipopt option hessian={self.hessian!r}: expected one of {sorted(HESSIANS)}")
        if self.linear_solver not in LINEAR_SOLVERS:
            raise InvalidOptionError(f"Ipopt option linear_solver={self.linear_solver!r}: expected one of {list(LINEAR_SOLVERS)}")
        if self.linear_solver != "mumps":
            # loaded at run time from a library that may be absent: Ipopt would stop the solve
            # with "Invalid option encountered", without naming it
            from jtraj.solvers import ipopt_catalog

            if not ipopt_catalog.linear_solver_available(self.linear_solver):
                raise InvalidOptionError(f"Ipopt option linear_solver={self.linear_solver!r}: not available in this Ipopt build (its library is not installed); expected 'mumps'")
        if self.nlp_scaling_method not in SCALING_METHODS:
            raise InvalidOptionError(f"Ipopt option nlp_scaling_method={self.nlp_scaling_method!r}: expected one of {list(SCALING_METHODS)}")
        if self.nlp_scaling_method == "equilibration-based":
            from jtraj.solvers import ipopt_catalog

            if not ipopt_catalog.value_usable("nlp_scaling_method", self.nlp_scaling_method):  # it needs HSL's MC19
                raise InvalidOptionError(f"Ipopt option nlp_scaling_method={self.nlp_scaling_method!r}: not available in this Ipopt build (it needs HSL's MC19, which is not installed); expected 'gradient-based' or 'none'")
        if not isinstance(self.extra, dict):
            raise InvalidOptionError(f"Ipopt option extra={self.extra!r}: expected a dict of Ipopt option names to values")
        for key, value in self.extra.items():
            if not isinstance(key, str) or not isinstance(value, (str, int, float, bool, np.integer, np.floating, np.bool_)):
                raise InvalidOptionError(f"Ipopt option {key!r}={value!r}: expected a string, integer, float or boolean value")
            if key in _FIELDS or key == "hessian_approximation":
                raise _own_field_error(key)
        if self.extra:
            # against the bundled Ipopt's option list, here rather than when a solve starts (after
            # the compile), with Ipopt's value types (an integer for a real option becomes a float)
            from jtraj.solvers import ipopt_catalog

            checked = {}
            for key, value in self.extra.items():
                try:
                    checked[key] = ipopt_catalog.check(key, value)
                except ipopt_catalog.IpoptOptionError as e:
                    raise InvalidOptionError(f"Ipopt option {key}={value!r}: {e.expected}") from None
            object.__setattr__(self, "extra", checked)

    @classmethod
    def from_dict(cls, values: dict[str, Any] | None) -> IpoptOptions:
        """From Ipopt's own option names: the fields above by name (and Ipopt's
        ``hessian_approximation`` = "exact" / "limited-memory"), everything else into ``extra``.
        The string values of Ipopt's options ``linear_solver``, ``nlp_scaling_method`` and
        ``hessian_approximation`` are taken in any case, as Ipopt takes them (``NONE`` passed
        the command line's check and failed here). ``hessian`` and ``hessian_approximation``
        that ask for different Hessians raise `InvalidOptionError` (one was dropped)."""
        values = dict(values or {})
        for key in _IPOPT_STRINGS:
            if isinstance(values.get(key), str):
                values[key] = values[key].lower()
        hessian_approximation = values.pop("hessian_approximation", None)
        fields: dict[str, Any] = {}
        extra = _extra_beside(values)
        for key, value in values.items():
            if key in _FIELDS:
                fields[key] = value
            else:
                extra[key] = value
        if hessian_approximation is not None:
            names = {v: k for k, v in HESSIANS.items()}
            if not isinstance(hessian_approximation, str) or hessian_approximation not in names:
                raise InvalidOptionError(f"Ipopt option hessian_approximation={hessian_approximation!r}: expected one of {sorted(names)}")
            if "hessian" in fields and fields["hessian"] != names[hessian_approximation]:
                raise InvalidOptionError(
                    f"Ipopt option hessian_approximation={hessian_approximation!r}: conflicts with hessian={fields['hessian']!r}; "
                    f"expected hessian={names[hessian_approximation]!r} or only one of the two"
                )
            fields["hessian"] = names[hessian_approximation]
        return cls(**fields, extra=extra)

    def merge(self, values: dict[str, Any] | None) -> IpoptOptions:
        """These options with ``values`` (named as for `from_dict`) over them (Ipopt's
        ``hessian_approximation`` among them replaces the ``hessian`` of these)."""
        if not values:
            return self
        own = {k: v for k, v in self.as_dict().items() if k != "extra"}
        values = dict(values)
        # ``values``' own extra options are options of ``values``: they replace these options'
        # (they went to the top level beside these, and these won); a field among them is
        # refused, as `from_dict` refuses it
        extra = _extra_beside(values)
        for key in extra:
            if key in _FIELDS or key == "hessian_approximation":
                raise _own_field_error(key)
        given = extra | values
        if "hessian_approximation" in given:
            del own["hessian"]
        return IpoptOptions.from_dict({**own, **self.extra, **given})

    def to_ipopt(self) -> dict[str, Any]:
        """The options as Ipopt's names and values (quiet: no banner, no own printing)."""
        out: dict[str, Any] = {
            "tol": self.tol,
            "max_iter": int(self.max_iter),
            "hessian_approximation": HESSIANS[self.hessian],
            "nlp_scaling_method": self.nlp_scaling_method,
            "linear_solver": self.linear_solver,
            "max_wall_time": self.max_wall_time,
            "print_level": 0,
            "sb": "yes",
        }
        for name in ("acceptable_tol", "constr_viol_tol", "acceptable_constr_viol_tol"):
            if getattr(self, name) is not None:
                out[name] = getattr(self, name)
        for key, value in self.extra.items():
            out[key] = ("yes" if value else "no") if isinstance(value, bool) else value
        return out


_FIELDS = {f.name for f in dataclasses.fields(IpoptOptions)} - {"extra"}
#: Ipopt's string options among `from_dict`'s names, whose values Ipopt takes in any case
_IPOPT_STRINGS = ("linear_solver", "nlp_scaling_method", "hessian_approximation")


def _own_field_error(key: str) -> InvalidOptionError:
    """The error for an Ipopt option given among the extra ones that has its own field."""
    return InvalidOptionError(f"Ipopt option {key!r} has its own field: use IpoptOptions({_field_for(key)}=...)")


def _field_for(key: str) -> str:
    return "hessian" if key == "hessian_approximation" else key


#: the NLPs whose exact Hessian has been built and compiled in this process
_HESSIAN_COMPILED: weakref.WeakSet = weakref.WeakSet()
#: guards the test of `_HESSIAN_COMPILED` and the build it calls for
_HESSIAN_LOCK = threading.Lock()



def _extra_beside(values: dict[str, Any]) -> dict[str, Any]:
    """Pop ``values``' ``extra`` dict and return a copy of it; an option named both there and at
    the top level with another value raises `InvalidOptionError` (the top level's won without
    a word)."""
    extra = values.pop("extra", None) or {}
    if not isinstance(extra, dict):
        raise InvalidOptionError(f"Ipopt option extra={extra!r}: expected a dict of Ipopt option names to values")
    for key in sorted(set(extra) & set(values), key=str):
        if values[key] != extra[key]:
            raise InvalidOptionError(f"Ipopt option {key}: given as {values[key]!r} and in extra as {extra[key]!r}; expected one value")
    return dict(extra)


def forget_hessians() -> None:
    """Forget which NLPs' exact Hessians were compiled (`jtraj.solver.release_compiled` drops
    JAX's compiled programs: a later exact-Hessian solve compiles it again before its clock
    starts, not inside the timed solve)."""
    with _HESSIAN_LOCK:
        _HESSIAN_COMPILED.clear()


class _Problem:
    """The object cyipopt calls back: the bound NLP's functions on numpy vectors, timed."""

    def __init__(self, nlp: Any, f: BoundNLP, exact_hessian: bool, callback: AbstractCallback | None):
        self.f = f
        self.nlp = nlp
        self.timer = EvaluationTimer()
        self.callback = callback
        self.history: list[Iteration] = []
        self.problem: Any = None  # the cyipopt.Problem, for its current iterate
        self.failure: BaseException | None = None  # an exception of a callback, see _evaluate and _hessian
        if exact_hessian:
            self.hessianstructure = lambda: (nlp.hess_rows, nlp.hess_cols)
            self.hessian = self._hessian

    def _evaluate(self, key: str, fn, size: int, x):
        """``fn(x)``, timed; an exception is kept in ``failure`` (and raised to cyipopt, which
        keeps it too), and every later call returns NaN at once without evaluating. A Ctrl-C
        or the command line's SIGTERM raises only once: Ipopt's derivative checker took the
        failed evaluation in its stride and went on perturbing every variable, each a full
        evaluation (minutes on big_jump), so the command did not stop. `intermediate` stops
        Ipopt at its next iteration and `solve` raises the exception."""
        if self.failure is not None:
            return np.full(size, np.nan)
        try:
            return self.timer.call(key, fn, jnp.asarray(x))
        except BaseException as e:
            self.failure = e
            raise

    def objective(self, x):
        return float(self._evaluate("obj", self.f.objective, 1, x).reshape(-1)[0])

    def gradient(self, x):
        return self._evaluate("grad", self.f.gradient, self.nlp.n, x)

    def constraints(self, x):
        return self._evaluate("con", self.f.constraints, self.nlp.m, x)

    def jacobian(self, x):
        return self._evaluate("jac", self.f.jacobian, len(self.nlp.jac_rows), x)

    def jacobianstructure(self):
        return self.nlp.jac_rows, self.nlp.jac_cols

    def _hessian(self, x, lagrange, obj_factor):
        # cyipopt (1.7.0.dev0) loses an exception of this callback, which its other callbacks
        # keep and raise after the solve: its hessian_cb cannot store it and reports success.
        # A Ctrl-C (or the command line's SIGTERM) during an exact-Hessian solve was then
        # ignored, and the iteration went on with the values Ipopt's array happened to hold
        # (the solve "solved" in 52 or 75 iterations where it takes 35). Kept here instead:
        # the iteration ends with a zero Hessian, `intermediate` stops Ipopt, and `solve`
        # raises it.
        if self.failure is not None:
            return np.zeros(len(self.nlp.hess_rows))
        try:
            return self.timer.call("hess", self.f.hessian, jnp.asarray(x), jnp.asarray(lagrange), float(obj_factor))
        except BaseException as e:
            self.failure = self.failure or e
            return np.zeros(len(self.nlp.hess_rows))

    def intermediate(self, alg_mod, iter_count, obj_value, inf_pr, inf_du, mu, d_norm, regularization_size, alpha_du, alpha_pr, ls_trials):
        if self.failure is not None:  # (`_hessian`): stop here, raised after the solve
            return False
        it = Iteration(int(iter_count), float(obj_value), float(inf_pr), float(inf_du), float(mu), float(alpha_pr))
        self.history.append(it)
        if self.callback is None:
            return True
        if self.callback.wants_iterates:
            self.callback.on_iterate(it, np.asarray(self.problem.get_current_iterate(scaled=False)["x"]))
        return self.callback.on_iteration(it) is not False


class IpoptSolver(AbstractSolver):
    """Ipopt, an interior-point method with a filter line search (sparse, MUMPS by default)."""

    name: ClassVar[str] = "ipopt"
    Options: ClassVar[type[AbstractOptions]] = IpoptOptions

    def solve(
        self,
        nlp: Any,
        x0: np.ndarray,
        theta: Any = None,
        options: AbstractOptions | dict[str, Any] | None = None,
        callback: AbstractCallback | None = None,
    ) -> Solution:
        import cyipopt

        opts = self.options(options)
        assert isinstance(opts, IpoptOptions)
        x0 = initial_guess(nlp, x0)
        f = bind(nlp, theta)
        problem_text = f.inconsistent()
        if problem_text is not None:  # Ipopt's INVALID_PROBLEM, with the bound named
            return invalid_problem(f, x0, problem_text, nlp.m, nlp, callback)
        exact = opts.hessian == "exact"
        x0 = np.clip(x0, f.x_lower, f.x_upper)
        time_compile = 0.0
        with _HESSIAN_LOCK:  # (two threads' solves of one NLP both built it and reported it)
            if exact and nlp not in _HESSIAN_COMPILED:  # (an object without weak references never is)
                # built and called once before the clock starts, as the other callbacks are
                # compiled before a solve (its first call compiles its jitted scatter: it ran
                # inside the timed solve); reported as the backend's compile time
                t0 = time.perf_counter()
                nlp.build_hessian()
                np.asarray(f.hessian(jnp.asarray(x0), jnp.zeros(nlp.m), 1.0))
                time_compile = time.perf_counter() - t0
                with contextlib.suppress(TypeError):  # an NLP of its own kind without weak references: built again each solve
                    _HESSIAN_COMPILED.add(nlp)
        problem_obj = _Problem(nlp, f, exact, callback)
        problem = cyipopt.Problem(n=nlp.n, m=nlp.m, problem_obj=problem_obj, lb=f.x_lower, ub=f.x_upper, cl=f.g_lower, cu=f.g_upper)
        problem_obj.problem = problem
        for key, value in opts.to_ipopt().items():
            try:
                problem.add_option(key, value)
            except TypeError as e:  # cyipopt raises TypeError for unknown options and bad values
                raise InvalidOptionError(f"Ipopt rejected option {key}={value!r}: {e}") from None
        if callback is not None:
            callback.on_start(nlp)
        t0 = time.perf_counter()
        x, info = problem.solve(x0)
        total = time.perf_counter() - t0
        if problem_obj.failure is not None:
            raise problem_obj.failure
        g = np.asarray(f.constraints(jnp.asarray(x)))
        message = info["status_msg"]
        message = message.decode() if isinstance(message, bytes) else str(message)
        status = IPOPT_STATUS.get(int(info["status"]), Status.INTERNAL_ERROR)
        if message == "Unknown status":  # cyipopt has no text for some codes (-5: max_wall_time)
            message = status.message
        history = tuple(problem_obj.history)
        solution = Solution(
            x=np.asarray(x),
            status=status,
            message=message,
            # Ipopt's obj_val is 0.0 when it stopped before evaluating its start (a NaN in x0)
            objective=float(info["obj_val"]) if history else float(f.objective(jnp.asarray(x))),
            constraint_violation=max_violation(g, f.g_lower, f.g_upper, x, f.x_lower, f.x_upper),
            mult_g=np.asarray(info["mult_g"]),
            mult_x_lower=np.asarray(info["mult_x_L"]),
            mult_x_upper=np.asarray(info["mult_x_U"]),
            stats=problem_obj.timer.stats(history[-1].iter if history else 0, total),
            history=history,
            time_compile=time_compile,
        )
        if callback is not None:
            callback.on_end(solution)
        return solution
