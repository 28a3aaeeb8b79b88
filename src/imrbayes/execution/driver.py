"""``run_units``: run units on an executor, checkpoint each as it finishes, contain failures.

>>> from imrbayes.execution import RunStore, Unit, make_executor, run_units
>>> units = [Unit(f"exp={i:03d}", data) for i, data in enumerate(experiments)]   # doctest: +SKIP
>>> with RunStore.open(out, config, resume=resume) as store, make_executor(workers, scheduler) as ex:
...     report = run_units(units, solve_one, seed=config["seed"], store=store, executor=ex)  # doctest: +SKIP
>>> report.results["exp=000"]                                                     # doctest: +SKIP

``solve_one(unit, rng)`` is a top-level function (so processes and Dask workers can import it) that
uses only ``rng`` for random numbers.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
import time
import warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from imrbayes.execution.backends import Executor, InProcessExecutor
from imrbayes.execution.store import CorruptUnitError, RunStore
from imrbayes.execution.units import normalize_units

__all__ = ["run_units", "RunReport", "UnitFailure", "RunInterrupted"]


class RunInterrupted(KeyboardInterrupt):
    """SIGTERM (or SIGINT) arrived during :func:`run_units`. Finished units are on disk; in-flight
    ones are lost; ``--resume`` continues. A ``KeyboardInterrupt``, so ``except Exception`` in unit
    code does not swallow it and the CLI reports "interrupted"."""

    def __init__(self, signum: int):
        self.signum = signum
        super().__init__(f"interrupted by {signal.Signals(signum).name}")


#: how an interrupt shows in a stored traceback (the class's qualified name)
INTERRUPT_MARK = f"{RunInterrupted.__module__}.{RunInterrupted.__qualname__}"


@dataclass
class UnitFailure:
    """A unit whose function raised: ``error`` is ``"Type: message"`` (one line)."""

    unit_id: str
    error: str
    traceback: str | None = None
    worker: str | None = None
    from_checkpoint: bool = False

    def __str__(self) -> str:
        return f"{self.unit_id}: {self.error}"


@dataclass
class RunReport:
    """What :func:`run_units` did.

    ``results`` maps unit id to value for every unit that succeeded, in the order the units were
    given (whatever order they finished in); ``failures`` maps unit id to :class:`UnitFailure`.
    ``n_computed`` units ran now, ``n_resumed`` were read from checkpoints (``n_failed`` counts
    failures from both)."""

    results: dict[str, Any]
    failures: dict[str, UnitFailure]
    n_units: int
    n_computed: int
    n_resumed: int
    wall_s: float
    unit_seconds: dict[str, float] = field(default_factory=dict)

    @property
    def n_failed(self) -> int:
        return len(self.failures)

    @property
    def ok(self) -> bool:
        return not self.failures

    def summary(self) -> str:
        """One line, e.g. ``"12 units: 9 computed, 2 from checkpoints, 1 failed (exp=003: ValueError: x)"``."""
        text = f"{self.n_units} units: {self.n_computed} computed, {self.n_resumed} from checkpoints"
        if self.failures:
            first = next(iter(self.failures.values()))
            more = f" and {self.n_failed - 1} more" if self.n_failed > 1 else ""
            text += f", {self.n_failed} failed ({first}{more})"
        return text

    def raise_if_failed(self) -> None:
        """``RuntimeError`` naming the failed units, if any."""
        if self.failures:
            raise RuntimeError(self.summary())


@contextlib.contextmanager
def _signals_as_interrupt(enabled: bool):
    """SIGTERM (and SIGINT) raise :class:`RunInterrupted` in the main thread while the body runs,
    so executors get to cancel work and stop their workers; the old handlers come back after.
    Handlers that someone else installed (or SIG_IGN) are left alone."""
    if not enabled or threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        raise RunInterrupted(signum)

    old = {}
    try:
        # only where nobody else decided: SIGTERM at its default, SIGINT at Python's KeyboardInterrupt
        for sig, default in ((signal.SIGTERM, signal.SIG_DFL), (signal.SIGINT, signal.default_int_handler)):
            if signal.getsignal(sig) is default:
                old[sig] = signal.signal(sig, handler)
        yield
    finally:
        for sig, prev in old.items():
            signal.signal(sig, prev)


def _progress_bar(progress, total: int, initial: int, desc: str | None):
    """A tqdm bar (``progress=True``, or ``None`` on a terminal), else ``None``."""
    show = progress if isinstance(progress, bool) else (progress is None and _isatty(sys.stderr))
    if not show:
        return None
    from imrbayes.execution.progress import progress_bar

    bar = progress_bar(total=total, desc=desc or "units", unit="units", file=sys.stderr)
    if initial:
        bar.update(initial)
    return bar


def _isatty(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


def _resume(items, store, seed: int, retry_failed: bool, results: dict, failures: dict):
    """Read back the units ``store`` already holds (None: nothing to resume).

    items [(unit_id, unit)]; ``results`` and ``failures`` get the stored values and failures.
    Returns ``(todo [(unit_id, unit)] still to run, number read back)``.
    """
    todo = []
    n_resumed = 0
    for uid, unit in items:
        state = store.status(uid) if store is not None else None
        if state == "done":
            try:
                results[uid] = store.load(uid, seed=seed)
                n_resumed += 1
                continue
            except CorruptUnitError as exc:
                warnings.warn(f"{exc}; recomputing unit {uid!r}", RuntimeWarning, stacklevel=3)
        elif state == "failed" and not retry_failed:
            try:
                rec = store.load_failure(uid)
            except CorruptUnitError as exc:
                warnings.warn(f"{exc}; rerunning unit {uid!r}", RuntimeWarning, stacklevel=3)
            else:
                if INTERRUPT_MARK in (rec.get("traceback") or ""):
                    # written before interrupts inside compiled code were told apart from failures
                    warnings.warn(
                        f"unit {uid!r} was recorded as failed when an interrupt stopped it; rerunning it",
                        RuntimeWarning,
                        stacklevel=3,
                    )
                    todo.append((uid, unit))
                    continue
                failures[uid] = UnitFailure(
                    uid, rec.get("error", "?"), rec.get("traceback"), rec.get("worker"), from_checkpoint=True
                )
                n_resumed += 1
                continue
        todo.append((uid, unit))
    return todo, n_resumed


def _record_outcome(out, store, seed: int, results: dict, failures: dict) -> None:
    """Put one executor outcome into ``results`` or ``failures`` and checkpoint it in ``store``."""
    uid = out.unit_id
    if out.ok:
        results[uid] = (
            store.save(uid, out.value, seed=seed, seconds=out.seconds, worker=out.worker)
            if store is not None
            else out.value
        )
        failures.pop(uid, None)
    else:
        failures[uid] = UnitFailure(uid, out.error, out.traceback, out.worker)
        if store is not None:
            store.save_failure(
                uid,
                seed=seed,
                error=out.error,
                traceback=out.traceback,
                seconds=out.seconds,
                worker=out.worker,
            )


def _write_status(store, items, results: dict, failures: dict, complete: bool, interrupted: bool) -> None:
    """Write the run's ``status.json`` (counts, failed ids, complete/interrupted flags) to ``store``."""
    try:
        store.write_status(
            {
                "n_units": len(items),
                "n_done": sum(1 for uid, _ in items if uid in results),
                "n_failed": len(failures),
                "failed": sorted(failures),
                "complete": complete,
                "interrupted": interrupted,
            }
        )
    except OSError:  # never mask the original problem
        pass


