"""Ipopt's own option list, read from the bundled Ipopt, to check options before any solve.

Ipopt knows its options (name, type, bounds, allowed strings) but reports a bad one only when
a solve starts, and cyipopt then raises a bare ``TypeError``; an integer given for a real
option (``tol=1``) is refused too, because cyipopt picks Ipopt's setter from the Python type.
Here the catalog comes from Ipopt's ``print_options_documentation`` (printed once per process
by a one-variable problem, captured from file descriptor 1), and `check` turns a user's
``NAME=VALUE`` into the value Ipopt expects, or raises `IpoptOptionError` with one line.

The printed documentation does not say whether a numeric option is an integer or a real
(``max_iter`` and ``s_max`` both print ``100``-like defaults); `check` asks Ipopt by setting
the option to its documented default as a float on a throwaway problem.

Linear solvers other than MUMPS are loaded by Ipopt at run time from libraries that may be
absent; `linear_solver_available` solves the one-variable problem with one to find out.
"""

from __future__ import annotations

import contextlib
import dataclasses
import difflib
import functools
import math
import os
import re
import sys
import tempfile
import threading
from typing import Any

import numpy as np

__all__ = ["IpoptOptionError", "OptionSpec", "catalog", "check", "check_all", "linear_solver_available"]


class IpoptOptionError(ValueError):
    """An Ipopt option that Ipopt does not know or whose value it would refuse.

    ``str(error)`` is ``"--ipopt NAME: VALUE: EXPECTED"``."""

    def __init__(self, name: str, value: Any, expected: str):
        self.name, self.field, self.value, self.expected = name, f"--ipopt {name}", value, expected
        super().__init__(f"{self.field}: {value!r}: {expected}")

    def __reduce__(self):
        # as it was made (Exception's pickling passes the message alone, which this
        # constructor does not take): a sweep's worker process sends it back
        return (type(self), (self.name, self.value, self.expected))


@dataclasses.dataclass(frozen=True)
class OptionSpec:
    """One Ipopt option: ``kind`` is "number" (integer or real, see `check`) or "string"."""

    name: str
    kind: str
    default: str
    lower: float = -math.inf
    upper: float = math.inf
    lower_strict: bool = False
    upper_strict: bool = False
    values: tuple[str, ...] | None = None  # allowed strings; None: any string


class _Tiny:
    """min x^2 on [-1, 1]: the smallest problem Ipopt accepts."""

    def objective(self, x):
        return float(x[0] ** 2)

    def gradient(self, x):
        return 2.0 * x

    def constraints(self, x):
        return np.zeros(0)

    def jacobian(self, x):
        return np.zeros(0)


def _problem():
    import cyipopt

    return cyipopt.Problem(n=1, m=0, problem_obj=_Tiny(), lb=[-1.0], ub=[1.0], cl=[], cu=[])


#: one capture of file descriptor 1 at a time: two threads' captures interleaved (building
#: options in threads, the first use of `catalog`) saved and restored each other's redirection
#: and could leave the process's stdout in a closed temporary file
_CAPTURE_LOCK = threading.Lock()


@contextlib.contextmanager
def _captured_stdout():
    """Capture what C code writes on file descriptor 1 (Ipopt prints there, not via Python);
    one thread at a time (`_CAPTURE_LOCK`)."""
    with _CAPTURE_LOCK, tempfile.TemporaryFile(mode="w+") as tmp:
        sys.stdout.flush()
        saved = os.dup(1)
        os.dup2(tmp.fileno(), 1)
        out: list[str] = []
        try:
            yield out
        finally:
            sys.stdout.flush()
            os.dup2(saved, 1)
            os.close(saved)
            tmp.seek(0)
            out.append(tmp.read())


_NUMBER = re.compile(r"^(\w+)\s+(\S+)\s+(<=|<)\s+\(\s*(\S+)\)\s+(<=|<)\s+(\S+)\s*$")
_STRING = re.compile(r'^(\w+)\s+\("(.*)"\)\s*$')
_VALUE = re.compile(r"^\s+- (\S+)")


