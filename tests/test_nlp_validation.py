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


def _nlp(cost_knots=None, step_knots=None, active=None, lower=None, upper=None, row_lower=None, step_fn=None, cost_fn=None, row_upper=None, batched_jacobian=None):
    """x_{k+1} = x_k at the knots ``step_knots`` (default 0 to N - 2), cost |u_k|^2 at
    ``cost_knots`` (default all), variables within [lower, upper] (default [-1, 1]);
    ``step_fn``, ``cost_fn``, ``row_upper`` and ``batched_jacobian`` replace the groups' own."""
    cost_knots = np.arange(N) if cost_knots is None else cost_knots
    step_knots = np.arange(N - 1) if step_knots is None else step_knots
    lower = np.full((N, 3), -1.0) if lower is None else lower
    upper = np.full((N, 3), 1.0) if upper is None else upper
    K = len(step_knots)
    step = ConstraintGroup(
        "step", (Dep("x"), Dep("x", 1)), step_fn or (lambda theta, data, x, x1: x1 - x), step_knots,
        np.zeros((K, 2)) if row_lower is None else row_lower, row_upper or (lambda theta: 0.0), np.ones((K, 2), bool) if active is None else active,
        batched_jacobian=batched_jacobian,
    )
    effort = CostGroup("effort", (Dep("u"),), cost_fn or (lambda theta, data, u: jnp.sum(u**2)), cost_knots)
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
    with pytest.raises(ValueError, match=r"variable bounds: 1 with lower > upper \(or NaN, or a lower bound of \+inf or an upper one of -inf\), the first at knot 1, slot 'u' entry 0: lower 2, upper 1"):
        _nlp(lower=lower)
    upper = np.full((N, 3), 1.0)
    upper[2, 1] = np.nan
    with pytest.raises(ValueError, match=r"the first at knot 2, slot 'x' entry 1: lower -1, upper nan"):
        _nlp(upper=upper)
    row_lower = np.zeros((N - 1, 2))
    row_lower[1, 1] = 0.5  # the rows' upper bound is 0
    with pytest.raises(ValueError, match=r"constraint bounds: 1 rows with lower > upper \(or NaN, or a lower bound of \+inf or an upper one of -inf\), the first in group step at knot 1, row 1: lower 0.5, upper 0"):
        _nlp(row_lower=row_lower)
    # a dropped row's bounds are not looked at
    active = np.ones((N - 1, 2), bool)
    active[1, 1] = False
    assert _nlp(row_lower=row_lower, active=active).m == 3


def test_bounds_that_nothing_meets_are_refused():
    """A lower bound of +inf (or an upper one of -inf) passed `lower <= upper`: jtraj's solver
    then reported the problem solved, Ipopt a numerical error."""
    lower = np.full((N, 3), -1.0)
    lower[2, 0] = np.inf
    upper = np.full((N, 3), np.inf)
    with pytest.raises(ValueError, match=r"variable bounds: 1 with .*, the first at knot 2, slot 'x' entry 0: lower inf, upper inf$"):
        _nlp(lower=lower, upper=upper)
    row_lower = np.zeros((N - 1, 2))
    row_lower[0, 1] = np.inf
    with pytest.raises(ValueError, match=r"constraint bounds: 1 rows with .*, the first in group step at knot 0, row 1: lower inf, upper inf$"):
        _nlp(row_lower=row_lower, row_upper=lambda theta: np.inf)
    upper = np.full((N, 3), 1.0)
    upper[0, 2] = -np.inf
    with pytest.raises(ValueError, match=r"the first at knot 0, slot 'u' entry 0: lower -1, upper -inf$"):
        _nlp(upper=upper)


def test_a_solvers_bound_check_refuses_infinite_bounds_nothing_meets():
    """The backends' check of the bounds at the theta they solve at (a traced or other theta
    than the NLP's default) let a +inf lower bound through."""
    from jtraj.solvers.base import BoundNLP

    def bound(**changes):
        fields = dict(x_lower=np.full(2, -1.0), x_upper=np.full(2, 1.0), g_lower=np.zeros(1), g_upper=np.zeros(1))
        return BoundNLP(None, None, None, None, None, **{**fields, **changes})

    assert bound().inconsistent() is None
    assert bound(x_upper=np.array([1.0, np.inf])).inconsistent() is None
    assert bound(g_lower=np.array([np.inf]), g_upper=np.array([np.inf])).inconsistent() == "inconsistent bounds: g_lower[0]=inf and g_upper[0]=inf (1 such g bound(s))"
    assert bound(x_upper=np.array([1.0, -np.inf])).inconsistent() == "inconsistent bounds: x_lower[1]=-1.0 > x_upper[1]=-inf (1 such x bound(s))"
    assert bound(x_lower=np.array([2.0, -1.0])).inconsistent() == "inconsistent bounds: x_lower[0]=2.0 > x_upper[0]=1.0 (1 such x bound(s))"


