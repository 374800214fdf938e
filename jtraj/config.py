"""Process-wide settings: JAX's CPU devices and its persistent compilation cache."""

from __future__ import annotations

import os
import re
import sys
import warnings
from pathlib import Path

import jax

from jtraj.numbers import is_whole

__all__ = ["CACHE_MAX_BYTES", "cpu_count", "split_cpu", "default_cache_dir", "enable_compilation_cache"]

_enabled: Path | None = None
_given = False  # whether _enabled was a folder given to enable_compilation_cache
_env_at_given: str | None = None  # JTRAJ_CACHE_DIR when it was given

#: Size limit of the persistent compilation cache (least recently used entries go first).
CACHE_MAX_BYTES = 4 * 2**30


def cpu_count() -> int:
    """The cores this process may run on (its CPU affinity, not the machine's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def split_cpu(count: int | None = None) -> int | None:
    """Give JAX one CPU device per core (``count`` devices; default ``JTRAJ_CPU_DEVICES``, else
    `cpu_count`), so that a vmapped jtraj solve on the CPU splits its batch over every core in
    one program (`jtraj.solvers.ipm`); a one-problem program still runs on one device. Called
    by ``import jtraj``. Leaves things as they are, and returns None, where the count is
    already chosen (``jax_num_cpu_devices``, ``JAX_NUM_CPU_DEVICES`` or XLA's
    ``--xla_force_host_platform_device_count``) or JAX has started its backends (the setting
    must come before the first computation); returns the count set otherwise.
    ``JTRAJ_CPU_DEVICES=1`` keeps JAX's single CPU device."""
    chosen = jax.config.jax_num_cpu_devices  # type: ignore[attr-defined]  # (-1: not chosen)
    if chosen != -1 or "xla_force_host_platform_device_count" in os.environ.get("XLA_FLAGS", ""):
        return None
    if count is None:
        given = os.environ.get("JTRAJ_CPU_DEVICES")
        try:
            # ASCII digits only: int() also read "1_6" as 16 and other scripts' digits
            if given and not re.fullmatch(r"\s*[+-]?[0-9]+\s*", given):
                raise ValueError
            count = int(given) if given else cpu_count()
        except ValueError:
            raise ValueError(f"JTRAJ_CPU_DEVICES={given!r}: expected a positive whole number of CPU devices") from None
        if count < 1:
            raise ValueError(f"JTRAJ_CPU_DEVICES={given!r}: {count} CPU devices; expected a positive count (unset JTRAJ_CPU_DEVICES for one device per core)")
    # (JAX refused a numpy integer, took True as 1 and said of 2.5 only that it wants an int)
    if not is_whole(count) or count < 1:
        raise ValueError(f"split_cpu(count={count!r}): expected a positive whole number of CPU devices")
    try:
        jax.config.update("jax_num_cpu_devices", int(count))
    except RuntimeError:  # JAX computed before jtraj was imported: its devices are fixed
        return None
    return int(count)


def _runs_the_command_line() -> bool:
    """Whether this process is jtraj's command line: the ``jtraj`` console script (its
    ``__main__`` imports jtraj.cli), ``python -m jtraj`` or ``python -m jtraj.cli``
    (``sys.argv[0]`` is ``-m`` while the package is imported; ``-m jtraj`` was missed, and a
    bad JTRAJ_CPU_DEVICES ended in a traceback there)."""
    if sys.argv[:1] == ["-m"]:
        argv = getattr(sys, "orig_argv", [])
        return any(a == "-m" and b in ("jtraj", "jtraj.cli") for a, b in zip(argv, argv[1:]))
    path = getattr(sys.modules.get("__main__"), "__file__", None)
    return path is not None and Path(path).name in ("jtraj", "jtraj-script.py", "jtraj.exe")


