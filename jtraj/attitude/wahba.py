"""Wahba's problem solved by Gauss-Newton on unit quaternions (paper Section IV, Fig. 2).

Given unit vectors ``v_world[i]`` known in the world frame and their measurements
``v_body[i]`` in the body frame, find the body-to-world attitude ``q_world_body`` (wxyz)
minimizing Wahba's loss (eq. 19, unweighted)::

    loss(q) = sum_i |v_world[i] - A(q) v_body[i]|^2 = |r(q)|^2,     r(q) in R^(3n).

Methods (each takes one `WahbaProblem` and returns the iterates, shape (iterations + 1, 4),
row 0 being the initial guess; `jax.vmap` them over problems):

- `solve_svd`: Markley's SVD method, the exact minimizer and the reference of every error.
- `projected_gauss_newton` (Algorithm 1): ``J = dr/dq`` in R^4, additive step
  ``dq = -(J^T J)^-1 J^T r``, projection ``q / |q|``.
- `multiplicative_gauss_newton` (Algorithm 2): ``J = dr/dq G(q)`` (eq. 21), step
  ``phi = -(J^T J)^-1 J^T r``, update ``q (x) cayley(phi)``.
- `multiplicative_newton`: Algorithm 2 with the exact Hessian in Rodrigues coordinates
  (eq. 15, `jtraj.quaternion.hessian_correction`) in place of ``J^T J``. Not in the paper;
  it is here because it, and not Gauss-Newton, converges superlinearly (see below).

What the numbers show (``run_wahba()``, 100 trials, seed 0; see `main_wahba`):

- Gauss-Newton on a problem whose residual is not zero at the solution converges
  *linearly*, with rate ``rho(I - (J^T J)^-1 H)`` at the solution (H the exact Hessian);
  with 5 degrees of noise rho is about 0.02-0.05, so Algorithm 2 still reaches the double
  precision floor (~4e-16 rad) within about 9 iterations, but it is not quadratic.
  The paper's own Fig. 2 data show the same linear rate (mean error 10 -> 0.26 -> 6.4e-3
  -> 1.9e-4 -> 6.2e-6 degrees, ratio about 0.03 per iteration; `PAPER_FIG2_MEAN_DEG`).
  `multiplicative_newton` converges superlinearly, at least quadratically: the median error
  goes 0.17 -> 1.4e-3 -> 6.5e-10 -> 4e-16 rad, an estimated order of about 3. (In Rodrigues
  coordinates about the current iterate the loss is a Rayleigh quotient of Davenport's K
  matrix, ``const - 2 y^T K y / y^T y`` with ``y = [1; phi]``, whose symmetric structure makes
  the quadratic error term vanish, as in Rayleigh-quotient iteration.)
- Whether Algorithm 1 stalls depends on how ``A(q)`` is extended off the unit sphere, which
  the paper does not say. With the Euler-Rodrigues formula ``I + 2 s [v]x + 2 [v]x^2`` (what
  the paper's public code uses; `rotation_matrix_euler_rodrigues`), the fixed point of
  ``q -> Pi(q + dq)`` is not the minimizer and the iteration stops dead a few 1e-3 rad away
  (median 3.9e-3 rad = 0.22 degrees, mean 0.43 degrees, over ``jtraj wahba --trials 100
  --iterations 12``; the paper's Fig. 2 mean: 0.28 degrees).
  With eq. 9, ``A(q) = H^T L(q) R(q)^T H``, which is homogeneous (``A(c q) = c^2 A(q)``),
  ``J^T r`` parallel to q is both the fixed-point condition of the projected step and the
  constrained first-order condition, so Algorithm 1 converges (linearly, like Algorithm 2).
  Both extensions are run and reported; "projected" means the Euler-Rodrigues one.

Problem instances (`generate_problem`), following the paper and its public code:
``n`` world vectors uniform on the sphere; a uniformly random true attitude; each
measurement is ``v_body[i] = A(q_true)^T Exp(xi_i) v_world[i]`` with
``xi_i ~ N(0, sigma^2 I3)``, ``sigma`` = 5 degrees per axis (so each vector is displaced by
a Rayleigh-distributed angle with scale 5 degrees, mean 6.3 degrees); the initial guess is
the SVD solution rotated by exactly 10 degrees about a uniformly random axis,
``q_init = q_svd (x) Exp(10 deg * axis)``, so that every curve starts at 10 degrees as in
Fig. 2 (the SVD solution itself is about 2 degrees from the true attitude: 1.4 degrees per
axis, ``5 / sqrt(2 n / 3)`` for n = 20 vectors; mean 2.3 degrees over the 100 trials of seed 0).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jtraj import io
from jtraj import quaternion as quat
from jtraj.lie import SO3, skew
from jtraj.numbers import is_real, is_whole

__all__ = [
    "PAPER_FIG2_MEAN_DEG",
    "WahbaProblem",
    "WahbaErrors",
    "WahbaResult",
    "generate_problem",
    "rotation_matrix_euler_rodrigues",
    "wahba_residual",
    "wahba_loss",
    "solve_svd",
    "angle_error",
    "projected_gauss_newton",
    "multiplicative_gauss_newton",
    "multiplicative_newton",
    "solve_trial",
    "solve_trials",
    "run_wahba",
    "convergence_order",
    "summarize",
    "write_wahba_data",
    "plot_wahba",
    "main_wahba",
]

RotationFn = Callable[[jax.Array], jax.Array]

#: Mean angle error (degrees) over the paper's 100 trials at iterations 0-4, read from the data
#: of its Fig. 2 (public code, `wahba_convergence.tikz`): Algorithm 1 ("original") and
#: Algorithm 2 ("modified"), both with a backtracking line search that never shortened a step
#: from 10 degrees. For comparison with `summarize`'s ``mean_per_iteration_deg``.
PAPER_FIG2_MEAN_DEG: dict[str, tuple[float, ...]] = {
    "projected": (10.0, 0.6328, 0.2856, 0.2828, 0.2827),
    "multiplicative": (10.0, 0.2573, 6.405e-3, 1.902e-4, 6.200e-6),
}


#: Default measurement noise (rad, standard deviation) and initial-guess offset (rad).
NOISE_STD = math.radians(5.0)
INIT_OFFSET = math.radians(10.0)


class WahbaProblem(NamedTuple):
    """One instance of Wahba's problem (a pytree; batch it with leading axes).

    v_world: (n, 3) unit vectors in the world frame.
    v_body: (n, 3) their noisy measurements in the body frame.
    q_world_body_true: (4,) wxyz, the attitude the data were generated from.
    q_world_body_init: (4,) wxyz, the initial guess of the iterative methods.
    """

    v_world: jax.Array
    v_body: jax.Array
    q_world_body_true: jax.Array
    q_world_body_init: jax.Array


class WahbaErrors(NamedTuple):
    """Angle errors to the SVD solution (rad), each (iterations + 1,), row 0 the initial guess."""

    projected: jax.Array
    multiplicative: jax.Array
    newton: jax.Array
    projected_homogeneous: jax.Array


def _unit(x: jax.Array) -> jax.Array:
    return x / jnp.linalg.norm(x, axis=-1, keepdims=True)


def rotation_matrix_euler_rodrigues(q: jax.Array) -> jax.Array:
    """Euler-Rodrigues formula ``I + 2 s [v]x + 2 [v]x^2`` of ``q = [s, v]``; (4,) -> (3, 3).

    Equal to `jtraj.quaternion.rotation_matrix` (eq. 9) on unit quaternions, but not
    homogeneous off the sphere; it is the extension under which Algorithm 1 stalls.
    """
    K = skew(q[1:])
    return jnp.eye(3, dtype=q.dtype) + 2.0 * q[0] * K + 2.0 * K @ K


def wahba_residual(q: jax.Array, problem: WahbaProblem, rotation: RotationFn = quat.rotation_matrix) -> jax.Array:
    """Stacked residuals ``r_i = v_world[i] - A(q) v_body[i]`` (eq. 19); (4,) -> (3 n,).

    ``rotation`` gives ``A(q)``; it matters only for q off the unit sphere (Algorithm 1).
    """
    return (problem.v_world - problem.v_body @ rotation(q).T).reshape(-1)


def wahba_loss(q: jax.Array, problem: WahbaProblem) -> jax.Array:
    """Wahba's loss ``|r(q)|^2`` (eq. 19, unit weights)."""
    r = wahba_residual(q, problem)
    return r @ r