@pytest.mark.parametrize(
    "kwargs, message",
    [
        # one row where active has two: the gather clamped its indices and read garbage rows
        (dict(step_fn=lambda theta, data, x, x1: (x1 - x)[:1]), r"group step: fn returns ShapeDtypeStruct\(shape=\(1,\), dtype=float64\) per knot; expected \(2,\) \(one value per row of active\), of floats$"),
        # three rows: numpy's broadcasting error, naming no group
        (dict(step_fn=lambda theta, data, x, x1: jnp.concatenate([x1 - x, x[:1]])), r"group step: fn returns .*shape=\(3,\).*; expected \(2,\)"),
        (dict(step_fn=lambda theta, data, x, x1: (x1 - x)[:, None]), r"group step: fn returns .*shape=\(2, 1\).*; expected \(2,\)"),
        # integers truncated the values and made the Jacobian zero
        (dict(step_fn=lambda theta, data, x, x1: (x1 - x).astype(jnp.int32)), r"group step: fn returns .*dtype=int32.*; expected \(2,\) \(one value per row of active\), of floats$"),
        # a vector cost was summed without a word
        (dict(cost_fn=lambda theta, data, u: u**2), r"group effort: fn returns .*shape=\(1,\).*; expected a scalar cost per knot, of floats$"),
        (dict(batched_jacobian=lambda theta, data, x, x1: jnp.zeros((2, 4))), r"group step: batched_jacobian returns .*shape=\(2, 4\).*; expected shape \(2, 2, 4\) \(knots, rows, dependency columns\)$"),
        (dict(row_upper=lambda theta: jnp.zeros(3)), r"group step: upper\(theta\) has shape \(3,\); expected one that broadcasts to the shape of active \(2, 2\) \(K, rows\)$"),
        # a float mask failed deep in the build; a 0/1 integer one indexed rows by number
        (dict(active=np.ones((N - 1, 2))), r"group step: active has dtype float64; expected a boolean \(K, rows\) mask \(or 0/1 integers\)$"),
        (dict(active=np.full((N - 1, 2), 2)), r"group step: active has dtype int64"),
        (dict(step_knots=np.array([0.0, 1.0])), r"group step: knots has shape \(2,\) and dtype float64; expected a 1-D array of knot indices \(integers\)$"),
    ],
)
def test_groups_whose_functions_return_the_wrong_shape_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        _nlp(**kwargs)


def test_a_01_integer_mask_and_a_list_of_knots_are_taken():
    """A 0/1 integer mask was used as row numbers (a wrong Jacobian); a list of knots raised an
    AttributeError."""
    import jax

    nlp = _nlp(active=np.ones((N - 1, 2), int), step_knots=[0, 1])
    x = jnp.asarray(np.random.default_rng(0).normal(size=nlp.n))
    assert nlp.m == 4 and np.allclose(nlp.dense_jacobian(x), jax.jacfwd(lambda y: nlp.constraints(y, None))(x))


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


def test_dense_groups_and_costs_keep_their_whole_hessian_block():
    """``dense`` reached the Jacobian's structure only: the Hessian's probes, whose entries are
    0.2 to 1 in size, dropped the x entry of ``y + max(x - 1.5, 0) ** 2`` (a row and a cost),
    and Ipopt's exact Hessian and the implicit derivatives read it as 0 (3.4 at x = 2)."""
    import jax

    layout = Layout((("x", 1), ("y", 1)))
    kink = lambda x: jnp.maximum(x - 1.5, 0.0) ** 2  # noqa: E731

    def build(dense):
        row = ConstraintGroup("row", (Dep("x"), Dep("y")), lambda theta, data, x, y: y + kink(x), np.arange(1), np.zeros((1, 1)), np.zeros((1, 1)), np.ones((1, 1), bool), dense=dense)
        cost = CostGroup("cost", (Dep("x"), Dep("y")), lambda theta, data, x, y: jnp.sum(kink(x) + y**2), np.arange(1), dense=dense)
        nlp = KnotNLP(layout, 1, [cost], [row], np.full((1, 2), -10.0), np.full((1, 2), 10.0))
        nlp.build_hessian()
        return nlp

    x, lam = jnp.array([2.0, 0.3]), jnp.array([0.7])
    lagrangian = lambda z: jnp.sum(kink(z[0]) + z[1] ** 2) + lam[0] * (z[1] + kink(z[0]))  # noqa: E731
    reference = np.tril(np.asarray(jax.hessian(lagrangian)(x)))
    assert reference[0, 0] == pytest.approx(3.4)
    for dense, expected in ((True, reference), (False, np.diag([0.0, 2.0]))):  # probed: the entry is lost
        nlp = build(dense)
        got = np.zeros((2, 2))
        np.add.at(got, (nlp.hess_rows, nlp.hess_cols), np.asarray(nlp.hessian(x, lam, 1.0, None)))
        np.testing.assert_allclose(got, expected, atol=1e-12)


