"""A stage view of a `jtraj.nlp.KnotNLP`: per knot, a fixed-size block of constraint rows.

Every constraint row of a KnotNLP reads knots k and k+1 at most; it is assigned to knot k
(its group's knot). Per knot, the active rows are packed into ``m`` slots, ``m`` the largest
number of rows at any knot, with a mask; so every knot has the same shapes and the KKT system
is block tridiagonal (`jtraj.solvers.kkt`). The values come from the NLP's own jitted
functions (constraints, sparse Jacobian, gradient, Hessian), scattered by index arrays built
once here, so the view stays exact for any group the NLP holds.

Shapes: K knots, n = nz variables per knot, m rows per knot.
- ``C`` (K, m): constraint values (0 on inactive slots);
- ``A`` (K, m, n) = dC_k/dz_k, ``B`` (K, m, n) = dC_k/dz_{k+1} (B[K-1] = 0), held as the vector
  of their nonzeros in the order of the view's `JacobianPattern` (``pattern.dense`` gives the
  blocks);
- ``H`` (K, 2n, 2n): element Hessians on (z_k, z_{k+1}) whose sum is the Lagrangian's Hessian.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jtraj.nlp import KnotNLP
from jtraj.solvers.kkt import JacobianPattern

__all__ = ["StageView", "INFINITY"]

#: Bounds at or beyond this magnitude are absent (Ipopt's nlp_lower/upper_bound_inf).
INFINITY = 1e19


class StageView:
    """Knot-blocked values and derivatives of ``nlp`` (see the module docstring).

    Attributes:
        K, n, m: knots, variables per knot, row slots per knot.
        row_flat: (nlp.m,) index of each NLP row in the flattened (K, m) stage array.
        active: (K, m) bool, slots that hold a row.
    """

    def __init__(self, nlp: KnotNLP):
        self.nlp = nlp
        K, n = nlp.n_knots, nlp.nz
        self.K, self.n = K, n
        # knot of every NLP row, in the NLP's row order
        knots = [g.knots[nlp.row_index[gi] // g.n_rows] for gi, g in enumerate(nlp.groups)]
        row_knot = np.concatenate(knots).astype(np.int64) if knots else np.zeros(0, np.int64)
        counts = np.bincount(row_knot, minlength=K)
        self.m = m = max(int(counts.max(initial=0)), 1)
        order = np.argsort(row_knot, kind="stable")
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        slot = np.empty(row_knot.size, np.int64)
        slot[order] = np.arange(row_knot.size) - starts[row_knot[order]]
        self.row_flat = row_knot * m + slot
        active = np.zeros(K * m, bool)
        active[self.row_flat] = True
        self.active = active.reshape(K, m)
        # Jacobian nonzeros -> (K, m, 2n)
        col_knot = nlp.jac_cols // n
        off = col_knot - row_knot[nlp.jac_rows]
        if off.size and (off.min() < 0 or off.max() > 1):
            raise ValueError("a constraint row reads a knot other than its own and the next one; the stage view needs offsets 0 or 1")
        self._jac_flat = self.row_flat[nlp.jac_rows] * (2 * n) + off * n + nlp.jac_cols % n
        slot_flat = self.row_flat[nlp.jac_rows]
        #: the blocks' static sparsity, for the KKT solve's products (`kkt.JacobianPattern`)
        self.pattern = JacobianPattern(K, m, n, slot_flat // m, slot_flat % m, off * n + nlp.jac_cols % n)
        # the NLP's Jacobian values -> the pattern's vector: a gather when each nonzero is given
        # once (the usual case), else a scatter-add of the repeats
        pos = self.pattern.index(self._jac_flat)
        self._jac_gather = None
        if pos.size == self.pattern.nnz and np.unique(pos).size == pos.size:
            self._jac_gather = np.argsort(pos).astype(np.int32)
        self._jac_pos = pos.astype(np.int32)
        # an NLP with parameters has bounds(theta) and functions of (x, theta) (`jtraj.solvers.base.bind`)
        self._theta = callable(getattr(nlp, "bounds", None))

    # ------------------------------------------------------------------ helpers
    def _theta_or_default(self, theta: Any) -> Any:
        """``theta``, or the NLP's own default parameters ``nlp.theta`` for None (as the NLP's
        `dense_jacobian` and `violation` take it)."""
        return getattr(self.nlp, "theta", None) if theta is None else theta

    def _call(self, fn, *args, theta):
        return fn(*args, self._theta_or_default(theta)) if self._theta else fn(*args)

    def to_stage_rows(self, values: jax.Array, fill: float = 0.0) -> jax.Array:
        """(nlp.m,) row values -> (K, m), ``fill`` on inactive slots."""
        out = jnp.full(self.K * self.m, fill, dtype=values.dtype).at[self.row_flat].set(values)
        return out.reshape(self.K, self.m)

    def from_stage_rows(self, values: jax.Array) -> jax.Array:
        """(K, m) -> (nlp.m,) in the NLP's row order."""
        return values.reshape(-1)[self.row_flat]

    # ------------------------------------------------------------------ problem data
    def bounds(self, theta: Any = None) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
        """(x_lower, x_upper) (K, n) and row bounds (c_lower, c_upper) (K, m); +-inf where absent
        and on inactive slots (those are masked by ``active``). ``theta`` None here and in the
        methods below: the NLP's own ``nlp.theta``."""
        nlp = self.nlp
        if self._theta:
            xl, xu, gl, gu = nlp.bounds(self._theta_or_default(theta))
        else:
            xl, xu, gl, gu = nlp.x_lower, nlp.x_upper, nlp.g_lower, nlp.g_upper
        xl, xu, gl, gu = (jnp.asarray(b, jnp.float64) for b in (xl, xu, gl, gu))
        clean = lambda b, s: jnp.where(jnp.abs(b) >= INFINITY, s * jnp.inf, b)  # noqa: E731
        return (
            clean(xl, -1).reshape(self.K, self.n),
            clean(xu, 1).reshape(self.K, self.n),
            self.to_stage_rows(clean(gl, -1), -jnp.inf),
            self.to_stage_rows(clean(gu, 1), jnp.inf),
        )

    def values(self, Z: jax.Array, theta: Any = None) -> tuple[jax.Array, jax.Array]:
        """Objective (scalar) and constraints C (K, m) at Z (K, n)."""
        with jax.named_scope("nlp_values"):  # the scopes name the phases in profiles (bench/profile_solve.py)
            x = Z.reshape(-1)
            f = self._call(self.nlp.objective, x, theta=theta)
            c = self._call(self.nlp.constraints, x, theta=theta)
            return f, self.to_stage_rows(c)

    def derivatives(self, Z: jax.Array, theta: Any = None) -> tuple[jax.Array, jax.Array]:
        """Objective gradient (K, n) and the Jacobian's nonzeros (pattern.nnz,) at Z."""
        with jax.named_scope("nlp_derivatives"):
            x = Z.reshape(-1)
            grad = self._call(self.nlp.gradient, x, theta=theta).reshape(self.K, self.n)
            vals = self._call(self.nlp.jacobian, x, theta=theta)
            if self._jac_gather is not None:
                return grad, vals[self._jac_gather]
            return grad, jnp.zeros(self.pattern.nnz, vals.dtype).at[self._jac_pos].add(vals)

    def prepare_hessian(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Build the NLP's Hessian structure (host work: call before tracing) and the scatter
        of its lower-triangle entries into element blocks; returns that scatter."""
        if not hasattr(self, "_hess_index"):
            nlp, n = self.nlp, self.n
            nlp.build_hessian()
            r, c = nlp.hess_rows, nlp.hess_cols  # lower triangle, r >= c
            kr, kc = r // n, c // n
            if (kr - kc).max(initial=0) > 1:
                raise ValueError("the Hessian couples knots further apart than one; the stage view needs offsets 0 or 1")
            # element kc holds every entry, in (z_k, z_{k+1}) coordinates
            self._hess_index = (kc, (kr - kc) * n + r % n, c % n)
        return self._hess_index

    def hessian(self, Z: jax.Array, Y: jax.Array, obj_factor: float | jax.Array = 1.0, theta: Any = None) -> jax.Array:
        """Element Hessians (K, 2n, 2n) of ``obj_factor f + Y . C`` (exact, from the NLP's
        Hessian; expensive on big robots)."""
        kc, i, j = self.prepare_hessian()
        with jax.named_scope("nlp_hessian"):
            vals = self._call(self.nlp.hessian, Z.reshape(-1), self.from_stage_rows(Y), obj_factor, theta=theta)
            H = jnp.zeros((self.K, 2 * self.n, 2 * self.n), vals.dtype)
            H = H.at[kc, i, j].add(vals)
            off = jnp.where(i != j, vals, 0.0)
            return H.at[kc, j, i].add(off)
