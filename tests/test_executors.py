"""Executors of sweeps: every group runs once, results come back with their index.

The Ray executor's dispatch is checked against a stand-in `ray` module (init / remote / wait /
get / cancel with Ray's semantics, completion out of submission order, streaming generator
tasks, a worker's loss raised by get), and a tiny sweep runs on a real local Ray instance when
Ray is installed (the ``ray`` extra, part of the ``test`` extra).
"""

from __future__ import annotations

import operator
import os
import re
import signal
import subprocess
import sys
import time
import types
from pathlib import Path

import numpy as np
import pytest

from jtraj.executors import EXECUTORS, ExecutorUnavailableError, GroupError, LocalExecutor, RayExecutor, WorkerLostError, check_executor, executor_for


def test_local_in_process_keeps_order():
    out = list(LocalExecutor(workers=1).map(operator.add, [(1, 2), (3, 4), (5, 6)]))
    assert out == [(0, 3), (1, 7), (2, 11)]


def test_local_workers_return_every_group():
    out = dict(LocalExecutor(workers=2).map(operator.mul, [(2, 3), (4, 5), (6, 7)]))
    assert out == {0: 6, 1: 20, 2: 42}


def _group(i: int, folder: str, action: str) -> int:
    """A group for worker processes: writes its process id to ``folder/started-i``, then
    returns i at once ("quick"), after 60 s ("sleep"), raises once group 0 has started
    ("raise") or kills its own process ("die")."""
    # written whole, then renamed: a worker stopped between creating the file and writing its
    # id left an empty started-i, which _workers_ended could not read
    partial = Path(folder, f".started-{i}.{os.getpid()}")
    partial.write_text(str(os.getpid()))
    partial.rename(Path(folder, f"started-{i}"))
    if action == "raise":
        # after group 0 started: raised before it, no other worker was solving, and the test's
        # check that the others are stopped had nothing to check
        _wait_for(Path(folder, "started-0"))
        raise RuntimeError(f"group {i} failed")
    if action == "die":
        os.kill(os.getpid(), signal.SIGKILL)
    if action == "sleep":
        time.sleep(60)
    return i


def _wait_for(path: Path, timeout: float = 30.0) -> None:
    """Wait until ``path`` exists (a group's started file), at most ``timeout`` seconds."""
    end = time.monotonic() + timeout
    while not path.exists() and time.monotonic() < end:
        time.sleep(0.02)
    assert path.exists(), f"{path.name} was not written in {timeout:g} s"


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
    assert (tmp_path / "started-0").exists() and (tmp_path / "started-1").exists() and _workers_ended(tmp_path)


def test_local_workers_stop_when_the_caller_is_interrupted(tmp_path):
    """A Ctrl-C in the caller's loop (thrown into the generator where it waits) stops the
    workers instead of waiting for their groups."""
    groups = LocalExecutor(workers=2).map(_group, [(0, str(tmp_path), "quick"), (1, str(tmp_path), "sleep"), (2, str(tmp_path), "sleep")])
    start = time.monotonic()
    assert next(groups) == (0, 0)
    # group 1 is being solved when the Ctrl-C comes (thrown before it started, the check below
    # found no worker to check)
    _wait_for(tmp_path / "started-1")
    with pytest.raises(KeyboardInterrupt):
        groups.throw(KeyboardInterrupt)
    assert time.monotonic() - start < 40
    assert _workers_ended(tmp_path)


def test_a_killed_local_worker_is_one_clear_error(tmp_path):
    """A worker that ends without its group, killed or failing to start (a worker process's
    traceback, e.g. of a script without ``if __name__ == "__main__":``, comes before it): the
    message said only "killed from outside"."""
    with pytest.raises(WorkerLostError, match=r"a worker process ended without finishing its group: it failed to start \(see its output above\) or was killed from outside"):
        list(LocalExecutor(workers=2).map(_group, [(0, str(tmp_path), "die"), (1, str(tmp_path), "sleep")]))
    assert _workers_ended(tmp_path)


class _TwoArgumentError(Exception):
    """An exception that does not survive pickling: Exception's pickling passes its message
    alone to a constructor that takes two arguments."""

    def __init__(self, field: str, detail: str):
        super().__init__(f"{field}: {detail}")


class _Unsendable:
    def __reduce__(self):
        raise TypeError("not this one")


