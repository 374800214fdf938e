"""Executors of sweeps: every group runs once, results come back with their index.

The Ray executor's dispatch is checked against a stand-in `ray` module (init / remote / wait /
get with Ray's semantics, completion out of submission order), and a tiny sweep runs on a real
local Ray instance when Ray is installed (the ``ray`` extra, part of the ``test`` extra).
"""

from __future__ import annotations

import operator
import os
import signal
import sys
import time
import types
from pathlib import Path

import pytest

from jtraj.executors import EXECUTORS, ExecutorUnavailableError, LocalExecutor, RayExecutor, WorkerLostError, executor_for


def test_local_in_process_keeps_order():
    out = list(LocalExecutor(workers=1).map(operator.add, [(1, 2), (3, 4), (5, 6)]))
    assert out == [(0, 3), (1, 7), (2, 11)]


def test_local_workers_return_every_group():
    out = dict(LocalExecutor(workers=2).map(operator.mul, [(2, 3), (4, 5), (6, 7)]))
    assert out == {0: 6, 1: 20, 2: 42}


def _group(i: int, folder: str, action: str) -> int:
    """A group for worker processes: writes its process id to ``folder/started-i``, then
    returns i at once ("quick"), after 60 s ("sleep"), raises ("raise") or kills its own
    process ("die")."""
    # written whole, then renamed: a worker stopped between creating the file and writing its
    # id left an empty started-i, which _workers_ended could not read
    partial = Path(folder, f".started-{i}.{os.getpid()}")
    partial.write_text(str(os.getpid()))
    partial.rename(Path(folder, f"started-{i}"))
    if action == "raise":
        raise RuntimeError(f"group {i} failed")
    if action == "die":
        os.kill(os.getpid(), signal.SIGKILL)
    if action == "sleep":
        time.sleep(60)
    return i


def _workers_ended(folder: Path) -> bool:
    """Whether every process that started a `_group` has ended (and was reaped)."""
    for path in folder.glob("started-*"):
        try:
            os.kill(int(path.read_text()), 0)
        except ProcessLookupError:
            continue
        return False
    return True


def test_local_workers_stop_when_a_group_raises(tmp_path):
    """The error comes back at once and the workers solving or queued for other groups are
    stopped (the pool's with block waited for every queued group: here 2 x 60 s)."""
    start = time.monotonic()
    with pytest.raises(RuntimeError, match="group 1 failed"):
        list(LocalExecutor(workers=2).map(_group, [(0, str(tmp_path), "sleep"), (1, str(tmp_path), "raise"), (2, str(tmp_path), "sleep"), (3, str(tmp_path), "sleep")]))
    assert time.monotonic() - start < 40
    assert (tmp_path / "started-1").exists() and _workers_ended(tmp_path)


def test_local_workers_stop_when_the_caller_is_interrupted(tmp_path):
    """A Ctrl-C in the caller's loop (thrown into the generator where it waits) stops the
    workers instead of waiting for their groups."""
    groups = LocalExecutor(workers=2).map(_group, [(0, str(tmp_path), "quick"), (1, str(tmp_path), "sleep"), (2, str(tmp_path), "sleep")])
    start = time.monotonic()
    assert next(groups) == (0, 0)
    with pytest.raises(KeyboardInterrupt):
        groups.throw(KeyboardInterrupt)
    assert time.monotonic() - start < 40
    assert _workers_ended(tmp_path)


def test_a_killed_local_worker_is_one_clear_error(tmp_path):
    with pytest.raises(WorkerLostError, match=r"a worker process ended without finishing its group \(killed from outside"):
        list(LocalExecutor(workers=2).map(_group, [(0, str(tmp_path), "die"), (1, str(tmp_path), "sleep")]))
    assert _workers_ended(tmp_path)


def _fake_ray(calls: dict) -> types.ModuleType:
    """A `ray` stand-in: tasks run when submitted, ``wait`` hands them back last-first."""
    ray = types.ModuleType("ray")
    state = {"initialized": False}

    class Ref:
        def __init__(self, value):
            self.value = value

    def init(address=None, **kwargs):
        calls["address"] = address
        state["initialized"] = True

    def remote(**options):
        calls["options"] = options

        def wrap(fn):
            return types.SimpleNamespace(remote=lambda *args: Ref(fn(*args)))

        return wrap

    def wait(refs, num_returns=1):
        return refs[-num_returns:], refs[:-num_returns]

    def cancel(ref, force=False):
        calls.setdefault("cancelled", []).append((ref.value, force))

    ray.init = init
    ray.cancel = cancel
    ray.is_initialized = lambda: state["initialized"]
    ray.remote = remote
    ray.wait = wait
    ray.get = lambda ref: ref.value
    return ray


