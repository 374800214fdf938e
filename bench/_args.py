"""Command-line arguments that several benchmarks define the same way, defined once here.

bench/ is not a package: a script imports this module after putting its own folder on
``sys.path`` (as ``bench/trace_iterates.py`` imports ``side_by_side``), which also works when
the tests load the script from its file. jtraj is imported inside the functions: some scripts
set XLA's flags before their first import of jtraj.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

#: the runner of the paper's public code, which runs one task and prints one JSON line (outside
#: this repository: a checkout has it beside its own folder, under shared/peers/)
DEFAULT_PEER = Path(__file__).resolve().parents[1].parent / "shared" / "peers" / "run-se3-trajopt"


def add_tasks(ap: argparse.ArgumentParser, default: Sequence[str] | None = None) -> None:
    """Positional ``tasks``: built-in tasks or task files, each checked as it is parsed
    (`jtraj.task.task_argument`), and each given once (`_EachTaskOnce`); ``default`` when none
    is given (None: an empty list)."""
    from jtraj.task import task_argument

    if default is None:
        ap.add_argument("tasks", nargs="*", type=task_argument, action=_EachTaskOnce)
    else:
        ap.add_argument("tasks", nargs="*", type=task_argument, action=_EachTaskOnce, default=list(default))


class _EachTaskOnce(argparse.Action):
    """The ``tasks`` of `add_tasks`, refused (argparse's one-line error) where one is given
    twice (``walk walk``, or a task file under two names): a benchmark would solve it twice
    and table it twice, or (bench/revisions.py) pair the wrong records."""

    def __call__(self, parser, namespace, values, option_string=None):
        tasks = list(values or [])
        refuse_repeats(parser, "tasks", tasks, "task", keys=[Path(t).resolve() if t.endswith(".toml") else t for t in tasks])
        setattr(namespace, self.dest, values)


def refuse_repeats(ap: argparse.ArgumentParser, field: str, names: Sequence[str], what: str, keys: Sequence | None = None) -> None:
    """argparse's one-line error where a name of ``names`` (a comma-separated option's items,
    or positional tasks) is given twice, or two have one of ``keys`` (default: the names
    themselves): the benchmark would solve and table it twice."""
    from jtraj.experiments import RepeatedValueError, _refuse_repeats

    try:
        _refuse_repeats(field, names, names if keys is None else keys, what)
    except RepeatedValueError as e:
        ap.error(str(e))


def add_param(ap: argparse.ArgumentParser, default: str = "se3") -> None:
    """``--param``: one of jtraj's floating-base parameterizations."""
    from jtraj.parameterization import PARAMETERIZATIONS

    ap.add_argument("--param", default=default, choices=list(PARAMETERIZATIONS))


def add_variables(ap: argparse.ArgumentParser, default: str, help: str | None = None) -> None:
    """``--variables``: one of `jtraj.solver.VARIABLES`."""
    from jtraj.solver import VARIABLES

    ap.add_argument("--variables", default=default, choices=list(VARIABLES), help=help)


def add_out(ap: argparse.ArgumentParser, name: str, default: str | None = None) -> None:
    """``--out DIR``: where `jtraj.provenance.write_results` writes ``NAME.json``, ``NAME.md``
    and ``provenance.json``; a folder that cannot be written (a file, no permission) is
    argparse's one-line error as the command line is parsed, not a traceback after the work.
    ``default``: the folder without ``--out`` (None: nothing is written)."""
    where = f" (default {default})" if default is not None else ""
    ap.add_argument("--out", type=out_folder, default=default, metavar="DIR", help=f"write DIR/{name}.json, DIR/{name}.md, DIR/provenance.json{where}")


def results_record(script: str, argv: Sequence[str] | None, complete: bool) -> dict:
    """The ``provenance.json`` record of a benchmark that rewrites its results folder after each
    task (`jtraj.provenance.write_results`'s ``record``): the command ``python SCRIPT ARGS``
    (``argv``, default this process's arguments) and ``"complete"``, false while tasks remain
    (a folder left by a run stopped part-way is not taken for a finished one's), true after
    the last."""
    from jtraj.provenance import provenance

    return {**provenance(["python", script, *(sys.argv[1:] if argv is None else argv)]), "complete": complete}


def out_folder(text: str) -> str:
    """argparse ``type=`` of an output folder: ``text`` itself where `jtraj.cli._check_out`
    accepts it (a folder, existing or to be created, that this user can write in)."""
    from jtraj.cli import InputError, _check_out

    try:
        _check_out(text)
    except InputError as e:
        raise argparse.ArgumentTypeError(f"{e.value!r}: {e.expected}") from None
    return text


def add_peer_options(ap: argparse.ArgumentParser, peer_python, peer_src_default: str) -> None:
    """The options of the scripts that run the paper's public code beside jtraj (side_by_side,
    trace_iterates): ``--robot ROBOT=OTHER`` and ``--set FIELD=VALUE`` (repeatable), and where
    the public code's sources and its environment's Python are (``--peer-src`` None unless
    given: the script takes the sources beside the runner, ``peer_src_default`` says which in
    the help; ``--peer-python`` default ``peer_python``)."""
    ap.add_argument("--peer-src", type=Path, default=None, help=f"the public code's sources (noisy flips run them through a driver that reads the last iterate; default: {peer_src_default})")
    ap.add_argument("--peer-python", type=Path, default=peer_python, help="the Python of the environment the runner creates")
    ap.add_argument("--robot", action="append", default=[], metavar="ROBOT=OTHER", help="jtraj solves tasks on ROBOT with the model OTHER (e.g. talos=talos_full: the study's Talos)")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="FIELD=VALUE",
        help="replace a string field of the variables' TranscriptionOptions, e.g. force_limits=rows (repeatable)",
    )
