"""Atomic writers and strict JSON (jtraj.io)."""

import json
import math
import os

import numpy as np
import pytest

from jtraj import io


def test_write_json_is_strict_and_maps_nonfinite_to_null(tmp_path):
    path = io.write_json(tmp_path / "r.json", {"a": float("nan"), "b": [np.float64(np.inf), -math.inf, 1.5], "c": np.arange(3), "d": np.bool_(True)})
    text = path.read_text()
    assert "NaN" not in text and "Infinity" not in text
    # the strictest reader: refuses any non-JSON constant
    data = json.loads(text, parse_constant=lambda name: pytest.fail(f"non-JSON token {name}"))
    assert data == {"a": None, "b": [None, None, 1.5], "c": [0, 1, 2], "d": True}
    assert io.read_json(path) == data


def test_jax_arrays_are_written_as_numbers(tmp_path):
    """jtraj computes in JAX: a JAX scalar or array (a metric, a cost from jtraj.differentiable)
    raised 'cannot write ArrayImpl to JSON'."""
    import jax.numpy as jnp

    path = io.write_json(tmp_path / "r.json", {"cost": jnp.float64(1.5), "x": jnp.arange(3), "bad": jnp.array([jnp.nan, 2.0])})
    assert io.read_json(path) == {"cost": 1.5, "x": [0, 1, 2], "bad": [None, 2.0]}


def test_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "out.json"
    io.write_json(path, {"v": 1})
    with pytest.raises(TypeError, match="cannot write object to JSON"):
        io.write_json(path, {"v": object()})
    with pytest.raises(RuntimeError):
        with io.atomic_open(path) as f:
            f.write('{"v": 2, "trunc')
            raise RuntimeError("killed mid-write")
    assert io.read_json(path) == {"v": 1}
    assert sorted(os.listdir(tmp_path)) == ["out.json"]


@pytest.mark.parametrize("content, expected", [(None, "does not exist"), ("", "empty"), ("  \n", "empty"), ('{"a": 1', "not valid JSON"), ('{"a": NaN}', "not valid JSON")])
def test_read_json_names_the_file(tmp_path, content, expected):
    path = tmp_path / "result.json"
    if content is not None:
        path.write_text(content)
    with pytest.raises(io.FileFormatError) as e:
        io.read_json(path)
    msg = str(e.value)
    assert str(path) in msg and expected in msg and "\n" not in msg


def test_read_json_of_a_path_under_a_file_or_unreadable_names_the_file(tmp_path, monkeypatch):
    """A path through a file and an unreadable file were raw OSErrors, not FileFormatError."""
    (tmp_path / "a.npz").write_text("x")
    with pytest.raises(io.FileFormatError, match=r"a\.npz/result\.json: file does not exist \(a folder on its path is a file\)$"):
        io.read_json(tmp_path / "a.npz" / "result.json")
    locked = tmp_path / "locked.json"
    locked.write_text("{}")

    def denied(self, *args, **kwargs):  # a file's mode does not stop root, who runs CI
        raise PermissionError(13, "Permission denied", str(self))

    monkeypatch.setattr(type(locked), "read_text", denied)
    with pytest.raises(io.FileFormatError, match=r"locked\.json: not readable \(permission denied\)$"):
        io.read_json(locked)


def test_jsonl_append_and_torn_last_line(tmp_path):
    path = tmp_path / "runs.jsonl"
    for i in range(3):
        io.append_jsonl(path, {"i": i, "x": float("nan") if i == 1 else 0.5})
    with open(path, "ab") as f:
        f.write(b'{"i": 3, "x"')  # what a kill in the middle of a write could leave
    records, bad = io.read_jsonl(path)
    assert records == [{"i": 0, "x": 0.5}, {"i": 1, "x": None}, {"i": 2, "x": 0.5}]
    assert bad == [4]
    assert io.read_jsonl_lines(path) == (list(enumerate(records, 1)), [4])  # with their line numbers


@pytest.mark.parametrize("last", ['{"i": 0}', '{"i": 0}\n{"i": 1, "x"'])
def test_jsonl_append_after_a_last_line_without_newline(tmp_path, last):
    """A file that ends without a newline (files joined by hand, a torn write) gets one before
    the record: glued onto the last line, both were lost."""
    path = tmp_path / "runs.jsonl"
    path.write_text(last)
    io.append_jsonl(path, {"i": 2})
    io.append_jsonl(path, {"i": 3})
    records, bad = io.read_jsonl(path)
    assert records == [{"i": 0}, {"i": 2}, {"i": 3}]
    assert bad == ([] if last.endswith("}") else [2])


