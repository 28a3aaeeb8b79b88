"""Held-out predictive performance of a candidate (data the fit did not see).

* ``forecast``: fit to the samples up to the 2nd measured collapse (all experiments), predict the
  rest of the record (3rd collapse onwards); RMSE of R* per experiment on the unseen samples.
* ``loeo``: leave one experiment out: fit to the other N_exp - 1 experiments (whole record),
  predict the left-out one; its geometry and alignment (Rmax, Req, time of the maximum: the
  nuisances) are fitted with the material held at the others' estimate -- a new bubble's geometry
  is measured, its material predicted; RMSE over its samples 1..N_t.
* ``elpd``: PSIS-LOO (``az.loo``) over experiments on the Laplace posterior of the whole-record
  fit: pointwise Gaussian log-likelihood (each record's variance and tempering of the observation
  model, nuisances at their MAP) summed over time per experiment
  (arviz-1x-notes §4), so each "point" is one experiment; ``az.compare`` gives the difference to
  the baseline and its SE.
"""

from __future__ import annotations

import numpy as np

from imrbayes.diagnosis.candidates import BASELINE
from imrbayes.diagnosis.lsq import fit_map, fit_nuisances, predict

__all__ = ["forecast", "loeo", "loglik_draws", "elpd_compare", "paired"]


def _rmse_rows(pred, y):
    r = pred - y
    bad = ~np.isfinite(r)
    r = np.where(bad, 1.0, r)
    return np.sqrt(np.mean(r * r, axis=-1))


def forecast(cand, obs, phases, full_fit, om=None) -> dict:
    from imrbayes.diagnosis.lsq import ObsModel

    om = ObsModel.of(obs) if om is None else om
    K2 = phases.collapse_index(2)
    n = obs.n_samples
    if K2 >= n - 5:
        return {"per_experiment": [], "rmse": float("nan"), "note": "record too short after the 2nd collapse"}
    f = fit_map(cand, obs, K=K2, minima=phases.minima, om=om, starts=[full_fit.z], nu0=full_fit.nu)
    pred = predict(cand, f.z[None], obs, np.arange(obs.n_exp), phases.minima, n - 1, f.nu, om.frames)[0]
    per = _rmse_rows(pred[:, K2 + 1 :], obs.R_star[:, K2 + 1 :])
    return {
        "scheme": f"fit to t* <= {obs.t_star[K2]:.3f} (2nd collapse), predict t* > {obs.t_star[K2]:.3f}",
        "per_experiment": per.tolist(),
        "rmse": float(np.sqrt(np.mean(per**2))),
        "z": f.z.tolist(),
    }


def loeo(cand, obs, phases, full_fit, om=None) -> dict:
    if obs.n_exp < 2:
        return {"per_experiment": [], "rmse": float("nan"), "note": "needs >= 2 experiments"}
    per = []
    for e in range(obs.n_exp):
        rest = np.array([i for i in range(obs.n_exp) if i != e])
        f = fit_map(cand, obs, idx=rest, minima=phases.minima, om=om, starts=[full_fit.z], nu0=full_fit.nu)
        g = fit_nuisances(cand, obs, [e], f.z, minima=phases.minima, om=om, nu0=full_fit.nu)
        per.append(float(_rmse_rows(g.fitted[0, 1:], obs.R_star[e, 1:])))
    per = np.array(per)
    return {
        "scheme": "leave one experiment out (fit N_exp - 1 experiments, predict the left-out one)",
        "per_experiment": per.tolist(),
        "rmse": float(np.sqrt(np.mean(per**2))),
    }


def paired(base_rows, ext_rows) -> dict:
    """Mean and SE over experiments of the RMSE difference baseline - extended (> 0: extended better)."""
    a, b = np.asarray(base_rows, dtype=float), np.asarray(ext_rows, dtype=float)
    if a.size == 0 or a.size != b.size:
        return {"mean_diff": float("nan"), "se": float("nan")}
    d = a - b
    se = float(np.std(d, ddof=1) / np.sqrt(d.size)) if d.size > 1 else float("nan")
    return {"mean_diff": float(d.mean()), "se": se}


