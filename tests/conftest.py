"""Shared test helpers. jtraj enables float64 on import; import it first."""

import numpy as np
import pytest

import jtraj  # noqa: F401  (float64)


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


def central_difference(f, x, eps=1e-6):
    """Central finite-difference Jacobian of f at x (numpy in, numpy out)."""
    x = np.asarray(x, dtype=float)
    f0 = np.asarray(f(x))
    J = np.zeros(f0.shape + x.shape)
    for i in np.ndindex(x.shape):
        dx = np.zeros_like(x)
        dx[i] = eps
        J[(...,) + i] = (np.asarray(f(x + dx)) - np.asarray(f(x - dx))) / (2 * eps)
    return J


def random_unit_vectors(rng, n, dim=3):
    v = rng.normal(size=(n, dim))
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def pytest_collection_modifyitems(session, config, items):
    """Run the rendering tests last.

    Drawing with Mesa's software EGL (llvmpipe) loads Mesa's own LLVM into the test process.
    Two full CI runs crashed (segmentation fault) inside XLA later in the same process; a run
    of the rendering tests followed by the crashing test passed, so this ordering is a
    precaution (see also vm.max_map_count in .ci/run), not a proven fix.
    """
    items.sort(key=lambda item: item.nodeid.startswith("tests/test_render.py"))
