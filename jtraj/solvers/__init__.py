"""NLP solver backends behind one contract (`AbstractSolver`, `Solution`, `Status`).

``SOLVERS`` maps a name to a backend class; `get` returns an instance. Adding a backend is one
class (a subclass of `AbstractSolver` with its `AbstractOptions`) and one entry here.
"""

from __future__ import annotations

from jtraj.registry import lookup
from jtraj.solvers.base import (
    AbstractCallback,
    AbstractOptions,
    AbstractSolver,
    CallbackList,
    InvalidOptionError,
    Iteration,
    PrintProgress,
    Progress,
    RecordIterates,
    Solution,
    Stats,
    Status,
    resolve_progress,
)
from jtraj.solvers.ipm import IpmOptions, JtrajSolver
from jtraj.solvers.ipopt import IpoptOptions, IpoptSolver

__all__ = [
    "SOLVERS",
    "get",
    "AbstractSolver",
    "AbstractOptions",
    "AbstractCallback",
    "CallbackList",
    "InvalidOptionError",
    "Iteration",
    "PrintProgress",
    "RecordIterates",
    "Progress",
    "Solution",
    "Stats",
    "Status",
    "resolve_progress",
    "IpoptOptions",
    "IpoptSolver",
    "IpmOptions",
    "JtrajSolver",
]

#: Solver backends by name (``jtraj.solve(..., solver=NAME)``, ``jtraj solve --solver NAME``).
SOLVERS: dict[str, type[AbstractSolver]] = {"ipopt": IpoptSolver, "jtraj": JtrajSolver}


def get(solver: str | AbstractSolver | type[AbstractSolver]) -> AbstractSolver:
    """A solver backend from its registry name (or the solver itself, or its class)."""
    if isinstance(solver, AbstractSolver):
        return solver
    if isinstance(solver, type) and issubclass(solver, AbstractSolver):  # solver=IpoptSolver: was "unknown solver <class ...>"
        return solver()
    return lookup(SOLVERS, solver, "solver")()
