"""bench/revisions.py: its table, and its refusal of a process that imported the wrong jtraj."""

import pytest
from conftest import bench_module


@pytest.fixture(scope="module")
def revisions():
    return bench_module("revisions")


def test_table_gives_each_revision_its_fastest_solve_and_the_ratio(revisions):
    records = [
        dict(task="walk", label="aaa", iterations=16, cost=0.0, times=[9.0, 8.0, 8.5]),
        dict(task="walk", label="bbb", iterations=16, cost=0.0, times=[6.5, 6.4, 7.0]),
        dict(task="sideflip", label="aaa", iterations=33, cost=0.5, times=[3.3]),
        dict(task="sideflip", label="bbb", iterations=32, cost=0.25, times=[3.0]),
    ]
    lines = revisions.table(records, ("aaa", "bbb")).splitlines()
    assert lines[0].startswith("| task | iterations (aaa / bbb) |")
    assert len(lines) == 4
    assert lines[2] == "| walk | 16 / 16 | 0 / 0 | 8.00 | 6.40 | 0.500 | 0.400 | 1.25x |"
    assert lines[3] == "| sideflip | 33 / 32 | 0.5 / 0.25 | 3.30 | 3.00 | 0.100 | 0.094 | 1.10x |"


def test_a_process_that_imports_jtraj_from_elsewhere_is_refused(revisions, tmp_path):
    """A tree without jtraj: the child imports the installed one, says so and stops before
    solving anything."""
    with pytest.raises(RuntimeError, match="not from"):
        revisions.run_child(tmp_path, "no_such_task", "se3", "compact", 1)
