"""The comparative study's experiments: Table IV (every task with every parameterization) and the
noise-robustness study (Table III, Fig. 2).

Warm starts of the robustness study are drawn for all replicates and noise levels at once with
`jax.vmap` over PRNG keys, and solved with the same compiled NLP (one compile per task and
parameterization): by Ipopt one replicate after another, by jtraj's own solver (``solver=
"jtraj"``) each noise level's replicates in one batched call. Both write their results as JSON
and Markdown tables; the robustness study also draws Fig. 2 (``jtraj plot OUT`` draws a
comparison's figure).
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import functools
import hashlib
import json
import math
import os
import shutil
import sys
import zlib
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, TextIO

import jax
import jax.numpy as jnp
import numpy as np

from jtraj import io as jio
from jtraj import solvers
from jtraj.deprecation import renamed_argument
from jtraj.executors import KeyMismatchError, WorkerLostError, check_executor, executor_for
from jtraj.numbers import is_real, is_seed, is_whole
from jtraj.parameterization import PARAMETERIZATIONS, AbstractParameterization
from jtraj.provenance import FolderInUseError, begin_run, end_run, holding
from jtraj.result import Outcome
from jtraj.solver import evaluate, prepare, solve, solver_options, transcription_options, variables_label
from jtraj.success import FEASIBILITY_TOL
from jtraj.tables import markdown_table
from jtraj.task import Task
from jtraj.task import load as load_task
from jtraj.transcription import TranscriptionOptions

__all__ = ["compare", "robustness", "table_iii", "noisy_warm_starts", "chart_noisy_warm_starts", "check_noise_chart", "check_runs_file", "poses_in_chart", "NoiseChartError", "noise_key", "run_key", "variables_hash", "read_runs", "summarize_robustness", "select_runs", "setting_label", "TABLE_IV_PAPER_SE3", "RepeatedValueError", "KeyMismatchError", "plot_iterations"]

#: Iterations of the SE(3) tangent parameterization in the paper's Table IV.
TABLE_IV_PAPER_SE3 = {"walk": 14, "hopscotch": 10, "big_jump": 11, "handstand": 88, "backflip": 28, "sideflip": 29}
ALL_TASKS = ("walk", "hopscotch", "big_jump", "handstand", "backflip", "sideflip")
ROBUSTNESS_TASKS = ("walk", "big_jump", "backflip", "sideflip")
ROBUSTNESS_PARAMS = ("euler", "quat1", "quat2", "se3")
SIGMAS = (1e-6, 1e-3, 0.1, 0.5)

_ROW_KEYS = ("task", "robot", "parameterization", "solver", "status", "solver_status", "converged", "success", "turns", "iterations", "obj_evals", "grad_evals", "con_evals", "jac_evals", "cost", "constraint_violation", "time_s", "time_compile")


def _row(result) -> dict:
    row = {k: getattr(result, k) for k in _ROW_KEYS}
    row["status"] = result.status.value
    row["solver_status"] = result.solver_status.value
    row["task_check"] = result.metrics.get("task_check") or None  # why the task check failed
    # the code that solved it (not part of the run's key): a study resumed after a change of
    # code mixed two commits' runs in one table, and nothing said which run was whose
    row["source"] = _code_source()
    # and where: the process's JAX backend and device (a Ray worker's, not the caller's that
    # provenance.json describes; a resumed study can mix CPU and GPU runs, whose rounding differs)
    row["device"] = _device()
    return row


@functools.lru_cache(maxsize=1)
def _device() -> dict:
    """This process's JAX backend, device kind and count (`jtraj.provenance`'s ``"jax"`` record)."""
    from jtraj.provenance import _jax_devices

    return _jax_devices()


@functools.lru_cache(maxsize=1)
def _code_source() -> dict | None:
    """`jtraj.provenance.source` of this process (its commit and whether the checkout differs),
    asked once, before a process's first solve (`_compare_one`, `_robustness_rows`): the code
    it imported does not change while it runs."""
    from jtraj.provenance import source

    return source()


def _other_code_note(resumed: list[dict]) -> str | None:
    """A note when runs a study resumes were solved by other code than this process's: another
    commit, or a changed checkout on either side, or before runs recorded theirs; else None
    (also where this process's commit is unknown)."""
    here = _code_source()
    if here is None:
        return None
    others = [r for r in resumed if r.get("source") != here or here.get("dirty")]
    if not others:
        return None

    def named(source: dict | None) -> str:
        return "unrecorded" if not source else source["commit"][:7] + (" with changes" if source.get("dirty") else "")

    return (
        f"note: {len(others)} of the resumed runs were solved by other code ({', '.join(sorted({named(r.get('source')) for r in others}))}) "
        f"than this call's ({named(here)}), or code that may differ; their rows are kept in the tables (without resume, all are solved again)"
    )


def compare(
    tasks: Sequence[str | Task] = ALL_TASKS,
    params: Sequence[str | AbstractParameterization] = tuple(PARAMETERIZATIONS),
    out: str | Path = "runs/table_iv",
    variables: str | TranscriptionOptions = "paper",
    exact_hessian: bool = False,
    progress: TextIO | bool | None = True,
    save_trajectories: bool = True,
    executor: str = "local",
    workers: int = 1,
    ray_address: str | None = None,
    layout: str | None = None,
    solver: str = "ipopt",
    record_run: bool = True,
    ray_gpus: float | None = None,
) -> list[dict]:
    """Table IV: solve every task with every parameterization; write table_iv.{json,md}.

    ``params``: names of `PARAMETERIZATIONS` (or the parameterization objects of those names).
    ``solver``: the backend of every cell (a name of `jtraj.solvers.SOLVERS`, or such a solver
    or its class; each row records its name).
    ``variables``: the variables per knot (a `jtraj.solver.VARIABLES` name, default the study's,
    or a `TranscriptionOptions`, e.g. `jtraj.solver.with_changes("paper", {...})`);
    ``layout`` is its deprecated former name. ``progress``: True (default) prints to the
    ``sys.stdout`` of the call, a text stream prints there, False or None is quiet.

    ``executor`` (`jtraj.executors`): ``"local"`` solves in this process (``workers`` > 1: in
    that many worker processes), ``"ray"`` one Ray task per solve on the cluster at
    ``ray_address`` (``ray_address`` is for ``"ray"`` only, ``workers`` > 1 for ``"local"``
    only: each is refused with the other; ``ray_gpus``, for ``"ray"`` too, the GPUs each task
    reserves, `jtraj.executors.RayExecutor.num_gpus`: without them Ray hides a node's GPUs
    from the task). Rows keep the order of ``tasks`` x ``params``
    whatever the executor. Each cell is given its task as loaded here and its folder as an
    absolute path, so a worker in another folder (a Ray cluster's) solves the same task into
    ``out``; on a cluster of several machines the cell folders are written on the machine
    that solved the cell (the tables are written here).
    table_iv.{json,md} are written again as each cell finishes; a cell that raises, or an
    interrupt, stops the other cells, and the tables hold the cells finished before it. An
    earlier call's tables and their figure (``comparison.png``, from ``jtraj plot OUT``) are
    removed as the sweep starts (a folder in the place of one is refused then, not after the
    solves). ``record_run`` (default True) writes ``out/provenance.json`` (`jtraj.provenance`:
    unfinished until the tables are written; the command line, which writes its own, passes
    False).
    """
    variables = renamed_argument(variables, layout, "variables", "layout", "paper")
    progress = _progress_stream(progress)
    out = Path(out)
    solver = _solver_name("compare", solver)  # an unknown name fails here, before the first solve
    check_executor(executor, workers, ray_address, "compare", ray_gpus=ray_gpus)  # before anything is written
    params = _parameterization_names("compare", params)
    # the tasks loaded here are the ones solved: a Ray worker runs in another folder (or on
    # another machine), where a relative .toml path names another file or none
    loaded = [load_task(t) for t in tasks]
    # a cell's folder is named after its task (a .toml path's file name need not be), as its
    # rows are and as `jtraj.plots.plot_comparison` looks for it: OUT/{task}_{parameterization}
    _refuse_repeats("compare: tasks", tasks, [t.name for t in loaded], "task")
    _refuse_repeats("compare: params", params, params, "parameterization")
    # each cell folder's provenance.json names this process's command (a worker's, a Ray
    # worker's above all, is not the sweep's)
    command = list(sys.argv)
    folder = out.absolute()  # not relative to a Ray worker's own folder
    jobs = [(task, p, variables, exact_hessian, solver, str(folder / f"{task.name}_{p}") if save_trajectories else None, command) for task in loaded for p in params]
    # a cell folder that cannot take its result failed in its cell's solve, after the cells
    # before it were solved
    if save_trajectories and (problem := cell_folder_problem(folder, [t.name for t in loaded], params)) is not None:
        raise ValueError(f"compare: out={str(out)!r}: {problem}")
    # an earlier call's table, and `jtraj plot OUT`'s figure of it: this call writes its own
    # table as its cells finish (an interrupt before the first left the earlier one in OUT,
    # which then read as this call's)
    _connect_first(executor, ray_address, ray_gpus)
    # held from here (`jtraj.provenance.holding`): another process's run in OUT is refused before
    # this one clears its tables
    with holding(out):
        _clear_outputs("compare", out, COMPARE_OUTPUTS)
        # called from Python, an earlier command's complete record stayed beside this call's tables
        run = _begin_call(out, "compare", record_run, _call_settings(loaded, params, variables, exact_hessian, solver, executor=executor, workers=workers, ray_address=ray_address, ray_gpus=ray_gpus))
        in_process = executor == "local" and workers <= 1
        cells = ((i, _compare_one(*job, progress=progress)) for i, job in enumerate(jobs)) if in_process else executor_for(executor, workers, ray_address, ray_gpus).map(_compare_one, jobs)
        done: dict[int, dict] = {}
        try:
            with contextlib.closing(cells):  # stops the executor's other cells on the way out
                for i, row in cells:
                    done[i] = row
                    if progress is not None and not in_process:  # a solve here prints its own lines
                        print(f"{row['task']:10s} {row['parameterization']:6s}: {row['status']:26s} {row['iterations']:4d} it{_why(row)}", file=progress, flush=True)
                    _write_table_iv([done[k] for k in sorted(done)], out)
        except BaseException as e:
            # the cells finished so far, also one that arrived as the interrupt or a broken progress stream came
            if done:
                with contextlib.suppress(Exception):  # the first error is the one to report
                    _write_table_iv([done[k] for k in sorted(done)], out)
            kept = f"{out / 'table_iv.json'} holds the {len(done)} of {len(jobs)} cells finished before it" if done else f"none of the {len(jobs)} cells had finished"
            if isinstance(e, WorkerLostError):
                raise WorkerLostError(f"{e}; {kept}") from e.__cause__  # one message, after the pool's own error
            if isinstance(e, KeyboardInterrupt):  # the command line says what was kept (an earlier table_iv.json is not this call's)
                raise KeyboardInterrupt(kept) from None
            if isinstance(e, BrokenPipeError):  # (the progress stream closed) the command line says it too
                e.add_note(kept)
            if isinstance(e, FolderInUseError):  # a cell's folder, taken by another process since the check
                raise FolderInUseError(f"{e}; {kept}") from None
            raise
        if run is not None:
            end_run(out, run)
    return [done[k] for k in sorted(done)]


def cell_folder_problem(out: str | Path, tasks: Sequence[str], params: Sequence[str]) -> str | None:
    """What stops `compare` from saving a cell's result into its folder ``out/{task}_{param}``
    (a file in its place, a folder where one of its files goes, a folder this user cannot write
    in, another process's run in it), or None."""
    from jtraj.io import output_folder_problem
    from jtraj.provenance import in_use
    from jtraj.result import folder_in_the_way

    for task in tasks:
        for p in params:
            cell = Path(out) / f"{task}_{p}"
            if (problem := output_folder_problem(cell) or folder_in_the_way(cell)) is not None:
                return f"the cell folder {cell}: {problem}"
            if (busy := in_use(cell)) is not None:  # another process's solve in it: refused at that cell
                return busy
    return None


def _connect_first(executor: str, ray_address: str | None, ray_gpus: float | None = None) -> None:
    """A sweep's Ray cluster connected, or refused (`jtraj.executors.ExecutorUnavailableError`),
    before the sweep touches its folder: inside the executor's map the refusal came after the
    earlier tables were cleared. (Only an executor that connects: tests stand others in.)"""
    if executor == "ray" and callable(connect := getattr(executor_for("ray", 1, ray_address, ray_gpus), "connect", None)):
        connect()


def _begin_call(out: Path, function: str, record_run: bool, settings: dict | None = None) -> dict | None:
    """`jtraj.provenance.begin_run` for a sweep called from Python, or None without
    ``record_run``. Its command is the process's (a script's name, or a notebook kernel's
    launcher), so ``"call"`` names the function and gives ``settings``, the arguments that
    decide what is solved (tasks by name and content hash, variables by name and content
    hash): from the folder alone the seed, the replicates and the solver options were unknown."""
    if not record_run:
        return None
    return begin_run(out, None, {"call": {"function": f"jtraj.experiments.{function}", **jio.to_jsonable(settings or {})}})


def _call_settings(tasks: Sequence[Task], params: Sequence[str], variables, exact_hessian: bool, solver: str, **more: Any) -> dict:
    """The arguments of a sweep that decide its runs, for its provenance (`_begin_call`)."""
    return dict(
        tasks=[{"name": t.name, "task_hash": t.content_hash()} for t in tasks], params=list(params),
        variables=variables_label(variables), variables_hash=variables_hash(variables), exact_hessian=bool(exact_hessian), solver=solver, **more,
    )


class RepeatedValueError(ValueError):
    """A sweep's list gives one task, parameterization or noise level more than once
    (`_refuse_repeats`)."""


def _refuse_repeats(where: str, given: Sequence, keys: Sequence, what: str) -> None:
    """A `RepeatedValueError` naming the items of ``given`` whose ``keys`` (a task's name, a noise
    level's value) repeat: a sweep would solve, count and table them twice. ``where`` begins
    the message: the function and argument (``compare: tasks``), or the command line's option
    (``--tasks``, `jtraj.cli`, which checks before anything is written)."""
    groups: dict = {}
    for item, key in zip(given, keys):
        groups.setdefault(key, []).append(f"Task {item.name!r}" if isinstance(item, Task) else repr(item if isinstance(item, (str, float, int)) else str(item)))
    found = []
    for key, items in groups.items():
        labels = list(dict.fromkeys(items))
        if len(items) > 1:
            found.append(f"{labels[0]} given {len(items)} times" if len(labels) == 1 else f"{' and '.join(labels)} are the same {what} ({key!r})")
    if found:
        raise RepeatedValueError(f"{where}: {'; '.join(found)}; expected each {what} once")


def _parameterization_names(function: str, params: Sequence) -> list[str]:
    """The names of ``params`` (names, or parameterization objects: each stands for its name,
    which rows record and runs are keyed by), each one of `PARAMETERIZATIONS`: a ValueError
    naming the first that is not, before anything compiles. Keyed by the object, a robustness
    run was never found again (its row records the name), so nothing resumed."""
    names = [p if isinstance(p, str) else getattr(p, "name", p) for p in params]
    for given, name in zip(params, names):
        if name not in PARAMETERIZATIONS:
            raise ValueError(f"{function}: params: {given if isinstance(given, str) else str(given)!r}: unknown parameterization; expected some of {', '.join(PARAMETERIZATIONS)}")
    return names


def _solver_name(function: str, solver) -> str:
    """The registry name of ``solver`` (a name of `jtraj.solvers.SOLVERS`, or such a solver or
    its class), which rows record and runs are keyed by; a ValueError for an unknown one,
    before anything compiles."""
    try:
        name = solvers.get(solver).name
        solvers.get(name)  # a backend outside the registry: a worker could not find it by name
    except ValueError as e:
        raise ValueError(f"{function}: {e}") from None
    return name


def _why(row: dict) -> str:
    """The end of a cell's progress line: why it failed, if it did."""
    if row["status"] == Outcome.TASK_FAILED.value and row.get("task_check"):
        return f"  (task check: {row['task_check']})"
    if row["status"] == Outcome.NOT_CONVERGED.value:
        if row.get("converged"):
            return f"  ({row['solver'] or 'solver'} converged, but to a violation of {row['constraint_violation']:.1e}, over the feasibility tolerance {FEASIBILITY_TOL:g})"
        return f"  ({row['solver'] or 'solver'}: {row['solver_status']})"
    return ""


def _compare_one(task, p, variables, exact_hessian, solver, out, command=None, progress=None) -> dict:
    """One cell of Table IV (a module-level function: executors ship it to other processes);
    ``command``: what its folder's provenance.json names (the sweep's)."""
    _code_source()  # read before the solve, as this process's code is (an edit during it is not)
    return _row(solve(task, p, variables=variables, solver=solver, exact_hessian=exact_hessian, progress=progress, progress_every=10, out=out, command=command))


def _write_table_iv(rows: list[dict], out: Path) -> None:
    """Table IV of ``rows`` (`_row`, or the rows of a table_iv.json) as table_iv.json and
    table_iv.md. The JSON holds a NaN or infinite number as null, so a number is formatted
    alike from either (`_table_iv_number`): table_iv.md is the same whether rendered from the
    rows in memory or from the JSON it wrote."""
    out.mkdir(parents=True, exist_ok=True)
    jio.write_json(out / "table_iv.json", rows)
    # the robot column where the rows name it (tables written before they did have none)
    robots = any("robot" in r for r in rows)
    header = ("task", *(("robot",) if robots else ()), "parameterization", "status", "iterations (paper, SE(3))", "obj evals", "jac evals", "cost", "violation", "turns", "time (s)", "solver")
    cells = []
    for r in rows:
        paper = TABLE_IV_PAPER_SE3.get(r["task"]) if r["parameterization"] == "se3" else None
        iterations = f"{r['iterations']}" + (f" ({paper})" if paper else "")
        cells.append(
            (
                r["task"],
                *((r.get("robot") or "-",) if robots else ()),
                r["parameterization"],
                r["status"],
                iterations,
                r["obj_evals"],
                r["jac_evals"],
                _table_iv_number(r["cost"], ".3g"),
                _table_iv_number(r["constraint_violation"], ".1e"),
                _table_iv_number(r["turns"], "+.2f", missing=""),
                _table_iv_number(r["time_s"], ".1f"),
                r.get("solver", "ipopt"),
            )
        )
    jio.write_text(out / "table_iv.md", markdown_table(header, cells))


def _table_iv_number(x: float | None, spec: str, missing: str = "-") -> str:
    """A number of Table IV formatted with ``spec``; ``missing`` for None and for a NaN or
    infinite one (which table_iv.json holds as null), "-" as Table III writes a missing median.
    Turns are blank (``missing=""``): the committed tables leave them blank for tasks with no
    flip, whose rows hold null."""
    return missing if x is None or not math.isfinite(x) else format(x, spec)


def _progress_stream(progress: TextIO | bool | None) -> TextIO | None:
    """The stream a ``progress=`` argument names: True the ``sys.stdout`` of this moment (not
    of the import: pytest and notebooks replace it), a text stream itself, False or None
    none (quiet)."""
    if progress is True:
        return sys.stdout
    if progress is False or progress is None:
        return None
    if not hasattr(progress, "write"):
        raise TypeError(f"progress={progress!r}: expected True, False/None or a text stream")
    return progress


def _sigma_bits(sigma: float) -> int:
    return zlib.crc32(repr(float(sigma)).encode())  # fold_in takes 32-bit data


def noise_key(seed: int, sigma: float, replicate: int) -> jax.Array:
    """PRNG key of replicate ``replicate`` at noise level ``sigma``: folded from (seed, sigma,
    replicate) alone, so a run's noise does not change when the lists of noise levels or
    replicates change (adding a sigma or more replicates keeps every earlier run valid)."""
    return jax.random.fold_in(jax.random.fold_in(jax.random.PRNGKey(seed), _sigma_bits(sigma)), replicate)


def noisy_warm_starts(x0: np.ndarray, sigmas: Sequence[float], replicates: int | Sequence[int], seed: int = 0) -> np.ndarray:
    """Warm starts plus zero-mean Gaussian noise, (len(sigmas), n_replicates, *x0.shape): the
    keys of `noise_key` and the draws in one vmapped call. ``replicates`` is a count (0..n-1)
    or the replicate numbers themselves."""
    # a count (a numpy one too), or the replicate numbers
    reps = np.arange(int(replicates)) if is_whole(replicates) else np.asarray(list(replicates), dtype=np.int64)
    base = jnp.asarray(x0)
    bits = jnp.asarray([_sigma_bits(s) for s in sigmas], jnp.uint32)
    root = jax.random.PRNGKey(seed)

    def one(sigma_bits, sigma, r):
        key = jax.random.fold_in(jax.random.fold_in(root, sigma_bits), r)
        return base + sigma * jax.random.normal(key, base.shape, base.dtype)

    draw = jax.vmap(jax.vmap(one, in_axes=(None, None, 0)), in_axes=(0, 0, None))
    return np.asarray(draw(bits, jnp.asarray(sigmas, base.dtype), jnp.asarray(reps, jnp.uint32)))


class NoiseChartError(ValueError):
    """Noise drawn in one chart cannot be given to another (`chart_noisy_warm_starts`)."""


def poses_in_chart(starts: np.ndarray, src, dst, reference: np.ndarray | None = None) -> np.ndarray:
    """Warm starts (..., n_knots, nz) of the transcription ``src`` written in the chart of the
    transcription ``dst`` (same task, robot and variables per knot): each knot's base pose
    (``src.param.to_pose``) as ``dst.param.from_pose`` gives it, every other variable (joint
    angles, velocities, accelerations, forces, contact points) copied slot by slot. In a
    quaternion chart, ``reference`` (n_knots, nz), the chart's noise-free warm start, picks
    each knot's sign of rho: the one nearer the reference's (a flip's warm start turns rho into
    -rho along the way, where `from_pose` gives one representative)."""
    if [n for n, _ in src.layout.slots] != [n for n, _ in dst.layout.slots]:
        raise ValueError(f"poses_in_chart: the two transcriptions have different variables per knot ({src.layout.slots} and {dst.layout.slots})")
    x = np.asarray(starts, float)
    out = np.zeros(x.shape[:-1] + (dst.layout.nz,))
    na, nb = src.param.nq, dst.param.nq
    convert = jax.jit(jax.vmap(lambda q: dst.param.from_pose(src.param.to_pose(q))))
    for name, _ in dst.layout.slots:
        a, b = src.layout.slice(name), dst.layout.slice(name)
        if name != "q":
            out[..., b] = x[..., a]
            continue
        base = x[..., a.start : a.start + na]
        out[..., b.start : b.start + nb] = np.asarray(convert(base.reshape(-1, na))).reshape(base.shape[:-1] + (nb,))
        if reference is not None and dst.param.name.startswith("quat"):
            rho = out[..., b.start + 3 : b.start + 7]
            ref = np.asarray(reference)[..., b.start + 3 : b.start + 7]
            rho *= np.where(np.sum(rho * ref, axis=-1, keepdims=True) < 0, -1.0, 1.0)
        out[..., b.start + nb : b.stop] = x[..., a.start + na : a.stop]
    return out


def chart_noisy_warm_starts(tr, noise_chart: str | None, sigmas: Sequence[float], replicates: int | Sequence[int], seed: int = 0, source=None) -> np.ndarray:
    """`noisy_warm_starts` of the transcription ``tr`` with the noise drawn in another chart's
    coordinates: the draws (same keys) of ``noise_chart``'s warm start, each knot's noisy base
    pose written in ``tr``'s chart (`poses_in_chart`). The two charts then start from the same
    poses, and only the chart differs. Noise of sigma on a quaternion's four entries turns the
    base further than noise of sigma on three rotation coordinates (on the study's walk at sigma
    0.5, 1.41 rad against 0.80 on average), so this is how the charts are compared at equal
    noise on the pose. ``noise_chart`` None or ``tr``'s own chart: its own draws. Raises
    ValueError where the noise-free warm starts are not one trajectory in both charts (a flip's
    full turn, which an SE(3) Log writes as its principal angle). ``source``: a transcription of
    the same task in ``noise_chart`` to reuse (its warm start's compiled helpers, about 3 s a
    transcription); None builds one."""
    if noise_chart is None or noise_chart == tr.param.name:
        return noisy_warm_starts(tr.warm_start(), sigmas, replicates, seed)
    from jtraj.transcription import Transcription

    if noise_chart not in PARAMETERIZATIONS:
        raise NoiseChartError(f"noise_chart={noise_chart!r}: expected one of {', '.join(PARAMETERIZATIONS)}")
    if source is not None and (source.param.name, source.task, source.options, source.robot.name) != (noise_chart, tr.task, tr.options, tr.robot.name):
        raise ValueError(f"chart_noisy_warm_starts: source is a {source.param.name} transcription of {source.task.name!r}, not the {noise_chart} one of {tr.task.name!r} with the same options")
    src = Transcription(tr.robot, tr.task, PARAMETERIZATIONS[noise_chart], tr.options) if source is None else source
    x0, x0_src = tr.warm_start(), src.warm_start()
    if not np.allclose(poses_in_chart(x0_src[None], src, tr, x0)[0], x0, rtol=0, atol=1e-9):
        raise NoiseChartError(
            f"{tr.task.name}: the {noise_chart} warm start written in the {tr.param.name} chart is not the {tr.param.name} warm start "
            f"(e.g. a flip's full turn, which Log writes as its principal angle), so noise drawn in the {noise_chart} chart cannot be given to it"
        )
    noisy = noisy_warm_starts(x0_src, sigmas, replicates, seed)
    return poses_in_chart(noisy, src, tr, x0)


def check_noise_chart(tasks: Sequence[str | Task], params: Sequence[str], variables: str | TranscriptionOptions, noise_chart: str | None) -> None:
    """Raise `NoiseChartError` before any NLP compiles where ``noise_chart``'s noisy poses cannot
    be given to one of ``params`` on one of ``tasks`` (`chart_noisy_warm_starts`; it builds
    each parameterization's warm start and the noise chart's once per task, about 3 s each on
    two cores). A (task, parameterization) pair that passed is not built again in this process:
    the command line checks before it writes OUT, and `robustness` checks again."""
    if noise_chart is None:
        return
    if noise_chart not in PARAMETERIZATIONS:
        raise NoiseChartError(f"noise_chart={noise_chart!r}: expected one of {', '.join(PARAMETERIZATIONS)} or None")
    from jtraj.robot import load as load_robot
    from jtraj.transcription import Transcription

    options = transcription_options(variables)
    options_hash = variables_hash(options)
    for task in tasks:
        task = load_task(task)
        todo = [p for p in params if p != noise_chart and (task.content_hash(), p, options_hash, noise_chart) not in _NOISE_CHARTS_PASSED]
        if not todo:
            continue
        robot = load_robot(task.robot)
        source = Transcription(robot, task, PARAMETERIZATIONS[noise_chart], options)
        for p in todo:
            chart_noisy_warm_starts(Transcription(robot, task, PARAMETERIZATIONS[p], options), noise_chart, [0.0], [0], source=source)
            _NOISE_CHARTS_PASSED.add((task.content_hash(), p, options_hash, noise_chart))


#: (task content hash, parameterization, variables hash, noise chart) of the checks passed
_NOISE_CHARTS_PASSED: set[tuple[str, str, str, str]] = set()


#: the fields of a run's key, beside its task's name (kept for the tables); "layout" holds the
#: ``variables`` name under its former key, and "variables_hash" the content of the options
#: that name stood for when the run was solved (a name such as "paper" can change meaning
#: between versions: its Euler warm start did); "robot_hash" the content of the task's robot
#: (`jtraj.robot.Robot.content_hash`: a robot file can change while its name stays)
RUN_KEY = ("task_hash", "parameterization", "layout", "variables_hash", "hessian", "options_hash", "seed", "sigma", "replicate", "solver", "noise_chart", "robot_hash")
RUNS_FILE = "runs.jsonl"
#: key fields that rows of earlier runs.jsonl files lack, and their value there: before the
#: solver was recorded every run was an Ipopt solve; before the noise's chart was, every run's
#: noise was drawn in its own chart (None); before the variables' or the robot's content was,
#: it is unknown (None), so such rows are kept in the file but never taken for a run of this version
_KEY_DEFAULTS: dict[str, str | None] = {"solver": "ipopt", "variables_hash": None, "noise_chart": None, "robot_hash": None}
#: the key fields that earlier files lack and whose value there is unknown
_UNKNOWN_KEYS = ("variables_hash", "robot_hash")


def _options_hash(options: dict | None) -> str:
    text = json.dumps(jio.to_jsonable(options or {}), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def variables_hash(variables: str | TranscriptionOptions) -> str:
    """A short hash of the `TranscriptionOptions` that ``variables`` stands for, field by field."""
    return _options_hash(dataclasses.asdict(transcription_options(variables)))


def _robot_hash(name: str) -> str:
    from jtraj.robot import load as load_robot

    return load_robot(name).content_hash()


def _hessian_label(exact_hessian: bool, options) -> str:
    """The Hessian a group's solves use, for its runs' key: ``"exact"``, ``"limited-memory"``
    (the default of both solvers) or ``"bfgs"`` (jtraj's partitioned BFGS), from
    ``exact_hessian`` or the solver options that ask for one (Ipopt's
    ``hessian_approximation``, the backends' ``hessian``; any case, as the solvers take them)."""
    if exact_hessian:
        return "exact"
    names = {"exact": "exact", "limited-memory": "limited-memory", "lbfgs": "limited-memory", "bfgs": "bfgs"}
    for key in ("hessian_approximation", "hessian"):
        value = (options or {}).get(key)
        if isinstance(value, str) and value.lower() in names:
            return names[value.lower()]
    return "limited-memory"


def _numbers_as_taken(solver: str, options: dict | None) -> dict | None:
    """``options`` with a whole number given for a real option written as the real the solver
    takes (``mu_init=1`` as ``1.0``), so that the two spellings of one setting key the same
    runs: a study resumed with ``--ipopt mu_init=1.0`` solved again every run of ``=1``. Real
    options are those typed float (`jtraj.solvers.IpmOptions`, None allowed) or that Ipopt's
    catalog calls real."""
    if not options:
        return options
    if solver == "jtraj":
        import typing

        from jtraj.solvers.ipm import IpmOptions

        hints = typing.get_type_hints(IpmOptions)  # float, or float | None (mu_max's None: unset)
        real = {f.name for f in dataclasses.fields(IpmOptions) if hints.get(f.name) is float or float in typing.get_args(hints.get(f.name))}
    elif solver == "ipopt":
        from jtraj.solvers.ipopt_catalog import catalog

        real = {name for name, spec in catalog().items() if spec.kind == "real"}
    else:
        return options
    return {k: float(v) if k in real and is_whole(v) else v for k, v in options.items()}


def _group_key(task: Task, p: str, variables: str | TranscriptionOptions, exact_hessian: bool, options, seed: int, solver: str, noise_chart: str | None = None) -> dict:
    """The `RUN_KEY` fields that every run of one (task, parameterization) group shares; a
    group's noise drawn in its own chart has ``noise_chart`` None, as before it was recorded."""
    return dict(
        robot_hash=_robot_hash(task.robot),
        task_hash=task.content_hash(), parameterization=p, layout=variables_label(variables), variables_hash=variables_hash(variables),
        hessian=_hessian_label(exact_hessian, options), options_hash=_options_hash(_numbers_as_taken(solver, options)), seed=seed, solver=solver,
        noise_chart=None if noise_chart == p else noise_chart,
    )


def run_key(row: dict) -> tuple:
    """The identity of a robustness run, its values of `RUN_KEY`: (task content hash,
    parameterization, variables by name and by content hash, Hessian mode, solver-options hash,
    seed, sigma, replicate, solver, noise chart, robot content hash); a field an earlier file's
    row lacks takes the value it meant then (no solver: an Ipopt run; `_key_value`)."""
    return tuple(_key_value(row, k) for k in RUN_KEY)


def _key_value(row: dict, field: str) -> Any:
    """A run's value of the key field ``field``, or what an earlier file's row without it means
    (`_KEY_DEFAULTS`)."""
    return row.get(field, _KEY_DEFAULTS.get(field))


def select_runs(runs: list[dict], **fields: Any) -> list[dict]:
    """The runs whose value of each given field equals it (``select_runs(runs, seed=0,
    solver="jtraj")``), in their order: one setting's runs of a runs.jsonl that keeps other
    settings' too, for `table_iii` and `plot_iterations`. A field of `RUN_KEY` that an earlier
    file's row lacks has the value it meant then (no solver: ``"ipopt"``)."""
    unknown = sorted(set(fields) - set(RUN_KEY) - set(_RUN_FIELDS))
    if unknown:  # a misspelt field selected nothing
        raise ValueError(f"select_runs: {', '.join(unknown)}: not a field of a run; expected some of {', '.join(RUN_KEY + _RUN_FIELDS)}")
    return [r for r in runs if all(_key_value(r, k) == v for k, v in fields.items())]


#: the fields of a run that the tables read, beside those of its key
_RUN_FIELDS = ("task", "converged", "constraint_violation", "success", "iterations")


#: the JSON kind of each field of `RUN_KEY` and `_RUN_FIELDS`, as the sweeps write them: a key
#: field's value is hashed and compared (a list made `run_key` unhashable), a result field's
#: is compared and counted by the tables (a string violation crashed Table III); null where
#: the value can be unknown (the fields `_KEY_DEFAULTS` gives None, a NaN violation)
_FIELD_KINDS = {
    **{k: (lambda v: isinstance(v, str), "a string") for k in ("task_hash", "parameterization", "layout", "hessian", "options_hash", "solver", "task")},
    **{k: (lambda v: v is None or isinstance(v, str), "a string or null") for k in ("variables_hash", "noise_chart", "robot_hash")},
    "seed": (is_whole, "an integer"),
    "sigma": (is_real, "a number"),
    "replicate": (is_whole, "an integer"),
    "converged": (lambda v: isinstance(v, bool), "true or false"),
    "constraint_violation": (lambda v: v is None or is_real(v), "a number or null"),
    "success": (lambda v: isinstance(v, bool), "true or false"),
    "iterations": (is_whole, "an integer"),
}


def _json_kind(value) -> str:
    """The JSON kind of a parsed value, for a message."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    return {str: "a string", int: "an integer", float: "a number", list: "an array", dict: "an object"}.get(type(value), type(value).__name__)


def _not_a_run(record) -> str | None:
    """Why a parsed line of a runs file is not a run (None: it is one): not an object, a field of
    its key or of the tables missing (a field `_KEY_DEFAULTS` gives may be, in earlier files), or
    one of another kind than the sweeps write (`_FIELD_KINDS`)."""
    if not isinstance(record, dict):
        return f"a JSON {type(record).__name__}, not an object"
    missing = [k for k in (*RUN_KEY, *_RUN_FIELDS) if k not in record and k not in _KEY_DEFAULTS]
    if missing:
        return f"no {', '.join(map(repr, missing))}"
    wrong = [f"{k!r} is {_json_kind(record[k])} (expected {kind})" for k, (fits, kind) in _FIELD_KINDS.items() if k in record and not fits(record[k])]
    return ", ".join(wrong) or None


def check_runs_file(out: str | Path, resume: bool = True) -> None:
    """Raise `jtraj.io.FileFormatError` naming OUT/runs.jsonl where something there cannot be a
    runs file (a folder, a named pipe) or, with ``resume``, cannot be read: before a study
    writes or compiles anything (`robustness` checks it, and the command line can before it
    writes OUT/provenance.json). Without ``resume`` the file is moved aside, not read."""
    jio.check_file(Path(out) / RUNS_FILE, "a JSON-lines file of runs (or none, to start the study)", read=resume)


def _lines(numbers: list[int]) -> str:
    """Line numbers for a message: the first five, and how many more."""
    return f"{numbers[:5]}" + (f" and {len(numbers) - 5} more" if len(numbers) > 5 else "")


def _aside_name(path: Path, why: str) -> Path:
    """``path.why-N`` with the first N not taken."""
    n = 1
    while path.with_name(f"{path.name}.{why}-{n}").exists():
        n += 1
    return path.with_name(f"{path.name}.{why}-{n}")


def _move_aside(path: Path, why: str) -> Path:
    """Rename ``path`` to ``path.why-N`` with the first N not taken; returns the new name."""
    aside = _aside_name(path, why)
    os.replace(path, aside)
    return aside


def read_runs(path: str | Path, progress: TextIO | None = None, *, repair: bool = False) -> list[dict]:
    """Runs of a runs.jsonl file, first of each key kept. Lines that do not parse (a kill during
    a write, damage, or a line a running study is writing now) or are not runs (not a JSON
    object, or without a field of a run's key or one the tables read, or with one of another
    kind than the sweeps write: `_not_a_run`) are left out, with a warning on ``progress``
    (None: the ``sys.stderr`` of the call). The file is not changed: a study may be appending
    to it (a notebook reading `jtraj robustness`'s folder while it runs).

    ``repair`` (the sweeps', on the folder they hold, `jtraj.provenance.holding`): such a file
    is also copied aside to ``runs.jsonl.corrupt-N`` and replaced, atomically, by the lines
    that are runs (the runs of the others are solved again). A folder or a file that cannot be
    read there raises `jtraj.io.FileFormatError` naming it (a missing file holds no runs)."""
    path = Path(path)
    numbered, bad = jio.read_jsonl_lines(path)
    checked = [(line, r, _not_a_run(r)) for line, r in numbered]
    records = [r for _, r, why in checked if why is None]
    odd = [(line, why) for line, _, why in checked if why is not None]
    if bad or odd:
        found = [f"line(s) {_lines(bad)} did not parse"] if bad else []
        if odd:
            found.append(f"line(s) {_lines([line for line, _ in odd])} are not runs ({'; '.join(f'line {line}: {why}' for line, why in odd[:3])}{'; ...' if len(odd) > 3 else ''})")
        if repair:
            # copied, then replaced whole: a kill in between leaves the file as it was (moved
            # aside first, a kill before the rewrite left no runs file, and the next call
            # solved every run)
            aside = _aside_name(path, "corrupt")
            shutil.copy2(path, aside)
            jio.write_text(path, "".join(jio.dumps(r, indent=None) + "\n" for r in records))
            done = f"the file was copied to {aside} and its {len(records)} good runs kept"
        else:
            done = f"its {len(records)} good runs read, the file left as it is"
        print(f"warning: {path}: {' and '.join(found)}; {done}", file=progress or sys.stderr, flush=True)
    seen: dict[tuple, dict] = {}
    for r in records:
        seen.setdefault(run_key(r), r)
    return list(seen.values())


def _robustness_group(task, p, sigmas, replicates, seed, variables, exact_hessian, options, solver, noise_chart, done, runs_path, progress=None, expected=None) -> int:
    """One (task, parameterization) of the study (`_robustness_rows`), each run appended to
    ``runs_path`` as soon as it is solved (also from a worker process: a kill loses only the
    solves in flight). Returns the number solved."""
    solved = 0
    for row in _robustness_rows(task, p, sigmas, replicates, seed, variables, exact_hessian, options, solver, noise_chart, done, progress, expected):
        jio.append_jsonl(runs_path, row)
        solved += 1
    return solved


def _robustness_rows(task, p, sigmas, replicates, seed, variables, exact_hessian, options, solver, noise_chart, done, progress=None, expected=None) -> Iterator[dict]:
    """One (task, parameterization) of the study: one compile, then every noisy replicate whose
    key is not in ``done``, each run's row yielded as soon as it is solved (a progress line
    comes after its rows are taken). A backend with ``solve_batch`` (jtraj's interior point)
    solves each sigma's missing replicates in one batched call (one vmapped program on an
    accelerator, the one-problem program on every core of a CPU), with one compile per group;
    Ipopt solves them one by one. ``noise_chart`` as in `robustness`.

    ``expected``: the group's key (`_group_key`) as the calling process computed it, where this
    runs in another (a worker, a Ray node): `KeyMismatchError`, before any solve, where this
    process computes another. A Ray node with another MuJoCo compiles the robot to another model
    (`Robot.content_hash` hashes it), whose rows the calling process did not select: they were
    written to the runs file under the node's keys and left out of the table without a word,
    and every resume solved them again."""
    _code_source()  # read before the solves, as this process's code is (an edit during them is not)
    task = load_task(task)
    base = _group_key(task, p, variables, exact_hessian, options, seed, solver, noise_chart)
    if expected is not None and base != expected:
        differ = ", ".join(f"{k} {base.get(k)!r} here, {expected.get(k)!r} there" for k in sorted(set(base) | set(expected)) if base.get(k) != expected.get(k))
        raise KeyMismatchError(
            f"{task.name} {p}: this worker keys the group's runs otherwise than the process that called the sweep ({differ}): "
            "its jtraj, MuJoCo, or robot or task files differ from the caller's (a cluster's nodes need the caller's versions)"
        )
    todo = [(s, r) for s in sigmas for r in range(replicates) if run_key(base | {"sigma": float(s), "replicate": r}) not in done]
    if not todo:
        return
    prep = prepare(task, p, variables)
    # each sigma's missing replicates, drawn at once (a replicate's draw does not depend on
    # which others are drawn with it: `noise_key`)
    levels, numbers = list(dict.fromkeys(s for s, _ in todo)), sorted({r for _, r in todo})
    draws = chart_noisy_warm_starts(prep.transcription, base["noise_chart"], levels, numbers, seed)  # one other-chart transcription per group
    starts: dict[float, dict[int, np.ndarray]] = {s: {} for s in levels}
    for sigma, r in todo:
        starts[sigma][r] = draws[levels.index(sigma), numbers.index(r)]
    if hasattr(solvers.get(solver), "solve_batch"):
        for sigma, members in starts.items():
            yield from _robustness_batch(prep, sigma, list(members), np.stack(list(members.values())), replicates, exact_hessian, options, solver, base, progress)
        return
    for sigma, r in todo:
        start = starts[sigma][r]
        res = solve(task, p, variables=variables, solver=solver, warm_start=start, exact_hessian=exact_hessian, ipopt_options=dict(options or {}), progress=None, keep_trajectory=False)
        row = base | {"sigma": float(sigma), "replicate": r} | _row(res) | {"batch": 1}
        yield row
        if progress is not None:
            print(_run_line(row), file=progress, flush=True)


def _run_line(row: dict) -> str:
    """A run's progress line, from its row."""
    return f"{row['task']:10s} {row['parameterization']:6s} sigma={row['sigma']:<7g} #{row['replicate']}: {row['status']:26s} {row['iterations']:4d} it  {row['time_s']:6.1f} s{_why(row)}"


def _robustness_batch(prep, sigma: float, reps: list[int], starts: np.ndarray, replicates: int, exact_hessian: bool, options, solver: str, base: dict, progress) -> Iterator[dict]:
    """Replicates ``reps`` of one sigma, from the warm starts ``starts``, in one call of ``solver``'s ``solve_batch``, compiled
    for ``replicates`` members (a resumed group's shorter batch is padded, so every sigma and
    every resume reuses one program); yields their rows. Each replicate's row has the fields of a one-by-one
    solve's (through `jtraj.solver.evaluate`, as `solve` makes them); its ``time_s`` is the
    batched call's wall time over the replicates, ``batch`` the number solved in that call.
    (On a CPU the batch runs the one-problem program, so a row is the one `jtraj.solve` with
    ``replicate=`` gives; on an accelerator the vmapped program's rounding differs, and a row
    can differ from it: `JtrajSolver.solve_batch`.)"""
    tr, nlp = prep.transcription, prep.nlp
    backend = solvers.get(solver)
    theta = tr.resolve_theta(None)
    opts = solver_options(backend, None, options, exact_hessian, tr.task.max_iter)
    solutions, total, compile_time = backend.solve_batch(nlp, starts, theta, opts, batch_size=replicates)  # type: ignore[attr-defined]
    compile_time += prep.time_compile
    prep.time_compile = 0.0  # counted once per process, as `solve` does
    settings = {"solver": backend.name, **opts.as_dict(), "layout": dataclasses.asdict(tr.options)}
    rows = []
    for r, sol in zip(reps, solutions):
        res = evaluate(tr, sol, tr.decode(sol.x, theta), compile_time, settings, nlp.nnz_jac, nlp.violation_by_group(sol.x, theta), theta, backend.name)
        compile_time = 0.0  # the first row carries the compile
        res.trajectory = None
        rows.append(base | {"sigma": float(sigma), "replicate": r} | _row(res) | {"batch": len(reps)})
        yield rows[-1]
    if progress is not None:
        # Table III's converged (`_converged`: feasible too), not the solver's own success,
        # which counted a run converged to a violation over FEASIBILITY_TOL
        converged = sum(_converged(row) for row in rows)
        iterations = np.mean([row["iterations"] for row in rows])
        print(f"{tr.task.name:10s} {base['parameterization']:6s} sigma={sigma:<7g} {solver}: {converged}/{len(reps)} converged, {iterations:5.1f} it mean, {total:6.2f} s for the batch of {len(reps)}", file=progress, flush=True)


def _robustness_group_in_worker(*args) -> int:
    """`_robustness_group` in a local worker process, appending to the shared runs file; the
    last argument says whether to print (a stream does not cross processes: a worker prints to
    its own stdout)."""
    *args, expected, verbose = args
    return _robustness_group(*args, progress=sys.stdout if verbose else None, expected=expected)


def robustness(
    tasks: Sequence[str | Task] = ROBUSTNESS_TASKS,
    params: Sequence[str | AbstractParameterization] = ROBUSTNESS_PARAMS,
    sigmas: Sequence[float] = SIGMAS,
    replicates: int = 10,
    seed: int = 0,
    out: str | Path = "runs/robustness",
    variables: str | TranscriptionOptions = "paper",
    exact_hessian: bool = False,
    progress: TextIO | bool | None = True,
    workers: int = 1,
    resume: bool = True,
    ipopt_options: dict | None = None,
    executor: str = "local",
    ray_address: str | None = None,
    layout: str | None = None,
    solver: str = "ipopt",
    noise_chart: str | None = None,
    record_run: bool = True,
    ray_gpus: float | None = None,
) -> list[dict]:
    """Table III and Fig. 2: converged and task-success rates and iterations under warm-start noise.

    Every finished solve is appended at once to ``out/runs.jsonl``, one JSON line keyed by
    `run_key` (task content, robot content (`robot_hash`), parameterization, variables per knot by name and by content
    (`variables_hash`), Hessian mode, solver options, seed, sigma, replicate, solver). With ``resume`` (default) runs already there are not solved again, so a study
    stopped or killed at any point goes on where it ended; runs of other settings in the file
    are kept and left out of this call's tables. Without ``resume`` the file is moved to
    ``runs.jsonl.previous-N`` (the first N not taken, so earlier ones are kept) and this call's runs start a new one. The noise of replicate r at
    level sigma depends only on (seed, sigma, r) (`noise_key`).

    ``workers > 1`` solves (task, parameterization) groups in that many processes, each
    appending to the same file and printing its progress lines to its own standard output (a
    stream does not cross processes: ``progress`` there only says whether they print); with one
    group it is solved here, printing to ``progress``. ``executor="ray"`` makes each group a Ray task on the cluster
    at ``ray_address`` (`jtraj.executors`; ``ray_address`` and ``ray_gpus``, the GPUs each
    task reserves, are for it only, ``workers`` > 1 for the local executor only: each is
    refused with the other; without ``ray_gpus`` a task sees no GPU); each run's row comes back as it
    is solved (a streaming task) and is appended here, under the same keys and resume rules,
    and its progress line printed here. A group that raises, or an interrupt, stops the groups
    running and queued (`jtraj.executors`); the runs they finished stay in the file (of a Ray
    group: those whose rows had come back). Returns this call's runs; writes
    table_iii.{json,md} and fig2.png (an earlier call's are removed before the first solve;
    the tables are written again after each group when the groups run here, one after
    another). ``progress`` as in `compare`; ``layout`` is the
    deprecated former name of ``variables``. ``params`` are names of `PARAMETERIZATIONS` (or
    the parameterization objects of those names: runs are keyed by the name).

    ``solver`` (`jtraj.solvers.SOLVERS`, a name or such a solver or its class: runs are keyed
    by its name): ``"ipopt"`` solves the replicates one by one;
    ``"jtraj"`` solves each (task, parameterization, sigma) group's replicates in one batched
    call of its interior point (`JtrajSolver.solve_batch`: vmapped on an accelerator, member by
    member on every core of a CPU; one compiled program per task and parameterization, compiled
    before the clock starts; a row's ``time_s`` is the call's time over its replicates, and
    ``batch`` says how many it solved). ``ipopt_options`` are the solver's options (Ipopt's
    names for Ipopt, `jtraj.solvers.IpmOptions` fields for jtraj).

    ``noise_chart`` (a parameterization's name; default None: each chart's own) draws the noise
    in that chart's coordinates and gives every parameterization the same noisy poses
    (`chart_noisy_warm_starts`): the study adds sigma to each chart's own coordinates, which
    turns a quaternion's base further than SE(3)'s or Euler's. Runs record it in their key.

    ``record_run`` (default True) writes ``out/provenance.json`` (`jtraj.provenance`:
    unfinished until the tables and figure are written; an earlier record is kept under
    ``earlier``); the command line, which writes its own, passes False.
    """
    variables = renamed_argument(variables, layout, "variables", "layout", "paper")
    sigmas = [float(s) for s in sigmas]
    for s in sigmas:
        if not (math.isfinite(s) and s >= 0):
            raise ValueError(f"robustness: sigma={s!r}: expected noise levels (standard deviations) >= 0")
    if not is_seed(seed):
        raise ValueError(f"robustness: seed={seed!r}: expected a 64-bit integer (below 2**63 in magnitude)")
    # 2.5 passed, cleared the folder's tables and failed at the first draw
    if not is_whole(replicates) or replicates < 1:
        raise ValueError(f"robustness: replicates={replicates!r}: expected an integer >= 1")
    replicates = int(replicates)
    # names, as rows record them and runs are keyed: a solver or parameterization object in
    # the key matched no row, so nothing resumed (and the call returned none of its runs)
    params = _parameterization_names("robustness", params)
    solver = _solver_name("robustness", solver)  # an unknown name fails here, before the first solve
    loaded = [load_task(t) for t in tasks]
    _refuse_repeats("robustness: tasks", tasks, [t.name for t in loaded], "task")
    tasks = loaded
    _refuse_repeats("robustness: params", params, params, "parameterization")
    _refuse_repeats("robustness: sigmas", sigmas, sigmas, "noise level")
    check_executor(executor, workers, ray_address, "robustness", ray_gpus=ray_gpus)  # before anything is written
    _connect_first(executor, ray_address, ray_gpus)
    progress = _progress_stream(progress)
    out = Path(out)
    check_runs_file(out, resume)
    # held from here (`jtraj.provenance.holding`): another process's run in OUT is refused
    # before this one reads, moves aside or appends to its runs. `holding` makes the folder, and
    # removes it again where the study fails before writing (an mkdir here left an empty OUT
    # behind an error such as empty sigmas)
    with holding(out):
        runs_path = out / RUNS_FILE
        if not tasks or not params or not sigmas:
            raise ValueError("robustness: no runs (empty tasks, parameterizations or sigmas)")
        if noise_chart is not None and progress is not None:
            print(f"checking that the {noise_chart} chart's noisy poses can be written in the other charts", file=progress, flush=True)
        check_noise_chart(tasks, params, variables, noise_chart)
        before = read_runs(runs_path, progress, repair=True) if resume else []
        if not resume and runs_path.exists():
            aside = _move_aside(runs_path, "previous")
            if progress is not None:
                print(f"not resuming: the earlier runs of {runs_path} are kept in {aside}", file=progress, flush=True)
        done = {run_key(r) for r in before}
        args = [(t, p, tuple(sigmas), replicates, seed, variables, exact_hessian, ipopt_options, solver, noise_chart, done, runs_path) for t in tasks for p in params]
        # each group's key as this process computes it: a worker refuses to key its runs otherwise
        bases = [_group_key(*a[:2], variables, exact_hessian, ipopt_options, seed, solver, noise_chart) for a in args]
        if progress is not None and before:
            wanted = {run_key(base | {"sigma": s, "replicate": r}) for base in bases for s in sigmas for r in range(replicates)}
            known = [r for r in before if all(k in r for k in _UNKNOWN_KEYS)]
            unknown = len(before) - len(known)
            settings = {_settings_key(base) for base in bases}
            others = sum(1 for r in known if _settings_key(r) not in settings)
            # (runs of this call's settings at noise levels or replicates it does not ask for were
            # counted as runs of other settings)
            elsewhere = sum(1 for r in known if _settings_key(r) in settings and run_key(r) not in wanted)
            if unknown:
                print(f"note: {unknown} runs in {runs_path} were written without the content of their variables or robot (before jtraj recorded it) and are not resumed", file=progress, flush=True)
            if known:
                kept = [f"{others} runs of other settings"] if others else []
                kept += [f"{elsewhere} runs of these settings at other noise levels or replicates"] if elsewhere else []
                kept_text = f"; its {' and '.join(kept)} are kept" if kept else ""
                print(f"resuming: {len(wanted & done)} of this call's {len(wanted)} runs already in {runs_path}{kept_text}", file=progress, flush=True)
                if note := _other_code_note([r for r in known if run_key(r) in wanted]):
                    print(note, file=progress, flush=True)
                if not wanted & done and (differ := _settings_differ(known, bases)):
                    # a forgotten --seed or --ipopt solved the whole study again without a word
                    print(f"note: none of them is this call's: the file's runs of these tasks and parameterizations differ in {differ}", file=progress, flush=True)
        # an earlier call's tables and figure, perhaps of other settings: this call's are written
        # at its checkpoints and its end (the figure at the end only, and with workers or Ray the
        # tables too), and an interrupt before them left the earlier ones in OUT as if this call's
        _clear_outputs("robustness", out, ROBUSTNESS_OUTPUTS)
        run = _begin_call(
            out, "robustness", record_run,
            _call_settings(tasks, params, variables, exact_hessian, solver, sigmas=list(sigmas), replicates=replicates, seed=seed, ipopt_options=ipopt_options or {},
                           noise_chart=noise_chart, resume=resume, executor=executor, workers=workers, ray_address=ray_address, ray_gpus=ray_gpus),
        )
        # one group is solved here (the local executor would run it in this process, whose
        # stdout took its lines in place of the given stream)
        if executor == "local" and (workers <= 1 or len(args) <= 1):
            for k, a in enumerate(args):
                _robustness_group(*a, progress=progress)
                # a checkpoint: the table of every group so far, should the study stop here
                runs = read_runs(runs_path, progress, repair=True)
                _write_robustness_outputs([r for b in args[: k + 1] for r in _select(runs, *b[:10])], sigmas, out, figure=False)
        else:
            try:
                if executor == "local":
                    groups = executor_for("local", workers).map(_robustness_group_in_worker, [(*a, base, progress is not None) for a, base in zip(args, bases)])
                    with contextlib.closing(groups):
                        for _ in groups:
                            pass
                else:
                    # each row as it is solved on the cluster (a streaming task, on a machine that
                    # may not see the study's folder; it prints nothing, this process does): an
                    # interrupt or a failing group keeps the runs that came back (they came only at
                    # a group's end, and were lost with it)
                    rows = executor_for(executor, workers, ray_address, ray_gpus).stream(_robustness_rows, [(*a[:-1], None, base) for a, base in zip(args, bases)])
                    with contextlib.closing(rows):
                        for _, row in rows:
                            jio.append_jsonl(runs_path, row)
                            if progress is not None:
                                print(_run_line(row), file=progress, flush=True)
            except WorkerLostError as e:
                # without resume this call moved the earlier file aside: the same call again would too
                again = "the same call again resumes from them" if resume else "the same call with resume=True (jtraj robustness without --no-resume) resumes from them"
                raise WorkerLostError(f"{e}; the runs finished before it are kept in {runs_path}, and {again}") from e.__cause__
        runs = [r for a in args for r in _select(read_runs(runs_path, progress, repair=True), *a[:10])]
        _write_robustness_outputs(runs, sigmas, out)
        if run is not None:
            end_run(out, run)
    return runs


#: the files a call of `compare` / `robustness` writes into its folder beside the runs (an
#: earlier call's are removed as it starts; the command line checks them before it writes OUT)
COMPARE_OUTPUTS = ("table_iv.json", "table_iv.md", "comparison.png")
ROBUSTNESS_OUTPUTS = ("table_iii.json", "table_iii.md", "fig2.png")


def _clear_outputs(who: str, out: Path, names: tuple[str, ...]) -> None:
    """Remove an earlier call's output files ``names`` from ``out``; a folder in the place of
    one is refused (`ValueError`) before anything is solved (writing the file failed after
    the solves)."""
    for name in names:
        if (out / name).is_dir():
            raise ValueError(f"{who}: {out / name} is a folder; expected room for the file {name}")
    for name in names:
        (out / name).unlink(missing_ok=True)


#: the settings a run's key holds beside its task, parameterization, sigma and replicate, as
#: the resume note names them when none of a file's runs is of a call's settings
_SETTING_NAMES = {
    "layout": "variables (--variables, --set)", "variables_hash": "variables (--variables, --set)", "hessian": "Hessian (--ipopt hessian_approximation or hessian)",
    "options_hash": "solver options (--ipopt)", "seed": "seed (--seed)", "solver": "solver (--solver)",
    "noise_chart": "noise chart (--noise-chart)", "robot_hash": "robot model (--robot)",
}


def _settings_key(row: dict) -> tuple:
    """A run's key without its sigma and replicate: the settings of its group."""
    return tuple(_key_value(row, k) for k in RUN_KEY if k not in ("sigma", "replicate"))


def _settings_differ(runs: list[dict], bases: list[dict]) -> str:
    """The settings (`_SETTING_NAMES`) in which ``runs`` of the same task and parameterization
    as one of ``bases`` differ from it, as text ("" if no run is of those)."""
    names: dict[str, None] = {}
    for base in bases:
        for r in runs:
            if (r["task_hash"], r["parameterization"]) == (base["task_hash"], base["parameterization"]):
                for k, name in _SETTING_NAMES.items():
                    if _key_value(r, k) != _key_value(base, k):
                        names[name] = None
    return ", ".join(names)


def _select(runs: list[dict], task: Task, p: str, sigmas, replicates: int, seed: int, variables: str | TranscriptionOptions, exact_hessian: bool, options, solver: str, noise_chart: str | None = None) -> list[dict]:
    """The runs of one group of this call's settings, in (sigma, replicate) order."""
    base = _group_key(task, p, variables, exact_hessian, options, seed, solver, noise_chart)
    keys = {run_key(base | {"sigma": float(s), "replicate": r}): (i, r) for i, s in enumerate(sigmas) for r in range(replicates)}
    sel = [(keys[run_key(r)], r) for r in runs if run_key(r) in keys]
    return [r for _, r in sorted(sel, key=lambda x: x[0])]


def _write_robustness_outputs(runs: list[dict], sigmas: Sequence[float], out: Path, figure: bool = True) -> None:
    summary = summarize_robustness(runs)
    jio.write_json(out / "table_iii.json", summary)
    jio.write_text(out / "table_iii.md", _table_iii_markdown(summary, sigmas))
    if figure and runs:
        plot_iterations(runs, out / "fig2.png")


def _converged(run: dict) -> bool:
    # the paper's Table III success: the solver converged to a feasible point
    violation = run.get("constraint_violation")
    return bool(run["converged"]) and violation is not None and violation < FEASIBILITY_TOL


def _setting(run: dict) -> tuple[str, str | None]:
    """The settings that runs of one cell can share a runs.jsonl with: (solver, noise chart)."""
    return run.get("solver", "ipopt"), run.get("noise_chart")


def setting_label(row: dict, rows: Sequence[dict] = (), name: str | None = None) -> str:
    """A row's parameterization (or ``name``), followed by its solver and noise chart where
    ``rows`` hold more than one of them (``quat1 (jtraj, noise in se3)``)."""
    name = row["parameterization"] if name is None else name
    settings = {_setting(r) for r in rows}
    if len(settings) <= 1:
        return name
    solver, chart = _setting(row)
    parts = [solver] if len({s for s, _ in settings}) > 1 else []
    if len({c for _, c in settings}) > 1:
        parts.append(f"noise in {chart or 'own chart'}")
    return f"{name} ({', '.join(parts)})"


def summarize_robustness(runs: list[dict]) -> list[dict]:
    """Per (task, parameterization, sigma), and solver and noise chart where a runs file holds
    several: the rate of runs that converged to a feasible point (the solver's success and
    largest constraint violation below `jtraj.success.FEASIBILITY_TOL`, the paper's Table III
    success), the rate that moreover did the task (`jtraj.success`: e.g. a flip with the right
    sign, count and axis), and iterations of the converged runs. The runs of a cell must share
    their other settings (`_CELL_SETTINGS`; a ValueError otherwise)."""
    # the paper's order: tasks as in Table III, parameterizations as in Table I, then others
    task_rank = {t: i for i, t in enumerate(("walk", "big_jump", "backflip", "sideflip", "hopscotch", "handstand"))}
    param_rank = {p: i for i, p in enumerate(PARAMETERIZATIONS)}
    keys = sorted(
        {(r["task"], r["parameterization"], *_setting(r), r["sigma"]) for r in runs},
        key=lambda k: (task_rank.get(k[0], len(task_rank)), k[0], param_rank.get(k[1], len(param_rank)), k[1], k[2], k[3] or "", k[4]),
    )
    rows = []
    for task, p, solver, chart, sigma in keys:
        sel = [r for r in runs if (r["task"], r["parameterization"], *_setting(r), r["sigma"]) == (task, p, solver, chart, sigma)]
        _refuse_mixed_settings(sel, task, p, sigma)
        conv = [r for r in sel if _converged(r)]
        its = np.array([r["iterations"] for r in conv]) if conv else np.array([])
        rows.append(
            dict(
                task=task,
                parameterization=p,
                sigma=sigma,
                solver=solver,
                noise_chart=chart,
                runs=len(sel),
                converged_rate=len(conv) / len(sel),
                task_success_rate=sum(1 for r in conv if r["success"]) / len(sel),
                converged_without_task=sum(1 for r in conv if not r["success"]),
                iterations_median=float(np.median(its)) if its.size else None,
                iterations_p25=float(np.percentile(its, 25)) if its.size else None,
                iterations_p75=float(np.percentile(its, 75)) if its.size else None,
            )
        )
    return rows


#: the settings of a run that Table III's cells do not tell apart (its rows show the solver and
#: the noise chart): a cell's runs must share them
_CELL_SETTINGS = ("task_hash", "robot_hash", "layout", "variables_hash", "hessian", "options_hash", "seed")


def _refuse_mixed_settings(runs: list[dict], task: str, p: str, sigma: float) -> None:
    """ValueError where the runs of one Table III cell come from different settings (another
    task file, robot, variables, Hessian, solver options or seed: a runs.jsonl keeps the runs of
    earlier settings beside a study's, `robustness`): counted together, the cell's rates had a
    mixed denominator. A field an earlier file did not record (null) matches any value, so a
    replicate that appears twice in the cell is refused too: a study resumed in the folder of
    runs written before jtraj recorded those fields solves them again beside them, and the
    cell counted both."""
    counts = collections.Counter(r["replicate"] for r in runs if "replicate" in r)
    if twice := sorted(k for k, n in counts.items() if n > 1):
        raise ValueError(
            f"Table III: the runs of {task} / {p} at sigma {sigma:g} hold replicate(s) {twice[:6]}{' ...' if len(twice) > 6 else ''} more than once "
            "(runs of two settings, e.g. earlier ones written before jtraj recorded variables_hash and robot_hash); expected one setting's runs per cell: "
            "select them first (e.g. select_runs(runs, variables_hash=...); jtraj robustness writes each call's own table)"
        )
    for field in _CELL_SETTINGS:
        values = sorted({str(v) for r in runs if (v := _key_value(r, field)) is not None})
        if len(values) > 1:
            last = next(v for r in reversed(runs) if (v := _key_value(r, field)) is not None)
            raise ValueError(
                f"Table III: the runs of {task} / {p} at sigma {sigma:g} differ in {field} ({', '.join(values[:4])}{', ...' if len(values) > 4 else ''}); "
                f"expected one setting's runs per cell: select them first (e.g. select_runs(runs, {field}={last!r}), "
                "the setting of the last run; jtraj robustness writes each call's own table)"
            )


def table_iii(runs: list[dict], iterations: bool = False) -> str:
    """Table III of ``runs`` (a runs.jsonl's rows, `read_runs`) in Markdown, as ``jtraj
    robustness`` writes it to ``table_iii.md``: a row per task and setting (parameterization,
    and solver or noise chart where the runs hold several), a column per noise level, each cell
    converged / task done in % of the runs. ``iterations`` adds to each cell the median
    iterations of its converged runs ("-": none converged)."""
    summary = summarize_robustness(runs)
    return _table_iii_markdown(summary, sorted({r["sigma"] for r in summary}), iterations)


def _percent(rate: float) -> str:
    """A rate as Table III prints it: whole percent, but never 0 % or 100 % for a rate that is
    not (399 of 400 read "100%", hiding the one run that failed, or the one jump counted as a
    flip, that the cell's two rates are there to show)."""
    text = f"{100 * rate:.0f}%"
    if text == "100%" and rate < 1:
        return ">99%"
    if text == "0%" and rate > 0:
        return "<1%"
    return text


def _table_iii_markdown(summary: list[dict], sigmas: Sequence[float], iterations: bool = False) -> str:
    """Table III of ``summary`` (`summarize_robustness`) at the noise levels ``sigmas``; its
    heading names the solvers and noise charts of the summary's rows (the one place
    `table_iii` and ``jtraj robustness``'s table_iii.md work them out)."""
    solver_names = sorted({r["solver"] for r in summary})
    noise_charts = sorted({r["noise_chart"] for r in summary if r["noise_chart"]})
    noise = ""
    if noise_charts:
        labels = " and ".join(PARAMETERIZATIONS[c].label for c in noise_charts)
        noise = f" The noise was drawn in the coordinates of {labels} and each run started from those noisy poses written in its own chart."
    lines = [
        f"Each cell: converged / task done, in % of the runs (converged: success of the solver ({', '.join(solver_names)}) with the largest "
        f"constraint violation below {FEASIBILITY_TOL:g}, the paper's success; task done: converged and "
        "the motion does the task, e.g. a flip with the expected sign, count and axis; where the two "
        "differ the paper marks the cell with *)." + noise
        + (" In parentheses: the median iterations of the converged runs (-: none converged)." if iterations else ""),
    ]

    def cell(r: dict) -> str:
        rates = f"{_percent(r['converged_rate'])} / {_percent(r['task_success_rate'])}"
        if not iterations:
            return rates
        return rates + (" (-)" if r["iterations_median"] is None else f" ({r['iterations_median']:g})")  # (:.0f made 16.5 "16" and 49.5 "50")

    rows = []
    for group in dict.fromkeys((r["task"], r["parameterization"], _setting(r)) for r in summary):
        by_sigma = {r["sigma"]: r for r in summary if (r["task"], r["parameterization"], _setting(r)) == group}
        cells = [cell(r) if (r := by_sigma.get(s)) else "" for s in sigmas]
        rows.append((group[0], setting_label(next(iter(by_sigma.values())), summary), *cells))
    return "\n".join(lines) + "\n\n" + markdown_table(("task", "parameterization", *(f"sigma={s:g}" for s in sigmas)), rows)


def plot_iterations(runs: list[dict], path: str | Path) -> None:
    """Fig. 2: iterations to convergence against noise (median, 25-75th percentiles of the
    converged runs, Table III's: the paper's caption says "median over 10 replicates" of the
    iterations to convergence), a panel per task. Where fewer than all of a point's runs
    converged, the point is labelled with how many did ("3/10"): a median of few runs is not
    one of ten. A setting's line and band break at a noise level where none of its runs converged
    (drawn across, they would show data there); a setting with no converged run in a panel is
    named in it ("Quaternion #1: no converged run", in its colour), and the figure's one legend
    lists every setting, so that a failure is seen rather than left out."""
    import matplotlib
    from matplotlib.lines import Line2D

    from jtraj.plots import _figure  # built without pyplot: a notebook's backend and figures are left alone

    summary = summarize_robustness(runs)
    tasks = list(dict.fromkeys(r["task"] for r in summary))
    # one colour and marker per setting in every panel (a setting with no converged run in one
    # panel must not shift the others' colours there), and one legend for the figure
    settings = list(dict.fromkeys((r["parameterization"], _setting(r)) for r in summary))
    cycle = matplotlib.rcParams["axes.prop_cycle"].by_key()["color"]
    markers = "osD^vP*X"
    style = {key: dict(color=cycle[i % len(cycle)], marker=markers[i % len(markers)]) for i, key in enumerate(settings)}
    labels: dict[tuple, str] = {}
    for r in summary:
        p = r["parameterization"]
        labels.setdefault((p, _setting(r)), setting_label(r, summary, PARAMETERIZATIONS[p].label if p in PARAMETERIZATIONS else p))
    positive = [r["sigma"] for r in summary if r["sigma"] > 0]
    fig = _figure(figsize=(4 * len(tasks), 3.4))
    axes = fig.subplots(1, len(tasks), squeeze=False)

    def column(rows: list[dict], key: str) -> np.ndarray:
        return np.array([np.nan if r[key] is None else r[key] for r in rows], dtype=float)

    for ax, task in zip(axes[0], tasks):
        failed = []
        for key in settings:
            rows = [r for r in summary if r["task"] == task and (r["parameterization"], _setting(r)) == key]
            if not rows:
                continue
            if all(r["iterations_median"] is None for r in rows):
                failed.append(key)
                continue
            s = np.array([r["sigma"] for r in rows], dtype=float)
            medians = column(rows, "iterations_median")
            ax.plot(s, medians, label=labels[key], **style[key])
            ax.fill_between(s, column(rows, "iterations_p25"), column(rows, "iterations_p75"), alpha=0.2, color=style[key]["color"])
            for r, x, y in zip(rows, s, medians):
                converged = round(r["converged_rate"] * r["runs"])
                if converged < r["runs"] and np.isfinite(y):  # the point is a median of fewer runs
                    ax.annotate(f"{converged}/{r['runs']}", (x, y), textcoords="offset points", xytext=(4, 4), fontsize=7, color=style[key]["color"])
        if len(positive) < len(summary):  # sigma 0 (no noise) has no place on a log axis
            ax.set_xscale("symlog", linthresh=min(positive, default=1.0))
        else:
            ax.set_xscale("log")
        # every noise level of the panel on its axis: autoscaled from the converged medians alone,
        # it ended before a largest sigma where no setting converged, which vanished from the figure
        xs = np.array(sorted({r["sigma"] for r in summary if r["task"] == task}), dtype=float)
        drawn = ax.has_data()
        ax.update_datalim(np.column_stack([xs, np.zeros_like(xs)]), updatey=False)
        ax.autoscale_view()
        if not drawn:  # (no converged run in the panel: matplotlib's empty axis, not one around 0)
            ax.set_ylim(0.0, 1.0)
        ax.set_title(task)
        ax.set_xlabel("warm-start noise sigma")
        ax.set_ylabel("iterations to convergence\n(converged runs)")
        for i, key in enumerate(failed):
            ax.text(0.03, 0.97 - 0.08 * i, f"{labels[key]}: no converged run", transform=ax.transAxes, ha="left", va="top", fontsize=8, color=style[key]["color"])
    handles = [Line2D([], [], label=labels[key], **style[key]) for key in settings]
    if handles:
        axes[0][0].legend(handles=handles, fontsize=8)
    fig.tight_layout()
    jio.save_figure(fig, path, dpi=120)
