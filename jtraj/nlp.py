"""Sparse nonlinear programs with knot structure, assembled from per-knot JAX functions.

A trajectory NLP has one block of variables per knot, ``z_k`` (the same layout, a tuple of
named slots, at every knot) stacked as ``Z`` of shape (n_knots, nz); the Ipopt vector is
``Z.ravel()``. Costs and constraints come in groups. A group is written for ONE knot: it reads
some slots of knot k and possibly of knot k+1 (its dependencies) and returns a fixed number of
rows; it is vmapped over the knots it applies to. Per knot, a boolean mask selects which rows
are real constraints (a contact that is not active drops its rows); masks, knots and bounds
are numpy data fixed when the NLP is built.

The sparse constraint Jacobian:
- structure: once, from the dependencies of each group (a dense block per knot, rows x
  dependency columns) thinned to the entries that are nonzero at random probe points; the
  COO (row, col) arrays then follow from the knot indices and the slot offsets;
- values: one jitted function evaluates every group's block Jacobian at every knot
  (``vmap(jacfwd)`` or the group's own batched Jacobian) and gathers the nonzeros in COO
  order.
The Hessian of the Lagrangian is assembled the same way from per-knot blocks (lower
triangle), for the exact-Hessian option.

This module is pure JAX + numpy and knows nothing of robots or of Ipopt.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["Layout", "Dep", "ConstraintGroup", "CostGroup", "KnotNLP"]


@dataclasses.dataclass(frozen=True)
class Layout:
    """Named slots of one knot's variables: ``slots = (("q", 37), ("v", 36), ...)``."""

    slots: tuple[tuple[str, int], ...]

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
        return dict(self.slots)[name]

    def slice(self, name: str) -> slice:
        off = self.offset(name)
        return slice(off, off + self.size(name))

    def split(self, z: jax.Array) -> dict[str, jax.Array]:
        """Slots of one knot (or of a stack of knots along the leading axes)."""
        return {name: z[..., self.slice(name)] for name, _ in self.slots}

    def join(self, parts: dict[str, Any], batch: tuple[int, ...] = ()) -> np.ndarray:
        """Numpy array (…, nz) from slot values (missing slots are zero)."""
        out = np.zeros(batch + (self.nz,))
        for name, value in parts.items():
            out[..., self.slice(name)] = value
        return out


@dataclasses.dataclass(frozen=True)
class Dep:
    """A dependency of a group: slot ``slot`` of knot ``k + offset`` (offset 0 or 1)."""

    slot: str
    offset: int = 0


@dataclasses.dataclass(eq=False)
class ConstraintGroup:
    """Rows ``lower <= fn(data_k, *deps_k) <= upper`` at each knot k of ``knots``.

    Attributes:
        name: for reports.
        deps: the slots the group reads, in the order ``fn`` takes them.
        fn: ``fn(data, *deps) -> (n_rows,)`` for one knot; ``data`` is this knot's slice of
            ``data`` (any pytree with a leading knot axis, or None).
        knots: (K,) knot indices where the group applies.
        lower, upper: (K, n_rows) bounds (equal for equalities).
        active: (K, n_rows) rows that exist (False rows are dropped from the NLP).
        data: per-knot data pytree with leading axis K (traced: changing values does not
            recompile).
        batched_jacobian: optional ``(data, *deps) -> (K, n_rows, sum dep sizes)`` with
            leading knot axes, replacing ``vmap(jacfwd(fn))``.
        dense: skip probing, keep the full dependency block in the structure.
    """

    name: str
    deps: tuple[Dep, ...]
    fn: Callable[..., jax.Array]
    knots: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    active: np.ndarray
    data: Any = None
    batched_jacobian: Callable[..., jax.Array] | None = None
    dense: bool = False

    @property
    def n_rows(self) -> int:
        return self.lower.shape[1]


@dataclasses.dataclass(eq=False)
class CostGroup:
    """Cost ``sum_k fn(data_k, *deps_k)`` over ``knots`` (scalar per knot)."""

    name: str
    deps: tuple[Dep, ...]
    fn: Callable[..., jax.Array]
    knots: np.ndarray
    data: Any = None


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


