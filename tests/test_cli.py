"""The command line's input checks: every bad input ends with exit status 2 and one line
naming the field, the value and what was expected, before anything compiles or solves."""

import dataclasses
import json
import sys
import types
from pathlib import Path

import pytest

from jtraj import cli

GOOD_TOML = 'name = "x"\nrobot = "go2"\ntimestep = 0.05\n[[phases]]\ncontacts = ["FL_foot", "FR_foot", "RL_foot", "RR_foot"]\nduration = 0.2\n'


@pytest.fixture
def no_solve(monkeypatch):
    """Fail the test if a bad input reached the solver or a compile (the attitude benchmarks'
    and Wahba's work too: they were not watched)."""
    import jtraj.attitude.cli
    import jtraj.attitude.wahba
    import jtraj.experiments
    import jtraj.solver

    def boom(*args, **kwargs):
        raise AssertionError("a solve started despite a bad input")

    for module, name in (
        (jtraj.solver, "solve"), (jtraj.solver, "prepare"), (jtraj.experiments, "robustness"), (jtraj.experiments, "compare"),
        (jtraj.attitude.cli, "main"), (jtraj.attitude.wahba, "main_wahba"),
    ):
        monkeypatch.setattr(module, name, boom)


def _run(argv, capsys):
    code = cli.main(argv)
    err = capsys.readouterr().err
    return code, err


@pytest.mark.parametrize(
    "argv, line",
    [
        (["solve", "moonwalk"], "jtraj solve: task: 'moonwalk': unknown task; expected one of ['backflip', 'big_jump'"),
        (["robustness", "--tasks", "walk,jump"], "jtraj robustness: --tasks: 'jump': unknown task; expected some of backflip"),
        (["compare", "--params", "se3,quat9"], "jtraj compare: --params: 'quat9': unknown parameterization; expected some of se3, quat1"),
        (["robustness", "--tasks", "big_jump", "--params", "euler,se4"], "jtraj robustness: --params: 'se4': unknown parameterization"),
        (["robustness", "--tasks", "big_jump", "--sigmas", "abc"], "jtraj robustness: --sigmas: 'abc': expected comma-separated noise levels >= 0"),
        (["robustness", "--tasks", "big_jump", "--sigmas", "0.1,-1"], "jtraj robustness: --sigmas: '-1': expected"),
        (["robustness", "--tasks", "big_jump", "--replicates", "0"], "jtraj robustness: --replicates: 0: expected an integer >= 1"),
        (["robustness", "--tasks", "big_jump", "--replicates", "two"], "jtraj robustness: argument --replicates: invalid int value: 'two'"),
        (["solve", "big_jump", "--noise", "-1"], "jtraj solve: --noise: -1.0: expected a standard deviation >= 0"),
        (["solve", "big_jump", "--replicate", "2"], "jtraj solve: --replicate: 2: needs the noise level --noise SIGMA > 0"),
        (["solve", "big_jump", "--seed", "3"], "jtraj solve: --seed: 3: needs the noise level --noise SIGMA > 0 (the seed is that noise's)"),  # it was ignored
        (["solve", "big_jump", "--noise", "0.1", "--replicate", "-1"], "jtraj solve: --replicate: -1: expected an integer in [0, 4294967295]"),
        (["solve", "big_jump", "--noise", "0.1", "--replicate", "4294967296"], "jtraj solve: --replicate: 4294967296: expected an integer in [0, 4294967295]"),
        (["solve", "big_jump", "--noise", "0.1", "--seed", "-1"], "jtraj solve: --seed: -1: expected a seed >= 0 for --noise without --replicate (numpy draws that noise; --replicate R draws with JAX, which takes any)"),
        (["solve", "big_jump", "--noise", "0.1", "--noise-chart", "se3"], "jtraj solve: --noise-chart: 'se3': needs --noise SIGMA --replicate R"),
        (["solve", "walk", "--robot", "talos"], "jtraj solve: --robot: 'talos': expected ROBOT=OTHER"),
        (["compare", "--tasks", "walk", "--robot", "talos=atlas"], "jtraj compare: --robot: 'talos=atlas': unknown robot 'atlas'; expected one of g1, go2, talos, talos_full"),
        (["robustness", "--tasks", "walk", "--robot", "talos=go2"], "jtraj robustness: tasks/walk.toml: phases[0].contacts: 'left_foot': expected a contact of robot 'go2'"),
        (["solve", "big_jump", "--ipopt", "tol"], "jtraj solve: --ipopt: 'tol': expected NAME=VALUE"),
        # the last one won without a word (and changed which runs a study resumed)
        (["solve", "big_jump", "--ipopt", "max_iter=50", "--ipopt", "max_iter=100"], "jtraj solve: --ipopt: 'max_iter=100': option 'max_iter' already given; expected each option once"),
        (["robustness", "--tasks", "walk", "--set", "force_limits=rows", "--set", "force_limits=bounds"], "jtraj robustness: --set: 'force_limits=bounds': field 'force_limits' already set by --set force_limits=rows; expected each field once"),
        (["solve", "big_jump", "--ipopt", "tol=abc"], "jtraj solve: --ipopt tol: 'abc': expected a real number in (0, inf)"),
        (["solve", "big_jump", "--ipopt", "max_itr=3"], "jtraj solve: --ipopt max_itr: 3: unknown Ipopt option; did you mean max_iter"),
        (["solve", "big_jump", "--ipopt", "max_iter=2.5"], "jtraj solve: --ipopt max_iter: 2.5: expected an integer in [0, inf)"),
        (["solve", "big_jump", "--ipopt", "mu_strategy=fast"], "jtraj solve: --ipopt mu_strategy: 'fast': expected one of ['monotone', 'adaptive']"),
        (["solve", "big_jump", "--ipopt", "linear_solver=ma27"], "jtraj solve: --ipopt linear_solver: 'ma27': not available in this Ipopt build"),
        (["solve", "big_jump", "--solver", "jtraj", "--ipopt", "constr_viol_tol=-1"], "jtraj solve: --ipopt: 'constr_viol_tol=-1': jtraj option constr_viol_tol=-1: expected a positive number"),
        (["robustness", "--tasks", "big_jump", "--solver", "jtraj", "--ipopt", "foo=1"], "jtraj robustness: --ipopt: 'foo=1': unknown jtraj option(s) ['foo']"),
        # several items: the error names the bad one alone
        (["solve", "big_jump", "--solver", "jtraj", "--ipopt", "tol=1e-6", "--ipopt", "constr_viol_tol=-1"], "jtraj solve: --ipopt: 'constr_viol_tol=-1': jtraj option constr_viol_tol=-1"),
        (["attitude", "all", "--render"], "jtraj attitude: --render: all: draws one benchmark; give its name"),
        (["wahba", "--seed", "-1"], "jtraj wahba: --seed: -1: expected an integer >= 0"),
        (["robustness", "--tasks", "big_jump", "--ipopt", "max_itr=3"], "jtraj robustness: --ipopt max_itr: 3: unknown Ipopt option; did you mean max_iter"),
        # JAX's PRNGKey raised OverflowError where the noise was drawn, after the compile
        (["robustness", "--tasks", "big_jump", "--seed", str(2**63)], f"jtraj robustness: --seed: {2**63}: expected a 64-bit integer"),
        (["solve", "big_jump", "--noise", "0.1", "--seed", str(-(2**63) - 1)], f"jtraj solve: --seed: {-(2**63) - 1}: expected a 64-bit integer"),
        # an option of the other executor was ignored without a word
        (["compare", "--tasks", "big_jump", "--ray-address", "auto"], "jtraj compare: --ray-address: 'auto': needs --executor ray (the local executor does not use a cluster)\n"),
        (["robustness", "--tasks", "big_jump", "--executor", "local", "--ray-address", "auto"], "jtraj robustness: --ray-address: 'auto': needs --executor ray (the local executor does not use a cluster)\n"),
        (["compare", "--tasks", "big_jump", "--executor", "ray", "--workers", "4"], "jtraj compare: --workers: 4: is for --executor local; with --executor ray each group is a Ray task"),
        (["robustness", "--tasks", "big_jump", "--executor", "ray", "--workers", "2"], "jtraj robustness: --workers: 2: is for --executor local"),
        (["compare", "--tasks", "big_jump", "--ray-gpus", "0.5"], "jtraj compare: --ray-gpus: 0.5: needs --executor ray (the local executor's processes see the machine's GPUs)\n"),
        (["robustness", "--tasks", "big_jump", "--executor", "ray", "--ray-gpus", "-1"], "jtraj robustness: --ray-gpus: -1.0: expected a number >= 0 (the GPUs each group's Ray task reserves; a fraction shares one)\n"),
        (["robustness", "--tasks", "big_jump", "--executor", "ray", "--ray-gpus", "nan"], "jtraj robustness: --ray-gpus: nan: expected a number >= 0"),
        # a sweep's repeats would be solved and counted twice
        (["robustness", "--tasks", "big_jump", "--sigmas", "0.1,1e-1"], "jtraj robustness: --sigmas: '0.1' and '1e-1' are the same noise level (0.1); expected each noise level once\n"),
        (["robustness", "--tasks", "big_jump", "--sigmas", "0.1,0.1"], "jtraj robustness: --sigmas: '0.1' given 2 times; expected each noise level once\n"),
        (["compare", "--params", "se3,euler,se3"], "jtraj compare: --params: 'se3' given 2 times; expected each parameterization once\n"),
        (["compare", "--tasks", "walk,big_jump,tasks/walk.toml"], "jtraj compare: --tasks: 'walk' and 'tasks/walk.toml' are the same task ('walk'); expected each task once\n"),
        # OverflowError from JAX's PRNGKey, and JAX's (MLIR's) errors for a count past any memory
        (["params", "--seed", str(10**23)], f"jtraj params: --seed: {10**23}: expected a 64-bit integer (below 2**63 in magnitude)\n"),
        (["wahba", "--seed", str(10**23)], f"jtraj wahba: --seed: {10**23}: expected a 64-bit integer (below 2**63 in magnitude)\n"),
        (["wahba", "--trials", str(10**20)], f"jtraj wahba: --trials: {10**20}: expected an integer in [1, {cli.WAHBA_MAX_TRIALS}]\n"),
        (["wahba", "--iterations", str(cli.WAHBA_MAX_ITERATIONS + 1)], f"jtraj wahba: --iterations: {cli.WAHBA_MAX_ITERATIONS + 1}: expected an integer in [1, {cli.WAHBA_MAX_ITERATIONS}]\n"),
        # the explicit option was dropped and the exact Hessian used
        (["solve", "big_jump", "--exact-hessian", "--ipopt", "hessian_approximation=limited-memory"], "jtraj solve: --ipopt hessian_approximation: 'limited-memory': conflicts with --exact-hessian; expected 'exact' or no --exact-hessian\n"),
        (["solve", "big_jump", "--solver", "jtraj", "--exact-hessian", "--ipopt", "hessian=bfgs"], "jtraj solve: --ipopt hessian: 'bfgs': conflicts with --exact-hessian"),
        # a mapping the one task does not use, and a second mapping of a robot, were ignored
        (["solve", "big_jump", "--robot", "go2=talos"], "jtraj solve: --robot: 'go2=talos': task 'big_jump' is on robot 'talos'; expected --robot talos=OTHER or no --robot\n"),
        (["solve", "big_jump", "--robot", "talos=talos_full", "--robot", "go2=talos"], "jtraj solve: --robot: 'go2=talos': task 'big_jump' is on robot 'talos'"),
        (["solve", "big_jump", "--robot", "talos=talos_full", "--robot", "talos=g1"], "jtraj solve: --robot: 'talos=g1': robot 'talos' already mapped by --robot talos=talos_full; expected each robot once\n"),
        (["compare", "--tasks", "walk", "--robot", "talos=talos_full", "--robot", "talos=talos_full"], "jtraj compare: --robot: 'talos=talos_full': robot 'talos' already mapped"),
        # a sweep's mapping may be for some of its tasks, not for none of them
        (["compare", "--tasks", "walk,sideflip", "--robot", "g1=talos"], "jtraj compare: --robot: 'g1=talos': no task of --tasks is on robot 'g1'; expected a mapping of go2, talos\n"),
        # an empty --out wrote to the default folder (solve) or the current one (the sweeps)
        (["solve", "big_jump", "--out", ""], "jtraj solve: --out: '': expected a folder name (existing or to be created)\n"),
        (["compare", "--tasks", "walk", "--out", ""], "jtraj compare: --out: '': expected a folder name"),
        # the first check said ">= 3", the benchmark's then ">= 11"
        (["attitude", "satellite", "--knots", "2"], "jtraj attitude: --knots: 2: benchmark satellite: n_knots must be an integer >= 11"),
        # numpy's allocation failed (163 PiB), a traceback
        (["attitude", "satellite", "--knots", str(10**15)], f"jtraj attitude: --knots: {10**15}: expected an integer in [1, {cli.ATTITUDE_MAX_KNOTS}]\n"),
    ],
)
def test_bad_command_lines(argv, line, capsys, no_solve):
    try:
        code, err = _run(argv, capsys)
    except SystemExit as e:  # argparse's own errors
        code, err = e.code, capsys.readouterr().err
    assert code == 2
    assert err.startswith(line), err
    assert err.count("\n") == 1


