"""bench/fatrop.py's table footer describes the solvers its records hold: the Hessian FATROP was
given (``--hessian``), Ipopt only when it ran (not ``--no-ipopt``), jtraj only with ``--jtraj``."""

from conftest import bench_module


def _records(*solvers: str) -> list[dict]:
    row = dict(status="0", iterations=25, time_s=2.0, time_derivatives=1.5, time_solver=0.5, cost=0.0, constraint_violation=1e-6)
    return [dict(task="sideflip", machine=dict(cpus=2), solvers=[dict(row, solver=s) for s in solvers])]


def _footer(*solvers: str) -> str:
    return bench_module("fatrop").markdown(_records(*solvers)).strip().splitlines()[-1]


def test_the_footer_of_all_three_solvers_is_unchanged():
    assert _footer("fatrop", "ipopt", "jtraj") == (
        "Machine: 2 CPUs. FATROP: exact Hessian from JAX, tol 1e-3, the task's max_iter, on the stage form of the compact NLP "
        "(bench/fatrop.py docstring); Ipopt: jtraj's defaults (L-BFGS, tol 1e-3, MUMPS); cost and violation of the original NLP. "
        "FATROP's status is its return code (0: converged). jtraj's time is its whole jitted solve (no separate JAX evaluation)."
    )


def test_the_footer_follows_the_options():
    clip = _footer("fatrop (clip)")
    assert "FATROP: JAX's exact Hessian with each stage block's eigenvalues clipped at 1e-6, tol 1e-3" in clip
    assert "exact Hessian from JAX" not in clip and "Ipopt" not in clip and "jtraj's time" not in clip
    assert "Ipopt: jtraj's defaults" in _footer("fatrop", "ipopt") and "jtraj's time" not in _footer("fatrop", "ipopt")