def test_ray_executor_submits_one_task_per_group(monkeypatch):
    calls = {}
    monkeypatch.setitem(sys.modules, "ray", _fake_ray(calls))
    monkeypatch.setattr("jtraj.executors._reachable", lambda address: None)  # no host 'head' here
    out = list(RayExecutor(address="ray://head:10001").map(operator.sub, [(10, 1), (10, 2), (10, 3)]))
    assert calls["address"] == "ray://head:10001"
    assert calls["options"]["num_cpus"] == 1.0
    assert [i for i, _ in out] == [2, 1, 0]  # completion order, not submission order
    assert dict(out) == {0: 9, 1: 8, 2: 7}


def test_ray_tasks_left_are_cancelled_when_the_caller_stops(monkeypatch):
    """A Ctrl-C or an error in the caller's loop cancels the tasks not handed back (force:
    a running one's worker is killed) rather than leave them running on the cluster."""
    calls: dict = {}
    monkeypatch.setitem(sys.modules, "ray", _fake_ray(calls))
    groups = RayExecutor().map(operator.sub, [(10, 1), (10, 2), (10, 3)])
    assert next(groups) == (2, 7)
    with pytest.raises(KeyboardInterrupt):
        groups.throw(KeyboardInterrupt)
    assert sorted(calls["cancelled"]) == [(8, True), (9, True)]


def test_ray_missing_says_how_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    with pytest.raises(ExecutorUnavailableError, match=r"jtraj\[ray\]"):
        list(RayExecutor().map(operator.add, [(1, 2)]))


def _refusing_ray(calls: dict, error: Exception) -> types.ModuleType:
    """`_fake_ray` whose ``init`` raises ``error``, as Ray's does without a cluster there."""
    ray = _fake_ray(calls)

    def refuse(address=None, **kwargs):
        raise error

    ray.init = refuse
    return ray


@pytest.mark.parametrize("error", [ConnectionError("Failed to connect to Ray cluster at head:1"), ValueError("Invalid address format: head")])
def test_ray_unreachable_cluster_is_one_clear_error(monkeypatch, error):
    """No cluster at the address, or a malformed one: `ExecutorUnavailableError` naming the
    address and Ray's reason, before any group is submitted."""
    calls: dict = {}
    monkeypatch.setitem(sys.modules, "ray", _refusing_ray(calls, error))
    monkeypatch.setattr("jtraj.executors._reachable", lambda address: None)  # Ray's own refusal
    with pytest.raises(ExecutorUnavailableError, match=r"Ray could not connect to a cluster at 'head:1'") as info:
        list(RayExecutor(address="head:1").map(operator.add, [(1, 2)]))
    assert str(error) in str(info.value)
    assert "options" not in calls  # nothing was submitted


