"""The solver-backend contract (`jtraj.solvers`): one status enumeration with messages, options
that fail at construction, the registry, progress resolved at call time, and Ipopt's solution
with its multipliers on a tiny bound-constrained problem."""

import dataclasses
import io
import sys

import jax.numpy as jnp
import numpy as np
import pytest

from jtraj import solvers
from jtraj.nlp import ConstraintGroup, CostGroup, Dep, KnotNLP, Layout
from jtraj.solvers import AbstractCallback, InvalidOptionError, IpmOptions, IpoptOptions, IpoptSolver, Status
from jtraj.solvers.base import bind
from jtraj.solvers.ipopt import IPOPT_STATUS

N = 6


@pytest.fixture(scope="module")
def walk_nlp():
    return _walk_nlp()


def _walk_nlp():
    """x_{k+1} = x_k + u_k from x_0 = 0; cost sum (x_k - 1)^2 + u_k^2; u_k <= 0.3 (active)."""
    layout = Layout((("x", 1), ("u", 1)))
    step = ConstraintGroup(
        name="step",
        deps=(Dep("x"), Dep("u"), Dep("x", 1)),
        fn=lambda theta, data, x, u, x_next: x_next - x - u,
        knots=np.arange(N - 1),
        lower=np.zeros((N - 1, 1)),
        upper=np.zeros((N - 1, 1)),
        active=np.ones((N - 1, 1), bool),
    )
    cost = CostGroup(name="track", deps=(Dep("x"), Dep("u")), fn=lambda theta, data, x, u: (x[0] - 1.0) ** 2 + u[0] ** 2, knots=np.arange(N))
    lower = np.full((N, 2), -np.inf)
    upper = np.full((N, 2), np.inf)
    upper[:, 1] = 0.3
    lower[0, 0] = upper[0, 0] = 0.0
    return KnotNLP(layout, N, [cost], [step], lower, upper)


def test_every_status_has_a_message_and_acceptable_is_not_solved():
    for status in Status:
        assert isinstance(status.value, str) and len(status.message) > 10
    assert Status.SOLVED.converged and Status.ACCEPTABLE.converged and Status.ACCEPTABLE is not Status.SOLVED
    assert not any(s.converged for s in Status if s not in (Status.SOLVED, Status.ACCEPTABLE))
    assert Status("max_iter") is Status.MAX_ITER
    # the shared status jtraj's line-search failure maps to says what happened in jtraj's solver
    # (committed runs name it restoration_failed, so the value stays)
    from jtraj.solvers.ipm import _STATUS, IpmStatus

    assert _STATUS[IpmStatus.LINE_SEARCH_FAILED] is Status.RESTORATION_FAILED and "line search" in Status.RESTORATION_FAILED.message
    # and every IpmStatus has jtraj's own wording (RUNNING's was its bare name)
    from jtraj.solvers.ipm import _MESSAGES

    assert set(_MESSAGES) == set(IpmStatus) and all(len(text) > 10 for text in _MESSAGES.values())


def test_a_tight_solve_stuck_at_mu_min_is_told_the_floor_under_delta_c():
    """jtraj's solver at its iteration limit with tol <= 1e-6, mu at mu_min and no floor under
    delta_c mu^(1/4) says which delta_c_min shortens that tail (1e-9 with L-BFGS, 1e-7 with the
    exact Hessian, docs/measurements.md); other stops keep the plain message."""
    from jtraj.solvers.ipm import _MESSAGES, IpmOptions, IpmStatus, _status_message

    tight = IpmOptions(tol=1e-8)
    mu_min = tight.mu_min_value()
    hint = _status_message(IpmStatus.MAX_ITER, tight, mu_min)
    assert hint.startswith(_MESSAGES[IpmStatus.MAX_ITER]) and "delta_c_min=1e-9" in hint and "1.8e-11" in hint
    assert "delta_c_min=1e-7" in _status_message(IpmStatus.MAX_ITER, IpmOptions(tol=1e-10, hessian="exact"), mu_min)
    plain = _MESSAGES[IpmStatus.MAX_ITER]
    assert _status_message(IpmStatus.MAX_ITER, IpmOptions(), mu_min) == plain  # the study's tol 1e-3
    assert _status_message(IpmStatus.MAX_ITER, tight, 10 * mu_min) == plain  # mu above its floor
    assert _status_message(IpmStatus.MAX_ITER, IpmOptions(tol=1e-8, delta_c_min=1e-9), mu_min) == plain  # floored already
    assert _status_message(IpmStatus.MAX_ITER, IpmOptions(tol=1e-8, delta_c_mu_scaled=False), mu_min) == plain
    assert _status_message(IpmStatus.LINE_SEARCH_FAILED, tight, mu_min) == _MESSAGES[IpmStatus.LINE_SEARCH_FAILED]
    # at tol 1e-13 mu_min is Ipopt's tol / 2, and the hint reads that floor
    tighter = IpmOptions(tol=1e-13, compl_inf_tol=1e-13)
    assert "delta_c_min=1e-9" in _status_message(IpmStatus.MAX_ITER, tighter, 5e-14)
    assert _status_message(IpmStatus.MAX_ITER, tighter, 1e-11) == plain


