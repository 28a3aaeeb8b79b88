"""Calibrated constant-parameter check (parametric bootstrap).

Statistics of one dataset under the baseline (constant-parameter NHKV):

* ``drift``: the largest squared Mahalanobis distance between the (log G, log mu) estimates of
  fits to the 1st collapse, to the 2nd collapse and to the whole record (covariances of the two
  Laplace posteriors added);
* ``misfit``: the normalised chi-square (mean of r^2/P_k) of the whole-record fit;
* ``phase_misfit``: the largest normalised chi-square of one phase of that fit;
* ``mienks_drift`` (when MIEnKS settings are given): the drift of the MIEnKS-MDA window estimates
  G(t), mu(t): weighted least-squares slopes of the fused window means of log G and log mu against
  the window centre t*, each divided by its standard error (window variances as weights), squared
  and summed. The windows overlap and are chained, so these standard errors are not the slopes'
  true ones (and the chain's walk from the prior is a drift of its own): the bootstrap, which runs
  the same smoother on constant-parameter replicates, is what makes the number comparable.

None of them has a known null distribution (residuals are correlated in time, P_k is estimated),
so each is calibrated by a parametric bootstrap: B synthetic datasets of the same design (same
Rmax, Req, number of experiments, independent Gaussian noise whose variance plus the spread of the
baseline curves across experiments reproduces P_k at every sample) generated from
the baseline fit, processed exactly as the data (P_k re-estimated as the across-experiment sample
variance, the same fits). p-values are (1 + #{T_b >= T}) / (B + 1); the combined p-value is the
bootstrap calibration of the smallest of them (so no Bonferroni factor is needed).
"""

from __future__ import annotations

import numpy as np

from imrbayes.data.noise import noise_variance
from imrbayes.diagnosis.lsq import fit_map, predict
from imrbayes.ensemble import Observations

__all__ = ["statistics", "bootstrap_check", "window_drift", "mienks_drift"]

STATS = ("drift", "misfit", "phase_misfit")


def mienks_drift(base, obs, settings, seed: int = 0) -> tuple:
    """MIEnKS-MDA of the baseline over the whole record; returns (statistic, details) with the
    slopes of log G and log mu per unit t* and their standard errors (see module doc)."""
    from imrbayes.ensemble import ParamSpace
    from imrbayes.ensemble.mienks import fit_mienks

    sp = ParamSpace.for_model(base.fm.constitutive)
    with np.errstate(all="ignore"):
        r = fit_mienks(base.fm, obs, sp, settings, seed=seed)
    m = np.array([w["mean_internal"] for w in r.windows])[:, :2]
    v = np.array([np.diag(w["cov_internal"]) for w in r.windows])[:, :2]
    tc = np.array([0.5 * (w["t_star"][0] + w["t_star"][1]) for w in r.windows])
    slope, se = np.zeros(2), np.zeros(2)
    for i in range(2):
        w = 1.0 / np.maximum(v[:, i], 1e-12)
        tb = np.sum(w * tc) / w.sum()
        sxx = np.sum(w * (tc - tb) ** 2)
        slope[i] = np.sum(w * (tc - tb) * (m[:, i] - np.sum(w * m[:, i]) / w.sum())) / sxx
        se[i] = 1.0 / np.sqrt(sxx)
    T = float(np.sum((slope / se) ** 2))
    return T, {"slope_log_G": float(slope[0]), "slope_log_mu": float(slope[1]), "se_log_G": float(se[0]),
               "se_log_mu": float(se[1]), "t_star_windows": tc.tolist(),
               "G_windows": np.exp(m[:, 0]).tolist(), "mu_windows": np.exp(m[:, 1]).tolist()}


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


def statistics(base, obs, phases, starts=None, mienks=None, seed: int = 0) -> dict:
    """Window fits and the statistics of ``obs`` under the baseline candidate ``base`` (with
    ``mienks``, an :class:`~imrbayes.ensemble.mienks.MIEnKSSettings`, also ``mienks_drift``, or,
    when it cannot be computed, ``mienks_error``: the one-line error)."""
    full = fit_map(base, obs, minima=phases.minima, starts=starts)
    drift, fits = window_drift(base, obs, phases, full)
    r2 = (obs.R_star[:, 1:] - full.fitted[:, 1:]) ** 2 / obs.P[None, 1:]
    per_phase = []
    for m in phases.masks():
        mm = m[1:]
        per_phase.append(float(np.nanmean(r2[:, mm])) if mm.any() else float("nan"))
    out = {"fits": fits, "drift": drift, "misfit": float(np.nanmean(r2)),
           "phase_misfit": float(np.nanmax(per_phase)), "phase_chi2": per_phase}
    if mienks is not None:
        try:
            T, det = mienks_drift(base, obs, mienks, seed=seed)
        except (RuntimeError, ValueError, np.linalg.LinAlgError) as exc:   # e.g. the smoother lost its members
            msg = str(exc).splitlines()
            out["mienks_error"] = f"{type(exc).__name__}: {msg[0]}" if msg else type(exc).__name__
        else:
            if np.isfinite(T):
                out["mienks_drift"], out["mienks"] = T, det
            else:
                out["mienks_error"] = f"the statistic is not finite ({T})"
    return out


