"""The block-tridiagonal KKT solve against a dense solve of the same system."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jtraj.solvers import kkt


def random_system(rng, K=5, n=4, m=3, indefinite=False):
    """A random stage KKT system: element Hessians (PSD, or indefinite), equality and
    inequality rows, one inactive row, some fixed variables."""
    H = rng.normal(size=(K, 2 * n, 2 * n))
    H = np.einsum("kij,klj->kil", H, H) / (2 * n)
    if indefinite:
        H = H - 3.0 * np.eye(2 * n)
    H[-1, n:, :] = 0.0
    H[-1, :, n:] = 0.0
    sigma = rng.uniform(0.0, 2.0, size=(K, n))
    A = rng.normal(size=(K, m, n))
    B = rng.normal(size=(K, m, n))
    B[-1] = 0.0
    d0 = np.where(rng.uniform(size=(K, m)) < 0.5, 0.0, rng.uniform(0.1, 1.0, size=(K, m)))
    # an inactive row: zero Jacobian, positive d0
    A[1, 0] = 0.0
    B[1, 0] = 0.0
    d0[1, 0] = 1.0
    free = np.ones((K, n), bool)
    free[0, :2] = False
    free[-1, -1] = False
    return kkt.KKTSystem(*(jnp.asarray(a) for a in (H, sigma, A, B, d0, free)))


def dense_kkt(system, delta_w):
    """Dense KKT matrix over the free variables and all rows."""
    H, sigma, A, B, d0, free = (np.asarray(a) for a in system[:6])
    K, n = sigma.shape
    m = A.shape[1]
    N = K * n
    Hd = np.zeros((N, N))
    J = np.zeros((K * m, N))
    for k in range(K):
        sl = slice(k * n, (k + 1) * n)
        Hd[sl, sl] += H[k, :n, :n]
        J[k * m : (k + 1) * m, sl] = A[k]
        if k < K - 1:
            sn = slice((k + 1) * n, (k + 2) * n)
            Hd[sn, sn] += H[k, n:, n:]
            Hd[sl, sn] += H[k, :n, n:]
            Hd[sn, sl] += H[k, n:, :n]
            J[k * m : (k + 1) * m, sn] = B[k]
    Hd += np.diag(sigma.reshape(-1) + delta_w)
    keep = free.reshape(-1)
    Hf, Jf = Hd[np.ix_(keep, keep)], J[:, keep]
    M = np.block([[Hf, Jf.T], [Jf, -np.diag(d0.reshape(-1))]])
    return M, keep


@pytest.fixture(params=["lapack", "halves"])
def split(request, monkeypatch):
    """The factor's blocks by one LAPACK call each, or in halves (`kkt.SPLIT_ABOVE` lowered
    so that these small blocks take the path of the whole-body tasks' 156-wide ones).

    Returns the mode and the list of `kkt._split`'s decisions made while the test traced, for
    `_took`: `_split` is read when tracing, so a function JAX has traced before with the same
    shapes would run its old program (the tests jit fresh wrappers, never the module's
    functions themselves)."""
    if request.param == "halves":
        monkeypatch.setattr(kkt, "SPLIT_ABOVE", 2)
    decisions: list[bool] = []
    real = kkt._split

    def spy(n):
        decisions.append(real(n))
        return decisions[-1]

    monkeypatch.setattr(kkt, "_split", spy)
    return request.param, decisions


def _took(split):
    """The programs of the test took the path its mode names (some block was halved iff
    "halves")."""
    mode, decisions = split
    assert decisions, "nothing was traced: an old program ran"
    assert any(decisions) == (mode == "halves")


@pytest.mark.parametrize("indefinite", [False, True])
def test_kkt_solve_equals_dense_solve(rng, indefinite, split):
    system = random_system(rng, indefinite=indefinite)
    K, n = system.sigma.shape
    m = system.A.shape[1]
    r_x = rng.normal(size=(K, n))
    r_c = rng.normal(size=(K, m))
    # fresh wrappers: jax.jit(kkt.factor_with_correction) would reuse the program the other
    # mode traced with these shapes (see `split`)
    fac, delta_w, ok = jax.jit(lambda *a: kkt.factor_with_correction(*a))(system, jnp.asarray(1e-9), jnp.asarray(0.0))
    assert bool(ok)
    if indefinite:
        # the correction was needed, and the corrected KKT matrix has the right inertia
        assert float(delta_w) > 0.0
    else:
        assert float(delta_w) == 0.0
    M, keep = dense_kkt(system, float(delta_w))
    eig = np.linalg.eigvalsh(M)
    assert np.sum(eig > 0) == keep.sum() and np.sum(eig < 0) == K * m
    dx, dy = jax.jit(lambda *a: kkt.solve(*a))(system, fac, delta_w, jnp.asarray(1e-9), jnp.asarray(r_x), jnp.asarray(r_c))
    _took(split)
    ref = np.linalg.solve(M, np.concatenate([r_x.reshape(-1)[keep], r_c.reshape(-1)]))
    np.testing.assert_allclose(np.asarray(dx).reshape(-1)[keep], ref[: keep.sum()], rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(np.asarray(dy).reshape(-1), ref[keep.sum() :], rtol=1e-8, atol=1e-8)
    assert np.all(np.asarray(dx).reshape(-1)[~keep] == 0.0)


def test_kkt_solve_keeps_float32_blocks(rng):
    """The mask of the last knot was float64 and turned float32 Jacobian blocks into float64
    ones: the factorization refused the mixed types (TypeError in triangular_solve). Float32
    blocks now give float32 steps, which solve the dense system to float32's precision."""
    system = random_system(rng)
    single = kkt.KKTSystem(*(a.astype(jnp.float32) if a.dtype == jnp.float64 else a for a in system[:6]))
    K, n = system.sigma.shape
    m = system.A.shape[1]
    r_x, r_c = rng.normal(size=(K, n)), rng.normal(size=(K, m))
    delta_c = 1e-3  # (float32 has no room for the IPM's 1e-8: its D^-1 J^T J would swamp H)
    fac, delta_w, ok = kkt.factor_with_correction(single, jnp.float32(delta_c), jnp.float32(0.0))
    dx, dy = kkt.solve(single, fac, delta_w, jnp.float32(delta_c), jnp.asarray(r_x, jnp.float32), jnp.asarray(r_c, jnp.float32))
    assert bool(ok) and fac.diag.dtype == dx.dtype == dy.dtype == jnp.float32
    M, keep = dense_kkt(system, float(delta_w))
    ref = np.linalg.solve(M, np.concatenate([r_x.reshape(-1)[keep], r_c.reshape(-1)]))
    np.testing.assert_allclose(np.asarray(dx, float).reshape(-1)[keep], ref[: keep.sum()], rtol=1e-3, atol=1e-3)
    np.testing.assert_allclose(np.asarray(dy, float).reshape(-1), ref[keep.sum() :], rtol=1e-3, atol=1e-3)


