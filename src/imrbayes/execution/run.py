"""Where a method's units run and are checkpointed: :class:`Execution`, what every inference
method, the MCMC layer, the diagnosis and the validation suite take as ``execution=``."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from imrbayes.execution.driver import run_units

__all__ = ["Execution"]


@dataclass
class Execution:
    """Where a method's units run and are checkpointed (default: this process, no checkpoints).

    store: :class:`~imrbayes.execution.RunStore` or None; executor: an
    :class:`~imrbayes.execution.Executor` or None (in-process); retry_failed: rerun units that failed
    in a stored run; progress: as :func:`~imrbayes.execution.run_units` (None: a bar per batch on a
    terminal); bar: a tqdm bar (:func:`imrbayes.execution.progress.progress_bar`) that every batch
    advances instead (``progress`` is then ignored): its total is the whole run's units when the
    command planned it (:func:`imrbayes.execution.progress.plan`), raised only when a batch goes
    beyond the plan; the batch being run shows after the bar.
    """

    store: Any = None
    executor: Any = None
    retry_failed: bool = False
    progress: Any = None
    reports: list = field(default_factory=list)
    bar: Any = None

    def run(self, units, fn, seed: int, desc: str):
        """:func:`~imrbayes.execution.run_units` of ``fn(unit, rng)`` over ``units``; returns its
        :class:`~imrbayes.execution.RunReport` (also kept in ``reports``)."""
        units = list(units)
        progress = self.progress
        if self.bar is not None:  # one bar over every batch (MIEnKS: a batch per window)
            bar, last = self.bar, [None]
            if not bar.total or bar.n + len(units) > bar.total:  # no plan, or the plan was short
                bar.total = bar.n + len(units)
            bar.set_postfix_str(desc, refresh=False)

            def progress(done, total):
                bar.update(1 if last[0] is None else done - last[0])
                last[0] = done

        rep = run_units(
            units,
            fn,
            seed=seed,
            store=self.store,
            executor=self.executor,
            retry_failed=self.retry_failed,
            progress=progress,
            desc=desc,
        )
        if self.bar is not None:
            self.bar.update(rep.n_resumed)
        self.reports.append((desc, rep))
        return rep

    def summary(self) -> dict:
        """Counts over every batch run so far, and the failed units (id and one-line error)."""
        out = {"n_units": 0, "n_computed": 0, "n_resumed": 0, "n_failed": 0, "failed": []}
        for _, rep in self.reports:
            out["n_units"] += rep.n_units
            out["n_computed"] += rep.n_computed
            out["n_resumed"] += rep.n_resumed
            out["n_failed"] += rep.n_failed
            out["failed"] += [{"unit": f.unit_id, "error": f.error} for f in rep.failures.values()]
        if self.executor is not None:
            try:
                out["executor"] = self.executor.describe()
            except Exception:  # pragma: no cover - informative only
                pass
        return out
