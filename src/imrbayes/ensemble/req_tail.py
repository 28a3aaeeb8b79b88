"""Req from the model's own tail (``--set req_tail=inline``, En4D-Var).

Preprocessing estimates Req as the mean of a record's last frames. A bubble whose contents are
still cooling (the thermal model) oscillates about a mean that lies *above* Req there and settles
from above, so that estimate is biased high (camera records to t* = 3.6: +2.3 % on average,
docs/validation.md), and along the (G, Req) ridge of the likelihood a few per cent of Req are
~9 times as many per cent of G and ~1x of mu. The forward model knows how far above Req its tail
lies: with a material estimate theta and each experiment's Rmax,

    Req = Req_hat / c,   c = mean_j R(t*_j; theta, Rmax, Req) / Req

over the same frames t*_j (:attr:`Observations.req_tail_t`), iterated because c depends on Req
a little. c depends on mu (damping sets how far the rebounds have decayed: at 3x the true mu the
correction is half the truth's), so it is computed at a fit's estimate, not the prior's: a quick
first fit of all experiments (``model``, :func:`model_tail_req`), or each experiment's own
posterior after its first cycle inside its unit (``inline``, the thermal default; :func:`tail_req`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

__all__ = [
    "ReqTailStart",
    "model_tail_req",
    "tail_req",
    "with_req",
    "req_shift_z",
    "alignment_shift_z",
    "REQ_CONFLICT_Z",
]

#: |z| beyond which a fit's Req contradicts the record's own tail (:func:`req_shift_z`). On constant-NHKV
#: camera records the largest |z| was 2.14 over 360 bubbles (``validation/req_conflict_probe.py``) and
#: 3.6 over the 178 bubbles of 40 constant-NHKV datasets of diagnose's designs, 2 of them beyond 3
#: (``validation/req_conflict_classes.py``, docs/methods.md "The Req conflict").
REQ_CONFLICT_Z = 3.0


def tail_req(runner, theta_si, rmax_m, req_hat_m, tails, iterations: int = 3) -> tuple:
    """Req_hat / c per experiment: theta_si (d,) or (E, d) [SI], rmax_m and req_hat_m (E,) [m] (the
    tail means), tails: E arrays of the frames averaged [t*]. Returns ``(req (E,) [m], c (E,))``, c = 1
    (and Req_hat kept) where a record has no tail or a solve failed."""
    req_hat = np.asarray(req_hat_m, dtype=np.float64)
    E = req_hat.size
    theta = np.broadcast_to(np.asarray(theta_si, dtype=np.float64), (E, np.shape(theta_si)[-1])).copy()
    rmax = np.asarray(rmax_m, dtype=np.float64)
    use = np.array([t.size > 0 and np.all(t > 0) for t in tails])
    factor = np.ones(E)
    req = req_hat.copy()
    if use.any():
        idx = np.flatnonzero(use)
        J = max(tails[i].size for i in idx)
        T = np.array([np.concatenate([np.sort(tails[i]), np.full(J - tails[i].size, np.max(tails[i]))]) for i in idx])
        n = np.array([tails[i].size for i in idx])
        cur = req_hat[idx].copy()
        ok = np.ones(idx.size, dtype=bool)
        for _ in range(iterations):
            out = runner.simulate(theta[idx], rmax[idx], cur, T)
            R = np.asarray(out.R_star, dtype=np.float64)
            mean = np.array([R[k, : n[k]].mean() for k in range(idx.size)]) * rmax[idx]
            c = mean / cur
            ok &= ~np.asarray(out.failed, dtype=bool) & np.isfinite(c) & (c > 0.5) & (c < 2.0)
            cur = np.where(ok, req_hat[idx] / np.where(ok, c, 1.0), req_hat[idx])
        factor[idx] = np.where(ok, req_hat[idx] / cur, 1.0)
        req[idx] = cur
    return req, factor


@dataclass(frozen=True)
class ReqTailStart:
    """Where the model's tail is evaluated when a fit of the same records exists (instead of a first pass).

    theta_si : (d,) or (E, d) material [SI] (per experiment where the fit has bubble offsets);
    rmax_m : (E,) fitted Rmax [m]; source : what the fit was (written to the run's details).
    Given to :func:`imrbayes.ensemble.fit_en4dvar`, it replaces the quick first pass: the
    correction only needs a material and Rmax near the data's, not that pass's estimate
    (``diagnose`` has its baseline's least-squares fit of the same model and records).
    """

    theta_si: np.ndarray
    rmax_m: np.ndarray
    source: str


def model_tail_req(runner, obs, theta_si, rmax_m=None, iterations: int = 3) -> tuple:
    """Each experiment's Req corrected by the model's tail.

    runner : :class:`~imrbayes.forward.Runner` (``simulate(theta (M, d) SI, rmax (M,), req (M,),
        t (M, J)) -> out.R_star, out.failed``); obs : :class:`~imrbayes.ensemble.Observations` with
        ``req_tail_t``; theta_si : (d,) or (E, d) material [SI]; rmax_m : (E,) [m] (default
        ``obs.rmax_m``).

    Returns ``(obs', factor)``: a copy of ``obs`` whose ``req_m`` is Req_hat / c (its Req prior sd
    scaled with it) and ``c`` (E,) [-] (1 where the record has no measured tail or a solve failed).
    """
    E = obs.n_exp
    rmax = np.asarray(obs.rmax_m if rmax_m is None else rmax_m, dtype=np.float64)
    req, factor = tail_req(runner, theta_si, rmax, obs.req_m, obs.req_tail_t or [np.empty(0)] * E, iterations)
    return with_req(obs, req), factor


def with_req(obs, req_m):
    """``obs`` with each Req's prior centred at ``req_m`` (E,) [m], keeping its relative sd."""
    sd = obs.nuisance_sd.copy()
    sd[:, 2] *= req_m / obs.req_m  # the same relative uncertainty about the corrected value
    return replace(obs, req_m=np.asarray(req_m, dtype=np.float64), nuisance_sd=sd)


def req_shift_z(obs, per_experiment) -> list:
    """How far a fit moved each measured Req from the record's tail, in the tail's sd.

    obs : the fitted :class:`~imrbayes.ensemble.Observations` (``req_m`` the preprocessing's tail
    estimate [m], ``nuisance_sd[:, 2]`` its sd [m]); per_experiment : a fit's ``per_experiment``
    entries (``name`` and ``nuisance.req_m`` = {mean, sd} [m], as En4D-Var writes them).
    Returns one dict per experiment whose Req was estimated (prior sd > 0) and fitted: experiment,
    z = (fitted mean - tail Req) / tail sd, fitted_req_m, fitted_req_sd_m, preprocessing_req_m,
    preprocessing_req_sd_m. Why it matters: the fits see t* <= 3 (the analysis grid), the tail
    Req of a long record comes from frames after it, so a large |z| means the model reproduces
    the collapses only with a bubble size its own later record contradicts (docs/methods.md,
    "The Req conflict")."""
    names = list(obs.names)
    req = np.asarray(obs.req_m, dtype=np.float64)
    sd = np.asarray(obs.nuisance_sd, dtype=np.float64)[:, 2]
    out = []
    for e in per_experiment:
        q = (e.get("nuisance") or {}).get("req_m")
        g = names.index(e["name"]) if e.get("name") in names else None
        if g is None or q is None or not sd[g] > 0 or not (np.isfinite(q["mean"]) and q["sd"] > 0):
            continue
        out.append(
            {
                "experiment": names[g],
                "z": float((float(q["mean"]) - req[g]) / sd[g]),
                "fitted_req_m": float(q["mean"]),
                "fitted_req_sd_m": float(q["sd"]),
                "preprocessing_req_m": float(req[g]),
                "preprocessing_req_sd_m": float(sd[g]),
            }
        )
    return out


def alignment_shift_z(per_experiment) -> list:
    """How far a fit moved each experiment's Rmax and time of the maximum from the preprocessing's
    local fit of the maximum, in that fit's sd: one dict per experiment with ``experiment``,
    ``z_rmax``, ``z_t0`` (None where the quantity was taken as known) and the shifts
    ``rmax_rel`` (relative) and ``t0_shift_s`` [s]. per_experiment: a fit's entries (``nuisance.rmax_m``
    and ``nuisance.t0_s`` = {prior_mean, prior_sd, mean}, SI, as En4D-Var writes them). Why: the
    local fit sees only the frames around the maximum, the fit the whole collapse and rebounds; a
    model whose collapse needs another maximum than the filmed one moves them by many sd
    (docs/methods.md, "The alignment conflict")."""
    out = []
    for e in per_experiment:
        nu = e.get("nuisance") or {}
        row = {"experiment": e.get("name")}
        q = nu.get("rmax_m")
        ok = q is not None and q.get("prior_sd", 0) > 0
        row["z_rmax"] = float((q["mean"] - q["prior_mean"]) / q["prior_sd"]) if ok else None
        row["rmax_rel"] = float(q["mean"] / q["prior_mean"] - 1.0) if q and q.get("prior_mean") else None
        q = nu.get("t0_s") or {}
        # in t*, where the offset lives: the file's clock (and so the shift in s) may be unknown
        ok = q.get("prior_sd_star", 0) > 0 and np.isfinite(q.get("offset_star", np.nan))
        row["z_t0"] = float(q["offset_star"] / q["prior_sd_star"]) if ok else None
        row["t0_shift_s"] = (
            float(q["mean"] - q["prior_mean"])
            if np.isfinite(q.get("mean", np.nan)) and np.isfinite(q.get("prior_mean", np.nan))
            else None
        )
        out.append(row)
    return out
