"""Scale-out and never-lose-work layer: run independent units anywhere, checkpoint each one.

A fit is split into *units* (one experiment, one window, one grid chunk, one MCMC chain) with stable
ids. :func:`run_units` runs ``fn(unit, rng)`` for each on an :class:`Executor` (in this process, a
local process pool, or a Dask cluster: :func:`make_executor`), writes each finished unit atomically
into a :class:`RunStore` under ``--out``, skips finished units on ``--resume``, and contains
failures (:class:`Execution` bundles store, executor and progress for the methods' ``execution=``).
Each unit's random generator comes from (run seed, unit id), so results are bit-identical
whatever the backend, the worker count, or interruptions and resumes.

>>> from imrbayes.execution import RunStore, Unit, make_executor, run_units
>>> with RunStore.open(out, config, resume=resume) as store, make_executor(workers, scheduler) as ex:  # doctest: +SKIP
...     report = run_units(units, fn, seed=seed, store=store, executor=ex)
"""

from imrbayes.execution.backends import (
    DaskExecutor,
    ExecutionError,
    Executor,
    InProcessExecutor,
    Outcome,
    ProcessPoolExecutor,
    make_executor,
)
from imrbayes.execution.driver import RunInterrupted, RunReport, UnitFailure, run_units
from imrbayes.execution.run import Execution
from imrbayes.execution.store import CorruptUnitError, RunStore, canonical_config, config_fingerprint
from imrbayes.execution.units import (
    Unit,
    normalize_units,
    safe_name,
    unit_id,
    unit_rng,
    unit_seed_sequence,
    unit_stream,
)

__all__ = [
    "Executor",
    "InProcessExecutor",
    "ProcessPoolExecutor",
    "DaskExecutor",
    "make_executor",
    "Outcome",
    "ExecutionError",
    "run_units",
    "RunReport",
    "UnitFailure",
    "RunInterrupted",
    "RunStore",
    "CorruptUnitError",
    "canonical_config",
    "config_fingerprint",
    "Execution",
    "Unit",
    "unit_id",
    "unit_rng",
    "unit_seed_sequence",
    "unit_stream",
    "normalize_units",
    "safe_name",
]
