"""Execution backends: where units run.

One small interface, :class:`Executor`, three implementations:

* :class:`InProcessExecutor` (the default): units run one after another in this process.
* :class:`ProcessPoolExecutor`: ``workers`` local processes (``concurrent.futures``, *spawn* start
  method: safe with numba/BLAS/Dask threads in the parent; the unit function must be importable, i.e.
  defined at the top level of a module, not in ``__main__`` of ``python -c``).
* :class:`DaskExecutor`: a Dask distributed cluster, either one it starts on this machine
  (``scheduler="local"``: a ``LocalCluster``) or an existing one (``scheduler="tcp://host:8786"``).

``Executor.map(fn, units, seed=...)`` yields one :class:`Outcome` per unit *as units finish*
(completion order, not input order). Each unit runs as ``fn(unit, rng)`` with
``rng = unit_rng(seed, unit_id)``, so results do not depend on the backend or the number of workers.
An exception raised by ``fn`` is caught where the unit ran and comes back as an ``Outcome`` with
``ok=False``; it never stops the other units. A failure of the machinery itself (a worker process
that died, a lost connection to the scheduler) raises :class:`ExecutionError`.

Executors are context managers and are closed cleanly (pool shut down, cluster and client closed);
an executor can serve several ``map`` calls (e.g. one per assimilation window) before it is closed.
"""

from __future__ import annotations

import concurrent.futures as cf
import logging
import multiprocessing as mp
import os
import signal
import socket
import threading
import time
import traceback
import uuid
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from itertools import islice
from typing import Any

from imrbayes.errors import InputError
from imrbayes.execution.units import normalize_units, unit_rng, unit_stream

__all__ = [
    "Outcome",
    "Executor",
    "InProcessExecutor",
    "ProcessPoolExecutor",
    "DaskExecutor",
    "ExecutionError",
    "make_executor",
    "run_one",
]


class ExecutionError(RuntimeError):
    """The execution machinery failed (a worker process died, the cluster went away). Finished units
    are already checkpointed; the run can be resumed."""


@dataclass
class Outcome:
    """What running one unit gave.

    ``value`` is ``fn``'s return value when ``ok``; otherwise ``error`` is ``"Type: message"`` and
    ``traceback`` the formatted traceback from the worker. ``seconds`` is the unit's wall time and
    ``worker`` names where it ran (``host:pid``)."""

    unit_id: str
    ok: bool
    value: Any = None
    error: str | None = None
    traceback: str | None = None
    seconds: float = 0.0
    worker: str = ""


def _worker_name() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def interrupt_behind(exc: BaseException) -> KeyboardInterrupt | None:
    """The interrupt (SIGTERM/SIGINT turned into an exception) that ``exc`` wraps, if any: a signal
    that arrives inside compiled code (a numba kernel) comes back as a ``SystemError`` whose cause is
    the interrupt. Such a unit was stopped, not failed."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def run_one(fn: Callable, unit, uid: str, seed: int) -> Outcome:
    """Run ``fn(unit, rng)``, ``rng = unit_rng(seed, unit_stream(unit, uid))`` (the unit's stream key,
    by default its id), and wrap the result or the exception (top-level, so
    every backend can ship it to a worker). An interrupt, also one wrapped in another exception, is
    raised, never recorded as the unit's failure (a resumed run must compute the unit)."""
    t0 = time.perf_counter()
    try:
        value = fn(unit, unit_rng(seed, unit_stream(unit, uid)))
    except Exception as exc:  # contained: reported per unit, never fatal to the others
        stop = interrupt_behind(exc)
        if stop is not None:
            raise stop from exc
        msg = str(exc).strip().splitlines()
        return Outcome(
            uid,
            False,
            error=f"{type(exc).__name__}: {msg[0]}" if msg else type(exc).__name__,
            traceback=traceback.format_exc(),
            seconds=time.perf_counter() - t0,
            worker=_worker_name(),
        )
    return Outcome(uid, True, value=value, seconds=time.perf_counter() - t0, worker=_worker_name())