def solve_svd(problem: WahbaProblem) -> jax.Array:
    """Markley's SVD solution of Wahba's problem, the exact minimizer; returns wxyz (4,).

    With ``B = sum_i v_world[i] v_body[i]^T = U S V^T`` the body-to-world rotation is
    ``U diag(1, 1, det U det V) V^T``; the quaternion is returned with ``q_s >= 0``.
    """
    B = problem.v_world.T @ problem.v_body
    U, _, Vt = jnp.linalg.svd(B)
    d = jnp.linalg.det(U) * jnp.linalg.det(Vt)
    A = U @ jnp.diag(jnp.array([1.0, 1.0, d])) @ Vt
    q = SO3.from_matrix(A).wxyz
    return jnp.where(q[0] < 0.0, -q, q)


def angle_error(q: jax.Array, q_ref: jax.Array) -> jax.Array:
    """Rotation angle (rad, in [0, pi]) between two attitudes, accurate down to 1e-16.

    ``2 atan2(|e_v|, |e_s|)`` of ``e = q_ref^* (x) q``; unlike ``2 acos(|q_ref . q|)``
    it does not lose half the digits near zero. Invariant under ``q -> -q``.
    """
    e = quat.multiply(quat.conjugate(q_ref), q)
    return 2.0 * jnp.arctan2(jnp.linalg.norm(e[1:]), jnp.abs(e[0]))


