"""Derivatives of optimal Go2 hops through the solver against central differences of re-solves.

One `jtraj.differentiable` function (compiled once, module fixture) is evaluated at a few
parameter values; every finite difference re-solves from the solution at tight tolerance.
"""

import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jaxlie import SO3

import jtraj  # noqa: F401  (float64)
from jtraj.differentiate import differentiable
from jtraj.sensitivity import kkt_system
from jtraj.task import Phase, Task

FEET = ("FL_foot", "FR_foot", "RL_foot", "RR_foot")
TAKE_OFF = 3  # first knot of the flight phase: its velocity is the take-off velocity


#: what `hop`'s differentiable() said on stderr as it was built (this process's fixture)
BUILD_LINES: list[str] = []


@pytest.fixture(scope="module")
def hop():
    import contextlib
    import io

    task = Task(
        name="hop", robot="go2", timestep=0.05,
        phases=(Phase(FEET, 0.15), Phase((), 0.1), Phase(FEET, 0.15)),
        target_translation=(0.1, 0.0, 0.0), configuration_weight=1.0, acceleration_weight=1e-3,
    )
    with contextlib.redirect_stderr(io.StringIO()) as err:
        f = differentiable(task)
    BUILD_LINES[:] = err.getvalue().splitlines()
    return f


def test_what_compiles_is_said_before_it_does(hop):
    """The exact Hessian's build and the first forward solve compiled for minutes without a
    line (the first derivative's line: tests/test_sensitivity.py)."""
    from jtraj.differentiate import DifferentiableTask

    assert len(BUILD_LINES) == 2 and "hop on go2 with SE(3) tangent" in BUILD_LINES[0] and "compiling the exact Hessian" in BUILD_LINES[0]
    assert BUILD_LINES[1].startswith("jtraj.differentiable: hop: the exact Hessian built in ")
    said: list[str] = []
    f = DifferentiableTask(hop.transcription, hop.nlp, hop.backend, hop.options, 1e-6, said.append)
    f()
    f()
    assert len(said) == 2 and said[0] == "jtraj.differentiable: hop: first forward solve with ipopt (compiles the NLP's functions, once)"
    assert said[1].startswith("jtraj.differentiable: hop: solved in ") and " iterations, " in said[1]


def peak_joint_torque(m):
    return jnp.max(jnp.abs(m.tau[:, 6:]))


def take_off_vertical_velocity(m):
    # body twist -> world linear velocity of the base at take-off
    return SO3(m.base_xyz_wxyz[TAKE_OFF, 3:]).apply(m.v[TAKE_OFF, :3])[2]


def cost(m):
    return m.cost


def with_entry(theta, field, index, value):
    arr = np.array(getattr(theta, field), float)
    arr[index] = value
    return theta.replace(**{field: arr})


def gradient_and_difference(f, theta, field, index, scalar, eps):
    """(d scalar / d theta.field[index] through the solver, its central difference)."""
    m = f(theta)
    x_star = np.asarray(m.x)
    grad = jax.grad(lambda th: scalar(f(th)))(theta)
    g = float(np.asarray(getattr(grad, field))[index])
    base = float(np.asarray(getattr(theta, field))[index])
    values = []
    for sign in (1.0, -1.0):
        f.warm_start_from(x_star)
        values.append(float(scalar(f(with_entry(theta, field, index, base + sign * eps)))))
    f.warm_start_from(x_star)
    return g, (values[0] - values[1]) / (2 * eps), m


def active_groups(f, m, theta):
    """Names of the constraint groups with a row active at the solution (and not dropped)."""
    s = kkt_system(f.nlp, np.asarray(m.x), np.asarray(m.lam), theta)
    inequality = f.nlp.g_lower != f.nlp.g_upper
    return set(f.nlp.row_group[s.active.row_active & inequality].tolist()), s.active