def test_a_robot_that_cannot_be_loaded_is_one_line(monkeypatch, capsys, no_solve):
    """A bad JTRAJ_ROBOT_DATA (or no example-robot-data) raises RobotLoadError as the task's
    robot loads: one line naming it and exit status 2, not a traceback."""
    import jtraj.robot

    def unloadable(name):
        raise jtraj.robot.RobotLoadError(f"{jtraj.robot.ROBOT_DATA_ENV}='/nonexistent' is not a folder")

    monkeypatch.setattr(jtraj.robot, "load", unloadable)
    code, err = _run(["solve", "walk"], capsys)
    assert code == 2
    assert err == "jtraj solve: JTRAJ_ROBOT_DATA='/nonexistent' is not a folder\n"


def test_out_must_be_a_writable_folder(tmp_path, capsys, no_solve):
    afile = tmp_path / "notes.txt"
    afile.write_text("x")
    code, err = _run(["robustness", "--tasks", "big_jump", "--out", str(afile)], capsys)
    assert code == 2 and err == f"jtraj robustness: --out: {str(afile)!r}: is a file; expected a folder (existing or to be created)\n"
    code, err = _run(["compare", "--tasks", "big_jump", "--out", str(afile / "sub")], capsys)
    assert code == 2 and "is a file; expected a folder" in err
    code, err = _run(["compare", "--tasks", "big_jump", "--out", "/proc/jtraj-out"], capsys)
    assert code == 2 and err.startswith("jtraj compare: --out: '/proc/jtraj-out': cannot create a file in /proc (the system says: ")


def test_solve_checks_its_default_out_folder(monkeypatch, capsys, no_solve):
    """Without --out, `jtraj solve` writes runs/TASK_PARAM: that folder is checked too."""
    monkeypatch.chdir("/proc")
    code, err = _run(["solve", "big_jump"], capsys)
    assert code == 2 and err.startswith("jtraj solve: --out: 'runs/big_jump_se3': cannot create a file in /proc (the system says: ")


def test_plot_and_render_check_their_folders_before_drawing(tmp_path, monkeypatch, capsys):
    import jtraj.plots
    import jtraj.render

    def boom(*args, **kwargs):
        raise AssertionError("drawing started despite a bad input")

    monkeypatch.setattr(jtraj.render, "render_directory", boom)
    monkeypatch.setattr(jtraj.plots, "plot_directory", boom)
    run = tmp_path / "run"
    run.mkdir()
    (run / "trajectory.npz").write_bytes(b"x")  # no result.json
    code, err = _run(["plot", str(run)], capsys)
    assert code == 2 and err == f"jtraj plot: DIR: {str(run)!r}: expected a folder written by `jtraj solve` (result.json and trajectory.npz) or `jtraj compare` (table_iv.json)\n"
    code, err = _run(["render", str(run)], capsys)
    assert code == 2 and err == "jtraj render: --out, --strip: neither given: expected --out FILE.mp4|FILE.gif and/or --strip FILE.png\n"
    for flag, name in (("--out", "v.mp4"), ("--strip", "s.png")):
        code, err = _run(["render", str(run), flag, f"/proc/jtraj-x/{name}"], capsys)
        assert code == 2 and err.startswith(f"jtraj render: {flag}: '/proc/jtraj-x/{name}': cannot create a file in /proc"), err
    # a file name that is a folder failed in the write, after the drawing
    for flag, name, example in (("--out", "v.mp4", "motion.mp4"), ("--strip", "s.png", "keyframes.png")):
        (tmp_path / name).mkdir()
        code, err = _run(["render", str(run), flag, str(tmp_path / name)], capsys)
        assert code == 2 and err == f"jtraj render: {flag}: {str(tmp_path / name)!r}: is a folder; expected a file name, e.g. {tmp_path / name / example}\n"
    # the strip's options without --strip did nothing, without a word (exit 0 with the video)
    code, err = _run(["render", str(run), "--out", str(tmp_path / "v.gif"), "--keyframes", "10", "--layout", "overlay"], capsys)
    assert code == 2 and err == "jtraj render: --keyframes, --layout: 10, overlay: the keyframe strip's options; they need --strip FILE.png\n", err


def jtraj_render_of(folder):
    import jtraj.render

    return jtraj.render.render(folder)


def test_plot_and_render_of_an_attitude_folder(tmp_path, capsys, monkeypatch):
    """`jtraj plot` draws a rigid-body benchmark's folder with its own figure; `jtraj render`
    draws its body along its path (it refused the folder, pointing to a Python function: a saved
    benchmark could not be drawn from the command line without solving it again)."""
    from test_result import make_result, state_trajectory

    run = tmp_path / "att"
    make_result(state_trajectory()).save(run)
    code = cli.main(["render", str(run), "--out", str(tmp_path / "v.gif"), "--strip", str(tmp_path / "k.png"), "--keyframes", "3", "--width", "64", "--height", "48", "--fps", "4", "--no-shadows"])
    assert code == 0
    printed = capsys.readouterr().out
    assert f"wrote {tmp_path / 'v.gif'}" in printed and f"wrote {tmp_path / 'k.png'}" in printed
    from PIL import Image

    with Image.open(tmp_path / "v.gif") as video:
        assert video.size == (64, 48) and video.n_frames == 5  # 1 s at 4 fps
    with Image.open(tmp_path / "k.png") as keyframes:
        assert keyframes.size[1] == 48
    # a rigid body's trajectory still is not a robot's: the Python function for robots says so
    with pytest.raises(ValueError, match="or its folder with jtraj render"):
        jtraj_render_of(run)
    assert cli.main(["plot", str(run), "--out", str(tmp_path / "p")]) == 0
    # only the folder's faults are worded as DIR's: a ValueError from drawing itself is not
    import jtraj.render

    def draw_fails(*args, **kwargs):
        raise ValueError("a fault while drawing")

    monkeypatch.setattr(jtraj.render, "render_directory", draw_fails)
    with pytest.raises(ValueError, match="a fault while drawing"):
        cli.main(["render", str(run), "--out", str(tmp_path / "v.gif")])
    assert (tmp_path / "p" / "solution.png").stat().st_size > 0 and (tmp_path / "p" / "convergence.png").stat().st_size > 0


