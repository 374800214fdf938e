"""Files that are never half-written, and JSON that every strict reader accepts.

Every writer here writes into a temporary file in the destination's own folder, flushes and
fsyncs it, then renames it over the destination with `os.replace` (atomic on POSIX when both
are on one file system, which the same folder guarantees). A reader therefore sees either the
old file or the new one, never a truncated mix, even when the writer is killed.

JSON is strict (RFC 8259): ``NaN``, ``Infinity`` and ``-Infinity`` are not JSON, and Python's
default ``json.dump`` writes them anyway. Here a non-finite float is written as ``null``
(a failed solve can legitimately have a NaN objective, and losing the whole result file over
it would be worse); the encoder then runs with ``allow_nan=False`` so that nothing non-finite
can slip through. numpy and JAX scalars and arrays, enums and dataclasses are converted on the way.

`read_json` raises `FileFormatError` (a `ValueError`) with one line naming the file when it is
missing, empty or not valid JSON; `read_jsonl` when it is a folder or cannot be read.
"""

from __future__ import annotations

import contextlib
import dataclasses
import enum
import json
import math
import os
import stat
import tempfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import IO, Any

import numpy as np

__all__ = [
    "FileFormatError",
    "atomic_open",
    "write_text",
    "write_json",
    "to_jsonable",
    "dumps",
    "read_json",
    "append_jsonl",
    "read_jsonl",
    "read_jsonl_lines",
    "check_file",
    "output_folder_problem",
    "write_npz",
    "save_figure",
]


class FileFormatError(ValueError):
    """A file that is missing, empty, unreadable or not in the expected format; the message names it."""


@contextlib.contextmanager
def atomic_open(path: str | Path, mode: str = "w", encoding: str | None = "utf-8") -> Iterator[IO]:
    """Open a temporary file next to ``path``; on a clean exit, fsync it and rename it over
    ``path``. On an exception the temporary file is removed and ``path`` is untouched.

    ``mode`` is ``"w"`` (text) or ``"wb"`` (binary). The parent folder is created.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_open: mode {mode!r}; expected 'w' or 'wb'")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        # mkstemp makes the file private (0600); give it the mode a plain open() would
        os.chmod(tmp, 0o666 & ~_umask())
        with os.fdopen(fd, mode, encoding=None if "b" in mode else encoding) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    _fsync_dir(path.parent)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _fsync_dir(folder: Path) -> None:
    # the rename itself is durable only once the directory entry is on disk
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (a Markdown table, a log...) atomically."""
    with atomic_open(path, "w") as f:
        f.write(text)
    return Path(path)


def to_jsonable(obj: Any) -> Any:
    """``obj`` as plain JSON types: numpy and JAX scalars/arrays to numbers/lists, enums to their value,
    dataclasses to dicts, tuples to lists, non-finite floats to ``None``."""
    if obj is None or isinstance(obj, (str, bool)):
        return obj
    if isinstance(obj, enum.Enum):
        return to_jsonable(obj.value)
    if isinstance(obj, (int, np.integer)) and not isinstance(obj, np.bool_):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, (float, np.floating)):
        x = float(obj)
        return x if math.isfinite(x) else None
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, Mapping):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    if hasattr(obj, "__array__") and hasattr(obj, "dtype"):  # a JAX array (jtraj's own numbers)
        return to_jsonable(np.asarray(obj))
    raise TypeError(f"cannot write {type(obj).__name__} to JSON")


def dumps(obj: Any, indent: int | None = 2) -> str:
    """Strict JSON text of ``obj`` (see `to_jsonable`)."""
    return json.dumps(to_jsonable(obj), indent=indent, allow_nan=False)


def write_json(path: str | Path, obj: Any, indent: int | None = 2) -> Path:
    """Write ``obj`` as strict JSON, atomically (non-finite floats become ``null``)."""
    text = dumps(obj, indent)  # before opening: a bad object leaves no temporary file
    return write_text(path, text + "\n")


