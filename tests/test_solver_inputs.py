"""The solvers' inputs (initial guesses, parameters, bounds) are checked on the host, before
anything compiles, with errors that name them; a problem Ipopt calls invalid is invalid for
jtraj's solver too. Tiny knot problems (tests/test_ipm.py's double integrator)."""

import json
import re
from types import SimpleNamespace

import jax.numpy as jnp
import numpy as np
import pytest
from test_ipm import K, double_integrator

from jtraj import solvers
from jtraj.nlp import KnotNLP
from jtraj.solvers import Status
from jtraj.solvers.base import bind


def speed_limited(theta=None) -> KnotNLP:
    """The double integrator with its speed limits as parameters vmin <= v <= vmax."""
    theta = {"vmin": jnp.asarray(-1.0), "vmax": jnp.asarray(0.35)} if theta is None else theta
    return double_integrator(lambda th: th["vmin"] * jnp.ones((K, 1)), lambda th: th["vmax"] * jnp.ones((K, 1)), theta)


def no_program(nlp: KnotNLP) -> bool:
    """Nothing was built for ``nlp`` (let alone compiled): no program of jtraj's solver, and no
    call of the NLP's jitted functions, which Ipopt's callbacks make (only the solver programs
    were looked at, and an Ipopt that compiled its callbacks before its checks passed)."""
    return not nlp.solver_programs and all(getattr(nlp, f)._cache_size() == 0 for f in ("objective", "gradient", "constraints"))


def test_theta_none_means_the_nlps_own_parameters():
    nlp = speed_limited()
    jt = solvers.get("jtraj")
    given = jt.solve(nlp, np.zeros(nlp.n), nlp.theta)
    assert given.converged
    default = jt.solve(nlp, np.zeros(nlp.n))  # was TypeError: 'NoneType' object is not subscriptable
    assert default.status is given.status and default.stats.iterations == given.stats.iterations
    np.testing.assert_array_equal(default.x, given.x)
    batch, _, compiled = jt.solve_batch(nlp, np.zeros((1, nlp.n)), strategy="threads")
    assert compiled == 0.0  # the program of the solves above
    np.testing.assert_array_equal(batch[0].x, given.x)


@pytest.mark.parametrize("x0s", [np.zeros(K * 3), np.zeros((0, K * 3)), [], np.zeros((2, K * 3, 1)), np.zeros((2, 5))])
def test_solve_batch_wants_a_batch_of_whole_guesses(x0s):
    nlp = double_integrator()
    with pytest.raises(ValueError, match=r"x0s of shape .*expected B >= 1 initial guesses, of shape \(B, 48\) or \(B, 16, 3\)"):
        solvers.get("jtraj").solve_batch(nlp, x0s, strategy="threads")
    assert no_program(nlp)


@pytest.mark.parametrize("solver", ["jtraj", "ipopt"])
@pytest.mark.parametrize("x0", [0.3, [0.3], np.zeros((K * 3, 1)), np.zeros((K, 2)), np.zeros(K * 3 + 1)])
def test_an_initial_guess_of_another_size_is_refused(solver, x0):
    nlp = double_integrator()
    with pytest.raises(ValueError, match=r"x0 of shape .*: expected \(48,\) or \(16, 3\)"):
        solvers.get(solver).solve(nlp, x0)
    assert no_program(nlp)


def test_ipopt_takes_a_knot_shaped_guess():
    """A (K, n) guess is read knot after knot, as its row-major flattening: a guess that differs
    from knot to knot and variable to variable (an all-zero one would hide a transposed or
    column-major reading) starts where the flat guess starts and ends where it ends."""
    nlp = double_integrator()
    x0 = np.random.default_rng(0).uniform(-0.1, 0.1, (K, 3))
    firsts = []
    for guess in (x0, x0.reshape(-1)):
        rec = solvers.RecordIterates()
        firsts.append(rec)
        assert solvers.get("ipopt").solve(nlp, guess, None, None, rec).converged
    a, b = firsts
    np.testing.assert_array_equal(a.iterates[0], b.iterates[0])
    # Ipopt starts from the guess pushed inside the variable bounds (bound_push); the fixed
    # variables sit on their bounds and the free ones are the flat guess's
    free = nlp.x_lower < nlp.x_upper
    np.testing.assert_array_equal(a.iterates[0][free], x0.reshape(-1)[free])
    assert len(a.iterates) == len(b.iterates)
    np.testing.assert_array_equal(a.iterates[-1], b.iterates[-1])


