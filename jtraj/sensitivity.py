"""Sensitivity of an NLP's solution to its parameters (the implicit function theorem at a KKT point).

The NLP, with a parameter pytree ``theta``::

    min_x f(x, theta)   s.t.   g_l(theta) <= g(x, theta) <= g_u(theta),   x_l(theta) <= x <= x_u(theta)

is given as JAX functions (`ParametricNLP`: objective, constraints, bounds, sparse constraint
Jacobian and lower-triangle Lagrangian Hessian in COO form; `jtraj.nlp.KnotNLP` is one, and
`DenseNLP` wraps small hand-written problems). At a solution ``x`` with constraint multipliers
``lam`` (Ipopt's sign convention: ``grad f + J^T lam - z_L + z_U = 0``; ``lam > 0`` on rows at
their upper bound), `kkt_system` identifies the active set and assembles the sensitivity
system; `KKTSystem.solve` is its one sparse LU (scipy.sparse.linalg.splu), for a tangent (JVP)
or, transposed, for a cotangent (VJP).

Active set (decided once, at the solution, and then held fixed):
- constraint rows with ``g_l == g_u`` (equalities) are always active;
- an inequality row is active at its nearer bound when its multiplier exceeds its slack
  (``|lam_j| > s_j``; at an interior-point solution one of the two is of the order of the
  barrier parameter, the other of order one);
- a variable is held at a bound when it is fixed (``x_l == x_u``) or when its bound
  multiplier ``z_i = |grad f + J^T lam|_i`` exceeds its slack. Bound multipliers are read off
  stationarity, so any solver that returns ``x`` and ``lam`` will do. A variable at a bound
  follows the bound's dependence on theta (this is how boundary conditions, e.g. a target
  pose, drive the solution).
- An active row with no nonzero Jacobian entry in a free variable (it constrains only
  variables already fixed by their bounds, e.g. a foot-height row at a fixed initial pose)
  carries no information about ``dx`` and would make the system singular; it is dropped.

Unknowns ``z = (x, lam)`` (n + m) and the residual ``r(z, theta)`` whose Jacobian is the
system matrix ``K = dr/dz``::

    free variable i        (grad f + J^T lam_A)_i          (Lagrangian stationarity)
    variable i at bound    x_i - x_bound_i(theta)
    active row j           g_j(x, theta) - g_bound_j(theta)
    inactive row j         lam_j

so ``dz/dtheta = -K^{-1} dr/dtheta`` and ``dx/dtheta`` is its first n rows (`residual` gives
``r`` in JAX for the tangent ``dr/dtheta . dtheta`` and its transpose). Linearly dependent
active rows (which a trajectory's fixed end state creates) leave dx unique but not the
multipliers; `KKTSystem.solve` regularizes and refines so that dx is exact.

What is not differentiated: the active set itself. Where strict complementarity fails (a
constraint or bound at its limit with a multiplier of about zero: weakly active) the solution
is only one-sidedly differentiable; the weakly active rows are treated as inactive and the
system reports ``degenerate``. The derivative is then that of the problem without those rows,
a one-sided derivative only where its tangent keeps each of them satisfied (checked by no
one here: a tangent can break some for a step up and others for a step down). Active rows
that involve only variables at their bounds are dropped (`active_set`'s ``dropped_rows``):
the bounds meet them at the solution, and a theta that moves them apart makes the problem
infeasible, a direction with no derivative at all.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, Protocol

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from jtraj.numbers import is_real

__all__ = ["ParametricNLP", "DenseNLP", "ActiveSet", "ActiveArrays", "active_set", "active_arrays", "KKTSystem", "kkt_system", "residual", "check_weak_tol", "SingularKKTError", "SINGULAR_PREFIX", "NotDifferentiableWarning", "undifferentiable_parameters", "entry_names", "NotAKKTPointError", "kkt_errors", "check_kkt_point", "check_kkt_tol", "KKT_TOL"]


class NotAKKTPointError(ValueError):
    """The point given as a solution is not a KKT point of the NLP at theta (`kkt_errors` above
    ``kkt_tol``): a solve stopped early or at a loose tolerance, or a forward that returns
    something else. The implicit function theorem holds at KKT points only: the derivatives
    there would be of no solution (an unconverged point of ``min (x - theta)^2 / 2, x <= 1``
    at theta = 2, x = 0.5, gave dx/dtheta = 1 where the solution's is 0)."""


#: `kkt_system`'s default ``kkt_tol``: the largest `kkt_errors` accepted. A solve to Ipopt's
#: tol 1e-10 (`jtraj.differentiate`'s forward) ends near 1e-10; the study's tol 1e-3 ends with
#: violations near 1e-6 or below.
KKT_TOL = 1e-4


#: the words each `SingularKKTError`'s message starts with: a caller that gets it through a
#: jitted derivative (as JAX's ``JaxRuntimeError``, whose message ends with this one's) tells it
#: by ``SINGULAR_PREFIX in str(error)`` (the design notebook does)
SINGULAR_PREFIX = "the sensitivity system"


class SingularKKTError(RuntimeError):
    """The sensitivity system has no solution here: its LU found it exactly singular (the
    reduced Hessian is singular on the active constraints' null space, an optimum that is not
    unique), or the solve left a residual (dependent active constraints that theta moves
    inconsistently). Dependent active constraints alone are not an error (`KKTSystem.solve`).

    A singularity that rounding hides is not always caught: the LU then succeeds and dx is
    one of many (measured: ``min (0.1 x0 + 0.3 x1 - theta)^2`` gives dx = (4, 2) without an
    error; the Go2 hop with a zero acceleration weight, which `jtraj.differentiable` refuses,
    gave 0.025 and 0.034 for a derivative of 0.037). The NLP must have a unique optimum.
    """


class NotDifferentiableWarning(RuntimeWarning):
    """A gradient (a reverse-mode derivative) whose components along some of theta's entries
    are not derivatives: the solution has none along them at this theta (moving one of them
    alone leaves the linearized active constraints inconsistent), and the sensitivity system's
    transposed solve, which always has solutions then, gave those components an arbitrary
    value. Forward mode along them fails with a `SingularKKTError`. The warning names the
    entries (`undifferentiable_parameters`); a ``warnings`` filter "error" makes it an
    exception. Both are raised in a host callback of a compiled program (`jtraj.implicit`), so
    they reach the caller as JAX's runtime error (``jax.errors.JaxRuntimeError``), whose
    message ends with theirs."""


class ParametricNLP(Protocol):
    """What the sensitivity system needs of an NLP (`jtraj.nlp.KnotNLP` provides it).

    Shapes: x (n,), lam (m,); theta is any pytree of arrays.
    """

    n: int
    m: int
    jac_rows: np.ndarray  # (nnz_jac,) COO structure of dg/dx
    jac_cols: np.ndarray
    hess_rows: np.ndarray  # (nnz_hess,) lower triangle (row >= col) of the Lagrangian Hessian
    hess_cols: np.ndarray

    def objective(self, x, theta): ...

    def gradient(self, x, theta): ...  # (n,)

    def constraints(self, x, theta): ...

    def jacobian(self, x, theta): ...  # (nnz_jac,) values

    def hessian(self, x, lam, obj_factor, theta): ...  # (nnz_hess,) values of obj_factor f + lam.g

    def bounds(self, theta): ...  # (x_lower (n,), x_upper (n,), g_lower (m,), g_upper (m,))


class DenseNLP:
    """A small `ParametricNLP` from plain JAX functions, with dense derivative structure.

    Args:
        objective: ``f(x, theta) -> ()``.
        constraints: ``g(x, theta) -> (m,)``.
        bounds: ``bounds(theta) -> (x_lower, x_upper, g_lower, g_upper)`` (use +-inf for none).
        n, m: sizes.
    """

    def __init__(self, objective: Callable, constraints: Callable, bounds: Callable, n: int, m: int):
        self.n, self.m = n, m
        self._f, self._g, self._bounds = objective, constraints, bounds
        self.jac_rows, self.jac_cols = (a.reshape(-1) for a in np.meshgrid(np.arange(m), np.arange(n), indexing="ij"))
        self.hess_rows, self.hess_cols = np.tril_indices(n)
        self.objective = jax.jit(objective)
        self.gradient = jax.jit(jax.grad(objective))
        self.constraints = jax.jit(constraints)
        self.jacobian = jax.jit(lambda x, theta: jax.jacfwd(constraints)(x, theta).reshape(-1))

        def hessian(x, lam, obj_factor, theta):
            H = jax.hessian(lambda y: obj_factor * objective(y, theta) + lam @ constraints(y, theta))(x)
            return H[self.hess_rows, self.hess_cols]

        self.hessian = jax.jit(hessian)

    def bounds(self, theta):
        return self._bounds(theta)


@dataclasses.dataclass(frozen=True)
class ActiveSet:
    """The active set at a solution (numpy bool arrays).

    Attributes:
        at_bound: (n,) variable held at a bound (fixed, or bound multiplier > slack and not
            weakly active).
        at_upper: (n,) which bound (True: upper) for ``at_bound`` variables.
        row_active: (m,) constraint rows held at a bound (equalities always, except the
            ``dropped_rows``; inequalities not weakly active).
        row_upper: (m,) which bound (True: upper) for active rows.
        weak_rows: (m,) inequality rows at a bound with a multiplier of about zero.
        weak_bounds: (n,) variables at a bound with a bound multiplier of about zero.
        dropped_rows: (m,) active rows that only involve variables at bounds (left out).
    """

    at_bound: np.ndarray
    at_upper: np.ndarray
    row_active: np.ndarray
    row_upper: np.ndarray
    weak_rows: np.ndarray
    weak_bounds: np.ndarray
    dropped_rows: np.ndarray

    @property
    def degenerate(self) -> bool:
        """Strict complementarity fails somewhere: the derivative is one-sided."""
        return bool(self.weak_rows.any() or self.weak_bounds.any())

    def summary(self) -> dict[str, int]:
        """Counts of variables at bounds and of active, weakly active and dropped rows."""
        return dict(
            variables_at_bounds=int(self.at_bound.sum()),
            active_rows=int(self.row_active.sum()),
            weakly_active_rows=int(self.weak_rows.sum()),
            weakly_active_bounds=int(self.weak_bounds.sum()),
            dropped_rows=int(self.dropped_rows.sum()),
        )


def check_weak_tol(weak_tol: Any) -> None:
    """Refuse a weak-activity tolerance outside [0, 1) (`active_set`'s ``weak_tol``)."""
    if not is_real(weak_tol) or not (0 <= weak_tol < 1):
        raise ValueError(f"weak_tol must be a number in [0, 1) (relative to the largest multiplier), got {weak_tol!r}")


def _solution_point(nlp: ParametricNLP, x: Any, lam: Any, weak_tol: Any) -> tuple[np.ndarray, np.ndarray]:
    """``x`` and ``lam`` as float arrays, checked: the NLP's sizes, finite; ``weak_tol`` too."""
    # a wrong shape failed inside the NLP's JAX functions (dot_general ... same shape), and a NaN
    # point or a negative weak_tol gave an active set and a system without a word
    check_weak_tol(weak_tol)
    x = np.asarray(x, float)
    lam = np.asarray(lam, float)
    if x.shape != (nlp.n,) or lam.shape != (nlp.m,):
        raise ValueError(f"x of shape {x.shape} and lam of shape {lam.shape}; expected ({nlp.n},) and ({nlp.m},), the NLP's sizes")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(lam))):
        raise ValueError("x or lam has NaN or infinite entries: not a solution of the NLP")
    return x, lam