class Executor:
    """Runs units; see the module docstring. Subclasses implement :meth:`map` and :meth:`close`."""

    name = "executor"

    @property
    def n_workers(self) -> int:
        return 1

    def map(self, fn: Callable, units: Iterable, *, seed: int = 0) -> Iterator[Outcome]:
        """Run ``fn(unit, rng)`` for every unit; yield :class:`Outcome` objects as units finish.

        Stopping the iteration early (``break``, an exception, Ctrl-C / SIGTERM turned into an
        exception) cancels the units not yet started; units in flight are abandoned."""
        raise NotImplementedError

    def describe(self) -> dict:
        """A JSON-able description (recorded in ``run.json``; not part of the configuration)."""
        return {"backend": self.name, "workers": self.n_workers}

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class InProcessExecutor(Executor):
    """Units run one after another in this process (no pickling; the easiest to debug)."""

    name = "in-process"

    def map(self, fn, units, *, seed=0):
        for uid, unit in normalize_units(units):
            yield run_one(fn, unit, uid, seed)


# --------------------------------------------------------------------------------------- processes


def _watch_parent(parent_pid: int) -> None:  # pragma: no cover - runs in worker processes
    while True:
        time.sleep(0.5)
        if os.getppid() != parent_pid:
            os._exit(1)  # the parent was killed (e.g. SIGKILL): do not linger as an orphan


def _worker_init(parent_pid: int) -> None:  # pragma: no cover - runs in worker processes
    # Ctrl-C reaches the whole process group; the parent decides what to do, workers ignore it.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True, name="imrbayes-parent-watch").start()


class ProcessPoolExecutor(Executor):
    """``workers`` local processes (``concurrent.futures.ProcessPoolExecutor``).

    Parameters
    ----------
    workers : int
        Number of processes (>= 1).
    mp_context : str
        Start method, ``"spawn"`` by default (``"forkserver"`` also works; ``"fork"`` is unsafe once
        threads exist in the parent).
    max_in_flight : int or None
        Units submitted ahead of completion (default ``2 * workers``): bounds memory and what has to
        be cancelled on an interruption.

    The pool starts on the first :meth:`map` and is reused by later ones. Workers ignore SIGINT and
    exit on their own if the parent process disappears.
    """

    name = "process-pool"

    def __init__(self, workers: int, mp_context: str = "spawn", max_in_flight: int | None = None):
        if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
            raise ValueError(f"workers must be a positive integer, got {workers!r}")
        self.workers = workers
        self.mp_context = mp_context
        self.max_in_flight = max_in_flight or 2 * workers
        self._pool: cf.ProcessPoolExecutor | None = None

    @property
    def n_workers(self) -> int:
        return self.workers

    def _get_pool(self) -> cf.ProcessPoolExecutor:
        if self._pool is None:
            self._pool = cf.ProcessPoolExecutor(
                self.workers,
                mp_context=mp.get_context(self.mp_context),
                initializer=_worker_init,
                initargs=(os.getpid(),),
            )
        return self._pool

    def map(self, fn, units, *, seed=0):
        pending = iter(normalize_units(units))
        pool = self._get_pool()
        running: dict[cf.Future, str] = {}

        def submit(n):
            for uid, unit in islice(pending, n):
                running[pool.submit(run_one, fn, unit, uid, seed)] = uid

        finished = False
        try:
            submit(self.max_in_flight)
            while running:
                done, _ = cf.wait(running, return_when=cf.FIRST_COMPLETED)
                for fut in done:
                    uid = running.pop(fut)
                    try:
                        out = fut.result()
                    except Exception as exc:  # BrokenProcessPool, unpicklable unit or result, ...
                        raise ExecutionError(
                            f"unit {uid!r} could not be run in a worker process: {type(exc).__name__}: {exc}"
                        ) from exc
                    yield out
                submit(self.max_in_flight - len(running))
            finished = True
        finally:
            if not finished:
                self._abort(running)

    def _abort(self, running) -> None:
        """Cancel queued units and stop the workers at once (in-flight units are lost by design)."""
        for fut in running:
            fut.cancel()
        pool, self._pool = self._pool, None
        if pool is None:
            return
        terminate = getattr(pool, "terminate_workers", None)  # Python >= 3.14
        if terminate is not None:
            terminate()
        else:
            for proc in list((getattr(pool, "_processes", None) or {}).values()):
                if proc.is_alive():
                    proc.terminate()
        pool.shutdown(wait=True, cancel_futures=True)

    def close(self) -> None:
        pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)