CASES = {
    # name: (theta overrides, field, index, scalar, eps, inequality groups that must be active,
    #        the groups with weakly active rows)
    # At the task's own theta a joint torque limit and friction facets are active.
    "cost/target_x": ({}, "target_translation", 0, cost, 1e-4, {"dynamics", "friction"}, set()),
    "take_off_vz/trunk_mass": ({}, "body_masses", 1, take_off_vertical_velocity, 1e-4, {"dynamics", "friction"}, set()),
    # At mu = 0.3 two friction facets are weakly active (flagged degenerate); measured, the
    # one-sided derivative agrees with the central difference to 3e-6 there.
    "peak_torque/friction": ({"friction": 0.3}, "friction", (), peak_joint_torque, 1e-5, {"friction"}, {"friction"}),
}


@pytest.mark.parametrize("case", list(CASES))
def test_derivative_matches_resolved_central_difference(hop, case):
    overrides, field, index, scalar, eps, must_be_active, weak_groups = CASES[case]
    theta = hop.theta
    theta = theta.replace(**overrides)
    g, g_fd, m = gradient_and_difference(hop, theta, field, index, scalar, eps)
    groups, active = active_groups(hop, m, theta)
    weak = set(hop.nlp.row_group[active.weak_rows].tolist())
    print(f"{case}: through the solver {g:.8e}, central difference {g_fd:.8e}, rel. {abs(g - g_fd) / abs(g_fd):.1e}; active {sorted(groups)}, weak {sorted(weak)}")
    assert must_be_active <= groups, f"{case}: expected {must_be_active} active, got {groups}"
    assert weak == weak_groups, f"{case}: weakly active rows in {weak}, {active.summary()}"
    assert bool(m.degenerate) == bool(weak)  # a weakly active row is reported, and only then
    assert abs(g - g_fd) <= 1e-4 * abs(g_fd)


def test_grad_composes_with_jit_and_jvp_agrees(hop):
    theta = hop.theta

    def loss(th):
        m = hop(th)
        return m.cost + 0.01 * take_off_vertical_velocity(m) ** 2

    g = jax.grad(loss)(theta)
    g_jit = jax.jit(jax.grad(loss))(theta)
    # the entries of theta with no derivative at this solution are arbitrary (whichever solution
    # of the singular transposed system the LU gives, NotDifferentiableWarning): compared,
    # they differed between the two solves with the rounding of the code (target_translation[2],
    # -0.0082240 against -0.0082240172)
    from jtraj.sensitivity import entry_names, undifferentiable_parameters

    m = hop(theta)
    s = kkt_system(hop.nlp, np.asarray(m.x), np.asarray(m.lam), theta)
    arbitrary = set(undifferentiable_parameters(hop.nlp, s, np.asarray(m.x), np.asarray(m.lam), theta))
    assert "target_translation[2]" in arbitrary
    flat = lambda tree: np.concatenate([np.ravel(leaf) for leaf in jax.tree.leaves(tree)])  # noqa: E731
    compared = 0
    for name, a, b in zip(entry_names(theta), flat(g), flat(g_jit), strict=True):
        if name in arbitrary:
            continue
        # the jitted loss re-solves (warm-started): the solutions agree to Ipopt's tolerance
        np.testing.assert_allclose(b, a, rtol=1e-6, atol=1e-9, err_msg=name)
        compared += 1
    assert compared > 10
    direction = jax.tree.map(jnp.zeros_like, theta).replace(target_translation=jnp.array([1.0, 0.5, 0.0]), friction=jnp.array(1.0))
    _, dloss = jax.jvp(loss, (theta,), (direction,))
    expected = sum(float(jnp.vdot(a, b)) for a, b in zip(jax.tree.leaves(g), jax.tree.leaves(direction)))
    np.testing.assert_allclose(float(dloss), expected, rtol=1e-6, atol=1e-9)


def test_first_call_can_be_under_grad(hop):
    """The README's ``jax.grad(lambda th: f(th).cost)(f.theta)`` as the function's first call:
    the forward solve builds the task's warm start in numpy, inside the eager gradient's rule
    (regression: TracerArrayConversionError when no solve had run before)."""
    theta = hop.theta
    hop.warm_start_from(None)
    g_first = jax.grad(lambda th: hop(th).cost)(theta)
    hop.warm_start_from(None)
    hop(theta)  # the way the other tests call it: a solve first, then the gradient
    g_after = jax.grad(lambda th: hop(th).cost)(theta)
    for a, b in zip(jax.tree.leaves(g_first), jax.tree.leaves(g_after), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-9)


