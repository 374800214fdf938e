"""The primal-dual Newton (KKT) system of a knot-structured NLP, solved by a block-tridiagonal
Cholesky factorization over the knots.

The system, for K knots of n variables and m constraint rows per knot (rows of knot k read
knots k and k+1 only)::

    [ H + diag(sigma) + delta_w I    J^T  ] [dx]   [r_x]
    [ J                             -D0   ] [dy] = [r_c]

- ``H``: the Hessian of the Lagrangian as a sum of *element* blocks ``H_k`` (2n x 2n) over the
  pair (z_k, z_{k+1}) (the element of the last knot only uses its first n x n block);
- ``sigma`` (K, n) >= 0: the primal-dual barrier terms of the variable bounds;
- ``J``: the constraint Jacobian, rows of knot k = ``[A_k, B_k]`` (m x n each) on (z_k, z_{k+1});
- ``D0`` (K, m) >= 0: 0 on equality rows, ``1 / sigma_s`` on inequality rows whose slack was
  eliminated (Ipopt's reduced system; with ``KKTSystem.slack`` a ``delta_w`` perturbs them
  too, ``1 / (sigma_s + delta_w)``), anything positive on inactive rows (their J rows are 0).
Fixed variables (``free == False``) are removed: their rows and columns are replaced by the
identity and their step is 0. Their entries of H, J and r_x are masked by products with 0, so
they must be finite: a caller whose derivatives may be NaN or Inf there removes them first with
``jnp.where`` (`jtraj.solvers.ipm` does, with `JacobianPattern.free_columns`).

Solve: with a dual regularization ``delta_c > 0`` added to D0 on every row (``D = D0 +
delta_c``), the multipliers are eliminated, ``dy = (J dx - r_c) / D``, leaving the condensed
matrix ``M = H + diag(sigma) + delta_w I + J^T D^-1 J``, which is block tridiagonal with
n x n blocks because J couples knots k and k+1 only. Since ``-D`` is negative definite, the KKT
matrix has the inertia an interior-point method wants (n positive, m negative eigenvalues) iff
M is positive definite, i.e. iff its Cholesky factorization succeeds: a failed factorization
(NaN) calls for a larger ``delta_w`` (inertia correction, `factor_with_correction`, Ipopt's
rules). The ``delta_c`` error is removed by iterative refinement against the system with D0.

Cost: O(K (n^3 + m n^2)); the factorization and the two triangular sweeps are ``lax.scan``s.
With a `JacobianPattern` (the Jacobian's static sparsity, which `jtraj.solvers.stage.StageView`
knows), the products with J and the condensed blocks ``J^T D^-1 J`` touch only the nonzeros:
on big_jump about a sixteenth of the dense blocks' entries (135,236 of 2.33 million), and the dense products were
most of a Newton step's time (they are memory-bound on a CPU). The pattern also knows which
columns of a knot the rows of the knot before read (`JacobianPattern.coupled`): the only
nonzero columns of the off-diagonal blocks, and so the only nonzero rows of the factor's
``L[k+1, k]``, which `factor` then keeps alone (``O(K (n^3 / 3 + n^2 c + c^2 n))``).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.scipy.linalg import solve_triangular


def _scoped(name: str) -> Callable[[Callable], Callable]:
    """Trace the function under ``jax.named_scope(name)``: profiles (bench/profile_solve.py) tell
    the phases of a Newton step by these names; the compiled code is the same."""

    def wrap(fn: Callable) -> Callable:
        @functools.wraps(fn)
        def scoped(*args, **kwargs):
            with jax.named_scope(name):
                return fn(*args, **kwargs)

        return scoped

    return wrap


__all__ = [
    "KKTSystem",
    "BlockFactor",
    "condensed_blocks",
    "factor",
    "coupled_columns",
    "solve_factored",
    "factor_with_correction",
    "solve",
    "multiply",
    "InertiaOptions",
    "LowRank",
    "JacobianPattern",
]


class KKTSystem(NamedTuple):
    """The KKT matrix's pieces (see the module docstring); float arrays but ``pattern``.

    Attributes:
        H: (K, 2n, 2n) symmetric element Hessians on (z_k, z_{k+1}); H[K-1][n:, :] is ignored;
            None for no block Hessian (a limited-memory Hessian is all low-rank term).
        sigma: (K, n) diagonal barrier terms of the variable bounds.
        A: (K, m, n) Jacobian of knot k's rows with respect to z_k; with a ``pattern``, the
            vector (pattern.nnz,) of the Jacobian's nonzeros in the pattern's order instead
            (`JacobianPattern.values`).
        B: (K, m, n) ... with respect to z_{k+1} (B[K-1] is ignored); None with a pattern.
        d0: (K, m) the (2, 2) block is ``-diag(d0)``; 0 for equalities.
        free: (K, n) bool, False for fixed variables.
        pattern: the static sparsity of A and B (entries outside it are taken as zero), or
            None for dense blocks.
        slack: (K, m) bool, or None: the rows whose ``d0`` is ``1 / sigma_s`` of an eliminated
            slack. A ``delta_w`` perturbs their slack's block too, as Ipopt's inertia correction
            perturbs ``Sigma_s + delta_w I`` with the variables' (Wächter & Biegler 2006,
            eq. 13): their (2, 2) entry is then ``1 / (1/d0 + delta_w)`` (`perturbed_d0`).
    """

    H: jax.Array | None
    sigma: jax.Array
    A: jax.Array
    B: jax.Array | None
    d0: jax.Array
    free: jax.Array
    pattern: JacobianPattern | None = None
    slack: jax.Array | None = None


def perturbed_d0(system: KKTSystem, delta_w: jax.Array) -> jax.Array:
    """The (2, 2) block's ``d0`` at the perturbation ``delta_w``: on the slack rows
    (`KKTSystem.slack`) ``1 / (1/d0 + delta_w) = d0 / (1 + delta_w d0)``, elsewhere ``d0``."""
    if system.slack is None:
        return system.d0
    return jnp.where(system.slack, system.d0 / (1.0 + delta_w * system.d0), system.d0)


@jax.tree_util.register_static
class JacobianPattern:
    """The static sparsity of the stage Jacobian blocks A, B (K, m, n), and the products that
    use only their nonzeros.

    Built once from the nonzeros' (knot k, row slot r, column c in [0, 2n)): c < n is an entry
    of A[k, r, c], c >= n one of B[k, r, c - n] (rows of knot k reading knot k + 1).

    The Jacobian is then the vector of its nonzeros, A's then B's, each in (knot, slot,
    column) order (`values` takes them from dense blocks, `dense` puts them back): 1/16 of the
    dense blocks' memory on the whole-body tasks, which matters because a Newton step is
    memory-bound on a CPU, most of all under ``vmap``.

    - `apply_J` / `apply_JT`: products with the nonzeros and a scatter-add, instead of dense
      (K, m, n) products.
    - `condensed`: the blocks of ``J^T diag(w) J``. Each row adds ``w_r`` times the outer
      product of its nonzeros, so its entries are sums over pairs of nonzeros of one row:
      those pairs (index arrays) are built here and summed by one sorted segment sum. Row
      slots with many nonzeros in A (the dynamics rows, whose pairs grow as the square)
      contribute their A-A part by a dense batched product over those slots instead; which
      slots, by a cost model (``pair_cost`` flops per pair).

    Registered as a static pytree node, so a `KKTSystem` carrying it passes through ``jit``
    and ``vmap`` (it is hashed by identity).
    """

    def __init__(self, K: int, m: int, n: int, knot: np.ndarray, slot: np.ndarray, col: np.ndarray, pair_cost: float = 200.0):
        knot, slot, col = (np.asarray(a, np.int64) for a in (knot, slot, col))
        flat = np.unique((knot * m + slot) * (2 * n) + col)
        knot, slot, col = flat // (m * 2 * n), (flat // (2 * n)) % m, flat % (2 * n)
        is_b = col >= n
        if np.any(is_b & (knot >= K - 1)):
            raise ValueError("a row of the last knot reads a next knot")
        self.K, self.m, self.n = K, m, n
        self.nnz = int(flat.size)
        i32 = lambda a: np.asarray(a, np.int32)  # noqa: E731
        row = knot * m + slot
        # gathers from A.ravel() and B.ravel(); columns into the (K + 1) n padded vector
        ka, ra, ca = knot[~is_b], row[~is_b], col[~is_b]
        kb, rb, cb = knot[is_b], row[is_b], col[is_b] - n
        self._a = (i32(ra * n + ca), i32(ra), i32(ka * n + ca))
        self._b = (i32(rb * n + cb), i32(rb), i32((kb + 1) * n + cb))
        self.n_a = int(ka.size)
        #: the columns of a knot that rows of the knot before read (B's columns, over all
        #: knots): the only columns of the condensed matrix's off-diagonal blocks (`factor`)
        self.coupled = np.unique(cb).astype(np.int32)
        #: the (K * m) stage row of every nonzero, in the vector's order
        self.rows = i32(np.concatenate([ra, rb]))
        #: the flat key (knot m + slot) 2n + column of every nonzero, in the vector's order
        self.keys = np.concatenate([flat[~is_b], flat[is_b]])
        # every nonzero, in the vector's order: its row, the knot of its column, its column
        e_row = np.concatenate([ra, rb])
        e_knot = np.concatenate([ka, kb + 1])
        e_col = np.concatenate([ca, cb])
        e_a = np.concatenate([np.ones(ka.size, bool), np.zeros(kb.size, bool)])
        # dense slots: the fewest (largest-A) slots that minimize dense flops + pair_cost * pairs
        n_a = np.bincount(ra, minlength=K * m).reshape(K, m)
        per_slot_aa = (n_a.astype(np.int64) ** 2).sum(axis=0)
        by_size = np.argsort(-n_a.max(axis=0), kind="stable")
        cost = [pair_cost * per_slot_aa.sum()]
        for j in range(m):
            cost.append(cost[-1] - pair_cost * per_slot_aa[by_size[j]] + 2.0 * K * n * n)
        self.dense_slots = np.sort(by_size[: int(np.argmin(cost))]).astype(np.int32)
        dense_row = np.zeros(K * m, bool)
        dense_row[(np.arange(K)[:, None] * m + self.dense_slots[None, :]).ravel()] = True
        # pairs (p, q) of nonzeros in one row with knot(p) <= knot(q), A-A pairs of dense rows left out
        order = np.argsort(e_row, kind="stable")
        counts = np.bincount(e_row, minlength=K * m)
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        per = counts[e_row[order]]
        p = np.repeat(order, per)
        first = np.repeat(starts[e_row[order]], per)
        offset = np.arange(p.size) - np.repeat(np.cumsum(per) - per, per)
        q = order[first + offset]
        keep = (e_knot[p] <= e_knot[q]) & ~(dense_row[e_row[p]] & e_a[p] & e_a[q])
        p, q = p[keep], q[keep]
        # target: diag (offset 0) block of knot(p), entry (col p, col q), or upper (offset 1)
        # block of knot(p) stored by its coupled columns only (q reads the next knot, so its
        # column is one of them): entry (col p, place of col q among the coupled)
        c = self.coupled.size
        place = np.zeros(n, np.int64)
        place[self.coupled] = np.arange(c)
        upper_pair = e_knot[q] > e_knot[p]
        target = np.where(upper_pair, K * n * n + e_knot[p] * (n * c) + e_col[p] * c + place[e_col[q]], e_knot[p] * (n * n) + e_col[p] * n + e_col[q])
        srt = np.argsort(target, kind="stable")
        self._pairs = (i32(p[srt]), i32(q[srt]), i32(e_row[p[srt]]), i32(target[srt]))
        self.n_pairs = int(p.size)
        # the targets are sorted, diag's (< K n n) first: how many pairs land on diag
        self._n_diag_pairs = int(np.searchsorted(target[srt], K * n * n))
        # A's nonzeros in the dense slots: their index in the vector, their place in (K, slots, n)
        where = np.full(m, -1)
        where[self.dense_slots] = np.arange(self.dense_slots.size)
        in_dense = where[slot[~is_b]] >= 0
        self._dense = (i32(np.flatnonzero(in_dense)), i32((ka[in_dense] * self.dense_slots.size + where[slot[~is_b]][in_dense]) * n + ca[in_dense]))

    def index(self, keys: np.ndarray) -> np.ndarray:
        """Positions in the vector of nonzeros of flat keys ``(knot m + slot) 2n + column``
        (each must be in the pattern)."""
        keys = np.asarray(keys, np.int64)
        order = np.argsort(self.keys, kind="stable")
        pos = order[np.minimum(np.searchsorted(self.keys, keys, sorter=order), max(self.keys.size - 1, 0))]
        if keys.size and not np.array_equal(self.keys[pos], keys):
            raise ValueError("a key outside the pattern")
        return pos

    def values(self, A: jax.Array, B: jax.Array) -> jax.Array:
        """The vector of nonzeros (nnz,) of dense blocks A, B (K, m, n)."""
        return jnp.concatenate([A.reshape(-1)[self._a[0]], B.reshape(-1)[self._b[0]]])

    def free_columns(self, free: jax.Array) -> jax.Array:
        """(nnz,) bool: which nonzeros lie in the column of a free variable, for ``free`` (K, n)
        (a fixed variable's entries are to be removed with ``jnp.where``, not multiplied by 0,
        so that a NaN or Inf there cannot reach the step)."""
        padded = jnp.concatenate([free.reshape(-1), jnp.zeros(self.n, bool)])
        return jnp.concatenate([padded[self._a[2]], padded[self._b[2]]])

    def dense(self, v: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Dense blocks (A, B), each (K, m, n), of the vector of nonzeros ``v``."""
        size = self.K * self.m * self.n
        A = jnp.zeros(size, v.dtype).at[self._a[0]].set(v[: self.n_a])
        B = jnp.zeros(size, v.dtype).at[self._b[0]].set(v[self.n_a :])
        return A.reshape(self.K, self.m, self.n), B.reshape(self.K, self.m, self.n)

    def apply_J(self, v: jax.Array, x: jax.Array) -> jax.Array:
        """J x (K, m) for the nonzeros v and x (K, n)."""
        K, m, n = self.K, self.m, self.n
        xf = jnp.concatenate([x.reshape(-1), jnp.zeros(n, x.dtype)])
        (_, ra, ca), (_, rb, cb) = self._a, self._b
        out = jnp.zeros(K * m, x.dtype).at[ra].add(v[: self.n_a] * xf[ca]).at[rb].add(v[self.n_a :] * xf[cb])
        return out.reshape(K, m)

    def apply_JT(self, v: jax.Array, y: jax.Array) -> jax.Array:
        """J^T y (K, n) for the nonzeros v and y (K, m)."""
        K, n = self.K, self.n
        yf = y.reshape(-1)
        (_, ra, ca), (_, rb, cb) = self._a, self._b
        out = jnp.zeros((K + 1) * n, y.dtype).at[ca].add(v[: self.n_a] * yf[ra]).at[cb].add(v[self.n_a :] * yf[rb])
        return out[: K * n].reshape(K, n)

    def condensed(self, v: jax.Array, w: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The blocks of ``J^T diag(w) J`` for the nonzeros v and w (K, m): (diag (K, n, n),
        upper (K, n, c)), upper[k] = the (k, k+1) block's `coupled` columns (its others are
        zero); the B-B products land on diag[k + 1]."""
        K, n, c = self.K, self.n, self.coupled.size
        p, q, row, target = self._pairs
        nd = self._n_diag_pairs
        prods = v[p] * v[q] * w.reshape(-1)[row]
        # diag's pairs are added into the dense slots' product (or zeros), upper's into zeros:
        # two sorted scatter-adds, with no zero-filled buffer and no add pass for diag (a
        # profile of big_jump's solve: those were about 2 % of it)
        if self.dense_slots.size:
            s = self.dense_slots.size
            Ad = jnp.zeros(K * s * n, v.dtype).at[self._dense[1]].set(v[self._dense[0]]).reshape(K, s, n)
            base = (jnp.swapaxes(Ad * w[:, self.dense_slots, None], 1, 2) @ Ad).reshape(-1)
        else:
            base = jnp.zeros(K * n * n, v.dtype)
        diag = base.at[target[:nd]].add(prods[:nd], indices_are_sorted=True, mode="promise_in_bounds").reshape(K, n, n)
        upper = jnp.zeros(K * n * c, v.dtype).at[target[nd:] - K * n * n].add(prods[nd:], indices_are_sorted=True, mode="promise_in_bounds")
        # (the pairs of one knot's columns come in both orders, so diag is symmetric)
        return diag, upper.reshape(K, n, c)


class LowRank(NamedTuple):
    """A low-rank term of the Hessian in the compact form of a limited-memory BFGS matrix
    (Byrd, Nocedal and Schnabel, Math. Prog. 63, 1994): the Hessian is the block part minus
    ``W^T M^-1 W``.

    Attributes:
        W: (r, K, n) the r vectors (the columns of the N x r matrix), 0 on fixed variables.
        M: (r, r) symmetric and nonsingular.
    """

    W: jax.Array
    M: jax.Array


def _low_rank_apply(low_rank: LowRank, x: jax.Array) -> jax.Array:
    """``-W^T M^-1 W x`` for x (K, n)."""
    wx = jnp.einsum("rkn,kn->r", low_rank.W, x)
    return -jnp.einsum("rkn,r->kn", low_rank.W, jnp.linalg.solve(low_rank.M, wx))


class BlockFactor(NamedTuple):
    """Block Cholesky factor of a block-tridiagonal matrix: ``L[k,k] = diag[k]^T``, ``L[k,k-1] =
    sub[k]`` (sub[0] = 0), or, factored with ``coupled`` columns (`factor`), those rows of it.

    The diagonal blocks are kept transposed (upper triangular): a row-major ``L^T`` is the
    column-major ``L`` that LAPACK's triangular solves read, so XLA's CPU code slices a block
    for them without transposing it (measured, `factor`)."""

    diag: jax.Array  # (K, n, n) upper triangular: L[k,k]^T
    sub: jax.Array  # (K, n, n), or (K, c, n) with c coupled columns


class InertiaOptions(NamedTuple):
    """Ipopt's inertia-correction constants (Wächter & Biegler 2006, Algorithm IC)."""

    delta_w_first: float = 1e-4  # first trial when no earlier value
    delta_w_min: float = 1e-20
    delta_w_max: float = 1e40
    kappa_minus: float = 1.0 / 3.0  # shrink the last value before trying it
    kappa_plus: float = 8.0
    kappa_plus_first: float = 100.0
    max_attempts: int = 40


