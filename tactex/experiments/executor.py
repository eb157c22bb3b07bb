"""Where independent runs execute: local worker processes (the default) or a Ray cluster.

A study or a sweep is a list of runs, each a pure function of its task (config and seed) and of
read-only inputs shared by all runs (clouds, eigenbases). :class:`Executor` runs them and yields an
:class:`Outcome` per run as it finishes, in whatever order; the caller orders the results by run
index, so what it writes does not depend on the executor or the order.

- :class:`LocalExecutor`: ``workers`` spawned processes; the shared inputs go to each process once
  (its initializer). A process that dies (out of memory, killed) breaks the pool: it is rebuilt and
  the unfinished runs are submitted again, up to ``max_retries`` times.
- :class:`RayExecutor`: Ray tasks on a local instance (``address=None``) or an existing cluster
  (``"auto"``, ``"HOST:PORT"``, ``"ray://HOST:10001"``). The shared inputs are put in Ray's object
  store once; a node fetches them once and its workers read them without a copy. Ray re-runs a task
  whose worker or node is lost (``max_retries``); an exception raised by the run itself is not retried.
  On an existing cluster the runs execute this process's tactex: the package is shipped to the nodes
  in Ray's runtime environment (``py_modules``), so a node needs only Python, Ray and tactex's
  third-party dependencies, and can never run another version of tactex than the driver's.

Either way a run that raises becomes an outcome with its error and traceback (the study goes on),
every run is limited to one BLAS thread (the processes are the parallelism, and results do not
depend on a thread count), and Ctrl-C (KeyboardInterrupt in the caller) cancels what is pending or
running before it propagates. Ray is imported only by :class:`RayExecutor`.
"""

from __future__ import annotations

import multiprocessing
import os
import socket
import time
import traceback
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tactex.errors import ConfigError, ExecutorError, MissingDependencyError

__all__ = ["RAY_PROBE_S", "Executor", "LocalExecutor", "Outcome", "RayExecutor", "check_ray_address",
           "cluster_runtime_env", "echo", "make_executor", "start_local_ray"]

#: A run: ``fn(task, shared)`` → a picklable result. Must be a module-level function.
RunFn = Callable[[Any, Any], Any]

#: How often a run is started again after its worker process or node was lost.
DEFAULT_MAX_RETRIES = 3


@dataclass
class Outcome:
    """One finished run: ``index`` into the task list; ``value`` when it returned, otherwise
    ``error`` (``Type: message``) and ``traceback``. ``worker`` is ``host:pid`` of the process
    that ran it (on Ray the host is the node's IP address, as Ray names nodes); ``seconds`` its wall
    time there [s]; ``attempt`` how many earlier starts of the run were lost with their worker
    process or node (0: it ran once)."""

    index: int
    value: Any = None
    error: str = ""
    traceback: str = ""
    worker: str = ""
    seconds: float = 0.0
    attempt: int = 0

    @property
    def ok(self) -> bool:
        return not self.error


def _limit_threads() -> None:
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")


def _call(fn: RunFn, index: int, task: Any, shared: Any, host: str = "") -> Outcome:
    """Run one task where it is executed; an exception becomes an error outcome. ``host`` names this
    machine in :attr:`Outcome.worker` (default: its hostname)."""
    from threadpoolctl import threadpool_limits

    where = f"{host or socket.gethostname()}:{os.getpid()}"
    t0 = time.perf_counter()
    try:
        with threadpool_limits(limits=1):
            value = fn(task, shared)
    except Exception as exc:  # recorded with its run; KeyboardInterrupt / SystemExit still propagate
        return Outcome(index, error=f"{type(exc).__name__}: {exc}", traceback=traceback.format_exc(), worker=where,
                       seconds=time.perf_counter() - t0)
    return Outcome(index, value=value, worker=where, seconds=time.perf_counter() - t0)


def echo(task: Any, shared: Any = None) -> Any:
    """A run that returns its task at once: what an executor costs per run by itself (bench)."""
    return task