def test_bad_arguments_are_refused_before_building(monkeypatch):
    """differentiable() checks its numbers and its solver before it builds the task's NLP."""
    import jtraj.differentiate as D

    monkeypatch.setattr(D.tasks, "load", lambda task: pytest.fail("the task was loaded before the arguments were checked"))
    for kwargs, match in [
        ({"force_weight": float("nan")}, "force_weight must be a finite number > 0"),
        ({"force_weight": "1e-3"}, "force_weight must be a finite number > 0"),
        ({"force_weight": 0.0}, "force_weight must be a finite number > 0"),
        ({"weak_tol": -1}, r"weak_tol must be a number in \[0, 1\)"),
        ({"weak_tol": "x"}, r"weak_tol must be a number in \[0, 1\)"),
        ({"progress": "no"}, r"progress='no': expected True or False"),
    ]:
        with pytest.raises(ValueError, match=match):
            differentiable("hop", **kwargs)
    with pytest.raises(ValueError, match="bogus"):
        differentiable("hop", solver="bogus")
    # and its parameterization and variables (they were looked up after the task and the robot were loaded)
    with pytest.raises(ValueError, match="unknown parameterization 'bogus'"):
        differentiable("hop", "bogus")
    with pytest.raises(ValueError, match="unknown variables 'bogus'"):
        differentiable("hop", variables="bogus")


def test_forward_options_keep_the_tight_defaults_a_dict_does_not_change():
    from jtraj import solvers
    from jtraj.differentiate import IPOPT_OPTIONS, forward_options

    ipopt = solvers.get("ipopt")
    merged = forward_options(ipopt, {"max_iter": 50})
    assert merged.max_iter == 50 and merged.tol == IPOPT_OPTIONS["tol"] == 1e-10 and merged.hessian == "exact"
    assert forward_options(ipopt, None) == ipopt.options(IPOPT_OPTIONS)
    given = solvers.IpoptOptions(tol=1e-4)
    assert forward_options(ipopt, given) is given or forward_options(ipopt, given) == given


def test_options_assigned_as_a_dict_keep_the_tight_defaults(hop):
    """``f.options = {...}`` takes a dict as differentiable(options=...) does (regression: the
    dict went to Ipopt as it was, with Ipopt's tol 1e-8 and L-BFGS instead of IPOPT_OPTIONS)."""
    from jtraj import solvers
    from jtraj.differentiate import IPOPT_OPTIONS

    options = hop.options
    try:
        hop.options = {"max_iter": 50}
        assert isinstance(hop.options, solvers.IpoptOptions)
        assert hop.options.max_iter == 50 and hop.options.tol == IPOPT_OPTIONS["tol"] and hop.options.hessian == "exact"
        with pytest.raises(ValueError, match="max_iter"):
            hop.options = {"max_iter": -1}
    finally:
        hop.options = options
    assert hop.options is options


def test_call_checks_theta_and_a_failed_solve_raises_solve_error(hop):
    import dataclasses

    from jtraj.differentiate import SolveError

    theta = hop.theta
    # the mapping form jtraj.solve takes: the same solution as the TaskParams it stands for
    hop.warm_start_from(None)
    m_dict = hop({"friction": 0.6})
    hop.warm_start_from(None)
    m_params = hop(theta.replace(friction=0.6))
    np.testing.assert_array_equal(np.asarray(m_dict.x), np.asarray(m_params.x))
    assert float(m_dict.cost) != float(hop(theta).cost)  # the override took effect
    # impossible values and shapes are refused before a solve
    solves = hop.last_solution
    with pytest.raises(ValueError, match="friction"):
        hop(theta.replace(friction=-1.0))
    with pytest.raises(ValueError, match="timestep"):
        hop({"timestep": -0.05})
    with pytest.raises(ValueError, match="shape"):
        hop({"friction": [0.6, 0.6]})
    with pytest.raises(TypeError, match="theta must be"):
        hop([0.6])
    with pytest.raises(ValueError, match="sets no max_delta_force"):  # as jtraj.solve refuses it
        hop({"max_delta_force": 100.0})
    with pytest.raises(ValueError, match="sets no max_delta_force"):  # also as a field of TaskParams (it was ignored)
        hop(theta.replace(max_delta_force=100.0))
    # inf (no bound) is what the task says, in either form
    assert hop.transcription.resolve_theta({"max_delta_force": np.inf}).max_delta_force == np.inf
    assert hop.transcription.resolve_theta(theta.replace(max_delta_force=np.inf)).max_delta_force == np.inf
    assert hop.last_solution is solves
    with pytest.raises(ValueError, match=r"warm start of shape \(5,\)"):
        hop.warm_start_from(np.zeros(5))
    # a forward solve that stops short raises SolveError itself, catchable as such
    options = hop.options
    hop.options = dataclasses.replace(options, max_iter=1)
    hop.warm_start_from(None)
    try:
        with pytest.raises(SolveError, match="did not converge"):
            hop(theta)
    finally:
        hop.options = options
    assert not hop.last_solution.status.converged