@pytest.mark.parametrize("solver", ["jtraj", "ipopt"])
def test_nan_bounds_are_refused(solver):
    nlp = speed_limited()
    theta = {"vmin": jnp.asarray(-1.0), "vmax": jnp.asarray(np.nan)}
    # a knot NLP's bound is named by its place too (KnotNLP.locate)
    with pytest.raises(ValueError, match=r"bound g_upper\[30\] \(at group speed at knot 0, row 0\) is NaN"):
        solvers.get(solver).solve(nlp, np.zeros(nlp.n), theta)
    assert no_program(nlp)
    # a KnotNLP refuses NaN variable bounds when it is built (jtraj.nlp): bind's own check, for
    # any NLP object, on one with fixed bounds and no parameters
    f = bind(nlp)
    lower = np.where(np.arange(nlp.n) == 3, np.nan, f.x_lower)
    fixed = SimpleNamespace(n=nlp.n, x_lower=lower, x_upper=f.x_upper, g_lower=f.g_lower, g_upper=f.g_upper)
    with pytest.raises(ValueError, match=r"bound x_lower\[3\] is NaN"):
        bind(fixed)


def test_inconsistent_bounds_are_an_invalid_problem_for_both_solvers():
    nlp = speed_limited()
    theta = {"vmin": jnp.asarray(0.5), "vmax": jnp.asarray(0.35)}
    ipopt = solvers.get("ipopt").solve(nlp, np.zeros(nlp.n), theta)
    jt = solvers.get("jtraj").solve(nlp, np.zeros(nlp.n), theta)
    batch, total, compiled = solvers.get("jtraj").solve_batch(nlp, np.zeros((2, nlp.n)), theta)
    assert no_program(nlp)  # refused before compiling (it was NUMERICAL_ERROR after a compile)
    # the first speed row, after the 2(K-1) dynamics rows, and its place in the knot NLP
    first = "g_lower[30]=0.5 > g_upper[30]=0.35 (at group speed at knot 0, row 0)"
    for s in [ipopt, jt, *batch]:
        assert s.status is Status.INVALID_PROBLEM and first in s.message
    assert len(batch) == 2 and total == compiled == 0.0


def test_a_stop_request_jtraj_cannot_honour_warns():
    """jtraj's solver replays its iterations to the callback after its compiled loop has ended:
    a callback returning False cannot stop it, and it says so instead of ignoring the request."""
    from test_solvers import StopAtTwo

    nlp = speed_limited()
    stop = StopAtTwo()
    with pytest.warns(RuntimeWarning, match=r"cannot stop at a callback's request \(iteration 2\)"):
        solution = solvers.get("jtraj").solve(nlp, np.zeros(nlp.n), nlp.theta, callback=stop)
    assert stop.seen == [0, 1, 2] and solution.converged  # ran to its own end


def test_a_warm_start_of_another_shape_is_refused_by_name(monkeypatch):
    """`jtraj.solve` flattened a given warm start before the backend's check: a transposed
    (nz, n_knots) guess had the NLP's size and was solved from scrambled knots, and one of
    another size was refused as "x0 of shape (396,)". A refused warm start leaves the NLP's
    compile time to the next solve's result."""
    from test_transcription import HOP

    import jtraj.solver

    monkeypatch.setattr(jtraj.solver, "_CACHE", {})  # this test's own compile of the NLP
    prep = jtraj.solver.prepare(HOP)
    ws = prep.transcription.warm_start()
    knots, nz = ws.shape
    for bad in (ws.T, ws[:-1]):
        with pytest.raises(ValueError, match=rf"warm_start of shape \({bad.shape[0]}, {bad.shape[1]}\): expected \({knots * nz},\) or \({knots}, {nz}\)"):
            jtraj.solver.solve(HOP, warm_start=bad, progress=None, keep_trajectory=False, ipopt_options={"max_iter": 1})
    assert prep.time_compile > 0