def _split_last(K: int, dtype) -> jax.Array:
    """(K,) 1.0 on knots that have a successor, 0.0 on the last, in the blocks' ``dtype`` (a
    float64 mask turned float32 blocks into float64 ones, and the factorization refused them)."""
    return (jnp.arange(K) < K - 1).astype(dtype)


def condensed_blocks(system: KKTSystem, d: jax.Array, delta_w: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Blocks of ``M = H + diag(sigma) + delta_w I + J^T diag(1/d) J`` restricted to the free
    variables (identity on fixed ones): (diag (K, n, n), upper (K, n, n) with upper[k] =
    M[k, k+1], upper[K-1] = 0). Where `coupled_columns` gives columns (a pattern, no block
    Hessian), upper is those columns of the blocks alone, (K, n, c), as `factor` takes them.

    `factor_with_correction` does not form these: it hands `factor` the blocks of
    `_product_blocks` with the diagonal and the free variables' mask, which the factor applies
    to each block as it reads it (the same matrix)."""
    diag, upper = _product_blocks(system, d)
    f = system.free.astype(diag.dtype)
    keep_next = _keep_next(f, coupled_columns(system.pattern, system.H is not None))
    blocks: tuple[jax.Array, jax.Array] = jax.vmap(_finish)(diag, upper, system.sigma + delta_w, f, keep_next)
    return blocks


@_scoped("kkt_condensed")
def _product_blocks(system: KKTSystem, d: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The blocks of ``H + J^T diag(1/d) J`` (no diagonal terms, no mask), shaped as
    `condensed_blocks`'."""
    H, sigma, A, B, pattern = system.H, system.sigma, system.A, system.B, system.pattern
    K, n = sigma.shape
    has_next = _split_last(K, sigma.dtype)
    w = 1.0 / d
    coupled = coupled_columns(pattern, H is not None)
    if pattern is not None:
        diag, upper = pattern.condensed(A, w)
        if coupled is None:  # the whole blocks
            upper = jnp.zeros((K, n, n), upper.dtype).at[:, :, pattern.coupled].set(upper)
    else:
        assert B is not None, "dense blocks need B"
        Bm = jnp.where(has_next[:, None, None] > 0, B, 0.0)  # B[K-1] ignored, even a NaN there
        AtW = jnp.swapaxes(A * w[:, :, None], 1, 2)
        BtW = jnp.swapaxes(Bm * w[:, :, None], 1, 2)
        diag = (AtW @ A).at[1:].add((BtW @ Bm)[:-1])  # B_k's products land on knot k+1
        upper = AtW @ Bm
    if H is not None:
        diag = (diag + H[:, :n, :n]).at[1:].add(H[:-1, n:, n:])
        upper = upper + H[:, :n, n:] * has_next[:, None, None]
    return diag, upper


def _keep_next(f: jax.Array, coupled: np.ndarray | None) -> jax.Array:
    """(K, n) or (K, c): the free mask of knot k + 1 (0 after the last), on ``coupled``'s
    columns where given."""
    f_next = jnp.concatenate([f[1:], jnp.zeros_like(f[:1])], axis=0)
    return f_next if coupled is None else f_next[:, coupled]


def _finish(D: jax.Array, U: jax.Array, shift: jax.Array, keep: jax.Array, keep_next: jax.Array) -> tuple[jax.Array, jax.Array]:
    """One knot's blocks of `condensed_blocks` from `_product_blocks`': ``shift`` (n,) added to
    the diagonal, the rows and columns of the fixed variables (``keep`` 0) replaced by the
    identity's, and U's columns of fixed variables of the next knot zeroed."""
    eye = jnp.eye(D.shape[-1], dtype=D.dtype)
    D = D * (keep[:, None] * keep[None, :]) + eye * (shift * keep + 1.0 - keep)[None, :]
    return D, U * (keep[:, None] * keep_next[None, :])


def coupled_columns(pattern: JacobianPattern | None, block_hessian: bool) -> np.ndarray | None:
    """The static columns of the next knot in which the condensed matrix's off-diagonal blocks
    can be nonzero (`JacobianPattern.coupled`), or None for all of them: with a pattern and no
    block Hessian (whose element blocks couple every column), when they are fewer than n."""
    if pattern is None or block_hessian or pattern.coupled.size >= pattern.n:
        return None
    return pattern.coupled


def _places(n: int, cols: np.ndarray) -> np.ndarray:
    """(n,) each column's place among the coupled columns ``cols``, or ``cols.size`` (the index
    of a zero padded after them) for the others: a gather that puts c-sized results into n."""
    place = np.full(n, cols.size)
    place[cols] = np.arange(cols.size)
    return place


#: blocks larger than this are factored by `_cholesky` and `_solve_lower_t` in two halves
#: (recursively), smaller ones by one LAPACK call each. OpenBLAS's Cholesky (``dpotrf``) ran
#: at 3 to 5 GFLOP/s on 78 to 156 square blocks on this project's 2-core machines, where a
#: matrix product of that size runs at about 30: the halves move a quarter of the Cholesky's
#: flops and half of the triangular solve's into matrix products. The factor of random blocks
#: with K = 47, n = 156, c = 96 (big_jump's block size with the study's variables, with fewer
#: coupled columns than its 112) took 1.14 to 1.19 times less median time
#: (`bench/factor_split.py`, `results/factor_split/`; each task's own shapes 1.02 to 1.10 in
#: `results/factor_split_tasks/`); on the side-flip's n = 78 halves of 40
#: were slower in a scratch run, hence the threshold. Only where JAX's default backend is the
#: CPU: on a GPU, cuSOLVER's kernels are another matter, not measured with the halves.
SPLIT_ABOVE = 96


def _split(n: int) -> bool:
    """Whether an n x n block is factored in halves (`SPLIT_ABOVE`), decided when tracing."""
    return n > SPLIT_ABOVE and jax.default_backend() == "cpu"


def _cholesky(A: jax.Array) -> jax.Array:
    """Lower Cholesky factor of the symmetric ``A`` (its lower triangle is read), NaN where
    ``A`` is not numerically positive definite, as ``lax.linalg.cholesky``'s: in two halves
    above `SPLIT_ABOVE` rows on the CPU (`_split`): ``L11 = chol(A11)``, ``L21 = A21 L11^-T``,
    ``L22 = chol(A22 - L21 L21^T)`` (a failed half makes its rows NaN, and L11's NaN reach L21
    and L22)."""
    n = A.shape[-1]
    if not _split(n):
        return lax.linalg.cholesky(A, symmetrize_input=False)
    h = (n + 1) // 2
    L11 = _cholesky(A[:h, :h])
    L21 = _solve_lower_t(L11, A[h:, :h])
    L22 = _cholesky(A[h:, h:] - L21 @ L21.T)
    top = jnp.concatenate([L11, jnp.zeros((h, n - h), A.dtype)], axis=1)
    return jnp.concatenate([top, jnp.concatenate([L21, L22], axis=1)], axis=0)


def _solve_lower_t(L: jax.Array, B: jax.Array) -> jax.Array:
    """X with ``X L^T = B`` for the lower triangular L (n x n) and B (r x n), in two halves of
    L's columns above `SPLIT_ABOVE`: ``X1 = B1 L11^-T``, ``X2 = (B2 - X1 L21^T) L22^-T``."""
    n = L.shape[-1]
    if not _split(n):
        return lax.linalg.triangular_solve(L, B, left_side=False, lower=True, transpose_a=True)
    h = (n + 1) // 2
    X1 = _solve_lower_t(L[:h, :h], B[:, :h])
    X2 = _solve_lower_t(L[h:, h:], B[:, h:] - X1 @ L[h:, :h].T)
    return jnp.concatenate([X1, X2], axis=1)


@_scoped("kkt_factor")
def factor(
    diag: jax.Array, upper: jax.Array, coupled: np.ndarray | None = None, shift: jax.Array | None = None, keep: jax.Array | None = None
) -> tuple[BlockFactor, jax.Array]:
    """Block Cholesky of the symmetric block-tridiagonal matrix (diag, upper); returns the
    factor and whether it succeeded (the matrix is numerically positive definite).

    ``shift`` and ``keep`` (K, n), given together: factor instead the matrix whose blocks
    `condensed_blocks` makes of these (``shift`` added to the diagonal, the variables with
    ``keep`` 0 fixed: their rows and columns the identity's), each block finished as the knot
    step reads it, with no pass over the whole blocks (in a profile of big_jump's solve, the
    passes that made the diagonal and the mask took about 3 % of it).

    ``coupled`` (static, c of the n columns): the only columns in which the blocks ``upper``
    may be nonzero (`coupled_columns`). Then ``L[k+1, k] = upper[k]^T L_k^-T`` is nonzero on
    those rows only, and the factor keeps them alone (``sub`` (K, c, n)): the off-diagonal
    solve costs n^2 c instead of n^3 and the Schur update ``L[k+1,k] L[k+1,k]^T`` c^2 n instead
    of n^3 (the walk: c = 88 of n = 156). ``upper`` may be given whole (K, n, n) or as those
    columns (K, n, c).

    The knot step is written for XLA's CPU code, in which copying a block between layouts
    cost about as much as the LAPACK calls on it (a profile of big_jump's solve): the Schur
    update gathers ``L[k+1,k] L[k+1,k]^T`` into the block's coupled rows and columns in one
    fused subtraction (not a scatter), the matrix is not symmetrized again (the condensed
    blocks are symmetric, and LAPACK reads one triangle), ``L[k+1, k]`` comes from a
    right-side triangular solve in its own orientation, and the diagonal factors are kept
    transposed (`BlockFactor`). On random blocks of big_jump's shapes (K = 47, n = 132,
    c = 96), jitted alone in one process, that took a factor from 25.1 to 21.4 ms; whole
    solves, `results/solver_layouts`."""
    n = diag.shape[-1]
    cols = None if coupled is None else np.asarray(coupled)
    if cols is None:
        schur = lambda D, S: D - S @ S.T  # noqa: E731
    else:
        place = _places(n, cols)
        schur = lambda D, S: D - jnp.pad(S @ S.T, ((0, 1), (0, 1)))[place[:, None], place[None, :]]  # noqa: E731
        if upper.shape[-1] != cols.size:
            upper = upper[:, :, cols]

    finish: Callable[..., tuple[jax.Array, jax.Array]]
    if shift is None:
        finish = lambda D, U: (D, U)  # noqa: E731
        extra: tuple[jax.Array, ...] = ()
    else:
        assert keep is not None, "shift and keep go together"
        finish = _finish
        extra = (shift, keep, _keep_next(keep, cols))

    def step(sub_k, blocks):
        D_k, U_k = finish(*blocks)
        L_k = _cholesky(schur(D_k, sub_k))
        # L[k+1, k] = U_k^T L_k^-T, i.e. X L_k^T = U_k^T: (n, n), or (c, n) for its rows `cols`
        sub_next = _solve_lower_t(L_k, U_k.T)
        return sub_next, (L_k.T, sub_k)

    sub0 = jnp.zeros((n if cols is None else cols.size, n), diag.dtype)
    _, (Lt, sub) = lax.scan(step, sub0, (diag, upper, *extra))
    # a failed block is NaN (LAPACK's info), and a non-finite entry of a row of L_k makes that
    # row's pivot non-finite: the pivots tell both
    pivots = jnp.diagonal(Lt, axis1=1, axis2=2)
    ok = jnp.all(jnp.isfinite(pivots) & (pivots > 0.0))
    return BlockFactor(Lt, sub), ok


@_scoped("kkt_sweeps")
def solve_factored(fac: BlockFactor, b: jax.Array, coupled: np.ndarray | None = None) -> jax.Array:
    """``M^-1 b`` for b of shape (K, n), by a forward and a backward block sweep; ``coupled``
    as given to `factor`."""
    Lt, sub = fac
    n = b.shape[-1]
    cols = None if coupled is None else np.asarray(coupled)
    # L[k,k-1] y_{k-1} and L[k+1,k]^T x_{k+1}, with L[k,k-1] whole or as its rows `cols`
    if cols is None:
        below = lambda S, y: S @ y  # noqa: E731
        above = lambda S, x: S.T @ x  # noqa: E731
    else:
        place = _places(n, cols)
        below = lambda S, y: jnp.pad(S @ y, (0, 1))[place]  # noqa: E731
        above = lambda S, x: S.T @ x[cols]  # noqa: E731

    def forward(y_prev, inp):
        Lt_k, S_k, b_k = inp
        y = solve_triangular(Lt_k.T, b_k - below(S_k, y_prev), lower=True)
        return y, y

    _, y = lax.scan(forward, jnp.zeros_like(b[0]), (Lt, sub, b))

    # backward: x_k = L_k^-T (y_k - L[k+1,k]^T x_{k+1}); knot k+1's step hands knot k the
    # product L[k+1,k]^T x_{k+1} (so the scan reads sub[k] at knot k, not a shifted copy)
    def backward(from_next, inp):
        Lt_k, S_k, y_k = inp
        x = solve_triangular(Lt_k.T, y_k - from_next, lower=True, trans="T")
        return above(S_k, x), x

    _, x = lax.scan(backward, jnp.zeros_like(b[0]), (Lt, sub, y), reverse=True)
    return x


def factor_with_correction(
    system: KKTSystem, delta_c: jax.Array, delta_w_last: jax.Array, options: InertiaOptions = InertiaOptions(), active: jax.Array | bool = True
) -> tuple[BlockFactor, jax.Array, jax.Array]:
    """Factor with the smallest ``delta_w`` of Ipopt's sequence that gives the right inertia.

    Tries ``delta_w = 0`` first, then ``max(delta_w_min, kappa_minus delta_w_last)`` (or
    ``delta_w_first``), growing by ``kappa_plus`` until the condensed matrix is positive
    definite; as Ipopt's perturbation handler, it grows by ``kappa_plus_first`` instead when
    there was no earlier value or the trial is more than 1e5 times it, and it makes no trial
    above ``delta_w_max`` nor more than ``max_attempts``, and then gives up (ok False) with the
    last value tried. ``delta_w_last`` is the last positive ``delta_w`` used by any earlier
    factorization, not only the previous one (Wächter & Biegler 2006, Algorithm IC: only a
    correction sets it). ``active`` False makes no correction (the ``delta_w = 0`` trial only):
    under ``vmap`` the batch's loop runs while any member's does, and a member that has stopped
    (a NaN matrix fails every trial) made every later iteration of the batch pay the whole
    sequence of trials. Returns (factor, delta_w used, ok).
    """
    d = system.d0 + delta_c
    coupled = coupled_columns(system.pattern, system.H is not None)
    # the products J^T D^-1 J (and H) once; each attempt's delta_w and the free mask are
    # applied by the factor's knot step
    diag, upper = _product_blocks(system, d)
    keep = system.free.astype(diag.dtype)

    def attempt(dw, first=False):
        # with slack rows their block is perturbed too: their D, and so the products, change
        # with delta_w (the first attempt, delta_w = 0, takes those made above)
        blocks = (diag, upper) if first or system.slack is None else _product_blocks(system, perturbed_d0(system, dw) + delta_c)
        return factor(*blocks, coupled=coupled, shift=system.sigma + dw, keep=keep)

    def following(dw, i):
        # the trial after ``dw``, the i-th (i >= 1): Ipopt's first nonzero value, then growth
        first = jnp.where(delta_w_last == 0.0, options.delta_w_first, jnp.maximum(options.delta_w_min, options.kappa_minus * delta_w_last))
        grow = jnp.where((delta_w_last == 0.0) | (1e5 * delta_w_last < dw), options.kappa_plus_first, options.kappa_plus) * dw
        return jnp.where(i == 1, first, grow)

    def cond(state):
        # as Ipopt's perturbation handler, a trial above delta_w_max is not made: the
        # correction gives up with the last value tried
        _, ok, dw, i = state
        # (the bound at the factor's precision: 1e40 is inf in float32, and numpy warned of it)
        return active & (~ok) & (i < options.max_attempts) & (following(dw, i) <= min(options.delta_w_max, float(jnp.finfo(dw.dtype).max)))

    def body(state):
        _, _, dw, i = state
        dw_new = following(dw, i)
        fac, ok = attempt(dw_new)
        return fac, ok, dw_new, i + 1

    # attempt 0 (delta_w = 0) before the loop, whose state it starts: no zero-filled factor
    # for the loop's first state (about 1 % of a profiled big_jump solve), at the price of a
    # second factorization in the program
    zero = jnp.zeros((), system.sigma.dtype)
    fac0, ok0 = attempt(zero, first=True)
    fac, ok, dw, _ = lax.while_loop(cond, body, (fac0, ok0, zero, jnp.ones((), jnp.int32)))
    return fac, dw, ok


def _apply_J(A, B, x, pattern: JacobianPattern | None = None):
    """J x: (K, m) rows of knot k from x_k and x_{k+1}."""
    if pattern is not None:
        return pattern.apply_J(A, x)
    K = x.shape[0]
    x_next = jnp.concatenate([x[1:], jnp.zeros_like(x[:1])], axis=0)
    return jnp.einsum("kmn,kn->km", A, x) + jnp.einsum("kmn,kn->km", jnp.where(_split_last(K, B.dtype)[:, None, None] > 0, B, 0.0), x_next)


def _apply_JT(A, B, y, pattern: JacobianPattern | None = None):
    """J^T y: (K, n)."""
    if pattern is not None:
        return pattern.apply_JT(A, y)
    K = y.shape[0]
    out = jnp.einsum("kmn,km->kn", A, y)
    from_prev = jnp.einsum("kmn,km->kn", jnp.where(_split_last(K, B.dtype)[:, None, None] > 0, B, 0.0), y)
    return out.at[1:].add(from_prev[:-1])


def _apply_H(H, x):
    K, n = x.shape
    x_next = jnp.concatenate([x[1:], jnp.zeros_like(x[:1])], axis=0)
    has_next = _split_last(K, x.dtype)[:, None]
    xx = jnp.concatenate([x, x_next * has_next], axis=1)
    Hx = jnp.einsum("kij,kj->ki", H, xx)
    out = Hx[:, :n]
    return out.at[1:].add((Hx[:, n:] * has_next)[:-1])


def multiply(system: KKTSystem, delta_w: jax.Array, dx: jax.Array, dy: jax.Array, d: jax.Array | None = None, low_rank: LowRank | None = None) -> tuple[jax.Array, jax.Array]:
    """The KKT matrix (with (2,2) block ``-diag(d)``, default D0; the Hessian's low-rank term
    if given) times (dx, dy), fixed variables removed (their rows return dx itself)."""
    H, sigma, A, B, _, free, pattern, _ = system
    d = perturbed_d0(system, delta_w) if d is None else d
    f = free.astype(dx.dtype)
    dxf = dx * f
    Hx = jnp.zeros_like(dxf) if H is None else _apply_H(H, dxf)
    if low_rank is not None:
        Hx = Hx + _low_rank_apply(low_rank, dxf)
    top = (Hx + (sigma + delta_w) * dxf + _apply_JT(A, B, dy, pattern)) * f + dx * (1.0 - f)
    bottom = _apply_J(A, B, dxf, pattern) - d * dy
    return top, bottom


def solve(
    system: KKTSystem,
    fac: BlockFactor,
    delta_w: jax.Array,
    delta_c: jax.Array,
    r_x: jax.Array,
    r_c: jax.Array,
    refine_steps: int = 3,
    remove_delta_c: bool = True,
    low_rank: LowRank | None = None,
    residual_ratio_max: float = 0.0,
    min_refine_steps: int = 0,
) -> tuple[jax.Array, jax.Array]:
    """Solve the KKT system for right-hand sides r_x (K, n) and r_c (K, m), given the factor of
    the ``delta_c``-regularized condensed matrix.

    ``remove_delta_c`` (default): iterative refinement is against the system with D0, i.e.
    without ``delta_c``; a correction is kept only where it lowers the residual, so a singular
    D0 system (dependent equality rows) falls back to the regularized solution. Otherwise the
    refinement is against the regularized system itself (Ipopt's treatment of a dependent
    Jacobian: ``delta_c`` is part of the system), which keeps the multiplier step bounded by
    ``|r_c| / delta_c`` where the linearized rows are inconsistent.
    Fixed variables get dx = 0 (their r_x entries are ignored).

    Iterative refinement (Ipopt's rule, its ``PDFullSpaceSolver``): after ``min_refine_steps``,
    it stops once the residual ratio ``|res| / (min(|sol|, 1e6 |rhs|) + |rhs|)`` (max norms) is
    at most ``residual_ratio_max``, or when a step does not lower the residual, and after
    ``refine_steps`` steps in any case. ``residual_ratio_max=0`` always takes ``refine_steps``
    steps, keeping each only where it lowers the residual. Unlike Ipopt, a solve whose ratio
    stays above the limit is returned as it is (Ipopt raises the perturbation and solves again
    above ``residual_ratio_singular``, 1e-5; `jtraj.solvers.ipm`'s list of differences).

    ``low_rank``: the Hessian has that term too (``fac`` factors the matrix without it, which
    must then be positive definite, as with a BFGS matrix); the condensed solve applies the
    Sherman-Morrison-Woodbury formula with r extra block solves and an r x r system, so the
    block-tridiagonal structure is kept.

    Several right-hand sides: r_x (R, K, n) and r_c (R, K, m) give dx, dy with that leading
    axis. Their first block solves share the sweeps with the r low-rank columns' (one pass of
    the factor over R + r columns instead of two passes), and each is then refined on its own.
    """
    many = r_x.ndim == 3
    if not many:
        r_x, r_c = r_x[None], r_c[None]
    A, B = system.A, system.B
    d = perturbed_d0(system, delta_w) + delta_c
    f = system.free.astype(r_x.dtype)
    r_x = r_x * f
    coupled = coupled_columns(system.pattern, system.H is not None)

    def block_rhs(rx, rc):
        return rx + _apply_JT(A, B, rc / d, system.pattern) * f

    def block_solves(bs):
        return jax.vmap(lambda b: solve_factored(fac, b, coupled))(bs) * f

    rhs = jax.vmap(block_rhs)(r_x, r_c)
    if low_rank is None:
        first = block_solves(rhs)
    else:
        # (M0 - W^T M^-1 W)^-1 = M0^-1 + M0^-1 W^T (M - W M0^-1 W^T)^-1 W M0^-1
        Wf = low_rank.W * f
        both = block_solves(jnp.concatenate([Wf, rhs]))
        Z, first = both[: Wf.shape[0]], both[Wf.shape[0] :]
        capacitance = low_rank.M - jnp.einsum("rkn,skn->rs", Wf, Z)

    def dual(dx, rc):
        if low_rank is not None:
            dx = dx + jnp.einsum("rkn,r->kn", Z, jnp.linalg.solve(capacitance, jnp.einsum("rkn,kn->r", Wf, dx)))
        dy = (_apply_J(A, B, dx, system.pattern) - rc) / d
        return dx, dy

    def condensed_solve(rx, rc):
        return dual(solve_factored(fac, block_rhs(rx, rc), coupled) * f, rc)

    def residual(r_x, r_c, dx, dy):
        top, bottom = multiply(system, delta_w, dx, dy, None if remove_delta_c else d, low_rank)
        return r_x - top * f, r_c - bottom

    def norm(rx, rc):
        return jnp.maximum(jnp.max(jnp.abs(rx)), jnp.max(jnp.abs(rc)))

    @_scoped("kkt_refine")
    def refined(r_x, r_c, dx0):
        dx, dy = dual(dx0, r_c)
        rx, rc = residual(r_x, r_c, dx, dy)
        rhs = norm(r_x, r_c)

        def ratio(dx, dy, rx, rc):
            return norm(rx, rc) / jnp.maximum(jnp.minimum(norm(dx, dy), 1e6 * rhs) + rhs, 1e-300)

        def refine_more(state):
            i, dx, dy, rx, rc, go_on = state
            return (i < refine_steps) & go_on & ((i < min_refine_steps) | (ratio(dx, dy, rx, rc) > residual_ratio_max))

        def refine(state):
            i, dx, dy, rx, rc, _ = state
            cx, cy = condensed_solve(rx, rc)
            nx, ny = dx + cx, dy + cy
            nrx, nrc = residual(r_x, r_c, nx, ny)
            better = norm(nrx, nrc) < norm(rx, rc)
            pick = lambda new, old: jnp.where(better, new, old)  # noqa: E731
            # a step that does not lower the residual ends the refinement only in the adaptive
            # mode: with residual_ratio_max = 0 the fixed count is kept (each step chooses anew)
            go_on = better | (residual_ratio_max <= 0.0)
            return i + 1, pick(nx, dx), pick(ny, dy), pick(nrx, rx), pick(nrc, rc), go_on

        _, dx, dy, _, _, _ = lax.while_loop(refine_more, refine, (jnp.asarray(0), dx, dy, rx, rc, jnp.asarray(True)))
        return dx, dy

    dx, dy = jax.vmap(refined)(r_x, r_c, first)
    return (dx, dy) if many else (dx[0], dy[0])