def _parse(text: str) -> dict[str, OptionSpec]:
    specs: dict[str, OptionSpec] = {}
    current: str | None = None
    for line in text.splitlines():
        if m := _NUMBER.match(line):
            lo, hi = (float(v) for v in (m.group(2), m.group(6)))
            specs[m.group(1)] = OptionSpec(m.group(1), "number", m.group(4), lo, hi, m.group(3) == "<", m.group(5) == "<")
            current = None
        elif m := _STRING.match(line):
            specs[m.group(1)] = OptionSpec(m.group(1), "string", m.group(2), values=())
            current = m.group(1)
        elif current and (m := _VALUE.match(line)):
            spec = specs[current]
            values = None if m.group(1) == "*" or spec.values is None else spec.values + (m.group(1),)
            specs[current] = dataclasses.replace(spec, values=values)
    # an undocumented but standard option: "sb=yes" suppresses Ipopt's banner
    specs.setdefault("sb", OptionSpec("sb", "string", "no", values=("yes", "no")))
    return specs


@functools.lru_cache(maxsize=1)
def catalog() -> dict[str, OptionSpec]:
    """Every option of the bundled Ipopt, advanced ones included, by name."""
    p = _problem()
    for key, value in (("print_options_documentation", "yes"), ("print_advanced_options", "yes"), ("max_iter", 0), ("sb", "yes")):
        p.add_option(key, value)
    with _captured_stdout() as out:
        p.solve(np.array([0.5]))
    specs = _parse(out[0])
    if len(specs) < 100:  # a different print format: better to fail loudly than check nothing
        raise RuntimeError(f"could not read Ipopt's option list ({len(specs)} options parsed)")
    return specs


@functools.lru_cache(maxsize=None)
def _is_real(name: str) -> bool:
    spec = catalog()[name]
    with _captured_stdout():  # Ipopt prints why it refuses
        try:
            _problem().add_option(name, float(spec.default))
            return True
        except TypeError:
            return False


@functools.lru_cache(maxsize=None)
def linear_solver_available(name: str) -> bool:
    """Whether this Ipopt can solve with ``linear_solver=name`` (MUMPS is built in; the
    others are loaded at run time from libraries that may be absent)."""
    if name == "mumps":
        return True
    return _probe_status(("linear_solver", name)) in (0, 1)


def _probe_status(*options: tuple[str, Any]) -> int:
    """Ipopt's return status on the tiny problem with ``options`` (quiet, what it prints
    captured); cyipopt's TypeError for a value it refuses is raised as it is."""
    p = _problem()
    for key, value in (*options, ("print_level", 0), ("sb", "yes")):
        p.add_option(key, value)
    with _captured_stdout():
        _, info = p.solve(np.array([0.5]))
    return info["status"]


#: Ipopt's status for an option value it cannot use (Invalid_Option)
_INVALID_OPTION = -12
#: the string options some of whose values need a library Ipopt loads at run time (HSL's MC19),
#: probed by `value_usable` (a probe of every option's values set off the tiny problem's
#: missing Hessian, with a cyipopt error line, and refused values for other reasons)
_LIBRARY_OPTIONS = ("nlp_scaling_method", "linear_system_scaling")


@functools.lru_cache(maxsize=None)
def value_usable(name: str, value: str) -> bool:
    """Whether this Ipopt build can use the string option ``name=value`` (one that is in its
    list): some values need a library it loads at run time (``nlp_scaling_method=
    equilibration-based`` and ``linear_system_scaling=mc19`` need HSL's MC19), and without it a
    solve stops at its start with "Invalid option encountered.", naming none."""
    try:
        return _probe_status((name, value), ("max_iter", 1)) != _INVALID_OPTION
    except TypeError:  # cyipopt's refusal of a value Ipopt does not take
        return False


def _range(spec: OptionSpec) -> str:
    lo = ("(" if spec.lower_strict else "[") + f"{spec.lower:g}"
    hi = f"{spec.upper:g}" + (")" if spec.upper_strict else "]")
    return f"{lo}, {hi}"


#: Ipopt's free-text options that name a file: it finds a bad one only when a solve starts, and
#: then says "Invalid option encountered." (an output file it cannot open) or nothing at all
#: (an option file that does not exist is skipped after "Using option file ...")
_FILE_OPTIONS = ("output_file", "option_file_name")


