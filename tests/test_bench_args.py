"""The benchmarks' command lines: a mistake is argparse's one-line error naming the argument
(exit status 2), before anything is compiled or solved. Each test replaces what would do the
work with a function that fails the test if it is called."""

import sys

import pytest
from conftest import bench_module, refused


def _no_work(*args, **kwargs):
    raise AssertionError("did work after a bad input")


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--robot", "g1"], "--robot: 'g1': expected ROBOT=OTHER"),
        (["--set", "force_limits"], "--set: 'force_limits': expected FIELD=VALUE"),
        (["--set", "no_such_field=rows"], "--set: ['no_such_field']: not a field of the variables that can be set"),
        (["--peer-python", "/nonexistent/python"], "--peer-python: '/nonexistent/python' does not exist"),
        (["--peer-python", sys.executable, "--peer-src", "/nonexistent/src"], "--peer-src: '/nonexistent/src' does not hold the public code's examples/agile_exps"),
    ],
)
def test_trace_iterates(monkeypatch, capsys, argv, message):
    mod = bench_module("trace_iterates")
    for name in ("run_peer", "run_jtraj", "peer_iterates"):
        monkeypatch.setattr(mod, name, _no_work)
    refused(mod.main, ["backflip", *argv], capsys, message)


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
    "factor_split": ["measure"],
    "vmap_cpu": ["timed", "sweeps"],
    "dynamics": ["timed", "batched", "jtraj.robot.load"],
    "differentiate": ["differentiable"],
    "euler_warm_start": ["run"],
    "unit_norm": ["run"],
    "quat3_norms": ["run"],
    "trace_iterates": ["run_peer", "run_jtraj", "peer_iterates"],
    "solve": ["prepare", "run_variant", "run_peer"],
}


def _without_work(monkeypatch, script: str):
    """``bench/SCRIPT.py`` with what it calls to do its work (`WORK`) replaced by `_no_work`."""
    mod = bench_module(script)
    for name in WORK[script]:
        if "." in name:
            monkeypatch.setattr(name, _no_work)
        else:
            monkeypatch.setattr(mod, name, _no_work)
    return mod


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
        # bench/_args's helpers, as the scripts above (these defined the options by hand)
        ("dynamics", ["--param", "bogus"], UNKNOWN_PARAM),
        ("trace_iterates", ["backflip", "--variables", "bogus"], UNKNOWN_VARIABLES),
    ],
)
def test_tasks_parameterizations_and_variables_are_checked(monkeypatch, capsys, script, argv, message):
    refused(_without_work(monkeypatch, script).main, argv, capsys, message)