def test_theta_with_a_zero_cost_weight_is_refused(hop):
    """differentiable() refuses a task without positive configuration and acceleration weights
    (no unique optimum); theta sets them too, and is refused the same way (regression: with
    acceleration_weight 0, d cost / d target x came back 0.025 where re-solving gives 0.037)."""
    solves = hop.last_solution
    for weight in ("acceleration_weight", "configuration_weight"):
        with pytest.raises(ValueError, match=f"{weight}=0.0.*need configuration_weight > 0 and acceleration_weight > 0"):
            jax.grad(lambda th: hop(th).cost)(hop.theta.replace(**{weight: 0.0}))
    assert hop.last_solution is solves  # refused before a solve


def test_a_target_off_the_terrain_is_refused_before_a_solve(hop):
    """jtraj.solve refuses a target that lifts the last knot's feet; the differentiable task
    ran the solver to an infeasible stop (33 iterations) instead, also under jax.grad."""
    solves = hop.last_solution
    raised = hop.theta.replace(target_translation=jnp.asarray(hop.theta.target_translation) + jnp.array([0.0, 0.0, 0.3]))
    said = r"theta.target_translation and theta.target_rotation_rpy: the pose they give puts \w+ 0.3 m above the terrain at the last knot"
    with pytest.raises(ValueError, match=said):
        hop(raised)
    with pytest.raises(ValueError, match=said):
        jax.grad(lambda th: hop(th).cost)(raised)
    assert hop.last_solution is solves


def test_a_solve_stopped_at_the_acceptable_level_warns(hop):
    """Ipopt's acceptable level (violation and complementarity up to 1e-2) is "converged" to
    the Status, but the derivatives at such a point may be wrong: it warns, not silently
    (regression: the motion and its derivatives came back without a word). This one, accepted
    at thresholds of 1e3 after its first iterations, is then refused as no KKT point
    (violation 3.3): its derivatives would have been of no solution."""
    from jtraj.differentiate import forward_options
    from jtraj.sensitivity import NotAKKTPointError

    options = hop.options
    hop.options = forward_options(hop.backend, {"acceptable_iter": 1, "acceptable_tol": 1e3, "acceptable_constr_viol_tol": 1e3, "acceptable_compl_inf_tol": 1e3})
    hop.warm_start_from(None)
    try:
        with pytest.warns(RuntimeWarning, match="approximate solution"), pytest.raises(NotAKKTPointError, match=r"infeasibility \d"):
            hop(hop.theta)
    finally:
        hop.options = options
        hop.warm_start_from(None)
    assert hop.last_solution.status.value == "acceptable"


@pytest.fixture(scope="module")
def hop_jtraj(hop):
    """The same hop with jtraj's solver for the forward solve (its tight defaults)."""
    return differentiable(hop.transcription.task, solver="jtraj")


