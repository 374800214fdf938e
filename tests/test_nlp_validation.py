"""Input checks of `jtraj.nlp`: layouts, groups and bounds that cannot make an NLP are refused
with a message naming what is wrong (tiny problems: three knots, three variables each)."""

import jax.numpy as jnp
import numpy as np
import pytest

from jtraj.nlp import ConstraintGroup, CostGroup, Dep, KnotNLP, Layout

LAYOUT = Layout((("x", 2), ("u", 1)))


def test_unknown_slot_names_the_layout():
    """Every look-up of an unknown slot says which slots there are; size() raised a bare KeyError('y')."""
    for lookup in (LAYOUT.size, LAYOUT.offset, LAYOUT.slice, lambda name: LAYOUT.columns([name])):
        with pytest.raises(KeyError, match=r"no slot 'y' in layout \['x', 'u'\]"):
            lookup("y")


@pytest.mark.parametrize(
    "slots, message",
    [
        # offset() found the first 'x' and size() the last one's size
        ((("x", 2), ("x", 3)), r"slot 'x' appears twice"),
        ((("x", -1),), r"slot 'x' has size -1; expected a whole number >= 0"),
        ((("x", 1.5),), r"slot 'x' has size 1.5"),
    ],
)
def test_layout_refuses_repeated_names_and_bad_sizes(slots, message):
    with pytest.raises(ValueError, match=message):
        Layout(slots)


N = 3  # knots


def _nlp(cost_knots=None, step_knots=None, active=None, lower=None, upper=None, row_lower=None):
    """x_{k+1} = x_k at the knots ``step_knots`` (default 0 to N - 2), cost |u_k|^2 at
    ``cost_knots`` (default all), variables within [lower, upper] (default [-1, 1])."""
    cost_knots = np.arange(N) if cost_knots is None else cost_knots
    step_knots = np.arange(N - 1) if step_knots is None else step_knots
    lower = np.full((N, 3), -1.0) if lower is None else lower
    upper = np.full((N, 3), 1.0) if upper is None else upper
    K = step_knots.size
    step = ConstraintGroup(
        "step", (Dep("x"), Dep("x", 1)), lambda theta, data, x, x1: x1 - x, step_knots,
        np.zeros((K, 2)) if row_lower is None else row_lower, lambda theta: 0.0, np.ones((K, 2), bool) if active is None else active,
    )
    effort = CostGroup("effort", (Dep("u"),), lambda theta, data, u: jnp.sum(u**2), cost_knots)
    return KnotNLP(LAYOUT, N, [effort], [step], lower, upper)


def test_small_nlp_builds():
    nlp = _nlp()
    assert (nlp.n, nlp.m) == (9, 4)
    assert float(nlp.objective(jnp.ones(nlp.n), None)) == 3.0


@pytest.mark.parametrize(
    "kwargs, message",
    [
        # a cost's knots were not checked: knots 3 and 4 read knot 2 again (objective 5, not 3)
        (dict(cost_knots=np.arange(N + 2)), r"group effort: knots reach past the last knot 2"),
        # a negative knot read knot N - 1 (numpy's and JAX's wrap-around)
        (dict(cost_knots=np.array([-1, 0])), r"group effort: knots must be >= 0, got -1"),
        (dict(step_knots=np.array([-1, 0])), r"group step: knots must be >= 0, got -1"),
        # more rows of active than knots, bounds as functions of theta: the NLP was built with
        # rows for a knot the group does not have
        (dict(active=np.ones((N, 2), bool), row_lower=lambda theta: 0.0), r"group step: active has shape \(3, 2\); expected \(K, rows\) with K = 2 knots"),
    ],
)
def test_groups_must_stay_within_the_knots(kwargs, message):
    with pytest.raises(ValueError, match=message):
        _nlp(**kwargs)


def test_bounds_with_lower_above_upper_are_refused():
    """An empty interval among the bounds is refused when the NLP is built, naming where it is;
    it was built, and a solver reports such a problem only as infeasible or invalid."""
    lower = np.full((N, 3), -1.0)
    lower[1, 2] = 2.0  # knot 1, slot u, entry 0
    with pytest.raises(ValueError, match=r"variable bounds: 1 with lower > upper \(or NaN\), the first at knot 1, slot 'u' entry 0: lower 2, upper 1"):
        _nlp(lower=lower)
    upper = np.full((N, 3), 1.0)
    upper[2, 1] = np.nan
    with pytest.raises(ValueError, match=r"the first at knot 2, slot 'x' entry 1: lower -1, upper nan"):
        _nlp(upper=upper)
    row_lower = np.zeros((N - 1, 2))
    row_lower[1, 1] = 0.5  # the rows' upper bound is 0
    with pytest.raises(ValueError, match=r"constraint bounds: 1 rows with lower > upper \(or NaN\), the first in group step at knot 1, row 1: lower 0.5, upper 0"):
        _nlp(row_lower=row_lower)
    # a dropped row's bounds are not looked at
    active = np.ones((N - 1, 2), bool)
    active[1, 1] = False
    assert _nlp(row_lower=row_lower, active=active).m == 3


def test_violation_of_a_nan_point_is_nan():
    """A NaN variable is no feasible point, also where no constraint row reads it (Python's
    max(0.0, nan) is 0.0, which reported it as feasible)."""
    layout = Layout((("p", 1), ("u", 1)))
    K = 3
    rows = ConstraintGroup("p", (Dep("p"),), lambda theta, data, p: p, np.arange(K), np.full((K, 1), -1.0), np.full((K, 1), 1.0), np.ones((K, 1), bool))
    cost = CostGroup("u", (Dep("u"),), lambda theta, data, u: jnp.sum(u**2), np.arange(K))
    nlp = KnotNLP(layout, K, [cost], [rows], np.full((K, 2), -1.0), np.full((K, 2), 1.0))
    x = np.zeros(nlp.n)
    assert nlp.violation(x) == 0.0
    x[1] = np.nan  # u at the first knot: no row reads it
    assert np.isnan(nlp.violation(x))
    assert np.isnan(nlp.violation_by_group(x)["bounds"]) and nlp.violation_by_group(x)["p"] == 0.0
