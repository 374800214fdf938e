"""Where the groups of a sweep run: worker processes on this machine, or Ray tasks on a cluster.

A sweep (`jtraj compare`, `jtraj robustness`) is a list of independent groups, one per (task,
parameterization): each group compiles its NLP once and solves its runs. An executor runs
``fn(*args)`` for every ``args`` of the list and yields ``(index, result)`` pairs as groups
finish, in completion order, so the caller can checkpoint each group's rows as it arrives.

    for i, rows in executor_for("local", workers=2).map(fn, arg_list):
        ...

``fn`` must be importable (a module-level function) and its arguments and results picklable:
both executors ship them to other processes.

``stream(fn, arg_list)`` is the same for a generator function ``fn``: it yields ``(index, item)``
for every item a group yields, so that the caller can keep each item (a solve of the group) as
it comes: a Ray task hands each back as it is yielded (a streaming generator task), local worker
processes hand back a group's items when the group ends (a group that must keep its items
sooner writes them itself, as `jtraj.experiments.robustness` does).

A group that raises, an interrupt (Ctrl-C, or SIGTERM, which the command line turns into one)
or a caller that stops iterating (an exception in its loop, ``close()``) ends the sweep: groups
not started are cancelled, those running are stopped (their worker processes terminated, their
Ray tasks cancelled), and the exception goes on to the caller as the group raised it (one
that cannot be pickled back from a local worker process comes as a `GroupError` with its type,
message and traceback as text). A worker that ends without
handing back its group (a local worker process that failed to start or was killed from outside,
e.g. by the kernel when memory ran out; a Ray worker that crashed or was killed, by Ray's memory
monitor too, or whose node died) ends it with `WorkerLostError`. A local worker process dies
with its caller on Linux (a parent-death signal), also when the caller is killed without
running its cleanup.

- `LocalExecutor`: ``workers`` fresh Python processes (spawn: JAX is not fork-safe); with
  ``workers <= 1`` the groups run in this process, one after the other.
- `RayExecutor`: one Ray task per group on the cluster ``ray.init(address=...)`` connects to
  (``None`` starts a fresh local Ray instance, even where a cluster runs on this machine or
  ``RAY_ADDRESS`` is set; ``"auto"`` joins the cluster of this node). Needs the optional extra
  ``pip install "jtraj[ray]"``.
"""

from __future__ import annotations

import abc
import contextlib
import dataclasses
import math
import os
import sys
from collections.abc import Callable, Generator, Iterator, Sequence
from typing import Any

from jtraj.numbers import is_whole

__all__ = ["AbstractExecutor", "LocalExecutor", "RayExecutor", "EXECUTORS", "ExecutorUnavailableError", "WorkerLostError", "GroupError", "KeyMismatchError", "check_executor_name", "check_executor", "executor_for", "SHARED_ACCELERATOR_ENV", "share_the_accelerator"]

#: Names accepted by `executor_for` and the command line's ``--executor``.
EXECUTORS = ("local", "ray")


class ExecutorUnavailableError(RuntimeError):
    """The executor cannot start here: Ray is not installed, or ``ray.init`` cannot reach the
    cluster at the given address (the message says which, and what to do)."""


class WorkerLostError(RuntimeError):
    """A worker ended without handing back its group: a local worker process failed to start or
    was killed from outside (e.g. by the kernel when memory ran out), or a Ray worker crashed or
    was killed (by Ray's memory monitor too) or its node died; the sweep's other groups were
    stopped."""


class AbstractExecutor(abc.ABC):
    """Runs independent groups of a sweep; see the module docstring."""

    @abc.abstractmethod
    def map(self, fn: Callable[..., Any], arg_list: Sequence[tuple]) -> Generator[tuple[int, Any], None, None]:
        """Yield ``(i, fn(*arg_list[i]))`` for every i, in the order the groups finish; closing
        the generator (``contextlib.closing``) stops the groups left."""

    @abc.abstractmethod
    def stream(self, fn: Callable[..., Iterator[Any]], arg_list: Sequence[tuple]) -> Generator[tuple[int, Any], None, None]:
        """Yield ``(i, item)`` for every item of every generator ``fn(*arg_list[i])``, each
        group's in its order (see the module docstring for when each comes back); closing the
        generator stops the groups left."""