def test_cli_unreachable_ray_cluster_exits_2_with_one_line(monkeypatch, tmp_path, capsys):
    from jtraj import cli

    monkeypatch.setitem(sys.modules, "ray", _refusing_ray({}, ConnectionError("Failed to connect to Ray cluster at head:1")))
    monkeypatch.setattr("jtraj.executors._reachable", lambda address: None)
    monkeypatch.setattr("jtraj.experiments._compare_one", lambda *args, **kwargs: pytest.fail("a solve started"))
    rc = cli.main(["compare", "--tasks", "big_jump", "--params", "se3", "--executor", "ray", "--ray-address", "head:1", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == cli.EXIT_BAD_INPUT
    assert err.count("\n") == 1 and err.startswith("jtraj compare: Ray could not connect to a cluster at 'head:1'"), err


def test_an_address_nothing_answers_at_is_refused_before_ray_init(monkeypatch):
    """``ray.init`` retries a HOST:PORT that takes no connection for minutes without a word
    (127.0.0.1:1 was still waiting after 500 s): such an address is refused at once, and
    one that takes a connection is handed to Ray."""
    import socket

    calls: dict = {}
    monkeypatch.setitem(sys.modules, "ray", _fake_ray(calls))
    with pytest.raises(ExecutorUnavailableError, match=r"Ray could not connect to a cluster at 'ray://127.0.0.1:1': nothing answers at 127.0.0.1:1"):
        RayExecutor(address="ray://127.0.0.1:1").connect()
    assert "address" not in calls  # ray.init was not called
    with socket.create_server(("127.0.0.1", 0)) as server:
        address = f"127.0.0.1:{server.getsockname()[1]}"
        RayExecutor(address=address).connect()
    assert calls["address"] == address
    RayExecutor(address="auto").connect()  # left to Ray (the fake is initialized by now)


def test_executor_for_names():
    assert isinstance(executor_for("local", workers=3), LocalExecutor)
    assert executor_for("local", workers=3).workers == 3
    assert executor_for("ray", ray_address="auto").address == "auto"
    assert set(EXECUTORS) == {"local", "ray"}
    with pytest.raises(ValueError, match=r"^executor_for: executor='dask': expected one of local, ray$"):  # the message of compare's and robustness's check
        executor_for("dask")


def test_robustness_table_with_ray_executor_equals_local(tmp_path, monkeypatch):
    from test_transcription import HOP

    from jtraj.experiments import robustness

    calls = {}
    monkeypatch.setitem(sys.modules, "ray", _fake_ray(calls))
    kw = dict(sigmas=[1e-2], replicates=2, seed=2, progress=None, resume=False)
    local = robustness([HOP], ["se3"], out=tmp_path / "local", **kw)
    ray_runs = robustness([HOP], ["se3"], out=tmp_path / "ray", executor="ray", ray_address="auto", **kw)
    assert calls["address"] == "auto"
    assert [(r["replicate"], r["status"], r["iterations"]) for r in ray_runs] == [(r["replicate"], r["status"], r["iterations"]) for r in local]
    assert (tmp_path / "ray" / "table_iii.md").read_text() == (tmp_path / "local" / "table_iii.md").read_text()


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")  # ray.init starts its processes by fork and exec
def test_robustness_table_on_a_local_ray_instance_equals_local(tmp_path):
    """The same tiny sweep on a real local Ray instance (one worker process, started here)."""
    ray = pytest.importorskip("ray")
    from test_transcription import HOP

    from jtraj.experiments import robustness

    kw = dict(sigmas=[1e-2], replicates=2, seed=2, progress=None, resume=False)
    local = robustness([HOP], ["se3"], out=tmp_path / "local", **kw)
    try:  # no address: the executor starts a local instance
        ray_runs = robustness([HOP], ["se3"], out=tmp_path / "ray", executor="ray", **kw)
    finally:
        ray.shutdown()
    assert [(r["replicate"], r["status"], r["iterations"]) for r in ray_runs] == [(r["replicate"], r["status"], r["iterations"]) for r in local]
    assert (tmp_path / "ray" / "table_iii.md").read_text() == (tmp_path / "local" / "table_iii.md").read_text()


@pytest.mark.parametrize("ray", ["missing", "unreachable"])
def test_cli_ray_unavailable_is_refused_before_the_output_folder_is_touched(monkeypatch, tmp_path, capsys, ray):
    """Ray missing or its cluster unreachable was found when the first group was submitted:
    after provenance.json was written (a run 'not complete') and, with --no-resume, after the
    study's runs.jsonl was moved to runs.jsonl.previous. It is an input error found first."""
    from jtraj import cli

    module = None if ray == "missing" else _refusing_ray({}, ConnectionError("Failed to connect to Ray cluster at head:1"))
    monkeypatch.setitem(sys.modules, "ray", module)
    out = tmp_path / "study"
    out.mkdir()
    (out / "runs.jsonl").write_text("{}\n")
    argv = ["robustness", "--tasks", "big_jump", "--params", "se3", "--executor", "ray", "--no-resume", "--out", str(out)]
    rc = cli.main(argv + ([] if ray == "missing" else ["--ray-address", "head:1"]))
    err = capsys.readouterr().err
    assert rc == cli.EXIT_BAD_INPUT and err.count("\n") == 1, err
    assert ('pip install "jtraj[ray]"' if ray == "missing" else "Ray could not connect to a cluster at 'head:1'") in err
    assert sorted(p.name for p in out.iterdir()) == ["runs.jsonl"]


def test_local_workers_leave_ctrl_c_to_the_caller():
    """Ctrl-C in a terminal reaches the workers too (one process group): each printed a
    KeyboardInterrupt traceback of its own over the caller's message. They ignore it, and the
    caller, which gets it, stops them (test_local_workers_stop_when_the_caller_is_interrupted)."""
    handlers = dict(LocalExecutor(workers=2).map(signal.getsignal, [(signal.SIGINT,), (signal.SIGINT,)]))
    assert handlers == {0: signal.SIG_IGN, 1: signal.SIG_IGN}