def test_ipopt_return_codes_map_to_the_enumeration():
    # every code of Ipopt's ApplicationReturnStatus
    codes = {0, 1, 2, 3, 4, 5, 6, -1, -2, -3, -4, -5, -10, -11, -12, -13, -100, -101, -102, -199}
    assert set(IPOPT_STATUS) == codes
    assert IPOPT_STATUS[0] is Status.SOLVED and IPOPT_STATUS[1] is Status.ACCEPTABLE
    assert IPOPT_STATUS[-1] is Status.MAX_ITER and IPOPT_STATUS[-5] is Status.MAX_WALL_TIME
    assert IPOPT_STATUS[-2] is Status.RESTORATION_FAILED and IPOPT_STATUS[2] is Status.INFEASIBLE


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"tol": -1.0}, "tol=-1.0: expected a positive number"),
        ({"max_iter": 2.5}, "max_iter=2.5: expected an integer"),
        ({"hessian": "bfgs"}, r"hessian='bfgs': expected one of \['exact', 'lbfgs'\]"),
        ({"hessian": ["exact"]}, r"hessian=\['exact'\]: expected one of \['exact', 'lbfgs'\]"),  # was TypeError: unhashable type
        ({"linear_solver": "umfpack"}, "linear_solver='umfpack'"),
        # a known linear solver whose library this Ipopt lacks (the solve said only "Invalid option encountered")
        ({"linear_solver": "ma27"}, "linear_solver='ma27': not available in this Ipopt build"),
        # Ipopt's integer options are C ints (a raw OverflowError at the solve)
        ({"max_iter": 10**12}, r"max_iter=1000000000000: expected an integer in \[0, 2147483647\]"),
        ({"extra": {"acceptable_iter": 2**31}}, "acceptable_iter=2147483648: expected an integer"),
        ({"extra": {"tol": 1e-3}}, r"use IpoptOptions\(tol=...\)"),
        # other Ipopt options against the bundled Ipopt's list, here and not when a solve starts
        ({"extra": {"max_itr": 3}}, "max_itr=3: unknown Ipopt option; did you mean max_iter"),
        ({"extra": {"mu_strategy": "fast"}}, r"mu_strategy='fast': expected one of \['monotone', 'adaptive'\]"),
        # file options Ipopt finds bad only at the solve ("Invalid option encountered.") or skips
        ({"extra": {"output_file": "/proc/no-such-folder/ipopt.txt"}}, "output_file='/proc/no-such-folder/ipopt.txt': expected a file path in an existing, writable folder"),
        ({"extra": {"output_file": "/"}}, "output_file='/': a folder; expected a file path"),
        ({"extra": {"option_file_name": "/no-such-file.opt"}}, "option_file_name='/no-such-file.opt': expected a readable Ipopt options file"),
    ],
)
def test_bad_options_fail_at_construction(kwargs, match):
    with pytest.raises(InvalidOptionError, match=match):
        IpoptOptions(**kwargs)


@pytest.mark.parametrize(
    "kwargs,match",
    [
        # int32 counters in the compiled program: the loop ended at once with INTERNAL_ERROR 'RUNNING'
        ({"max_iter": 70_000_000}, r"max_iter=70000000: expected at most 61356674 with max_line_search=30 and max_soc=4"),
        ({"max_iter": 2**31}, r"max_iter=2147483648: expected an integer in \[0, 2147483647\]"),
        ({"lbfgs_memory": 2**40}, "lbfgs_memory=1099511627776: expected an integer in"),
        # the ranges of the options that follow Ipopt's (they were not checked at all)
        ({"bound_push": 0.0}, r"bound_push=0.0: expected a number in \(0, inf\)"),
        ({"bound_frac": 0.6}, r"bound_frac=0.6: expected a number in \(0, 0.5\]"),
        ({"mu_min": 0.0}, r"mu_min=0.0: expected a number in \(0, inf\)"),
        ({"kappa_mu": 1.0}, r"kappa_mu=1.0: expected a number in \(0, 1\)"),
        ({"theta_mu": 2.0}, r"theta_mu=2.0: expected a number in \(1, 2\)"),
        ({"tau_min": 1.0}, r"tau_min=1.0: expected a number in \(0, 1\)"),
        ({"kappa_sigma": 0.5}, r"kappa_sigma=0.5: expected a number in \[1, inf\)"),
        ({"s_max": -1.0}, r"s_max=-1.0: expected a number in \(0, inf\)"),
        ({"armijo": 0.5}, r"armijo=0.5: expected a number in \(0, 0.5\)"),
        ({"sigma_min": 10.0, "sigma_max": 1.0}, "sigma_min=10.0: expected at most sigma_max=1.0"),
        ({"lbfgs_init_min": 2.0, "lbfgs_init_max": 1.0}, "lbfgs_init_min=2.0: expected at most lbfgs_init_max=1.0"),
        ({"max_line_search_failures": 0}, "max_line_search_failures=0: expected an integer >= 1"),
        # accepted before, though Ipopt's range starts at 1 (0 reset the L-BFGS memory every iteration)
        ({"lbfgs_max_skipping": 0}, "lbfgs_max_skipping=0: expected an integer >= 1"),
        ({"min_refine_steps": 4, "refine_steps": 3}, "min_refine_steps=4: expected at most refine_steps=3"),
        # accepted and ignored before: the floor is under the scaled regularization only
        ({"delta_c_min": 1e-7, "delta_c_mu_scaled": False}, "delta_c_min=1e-07: a floor under the scaled delta_c mu"),
        # mu_min is None when not given; a given one is a finite number in Ipopt's range
        ({"mu_min": float("nan")}, "mu_min=nan: expected a finite number"),
        ({"mu_min": "1e-9"}, "mu_min='1e-9': expected a finite number"),
    ],
)
def test_bad_jtraj_options_fail_at_construction(kwargs, match):
    with pytest.raises(InvalidOptionError, match=match):
        IpmOptions(**kwargs)
    IpmOptions(max_iter=61356674)  # the largest the default line search allows