def generate_problem(
    key: jax.Array,
    n_vectors: int = 20,
    noise_std: float | jax.Array = NOISE_STD,
    init_offset: float | jax.Array = INIT_OFFSET,
) -> WahbaProblem:
    """A random instance of Wahba's problem (see the module docstring for the noise model).

    key: a PRNG key. n_vectors: static. noise_std: per-axis standard deviation (rad) of the
    rotation vector that perturbs each world vector. init_offset: angle (rad) between the
    initial guess and the SVD solution.
    """
    if not is_whole(n_vectors) or n_vectors < 2:
        raise ValueError(f"n_vectors must be an integer >= 2 (one vector leaves the attitude free about it), got {n_vectors!r}")
    k_att, k_vec, k_noise, k_axis = jax.random.split(key, 4)
    q_true = _unit(jax.random.normal(k_att, (4,)))
    q_true = jnp.where(q_true[0] < 0.0, -q_true, q_true)
    v_world = _unit(jax.random.normal(k_vec, (n_vectors, 3)))
    xi = noise_std * jax.random.normal(k_noise, (n_vectors, 3))
    v_world_noisy = jax.vmap(lambda x, v: SO3.exp(x) @ v)(xi, v_world)
    # v_body = A(q)^T v for every row at once: (A^T v)^T = v^T A.
    v_body = v_world_noisy @ quat.rotation_matrix(q_true)
    problem = WahbaProblem(v_world, v_body, q_true, q_true)
    q_svd = solve_svd(problem)
    axis = _unit(jax.random.normal(k_axis, (3,)))
    q_init = quat.multiply(q_svd, SO3.exp(init_offset * axis).wxyz)
    return problem._replace(q_world_body_init=q_init)


def _iterate(step: Callable[[jax.Array], jax.Array], q0: jax.Array, iterations: int) -> jax.Array:
    def body(q, _):
        q_next = step(q)
        return q_next, q_next

    _, qs = jax.lax.scan(body, q0, None, length=iterations)
    return jnp.concatenate([q0[None], qs], axis=0)


def projected_gauss_newton(
    problem: WahbaProblem,
    iterations: int,
    rotation: RotationFn = rotation_matrix_euler_rodrigues,
) -> jax.Array:
    """Algorithm 1: Gauss-Newton in R^4 with additive steps and projection ``q / |q|``.

    ``rotation`` extends ``A(q)`` off the sphere (static): `rotation_matrix_euler_rodrigues`
    reproduces the stall of Fig. 2, `jtraj.quaternion.rotation_matrix` (eq. 9) converges.
    Returns the iterates, shape (iterations + 1, 4).
    """

    def residual(q):
        return wahba_residual(q, problem, rotation)

    def step(q):
        r = residual(q)
        J = jax.jacfwd(residual)(q)
        dq = -jnp.linalg.solve(J.T @ J, J.T @ r)
        return _unit(q + dq)

    return _iterate(step, problem.q_world_body_init, iterations)


