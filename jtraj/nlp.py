"""Sparse nonlinear programs with knot structure and parameters, assembled from per-knot JAX functions.

A trajectory NLP has one block of variables per knot, ``z_k`` (the same `Layout`, a tuple of
named slots, at every knot) stacked as ``Z`` of shape (n_knots, nz); the solver's vector is
``x = Z.ravel()``. Costs and constraints come in groups. A group is written for ONE knot: it
reads some slots of knot k and possibly of knot k+1 (its dependencies) and returns a fixed
number of rows; it is vmapped over the knots it applies to. Per knot, a boolean mask selects
which rows are real constraints (a contact that is not active drops its rows); masks and
knots are numpy data fixed when the NLP is built.

Parameters. Every number a user may vary or differentiate enters as a parameter pytree
``theta`` (any pytree of float arrays; the whole-body problem's is
`jtraj.transcription.TaskParams`), an explicit argument of every function:

    objective(x, theta) -> ()                 gradient(x, theta) -> (n,)
    constraints(x, theta) -> (m,)             jacobian(x, theta) -> (nnz_jac,) COO values
    hessian(x, lam, obj_factor, theta) -> (nnz_hess,) lower-triangle COO values
    bounds(theta) -> (x_lower (n,), x_upper (n,), g_lower (m,), g_upper (m,))

A group's function is ``fn(theta, data_k, *deps_k)`` (a cost's likewise); its row bounds and
the variable bounds are arrays or callables of theta. ``theta`` is traced: all functions are
jitted once per shape, changing its values never recompiles, and ``jax.vmap`` over theta (or
over x) works for all of them (give its leaves as float64 arrays: a Python scalar is weakly
typed, another signature, and compiles once more). ``nlp.theta`` holds the default parameters the builder gave;
``x_lower``, ``x_upper``, ``g_lower``, ``g_upper`` are numpy copies of the bounds there.
An NLP without parameters passes ``theta=None``.

The sparse constraint Jacobian:
- structure: once, from the dependencies of each group (a dense block per knot, rows x
  dependency columns) thinned to the entries that are nonzero at random probe points (random
  variables, and parameters perturbed randomly from the default so that an entry scaled by a
  parameter that is zero by default, a weight say, stays in the structure); the COO (row,
  col) arrays then follow from the knot indices and the slot offsets. A group whose
  derivative is zero on the probes and not elsewhere (piecewise: a clip, ``maximum``) sets
  ``dense=True``;
- values: one jitted function evaluates every group's block Jacobian at every knot
  (``vmap(jacfwd)`` or the group's own batched Jacobian) and gathers the nonzeros in COO
  order.
The Hessian of the Lagrangian is assembled the same way from per-knot blocks (lower
triangle), for the exact-Hessian option.

Knot structure. `KnotStructure` (``nlp.structure`` where the builder gives one) says which
slots of a knot are the state ``x_k`` and which the controls ``u_k``, and gives the explicit
step ``x_{k+1} = step(x_k, u_k, theta)`` that the equality rows between two knots encode, for
a solver that eliminates the dynamics (Riccati recursions, iLQR).

This module is pure JAX + numpy and knows nothing of robots or of Ipopt.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np

from jtraj.numbers import is_whole

__all__ = ["Layout", "Dep", "ConstraintGroup", "CostGroup", "KnotStructure", "KnotNLP"]

#: Bounds given as an array or as a function of the parameters theta.
Bound = Any  # np.ndarray | Callable[[theta], array]


@dataclasses.dataclass(frozen=True)
class Layout:
    """Named slots of one knot's variables: ``slots = (("q", 37), ("v", 36), ...)``."""

    slots: tuple[tuple[str, int], ...]

    def __post_init__(self):
        names = [name for name, _ in self.slots]
        for name in names:
            if names.count(name) > 1:
                raise ValueError(f"layout {names}: slot {name!r} appears twice")
        for name, size in self.slots:
            if not is_whole(size) or size < 0:
                raise ValueError(f"layout {names}: slot {name!r} has size {size!r}; expected a whole number >= 0")

    @property
    def nz(self) -> int:
        return sum(size for _, size in self.slots)

    def offset(self, name: str) -> int:
        off = 0
        for slot, size in self.slots:
            if slot == name:
                return off
            off += size
        raise KeyError(f"no slot {name!r} in layout {[s for s, _ in self.slots]}")

    def size(self, name: str) -> int:
        sizes = dict(self.slots)
        if name not in sizes:
            raise KeyError(f"no slot {name!r} in layout {list(sizes)}")
        return sizes[name]

    def slice(self, name: str) -> slice:
        off = self.offset(name)
        return slice(off, off + self.size(name))

    def columns(self, names: Sequence[str]) -> np.ndarray:
        """Columns of z_k holding the slots ``names``, concatenated in that order."""
        return np.concatenate([np.arange(self.offset(n), self.offset(n) + self.size(n)) for n in names]) if names else np.zeros(0, int)

    def split(self, z: jax.Array) -> dict[str, jax.Array]:
        """Slots of one knot (or of a stack of knots along the leading axes): z (…, nz)."""
        # a flat x (n,) was taken for one knot and gave knot 0's values, and a short z
        # reads clamped (JAX) or short (numpy) slots; shapes are static under jit
        _check_last_axis(z, self.nz, "z", "nz")
        return {name: z[..., self.slice(name)] for name, _ in self.slots}

    def join(self, parts: dict[str, Any], batch: tuple[int, ...] = ()) -> np.ndarray:
        """Numpy array (…, nz) from slot values (missing slots are zero)."""
        out = np.zeros(batch + (self.nz,))
        for name, value in parts.items():
            out[..., self.slice(name)] = value
        return out


