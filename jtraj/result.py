"""One result type for every solve of jtraj: whole-body tasks and the attitude benchmarks.

A `Result` holds what the solver returned (its `jtraj.solvers.Status`, counts and time split
in `jtraj.solvers.Stats`, the per-iteration history), the problem's own task check (an
`Outcome` and the ``metrics`` it computed: turns of a flip, a keep-out margin...) and the
decoded trajectory (any dataclass of arrays: `jtraj.transcription.Trajectory` for a robot,
`jtraj.attitude.transcription.StateTrajectory` for a rigid body).

Files: ``save(DIR)`` writes ``DIR/result.json`` (strict JSON, atomically) and
``DIR/trajectory.npz`` (atomically; removed when the result has no trajectory, so that an
older one cannot be taken for this result's); `Result.load` reads them back and raises
`jtraj.io.FileFormatError` naming the file when one is missing, empty or corrupt. Each file
is atomic, the pair is not: ``result.json`` records a digest of the trajectory file's arrays
(``trajectory_sha256``, null without a trajectory), so that a save interrupted between the
two files is refused by `Result.load` instead of pairing one solve's result with another's
trajectory. Files written before the digest load as they are. A save also removes the files
that jtraj derives from a result into its folder (`DERIVED_FILES`: figures, video, keyframe
strip), which would otherwise show an earlier solve beside this one.

Strict JSON writes NaN and infinities as null, and a null can also be meaningful (a ``turns``
of None: not a flip task): ``result.json`` lists where the result held non-finite numbers
(the metrics, options, violations per group, history, and the numbers of the top level such as
the cost) and which (``non_finite_values``: a path of keys and indices, and ``"nan"``, ``"inf"``
or ``"-inf"``; e.g. a theta's infinite ``max_delta_force``), and `Result.load` puts them back.
Files written before that list name only the metrics that held one (``metrics_non_finite``),
whose nulls are read back as NaN; in files written before either, a null stays None.

A save also removes a ``provenance.json`` from the folder: it records the run that wrote the
earlier result (`jtraj.solve` with ``out`` writes its own after saving).

This module imports neither MuJoCo nor the transcription: the trajectory's class is recorded
by name in the NPZ file and imported when the file is loaded.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import math
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from jtraj import io
from jtraj.solvers.base import MessageEnum, Solution, Stats, Status

__all__ = ["Outcome", "Result"]

RESULT_FILE = "result.json"
TRAJECTORY_FILE = "trajectory.npz"
_KIND_KEY = "__trajectory_class__"
_DIGEST_KEY = "trajectory_sha256"
_NON_FINITE_KEY = "metrics_non_finite"
_NON_FINITE_VALUES_KEY = "non_finite_values"
#: The fields whose non-finite numbers `Result.save` lists where they are (`_non_finite_values`).
_EXACT_FIELDS = ("metrics", "options", "violation_by_group", "history")
#: The fields ``non_finite_values`` lists; the others' entries, and the top level's, are under
#: `_NON_FINITE_MORE_KEY`: a reader of files before them (jtraj at 7307760) refuses an entry of
#: another field in ``non_finite_values``, and ignores a key it does not know
_FIRST_EXACT_FIELDS = ("metrics", "options")
_NON_FINITE_MORE_KEY = "non_finite_values_more"
PROVENANCE_FILE = "provenance.json"
#: The files jtraj writes into a result's folder from its result: `jtraj solve`'s figures
#: (``trajectory.png``, ``convergence.png``), ``jtraj plot``'s (``solution.png``), ``jtraj
#: attitude``'s (``plot.png``) and ``--render``'s video and strip (``motion.mp4``,
#: ``keyframes.png``). `Result.save` removes them: they are of the result it replaces.
DERIVED_FILES = ("trajectory.png", "convergence.png", "solution.png", "plot.png", "motion.mp4", "keyframes.png")
#: every file `Result.save` writes or removes in a result's folder
RESULT_FOLDER_FILES = (RESULT_FILE, TRAJECTORY_FILE, PROVENANCE_FILE, *DERIVED_FILES)


def folder_in_the_way(directory: str | Path, names: tuple[str, ...] = RESULT_FOLDER_FILES) -> str | None:
    """What stops a write of ``names`` into ``directory`` ("D/motion.mp4 is a folder; expected
    room for the file motion.mp4"), or None: a folder at one of them (by default
    `RESULT_FOLDER_FILES`, where `Result.save` failed with IsADirectoryError after the solve).
    Checked before a solve that saves there (`jtraj.solve`, the command line)."""
    for name in names:
        if (Path(directory) / name).is_dir():
            return f"{Path(directory) / name} is a folder; expected room for the file {name}"
    return None


class Outcome(MessageEnum):
    """Did the solve do the task? From the solver's status, feasibility and the task check."""

    SOLVED = ("solved", "the solver converged to a feasible point and the task check passed")
    TASK_FAILED = ("converged_but_task_failed", "the solver converged to a feasible point that does not do the task (e.g. a jump instead of a flip)")
    NOT_CONVERGED = ("not_converged", "the solver did not return a feasible solution; see solver_status")

    @classmethod
    def of(cls, feasible: bool, task_ok: bool) -> Outcome:
        """SOLVED when feasible (converged, and within the problem's violation tolerance) and
        the task check passed; TASK_FAILED when only feasible; NOT_CONVERGED otherwise."""
        if not feasible:
            return cls.NOT_CONVERGED
        return cls.SOLVED if task_ok else cls.TASK_FAILED


