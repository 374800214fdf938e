"""bench/compile.py: its table, and what a failed process leaves."""

import pytest
from conftest import bench_module


def test_table_gives_the_fastest_solve_and_names_the_flags():
    records = [
        dict(task="big_jump", flags="", build=36.04, program=42.26, times=[1.7, 1.65, 1.66], iterations=12),
        dict(task="big_jump", flags="--xla_backend_optimization_level=0", build=25.1, program=34.7, times=[6.2, 5.72], iterations=12),
    ]
    lines = bench_module("compile").table(records).splitlines()
    assert lines[0].startswith("| task | XLA_FLAGS |")
    assert lines[2] == "| big_jump | (none) | 36.0 | 42.3 | 1.65 | 12 |"
    assert lines[3] == "| big_jump | `--xla_backend_optimization_level=0` | 25.1 | 34.7 | 5.72 | 12 |"


def test_table_shows_the_status_of_a_solve_that_failed():
    """The child records each solve's status, the table left it out: a solve that stopped at its
    iteration limit showed its time and iterations as a solved one's."""
    records = [
        dict(task="big_jump", flags="", build=36.0, program=42.3, times=[1.7], iterations=12, status="solved"),
        dict(task="sideflip", flags="", build=20.0, program=30.0, times=[9.5], iterations=200, status="not_converged"),
    ]
    lines = bench_module("compile").table(records).splitlines()
    assert lines[2].endswith("| 1.70 | 12 |")
    assert lines[3].endswith("| 9.50 | 200 (not_converged) |")


def test_a_failed_process_keeps_the_records_measured_before_it(monkeypatch, capsys, tmp_path):
    """One failed child raised RuntimeError with a traceback, and the records measured before it
    were lost (the files were written at the end): now they are written, marked incomplete, and
    the benchmark stops with one line."""
    import json

    import jtraj.provenance

    bench = bench_module("compile")
    calls = []

    def child(task, param, variables, flags, repeats):
        calls.append(flags)
        if len(calls) == 2:
            raise RuntimeError(f"{task} with XLA_FLAGS={flags!r}: exit 1: MemoryError")
        return dict(task=task, build=1.0, program=2.0, iterations=12, status="solved", times=[0.5], flags=flags, param=param, variables=variables)

    monkeypatch.setattr(bench, "run_child", child)
    monkeypatch.setattr(jtraj.provenance, "provenance", lambda argv=None: {"command": " ".join(argv)})
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exc:
        bench.main(["big_jump", "--flags=|--xla_a=1|--xla_b=1", "--out", str(out)])
    message = str(exc.value.code)
    assert message == f"bench/compile.py: big_jump with XLA_FLAGS='--xla_a=1': exit 1: MemoryError; {out}/compile.json holds the 1 records measured before it"
    assert calls == ["", "--xla_a=1"]  # stopped at the failure
    assert [r["flags"] for r in json.loads((out / "compile.json").read_text())] == [""]
    assert json.loads((out / "provenance.json").read_text())["complete"] is False
    assert (out / "compile.md").read_text().splitlines()[2].startswith("| big_jump | (none) |")


def test_a_failed_first_process_writes_nothing(monkeypatch, tmp_path):
    bench = bench_module("compile")

    def child(task, param, variables, flags, repeats):
        raise RuntimeError(f"{task} with XLA_FLAGS={flags!r}: exit 1: boom")

    monkeypatch.setattr(bench, "run_child", child)
    with pytest.raises(SystemExit, match=r"^bench/compile\.py: big_jump with XLA_FLAGS='': exit 1: boom$"):
        bench.main(["big_jump", "--out", str(tmp_path / "out")])
    assert not (tmp_path / "out").exists()


def test_a_failed_process_is_one_line_with_its_last_words(monkeypatch):
    """The child's error: its exit status and the last lines of its stderr, on one line."""
    bench = bench_module("compile")
    done = bench.subprocess.CompletedProcess([], 1, "", "Traceback (most recent call last):\n  File x\nValueError: bad\n")
    monkeypatch.setattr(bench.subprocess, "run", lambda *a, **k: done)
    with pytest.raises(RuntimeError) as exc:
        bench.run_child("big_jump", "se3", "paper", "", 1)
    assert str(exc.value) == "big_jump with XLA_FLAGS='': exit 1: Traceback (most recent call last): |   File x | ValueError: bad"