# -------------------------------------------------------------------------------------------- dask


def _worker_versions() -> dict:  # pragma: no cover - runs on Dask workers
    try:
        import numpy

        import imrbayes
    except ImportError as exc:
        return {"error": str(exc)}
    return {"imrbayes": imrbayes.__version__, "numpy": numpy.__version__}


def _quiet_gather_exits(client) -> None:
    """On the event loop of a client we own, drop asyncio's "Task exception was never retrieved" for
    distributed's internal ``AllExit``: when SIGTERM interrupts ``future.result()`` and the client is
    closed, the gather's waiter tasks end with it and nobody awaits them, so asyncio printed their
    traceback at garbage collection (seen under load in the SIGTERM-with-Dask resume test) -- noise
    after a clean interruption, never a result. Every other loop exception goes to the handler as before."""
    from distributed.client import AllExit

    loop = getattr(client.loop, "asyncio_loop", None)
    if loop is None:
        return
    previous = loop.get_exception_handler()

    def handler(lp, context):
        if isinstance(context.get("exception"), AllExit):
            return
        if previous is not None:
            previous(lp, context)
        else:
            lp.default_exception_handler(context)

    loop.set_exception_handler(handler)


class DaskExecutor(Executor):
    """Units as tasks on a Dask distributed cluster.

    Parameters
    ----------
    scheduler : str
        ``"local"``: start a ``LocalCluster`` on this machine (``n_workers`` processes with
        ``threads_per_worker`` threads each, no dashboard); otherwise the address of a running
        scheduler (``"tcp://host:8786"``), whose workers must have the same imrbayes installed.
    n_workers : int or None
        Local cluster only: worker processes (default: the number of CPUs).
    threads_per_worker : int
        Local cluster only (default 1: the forward model brings its own threads).
    client : distributed.Client or None
        Use this client instead (it is not closed by :meth:`close`).
    max_in_flight : int or None
        Units submitted ahead of completion (default: twice the cluster's thread count, at least 4).
    connect_timeout : float
        Seconds to wait for a remote scheduler.
    """

    name = "dask"

    def __init__(
        self,
        scheduler: str = "local",
        n_workers: int | None = None,
        threads_per_worker: int = 1,
        client=None,
        max_in_flight: int | None = None,
        connect_timeout: float = 10.0,
    ):
        import distributed

        self._cluster = None
        self._own_client = client is None
        self.scheduler = scheduler if client is None else "client"
        if client is not None:
            self._client = client
        elif scheduler == "local":
            n = n_workers or os.cpu_count() or 1
            self._cluster = distributed.LocalCluster(
                n_workers=n,
                threads_per_worker=threads_per_worker,
                processes=True,
                dashboard_address=None,
                silence_logs=logging.ERROR,
            )
            try:
                self._client = distributed.Client(self._cluster, set_as_default=False)
            except BaseException:
                self._cluster.close()
                raise
            _quiet_gather_exits(self._client)
        else:
            try:
                self._client = distributed.Client(scheduler, timeout=connect_timeout, set_as_default=False)
            except (OSError, TimeoutError, ValueError) as exc:
                raise InputError("--scheduler", f"cannot connect to a Dask scheduler at {scheduler!r}: {exc}")
            _quiet_gather_exits(self._client)
            try:
                self._check_workers()
            except BaseException:
                self.close()
                raise
        self.max_in_flight = max_in_flight

    def _check_workers(self) -> None:
        import numpy

        import imrbayes

        versions = self._client.run(_worker_versions)
        for worker, ver in versions.items():
            if "error" in ver:
                raise InputError(
                    "--scheduler",
                    f"Dask worker {worker} cannot import imrbayes ({ver['error']}); install it on every worker",
                )
            if ver["imrbayes"] != imrbayes.__version__ or ver["numpy"] != numpy.__version__:
                logging.getLogger(__name__).warning(
                    "Dask worker %s has imrbayes %s / numpy %s, this process %s / %s: results may differ",
                    worker,
                    ver["imrbayes"],
                    ver["numpy"],
                    imrbayes.__version__,
                    numpy.__version__,
                )

    @property
    def client(self):
        return self._client

    @property
    def n_workers(self) -> int:
        return max(1, sum(self._client.nthreads().values()))

    def describe(self) -> dict:
        info = self._client.scheduler_info()
        return {
            "backend": self.name,
            "scheduler": self.scheduler,
            "address": self._client.scheduler.address,
            "workers": len(info.get("workers", {})),
            "threads": self.n_workers,
        }

    def map(self, fn, units, *, seed=0):
        import distributed

        pending = iter(normalize_units(units))
        limit = self.max_in_flight or max(4, 2 * self.n_workers)
        running: dict[str, tuple[Any, str]] = {}
        ac = distributed.as_completed(loop=self._client.loop)
        token = uuid.uuid4().hex[:12]

        def submit(n):
            for uid, unit in islice(pending, n):
                fut = self._client.submit(
                    run_one, fn, unit, uid, seed, pure=False, key=f"imrbayes-unit-{token}-{uuid.uuid4().hex[:12]}"
                )
                running[fut.key] = (fut, uid)
                ac.add(fut)

        finished = False
        try:
            submit(limit)
            while running:
                fut = next(ac)
                _, uid = running.pop(fut.key)
                try:
                    out = fut.result()
                except Exception as exc:  # KilledWorker, lost scheduler, unpicklable payload ...
                    raise ExecutionError(
                        f"unit {uid!r} could not be run on the Dask cluster: {type(exc).__name__}: {exc}"
                    ) from exc
                finally:
                    fut.release()
                yield out
                submit(limit - len(running))
            finished = True
        finally:
            if not finished and running:
                try:
                    self._client.cancel([f for f, _ in running.values()])
                except Exception:  # the cluster may already be gone
                    pass

    def close(self) -> None:
        client, self._client = getattr(self, "_client", None), None
        if client is not None and self._own_client:
            client.close()
        cluster, self._cluster = self._cluster, None
        if cluster is not None:
            cluster.close()