@pytest.mark.parametrize(
    "statuses, code",
    [(["solved", "solved"], 0), (["solved", "converged_but_task_failed"], cli.EXIT_TASK_FAILED), (["converged_but_task_failed", "not_converged"], cli.EXIT_NOT_CONVERGED)],
)
def test_attitude_exit_status_says_what_happened(statuses, code, monkeypatch, tmp_path):
    """`jtraj attitude`'s statuses are `jtraj solve`'s: 2 stays a bad input's."""
    import jtraj.attitude.cli as attitude_cli
    from jtraj.result import Outcome

    monkeypatch.setattr(attitude_cli, "compare_benchmarks", lambda *a, **k: [{"status": s} for s in statuses])
    fake = types.SimpleNamespace(status=Outcome(statuses[-1]))
    monkeypatch.setattr(attitude_cli, "main_attitude", lambda *a, **k: fake)
    assert cli.main(["attitude", "all", "--out", str(tmp_path)]) == code
    alone = 0 if statuses[-1] == "solved" else cli.EXIT_TASK_FAILED if statuses[-1] == "converged_but_task_failed" else cli.EXIT_NOT_CONVERGED
    assert cli.main(["attitude", "quadflip", "--out", str(tmp_path)]) == alone


def test_bad_task_file_is_one_line(tmp_path, capsys, no_solve):
    path = tmp_path / "t.toml"
    path.write_text(GOOD_TOML.replace("timestep = 0.05", "timestep = 0.05\n[costs]\nconfigration = 1.0"))
    code, err = _run(["solve", str(path)], capsys)
    assert code == 2 and err == f"jtraj solve: {path}: costs.configration: unknown key: did you mean 'configuration'? expected one of ['configuration', 'acceleration']\n"
    path.write_text(GOOD_TOML.replace('"FL_foot"', '"FL_paw"'))
    code, err = _run(["solve", str(path)], capsys)
    assert code == 2 and err.startswith(f"jtraj solve: {path}: phases[0].contacts: 'FL_paw': expected a contact of robot 'go2'")
    # the name makes the run folder, runs/NAME_PARAM: this one wrote outside runs/
    path.write_text(GOOD_TOML.replace('name = "x"', 'name = "../../escaped"'))
    code, err = _run(["solve", str(path)], capsys)
    assert code == 2 and err.startswith(f"jtraj solve: {path}: name: '../../escaped': expected a plain name for the run folders") and err.count("\n") == 1
    (tmp_path / "dir.toml").mkdir()
    code, err = _run(["solve", str(tmp_path / "dir.toml")], capsys)
    assert code == 2 and err == f"jtraj solve: task file: {str(tmp_path / 'dir.toml')!r}: is a folder; expected a .toml task file\n"


def test_real_options_accept_integers():
    options = cli._check_ipopt(["tol=1", "max_wall_time=100", "max_iter=5", "print_level=0", "mu_strategy=adaptive"])
    assert options == {"tol": 1.0, "max_wall_time": 100.0, "max_iter": 5, "print_level": 0, "mu_strategy": "adaptive"}
    assert type(options["tol"]) is float and type(options["max_iter"]) is int


def test_ipopt_string_values_in_any_case_are_ipopts_own(monkeypatch, tmp_path):
    """Ipopt takes its string values in any case, and so did this check, but the options object
    then refused ``NONE`` with a traceback (exit status 1); the values come back in Ipopt's
    own spelling, which the solve's options and --exact-hessian read."""
    import jtraj.plots
    import jtraj.solver
    from jtraj.solvers import IpoptOptions

    items = ["nlp_scaling_method=NONE", "linear_solver=MUMPS", "hessian_approximation=EXACT", "mu_strategy=Adaptive"]
    options = cli._check_ipopt(items)
    assert options == {"nlp_scaling_method": "none", "linear_solver": "mumps", "hessian_approximation": "exact", "mu_strategy": "adaptive"}
    assert IpoptOptions().merge(options).hessian == "exact"
    seen = []
    monkeypatch.setattr(jtraj.solver, "solve", lambda task, p, **kwargs: seen.append(kwargs) or types.SimpleNamespace(converged=True, success=True))
    monkeypatch.setattr(jtraj.plots, "plot_result", lambda *a, **k: None)
    monkeypatch.setattr(jtraj.plots, "plot_convergence", lambda *a, **k: None)
    argv = ["solve", "big_jump", "--exact-hessian", "--ipopt", "hessian_approximation=EXACT", "--ipopt", "nlp_scaling_method=NONE", "--out", str(tmp_path / "r")]
    assert cli.main(argv) == 0
    assert seen[-1]["ipopt_options"] == {"hessian_approximation": "exact", "nlp_scaling_method": "none"}


def test_an_option_the_options_object_refuses_is_one_line(monkeypatch, tmp_path, capsys):
    """An `InvalidOptionError` raised past the command line's own checks (the options object's)
    is an input error: one line, exit status 2, not a traceback."""
    import jtraj.solver
    from jtraj.solvers import InvalidOptionError

    def refuse(*args, **kwargs):
        raise InvalidOptionError("Ipopt option nlp_scaling_method='x': expected one of ['none']")

    monkeypatch.setattr(jtraj.solver, "solve", refuse)
    code, err = _run(["solve", "big_jump", "--out", str(tmp_path / "r")], capsys)
    assert code == 2 and err == "jtraj solve: Ipopt option nlp_scaling_method='x': expected one of ['none']\n"


def test_none_turns_off_a_jtraj_option_and_stays_a_word_for_ipopt():
    assert cli._check_ipopt(["feasibility_polish_tol=none", "feasibility_polish_iter=3"], solver="jtraj") == {"feasibility_polish_tol": None, "feasibility_polish_iter": 3}
    # a boolean option reads "false" as False (the string "false" would be truthy)
    assert cli._check_ipopt(["delta_c_mu_scaled=false", "bfgs_scaling=True"], solver="jtraj") == {"delta_c_mu_scaled": False, "bfgs_scaling": True}
    assert cli._check_ipopt(["nlp_scaling_method=none"]) == {"nlp_scaling_method": "none"}
    with pytest.raises(cli.InputError, match="feasibility_polish_tol=0: expected a positive number"):
        cli._check_ipopt(["feasibility_polish_tol=0"], solver="jtraj")
    # any other word for a boolean, or a word for a number, is refused, not run as truthy
    with pytest.raises(cli.InputError, match="delta_c_mu_scaled='maybe': expected true or false"):
        cli._check_ipopt(["delta_c_mu_scaled=maybe"], solver="jtraj")
    with pytest.raises(cli.InputError, match="armijo='small': expected a finite number"):
        cli._check_ipopt(["armijo=small"], solver="jtraj")


@pytest.mark.parametrize(
    "converged, status, code",
    [
        (True, "solved", 0),
        (True, "converged_but_task_failed", cli.EXIT_TASK_FAILED),
        (False, "not_converged", cli.EXIT_NOT_CONVERGED),
        (True, "not_converged", cli.EXIT_NOT_CONVERGED),  # converged, but over the task check's violation tolerance
    ],
)
def test_solve_exit_status_says_what_happened(converged, status, code, monkeypatch, tmp_path, capsys):
    import jtraj.plots
    import jtraj.solver
    from jtraj.result import Outcome

    fake = types.SimpleNamespace(converged=converged, status=Outcome(status), success=status == "solved")
    monkeypatch.setattr(jtraj.solver, "solve", lambda *a, **k: fake)
    monkeypatch.setattr(jtraj.plots, "plot_result", lambda *a, **k: None)
    monkeypatch.setattr(jtraj.plots, "plot_convergence", lambda *a, **k: None)
    assert cli.main(["solve", "big_jump", "--out", str(tmp_path / "r")]) == code
    # --render where nothing can be drawn: one line, the solve's status kept, 1 after a success
    import jtraj.render

    def no_opengl(*args, **kwargs):
        raise jtraj.render.RenderError("no OpenGL here (test)")

    monkeypatch.setattr(jtraj.render, "render_directory", no_opengl)
    capsys.readouterr()
    assert cli.main(["solve", "big_jump", "--out", str(tmp_path / "r"), "--render"]) == (code or 1)
    assert capsys.readouterr().err == f"jtraj solve: --render: no OpenGL here (test) (the solution is saved in {tmp_path / 'r'})\n"

    # a solve stopped by a numerical error leaves NaN poses, which render refuses (NotDrawable)
    def nan_poses(*args, **kwargs):
        raise jtraj.render.NotDrawable("NaN base poses at knots [3] (test)")

    monkeypatch.setattr(jtraj.render, "render_directory", nan_poses)
    assert cli.main(["solve", "big_jump", "--out", str(tmp_path / "r"), "--render"]) == (code or 1)
    assert capsys.readouterr().err == f"jtraj solve: --render: NaN base poses at knots [3] (test) (the solution is saved in {tmp_path / 'r'})\n"


