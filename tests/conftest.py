"""Shared test helpers. jtraj enables float64 on import; import it first."""

import importlib.util
import os
import sys
from pathlib import Path

# The suite is bound by XLA compiles of small problems, and two flags make them cheaper; the
# programs run slower, which small problems do not feel. LLVM's optimization level 0 compiles
# about a fifth faster (measured: an interior-point test 32.7 -> 25.7 s, the Go2-hop
# convergence test 69.7 -> 51.7 s). XLA's CPU loop emitters instead of its fusion emitters:
# 87.4 -> 64.2 s for an interior-point vmap test, a Talos Jacobian test and a Go2 NLP build
# together (2026-11-28, no compilation cache), and `.ci/run` on a clean clone went from
# 27 min 56 s (pytest 25:24) to 18 min 8 s (pytest 15:33). Set before the first computation
# (XLA reads the flags then); notebook kernels inherit them. A flag already in XLA_FLAGS wins.
for _flag, _value in (("xla_backend_optimization_level", "0"), ("xla_cpu_use_fusion_emitters", "false")):
    if _flag not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + f" --{_flag}={_value}").strip()

# Two CPU devices whatever the machine (`jtraj.config.split_cpu` gives one per core): the vmapped
# interior point's split over devices is what the tests check.
os.environ.setdefault("JTRAJ_CPU_DEVICES", "2")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

import jtraj  # noqa: E402, F401  (float64, the CPU devices)


@pytest.fixture(autouse=True)
def _accelerator_setting_put_back():
    """`jtraj.cli.main` with --workers > 1 or --executor ray sets XLA_PYTHON_CLIENT_PREALLOCATE in
    the process (`jtraj.executors.share_the_accelerator`): put back as it was after each test,
    so that no test sees another's setting."""
    name = "XLA_PYTHON_CLIENT_PREALLOCATE"
    before = os.environ.get(name)
    yield
    if before is None:
        os.environ.pop(name, None)
    else:
        os.environ[name] = before


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


def bench_module(name: str):
    """``bench/NAME.py`` imported as the module ``bench_NAME`` (bench/ is not a package); it is
    registered in ``sys.modules``, where dataclasses defined in it look their module up."""
    path = Path(__file__).resolve().parents[1] / "bench" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"bench_{name}", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def mujoco_contact_positions(robot, qpos) -> np.ndarray:
    """World positions (P, 3) of a robot's contact points at MuJoCo coordinates ``qpos``, by
    MuJoCo's own forward kinematics (not jtraj's JAX kinematics): each point is its body's
    frame applied to its offset there."""
    import mujoco

    m = robot.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = qpos
    mujoco.mj_kinematics(m, d)
    b = robot.contact_body_ids
    return d.xpos[b] + np.einsum("cij,cj->ci", d.xmat[b].reshape(-1, 3, 3), robot.contact_offsets)


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


#: Seconds each test file took in one worker (`pytest --durations=0`, 2026-11-27, 2 cores),
#: rounded. Files go to the two workers heaviest first (``--no-loadscope-reorder`` keeps this
#: order): the workers then finish together. xdist's own order (most tests first) sent the
#: notebooks and the differentiation tests last, and one worker ran alone for minutes.
FILE_SECONDS = {
    "test_transcription.py": 610, "test_differentiable.py": 480, "test_notebooks.py": 430, "test_ipm.py": 330,
    "test_attitude_benchmarks.py": 260, "test_dynamics.py": 250, "test_experiments.py": 160, "test_wahba.py": 90,
    "test_attitude_models.py": 75, "test_parameterization.py": 70, "test_lie.py": 65, "test_sensitivity.py": 60,
}


def pytest_collection_modifyitems(session, config, items):
    """Heaviest test files first (`FILE_SECONDS`), and the rendering tests last.

    Drawing with Mesa's software EGL (llvmpipe) loads Mesa's own LLVM into the test process.
    Two full CI runs crashed (segmentation fault) inside XLA later in the same process; a run
    of the rendering tests followed by the crashing test passed, so running them last is a
    precaution (see also vm.max_map_count in .ci/run), not a proven fix.
    """

    def rank(item):
        name = item.path.name
        return (name == "test_render.py", -FILE_SECONDS.get(name, 0))

    items.sort(key=rank)  # stable: the order within a file is kept


def fake_peer(folder: Path, body: str, name: str = "peer", executable: bool = True) -> Path:
    """A fake runner of the paper's public code for the benchmarks' tests: a shell script
    running ``body``."""
    path = folder / name
    path.write_text(f"#!/bin/sh\n{body}\n")
    path.chmod(0o755 if executable else 0o644)
    return path


def refused(main, argv, capsys, message: str) -> None:
    """``main(argv)`` (a benchmark's) stops with argparse's one-line error containing
    ``message``, exit status 2, no traceback."""
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert ": error: " in last and message in last, last
