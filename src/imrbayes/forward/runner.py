"""Batched forward runs for the methods and the units that carry a forward model to a worker.

:class:`Runner` wraps ``ForwardModel.propagate``: it splits a batch into chunks (for a progress
callback and to bound memory) and, with ``workers > 1``, runs the chunks in worker processes, each
running its members serially (the forward model itself spreads a batch over numba threads, so
``workers = 1`` already uses every core of one machine; processes help where threads do not scale). Members are independent, so
chunking never changes a result.

Units of work (:mod:`imrbayes.execution`) carry the forward model as a *spec*
(:func:`fm_spec`: constitutive name, options, physics) that a worker rebuilds (serial
kernel) and caches, and a token (:func:`register_runner`) under which a unit that runs in the
caller's process finds the caller's own runner; :func:`runner_for` resolves the two.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing as mp
import os
import time

import numpy as np

from imrbayes.forward.model import BatchState, ForwardModel, Propagation

__all__ = ["Runner", "fm_spec", "forward_model_from_spec", "register_runner", "runner_for"]

_WORKER_FM: dict = {}          # spec -> serial ForwardModel, per process (Runner's worker processes)
_FM: dict = {}                 # spec -> ForwardModel for units (this process: the caller's own model)
_RUNNERS: dict = {}            # token -> the caller's Runner (units running in this process)


def fm_spec(fm) -> tuple:
    """(constitutive name, options, physics): what a worker needs to rebuild ``fm``. In this
    process the spec maps back to ``fm`` itself."""
    spec = (fm.constitutive.name, fm.options, fm.physics)
    _FM[repr(spec)] = fm
    return spec


def forward_model_from_spec(spec) -> ForwardModel:
    """The model of :func:`fm_spec` (``fm`` itself in the process that made the spec;
    elsewhere rebuilt once, with the serial kernel, and cached)."""
    key = repr(spec)
    fm = _FM.get(key)
    if fm is None:
        name, options, physics = spec
        fm = _FM[key] = ForwardModel(name, options=options, physics=physics, parallel=False)
    return fm


def register_runner(runner) -> str:
    """A token under which units running in this process find ``runner`` (other processes rebuild
    one from the spec)."""
    token = f"{os.getpid()}:{id(runner)}"
    _RUNNERS[token] = runner
    return token


def runner_for(data: dict):
    """The runner of a unit whose data hold ``"spec"`` and ``"runner"`` (token): the caller's
    (same process) or a fresh :class:`Runner` on the rebuilt model.

    ``IMRBAYES_UNIT_DELAY_S`` (seconds, a testing aid: makes every unit slow enough to interrupt
    a small run part-way) delays each unit; it never changes a result."""
    delay = os.environ.get("IMRBAYES_UNIT_DELAY_S")
    if delay:
        try:
            time.sleep(max(0.0, float(delay)))
        except ValueError:
            pass
    r = _RUNNERS.get(data.get("runner"))
    return r if r is not None else Runner(forward_model_from_spec(data["spec"]))


def _worker_propagate(spec, y, t0, rmax, req, params, t_end, t_eval):
    key = repr(spec)
    fm = _WORKER_FM.get(key)
    if fm is None:
        name, options, physics = spec
        fm = _WORKER_FM[key] = ForwardModel(name, options=options, physics=physics, parallel=False)
    out = fm.propagate(BatchState(y, t0, rmax, req), params, t_end, t_eval)
    return out.R_star, out.end.y, out.status, out.n_steps, out.n_rejected


class Runner:
    """Propagate ensembles through ``fm``.

    Parameters
    ----------
    fm : ForwardModel
    workers : int
        Processes (1 = in this process).
    chunk : int
        Members per call (default 4096 in-process; an even split, at least 64, with workers).
    progress : callable(n_members_done) or None
        Called after each chunk with the number of members it held.
    """

    def __init__(self, fm: ForwardModel, workers: int = 1, chunk: int | None = None, progress=None):
        self.fm = fm
        self.workers = max(1, int(workers))
        self.chunk = chunk
        self.progress = progress
        self._pool = None
        self.n_member_runs = 0
        self.n_failed = 0

    def close(self):
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
            self._pool = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _spec(self):
        return (self.fm.constitutive.name, self.fm.options, self.fm.physics)

    def counts_since(self, before: tuple) -> dict:
        """Member runs and failed member runs since ``before = (n_member_runs, n_failed)`` (what a
        unit reports)."""
        return {"member_runs": int(self.n_member_runs - before[0]),
                "failed_member_runs": int(self.n_failed - before[1])}

    def propagate(self, state: BatchState, params, t_end: float, t_eval=None) -> Propagation:
        """Like ``ForwardModel.propagate``; ``params`` an (N, n_params) SI array or a dict."""
        n = state.n
        if isinstance(params, dict):
            params = self.fm.constitutive.param_array(params, n=n)
        params = np.asarray(params, dtype=np.float64)
        t_eval = np.atleast_1d(np.asarray([t_end] if t_eval is None else t_eval, dtype=np.float64))
        per_member = t_eval.ndim == 2

        def rows(a, b):
            return t_eval[a:b] if per_member else t_eval
        if self.workers > 1 and n >= 2 * 32:
            size = self.chunk or max(32, -(-n // (4 * self.workers)))
        else:
            size = self.chunk or 4096
        bounds = [(a, min(n, a + size)) for a in range(0, n, size)]
        R = np.empty((n, t_eval.shape[-1]))
        Y = np.empty_like(state.y)
        status = np.empty(n, dtype=np.int64)
        nst = np.empty(n, dtype=np.int64)
        nrj = np.empty(n, dtype=np.int64)

        def put(a, b, res):
            R[a:b], Y[a:b], status[a:b], nst[a:b], nrj[a:b] = res
            if self.progress is not None:
                self.progress(b - a)

        if self.workers > 1 and len(bounds) > 1:
            if self._pool is None:
                self._pool = cf.ProcessPoolExecutor(self.workers, mp_context=mp.get_context("spawn"))
            futs = {self._pool.submit(_worker_propagate, self._spec(), state.y[a:b], state.t_star,
                                      state.rmax_m[a:b], state.req_m[a:b], params[a:b], t_end, rows(a, b)): (a, b)
                    for a, b in bounds}
            for fut in cf.as_completed(futs):
                a, b = futs[fut]
                put(a, b, fut.result())
        else:
            for a, b in bounds:
                out = self.fm.propagate(state.take(np.arange(a, b)), params[a:b], t_end, rows(a, b))
                put(a, b, (out.R_star, out.end.y, out.status, out.n_steps, out.n_rejected))
        end = BatchState(Y, float(t_end), state.rmax_m.copy(), state.req_m.copy())
        out = Propagation(t_eval, R, end, status, nst, nrj)
        self.n_member_runs += n
        self.n_failed += int(out.failed.sum())
        return out

    def simulate(self, params, rmax_m, req_m, t_star) -> Propagation:
        """From the maximum radius (t* = 0) for N members with their own Rmax, Req (N,); ``t_star``
        (m,) shared or (N, m) per member."""
        params = np.asarray(params, dtype=np.float64)
        st = self.fm.initial_state(rmax_m, req_m, n=params.shape[0])
        t_star = np.asarray(t_star, dtype=np.float64)
        return self.propagate(st, params, float(np.max(t_star[..., -1])), t_star)