@dataclasses.dataclass(frozen=True)
class LocalExecutor(AbstractExecutor):
    """``workers`` worker processes on this machine (1: in this process)."""

    workers: int = 1

    def map(self, fn, arg_list):
        if self.workers <= 1 or len(arg_list) <= 1:
            for i, args in enumerate(arg_list):
                yield i, fn(*args)
            return
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor, as_completed
        from concurrent.futures.process import BrokenProcessPool

        # JAX is not fork-safe: workers start fresh interpreters
        pool = ProcessPoolExecutor(max_workers=self.workers, mp_context=multiprocessing.get_context("spawn"), initializer=_start_worker)
        try:
            futures = {pool.submit(_portable, fn, *args): i for i, args in enumerate(arg_list)}
            for f in as_completed(futures):
                try:
                    result = f.result()
                except BrokenProcessPool as e:
                    raise WorkerLostError(
                        "a worker process ended without finishing its group: it failed to start (see its output above) or was killed "
                        "from outside, e.g. by the kernel when memory ran out (fewer workers need less)"
                    ) from e
                yield futures[f], result
        except BaseException:
            # the pool's own exit (a with block) waits for every queued group: minutes to hours
            # of solves nobody collects after a Ctrl-C or a failed group
            _stop(pool)
            raise
        pool.shutdown()

    def stream(self, fn, arg_list):
        if self.workers <= 1 or len(arg_list) <= 1:
            for i, args in enumerate(arg_list):
                for item in fn(*args):
                    yield i, item
            return
        # a generator does not cross processes: a worker hands back its group's items at its end
        groups = self.map(_collect, [(fn, *args) for args in arg_list])
        with contextlib.closing(groups):
            for i, items in groups:
                for item in items:
                    yield i, item


class KeyMismatchError(RuntimeError):
    """A worker of a sweep computed another key for its group's runs than the calling process
    (`jtraj.experiments`' ``expected``): its jtraj, MuJoCo or robot and task files differ.
    Here, beside the executors, so that the command line tells it without loading the sweeps."""


class GroupError(RuntimeError):
    """A group's exception that cannot be sent back from its worker process as it is (one that
    does not survive pickling, e.g. an exception class whose constructor takes several
    arguments and which has no ``__reduce__``): its type, message and the worker's traceback,
    as text."""


def _portable(fn: Callable[..., Any], *args) -> Any:
    """``fn(*args)`` in a local worker process, whose exception, or result, comes back to the
    caller: one that does not survive pickling broke the pool when the caller unpickled it,
    and the group's error was reported as a lost worker (killed by the kernel); it is raised
    as a `GroupError` that says what it was."""
    import pickle
    import traceback

    try:
        result = fn(*args)
    except Exception as e:
        try:
            pickle.loads(pickle.dumps(e))
        except Exception:
            raise GroupError(f"{type(e).__module__}.{type(e).__qualname__}: {e}\n(in the worker process:)\n{traceback.format_exc()}") from None
        raise
    try:
        pickle.loads(pickle.dumps(result))
    except Exception as e:
        raise GroupError(f"the group's result, a {type(result).__qualname__}, cannot be sent back from its worker process: {type(e).__name__}: {e}") from None
    return result


def _collect(fn: Callable[..., Iterator[Any]], *args) -> list:
    """The items of ``fn(*args)``, in a local worker process (`LocalExecutor.stream`)."""
    return list(fn(*args))


#: (the ray module, the address, its job id) of the connection `RayExecutor.connect` made in
#: this process
_RAY_CONNECTED: tuple[Any, str | None, Any] | None = None


def _job_id(ray) -> Any:
    """The job id of this process's Ray connection (new for each ``ray.init``), or None where
    Ray cannot say."""
    try:
        return ray.get_runtime_context().get_job_id()
    except Exception:  # an older Ray, or no runtime context
        return None