def test_exit_statuses_are_distinct():
    assert len({0, 1, cli.EXIT_BAD_INPUT, cli.EXIT_TASK_FAILED, cli.EXIT_NOT_CONVERGED, cli.EXIT_INTERRUPTED, cli.EXIT_TERMINATED}) == 7


@pytest.mark.parametrize("command, default", [(["solve", "big_jump"], "compact"), (["compare"], "paper"), (["robustness"], "paper")])
def test_variables_option_and_its_former_name_layout(command, default):
    parser = cli.build_parser()
    assert parser.parse_args(command).variables == default
    assert parser.parse_args([*command, "--variables", "lean"]).variables == "lean"
    assert parser.parse_args([*command, "--layout", "lean"]).variables == "lean"  # the former name still parses


def test_solve_passes_variables_to_the_solver(monkeypatch, tmp_path, capsys):
    import jtraj.plots
    import jtraj.solver

    seen = {}

    def fake_solve(*args, **kwargs):
        seen.update(kwargs)
        return types.SimpleNamespace(converged=True, success=True)

    monkeypatch.setattr(jtraj.solver, "solve", fake_solve)
    monkeypatch.setattr(jtraj.plots, "plot_result", lambda *a, **k: None)
    monkeypatch.setattr(jtraj.plots, "plot_convergence", lambda *a, **k: None)
    assert cli.main(["solve", "big_jump", "--layout", "lean", "--out", str(tmp_path / "r")]) == 0
    assert seen["variables"] == "lean" and "layout" not in seen
    # the former name warns (render's --layout is another option); the new one does not
    assert capsys.readouterr().err == "jtraj solve: --layout is deprecated: it is now called --variables\n"
    assert cli.main(["solve", "big_jump", "--variables", "lean", "--out", str(tmp_path / "r")]) == 0
    assert "deprecated" not in capsys.readouterr().err
    assert seen["replicate"] is None and seen["noise_chart"] is None
    argv = ["solve", "big_jump", "--noise", "0.5", "--seed", "4", "--replicate", "7", "--out", str(tmp_path / "r")]
    assert cli.main(argv) == 0
    assert (seen["noise"], seen["seed"], seen["replicate"]) == (0.5, 4, 7)  # the study's draw 7


def test_solve_writes_its_provenance_and_its_warm_start_options(monkeypatch, tmp_path):
    """A `jtraj solve` folder recorded neither its command, date and versions nor the noise of
    its warm start. solve() writes provenance.json (tests/test_solver_inputs.py checks it) and
    is given this command for it; --noise, --seed, --replicate and --noise-chart go to solve(),
    which records them in the result's options."""
    import jtraj.plots
    import jtraj.solver

    seen = []

    def fake_solve(task, p, **kwargs):
        seen.append(kwargs)
        return types.SimpleNamespace(converged=True, success=True)

    monkeypatch.setattr(jtraj.solver, "solve", fake_solve)
    monkeypatch.setattr(jtraj.plots, "plot_result", lambda *a, **k: None)
    monkeypatch.setattr(jtraj.plots, "plot_convergence", lambda *a, **k: None)
    out = str(tmp_path / "r")
    argv = ["solve", "big_jump", "--noise", "0.5", "--seed", "4", "--replicate", "7", "--out", out]
    assert cli.main(argv) == 0
    kwargs = seen[-1]
    assert (kwargs["noise"], kwargs["seed"], kwargs["replicate"], kwargs["noise_chart"], kwargs["out"]) == (0.5, 4, 7, None, out)
    assert kwargs["command"] == ["jtraj", *argv]


@pytest.mark.parametrize("solver", ["ipopt", "jtraj"])
def test_compare_passes_the_solver_to_every_cell(solver, monkeypatch, tmp_path, capsys):
    """`jtraj compare --solver S` runs the real `experiments.compare`; each of its cells' solves
    (faked here) gets S (and its task as the sweep loaded it), and the table it prints names S
    in every row."""
    import jtraj.experiments

    cells = []

    def fake_solve(task, p, **kwargs):
        cells.append((task.name, p, kwargs["solver"]))
        return task.name, p, kwargs["solver"]

    def fake_row(result):
        task, p, used = result
        return dict(task=task, parameterization=p, status="solved", iterations=3, obj_evals=4, jac_evals=4, cost=0.0, constraint_violation=0.0, turns=None, time_s=0.1, solver=used)

    monkeypatch.setattr(jtraj.experiments, "solve", fake_solve)
    monkeypatch.setattr(jtraj.experiments, "_row", fake_row)
    argv = ["compare", "--tasks", "big_jump,walk", "--params", "se3,euler", "--out", str(tmp_path)]
    assert cli.main(argv + (["--solver", solver] if solver != "ipopt" else [])) == 0
    assert cells == [(t, p, solver) for t in ("big_jump", "walk") for p in ("se3", "euler")]
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| big_jump") or line.startswith("| walk")]
    assert len(rows) == 4 and all(line.rstrip(" |").endswith(solver) for line in rows)
    # provenance.json names this call's arguments (not the test runner's sys.argv), complete
    prov = json.loads((tmp_path / "provenance.json").read_text())
    assert prov["command"].startswith("jtraj compare --tasks big_jump,walk --params se3,euler --out ")
    assert prov["complete"] is True and "earlier" not in prov


def test_compare_rejects_an_unknown_solver(no_solve, capsys):
    with pytest.raises(SystemExit) as exit:
        cli.main(["compare", "--solver", "fatrop"])
    assert exit.value.code == cli.EXIT_BAD_INPUT
    assert "--solver: invalid choice: 'fatrop'" in capsys.readouterr().err


def test_robustness_passes_the_solver_and_noise_chart(monkeypatch, tmp_path, capsys):
    import jtraj.experiments

    seen = {}

    def fake_robustness(tasks, params, sigmas, **kwargs):
        seen.update(kwargs, sigmas=sigmas)
        (tmp_path / "table_iii.md").write_text("table\n")
        return []

    monkeypatch.setattr(jtraj.experiments, "robustness", fake_robustness)
    assert cli.main(["robustness", "--tasks", "big_jump", "--sigmas", "0.1", "--solver", "jtraj", "--out", str(tmp_path)]) == 0
    assert seen["solver"] == "jtraj" and seen["sigmas"] == [0.1]
    assert seen["ipopt_options"] is None  # the study's settings
    assert cli.main(["robustness", "--tasks", "big_jump", "--solver", "jtraj", "--ipopt", "constr_viol_tol=1e-6", "--out", str(tmp_path)]) == 0
    assert seen["ipopt_options"] == {"constr_viol_tol": 1e-6}
    assert seen["noise_chart"] is None  # each chart's own noise
    assert cli.main(["robustness", "--tasks", "big_jump", "--noise-chart", "se3", "--out", str(tmp_path)]) == 0
    assert seen["noise_chart"] == "se3"

    # a winding chart is refused by the command line's checks (check_noise_chart), before robustness()
    seen.clear()
    assert cli.main(["robustness", "--tasks", "backflip", "--params", "euler", "--noise-chart", "se3", "--out", str(tmp_path)]) == cli.EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert err.startswith("jtraj robustness: backflip: the se3 warm start written in the euler chart is not the euler warm start") and err.count("\n") == 1, err
    assert not seen


def test_set_changes_the_variables_options(monkeypatch, tmp_path, capsys):
    """``--set FIELD=VALUE`` gives the sweep a TranscriptionOptions with those fields changed;
    a field that is not a string field, a value the options refuse or a malformed item is one
    line and exit status 2, before anything is solved."""
    import jtraj.experiments
    from jtraj.transcription import PAPER_VARIABLES

    seen = {}

    def fake_robustness(tasks, params, sigmas, **kwargs):
        seen.update(kwargs)
        (tmp_path / "table_iii.md").write_text("table\n")
        return []

    monkeypatch.setattr(jtraj.experiments, "robustness", fake_robustness)
    argv = ["robustness", "--tasks", "big_jump", "--out", str(tmp_path)]
    assert cli.main([*argv, "--set", "force_limits=rows", "--set", "contact_height=row"]) == 0
    assert seen["variables"] == dataclasses.replace(PAPER_VARIABLES, force_limits="rows", contact_height="row")
    assert cli.main(argv) == 0 and seen["variables"] == "paper"  # no --set: the name itself
    for bad, expected in [
        (["--set", "force_limit=rows"], "not a field of the variables that can be set"),
        (["--set", "liftoff_force_rate=False"], "not a field of the variables that can be set"),
        (["--set", "force_limits=ball"], "expected 'bounds' or 'rows'"),
        (["--set", "force_limits"], "expected FIELD=VALUE"),
        # the field cannot be set: the message names the variables that have it
        (["--variables", "compact", "--set", "contact_height=row"], "it needs contact_variables=True (as the variables 'paper' have: variables='paper', --variables paper)"),
        (["--variables", "lean", "--set", "position_step=stepped"], "it needs acceleration_variables=True (as the variables 'paper' and 'compact' have: variables='paper', --variables paper)"),
    ]:
        seen.clear()
        assert cli.main([*argv, *bad]) == cli.EXIT_BAD_INPUT
        err = capsys.readouterr().err.strip()
        assert err.startswith("jtraj robustness: --set") and expected in err and "\n" not in err
        assert not seen