def test_numpy_scalars_are_numbers_for_the_options():
    """A setting taken from a numpy array (np.float32, np.int64) was refused as "expected a
    positive number" or "expected a string, integer, float or boolean value" though it is one;
    Ipopt's options get Python's int and float, which cyipopt's setters take."""
    opts = IpoptOptions(tol=np.float32(0.5), max_wall_time=np.int64(5), extra={"acceptable_iter": np.int64(3), "mu_init": np.float32(0.5)})
    ipopt = opts.to_ipopt()
    for key, kind, value in (("tol", float, 0.5), ("max_wall_time", float, 5.0), ("acceptable_iter", int, 3), ("mu_init", float, 0.5)):
        assert type(ipopt[key]) is kind and ipopt[key] == value, key
    assert IpmOptions(tol=np.float32(0.5), mu_init=np.int64(1)).tol == 0.5
    with pytest.raises(InvalidOptionError, match=r"tol=-1.0: expected a positive number"):
        IpoptOptions(tol=np.float32(-1.0))
    with pytest.raises(InvalidOptionError, match=r"mu_init=np.float32\(-1.0\): expected a positive number"):
        IpmOptions(mu_init=np.float32(-1.0))


def test_jtraj_options_are_stored_as_their_fields_types():
    """An int for a real option (lbfgs_init_val=1) or a numpy scalar was kept as it was, reached
    the compiled loop's state as int64 or float32 and failed its trace; as IpoptOptions does,
    each value becomes its field's type (the defaults' values are unchanged)."""
    opts = IpmOptions(lbfgs_init_val=1, mu_init=np.int64(1), tau_min=np.float32(0.5), mu_max=1000, max_iter=np.int64(7), bfgs_scaling=np.bool_(False))
    for name, kind in (("lbfgs_init_val", float), ("mu_init", float), ("tau_min", float), ("mu_max", float), ("max_iter", int), ("bfgs_scaling", bool)):
        assert type(getattr(opts, name)) is kind, name
    assert (opts.lbfgs_init_val, opts.tau_min, opts.max_iter) == (1.0, 0.5, 7)
    assert IpmOptions(lbfgs_init_val=1).compiled_part() == IpmOptions().compiled_part()
    assert IpmOptions(mu_min=None).mu_min is None
    default = IpmOptions()
    assert all(type(getattr(default, f.name)) is type(f.default) for f in dataclasses.fields(IpmOptions) if f.default is not None)


def test_ipopts_two_names_of_the_hessian_must_agree():
    """``hessian`` (the field) and ``hessian_approximation`` (Ipopt's name) that ask for different
    Hessians: one was silently dropped (limited-memory won)."""
    with pytest.raises(InvalidOptionError, match=r"hessian_approximation='limited-memory': conflicts with hessian='exact'"):
        IpoptOptions.from_dict({"hessian": "exact", "hessian_approximation": "limited-memory"})
    assert IpoptOptions.from_dict({"hessian": "lbfgs", "hessian_approximation": "limited-memory"}).hessian == "lbfgs"
    assert IpoptOptions.from_dict({"hessian": "exact", "hessian_approximation": "exact"}).hessian == "exact"
    # merging Ipopt's name over options replaces their Hessian; both in the merged values must agree
    assert IpoptOptions(hessian="exact").merge({"hessian_approximation": "limited-memory"}).hessian == "lbfgs"
    with pytest.raises(InvalidOptionError, match="conflicts with hessian='lbfgs'"):
        IpoptOptions().merge({"hessian": "lbfgs", "hessian_approximation": "exact"})


