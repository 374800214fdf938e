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


#: what each script calls to do its work: replaced by `_no_work` (a dotted name: in jtraj)
WORK = {
    "options": ["measure"],
    "quaternion_noise": ["run"],
    "replicates": ["prepare", "solve"],
    "hessians": ["run"],
    "mu_oracle": ["jtraj.solver.prepare"],
    "profile_solve": ["profile"],
    "fatrop": ["prepare", "solve", "solve_fatrop"],
    "params_hop": ["run"],
    "compile": ["run_child"],
}

UNKNOWN_PARAM = "argument --param: invalid choice: 'bogus' (choose from 'se3', 'quat1', 'quat2', 'quat3', 'euler')"
UNKNOWN_VARIABLES = "argument --variables: invalid choice: 'bogus' (choose from 'paper', 'compact', 'lean')"
UNKNOWN_TASK = "unknown task; expected one of ['backflip', 'big_jump',"


@pytest.mark.parametrize(
    ("script", "argv", "message"),
    [
        ("options", ["bogus", "--variant", "default"], UNKNOWN_TASK),
        ("options", ["big_jump", "--variant", "default", "--param", "bogus"], UNKNOWN_PARAM),
        ("options", ["big_jump", "--variant", "default", "--variables", "bogus"], UNKNOWN_VARIABLES),
        ("quaternion_noise", ["--task", "bogus"], UNKNOWN_TASK),
        ("quaternion_noise", ["--params", "quat1,bogus"], "--params: 'bogus': unknown parameterization; expected some of se3, quat1, quat2, quat3, euler"),
        ("quaternion_noise", ["--variables", "bogus"], UNKNOWN_VARIABLES),
        ("replicates", ["--task", "bogus"], UNKNOWN_TASK),
        ("replicates", ["--param", "bogus"], UNKNOWN_PARAM),
        ("hessians", ["big_jump", "--param", "bogus"], UNKNOWN_PARAM),
        ("hessians", ["big_jump", "--variables", "bogus"], UNKNOWN_VARIABLES),
        ("hessians", ["big_jump", "--hessians", "lbfgs,bogus"], "--hessians: jtraj option hessian='bogus': expected 'lbfgs', 'exact' or 'bfgs'"),
        ("hessians", ["big_jump", "--hessians", ","], "--hessians: ',': expected some of lbfgs,bfgs,exact"),
        ("mu_oracle", ["big_jump", "--param", "bogus"], UNKNOWN_PARAM),
        ("profile_solve", ["big_jump", "--param", "bogus"], UNKNOWN_PARAM),
        ("profile_solve", ["big_jump", "--variables", "bogus"], UNKNOWN_VARIABLES),
        ("fatrop", ["big_jump", "--param", "bogus"], UNKNOWN_PARAM),
        ("params_hop", ["--params", "se3,bogus"], "--params: 'bogus': unknown parameterization"),
        ("compile", ["big_jump", "--param", "bogus"], UNKNOWN_PARAM),
        ("compile", ["big_jump", "--variables", "bogus"], UNKNOWN_VARIABLES),
    ],
)
def test_tasks_parameterizations_and_variables_are_checked(monkeypatch, capsys, script, argv, message):
    mod = bench_module(script)
    for name in WORK[script]:
        if "." in name:
            monkeypatch.setattr(name, _no_work)
        else:
            monkeypatch.setattr(mod, name, _no_work)
    _refused(mod.main, argv, capsys, message)