def _pvals(T, Tb):
    Tb = np.asarray(Tb, dtype=float)
    Tb = np.where(np.isfinite(Tb), Tb, np.inf)      # a replicate without the statistic counts against rejection
    return (1.0 + np.sum(Tb >= T)) / (Tb.size + 1.0)


def bootstrap_unit(unit, rng) -> dict:
    """Unit ``bootstrap=007``: one replicate -- a synthetic dataset of the data's design from the
    baseline curves ``R0`` with noise sd ``sd`` (drawn from the unit's own ``rng``), processed as the
    data; returns its statistics. The baseline candidate is rebuilt from (options, physics, prior)."""
    from imrbayes.diagnosis.candidates import BASELINE
    from imrbayes.diagnosis.models import make_candidate

    d = unit.data
    obs = d["obs"]
    base = make_candidate(BASELINE.key, d["options"], d["physics"], d["prior"])
    R0, sd = d["R0"], d["sd"]
    Y = R0 + sd[None, :] * rng.standard_normal(R0.shape)
    Y[:, 0] = 1.0
    Y = np.maximum(Y, 1e-3)
    P, _ = noise_variance(obs.t_star, Y) if obs.n_exp >= 2 else (obs.P, None)
    ob = Observations(obs.t_star, Y, P, obs.rmax_m, obs.req_m, obs.t_collapse_star, list(obs.names))
    st = statistics(base, ob, d["phases"], starts=[d["z0"]], mienks=d["mienks"], seed=int(d["seed"]))
    return {k: float(st.get(k, float("nan"))) for k in d["stats"]}


def bootstrap_check(base, obs, phases, observed: dict, B: int = 19, seed: int = 0, alpha: float = 0.05,
                    progress=None, mienks=None, execution=None, build: dict | None = None) -> dict:
    """Verdict ``adequate``/``inadequate`` with the evidence (see module doc); ``mienks``: the
    MIEnKS settings the observed ``mienks_drift`` was computed with (None: not used).

    The B replicates are units of the execution layer (``bootstrap=007``, each with its own random
    stream from (seed, id)): parallel with ``--workers``, checkpointed, resumed. ``build`` =
    {options, physics, prior} rebuilds ``base`` in a unit (default: ``base``'s own). A replicate
    whose unit fails counts against rejection (its statistics are treated as +inf)."""
    import dataclasses

    from imrbayes.execution import Execution
    from imrbayes.execution import Unit

    stats = STATS + (("mienks_drift",) if mienks is not None and "mienks_drift" in observed else ())
    z0 = observed["fits"]["all"].z
    R0 = predict(base, z0[None], obs, np.arange(obs.n_exp), phases.minima, obs.n_samples - 1)[0]
    # measurement noise: P_k minus the across-experiment variance of the baseline curves (the part
    # of the sample variance that Rmax/Req differences explain), floored at P_k / 4, so that the
    # replicates' re-estimated P_k match the data's
    spread = np.var(R0, axis=0, ddof=1) if obs.n_exp >= 2 else np.zeros_like(obs.P)
    sd = np.sqrt(np.maximum(obs.P - spread, 0.25 * obs.P))
    build = build or {"options": base.fm.options, "physics": base.fm.physics, "prior": dict(base.space.prior_si)}
    common = {**build, "obs": obs, "phases": phases, "R0": R0, "sd": sd, "z0": z0, "stats": list(stats),
              "mienks": mienks if "mienks_drift" in stats else None}
    units = [Unit(f"bootstrap={b:03d}", {**common, "seed": seed + 1000 + b}) for b in range(B)]
    ex = execution or Execution(progress=False)
    if progress is not None and ex.bar is None:
        ex = dataclasses.replace(ex, progress=lambda done, total: progress(1))
    rep = ex.run(units, bootstrap_unit, seed, desc="diagnose bootstrap")
    boot = {k: [rep.results.get(f"bootstrap={b:03d}", {}).get(k, float("nan")) for b in range(B)] for k in stats}
    p = {k: float(_pvals(observed[k], boot[k])) for k in stats}
    # calibrate min-p: p-values of every bootstrap replicate against the others
    bmat = np.array([boot[k] for k in stats])            # (n_stats, B)
    pb = np.array([[(1.0 + np.sum(np.delete(bmat[i], j) >= bmat[i, j])) / B for j in range(B)]
                   for i in range(len(stats))])
    minp_b = pb.min(axis=0)
    minp = min(p.values())
    p_comb = float((1.0 + np.sum(minp_b <= minp)) / (B + 1.0))
    ev = {"n_bootstrap": B, "alpha": alpha, "p_value": p_comb,
          "rule": f"inadequate when the bootstrap-calibrated smallest p-value of ({', '.join(stats)}) "
                  "is <= alpha",
          "statistics": {}}
    for k in stats:
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
    if "mienks" in observed:
        ev["mienks_windows"] = {**observed["mienks"], "settings": {"n_ens": mienks.n_ens, "n_iter": mienks.n_iter,
                                                                   "L": mienks.L, "h": mienks.h}}
    return {"verdict": "inadequate" if p_comb <= alpha else "adequate", "evidence": ev}