class KnotNLP:
    """An NLP over ``Z`` (n_knots, nz) with costs and constraint groups.

    Builds, once, the row layout (which rows of which group at which knot), the Jacobian
    and Hessian sparsity, and jitted functions ``objective``, ``gradient``, ``constraints``,
    ``jacobian`` (COO values) and ``hessian`` (lower-triangle COO values) of the flat
    variable vector. Functions close over the group data passed at construction.
    """

    def __init__(
        self,
        layout: Layout,
        n_knots: int,
        costs: Sequence[CostGroup],
        constraints: Sequence[ConstraintGroup],
        lower: np.ndarray,
        upper: np.ndarray,
        probe_seed: int = 0,
        n_probes: int = 3,
    ):
        self.layout = layout
        self.n_knots = n_knots
        self.nz = layout.nz
        self.n = n_knots * layout.nz
        self.costs = list(costs)
        self.groups = list(constraints)
        self.x_lower = np.asarray(lower, float).reshape(self.n)
        self.x_upper = np.asarray(upper, float).reshape(self.n)
        for g in self.groups:
            for d in g.deps:
                if d.offset not in (0, 1):
                    raise ValueError(f"group {g.name}: dependency offsets must be 0 or 1, got {d.offset}")
            if g.knots.size and (g.knots.max() + max(d.offset for d in g.deps) >= n_knots):
                raise ValueError(f"group {g.name}: knots reach past the last knot {n_knots - 1}")
            if g.lower.shape != g.active.shape or g.upper.shape != g.active.shape:
                raise ValueError(f"group {g.name}: lower, upper and active must share one shape (K, rows)")

        self._build_rows()
        self._build_jacobian_structure(probe_seed, n_probes)
        self._hessian_built = False
        self._compile()

    # ------------------------------------------------------------------ rows and bounds
    def _build_rows(self) -> None:
        self.row_index = []  # per group: flat indices (into the group's (K, rows) array) of active rows
        offsets = []
        m = 0
        g_lower, g_upper, names = [], [], []
        for g in self.groups:
            flat = np.flatnonzero(g.active.reshape(-1))
            self.row_index.append(flat)
            offsets.append(m)
            m += flat.size
            g_lower.append(g.lower.reshape(-1)[flat])
            g_upper.append(g.upper.reshape(-1)[flat])
            names.extend([g.name] * flat.size)
        self.m = m
        self.group_row_offset = offsets
        self.g_lower = np.concatenate(g_lower) if g_lower else np.zeros(0)
        self.g_upper = np.concatenate(g_upper) if g_upper else np.zeros(0)
        self.row_group = np.array(names)

    # ------------------------------------------------------------------ jacobian structure
    def _group_block_jacobian(self, g: ConstraintGroup):
        """(Z) -> (K, rows, ndep) block Jacobians of group g."""
        layout = self.layout

        def blocks(Z):
            deps = _gather_deps(layout, Z, g.knots, g.deps)
            if g.batched_jacobian is not None:
                return g.batched_jacobian(g.data, *deps)
            sizes = [d.shape[-1] for d in deps]

            def one(data, flat):
                parts = jnp.split(flat, np.cumsum(sizes)[:-1])
                return g.fn(data, *parts)

            flat = jnp.concatenate(deps, axis=-1)
            in_axes = (None if g.data is None else 0, 0)
            return jax.vmap(jax.jacfwd(one, argnums=1), in_axes=in_axes)(g.data, flat)

        return blocks

    def _build_jacobian_structure(self, seed: int, n_probes: int) -> None:
        rng = np.random.default_rng(seed)
        block_fns = [self._group_block_jacobian(g) for g in self.groups]
        # One jitted function evaluates every group's blocks; it serves the probes here
        # and every later Jacobian evaluation (one compile).
        self._all_blocks = jax.jit(lambda x: [fn(x.reshape(self.n_knots, self.nz)) for fn in block_fns])
        patterns = [
            np.ones((g.n_rows, _dep_columns(self.layout, g.deps)[1].size), bool)
            if g.dense
            else np.zeros((g.n_rows, _dep_columns(self.layout, g.deps)[1].size), bool)
            for g in self.groups
        ]
        if any(not g.dense for g in self.groups):
            for _ in range(n_probes):
                Z = rng.uniform(0.2, 1.0, size=(self.n_knots, self.nz)) * rng.choice([-1.0, 1.0], size=(self.n_knots, self.nz))
                for g, pattern, B in zip(self.groups, patterns, self._all_blocks(jnp.asarray(Z.reshape(-1)))):
                    if not g.dense:
                        pattern |= np.any(np.asarray(B) != 0.0, axis=0)
        rows, cols, self._jac_gather = [], [], []
        for gi, (g, pattern) in enumerate(zip(self.groups, patterns)):
            knot_off, col_in_knot = _dep_columns(self.layout, g.deps)
            ndep = col_in_knot.size
            r_in, c_in = np.nonzero(pattern)  # structural entries of one knot's block
            K = g.knots.size
            # position in the NLP of each active (knot, row) of this group
            nlp_row = -np.ones((K, g.n_rows), int)
            nlp_row.reshape(-1)[self.row_index[gi]] = self.group_row_offset[gi] + np.arange(self.row_index[gi].size)
            kk = np.repeat(np.arange(K), r_in.size)
            rr = np.tile(r_in, K)
            cc = np.tile(c_in, K)
            keep = g.active[kk, rr]
            kk, rr, cc = kk[keep], rr[keep], cc[keep]
            rows.append(nlp_row[kk, rr])
            cols.append((g.knots[kk] + knot_off[cc]) * self.nz + col_in_knot[cc])
            # gather index into the flattened (K, rows, ndep) block array
            self._jac_gather.append((kk * g.n_rows + rr) * ndep + cc)
        self.jac_rows = np.concatenate(rows).astype(np.int64) if rows else np.zeros(0, np.int64)
        self.jac_cols = np.concatenate(cols).astype(np.int64) if cols else np.zeros(0, np.int64)
        self.nnz_jac = self.jac_rows.size

    # ------------------------------------------------------------------ functions
    def _compile(self) -> None:
        layout, n_knots, nz = self.layout, self.n_knots, self.nz

        def unflatten(x):
            return x.reshape(n_knots, nz)

        def objective(x):
            Z = unflatten(x)
            total = jnp.zeros((), x.dtype)
            for c in self.costs:
                deps = _gather_deps(layout, Z, c.knots, c.deps)
                in_axes = (None if c.data is None else 0,) + (0,) * len(deps)
                total = total + jnp.sum(jax.vmap(c.fn, in_axes=in_axes)(c.data, *deps))
            return total

        def constraints(x):
            Z = unflatten(x)
            out = []
            for gi, g in enumerate(self.groups):
                deps = _gather_deps(layout, Z, g.knots, g.deps)
                in_axes = (None if g.data is None else 0,) + (0,) * len(deps)
                vals = jax.vmap(g.fn, in_axes=in_axes)(g.data, *deps)
                out.append(vals.reshape(-1)[self.row_index[gi]])
            return jnp.concatenate(out) if out else jnp.zeros(0, x.dtype)

        gathers = self._jac_gather

        def gather(blocks):
            vals = [B.reshape(-1)[idx] for B, idx in zip(blocks, gathers)]
            return jnp.concatenate(vals) if vals else jnp.zeros(0)

        gather_jit = jax.jit(gather)
        all_blocks = self._all_blocks

        def jacobian(x):
            return gather_jit(all_blocks(x))

        self._objective_py = objective
        self._constraints_py = constraints
        self.objective = jax.jit(objective)
        self.gradient = jax.jit(jax.grad(objective))
        self.constraints = jax.jit(constraints)
        self.jacobian = jacobian

    def dense_jacobian(self, x: jax.Array) -> np.ndarray:
        """Dense Jacobian assembled from the sparse values (for tests and debugging)."""
        J = np.zeros((self.m, self.n))
        np.add.at(J, (self.jac_rows, self.jac_cols), np.asarray(self.jacobian(x)))
        return J

    # ------------------------------------------------------------------ hessian
    def build_hessian(self, seed: int = 1, n_probes: int = 2) -> None:
        """Structure and jitted values of the Hessian of the Lagrangian (lower triangle).

        Per group and knot, the Hessian of ``lambda_k . g_k`` (and of each cost term) with
        respect to the group's dependency vector is a dense block; entries are kept where
        they are nonzero at random probes, and mapped to the global (row >= col) COO list,
        summing where blocks of neighbouring knots or groups overlap.
        """
        if self._hessian_built:
            return
        layout, n_knots, nz = self.layout, self.n_knots, self.nz
        rng = np.random.default_rng(seed)

        def term_blocks(fn, deps, knots, data, weights):
            """(K, ndep, ndep) Hessians of weights_k . fn(data_k, deps_k)."""
            sizes = [layout.size(d.slot) for d in deps]

            def one(d, flat, w):
                parts = jnp.split(flat, np.cumsum(sizes)[:-1])
                return jnp.sum(w * fn(d, *parts))

            def blocks(Z):
                flat = jnp.concatenate(_gather_deps(layout, Z, knots, deps), axis=-1)
                in_axes = (None if data is None else 0, 0, 0)
                return jax.vmap(jax.hessian(one, argnums=1), in_axes=in_axes)(data, flat, weights)

            return blocks

        def lam_to_groups(lam):
            """Multipliers of the NLP rows -> per group (K, rows) arrays (0 on dropped rows)."""
            out = []
            for gi, g in enumerate(self.groups):
                full = jnp.zeros(g.active.size, lam.dtype)
                idx = self.group_row_offset[gi] + np.arange(self.row_index[gi].size)
                out.append(full.at[self.row_index[gi]].set(lam[idx]).reshape(g.active.shape))
            return out

        terms = [(c.fn, c.deps, c.knots, c.data) for c in self.costs]
        terms += [(g.fn, g.deps, g.knots, g.data) for g in self.groups]

        def all_blocks(x, lam, obj_factor):
            Z = x.reshape(n_knots, nz)
            weights = [jnp.full((c.knots.size,), obj_factor) for c in self.costs] + lam_to_groups(lam)
            return [term_blocks(fn, deps, knots, data, w)(Z) for (fn, deps, knots, data), w in zip(terms, weights)]

        all_blocks_jit = jax.jit(all_blocks)
        patterns = [np.zeros((_dep_columns(layout, t[1])[1].size,) * 2, bool) for t in terms]
        for _ in range(n_probes):
            Z = rng.uniform(0.2, 1.0, size=(n_knots, nz)) * rng.choice([-1.0, 1.0], size=(n_knots, nz))
            lam = rng.normal(size=self.m)
            for pattern, B in zip(patterns, all_blocks_jit(jnp.asarray(Z.reshape(-1)), jnp.asarray(lam), 1.0)):
                pattern |= np.any(np.asarray(B) != 0.0, axis=0)

        rows, cols, gathers = [], [], []
        for (fn, deps, knots, data), pattern in zip(terms, patterns):
            knot_off, col_in_knot = _dep_columns(layout, deps)
            ndep = col_in_knot.size
            pattern = pattern | pattern.T
            a_in, b_in = np.nonzero(pattern)
            K = knots.size
            kk = np.repeat(np.arange(K), a_in.size)
            aa = np.tile(a_in, K)
            bb = np.tile(b_in, K)
            ga = (knots[kk] + knot_off[aa]) * nz + col_in_knot[aa]
            gb = (knots[kk] + knot_off[bb]) * nz + col_in_knot[bb]
            keep = ga >= gb  # lower triangle of the global matrix
            rows.append(ga[keep])
            cols.append(gb[keep])
            gathers.append((kk[keep] * ndep + aa[keep]) * ndep + bb[keep])
        rows = np.concatenate(rows)
        cols = np.concatenate(cols)
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

        def hessian(x, lam, obj_factor):
            return scatter(all_blocks_jit(x, lam, obj_factor))

        self.hessian = hessian
        self._hessian_built = True

    # ------------------------------------------------------------------ helpers
    def row_groups_summary(self) -> dict[str, int]:
        names, counts = np.unique(self.row_group, return_counts=True)
        return dict(zip(names.tolist(), counts.tolist()))

    def violation_by_group(self, x: np.ndarray) -> dict[str, float]:
        """Max violation of each constraint group's rows, and of the variable bounds, at x."""
        g = np.asarray(self.constraints(jnp.asarray(x)))
        viol = np.maximum(np.maximum(self.g_lower - g, g - self.g_upper), 0.0)
        out = {name: float(viol[self.row_group == name].max(initial=0.0)) for name in dict.fromkeys(self.row_group.tolist())}
        out["bounds"] = float(np.maximum(np.maximum(self.x_lower - x, x - self.x_upper), 0.0).max(initial=0.0))
        return out

    def violation(self, x: np.ndarray) -> float:
        """Max violation of the constraint rows and variable bounds at x."""
        g = np.asarray(self.constraints(jnp.asarray(x)))
        viol = np.maximum(np.maximum(self.g_lower - g, g - self.g_upper), 0.0)
        bviol = np.maximum(np.maximum(self.x_lower - x, x - self.x_upper), 0.0)
        return float(max(viol.max(initial=0.0), bviol.max(initial=0.0)))