@dataclasses.dataclass(frozen=True)
class RayExecutor(AbstractExecutor):
    """One Ray task per group.

    Attributes:
        address: passed to ``ray.init``: ``None`` starts a fresh local instance (or reuses the
            one this process already started; ``ray.init(address="local")``, so a cluster
            running on this machine or ``RAY_ADDRESS`` is not joined), ``"auto"`` joins a
            running cluster, or ``"ray://host:10001"`` connects a client to a remote cluster.
        num_cpus: CPUs each group reserves on the cluster (its JAX evaluation and Ipopt run
            mostly on one core).
        num_gpus: GPUs each group reserves (default 0). Ray hides every GPU from a task that
            reserves none (its ``CUDA_VISIBLE_DEVICES`` is empty), so a group's JAX computes
            on the CPU of a GPU node unless this is given; a fraction lets that many groups
            share one GPU, and then their processes take GPU memory as they need it
            (`SHARED_ACCELERATOR_ENV`, through the task's ``runtime_env``): each reserved
            three quarters of it.
    """

    address: str | None = None
    num_cpus: float = 1.0
    num_gpus: float = 0.0

    def _options(self) -> dict:
        """The resources (and environment) of each group's ``ray.remote``."""
        options: dict = dict(num_cpus=self.num_cpus, num_gpus=self.num_gpus, max_retries=0)
        if 0.0 < self.num_gpus < 1.0:
            options["runtime_env"] = {"env_vars": dict(SHARED_ACCELERATOR_ENV)}
        return options

    def connect(self):
        """Import Ray and connect to (or start) the cluster, once per process; returns the ``ray``
        module. `ExecutorUnavailableError` where Ray is missing or the cluster cannot be
        reached, or where an earlier sweep of this process connected to another address (Ray
        connects a process once): the command line calls it while checking its inputs, before
        writing anything."""
        ray = _import_ray()
        global _RAY_CONNECTED
        if not ray.is_initialized() or (_RAY_CONNECTED and (_RAY_CONNECTED[0] is not ray or _RAY_CONNECTED[2] != _job_id(ray))):
            # shut down since (ray.shutdown()), connected again by the caller (another job), or
            # another ray module (a test's): the record is not of the connection there is now
            _RAY_CONNECTED = None
        if ray.is_initialized() and _RAY_CONNECTED and _RAY_CONNECTED[1] != self.address:
            # the second sweep of a notebook ran on the first one's instance, the cluster it
            # named neither reached nor refused
            was = "a local instance" if _RAY_CONNECTED[1] is None else f"the cluster at {_RAY_CONNECTED[1]!r}"
            now = "a local instance (no address)" if self.address is None else f"the cluster at {self.address!r}"
            raise ExecutorUnavailableError(
                f"Ray is connected to {was} in this process, and this sweep asks for {now}: call ray.shutdown() first, "
                "or give the same address"
            )
        if not ray.is_initialized():
            # the workers import jtraj from their own environment: the cluster's nodes must have
            # jtraj installed (or use a runtime_env); a local instance shares this one
            kwargs: dict = dict(include_dashboard=False, log_to_driver=False)
            if self.address is None:
                # a local instance's workers do the sweep's whole work: Ray's default worker
                # niceness (15) made them yield to every other process on the machine (measured:
                # a tiny sweep's compile took 152 s in a worker beside two busy processes on 2
                # cores, 11 s in the calling process)
                kwargs["_system_config"] = {"worker_niceness": 0}
            _reachable(self.address)
            try:
                # ray.init sets its own SIGTERM handler (sys.exit): the caller's (jtraj's command
                # line turns SIGTERM into Ctrl-C's cleanup and exit status 143) is put back
                with _keep_sigterm_handler():
                    # None: a fresh instance. ray.init(address=None) joined a cluster running on this
                    # machine (or RAY_ADDRESS's), which refuses _system_config: "could not connect at None"
                    ray.init(address="local" if self.address is None else self.address, **kwargs)
                _RAY_CONNECTED = (ray, self.address, _job_id(ray))
            except (ConnectionError, ValueError) as e:  # no cluster there, or a malformed address
                if self.address is None:
                    raise ExecutorUnavailableError(f"Ray could not start a local instance: {e} (give the address of a running cluster with --ray-address, or use --executor local)") from None
                raise ExecutorUnavailableError(
                    f"Ray could not connect to a cluster at {self.address!r}: {e} (give the address of a running cluster, "
                    "e.g. --ray-address auto on one of its nodes or ray://HOST:10001, or leave it out to start a local instance)"
                ) from None
        if self.num_gpus > 0 and (gpus := float(ray.cluster_resources().get("GPU", 0.0))) < self.num_gpus:
            # Ray queues a task no node can take, and the sweep waited without end
            where = "the local instance" if self.address is None else f"the cluster at {self.address!r}"
            raise ExecutorUnavailableError(
                f"each group's Ray task reserves {self.num_gpus:g} GPUs (--ray-gpus), and {where} has {gpus:g}: Ray would never start one "
                "(give fewer, or none to compute on the CPUs)"
            )
        return ray

    def map(self, fn, arg_list):
        ray = self.connect()
        remote = ray.remote(**self._options())(fn)
        pending = {remote.remote(*args): i for i, args in enumerate(arg_list)}
        try:
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1)
                for ref in ready:
                    i = pending.pop(ref)
                    with _lost_as_worker_lost(ray):
                        result = ray.get(ref)
                    yield i, result
        except BaseException:
            _cancel(ray, pending)
            raise

    def stream(self, fn, arg_list):
        """One streaming generator task per group: each item comes back as the task yields it."""
        ray = self.connect()
        remote = ray.remote(**self._options(), num_returns="streaming")(fn)
        pending = {remote.remote(*args): i for i, args in enumerate(arg_list)}
        try:
            while pending:
                # a generator is ready when its next item has come, or its task has ended
                ready, _ = ray.wait(list(pending), num_returns=1)
                for gen in ready:
                    with _lost_as_worker_lost(ray):
                        try:
                            item = ray.get(next(gen))  # a group's error, or its worker's loss, comes as an item
                        except StopIteration:
                            del pending[gen]
                            continue
                    yield pending[gen], item
        except BaseException:
            _cancel(ray, pending)
            raise


