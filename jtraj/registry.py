"""Name look-ups in jtraj's registries (parameterizations, solvers, layouts, benchmarks...),
with one error wording: the unknown name and the names that exist."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TypeVar

__all__ = ["lookup"]

T = TypeVar("T")


def lookup(table: Mapping[str, T], name: str, what: str, error: type[Exception] = ValueError, hint: str = "") -> T:
    """``table[name]``, or ``error("unknown WHAT 'name'; expected one of [...]HINT")``."""
    try:
        return table[name]
    except (KeyError, TypeError):
        raise error(f"unknown {what} {name!r}; expected one of {sorted(table)}{hint}") from None