def default_cache_dir() -> Path:
    """The compilation cache's folder when ``JTRAJ_CACHE_DIR`` is not set:
    ``$XDG_CACHE_HOME/jtraj/jax``, else ``~/.cache/jtraj/jax``."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "jtraj" / "jax"


def enable_compilation_cache(path: str | Path | None = None) -> Path | None:
    """Turn on JAX's persistent compilation cache (default ``~/.cache/jtraj/jax``), so a second
    process reuses the compiled NLP functions. ``JTRAJ_NO_CACHE=1`` turns it off (``0``,
    ``false``, ``no``, ``off`` or an empty value leave it on); an empty ``JTRAJ_CACHE_DIR`` is
    the default folder, not the working directory. Returns the folder JAX's cache is in from
    then on, or None where it is off: turned off, or its folder cannot be made (a
    `RuntimeWarning` says which and what to set: the solve goes on without the cache, or with
    the folder JAX had, which is returned).

    Each call reads its arguments and the environment again, and a change takes effect in
    this process: another folder (``path``, or a changed ``JTRAJ_CACHE_DIR``) is where the
    compilations from then on are written and looked up, and ``JTRAJ_NO_CACHE=1`` set after
    an earlier call turns the cache this module turned on off again (JAX sets its cache up
    once, at the first compilation after the folder is chosen; it is reset here, by
    ``jax.experimental.compilation_cache.compilation_cache.reset_cache``). Programs compiled
    before stay in memory, and in the folder they were written to.

    A cache set up for JAX before (``jax.config.update("jax_compilation_cache_dir", ...)`` or
    ``JAX_COMPILATION_CACHE_DIR``) is left as it is, with its thresholds, and its folder is
    returned, unless ``path`` or ``JTRAJ_CACHE_DIR`` asks for another; so is a cache this module
    turned on and the user turned off for JAX since (None is returned); so is a folder given as
    ``path`` before, until ``JTRAJ_CACHE_DIR`` changes. `jtraj.solve`,
    `jtraj.differentiate.differentiable` and the attitude benchmarks' solves call this
    without arguments."""
    global _enabled, _given, _env_at_given
    if os.environ.get("JTRAJ_NO_CACHE", "").strip().lower() not in ("", "0", "false", "no", "off"):
        if _enabled is not None:  # turned on by an earlier call: JAX would go on using it
            jax.config.update("jax_compilation_cache_dir", None)
            _reset_jax_cache()
            _enabled = None
        return None
    # a cache the user set up for JAX (jax.config, or JAX_COMPILATION_CACHE_DIR) is theirs: its
    # folder and thresholds were overwritten by the first solve; a folder given here, or
    # JTRAJ_CACHE_DIR, still asks for jtraj's. A folder given here before is kept too (the next
    # solve's call without one moved to the default), until JTRAJ_CACHE_DIR changes
    own = _jax_cache_dir()
    env = os.environ.get("JTRAJ_CACHE_DIR") or None
    if path is None and own is None and _enabled is not None and env == _env_at_given:
        # the cache this module turned on, turned off for JAX since (jax.config): the user's
        # setting, kept (the folder jtraj had chosen was returned, or the default turned on)
        return None
    if path is None and own:
        users = _enabled is None or str(_enabled) != own
        if (users and env is None) or (not users and _given and env == _env_at_given):
            return Path(own)
    # "~/x" (a quoted path in a shell, or a .env file) made a folder named "~" here
    target = (Path(path) if path is not None else Path(env or default_cache_dir())).expanduser()
    if _enabled == target and own == str(target):
        if path is not None:
            _given, _env_at_given = True, env
        return target
    try:
        target.mkdir(parents=True, exist_ok=True)
    except OSError as e:  # a read-only home, a file in the way: compile without the cache
        # (or with the one JAX has: it said "no compilation cache" and returned None while JAX
        # went on writing to an earlier folder)
        still = f"the compilations go on to {own!r}" if own else "no compilation cache"
        warnings.warn(f"jtraj: {still}: the folder {str(target)!r} cannot be made ({e.strerror or e}); set JTRAJ_CACHE_DIR to a writable folder, or JTRAJ_NO_CACHE=1", RuntimeWarning, stacklevel=2)
        return Path(own) if own else None
    jax.config.update("jax_compilation_cache_dir", str(target))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    # A size limit turns on JAX's LRU eviction and with it a file lock around every read and
    # write of the cache: without it, JAX writes entries in place, and a process reading an
    # entry that another process (a notebook kernel, a sweep's worker) is still writing gets
    # a torn executable (seen here: a segmentation fault in deserialize_executable).
    jax.config.update("jax_compilation_cache_max_size", CACHE_MAX_BYTES)
    # JAX opens its folder at its first compilation and keeps it: without the reset, a second
    # call's folder was returned while the entries still went to the first one
    _reset_jax_cache()
    _enabled, _given, _env_at_given = target, path is not None, env
    return target


def _jax_cache_dir() -> str | None:
    """The folder of JAX's persistent cache as JAX's settings have it now (None: off)."""
    return jax.config.jax_compilation_cache_dir  # type: ignore[attr-defined]


def _reset_jax_cache() -> None:
    """Have JAX set its persistent cache up again, from its current settings, at its next
    compilation (it does so once per process otherwise)."""
    from jax.experimental.compilation_cache import compilation_cache

    compilation_cache.reset_cache()
