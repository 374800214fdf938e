"""Process-wide settings: JAX's persistent compilation cache."""

from __future__ import annotations

import os
from pathlib import Path

import jax

_enabled: Path | None = None

#: Size limit of the persistent compilation cache (least recently used entries go first).
CACHE_MAX_BYTES = 4 * 2**30


def default_cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "jtraj" / "jax"


def enable_compilation_cache(path: str | Path | None = None) -> Path | None:
    """Turn on JAX's persistent compilation cache (default ``~/.cache/jtraj/jax``), so a second
    process reuses the compiled NLP functions. ``JTRAJ_NO_CACHE=1`` turns it off."""
    global _enabled
    if os.environ.get("JTRAJ_NO_CACHE"):
        return None
    target = Path(path) if path is not None else Path(os.environ.get("JTRAJ_CACHE_DIR", default_cache_dir()))
    if _enabled == target:
        return target
    target.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(target))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    # A size limit turns on JAX's LRU eviction and with it a file lock around every read and
    # write of the cache: without it, JAX writes entries in place, and a process reading an
    # entry that another process (a notebook kernel, a sweep's worker) is still writing gets
    # a torn executable (seen here: a segmentation fault in deserialize_executable).
    jax.config.update("jax_compilation_cache_max_size", CACHE_MAX_BYTES)
    _enabled = target
    return target