@pytest.mark.parametrize("case", ["cost/target_x", "take_off_vz/trunk_mass"])
def test_jtraj_solver_gives_ipopts_derivatives(hop, hop_jtraj, case):
    """With `JTRAJ_OPTIONS` jtraj's solver solves the hop as tightly as Ipopt, in as few
    iterations, and the derivatives agree (regression: with its study defaults, tol 1e-3, they
    agreed to 1e-3 only; at tol 1e-10 without the floor under delta_c the solve stopped at 500
    iterations, and with a floor of 1e-9 it took 211, Ipopt 15)."""
    _, field, index, scalar, _, _, _ = CASES[case]
    theta = hop.theta
    hop_jtraj.warm_start_from(None)
    m = hop_jtraj(theta)
    sol = hop_jtraj.last_solution
    assert sol.status.value == "solved" and sol.constraint_violation < 1e-9
    assert sol.stats.iterations <= 30, f"{sol.stats.iterations} iterations (Ipopt: 15 on this hop)"
    g = jax.grad(lambda th: scalar(hop_jtraj(th)))(theta)
    g_ipopt = jax.grad(lambda th: scalar(hop(th)))(theta)
    a, b = float(np.asarray(getattr(g, field))[index]), float(np.asarray(getattr(g_ipopt, field))[index])
    print(f"{case}: jtraj's solver {a:.10e}, Ipopt {b:.10e}; {sol.stats.iterations} iterations")
    assert abs(a - b) <= 1e-6 * abs(b)
    np.testing.assert_allclose(float(m.cost), float(hop(theta).cost), rtol=1e-8)


def test_forward_options_of_jtraj_keep_its_tight_defaults():
    from jtraj import solvers
    from jtraj.differentiate import JTRAJ_OPTIONS, forward_options

    jt = solvers.get("jtraj")
    merged = forward_options(jt, {"max_iter": 50})
    assert merged.max_iter == 50 and merged.tol == JTRAJ_OPTIONS["tol"] == 1e-10 and merged.hessian == "exact" and merged.delta_c_min == 1e-7
    assert forward_options(jt, None) == jt.options(JTRAJ_OPTIONS)
    given = solvers.IpmOptions(tol=1e-4)
    assert forward_options(jt, given) == given


@pytest.mark.heavy  # 107 s on a 2-core AVX2 machine; vmap of the gradient: the jtraj solver's test below
def test_vmap_over_theta_gives_each_members_solution_and_gradient(hop):
    """``jax.vmap`` of the optimal motion and of its gradient over a batch of parameters: each
    member is the one solved alone (the forward solves run one after another in the callback;
    the backward passes' linear solves take the batch at once)."""
    theta = hop.theta
    frictions = jnp.array([0.6, 0.9])

    def loss(friction):
        return hop(theta.replace(friction=friction)).cost

    values = jax.vmap(loss)(frictions)
    grads = jax.vmap(jax.grad(loss))(frictions)
    for i, friction in enumerate(frictions):
        np.testing.assert_allclose(float(values[i]), float(loss(friction)), rtol=1e-7)
        np.testing.assert_allclose(float(grads[i]), float(jax.grad(loss)(friction)), rtol=1e-6, atol=1e-9)
    assert float(values[0]) > float(values[1])  # a lower friction makes the hop dearer


def test_vmap_with_jtraj_solver_solves_the_batch_side_by_side(hop_jtraj, monkeypatch):
    """With jtraj's solver, ``jax.vmap`` over theta hands the batch to threads that solve its
    members side by side (the program compiled once); each member equals its solve alone."""
    from concurrent import futures

    pools = []
    real = futures.ThreadPoolExecutor

    def counting(workers, *args, **kwargs):
        pools.append(workers)
        return real(workers, *args, **kwargs)

    monkeypatch.setattr(futures, "ThreadPoolExecutor", counting)
    theta = hop_jtraj.theta
    frictions = jnp.array([0.6, 0.9])

    def loss(friction):
        return hop_jtraj(theta.replace(friction=friction)).cost

    grads = jax.vmap(jax.grad(loss))(frictions)
    assert pools and pools[0] == min(2, os.cpu_count() or 1)
    for i, friction in enumerate(frictions):
        np.testing.assert_allclose(float(grads[i]), float(jax.grad(loss)(friction)), rtol=1e-6, atol=1e-9)
