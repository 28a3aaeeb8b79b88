"""The methods' units of work for the execution layer (:mod:`imrbayes.execution`).

A fit is split into independent units, each with a stable id and its own random stream (from the
run seed and the id), so that it runs anywhere (this process, a process pool, a Dask cluster), is
checkpointed as soon as it finishes, and gives bit-identical numbers whatever the backend, the
worker count or interruptions:

* IMR: one unit per experiment (``exp=003``), the experiment's cost on the whole grid;
* En4D-Var: one unit per experiment (``exp=003``, every restart cycle), then one per experiment
  for the fitted curves and the draws' log-likelihood after the fusion (``post/exp=003``);
* MIEnKS-MDA: one unit per window and experiment (``window=004/exp=003``); windows run in order,
  the experiments of one window are independent; the unit's result holds the experiment's
  hand-off ensemble (full forward state and parameters), so a resume continues at the next window.

A unit that raises is contained: the experiment is left out of the fusion (of this and, for
MIEnKS, every later window), counted and reported (``FitResult.details["failed_units"]``).

The methods stay DAPPER-style: the unit data carry the forward model as a *spec* (constitutive
name, options, physics) that a worker rebuilds (serial kernel) and caches; in this process the
caller's own model (or runner) is used.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from imrbayes.execution import Unit, run_units
from imrbayes.forward import BatchState, ForwardModel

__all__ = ["Execution", "fm_spec", "runner_for", "imr_unit", "en4dvar_unit", "en4dvar_post_unit", "mienks_unit"]

_FM: dict = {}
_RUNNERS: dict = {}


def fm_spec(fm) -> tuple:
    """(constitutive name, options, physics): what a worker needs to rebuild ``fm``. In this
    process the spec maps back to ``fm`` itself."""
    spec = (fm.constitutive.name, fm.options, fm.physics)
    _FM[repr(spec)] = fm
    return spec


def _fm(spec) -> ForwardModel:
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
    """The runner of a unit: the caller's (same process) or a fresh one on the rebuilt model.

    ``IMRBAYES_UNIT_DELAY_S`` (seconds, a testing aid: makes every unit slow enough to interrupt
    a small run part-way) delays each unit; it never changes a result."""
    from imrbayes.ensemble.runner import Runner

    delay = os.environ.get("IMRBAYES_UNIT_DELAY_S")
    if delay:
        try:
            time.sleep(max(0.0, float(delay)))
        except ValueError:
            pass

    r = _RUNNERS.get(data.get("runner"))
    return r if r is not None else Runner(_fm(data["spec"]))


@dataclass
class Execution:
    """Where a method's units run and are checkpointed (default: this process, no checkpoints).

    store: :class:`~imrbayes.execution.RunStore` or None; executor: an
    :class:`~imrbayes.execution.Executor` or None (in-process); retry_failed: rerun units that failed
    in a stored run; progress: as :func:`~imrbayes.execution.run_units` (None: a bar per batch on a
    terminal); bar: a tqdm bar that every batch advances instead (``progress`` is then ignored).
    """

    store: Any = None
    executor: Any = None
    retry_failed: bool = False
    progress: Any = None
    reports: list = field(default_factory=list)
    bar: Any = None

    def run(self, units, fn, seed: int, desc: str):
        units = list(units)
        progress = self.progress
        if self.bar is not None:     # one bar over every batch (MIEnKS: a batch per window)
            bar, last = self.bar, [None]
            bar.total = (bar.total or 0) + len(units)
            bar.set_description(desc, refresh=False)

            def progress(done, total):
                bar.update(1 if last[0] is None else done - last[0])
                last[0] = done
        rep = run_units(units, fn, seed=seed, store=self.store, executor=self.executor,
                        retry_failed=self.retry_failed, progress=progress, desc=desc)
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


def _counts(runner, before) -> dict:
    return {"member_runs": int(runner.n_member_runs - before[0]),
            "failed_member_runs": int(runner.n_failed - before[1])}


# ----------------------------------------------------------------------------------------- IMR

def imr_unit(unit: Unit, rng) -> dict:
    """One experiment on the whole (G, mu) grid: cost J_n per grid point (inf where it failed)."""
    d = unit.data
    runner = runner_for(d)
    before = (runner.n_member_runs, runner.n_failed)
    theta = d["theta"]
    n_pts = theta.shape[0]
    K = int(d["K"])
    out = runner.simulate(theta, np.full(n_pts, d["rmax"]), np.full(n_pts, d["req"]), d["t_eval"])
    r = out.R_star[:, 1:K + 1] - d["y"][1:K + 1]
    j = np.sum(d["cw"][1:K + 1] * r * r, axis=1)
    bad = out.failed | ~np.isfinite(j)
    return {"J": np.where(bad, np.inf, j), "n_failed": int(bad.sum()), **_counts(runner, before)}


# ------------------------------------------------------------------------------------ En4D-Var

def en4dvar_unit(unit: Unit, rng) -> dict:
    """Every restart cycle of one experiment (methods.md §3): its last posterior and the prior
    that cycle started from."""
    from imrbayes.ensemble.gaussian import draw, rtps
    from imrbayes.ensemble.gn import gauss_newton

    d = unit.data
    space, s = d["space"], d["settings"]
    runner = runner_for(d)
    before = (runner.n_member_runs, runner.n_failed)
    rmax, req, t_eval = d["rmax"], d["req"], d["t_eval"]

    def evaluate(groups, Z):
        out = runner.simulate(space.to_si(Z), np.full(len(Z), rmax), np.full(len(Z), req), t_eval)
        return out.R_star[:, 1:], out.failed | ~np.all(np.isfinite(out.R_star), axis=1)

    mean, cov = space.prior_mean.copy(), space.prior_cov.copy()
    cycles = []
    res = None
    for r in range(s.n_runs):
        E0 = draw(rng, mean, cov, s.n_ens, exact=s.exact_moments)[None]
        res = gauss_newton(E0, evaluate, d["y"][None], d["weight"][None], n_iter=s.n_iter, rng=rng)
        infl = rtps(res.prior_anoms, res.anoms, s.rtps)
        mean = res.mean[0].copy()
        cov = np.einsum("gnd,gne->gde", infl, infl)[0]
        cycles.append({"cycle": r + 1, "cost": res.cost[0], "n_failed": res.n_failed[0],
                       "n_redrawn": int(res.n_redrawn[0]), "stopped": bool(res.stopped[0])})
    qa = res.prior_anoms[0]
    return {"mean": res.mean[0], "cov": res.cov[0], "prior_mean": res.prior_ensemble[0].mean(axis=0),
            "prior_cov": qa.T @ qa, "stopped": bool(res.stopped[0]), "cycles": cycles, **_counts(runner, before)}


def en4dvar_post_unit(unit: Unit, rng) -> dict:
    """After the fusion, one experiment: R* at the fused median and at its own posterior mean, and
    at every posterior draw (for the pointwise log-likelihood)."""
    d = unit.data
    runner = runner_for(d)
    before = (runner.n_member_runs, runner.n_failed)
    pts = d["points"]
    n = pts.shape[0]
    out = runner.simulate(pts, np.full(n, d["rmax"]), np.full(n, d["req"]), d["t_eval"])
    return {"R_star": out.R_star, **_counts(runner, before)}


# ---------------------------------------------------------------------------------- MIEnKS-MDA

def mienks_unit(unit: Unit, rng) -> dict:
    """One window of one experiment (methods.md §4, steps 2, 4, 5): Gauss–Newton analysis of the
    augmented ensemble, RTPS, hand-off to the next window (failed members redrawn; the analysis is
    rejected, and the window prior handed on, when too few members survive). Window 0 starts from
    the state at the maximum radius with parameters drawn from the prior."""
    from imrbayes.ensemble.gaussian import draw, rtps_factors
    from imrbayes.ensemble.gn import gauss_newton
    from imrbayes.ensemble.mienks import _redraw_failed

    d = unit.data
    space, s = d["space"], d["settings"]
    runner = runner_for(d)
    before = (runner.n_member_runs, runner.n_failed)
    t, a, b, a2, last = d["t"], int(d["a"]), int(d["b"]), int(d["a2"]), bool(d["last"])
    rmax, req, N, dp = float(d["rmax"]), float(d["req"]), int(s.n_ens), space.n
    E = d["E"]
    if E is None:
        st0 = runner.fm.initial_state(np.full(N, rmax), np.full(N, req))
        ns = st0.y.shape[1]
        E = np.empty((N, ns + dp))
        E[:, :ns] = st0.y
        E[:, ns:] = draw(rng, space.prior_mean, space.prior_cov, N)
    E = np.array(E, dtype=np.float64)
    ns = E.shape[1] - dp
    t_eval = t[a:b + 1]
    # The analysis sees log p_b instead of p_b (``log_pressure``): near a collapse the members' p_b
    # spans orders of magnitude, and a linear update of p_b itself drives most of them negative.
    ipb = runner.fm.layout()["pb"].start if getattr(s, "log_pressure", False) else None

    def to_analysis(Z):
        Z = np.array(Z, dtype=np.float64)
        if ipb is not None:
            with np.errstate(divide="ignore", invalid="ignore"):
                Z[:, ipb] = np.log(Z[:, ipb])
        return Z

    def from_analysis(Z):
        Z = np.array(Z, dtype=np.float64)
        if ipb is not None:
            with np.errstate(over="ignore"):
                Z[:, ipb] = np.exp(Z[:, ipb])
        return Z

    E = to_analysis(E)

    def propagate(Z, t0, t1, t_ev):
        """R* (M, len(t_ev)), end state (M, ns, physical), failed (M,) of members Z (M, ns + d, analysis
        coordinates). A member whose state is not physical (ForwardModel.state_is_valid: R* <= 0,
        p_b <= 0, vapour fraction outside [0, 1], ...) or whose parameters are not finite is failed
        without a solve."""
        Z = from_analysis(Z)
        ok = np.all(np.isfinite(Z[:, ns:]), axis=1) & runner.fm.state_is_valid(Z[:, :ns])
        R = np.full((Z.shape[0], len(t_ev)), np.nan)
        Y = Z[:, :ns].copy()
        failed = ~ok
        if ok.any():
            m = int(ok.sum())
            st = BatchState(Z[ok, :ns].copy(), t0, np.full(m, rmax), np.full(m, req))
            out = runner.propagate(st, space.to_si(Z[ok, ns:]), t1, t_ev)
            R[ok], Y[ok] = out.R_star, out.end.y
            failed[ok] = out.failed | ~np.all(np.isfinite(out.R_star), axis=1) | ~np.all(np.isfinite(out.end.y), axis=1)
        return R, Y, failed

    def evaluate(groups, Z):
        R, _, failed = propagate(np.asarray(Z, dtype=np.float64), t[a], t[b], t_eval)
        return R, failed

    res = gauss_newton(E[None], evaluate, d["y"][None], d["weight"][None], n_iter=s.n_iter, rng=rng,
                       max_redraw=s.max_redraw, transform=s.transform)
    f = rtps_factors(res.prior_anoms, res.anoms, s.rtps)[0]
    if not s.rtps_state:
        f[:ns] = 1.0
    Ea = res.mean[0][None, :] + np.sqrt(N - 1.0) * res.anoms[0] * f[None, :]
    problems = runner.fm.state_problems(from_analysis(Ea)[:, :ns])     # analysed states that are not physical
    n_invalid = int(np.any(np.stack(list(problems.values())), axis=0).sum())
    invalid_why = {k: int(v.sum()) for k, v in problems.items() if v.any()}
    Rseg, Ynew, failed = propagate(Ea, t[a], t[a2], t[a:a2 + 1])
    n_failed_analysed = int(failed.sum())
    rejected = False
    if (~failed).sum() < max(2, N // 4):
        # too few analysed members survived the hand-off: hand on the window's prior ensemble
        # instead (analysis rejected for this window, reported), propagated the same way
        Ep = res.prior_ensemble[0]
        Rseg, Ynew, failed = propagate(Ep, t[a], t[a2], t[a:a2 + 1])
        if (~failed).sum() < 2:
            raise RuntimeError(f"fewer than two ensemble members survived window t* {t[a]:.3g}-{t[b]:.3g}, "
                               f"with and without the analysis")
        Ea = Ep.copy()
        rejected = True
    with np.errstate(invalid="ignore"):
        seg = np.nanmean(np.where(failed[:, None], np.nan, Rseg), axis=0)
    E_next = to_analysis(np.concatenate([Ynew, Ea[:, ns:]], axis=1))
    n_fail = int(failed.sum())
    n_red = _redraw_failed(E_next[None], failed[None], rng) if (n_fail and not last) else 0
    E_next = from_analysis(E_next)                  # handed on as physical states
    qa = res.prior_anoms[0, :, ns:]
    return {"E": None if last else E_next, "seg": seg, "pm": res.mean[0, ns:], "pc": res.cov[0, ns:, ns:],
            "qm": res.prior_ensemble[0, :, ns:].mean(axis=0), "qc": qa.T @ qa,
            "n_failed_iter": res.n_failed[0], "n_redrawn_prior": int(res.n_redrawn[0]), "n_failed_handoff": n_fail,
            "n_redrawn_handoff": int(n_red), "stopped": bool(res.stopped[0]), "rejected": rejected,
            "n_invalid_analysed": n_invalid, "n_failed_analysed": n_failed_analysed, "invalid_why": invalid_why,
            "cost": res.cost[0], "state_size": int(ns), **_counts(runner, before)}
