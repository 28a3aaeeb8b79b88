"""Shared command-line plumbing of the execution layer (docs/scaling.md): ``--workers``,
``--scheduler``, ``--resume``, ``--retry-failed`` for ``fit``, ``diagnose`` and ``validate``.

The run directory is ``--out``: ``run.json`` (the exact configuration, its fingerprint, the
imrbayes version), ``status.json`` and ``units/`` (one checkpoint per finished unit) next to the
command's own outputs.
"""

from __future__ import annotations

import contextlib
import hashlib
import sys

import click
import numpy as np

from imrbayes.errors import InputError

__all__ = ["execution_options", "open_execution", "data_fingerprint", "echo_execution"]


def execution_options(with_workers: bool = True):
    """Decorator adding ``--scheduler``, ``--resume``, ``--retry-failed`` (and ``--workers``)."""

    def deco(f):
        f = click.option("--retry-failed", "retry_failed", is_flag=True, default=None,
                         help="With --resume: rerun the units that failed last time (default: report them again).")(f)
        f = click.option("--resume", is_flag=True, default=None,
                         help="Continue the run in --out: finished units are read back, not rerun. Refused if "
                              "the configuration (data, model, settings, seed) or the imrbayes version differs.")(f)
        f = click.option("--scheduler", default=None, metavar="local|tcp://HOST:PORT",
                         help="Run the units on a Dask cluster: 'local' starts a LocalCluster with --workers "
                              "processes; an address uses an existing cluster's workers.")(f)
        if with_workers:
            f = click.option("--workers", type=int, default=None,
                             help="Worker processes for the units (experiments, windows, cases) [default: 1: "
                                  "in this process].")(f)
        return f

    return deco


def data_fingerprint(*arrays, names=()) -> str:
    """SHA-256 of the arrays' bytes (dtype, shape, contents) and the names: what the units see."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(np.asarray(a))
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    for n in names:
        h.update(str(n).encode("utf-8") + b"\0")
    return h.hexdigest()


def check_options(workers, scheduler, resume, retry_failed) -> tuple:
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise InputError("--workers", f"must be a positive integer, got {workers!r}")
    if retry_failed and not resume:
        raise InputError("--retry-failed", "only makes sense with --resume")
    if scheduler is not None:
        s = str(scheduler).strip()
        if s != "local" and "://" not in s:
            raise InputError("--scheduler", f"must be 'local' or a scheduler address such as tcp://host:8786, "
                                            f"got {scheduler!r}")
    return workers, scheduler, bool(resume), bool(retry_failed)


@contextlib.contextmanager
def open_execution(out, config: dict, *, workers=None, scheduler=None, resume=False, retry_failed=False,
                   quiet: bool = False):
    """RunStore under ``out`` for ``config`` + the executor ``--workers/--scheduler`` ask for, as an
    :class:`imrbayes.ensemble.units.Execution`. Bad options and refused resumes raise InputError."""
    from imrbayes.ensemble.output import jsonable
    from imrbayes.ensemble.units import Execution
    from imrbayes.execution import RunStore, make_executor

    workers, scheduler, resume, retry_failed = check_options(workers, scheduler, resume, retry_failed)
    # the executor first: an unreachable --scheduler must not leave a new run directory behind
    with make_executor(workers, scheduler) as ex, \
            RunStore.open(out, jsonable(config), resume=resume) as store:
        bar = None
        if not quiet and _isatty(sys.stderr):
            from tqdm.auto import tqdm

            bar = tqdm(total=0, unit="unit", file=sys.stderr, dynamic_ncols=True)
        try:
            yield Execution(store=store, executor=ex, retry_failed=retry_failed, progress=False, bar=bar)
        finally:
            if bar is not None:
                bar.close()


def _isatty(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


def echo_execution(summary: dict, quiet: bool, what: str = "units") -> None:
    """One line with the unit counts; every failed unit on stderr (never silently dropped)."""
    if summary.get("n_units") and not quiet:
        click.echo(f"{summary['n_units']} {what}: {summary['n_computed']} computed, {summary['n_resumed']} from "
                   f"checkpoints, {summary['n_failed']} failed")
    for f in summary.get("failed", []):
        click.echo(f"imrbayes: warning: unit {f['unit']} failed: {f['error']}", err=True)