class Executor(ABC):
    """Runs independent tasks; use as a context manager (``close`` frees workers or a Ray instance)."""

    name = "executor"

    @property
    @abstractmethod
    def slots(self) -> int:
        """How many runs execute at once."""

    @abstractmethod
    def run(self, fn: RunFn, tasks: Sequence[Any], shared: Any = None) -> Iterator[Outcome]:
        """Run ``fn(task, shared)`` for every task; yield an :class:`Outcome` per task as each
        finishes. ``running`` tells how many are executing now (for progress lines)."""

    running: int = 0

    def describe(self) -> str:
        return f"{self.name} ({self.slots} worker{'s' if self.slots != 1 else ''})"

    def close(self) -> None:  # noqa: B027 — nothing to free by default
        pass

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# -- local processes -------------------------------------------------------------------------------------
_SHARED: dict[str, Any] = {}


def _init_local_worker(shared: Any) -> None:
    _limit_threads()
    _SHARED["value"] = shared


def _call_local(fn: RunFn, index: int, task: Any) -> Outcome:
    return _call(fn, index, task, _SHARED.get("value"))


class LocalExecutor(Executor):
    """``workers`` processes on this machine (0 = one per core); 1 runs in this process."""

    name = "local"

    def __init__(self, workers: int = 0, *, max_retries: int = DEFAULT_MAX_RETRIES) -> None:
        if isinstance(workers, bool) or not isinstance(workers, int) or workers < 0:
            raise ConfigError(f"--workers must be an integer ≥ 0 (0 = one per core), got {workers!r}")
        self.workers = workers or os.cpu_count() or 1
        self.max_retries = max_retries

    @property
    def slots(self) -> int:
        return self.workers

    def run(self, fn: RunFn, tasks: Sequence[Any], shared: Any = None) -> Iterator[Outcome]:
        if not tasks:
            return
        if self.workers == 1:
            yield from self._run_here(fn, tasks, shared)
        else:
            yield from self._run_pool(fn, tasks, shared)

    def _run_here(self, fn: RunFn, tasks: Sequence[Any], shared: Any) -> Iterator[Outcome]:
        for i, task in enumerate(tasks):
            self.running = 1
            out = _call(fn, i, task, shared)
            self.running = 0
            yield out

    def _run_pool(self, fn: RunFn, tasks: Sequence[Any], shared: Any) -> Iterator[Outcome]:
        remaining = set(range(len(tasks)))
        attempts = dict.fromkeys(remaining, 0)
        # spawn, not fork: the caller may hold threads (a Ray driver, BLAS pools) that fork would copy half-way
        ctx = multiprocessing.get_context("spawn")
        try:
            while remaining:
                pool = ProcessPoolExecutor(max_workers=min(self.workers, len(remaining)), mp_context=ctx,
                                           initializer=_init_local_worker, initargs=(shared,))
                pending: dict[Future, int] = {}
                broken = False
                try:
                    for i in sorted(remaining):
                        attempts[i] += 1
                        pending[pool.submit(_call_local, fn, i, tasks[i])] = i
                    while pending:
                        self.running = min(len(pending), self.workers)
                        done, _ = wait(pending, return_when=FIRST_COMPLETED)
                        for fut in done:
                            i = pending.pop(fut)
                            try:
                                out = fut.result()
                            except BrokenProcessPool:  # a worker died: this run goes to a fresh pool
                                broken = True
                                continue
                            remaining.discard(i)
                            self.running = min(len(pending), self.workers)
                            out.attempt = attempts[i] - 1
                            yield out
                except BaseException:
                    _stop_pool(pool)
                    raise
                if broken:
                    _stop_pool(pool)
                else:
                    pool.shutdown(wait=True)
                for i in sorted(remaining):
                    if attempts[i] > self.max_retries:
                        remaining.discard(i)
                        yield Outcome(i, error=f"WorkerLost: the worker process died in all {attempts[i]} attempts")
        finally:
            self.running = 0


def _stop_pool(pool: ProcessPoolExecutor) -> None:
    """Cancel the queue and end the workers now (Ctrl-C, or a broken pool)."""
    # the executor has no public way to end its workers before Python 3.14 (terminate_workers): its
    # process table is the only handle
    procs = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        if p.is_alive():
            p.terminate()
    for p in procs:
        p.join(timeout=5)


