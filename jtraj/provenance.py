"""Where a table came from: the command, the date, the machine and the software versions.

`jtraj compare` and `jtraj robustness` write ``provenance.json`` beside their tables so that a
number quoted from ``results/`` can be traced to the run that produced it.
"""

from __future__ import annotations

import datetime
import os
import platform
import shlex
import sys
from importlib import metadata
from pathlib import Path

__all__ = ["provenance", "write_provenance", "write_results"]


def _version(dist: str) -> str | None:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def provenance(argv: list[str] | None = None) -> dict:
    """Command line (``argv``, default this process's), UTC date, machine and versions."""
    import jtraj

    argv = sys.argv if argv is None else argv
    return {
        "command": shlex.join(["jtraj", *argv[1:]] if Path(argv[0]).name in ("jtraj", "cli.py") else argv),
        "date_utc": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "machine": {"cores": os.cpu_count(), "cpu": _cpu_model(), "system": f"{platform.system()} {platform.release()}", "python": platform.python_version()},
        "versions": {"jtraj": jtraj.__version__, "jax": _version("jax"), "cyipopt": _version("cyipopt-wheels") or _version("cyipopt"), "mujoco": _version("mujoco")},
    }


def write_provenance(out: str | Path, argv: list[str] | None = None) -> Path:
    """Write ``out/provenance.json``; return its path."""
    from jtraj import io

    Path(out).mkdir(parents=True, exist_ok=True)
    return io.write_json(Path(out) / "provenance.json", provenance(argv))


def write_results(out: str | Path, name: str, records: object, markdown: str, script: str, argv: list[str] | None = None) -> list[Path]:
    """A benchmark's results folder: ``out/NAME.json`` (its records, strict JSON), ``out/NAME.md``
    (the table rendered from them) and ``out/provenance.json``, whose command is ``python SCRIPT``
    with ``argv`` (default: this process's arguments). Returns the three paths."""
    from jtraj import io

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    command = ["python", script, *(sys.argv[1:] if argv is None else argv)]
    return [io.write_json(out / f"{name}.json", records), io.write_text(out / f"{name}.md", markdown), write_provenance(out, command)]
