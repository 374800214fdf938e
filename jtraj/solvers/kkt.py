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
  eliminated (Ipopt's reduced system), anything positive on inactive rows (their J rows are 0).
Fixed variables (``free == False``) are removed: their rows and columns are replaced by the
identity and their step is 0.

Solve: with a dual regularization ``delta_c > 0`` added to D0 on every row (``D = D0 +
delta_c``), the multipliers are eliminated, ``dy = (J dx - r_c) / D``, leaving the condensed
matrix ``M = H + diag(sigma) + delta_w I + J^T D^-1 J``, which is block tridiagonal with
n x n blocks because J couples knots k and k+1 only. Since ``-D`` is negative definite, the KKT
matrix has the inertia an interior-point method wants (n positive, m negative eigenvalues) iff
M is positive definite, i.e. iff its Cholesky factorization succeeds: a failed factorization
(NaN) calls for a larger ``delta_w`` (inertia correction, `factor_with_correction`, Ipopt's
rules). The ``delta_c`` error is removed by iterative refinement against the system with D0.

Cost: O(K (n^3 + m n^2)); the factorization and the two triangular sweeps are ``lax.scan``s.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax
from jax.scipy.linalg import solve_triangular

__all__ = [
    "KKTSystem",
    "BlockFactor",
    "condensed_blocks",
    "factor",
    "solve_factored",
    "factor_with_correction",
    "solve",
    "multiply",
    "InertiaOptions",
    "LowRank",
]


class KKTSystem(NamedTuple):
    """The KKT matrix's pieces (see the module docstring); all float arrays.

    Attributes:
        H: (K, 2n, 2n) symmetric element Hessians on (z_k, z_{k+1}); H[K-1][n:, :] is ignored.
        sigma: (K, n) diagonal barrier terms of the variable bounds.
        A: (K, m, n) Jacobian of knot k's rows with respect to z_k.
        B: (K, m, n) ... with respect to z_{k+1} (B[K-1] is ignored).
        d0: (K, m) the (2, 2) block is ``-diag(d0)``; 0 for equalities.
        free: (K, n) bool, False for fixed variables.
    """

    H: jax.Array
    sigma: jax.Array
    A: jax.Array
    B: jax.Array
    d0: jax.Array
    free: jax.Array


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
    """Block Cholesky factor of a block-tridiagonal matrix: ``L[k,k] = diag[k]``, ``L[k,k-1] =
    sub[k]`` (sub[0] = 0)."""

    diag: jax.Array  # (K, n, n) lower triangular
    sub: jax.Array  # (K, n, n)


class InertiaOptions(NamedTuple):
    """Ipopt's inertia-correction constants (Wächter & Biegler 2006, Algorithm IC)."""

    delta_w_first: float = 1e-4  # first trial when no earlier value
    delta_w_min: float = 1e-20
    delta_w_max: float = 1e40
    kappa_minus: float = 1.0 / 3.0  # shrink the last value before trying it
    kappa_plus: float = 8.0
    kappa_plus_first: float = 100.0
    max_attempts: int = 40


def _split_last(K: int) -> jax.Array:
    """(K,) 1.0 on knots that have a successor, 0.0 on the last."""
    return (jnp.arange(K) < K - 1).astype(jnp.float64)


def condensed_blocks(system: KKTSystem, d: jax.Array, delta_w: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Blocks of ``M = H + diag(sigma) + delta_w I + J^T diag(1/d) J`` restricted to the free
    variables (identity on fixed ones): (diag (K, n, n), upper (K, n, n) with upper[k] =
    M[k, k+1], upper[K-1] = 0)."""
    H, sigma, A, B, _, free = system
    K, n = sigma.shape
    has_next = _split_last(K)
    Bm = B * has_next[:, None, None]
    w = 1.0 / d
    AtW = jnp.swapaxes(A * w[:, :, None], 1, 2)
    BtW = jnp.swapaxes(Bm * w[:, :, None], 1, 2)
    diag = H[:, :n, :n] + AtW @ A
    nxt = (H[:, n:, n:] * has_next[:, None, None]) + BtW @ Bm  # lands on knot k+1
    diag = diag.at[1:].add(nxt[:-1])
    upper = (H[:, :n, n:] * has_next[:, None, None]) + AtW @ Bm
    diag = diag + jax.vmap(jnp.diag)(sigma + delta_w)
    f = free.astype(diag.dtype)
    f_next = jnp.concatenate([f[1:], jnp.zeros_like(f[:1])], axis=0)
    diag = diag * f[:, :, None] * f[:, None, :] + jax.vmap(jnp.diag)(1.0 - f)
    upper = upper * f[:, :, None] * f_next[:, None, :]
    return diag, upper


def factor(diag: jax.Array, upper: jax.Array) -> tuple[BlockFactor, jax.Array]:
    """Block Cholesky of the symmetric block-tridiagonal matrix (diag, upper); returns the
    factor and whether it succeeded (the matrix is numerically positive definite)."""

    def step(sub_k, blocks):
        D_k, U_k = blocks
        S = D_k - sub_k @ sub_k.T
        L_k = jnp.linalg.cholesky(S)
        # L[k+1, k] = U_k^T L_k^-T
        sub_next = solve_triangular(L_k, U_k, lower=True).T
        return sub_next, (L_k, sub_k)

    n = diag.shape[-1]
    _, (L, sub) = lax.scan(step, jnp.zeros((n, n), diag.dtype), (diag, upper))
    pivots = jnp.diagonal(L, axis1=1, axis2=2)
    ok = jnp.all(jnp.isfinite(L)) & jnp.all(pivots > 0.0)
    return BlockFactor(L, sub), ok


def solve_factored(fac: BlockFactor, b: jax.Array) -> jax.Array:
    """``M^-1 b`` for b of shape (K, n), by a forward and a backward block sweep."""
    L, sub = fac

    def forward(y_prev, inp):
        L_k, S_k, b_k = inp
        y = solve_triangular(L_k, b_k - S_k @ y_prev, lower=True)
        return y, y

    _, y = lax.scan(forward, jnp.zeros_like(b[0]), (L, sub, b))
    # backward: x_k = L_k^-T (y_k - L[k+1,k]^T x_{k+1})
    sub_next = jnp.concatenate([sub[1:], jnp.zeros_like(sub[:1])], axis=0)

    def backward(x_next, inp):
        L_k, S_next, y_k = inp
        x = solve_triangular(L_k, y_k - S_next.T @ x_next, lower=True, trans="T")
        return x, x

    _, x = lax.scan(backward, jnp.zeros_like(b[0]), (L, sub_next, y), reverse=True)
    return x


def factor_with_correction(
    system: KKTSystem, delta_c: jax.Array, delta_w_last: jax.Array, options: InertiaOptions = InertiaOptions()
) -> tuple[BlockFactor, jax.Array, jax.Array]:
    """Factor with the smallest ``delta_w`` of Ipopt's sequence that gives the right inertia.

    Tries ``delta_w = 0`` first, then ``max(delta_w_min, kappa_minus delta_w_last)`` (or
    ``delta_w_first``), growing by ``kappa_plus`` (``kappa_plus_first`` when there was no
    earlier value) until the condensed matrix is positive definite.
    Returns (factor, delta_w used, ok).
    """
    d = system.d0 + delta_c
    n = system.sigma.shape[1]
    # one factorization in the program (attempt 0 is delta_w = 0), to keep compile time low
    empty = BlockFactor(jnp.zeros_like(system.H[:, :n, :n]), jnp.zeros_like(system.H[:, :n, :n]))

    def cond(state):
        _, ok, dw, i = state
        return (~ok) & (i < options.max_attempts) & (dw <= options.delta_w_max)

    def body(state):
        _, _, dw, i = state
        first = jnp.where(delta_w_last == 0.0, options.delta_w_first, jnp.maximum(options.delta_w_min, options.kappa_minus * delta_w_last))
        grow = jnp.where(delta_w_last == 0.0, options.kappa_plus_first, options.kappa_plus) * dw
        dw_new = jnp.where(i == 0, 0.0, jnp.where(i == 1, first, grow))
        fac, ok = factor(*condensed_blocks(system, d, dw_new))
        return fac, ok, dw_new, i + 1

    fac, ok, dw, _ = lax.while_loop(cond, body, (empty, jnp.asarray(False), jnp.zeros(()), jnp.zeros((), jnp.int32)))
    return fac, dw, ok


def _apply_J(A, B, x):
    """J x: (K, m) rows of knot k from x_k and x_{k+1}."""
    K = x.shape[0]
    x_next = jnp.concatenate([x[1:], jnp.zeros_like(x[:1])], axis=0)
    return jnp.einsum("kmn,kn->km", A, x) + jnp.einsum("kmn,kn->km", B * _split_last(K)[:, None, None], x_next)


def _apply_JT(A, B, y):
    """J^T y: (K, n)."""
    K = y.shape[0]
    out = jnp.einsum("kmn,km->kn", A, y)
    from_prev = jnp.einsum("kmn,km->kn", B * _split_last(K)[:, None, None], y)
    return out.at[1:].add(from_prev[:-1])


def _apply_H(H, x):
    K, n = x.shape
    x_next = jnp.concatenate([x[1:], jnp.zeros_like(x[:1])], axis=0)
    has_next = _split_last(K)[:, None]
    xx = jnp.concatenate([x, x_next * has_next], axis=1)
    Hx = jnp.einsum("kij,kj->ki", H, xx)
    out = Hx[:, :n]
    return out.at[1:].add((Hx[:, n:] * has_next)[:-1])


def multiply(system: KKTSystem, delta_w: jax.Array, dx: jax.Array, dy: jax.Array, d: jax.Array | None = None, low_rank: LowRank | None = None) -> tuple[jax.Array, jax.Array]:
    """The KKT matrix (with (2,2) block ``-diag(d)``, default D0; the Hessian's low-rank term
    if given) times (dx, dy), fixed variables removed (their rows return dx itself)."""
    H, sigma, A, B, d0, free = system
    d = d0 if d is None else d
    f = free.astype(dx.dtype)
    dxf = dx * f
    Hx = _apply_H(H, dxf) if low_rank is None else _apply_H(H, dxf) + _low_rank_apply(low_rank, dxf)
    top = (Hx + (sigma + delta_w) * dxf + _apply_JT(A, B, dy)) * f + dx * (1.0 - f)
    bottom = _apply_J(A, B, dxf) - d * dy
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

    ``low_rank``: the Hessian has that term too (``fac`` factors the matrix without it, which
    must then be positive definite, as with a BFGS matrix); the condensed solve applies the
    Sherman-Morrison-Woodbury formula with r extra block solves and an r x r system, so the
    block-tridiagonal structure is kept.
    """
    A, B = system.A, system.B
    d = system.d0 + delta_c
    f = system.free.astype(r_x.dtype)
    r_x = r_x * f

    if low_rank is not None:
        # (M0 - W^T M^-1 W)^-1 = M0^-1 + M0^-1 W^T (M - W M0^-1 W^T)^-1 W M0^-1
        Wf = low_rank.W * f
        Z = jax.vmap(lambda w: solve_factored(fac, w) * f)(Wf)
        capacitance = low_rank.M - jnp.einsum("rkn,skn->rs", Wf, Z)

    def condensed_solve(rx, rc):
        b = rx + _apply_JT(A, B, rc / d) * f
        dx = solve_factored(fac, b) * f
        if low_rank is not None:
            dx = dx + jnp.einsum("rkn,r->kn", Z, jnp.linalg.solve(capacitance, jnp.einsum("rkn,kn->r", Wf, dx)))
        dy = (_apply_J(A, B, dx) - rc) / d
        return dx, dy

    def residual(dx, dy):
        top, bottom = multiply(system, delta_w, dx, dy, None if remove_delta_c else d, low_rank)
        return r_x - top * f, r_c - bottom

    def norm(rx, rc):
        return jnp.maximum(jnp.max(jnp.abs(rx)), jnp.max(jnp.abs(rc)))

    dx, dy = condensed_solve(r_x, r_c)
    rx, rc = residual(dx, dy)

    def refine(_, state):
        dx, dy, rx, rc = state
        cx, cy = condensed_solve(rx, rc)
        nx, ny = dx + cx, dy + cy
        nrx, nrc = residual(nx, ny)
        better = norm(nrx, nrc) < norm(rx, rc)
        pick = lambda new, old: jnp.where(better, new, old)  # noqa: E731
        return pick(nx, dx), pick(ny, dy), pick(nrx, rx), pick(nrc, rc)

    dx, dy, _, _ = lax.fori_loop(0, refine_steps, refine, (dx, dy, rx, rc))
    return dx, dy