@pytest.mark.parametrize(
    ("script", "argv", "message"),
    [
        ("factor_split", ["--shapes", "bogus"], "argument --shapes: 'bogus': expected KxNxC (knots, block size, coupled columns), e.g. 47x156x96"),
        ("factor_split", ["--shapes", "47x156x96,2x4"], "argument --shapes: '2x4': expected KxNxC"),
        ("factor_split", ["--shapes", "2x4x8"], "argument --shapes: '2x4x8': expected K >= 1 knots and 1 <= C <= N coupled columns"),
        ("factor_split", ["--rounds", "0"], "--rounds: 0: expected an integer >= 1"),
        ("vmap_cpu", ["--sizes", "x"], "argument --sizes: 'x': expected comma-separated block sizes >= 1"),
        ("vmap_cpu", ["--sizes", "32,0"], "argument --sizes: '32,0': expected comma-separated block sizes >= 1"),
        ("vmap_cpu", ["--members", "0"], "--members: 0: expected an integer >= 1"),
        ("replicates", ["--batches", "x"], "--batches: 'x': expected comma-separated batch sizes >= 1"),
        ("replicates", ["--batches", "0"], "--replicates and --batches take positive whole numbers"),
        ("replicates", ["--sigma", "-1"], "--sigma: -1.0: expected a noise level (standard deviation) >= 0"),
        ("dynamics", ["--robot", "bogus"], "argument --robot: invalid choice: 'bogus' (choose from 'g1', 'go2', 'talos', 'talos_full')"),
        ("dynamics", ["--knots", "0"], "--knots: 0: expected an integer >= 1"),
        ("dynamics", ["--repeats", "0"], "--repeats: 0: expected an integer >= 1"),
        ("differentiate", ["--knots-scale", "0"], "--knots-scale: 0: expected an integer >= 1"),
        ("differentiate", ["--knots-scale", "-1"], "--knots-scale: -1: expected an integer >= 1"),
        ("differentiate", ["--repeat", "0"], "--repeat: 0: expected an integer >= 1"),
        # the benchmark's own messages (argparse's usage line names every option)
        ("differentiate", ["--solvers", "ipopt,bogus"], "--solvers: 'ipopt,bogus': expected distinct names of "),
        ("differentiate", ["--solvers", ""], "--solvers: '': expected distinct names of "),
        ("differentiate", ["--solvers", "ipopt,ipopt"], "--solvers: 'ipopt,ipopt': expected distinct names of "),
        ("differentiate", ["--batch", "1"], "--batch: 1: expected an integer >= 2"),
        ("compile", ["big_jump", "--repeats", "0"], "--repeats: 0: expected an integer >= 1"),
        ("mu_oracle", ["big_jump", "--repeat", "0"], "--repeat: 0: expected an integer >= 1"),
        ("quaternion_noise", ["--draws", "0"], "--draws: 0: expected an integer >= 1"),
        ("quaternion_noise", ["--first", "-1"], "--first: -1: expected an integer >= 0"),
        ("quaternion_noise", ["--max-iter", "0"], "--max-iter: 0: expected an integer >= 1"),
        ("quaternion_noise", ["--sigma", "-1"], "--sigma: -1.0: expected a noise level (standard deviation) >= 0"),
        # a name given twice was solved and tabled twice
        ("quaternion_noise", ["--modes", "raw,unit,raw"], "--modes: 'raw' given 2 times; expected each mode once"),
        ("hessians", ["walk", "--hessians", "lbfgs,lbfgs"], "--hessians: 'lbfgs' given 2 times; expected each Hessian once"),
        ("unit_norm", ["--params", "quat3,quat3"], "--params: 'quat3' given 2 times; expected each chart once"),
        ("euler_warm_start", ["--variants", "matrix,matrix"], "--variants: 'matrix' given 2 times; expected each variant once"),
        ("quat3_norms", ["walk", "walk"], "tasks: 'walk' given 2 times; expected each task once"),
    ],
)
def test_lists_and_counts_are_checked(monkeypatch, capsys, script, argv, message):
    refused(_without_work(monkeypatch, script).main, argv, capsys, message)


@pytest.mark.parametrize(
    ("script", "argv", "message"),
    [
        # JAX's PRNGKey raised OverflowError after the compile
        ("replicates", ["--seed", str(2**64)], f"--seed: {2**64}: expected a 64-bit integer (below 2**63 in magnitude)"),
        ("replicates", ["--seed", str(-(2**63) - 1)], "expected a 64-bit integer (below 2**63 in magnitude)"),
        # each timed twice, and the second overwrote the first in the report
        ("replicates", ["--strategies", "vmap,threads,vmap"], "--strategies: 'vmap' given 2 times; expected each strategy once"),
        # NaN left out every row the rank test reads, a negative tolerance none
        ("fatrop", ["--rtol", "nan"], "--rtol: nan: expected a finite relative tolerance 0 < rtol < 1"),
        ("fatrop", ["--rtol=-1e-7"], "--rtol: -1e-07: expected a finite relative tolerance 0 < rtol < 1"),
        ("fatrop", ["--rtol", "0"], "--rtol: 0.0: expected a finite relative tolerance 0 < rtol < 1"),
        ("fatrop", ["--rtol", "inf"], "--rtol: inf: expected a finite relative tolerance 0 < rtol < 1"),
        # solved with unit_norm=True, a row the module's docstring says these charts do not get
        ("unit_norm", ["--params", "quat1"], "--params: 'quat1': its integration rows fix rho's norm at every interior knot, so a unit-norm row would contradict them"),
        ("unit_norm", ["--params", "quat3,quat2"], "--params: 'quat2': its integration rows fix rho's norm at every interior knot, so a unit-norm row would repeat them"),
    ],
)
def test_seeds_tolerances_charts_and_repeated_names_are_checked(monkeypatch, capsys, script, argv, message):
    """Found by the work itself (or not at all: a bad tolerance silently changed the rows left
    out), or accepted against the script's own docstring."""
    if script == "fatrop":
        pytest.importorskip("casadi")
    refused(_without_work(monkeypatch, script).main, argv, capsys, message)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--params", "quat1,quat2", "--modes", "raw,quat2"], "--modes: quat2: with --params quat2 it is mode raw"),
        (["--params", "quat1,se3", "--modes", "raw,unit"], "--modes: unit: needs quaternion charts; --params has se3"),
        # needs each chart's warm start (a few seconds): a flip's full turn, which SE(3)'s Log cannot write
        (["--task", "backflip", "--params", "quat1,euler", "--modes", "raw,se3"], "--modes: se3: backflip: the se3 warm start written in the euler chart is not the euler warm start"),
    ],
)
def test_quaternion_noise_checks_every_parameterization_and_mode_first(monkeypatch, capsys, argv, message):
    """The pairs were checked in `run`, after the first parameterization's compile and solves."""
    refused(_without_work(monkeypatch, "quaternion_noise").main, argv, capsys, message)