def test_a_nan_in_the_start_is_refused_alone_and_a_numerical_error_of_that_batch_member_alone():
    """A NaN in an initial guess of one solve is refused by its place before anything compiles
    (it ended in NUMERICAL_ERROR with a NaN objective); in a batch of jtraj's solver that member
    ends in NUMERICAL_ERROR and the other members solve as they do alone."""
    nlp = double_integrator()
    x0 = np.zeros(nlp.n)
    bad = x0.copy()
    bad[5] = np.nan
    for solver in ("ipopt", "jtraj"):
        with pytest.raises(ValueError, match=r"x0\[5\] \(at knot 1, slot 'u' entry 0\) is nan"):
            solvers.get(solver).solve(nlp, bad)
    alone = solvers.get("jtraj").solve(nlp, x0)
    batch, _, _ = solvers.get("jtraj").solve_batch(nlp, np.stack([x0, bad, x0]), strategy="vmap")
    assert [s.status for s in batch] == [Status.SOLVED, Status.NUMERICAL_ERROR, Status.SOLVED]
    assert np.isnan(batch[1].objective) and np.isnan(batch[1].constraint_violation)
    for s in (batch[0], batch[2]):
        assert s.stats.iterations == alone.stats.iterations
        np.testing.assert_allclose(s.x, alone.x, atol=1e-9)


@pytest.mark.parametrize("solver", ["jtraj", "ipopt"])
def test_a_batch_of_parameters_is_refused_by_name(solver):
    """The solvers solve at one theta (`JtrajSolver.solve_batch`'s members share it): a theta
    with a leading batch axis failed inside the NLP's bound functions with JAX's "Incompatible
    types for broadcasting"; it is refused naming the parameter and the NLP's shape."""
    nlp = speed_limited()
    batched = {"vmin": jnp.asarray([-1.0, -1.0]), "vmax": jnp.asarray([0.35, 0.3])}
    match = r"theta\['vmax'\] has shape \(2,\), the NLP's own theta \(\): a solve is at one theta"
    backend = solvers.get(solver)
    with pytest.raises(ValueError, match=match):
        backend.solve(nlp, np.zeros(nlp.n), batched)
    if solver == "jtraj":
        with pytest.raises(ValueError, match=match):
            backend.solve_batch(nlp, np.zeros((2, nlp.n)), batched)
    assert no_program(nlp)


@pytest.mark.parametrize("kwargs", [{"threads": 1.5}, {"threads": True}, {"batch_size": 2.5, "strategy": "vmap"}, {"batch_size": 0, "strategy": "vmap"}])
def test_solve_batch_counts_are_whole_numbers(kwargs):
    """threads=1.5 ran (as 1), batch_size=2.5 failed inside numpy after the checks, and
    batch_size=0 was refused as "1 initial guesses for a batch of 0; expected 1 to 0"."""
    nlp = double_integrator()
    name, value = next(iter(kwargs.items()))
    with pytest.raises(ValueError, match=rf"solve_batch: {name}={value!r}; expected a positive count"):
        solvers.get("jtraj").solve_batch(nlp, np.zeros((1, nlp.n)), **{"strategy": "threads", **kwargs})
    assert no_program(nlp)


def test_solve_refuses_bad_seeds_and_replicates_before_building_anything(monkeypatch):
    """A negative seed of the warm start's noise (numpy's default_rng) failed only after the NLP
    was built; replicate=1.5 silently drew replicate 1 and replicate=-1 a draw of no study."""
    import jtraj.solver

    def boom(*args, **kwargs):
        raise AssertionError("the NLP was built despite a bad argument")

    monkeypatch.setattr(jtraj.solver, "prepare", boom)
    for kwargs, match in (
        ({"noise": 0.1, "seed": -1}, r"seed=-1: expected a seed >= 0 for numpy's default_rng"),
        ({"noise": 0.1, "seed": 1.5}, r"seed=1.5: expected an integer"),
        ({"noise": 0.1, "replicate": 1.5}, r"replicate=1.5: expected a replicate number >= 0"),
        ({"noise": 0.1, "replicate": -1}, r"replicate=-1: expected a replicate number >= 0"),
        # the study's draws take JAX's PRNGKey, which raised OverflowError after the compile
        ({"noise": 0.1, "replicate": 0, "seed": 2**64}, r"seed=18446744073709551616: expected a 64-bit integer"),
        # JAX folds 32 bits of it in: 2**32 drew replicate 0's noise, recorded as 2**32
        ({"noise": 0.1, "replicate": 2**32}, r"replicate=4294967296: expected a replicate number >= 0 and below 2\*\*32"),
        # noise=True was sigma 1, exact_hessian="false" the exact Hessian
        ({"noise": True}, r"noise=True: expected a standard deviation >= 0"),
        ({"exact_hessian": "false"}, r"exact_hessian='false': expected True or False"),
        ({"keep_trajectory": None}, r"keep_trajectory=None: expected True or False"),
    ):
        with pytest.raises(ValueError, match=match):
            jtraj.solver.solve("big_jump", **kwargs)
    # JAX's draws of a replicate take a negative seed (as `jtraj robustness --seed` does)
    with pytest.raises(AssertionError, match="the NLP was built"):
        jtraj.solver.solve("big_jump", noise=0.1, seed=-1, replicate=0)
    # numpy's and JAX's scalars are numbers (the bool check refused them for a while)
    import jax.numpy as jnp

    for noise in (np.array(0.05), jnp.float32(0.05), np.int64(0)):
        with pytest.raises(AssertionError, match="the NLP was built"):
            jtraj.solver.solve("big_jump", noise=noise)
    with pytest.raises(ValueError, match=r"noise=array\(\[0.1, 0.2\]\): expected a standard deviation"):
        jtraj.solver.solve("big_jump", noise=np.array([0.1, 0.2]))



