"""Markdown tables (`jtraj.tables.markdown_table`): cells that hold Markdown's own separators."""

import pytest

from jtraj.tables import markdown_table


def _cells(line: str) -> list[str]:
    """A table line's cells as GitHub splits them: on the '|' that are not escaped."""
    parts, cell, i = [], "", 0
    body = line.strip()[1:-1]
    while i < len(body):
        if body[i] == "\\" and i + 1 < len(body):
            cell += body[i : i + 2]
            i += 2
            continue
        if body[i] == "|":
            parts.append(cell.strip())
            cell = ""
        else:
            cell += body[i]
        i += 1
    return [*parts, cell.strip()]


def test_a_pipe_or_a_line_break_in_a_cell_keeps_the_columns():
    text = markdown_table(["norm |q|", "status"], [["|q| = 1", "ok"], ["line one\nline two", "failed | restored"]])
    lines = text.splitlines()
    assert len(lines) == 4  # header, rule, two rows: the line break did not start a row
    assert [len(_cells(line)) for line in lines if not line.startswith("|---")] == [2, 2, 2]
    assert _cells(lines[0]) == [r"norm \|q\|", "status"]
    assert _cells(lines[2]) == [r"\|q\| = 1", "ok"]
    assert _cells(lines[3]) == ["line one line two", r"failed \| restored"]


def test_a_backslash_before_a_pipe_keeps_the_columns():
    """A cell's own backslash before a '|' escaped the escape: 'a\\|b' ended the cell there."""
    lines = markdown_table(["path", "status"], [["a\\|b", "ok"], ["C:\\dir\\", "x"]]).splitlines()
    assert [len(_cells(line)) for line in lines if not line.startswith("|---")] == [2, 2, 2]
    assert _cells(lines[2]) == ["a\\\\\\|b", "ok"]  # '\\' (the backslash) then '\|' (the pipe)
    assert _cells(lines[3]) == ["C:\\dir\\", "x"]  # no pipe: as given


def test_plain_cells_are_written_as_given():
    assert markdown_table(("a", "b"), [(1, None), (float("nan"), "x")], note="n.") == "| a | b |\n|---|---|\n| 1 | None |\n| nan | x |\n\nn.\n"


def test_a_row_of_the_wrong_length_is_refused():
    with pytest.raises(ValueError, match="table row has 1 cells, the header 2"):
        markdown_table(("a", "b"), [("x",)])


@pytest.mark.parametrize("header", [(), "task"])
def test_a_header_that_is_not_a_list_of_columns_is_refused(header):
    # () wrote '|  |' over a bare '|', no table; a string was split into one column per letter
    with pytest.raises(ValueError, match="expected a sequence of one or more column names"):
        markdown_table(header, [])
