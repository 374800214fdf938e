"""Where a table came from: the command, the date, the machine and the software versions.

`jtraj compare` and `jtraj robustness` write ``provenance.json`` beside their tables, and
`jtraj.solve` (``jtraj solve``) in its ``out`` folder, so that a number quoted from ``results/``
can be traced to the run that produced it: when the run starts
(``"complete": false``, so a table left by a stopped run is not taken for a finished one's) and
again when it ends. A run that resumes a folder keeps the folder's earlier records under
``"earlier"``, oldest first: its tables may hold their runs.

A run holds its folder while it writes there (`holding`; `recording` also writes the record):
another process's run that begins in the same folder meanwhile raises `FolderInUseError` (an
advisory ``flock`` of the folder, which ends with the block or the process; two runs in one
folder appended to one ``runs.jsonl``, solved the same cells twice and overwrote each other's
tables and ``provenance.json``). Within one process a folder may be held by several blocks at
once (a solve's inside a sweep's, two threads'); where the file system has no ``flock``
nothing is locked.
"""

from __future__ import annotations

import contextlib
import datetime
import os
import platform
import shlex
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from importlib import metadata
from pathlib import Path

__all__ = ["begin_run", "end_run", "holding", "in_use", "recording", "FolderInUseError", "provenance", "write_provenance", "write_results", "source", "vector_extension", "VECTOR_EXTENSIONS"]


def _version(dist: str) -> str | None:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def _cpuinfo() -> str:
    try:
        return Path("/proc/cpuinfo").read_text()
    except OSError:
        return ""


def _cpu_model(cpuinfo: str) -> str:
    for line in cpuinfo.splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine()


#: x86 vector extensions, widest first. XLA emits code for the widest one the CPU has (unless
#: ``--xla_cpu_max_isa`` caps it), and the rounding of that code can change a solve's iterations.
VECTOR_EXTENSIONS = ("avx512f", "avx2", "avx", "sse4_2")


def vector_extension(cpuinfo: str) -> str | None:
    """The widest of `VECTOR_EXTENSIONS` in the first ``flags`` line of a ``/proc/cpuinfo`` text,
    or None (no such line, or not an x86 CPU)."""
    for line in cpuinfo.splitlines():
        if line.startswith("flags"):
            flags = set(line.split(":", 1)[1].split())
            return next((ext for ext in VECTOR_EXTENSIONS if ext in flags), None)
    return None


#: the checkout's folders whose files a run loads without their being tracked (the package,
#: and the built-in tasks and robots, which are any .toml there)
LOADED_FOLDERS = ("jtraj", "tasks", "robots")

#: the tracked paths whose changes make a run's code differ from its commit: the folders a run
#: loads, the benchmarks (their runs record this too) and the package's metadata. A change
#: elsewhere, such as the tracked files a sweep writes into ``results/`` itself, does not count.
CODE_PATHS = (*LOADED_FOLDERS, "bench", "pyproject.toml")


#: git's environment variables that choose the repository, index or objects it reads
_REPOSITORY_VARIABLES = frozenset(
    ("GIT_DIR", "GIT_WORK_TREE", "GIT_INDEX_FILE", "GIT_OBJECT_DIRECTORY", "GIT_ALTERNATE_OBJECT_DIRECTORIES", "GIT_COMMON_DIR", "GIT_NAMESPACE", "GIT_PREFIX", "GIT_CEILING_DIRECTORIES", "GIT_DISCOVERY_ACROSS_FILESYSTEM")
)


def source(root: str | Path | None = None) -> dict | None:
    """The git commit jtraj runs from (or the checkout at ``root``) and whether the run's code
    differs from it (``dirty``):
    a tracked file in `CODE_PATHS` changed, or a file that git does not ignore and does not track in one of
    `LOADED_FOLDERS` (a new ``tasks/*.toml`` is a built-in task the commit lacks; it is named in
    ``untracked``), when jtraj is imported from a git checkout (an editable install); None
    otherwise."""
    root = Path(__file__).resolve().parent.parent if root is None else Path(root)
    if not (root / ".git").exists():
        return None
    try:
        # git's variables that choose the repository (set in hooks and some shells) pointed it
        # at another repository or index, whose commit was recorded; the others (a container's
        # GIT_CONFIG_* for safe.directory) stay
        env = {k: v for k, v in os.environ.items() if k not in _REPOSITORY_VARIABLES}

        def git(*args: str) -> str:
            return subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, timeout=20, check=True, env=env).stdout.strip()

        # only the code's paths: a sweep written into a tracked results folder rewrites its own
        # provenance.json and tables, and the checkout then read dirty at its first solve
        changed = bool(git("status", "--porcelain", "--untracked-files=no", "--", *CODE_PATHS))
        untracked = git("ls-files", "--others", "--exclude-standard", "--", *LOADED_FOLDERS).splitlines()
        record: dict = {"commit": git("rev-parse", "HEAD"), "dirty": changed or bool(untracked)}
        if untracked:
            record["untracked"] = untracked[:20] + ([f"... {len(untracked) - 20} more"] if len(untracked) > 20 else [])
        return record
    except (OSError, subprocess.SubprocessError):
        return None