def _raises_unpicklable(i: int):
    if i == 1:
        raise _TwoArgumentError("--tasks", "no such task")
    if i == 2:
        from jtraj.cli import InputError

        raise InputError("--tasks", "moonwalk", "expected a task name")
    if i == 3:
        return _Unsendable()
    return i


@pytest.mark.parametrize(
    ("i", "error", "match"),
    [
        (1, GroupError, r"^test_executors._TwoArgumentError: --tasks: no such task\n\(in the worker process:\)\nTraceback"),
        (2, None, r"^--tasks: 'moonwalk': expected a task name$"),  # the command line's own error comes back as it is
        (3, GroupError, r"^the group's result, a _Unsendable, cannot be sent back from its worker process: TypeError: not this one$"),
    ],
)
def test_a_group_error_that_cannot_be_pickled_is_said_not_lost(i, error, match):
    """A group's exception (or result) that did not survive pickling broke the pool when the
    caller unpickled it, and came back as a WorkerLostError blaming the kernel's memory."""
    from jtraj.cli import InputError

    with pytest.raises(error or InputError, match=match):
        list(LocalExecutor(workers=2).map(_raises_unpicklable, [(0,), (i,)]))


_ORPHANED = """
import sys
sys.path.insert(0, {tests!r})
from test_executors import _group
from jtraj.executors import LocalExecutor
if __name__ == "__main__":
    for i, r in LocalExecutor(workers=2).map(_group, [(0, {folder!r}, "sleep"), (1, {folder!r}, "sleep")]):
        pass
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the parent-death signal is Linux's")
def test_local_workers_die_with_a_killed_caller(tmp_path):
    """A caller killed without its cleanup (SIGKILL; SIGTERM before the command line turned it
    into an interrupt) left its worker processes solving, then waiting forever: they now die
    with it (a parent-death signal)."""
    script = tmp_path / "caller.py"
    script.write_text(_ORPHANED.format(tests=str(Path(__file__).parent), folder=str(tmp_path)))
    caller = subprocess.Popen([sys.executable, str(script)])
    try:
        deadline = time.monotonic() + 120
        while not all((tmp_path / f"started-{i}").exists() for i in (0, 1)):
            assert caller.poll() is None and time.monotonic() < deadline, "the workers did not start"
            time.sleep(0.1)
    finally:
        caller.kill()
        caller.wait()
    pids = [int((tmp_path / f"started-{i}").read_text()) for i in (0, 1)]
    deadline = time.monotonic() + 20
    while any(map(_running, pids)) and time.monotonic() < deadline:
        time.sleep(0.1)
    alive = [pid for pid in pids if _running(pid)]
    for pid in alive:  # the old behaviour: do not leave them sleeping after the test
        os.kill(pid, signal.SIGKILL)
    assert not alive, "the workers outlived their killed caller"


def _running(pid: int) -> bool:
    """Whether process ``pid`` runs (an orphan that ended may wait, a zombie, for a reaper)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state not in ("Z", "X")


def _items(i: int, n: int, fail_at: int | None = None):
    """A streaming group: yields (i, 0), (i, 1), ... (i, n - 1), raising at ``fail_at``."""
    for k in range(n):
        if k == fail_at:
            raise RuntimeError(f"group {i} failed at item {k}")
        yield i, k


def test_local_stream_hands_back_every_item():
    assert list(LocalExecutor(workers=1).stream(_items, [(0, 2), (1, 3)])) == [(0, (0, 0)), (0, (0, 1)), (1, (1, 0)), (1, (1, 1)), (1, (1, 2))]
    out = list(LocalExecutor(workers=2).stream(_items, [(0, 2), (1, 3)]))
    assert sorted(out) == [(0, (0, 0)), (0, (0, 1)), (1, (1, 0)), (1, (1, 1)), (1, (1, 2))]
    assert [item for i, item in out if i == 1] == [(1, 0), (1, 1), (1, 2)]  # each group's in its order


class _RayCrash(Exception):
    """Stands for Ray's errors of a lost worker in `_fake_ray`'s ``exceptions``."""