#: `active_set`: a slack and a multiplier both small and within this factor of each other are
#: a weakly active pair, not a strictly complementary one
WEAK_RATIO = 100.0


def _rows_and_multipliers(nlp: ParametricNLP, x: np.ndarray, lam: np.ndarray, theta: Any, jac_values: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """At ``x``: the rows g, the Jacobian's values J (``jac_values`` where the caller has them),
    the gradient of f, and the bound multipliers read off stationarity,
    ``z = z_L - z_U = grad f + J^T lam``."""
    xj = jnp.asarray(x)
    g = np.asarray(nlp.constraints(xj, theta))
    J = np.asarray(nlp.jacobian(xj, theta)) if jac_values is None else jac_values
    grad = np.asarray(nlp.gradient(xj, theta))
    z = grad.copy()
    np.add.at(z, nlp.jac_cols, J * lam[nlp.jac_rows])
    return g, J, grad, z


def _side_and_slack(value, lower, upper):
    """Nearer bound (True: upper) and the slack to it, elementwise."""
    s_lo = np.where(np.isfinite(lower), value - lower, np.inf)
    s_up = np.where(np.isfinite(upper), upper - value, np.inf)
    upper_side = s_up < s_lo
    return upper_side, np.abs(np.where(upper_side, s_up, s_lo))


def active_set(
    nlp: ParametricNLP, x: np.ndarray, lam: np.ndarray, theta: Any, *, weak_tol: float = 1e-6, jac_values: np.ndarray | None = None
) -> ActiveSet:
    """Active set at a KKT point (see the module docstring for the rules).

    ``weak_tol``: a constraint or bound is weakly active when both its slack and its
    multiplier are below ``weak_tol * max(1, largest multiplier)``, or when both are below
    ``sqrt(weak_tol)`` times that scale and within a factor `WEAK_RATIO` of each other: an
    interior-point solve ends a weakly active pair with both near ``sqrt(mu)``, which at tol
    1e-10 (Ipopt, ``jtraj.differentiate``'s forward solve) is about 4e-6, above ``weak_tol``,
    while a strictly complementary pair ends with one of the two near ``mu`` over the other.
    ``weak_tol=0`` turns both tests off.
    """
    x, lam = _solution_point(nlp, x, lam, weak_tol)
    return _active_set_at(nlp, x, lam, theta, weak_tol, _rows_and_multipliers(nlp, x, lam, theta, jac_values))


def _active_set_at(nlp: ParametricNLP, x: np.ndarray, lam: np.ndarray, theta: Any, weak_tol: float, point: tuple) -> ActiveSet:
    """`active_set` of a checked point whose `_rows_and_multipliers` are ``point``."""
    xl, xu, gl, gu = (np.asarray(b, float) for b in nlp.bounds(theta))
    g, J, _, z = point
    fixed = xl == xu
    # (a fixed variable's z is not a multiplier that can vanish: it must not set the scale)
    scale = max(1.0, float(np.abs(lam).max(initial=0.0)), float(np.abs(z[~fixed]).max(initial=0.0)))
    tol = weak_tol * scale

    def weak(slack, mult):
        near = np.minimum(slack, mult) * WEAK_RATIO >= np.maximum(slack, mult)
        return ((slack < tol) & (mult < tol)) | (near & (np.maximum(slack, mult) < np.sqrt(weak_tol) * scale))

    x_up, x_slack = _side_and_slack(x, xl, xu)
    z_mag = np.abs(z)
    at_bound = fixed | (np.isfinite(x_slack) & (z_mag > x_slack))
    weak_bounds = ~fixed & np.isfinite(x_slack) & weak(x_slack, z_mag)

    equality = gl == gu
    g_up, g_slack = _side_and_slack(g, gl, gu)
    g_up = np.where(equality, False, g_up)
    lam_mag = np.abs(lam)
    row_active = equality | (np.isfinite(g_slack) & (lam_mag > g_slack))
    weak_rows = ~equality & np.isfinite(g_slack) & weak(g_slack, lam_mag)
    # weakly active: one-sided; keep the side where the constraint may become slack
    at_bound &= ~weak_bounds
    row_active &= ~weak_rows

    # active rows touching no free variable say nothing about dx (and make K singular)
    free_cols = ~at_bound[nlp.jac_cols] & (J != 0.0)
    touches_free = np.zeros(nlp.m, bool)
    touches_free[nlp.jac_rows[free_cols]] = True
    dropped = row_active & ~touches_free
    row_active &= touches_free
    return ActiveSet(at_bound, x_up & at_bound, row_active, g_up & row_active, weak_rows, weak_bounds, dropped)


def residual(nlp: ParametricNLP, x, lam, theta, act: "ActiveArrays"):
    """The residual r(x, lam, theta) of the module docstring, (n + m,), in JAX.

    ``act`` holds the active set as arrays (`active_arrays` of an `ActiveSet`) so that this
    traces once.
    """
    xl, xu, gl, gu = nlp.bounds(theta)
    lam_a = jnp.where(act.row_active, lam, 0.0)
    grad_l = jax.grad(lambda y: nlp.objective(y, theta) + lam_a @ nlp.constraints(y, theta))(x)
    x_bound = jnp.where(act.at_upper, xu, xl)
    r_x = jnp.where(act.at_bound, x - jnp.where(act.at_bound, x_bound, 0.0), grad_l)
    g_bound = jnp.where(act.row_upper, gu, gl)
    g = nlp.constraints(x, theta)
    r_g = jnp.where(act.row_active, g - jnp.where(act.row_active, g_bound, 0.0), lam)
    return jnp.concatenate([r_x, r_g])


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ActiveArrays:
    """`ActiveSet` as JAX-friendly boolean arrays (a pytree), for `residual`."""

    at_bound: Any
    at_upper: Any
    row_active: Any
    row_upper: Any


def active_arrays(act: ActiveSet) -> ActiveArrays:
    """The arrays of ``act`` that `residual` needs, as an `ActiveArrays` pytree."""
    return ActiveArrays(act.at_bound, act.at_upper, act.row_active, act.row_upper)


@dataclasses.dataclass
class KKTSystem:
    """The factorized sensitivity system ``K dz = rhs`` at one solution.

    Attributes:
        active: the active set it was built for.
        matrix: (n + m, n + m) scipy CSC matrix K = dr/d(x, lam).
    """

    active: ActiveSet
    matrix: sp.csc_matrix
    _lu: Any = None
    _null: np.ndarray | None = None
    _undifferentiable: list[str] | None = None  # `undifferentiable_parameters`, once computed

    @property
    def degenerate(self) -> bool:
        return self.active.degenerate

    def _factor(self) -> tuple[Any, float, np.ndarray]:
        """The LU of K with ``-delta`` on the active rows' diagonal (`solve`), delta and the
        mask of those rows."""
        n = self.active.at_bound.size
        delta = 1e-10 * max(1.0, float(np.abs(self.matrix.data).max(initial=0.0)))
        rows = np.zeros(self.matrix.shape[0])
        rows[n:][self.active.row_active] = 1.0
        if self._lu is None:
            try:
                self._lu = spla.splu((self.matrix - delta * sp.diags(rows)).tocsc())
            except RuntimeError as e:  # "Factor is exactly singular"
                raise SingularKKTError(
                    f"the sensitivity system is singular ({e}) at this solution ({self.active.summary()}): the reduced "
                    f"Hessian is singular on the active constraints' null space (the optimum is not unique)"
                ) from None
        return self._lu, delta, rows

    def left_null_space(self) -> np.ndarray:
        """An orthonormal basis U (n + m, k) of K's left null space (``U^T K = 0``; k = 0 where
        the active rows are independent). A tangent ``K dz = rhs`` has a solution only where
        ``U^T rhs = 0``, and a cotangent's ``K^T w = b`` has solutions ``w + U c`` for every c.

        Found by subspace iteration on ``u -> -delta K_reg^-T D u`` (K_reg the factorized
        matrix, D the active rows' mask), whose fixed points are exactly the vectors of the
        left null space (``K_reg^T u = K^T u - delta D u``); its other eigenvalues are about
        delta over K's smallest other singular values, so a few steps separate them (on the
        Go2 hop: 12 null vectors, ``|K^T u|`` 1e-17 of ``max|K|`` against 4e-4 and more for
        the rest)."""
        if self._null is not None:
            return self._null
        lu, delta, rows = self._factor()
        size, scale = self.matrix.shape[0], delta / 1e-10
        rng = np.random.default_rng(0)
        p = min(16, size)
        while True:
            X = rng.standard_normal((size, p))
            for _ in range(6):
                X = -delta * lu.solve(np.ascontiguousarray(rows[:, None] * X), trans="T")
                X /= np.maximum(np.linalg.norm(X, axis=0), np.finfo(float).tiny)
            Q, _ = np.linalg.qr(X)
            _, sv, Vt = np.linalg.svd(np.asarray(self.matrix.T @ Q), full_matrices=False)
            null = sv <= 1e-10 * scale
            # every vector null: there may be more than p of them
            if null.sum() < p or p == size:
                self._null = Q @ Vt[null].T
                return self._null
            p = min(2 * p, size)

    def solve(self, rhs: np.ndarray, transpose: bool = False, refinements: int = 3) -> np.ndarray:
        """K^{-1} rhs (or K^{-T} rhs); rhs (n + m,) or (batch, n + m).

        Active rows may be linearly dependent (a trajectory's last knots: v_N = 0 and a fixed
        q_N fix q_{N-1} through the integration rows, which makes that knot's contact rows
        redundant). dx is still unique, the multipliers of such rows are not: the LU is of
        K with ``-delta`` on the active rows' diagonal (``delta = 1e-10 max|K|``), and
        iterative refinement against K itself removes the regularization's error from dx.
        """
        size = self.matrix.shape[0]
        if np.ndim(rhs) not in (1, 2) or np.shape(rhs)[-1] != size:  # scipy said only "b is of incompatible size"
            raise ValueError(f"rhs of shape {np.shape(rhs)}; expected ({size},) or (batch, {size}): n + m, the system's size")
        self._factor()
        rhs = np.asarray(rhs, float)
        K = self.matrix.T if transpose else self.matrix
        trans = "T" if transpose else "N"
        B = np.atleast_2d(rhs).T  # (N, batch)
        Z = self._lu.solve(np.ascontiguousarray(B), trans=trans)
        for _ in range(refinements):
            Z = Z + self._lu.solve(np.ascontiguousarray(B - K @ Z), trans=trans)
        # per right-hand side and relative to it: a floor of 1 let any Z pass for a small one
        # (an inconsistent system's tangent of size 1e-6 came back as a value, of size 1 as
        # SingularKKTError)
        residual = np.abs(B - K @ Z).max(axis=0, initial=0.0)
        if not (np.all(np.isfinite(Z)) and np.all(residual <= 1e-6 * np.abs(B).max(axis=0, initial=0.0))):
            why = (
                # K's null space lies in the multipliers: a cotangent that reaches them
                "the output's cotangent reaches multipliers (lam) of linearly dependent active rows, which are not unique "
                "here: lam has no derivative at this solution (x has)"
                if transpose
                else "the direction of theta leaves the linearized active constraints inconsistent: the solution has no "
                "derivative along it here"
            )
            raise SingularKKTError(f"the sensitivity system could not be solved at this solution (residual {residual.max():.1e}; {self.active.summary()}): {why}")
        return Z.T.reshape(rhs.shape)


def undifferentiable_parameters(nlp: ParametricNLP, system: KKTSystem, x: Any, lam: Any, theta: Any) -> list[str]:
    """The entries of theta along which the solution ``(x, lam)`` has no derivative, named as
    ``field[index]`` (``target_translation[2]``; a scalar field by its name): those whose
    unit direction ``e`` leaves ``K dz = -dr/dtheta e`` inconsistent, that is where
    ``(dr/dtheta)^T U`` (U: `KKTSystem.left_null_space`) has a nonzero row. A gradient's
    components there are arbitrary (`NotDifferentiableWarning`). Computed once per system (a
    few solves and VJPs), for the solution it was built at."""
    if system._undifferentiable is None:
        system._undifferentiable = _undifferentiable(nlp, system, x, lam, theta)
    return system._undifferentiable


def _undifferentiable(nlp: ParametricNLP, system: KKTSystem, x: Any, lam: Any, theta: Any) -> list[str]:
    U = system.left_null_space()
    if U.shape[1] == 0:
        return []
    act = active_arrays(system.active)
    lam_a = np.where(system.active.row_active, np.asarray(lam, float), 0.0)
    theta = jax.tree_util.tree_map(jnp.asarray, theta)
    _, vjp = jax.vjp(lambda th: residual(nlp, jnp.asarray(x, float), jnp.asarray(lam_a), th, act), theta)
    A = jax.vmap(lambda u: vjp(u)[0])(jnp.asarray(U.T))  # theta's pytree, each leaf with k rows in front
    leaves = [np.abs(np.asarray(leaf)).reshape(U.shape[1], -1).max(axis=0) for leaf in jax.tree_util.tree_leaves(A)]
    largest = max((float(a.max(initial=0.0)) for a in leaves), default=0.0)
    names = entry_names(theta)
    return [names[i] for i in np.flatnonzero(np.concatenate(leaves) > max(1e-8 * largest, 1e-9))]  # (rounding leaves about 1e-14)


def entry_names(theta: Any) -> list[str]:
    """The name of every entry of ``theta``, leaf by leaf in `jax.tree_util.tree_leaves` order and
    each leaf's entries in C order, as `undifferentiable_parameters` names them: ``field[index]``
    (``target_translation[2]``), a scalar field by its name."""
    names = []
    for path, leaf in jax.tree_util.tree_flatten_with_path(theta)[0]:
        field = jax.tree_util.keystr(path).lstrip(".") or "theta"  # (theta an array itself)
        shape = np.shape(leaf)
        names += [field] if not shape else [f"{field}[{', '.join(map(str, i))}]" for i in np.ndindex(shape)]
    return names


def kkt_errors(nlp: ParametricNLP, x: Any, lam: Any, theta: Any, jac_values: np.ndarray | None = None) -> dict[str, float]:
    """How far ``(x, lam)`` is from a KKT point of ``nlp`` at ``theta`` (Ipopt's sign convention,
    module docstring), each the largest over the variables and rows:

    - ``infeasibility``: a row's or a variable's violation of its bounds (absolute);
    - ``dual``: the bound multiplier ``z = grad f + J^T lam`` a variable cannot have (of the sign
      of its nearer bound's, 0 without a finite bound; a fixed variable takes any), and a
      row's multiplier of the wrong sign for its nearer bound (an equality's takes any);
    - ``complementarity``: ``|z_i| min(slack_i, 1)`` and ``|lam_j| min(slack_j, 1)`` (to the
      nearer bound; a multiplier on a slack bound, which a large slack would otherwise
      magnify: an interior-point solution's small multipliers times bounds far away).

    ``dual`` and ``complementarity`` are relative to ``max(1, |grad f|, |lam|)`` (largest
    entries), as Ipopt scales its dual residual by the multipliers' size. Bounds of 1e19 and
    beyond in magnitude are infinite, as in Ipopt's convention."""
    x, lam = _solution_point(nlp, x, lam, 0.0)
    return _kkt_errors_at(nlp, x, lam, theta, _rows_and_multipliers(nlp, x, lam, theta, jac_values))


def _kkt_errors_at(nlp: ParametricNLP, x: np.ndarray, lam: np.ndarray, theta: Any, point: tuple) -> dict[str, float]:
    """`kkt_errors` of a checked point whose `_rows_and_multipliers` are ``point``."""
    from jtraj.solvers.stage import INFINITY  # Ipopt's nlp_lower/upper_bound_inf, as jtraj's solver reads bounds

    xl, xu, gl, gu = (np.asarray(b, float) for b in nlp.bounds(theta))
    xl, gl = (np.where(b <= -INFINITY, -np.inf, b) for b in (xl, gl))
    xu, gu = (np.where(b >= INFINITY, np.inf, b) for b in (xu, gu))
    g, _, grad, z = point
    scale = max(1.0, float(np.abs(grad).max(initial=0.0)), float(np.abs(lam).max(initial=0.0)))
    infeasible = max(
        float(np.max(np.maximum(xl - x, x - xu), initial=0.0)),
        float(np.max(np.maximum(gl - g, g - gu), initial=0.0)),
    )

    def dual_and_compl(value, mult, lower, upper, free_sign):
        upper_side, slack = _side_and_slack(value, lower, upper)
        bounded = np.isfinite(slack)
        # the multiplier's own sign: >= 0 at a lower bound, <= 0 at an upper one (z = z_L - z_U;
        # a row's lam is -lam_L + lam_U, the other way round)
        signed = np.where(upper_side, -mult, mult) if free_sign is None else np.where(upper_side, mult, -mult)
        wrong = np.where(bounded, np.maximum(-signed, 0.0), np.abs(mult))
        wrong = np.where(free_sign if free_sign is not None else lower == upper, 0.0, wrong)
        compl = np.abs(mult) * np.where(bounded, np.minimum(np.maximum(slack, 0.0), 1.0), 0.0)  # (no inf * 0)
        return float(np.max(wrong, initial=0.0)), float(np.max(compl, initial=0.0))

    dual_x, compl_x = dual_and_compl(x, z, xl, xu, None)
    dual_g, compl_g = dual_and_compl(g, lam, gl, gu, gl == gu)
    return dict(infeasibility=infeasible, dual=max(dual_x, dual_g) / scale, complementarity=max(compl_x, compl_g) / scale)


def check_kkt_tol(kkt_tol: Any) -> None:
    """Refuse a ``kkt_tol`` that is neither a number > 0 nor None."""
    if kkt_tol is not None and not (is_real(kkt_tol) and kkt_tol > 0):
        raise ValueError(f"kkt_tol must be a number > 0 or None (no check), got {kkt_tol!r}")


def check_kkt_point(nlp: ParametricNLP, x: Any, lam: Any, theta: Any, kkt_tol: float | None = KKT_TOL, jac_values: np.ndarray | None = None) -> None:
    """Raise `NotAKKTPointError` where a `kkt_errors` of ``(x, lam)`` is above ``kkt_tol``
    (None: no check)."""
    check_kkt_tol(kkt_tol)
    if kkt_tol is not None:
        _refuse_above(kkt_errors(nlp, x, lam, theta, jac_values), kkt_tol)


def _refuse_above(errors: dict[str, float], kkt_tol: float) -> None:
    """`NotAKKTPointError` where one of `kkt_errors`'s ``errors`` is above ``kkt_tol``."""
    above = {k: v for k, v in errors.items() if not v <= kkt_tol}
    if above:
        said = ", ".join(f"{k} {v:.3g}" for k, v in above.items())
        raise NotAKKTPointError(
            f"not a KKT point of the NLP at this theta: {said} (kkt_tol={kkt_tol:g}); its implicit derivatives would be of no solution. "
            "Solve to a tighter tolerance, or check what the forward returns (jtraj.implicit.implicit_solution's kkt_tol=None skips this check)"
        )


def kkt_system(
    nlp: ParametricNLP, x: np.ndarray, lam: np.ndarray, theta: Any, *, weak_tol: float = 1e-6, kkt_tol: float | None = KKT_TOL, active: ActiveSet | None = None
) -> KKTSystem:
    """Active set and sensitivity matrix K at a solution ``(x, lam)`` of ``nlp`` at ``theta``.

    K is built from the sparse Jacobian and Lagrangian Hessian values of ``nlp`` (the
    Hessian with the active rows' multipliers only); `residual` is the function it is the
    Jacobian of. The LU factorization happens on the first `KKTSystem.solve`. A point farther
    from a KKT point than ``kkt_tol`` (`kkt_errors`; None: not checked) is refused with
    `NotAKKTPointError`.

    ``active``: the active set to hold instead of the one found at ``(x, lam)`` (a system
    built again for a solution whose multipliers were since zeroed off it: found again, it
    could differ, `jtraj.implicit`); K reads only its ``at_bound``, ``row_active`` and the
    active rows' multipliers.
    """
    n, m = nlp.n, nlp.m
    x, lam = _solution_point(nlp, x, lam, weak_tol)
    check_kkt_tol(kkt_tol)
    xj = jnp.asarray(x)
    point = _rows_and_multipliers(nlp, x, lam, theta, None)  # (once for both uses)
    if kkt_tol is not None:
        _refuse_above(_kkt_errors_at(nlp, x, lam, theta, point), kkt_tol)
    act = _active_set_at(nlp, x, lam, theta, weak_tol, point) if active is None else active
    J = point[1]
    lam_a = np.where(act.row_active, np.asarray(lam, float), 0.0)
    Hv = np.asarray(nlp.hessian(xj, jnp.asarray(lam_a), 1.0, theta))
    hr, hc = np.asarray(nlp.hess_rows), np.asarray(nlp.hess_cols)
    off = hr != hc
    # full symmetric Hessian from its lower triangle
    Hr = np.concatenate([hr, hc[off]])
    Hc = np.concatenate([hc, hr[off]])
    Hv = np.concatenate([Hv, Hv[off]])
    free = ~act.at_bound
    jr, jc = np.asarray(nlp.jac_rows), np.asarray(nlp.jac_cols)
    rows, cols, vals = [], [], []
    keep = free[Hr]  # stationarity rows of free variables: H
    rows.append(Hr[keep]), cols.append(Hc[keep]), vals.append(Hv[keep])
    keep = free[jc] & act.row_active[jr]  # ... and J^T of the active rows
    rows.append(jc[keep]), cols.append(n + jr[keep]), vals.append(J[keep])
    keep = act.row_active[jr]  # active rows: J
    rows.append(n + jr[keep]), cols.append(jc[keep]), vals.append(J[keep])
    b = np.flatnonzero(act.at_bound)  # bound rows: identity on x
    rows.append(b), cols.append(b), vals.append(np.ones(b.size))
    i = np.flatnonzero(~act.row_active)  # inactive rows: identity on lam
    rows.append(n + i), cols.append(n + i), vals.append(np.ones(i.size))
    K = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n + m, n + m)).tocsc()
    K.sum_duplicates()
    return KKTSystem(act, K)