def test_solve_refuses_an_iteration_limit_of_the_task_that_its_solver_cannot_hold_before_building(monkeypatch):
    """jtraj's solver refuses an iteration limit its 32-bit loop bound cannot hold; the early
    check of the options used a limit of 0, so a task file's limit of 1e8 was refused only after
    the NLP's build and compile."""
    import dataclasses

    from test_transcription import HOP

    import jtraj.solver

    def boom(*args, **kwargs):
        raise AssertionError("the NLP was built despite a bad iteration limit")

    monkeypatch.setattr(jtraj.solver, "prepare", boom)
    with pytest.raises(solvers.InvalidOptionError, match=r"jtraj option max_iter=100000000: expected at most"):
        jtraj.solver.solve(dataclasses.replace(HOP, max_iter=10**8), solver="jtraj")


def test_a_nan_in_the_point_is_a_nan_violation():
    """`max_violation` took Python's max of the rows' and the bounds' violations, and max(0.0,
    nan) is 0.0: a solution whose x had a NaN was reported within the bounds when its rows
    were satisfied (or had none)."""
    from jtraj.solvers.base import max_violation

    lo, hi, none = np.array([-1.0]), np.array([1.0]), np.zeros(0)
    assert np.isnan(max_violation(none, none, none, np.array([np.nan]), lo, hi))
    assert np.isnan(max_violation(np.array([0.5]), np.zeros(1), np.zeros(1), np.array([np.nan]), lo, hi))
    assert np.isnan(max_violation(np.array([np.nan]), np.zeros(1), np.zeros(1), np.array([0.0]), lo, hi))
    assert max_violation(np.array([0.5]), np.zeros(1), np.zeros(1), np.array([2.0]), lo, hi) == 1.0


def test_a_knot_nlp_locates_variables_and_rows():
    """`KnotNLP.locate`, which the solvers' bound messages use: knot and slot of a variable,
    group, knot and row of a constraint row; another kind is refused by name."""
    nlp = speed_limited()
    assert nlp.locate("x", 3 * 2 + 1) == "knot 2, slot 'v' entry 0"
    assert nlp.locate("g", 30 + 4) == "group speed at knot 4, row 0"
    assert nlp.locate("g", 1) == "group dynamics at knot 0, row 1"
    with pytest.raises(ValueError, match=r"kind='u': expected 'x'"):
        nlp.locate("u", 0)
    # an index outside the NLP is refused, not wrapped or taken from the last group
    for kind, i, size in (("x", nlp.n, nlp.n), ("x", -1, nlp.n), ("g", nlp.m, nlp.m)):
        with pytest.raises(IndexError, match=rf"{kind}\[{i}\]: the NLP has {size} "):
            nlp.locate(kind, i)


