"""Renamed arguments and names: the old spelling keeps working and warns once per call site."""

from __future__ import annotations

import warnings
from typing import Any, TypeVar

__all__ = ["renamed_argument", "warn_renamed"]

T = TypeVar("T")


def warn_renamed(old: str, new: str, stacklevel: int = 3) -> None:
    """A `DeprecationWarning` that ``old`` is now called ``new``."""
    warnings.warn(f"{old} is deprecated: it is now called {new}", DeprecationWarning, stacklevel=stacklevel)


def _is_default(value: Any, default: Any) -> bool:
    """Whether ``value`` is the argument's default: the same object, or equal to it as one
    truth value. An array, whose ``==`` is elementwise, is never the default."""
    if value is default:
        return True
    try:
        same = value == default
    except (TypeError, ValueError):
        return False
    # an array's == is an array (one entry or many): not one truth value
    return getattr(same, "ndim", 0) == 0 and bool(same)


def renamed_argument(new_value: T, old_value: Any, new: str, old: str, default: Any, stacklevel: int = 4) -> T:
    """The value of an argument renamed from ``old`` to ``new``.

    ``old_value`` is None when the caller used the new name (or neither): ``new_value`` is
    returned. Otherwise the old name's value is returned with a `DeprecationWarning`;
    passing both (the new one not at its ``default``) is a `TypeError`. ``stacklevel`` 4
    points the warning at the caller of the function that calls this one."""
    if old_value is None:
        return new_value
    if not _is_default(new_value, default):
        raise TypeError(f"got both {new}= and {old}=; pass only {new}= ({old}= is its former name)")
    warn_renamed(f"{old}=", f"{new}=", stacklevel)
    return old_value
