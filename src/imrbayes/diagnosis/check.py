"""Calibrated constant-parameter check (parametric bootstrap).

Statistics of one dataset under the baseline (constant-parameter NHKV):

* ``drift``: the largest squared Mahalanobis distance between the (log G, log mu) estimates of
  fits to the 1st collapse, to the 2nd collapse and to the whole record (covariances of the two
  Laplace posteriors added);
* ``misfit``: the normalised chi-square (mean of r^2/P_k) of the whole-record fit;
* ``phase_misfit``: the largest normalised chi-square of one phase of that fit.

None of them has a known null distribution (residuals are correlated in time, P_k is estimated),
so each is calibrated by a parametric bootstrap: B synthetic datasets of the same design (same
Rmax, Req, number of experiments, independent Gaussian noise whose variance plus the spread of the
baseline curves across experiments reproduces P_k at every sample) generated from
the baseline fit, processed exactly as the data (P_k re-estimated as the across-experiment sample
variance, the same fits). p-values are (1 + #{T_b >= T}) / (B + 1); the combined p-value is the
bootstrap calibration of the smallest of the three (so no Bonferroni factor is needed).
"""

from __future__ import annotations

import numpy as np

from imrbayes.data.noise import noise_variance
from imrbayes.diagnosis.lsq import fit_map, predict
from imrbayes.ensemble import Observations

__all__ = ["statistics", "bootstrap_check", "window_drift"]

STATS = ("drift", "misfit", "phase_misfit")


def window_drift(cand, obs, phases, full) -> tuple:
    """Largest squared Mahalanobis distance between the (log G, log mu) of the whole-record fit
    ``full`` and fits of ``cand`` to the 1st and 2nd collapse; returns (drift, fits)."""
    K1, K2 = phases.collapse_index(1), phases.collapse_index(2)
    fits = {"all": full}
    for name, K in (("collapse-1", K1), ("collapse-2", K2)):
        fits[name] = fit_map(cand, obs, K=K, minima=phases.minima, starts=[full.z])
    keys = list(fits)
    drift = 0.0
    for i in range(len(keys)):
        for j in range(i + 1, len(keys)):
            a, b = fits[keys[i]], fits[keys[j]]
            dz = a.z[:2] - b.z[:2]
            C = a.cov[:2, :2] + b.cov[:2, :2]
            try:
                drift = max(drift, float(dz @ np.linalg.solve(C, dz)))
            except np.linalg.LinAlgError:
                pass
    return drift, fits


def statistics(base, obs, phases, starts=None) -> dict:
    """Window fits and the three statistics of ``obs`` under the baseline candidate ``base``."""
    full = fit_map(base, obs, minima=phases.minima, starts=starts)
    drift, fits = window_drift(base, obs, phases, full)
    r2 = (obs.R_star[:, 1:] - full.fitted[:, 1:]) ** 2 / obs.P[None, 1:]
    per_phase = []
    for m in phases.masks():
        mm = m[1:]
        per_phase.append(float(np.nanmean(r2[:, mm])) if mm.any() else float("nan"))
    return {"fits": fits, "drift": drift, "misfit": float(np.nanmean(r2)),
            "phase_misfit": float(np.nanmax(per_phase)), "phase_chi2": per_phase}


def _pvals(T, Tb):
    Tb = np.asarray(Tb, dtype=float)
    return (1.0 + np.sum(Tb >= T)) / (Tb.size + 1.0)


def bootstrap_check(base, obs, phases, observed: dict, B: int = 19, seed: int = 0, alpha: float = 0.05,
                    progress=None) -> dict:
    """Verdict ``adequate``/``inadequate`` with the evidence (see module doc)."""
    rng = np.random.default_rng(seed)
    z0 = observed["fits"]["all"].z
    R0 = predict(base, z0[None], obs, np.arange(obs.n_exp), phases.minima, obs.n_samples - 1)[0]
    # measurement noise: P_k minus the across-experiment variance of the baseline curves (the part
    # of the sample variance that Rmax/Req differences explain), floored at P_k / 4, so that the
    # replicates' re-estimated P_k match the data's
    spread = np.var(R0, axis=0, ddof=1) if obs.n_exp >= 2 else np.zeros_like(obs.P)
    sd = np.sqrt(np.maximum(obs.P - spread, 0.25 * obs.P))
    boot = {k: [] for k in STATS}
    for b in range(B):
        Y = R0 + sd[None, :] * rng.standard_normal(R0.shape)
        Y[:, 0] = 1.0
        Y = np.maximum(Y, 1e-3)
        P, _ = noise_variance(obs.t_star, Y) if obs.n_exp >= 2 else (obs.P, None)
        ob = Observations(obs.t_star, Y, P, obs.rmax_m, obs.req_m, obs.t_collapse_star, list(obs.names))
        st = statistics(base, ob, phases, starts=[z0])
        for k in STATS:
            boot[k].append(st[k])
        if progress is not None:
            progress(1)
    p = {k: float(_pvals(observed[k], boot[k])) for k in STATS}
    # calibrate min-p: p-values of every bootstrap replicate against the others
    bmat = np.array([boot[k] for k in STATS])            # (3, B)
    pb = np.array([[(1.0 + np.sum(np.delete(bmat[i], j) >= bmat[i, j])) / B for j in range(B)]
                   for i in range(len(STATS))])
    minp_b = pb.min(axis=0)
    minp = min(p.values())
    p_comb = float((1.0 + np.sum(minp_b <= minp)) / (B + 1.0))
    ev = {"n_bootstrap": B, "alpha": alpha, "p_value": p_comb,
          "rule": "inadequate when the bootstrap-calibrated smallest p-value of (drift, misfit, phase_misfit) "
                  "is <= alpha",
          "statistics": {}}
    for k in STATS:
        q = np.quantile(boot[k], [0.05, 0.5, 0.95]).tolist()
        ev["statistics"][k] = {"observed": float(observed[k]), "bootstrap_q05_q50_q95": q, "p_value": p[k],
                               "bootstrap": [float(v) for v in boot[k]]}
    ev["window_estimates"] = {}
    for name, f in observed["fits"].items():
        th = base.to_si(f.z)
        sd_ = np.sqrt(np.diag(f.cov))
        ev["window_estimates"][name] = {
            "t_star_end": float(obs.t_star[f.K]),
            **{n: {"median": float(th[i]), "sd_log": float(sd_[i])} for i, n in enumerate(base.names)}}
    ev["phase_chi2"] = observed["phase_chi2"]
    return {"verdict": "inadequate" if p_comb <= alpha else "adequate", "evidence": ev}