def test_solve_checks_out_before_building_anything(tmp_path, monkeypatch):
    """out= a file (or a folder under one) failed in Result.save, after the compile and the
    solve, and the result was lost; out="" wrote into the current folder. Checked first, by
    the rule of ``jtraj solve --out``."""
    import jtraj.solver

    monkeypatch.setattr(jtraj.solver, "prepare", lambda *a, **k: pytest.fail("the NLP was built despite a bad out"))
    afile = tmp_path / "afile"
    afile.write_text("x")
    (tmp_path / "link").symlink_to(tmp_path / "gone")
    for out, match in (
        (str(afile), r"is a file; expected a folder \(existing or to be created\)"),
        (str(afile / "sub"), rf"{afile} is a file; expected a folder"),
        (afile, r"is a file; expected a folder"),
        ("", r"expected a folder name"),
        # a link to nothing passed, and making the folder failed after the compile
        (str(tmp_path / "link"), rf"{tmp_path / 'link'} is a link to {tmp_path / 'gone'}, which does not exist; expected a folder"),
        (str(tmp_path / "link" / "sub"), rf"{tmp_path / 'link'} is a link to"),
    ):
        with pytest.raises(ValueError, match=rf"^solve: out={re.escape(repr(out))}: {match}"):
            jtraj.solver.solve("big_jump", out=out)
    # a folder another process's run holds: refused before the build (it was, after the NLP was
    # built and compiled), and left as it was
    import fcntl
    import os

    from jtraj.provenance import FolderInUseError

    held = tmp_path / "held"
    held.mkdir()
    fd = os.open(held, os.O_RDONLY)  # another open description: as another process's hold
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        with pytest.raises(FolderInUseError, match=rf"^{re.escape(str(held))} is in use by another run"):
            jtraj.solver.solve("big_jump", out=str(held))
    finally:
        os.close(fd)
    assert not any(held.iterdir())


def test_the_result_records_how_its_warm_start_was_made(tmp_path):
    """A solve's result (and its result.json) named neither the noise nor the seed of its
    warm start: a folder of ``jtraj solve --noise 0.5 --seed 3`` read as one from the task's
    own start."""
    from test_transcription import HOP

    import jtraj.solver
    from jtraj.result import Result

    quick = {"progress": None, "ipopt_options": {"max_iter": 1}}
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "provenance.json").write_text(json.dumps({"command": "an earlier solve", "complete": True}))
    r = jtraj.solver.solve(HOP, noise=0.01, seed=3, out=str(tmp_path / "r"), command=["jtraj", "solve", "hop"], **quick)
    drawn = {"given": False, "noise": 0.01, "seed": 3, "replicate": None, "noise_chart": None}
    assert r.options["warm_start"] == drawn
    assert Result.load(tmp_path / "r").options["warm_start"] == drawn
    # the folder's provenance (none was written from Python): this call, the given command,
    # complete, and not the record of the solve whose result this one replaced
    prov = json.loads((tmp_path / "r" / "provenance.json").read_text())
    assert prov["command"] == "jtraj solve hop" and prov["complete"] is True and "earlier" not in prov
    assert prov["call"] == {"function": "jtraj.solve", "task": HOP.name, "parameterization": "se3", "solver": "ipopt", "variables": r.options["layout"], "theta_given": False}
    assert {"date_utc", "date_end_utc", "versions", "machine"} <= prov.keys() and prov["versions"]["jtraj"]
    # and the ground its feet touch, where jtraj render draws it
    assert r.options["terrain_height"] == HOP.terrain_height == Result.load(tmp_path / "r").options["terrain_height"]
    given = jtraj.solver.solve(HOP, warm_start=jtraj.solver.prepare(HOP).transcription.warm_start(), **quick)
    assert given.options["warm_start"] == {"given": True, "noise": 0.0, "seed": None, "replicate": None, "noise_chart": None}
    # a seed without noise draws nothing, and recorded seed 3 for the task's own start
    plain = jtraj.solver.solve(HOP, seed=3, **quick)
    assert plain.options["warm_start"] == {"given": False, "noise": 0.0, "seed": None, "replicate": None, "noise_chart": None}
    # the folder is held while the solve runs and let go however it ends (here: its progress
    # stream fails): a solve that raised kept other processes' runs out of it
    from test_provenance import _flock_free

    class Failing:
        def write(self, text):
            assert not _flock_free(tmp_path / "r")
            raise OSError("the progress stream failed")

    assert _flock_free(tmp_path / "r")
    with pytest.raises(OSError, match="the progress stream failed"):
        jtraj.solver.solve(HOP, out=str(tmp_path / "r"), progress=Failing(), ipopt_options={"max_iter": 1})
    assert _flock_free(tmp_path / "r")