class RayTaskError(Exception):
    """Stands for Ray's error of a task that raised: a multi-line message of the worker's
    traceback, the task's exception as ``cause``."""

    def __init__(self, cause: Exception):
        super().__init__(f"\x1b[36mray::group()\x1b[39m (pid=1, ip=192.0.2.2)\n  File ...\n{type(cause).__name__}: {cause}")
        self.cause = cause


def _fake_ray(calls: dict) -> types.ModuleType:
    """A `ray` stand-in: tasks run when submitted, ``wait`` hands them back last-first, and
    ``get`` raises a task's error, as Ray's does. A streaming task (``num_returns="streaming"``)
    is a generator of refs that runs its function one item per ``next``; one that raised hands
    back a ref of its error, then ends. ``ray.exceptions`` holds Ray's errors of a lost worker
    (`_RayCrash` subclasses, raised by a task to stand for its worker's loss)."""
    ray = types.ModuleType("ray")
    state = {"initialized": False}

    class Ref:
        def __init__(self, value=None, error=None):
            self.value, self.error = value, error

    class Stream:
        def __init__(self, items, args):
            self.items, self.ended = items, False
            self.value = args  # what cancel records

        def __iter__(self):
            return self

        def __next__(self):
            if self.ended:
                raise StopIteration
            try:
                return Ref(next(self.items))
            except StopIteration:
                self.ended = True
                raise
            except Exception as e:
                self.ended = True
                return Ref(error=wrapped(e))

    def run(fn, *args):
        try:
            return Ref(fn(*args))
        except Exception as e:
            return Ref(error=wrapped(e))

    def wrapped(e):
        # Ray's get raises a group's own error as a RayTaskError: the worker's traceback, with
        # terminal colours, and the group's exception as its cause; a lost worker's as it is
        return e if isinstance(e, _RayCrash) else RayTaskError(e)

    def init(address=None, **kwargs):
        calls["address"] = address
        calls["init"] = kwargs
        state["initialized"] = True

    def remote(**options):
        calls["options"] = options

        def wrap(fn):
            if options.get("num_returns") == "streaming":
                return types.SimpleNamespace(remote=lambda *args: Stream(fn(*args), args))
            return types.SimpleNamespace(remote=lambda *args: run(fn, *args))

        return wrap

    def wait(refs, num_returns=1):
        return refs[-num_returns:], refs[:-num_returns]

    def cancel(ref, force=False):
        calls.setdefault("cancelled", []).append((ref.value, force))

    def get(ref):
        if ref.error is not None:
            raise ref.error
        return ref.value

    ray.init = init
    ray.cancel = cancel
    ray.is_initialized = lambda: state["initialized"]
    ray.remote = remote
    ray.wait = wait
    ray.get = get
    ray.exceptions = types.SimpleNamespace(**{name: type(name, (_RayCrash,), {}) for name in ("WorkerCrashedError", "OutOfMemoryError", "NodeDiedError", "ObjectLostError")})
    ray.exceptions.RayTaskError = RayTaskError
    return ray


@pytest.mark.parametrize("how", ["map", "stream"])
@pytest.mark.parametrize("gpus, env", [(None, None), (0.25, {"XLA_PYTHON_CLIENT_PREALLOCATE": "false"}), (1, None)])
def test_ray_tasks_reserve_the_gpus_asked_for(monkeypatch, how, gpus, env):
    """Each group's Ray task reserves ``ray_gpus`` GPUs (none by default). Ray hides the GPUs
    from a task that reserves none, and jtraj's did: on a GPU cluster every group computed on
    the CPU. Groups that share a GPU (a fraction) take its memory as they need it."""
    calls: dict = {}
    ray = _fake_ray(calls)
    ray.cluster_resources = lambda: {"CPU": 8.0, "GPU": 2.0}
    monkeypatch.setitem(sys.modules, "ray", ray)
    executor = executor_for("ray", ray_gpus=gpus)
    if how == "map":
        assert sorted(executor.map(operator.neg, [(1,), (2,)])) == [(0, -1), (1, -2)]
    else:
        assert sorted(executor.stream(lambda i: iter([i]), [(1,), (2,)])) == [(0, 1), (1, 2)]
    assert calls["options"]["num_gpus"] == (gpus or 0) and calls["options"]["num_cpus"] == 1.0
    assert calls["options"].get("runtime_env") == (None if env is None else {"env_vars": env})


