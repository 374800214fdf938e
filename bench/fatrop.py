"""FATROP (a Riccati interior point for optimal control, through CasADi 3.8.2's ``fatrop``
plugin) on jtraj's NLP of a task, beside jtraj's Ipopt backend (and, with ``--jtraj``,
jtraj's own interior point) in the same run: the like-for-like reference of what a
structure-exploiting interior point achieves on these problems.

    python bench/fatrop.py [big_jump sideflip ...] [--param se3] [--jtraj] [--out DIR]

Needs ``pip install -e ".[bench]"`` (casadi 3.8.2; not a dependency of jtraj itself).

The problem handed to FATROP
----------------------------
FATROP solves ``min sum_k l_k(x_k, u_k)`` subject to the gap-closing rows
``x_{k+1} - F_k(x_k, u_k) = 0`` (an identity in x_{k+1}, nothing else of stage k+1) and
stage constraints and bounds that read ``(x_k, u_k)`` only. CasADi's interface
(``structure_detection="manual"`` with N, nx, nu, ng) wants the variables ordered
``[x_0 u_0 x_1 u_1 ... x_N u_N]`` and the rows ordered per stage k as nx[k+1] gap-closing rows
then the ng[k] stage rows; it checks that the Jacobian's sparsity fits that block pattern and
that the gap rows' coefficients of x_{k+1} are exactly +1, and it keeps only the stage-diagonal
blocks of the Lagrangian's Hessian. jtraj's compact NLP (z_k = (q, v, a, f), state (q, v),
controls (a, f)) does not have that form as it is, for three kinds of rows (`stage_form`):

- ``integration`` (semi-implicit Euler) reads q_{k+1} through the chart difference
  ``difference(integrate(q_b, v_{k+1}, h), q_{k+1})`` and v_{k+1} in the joints' position
  rows: not an identity in x_{k+1}. Replaced by ``x_{k+1} - step(x_k, u_k)`` with the NLP's own
  `jtraj.nlp.KnotStructure.step`, whose rows vanish exactly where the integration rows vanish
  (the structure's contract). No reordering can do this: the coefficient block of x_{k+1} is
  not a permutation.
- rows that read the *state* of knot k+1 (``stationary``: the feet's x, y kept in contact) are
  written through the step, ``g(z_k, step(x_k, u_k))``: the same rows wherever the dynamics
  hold, so the same feasible set.
- rows that read a *control* of knot k+1 (``force_rate``: f_{k+1} - f_k) cannot go through the
  step; they move to stage k+1, where the values of knot k they read are held by extra states
  ("memory", p_{k+1} = f_k, gap rows with identity in p_{k+1}; p_0 fixed to 0 by bounds).
  This adds 3P variables and 3P equality rows per knot.

Costs and every other row are jtraj's own functions of one knot, unchanged. The result is a
new `jtraj.nlp.KnotNLP` over the stage variables (layout q, v, memory, a, f), whose jitted
objective, gradient, constraints, sparse Jacobian and exact Lagrangian Hessian (all from JAX)
are handed to FATROP through a `casadi.Callback` oracle whose ``get_factory`` returns
callbacks for exactly the functions the plugin asks for (``nlp_f``, ``nlp_g``,
``nlp_grad_f``, ``nlp_jac_g``, ``nlp_hess_l``, ``nlp_grad``): CasADi differentiates nothing.
Cost and maximum violation are reported for the original NLP at the solution mapped back
(the memory columns dropped), with ``nlp.violation``, every original row included.

FATROP needs linearly independent equality rows, which the NLP does not have (Ipopt absorbs
the dependence with its ``delta_c`` perturbation, jtraj's interior point likewise):
`drop_dependent` leaves out the rows that a pivoted QR at a probe point finds dependent on the
others (its docstring says which they are and why they are implied). With quaternion charts
the gap rows fix all nq base coordinates and the chart rows at knots >= 1 become dependent
too; only ``--param se3`` (the default, minimal coordinates) has been run.

Settings: FATROP's ``tol`` 1e-3 (as Ipopt's ``tol`` in the study's settings; FATROP's own
convergence test, an Ipopt-like one) and the task's ``max_iter``; exact Hessian (FATROP has
no quasi-Newton option) against Ipopt's L-BFGS default (jtraj's solve defaults). Timing: the
stage NLP's JAX functions are compiled and each called once (and the CasADi solver object
built) before the clock starts; ``time`` is the wall time of the solve call, ``JAX eval`` the
part spent in the callbacks' bodies (JAX and the host conversions: reordering rows and values,
building the ``casadi.DM``), ``FATROP own`` the difference.
``--out DIR`` writes ``DIR/fatrop.json`` (raw records), ``DIR/fatrop.md`` (the table) and
``DIR/provenance.json``, again after each task, with ``"complete": false`` until the last.

State (measured on the 2-core CPU, ``python bench/fatrop.py sideflip big_jump --jtraj --out
results/fatrop``, 2026-12-07, the run `results/fatrop/` holds): on the Go2 sideflip FATROP
converges in 19 iterations (Ipopt 41, jtraj's solver 39) with 0.87 s of its own time, plus
10.3 s in the callbacks (JAX's exact Hessians, per knot, are slow); on Talos' big_jump it does
not converge (return code 1 after 160 iterations, violation 0.6; Ipopt 11 iterations, jtraj 11). There, from the first iteration, its inertia
correction adds delta_w of 1e2 to 1e3 each iteration, with the exact Hessian and with its stage
blocks made positive definite (``--hessian clip``) alike, and also with the nearly dependent
rows left out (``--rtol 1e-5``, 494 rows); a small Go2 hop behaved so until the exactly
dependent rows were left out (then 7 iterations). The likely cause, not proven, is the four
corner points per Talos foot: the rigid foot makes their rows dependent and nearly dependent
(the presolve's QR pivots spread from 1e-12 to 1e-4), which Ipopt's and jtraj's delta_c absorb
while FATROP's Riccati factorization apparently reports indefiniteness, so only delta_w grows.
"""