def _check_last_axis(a: Any, size: int, name: str, what: str) -> None:
    """Raise ValueError unless ``a`` has shape (…, size): an array of another size is not an
    error in an index (JAX clamps it) nor in ``.at[].set`` (a size-1 one broadcasts)."""
    shape = np.shape(a)
    if not shape or shape[-1] != size:
        raise ValueError(f"{name} has shape {shape}; expected (..., {what}) with {what} = {size}")


@dataclasses.dataclass(frozen=True)
class Dep:
    """A dependency of a group: slot ``slot`` of knot ``k + offset`` (offset 0 or 1)."""

    slot: str
    offset: int = 0


@dataclasses.dataclass(eq=False)
class ConstraintGroup:
    """Rows ``lower <= fn(theta, data_k, *deps_k) <= upper`` at each knot k of ``knots``.

    Attributes:
        name: for reports.
        deps: the slots the group reads, in the order ``fn`` takes them.
        fn: ``fn(theta, data, *deps) -> (n_rows,)`` for one knot; ``theta`` the NLP's
            parameters (shared by all knots), ``data`` this knot's slice of ``data`` (any
            pytree with a leading knot axis, or None).
        knots: (K,) knot indices where the group applies.
        lower, upper: (K, n_rows) bounds (equal for equalities), or callables
            ``theta -> array`` broadcastable to (K, n_rows).
        active: (K, n_rows) rows that exist (False rows are dropped from the NLP).
        data: per-knot data pytree with leading axis K.
        batched_jacobian: optional ``(theta, data, *deps) -> (K, n_rows, sum dep sizes)``
            with leading knot axes, replacing ``vmap(jacfwd(fn))``.
        dense: skip probing, keep the full dependency block in the structure of the Jacobian
            and of the Hessian (`KnotNLP.build_hessian`). Needed by a function whose
            derivative can vanish at every probe point (entries of magnitude 0.2 to 1, either
            sign) and not elsewhere: a clip, ``maximum``, ``where`` (``y + max(x - 1.5, 0)``
            lost its x column, and both solvers stopped "solved" at a wrong optimum; the
            Hessian's probes dropped the x entry of ``y + max(x - 1.5, 0) ** 2``).
    """

    name: str
    deps: tuple[Dep, ...]
    fn: Callable[..., jax.Array]
    knots: np.ndarray
    lower: Bound
    upper: Bound
    active: np.ndarray
    data: Any = None
    batched_jacobian: Callable[..., jax.Array] | None = None
    dense: bool = False

    def __post_init__(self):
        self.knots = _knot_indices(self.name, self.knots)
        active = np.asarray(self.active)
        # a 0/1 integer mask indexed rows by number where it was taken for a mask (a wrong
        # Jacobian), and a float one failed deep in the build
        if active.dtype != bool and not (active.dtype.kind in "iu" and np.isin(active, (0, 1)).all()):
            raise ValueError(f"group {self.name}: active has dtype {active.dtype}; expected a boolean (K, rows) mask (or 0/1 integers)")
        self.active = active.astype(bool)

    @property
    def n_rows(self) -> int:
        return self.active.shape[1]

    def row_bounds(self, theta: Any) -> tuple[jax.Array, jax.Array]:
        """(K, n_rows) lower and upper bounds at ``theta``."""
        lo = self.lower(theta) if callable(self.lower) else self.lower
        hi = self.upper(theta) if callable(self.upper) else self.upper
        shape = self.active.shape
        return jnp.broadcast_to(jnp.asarray(lo, float), shape), jnp.broadcast_to(jnp.asarray(hi, float), shape)


@dataclasses.dataclass(eq=False)
class CostGroup:
    """Cost ``sum_k fn(theta, data_k, *deps_k)`` over ``knots`` (scalar per knot).

    ``dense``: keep the full Hessian block of the group's dependencies in the Hessian's
    structure instead of probing it (as `ConstraintGroup.dense`): a cost whose second
    derivative can vanish at every probe point and not elsewhere (``max(x - 1.5, 0) ** 2``)
    lost that entry."""

    name: str
    deps: tuple[Dep, ...]
    fn: Callable[..., jax.Array]
    knots: np.ndarray
    data: Any = None
    dense: bool = False

    def __post_init__(self):
        self.knots = _knot_indices(self.name, self.knots)


def _knot_indices(name: str, knots: Any) -> np.ndarray:
    """A group's ``knots`` as a 1-D integer array (a list was an AttributeError in the build;
    floats would index by truncation)."""
    k = np.asarray(knots)
    if k.size == 0:
        return k.reshape(0).astype(int)
    if k.ndim != 1 or k.dtype.kind not in "iu":
        raise ValueError(f"group {name}: knots has shape {k.shape} and dtype {k.dtype}; expected a 1-D array of knot indices (integers)")
    return k