def test_ray_gpus_the_cluster_lacks_are_refused_when_connecting(monkeypatch):
    """Ray queues a task that no node can take without end: GPUs per task above the cluster's
    are refused as it connects, before a sweep writes anything."""
    calls: dict = {}
    ray = _fake_ray(calls)
    ray.cluster_resources = lambda: {"CPU": 8.0}
    monkeypatch.setitem(sys.modules, "ray", ray)
    with pytest.raises(ExecutorUnavailableError, match=r"^each group's Ray task reserves 0.5 GPUs \(--ray-gpus\), and the local instance has 0: Ray would never start one"):
        RayExecutor(num_gpus=0.5).connect()
    ray.cluster_resources = lambda: {"CPU": 8.0, "GPU": 1.0}
    assert RayExecutor(num_gpus=0.5).connect() is ray


@pytest.mark.parametrize(
    "name, gpus, message",
    [
        ("local", 1, r"^f: ray_gpus=1: needs executor='ray'"),
        ("ray", -0.5, r"^f: ray_gpus=-0.5: expected a number >= 0"),
        ("ray", float("nan"), r"^f: ray_gpus=nan: expected a number >= 0"),
        ("ray", True, r"^f: ray_gpus=True: expected a number >= 0"),
        ("ray", "1", r"^f: ray_gpus='1': expected a number >= 0"),
    ],
)
def test_check_executor_refuses_ray_gpus_it_cannot_use(name, gpus, message):
    with pytest.raises(ValueError, match=message):
        check_executor(name, ray_gpus=gpus, where="f")


def _lost_worker(ray, name: str, message: str):
    """A group whose Ray worker is lost: Ray's error ``name`` comes back in its place."""

    def group(*args):
        raise getattr(ray.exceptions, name)(message)

    return group


@pytest.mark.parametrize(
    "name, message",
    [
        ("WorkerCrashedError", "The worker died unexpectedly while executing this task. Check python-core-worker-*.log files for more information."),
        ("OutOfMemoryError", "Task was killed due to the node running low on memory.\nMemory on the node (IP: 10.0.0.2) was 7.5GB / 8GB"),
        ("NodeDiedError", "\nThe node with node id: 3f40b3 has been marked dead"),
    ],
)
@pytest.mark.parametrize("how", ["map", "stream"])
def test_a_lost_ray_worker_is_worker_lost_error(monkeypatch, name, message, how):
    """A Ray worker that crashed, was killed when memory ran out, or whose node died raised
    Ray's own error through the sweep (a traceback; compare's note of the cells its table
    holds was never made): it is `WorkerLostError`, saying what happened with Ray's first
    line, and the groups left are cancelled."""
    calls: dict = {}
    ray = _fake_ray(calls)
    monkeypatch.setitem(sys.modules, "ray", ray)
    if how == "map":
        groups = RayExecutor().map(_lost_worker(ray, name, message), [(1,), (2,)])
    else:
        lost = _lost_worker(ray, name, message)

        def stream(i):
            yield i
            lost()

        groups = RayExecutor().stream(stream, [(1,), (2,)])
        assert next(groups) == (1, 2)  # the last submitted comes first; its first item
    with pytest.raises(WorkerLostError) as info:
        list(groups)
    first = next(line for line in message.splitlines() if line)
    assert str(info.value) == (
        "a Ray worker ended without finishing its group: its process crashed or was killed (e.g. by Ray when the node's memory ran out) "
        f"or its node died (Ray's {name}: {first})"
    )
    assert type(info.value.__cause__) is getattr(ray.exceptions, name)
    assert len(calls["cancelled"]) == (2 if how == "stream" else 1)  # the groups not handed back (a streaming one still open)