@contextlib.contextmanager
def _keep_sigterm_handler():
    """Put back the SIGTERM handler the block replaced (in the main thread, the only one that
    can set one)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.getsignal(signal.SIGTERM)
    try:
        yield
    finally:
        if previous is not None:  # None: set outside Python, which cannot be put back
            signal.signal(signal.SIGTERM, previous)


def _cancel(ray, pending) -> None:
    """Cancel the Ray tasks (object refs or streaming generators) left: queued tasks are
    dropped, running ones' workers killed."""
    for ref in pending:
        with contextlib.suppress(Exception):
            ray.cancel(ref, force=True)


#: Ray's errors of a task whose worker ended without finishing it: its process crashed or was
#: killed (by Ray's memory monitor: OutOfMemoryError), its node died, or its result was lost
#: with the node that held it
_RAY_LOST = ("WorkerCrashedError", "OutOfMemoryError", "NodeDiedError", "ObjectLostError")


@contextlib.contextmanager
def _lost_as_worker_lost(ray):
    """Raise Ray's errors of a lost worker (`_RAY_LOST`) as `WorkerLostError` (the command line
    says it in one line and the sweeps say what they kept), with the first line of Ray's
    message; they were raw tracebacks of Ray's own. A group's own error (Ray's
    ``RayTaskError``) is raised as the group raised it."""
    exceptions = getattr(ray, "exceptions", None)
    lost = tuple(error for name in _RAY_LOST if isinstance(error := getattr(exceptions, name, None), type))
    task_error = getattr(exceptions, "RayTaskError", None)
    group = task_error if isinstance(task_error, type) else ()
    try:
        yield
    except group as e:
        # a group's own error: Ray's carries the group's exception (``cause``) in a message of
        # its worker's whole traceback, with terminal colours, which the command line printed
        # as its one line; the group's exception goes on, Ray's as its cause
        cause = getattr(e, "cause", None)
        if not isinstance(cause, Exception):
            raise
        raise cause from e
    except lost as e:
        said = next((line.strip() for line in str(e).splitlines() if line.strip()), type(e).__name__)
        raise WorkerLostError(
            f"a Ray worker ended without finishing its group: its process crashed or was killed (e.g. by Ray when the node's memory ran out) "
            f"or its node died (Ray's {type(e).__name__}: {said})"
        ) from e


#: set (where not set already) in a sweep's worker processes, and by the command line in the
#: process that starts them: JAX reserves 75 % of a GPU's memory in every process that uses it,
#: and several processes on one GPU ran out of memory (its documentation's advice; the
#: multi-worker GPU runs in results/ set it by hand). Only GPUs read it.
SHARED_ACCELERATOR_ENV = {"XLA_PYTHON_CLIENT_PREALLOCATE": "false"}


def share_the_accelerator() -> None:
    """Set `SHARED_ACCELERATOR_ENV` in this process's environment where a variable is not set
    already (a user's own value stays): before JAX first uses a GPU, so that the processes of a
    sweep each take the memory they need instead of three quarters of it."""
    for name, value in SHARED_ACCELERATOR_ENV.items():
        os.environ.setdefault(name, value)


def _start_worker() -> None:
    """A local worker process's start: Ctrl-C is the caller's (`_ignore_interrupt`), the
    worker dies with the caller (`_die_with_parent`), and it shares the GPU with the others
    (`share_the_accelerator`)."""
    _ignore_interrupt()
    _die_with_parent()
    share_the_accelerator()