@dataclasses.dataclass(frozen=True)
class KnotStructure:
    """State and controls of a knot, and the explicit step between knots.

    ``z_k[state_columns]`` is the state ``x_k`` (the slots ``state`` concatenated in that
    order), ``z_k[control_columns]`` the controls ``u_k``; every column of z_k is one or the
    other. ``step(x_k, u_k, theta) -> x_{k+1}`` (one knot, vmap for many) is the dynamics
    that the NLP's equality rows between knots k and k+1 encode: those rows vanish when
    ``x_{k+1} = step(x_k, u_k, theta)``. Not only then: a chart may give one pose several
    coordinates (a quaternion's sign and, where it is free, its norm; SE(3)'s whole turns),
    and the rows vanish at any of them, while ``step`` returns one.
    """

    layout: Layout
    state: tuple[str, ...]
    control: tuple[str, ...]
    step: Callable[[jax.Array, jax.Array, Any], jax.Array]

    def __post_init__(self):
        names = [s for s, _ in self.layout.slots]
        if sorted(self.state + self.control) != sorted(names):
            raise ValueError(f"state {self.state} and control {self.control} must split the slots {names} exactly")

    @property
    def state_columns(self) -> np.ndarray:
        return self.layout.columns(self.state)

    @property
    def control_columns(self) -> np.ndarray:
        return self.layout.columns(self.control)

    @property
    def nx(self) -> int:
        return self.state_columns.size

    @property
    def nu(self) -> int:
        return self.control_columns.size

    def split(self, z: jax.Array) -> tuple[jax.Array, jax.Array]:
        """(x, u) of one knot's (or stacked knots') variables z (…, nz)."""
        _check_last_axis(z, self.layout.nz, "z", "nz")
        return z[..., self.state_columns], z[..., self.control_columns]

    def join(self, x: jax.Array, u: jax.Array) -> jax.Array:
        """z (…, nz) from state x (…, nx) and controls u (…, nu)."""
        _check_last_axis(x, self.nx, "x", "nx")
        _check_last_axis(u, self.nu, "u", "nu")
        z = jnp.zeros(x.shape[:-1] + (self.layout.nz,), jnp.result_type(x, u))
        return z.at[..., self.state_columns].set(x).at[..., self.control_columns].set(u)


def _gather_deps(layout: Layout, Z: jax.Array, knots: np.ndarray, deps: Sequence[Dep]) -> list[jax.Array]:
    return [Z[knots + d.offset, layout.slice(d.slot)] for d in deps]


def _dep_columns(layout: Layout, deps: Sequence[Dep]) -> tuple[np.ndarray, np.ndarray]:
    """For the concatenated dependency vector: (knot offset, column within z_k) of each entry."""
    offs, cols = [], []
    for d in deps:
        start = layout.offset(d.slot)
        size = layout.size(d.slot)
        offs.append(np.full(size, d.offset))
        cols.append(np.arange(start, start + size))
    return np.concatenate(offs), np.concatenate(cols)


def _on_flat(fn: Callable, sizes: Sequence[int]) -> Callable:
    """``fn(theta, data, *deps)`` as a function of the dependencies concatenated into one
    vector, ``(theta, data, flat) -> fn(...)``: the argument a block derivative is taken of."""
    splits = np.cumsum(sizes)[:-1]

    def flat_fn(theta, data, flat):
        return fn(theta, data, *jnp.split(flat, splits))

    return flat_fn


def _knot_blocks(derivative: Callable, fn: Callable, layout: Layout, Z: jax.Array, knots: np.ndarray, deps: Sequence[Dep], theta: Any, data: Any, *batched: jax.Array) -> jax.Array:
    """``derivative(fn, argnums=2)`` (`jax.jacfwd` or `jax.hessian`) at every knot, with
    respect to the knot's concatenated dependency vector: one dense block per knot, leading
    axis K. ``fn(theta, data_k, flat_k, *batched_k)``; theta shared, the rest batched."""
    flat = jnp.concatenate(_gather_deps(layout, Z, knots, deps), axis=-1)
    in_axes = (None, None if data is None else 0, 0) + (0,) * len(batched)
    return jax.vmap(derivative(fn, argnums=2), in_axes=in_axes)(theta, data, flat, *batched)


def _knot_jacobians(fn: Callable, layout: Layout, Z: jax.Array, knots: np.ndarray, deps: Sequence[Dep], theta: Any, data: Any) -> jax.Array:
    """The block Jacobian of ``fn(theta, data, *deps)`` at every knot, (K, rows, sum of dep
    sizes), as `_knot_blocks` with `jax.jacfwd` gives it, one dependency at a time.

    Forward mode pushes one tangent per column through the whole function. Differentiating
    with respect to one dependency, the others held, lets JAX skip (symbolic zero tangents)
    every part of ``fn`` that does not read it: the step rows, whose dependencies each enter a
    few rows, and the stationary-contact rows, a kinematics call at each of two knots. Measured
    on big_jump's groups (2 cores): 30 -> 5 ms and 28 -> 14 ms, the same values."""
    args = _gather_deps(layout, Z, knots, deps)

    def one(theta, data, *ds):
        blocks = []
        for j in range(len(ds)):
            def of_j(dj, j=j):
                return fn(theta, data, *ds[:j], dj, *ds[j + 1 :])

            blocks.append(jax.jacfwd(of_j)(ds[j]))
        return jnp.concatenate(blocks, axis=-1)

    in_axes = (None, None if data is None else 0) + (0,) * len(deps)
    return jax.vmap(one, in_axes=in_axes)(theta, data, *args)