@dataclasses.dataclass(kw_only=True, eq=False)
class Result:
    """A solve and its check.

    Attributes:
        problem: the task or benchmark name.
        variant: how the attitude enters the NLP: the floating-base parameterization
            (``"se3"``...) or the attitude formulation (``"naive"``, ``"attitude"``).
        model: the robot or rigid-body model.
        solver: the backend's registry name.
        status: the `Outcome`.
        solver_status: the backend's `Status`; ``status_msg`` its own wording.
        stats: iterations, evaluation counts, time split (compilation excluded).
        time_compile: seconds spent compiling for this solve: the NLP and, with jtraj's solver,
            its program (0 when both were compiled before in this process).
        cost: objective at the solution.
        constraint_violation: max violation of the constraint rows and bounds.
        violation_by_group: the same per constraint group (and ``"bounds"``).
        metrics: the task check's numbers (e.g. ``turns``, ``min_sun_angle_deg``).
        n_variables, n_constraints, nnz_jacobian: problem size.
        options: the solver options and transcription settings used.
        history: per iteration: iter, objective, inf_pr, inf_du, mu, alpha_pr.
        trajectory: the decoded solution (a dataclass of arrays) or None.
    """

    problem: str
    variant: str
    model: str
    solver: str
    status: Outcome
    solver_status: Status
    status_msg: str
    stats: Stats
    time_compile: float
    cost: float
    constraint_violation: float
    violation_by_group: dict[str, float]
    metrics: dict[str, Any]
    n_variables: int
    n_constraints: int
    nnz_jacobian: int = 0
    options: dict[str, Any] = dataclasses.field(default_factory=dict)
    history: list[dict[str, float]] = dataclasses.field(default_factory=list)
    trajectory: Any = None

    @classmethod
    def from_solution(
        cls,
        solution: Solution,
        *,
        feasibility_tol: float,
        task_ok: bool,
        violation_by_group: dict[str, float],
        **fields: Any,
    ) -> Result:
        """The result of ``solution``: feasible when the solver converged with a constraint
        violation below ``feasibility_tol`` (the problem's own units; the rule Table III's
        summary applies to runs); ``task_ok`` is the problem's task check; ``fields`` are the
        problem's descriptive fields."""
        feasible = solution.converged and solution.constraint_violation < feasibility_tol
        return cls(
            status=Outcome.of(feasible, task_ok),
            solver_status=solution.status,
            status_msg=solution.message,
            stats=solution.stats,
            cost=solution.objective,
            constraint_violation=solution.constraint_violation,
            violation_by_group=violation_by_group,
            n_constraints=solution.mult_g.size,
            history=[it.as_dict() for it in solution.history],
            **fields,
        )

    # ------------------------------------------------------------------ derived
    @property
    def converged(self) -> bool:
        """The solver reported convergence (solved or acceptable)."""
        return self.solver_status.converged

    @property
    def success(self) -> bool:
        """Converged, feasible and the task check passed."""
        return self.status is Outcome.SOLVED

    @property
    def iterations(self) -> int:
        return self.stats.iterations

    @property
    def obj_evals(self) -> int:
        return self.stats.obj_evals

    @property
    def grad_evals(self) -> int:
        return self.stats.grad_evals

    @property
    def con_evals(self) -> int:
        return self.stats.con_evals

    @property
    def jac_evals(self) -> int:
        return self.stats.jac_evals

    @property
    def hess_evals(self) -> int:
        return self.stats.hess_evals

    @property
    def time_s(self) -> float:
        """Time to solution (s), compilation excluded."""
        return self.stats.time_total

    @property
    def time_derivatives(self) -> float:
        """Seconds in the NLP's JAX functions and derivatives during the solve (0 where the
        solver does not measure them apart: jtraj's, whose solve is one compiled program)."""
        return self.stats.time_evaluations

    @property
    def time_solver(self) -> float:
        """Seconds of the solver's own work (linear algebra, line search...)."""
        return self.stats.time_solver

    # the whole-body names of the same fields
    @property
    def task(self) -> str:
        return self.problem

    @property
    def parameterization(self) -> str:
        return self.variant

    @property
    def robot(self) -> str:
        return self.model

    @property
    def turns(self) -> float | None:
        """Signed turns about a flip task's axis (None for other problems)."""
        return self.metrics.get("turns")

    def summary(self) -> str:
        turns = "" if self.turns is None else f", turns {self.turns:+.2f}"
        if self.time_derivatives == 0.0 and self.time_s > 0.0:
            # a solver that does not split its time (jtraj's: one compiled program) reported
            # "derivatives 0.00 s" beside all of the time as its own
            split = f"not split between the NLP's functions and {self.solver}"
        else:
            split = f"derivatives {self.time_derivatives:.2f} s, {self.solver} {self.time_solver:.2f} s"
        return (
            f"{self.problem} [{self.variant}] {self.status.value}: {self.iterations} iterations, "
            f"cost {self.cost:.6g}, violation {self.constraint_violation:.2e}{turns}, "
            f"{self.time_s:.2f} s (compile {self.time_compile:.1f} s; {split})"
        )

    def plot(self, path: str | Path | None = None, **kwargs: Any) -> Any:
        """The result's figure: the trajectory's own ``plot_result(result, path)`` where it has
        one (the attitude benchmarks), else `jtraj.plots.plot_solution` (base pose, joints and
        torques against their limits, contact forces, friction-pyramid use). Returns the figure,
        or the path when ``path`` is given."""
        own = getattr(self.trajectory, "plot_result", None)
        if own is not None:
            return own(self, path, **kwargs)
        from jtraj.plots import plot_solution

        return plot_solution(self, path, **kwargs)

    # ------------------------------------------------------------------ files
    def to_json(self) -> dict[str, Any]:
        """Everything but the trajectory, as JSON types; stats are flattened into the top level."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            if f.name in ("trajectory", "stats"):
                continue
            out[f.name] = getattr(self, f.name)
        out["status"] = self.status.value
        out["solver_status"] = self.solver_status.value
        out["converged"] = self.converged
        out["success"] = self.success
        out.update(dataclasses.asdict(self.stats))
        out["time_solver"] = self.stats.time_solver
        return io.to_jsonable(out)

    def save(self, directory: str | Path) -> Path:
        """Write ``result.json`` and ``trajectory.npz`` into ``directory`` (created). The
        `DERIVED_FILES` of an earlier result there (its figures and video) and its
        ``provenance.json`` (the record of the run that wrote it) are removed before either
        file is written; without a trajectory, an older ``trajectory.npz`` is removed."""
        d = Path(directory)
        # before anything there is removed: "" (an unset variable) was the current folder, whose
        # figures and provenance.json went; a file or an unwritable place raised the OS's error
        if (problem := io.output_folder_problem(directory) or folder_in_the_way(d)) is not None:
            raise ValueError(f"Result.save: directory={str(directory)!r}: {problem}")
        d.mkdir(parents=True, exist_ok=True)
        arrays = None if self.trajectory is None else _trajectory_arrays(self.trajectory)
        data = self.to_json()
        for name in (*DERIVED_FILES, PROVENANCE_FILE):
            (d / name).unlink(missing_ok=True)
        exact = [[[name, *path], text] for name in _EXACT_FIELDS for path, text in _non_finite_values(getattr(self, name))]
        # and the numbers of the top level (stats flattened into it: `to_json`): an infinite
        # cost came back as NaN
        top = {**{f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name not in ("trajectory", "stats", *_EXACT_FIELDS)}, **dataclasses.asdict(self.stats)}
        exact += [[[name], text] for name, value in top.items() if isinstance(value, (float, np.floating)) for _, text in _non_finite_values(value)]
        # the earlier list, of the metrics holding one, for readers of files before the exact one
        non_finite = list(dict.fromkeys(path[1] for path, _ in exact if path[0] == "metrics"))
        first = [e for e in exact if len(e[0]) > 1 and e[0][0] in _FIRST_EXACT_FIELDS]
        more = [e for e in exact if not (len(e[0]) > 1 and e[0][0] in _FIRST_EXACT_FIELDS)]
        # the two files are replaced one after the other: the digest ties them together
        io.write_json(
            d / RESULT_FILE,
            {**data, _NON_FINITE_KEY: non_finite, _NON_FINITE_VALUES_KEY: first, _NON_FINITE_MORE_KEY: more, _DIGEST_KEY: None if arrays is None else _digest(arrays)},
        )
        npz = d / TRAJECTORY_FILE
        if arrays is None:
            npz.unlink(missing_ok=True)
        else:
            io.write_npz(npz, **arrays)
        return d

    @classmethod
    def load(cls, directory: str | Path) -> Result:
        """Read a result saved by `save` from its folder (or its ``result.json`` or
        ``trajectory.npz``); `jtraj.io.FileFormatError` names the file that is missing, empty
        or corrupt."""
        d = result_folder(directory)
        path = d / RESULT_FILE
        data = io.read_json(path)
        if not isinstance(data, dict):
            raise io.FileFormatError(f"{path}: expected a JSON object, got {type(data).__name__}")
        try:
            more = data.get(_NON_FINITE_MORE_KEY)
            if more is not None and not isinstance(more, list):
                raise ValueError(f"{_NON_FINITE_MORE_KEY}: expected a list, got {type(more).__name__}")
            top = [e for e in more or [] if isinstance(e, list) and len(e) == 2 and isinstance(e[0], list) and len(e[0]) == 1]
            data = _restore_top_level(data, top)
            # (Stats' fields have defaults, but every file has them: a missing one is no result)
            stats = Stats(**{f.name: _field_value(f, data, required=True) for f in dataclasses.fields(Stats)})
            fields = {f.name: _field_value(f, data) for f in dataclasses.fields(cls) if f.name not in ("stats", "trajectory")}
            fields["status"] = _member(Outcome, data["status"])
            fields["solver_status"] = _member(Status, data["solver_status"])
            # the numbers of these tables are floats too (NaN for a failed group or iteration)
            fields["violation_by_group"] = _nan_for_null(fields["violation_by_group"])
            fields["history"] = [_nan_for_null(row) for row in fields["history"]] if isinstance(fields["history"], list) else fields["history"]
            if _NON_FINITE_VALUES_KEY in data:  # each non-finite number where it was
                _restore_non_finite(fields, data[_NON_FINITE_VALUES_KEY], _FIRST_EXACT_FIELDS)
                _restore_non_finite(fields, [e for e in more or [] if not any(e is t for t in top)], _EXACT_FIELDS, _NON_FINITE_MORE_KEY)
            else:  # a file from before that list: a named metric's nulls are NaN
                fields["metrics"] = _restore_metrics(fields["metrics"], data.get(_NON_FINITE_KEY))
        except KeyError as e:
            raise io.FileFormatError(f"{path}: missing field {e.args[0]!r}; not a jtraj result") from None
        except ValueError as e:
            raise io.FileFormatError(f"{path}: {e}") from None
        npz = d / TRAJECTORY_FILE
        trajectory = None
        if _DIGEST_KEY in data and data[_DIGEST_KEY] is None:
            pass  # saved without a trajectory: a trajectory file beside it is an earlier one
        elif isinstance(data.get(_DIGEST_KEY), str) and not npz.exists():
            raise io.FileFormatError(f"{npz}: file does not exist; {path} was saved with a trajectory")
        elif npz.exists():
            trajectory, digest = _load_trajectory(npz)
            if _DIGEST_KEY in data and data[_DIGEST_KEY] != digest:
                raise io.FileFormatError(f"{npz}: not the trajectory of {path} (its digest differs: a save interrupted between the two files?)")
        return cls(**fields, stats=stats, trajectory=trajectory)


def result_folder(path: str | Path) -> Path:
    """The folder of the result ``path`` names: the folder itself, or one of the result's own
    files (``result.json``, ``trajectory.npz``) named instead; `jtraj.io.FileFormatError` for
    another file."""
    d = Path(path)
    if d.is_file():
        if d.name not in (RESULT_FILE, TRAJECTORY_FILE):
            raise io.FileFormatError(f"{d}: is a file; expected a result's folder (with {RESULT_FILE})")
        d = d.parent
    return d


def stale_trajectory_note(folder: str | Path) -> str:
    """For a result in ``folder`` saved without a trajectory (`Result.load` leaves out a
    trajectory file beside it): ``"; the trajectory.npz beside it is an earlier solve's"``
    where there is one, else nothing."""
    return f"; the {TRAJECTORY_FILE} beside it is an earlier solve's" if (Path(folder) / TRAJECTORY_FILE).exists() else ""


#: what each annotation of a result's field takes from JSON (a number for a float: an int too)
_JSON_TYPES: dict[str, tuple[type, ...]] = {"float": (int, float), "int": (int,), "str": (str,)}


def _field_value(field: dataclasses.Field, data: dict[str, Any], required: bool = False) -> Any:
    """``field``'s value in a result file's ``data``: its default where the file has none (a
    field added later), KeyError where it has no default; ValueError naming it where the file
    holds something of another type (\"12\" for the iterations loaded as a string, and a cost
    of "abc" failed later in `Result.summary`)."""
    if field.name not in data and not required and field.default is not dataclasses.MISSING:
        return field.default
    if field.name not in data and not required and field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    value = _float_or_nan(field, data[field.name])
    annotation = str(field.type)
    expected = _JSON_TYPES.get(annotation) or ((dict,) if annotation.startswith("dict") else (list,) if annotation.startswith("list") else None)
    if expected is not None and value is not None and (isinstance(value, bool) or not isinstance(value, expected)):
        raise ValueError(f"field {field.name!r}: {value!r}: expected {'a number' if annotation == 'float' else 'an integer' if annotation == 'int' else 'a ' + expected[0].__name__}")
    return float(value) if annotation == "float" and value is not None else value


def _float_or_nan(field: dataclasses.Field, value: Any) -> Any:
    """A float field's value as read back: strict JSON writes NaN and infinities as null (a
    file before the list of non-finite values: NaN for either)."""
    return math.nan if value is None and field.type in ("float", float) else value


def _nan_for_null(table: Any) -> Any:
    """A table of floats as read back: its nulls (NaN and infinities when written; the list of
    non-finite values then puts the infinities back) are NaN (`_all_nan_for_null`); anything
    but a table as it is."""
    return _all_nan_for_null(table) if isinstance(table, dict) else table


def _non_finite_values(value: Any, path: tuple = ()) -> list[tuple[list, str]]:
    """Where ``value`` (numbers, arrays, and dicts, lists and dataclasses of them, as
    `jtraj.io.to_jsonable` writes them) holds NaN or infinities: (path of keys and indices,
    ``"nan"``, ``"inf"`` or ``"-inf"``) for each."""
    if isinstance(value, (float, np.floating)):
        x = float(value)
        return [] if math.isfinite(x) else [(list(path), "nan" if math.isnan(x) else ("inf" if x > 0 else "-inf"))]
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        value = {f.name: getattr(value, f.name) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return [hit for k, v in value.items() for hit in _non_finite_values(v, (*path, str(k)))]
    if isinstance(value, (list, tuple)):
        return [hit for i, v in enumerate(value) for hit in _non_finite_values(v, (*path, i))]
    if isinstance(value, np.ndarray) or (hasattr(value, "__array__") and hasattr(value, "dtype")):
        a = np.asarray(value)
        return _non_finite_values(a.tolist(), path) if a.dtype.kind == "f" else []
    return []


def _restore_top_level(data: dict[str, Any], entries: list) -> dict[str, Any]:
    """``data`` with the non-finite numbers of its top level (entries ``[[name], text]`` of
    `_NON_FINITE_MORE_KEY`, `Result.save`) back in place of their nulls; ValueError for one
    that names no null."""
    values = {"nan": math.nan, "inf": math.inf, "-inf": -math.inf}
    data = dict(data)
    for entry in entries:
        (name,), text = entry
        # (a name that is no string, e.g. a list, was a TypeError from the dict, not this error)
        if not isinstance(name, str) or not isinstance(text, str) or name not in data or data[name] is not None or text not in values or name in _EXACT_FIELDS:
            raise ValueError(f"{_NON_FINITE_MORE_KEY}: {entry!r} names no null of the result")
        data[name] = values[text]
    return data


def _restore_non_finite(fields: dict[str, Any], entries: Any, names: tuple[str, ...] = _EXACT_FIELDS, key: str = _NON_FINITE_VALUES_KEY) -> None:
    """Put the non-finite numbers ``entries`` lists (`Result.save`'s ``non_finite_values``, or
    the entries of `_NON_FINITE_MORE_KEY` below the top level) back in place of their nulls in
    the fields ``names`` of ``fields``; ValueError (naming ``key``) for an entry that names no
    null."""
    if entries is None:  # a file written before the list
        return
    if not isinstance(entries, list):
        raise ValueError(f"{key}: expected a list, got {type(entries).__name__}")
    values = {"nan": math.nan, "inf": math.inf, "-inf": -math.inf}
    for entry in entries:
        try:
            (name, *keys, last), text = entry
            assert name in names and text in values
            parent = fields[name]
            for part in keys:  # not ``key``: the error below names the list by it
                parent = parent[part]
            if parent[last] is not None and not (isinstance(parent[last], float) and math.isnan(parent[last])):
                raise TypeError
            parent[last] = values[text]
        except (AssertionError, KeyError, IndexError, TypeError, ValueError):
            raise ValueError(f"{key}: {entry!r} names no null of the result") from None


def _all_nan_for_null(value: Any) -> Any:
    """``value`` as read back with its nulls, at any depth, as NaN."""
    if value is None:
        return math.nan
    if isinstance(value, dict):
        return {k: _all_nan_for_null(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_all_nan_for_null(v) for v in value]
    return value


def _restore_metrics(metrics: Any, non_finite: Any) -> Any:
    """The metrics as saved: the nulls of those named in ``non_finite`` (the saved list of
    metrics that held NaN or infinities) are NaN; other nulls stay None (e.g. ``turns`` of a
    task without a flip), as do all of them in a file written before that list."""
    if not isinstance(metrics, dict) or not isinstance(non_finite, list):
        return metrics
    return {k: _all_nan_for_null(v) if k in non_finite else v for k, v in metrics.items()}


def _member(enum_cls: Any, value: Any) -> Any:
    """The member of ``enum_cls`` with ``value`` (ValueError naming the values otherwise)."""
    for member in enum_cls:
        if member.value == value:
            return member
    raise ValueError(f"{value!r} is not a {enum_cls.__name__}; expected one of {[m.value for m in enum_cls]}")


#: A trajectory file's arrays with one row per knot (beside ``t``).
_PER_KNOT = ("base_xyz_wxyz", "q_base", "q_joints", "v", "a", "tau", "forces", "contact_positions", "in_contact")


def _trajectory_arrays(trajectory: Any) -> dict[str, np.ndarray]:
    if not dataclasses.is_dataclass(trajectory) or isinstance(trajectory, type):
        raise TypeError(f"a result's trajectory must be a dataclass of arrays, got {type(trajectory).__name__}")
    arrays = {f.name: np.asarray(getattr(trajectory, f.name)) for f in dataclasses.fields(trajectory)}
    for name, a in arrays.items():
        if a.dtype.kind == "O":  # None, ragged lists: NPZ pickles them, and load (no pickle) refuses the file
            raise TypeError(f"a result's trajectory field {name!r} is {type(getattr(trajectory, name)).__name__}, not an array of numbers, bools or strings; it could be saved but not loaded")
    arrays[_KIND_KEY] = np.array(f"{type(trajectory).__module__}:{type(trajectory).__qualname__}")
    return arrays


def _digest(arrays: dict[str, np.ndarray]) -> str:
    """SHA-256 of a trajectory file's arrays: names, dtypes, shapes and bytes."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}\0{a.dtype.str}\0{a.shape}\0".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _load_trajectory(path: Path) -> tuple[Any, str]:
    """The trajectory in ``path`` and the `_digest` of its arrays."""
    try:
        with np.load(path) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as e:
        # numpy takes a file that is no archive for a pickle, and advises loading it unsafely
        reason = "not a zip archive" if isinstance(e, ValueError) and "pickle" in str(e) else str(e)
        raise io.FileFormatError(f"{path}: not a readable NPZ file ({reason})") from None
    digest = _digest(arrays)
    kind = arrays.pop(_KIND_KEY, None)
    if kind is None:
        raise io.FileFormatError(f"{path}: no {_KIND_KEY} entry; not a jtraj trajectory")
    module, _, name = str(kind).partition(":")
    if module != "jtraj" and not module.startswith("jtraj."):
        raise io.FileFormatError(f"{path}: its {_KIND_KEY} is {str(kind)!r}; expected a jtraj trajectory class (module jtraj...)")
    try:
        cls = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as e:
        raise io.FileFormatError(f"{path}: its trajectory class {str(kind)!r} does not exist in this jtraj ({e})") from None
    if not (dataclasses.is_dataclass(cls) and isinstance(cls, type)):
        raise io.FileFormatError(f"{path}: {str(kind)!r} is not a trajectory class")
    t = arrays.get("t")
    if t is not None:
        if t.ndim != 1:
            raise io.FileFormatError(f"{path}: 't' has shape {t.shape}; expected (knots,)")
        for key in _PER_KNOT:
            if key in arrays and (arrays[key].ndim == 0 or arrays[key].shape[0] != t.shape[0]):
                raise io.FileFormatError(f"{path}: {key!r} has shape {arrays[key].shape}, but 't' has {t.shape[0]} knots")
    # string arrays (contact names) come back as tuples of str
    values = {k: tuple(str(s) for s in v) if v.dtype.kind == "U" and v.ndim == 1 else v for k, v in arrays.items()}
    try:
        return cls(**values), digest
    except TypeError as e:
        raise io.FileFormatError(f"{path}: does not match {name} ({e})") from None