def test_wrong_inertia_is_detected(rng, split):
    """With delta_w = 0 an indefinite Hessian (on the null space of J) fails to factor."""
    system = random_system(rng, indefinite=True)
    d = system.d0 + 1e-9
    _, ok = kkt.factor(*kkt.condensed_blocks(system, d, jnp.asarray(0.0)))
    M, keep = dense_kkt(system, 0.0)
    eig = np.linalg.eigvalsh(M)
    wrong = np.sum(eig > 0) != keep.sum()
    assert wrong and not bool(ok)
    _took(split)


def test_inertia_correction_stops_below_delta_w_max(rng):
    """As Ipopt's, the correction makes no trial above ``delta_w_max``: it gives up (not ok)
    with the last value it tried, which is at most the cap."""
    system = random_system(rng, indefinite=True)
    _, needed, ok = kkt.factor_with_correction(system, jnp.asarray(1e-9), jnp.asarray(0.0))
    # from delta_w_last = 0 the trials are 1e-4, 1e-2, 1, ...: cap below the value that worked,
    # above the trial before it
    assert bool(ok) and float(needed) > 1e-2
    cap = 0.5 * float(needed)
    options = kkt.InertiaOptions(delta_w_max=cap)
    _, delta_w, ok = kkt.factor_with_correction(system, jnp.asarray(1e-9), jnp.asarray(0.0), options)
    assert not bool(ok)
    assert 0.0 < float(delta_w) <= cap
    assert float(delta_w) == pytest.approx(float(needed) / 100.0)


def _least_shift(system, delta_c):
    """The smallest delta_w (to 1e-12 relative) at which the condensed matrix factors."""
    d = system.d0 + delta_c

    def ok(dw):
        return bool(kkt.factor(*kkt.condensed_blocks(system, d, jnp.asarray(dw)))[1])

    lo, hi = 0.0, 1.0
    while not ok(hi):
        lo, hi = hi, 2.0 * hi
    while hi - lo > 1e-12 * hi:
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if ok(mid) else (mid, hi)
    return hi


def test_inertia_correction_from_a_remembered_value_grows_as_ipopt(rng):
    """From an earlier ``delta_w_last`` the trials are ``delta_w_last / 3`` grown by 8, and by
    100 once a trial is more than 1e5 times ``delta_w_last`` (Ipopt's PDPerturbationHandler).
    Growing by 8 throughout stopped at 2.86 times the least shift that works instead of 6.99."""
    system = random_system(rng, indefinite=True)
    delta_c = jnp.asarray(1e-9)
    least = _least_shift(system, delta_c)
    last = 1e-9 * least
    _, delta_w, ok = kkt.factor_with_correction(system, delta_c, jnp.asarray(last))
    # last/3 * 8^7 = 6.99e5 last > 1e5 last, then two factors of 100
    assert bool(ok)
    assert float(delta_w) == pytest.approx(last / 3.0 * 8.0**7 * 100.0**2, rel=1e-12)
    assert float(delta_w) / least == pytest.approx(6.99, abs=0.01)


