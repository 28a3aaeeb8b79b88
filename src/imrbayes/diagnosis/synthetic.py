"""Synthetic datasets with a hidden mechanism (tests, ``scripts/diagnosis_confusion.py``).

Parameters are drawn (seeded) from realistic ranges: G 3-12 kPa, mu 0.04-0.15 Pa s (log-uniform),
Rmax ~ N(300, 30) µm, Rmax/Req ~ N(7.5, 0.4) (methods.md §6), and the mechanism's own parameters
from its candidate's ``synthetic`` ranges (:mod:`imrbayes.diagnosis.candidates`), where the effect
is of the size seen in real gels. Noise: the paper's verification noise (methods.md §5) times
``noise_scale``, independent per sample; P_k is the across-experiment sample variance, as for
measured data.
"""

from __future__ import annotations

import numpy as np

from imrbayes.data.noise import noise_variance, paper_sigma
from imrbayes.diagnosis.candidates import BASELINE, CANDIDATES, Range
from imrbayes.diagnosis.lsq import predict
from imrbayes.diagnosis.models import make_candidate
from imrbayes.diagnosis.phases import phases_of
from imrbayes.ensemble import Observations

__all__ = ["GENERATORS", "BASELINE_TRUTH", "synthetic_obs"]

#: True (G, mu) of every synthetic dataset [Pa, Pa s]; the mechanism's own come from its candidate.
BASELINE_TRUTH = {"G": Range(3e3, 12e3, log=True), "mu": Range(0.04, 0.15, log=True)}


def _generators() -> dict:
    out = {BASELINE.mechanism: BASELINE.key}
    for c in CANDIDATES.values():
        if c.synthetic is not None:
            out.setdefault(c.mechanism, c.key)
    return out


#: mechanism -> key of the candidate that simulates it (the first registered one with ``synthetic``),
#: in registry order (``scripts/diagnosis_confusion.py`` derives its seeds from this order).
GENERATORS = _generators()


def synthetic_obs(mechanism: str, seed: int, options, n_exp: int = 5, noise_scale: float = 1.0,
                  n_steps: int = 120, dt_star: float = 0.025):
    """(Observations, truth dict) of ``n_exp`` noisy experiments with the hidden ``mechanism``."""
    rng = np.random.default_rng(seed)
    key = GENERATORS[mechanism]
    cand = make_candidate(key, options)
    theta = {n: r.draw(rng) for n, r in {**BASELINE_TRUTH, **cand.spec.synthetic}.items()}
    rmax = np.clip(rng.normal(300e-6, 30e-6, n_exp), 220e-6, 400e-6)
    ratio = np.clip(rng.normal(7.5, 0.4, n_exp), 6.5, 8.5)
    req = rmax / ratio
    t = np.arange(n_steps + 1) * dt_star
    z = cand.to_internal([theta[n] for n in cand.names])
    blank = Observations(t, np.ones((n_exp, t.size)), np.ones(t.size), rmax, req)
    minima = None
    if cand.piecewise:   # breaks at the collapses of the baseline bubble's curve, then refined once
        base = make_candidate(BASELINE.key, options)
        R0 = predict(base, z[None, :2], blank, np.arange(n_exp), None, n_steps)[0]
        minima = phases_of(Observations(t, np.maximum(R0, 1e-3), np.ones(t.size), rmax, req)).minima
        R1 = predict(cand, z[None], blank, np.arange(n_exp), minima, n_steps)[0]
        minima = phases_of(Observations(t, np.maximum(R1, 1e-3), np.ones(t.size), rmax, req)).minima
    R = predict(cand, z[None], blank, np.arange(n_exp), minima, n_steps)[0]
    if not np.all(np.isfinite(R)):
        raise RuntimeError(f"forward solve failed for the synthetic truth {theta}")
    Y = R + noise_scale * paper_sigma(t, R) * rng.standard_normal(R.shape)
    Y[:, 0] = 1.0
    Y = np.maximum(Y, 1e-3)
    P, _ = noise_variance(t, Y)
    obs = Observations(t, Y, P, rmax, req, names=[f"exp_{i + 1:03d}" for i in range(n_exp)])
    return obs, {"mechanism": mechanism, "model": key, "theta": theta, "rmax_m": rmax.tolist(),
                 "req_m": req.tolist(), "noise_scale": noise_scale, "seed": seed}