def test_robot_option_moves_the_tasks_to_that_model(monkeypatch, tmp_path, capsys):
    """``--robot talos=talos_full`` hands the sweep Task objects on the study's Talos; tasks on
    other robots, and runs without the option, keep their names."""
    import jtraj.experiments

    seen = {}

    def fake_compare(tasks, params, **kwargs):
        seen["tasks"] = tasks
        (tmp_path / "table_iv.md").write_text("table")
        return [{}]

    monkeypatch.setattr(jtraj.experiments, "compare", fake_compare)
    assert cli.main(["compare", "--tasks", "walk,sideflip", "--params", "se3", "--out", str(tmp_path), "--robot", "talos=talos_full"]) == 0
    walk, sideflip = seen["tasks"]
    assert (walk.name, walk.robot) == ("walk", "talos_full")
    assert sideflip.robot == "go2"
    assert cli.main(["compare", "--tasks", "walk", "--params", "se3", "--out", str(tmp_path)]) == 0
    assert seen["tasks"] == ["walk"]


def test_each_task_is_loaded_once(monkeypatch, tmp_path):
    """The tasks checked before the command runs are the ones it solves: each task file is
    read (and moved to the ``--robot`` model) once, by the check."""
    import jtraj.experiments
    import jtraj.plots
    import jtraj.solver
    from jtraj import task as tasks

    loads = []
    load = tasks.load
    monkeypatch.setattr(tasks, "load", lambda name: loads.append(name) or load(name))
    seen = {}

    def fake_solve(task, *args, **kwargs):
        seen["task"] = task
        return types.SimpleNamespace(converged=True, success=True)

    def fake_compare(tasks, params, **kwargs):
        seen["tasks"] = tasks
        (tmp_path / "table_iv.md").write_text("table\n")
        return [{}]

    monkeypatch.setattr(jtraj.solver, "solve", fake_solve)
    monkeypatch.setattr(jtraj.plots, "plot_result", lambda *a, **k: None)
    monkeypatch.setattr(jtraj.plots, "plot_convergence", lambda *a, **k: None)
    monkeypatch.setattr(jtraj.experiments, "compare", fake_compare)

    assert cli.main(["solve", "big_jump", "--robot", "talos=talos_full", "--out", str(tmp_path / "r")]) == 0
    assert loads == ["big_jump"] and (seen["task"].name, seen["task"].robot) == ("big_jump", "talos_full")
    loads.clear()
    assert cli.main(["compare", "--tasks", "walk,sideflip", "--params", "se3", "--out", str(tmp_path), "--robot", "talos=talos_full"]) == 0
    assert loads == ["walk", "sideflip"] and [t.robot for t in seen["tasks"]] == ["talos_full", "go2"]