def test_ipopts_string_values_take_any_case():
    """Ipopt takes its string options in any case, and so did the command line's check; the
    options object refused ``NONE`` with a traceback after it."""
    opts = IpoptOptions.from_dict({"nlp_scaling_method": "NONE", "linear_solver": "MUMPS", "hessian_approximation": "Limited-Memory"})
    assert (opts.nlp_scaling_method, opts.linear_solver, opts.hessian) == ("none", "mumps", "lbfgs")


def test_unknown_jtraj_option_names_the_nearest():
    with pytest.raises(InvalidOptionError, match=r"unknown jtraj option\(s\) \['max_itr', 'zzz'\] \(did you mean 'max_itr' for 'max_iter'\?\); expected one of"):
        IpmOptions.from_dict({"max_itr": 10, "zzz": 1})
    with pytest.raises(InvalidOptionError, match=r"unknown jtraj option\(s\) \['zzz'\]; expected one of"):
        IpmOptions.from_dict({"zzz": 1})


def test_jtraj_option_ranges_are_ipopts():
    from jtraj.solvers import ipopt_catalog

    specs = ipopt_catalog.catalog()
    # the 22 options that follow Ipopt's ranges, among them the two special cases below and one
    # under another name in Ipopt: a loop over fewer (none) would check less than it says
    assert len(IpmOptions.RANGES) >= 22 and {"mu_min", "kappa_sigma", "bound_push", "kappa_eps"} <= set(IpmOptions.RANGES)
    for name, (lo, lo_open, hi, hi_open, ipopt_name) in IpmOptions.RANGES.items():
        spec = specs[ipopt_name]
        ours = (lo, lo_open, hi, hi_open) if name != "kappa_sigma" else (0.0, True, np.inf, True)  # Ipopt: below 1 turns it off
        assert ours == (spec.lower, spec.lower_strict, spec.upper, spec.upper_strict), name
        if name == "mu_min":  # not given (None): Ipopt's rule, its default at the usual tolerances
            assert IpmOptions().mu_min is None and IpmOptions(tol=1e-8).mu_min_value() == float(spec.default)
        else:
            assert getattr(IpmOptions(), name) == float(spec.default), name


def test_option_catalog_leaves_other_threads_output_alone(capfd):
    """The catalog was read from Ipopt's documentation by redirecting file descriptor 1 into a
    temporary file while Ipopt printed it: what another thread wrote meanwhile (a batch's
    progress lines) went into that file and was lost."""
    import os
    import threading

    from jtraj.solvers import ipopt_catalog

    ipopt_catalog.catalog.cache_clear()
    built, written = threading.Event(), []

    def writer():
        while not built.is_set() or len(written) < 3:
            line = f"line {len(written)}\n"
            os.write(1, line.encode())
            written.append(line)

    t = threading.Thread(target=writer)
    t.start()
    try:
        assert len(ipopt_catalog.catalog()) > 100
    finally:
        built.set()
        t.join()
    out = capfd.readouterr().out
    assert out == "".join(written) and len(written) >= 3  # every line, and none of Ipopt's
    assert ipopt_catalog.catalog()["max_iter"].kind == "integer" and ipopt_catalog.catalog()["tol"].kind == "real"


def test_an_absent_hsl_solver_is_refused_without_a_crash():
    """With HSL absent, Ipopt's MA97 interface crashed the process (segmentation fault) when the
    availability probe's problem was freed: IpoptOptions(linear_solver='ma97') ended Python."""
    import ctypes.util
    import subprocess
    import sys

    from jtraj.solvers import ipopt_catalog

    code = "from jtraj.solvers.ipopt_catalog import linear_solver_available as a; print(a('ma97'), a('ma27'))"
    child = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert child.returncode == 0, child.stderr[-2000:]
    # the child probe itself runs and reports Ipopt's status (a first version died importing
    # the module, and every solver read as absent): MUMPS solves the tiny problem
    assert ipopt_catalog._child_status("mumps") in (0, 1)
    assert ipopt_catalog._child_status("spral") is None  # not in this Ipopt's list: refused
    if ctypes.util.find_library("hsl") is None and ctypes.util.find_library("coinhsl") is None:
        assert child.stdout.split() == ["False", "False"]
        assert ipopt_catalog._child_status("ma27") == -12  # Ipopt's Invalid_Option: its library did not load
    else:  # an Ipopt that finds HSL solves with both
        assert child.stdout.split() == ["True", "True"]


