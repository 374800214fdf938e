"""Edges of the solver backends' inputs (`jtraj.solvers.base`): what an initial guess and a
theta must be, refused by name before anything compiles. Tiny NLPs only (tests/test_ipm.py's
double integrator, `jtraj.sensitivity.DenseNLP`); nothing here reaches a solver's program."""

import dataclasses
from types import SimpleNamespace

import jax.numpy as jnp
import numpy as np
import pytest
from test_ipm import K, double_integrator
from test_solver_inputs import no_program

from jtraj import solvers
from jtraj.result import Outcome, Result
from jtraj.sensitivity import DenseNLP
from jtraj.solvers import Stats, Status
from jtraj.solvers.base import bind, initial_guess
from jtraj.transcription import TaskParams, Trajectory


def _dense() -> DenseNLP:
    """min (x0 - 1)^2 + (x1 - 2)^2 with x0 + x1 = theta: an NLP without knots or locate."""
    return DenseNLP(
        lambda x, theta: (x[0] - 1.0) ** 2 + (x[1] - 2.0) ** 2,
        lambda x, theta: jnp.atleast_1d(x[0] + x[1] - theta),
        lambda theta: (np.full(2, -np.inf), np.full(2, np.inf), np.zeros(1), np.zeros(1)),
        2,
        1,
    )


def _result() -> Result:
    """A Result as a solve returns it (the numbers do not matter here)."""
    return Result(
        problem="p", variant="se3", model="m", solver="ipopt", status=Outcome.SOLVED, solver_status=Status.SOLVED, status_msg="",
        stats=Stats(), time_compile=0.0, cost=0.0, constraint_violation=0.0, violation_by_group={}, metrics={}, n_variables=3 * K,
        n_constraints=0,
    )


@pytest.mark.parametrize(
    "where, value, message",
    [
        # (K, nz): the index as given, and the knot and slot by the NLP's locate
        ((3, 1), np.nan, r"x0\[3, 1\] \(at knot 3, slot 'v' entry 0\) is nan \(2 NaN or infinite entries of x0\): an initial guess must be finite"),
        ((2, 2), -np.inf, r"x0\[2, 2\] \(at knot 2, slot 'u' entry 0\) is -inf \(2 NaN or infinite entries of x0\)"),
    ],
)
def test_a_non_finite_initial_guess_is_refused_by_its_place(where, value, message):
    # a NaN or inf start was taken: the solve compiled, then ended in NUMERICAL_ERROR with cost NaN
    nlp = double_integrator()
    x0 = np.zeros((K, 3))
    x0[where] = value
    x0[-1, 0] = np.nan  # a second bad entry, after the first
    with pytest.raises(ValueError, match=message):
        initial_guess(nlp, x0)
    flat = rf"x0\[{where[0] * 3 + where[1]}\] \(at knot {where[0]}, "  # the flat vector: its flat index, the same place
    with pytest.raises(ValueError, match=flat):
        initial_guess(nlp, x0.reshape(-1))
    for backend in ("ipopt", "jtraj"):  # refused before anything is built
        with pytest.raises(ValueError, match=message):
            solvers.get(backend).solve(nlp, x0)
    assert no_program(nlp)  # (neither solver built anything: Ipopt calls the jitted functions)


def test_a_non_finite_initial_guess_without_a_layout_names_its_flat_index():
    with pytest.raises(ValueError, match=r"^x0\[1\] is nan \(1 NaN or infinite entries of x0\)"):
        initial_guess(_dense(), [0.0, np.nan])
    # knots and columns, but no locate: the knot and column of the (knots, nz) form
    nlp = SimpleNamespace(n=6, n_knots=3, nz=2)
    with pytest.raises(ValueError, match=r"^warm_start\[1, 1\] \(at knot 1, column 1\) is inf"):
        initial_guess(nlp, np.array([[0, 0], [0, np.inf], [0, 0]]), "warm_start")
    np.testing.assert_array_equal(initial_guess(nlp, np.arange(6.0).reshape(3, 2)), np.arange(6.0))


