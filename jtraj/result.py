"""Results of a solve: a dataclass with the Ipopt outcome, timings, the decoded trajectory and
the task-success check; saved as ``result.json`` + ``trajectory.npz`` and loadable back."""

from __future__ import annotations

import dataclasses
import enum
import json
from pathlib import Path
from typing import Any

import numpy as np

from jtraj import lie
from jtraj.lie import SO3
from jtraj.transcription import Trajectory

__all__ = ["Status", "Result", "count_turns"]


class Status(enum.Enum):
    """Outcome of a solve, from Ipopt's status and the task-success check."""

    SOLVED = "solved"  # Ipopt converged and the task succeeded
    SOLVED_WRONG_MOTION = "converged_but_task_failed"  # e.g. a plain jump instead of a flip
    NOT_CONVERGED = "not_converged"


def count_turns(base_xyz_wxyz: np.ndarray, axis: np.ndarray) -> float:
    """Signed number of revolutions of the base about a world axis.

    Sums the world-frame rotation increments ``Log(R_{k+1} R_k^T)`` projected on the axis, so
    a back-flip gives about -1 about +y and a plain jump about 0.
    """
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    R = SO3(np.asarray(base_xyz_wxyz)[:, 3:7])
    steps = np.asarray(lie.log(SO3(R.wxyz[1:]) @ SO3(R.wxyz[:-1]).inverse()))
    return float(np.sum(steps @ axis) / (2 * np.pi))


@dataclasses.dataclass
class Result:
    task: str
    robot: str
    parameterization: str
    status: Status
    status_msg: str
    converged: bool
    success: bool
    turns: float | None
    iterations: int
    obj_evals: int
    grad_evals: int
    con_evals: int
    jac_evals: int
    hess_evals: int
    cost: float
    constraint_violation: float
    violation_by_group: dict[str, float]
    final_position_error: float
    time_s: float  # time to solution, compile excluded
    time_compile: float
    time_derivatives: float  # JAX function and derivative evaluations inside Ipopt's callbacks
    time_ipopt: float  # Ipopt's own work (linear algebra, line search, ...)
    n_variables: int
    n_constraints: int
    nnz_jacobian: int
    options: dict[str, Any]
    history: list[dict[str, float]]
    trajectory: Trajectory | None = None

    def summary(self) -> str:
        turns = "" if self.turns is None else f", turns {self.turns:+.2f}"
        return (
            f"{self.task} [{self.parameterization}] {self.status.value}: {self.iterations} iterations, "
            f"cost {self.cost:.4g}, violation {self.constraint_violation:.2e}{turns}, "
            f"{self.time_s:.2f} s (compile {self.time_compile:.1f} s; derivatives {self.time_derivatives:.2f} s, "
            f"Ipopt {self.time_ipopt:.2f} s)"
        )

    def plot(self, path: str | Path | None = None, **kwargs):
        """Base pose, joint angles and torques against their limits, contact forces and the
        friction-cone use, contact phases shaded (`jtraj.plots.plot_solution`): the figure,
        or the path when ``path`` is given."""
        from jtraj.plots import plot_solution

        return plot_solution(self, path, **kwargs)

    # ------------------------------------------------------------------ files
    def to_json(self) -> dict[str, Any]:
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "trajectory"}
        out["status"] = self.status.value
        return out

    def save(self, directory: str | Path) -> Path:
        """Write ``result.json`` and ``trajectory.npz`` into ``directory`` (created)."""
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        with open(d / "result.json", "w") as f:
            json.dump(self.to_json(), f, indent=2, default=_json_default)
        if self.trajectory is not None:
            arrays = {k: v for k, v in dataclasses.asdict(self.trajectory).items() if k != "contact_names"}
            np.savez_compressed(d / "trajectory.npz", contact_names=np.array(self.trajectory.contact_names), **arrays)
        return d

    @classmethod
    def load(cls, directory: str | Path) -> Result:
        d = Path(directory)
        with open(d / "result.json") as f:
            data = json.load(f)
        data["status"] = Status(data["status"])
        fields = {f.name for f in dataclasses.fields(cls)}
        data = {k: v for k, v in data.items() if k in fields}
        traj = None
        if (d / "trajectory.npz").exists():
            with np.load(d / "trajectory.npz") as z:
                arrays = {k: z[k] for k in z.files}
            arrays["contact_names"] = tuple(str(s) for s in arrays["contact_names"])
            traj = Trajectory(**arrays)
        return cls(**data, trajectory=traj)


def _json_default(obj: Any) -> Any:
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, enum.Enum):
        return obj.value
    raise TypeError(f"cannot write {type(obj).__name__} to JSON")