def test_options_from_ipopt_names():
    opts = IpoptOptions.from_dict({"tol": 1, "hessian_approximation": "exact", "mu_strategy": "adaptive", "warm_start_init_point": True})
    assert opts.tol == 1.0 and isinstance(opts.tol, float) and opts.hessian == "exact"
    ipopt = opts.to_ipopt()
    assert ipopt["hessian_approximation"] == "exact" and ipopt["mu_strategy"] == "adaptive" and ipopt["warm_start_init_point"] == "yes"
    merged = opts.merge({"max_iter": 7, "hessian_approximation": "limited-memory"})
    assert (merged.max_iter, merged.hessian, merged.tol, merged.extra["mu_strategy"]) == (7, "lbfgs", 1.0, "adaptive")
    with pytest.raises(InvalidOptionError, match=r"hessian_approximation=\['exact'\]: expected one of"):
        IpoptOptions.from_dict({"hessian_approximation": ["exact"]})  # was TypeError: unhashable type
    with pytest.raises(TypeError, match="positional argument"):
        IpoptOptions(1e-3)  # keyword-only
    # numpy's booleans are booleans (the message said booleans were taken, and refused np.True_)
    assert IpoptOptions.from_dict({"warm_start_init_point": np.True_}).to_ipopt()["warm_start_init_point"] == "yes"
    with pytest.raises(InvalidOptionError, match=r"mu_init=np.True_: expected a real number"):
        IpoptOptions.from_dict({"mu_init": np.True_})


def test_ipopt_takes_an_nlp_of_its_own_kind_without_weak_references_with_its_exact_hessian():
    """Ipopt takes anything with the NLP's functions; with the exact Hessian it failed on one
    that takes no weak reference (a SimpleNamespace) after the Hessian was built."""
    from types import SimpleNamespace

    nlp = SimpleNamespace(n=2, m=1, x_lower=np.full(2, -10.0), x_upper=np.full(2, 10.0), g_lower=np.ones(1), g_upper=np.ones(1))
    nlp.objective = lambda x: (x[0] - 1) ** 2 + (x[1] - 2) ** 2
    nlp.gradient = lambda x: jnp.array([2 * (x[0] - 1), 2 * (x[1] - 2)])
    nlp.constraints = lambda x: jnp.array([x[0] + x[1]])
    nlp.jacobian = lambda x: jnp.array([1.0, 1.0])
    nlp.jac_rows, nlp.jac_cols = np.array([0, 0]), np.array([0, 1])

    calls = []

    def build_hessian():
        nlp.hess_rows, nlp.hess_cols = np.array([0, 1]), np.array([0, 1])
        nlp.hessian = lambda x, lam, of: calls.append(of) or jnp.array([2.0 * of, 2.0 * of])

    nlp.build_hessian = build_hessian
    for _ in range(2):  # (built again each solve)
        calls.clear()
        sol = solvers.get("ipopt").solve(nlp, np.zeros(2), None, {"hessian": "exact", "print_level": 0})
        assert sol.status is Status.SOLVED
        np.testing.assert_allclose(sol.x, [0.0, 1.0], atol=1e-6)
        # Ipopt's iterations asked for the Hessian, not only a warm-up call before the clock
        # (a solve that fell back to L-BFGS reaches the same x on this quadratic)
        assert len(calls) > 1


def test_solve_refuses_bad_arguments_before_building_anything(monkeypatch):
    import jtraj.solver

    def boom(*args, **kwargs):
        raise AssertionError("the NLP was built despite a bad argument")

    monkeypatch.setattr(jtraj.solver, "prepare", boom)
    for kwargs, match in (
        ({"noise": -1.0}, "noise=-1.0: expected a standard deviation >= 0"),
        ({"noise": float("nan")}, "noise=nan"),
        ({"ipopt_options": {"max_itr": 3}}, "did you mean max_iter"),
        ({"options": {"tol": -1.0}}, "tol=-1.0: expected a positive number"),
        ({"solver": "snopt"}, "unknown solver 'snopt'"),
        # progress arguments (they were refused only after the NLP was built)
        ({"progress_every": 0}, "progress_every=0: expected an integer >= 1"),
        ({"progress": False, "progress_every": 1.5}, "progress_every=1.5: expected an integer >= 1"),
        ({"progress": "loud"}, "progress='loud': expected True, False/None, a text stream or an AbstractCallback"),
        ({"progress": solvers.RecordIterates(), "solver": "jtraj"}, "which solver='jtraj' does not report: record them with solver='ipopt'"),
    ):
        with pytest.raises((ValueError, TypeError), match=match):
            jtraj.solver.solve("big_jump", **kwargs)


def test_registry_names_the_choices():
    assert isinstance(solvers.get("ipopt"), IpoptSolver)
    assert isinstance(solvers.get(IpoptSolver), IpoptSolver)  # the class for an object: was "unknown solver <class ...>"
    with pytest.raises(ValueError, match=r"unknown solver 'snopt'; expected one of \['ipopt'"):
        solvers.get("snopt")


def test_progress_true_prints_to_the_stdout_of_the_call(walk_nlp, monkeypatch):
    # resolved when the solve runs: a stream swapped in after import still receives it
    stream = io.StringIO()
    monkeypatch.setattr(sys, "stdout", stream)
    IpoptSolver().solve(walk_nlp, np.zeros(walk_nlp.n), None, None, solvers.resolve_progress(True))
    assert "inf_pr" in stream.getvalue()
    assert solvers.resolve_progress(False) is None and solvers.resolve_progress(None) is None
    with pytest.raises(TypeError, match="progress=3"):
        solvers.resolve_progress(3)


