"""Sampled (non-Gaussian) per-experiment posteriors and their fusion across bubbles.

Why: on camera-style thermal records one bubble's posterior of (log G, log mu) with its Rmax,
time of the maximum and Req is a curved, skewed ridge; its Gaussian (the ensemble's, or the
Laplace one at the MAP) is too narrow and centred too high, and multiplying six of them is
confidently wrong (docs/results.md, "Why the thermal rows miss"). Sampling each bubble's
posterior and fusing the samples keeps the shape.

* :func:`adaptive_importance` — population Monte Carlo: a multivariate-t proposal started at a
  Gaussian, refitted to the weighted draws each round; every round's draws are kept, weighted
  against the mixture of all proposals (deterministic-mixture weights).
* :func:`fuse_draws` — the gel-level mean mu given every experiment's weighted draws and a
  between-bubble covariance T = diag(tau^2): experiment n's likelihood of its own theta_n is the
  kernel density of its draws over the prior they were drawn under, so with theta_n ~ N(mu, T)
  integrated out it is a Gaussian mixture in mu; mu | data is sampled by
  :func:`adaptive_importance` from the Gaussian fusion.

Everything is in the internal coordinates z (log for positive parameters).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

from imrbayes.ensemble.gaussian import sym

__all__ = ["WeightedDraws", "adaptive_importance", "fuse_draws", "weighted_quantiles"]


@dataclass
class WeightedDraws:
    """x (M, d) draws, w (M,) normalised weights, ess: Kish's effective sample size 1 / sum w^2."""

    x: np.ndarray
    w: np.ndarray
    ess: float

    @property
    def mean(self) -> np.ndarray:
        return self.w @ self.x

    @property
    def cov(self) -> np.ndarray:
        dx = self.x - self.mean
        return sym((self.w[:, None] * dx).T @ dx)

    def thinned(self, n: int, rng) -> "WeightedDraws":
        """At most ``n`` draws: systematic resampling (equal weights) when there are more, dropping
        draws of negligible weight first."""
        keep = self.w > 1e-12 * self.w.max()
        x, w = self.x[keep], self.w[keep] / self.w[keep].sum()
        if x.shape[0] <= n:
            return WeightedDraws(x, w, self.ess)
        u = (rng.random() + np.arange(n)) / n
        idx = np.minimum(np.searchsorted(np.cumsum(w), u), x.shape[0] - 1)
        return WeightedDraws(x[idx], np.full(n, 1.0 / n), self.ess)


def _t_logpdf(x, mean, chol, df):
    d = mean.size
    dev = np.linalg.solve(chol, (x - mean).T).T
    return (math.lgamma(0.5 * (df + d)) - math.lgamma(0.5 * df) - 0.5 * d * math.log(df * math.pi)
            - np.sum(np.log(np.diag(chol))) - 0.5 * (df + d) * np.log1p(np.sum(dev ** 2, axis=1) / df))


def adaptive_importance(log_target, mean, cov, rng, n_draws: int = 1000, rounds: int = 4,
                        df: float = 3.0) -> WeightedDraws:
    """Weighted draws of the density exp(log_target) (unnormalised).

    log_target: (M, d) -> (M,) (-inf where the model fails); mean (d,), cov (d, d): the first
    proposal's centre and scale (e.g. a Gaussian approximation); ``rounds`` proposals of
    ``n_draws`` each, multivariate t with ``df`` degrees of freedom, each refitted to the weighted
    draws of all rounds so far. Returns all rounds' draws with deterministic-mixture weights.
    """
    mean = np.asarray(mean, dtype=np.float64).copy()
    d = mean.size
    cov = sym(cov)
    props, xs, lps = [], [], []
    w = None
    X = None
    for _ in range(rounds):
        scale = np.sqrt(np.maximum(np.diag(cov), 1e-300))
        chol = np.linalg.cholesky(sym(cov) + 1e-10 * np.diag(scale ** 2) + 1e-300 * np.eye(d))
        z = rng.standard_normal((n_draws, d)) @ chol.T
        x = mean + z / np.sqrt(rng.chisquare(df, n_draws) / df)[:, None]
        props.append((mean.copy(), chol))
        xs.append(x)
        lp = np.asarray(log_target(x), dtype=np.float64)
        lps.append(np.where(np.isfinite(lp), lp, -np.inf))
        X, LP = np.vstack(xs), np.concatenate(lps)
        lq = logsumexp(np.stack([_t_logpdf(X, m, c, df) for m, c in props]), axis=0) - math.log(len(props))
        lw = LP - lq
        if not np.any(np.isfinite(lw)):
            raise RuntimeError("importance sampling: every draw failed or has zero density")
        w = np.exp(lw - np.max(lw))
        w /= w.sum()
        mean = w @ X
        dx = X - mean
        cov = sym((w[:, None] * dx).T @ dx)
    return WeightedDraws(X, w, float(1.0 / np.sum(w ** 2)))


def weighted_quantiles(x, w, q) -> np.ndarray:
    """Quantiles ``q`` of the weighted sample x (M,) with weights w (M,) (inverse of the weighted CDF)."""
    order = np.argsort(x)
    cw = np.cumsum(w[order]) / np.sum(w)
    idx = np.minimum(np.searchsorted(cw, np.asarray(q)), x.size - 1)
    return x[order][idx]