def multiplicative_gauss_newton(problem: WahbaProblem, iterations: int) -> jax.Array:
    """Algorithm 2: ``J = dr/dq G(q)`` (eq. 21), ``phi = -(J^T J)^-1 J^T r``,
    ``q <- q (x) cayley(phi)``. Returns the iterates, shape (iterations + 1, 4)."""

    def residual(q):
        return wahba_residual(q, problem)

    def step(q):
        r = residual(q)
        J = quat.jacobian_correction(jax.jacfwd(residual)(q), q)
        phi = -jnp.linalg.solve(J.T @ J, J.T @ r)
        return quat.multiplicative_update(q, phi)

    return _iterate(step, problem.q_world_body_init, iterations)


def multiplicative_newton(problem: WahbaProblem, iterations: int) -> jax.Array:
    """Newton's method in Rodrigues coordinates: gradient ``dl/dq G(q)`` (eq. 14), Hessian
    eq. 15 (sign-corrected, `jtraj.quaternion.hessian_correction`), multiplicative update.

    No globalization: started 10 degrees from the solution the Hessian is positive definite.
    Returns the iterates, shape (iterations + 1, 4).
    """

    def loss(q):
        return wahba_loss(q, problem)

    def step(q):
        g = jax.grad(loss)(q)
        hess = quat.hessian_correction(jax.hessian(loss)(q), g, q)
        phi = -jnp.linalg.solve(hess, quat.jacobian_correction(g, q))
        return quat.multiplicative_update(q, phi)

    return _iterate(step, problem.q_world_body_init, iterations)


def solve_trial(
    key: jax.Array,
    iterations: int,
    n_vectors: int = 20,
    noise_std: float | jax.Array = NOISE_STD,
    init_offset: float | jax.Array = INIT_OFFSET,
) -> WahbaErrors:
    """One trial: generate a problem, run every method, measure the angle errors to the SVD
    solution. Each error history has shape (iterations + 1,)."""
    problem = generate_problem(key, n_vectors, noise_std, init_offset)
    q_svd = solve_svd(problem)

    def errors(iterates):
        return jax.vmap(angle_error, in_axes=(0, None))(iterates, q_svd)

    return WahbaErrors(
        projected=errors(projected_gauss_newton(problem, iterations)),
        multiplicative=errors(multiplicative_gauss_newton(problem, iterations)),
        newton=errors(multiplicative_newton(problem, iterations)),
        projected_homogeneous=errors(projected_gauss_newton(problem, iterations, quat.rotation_matrix)),
    )


def _solve_trials(keys, iterations, n_vectors, noise_std, init_offset):
    """`solve_trial` for each PRNG key of ``keys`` (trials,): a `WahbaErrors` whose arrays
    have the trials axis first. Jit-compiled as `solve_trials`, with ``iterations`` and
    ``n_vectors`` static (the noise level and offset are traced: no recompilation)."""
    return jax.vmap(solve_trial, in_axes=(0, None, None, None, None))(keys, iterations, n_vectors, noise_std, init_offset)


#: `solve_trial` vmapped over a batch of keys (trials,) and jit-compiled; ``iterations`` and
#: ``n_vectors`` are static, the noise level and offset are traced (no recompilation).
solve_trials = jax.jit(_solve_trials, static_argnames=("iterations", "n_vectors"))


@dataclass(frozen=True)
class WahbaResult:
    """Angle errors (rad) to the SVD solution, each (trials, iterations + 1), numpy."""

    projected: np.ndarray
    multiplicative: np.ndarray
    newton: np.ndarray
    projected_homogeneous: np.ndarray
    seed: int
    n_vectors: int
    noise_std_deg: float
    init_offset_deg: float

    @property
    def trials(self) -> int:
        return self.projected.shape[0]

    @property
    def iterations(self) -> int:
        return self.projected.shape[1] - 1

    def methods(self) -> dict[str, np.ndarray]:
        return {name: getattr(self, name) for name in _METHODS}


_METHODS = ("projected", "multiplicative", "newton", "projected_homogeneous")
_LABELS = {
    "projected": "projected Gauss-Newton (Alg. 1)",
    "multiplicative": "multiplicative Gauss-Newton (Alg. 2)",
    "newton": "multiplicative Newton (eq. 15 Hessian)",
    "projected_homogeneous": "projected Gauss-Newton, A(q) of eq. 9",
}