@pytest.mark.parametrize("n_probes", [0, -1, 1.5, True])
def test_probes_must_be_a_whole_number_of_at_least_one(n_probes):
    """No probe kept no entry: n_probes=0 built an NLP with an empty Jacobian (and
    build_hessian an empty Hessian) without a word."""
    message = rf"n_probes={n_probes!r}: expected a whole number >= 1"
    with pytest.raises(ValueError, match=message):
        KnotNLP(LAYOUT, N, [], [], -1.0, 1.0, n_probes=n_probes)
    nlp = _nlp()
    with pytest.raises(ValueError, match=message):
        nlp.build_hessian(n_probes=n_probes)
    assert nlp.nnz_jac > 0


def test_split_and_join_check_the_size_of_the_last_axis():
    """A flat x (n,) split as one knot gave knot 0's slots; a short z read clamped entries
    (JAX) and join broadcast a state of size 1 over the whole state."""
    from jtraj.nlp import KnotStructure

    with pytest.raises(ValueError, match=r"z has shape \(9,\); expected \(\.\.\., nz\) with nz = 3"):
        LAYOUT.split(jnp.zeros(N * 3))
    assert LAYOUT.split(jnp.zeros((N, 3)))["x"].shape == (N, 2)
    S = KnotStructure(LAYOUT, ("x",), ("u",), lambda x, u, theta: x)
    with pytest.raises(ValueError, match=r"z has shape \(2,\); expected \(\.\.\., nz\) with nz = 3"):
        S.split(jnp.zeros(2))
    with pytest.raises(ValueError, match=r"x has shape \(1,\); expected \(\.\.\., nx\) with nx = 2"):
        S.join(jnp.ones(1), jnp.ones(1))
    with pytest.raises(ValueError, match=r"u has shape \(N, 2\); expected \(\.\.\., nu\) with nu = 1".replace("N", str(N))):
        S.join(jnp.ones((N, 2)), jnp.ones((N, 2)))
    z = jnp.arange(6.0).reshape(2, 3)
    x, u = S.split(z)
    np.testing.assert_array_equal(S.join(x, u), z)


def test_hessian_before_build_hessian_says_so():
    """nlp.hessian and its structure exist once build_hessian() has run: before, the message
    named the attribute alone; and an NLP without cost or rows ended in numpy's "need at least
    one array to concatenate"."""
    nlp = _nlp()
    for name in ("hessian", "hess_rows", "hess_cols", "nnz_hess"):
        with pytest.raises(AttributeError, match=rf"KnotNLP.{name} is built by build_hessian\(\): call build_hessian\(\) first"):
            getattr(nlp, name)
    with pytest.raises(AttributeError, match="has no attribute 'hesian'"):
        nlp.hesian  # noqa: B018
    nlp.build_hessian()
    assert nlp.nnz_hess > 0 and nlp.hess_rows.size == nlp.nnz_hess
    empty = KnotNLP(LAYOUT, N, [], [], -1.0, 1.0)
    empty.build_hessian()
    assert (empty.m, empty.nnz_jac, empty.nnz_hess) == (0, 0, 0)
    assert empty.hessian(jnp.zeros(empty.n), jnp.zeros(0), 1.0, None).shape == (0,)


def test_variable_bounds_and_group_data_of_the_wrong_shape_name_them():
    """Flat (n,) variable bounds (the solver's shape) failed in JAX's broadcasting, and a group's
    data with another leading axis than its knots in vmap, naming neither."""
    flat = np.full(N * 3, -1.0)
    expected = r"expected one that broadcasts to \(n_knots, nz\) = \(3, 3\)$"
    with pytest.raises(ValueError, match=r"variable bounds: lower has shape \(9,\); " + expected):
        _nlp(lower=flat)
    with pytest.raises(ValueError, match=r"variable bounds: upper\(theta\) has shape \(9,\); " + expected):
        _nlp(upper=lambda theta: jnp.ones(N * 3))
    assert _nlp(lower=-1.0, upper=np.ones(3)).n == N * 3  # what broadcasts is taken

    def weighted(data):
        cost = CostGroup("weighted", (Dep("u"),), lambda theta, data, u: data["w"] * jnp.sum(u**2), np.arange(N), data=data)
        return KnotNLP(LAYOUT, N, [cost], [], -1.0, 1.0)

    with pytest.raises(ValueError, match=r"group weighted: data\['w'\] has shape \(4,\); expected a leading knot axis of K = 3 \(one entry per knot of knots\)$"):
        weighted({"w": jnp.ones(N + 1)})
    with pytest.raises(ValueError, match=r"group weighted: data\['w'\] has shape \(\); expected a leading knot axis of K = 3"):
        weighted({"w": 2.0})
    assert float(weighted({"w": jnp.full(N, 2.0)}).objective(jnp.ones(N * 3), None)) == 2.0 * N