def test_block_factor_equals_dense_cholesky(rng, split):
    K, n = 4, 3
    X = rng.normal(size=(K * n, K * n))
    band = np.zeros_like(X)
    for k in range(K):
        for j in (k - 1, k, k + 1):
            if 0 <= j < K:
                band[k * n : (k + 1) * n, j * n : (j + 1) * n] = 1.0
    M = (X @ X.T + K * n * np.eye(K * n)) * band
    diag = np.stack([M[k * n : (k + 1) * n, k * n : (k + 1) * n] for k in range(K)])
    upper = np.stack([M[k * n : (k + 1) * n, (k + 1) * n : (k + 2) * n] if k < K - 1 else np.zeros((n, n)) for k in range(K)])
    fac, ok = kkt.factor(jnp.asarray(diag), jnp.asarray(upper))
    assert bool(ok)
    L = np.linalg.cholesky(M)
    for k in range(K):
        # the diagonal blocks are kept transposed (BlockFactor), the blocks below as they are
        np.testing.assert_allclose(fac.diag[k].T, L[k * n : (k + 1) * n, k * n : (k + 1) * n], atol=1e-10)
        np.testing.assert_allclose(fac.sub[k], L[k * n : (k + 1) * n, (k - 1) * n : k * n] if k else 0.0, atol=1e-10)
    b = rng.normal(size=(K, n))
    np.testing.assert_allclose(np.asarray(kkt.solve_factored(fac, jnp.asarray(b))).reshape(-1), np.linalg.solve(M, b.reshape(-1)), atol=1e-10)
    _took(split)