def test_render_help_says_the_strip_is_at_most_480_pixels(capsys):
    """The strip's panels are capped at 480 x 480 pixels, which only a docstring said."""
    with pytest.raises(SystemExit):
        cli.main(["render", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "image width in pixels (default 640; the strip's panels at most 480)" in text
    assert "image height in pixels (default 480; the strip's panels at most 480)" in text


def test_version_and_a_subcommands_unrecognized_arguments(capsys):
    """``jtraj --version`` said "the following arguments are required: command"; an argument
    a subcommand does not take was reported by the top-level parser ("jtraj: unrecognized
    arguments"), where every other error of a subcommand's arguments names it."""
    from jtraj import __version__

    with pytest.raises(SystemExit) as info:
        cli.main(["--version"])
    assert info.value.code == 0 and capsys.readouterr().out == f"jtraj {__version__}\n"
    for argv, line in (
        (["solve", "big_jump", "extra_arg"], "jtraj solve: unrecognized arguments: extra_arg\n"),
        (["compare", "--ipopt", "max_iter=5"], "jtraj compare: unrecognized arguments: --ipopt max_iter=5\n"),
    ):
        with pytest.raises(SystemExit) as info:
            cli.main(argv)
        assert info.value.code == cli.EXIT_BAD_INPUT and capsys.readouterr().err == line


def test_every_option_says_what_it_does():
    """`jtraj CMD --help` describes every argument (the README's summary points there)."""
    import argparse

    sub = next(a for a in cli.build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    silent = [(name, b.dest) for name, parser in sub.choices.items() for b in parser._actions if not b.help]
    assert len(sub.choices) == 8 and silent == []


@pytest.mark.parametrize("command", ["compare", "robustness"])
@pytest.mark.parametrize(
    "error, message",
    [
        ("WorkerLostError", "a worker process ended without finishing its group; the runs finished before it are kept"),
        # (these two ended in a traceback around their message until they were caught too)
        ("KeyMismatchError", "walk se3: this worker keys the group's runs otherwise than the process that called the sweep (robot_hash 'a' here, 'b' there)"),
        ("GroupError", "ValueError: bad\nthe worker's traceback:\n  File ..."),
    ],
)
def test_a_workers_error_is_its_message_and_exit_1(command, error, message, monkeypatch, tmp_path, capsys):
    """`WorkerLostError` (a worker process killed, e.g. out of memory) says what was kept and
    how to go on, `KeyMismatchError` that a worker's versions differ, `GroupError` a group's
    error that could not cross processes; each ended in a traceback around its message."""
    import jtraj.executors
    import jtraj.experiments

    def lost(*args, **kwargs):
        raise getattr(jtraj.executors, error)(message)

    monkeypatch.setattr(jtraj.experiments, command, lost)
    code, err = _run([command, "--tasks", "big_jump", "--params", "se3", "--out", str(tmp_path / "out")], capsys)
    assert code == 1
    assert err == f"jtraj {command}: {message}\n"


@pytest.mark.parametrize(
    "command, kept",
    [("robustness", "; no run was solved; {out}/provenance.json records the run as unfinished"), ("compare", "; no cell was solved and no table written; {out}/provenance.json records the run as unfinished"), ("solve", "")],
)
def test_ctrl_c_is_one_line_saying_what_was_kept(command, kept, monkeypatch, tmp_path, capsys):
    """Ctrl-C in a sweep: exit 130 and one line saying where the finished work is; it was a
    traceback from wherever the solve was."""
    import jtraj.experiments
    import jtraj.solver

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(jtraj.experiments, "robustness", interrupted)
    monkeypatch.setattr(jtraj.experiments, "compare", interrupted)
    monkeypatch.setattr(jtraj.solver, "solve", interrupted)
    out = tmp_path / "out"
    argv = ["solve", "big_jump", "--out", str(out)] if command == "solve" else [command, "--tasks", "big_jump", "--params", "se3", "--out", str(out)]
    code, err = _run(argv, capsys)
    assert code == cli.EXIT_INTERRUPTED == 130
    assert err.startswith(f"jtraj {command}: interrupted{kept.format(out=out)}") and err.count("\n") == 1, err


@pytest.mark.parametrize("command", ["robustness", "compare"])
def test_ctrl_c_while_the_inputs_are_checked_says_nothing_was_written(command, monkeypatch, tmp_path, capsys):
    """Stopped while it checked its inputs (a noise chart's check takes seconds), robustness
    said its finished runs were kept in OUT/runs.jsonl, which did not exist."""

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "_check_out", interrupted)
    out = tmp_path / "out"
    code, err = _run([command, "--tasks", "big_jump", "--params", "se3", "--out", str(out)], capsys)
    assert code == cli.EXIT_INTERRUPTED
    assert err.startswith(f"jtraj {command}: interrupted; nothing was written to {out}") and err.count("\n") == 1, err
    assert not out.exists()


def test_ctrl_c_after_no_resume_says_to_run_without_it(monkeypatch, tmp_path, capsys):
    """With --no-resume the same command moves the runs aside again and solves every run: the
    interrupt said that the same command again resumes from them."""
    import jtraj.experiments

    out = tmp_path / "out"

    def interrupted(*args, **kwargs):
        (out / "runs.jsonl").write_text("{}\n")  # a run solved before it
        raise KeyboardInterrupt

    monkeypatch.setattr(jtraj.experiments, "robustness", interrupted)
    code, err = _run(["robustness", "--tasks", "big_jump", "--params", "se3", "--no-resume", "--out", str(out)], capsys)
    assert code == cli.EXIT_INTERRUPTED
    assert err == f"jtraj robustness: interrupted; the runs finished are kept in {out}/runs.jsonl, and the same command without --no-resume resumes from them\n"


def test_ctrl_c_before_the_first_run_of_no_resume_says_where_the_earlier_runs_went(monkeypatch, tmp_path, capsys):
    """--no-resume moves runs.jsonl to runs.jsonl.previous-N, then the study begins: stopped
    before its first run, it said that no run was solved, and not where the earlier runs were."""
    import jtraj.experiments

    out = tmp_path / "out"
    out.mkdir()
    (out / "runs.jsonl").write_text("{}\n")
    for n in (1, 3):
        (out / f"runs.jsonl.previous-{n}").write_text("{}\n")  # earlier studies' runs moved aside

    def interrupted(*args, **kwargs):
        jtraj.experiments._move_aside(out / "runs.jsonl", "previous")  # as robustness() does first
        raise KeyboardInterrupt

    monkeypatch.setattr(jtraj.experiments, "robustness", interrupted)
    code, err = _run(["robustness", "--tasks", "big_jump", "--params", "se3", "--no-resume", "--out", str(out)], capsys)
    assert code == cli.EXIT_INTERRUPTED
    assert err == f"jtraj robustness: interrupted; no run was solved; the earlier runs were moved to {out}/runs.jsonl.previous-2; {out}/provenance.json records the run as unfinished\n"
    # nothing to move: not said (an older study's previous-N is not this run's)
    monkeypatch.setattr(jtraj.experiments, "robustness", lambda *a, **k: (_ for _ in ()).throw(KeyboardInterrupt))
    code, err = _run(["robustness", "--tasks", "big_jump", "--params", "se3", "--no-resume", "--out", str(out)], capsys)
    assert err == f"jtraj robustness: interrupted; no run was solved; {out}/provenance.json records the run as unfinished\n"


def test_sigterm_stops_a_command_as_ctrl_c_does(monkeypatch, tmp_path, capsys):
    """SIGTERM (a job scheduler's, ``kill``) ended the process at once, without the cleanup of
    Ctrl-C: --workers processes went on solving, then waited forever. It takes Ctrl-C's way
    (the executors stop their workers, the message says what was kept), exit status 143, and
    the handler before the command is put back."""
    import os
    import signal
    import threading
    import time

    import jtraj.experiments

    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signal handlers are the main thread's")

    class Sentinel(Exception):
        """Raised by the SIGTERM handler in place before the command (the old default killed pytest)."""

    def sentinel(signum, frame):
        raise Sentinel

    out = tmp_path / "out"

    def terminated(*args, **kwargs):
        (out / "runs.jsonl").write_text("{}\n")  # a run solved before it
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(10)  # the signal's handler runs before this ends
        raise AssertionError("SIGTERM did not stop the command")

    monkeypatch.setattr(jtraj.experiments, "robustness", terminated)
    previous = signal.signal(signal.SIGTERM, sentinel)
    try:
        code, err = _run(["robustness", "--tasks", "big_jump", "--params", "se3", "--out", str(out)], capsys)
        assert signal.getsignal(signal.SIGTERM) is sentinel
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert code == cli.EXIT_TERMINATED == 143
    assert err == f"jtraj robustness: terminated (SIGTERM); the runs finished are kept in {out}/runs.jsonl, and the same command again resumes from them\n"


@pytest.mark.parametrize(
    "command, words",
    [("compare", ["table_iv.json", "does not resume", "OUT/TASK_PARAM"]), ("robustness", ["OUT/runs.jsonl", "resumes", "table_iii.md", "fig2.png"])],
)
def test_sweep_help_says_what_it_writes_and_how_it_resumes(command, words, capsys):
    """`jtraj compare --help` and `jtraj robustness --help` had no description: nothing said
    what they write, that robustness resumes from OUT/runs.jsonl, or that compare does not."""
    with pytest.raises(SystemExit):
        cli.main([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert all(w in text for w in words), text


def test_a_mujoco_gl_that_mujoco_refuses_is_one_line():
    """MuJoCo refuses an unknown MUJOCO_GL when it is imported: every command ended in a
    traceback from that import. A fresh process, since this one has imported MuJoCo."""
    import os
    import subprocess

    env = {**os.environ, "MUJOCO_GL": "foo"}
    done = subprocess.run([sys.executable, "-m", "jtraj.cli", "solve", "big_jump"], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == cli.EXIT_BAD_INPUT, done.stderr
    assert done.stderr == "jtraj solve: invalid value for environment variable MUJOCO_GL: foo; expected egl, osmesa or glfw, or leave it unset (jtraj then takes egl or osmesa where there is no display and their libraries load)\n"


#: run first in a child process: OpenGL's libraries fail to load, as on a machine without them
_NO_GL_LIBRARIES = """
import ctypes, os, sys
_cdll = ctypes.CDLL.__init__
def _refuse(self, name, *args, **kwargs):
    if name and any(lib in str(name) for lib in ("libEGL", "libOpenGL", "libGL.", "libOSMesa")):
        raise OSError(f"{name}: cannot open shared object file (test)")
    _cdll(self, name, *args, **kwargs)
ctypes.CDLL.__init__ = _refuse
"""


def test_without_opengl_libraries_everything_but_drawing_works():
    """`import jtraj` set MUJOCO_GL=egl wherever there was no display; without libEGL that made
    `import mujoco` fail (PyOpenGL's AttributeError), and with it every robot. It now takes
    osmesa or, failing that, none: robots load, and drawing says what to install."""
    import os
    import subprocess

    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY", "WAYLAND_DISPLAY")}
    script = _NO_GL_LIBRARIES + (
        "import jtraj, mujoco\n"
        "from jtraj import robot, render\n"
        "print(os.environ['MUJOCO_GL'], robot.load('go2').nv)\n"
        "try:\n    render._mujoco()\nexcept render.RenderError as e:\n    print(e)\n"
    )
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    first, message = done.stdout.splitlines()
    assert first == "disable 18"
    assert message.startswith("MuJoCo has no OpenGL backend (MUJOCO_GL='disable'; jtraj found neither libEGL with libOpenGL or libGL nor libOSMesa to load)")


def test_a_mujoco_gl_whose_library_is_missing_is_one_line():
    """MUJOCO_GL=egl (or osmesa) set by the user where its library does not load: every command
    that loads a robot ended in PyOpenGL's AttributeError traceback."""
    import os
    import subprocess

    env = {**os.environ, "MUJOCO_GL": "egl"}
    script = _NO_GL_LIBRARIES + "from jtraj import cli\nsys.exit(cli.main(['solve', 'big_jump']))\n"
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == cli.EXIT_BAD_INPUT, done.stderr[-3000:]
    assert done.stderr.startswith("jtraj solve: MUJOCO_GL='egl': MuJoCo could not load that OpenGL backend (") and done.stderr.count("\n") == 1, done.stderr
    assert "apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri libopengl0" in done.stderr  # the README's packages


def test_the_egl_packages_are_the_same_everywhere():
    """The README, .ci/run and the render errors name the same packages, libOpenGL among them
    (jtraj takes EGL only where libOpenGL or libGL loads beside libEGL: the README and the render
    errors named three packages, none of which brings it)."""
    import pathlib

    from jtraj import render

    root = pathlib.Path(__file__).resolve().parents[1]
    packages = "libegl1 libegl-mesa0 libgl1-mesa-dri libopengl0"
    assert packages in " ".join((root / "README.md").read_text().split())
    assert f"install -y -qq {packages}" in (root / ".ci" / "run").read_text()
    source = pathlib.Path(render.__file__).read_text()
    assert source.count("apt-get install libegl1") == source.count(f"apt-get install {packages}") >= 2


def test_the_headless_backend_is_one_whose_libraries_load():
    from jtraj._gl import headless_backend

    for present, backend in [
        ({"EGL", "OpenGL", "GL", "OSMesa"}, "egl"),
        ({"EGL", "GL"}, "egl"),
        ({"EGL", "OSMesa"}, "osmesa"),  # libEGL alone: PyOpenGL's EGL backend needs an OpenGL library too
        ({"OSMesa"}, "osmesa"),
        ({"EGL"}, "disable"),
        (set(), "disable"),
    ]:
        assert headless_backend(present.__contains__) == backend, present


def test_attitude_render_refuses_a_mujoco_gl_that_mujoco_refuses_before_solving(tmp_path):
    """jtraj attitude skips MuJoCo's import, but --render draws with it: the refusal still comes
    first, as one line, not as a traceback after the solve."""
    import os
    import subprocess

    env = {**os.environ, "MUJOCO_GL": "foo"}
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-m", "jtraj.cli", "attitude", "satellite", "--render", "--out", str(out)], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == cli.EXIT_BAD_INPUT, done.stderr
    assert done.stderr.startswith("jtraj attitude: invalid value for environment variable MUJOCO_GL: foo; ") and done.stderr.count("\n") == 1, done.stderr
    assert not out.exists()


@pytest.mark.parametrize("argv, code, err", [(["params"], 0, ""), (["wahba", "--trials", "0"], cli.EXIT_BAD_INPUT, f"jtraj wahba: --trials: 0: expected an integer in [1, {cli.WAHBA_MAX_TRIALS}]\n")])
def test_commands_without_a_robot_do_not_import_mujoco(argv, code, err):
    """jtraj params and wahba load no robot, yet every command imported MuJoCo at its start to
    check MUJOCO_GL (0.1 to 0.2 s), and refused to run where MuJoCo refuses the variable; an
    input error imported it too, to list jtraj.experiments's errors."""
    import os
    import subprocess

    env = {**os.environ, "MUJOCO_GL": "foo"}
    script = "import sys; from jtraj import cli; code = cli.main(sys.argv[1:]); assert 'mujoco' not in sys.modules, 'imported mujoco'; sys.exit(code)"
    done = subprocess.run([sys.executable, "-c", script, *argv], env=env, capture_output=True, text=True, timeout=300)
    assert (done.returncode, done.stderr) == (code, err)


def test_ctrl_c_in_compare_before_any_cell_says_none_finished(monkeypatch, tmp_path, capsys):
    """compare's interrupt says how many cells its table holds; with none, the line must not
    send the user to a table_iv.json that an earlier run left."""
    import jtraj.experiments

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt("none of the 2 cells had finished")

    monkeypatch.setattr(jtraj.experiments, "compare", interrupted)
    code, err = _run(["compare", "--tasks", "big_jump", "--params", "se3,euler", "--out", str(tmp_path / "out")], capsys)
    assert code == cli.EXIT_INTERRUPTED
    assert err == "jtraj compare: interrupted; none of the 2 cells had finished (the same command again solves every cell)\n"


@pytest.mark.parametrize("when", ["checking inputs", "after its cells"])
def test_ctrl_c_in_compare_outside_its_cells_says_what_was_written(when, monkeypatch, tmp_path, capsys):
    """An interrupt that compare() did not word (while the inputs were checked, or once its
    cells were done) said OUT/table_iv.json holds the cells finished before it: there was no
    table yet, or it held them all."""
    import jtraj.experiments
    import jtraj.provenance

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    def solved(tasks, params, out, **kwargs):
        return [dict(task=str(t), parameterization=p) for t in tasks for p in params]

    out = tmp_path / "out"
    if when == "checking inputs":
        monkeypatch.setattr(cli, "_check_out", interrupted)
        said = f"nothing was written to {out}"
    else:
        monkeypatch.setattr(jtraj.experiments, "compare", solved)
        monkeypatch.setattr(jtraj.provenance, "end_run", interrupted)
        said = f"{out}/table_iv.json holds all 2 cells"
    code, err = _run(["compare", "--tasks", "big_jump", "--params", "se3,euler", "--out", str(out)], capsys)
    assert code == cli.EXIT_INTERRUPTED
    assert err == f"jtraj compare: interrupted; {said} (the same command again solves every cell)\n"
    assert out.exists() == (when != "checking inputs")


def test_robustness_refuses_a_winding_noise_chart_before_writing_out(tmp_path, capsys, no_solve):
    """A noise chart whose poses cannot be given to a parameterization (the back-flip's Euler
    warm start winds) was found inside robustness(), after OUT/provenance.json had been written
    as an unfinished run."""
    out = tmp_path / "study"
    code, err = _run(["robustness", "--tasks", "backflip", "--params", "euler", "--noise-chart", "se3", "--replicates", "1", "--sigmas", "0.1", "--out", str(out)], capsys)
    assert code == cli.EXIT_BAD_INPUT and err.startswith("jtraj robustness: ") and err.count("\n") == 1, err
    assert not (out / "provenance.json").exists()


def test_solve_on_another_robot_has_its_own_default_folder(monkeypatch, tmp_path):
    """`jtraj solve big_jump --robot talos=talos_full` wrote to runs/big_jump_se3, over the
    solve on the task's own robot."""
    import jtraj.plots
    import jtraj.solver

    outs = []
    monkeypatch.setattr(jtraj.solver, "solve", lambda task, p, **kwargs: (outs.append(kwargs["out"]), types.SimpleNamespace(converged=True, success=True))[1])
    monkeypatch.setattr(jtraj.plots, "plot_result", lambda *a, **k: None)
    monkeypatch.setattr(jtraj.plots, "plot_convergence", lambda *a, **k: None)
    monkeypatch.chdir(tmp_path)
    assert cli.main(["solve", "big_jump"]) == 0
    assert cli.main(["solve", "big_jump", "--robot", "talos=talos_full"]) == 0
    assert cli.main(["solve", "sideflip", "--robot", "talos=talos_full"]) == cli.EXIT_BAD_INPUT  # a Go2 task: the mapping would be ignored
    assert outs == ["runs/big_jump_se3", "runs/big_jump_se3_talos_full"]


def test_a_task_whose_first_knot_is_below_the_terrain_is_one_line_before_the_solve(tmp_path, capsys):
    """A task starting on Talos's hands put its feet 0.74 m below the ground at the fixed first
    knot and went to the solver, which could only fail; it is refused when its NLP is built."""
    import importlib.resources

    text = (importlib.resources.files("jtraj.tasks") / "big_jump.toml").read_text()
    path = tmp_path / "hands.toml"
    path.write_text(text.replace('contacts = ["left_foot", "right_foot"]', 'contacts = ["left_hand", "right_hand"]', 1))
    code, err = _run(["solve", str(path), "--out", str(tmp_path / "run")], capsys)
    assert code == cli.EXIT_BAD_INPUT and err.count("\n") == 1
    assert err.startswith(f"jtraj solve: {path}: phases[0].contacts: ['left_hand', 'right_hand']: the standing pose of 'talos' lowered until phase 0's contacts touch the terrain puts left_foot_")
    assert not (tmp_path / "run").exists()
    # a sweep refuses it with its other inputs, not when its cells begin (after the cells
    # before them had solved, with OUT/provenance.json written), on another robot model too
    for command in (["compare", "--params", "se3"], ["robustness", "--params", "se3", "--sigmas", "0.1", "--replicates", "1"]):
        for robot in ([], ["--robot", "talos=talos_full"]):
            code, err = _run([*command, "--tasks", f"big_jump,{path}", *robot, "--out", str(tmp_path / "sweep")], capsys)
            assert code == cli.EXIT_BAD_INPUT and err.count("\n") == 1, err
            assert err.startswith(f"jtraj {command[0]}: {path}: phases[0].contacts: ['left_hand', 'right_hand']: the standing pose of 'talos")
            assert not (tmp_path / "sweep").exists()


def test_a_rule_the_euler_angles_cannot_write_is_one_line_before_the_sweep(tmp_path, capsys, no_solve):
    """A task file's warm-start rule about a diagonal axis, which the Euler angles with the
    study's variables cannot write: a traceback from warm_start, and compare found it after the
    other charts' cells had solved (euler runs last there)."""
    import importlib.resources

    text = (importlib.resources.files("jtraj.tasks") / "backflip.toml").read_text()
    path = tmp_path / "diagonal.toml"
    path.write_text(text.replace("\naxis = [0.0, 1.0, 0.0]", "\naxis = [1.0, 1.0, 0.0]", 1))
    line = f"{path}: warm_start_rules[0].axis: [1.0, 1.0, 0.0]: with the Euler angles and warm_start_euler='angles'"
    code, err = _run(["solve", str(path), "--param", "euler", "--variables", "paper", "--out", str(tmp_path / "run")], capsys)
    assert code == cli.EXIT_BAD_INPUT and err.startswith(f"jtraj solve: {line}") and err.count("\n") == 1, err
    for command in (["compare"], ["robustness", "--sigmas", "0.1", "--replicates", "1"]):
        code, err = _run([*command, "--tasks", f"big_jump,{path}", "--params", "se3,euler", "--out", str(tmp_path / "sweep")], capsys)
        assert code == cli.EXIT_BAD_INPUT and err.startswith(f"jtraj {command[0]}: {line}") and err.count("\n") == 1, err
        assert not (tmp_path / "sweep").exists()
    # other variables rotate the poses: the sweep goes on to its solves
    with pytest.raises(AssertionError, match="a solve started"):
        _run(["compare", "--tasks", str(path), "--params", "euler", "--variables", "compact", "--out", str(tmp_path / "sweep")], capsys)


def test_attitude_and_wahba_refuse_an_output_they_could_not_write_before_solving(tmp_path, capsys, monkeypatch):
    """A file at OUT/BENCH_VARIANT failed jtraj attitude after its solve, a folder at
    OUT/wahba.png jtraj wahba after its other two files (tracebacks); a knot count a benchmark
    refuses was found after OUT/provenance.json was written."""
    import jtraj.attitude.cli
    import jtraj.attitude.wahba

    monkeypatch.setattr(jtraj.attitude.cli, "main", lambda *a, **k: pytest.fail("solved after a bad input"))
    monkeypatch.setattr(jtraj.attitude.wahba, "main_wahba", lambda *a, **k: pytest.fail("solved after a bad input"))
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "quadflip_naive").write_text("a file")
    (tmp_path / "w" / "wahba.png").mkdir(parents=True)
    code, err = _run(["attitude", "all", "--out", str(tmp_path / "a")], capsys)
    assert code == 2 and err == f"jtraj attitude: --out: '{tmp_path / 'a' / 'quadflip_naive'}': is a file; expected a folder (existing or to be created)\n"
    code, err = _run(["wahba", "--out", str(tmp_path / "w")], capsys)
    assert code == 2 and err == f"jtraj wahba: --out: '{tmp_path / 'w'}': {tmp_path / 'w' / 'wahba.png'} is a folder; expected room for the file wahba.png\n"
    code, err = _run(["attitude", "quadflip", "--knots", "12", "--out", str(tmp_path / "k")], capsys)
    assert code == 2 and "two attitude waypoints on one knot" in err and not (tmp_path / "k").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "w"] and not (tmp_path / "w" / "wahba.npz").exists()


@pytest.mark.parametrize("command, name", [("compare", "table_iv.md"), ("robustness", "fig2.png"), ("robustness", "table_iii.json")])
def test_sweeps_refuse_a_folder_where_an_output_file_goes(monkeypatch, tmp_path, capsys, command, name):
    """A folder at OUT/fig2.png (or a table) failed jtraj robustness and compare with a
    traceback after all their solves (robustness: at its first checkpoint)."""
    import jtraj.experiments

    monkeypatch.setattr(jtraj.experiments, command, lambda *a, **k: pytest.fail("solved after a bad input"))
    (tmp_path / "o" / name).mkdir(parents=True)
    code, err = _run([command, "--tasks", "big_jump", "--params", "se3", "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and err == f"jtraj {command}: --out: '{tmp_path / 'o'}': {tmp_path / 'o' / name} is a folder; expected room for the file {name}\n"
    assert [p.name for p in (tmp_path / "o").iterdir()] == [name]  # no provenance.json


@pytest.mark.parametrize("name", ["motion.mp4", "result.json", "convergence.png"])
def test_solve_refuses_a_folder_where_a_result_file_goes(monkeypatch, tmp_path, capsys, name):
    """A folder at OUT/motion.mp4 (any of the files a result's folder holds, which saving it
    removes or writes, --render or not) ended jtraj solve, and jtraj.solve(out=...), in an
    IsADirectoryError after the solve, its solution unsaved."""
    import jtraj
    import jtraj.solver

    monkeypatch.setattr(jtraj.solver, "prepare", lambda *a, **k: pytest.fail("solved after a bad input"))
    (tmp_path / "o" / name).mkdir(parents=True)
    code, err = _run(["solve", "big_jump", "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and err == f"jtraj solve: --out: '{tmp_path / 'o'}': {tmp_path / 'o' / name} is a folder; expected room for the file {name}\n"
    with pytest.raises(ValueError, match=rf"solve: out=.*{name} is a folder; expected room for the file {name}"):
        jtraj.solve("big_jump", out=tmp_path / "o")
    assert [p.name for p in (tmp_path / "o").iterdir()] == [name]


def test_attitude_refuses_a_folder_where_its_files_go_and_a_variant_with_all(tmp_path, capsys, monkeypatch):
    """A folder at OUT/BENCH_VARIANT/plot.png (or result.json, or table.md with all) failed
    jtraj attitude after its solve with a traceback, its provenance left unfinished;
    --variant with all was ignored (all solves both)."""
    import jtraj.attitude.cli

    monkeypatch.setattr(jtraj.attitude.cli, "main", lambda *a, **k: pytest.fail("solved after a bad input"))
    # (a folder at a file Result.save removes, provenance.json or trajectory.png, passed the
    # check and failed after the solve: the check lists every file of a result's folder now)
    for where, argv in (
        ("quadflip_attitude/plot.png", ["quadflip"]),
        ("quadflip_naive/result.json", ["quadflip", "--variant", "naive"]),
        ("table.md", ["all"]),
        ("satellite_attitude/motion.mp4", ["satellite", "--render"]),
        ("barrelroll_attitude/trajectory.png", ["barrelroll"]),
        ("barrelroll_attitude/provenance.json", ["barrelroll"]),
    ):
        out = tmp_path / where.replace("/", "_")
        (out / where).mkdir(parents=True)
        folder = out / where.rsplit("/", 1)[0] if "/" in where else out
        name = where.rsplit("/", 1)[-1]
        code, err = _run(["attitude", *argv, "--out", str(out)], capsys)
        assert code == 2 and err == f"jtraj attitude: --out: '{folder}': {out / where} is a folder; expected room for the file {name}\n", err
        assert not (out / "provenance.json").exists()
    code, err = _run(["attitude", "all", "--variant", "naive", "--out", str(tmp_path / "v")], capsys)
    assert code == 2 and err == "jtraj attitude: --variant: 'naive': is for one benchmark; 'all' solves both variants of each\n"


def test_wahba_writes_its_provenance(tmp_path, capsys, monkeypatch):
    """jtraj wahba wrote no provenance.json (every other command writes one)."""
    import jtraj.attitude.wahba

    monkeypatch.setattr(jtraj.attitude.wahba, "main_wahba", lambda out, **k: (tmp_path / "wahba.json").write_text("{}"))
    code, _ = _run(["wahba", "--trials", "3", "--out", str(tmp_path)], capsys)
    prov = json.loads((tmp_path / "provenance.json").read_text())
    assert code == 0 and prov["command"] == f"jtraj wahba --trials 3 --out {tmp_path}" and prov["complete"] is True


def test_attitude_writes_its_provenance(tmp_path, capsys, monkeypatch):
    """jtraj attitude's folder had no provenance.json (jtraj solve's and the sweeps' do)."""
    import jtraj.attitude.cli

    monkeypatch.setattr(jtraj.attitude.cli, "main", lambda *a, **k: 0)
    code, _ = _run(["attitude", "quadflip", "--out", str(tmp_path)], capsys)
    prov = json.loads((tmp_path / "provenance.json").read_text())
    assert code == 0 and prov["command"] == f"jtraj attitude quadflip --out {tmp_path}" and prov["complete"] is True


@pytest.mark.parametrize("command", ["robustness", "compare"])
def test_a_closed_output_stops_a_sweep_with_one_line(monkeypatch, tmp_path, capsys, command):
    """`jtraj robustness ... | head -1`: the closed pipe ended the study in a BrokenPipeError
    traceback. It is one line saying what was kept, exit status 1."""
    import jtraj.experiments

    def closed(*args, **kwargs):
        (tmp_path / "o" / ("runs.jsonl" if command == "robustness" else "table_iv.json")).write_text("{}\n")  # work done before it
        e = BrokenPipeError(32, "Broken pipe")
        if command == "compare":
            e.add_note(f"{tmp_path / 'o' / 'table_iv.json'} holds the 1 of 2 cells finished before it")
        raise e

    monkeypatch.setattr(jtraj.experiments, command, closed)
    code, err = _run([command, "--tasks", "big_jump", "--params", "se3,quat1", "--out", str(tmp_path / "o")], capsys)
    kept = (
        f"the runs finished are kept in {tmp_path / 'o' / 'runs.jsonl'}, and the same command again resumes from them" if command == "robustness"
        else f"{tmp_path / 'o' / 'table_iv.json'} holds the 1 of 2 cells finished before it (the same command again solves every cell)"
    )
    assert code == 1 and err == f"jtraj {command}: stopped: its output was closed (broken pipe); {kept}\n"


def test_a_closed_stderr_too_ends_with_status_1_not_a_traceback(monkeypatch, tmp_path):
    """`jtraj robustness ... 2>&1 | head`: stderr is the closed pipe too, and the one line that
    says what was kept raised a second BrokenPipeError out of main (a traceback)."""
    import io

    import jtraj.experiments

    class Closed(io.StringIO):
        def write(self, s):
            raise BrokenPipeError(32, "Broken pipe")

        def fileno(self):  # a test's stream: no descriptor to point at /dev/null
            raise io.UnsupportedOperation("fileno")

    def closed(*args, **kwargs):
        print("a progress line")  # the first write to the closed pipe

    monkeypatch.setattr(jtraj.experiments, "robustness", closed)
    monkeypatch.setattr(sys, "stdout", Closed())
    monkeypatch.setattr(sys, "stderr", Closed())
    assert cli.main(["robustness", "--tasks", "big_jump", "--params", "se3", "--out", str(tmp_path / "o")]) == 1


def test_python_dash_m_jtraj_is_the_command(capsys):
    """`python -m jtraj` (no jtraj/__main__.py before: "No module named jtraj.__main__")."""
    import subprocess

    child = subprocess.run([sys.executable, "-m", "jtraj", "params", "--seed", "3"], capture_output=True, text=True, timeout=300)
    assert cli.main(["params", "--seed", "3"]) == child.returncode == 0, child.stderr[-2000:]
    ours = capsys.readouterr().out.splitlines()
    # the same pose and rows (the last digits of the errors may follow this process's XLA flags)
    assert child.stdout.splitlines()[0] == ours[0] and [r.split()[0] for r in child.stdout.splitlines()] == [r.split()[0] for r in ours]


def test_a_broken_mujoco_is_not_called_a_bad_mujoco_gl(tmp_path):
    """import jtraj sets MUJOCO_GL on a machine without a display, and every failure to import
    MuJoCo (a broken install, a C++ library mismatch) was reported as that backend's missing
    library, exit status 2, with advice to install libegl1: only the OpenGL backend's own
    failures are, the others keep their traceback."""
    import os
    import subprocess

    (tmp_path / "mujoco").mkdir()
    (tmp_path / "mujoco" / "__init__.py").write_text("raise ImportError(\"libstdc++.so.6: version `GLIBCXX_3.4.32' not found\")\n")
    env = {**os.environ, "MUJOCO_GL": "egl", "PYTHONPATH": str(tmp_path)}
    done = subprocess.run([sys.executable, "-c", "import sys; from jtraj import cli; sys.exit(cli.main(['solve', 'big_jump']))"], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 1 and "GLIBCXX_3.4.32" in done.stderr and "Traceback" in done.stderr, done.stderr[-2000:]
    assert "could not load that OpenGL backend" not in done.stderr


def test_jtraj_solve_holds_its_folder_until_its_figures_are_written(monkeypatch, tmp_path, capsys):
    """solve() let the folder go once its result was saved, and the figures (and --render's
    files) were written with the folder free for another run."""
    from test_provenance import _flock_free

    import jtraj.plots
    import jtraj.solver

    out = tmp_path / "out"
    drawn = []

    def fake_solve(task, *args, **kwargs):
        return types.SimpleNamespace(converged=True, success=True)

    def fake_plot(result, path):
        drawn.append(_flock_free(out))
        Path(path).write_text("a figure")

    monkeypatch.setattr(jtraj.solver, "solve", fake_solve)
    monkeypatch.setattr(jtraj.plots, "plot_result", fake_plot)
    monkeypatch.setattr(jtraj.plots, "plot_convergence", fake_plot)
    assert cli.main(["solve", "big_jump", "--out", str(out)]) == 0
    assert drawn == [False, False] and _flock_free(out)