def test_cli_lost_ray_worker_is_one_line_and_exit_1(monkeypatch, tmp_path, capsys):
    """`jtraj compare --executor ray` with a cell whose Ray worker crashed: one line saying so
    and how many cells the table holds, exit status 1 (a traceback of Ray's error before)."""
    import json

    from jtraj import cli

    ray = _fake_ray({})
    monkeypatch.setitem(sys.modules, "ray", ray)
    crash = _lost_worker(ray, "WorkerCrashedError", "The worker died unexpectedly while executing this task.")

    def cell(task, p, *args, **kwargs):
        if p == "se3":  # the stand-in hands the last task submitted back first: euler's cell finishes
            crash()
        row = dict(task=getattr(task, "name", task), parameterization=p, solver="ipopt", status="solved", solver_status="solved", converged=True, success=True, turns=None)
        return row | dict(iterations=3, obj_evals=4, grad_evals=3, con_evals=3, jac_evals=3, cost=0.0, constraint_violation=0.0, time_s=0.1, time_compile=0.0, task_check=None)

    monkeypatch.setattr("jtraj.experiments._compare_one", cell)
    out = tmp_path / "out"
    rc = cli.main(["compare", "--tasks", "big_jump", "--params", "se3,euler", "--executor", "ray", "--no-trajectories", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 1 and err.count("\n") == 1, err
    assert err.startswith("jtraj compare: a Ray worker ended without finishing its group: its process crashed or was killed")
    assert err.endswith(f"(Ray's WorkerCrashedError: The worker died unexpectedly while executing this task.); {out / 'table_iv.json'} holds the 1 of 2 cells finished before it\n")
    assert [r["parameterization"] for r in json.loads((out / "table_iv.json").read_text())] == ["euler"]


def test_ray_stream_hands_back_each_item_as_it_comes(monkeypatch):
    """`RayExecutor.stream`: one streaming generator task per group, each item handed back as
    the task yields it (a group's items came only when it ended, and were lost with it when it
    failed or the caller stopped); a group's error comes after the items it yielded."""
    calls: dict = {}
    monkeypatch.setitem(sys.modules, "ray", _fake_ray(calls))
    items = RayExecutor().stream(_items, [(0, 2), (1, 3, 2)])
    assert [next(items), next(items)] == [(1, (1, 0)), (1, (1, 1))]  # before the group's error
    assert calls["options"] == {"num_cpus": 1.0, "num_gpus": 0.0, "max_retries": 0, "num_returns": "streaming"}
    with pytest.raises(RuntimeError, match="group 1 failed at item 2"):
        next(items)
    assert sorted(calls["cancelled"]) == [((0, 2), True), ((1, 3, 2), True)]  # group 0 not started (group 1's ended: harmless, as in Ray)


def _raise_task_error(i: int):
    from jtraj.task import TaskError

    if i == 1:
        raise TaskError("phases[0].contacts", ["hand"], "expected contacts of the robot", "mine.toml")
    return i


def test_a_ray_groups_error_is_the_groups_own(monkeypatch):
    """Ray raises a group's error as its RayTaskError, a message of the worker's traceback in
    terminal colours, which the command line printed as its one line; the group's own error
    now comes back, Ray's as its cause, from map and from stream."""
    from jtraj.task import TaskError

    ray = _fake_ray({})
    monkeypatch.setitem(sys.modules, "ray", ray)
    said = "mine.toml: phases[0].contacts: ['hand']: expected contacts of the robot"
    with pytest.raises(TaskError) as info:
        list(RayExecutor().map(_raise_task_error, [(0,), (1,)]))
    assert str(info.value) == said and isinstance(info.value.__cause__, ray.exceptions.RayTaskError)
    with pytest.raises(RuntimeError, match=r"^group 0 failed at item 1$") as stream_info:
        list(RayExecutor().stream(_items, [(0, 3, 1)]))
    assert type(stream_info.value) is RuntimeError


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


def test_no_address_starts_a_fresh_local_instance(monkeypatch):
    """No address: a fresh local instance (``address="local"``), as the help promises.
    ``ray.init(address=None)`` joined a cluster already running on this machine (or
    RAY_ADDRESS's), which refused the local instance's settings, reported as a failure to
    connect 'at None'."""
    calls: dict = {}
    monkeypatch.setitem(sys.modules, "ray", _fake_ray(calls))
    monkeypatch.setenv("RAY_ADDRESS", "10.0.0.2:6379")
    RayExecutor().connect()
    assert calls["address"] == "local" and calls["init"]["_system_config"] == {"worker_niceness": 0}
    monkeypatch.setitem(sys.modules, "ray", _refusing_ray({}, ValueError("When connecting to an existing cluster, _system_config must not be provided.")))
    with pytest.raises(ExecutorUnavailableError, match=r"^Ray could not start a local instance: When connecting to an existing cluster, _system_config must not be provided. \(give the address"):
        RayExecutor().connect()


def test_ray_init_leaves_the_callers_sigterm_handler(monkeypatch):
    """ray.init sets a SIGTERM handler of its own (sys.exit(15)), which replaced the one jtraj's
    command line sets: SIGTERM during a Ray sweep ended it with status 15, without its message
    of what was kept."""
    import signal

    calls: dict = {}
    ray = _fake_ray(calls)
    init = ray.init

    def init_setting_a_handler(*args, **kwargs):
        signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(signum))
        return init(*args, **kwargs)

    monkeypatch.setattr(ray, "init", init_setting_a_handler)
    monkeypatch.setitem(sys.modules, "ray", ray)

    def mine(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, mine)
    try:
        RayExecutor().connect()
        assert signal.getsignal(signal.SIGTERM) is mine and calls["address"] == "local"
    finally:
        signal.signal(signal.SIGTERM, previous)


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
    fresh: dict = {}
    monkeypatch.setitem(sys.modules, "ray", _fake_ray(fresh))
    RayExecutor(address="auto").connect()  # left to Ray
    assert fresh["address"] == "auto"


def test_executor_for_names():
    assert isinstance(executor_for("local", workers=3), LocalExecutor)
    assert executor_for("local", workers=3).workers == 3
    assert executor_for("ray", ray_address="auto").address == "auto"
    assert set(EXECUTORS) == {"local", "ray"}
    with pytest.raises(ValueError, match=r"^executor_for: executor='dask': expected one of local, ray$"):  # the message of compare's and robustness's check
        executor_for("dask")
    # an option of the other executor, or a worker count that is not one, was ignored or failed later
    for kwargs, message in (
        (dict(name="ray", workers=4), "workers=4: is for executor='local'; with executor='ray' each group is a Ray task"),
        (dict(name="local", workers=2, ray_address="ray://10.0.0.1:10001"), "ray_address='ray://10.0.0.1:10001': needs executor='ray'"),
        (dict(name="local", workers=2.5), "workers=2.5: expected an integer >= 1"),
        (dict(name="local", workers=True), "workers=True: expected an integer >= 1"),
    ):
        with pytest.raises(ValueError, match=rf"^executor_for: {re.escape(message)}"):
            executor_for(**kwargs)
    assert executor_for("local", workers=np.int64(2)).workers == 2


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


def test_jtrajs_own_errors_survive_pickling():
    """Every exception class of jtraj whose constructor takes several arguments comes back from
    a worker process as it was raised (found by walking the package; InputError and
    IpoptOptionError did not survive pickling)."""
    import importlib
    import inspect
    import pickle
    import pkgutil

    import jtraj
    from jtraj.cli import InputError
    from jtraj.solvers.ipopt_catalog import IpoptOptionError
    from jtraj.task import TaskError

    samples = {InputError: InputError("--tasks", "moonwalk", "expected a task name"), IpoptOptionError: IpoptOptionError("tol", -1.0, "expected > 0"), TaskError: TaskError("timestep", 0.0, "expected > 0", "mine.toml")}
    found = set()
    for module in pkgutil.walk_packages(jtraj.__path__, "jtraj."):
        for cls in vars(importlib.import_module(module.name)).values():
            if inspect.isclass(cls) and issubclass(cls, BaseException) and cls.__module__ == module.name and "__init__" in vars(cls):
                required = [p for p in inspect.signature(cls.__init__).parameters.values() if p.default is p.empty and p.kind is p.POSITIONAL_OR_KEYWORD]
                if len(required) > 2:  # self and more than a message
                    found.add(cls)
    assert found == set(samples), found
    for cls, error in samples.items():
        back = pickle.loads(pickle.dumps(error))
        assert type(back) is cls and str(back) == str(error) and vars(back) == vars(error)


def test_a_second_sweep_asking_for_another_cluster_is_refused(monkeypatch):
    """Ray connects a process once: a notebook's second sweep with ray_address="ray://..."
    ran on the local instance its first sweep had started, the cluster it named neither
    reached nor refused. The same address connects again; another one is refused in words."""
    calls: dict = {}
    monkeypatch.setitem(sys.modules, "ray", _fake_ray(calls))
    monkeypatch.setattr("jtraj.executors._reachable", lambda address, timeout=5.0: None)
    RayExecutor().connect()  # a local instance
    assert calls["address"] == "local"
    calls.clear()
    RayExecutor().connect()  # the same: no second init
    assert "address" not in calls
    with pytest.raises(ExecutorUnavailableError, match=r"^Ray is connected to a local instance in this process, and this sweep asks for the cluster at 'ray://head:10001': call ray\.shutdown\(\) first"):
        RayExecutor(address="ray://head:10001").connect()
    assert "address" not in calls
    sys.modules["ray"].is_initialized = lambda: False  # ray.shutdown(): the record is void
    RayExecutor(address="ray://head:10001").connect()
    assert calls["address"] == "ray://head:10001"
    sys.modules["ray"].is_initialized = lambda: True
    with pytest.raises(ExecutorUnavailableError, match=r"^Ray is connected to the cluster at 'ray://head:10001' in this process, and this sweep asks for a local instance"):
        RayExecutor().connect()
    # the caller shut Ray down and connected again itself, between two calls (a new job): the
    # record is not of that connection, and the sweep takes it as it is
    sys.modules["ray"].get_runtime_context = lambda: types.SimpleNamespace(get_job_id=lambda: "02000000")
    calls.clear()
    RayExecutor().connect()
    assert "address" not in calls


def test_a_python_sweep_refused_its_cluster_leaves_its_folder_alone(monkeypatch, tmp_path):
    """From Python the cluster was first connected inside the executor's map, after the sweep
    had cleared its earlier tables and marked its provenance unfinished: a refused address
    left the folder without its table. It is connected (or refused) before OUT is touched."""
    from jtraj.experiments import compare, robustness

    calls: dict = {}
    monkeypatch.setitem(sys.modules, "ray", _fake_ray(calls))
    monkeypatch.setattr("jtraj.executors._reachable", lambda address, timeout=5.0: None)
    RayExecutor().connect()  # an earlier sweep's local instance
    (tmp_path / "table_iv.md").write_text("earlier table\n")
    (tmp_path / "runs.jsonl").write_text("")
    for sweep in (compare, robustness):
        with pytest.raises(ExecutorUnavailableError, match="Ray is connected to a local instance"):
            sweep(["big_jump"], ["se3"], out=tmp_path, executor="ray", ray_address="ray://head:10001", progress=None)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["runs.jsonl", "table_iv.md"]
    assert (tmp_path / "table_iv.md").read_text() == "earlier table\n"


def _environment(name: str) -> str | None:
    return os.environ.get(name)


def test_local_workers_share_the_gpu(monkeypatch):
    """JAX reserves 75 % of a GPU's memory in each process that uses it: a sweep's worker
    processes, and the command that starts them, asked for it one after another. Workers
    preallocate nothing unless the user said otherwise; so does the command line's process
    with --workers > 1 (a CPU ignores the variable)."""
    name = "XLA_PYTHON_CLIENT_PREALLOCATE"
    monkeypatch.setenv(name, "set")  # recorded, so that the test's end puts back the caller's
    monkeypatch.delenv(name)
    assert dict(LocalExecutor(workers=2).map(_environment, [(name,), (name,)])) == {0: "false", 1: "false"}
    assert name not in os.environ  # the caller's own environment is left alone
    monkeypatch.setenv(name, "true")  # a user's choice stays
    assert dict(LocalExecutor(workers=2).map(_environment, [(name,), (name,)])) == {0: "true", 1: "true"}


@pytest.mark.parametrize("argv, shared", [(["robustness", "--workers", "2"], True), (["compare", "--executor", "ray"], True), (["robustness"], False), (["solve", "big_jump"], False)])
def test_the_command_that_starts_workers_shares_the_gpu(monkeypatch, argv, shared):
    from jtraj import cli

    name = "XLA_PYTHON_CLIENT_PREALLOCATE"
    monkeypatch.setenv(name, "set")  # recorded, so that the test's end puts back the caller's
    monkeypatch.delenv(name)
    seen = []

    class Stop(Exception):
        pass

    def check(args):  # the first thing that could use a GPU: what it finds, then stop
        seen.append(os.environ.get(name))
        raise Stop

    monkeypatch.setattr(cli, "_check_inputs", check)
    monkeypatch.setattr(cli, "_loads_mujoco", lambda args: False)
    with pytest.raises(Stop):
        cli.main(argv)
    assert seen == (["false"] if shared else [None])