def loglik_draws(cand, obs, phases, full_fit, n_draws: int = 100, seed: int = 0, om=None) -> np.ndarray:
    """(n_draws, n_exp, N_t) pointwise log-likelihood (samples 1..N_t) of Laplace draws (nuisances
    at their MAP; each record's variance and tempering from ``om``)."""
    rng = np.random.default_rng(seed)
    try:
        L = np.linalg.cholesky(full_fit.cov + 1e-12 * np.eye(cand.d))
    except np.linalg.LinAlgError:
        L = np.diag(np.sqrt(np.abs(np.diag(full_fit.cov))))
    Z = full_fit.z[None] + rng.standard_normal((n_draws, cand.d)) @ L.T
    R = predict(
        cand,
        Z,
        obs,
        np.arange(obs.n_exp),
        phases.minima,
        obs.n_samples - 1,
        full_fit.nu,
        None if om is None else om.frames,
    )[..., 1:]
    if om is None:
        P, a = np.broadcast_to(obs.P[1:], (obs.n_exp, obs.n_samples - 1)), np.ones(obs.n_exp)
    else:
        P = np.broadcast_to((om.sd_used**2)[:, None], (obs.n_exp, obs.n_samples - 1))
        a = om.alpha
    ok = np.all(np.isfinite(R), axis=(1, 2))
    if ok.sum() >= 10:  # failed draws are dropped (their likelihood is not defined)
        R = R[ok]
    R = np.where(np.isfinite(R), R, 10.0)
    return -0.5 * a[None, :, None] * (np.log(2 * np.pi * P)[None] + (obs.R_star[None, :, 1:] - R) ** 2 / P[None])


def _loo(az, ll):
    t = az.from_dict(
        {"posterior": {"theta": np.zeros((1, ll.shape[0]))}, "log_likelihood": {"R": ll[None]}},
        dims={"R": [f"d{i}" for i in range(ll.ndim - 1)]},
    )
    return t, az.loo(t)


def elpd_compare(lls: dict, baseline: str = BASELINE.key) -> dict:
    """``az.loo`` per model and ``az.compare`` against the baseline; lls: key -> (draws, n_exp, N_t).

    Level ``experiment`` (log-likelihood summed over time: leave one experiment out) first; if PSIS
    fails for any model there (all importance weights but one underflow when a whole curve's
    log-likelihood varies by hundreds of nats across draws), level ``sample`` (leave one sample out)
    for every model, and the output says so."""
    import warnings

    import arviz as az

    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for level in ("experiment", "sample"):
            trees, res = {}, {}
            try:
                for k, ll in lls.items():
                    x = ll.sum(axis=-1) if level == "experiment" else ll
                    trees[k], lo = _loo(az, x)
                    res[k] = {
                        "elpd": float(lo.elpd),
                        "se": float(lo.se),
                        "level": level,
                        "n_points": int(np.prod(x.shape[1:])),
                        "pareto_k_max": float(np.nanmax(np.asarray(lo.pareto_k))),
                    }
            except ValueError:
                continue
            out = res
            break
        if not out:
            return {
                k: {
                    "elpd": float("nan"),
                    "se": float("nan"),
                    "elpd_diff": float("nan"),
                    "elpd_se": float("nan"),
                    "level": "failed",
                }
                for k in lls
            }
        for k in trees:
            if k == baseline:
                out[k]["elpd_diff"], out[k]["elpd_se"] = 0.0, 0.0
                continue
            out[k]["elpd_diff"] = float(out[k]["elpd"] - out[baseline]["elpd"])  # extended - baseline
            try:
                cmp = az.compare({baseline: trees[baseline], k: trees[k]})
                out[k]["elpd_se"] = float(cmp["dse"].max())
            except ValueError:  # e.g. a difference of 0 with SE 0: az.compare's rounding fails on the NaN
                out[k]["elpd_se"] = float("nan")
    return out