def test_solve_refuses_bad_starts_and_thetas_before_building_anything(monkeypatch):
    """These were refused only after the NLP was built and compiled (tens of seconds on a
    whole-body task); progress_every took no numpy integer, and was ignored with a callback."""
    import jtraj.solver

    class Built(Exception):
        pass

    def built(*args, **kwargs):
        raise Built

    monkeypatch.setattr(jtraj.solver, "prepare", built)
    for kwargs, error, match in (
        ({"noise_chart": "euler"}, ValueError, r"^solve: noise_chart= needs replicate="),
        ({"noise": 0.1, "replicate": 0, "warm_start": np.zeros((3, 4))}, ValueError, r"^solve: replicate= solves a run of the noise study"),
        ({"noise": 0.1, "replicate": 0, "theta": {"friction": 0.5}}, ValueError, r"^solve: replicate= solves a run of the noise study"),
        ({"noise": 0.1, "replicate": 0, "noise_chart": "eulr"}, ValueError, r"^solve: noise_chart='eulr': expected one of se3, quat1, quat2, quat3, euler or None$"),
        ({"theta": {"frictoin": 0.5}}, ValueError, r"^unknown task parameter 'frictoin'; expected one of \['target_translation'"),
        ({"theta": [0.5]}, TypeError, r"^theta must be None, a mapping of parameter overrides or a TaskParams, got list$"),
        ({"progress_every": 0}, ValueError, r"progress_every=0: expected an integer >= 1"),
        ({"progress_every": True}, ValueError, r"progress_every=True: expected an integer >= 1"),
        ({"progress_every": 5, "progress": solvers.RecordIterates()}, ValueError, r"^solve: progress_every=5 with a callback: the callback receives every iteration"),
        # a string was joined letter by letter into provenance.json's command
        ({"command": "python run.py --fast"}, ValueError, r"^solve: command='python run.py --fast': expected a list of strings \(shlex.split"),
        ({"command": ["jtraj", 3]}, ValueError, r"^solve: command=\['jtraj', 3\]: expected a list of strings"),
        # options that are not a mapping: "'str' object is not a mapping"
        ({"options": "tol=1e-4"}, solvers.InvalidOptionError, r"^solve: options='tol=1e-4': expected None, a dict or an options object$"),
        ({"ipopt_options": solvers.IpoptOptions(tol=1e-4)}, solvers.InvalidOptionError, r"^solve: ipopt_options=IpoptOptions\(.*\): IpoptOptions goes in options=$"),
        # a warm start's shape and theta's values, on the transcription alone (they were
        # refused after the build: 9 s on the hop, tens on a whole-body task)
        ({"warm_start": np.zeros(3)}, ValueError, r"^warm_start of shape \(3,\): expected \(6204,\) or \(47, 132\)"),
        ({"warm_start": np.zeros((132, 47))}, ValueError, r"^warm_start of shape \(132, 47\): expected"),
        ({"theta": {"friction": -1.0}}, ValueError, r"friction=-1.0: expected"),
        ({"theta": {"target_translation": [0.0, 0.0, 0.5]}}, ValueError, r"above the terrain at the last knot"),
    ):
        with pytest.raises(error, match=match):
            jtraj.solver.solve("big_jump", **kwargs)
    for kwargs in ({"progress_every": np.int64(2)}, {"theta": {"friction": 0.5}}, {"noise": 0.1, "replicate": 0, "noise_chart": "euler"}, {"warm_start": np.zeros((47, 132))}):
        with pytest.raises(Built):  # good: on to the build
            jtraj.solver.solve("big_jump", **kwargs)


def test_options_given_twice_must_agree():
    """options and ipopt_options are the same thing: given both as dicts, ipopt_options won
    where they disagreed; exact_hessian=True replaced an options object's own other Hessian."""
    from jtraj.solver import solver_options

    ipopt, jt = solvers.get("ipopt"), solvers.get("jtraj")
    with pytest.raises(ValueError, match=r"^solve: options and ipopt_options disagree on max_iter=5 and 50: expected each option once"):
        solver_options(ipopt, {"max_iter": 5, "tol": 1e-8}, {"max_iter": 50}, False, 200)
    assert solver_options(ipopt, {"max_iter": 5}, {"max_iter": 5, "tol": 1e-8}, False, 200).max_iter == 5
    with pytest.raises(ValueError, match=r"IpmOptions\(hessian='bfgs'\) with exact_hessian=True: expected hessian='exact'"):
        solver_options(jt, jt.options({"hessian": "bfgs"}), None, True, 10)
    assert solver_options(jt, jt.options({"tol": 1e-6}), None, True, 10).hessian == "exact"  # its default Hessian
    assert solver_options(ipopt, ipopt.options({"hessian": "exact"}), None, True, 10).hessian == "exact"