def run_units(
    units: Iterable,
    fn: Callable,
    *,
    seed: int = 0,
    store: RunStore | None = None,
    executor: Executor | None = None,
    retry_failed: bool = False,
    progress=None,
    desc: str | None = None,
    handle_signals: bool = True,
) -> RunReport:
    """Run ``fn(unit, rng)`` for every unit; checkpoint each result as it arrives.

    Parameters
    ----------
    units : iterable
        :class:`~imrbayes.execution.Unit` objects (or anything with a ``unit_id``, or dicts with a
        ``"unit_id"`` key); ids unique.
    fn : callable(unit, rng) -> value
        Top-level (importable) for process and Dask backends. ``rng`` is the unit's own generator
        (:func:`~imrbayes.execution.unit_rng`); the value must be storable (see
        :mod:`imrbayes.execution.store`) when a store is given.
    seed : int
        The run seed (part of every unit's random stream; stored with each unit and checked on resume).
    store : RunStore or None
        Where finished units go. Units already done in it are read back, not rerun; units recorded as
        failed are reported again without rerunning unless ``retry_failed``.
    executor : Executor or None
        Where units run (default: in this process). Not closed here unless created here.
    progress : None, bool or callable(n_done, n_total)
        ``None``: a tqdm bar on stderr only if stderr is a terminal; ``True``/``False``: always/never;
        a callable is called after every unit instead.
    handle_signals : bool
        Turn SIGTERM/SIGINT into :class:`RunInterrupted` while running (main thread only), so that
        workers are stopped and the store is left consistent. At most the units in flight are lost.

    Returns
    -------
    RunReport
        Results in input order and contained failures. A unit that raises never stops the others.

    Raises
    ------
    RunInterrupted
        On SIGTERM/SIGINT (after writing ``status.json``).
    ExecutionError
        When the machinery fails (worker process died, cluster lost).
    TypeError
        When a unit's value cannot be stored.
    """
    t0 = time.perf_counter()
    items = normalize_units(units)
    results: dict[str, Any] = {}
    failures: dict[str, UnitFailure] = {}
    seconds: dict[str, float] = {}
    todo, n_resumed = _resume(items, store, seed, retry_failed, results, failures)

    own = executor is None
    executor = InProcessExecutor() if own else executor
    total, done = len(items), len(items) - len(todo)
    bar = None if callable(progress) else _progress_bar(progress, total, done, desc)
    units_by_id = dict(todo)
    n_computed = 0
    interrupted = None
    try:
        with _signals_as_interrupt(handle_signals):
            if store is not None and todo:
                store.note_execution(executor.describe())
            if todo:
                for out in executor.map(fn, [u for _, u in todo], seed=seed):
                    uid = out.unit_id
                    if uid not in units_by_id:  # pragma: no cover - defensive
                        raise RuntimeError(f"executor returned an unknown unit {uid!r}")
                    seconds[uid] = out.seconds
                    _record_outcome(out, store, seed, results, failures)
                    n_computed += 1
                    done += 1
                    if bar is not None:
                        bar.update(1)
                        if failures:
                            bar.set_postfix(failed=len(failures), refresh=False)
                    elif callable(progress):
                        progress(done, total)
    except KeyboardInterrupt as exc:
        interrupted = exc
        raise
    finally:
        if bar is not None:
            bar.close()
        if own:
            executor.close()
        if store is not None:
            _write_status(
                store, items, results, failures, interrupted is None and done == total, interrupted is not None
            )

    order = {uid: i for i, (uid, _) in enumerate(items)}
    return RunReport(
        results={uid: results[uid] for uid, _ in items if uid in results},
        failures=dict(sorted(failures.items(), key=lambda kv: order[kv[0]])),
        n_units=total,
        n_computed=n_computed,
        n_resumed=n_resumed,
        wall_s=time.perf_counter() - t0,
        unit_seconds=seconds,
    )