def read_json(path: str | Path) -> Any:
    """Parse a JSON file; `FileFormatError` naming the file if it is missing, empty or corrupt."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FileFormatError(f"{path}: file does not exist") from None
    except IsADirectoryError:
        raise FileFormatError(f"{path}: is a folder; expected a JSON file") from None
    except NotADirectoryError:
        raise FileFormatError(f"{path}: file does not exist (a folder on its path is a file)") from None
    except PermissionError:
        raise FileFormatError(f"{path}: not readable (permission denied)") from None
    except UnicodeDecodeError:
        raise FileFormatError(f"{path}: not UTF-8 text; expected a JSON file") from None
    if not text.strip():
        raise FileFormatError(f"{path}: file is empty; expected JSON")
    try:
        return json.loads(text, parse_constant=_reject_constant)
    except (json.JSONDecodeError, ValueError) as e:
        raise FileFormatError(f"{path}: not valid JSON ({e})") from None


def _reject_constant(name: str) -> Any:
    raise ValueError(f"{name} is not JSON")


def append_jsonl(path: str | Path, record: Any) -> None:
    """Append one record as one strict-JSON line and fsync.

    One ``write`` of a line opened with ``O_APPEND`` lands whole at the end of the file even
    with several processes appending at once (lines here are far below the pipe-buffer size
    that local file systems honour in practice); a kill can leave at most one partial last
    line, which `read_jsonl` reports and skips. A file that does not end in a newline (that
    torn line, or files joined by hand) gets one before the record, in the same write: glued
    onto the last line, the record and that line would both be lost. (Two appends that find
    the same missing newline leave an empty line, which `read_jsonl` skips.) A short write is
    continued until the whole line is written.
    """
    line = (json.dumps(to_jsonable(record), allow_nan=False, separators=(",", ":")) + "\n").encode()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        size = os.fstat(fd).st_size
        if size and os.pread(fd, 1, size - 1) != b"\n":
            line = b"\n" + line
        rest = memoryview(line)
        while rest:
            rest = rest[os.write(fd, rest) :]
        os.fsync(fd)
    finally:
        os.close(fd)


def output_folder_problem(path: str | Path) -> str | None:
    """What is wrong with ``path`` as an output folder, in words ("is a file; expected a
    folder ..."), or None where it is a folder (or none yet) this user can write in: checked
    before a command or `jtraj.solve` computes what it would write there."""
    if not str(path):  # Path("") is the current folder: a default was meant, or a typo
        return "expected a folder name (existing or to be created)"
    p = Path(path)
    if p.exists() and not p.is_dir():
        return "is a file; expected a folder (existing or to be created)"
    existing = p
    while not existing.exists():
        if existing.is_symlink():  # a link to nothing: making the folder failed after the solve
            return f"{existing} is a link to {os.readlink(existing)}, which does not exist; expected a folder"
        existing = existing.parent
    if not existing.is_dir():
        return f"{existing} is a file; expected a folder"
    # a real probe: permission bits do not tell (root, read-only mounts, /proc)
    try:
        fd, probe = tempfile.mkstemp(prefix=".jtraj-write-test.", dir=existing)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        # the system's reason as it gives it (/proc answers "No such file or directory")
        return f"cannot create a file in {os.path.abspath(existing)} (the system says: {e.strerror}); expected a folder you can write in"
    return None


def check_file(path: str | Path, expected: str, read: bool = True) -> bool:
    """Whether ``path`` exists (False where it does not); `FileFormatError` naming it, with
    ``expected`` (what it should be, e.g. "a JSON-lines file"), where it is there but no regular
    file (a folder; a named pipe, whose read would wait for a writer) or, with ``read``, a file
    this process cannot open for reading. A caller checks before it writes or computes anything
    that a read of the file would then lose."""
    path = Path(path)
    try:
        mode = path.stat().st_mode
        if not stat.S_ISREG(mode):
            raise FileFormatError(f"{path}: {'is a folder' if stat.S_ISDIR(mode) else 'is not a regular file'}; expected {expected}")
        if read:
            with open(path, "rb"):
                pass
    except FileNotFoundError:
        return False
    except OSError as e:
        raise _unreadable(path, e, expected) from None
    return True


def _unreadable(path: Path, error: OSError, expected: str) -> FileFormatError:
    # the system's reason as it gives it (permission denied, an I/O error, a parent that is a file)
    return FileFormatError(f"{path}: cannot be read (the system says: {error.strerror or error}); expected {expected}")


def read_jsonl(path: str | Path) -> tuple[list[Any], list[int]]:
    """Records of a JSON-lines file and the 1-based numbers of the lines that did not parse
    (a torn last line after a kill, or damage). A missing file gives no records; a folder or
    a file that cannot be read, a `FileFormatError` naming it (`check_file`)."""
    numbered, bad = read_jsonl_lines(path)
    return [record for _, record in numbered], bad


def read_jsonl_lines(path: str | Path) -> tuple[list[tuple[int, Any]], list[int]]:
    """`read_jsonl` with the 1-based line number of each record: ``([(line, record), ...], bad)``."""
    path = Path(path)
    if not check_file(path, "a JSON-lines file", read=False):
        return [], []
    records, bad = [], []
    try:
        with open(path, "rb") as f:
            for i, raw in enumerate(f, 1):
                if not raw.strip():
                    continue
                try:
                    records.append((i, json.loads(raw.decode("utf-8"), parse_constant=_reject_constant)))
                except (UnicodeDecodeError, ValueError):
                    bad.append(i)
    except FileNotFoundError:  # removed since it was checked
        return [], []
    except OSError as e:
        raise _unreadable(path, e, "a JSON-lines file") from None
    return records, bad


def write_npz(path: str | Path, **arrays: Any) -> Path:
    """`numpy.savez_compressed` of ``arrays``, atomically."""
    with atomic_open(path, "wb") as f:
        np.savez_compressed(f, **arrays)
    return Path(path)


def save_figure(fig: Any, path: str | Path, **savefig_kwargs: Any) -> Path:
    """``fig.savefig`` (matplotlib) atomically; the format is taken from ``path``'s suffix."""
    path = Path(path)
    fmt = savefig_kwargs.pop("format", path.suffix.lstrip(".") or "png")
    with atomic_open(path, "wb") as f:
        fig.savefig(f, format=fmt, **savefig_kwargs)
    return path