def test_threads_that_prepare_one_task_at_once_build_it_once(monkeypatch):
    """Two threads that missed the cache together each built (and compiled) the NLP, and the
    second replaced the first's in the cache."""
    import threading
    import time
    from concurrent.futures import ThreadPoolExecutor

    import jtraj.solver

    builds: list[int] = []

    def slow_build(key, task, param, options):
        builds.append(threading.get_ident())
        time.sleep(0.3)
        prep = SimpleNamespace(key=key)
        jtraj.solver._CACHE[key] = prep
        return prep

    monkeypatch.setattr(jtraj.solver, "_build", slow_build)
    monkeypatch.setattr(jtraj.solver, "_CACHE", {})
    # (a failed build elsewhere in this process leaves its key's lock, for its retries)
    monkeypatch.setattr(jtraj.solver, "_BUILDING", {})
    with ThreadPoolExecutor(2) as pool:
        a, b = pool.map(lambda _: jtraj.solver.prepare("big_jump"), range(2))
    assert len(builds) == 1 and a is b
    assert not jtraj.solver._BUILDING  # no lock left behind


def test_exact_hessian_refuses_another_hessian_option():
    """exact_hessian=True dropped an explicit hessian_approximation='limited-memory' without a
    word and solved with the exact Hessian; an agreeing option is taken."""
    from jtraj.solver import solver_options

    ipopt, jt = solvers.get("ipopt"), solvers.get("jtraj")
    for backend, key, value in ((ipopt, "hessian_approximation", "limited-memory"), (ipopt, "hessian", "lbfgs"), (jt, "hessian", "lbfgs"), (jt, "hessian", "bfgs")):
        with pytest.raises(ValueError, match=rf"^solve: {key}='{value}' with exact_hessian=True: expected {key}='exact' or exact_hessian=False$"):
            solver_options(backend, None, {key: value}, True, 10)
        with pytest.raises(ValueError, match="with exact_hessian=True"):
            solver_options(backend, {key: value}, None, True, 10)
    assert solver_options(ipopt, None, {"hessian_approximation": "exact"}, True, 10).hessian == "exact"
    # Ipopt's own spelling in any case, as its options take it (it was refused as a conflict)
    assert solver_options(ipopt, None, {"hessian_approximation": "EXACT"}, True, 10).hessian == "exact"
    assert solver_options(jt, None, {"hessian": "exact"}, True, 10).hessian == "exact"
    assert solver_options(ipopt, None, {"hessian_approximation": "limited-memory"}, False, 10).hessian == "lbfgs"


def test_solve_refuses_a_theta_whose_fixed_knots_cannot_touch_the_terrain(monkeypatch):
    """A theta that raises the target (or tilts the standing pose) fixes the last (first) knot
    off the terrain its phases stand on: no solver could meet those rows, and the solve ran to
    its iteration limit. Refused after the NLP is built and before the solver runs."""
    from test_transcription import HOP

    import jtraj.solver

    prep = jtraj.solver.prepare(HOP)
    monkeypatch.setattr(type(jtraj.solvers.get("ipopt")), "solve", lambda *a, **k: pytest.fail("solved a theta no solver could meet"))
    with pytest.raises(ValueError, match=r"^theta.q_joints_standing and theta.base_xyz_wxyz_standing, theta.target_translation and theta.target_rotation_rpy: the pose they give puts \w+ 0.1 m above the terrain at the last knot"):
        jtraj.solver.solve(HOP, theta={"target_translation": [0.04, 0.0, 0.1]}, progress=None)
    tilted = [0.0, 0.0, 0.3, float(np.cos(0.05)), float(np.sin(0.05)), 0.0, 0.0]  # a roll of 0.1 rad
    with pytest.raises(ValueError, match=r"^theta.q_joints_standing and theta.base_xyz_wxyz_standing: the pose they give puts the contact points of phase 0 \d+.\d mm apart in height"):
        jtraj.solver.solve(HOP, theta={"base_xyz_wxyz_standing": tilted}, progress=None)
    assert prep.nlp is jtraj.solver.prepare(HOP).nlp


