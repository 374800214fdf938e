"""bench/solve.py says so when it runs without the paper's code beside it (a clone elsewhere),
instead of printing a table without the peer's column and no word why."""

from pathlib import Path

import pytest
from conftest import bench_module


class _Stop(Exception):
    pass


def _stop(*args, **kwargs):
    raise _Stop


@pytest.mark.parametrize(("argv", "warned"), [([], True), (["--no-peer"], False)])
def test_a_missing_default_peer_is_announced(monkeypatch, capsys, argv, warned):
    solve = bench_module("solve")
    missing = Path("/nonexistent/shared/peers/run-se3-trajopt")
    monkeypatch.setattr(solve, "DEFAULT_PEER", missing)
    monkeypatch.setattr(solve, "prepare", _stop)  # stop before any compile
    with pytest.raises(_Stop):
        solve.main(["big_jump", "--variants", "jtraj", *argv])
    err = capsys.readouterr().err
    assert (f"no peer: the paper's public code is not at {missing}" in err) == warned