def test_ipopt_solution_multipliers_satisfy_stationarity(walk_nlp):
    sol = IpoptSolver().solve(walk_nlp, np.zeros(walk_nlp.n), None, IpoptOptions(tol=1e-10, hessian="exact"))
    assert sol.status is Status.SOLVED and sol.converged, sol.message
    Z = sol.x.reshape(N, 2)
    assert np.all(Z[:, 1] <= 0.3 + 1e-8) and Z[0, 1] > 0.3 - 1e-6  # the first step is at its bound
    # grad f + J^T mult_g - mult_x_lower + mult_x_upper = 0 (Ipopt's sign convention)
    x = jnp.asarray(sol.x)
    J = walk_nlp.dense_jacobian(x)
    residual = np.asarray(walk_nlp.gradient(x, None)) + J.T @ sol.mult_g - sol.mult_x_lower + sol.mult_x_upper
    np.testing.assert_allclose(residual, 0.0, atol=1e-7)
    assert sol.mult_x_upper[1] > 1e-3  # the active bound carries a multiplier
    s = sol.stats
    assert s.iterations == sol.history[-1].iter and s.obj_evals > 0 and s.hess_evals > 0
    assert s.time_evaluations > 0.0  # time_solver = time_total - time_evaluations by definition


class StopAtTwo(AbstractCallback):
    """Records the iterations it sees and asks to stop at iteration 2."""

    def __init__(self):
        self.seen = []

    def on_iteration(self, it):
        self.seen.append(it.iter)
        return it.iter < 2


def test_callback_can_stop_the_solve(walk_nlp):
    cb = StopAtTwo()
    sol = IpoptSolver().solve(walk_nlp, np.zeros(walk_nlp.n), None, IpoptOptions(tol=1e-12), cb)
    assert sol.status is Status.USER_STOP and not sol.converged
    assert cb.seen == [0, 1, 2]


def test_record_iterates_keeps_ipopts_iterates(walk_nlp):
    """Ipopt's iterates through a callback: the starting point first, the solution
    last, one per reported iteration; with another callback in a list, both are served; jtraj's
    compiled solver refuses such a callback."""
    stream = io.StringIO()
    rec, progress = solvers.RecordIterates(), solvers.PrintProgress(stream)
    x0 = np.full(walk_nlp.n, 0.7)
    sol = IpoptSolver().solve(walk_nlp, x0, None, IpoptOptions(tol=1e-10, hessian="exact"), solvers.CallbackList([rec, progress]))
    assert sol.converged and len(rec.iterates) == len(sol.history) == sol.stats.iterations + 1 >= 3
    # the progress lines (a header, then one per iteration) were printed beside the recording
    assert len(stream.getvalue().splitlines()) == len(rec.iterates) + 1
    assert [it.iter for it in rec.iterations] == list(range(len(rec.iterates)))
    np.testing.assert_array_equal(rec.iterates[-1], sol.x)
    f = bind(walk_nlp, None)
    # the start clipped to the bounds, then pushed inside them by Ipopt (bound_push 1e-2)
    np.testing.assert_allclose(rec.iterates[0], np.clip(x0, f.x_lower, f.x_upper), atol=2e-2)
    assert not np.allclose(rec.iterates[1], rec.iterates[0])
    with pytest.raises(ValueError, match="no intermediate iterates"):
        solvers.get("jtraj").solve(walk_nlp, x0, None, None, solvers.RecordIterates())


def test_iteration_limit_is_reported(walk_nlp):
    sol = IpoptSolver().solve(walk_nlp, np.zeros(walk_nlp.n), None, {"max_iter": 1, "tol": 1e-12})
    assert sol.status is Status.MAX_ITER and "iteration" in sol.status.message


def test_wall_time_limit_is_reported_with_a_message(walk_nlp):
    sol = IpoptSolver().solve(walk_nlp, np.zeros(walk_nlp.n), None, {"max_wall_time": 1e-9, "tol": 1e-12})
    assert sol.status is Status.MAX_WALL_TIME
    assert sol.message == Status.MAX_WALL_TIME.message  # cyipopt's text for -5 was 'Unknown status'


def test_unknown_ipopt_option_names_it(walk_nlp):
    with pytest.raises(InvalidOptionError, match="not_an_option"):
        IpoptSolver().solve(walk_nlp, np.zeros(walk_nlp.n), None, {"not_an_option": 1})