def run_wahba(
    trials: int = 100,
    iterations: int = 12,
    seed: int = 0,
    n_vectors: int = 20,
    noise_std_deg: float = 5.0,
    init_offset_deg: float = 10.0,
) -> WahbaResult:
    """Run all methods on ``trials`` problems whose keys are split from ``PRNGKey(seed)``."""
    for name, value, minimum in (("trials", trials, 1), ("iterations", iterations, 1), ("n_vectors", n_vectors, 2), ("seed", seed, 0)):
        if not is_whole(value) or value < minimum:
            raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    for name, degrees in (("noise_std_deg", noise_std_deg), ("init_offset_deg", init_offset_deg)):
        if not is_real(degrees) or not (math.isfinite(degrees) and degrees >= 0):
            raise ValueError(f"{name} must be a finite number >= 0 (degrees), got {degrees!r}")
    keys = jax.random.split(jax.random.PRNGKey(seed), trials)
    errs = solve_trials(
        keys,
        iterations=iterations,
        n_vectors=n_vectors,
        noise_std=math.radians(noise_std_deg),
        init_offset=math.radians(init_offset_deg),
    )
    return WahbaResult(
        **{name: np.asarray(getattr(errs, name)) for name in _METHODS},
        seed=seed,
        n_vectors=n_vectors,
        noise_std_deg=noise_std_deg,
        init_offset_deg=init_offset_deg,
    )


def convergence_order(errors: np.ndarray, floor: float = 1e-13) -> np.ndarray:
    """Per-trial estimate of the convergence order from the last three errors above ``floor``.

    ``p = log(e_{k+1} / e_k) / log(e_k / e_{k-1})``: 1 for linear, 2 for quadratic
    convergence. errors: (trials, iterations + 1); returns (trials,), NaN where fewer than
    three errors lie above the floor or the errors stopped decreasing (a stall).
    """
    errors = np.atleast_2d(np.asarray(errors, dtype=float))
    out = np.full(errors.shape[0], np.nan)
    for t, e in enumerate(errors):
        k = np.flatnonzero(e > floor)
        k = k[k == np.arange(len(k))]  # leading run only
        if len(k) < 3:
            continue
        e0, e1, e2 = e[k[-3]], e[k[-2]], e[k[-1]]
        if not (e2 < e1 < e0) or e1 / e0 > 0.9:
            continue
        out[t] = math.log(e2 / e1) / math.log(e1 / e0)
    return out


def _no_order_note(errors: np.ndarray, floor: float) -> str:
    """Why `convergence_order` estimated no trial's order: fewer than three errors above the
    floor in every trial (too few iterations, or converged at once), else the errors stopped
    decreasing (a stall)."""
    above = np.cumprod(np.atleast_2d(errors) > floor, axis=1).sum(axis=1)  # leading run of each trial
    return f"fewer than three errors above {floor:g}" if np.all(above < 3) else "stalled"


def summarize(result: WahbaResult, floor: float = 1e-13) -> dict:
    """Medians per iteration, final median / max errors and convergence-order estimates."""
    summary: dict = {
        "trials": result.trials,
        "iterations": result.iterations,
        "seed": result.seed,
        "n_vectors": result.n_vectors,
        "noise_std_deg": result.noise_std_deg,
        "init_offset_deg": result.init_offset_deg,
        "error_unit": "rad",
        "methods": {},
    }
    for name, e in result.methods().items():
        order = convergence_order(e, floor)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = e[:, 1:] / e[:, :-1]
        ok = (e[:, :-1] > 1e-11) & (e[:, 1:] > floor)
        summary["methods"][name] = {
            "label": _LABELS[name],
            "median_per_iteration": np.median(e, axis=0).tolist(),
            "final_median": float(np.median(e[:, -1])),
            "final_max": float(np.max(e[:, -1])),
            "median_order_estimate": float(np.nanmedian(order)) if np.any(np.isfinite(order)) else None,
            # why there is no estimate: "stalled" was printed also for a run too short to have one
            "median_order_note": None if np.any(np.isfinite(order)) else _no_order_note(e, floor),
            "median_error_ratio": float(np.median(ratio[ok])) if np.any(ok) else None,
            # e_{k+1} / e_k^2 over errors above the floor: bounded for quadratic convergence.
            "max_quadratic_constant": float(np.max(ratio[ok] / e[:, :-1][ok])) if np.any(ok) else None,
            "first_iteration_below_1e-10_median": _first_below(np.median(e, axis=0), 1e-10),
            "mean_per_iteration_deg": np.degrees(np.mean(e, axis=0)).tolist(),
        }
        if name in PAPER_FIG2_MEAN_DEG:
            summary["methods"][name]["paper_fig2_mean_deg"] = list(PAPER_FIG2_MEAN_DEG[name])
    return summary


