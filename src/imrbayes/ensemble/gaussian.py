"""Gaussian algebra shared by the ensemble methods (all in the internal coordinates z); the fusion
of bubbles is :mod:`imrbayes.ensemble.fusion`.

* :func:`rtps` — relaxation to prior spread that keeps the correlations;
* :func:`precision_weighted` — the normalised precision weighting of methods.md §4;
* :func:`draw` — a Gaussian ensemble (optionally with exactly the requested sample moments);
* :func:`marginal_summary` — mean, sd and 95 % HDI in SI units of a (log-)normal marginal.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["rtps", "rtps_factors", "precision_weighted", "draw", "marginal_summary", "sym", "is_pd"]


def sym(a):
    """Symmetric part of a square matrix (or a stack of them)."""
    a = np.asarray(a, dtype=np.float64)
    return 0.5 * (a + np.swapaxes(a, -1, -2))


def is_pd(a) -> bool:
    """Whether the symmetric part of ``a`` (n, n) is positive definite (a Cholesky factor exists)."""
    try:
        np.linalg.cholesky(sym(a))
        return True
    except np.linalg.LinAlgError:
        return False


def rtps_factors(prior_anom, post_anom, a: float, tiny: float = 1e-12):
    """Per-component factors f = ((1 - a) s_post + a s_prior) / s_post of RTPS.

    prior_anom, post_anom : (..., N, n) ensemble anomalies (any common scaling). Components whose
    posterior spread is below ``tiny`` times the prior spread (or zero) get f = 1.
    """
    sp = np.sqrt(np.mean(np.square(prior_anom), axis=-2))
    sa = np.sqrt(np.mean(np.square(post_anom), axis=-2))
    with np.errstate(divide="ignore", invalid="ignore"):
        f = ((1.0 - a) * sa + a * sp) / sa
    return np.where((sa > tiny * np.maximum(sp, tiny)) & np.isfinite(f), f, 1.0)


def rtps(prior_anom, post_anom, a: float = 0.7):
    """Relaxation to prior spread (Whitaker & Hamill 2012): sd -> s_post + a (s_prior - s_post).

    Every anomaly row of component i is multiplied by the same factor f_i, so the posterior
    covariance becomes D C D (D = diag f): the correlations between parameters are kept.
    Returns the inflated anomalies, same shape as ``post_anom`` (..., N, n).
    """
    f = rtps_factors(prior_anom, post_anom, a)
    return post_anom * f[..., None, :]


def precision_weighted(means, covs, weights=None):
    """Normalised precision weighting (methods.md §4).

    ``Sigma^-1 = sum_j w_j S_j^-1``, ``mu = Sigma sum_j w_j S_j^-1 m_j`` with weights w_j (default
    1/J, so they sum to one and overlapping windows do not over-count precision).
    means (J, n), covs (J, n, n) -> (mean (n,), cov (n, n)).
    """
    means = np.atleast_2d(np.asarray(means, dtype=np.float64))
    J = means.shape[0]
    w = np.full(J, 1.0 / J) if weights is None else np.asarray(weights, dtype=np.float64)
    prec = np.linalg.inv(sym(covs))
    Lam = sym(np.einsum("j,jab->ab", w, prec))
    cov = sym(np.linalg.inv(Lam))
    return cov @ np.einsum("j,jab,jb->a", w, prec, means), cov


def draw(rng, mean, cov, n: int, exact: bool = True):
    """(n, d) draws of N(mean, cov). ``exact``: affinely corrected so that the sample mean and
    the sample covariance (ddof=1) equal ``mean`` and ``cov`` exactly (needs n > d)."""
    mean = np.asarray(mean, dtype=np.float64)
    cov = sym(cov)
    d = mean.size
    L = np.linalg.cholesky(cov + 1e-300 * np.eye(d))
    x = rng.standard_normal((n, d))
    if exact and n > d:
        x = x - x.mean(axis=0)
        C = np.cov(x, rowvar=False, ddof=1).reshape(d, d)
        x = x @ np.linalg.inv(np.linalg.cholesky(C)).T
    return mean + x @ L.T


def _hdi_lognormal(m, s, prob):
    """Shortest interval of log-normal(m, s) with probability ``prob``."""
    # scipy is imported where it is used: the method registry (imported when the CLI starts) stays cheap
    from scipy import optimize, stats

    def width(p):
        return math.exp(m + s * stats.norm.ppf(p + prob)) - math.exp(m + s * stats.norm.ppf(p))

    res = optimize.minimize_scalar(
        width, bounds=(1e-12, 1.0 - prob - 1e-12), method="bounded", options={"xatol": 1e-10}
    )
    p = float(res.x)
    return [math.exp(m + s * stats.norm.ppf(p)), math.exp(m + s * stats.norm.ppf(p + prob))]


def marginal_summary(m: float, s: float, log: bool, prob: float = 0.95) -> dict:
    """SI ``{"mean", "sd", "hdi95", "median"}`` of the marginal N(m, s^2) in z.

    ``log``: z = log(theta), so theta is log-normal: mean exp(m + s^2/2), sd mean sqrt(exp(s^2)-1),
    the HDI is the shortest 95 % interval (found numerically). Otherwise the Gaussian values.
    """
    m, s = float(m), float(abs(s))
    if not log:
        from scipy import stats

        h = stats.norm.ppf(0.5 + prob / 2) * s
        return {"mean": m, "sd": s, "hdi95": [m - h, m + h], "median": m}
    mean = math.exp(m + 0.5 * s * s)
    sd = mean * math.sqrt(math.expm1(s * s))
    hdi = _hdi_lognormal(m, s, prob) if s > 0 else [mean, mean]
    return {"mean": mean, "sd": sd, "hdi95": hdi, "median": math.exp(m)}