def _die_with_parent() -> None:
    """On Linux, have the kernel kill this worker process when the thread that started it (the
    caller's, which submitted the groups) ends (``prctl(PR_SET_PDEATHSIG, SIGKILL)``): a caller
    killed without running its cleanup (SIGKILL, a crash) left its workers solving groups
    nobody collects, then waiting forever. Elsewhere, or where prctl cannot be called, nothing
    is done."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes
    import multiprocessing
    import signal

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(1, int(signal.SIGKILL), 0, 0, 0) != 0:  # 1: PR_SET_PDEATHSIG
            return
    except (OSError, AttributeError):
        return
    parent = multiprocessing.parent_process()
    if parent is not None and os.getppid() != parent.pid:  # the caller ended before prctl
        os._exit(1)


def _ignore_interrupt() -> None:
    """Part of a worker process's start: Ctrl-C reaches every process of the terminal's
    process group, and each worker printed its own KeyboardInterrupt traceback; the caller
    alone handles it, and stops the workers (`_stop`)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _stop(pool) -> None:
    """Cancel a process pool's groups not started and terminate its worker processes."""
    processes = list((pool._processes or {}).values())  # shutdown() forgets them
    pool.shutdown(wait=False, cancel_futures=True)
    for p in processes:
        p.terminate()
    for p in processes:
        p.join(5)
        if p.is_alive():  # SIGTERM ignored or handled
            p.kill()
            p.join()


def _reachable(address: str | None, timeout: float = 5.0) -> None:
    """`ExecutorUnavailableError` where ``address`` names a host and port (``HOST:PORT`` or
    ``ray://HOST:PORT``) that takes no TCP connection within ``timeout`` seconds: ``ray.init``
    retries such an address for minutes without a word (measured: still waiting after 500 s
    for 127.0.0.1:1). Other addresses (None, ``"auto"``) are left to Ray."""
    import socket

    if not address:
        return
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not host or not port.isdigit():
        return
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout).close()
    except (OSError, ValueError) as e:
        raise ExecutorUnavailableError(
            f"Ray could not connect to a cluster at {address!r}: nothing answers at {host}:{port} ({e}); give the address of a running "
            "cluster, e.g. --ray-address auto on one of its nodes or ray://HOST:10001, or leave it out to start a local instance"
        ) from None


def _import_ray():
    try:
        import ray
    except ImportError:
        raise ExecutorUnavailableError('the Ray executor needs Ray: pip install "jtraj[ray]" (or pip install ray), or use --executor local') from None
    return ray


def check_executor_name(name: str, where: str = "executor_for") -> None:
    """A ValueError unless ``name`` is one of `EXECUTORS`; ``where`` (the function given it:
    ``executor_for``, or a sweep that checks before it writes anything) begins the message."""
    if name not in EXECUTORS:
        raise ValueError(f"{where}: executor={name!r}: expected one of {', '.join(EXECUTORS)}")


def check_executor(name: str, workers: int = 1, ray_address: str | None = None, where: str = "executor_for", ray_gpus: float | None = None) -> None:
    """A ValueError (its message begun by ``where``) for an unknown executor, a worker count that
    is not an integer >= 1, GPUs per Ray task (``ray_gpus``) that are not a number >= 0, or an
    option of the other executor (``ray_address`` or ``ray_gpus`` without ``"ray"``,
    ``workers`` > 1 with it), which would be ignored without a word."""
    check_executor_name(name, where)
    if not is_whole(workers) or workers < 1:
        raise ValueError(f"{where}: workers={workers!r}: expected an integer >= 1")
    if ray_address is not None and name != "ray":
        raise ValueError(f"{where}: ray_address={ray_address!r}: needs executor='ray' (the local executor does not use a cluster)")
    if ray_gpus is not None:
        if isinstance(ray_gpus, bool) or not isinstance(ray_gpus, (int, float)) or not (math.isfinite(ray_gpus) and ray_gpus >= 0):
            raise ValueError(f"{where}: ray_gpus={ray_gpus!r}: expected a number >= 0 (the GPUs each group's Ray task reserves; a fraction shares one)")
        if name != "ray":
            raise ValueError(f"{where}: ray_gpus={ray_gpus!r}: needs executor='ray' (the local executor's processes see the machine's GPUs)")
    if workers > 1 and name != "local":
        raise ValueError(f"{where}: workers={workers!r}: is for executor='local'; with executor={name!r} each group is a Ray task and the cluster runs as many at once as it has CPUs")


def executor_for(name: str = "local", workers: int = 1, ray_address: str | None = None, ray_gpus: float | None = None) -> AbstractExecutor:
    """The executor called ``name`` (one of `EXECUTORS`), checked by `check_executor`
    (``executor_for("ray", workers=4)`` ran one task at a time per CPU without a word);
    ``ray_gpus``: `RayExecutor.num_gpus` (None: 0)."""
    check_executor(name, workers, ray_address, ray_gpus=ray_gpus)
    return LocalExecutor(int(workers)) if name == "local" else RayExecutor(ray_address, num_gpus=float(ray_gpus or 0.0))
