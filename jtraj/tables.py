"""Result tables: one Markdown writer for every table jtraj prints or saves (Table IV, Table
III, the attitude benchmarks), and the JSON next to it."""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from jtraj import io

__all__ = ["markdown_table", "write_table"]


def _cell(value: Any) -> str:
    # a '|' would end the cell and a line break the row: escaped, and written as a space. The
    # backslashes before a '|' are doubled first: a cell's own '\' would escape the escape
    # ('a\|b' written as 'a\\|b' ended the cell at that '|')
    text = " ".join(str(value).splitlines())
    return re.sub(r"(\\*)\|", lambda m: m.group(1) * 2 + "\\|", text)


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[Any]], note: str = "") -> str:
    """A GitHub Markdown table of already formatted cells (``str(cell)``), one line per row,
    followed by ``note`` (a footnote paragraph) when given; ends with a newline. A ``|`` in a
    cell or a header is escaped (``\\|``) and a line break becomes a space, so that text such
    as ``|q|`` stays in its cell."""
    if isinstance(header, str) or not len(header):
        raise ValueError(f"table header {header!r}: expected a sequence of one or more column names")
    lines = ["| " + " | ".join(_cell(h) for h in header) + " |", "|" + "---|" * len(header)]
    for row in rows:
        cells = [_cell(c) for c in row]
        if len(cells) != len(header):
            raise ValueError(f"table row has {len(cells)} cells, the header {len(header)}: {cells}")
        lines.append("| " + " | ".join(cells) + " |")
    if note:
        lines.append("\n" + note)
    return "\n".join(lines) + "\n"


def write_table(directory: str | Path, stem: str, records: Any, markdown: str) -> tuple[Path, Path]:
    """Write ``records`` as ``stem.json`` and the Markdown text as ``stem.md`` into
    ``directory`` (atomically; created); returns both paths."""
    d = Path(directory)
    return io.write_json(d / f"{stem}.json", records), io.write_text(d / f"{stem}.md", markdown)