@pytest.mark.parametrize(
    ("script", "argv"),
    [
        ("compile", ["big_jump"]),
        ("euler_warm_start", ["backflip"]),
        ("factor_split", []),
        ("fatrop", ["big_jump"]),
        ("hessians", ["big_jump"]),
        ("options", ["big_jump", "--variant", "default"]),
        ("params_hop", []),
        ("profile_solve", ["big_jump"]),
        ("quat3_norms", ["walk"]),
        ("quaternion_noise", ["--modes", "raw"]),
        ("unit_norm", ["walk"]),
        ("trace_iterates", ["backflip", "--no-peer"]),
        ("solve", ["big_jump", "--no-peer"]),
        ("differentiate", []),
        ("dynamics", ["--robot", "go2"]),
        ("mu_oracle", ["big_jump"]),
        ("vmap_cpu", []),
    ],
)
def test_an_out_folder_that_is_a_file_is_refused_before_any_work(monkeypatch, capsys, tmp_path, script, argv):
    """``--out DIR`` is where write_results puts the tables after the work: a file there failed
    with a traceback once every solve was done (bench/_args.add_out checks it as it is parsed)."""
    path = tmp_path / "results"
    path.write_text("")
    refused(_without_work(monkeypatch, script).main, [*argv, "--out", str(path)], capsys, f"argument --out: '{path}': is a file; expected a folder")


#: the scripts whose positional tasks bench/_args.add_tasks defines, and what their command line needs before the tasks
TASK_SCRIPTS = [("compile", []), ("euler_warm_start", []), ("fatrop", []), ("hessians", []), ("options", ["--variant", "default"]), ("profile_solve", []), ("revisions", ["HEAD"]), ("solve", ["--no-peer"]), ("unit_norm", [])]


@pytest.mark.parametrize(("script", "before"), TASK_SCRIPTS)
def test_a_task_given_twice_is_refused_before_any_work(monkeypatch, capsys, script, before):
    """Only bench/revisions.py refused ``walk walk``: the others solved the task twice and
    tabled it twice (bench/_args.add_tasks refuses it as the command line is parsed)."""
    mod = bench_module(script) if script == "revisions" else _without_work(monkeypatch, script)
    if script == "revisions":
        monkeypatch.setattr(mod, "run_child", _no_work)
        monkeypatch.setattr(mod.tempfile, "TemporaryDirectory", _no_work)
    refused(mod.main, [*before, "walk", "big_jump", "walk"], capsys, "error: tasks: 'walk' given 2 times; expected each task once")


def test_a_task_file_named_twice_is_one_task(monkeypatch, capsys, tmp_path):
    """The same task file under two names is refused too; two files, or a file and a built-in
    task, are different tasks (a benchmark may compare a changed copy of walk with walk)."""
    import argparse
    from importlib.resources import files

    _args = bench_module("_args")
    ap = argparse.ArgumentParser(prog="bench")
    _args.add_tasks(ap, ["walk"])
    text = files("jtraj.tasks").joinpath("walk.toml").read_text()
    (tmp_path / "a.toml").write_text(text)
    (tmp_path / "b.toml").write_text(text)
    monkeypatch.chdir(tmp_path)
    assert ap.parse_args([]).tasks == ["walk"]
    assert ap.parse_args(["walk", "a.toml", "b.toml"]).tasks == ["walk", "a.toml", "b.toml"]
    with pytest.raises(SystemExit):
        ap.parse_args(["a.toml", f"{tmp_path}/a.toml"])
    assert f"'a.toml' and '{tmp_path}/a.toml' are the same task" in capsys.readouterr().err