def test_low_rank_hessian_term_equals_dense_solve(rng):
    """A limited-memory BFGS matrix in compact form, sigma I - W^T M^-1 W (built from the
    recursive BFGS updates it must equal), around the block factorization: the Woodbury solve
    equals a dense solve of the KKT system with that dense Hessian."""
    K, n, m, pairs, sig = 5, 4, 3, 3, 0.7
    system = random_system(rng, K, n, m)
    free = np.asarray(system.free)
    N = K * n
    S = rng.normal(size=(pairs, K, n)) * free
    Y = S + 0.3 * rng.normal(size=(pairs, K, n)) * free  # s^T y > 0 for these draws
    assert np.all(np.einsum("ikn,ikn->i", S, Y) > 0)
    # the dense BFGS matrix by the recursion from sigma I
    Bd = sig * np.eye(N)
    for s, y in zip(S.reshape(pairs, N), Y.reshape(pairs, N)):
        Bs = Bd @ s
        Bd = Bd - np.outer(Bs, Bs) / (s @ Bs) + np.outer(y, y) / (s @ y)
    SY = np.einsum("ikn,jkn->ij", S, Y)
    M = np.block([[sig * np.einsum("ikn,jkn->ij", S, S), np.tril(SY, -1)], [np.tril(SY, -1).T, -np.diag(np.diag(SY))]])
    low_rank = kkt.LowRank(W=jnp.asarray(np.concatenate([sig * S, Y])), M=jnp.asarray(M))
    W2 = np.asarray(low_rank.W).reshape(2 * pairs, N)
    np.testing.assert_allclose(sig * np.eye(N) - W2.T @ np.linalg.solve(M, W2), Bd, atol=1e-9)
    # block part: no element Hessian, sigma I on top of the barrier terms
    blocks = system._replace(H=jnp.zeros_like(system.H), sigma=system.sigma + sig)
    fac, delta_w, ok = kkt.factor_with_correction(blocks, jnp.asarray(1e-9), jnp.asarray(0.0))
    assert bool(ok) and float(delta_w) == 0.0
    r_x, r_c = rng.normal(size=(K, n)), rng.normal(size=(K, m))
    dx, dy = kkt.solve(blocks, fac, delta_w, jnp.asarray(1e-9), jnp.asarray(r_x), jnp.asarray(r_c), low_rank=low_rank)
    Md, keep = dense_kkt(blocks, 0.0)
    nf = keep.sum()
    Md[:nf, :nf] += (Bd - sig * np.eye(N))[np.ix_(keep, keep)]
    ref = np.linalg.solve(Md, np.concatenate([r_x.reshape(-1)[keep], r_c.reshape(-1)]))
    np.testing.assert_allclose(np.asarray(dx).reshape(-1)[keep], ref[:nf], rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(np.asarray(dy).reshape(-1), ref[nf:], rtol=1e-8, atol=1e-8)
    # several right-hand sides at once (their first solves share the sweeps with W's columns):
    # each equals the dense solve of its own
    R_x, R_c = rng.normal(size=(3, K, n)), rng.normal(size=(3, K, m))
    R_x[1], R_c[1] = r_x, r_c
    dxs, dys = kkt.solve(blocks, fac, delta_w, jnp.asarray(1e-9), jnp.asarray(R_x), jnp.asarray(R_c), low_rank=low_rank)
    assert dxs.shape == (3, K, n) and dys.shape == (3, K, m)
    for j in range(3):
        ref_j = np.linalg.solve(Md, np.concatenate([R_x[j].reshape(-1)[keep], R_c[j].reshape(-1)]))
        np.testing.assert_allclose(np.asarray(dxs[j]).reshape(-1)[keep], ref_j[:nf], rtol=1e-8, atol=1e-8)
        np.testing.assert_allclose(np.asarray(dys[j]).reshape(-1), ref_j[nf:], rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(dxs[1], dx, rtol=1e-12, atol=1e-14)


def sparse_system(rng, K=6, n=5, m=7, b_cols=None):
    """A random system whose A and B have a sparsity pattern (one dense row slot in A, sparse
    rows elsewhere, B on some rows only, and on the columns ``b_cols`` only if given), with
    that pattern; the element Hessians are None."""
    system = random_system(rng, K, n, m)
    mask_a = rng.uniform(size=(K, m, n)) < 0.3
    mask_a[:, 2, :] = True  # a dense row slot, as the dynamics rows are
    mask_a[:, np.arange(m), np.arange(m) % n] = True  # no empty row (the dense KKT stays regular)
    mask_b = (rng.uniform(size=(K, m, n)) < 0.3) & (np.arange(m)[None, :, None] < 4)
    if b_cols is not None:
        mask_b &= np.isin(np.arange(n), b_cols)[None, None, :]
        mask_b[:-1, 0, b_cols] = True  # every listed column is read
    mask_b[-1] = False
    knot, slot, col = np.nonzero(np.concatenate([mask_a, mask_b], axis=2))
    A = np.where(mask_a, np.asarray(system.A), 0.0)
    B = np.where(mask_b, rng.normal(size=(K, m, n)), 0.0)
    return system._replace(H=None, A=jnp.asarray(A), B=jnp.asarray(B)), (K, m, n, knot, slot, col)


@pytest.mark.parametrize("pair_cost", [0.0, 1e9])
def test_jacobian_pattern_products_equal_dense_ones(rng, pair_cost):
    """J x, J^T y and the condensed blocks J^T W J from the nonzeros equal the dense products,
    with every row as pairs (pair_cost 0) and with the dense slot by a dense product (1e9)."""
    system, args = sparse_system(rng)
    pattern = kkt.JacobianPattern(*args, pair_cost=pair_cost)
    assert (pattern.dense_slots.size > 0) == (pair_cost > 0)
    K, m, n = args[:3]
    A, B = system.A, system.B
    v = pattern.values(A, B)
    assert v.shape == (pattern.nnz,) and pattern.nnz == len(args[3])
    # the vector holds every nonzero once, and gives the blocks back
    for a, b in zip(pattern.dense(v), (A, B)):
        np.testing.assert_array_equal(a, b)
    x, y = jnp.asarray(rng.normal(size=(K, n))), jnp.asarray(rng.normal(size=(K, m)))
    np.testing.assert_allclose(pattern.apply_J(v, x), kkt._apply_J(A, B, x), atol=1e-12)
    np.testing.assert_allclose(pattern.apply_JT(v, y), kkt._apply_JT(A, B, y), atol=1e-12)
    d = jnp.asarray(rng.uniform(0.5, 2.0, size=(K, m)))
    dense = kkt.condensed_blocks(system, d, jnp.asarray(0.1))
    sparse = jax.jit(kkt.condensed_blocks)(system._replace(A=v, B=None, pattern=pattern), d, jnp.asarray(0.1))
    for a, b in zip(sparse, dense):
        np.testing.assert_allclose(a, b, atol=1e-12)


def test_kkt_solve_with_pattern_equals_dense_solve(rng):
    """The whole solve with a pattern (and no element Hessians) equals the dense KKT solve."""
    system, args = sparse_system(rng)
    pattern = kkt.JacobianPattern(*args)
    dense_system = system
    system = system._replace(A=pattern.values(system.A, system.B), B=None, pattern=pattern)
    K, m, n = args[:3]
    fac, delta_w, ok = jax.jit(kkt.factor_with_correction)(system, jnp.asarray(1e-9), jnp.asarray(0.0))
    assert bool(ok)
    r_x, r_c = rng.normal(size=(K, n)), rng.normal(size=(K, m))
    dx, dy = jax.jit(kkt.solve)(system, fac, delta_w, jnp.asarray(1e-9), jnp.asarray(r_x), jnp.asarray(r_c))
    M, keep = dense_kkt(dense_system._replace(H=jnp.zeros((K, 2 * n, 2 * n))), float(delta_w))
    ref = np.linalg.solve(M, np.concatenate([r_x.reshape(-1)[keep], r_c.reshape(-1)]))
    np.testing.assert_allclose(np.asarray(dx).reshape(-1)[keep], ref[: keep.sum()], rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(np.asarray(dy).reshape(-1), ref[keep.sum() :], rtol=1e-8, atol=1e-8)


def test_factor_on_the_coupled_columns_equals_the_whole_factor(rng):
    """When rows read only some columns of the next knot (the integration rows read its
    configuration and velocity, not its accelerations), the factor keeps only those rows of
    L[k+1, k]: the same factor as the whole one (whose other rows are zero), the same solves,
    and the whole KKT solve (with a limited-memory term) still equals the dense one."""
    K, m, n = 6, 7, 6
    cols = np.array([1, 3, 4])
    system, args = sparse_system(rng, K, n, m, b_cols=cols)
    pattern = kkt.JacobianPattern(*args)
    np.testing.assert_array_equal(pattern.coupled, cols)
    np.testing.assert_array_equal(kkt.coupled_columns(pattern, block_hessian=False), cols)
    assert kkt.coupled_columns(pattern, block_hessian=True) is None
    assert kkt.coupled_columns(None, block_hessian=False) is None
    d = jnp.asarray(rng.uniform(0.5, 2.0, size=(K, m)))
    diag, upper = kkt.condensed_blocks(system, d, jnp.asarray(0.1))
    np.testing.assert_array_equal(np.asarray(upper)[:, :, np.setdiff1d(np.arange(n), cols)], 0.0)
    # through the pattern, the off-diagonal blocks come as their coupled columns alone
    sys_p = system._replace(A=pattern.values(system.A, system.B), B=None, pattern=pattern)
    diag_p, upper_p = jax.jit(kkt.condensed_blocks)(sys_p, d, jnp.asarray(0.1))
    assert upper_p.shape == (K, n, cols.size)
    np.testing.assert_allclose(diag_p, diag, atol=1e-12)
    np.testing.assert_allclose(upper_p, np.asarray(upper)[:, :, cols], atol=1e-12)
    whole, ok = kkt.factor(diag, upper)
    part, ok_part = jax.jit(lambda a, b: kkt.factor(a, b, cols))(diag, upper)
    assert bool(ok) and bool(ok_part) and part.sub.shape == (K, cols.size, n)
    np.testing.assert_allclose(part.diag, whole.diag, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(part.sub, np.asarray(whole.sub)[:, cols], rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(np.asarray(whole.sub)[:, np.setdiff1d(np.arange(n), cols)], 0.0)
    # the columns alone (K, n, c) give the same factor as the whole blocks
    same, _ = kkt.factor(diag, upper[:, :, cols], cols)
    np.testing.assert_array_equal(same.sub, part.sub)
    b = jnp.asarray(rng.normal(size=(K, n)))
    np.testing.assert_allclose(kkt.solve_factored(part, b, cols), kkt.solve_factored(whole, b), rtol=1e-10, atol=1e-12)
    # the whole KKT solve through the pattern, with a limited-memory term, against the dense one
    fac, delta_w, ok = jax.jit(kkt.factor_with_correction)(sys_p, jnp.asarray(1e-9), jnp.asarray(0.0))
    assert bool(ok) and fac.sub.shape == (K, cols.size, n)
    W = jnp.asarray(rng.normal(size=(2, K, n)) * 0.1)
    low_rank = kkt.LowRank(W=W, M=jnp.asarray(np.diag([4.0, 5.0])))
    r_x, r_c = rng.normal(size=(K, n)), rng.normal(size=(K, m))
    dx, dy = jax.jit(kkt.solve)(sys_p, fac, delta_w, jnp.asarray(1e-9), jnp.asarray(r_x), jnp.asarray(r_c), low_rank=low_rank)
    Wd = np.asarray(W).reshape(2, -1)
    H_low = -Wd.T @ np.linalg.solve(np.asarray(low_rank.M), Wd)
    M, keep = dense_kkt(system._replace(H=jnp.zeros((K, 2 * n, 2 * n))), float(delta_w))
    M[: keep.sum(), : keep.sum()] += H_low[np.ix_(keep, keep)]
    ref = np.linalg.solve(M, np.concatenate([r_x.reshape(-1)[keep], r_c.reshape(-1)]))
    np.testing.assert_allclose(np.asarray(dx).reshape(-1)[keep], ref[: keep.sum()], rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(np.asarray(dy).reshape(-1), ref[keep.sum() :], rtol=1e-8, atol=1e-8)


def test_jacobian_pattern_index_finds_each_nonzero(rng):
    """`index` maps (knot, slot, column) keys to their place in the vector of nonzeros, and
    refuses a key outside the pattern."""
    system, args = sparse_system(rng)
    pattern = kkt.JacobianPattern(*args)
    K, m, n, knot, slot, col = args
    keys = (knot * m + slot) * (2 * n) + col
    shuffled = rng.permutation(keys.size)
    pos = pattern.index(keys[shuffled])
    v = np.asarray(pattern.values(system.A, system.B))
    dense = np.concatenate([np.asarray(system.A), np.asarray(system.B)], axis=2)
    np.testing.assert_array_equal(v[pos], dense[knot, slot, col][shuffled])
    missing = np.setdiff1d(np.arange(K * m * 2 * n), keys)[:1]
    with pytest.raises(ValueError, match="outside the pattern"):
        pattern.index(missing)


def test_jacobian_pattern_rejects_a_last_knot_reading_beyond():
    with pytest.raises(ValueError, match="last knot"):
        kkt.JacobianPattern(2, 1, 1, np.array([1]), np.array([0]), np.array([1]))


def test_adaptive_refinement_removes_delta_c_and_stops_early(rng):
    """Iterative refinement against the system without ``delta_c``: a large ``delta_c`` leaves
    the unrefined solution off the dense solve, the adaptive rule refines it to the dense
    solution, and a ratio already met (or ``min_refine_steps``) sets the number of steps."""
    system = random_system(rng)
    K, n = system.sigma.shape
    m = system.A.shape[1]
    r_x, r_c = jnp.asarray(rng.normal(size=(K, n))), jnp.asarray(rng.normal(size=(K, m)))
    delta_c = jnp.asarray(1e-3)
    fac, delta_w, ok = kkt.factor_with_correction(system, delta_c, jnp.asarray(0.0))
    assert bool(ok) and float(delta_w) == 0.0
    M, keep = dense_kkt(system, 0.0)
    ref = np.linalg.solve(M, np.concatenate([np.asarray(r_x).reshape(-1)[keep], np.asarray(r_c).reshape(-1)]))
    solve = jax.jit(kkt.solve, static_argnames=("refine_steps", "min_refine_steps", "residual_ratio_max"))

    def err(steps, **kw):
        dx, dy = solve(system, fac, delta_w, delta_c, r_x, r_c, refine_steps=steps, **kw)
        return np.max(np.abs(np.concatenate([np.asarray(dx).reshape(-1)[keep], np.asarray(dy).reshape(-1)]) - ref)), (dx, dy)

    unrefined, sol0 = err(0)
    assert unrefined > 1e-6
    refined, _ = err(60, residual_ratio_max=1e-10)
    assert refined < 1e-8 * max(1.0, np.max(np.abs(ref)))
    # a ratio already met: no step at all, the same numbers as refine_steps=0
    _, none = err(60, residual_ratio_max=1e3)
    np.testing.assert_array_equal(np.asarray(none[0]), np.asarray(sol0[0]))
    # min_refine_steps forces one step: the same numbers as refine_steps=1 without the rule
    _, one = err(60, residual_ratio_max=1e3, min_refine_steps=1)
    _, fixed_one = err(1, residual_ratio_max=0.0)
    np.testing.assert_array_equal(np.asarray(one[1]), np.asarray(fixed_one[1]))
    assert not np.array_equal(np.asarray(one[1]), np.asarray(sol0[1]))


@pytest.mark.parametrize("with_cols", [False, True])
def test_factor_finishes_the_blocks_as_condensed_blocks_does(rng, with_cols):
    """`factor` given the product blocks with ``shift`` and ``keep`` (what
    `factor_with_correction` hands it) is the factor of `condensed_blocks`' matrix: the shift
    on the diagonal, the fixed variables' rows and columns the identity's (the system has fixed
    variables at the first and last knot), the whole blocks and the coupled columns."""
    K, m, n = 6, 7, 6
    cols = np.array([1, 3, 4])
    system, args = sparse_system(rng, K, n, m, b_cols=cols)
    pattern = kkt.JacobianPattern(*args)
    sys_p = system._replace(A=pattern.values(system.A, system.B), B=None, pattern=pattern)
    assert not bool(np.all(system.free))
    d = jnp.asarray(rng.uniform(0.5, 2.0, size=(K, m)))
    dw = jnp.asarray(0.3)
    diag, upper = kkt.condensed_blocks(sys_p, d, dw)
    raw_diag, raw_upper = kkt._product_blocks(sys_p, d)
    coupled = cols if with_cols else None
    if not with_cols:
        upper = jnp.zeros((K, n, n)).at[:, :, cols].set(upper)
        raw_upper = jnp.zeros((K, n, n)).at[:, :, cols].set(raw_upper)
    ref, ok_ref = kkt.factor(diag, upper, coupled)
    keep = system.free.astype(float)
    got, ok = jax.jit(lambda a, b, s, f: kkt.factor(a, b, coupled, shift=s, keep=f))(raw_diag, raw_upper, system.sigma + dw, keep)
    assert bool(ok) and bool(ok_ref)
    np.testing.assert_allclose(got.diag, ref.diag, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(got.sub, ref.sub, rtol=1e-12, atol=1e-12)
    # a fixed variable's pivot is 1 and its row of the factor is the identity's
    Lt = np.asarray(got.diag)
    np.testing.assert_array_equal(Lt[0, 0], np.eye(n)[0])
    # the blocks differ from the unfinished ones (the check can fail)
    raw, _ = kkt.factor(raw_diag + jax.vmap(jnp.diag)(system.sigma + dw), raw_upper, coupled)
    assert not np.allclose(raw.diag, ref.diag)


@pytest.mark.parametrize("n", [7, 11])
def test_cholesky_in_halves_equals_lapack(rng, monkeypatch, n):
    """`kkt._cholesky` and `kkt._solve_lower_t` in halves (two and three levels here) equal the
    one-call results, zeros above the diagonal included, and a matrix that is not positive
    definite, in its leading half or only after it, gives NaN pivots as LAPACK's does."""
    monkeypatch.setattr(kkt, "SPLIT_ABOVE", 3)
    if not kkt._split(n):
        pytest.skip("blocks are factored in halves on the CPU only; here both sides would be LAPACK's")
    X = rng.normal(size=(n, n))
    A = X @ X.T + n * np.eye(n)
    L = np.asarray(kkt._cholesky(jnp.asarray(A)))
    np.testing.assert_allclose(L, np.linalg.cholesky(A), rtol=1e-12, atol=1e-12)
    B = rng.normal(size=(5, n))
    np.testing.assert_allclose(np.asarray(kkt._solve_lower_t(jnp.asarray(L), jnp.asarray(B))) @ L.T, B, atol=1e-10)
    for bad in (0, n - 1):  # the leading half fails, or only the trailing one
        C = A.copy()
        C[bad, bad] = -1.0
        pivots = np.diagonal(np.asarray(kkt._cholesky(jnp.asarray(C))))
        assert not np.all(np.isfinite(pivots) & (pivots > 0.0))


def test_the_slack_rows_block_is_perturbed_with_the_variables(rng):
    """Ipopt's inertia correction perturbs the slacks' block, Sigma_s + delta_w I, with the
    variables' (Wächter & Biegler 2006, eq. 13); eliminated, a slack row's (2, 2) entry is then
    1 / (1/d0 + delta_w). Only the variables' block was: the step differed from Ipopt's wherever
    delta_w > 0 (the exact Hessian's negative curvature). With ``slack`` rows the factorization
    and the solve are those of the perturbed system: equal to its dense solve, with its inertia."""
    system = random_system(rng, indefinite=True)
    K, n = system.sigma.shape
    m = system.A.shape[1]
    slack = np.asarray(system.d0) > 0.0
    slack[1, 0] = False  # the inactive row is no slack's
    system = system._replace(slack=jnp.asarray(slack))
    fac, delta_w, ok = kkt.factor_with_correction(system, jnp.asarray(1e-9), jnp.asarray(0.0))
    assert bool(ok) and float(delta_w) > 0.0
    d0w = np.where(slack, np.asarray(system.d0) / (1.0 + float(delta_w) * np.asarray(system.d0)), np.asarray(system.d0))
    np.testing.assert_allclose(np.asarray(kkt.perturbed_d0(system, delta_w)), d0w)
    M, keep = dense_kkt(system._replace(d0=jnp.asarray(d0w)), float(delta_w))
    eig = np.linalg.eigvalsh(M)
    assert np.sum(eig > 0) == keep.sum() and np.sum(eig < 0) == K * m
    r_x, r_c = rng.normal(size=(K, n)), rng.normal(size=(K, m))
    dx, dy = kkt.solve(system, fac, delta_w, jnp.asarray(1e-9), jnp.asarray(r_x), jnp.asarray(r_c))
    ref = np.linalg.solve(M, np.concatenate([r_x.reshape(-1)[keep], r_c.reshape(-1)]))
    np.testing.assert_allclose(np.asarray(dx).reshape(-1)[keep], ref[: keep.sum()], rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(np.asarray(dy).reshape(-1), ref[keep.sum() :], rtol=1e-8, atol=1e-8)


def test_free_columns_select_the_nonzeros_of_free_variables(rng):
    """`JacobianPattern.free_columns`: the nonzeros kept are exactly those in columns of free
    variables, of knot k in A[k] and of knot k + 1 in B[k] (what `jtraj.solvers.ipm` removes
    with ``jnp.where``, so that a NaN in a fixed variable's column cannot reach the step)."""
    system, args = sparse_system(rng)
    pattern = kkt.JacobianPattern(*args)
    K = args[0]
    free = rng.uniform(size=system.sigma.shape) < 0.6
    free_next = np.concatenate([free[1:], np.zeros_like(free[:1])])
    v = pattern.values(system.A, system.B)
    A, B = pattern.dense(jnp.where(pattern.free_columns(jnp.asarray(free)), v, 0.0))
    np.testing.assert_array_equal(A, np.asarray(system.A) * free[:, None, :])
    np.testing.assert_array_equal(B, np.asarray(system.B) * free_next[:, None, :])
    assert K > 1 and 0 < int(pattern.free_columns(jnp.asarray(free)).sum()) < pattern.nnz


def test_a_nan_in_the_last_knots_b_block_is_ignored(rng):
    """B[K-1] is documented as ignored, but it was masked by a product with 0: a NaN there made
    the step NaN while the factorization reported success."""
    system = random_system(rng)
    K, n = system.sigma.shape
    m = system.A.shape[1]
    r_x, r_c = jnp.asarray(rng.normal(size=(K, n))), jnp.asarray(rng.normal(size=(K, m)))
    solved = []
    for B in (system.B, system.B.at[-1].set(jnp.nan)):
        s = system._replace(B=B)
        fac, delta_w, ok = kkt.factor_with_correction(s, jnp.asarray(1e-9), jnp.asarray(0.0))
        assert bool(ok)
        solved.append(kkt.solve(s, fac, delta_w, jnp.asarray(1e-9), r_x, r_c))
    for a, b in zip(*solved):
        assert np.all(np.isfinite(b))
        np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize(("indefinite", "with_low_rank"), [(False, False), (True, False), (False, True), (True, True)])
def test_solve_keeping_delta_c_equals_the_regularized_dense_solve(rng, indefinite, with_low_rank):
    """``remove_delta_c=False`` (the interior point's default, Ipopt's treatment of a dependent
    Jacobian) solves the system with ``-(D0 + delta_c)`` in its (2, 2) block, with slack rows,
    a ``delta_w`` and a low-rank Hessian term."""
    system = random_system(rng, indefinite=indefinite)
    K, n = system.sigma.shape
    m = system.A.shape[1]
    slack = np.asarray(system.d0) > 0
    slack[1, 0] = False  # the inactive row
    system = system._replace(slack=jnp.asarray(slack))
    delta_c = 1e-2  # large enough that keeping or removing it shows
    fac, delta_w, ok = kkt.factor_with_correction(system, jnp.asarray(delta_c), jnp.asarray(0.0))
    assert bool(ok) and (float(delta_w) > 0.0) == indefinite
    low_rank = None
    if with_low_rank:
        W = rng.normal(size=(2, K, n)) * 0.3 * np.asarray(system.free)
        low_rank = kkt.LowRank(W=jnp.asarray(W), M=jnp.asarray(np.diag([5.0, 7.0])))
    r_x, r_c = rng.normal(size=(K, n)), rng.normal(size=(K, m))
    dx, dy = kkt.solve(system, fac, delta_w, jnp.asarray(delta_c), jnp.asarray(r_x), jnp.asarray(r_c), remove_delta_c=False, low_rank=low_rank)
    d = np.asarray(kkt.perturbed_d0(system, delta_w)) + delta_c
    M, keep = dense_kkt(system._replace(d0=jnp.asarray(d)), float(delta_w))
    nf = int(keep.sum())
    if with_low_rank:
        Wd = W.reshape(2, -1)
        M[:nf, :nf] -= (Wd.T @ np.linalg.solve(np.diag([5.0, 7.0]), Wd))[np.ix_(keep, keep)]
    ref = np.linalg.solve(M, np.concatenate([r_x.reshape(-1)[keep], r_c.reshape(-1)]))
    np.testing.assert_allclose(np.asarray(dx).reshape(-1)[keep], ref[:nf], rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(np.asarray(dy).reshape(-1), ref[nf:], rtol=1e-8, atol=1e-8)
    # the system without delta_c has another solution: the test can tell them apart
    M0, _ = dense_kkt(system._replace(d0=jnp.asarray(d - delta_c)), float(delta_w))
    if with_low_rank:
        M0[:nf, :nf] -= (Wd.T @ np.linalg.solve(np.diag([5.0, 7.0]), Wd))[np.ix_(keep, keep)]
    other = np.linalg.solve(M0, np.concatenate([r_x.reshape(-1)[keep], r_c.reshape(-1)]))
    assert np.max(np.abs(other - ref)) > 1e-4
