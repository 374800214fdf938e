"""Ipopt's own option list, read from the bundled Ipopt, to check options before any solve.

Ipopt knows its options (name, type, bounds, allowed strings) but reports a bad one only when
a solve starts, and cyipopt then raises a bare ``TypeError``; an integer given for a real
option (``tol=1``) is refused too, because cyipopt picks Ipopt's setter from the Python type.
Here the catalog comes from Ipopt's ``print_options_documentation`` (written once per process
by a one-variable problem into a temporary file, Ipopt's ``output_file``: its text form for
bounds and allowed strings, its doxygen form for which numbers are integers), and `check`
turns a user's ``NAME=VALUE`` into the value Ipopt expects, or raises `IpoptOptionError` with
one line. Nothing here redirects file descriptor 1.

Linear solvers other than MUMPS are loaded by Ipopt at run time from libraries that may be
absent; `linear_solver_available` solves the one-variable problem with one, in a child
process, to find out.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import os
import re
import subprocess
import sys
import tempfile
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
    """One Ipopt option: ``kind`` is "integer", "real" or "string"."""

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


def _documentation(mode: str) -> str:
    """Ipopt's option documentation in ``mode`` ("text" or "doxygen"), written by Ipopt to a
    temporary file (its own ``output_file``): nothing goes to file descriptor 1, so another
    thread's output meanwhile is not touched (a capture of descriptor 1 swallowed it)."""
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "options.txt")
        p = _problem()
        for key, value in (
            ("print_options_documentation", "yes"),
            ("print_options_mode", mode),
            ("print_advanced_options", "yes"),
            ("max_iter", 0),
            ("sb", "yes"),
            ("print_level", 0),
            ("output_file", path),
            ("file_print_level", 3),
        ):
            p.add_option(key, value)
        p.solve(np.array([0.5]))
        with open(path) as f:
            return f.read()


_NUMBER = re.compile(r"^(\w+)\s+(\S+)\s+(<=|<)\s+\(\s*(\S+)\)\s+(<=|<)\s+(\S+)\s*$")
_STRING = re.compile(r'^(\w+)\s+\("(.*)"\)\s*$')
_VALUE = re.compile(r"^\s+- (\S+)")
#: the doxygen form's option name and, later in its paragraph, its type
_DOXYGEN_TYPE = re.compile(r"<strong>(\w+)</strong>(?:(?!<strong>).)*?this (integer|real|string) option", re.S)


def _parse(text: str, types: dict[str, str]) -> dict[str, OptionSpec]:
    specs: dict[str, OptionSpec] = {}
    current: str | None = None
    for line in text.splitlines():
        if m := _NUMBER.match(line):
            lo, hi = (float(v) for v in (m.group(2), m.group(6)))
            kind = types.get(m.group(1))
            if kind not in ("integer", "real"):  # a format change: fail loudly, not guess
                raise RuntimeError(f"could not read the type of Ipopt's option {m.group(1)!r}")
            specs[m.group(1)] = OptionSpec(m.group(1), kind, m.group(4), lo, hi, m.group(3) == "<", m.group(5) == "<")
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
    # the text form gives bounds and allowed strings; the doxygen form says which numbers are
    # integers (the text form prints max_iter's and s_max's defaults alike), and cyipopt picks
    # Ipopt's setter from the Python type, so tol=1 must become 1.0
    types = {m.group(1): m.group(2) for m in _DOXYGEN_TYPE.finditer(_documentation("doxygen"))}
    specs = _parse(_documentation("text"), types)
    if len(specs) < 100:  # a different print format: better to fail loudly than check nothing
        raise RuntimeError(f"could not read Ipopt's option list ({len(specs)} options parsed)")
    return specs


#: run in a child process by `linear_solver_available`: this file loaded alone (not the jtraj
#: package, which imports JAX; registered in sys.modules, as its dataclasses need), the probe's
#: status printed, and the child ended at once
_CHILD_PROBE = """
import importlib.util, os, sys
spec = importlib.util.spec_from_file_location("_jtraj_ipopt_probe", sys.argv[1])
module = importlib.util.module_from_spec(spec)
sys.modules[spec.name] = module
spec.loader.exec_module(module)
try:
    status = module._probe_status(("linear_solver", sys.argv[2]))
except TypeError:  # cyipopt's refusal of a value this Ipopt does not list (spral, wsmp)
    status = "refused"
print(status, flush=True)
os._exit(0)
"""


def _child_status(name: str) -> int | None:
    """Ipopt's status on the tiny problem with ``linear_solver=name``, solved in a child
    process; None where this Ipopt refuses the name, or the child died of a signal (a crash in
    the solver's library: MA97 without HSL) or did not answer in time. A child that failed
    otherwise raises, with its error."""
    try:
        child = subprocess.run(
            [sys.executable, "-c", _CHILD_PROBE, os.path.abspath(__file__), name], capture_output=True, text=True, timeout=120
        )
    except subprocess.TimeoutExpired:
        return None
    last = (child.stdout.split() or [""])[-1]
    if last.lstrip("-").isdigit():
        return int(last)
    if last == "refused" or child.returncode < 0:
        return None
    raise RuntimeError(f"the probe of Ipopt's linear_solver={name!r} failed (exit status {child.returncode}): {child.stderr.strip()[-2000:]}")


@functools.lru_cache(maxsize=None)
def linear_solver_available(name: str) -> bool:
    """Whether this Ipopt can solve with ``linear_solver=name`` (MUMPS is built in; the
    others are loaded at run time from libraries that may be absent).

    Probed in a child process (`_child_status`): with HSL absent, Ipopt's MA97 interface
    crashes the process (segmentation fault) when the problem that tried to load it is freed."""
    if name == "mumps":
        return True
    return _child_status(name) in (0, 1)


def _probe_status(*options: tuple[str, Any]) -> int:
    """Ipopt's return status on the tiny problem with ``options``, quiet (``print_level`` 0:
    Ipopt prints nothing); cyipopt's TypeError for a value it refuses is raised as it is (and
    Ipopt prints why on file descriptor 1, so give only values its list allows)."""
    p = _problem()
    for key, value in (*options, ("print_level", 0), ("sb", "yes")):
        p.add_option(key, value)
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
    spec = catalog().get(name)
    if spec is None or spec.kind != "string" or (spec.values is not None and value not in spec.values):
        return False  # Ipopt would refuse it (and print why on file descriptor 1)
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
        if isinstance(value, (bool, np.bool_)):  # (numpy's too: it was "expected one of ['yes', 'no']")
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
    real = spec.kind == "real"
    number_types = (int, float, np.integer, np.floating) if real else (int, np.integer)
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, number_types):
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