def _log_gauss_norm(L) -> float:
    """log of the normalising factor of N(., ., L L^T)."""
    return -float(np.sum(np.log(np.diag(L)))) - 0.5 * L.shape[0] * math.log(2.0 * math.pi)


def _mixture_terms(draws: WeightedDraws, prior_mean, prior_cov, T, eps: float):
    """Experiment n's likelihood of mu, integral of p_n(theta) / p0(theta) N(theta; mu, T), as a
    Gaussian mixture in mu: groups of (centres (J, d), inverse Cholesky factor, log weights (J,)).

    p_n is the draws' kernel density mixed with the Gaussian of their moments (weight ``eps``: the
    far tails, where a few thousand draws say nothing). The kernel is h^2 C (C the draws'
    covariance, h Scott's factor) around the draws shrunk towards their mean by sqrt(1 - h^2), so
    the density keeps the draws' covariance (Liu & West; a plain kernel density widens every
    experiment by h^2); the prior p0 is taken as constant over one kernel. The Gaussian part over
    p0 is exactly Gaussian (precision C^-1 - C0^-1, as in likelihood_terms)."""
    d = draws.x.shape[1]
    h2 = max(draws.ess, 2.0) ** (-2.0 / (d + 4))
    m, C = draws.mean, draws.cov
    P0 = np.linalg.inv(sym(prior_cov))
    L0 = np.linalg.cholesky(sym(prior_cov))

    def log_prior(x):
        dx = x - prior_mean
        return -0.5 * np.einsum("nd,de,nd->n", dx, P0, dx) + _log_gauss_norm(L0)
    L = np.linalg.cholesky(sym(h2 * C + np.diag(T)))
    kde = (m + math.sqrt(1.0 - h2) * (draws.x - m), np.linalg.inv(L),
           math.log1p(-eps) + np.log(np.maximum(draws.w, 1e-300)) - log_prior(draws.x) + _log_gauss_norm(L))
    Ci = np.linalg.inv(C)
    Pl = sym(Ci - P0)
    Cl = np.linalg.inv(Pl)
    ml = Cl @ (Ci @ m - P0 @ prior_mean)
    # N(x; m, C) / p0(x) = K N(x; ml, Cl)
    _, logdet_c = np.linalg.slogdet(C)
    _, logdet_cl = np.linalg.slogdet(Cl)
    log_k = (-0.5 * (m @ Ci @ m - prior_mean @ P0 @ prior_mean) + 0.5 * ml @ Pl @ ml - 0.5 * logdet_c
             + 0.5 * logdet_cl - _log_gauss_norm(L0) + 0.5 * d * math.log(2.0 * math.pi))
    # log_k above: log N(x; m, C) - log p0(x) - log N(x; ml, Cl), which does not depend on x
    Lg = np.linalg.cholesky(sym(Cl + np.diag(T)))
    gauss = (ml[None, :], np.linalg.inv(Lg), np.array([math.log(eps) + log_k + _log_gauss_norm(Lg)]))
    return [kde, gauss]


def fuse_draws(draws, prior_mean, prior_cov, T, start_mean, start_cov, rng, n_draws: int = 1000,
               rounds: int = 3, max_kernel_draws: int = 2000, eps: float = 0.05,
               draw_prior=None) -> WeightedDraws:
    """The gel-level mean mu | data, T from every experiment's weighted posterior draws.

    draws: list of :class:`WeightedDraws` (internal coordinates), each drawn under the prior
    N(prior_mean, prior_cov), which is also mu's prior, unless ``draw_prior`` = (mean, cov) names
    the (working) prior they were drawn under; T (d,): between-bubble variances tau^2
    (zeros: one common theta, the product rule); start_mean, start_cov: a Gaussian approximation
    of the answer (the Gaussian fusion), the first proposal (its sd doubled); eps: the weight of
    each experiment's Gaussian in its density (:func:`_mixture_terms`).
    """
    prior_mean = np.asarray(prior_mean, dtype=np.float64)
    P0 = np.linalg.inv(sym(prior_cov))
    T = np.asarray(T, dtype=np.float64)
    dm0, dc0 = (prior_mean, prior_cov) if draw_prior is None else (np.asarray(draw_prior[0], dtype=np.float64),
                                                                    draw_prior[1])
    terms = [_mixture_terms(dr.thinned(max_kernel_draws, rng), dm0, dc0, T, eps) for dr in draws]

    def log_target(mu):
        dm = mu - prior_mean
        out = -0.5 * np.einsum("md,de,me->m", dm, P0, dm)
        for groups in terms:
            parts = []
            for xc, Li, la in groups:
                # (M, J) squared Mahalanobis distances through the group's Cholesky factor
                diff = (mu[:, None, :] - xc[None, :, :]) @ Li.T
                parts.append(la[None, :] - 0.5 * np.sum(diff ** 2, axis=2))
            out = out + logsumexp(np.concatenate(parts, axis=1), axis=1)
        return out

    return adaptive_importance(log_target, start_mean, 4.0 * sym(start_cov), rng, n_draws=n_draws, rounds=rounds)