def test_jsonl_append_finishes_a_short_write(tmp_path, monkeypatch):
    path = tmp_path / "runs.jsonl"
    write = os.write
    monkeypatch.setattr(os, "write", lambda fd, data: write(fd, bytes(data[:5])))  # 5 bytes a call at most
    io.append_jsonl(path, {"task": "walk", "replicate": 1})
    io.append_jsonl(path, {"task": "walk", "replicate": 2})
    assert io.read_jsonl(path) == ([{"task": "walk", "replicate": 1}, {"task": "walk", "replicate": 2}], [])


@pytest.mark.parametrize("kind, expected", [("folder", "is a folder"), ("fifo", "is not a regular file"), ("unreadable", "cannot be read (the system says: Input/output error)")])
def test_jsonl_that_cannot_be_read_is_named(tmp_path, monkeypatch, kind, expected):
    """A folder where a JSON-lines file should be raised IsADirectoryError (a traceback of
    jtraj robustness), a named pipe waited for a writer, another OSError escaped as it was:
    each is a `FileFormatError` of one line naming the file. A missing file holds no records."""
    path = tmp_path / "runs.jsonl"
    assert io.read_jsonl(path) == ([], []) and not io.check_file(path, "a JSON-lines file")
    if kind == "folder":
        path.mkdir()
    elif kind == "fifo":
        os.mkfifo(path)
    else:
        path.write_text('{"i": 0}\n')

        def unreadable(*args, **kwargs):
            raise OSError(5, "Input/output error")

        monkeypatch.setattr(io, "open", unreadable, raising=False)
    for read in (lambda: io.read_jsonl(path), lambda: io.check_file(path, "a JSON-lines file")):
        with pytest.raises(io.FileFormatError) as e:
            read()
        assert str(e.value) == f"{path}: {expected}; expected a JSON-lines file"
    if kind == "unreadable":  # without read, only what is there is checked
        assert io.check_file(path, "a JSON-lines file", read=False)


def test_npz_and_figure_round_trip(tmp_path):
    a = np.random.default_rng(0).standard_normal((4, 3))
    io.write_npz(tmp_path / "t.npz", a=a, names=np.array(["x", "y"]))
    with np.load(tmp_path / "t.npz") as z:
        np.testing.assert_array_equal(z["a"], a)
        assert list(z["names"]) == ["x", "y"]
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1])
    io.save_figure(fig, tmp_path / "f.png", dpi=50)
    plt.close(fig)
    assert (tmp_path / "f.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(os.listdir(tmp_path)) == ["f.png", "t.npz"]


def test_written_files_get_the_usual_permissions(tmp_path):
    old = os.umask(0o022)
    try:
        path = io.write_text(tmp_path / "t.md", "| a |\n")
    finally:
        os.umask(old)
    assert path.stat().st_mode & 0o777 == 0o644


def test_write_results_writes_records_table_and_the_command(tmp_path):
    from jtraj.provenance import write_results

    records = [{"task": "walk", "time_s": float("nan"), "iterations": 12}]
    paths = write_results(tmp_path / "r", "speed", records, "| task |\n|---|\n| walk |\n", "bench/solve.py", ["walk", "--out", "r"])
    assert [p.name for p in paths] == ["speed.json", "speed.md", "provenance.json"]
    assert io.read_json(tmp_path / "r" / "speed.json") == [{"task": "walk", "time_s": None, "iterations": 12}]
    assert (tmp_path / "r" / "speed.md").read_text() == "| task |\n|---|\n| walk |\n"
    assert io.read_json(tmp_path / "r" / "provenance.json")["command"] == "python bench/solve.py walk --out r"


def test_vector_extension_is_the_widest_flag_of_the_first_cpu():
    from jtraj.provenance import vector_extension

    zen4 = "processor\t: 0\nflags\t\t: fpu sse4_2 avx avx2 fma avx512f avx512bw\nprocessor\t: 1\nflags\t\t: fpu sse4_2\n"
    assert vector_extension(zen4) == "avx512f"
    assert vector_extension("flags\t: fpu sse4_2 avx avx2 fma\n") == "avx2"
    assert vector_extension("flags\t: fpu sse2\n") is None
    assert vector_extension("processor\t: 0\nFeatures\t: fp asimd\n") is None  # an ARM cpuinfo


def test_provenance_records_the_runs_xla_flags_only_when_set(monkeypatch):
    from jtraj.provenance import provenance

    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_max_isa=AVX2")
    assert provenance(["jtraj", "compare"])["machine"]["xla_flags"] == "--xla_cpu_max_isa=AVX2"
    monkeypatch.delenv("XLA_FLAGS")
    machine = provenance(["jtraj", "compare"])["machine"]
    assert "xla_flags" not in machine
    assert "vector_extension" in machine
