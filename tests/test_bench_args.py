"""The benchmarks' command lines: a mistake is argparse's one-line error naming the argument
(exit status 2), before anything is compiled or solved. Each test replaces what would do the
work with a function that fails the test if it is called."""

import pytest
from conftest import bench_module


def _no_work(*args, **kwargs):
    raise AssertionError("did work after a bad input")


def _refused(main, argv, capsys, message):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert ": error: " in last and message in last, last


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--robot", "g1"], "--robot: 'g1': expected ROBOT=OTHER"),
        (["--set", "force_limits"], "--set: 'force_limits': expected FIELD=VALUE"),
        (["--set", "no_such_field=rows"], "--set: "),
        (["--peer-python", "/nonexistent/python"], "--peer-python: '/nonexistent/python' does not exist"),
    ],
)
def test_trace_iterates(monkeypatch, capsys, argv, message):
    mod = bench_module("trace_iterates")
    for name in ("run_peer", "run_jtraj", "peer_iterates"):
        monkeypatch.setattr(mod, name, _no_work)
    _refused(mod.main, ["backflip", *argv], capsys, message)