from __future__ import annotations

import argparse
import dataclasses
import io
import os
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jtraj.nlp import ConstraintGroup, Dep, KnotNLP, Layout
from jtraj.provenance import write_results
from jtraj.solver import prepare, solve

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/_args.py, also when the tests load this file from its path
from _args import add_out, add_param, add_tasks, results_record  # noqa: E402

#: The NLP's group whose rows encode ``x_{k+1} = step(x_k, u_k)`` (jtraj.transcription).
DYNAMICS = "integration"
#: Name of the gap-closing group and of the memory slot of the stage NLP.
GAP, MEMORY = "gap", "memory"


@dataclasses.dataclass
class StageForm:
    """jtraj's NLP rewritten in FATROP's stage form (see the module docstring).

    Attributes:
        nlp: the stage NLP: layout (state slots, memory, control slots) at every knot.
        source: the original NLP.
        columns: (nz,) column of each original column of z_k in the stage layout.
        memory: slots of knot k held in the memory of knot k+1, in order.
        perm: FATROP's rows, in stage order: FATROP's row i is ``nlp``'s row ``perm[i]``
            (all rows of ``nlp``, less those `drop_dependent` left out).
        row_knot: (nlp.m,) stage of each row of ``nlp``.
        nx, nu, ng: per stage (length N + 1) sizes; ``N`` = knots - 1.
        dropped: rows left out per group (`drop_dependent`).
    """

    nlp: KnotNLP
    source: KnotNLP
    columns: np.ndarray
    memory: tuple[str, ...]
    perm: np.ndarray
    nx: list[int]
    nu: list[int]
    ng: list[int]
    row_knot: np.ndarray
    dropped: dict[str, int]

    @property
    def N(self) -> int:
        return self.nlp.n_knots - 1

    def lift(self, x: np.ndarray) -> np.ndarray:
        """Original variables (n,) -> stage variables: memory p_{k+1} = z_k[memory], p_0 = 0."""
        src, K = self.source, self.nlp.n_knots
        Z = np.asarray(x, float).reshape(K, src.nz)
        out = np.zeros((K, self.nlp.nz))
        out[:, self.columns] = Z
        if self.memory:
            held = np.concatenate([Z[:, src.layout.slice(s)] for s in self.memory], axis=1)
            out[1:, self.nlp.layout.slice(MEMORY)] = held[:-1]
        return out.reshape(-1)

    def drop(self, x: np.ndarray) -> np.ndarray:
        """Stage variables -> original variables (n,)."""
        return np.asarray(x, float).reshape(self.nlp.n_knots, self.nlp.nz)[:, self.columns].reshape(-1)


def _joiner(names: Sequence[str], layout: Layout) -> tuple[Callable, Callable]:
    """(join parts dict -> vector, split vector -> parts dict) for ``names`` of ``layout``."""
    sizes = [layout.size(s) for s in names]
    cuts = np.cumsum(sizes)[:-1]

    def join(parts: dict) -> jnp.ndarray:
        return jnp.concatenate([parts[s] for s in names]) if names else jnp.zeros(0)

    def split(vec: jnp.ndarray) -> dict:
        return dict(zip(names, jnp.split(vec, cuts)))

    return join, split


