"""A benchmark whose peer is not installed says so in one line before any work: Pinocchio for
bench/dynamics.py, casadi (FATROP's plugin) for bench/fatrop.py."""

import sys

from conftest import bench_module, refused


def _no_work(*args, **kwargs):
    raise AssertionError("did work without the peer")


def test_dynamics_without_pinocchio(monkeypatch, capsys):
    """``import pinocchio`` at the top failed with a traceback, --help included."""
    monkeypatch.setitem(sys.modules, "pinocchio", None)  # import pinocchio: ImportError
    mod = bench_module("dynamics")
    monkeypatch.setattr("jtraj.robot.load", _no_work)
    refused(mod.main, ["--robot", "go2"], capsys, "Pinocchio, the peer of this benchmark, is not installed: pip install pin==4.1.0")


def test_fatrop_without_casadi(monkeypatch, capsys):
    """casadi was imported where FATROP is first called: after the NLP's compile and the
    presolve of its rows (minutes on Talos), then a traceback."""
    monkeypatch.setitem(sys.modules, "casadi", None)
    mod = bench_module("fatrop")
    for name in ("prepare", "stage_form", "drop_dependent", "solve_fatrop"):
        monkeypatch.setattr(mod, name, _no_work)
    refused(mod.main, ["big_jump"], capsys, "casadi (whose wheel has the fatrop plugin) is not installed")