@pytest.mark.parametrize("given", ["result", "trajectory", "ragged", "word"])
def test_an_initial_guess_that_is_no_array_says_what_is_expected(given):
    # float() argument must be a string or a real number, not 'Result'
    nlp = double_integrator()
    x0 = {
        "result": _result(),
        "trajectory": Trajectory(**{f.name: np.zeros((K, 3)) for f in dataclasses.fields(Trajectory)}),
        "ragged": [[0.0, 0.0, 0.0]] * (K - 1) + [[0.0]],
        "word": "zeros",
    }[given]
    kind = type(x0).__name__
    with pytest.raises(TypeError, match=rf"^warm_start of type {kind}: expected an array of numbers of shape \({3 * K},\) or \({K}, 3\) .*"
                       r"a Result or its trajectory holds no such array \(jtraj.transcription.Transcription.warm_start gives a task's own start\)"):
        initial_guess(nlp, x0, "warm_start")


def _task_params() -> TaskParams:
    """A TaskParams of made-up values, without a task or robot."""
    return TaskParams(**{f.name: jnp.zeros(3) for f in dataclasses.fields(TaskParams)})


@pytest.mark.parametrize("theta", [{"friction": 0.5}, "fields"])
def test_a_theta_of_another_structure_names_the_type_expected(theta):
    # a dict of overrides (as jtraj.solve takes them) passed on to a backend failed inside the
    # bound functions with AttributeError: 'dict' object has no attribute 'max_delta_force'
    own = _task_params()
    nlp = double_integrator(theta=own)
    theta = tuple(vars(own).values()) if theta == "fields" else theta
    match = (
        rf"^theta of type {type(theta).__name__} does not have the structure of the NLP's own theta: expected a TaskParams with the same fields "
        r".*jtraj.transcription.Transcription.resolve_theta"
    )
    with pytest.raises(TypeError, match=match):
        bind(nlp, theta)
    for backend in ("ipopt", "jtraj"):
        with pytest.raises(TypeError, match=match):
            solvers.get(backend).solve(nlp, np.zeros(nlp.n), theta)
    assert no_program(nlp)  # (neither solver built anything: Ipopt calls the jitted functions)
    # None (the NLP's own) and a TaskParams of the same fields still bind
    for fine in (None, own, own.replace(friction=jnp.ones(3))):
        assert bind(nlp, fine).x_lower.shape == (nlp.n,)


def test_a_theta_of_another_structure_of_any_nlp_is_a_type_error():
    nlp = double_integrator(lambda th: th["vmin"] * jnp.ones((K, 1)), lambda th: th["vmax"] * jnp.ones((K, 1)), {"vmin": -1.0, "vmax": 0.35})
    with pytest.raises(TypeError, match=r"^theta of type dict does not have the structure of the NLP's own theta: expected a dict with the same fields \(nlp.theta, or None for it\)$"):
        bind(nlp, {"vmax": 0.3})
    assert float(bind(nlp, {"vmin": -2.0, "vmax": 0.3}).g_upper[-1]) == 0.3


def test_a_theta_with_the_same_leaves_in_another_sequence_type_binds():
    """The check compares the leaves' paths, not the tree types: a list for the NLP's tuple
    (the same parameters) was refused when the structures were compared."""
    nlp = double_integrator(lambda th: th[0] * jnp.ones((K, 1)), lambda th: th[1] * jnp.ones((K, 1)), (-1.0, 0.35))
    assert float(bind(nlp, [-2.0, 0.3]).g_upper[-1]) == 0.3
    with pytest.raises(TypeError, match=r"^theta of type list does not have the structure"):
        bind(nlp, [-2.0, 0.3, 1.0])


def test_a_traced_initial_guess_keeps_jaxs_own_error():
    """The solvers run on the host: a guess traced under jit was reported as "x0 of type
    DynamicJaxprTracer ... a Result or its trajectory holds no such array"."""
    import jax

    nlp = double_integrator()
    with pytest.raises(jax.errors.TracerArrayConversionError):
        jax.jit(lambda x: initial_guess(nlp, x).sum())(jnp.zeros(nlp.n))