# -- Ray -------------------------------------------------------------------------------------------------
def _import_ray():
    try:
        import ray
    except ImportError as exc:
        raise MissingDependencyError("ray", "distributed", "running on Ray (--ray, --ray-address)") from exc
    return ray


#: Every Ray worker of a study: one BLAS thread (the runs are the parallelism).
_RUNTIME_ENV = {"env_vars": {v: "1" for v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}}


def cluster_runtime_env() -> dict[str, Any]:
    """The runtime environment of a study on an existing cluster: :data:`_RUNTIME_ENV` and this
    process's tactex package (``py_modules``: Ray zips the folder once, keeps it in the cluster's
    store by content hash, and each node unpacks it in its own session folder before its first run)."""
    import tactex

    return {**_RUNTIME_ENV, "py_modules": [str(Path(tactex.__file__).parent)]}


def _call_ray(fn: RunFn, index: int, task: Any, shared: Any) -> Outcome:
    """:func:`_call` in a Ray worker: the node's IP address and the task's attempt in the outcome."""
    import ray

    out = _call(fn, index, task, shared, host=ray.util.get_node_ip_address())
    # Ray numbers the starts of a task (0 = first); it has no public call for it
    core = getattr(ray._private.worker.global_worker, "core_worker", None)
    attempt = getattr(core, "get_current_task_attempt_number", None)
    out.attempt = int(attempt()) if callable(attempt) else 0
    return out


def start_local_ray(num_cpus: int | None, attempts: int = 3) -> None:
    """Start a Ray instance on this machine with ``num_cpus`` CPUs (None: all).

    Tried ``attempts`` times: on a heavily loaded machine Ray's raylet can give up waiting for its
    agent process (a fixed 15 s wait) and the start fails; a second start usually succeeds.

    Its workers run at the nice level of this process unless ``RAY_worker_niceness`` says otherwise: Ray
    lowers them to nice 15, which suits a node of its own, but on a machine doing anything else a worker at
    nice 15 gets a twenty-fifth of the CPU a busy process at nice 0 gets, and the study crawls."""
    ray = _import_ray()
    os.environ.setdefault("RAY_worker_niceness", "0")  # read by the raylet this start spawns
    for attempt in range(1, attempts + 1):
        try:
            ray.init(num_cpus=num_cpus, include_dashboard=False, runtime_env=_RUNTIME_ENV, log_to_driver=False,
                     configure_logging=False)
            return
        except Exception as exc:  # Ray raises plain Exception / RuntimeError on a failed start
            ray.shutdown()
            if attempt == attempts:
                raise ExecutorError(
                    f"a local Ray instance (--ray) did not start in {attempts} attempts ({exc}); see "
                    "/tmp/ray/session_latest/logs, or start one yourself (ray start --head) and pass "
                    "--ray-address auto") from exc


#: Connections to a ``ray://`` address whose server was reached but whose session failed to start.
CLIENT_ATTEMPTS = 3


def _connect(ray, address: str) -> None:
    """Connect to the cluster at ``address`` with :func:`cluster_runtime_env`.

    A Ray client connection is tried again when the server answered but the session it starts for
    this client (a process on the head) failed: on a loaded head that start can fail once and succeed
    the next time. An address that does not answer fails at once (Ray has already waited for it)."""
    for attempt in range(1, CLIENT_ATTEMPTS + 1):
        try:
            ray.init(address=address, runtime_env=cluster_runtime_env(), log_to_driver=False, configure_logging=False)
            return
        except ConnectionError as exc:
            ray.shutdown()
            if "Initialization failure from server" in str(exc) and attempt < CLIENT_ATTEMPTS:
                time.sleep(1.0)
                continue
            raise ConfigError(f"cannot connect to the Ray cluster at --ray-address '{address}': {exc}") from exc