def _jax_devices() -> dict:
    """JAX's backend and its devices' kind and count (a GPU's name, or the CPU devices jtraj made)."""
    import jax

    devices = jax.devices()
    return {"backend": jax.default_backend(), "devices": len(devices), "device_kind": devices[0].device_kind}


def provenance(argv: list[str] | None = None) -> dict:
    """Command line (``argv``, default this process's), UTC date, machine and versions.

    The machine's entry names the CPU's widest vector extension (``vector_extension``) and, when
    set, the ``XLA_FLAGS`` of the run: on these problems a solve's iteration count can follow the
    rounding of the machine code XLA emits for them (docs/measurements.md, Table IV)."""
    import jtraj

    argv = sys.argv if argv is None else argv
    cpuinfo = _cpuinfo()
    machine = {"cores": _usable_cores(), "cpu": _cpu_model(cpuinfo), "vector_extension": vector_extension(cpuinfo), "system": f"{platform.system()} {platform.release()}", "python": platform.python_version()}
    if os.environ.get("XLA_FLAGS"):
        machine["xla_flags"] = os.environ["XLA_FLAGS"]
    record = {
        "command": shlex.join(["jtraj", *argv[1:]] if argv and Path(argv[0]).name in ("jtraj", "cli.py") else argv),
        "date_utc": _now(),
        "machine": machine,
        "jax": _jax_devices(),
        "versions": {"jtraj": jtraj.__version__, "jax": _version("jax"), "cyipopt": _version("cyipopt-wheels") or _version("cyipopt"), "mujoco": _version("mujoco")},
    }
    src = source()
    if src is not None:
        record["source"] = src
    return record


def _usable_cores() -> int | None:
    """The cores this process may run on (its CPU affinity, as ``taskset`` or a container's
    cpuset sets it), else the machine's count."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not on Linux
        return os.cpu_count()


def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def write_provenance(out: str | Path, argv: list[str] | None = None) -> Path:
    """Write ``out/provenance.json``; return its path."""
    from jtraj import io

    Path(out).mkdir(parents=True, exist_ok=True)
    return io.write_json(Path(out) / "provenance.json", provenance(argv))


class FolderInUseError(RuntimeError):
    """Another process's run holds the folder (`holding`)."""


#: the folders this process holds: their real path -> [the descriptor whose flock holds it, how
#: many `holding` blocks of this process hold it now, the folders the first of them made (to be
#: removed, where empty, when the last lets go)]
_HELD: dict[str, list] = {}
_HELD_GUARD = threading.Lock()
#: tries to lock a folder before it is refused: a probe of `in_use` (another process's) holds
#: the lock for a moment
_TRIES, _PAUSE = 3, 0.01


def _flock():
    try:
        import fcntl
    except ImportError:  # not a POSIX system: nothing is locked
        return None
    return fcntl


def _open_folder(key: str) -> int:
    """A descriptor of the folder ``key`` to flock (OSError where it cannot be opened)."""
    return os.open(key, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))


def _hold(key: str, out: Path, made: list[Path]) -> bool:
    """Take (or count once more) this process's hold of the folder ``key``; True where a hold
    was counted (and `_release` is owed), False where nothing could be locked."""
    fcntl = _flock()
    if fcntl is None:
        return False
    with _HELD_GUARD:
        if key in _HELD:  # this process's own (a nested run, a thread's)
            _HELD[key][1] += 1
            return True
        for attempt in range(_TRIES):
            try:
                fd = _open_folder(key)
            except FileNotFoundError:  # removed by the run that held it as it let go: made again
                Path(key).mkdir(parents=True, exist_ok=True)
                continue
            except OSError:  # (no descriptors left, no permission to read the folder)
                return False
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                if attempt + 1 < _TRIES:
                    time.sleep(_PAUSE)
                    continue
                raise FolderInUseError(_in_use_message(out)) from None
            except OSError:  # a file system without flock (some network ones): nothing is locked
                os.close(fd)
                return False
            try:  # the folder locked is the one at the path (not one removed meanwhile)
                here = os.path.samestat(os.fstat(fd), os.stat(key))
            except OSError:
                here = False
            if not here:
                os.close(fd)
                Path(key).mkdir(parents=True, exist_ok=True)
                continue
            _HELD[key] = [fd, 1, made]
            return True
        return False


def _release(key: str) -> None:
    """One hold of ``key`` less; the last one removes the folders its first holder made where
    they are empty (before the lock ends: another process cannot have begun in them) and ends
    the lock."""
    with _HELD_GUARD:
        held = _HELD.get(key)
        if held is None:
            return
        held[1] -= 1
        if held[1] > 0:
            return
        del _HELD[key]
        for folder in held[2]:  # deepest first
            with contextlib.suppress(OSError):  # (not empty: kept)
                folder.rmdir()
        os.close(held[0])  # (closing the descriptor ends its flock)


