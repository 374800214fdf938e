"""bench/quaternion_noise.py: its renormalization of the warm start's quaternions, and its table."""

import numpy as np
import pytest
from conftest import bench_module


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
