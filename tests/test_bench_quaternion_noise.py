"""bench/quaternion_noise.py: its renormalization of the warm start's quaternions, its angles
and its table; and `jtraj.experiments.poses_in_chart`, with which it gives one chart another's
noisy poses."""

import jax.numpy as jnp
import numpy as np
import pytest
from conftest import bench_module

from jtraj.experiments import poses_in_chart


@pytest.fixture(scope="module")
def qn():
    return bench_module("quaternion_noise")


def test_unit_quaternions_normalizes_rho_alone(qn):
    rng = np.random.default_rng(0)
    starts = rng.normal(size=(2, 5, 12))  # draws, knots, nz with q = columns 2:11
    q = slice(2, 11)
    out = qn.unit_quaternions(starts, q)
    np.testing.assert_allclose(np.linalg.norm(out[..., 5:9], axis=-1), 1.0)
    np.testing.assert_allclose(out[..., 5:9] * np.linalg.norm(starts[..., 5:9], axis=-1, keepdims=True), starts[..., 5:9])
    keep = np.r_[0:5, 9:12]
    np.testing.assert_array_equal(out[..., keep], starts[..., keep])
    assert not np.shares_memory(out, starts)


def test_table_counts_each_mode(qn):
    records = [dict(parameterization="quat1", mode=m, converged=c, success=c and r > 0, iterations=it) for m, cs in (("raw", (1, 1, 0)), ("unit", (1, 0, 0))) for r, (c, it) in enumerate(zip(map(bool, cs), (70, 90, 200)))]
    lines = qn.table(records).splitlines()
    assert lines[2] == "| quat1 | raw | 2 / 3 | 1 / 3 | 80 |"
    assert lines[3] == "| quat1 | unit | 1 / 3 | 0 / 3 | 70 |"


def test_table_median_of_an_even_count_is_not_rounded(qn):
    """Two converged runs of 12 and 13 iterations: their median is 12.5, which ``:.0f`` showed
    as 12 (and 13.5 as 14: Python rounds half to even), a figure no run took."""
    records = [dict(parameterization="quat1", mode="raw", converged=True, success=True, iterations=it) for it in (12, 13)]
    records += [dict(parameterization="quat1", mode="unit", converged=True, success=True, iterations=it) for it in (13, 14)]
    lines = qn.table(records).splitlines()
    assert lines[2] == "| quat1 | raw | 2 / 2 | 2 / 2 | 12.5 |"
    assert lines[3] == "| quat1 | unit | 2 / 2 | 2 / 2 | 13.5 |"

def _charts():
    import types

    from jtraj import parameterization
    from jtraj.nlp import Layout

    se3 = types.SimpleNamespace(param=parameterization.get("se3"), layout=Layout(slots=(("q", 8), ("v", 8), ("f", 3))))
    quat = types.SimpleNamespace(param=parameterization.get("quat1"), layout=Layout(slots=(("q", 9), ("v", 8), ("f", 3))))
    return se3, quat


def test_se3_draws_become_the_same_poses_in_the_quaternion_chart():
    se3, quat = _charts()
    rng = np.random.default_rng(1)
    starts = rng.normal(size=(3, 4, se3.layout.nz))  # draws, knots, nz: base xi (6) + 2 joints
    out = poses_in_chart(starts, se3, quat)
    assert out.shape == (3, 4, quat.layout.nz)
    for xi, q in zip(starts.reshape(-1, se3.layout.nz), out.reshape(-1, quat.layout.nz)):
        a, b = se3.param.to_pose(jnp.asarray(xi[:6])), quat.param.to_pose(jnp.asarray(q[:7]))
        np.testing.assert_allclose(np.asarray(b.translation()), np.asarray(a.translation()), atol=1e-12)
        np.testing.assert_allclose(np.asarray(b.rotation().as_matrix()), np.asarray(a.rotation().as_matrix()), atol=1e-12)
        np.testing.assert_allclose(np.linalg.norm(q[3:7]), 1.0)
    np.testing.assert_array_equal(out[..., 7:9], starts[..., 6:8])  # joint angles
    np.testing.assert_array_equal(out[..., 9:], starts[..., 8:])  # the other slots


def test_rotation_noise_is_the_angle_to_the_clean_orientation_at_interior_knots(qn):
    _, quat = _charts()
    clean = np.zeros((5, quat.layout.nz))
    clean[:, 3] = 1.0  # identity quaternions
    turned = np.repeat(clean[None], 2, axis=0)
    angles = np.array([[0.3, 1.0, 2.5], [0.0, 0.1, 3.0]])
    # rho of a turn by a about z, scaled: the chart normalizes rho, so its norm changes nothing
    turned[:, 1:-1, 3] = 2 * np.cos(angles / 2)
    turned[:, 1:-1, 6] = 2 * np.sin(angles / 2)
    turned[:, [0, -1], 6] = 1.0  # the end knots are not counted
    np.testing.assert_allclose(qn.rotation_noise(quat, turned, clean), angles, atol=1e-9)


def test_poses_in_chart_round_trip():
    """The quaternion chart's poses written as SE(3) coordinates and back are the same poses."""
    se3, quat = _charts()
    rng = np.random.default_rng(2)
    starts = rng.normal(size=(2, 3, quat.layout.nz))
    xi = poses_in_chart(starts, quat, se3)
    back = poses_in_chart(xi, se3, quat)
    rho, rho_back = starts[..., 3:7], back[..., 3:7]
    # the same rotation: rho / |rho| equal up to sign
    dots = np.abs(np.sum(rho * rho_back, axis=-1)) / np.linalg.norm(rho, axis=-1)
    np.testing.assert_allclose(dots, 1.0, atol=1e-9)
    np.testing.assert_allclose(back[..., :3], starts[..., :3], atol=1e-9)
    np.testing.assert_array_equal(back[..., 7:], starts[..., 7:])


def test_poses_in_chart_keeps_the_references_sign_of_rho():
    """A flip's quaternion warm start passes from rho to -rho; written from SE(3) poses, each
    knot keeps the sign nearer the reference's, not `from_pose`'s representative."""
    se3, quat = _charts()
    angles = np.linspace(0.0, 2 * np.pi, 5)  # a full turn about y
    xi = np.zeros((5, se3.layout.nz))
    reference = np.zeros((5, quat.layout.nz))
    reference[:, 3], reference[:, 5] = np.cos(angles / 2), np.sin(angles / 2)  # continuous: ends at -1
    xi[:, 4] = np.arctan2(np.sin(angles), np.cos(angles))  # the same rotations, principal angles
    out = poses_in_chart(xi[None], se3, quat, reference)[0]
    np.testing.assert_allclose(out[:, 3:7], reference[:, 3:7], atol=1e-9)
    unaligned = poses_in_chart(xi[None], se3, quat)[0]
    assert np.abs(unaligned[:, 3:7] - reference[:, 3:7]).max() > 1.0  # from_pose alone picks other signs
