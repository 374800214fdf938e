"""`jtraj.solvers.stage.StageView` of a tiny NLP with parameters: ``theta=None`` is the NLP's
own default theta, as in `KnotNLP.dense_jacobian` and `KnotNLP.violation`."""

import jax.numpy as jnp
import numpy as np

from jtraj.nlp import ConstraintGroup, CostGroup, Dep, KnotNLP, Layout
from jtraj.solvers.stage import StageView

N = 3  # knots
THETA = {"w": jnp.asarray(2.0), "band": jnp.asarray(0.5)}


def _view():
    """x_{k+1} - x_k - u_k within +-band, cost w |u_k|^2; variables within [-1, 1]."""
    step = ConstraintGroup(
        "step", (Dep("x"), Dep("u"), Dep("x", 1)), lambda theta, data, x, u, x1: x1 - x - u, np.arange(N - 1),
        lambda theta: -theta["band"], lambda theta: theta["band"], np.ones((N - 1, 2), bool),
    )
    effort = CostGroup("effort", (Dep("u"),), lambda theta, data, u: theta["w"] * jnp.sum(u**2), np.arange(N))
    layout = Layout((("x", 2), ("u", 1)))
    return StageView(KnotNLP(layout, N, [effort], [step], np.full((N, 3), -1.0), np.full((N, 3), 1.0), theta=THETA))


def test_theta_none_is_the_nlps_default():
    """Every method gave theta=None to the NLP's functions, which read theta['w']: a TypeError
    ('NoneType' object is not subscriptable) though None is each method's default."""
    view = _view()
    Z = jnp.asarray(np.random.default_rng(0).uniform(-1.0, 1.0, (N, 3)))
    Y = jnp.ones((view.K, view.m))
    for default, given in [
        (view.bounds(), view.bounds(THETA)),
        (view.values(Z), view.values(Z, THETA)),
        (view.derivatives(Z), view.derivatives(Z, THETA)),
        ((view.hessian(Z, Y),), (view.hessian(Z, Y, theta=THETA),)),
    ]:
        for a, b in zip(default, given):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert float(view.bounds()[3][0, 0]) == 0.5  # the band of THETA
    assert float(view.values(Z)[0]) == 2.0 * float(jnp.sum(Z[:, 2] ** 2))