def make_executor(
    workers: int | None = None, scheduler: str | None = None, *, threads_per_worker: int = 1, mp_context: str = "spawn"
) -> Executor:
    """The executor that ``--workers N`` / ``--scheduler ADDRESS|local`` ask for.

    * neither, or ``workers=1``: :class:`InProcessExecutor`;
    * ``workers=N > 1``: :class:`ProcessPoolExecutor` with N processes;
    * ``scheduler="local"``: :class:`DaskExecutor` on a new ``LocalCluster`` with ``workers`` worker
      processes (default: the CPU count) of ``threads_per_worker`` threads;
    * ``scheduler="tcp://host:8786"`` (any other string): :class:`DaskExecutor` connected to that
      scheduler; the cluster's own workers are used and ``workers`` is ignored.

    Bad values raise :class:`~imrbayes.errors.InputError` naming the option. Close the executor
    (``with make_executor(...) as ex:``) when done.
    """
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise InputError("--workers", f"must be a positive integer, got {workers!r}")
    if scheduler is not None:
        if not isinstance(scheduler, str) or not scheduler.strip():
            raise InputError(
                "--scheduler", f"must be 'local' or a scheduler address such as tcp://host:8786, got {scheduler!r}"
            )
        scheduler = scheduler.strip()
        if scheduler == "local":
            return DaskExecutor("local", n_workers=workers, threads_per_worker=threads_per_worker)
        return DaskExecutor(scheduler)
    if workers is None or workers == 1:
        return InProcessExecutor()
    return ProcessPoolExecutor(workers, mp_context=mp_context)