class RayExecutor(Executor):
    """Ray tasks, one CPU each. ``address`` None starts a local instance with ``workers`` CPUs (0 =
    all cores) and stops it on ``close``; otherwise connects to that cluster (``ray://`` client
    addresses included, with this process's tactex shipped to the nodes: :func:`cluster_runtime_env`)
    and only disconnects. If this process is already connected to Ray (a test,
    a notebook), that connection is used as it is. ``workers`` > 0 caps the runs in flight."""

    name = "ray"

    def __init__(self, workers: int = 0, *, address: str | None = None,
                 max_retries: int = DEFAULT_MAX_RETRIES) -> None:
        if isinstance(workers, bool) or not isinstance(workers, int) or workers < 0:
            raise ConfigError(f"--workers must be an integer ≥ 0 (0 = all CPUs of the cluster), got {workers!r}")
        ray = _import_ray()
        self._ray = ray
        self.max_retries = max_retries
        self._owns = False
        if not ray.is_initialized():
            if address is None:
                start_local_ray(workers or None)
            else:
                check_ray_address(address.strip())
                _connect(ray, address)
            self._owns = True
        cpus = int(ray.cluster_resources().get("CPU", 1))
        self.workers = min(workers, cpus) if workers else cpus
        self.address = address or "local"

    @property
    def slots(self) -> int:
        return self.workers

    def describe(self) -> str:
        return f"ray at {self.address} ({self.slots} worker{'s' if self.slots != 1 else ''})"

    def run(self, fn: RunFn, tasks: Sequence[Any], shared: Any = None) -> Iterator[Outcome]:
        ray = self._ray
        if not tasks:
            return
        # once into the object store; a task given the reference reads the node's copy
        shared_ref = ray.put(shared)
        remote = ray.remote(num_cpus=1, max_retries=self.max_retries, retry_exceptions=False)(_call_ray)
        queue = list(range(len(tasks)))
        refs: dict[Any, int] = {}
        try:
            while queue or refs:
                while queue and len(refs) < self.workers:
                    i = queue.pop(0)
                    refs[remote.remote(fn, i, tasks[i], shared_ref)] = i
                self.running = len(refs)
                ready, _ = ray.wait(list(refs), num_returns=1, timeout=1.0)
                for ref in ready:
                    i = refs.pop(ref)
                    self.running = len(refs)
                    try:
                        yield ray.get(ref)
                    except ray.exceptions.RayError as exc:  # worker or node lost more often than max_retries
                        yield Outcome(i, error=f"WorkerLost: {type(exc).__name__}: {exc}"[:2000])
        except BaseException:
            for ref in refs:
                ray.cancel(ref, force=True)
            raise
        finally:
            self.running = 0

    def close(self) -> None:
        if self._owns and self._ray.is_initialized():
            self._ray.shutdown()
        self._owns = False


#: How long a --ray-address's host may take to answer a TCP connection before the study is refused [s]: Ray's
#: own connection to a GCS address nobody serves retries without end.
RAY_PROBE_S = 5.0


def check_ray_address(address: str) -> None:
    """Refuse (:class:`ConfigError`) a ``--ray-address`` that is not ``auto``, ``HOST:PORT`` or
    ``ray://HOST:PORT``, or whose port does not accept a TCP connection within :data:`RAY_PROBE_S`."""
    if address == "auto":
        return
    client = address.startswith("ray://")
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ConfigError(f"--ray-address '{address}' is not HOST:PORT (the head's GCS, e.g. 10.0.0.2:6379), "
                          "ray://HOST:PORT (its Ray client server, e.g. ray://10.0.0.2:10001) or auto")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=RAY_PROBE_S).close()
    except OSError as exc:
        started = (f"ray start --head --ray-client-server-port {port}" if client else
                   f"ray start --head --port {port}")
        raise ConfigError(f"nothing answers at --ray-address '{address}' within {RAY_PROBE_S:g} s "
                          f"({exc.strerror or exc}): is the head started there ({started}) and its port open to "
                          "this machine? (docs/distributed.md)") from None


def make_executor(workers: int = 0, *, ray: bool = False, ray_address: str | None = None) -> Executor:
    """The executor of the CLI options ``--workers``, ``--ray`` and ``--ray-address``."""
    if ray_address is not None and not ray_address.strip():
        raise ConfigError("--ray-address is empty; give HOST:PORT, ray://HOST:10001 or auto")
    if ray or ray_address:
        return RayExecutor(workers, address=ray_address)
    return LocalExecutor(workers)