def stage_form(nlp: KnotNLP) -> StageForm:
    """FATROP's stage form of ``nlp`` (needs ``nlp.structure``: the variables with
    accelerations, compact or paper). Classifies every group as in the module docstring."""
    st = nlp.structure
    if st is None:
        raise ValueError("FATROP needs the explicit step x' = F(x, u) (nlp.structure): use variables with accelerations (compact or paper), not lean")
    layout, K = nlp.layout, nlp.n_knots
    state, control = tuple(st.state), tuple(st.control)
    if not any(g.name == DYNAMICS for g in nlp.groups):
        raise ValueError(f"no {DYNAMICS!r} group: the rows that x' = step(x, u) replaces are unknown")
    for c in nlp.costs:
        if any(d.offset for d in c.deps):
            raise ValueError(f"cost {c.name!r} reads knot k+1: FATROP's stage costs read one knot (write it through the step or on one knot)")
    path, through, remembered = [], [], []
    for g in nlp.groups:
        ahead = [d.slot for d in g.deps if d.offset == 1]
        if g.name == DYNAMICS:
            continue
        if not ahead:
            path.append(g)
        elif set(ahead) <= set(state):
            through.append(g)
        else:
            remembered.append(g)
    memory = tuple(dict.fromkeys(d.slot for g in remembered for d in g.deps if d.offset == 0))
    n_mem = sum(layout.size(s) for s in memory)
    slots = [(s, layout.size(s)) for s in state] + ([(MEMORY, n_mem)] if n_mem else []) + [(s, layout.size(s)) for s in control]
    aug = Layout(tuple(slots))
    big_state = state + ((MEMORY,) if n_mem else ())
    join_x, split_x = _joiner(state, aug)
    join_u, _ = _joiner(control, aug)
    join_mem, split_mem = _joiner(memory, layout)
    now_names = state + control

    def step(now: dict, theta: Any) -> dict:
        return split_x(st.step(join_x(now), join_u(now), theta))

    groups = []
    N = K - 1

    def gap(theta, data, *parts):
        now = dict(zip(big_state + control, parts[: len(big_state) + len(control)]))
        nxt = dict(zip(big_state, parts[len(big_state) + len(control) :]))
        rows = [join_x(nxt) - join_x(step(now, theta))]
        if n_mem:
            rows.append(nxt[MEMORY] - join_mem(now))
        return jnp.concatenate(rows)

    nX = aug.columns(big_state).size
    zeros = np.zeros((N, nX))
    groups.append(
        ConstraintGroup(GAP, tuple(Dep(s) for s in big_state + control) + tuple(Dep(s, 1) for s in big_state), gap, np.arange(N), zeros, zeros, np.ones((N, nX), bool))
    )
    groups += path

    def via_step(g: ConstraintGroup) -> ConstraintGroup:
        def fn(theta, data, *parts):
            now = dict(zip(now_names, parts))
            nxt = step(now, theta)
            return g.fn(theta, data, *[(nxt if d.offset else now)[d.slot] for d in g.deps])

        return ConstraintGroup(g.name, tuple(Dep(s) for s in now_names), fn, g.knots, g.lower, g.upper, g.active, g.data)

    def held(g: ConstraintGroup) -> ConstraintGroup:
        ahead = tuple(Dep(d.slot) for d in g.deps if d.offset == 1)

        def fn(theta, data, mem, *parts):
            before, it = split_mem(mem), iter(parts)
            return g.fn(theta, data, *[next(it) if d.offset else before[d.slot] for d in g.deps])

        return ConstraintGroup(g.name, (Dep(MEMORY),) + ahead, fn, g.knots + 1, g.lower, g.upper, g.active, g.data)

    groups += [via_step(g) for g in through] + [held(g) for g in remembered]
    columns = np.zeros(layout.nz, np.int64)  # original column j of z_k -> its column in the stage layout
    for s, size in layout.slots:
        columns[layout.slice(s)] = aug.offset(s) + np.arange(size)

    def widen(b: jnp.ndarray, fill: float) -> jnp.ndarray:
        out = jnp.full((K, aug.nz), fill).at[:, columns].set(b.reshape(K, layout.nz))
        return out.at[0, aug.slice(MEMORY)].set(0.0) if n_mem else out  # p_0 is unused: fixed

    stage = KnotNLP(
        aug, K, nlp.costs, groups,
        lambda theta: widen(nlp.bounds(theta)[0], -np.inf), lambda theta: widen(nlp.bounds(theta)[1], np.inf),
        theta=nlp.theta,
    )
    # rows per stage: the gap rows of knot k, then the other rows of knot k
    row_knot = np.concatenate([g.knots[stage.row_index[gi] // g.n_rows] for gi, g in enumerate(stage.groups)])
    is_gap = stage.row_group == GAP
    perm = np.lexsort((np.arange(stage.m), ~is_gap, row_knot))
    ng = np.bincount(row_knot[~is_gap], minlength=K).tolist()
    gaps = np.bincount(row_knot[is_gap], minlength=K)
    if not (np.all(gaps[:-1] == nX) and gaps[-1] == 0):
        raise AssertionError(f"gap rows per knot {gaps.tolist()}, expected {nX} at knots 0..N-1")
    nu = aug.columns(control).size
    return StageForm(stage, nlp, columns, memory, perm, [nX] * K, [nu] * K, ng, row_knot, {})


def drop_dependent(form: StageForm, x0: np.ndarray, theta: Any, seed: int = 0, rtol: float = 1e-7) -> StageForm:
    """``form`` without the equality rows that depend linearly on the others (and on the
    variables fixed by equal bounds), found at a probe point: the warm start ``x0`` (original
    variables) lifted, plus N(0, 0.01^2) noise on the free variables (so that no dependence is
    an accident of the symmetric standing pose).

    Why: the compact NLP has linearly dependent equality rows, and FATROP, unlike Ipopt (whose
    KKT perturbation ``delta_c`` absorbs them), cannot take them: its stage-wise elimination
    fails and the inertia correction then regularizes every iteration (measured on a small Go2
    hop: no convergence in 100 iterations; with the dependent rows left out, 7 iterations, as
    Ipopt with the exact Hessian). They are (i) the contact height and the stationarity of the
    feet at knot N-1: v_N = 0 and q_N are fixed by bounds, so the step gives q_{N-1} = q_N
    (semi-implicit Euler: q_N = q_{N-1} + h v_N), whose feet are on the terrain; (ii) with
    several contact points on one rigid foot (Talos' four corners), the points' heights and
    horizontal positions beyond the foot's six degrees of freedom (jtraj's own interior point
    regularizes these too, see jtraj.solvers.ipm); (iii) rows reading only fixed variables.
    Each is implied by the kept rows, (i) and (iii) exactly, (ii) locally, which is why the
    cost and violation reported are those of the original NLP with every row.

    Method: the gap rows (which FATROP needs, all kept) span a subspace; the other equality
    rows, restricted to the free variables, projected off it and scaled to unit norm, go
    through a column-pivoted QR; rows beyond its numerical rank (relative ``rtol``) are left out.
    Dense linear algebra: seconds for the Go2, about a minute for Talos (not in the solve time).
    """
    import scipy.linalg

    nlp = form.nlp
    xl, xu, gl, gu = (np.asarray(b, float) for b in nlp.bounds(theta))
    z = form.lift(x0)
    free = xl < xu
    z[free] += 1e-2 * np.random.default_rng(seed).standard_normal(int(free.sum()))
    z = np.clip(z, xl, xu)
    eq = form.perm[gl[form.perm] == gu[form.perm]]
    gap = eq[nlp.row_group[eq] == GAP]
    other = eq[nlp.row_group[eq] != GAP]
    J = nlp.dense_jacobian(z, theta)[:, free]
    Q, R = scipy.linalg.qr(J[gap].T, mode="economic")
    d = np.abs(np.diag(R))
    if d.min() <= rtol * d.max():
        raise ValueError(f"the gap rows are linearly dependent at the probe point (smallest |R_ii| {d.min():.1e}): FATROP cannot take this problem")
    B = J[other].T
    B -= Q @ (Q.T @ B)
    scale = np.linalg.norm(J[other], axis=1)
    B /= np.where(scale > 0, scale, 1.0)
    _, R2, piv = scipy.linalg.qr(B, mode="economic", pivoting=True)
    d2 = np.abs(np.diag(R2))
    rank = int(np.sum(d2 > rtol))
    drop = other[piv[rank:]]
    keep = np.ones(nlp.m, bool)
    keep[drop] = False
    perm = form.perm[keep[form.perm]]
    non_gap = perm[nlp.row_group[perm] != GAP]
    ng = np.bincount(form.row_knot[non_gap], minlength=nlp.n_knots).tolist()
    names, counts = np.unique(nlp.row_group[drop], return_counts=True)
    return dataclasses.replace(form, perm=perm, ng=ng, dropped=dict(zip(names.tolist(), counts.tolist())))


# ---------------------------------------------------------------------------- CasADi side
def casadi_block_diagonal(K: int, nz: int):
    """CasADi sparsity of K dense (nz, nz) blocks on the diagonal."""
    import casadi

    return casadi.diagcat(*[casadi.Sparsity.dense(nz, nz)] * K)


#: Hessians handed to FATROP: the exact Lagrangian Hessian, or its stage blocks with the
#: eigenvalues clipped from below (positive definite).
HESSIANS = ("exact", "clip")


def _ccs(n_rows: int, n_cols: int, rows: np.ndarray, cols: np.ndarray):
    """CasADi sparsity of COO (rows, cols) without duplicates, and the COO -> CCS order."""
    import casadi

    order = np.lexsort((rows, cols))
    colind = np.concatenate([[0], np.cumsum(np.bincount(cols, minlength=n_cols))])
    return casadi.Sparsity(n_rows, n_cols, colind.tolist(), rows[order].tolist()), order


class _Evaluator:
    """The stage NLP's functions at a fixed theta, in FATROP's row order, on numpy vectors,
    with the calls of each counted; ``seconds``: the time spent in the callbacks that call them
    (`_callback_class`'s oracle times their whole bodies)."""

    def __init__(self, form: StageForm, theta: Any, hessian: str = "exact", margin: float = 1e-6):
        if hessian not in HESSIANS:
            raise ValueError(f"hessian={hessian!r}: expected one of {list(HESSIANS)}")
        self.form, self.theta, self.hessian = form, theta, hessian
        nlp = form.nlp
        nlp.build_hessian()
        self.n = nlp.n
        self.sel = form.perm
        self.m = self.sel.size
        pos = np.full(nlp.m, -1)
        pos[self.sel] = np.arange(self.m)
        kept = np.flatnonzero(pos[nlp.jac_rows] >= 0)  # Jacobian entries of FATROP's rows
        self.jac_sp, order = _ccs(self.m, nlp.n, pos[nlp.jac_rows[kept]], nlp.jac_cols[kept])
        self.jac_order = kept[order]
        self.jac_rows, self.jac_cols = nlp.jac_rows, nlp.jac_cols
        r, c = nlp.hess_rows, nlp.hess_cols
        off = r != c
        hr, hc = np.concatenate([r, c[off]]), np.concatenate([c, r[off]])
        self.hess_sp, self.hess_order = _ccs(nlp.n, nlp.n, hr, hc)
        self.hess_off = off
        if hessian == "clip":
            # the Lagrangian's Hessian is block diagonal by stage (every term reads one knot):
            # each (nz, nz) block's eigenvalues are clipped from below at ``margin``
            K, nz = nlp.n_knots, nlp.nz
            k, i, j = r // nz, r % nz, c % nz
            if np.any(c // nz != k):
                raise AssertionError("the stage NLP's Hessian couples two knots: FATROP would drop those entries")
            self.hess_sp = casadi_block_diagonal(K, nz)
            full = nlp.hessian

            @jax.jit
            def clipped(x, lam, obj_factor, theta):
                low = full(x, lam, obj_factor, theta)
                B = jnp.zeros((K, nz, nz)).at[k, i, j].add(low)
                B = B + jnp.swapaxes(B, 1, 2) - B * jnp.eye(nz)  # the lower triangle mirrored
                w, V = jnp.linalg.eigh(B)
                return jnp.einsum("kij,kj,klj->kil", V, jnp.maximum(w, margin), V).reshape(-1)

            self._clipped = clipped
        self.seconds = 0.0
        self.counts: dict[str, int] = {}
        self.errors: list[str] = []

    def _counted(self, key: str, fn: Callable, *args) -> np.ndarray:
        """``fn(*args)`` as numpy, counted under ``key`` (timed by the callback it runs in)."""
        self.counts[key] = self.counts.get(key, 0) + 1
        return np.asarray(fn(*args))

    def clocked(self, fn: Callable, *args) -> Any:
        """``fn(*args)`` with its time added to ``seconds``: a callback's whole body (JAX and
        the host's work on the values), all of which is the JAX eval column, not FATROP's own."""
        t = time.perf_counter()
        try:
            return fn(*args)
        finally:
            self.seconds += time.perf_counter() - t

    def _lam(self, lam) -> np.ndarray:
        """FATROP's multipliers -> the stage NLP's rows (0 on the rows left out)."""
        out = np.zeros(self.form.nlp.m)
        out[self.sel] = np.asarray(lam).ravel()
        return out

    def f(self, x):
        return self._counted("f", self.form.nlp.objective, jnp.asarray(x), self.theta)

    def g(self, x):
        return self._counted("g", self.form.nlp.constraints, jnp.asarray(x), self.theta)[self.sel]

    def grad(self, x):
        return self._counted("grad", self.form.nlp.gradient, jnp.asarray(x), self.theta)

    def jac(self, x):
        """Values in the CCS order of ``jac_sp``."""
        return self._counted("jac", self.form.nlp.jacobian, jnp.asarray(x), self.theta)[self.jac_order]

    def grad_lagrangian(self, x, obj_factor, lam):
        """obj_factor grad f + J^T lam (lam in FATROP's row order)."""
        vals = self._counted("jac", self.form.nlp.jacobian, jnp.asarray(x), self.theta)
        lam_nlp = self._lam(lam)
        jt = np.bincount(self.jac_cols, weights=vals * lam_nlp[self.jac_rows], minlength=self.n)
        return obj_factor * self.grad(x) + jt

    def hess(self, x, obj_factor, lam):
        """Full symmetric Hessian of the Lagrangian, values in the CCS order of ``hess_sp``."""
        lam_nlp = self._lam(lam)
        if self.hessian == "clip":  # dense symmetric blocks: CCS order is the row-major order
            return self._counted("hess", self._clipped, jnp.asarray(x), jnp.asarray(lam_nlp), float(obj_factor), self.theta)
        low = self._counted("hess", self.form.nlp.hessian, jnp.asarray(x), jnp.asarray(lam_nlp), float(obj_factor), self.theta)
        return np.concatenate([low, low[self.hess_off]])[self.hess_order]


def _callback_class():
    """`casadi.Callback` subclasses, defined on first use (casadi is imported lazily)."""
    import casadi

    class Fn(casadi.Callback):
        """A function of named inputs and outputs with given sparsities, evaluated in Python."""

        def __init__(self, name: str, ins, outs, fn: Callable):
            casadi.Callback.__init__(self)
            self.ins, self.outs, self.fn = ins, outs, fn
            self.construct(name, {})

        def get_n_in(self):
            return len(self.ins)

        def get_n_out(self):
            return len(self.outs)

        def get_name_in(self, i):
            return self.ins[i][0]

        def get_name_out(self, i):
            return self.outs[i][0]

        def get_sparsity_in(self, i):
            return self.ins[i][1]

        def get_sparsity_out(self, i):
            return self.outs[i][1]

        def eval(self, arg):
            return self.fn(*arg)

    class Oracle(Fn):
        """The NLP (x, p) -> (f, g) whose derived functions are our own callbacks."""

        def __init__(self, ev: _Evaluator):
            self.ev = ev
            self.derived: list[Fn] = []  # CasADi holds them by reference: keep them alive
            n, m = ev.n, ev.m
            self.sp = {
                "x": casadi.Sparsity.dense(n, 1), "p": casadi.Sparsity(0, 1), "lam:f": casadi.Sparsity.dense(1, 1), "lam:g": casadi.Sparsity.dense(m, 1),
                "f": casadi.Sparsity.dense(1, 1), "g": casadi.Sparsity.dense(m, 1), "grad:f:x": casadi.Sparsity.dense(n, 1),
                "jac:g:x": ev.jac_sp, "grad:gamma:x": casadi.Sparsity.dense(n, 1), "hess:gamma:x:x": ev.hess_sp,
            }
            super().__init__("nlp", [("x", self.sp["x"]), ("p", self.sp["p"])], [("f", self.sp["f"]), ("g", self.sp["g"])], self._nlp)

        def _nlp(self, x, p):
            return self.ev.clocked(self._nlp_body, x)

        def _nlp_body(self, x):
            x = np.asarray(x).ravel()
            return [float(self.ev.f(x)), self.ev.g(x)]

        def _value(self, name: str, d: dict):
            ev, x = self.ev, np.asarray(d["x"]).ravel()
            if name == "f":
                return float(ev.f(x))
            if name == "g":
                return ev.g(x)
            if name == "grad:f:x":
                return ev.grad(x)
            if name == "jac:g:x":
                return casadi.DM(ev.jac_sp, ev.jac(x))
            lam_f, lam_g = float(np.asarray(d["lam:f"]).ravel()[0]), np.asarray(d["lam:g"]).ravel()
            if name == "grad:gamma:x":
                return ev.grad_lagrangian(x, lam_f, lam_g)
            if name == "hess:gamma:x:x":
                return casadi.DM(ev.hess_sp, ev.hess(x, lam_f, lam_g))
            raise KeyError(name)

        def get_factory(self, name, s_in, s_out, aux, opts):
            def sparsity(s):
                if s.endswith(":p"):  # derivatives with respect to the (empty) parameters
                    return casadi.Sparsity(0, 1) if s.startswith("grad") else casadi.Sparsity(self.sp[s.split(":")[1]].size1(), 0)
                if s not in self.sp:
                    raise KeyError(f"bench/fatrop.py: CasADi asked for {s!r} ({name}), which this oracle does not provide")
                return self.sp[s]

            def fn(*arg):
                d = dict(zip(s_in, arg))
                try:
                    return self.ev.clocked(lambda: [casadi.DM(sparsity(s)) if s.endswith(":p") else self._value(s, d) for s in s_out])
                except Exception as e:  # CasADi reports a failed callback and FATROP goes on: keep it
                    self.ev.errors.append(f"{name}: {type(e).__name__}: {e}")
                    raise

            out = Fn(name, [(s, sparsity(s)) for s in s_in], [(s, sparsity(s)) for s in s_out], fn)
            self.derived.append(out)
            return out

    return Oracle


#: FATROP's return codes (its ``return_flag``): 0 converged, others failures.
def solve_fatrop(form: StageForm, x0: np.ndarray, theta: Any, tol: float = 1e-3, max_iter: int = 200, print_level: int = 0, hessian: str = "exact", options: dict | None = None) -> dict:
    """Solve the stage NLP with FATROP from the original warm start ``x0`` (n,); the record
    holds status, iterations, time (s), the JAX part, cost and violation of the ORIGINAL NLP."""
    import casadi

    ev = _Evaluator(form, theta, hessian)
    oracle = _callback_class()(ev)
    opts = {
        "structure_detection": "manual", "N": form.N, "nx": form.nx, "nu": form.nu, "ng": form.ng,
        "fatrop": {"tol": tol, "max_iter": int(max_iter), "print_level": print_level, **(options or {})},
        "print_time": False,
    }
    solver = casadi.nlpsol("fatrop", "fatrop", oracle, opts)
    nlp = form.nlp
    xl, xu, gl, gu = (np.asarray(b, float) for b in nlp.bounds(theta))
    z0 = np.clip(form.lift(x0), xl, xu)
    # compile every JAX function (and run each once) before the clock starts
    lam = np.zeros(ev.m)
    ev.f(z0), ev.g(z0), ev.grad(z0), ev.jac(z0), ev.hess(z0, 1.0, lam), ev.grad_lagrangian(z0, 1.0, lam)
    ev.seconds, ev.counts = 0.0, {}
    t0 = time.perf_counter()
    out = solver(x0=z0, lbx=xl, ubx=xu, lbg=gl[form.perm], ubg=gu[form.perm])
    wall = time.perf_counter() - t0
    if ev.errors:
        raise RuntimeError(f"bench/fatrop.py: {len(ev.errors)} callback evaluations failed during the FATROP solve, first: {ev.errors[0]}")
    stats = solver.stats()
    x = form.drop(np.asarray(out["x"]).ravel())
    src = form.source
    return dict(
        solver="fatrop" if hessian == "exact" else f"fatrop ({hessian})",
        status=str(stats.get("return_status")),
        success=bool(stats.get("success")),
        iterations=int(stats.get("iter_count", -1)),
        time_s=wall,
        time_derivatives=ev.seconds,
        time_solver=wall - ev.seconds,
        evaluations=dict(ev.counts),
        cost=float(src.objective(jnp.asarray(x), theta)),
        constraint_violation=src.violation(x, theta),
        stage_sizes=dict(N=form.N, nx=form.nx[0], nu=form.nu[0], ng_max=max(form.ng), n=nlp.n, m=int(form.perm.size)),
        x=x,
    )


def _jtraj_record(solver: str, r) -> dict:
    return dict(
        solver=solver, status=r.status.value, success=r.success, iterations=r.iterations, time_s=r.time_s,
        time_derivatives=r.time_derivatives, time_solver=r.time_solver, cost=r.cost, constraint_violation=r.constraint_violation,
    )


def markdown(records: list[dict]) -> str:
    head = "| task | solver | status | iterations | time (s) | JAX eval (s) | solver own (s) | cost | max violation |"
    lines = [head, "|" + "---|" * head.count(" | ") + "---|"]
    for rec in records:
        for r in rec["solvers"]:
            lines.append(
                f"| {rec['task']} | {r['solver']} | {r['status']} | {r['iterations']} | {r['time_s']:.2f} | {r['time_derivatives']:.2f} | {r['time_solver']:.2f} "
                f"| {r['cost']:.6g} | {r['constraint_violation']:.1e} |"
            )
    for rec in records:
        if "dropped_rows" in rec:
            lines.append(f"\n{rec['task']}: FATROP's stage form leaves out {sum(rec['dropped_rows'].values())} linearly dependent equality rows {rec['dropped_rows']} (rank tolerance {rec.get('rtol', 1e-7):g}).")
    cpus = records[0]["machine"]["cpus"] if records else None
    # the notes of the solvers the records hold (--hessian, --no-ipopt, --jtraj)
    names = {r["solver"] for rec in records for r in rec["solvers"]}
    hessians = [text for name, text in (("fatrop", "exact Hessian from JAX"), ("fatrop (clip)", "JAX's exact Hessian with each stage block's eigenvalues clipped at 1e-6")) if name in names]
    lines.append(
        f"\nMachine: {cpus} CPUs. FATROP: {' / '.join(hessians)}, tol 1e-3, the task's max_iter, on the stage form of the compact NLP (bench/fatrop.py docstring); "
        + ("Ipopt: jtraj's defaults (L-BFGS, tol 1e-3, MUMPS); " if "ipopt" in names else "")
        + "cost and violation of the original NLP. FATROP's status is its return code (0: converged)."
        + (" jtraj's time is its whole jitted solve (no separate JAX evaluation)." if "jtraj" in names else "")
    )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    add_tasks(ap, ["big_jump"])
    add_param(ap)
    ap.add_argument("--jtraj", action="store_true", help="also solve with jtraj's own interior point")
    ap.add_argument("--no-ipopt", action="store_true", help="skip the Ipopt solve")
    ap.add_argument("--hessian", default="exact", choices=HESSIANS, help="FATROP's Hessian: exact, or its stage blocks with eigenvalues clipped at 1e-6")
    ap.add_argument("--rtol", type=float, default=1e-7, help="relative tolerance of drop_dependent's rank decision (default 1e-7)")
    ap.add_argument("--print-level", type=int, default=0, help="FATROP's print_level (0 quiet, 10 a line per iteration)")
    add_out(ap, "fatrop")
    args = ap.parse_args(argv)
    if not 0 < args.rtol < 1:  # drop_dependent's rank test: NaN dropped every row it tests (no pivot is > NaN), a negative rtol none
        ap.error(f"--rtol: {args.rtol}: expected a finite relative tolerance 0 < rtol < 1 (default 1e-7)")
    try:  # imported where FATROP is first called, after the NLP's compile and the presolve
        import casadi  # noqa: F401
    except ImportError:
        ap.error('casadi (whose wheel has the fatrop plugin) is not installed: pip install -e ".[bench]"')
    records = []
    for t, task in enumerate(args.tasks):
        rec = dict(task=task, param=args.param, machine=dict(cpus=os.cpu_count(), load_1min=os.getloadavg()[0]), solvers=[])
        prep = prepare(task, args.param)
        tr, nlp = prep.transcription, prep.nlp
        theta = tr.resolve_theta(None)
        x0 = tr.warm_start(theta).reshape(-1)
        t0 = time.perf_counter()
        form = stage_form(nlp)
        rec["stage_form_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        form = drop_dependent(form, x0, theta, rtol=args.rtol)
        rec["rtol"] = args.rtol
        rec["presolve_s"] = time.perf_counter() - t0
        rec["dropped_rows"] = form.dropped
        print(f"{task} [{args.param}]: {nlp.n} variables, {nlp.m} rows; stage form N={form.N}, nx={form.nx[0]}, nu={form.nu[0]}, ng<={max(form.ng)} ({form.nlp.n} variables, {form.nlp.m} rows), built in {rec['stage_form_s']:.1f} s; dependent rows left out {form.dropped} ({rec['presolve_s']:.1f} s)", flush=True)
        fat = solve_fatrop(form, x0, theta, tol=1e-3, max_iter=tr.task.max_iter, print_level=args.print_level, hessian=args.hessian)
        fat.pop("x")
        rec["solvers"].append(fat)
        print(f"  fatrop: {fat['status']}, {fat['iterations']} iterations, {fat['time_s']:.2f} s (JAX {fat['time_derivatives']:.2f} s), cost {fat['cost']:.6g}, violation {fat['constraint_violation']:.1e}", flush=True)
        if not args.no_ipopt:
            r = _jtraj_record("ipopt", solve(task, args.param, progress=io.StringIO()))
            rec["solvers"].append(r)
            print(f"  ipopt: {r['status']}, {r['iterations']} iterations, {r['time_s']:.2f} s, cost {r['cost']:.6g}, violation {r['constraint_violation']:.1e}", flush=True)
        if args.jtraj:
            r = _jtraj_record("jtraj", solve(task, args.param, solver="jtraj", progress=io.StringIO()))
            rec["solvers"].append(r)
            print(f"  jtraj: {r['status']}, {r['iterations']} iterations, {r['time_s']:.2f} s, cost {r['cost']:.6g}, violation {r['constraint_violation']:.1e}", flush=True)
        rec["load_1min_after"] = os.getloadavg()[0]
        records.append(rec)
        if args.out:
            write_results(args.out, "fatrop", records, markdown(records), "bench/fatrop.py", record=results_record("bench/fatrop.py", argv, complete=t == len(args.tasks) - 1))
    print(markdown(records))


if __name__ == "__main__":
    main()