def _check_probes(n_probes: Any) -> None:
    # 0 probes (or fewer) left every probed entry out: an empty Jacobian or Hessian structure
    if not is_whole(n_probes) or n_probes < 1:
        raise ValueError(f"n_probes={n_probes!r}: expected a whole number >= 1 (random points where the sparsity is probed)")


def _probe_point(rng: np.random.Generator, n_knots: int, nz: int) -> np.ndarray:
    """A random (n_knots, nz) point with no entry near 0, where a structural zero shows."""
    return rng.uniform(0.2, 1.0, size=(n_knots, nz)) * rng.choice([-1.0, 1.0], size=(n_knots, nz))


def _knot_entries(pattern: np.ndarray, K: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The entries (i, j) of one knot's block pattern repeated at each of K knots:
    (knot k, i, j) arrays in knot-major order."""
    i_in, j_in = np.nonzero(pattern)
    return np.repeat(np.arange(K), i_in.size), np.tile(i_in, K), np.tile(j_in, K)


def _variable_index(knots: np.ndarray, kk: np.ndarray, j: np.ndarray, dep_columns: tuple[np.ndarray, np.ndarray], nz: int) -> np.ndarray:
    """Index in x of entry j of the dependency vector at knot ``knots[kk]`` (``dep_columns``
    from `_dep_columns`)."""
    knot_off, col_in_knot = dep_columns
    return (knots[kk] + knot_off[j]) * nz + col_in_knot[j]


def _per_knot(fn, theta, data, deps):
    """``fn(theta, data_k, *deps_k)`` at every knot: theta shared, data and deps batched."""
    in_axes = (None, None if data is None else 0) + (0,) * len(deps)
    return jax.vmap(fn, in_axes=in_axes)(theta, data, *deps)


def _probe_thetas(theta: Any, rng: np.random.Generator, n: int) -> list[Any]:
    """``n`` parameter sets near ``theta``: each leaf scaled by U(0.5, 1.5) and shifted by
    U(0.05, 0.15), so that no entry vanishes because a parameter happens to be 0 or 1."""
    leaves, treedef = jax.tree.flatten(theta)
    out = []
    for _ in range(n):
        new = [
            jnp.asarray(np.asarray(leaf) * rng.uniform(0.5, 1.5, np.shape(leaf)) + rng.uniform(0.05, 0.15, np.shape(leaf)))
            for leaf in leaves
        ]
        out.append(jax.tree.unflatten(treedef, new))
    return out


class KnotNLP:
    """An NLP over ``Z`` (n_knots, nz) with costs, constraint groups and parameters theta.

    Builds, once, the row layout (which rows of which group at which knot), the Jacobian
    sparsity, and jitted functions of the flat variable vector and theta (see the module
    docstring); the Hessian's sparsity and ``hessian`` are built by `build_hessian`, on
    demand (a solver with a quasi-Newton Hessian never needs them). ``lower`` and ``upper``
    are the variable bounds (n_knots, nz), as arrays or callables of theta (anything that
    broadcasts to that shape); ``theta`` the default parameters; ``structure`` an optional
    `KnotStructure`. ``n_probes`` (>= 1) random points probe the Jacobian's sparsity.
    """

    #: what `build_hessian` sets: read before it, they name it (an AttributeError either way)
    _HESSIAN_ATTRIBUTES = ("hessian", "hess_rows", "hess_cols", "nnz_hess")

    def __init__(
        self,
        layout: Layout,
        n_knots: int,
        costs: Sequence[CostGroup],
        constraints: Sequence[ConstraintGroup],
        lower: Bound,
        upper: Bound,
        probe_seed: int = 0,
        n_probes: int = 3,
        *,
        theta: Any = None,
        structure: KnotStructure | None = None,
    ):
        _check_probes(n_probes)
        self.layout = layout
        self.n_knots = n_knots
        self.nz = layout.nz
        self.n = n_knots * layout.nz
        self.costs = list(costs)
        self.groups = list(constraints)
        self.theta = theta
        self.structure = structure
        #: what solvers compile for this NLP (`jtraj.solvers.ipm.IPM`'s programs), kept on the
        #: NLP so that it goes with it: a registry keyed by the NLP whose entries refer back to
        #: it would keep every NLP and its compiled programs alive
        self.solver_programs: dict[Any, Any] = {}
        self._lower, self._upper = lower, upper
        every: list[CostGroup | ConstraintGroup] = [*self.costs, *self.groups]
        for g in every:
            for d in g.deps:
                if d.offset not in (0, 1):
                    raise ValueError(f"group {g.name}: dependency offsets must be 0 or 1, got {d.offset}")
            # an index outside the knots is not an error in JAX: a gather clamps it (or wraps
            # a negative one), and the group silently reads other knots
            if g.knots.size and (g.knots.max() + max((d.offset for d in g.deps), default=0) >= n_knots):
                raise ValueError(f"group {g.name}: knots reach past the last knot {n_knots - 1}")
            if g.knots.size and g.knots.min() < 0:
                raise ValueError(f"group {g.name}: knots must be >= 0, got {g.knots.min()}")
            # vmapped over the knots with the deps: another leading axis failed there, in
            # JAX's words, naming no group
            for path, leaf in jax.tree_util.tree_flatten_with_path(g.data)[0]:
                if np.shape(leaf)[:1] != (g.knots.size,):
                    raise ValueError(
                        f"group {g.name}: data{jax.tree_util.keystr(path)} has shape {np.shape(leaf)}; "
                        f"expected a leading knot axis of K = {g.knots.size} (one entry per knot of knots)"
                    )
            if isinstance(g, CostGroup):
                continue
            if np.ndim(g.active) != 2 or np.shape(g.active)[0] != g.knots.size:
                raise ValueError(f"group {g.name}: active has shape {np.shape(g.active)}; expected (K, rows) with K = {g.knots.size} knots")
            for name in ("lower", "upper"):
                b = getattr(g, name)
                if not callable(b) and np.shape(b) != g.active.shape:
                    raise ValueError(f"group {g.name}: {name} has shape {np.shape(b)}; expected the shape of active {g.active.shape} (K, rows)")

        for g in every:
            self._check_shapes(g, theta)
        self._check_variable_bounds(theta)
        self._build_rows()
        self.bounds = jax.jit(self._bounds)
        self.x_lower, self.x_upper, self.g_lower, self.g_upper = (np.asarray(b) for b in self.bounds(theta))
        self._check_bounds()
        self._build_jacobian_structure(probe_seed, n_probes)
        self._hessian_built = False
        self._compile()

    if not TYPE_CHECKING:  # hidden from mypy, which would type every unknown attribute Any

        def __getattr__(self, name: str) -> Any:
            # only called for attributes that are not set
            if name in KnotNLP._HESSIAN_ATTRIBUTES:
                raise AttributeError(f"KnotNLP.{name} is built by build_hessian(): call build_hessian() first")
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def _check_variable_bounds(self, theta: Any) -> None:
        """Refuse variable bounds that do not broadcast to (n_knots, nz): a flat (n,) vector,
        the solver's shape, failed in JAX's broadcasting naming neither bound nor shape."""
        shape = (self.n_knots, self.nz)
        for name, b in (("lower", self._lower), ("upper", self._upper)):
            got = getattr(jax.eval_shape(b, theta), "shape", ()) if callable(b) else np.shape(b)
            try:
                ok = np.broadcast_shapes(got, shape) == shape
            except ValueError:
                ok = False
            if not ok:
                what = f"{name}(theta)" if callable(b) else name
                raise ValueError(f"variable bounds: {what} has shape {got}; expected one that broadcasts to (n_knots, nz) = {shape}")

    def _check_shapes(self, g: CostGroup | ConstraintGroup, theta: Any) -> None:
        """Refuse a group whose functions return the wrong shape or a non-float dtype at one
        knot (`jax.eval_shape`: traced, not run). Before, fewer rows than ``active`` has were
        read past their end (a gather clamps), an integer ``fn`` truncated its values and its
        Jacobian to zero, and more rows failed in numpy's broadcasting, naming no group."""
        if not g.knots.size:
            return
        dep_shapes = [jax.ShapeDtypeStruct((self.layout.size(d.slot),), jnp.zeros(0).dtype) for d in g.deps]
        data = None if g.data is None else jax.tree.map(lambda a: a[0], g.data)
        got = jax.eval_shape(g.fn, theta, data, *dep_shapes)
        rows = () if isinstance(g, CostGroup) else (g.n_rows,)
        ok_shapes = [()] if isinstance(g, CostGroup) else [rows] + ([()] if rows == (1,) else [])
        shape, dtype = getattr(got, "shape", None), getattr(got, "dtype", None)
        if shape not in ok_shapes or dtype is None or not jnp.issubdtype(dtype, jnp.floating):
            what = "a scalar cost per knot" if isinstance(g, CostGroup) else f"{rows} (one value per row of active)"
            raise ValueError(f"group {g.name}: fn returns {got} per knot; expected {what}, of floats")
        if isinstance(g, CostGroup):
            return
        K = g.knots.size
        if g.batched_jacobian is not None:
            batched = [jax.ShapeDtypeStruct((K, *d.shape), d.dtype) for d in dep_shapes]
            jac = jax.eval_shape(g.batched_jacobian, theta, g.data, *batched)
            expected = (K, g.n_rows, sum(d.shape[0] for d in dep_shapes))
            if getattr(jac, "shape", None) != expected:
                raise ValueError(f"group {g.name}: batched_jacobian returns {jac}; expected shape {expected} (knots, rows, dependency columns)")
        for name in ("lower", "upper"):
            b = getattr(g, name)
            if callable(b):
                shape = getattr(jax.eval_shape(b, theta), "shape", ())
                try:
                    if np.broadcast_shapes(shape, g.active.shape) != g.active.shape:
                        raise ValueError
                except ValueError:
                    raise ValueError(f"group {g.name}: {name}(theta) has shape {shape}; expected one that broadcasts to the shape of active {g.active.shape} (K, rows)") from None

    # ------------------------------------------------------------------ rows and bounds
    def _build_rows(self) -> None:
        self.row_index = []  # per group: flat indices (into the group's (K, rows) array) of active rows
        offsets = []
        m = 0
        names = []
        for g in self.groups:
            flat = np.flatnonzero(g.active.reshape(-1))
            self.row_index.append(flat)
            offsets.append(m)
            m += flat.size
            names.extend([g.name] * flat.size)
        self.m = m
        self.group_row_offset = offsets
        self.row_group = np.array(names)

    def locate(self, kind: str, i: int) -> str:
        """Where entry ``i`` of the flat variables (``kind`` "x") or constraint rows ("g") sits:
        ``"knot K, slot 'q' entry E"`` or ``"group NAME at knot K, row R"``. Solvers name it
        beside a bound they refuse (`jtraj.solvers.base.BoundNLP`)."""
        size = {"x": self.n, "g": self.m}.get(kind)
        if size is None:
            raise ValueError(f"kind={kind!r}: expected 'x' (variables) or 'g' (constraint rows)")
        if not 0 <= int(i) < size:
            raise IndexError(f"{kind}[{i}]: the NLP has {size} {'variables' if kind == 'x' else 'constraint rows'}")
        if kind == "x":
            knot, column = divmod(int(i), self.nz)
            slot = next(name for name, _ in self.layout.slots if self.layout.slice(name).start <= column < self.layout.slice(name).stop)
            return f"knot {knot}, slot {slot!r} entry {column - self.layout.offset(slot)}"
        gi = int(np.searchsorted(self.group_row_offset, i, side="right")) - 1
        g = self.groups[gi]
        knot, row = divmod(int(self.row_index[gi][int(i) - self.group_row_offset[gi]]), g.n_rows)
        return f"group {g.name} at knot {g.knots[knot]}, row {row}"

    def _check_bounds(self) -> None:
        """Raise ValueError where a lower bound is above its upper bound (or either is NaN, or
        a lower bound is +inf or an upper one -inf, which nothing meets) at the default theta, naming the variable or the group's row (`locate`), as the task is
        built: a solver reports such a problem only as invalid, at the theta it solves at."""
        bad = np.flatnonzero(~(self.x_lower <= self.x_upper) | (self.x_lower == np.inf) | (self.x_upper == -np.inf))
        if bad.size:
            i = int(bad[0])
            raise ValueError(
                f"variable bounds: {bad.size} with lower > upper (or NaN, or a lower bound of +inf or an upper one of -inf), the first at {self.locate('x', i)}: "
                f"lower {self.x_lower[i]:g}, upper {self.x_upper[i]:g}"
            )
        bad = np.flatnonzero(~(self.g_lower <= self.g_upper) | (self.g_lower == np.inf) | (self.g_upper == -np.inf))
        if bad.size:
            i = int(bad[0])
            raise ValueError(
                f"constraint bounds: {bad.size} rows with lower > upper (or NaN, or a lower bound of +inf or an upper one of -inf), the first in {self.locate('g', i)}: "
                f"lower {self.g_lower[i]:g}, upper {self.g_upper[i]:g}"
            )

    def _bounds(self, theta: Any) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
        def variable(b):
            b = b(theta) if callable(b) else b
            return jnp.broadcast_to(jnp.asarray(b, float), (self.n_knots, self.nz)).reshape(self.n)

        g_lower, g_upper = [], []
        for g, idx in zip(self.groups, self.row_index):
            lo, hi = g.row_bounds(theta)
            g_lower.append(lo.reshape(-1)[idx])
            g_upper.append(hi.reshape(-1)[idx])
        empty = jnp.zeros(0)
        return (
            variable(self._lower),
            variable(self._upper),
            jnp.concatenate(g_lower) if g_lower else empty,
            jnp.concatenate(g_upper) if g_upper else empty,
        )

    # ------------------------------------------------------------------ jacobian structure
    def _group_block_jacobian(self, g: ConstraintGroup):
        """(Z, theta) -> (K, rows, ndep) block Jacobians of group g."""
        layout = self.layout

        def blocks(Z, theta):
            if g.batched_jacobian is not None:
                return g.batched_jacobian(theta, g.data, *_gather_deps(layout, Z, g.knots, g.deps))
            return _knot_jacobians(g.fn, layout, Z, g.knots, g.deps, theta, g.data)

        return blocks

    def _build_jacobian_structure(self, seed: int, n_probes: int) -> None:
        rng = np.random.default_rng(seed)
        thetas = _probe_thetas(self.theta, np.random.default_rng(seed + 1000), n_probes)
        block_fns = [self._group_block_jacobian(g) for g in self.groups]
        # One jitted function evaluates every group's blocks; it serves the probes here
        # and every later Jacobian evaluation (one compile).
        self._all_blocks = jax.jit(lambda x, theta: [fn(x.reshape(self.n_knots, self.nz), theta) for fn in block_fns])
        patterns = [np.full((g.n_rows, _dep_columns(self.layout, g.deps)[1].size), bool(g.dense)) for g in self.groups]
        if any(not g.dense for g in self.groups):
            for theta in thetas:
                Z = _probe_point(rng, self.n_knots, self.nz)
                for g, pattern, B in zip(self.groups, patterns, self._all_blocks(jnp.asarray(Z.reshape(-1)), theta)):
                    if not g.dense:
                        pattern |= np.any(np.asarray(B) != 0.0, axis=0)
        rows, cols, self._jac_gather = [], [], []
        for gi, (g, pattern) in enumerate(zip(self.groups, patterns)):
            K = g.knots.size
            # position in the NLP of each active (knot, row) of this group
            nlp_row = -np.ones((K, g.n_rows), int)
            nlp_row.reshape(-1)[self.row_index[gi]] = self.group_row_offset[gi] + np.arange(self.row_index[gi].size)
            kk, rr, cc = _knot_entries(pattern, K)
            keep = g.active[kk, rr]
            kk, rr, cc = kk[keep], rr[keep], cc[keep]
            rows.append(nlp_row[kk, rr])
            cols.append(_variable_index(g.knots, kk, cc, _dep_columns(self.layout, g.deps), self.nz))
            # gather index into the flattened (K, rows, ndep) block array
            self._jac_gather.append(np.ravel_multi_index((kk, rr, cc), (K, *pattern.shape)))
        self.jac_rows = np.concatenate(rows).astype(np.int64) if rows else np.zeros(0, np.int64)
        self.jac_cols = np.concatenate(cols).astype(np.int64) if cols else np.zeros(0, np.int64)
        self.nnz_jac = self.jac_rows.size

    # ------------------------------------------------------------------ functions
    def _compile(self) -> None:
        layout, n_knots, nz = self.layout, self.n_knots, self.nz

        def unflatten(x):
            return x.reshape(n_knots, nz)

        def objective(x, theta):
            Z = unflatten(x)
            total = jnp.zeros((), x.dtype)
            for c in self.costs:
                deps = _gather_deps(layout, Z, c.knots, c.deps)
                total = total + jnp.sum(_per_knot(c.fn, theta, c.data, deps))
            return total

        def constraints(x, theta):
            Z = unflatten(x)
            out = []
            for gi, g in enumerate(self.groups):
                deps = _gather_deps(layout, Z, g.knots, g.deps)
                vals = _per_knot(g.fn, theta, g.data, deps)
                out.append(vals.reshape(-1)[self.row_index[gi]])
            return jnp.concatenate(out) if out else jnp.zeros(0, x.dtype)

        gathers = self._jac_gather

        def gather(blocks):
            vals = [B.reshape(-1)[idx] for B, idx in zip(blocks, gathers)]
            return jnp.concatenate(vals) if vals else jnp.zeros(0)

        gather_jit = jax.jit(gather)
        all_blocks = self._all_blocks

        def jacobian(x, theta):
            """COO values (nnz_jac,) of the constraint Jacobian at (x, theta)."""
            return gather_jit(all_blocks(x, theta))

        self._objective_py = objective
        self._constraints_py = constraints
        self.objective = jax.jit(objective)
        self.gradient = jax.jit(jax.grad(objective))
        self.constraints = jax.jit(constraints)
        self.jacobian = jacobian

    def _theta_or_default(self, theta: Any) -> Any:
        return self.theta if theta is None else theta

    def dense_jacobian(self, x: jax.Array, theta: Any = None) -> np.ndarray:
        """Dense Jacobian assembled from the sparse values (for tests and debugging)."""
        J = np.zeros((self.m, self.n))
        np.add.at(J, (self.jac_rows, self.jac_cols), np.asarray(self.jacobian(x, self._theta_or_default(theta))))
        return J

    # ------------------------------------------------------------------ hessian
    def build_hessian(self, seed: int = 1, n_probes: int = 2) -> None:
        """Structure and jitted values of the Hessian of the Lagrangian (lower triangle):
        ``hessian(x, lam, obj_factor, theta)``.

        Per group and knot, the Hessian of ``lambda_k . g_k`` (and of each cost term) with
        respect to the group's dependency vector is a dense block; entries are kept where
        they are nonzero at random probes (all of them for a ``dense`` group or cost), and
        mapped to the global (row >= col) COO list, summing where blocks of neighbouring
        knots or groups overlap.
        """
        _check_probes(n_probes)
        if self._hessian_built:
            return
        layout, n_knots, nz = self.layout, self.n_knots, self.nz
        rng = np.random.default_rng(seed)
        thetas = _probe_thetas(self.theta, np.random.default_rng(seed + 1000), n_probes)

        def weighted(fn, deps):
            """``(theta, data_k, flat_k, w_k) -> w_k . fn(...)``, whose Hessian is the block."""
            flat_fn = _on_flat(fn, [layout.size(d.slot) for d in deps])

            def one(theta, data, flat, w):
                return jnp.sum(w * flat_fn(theta, data, flat))

            return one

        def lam_to_groups(lam):
            """Multipliers of the NLP rows -> per group (K, rows) arrays (0 on dropped rows)."""
            out = []
            for gi, g in enumerate(self.groups):
                full = jnp.zeros(g.active.size, lam.dtype)
                idx = self.group_row_offset[gi] + np.arange(self.row_index[gi].size)
                out.append(full.at[self.row_index[gi]].set(lam[idx]).reshape(g.active.shape))
            return out

        terms = [(weighted(c.fn, c.deps), c.deps, c.knots, c.data) for c in self.costs]
        terms += [(weighted(g.fn, g.deps), g.deps, g.knots, g.data) for g in self.groups]
        dense = [bool(c.dense) for c in self.costs] + [bool(g.dense) for g in self.groups]

        def all_blocks(x, lam, obj_factor, theta):
            """(K, ndep, ndep) Hessians of weights_k . fn(theta, data_k, deps_k) per term."""
            Z = x.reshape(n_knots, nz)
            weights = [jnp.full((c.knots.size,), obj_factor) for c in self.costs] + lam_to_groups(lam)
            return [_knot_blocks(jax.hessian, fn, layout, Z, knots, deps, theta, data, w) for (fn, deps, knots, data), w in zip(terms, weights)]

        all_blocks_jit = jax.jit(all_blocks)
        # a dense term keeps its whole block (not probed), as in the Jacobian's structure
        patterns = [np.full((_dep_columns(layout, t[1])[1].size,) * 2, d) for t, d in zip(terms, dense)]
        if not all(dense):
            for theta in thetas:
                Z = _probe_point(rng, n_knots, nz)
                lam = rng.normal(size=self.m)
                for pattern, B in zip(patterns, all_blocks_jit(jnp.asarray(Z.reshape(-1)), jnp.asarray(lam), 1.0, theta)):
                    pattern |= np.any(np.asarray(B) != 0.0, axis=0)

        rows, cols, gathers = [], [], []
        for (_fn, deps, knots, _data), pattern in zip(terms, patterns):
            columns = _dep_columns(layout, deps)
            pattern = pattern | pattern.T
            K = knots.size
            kk, aa, bb = _knot_entries(pattern, K)
            ga = _variable_index(knots, kk, aa, columns, nz)
            gb = _variable_index(knots, kk, bb, columns, nz)
            keep = ga >= gb  # lower triangle of the global matrix
            rows.append(ga[keep])
            cols.append(gb[keep])
            # gather index into the flattened (K, ndep, ndep) block array
            gathers.append(np.ravel_multi_index((kk[keep], aa[keep], bb[keep]), (K, *pattern.shape)))
        # no cost and no constraint: an empty Hessian (np.concatenate refuses an empty list)
        rows = np.concatenate(rows) if rows else np.zeros(0, np.int64)
        cols = np.concatenate(cols) if cols else np.zeros(0, np.int64)
        key = rows * self.n + cols
        unique, inverse = np.unique(key, return_inverse=True)
        self.hess_rows = (unique // self.n).astype(np.int64)
        self.hess_cols = (unique % self.n).astype(np.int64)
        self.nnz_hess = unique.size
        inverse_parts = np.split(inverse, np.cumsum([g.size for g in gathers])[:-1])
        nnz = self.nnz_hess

        @jax.jit
        def scatter(blocks):
            out = jnp.zeros(nnz)
            for B, gather, inv in zip(blocks, gathers, inverse_parts):
                out = out.at[inv].add(B.reshape(-1)[gather])
            return out

        def hessian(x, lam, obj_factor, theta):
            """Lower-triangle COO values (nnz_hess,) of obj_factor * Hess f + sum lam_i Hess g_i."""
            return scatter(all_blocks_jit(x, lam, obj_factor, theta))

        self.hessian = hessian
        self._hessian_built = True

    # ------------------------------------------------------------------ helpers
    def row_groups_summary(self) -> dict[str, int]:
        names, counts = np.unique(self.row_group, return_counts=True)
        return dict(zip(names.tolist(), counts.tolist()))

    def _violations(self, x: np.ndarray, theta: Any) -> tuple[np.ndarray, np.ndarray]:
        theta = self._theta_or_default(theta)
        x_lower, x_upper, g_lower, g_upper = (np.asarray(b) for b in self.bounds(theta))
        g = np.asarray(self.constraints(jnp.asarray(x), theta))
        viol = np.maximum(np.maximum(g_lower - g, g - g_upper), 0.0)
        bviol = np.maximum(np.maximum(x_lower - x, x - x_upper), 0.0)
        return viol, bviol

    def violation_by_group(self, x: np.ndarray, theta: Any = None) -> dict[str, float]:
        """Max violation of each constraint group's rows, and of the variable bounds, at x
        (and theta, default `theta`)."""
        viol, bviol = self._violations(x, theta)
        out = {name: float(viol[self.row_group == name].max(initial=0.0)) for name in dict.fromkeys(self.row_group.tolist())}
        out["bounds"] = float(bviol.max(initial=0.0))
        return out

    def violation(self, x: np.ndarray, theta: Any = None) -> float:
        """Max violation of the constraint rows and variable bounds at x (and theta)."""
        viol, bviol = self._violations(x, theta)
        return float(np.max([viol.max(initial=0.0), bviol.max(initial=0.0)]))  # max(0.0, nan) is 0.0
