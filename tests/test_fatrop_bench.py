"""bench/fatrop.py: the stage form of a small Go2 hop is the same problem, and FATROP solves it.

casadi comes with the ``bench`` extra, which the ``test`` extra includes, so CI runs these;
an environment without it skips them."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import bench_module

casadi = pytest.importorskip("casadi")


@pytest.fixture(scope="module")
def hop():
    F = bench_module("fatrop")
    from jtraj import solver
    from jtraj.task import Phase, Task

    feet = ("FL_foot", "FR_foot", "RL_foot", "RR_foot")
    # max_delta_force: the force-rate rows read the next knot's controls (the memory states)
    task = Task(name="hop", robot="go2", timestep=0.05, phases=(Phase(feet, 0.15), Phase((), 0.1), Phase(feet, 0.15)), target_translation=(0.1, 0.0, 0.0), max_delta_force=50.0)
    prep = solver.prepare(task, "se3")
    form = F.stage_form(prep.nlp)
    return F, prep, form


def _rollout(prep, rng):
    """Original variables whose knots follow the step exactly (random controls)."""
    nlp, st = prep.nlp, prep.nlp.structure
    Z = prep.transcription.warm_start().copy()
    Z[:, st.control_columns] += 0.3 * rng.standard_normal((nlp.n_knots, st.nu))
    x = jnp.asarray(Z[0, st.state_columns])
    for k in range(nlp.n_knots - 1):
        x = st.step(x, jnp.asarray(Z[k, st.control_columns]), nlp.theta)
        Z[k + 1, st.state_columns] = np.asarray(x)
    return Z.reshape(-1)


@pytest.mark.slow
def test_stage_form_has_the_original_rows_where_the_dynamics_hold(hop, rng):
    F, prep, form = hop
    nlp, stage, theta = prep.nlp, form.nlp, prep.nlp.theta
    x = _rollout(prep, rng)
    z = form.lift(x)
    np.testing.assert_array_equal(form.drop(z), x)
    assert float(stage.objective(jnp.asarray(z), theta)) == pytest.approx(float(nlp.objective(jnp.asarray(x), theta)), rel=1e-12)
    g, c = np.asarray(nlp.constraints(jnp.asarray(x), theta)), np.asarray(stage.constraints(jnp.asarray(z), theta))
    assert np.abs(g[nlp.row_group == "integration"]).max() < 1e-9
    assert np.abs(c[stage.row_group == F.GAP]).max() < 1e-9
    for name in ("dynamics", "contact", "stationary", "force_rate", "friction"):
        np.testing.assert_allclose(c[stage.row_group == name], g[nlp.row_group == name], rtol=1e-9, atol=1e-9, err_msg=name)


@pytest.mark.slow
@pytest.mark.heavy  # 97 s on a 2-core AVX2 machine; FATROP's solve of the hop (last test) rests on this structure
def test_stage_structure_is_what_fatrop_needs(hop, rng):
    F, prep, form = hop
    stage, theta = form.nlp, prep.nlp.theta
    z = form.lift(_rollout(prep, rng))
    J = stage.dense_jacobian(z, theta)[form.perm]
    stage_of_col = np.arange(stage.n) // stage.nz
    nX = form.nx[0]
    row = 0
    for k in range(form.N + 1):
        if k < form.N:  # gap rows: identity in x_{k+1}, nothing else of stage k+1
            nxt = J[row : row + nX][:, stage_of_col == k + 1]
            np.testing.assert_array_equal(nxt[:, :nX], np.eye(nX))
            assert not nxt[:, nX:].any() and not J[row : row + nX][:, (stage_of_col != k) & (stage_of_col != k + 1)].any()
            row += nX
        assert not J[row : row + form.ng[k]][:, stage_of_col != k].any()
        row += form.ng[k]
    assert row == form.perm.size
    # the Lagrangian's Hessian is block diagonal by stage; the callbacks give its full symmetric values
    ev = F._Evaluator(form, theta)
    lam = rng.standard_normal(ev.m)
    H = np.array(casadi.DM(ev.hess_sp, ev.hess(z, 0.5, lam)).full())
    lam_nlp = ev._lam(lam)
    exact = np.asarray(jax.hessian(lambda v: 0.5 * stage._objective_py(v, theta) + jnp.dot(lam_nlp, stage._constraints_py(v, theta)))(jnp.asarray(z)))
    np.testing.assert_allclose(H, exact, atol=1e-8 * np.abs(exact).max())
    assert not exact[stage_of_col[:, None] != stage_of_col[None, :]].any()
    np.testing.assert_allclose(ev.grad_lagrangian(z, 0.5, lam), np.asarray(jax.grad(lambda v: 0.5 * stage._objective_py(v, theta) + jnp.dot(lam_nlp, stage._constraints_py(v, theta)))(jnp.asarray(z))), atol=1e-8)


@pytest.mark.slow
def test_fatrop_solves_the_hop_to_the_original_nlp_tolerance(hop):
    F, prep, form = hop
    nlp, tr, theta = prep.nlp, prep.transcription, prep.nlp.theta
    x0 = tr.warm_start().reshape(-1)
    reduced = F.drop_dependent(form, x0, theta)
    # the feet's rows at knot N-1 follow from q_{N-1} = q_N (v_N = 0 and q_N fixed); constants at knots 0 and N
    assert reduced.dropped == {"contact": 12, "stationary": 8}
    rec = F.solve_fatrop(reduced, x0, theta, tol=1e-3, max_iter=50)
    assert rec["success"] and rec["iterations"] < 50
    assert nlp.violation(rec["x"], theta) < 1e-4  # every row of the original NLP, the left-out ones included