def test_exact_hessian_is_compiled_before_the_timed_solve(monkeypatch):
    """With hessian="exact" the Hessian was built and its scatter compiled by Ipopt's first
    call, inside the timed solve: time_s held a compile that time_compile did not. It is now
    called once before the clock starts, once per NLP, and reported as time_compile."""
    import jtraj.solvers.ipopt as ipopt_backend

    nlp = _walk_nlp()
    calls_before_ipopt = []
    make_problem = ipopt_backend._Problem

    def counting_problem(nlp_, f, exact, callback):
        calls_before_ipopt.append(nlp_._hessian_built and calls[0])
        return make_problem(nlp_, f, exact, callback)

    calls = [0]
    monkeypatch.setattr(ipopt_backend, "_Problem", counting_problem)
    nlp.build_hessian()
    built = nlp.hessian
    monkeypatch.setattr(nlp, "hessian", lambda *a: (calls.__setitem__(0, calls[0] + 1), built(*a))[1])
    first = IpoptSolver().solve(nlp, np.zeros(nlp.n), None, IpoptOptions(tol=1e-10, hessian="exact"))
    second = IpoptSolver().solve(nlp, np.zeros(nlp.n), None, IpoptOptions(tol=1e-10, hessian="exact"))
    assert first.converged and second.converged
    assert calls_before_ipopt == [1, first.stats.hess_evals + 1]  # one warm-up call, before the first solve only
    assert first.time_compile > 0.0 and second.time_compile == 0.0
    lbfgs = IpoptSolver().solve(_walk_nlp(), np.zeros(nlp.n), None, IpoptOptions(tol=1e-10))
    assert lbfgs.time_compile == 0.0


@pytest.mark.parametrize("error", [KeyboardInterrupt, RuntimeError])
def test_an_exception_of_the_exact_hessian_stops_ipopt_and_is_raised(walk_nlp, monkeypatch, error):
    """cyipopt loses an exception raised in its Hessian callback (its other callbacks raise
    theirs after the solve): a Ctrl-C, or the command line's SIGTERM, during an exact-Hessian
    solve was ignored, and the solve went on from the values Ipopt's array happened to hold."""
    import jtraj.solvers.ipopt as ipopt_backend

    walk_nlp.build_hessian()
    real = walk_nlp.hessian
    calls = []

    def failing(*args):
        calls.append(1)
        if len(calls) == 3:
            raise error("stop here")
        return real(*args)

    class Recorder(AbstractCallback):
        def __init__(self):
            self.iterations = []

        def on_iteration(self, it):
            self.iterations.append(it.iter)

    monkeypatch.setattr(walk_nlp, "hessian", failing)
    monkeypatch.setattr(ipopt_backend, "_HESSIAN_COMPILED", {walk_nlp})  # (no compile call)
    recorder = Recorder()
    with pytest.raises(error, match="stop here"):
        IpoptSolver().solve(walk_nlp, np.zeros(walk_nlp.n), options={"hessian": "exact"}, callback=recorder)
    assert len(calls) == 3 and recorder.iterations == [0, 1, 2]  # (each report before its Hessian) stopped at the next one
    monkeypatch.setattr(walk_nlp, "hessian", real)
    assert IpoptSolver().solve(walk_nlp, np.zeros(walk_nlp.n), options={"hessian": "exact"}).status is Status.SOLVED


def test_an_option_of_the_other_solver_says_which_solver_takes_it():
    """Ipopt's linear_solver given to jtraj's solver was refused with the list of jtraj's ~50
    options; jtraj's delta_c_min given to Ipopt got Ipopt's nearest names (tau_min, delta)."""
    from jtraj.solvers.ipopt_catalog import IpoptOptionError, check

    with pytest.raises(InvalidOptionError, match=r"^unknown jtraj option\(s\) \['linear_solver'\] \('linear_solver' is an option of Ipopt: solver='ipopt', --solver ipopt\); expected one of"):
        IpmOptions.from_dict({"linear_solver": "ma57"})
    with pytest.raises(InvalidOptionError, match=r"\['bogus_name', 'linear_solver'\] \('linear_solver' is an option of Ipopt"):
        IpmOptions.from_dict({"linear_solver": "ma57", "bogus_name": 1})
    # an Ipopt option this solver has under another name: that name, not only "use Ipopt"
    with pytest.raises(InvalidOptionError, match=r"\('limited_memory_max_history' is this solver's 'lbfgs_memory'; 'linear_solver' is an option of Ipopt: solver='ipopt', --solver ipopt\)"):
        IpmOptions.from_dict({"linear_solver": "ma57", "limited_memory_max_history": 5})
    from jtraj.solvers.ipm import IPOPT_NAMES
    from jtraj.solvers.ipopt_catalog import catalog

    fields = {f.name for f in dataclasses.fields(IpmOptions)}
    assert all(name in catalog() and ours in fields and name not in fields for name, ours in IPOPT_NAMES.items())
    with pytest.raises(IpoptOptionError, match=r"^--ipopt delta_c_min: 1e-09: unknown Ipopt option; an option of jtraj's solver \(solver='jtraj', --solver jtraj\)$"):
        check("delta_c_min", 1e-9)
    with pytest.raises(IpoptOptionError, match=r"did you mean max_iter"):  # a typo still gets Ipopt's nearest names
        check("max_itr", 5)
    with pytest.raises(IpoptOptionError) as info:  # a name both take is no hint to the other solver
        check("hessian", "exact")
    assert "jtraj's solver" not in str(info.value)