def _check_file_option(name: str, path: str) -> None:
    """Refuse an ``output_file`` Ipopt could not open for writing, or an ``option_file_name``
    that is not a readable file."""
    if name == "output_file":
        from jtraj.io import output_folder_problem

        folder = os.path.dirname(os.path.abspath(path))
        if os.path.isdir(path):
            raise IpoptOptionError(name, path, "a folder; expected a file path")
        # Ipopt creates no folder; writable by a real probe (permission bits do not tell root's)
        if not os.path.isdir(folder) or output_folder_problem(folder) is not None:
            raise IpoptOptionError(name, path, f"expected a file path in an existing, writable folder ({folder} is not one)")
    elif not os.path.isfile(path) or not os.access(path, os.R_OK):
        raise IpoptOptionError(name, path, "expected a readable Ipopt options file (Ipopt skips one it cannot read)")


def check(name: str, value: Any) -> Any:
    """``value`` as Ipopt expects it for option ``name`` (an integer given for a real option
    becomes a float; True/False become "yes"/"no"), or `IpoptOptionError`."""
    specs = catalog()
    if name not in specs:
        from jtraj.solvers.ipm import IpmOptions
        from jtraj.solvers.ipopt import IpoptOptions

        # jtraj's solver's own (it suggested Ipopt's nearest names); not the names jtraj's
        # Ipopt options take themselves (hessian: --exact-hessian, hessian_approximation)
        if name in {f.name for f in dataclasses.fields(IpmOptions)} - {f.name for f in dataclasses.fields(IpoptOptions)}:
            raise IpoptOptionError(name, value, "unknown Ipopt option; an option of jtraj's solver (solver='jtraj', --solver jtraj)")
        close = difflib.get_close_matches(name, specs, n=3)
        hint = f"did you mean {', '.join(close)}?" if close else "see Ipopt's option list (print_options_documentation=yes)"
        raise IpoptOptionError(name, value, f"unknown Ipopt option; {hint}")
    spec = specs[name]
    if spec.kind == "string":
        if isinstance(value, bool):
            value = "yes" if value else "no"
        if not isinstance(value, str):
            expected = f"one of {list(spec.values)}" if spec.values else "a string"
            raise IpoptOptionError(name, value, f"expected {expected}")
        if spec.values is not None and value.lower() not in spec.values:
            raise IpoptOptionError(name, value, f"expected one of {list(spec.values)}")
        if name == "linear_solver" and not linear_solver_available(value.lower()):
            raise IpoptOptionError(name, value, "not available in this Ipopt build (its library is not installed); expected mumps")
        if value and name in _FILE_OPTIONS:
            _check_file_option(name, value)
        elif name in _LIBRARY_OPTIONS and not value_usable(name, value.lower()):
            raise IpoptOptionError(name, value, "this Ipopt build cannot use it (it needs a library that is not installed, such as HSL's MC19); Ipopt would stop with 'Invalid option encountered.'")
        return value
    real = _is_real(name)
    number_types = (int, float, np.integer, np.floating) if real else (int, np.integer)
    if isinstance(value, bool) or not isinstance(value, number_types):
        raise IpoptOptionError(name, value, f"expected {'a real number' if real else 'an integer'} in {_range(spec)}")
    x = float(value)
    below = x <= spec.lower if spec.lower_strict else x < spec.lower
    above = x >= spec.upper if spec.upper_strict else x > spec.upper
    if below or above or math.isnan(x):
        raise IpoptOptionError(name, value, f"expected {'a real number' if real else 'an integer'} in {_range(spec)}")
    if not real and abs(int(value)) > 2**31 - 1:  # a C int: cyipopt raises OverflowError at the solve
        raise IpoptOptionError(name, value, f"expected an integer in {_range(spec)} of at most {2**31 - 1} in magnitude")
    return x if real else int(value)


def check_all(options: dict[str, Any]) -> dict[str, Any]:
    """`check` every entry; the options with Ipopt's value types."""
    return {name: check(name, value) for name, value in options.items()}