def _alive(pid: int) -> bool:
    if os.name != "posix":  # (os.kill ends the process on Windows)
        return False
    try:
        os.kill(pid, 0)
    except PermissionError:  # another user's process
        return True
    except (OSError, OverflowError):  # no such process
        return False
    return True


def _in_use_message(out: Path) -> str:
    """The refusal, naming the run that holds ``out`` where its ``provenance.json`` says that
    run is unfinished and its process is alive (a record left by a killed run names no one)."""
    from jtraj import io

    who = ""
    with contextlib.suppress(OSError, ValueError, TypeError, KeyError):
        record = io.read_json(out / "provenance.json")
        pid = record.get("pid") if isinstance(record, dict) else None  # (a file that is not an object names no one)
        if isinstance(pid, int) and pid > 0 and record.get("complete") is False and _alive(pid):
            who = f" ({record['command']!s}, begun {record['date_utc']!s})"
    return f"{out} is in use by another run{who}: wait for it to end, or write to another folder"


def in_use(out: str | Path) -> str | None:
    """The refusal `holding` would raise for ``out`` now, or None where it is free (or not a
    folder yet, or held by this process): checked before a sweep's first solve for each folder
    it will write into (a compare cell's)."""
    fcntl = _flock()
    if fcntl is None or not Path(out).is_dir():
        return None
    key = os.path.realpath(out)
    with _HELD_GUARD:  # (this process's threads wait: the probe holds the lock for a moment)
        if key in _HELD:
            return None
        try:
            fd = _open_folder(key)
        except OSError:
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return _in_use_message(Path(out))
        except OSError:
            return None
        finally:
            os.close(fd)
    return None


@contextlib.contextmanager
def holding(out: str | Path) -> Iterator[None]:
    """Hold the folder ``out`` (made if missing) for this process while the block runs (module
    docstring): raises `FolderInUseError`, naming the run that holds it, where another process
    does. Blocks of one process may hold one folder at once (a solve's inside a sweep's, or two
    threads'); the folder is let go when the last of them ends, and the folders made for it are
    removed then where empty (its runs failed before writing)."""
    out = Path(out)
    made = [p for p in (out, *out.absolute().parents) if not p.exists()]  # deepest first
    out.mkdir(parents=True, exist_ok=True)
    key = os.path.realpath(out)  # (kept: a chdir in the block changes a relative out's)
    try:
        counted = _hold(key, out, [Path(p).absolute() for p in made])
    except BaseException:
        for folder in made:
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise
    try:
        yield
    finally:
        if counted:
            _release(key)


@contextlib.contextmanager
def recording(out: str | Path, argv: list[str] | None = None, fields: dict | None = None) -> Iterator[dict]:
    """`begin_run` inside `holding`: the block calls `end_run` when the run is complete (a block
    that raises leaves the record unfinished), and the folder is let go however the block ends."""
    with holding(out):
        yield begin_run(out, argv, fields)


def begin_run(out: str | Path, argv: list[str] | None = None, fields: dict | None = None) -> dict:
    """Write ``out/provenance.json`` as a sweep starts, marked ``"complete": false``, with
    ``fields`` added (e.g. `jtraj.solve`'s ``"call"``) and this process's id (``"pid"``: a
    refusal of the folder names this run while it is alive); an earlier record in the folder (of
    a run this one resumes or adds to) is kept under ``"earlier"``. Returns the record for
    `end_run`. (The record only: a run holds its folder with `holding` or `recording`.)"""
    from jtraj import io

    path = Path(out) / "provenance.json"
    record = {**provenance(argv), **(fields or {})}
    record["complete"] = False
    record["pid"] = os.getpid()
    earlier: list = []
    if path.is_file():
        try:
            previous = io.read_json(path)
        except (OSError, ValueError):
            previous = None  # an unreadable record is replaced
        if isinstance(previous, dict):
            earlier = list(previous.pop("earlier", []) or []) + [previous]
    if earlier:
        record["earlier"] = earlier
    Path(out).mkdir(parents=True, exist_ok=True)
    io.write_json(path, record)
    return record


def end_run(out: str | Path, record: dict) -> Path:
    """Write ``record`` (from `begin_run`) again, marked complete with its end date."""
    from jtraj import io

    record = {**record, "complete": True, "date_end_utc": _now()}
    return io.write_json(Path(out) / "provenance.json", record)


def write_results(
    out: str | Path, name: str, records: object, markdown: str, script: str, argv: list[str] | None = None, record: dict | None = None
) -> list[Path]:
    """A benchmark's results folder: ``out/NAME.json`` (its records, strict JSON), ``out/NAME.md``
    (the table rendered from them) and ``out/provenance.json``, whose command is ``python SCRIPT``
    with ``argv`` (default: this process's arguments), or ``record``, a provenance record the
    script built itself (e.g. with fields of its own, or one its records also hold). Returns the
    three paths."""
    from jtraj import io

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if record is None:
        record = provenance(["python", script, *(sys.argv[1:] if argv is None else argv)])
    return [io.write_json(out / f"{name}.json", records), io.write_text(out / f"{name}.md", markdown), io.write_json(out / "provenance.json", record)]