def test_ipopt_options_given_twice_are_refused_and_merge_takes_the_new_extra():
    """An Ipopt option given at the top level and in ``extra`` with two values: the top
    level's won without a word. merge() put these options' extra beside the new values at the
    top level, so a new value given in the new values' extra was dropped."""
    with pytest.raises(InvalidOptionError, match=r"^Ipopt option mu_init: given as 0.1 and in extra as 0.5; expected one value$"):
        IpoptOptions.from_dict({"mu_init": 0.1, "extra": {"mu_init": 0.5}})
    assert IpoptOptions.from_dict({"mu_init": 0.1, "extra": {"mu_init": 0.1}}).extra == {"mu_init": 0.1}
    old = IpoptOptions(extra={"mu_init": 0.1, "bound_push": 0.02})
    assert old.merge({"extra": {"mu_init": 0.5}}).extra == {"mu_init": 0.5, "bound_push": 0.02}
    assert old.merge({"mu_init": 0.5}).extra == {"mu_init": 0.5, "bound_push": 0.02}
    assert old.merge({"tol": 1e-6}).extra == old.extra and old.merge({"tol": 1e-6}).tol == 1e-6
    # a field in the new extra is refused as from_dict refuses it; hessian_approximation there
    # is refused the same way, not as a conflict with a hessian the caller never gave
    for extra in ({"tol": 1e-6}, {"hessian_approximation": "exact"}):
        with pytest.raises(InvalidOptionError, match="has its own field"):
            old.merge({"extra": extra})
    assert IpoptOptions().merge({"hessian_approximation": "exact"}).hessian == "exact"


def test_ipopt_options_this_build_cannot_use_are_refused_before_a_solve():
    """nlp_scaling_method='user-scaling' was accepted and solved as 'none' (jtraj gives Ipopt
    no scaling factors); 'equilibration-based' and extra linear_system_scaling='mc19' need HSL's
    MC19, which the bundled Ipopt lacks: accepted, the solve then stopped with 'Invalid option
    encountered.' naming none of them."""
    import ctypes.util

    from jtraj.solvers import ipopt_catalog

    with pytest.raises(InvalidOptionError, match=r"nlp_scaling_method='user-scaling': expected one of \['none', 'gradient-based', 'equilibration-based'\]"):
        IpoptOptions(nlp_scaling_method="user-scaling")
    # whether HSL is there, told apart from the probe under test (a probe that said "usable"
    # everywhere passed when the test branched on its own answer)
    hsl = ctypes.util.find_library("hsl") is not None or ctypes.util.find_library("coinhsl") is not None
    assert ipopt_catalog.value_usable("linear_system_scaling", "mc19") == hsl
    assert ipopt_catalog.value_usable("nlp_scaling_method", "equilibration-based") == hsl  # both are MC19
    assert ipopt_catalog.value_usable("linear_system_scaling", "none") and ipopt_catalog.value_usable("mu_strategy", "monotone")
    if hsl:  # an Ipopt built with HSL takes them
        IpoptOptions(nlp_scaling_method="equilibration-based", extra={"linear_system_scaling": "mc19"})
    else:
        with pytest.raises(InvalidOptionError, match=r"equilibration-based'.*needs HSL's MC19"):
            IpoptOptions(nlp_scaling_method="equilibration-based")
        with pytest.raises(InvalidOptionError, match=r"linear_system_scaling='mc19'.*cannot use it"):
            IpoptOptions(extra={"linear_system_scaling": "mc19"})
    assert IpoptOptions(extra={"linear_system_scaling": "none"}).extra == {"linear_system_scaling": "none"}
    # only those options are probed: a probe of hessian_approximation=exact on the tiny
    # problem (no Hessian) logged a false cyipopt error, and a value cyipopt's add_option
    # refuses raised its TypeError out of the check
    assert set(ipopt_catalog._LIBRARY_OPTIONS) == {"nlp_scaling_method", "linear_system_scaling"}
    assert not ipopt_catalog.value_usable("linear_system_scaling", "no-such-value")


def test_an_interrupt_during_ipopts_derivative_check_stops_the_evaluations(walk_nlp, monkeypatch):
    """A Ctrl-C, or the command line's SIGTERM (raised once), in a callback during Ipopt's
    derivative check: cyipopt keeps the exception and reports a failed evaluation, and the
    checker went on perturbing every variable, each a full evaluation (on big_jump, a SIGTERM
    was still unanswered after 100 s). After the exception no callback evaluates again, Ipopt
    stops, and the solve raises it."""
    real = walk_nlp.constraints
    calls = []

    def interrupted(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt("stop here")
        return real(*args, **kwargs)

    monkeypatch.setattr(walk_nlp, "constraints", interrupted)
    with pytest.raises(KeyboardInterrupt, match="stop here"):
        IpoptSolver().solve(walk_nlp, np.full(walk_nlp.n, 0.1), options={"derivative_test": "first-order", "print_level": 0})
    assert len(calls) == 3
    assert walk_nlp.n > 10  # the checker would have called the constraints once per variable