class FunctionsOnly:
    """An NLP with the documented functions alone (Ipopt takes it): x0 + x1 = 0.5 in [-1, 1]^2."""

    n, m = 2, 1
    x_lower, x_upper = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    g_lower, g_upper = np.array([0.5]), np.array([0.5])
    jac_rows, jac_cols = np.array([0, 0]), np.array([0, 1])

    def objective(self, x):
        return jnp.sum((x - 0.2) ** 2)

    def gradient(self, x):
        return 2.0 * (x - 0.2)

    def constraints(self, x):
        return jnp.array([x[0] + x[1]])

    def jacobian(self, x):
        return jnp.array([1.0, 1.0])


def test_jtraj_refuses_an_nlp_without_knots_by_name():
    """jtraj's solver works on a KnotNLP's knot structure: another NLP failed with a bare
    AttributeError ('solver_programs'); Ipopt solves it."""
    nlp = FunctionsOnly()
    assert solvers.get("ipopt").solve(nlp, np.zeros(2)).converged
    jt = solvers.get("jtraj")
    with pytest.raises(TypeError, match=r"jtraj's solver: nlp of type FunctionsOnly: expected a jtraj.nlp.KnotNLP"):
        jt.solve(nlp, np.zeros(2))
    with pytest.raises(TypeError, match=r"nlp of type FunctionsOnly: expected a jtraj.nlp.KnotNLP"):
        jt.solve_batch(nlp, np.zeros((2, 2)))


def test_solve_checks_the_noise_chart_before_the_compile(monkeypatch):
    """solve(replicate=, noise_chart=) refused a chart that cannot take the noisy poses only
    after its NLP was built and compiled (the command line checked it before)."""
    import jtraj.experiments
    import jtraj.solver

    seen = []

    def refuse(tasks, params, variables, chart):
        seen.append((list(params), variables, chart))
        raise jtraj.experiments.NoiseChartError("no room for these poses")

    monkeypatch.setattr(jtraj.experiments, "check_noise_chart", refuse)
    monkeypatch.setattr(jtraj.solver, "prepare", lambda *a, **k: pytest.fail("the NLP was built before the chart's check"))
    with pytest.raises(jtraj.experiments.NoiseChartError, match="no room"):
        jtraj.solver.solve("big_jump", "euler", variables="paper", noise=0.1, replicate=0, noise_chart="se3")
    assert seen == [(["euler"], "paper", "se3")]


def test_release_compiled_waits_for_the_cache_lock(monkeypatch):
    """release_compiled cleared the NLP cache without its lock: a thread in `prepare` between
    its test of a key and its read got a KeyError when a solve in another thread released the
    compiled programs (`release_compiled_if_crowded`)."""
    import threading

    import jax

    import jtraj.solver

    monkeypatch.setattr(jax, "clear_caches", lambda: None)
    monkeypatch.setattr(jtraj.solver, "_CACHE", {("a key",): "an NLP"})
    done = threading.Event()
    with jtraj.solver._CACHE_LOCK:
        thread = threading.Thread(target=lambda: (jtraj.solver.release_compiled(), done.set()))
        thread.start()
        assert not done.wait(0.3) and jtraj.solver._CACHE == {("a key",): "an NLP"}  # it waits
    thread.join(10)
    assert done.is_set() and jtraj.solver._CACHE == {}


def test_threads_default_to_the_cores_this_process_may_use(monkeypatch):
    """The threaded batch ran os.cpu_count() members at once, the machine's cores, where the
    process may use fewer (taskset, a container's cpuset, a Slurm allocation): its members
    then shared those few. It takes `jtraj.config.cpu_count`, the process's affinity."""
    import concurrent.futures
    import os

    from jtraj.solvers import ipm

    sizes = []

    class Recording(concurrent.futures.ThreadPoolExecutor):
        def __init__(self, max_workers=None, *args, **kwargs):
            sizes.append(max_workers)
            super().__init__(max_workers, *args, **kwargs)

    monkeypatch.setattr(concurrent.futures, "ThreadPoolExecutor", Recording)
    monkeypatch.setattr(ipm, "cpu_count", lambda: 1)
    monkeypatch.setattr(os, "cpu_count", lambda: 64)  # the machine's, more than the members
    nlp = double_integrator()
    batch, _, _ = solvers.get("jtraj").solve_batch(nlp, np.zeros((3, nlp.n)), strategy="threads")
    assert sizes == [1] and len(batch) == 3 and all(s.converged for s in batch)