def _first_below(e: np.ndarray, tol: float) -> int | None:
    k = np.flatnonzero(e < tol)
    return int(k[0]) if len(k) else None


def write_wahba_data(result: WahbaResult, npz_path: str | Path, json_path: str | Path) -> dict:
    """Write the error arrays to ``npz_path`` and `summarize` to ``json_path``; returns the summary."""
    meta = {k: v for k, v in asdict(result).items() if k not in _METHODS}
    io.write_npz(npz_path, **result.methods(), **{k: np.asarray(v) for k, v in meta.items()})
    summary = summarize(result)
    io.write_json(json_path, summary)
    return summary


def plot_wahba(result: WahbaResult, path: str | Path | None = None):
    """Fig. 2: angle error against iteration, log scale, every trial faint with the median bold
    (left: Algorithms 1 and 2); medians and 10-90 % bands of all four methods (right).

    Errors of exactly 0 are drawn at 1e-17 so that the log axis can show them. Returns the
    matplotlib Figure (built without pyplot, so it neither needs a display nor changes the
    backend of a notebook); writes it to ``path`` when given.
    """
    from matplotlib.figure import Figure

    floor = 1e-17
    it = np.arange(result.iterations + 1)
    colors = {
        "projected": "tab:blue",
        "multiplicative": "tab:orange",
        "newton": "tab:green",
        "projected_homogeneous": "tab:purple",
    }
    fig = Figure(figsize=(11, 4.2))
    axes = fig.subplots(1, 2, sharey=True)
    for name in ("projected", "multiplicative"):
        e = np.maximum(getattr(result, name), floor)
        axes[0].plot(it, e.T, color=colors[name], alpha=0.15, lw=0.6)
        axes[0].plot(it, np.median(e, axis=0), color=colors[name], lw=2.5, label=_LABELS[name])
    for name, e in result.methods().items():
        e = np.maximum(e, floor)
        lo, med, hi = np.percentile(e, [10, 50, 90], axis=0)
        axes[1].fill_between(it, lo, hi, color=colors[name], alpha=0.2, lw=0)
        axes[1].plot(it, med, color=colors[name], lw=2, marker="o", ms=3, label=_LABELS[name])
    for ax in axes:
        ax.set_yscale("log")
        ax.set_xlabel("iteration")
        ax.axhline(np.finfo(float).eps, color="k", ls=":", lw=0.8)
        ax.grid(True, which="major", alpha=0.4)
        ax.legend(fontsize=8, loc="center right")
    axes[0].set_ylabel("angle error to SVD solution (rad)")
    axes[0].set_title(f"Wahba's problem, {result.trials} trials (all trials + median)")
    axes[1].set_title("median and 10-90 % band")
    fig.tight_layout()
    if path is not None:
        io.save_figure(fig, path, dpi=150)
    return fig


def main_wahba(out_dir: str | Path, trials: int = 100, iterations: int = 12, seed: int = 0) -> dict:
    """Run the experiment and write ``out_dir``/wahba.npz, wahba.json and wahba.png.

    Prints a short summary and returns the summary dictionary.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    result = run_wahba(trials=trials, iterations=iterations, seed=seed)
    summary = write_wahba_data(result, out / "wahba.npz", out / "wahba.json")
    plot_wahba(result, out / "wahba.png")
    print(f"Wahba's problem: {trials} trials, {iterations} iterations, seed {seed}")
    print("median angle error to the SVD solution (rad) per iteration:")
    for name, s in summary["methods"].items():
        med = " ".join(f"{x:.1e}" for x in s["median_per_iteration"])
        order = s["median_order_estimate"]
        order_text = f"n/a ({s['median_order_note']})" if order is None else f"{order:.2f}"
        print(f"  {name:22s} {med}")
        print(f"  {'':22s} final median {s['final_median']:.2e}, order {order_text}")
        if "paper_fig2_mean_deg" in s:
            n = len(s["paper_fig2_mean_deg"])
            ours = " ".join(f"{x:.1e}" for x in s["mean_per_iteration_deg"][:n])
            paper = " ".join(f"{x:.1e}" for x in s["paper_fig2_mean_deg"])
            print(f"  {'':22s} mean (deg), iterations 0-{n - 1}: {ours}  (paper Fig. 2: {paper})")
    print(f"wrote {out / 'wahba.npz'}, {out / 'wahba.json'}, {out / 'wahba.png'}")
    return summary
