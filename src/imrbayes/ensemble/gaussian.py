"""Gaussian algebra shared by the ensemble methods (all in the internal coordinates z).

* :func:`fuse` — the prior-corrected product rule of methods.md §3 with a positive-definiteness guard;
* :func:`rtps` — relaxation to prior spread that keeps the correlations;
* :func:`precision_weighted` — the normalised precision weighting of methods.md §4;
* :func:`draw` — a Gaussian ensemble (optionally with exactly the requested sample moments);
* :func:`marginal_summary` — mean, sd and 95 % HDI in SI units of a (log-)normal marginal.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Fusion", "fuse", "likelihood_terms", "integrate_out_trailing", "marginal_under_reference", "fuse_likelihoods", "rtps", "rtps_factors", "precision_weighted", "draw", "marginal_summary",
           "sym", "is_pd"]


def sym(a):
    """Symmetric part of a square matrix (or a stack of them)."""
    a = np.asarray(a, dtype=np.float64)
    return 0.5 * (a + np.swapaxes(a, -1, -2))


def is_pd(a) -> bool:
    try:
        np.linalg.cholesky(sym(a))
        return True
    except np.linalg.LinAlgError:
        return False


@dataclass
class Fusion:
    """Result of :func:`fuse`.

    mean (n,), cov (n, n): the fused Gaussian. ``guard``: the prior-correction factor c actually
    used (1 = the exact rule) and why; ``pd``: whether the exact rule gave a positive-definite
    precision.
    """

    mean: np.ndarray
    cov: np.ndarray
    c: float = 1.0
    pd: bool = True
    notes: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"prior_correction_factor": self.c, "exact_rule_positive_definite": self.pd, "notes": self.notes}


def fuse(means, covs, prior_mean, prior_cov, margin: float = 1e-6) -> Fusion:
    """Fuse independent posteriors N(m_n, S_n) that share the prior N(m0, S0) (methods.md §3).

    ``Sigma^-1 = sum_n S_n^-1 - c (N - 1) S0^-1``,
    ``mu = Sigma [sum_n S_n^-1 m_n - c (N - 1) S0^-1 m0]``, with c = 1 (the exact product rule:
    p(theta | all) ∝ prod_n p(theta | y_n) / p0(theta)^(N-1)).

    Guard: when the exact precision is not positive definite (a posterior wider than the prior in
    some direction, e.g. after inflation), c is lowered to the largest value that keeps every
    eigenvalue of the precision at least ``margin`` times its largest: c = (1 - margin)/lambda_max
    with lambda_max the largest generalised eigenvalue of ((N-1) S0^-1, sum_n S_n^-1). c = 0 is
    the plain product of the posteriors. The factor and a note are returned (never silent).

    means : (N, n); covs : (N, n, n); prior_mean : (n,); prior_cov : (n, n).
    """
    means = np.atleast_2d(np.asarray(means, dtype=np.float64))
    covs = np.asarray(covs, dtype=np.float64).reshape(means.shape[0], means.shape[1], means.shape[1])
    N = means.shape[0]
    prec = np.linalg.inv(sym(covs))
    A = sym(prec.sum(axis=0))
    b = np.einsum("nij,nj->i", prec, means)
    P0 = np.linalg.inv(sym(prior_cov))
    B = (N - 1) * P0
    b0 = (N - 1) * P0 @ np.asarray(prior_mean, dtype=np.float64)
    c, notes = 1.0, []
    exact = sym(A - B)
    ok = is_pd(exact) and np.linalg.eigvalsh(exact).min() > margin * np.linalg.eigvalsh(exact).max()
    if N > 1 and not ok:
        from scipy.linalg import eigh
        lam = float(eigh(sym(B), A, eigvals_only=True).max())
        c = min(1.0, (1.0 - margin) / lam) if lam > 0 else 1.0
        notes.append(f"the exact prior-corrected product was not positive definite (largest generalised "
                     f"eigenvalue {lam:.4g}); prior correction scaled by c = {c:.4g}")
    Lam = sym(A - c * B)
    cov = sym(np.linalg.inv(Lam))
    mean = cov @ (b - c * b0)
    return Fusion(mean, cov, c, bool(ok or N == 1), notes)


def likelihood_terms(post_m, post_c, prior_m, prior_c, ridge: float = 1e-9):
    """Per-experiment likelihood (Lambda_n (N, d, d), eta_n (N, d)) = posterior / the prior it
    started from, projected onto the positive semi-definite cone (ensemble Gauss–Newton gives
    H >= I, so this only removes round-off); ``ridge`` times the prior precision keeps Lambda_n
    invertible in directions the data do not inform (it does not change eta_n). The algebra runs in
    units of each coordinate's prior sd, and the ridge is the prior precision matrix itself, not its
    largest eigenvalue times I: a parameter stated in small SI units (a Zener's retardation time,
    prior sd 5e-7 s, precision 4e12) would otherwise add 4e3 to every other coordinate's precision and pull each bubble's mean to z = 0 (G = 1 Pa,
    measured on stiff PA and synthetic Zener records, session 64). Returns (Lam, eta, m_n,
    n_clipped) with m_n the likelihood's centre."""
    post_m = np.atleast_2d(post_m)
    N, d = post_m.shape
    Lam, eta, mean = np.empty((N, d, d)), np.empty((N, d)), np.empty((N, d))
    clipped = 0
    for n in range(N):
        # in units of the prior sd (x = s u), so that no coordinate's unit sets the round-off
        sc = np.sqrt(np.diag(np.asarray(prior_c[n], dtype=np.float64)))
        sc = np.where(sc > 0, sc, 1.0)
        Si = np.linalg.inv(sym(post_c[n] / np.outer(sc, sc)))
        Qi = np.linalg.inv(sym(prior_c[n] / np.outer(sc, sc)))
        lam, V = np.linalg.eigh(sym(Si - Qi))
        clipped += int(np.sum(lam < 0))
        L = sym((V * np.maximum(lam, 0.0)) @ V.T + ridge * Qi)
        # the information Si m - Qi q, restricted to the directions the data inform
        e = V @ np.where(lam > 0, V.T @ (Si @ (post_m[n] / sc) - Qi @ (prior_m[n] / sc)), 0.0)
        Lam[n], eta[n] = L / np.outer(sc, sc), e / sc
        mean[n] = np.linalg.lstsq(L, e, rcond=None)[0] * sc
    return Lam, eta, mean, clipped


def integrate_out_trailing(Lam, eta, prior_sd):
    """A Gaussian likelihood exp(-x^T Lam x / 2 + eta^T x) of x = (z, r) ((d+k, d+k), (d+k,)) times
    the prior N(0, diag(prior_sd^2)) of its last k coordinates r, integrated over r: the likelihood
    of z, (Lam_z (d, d), eta_z (d,)) (a Schur complement). A prior_sd <= 0 fixes that coordinate at 0."""
    Lam, eta = np.asarray(Lam, dtype=np.float64), np.asarray(eta, dtype=np.float64)
    sd = np.atleast_1d(np.asarray(prior_sd, dtype=np.float64))
    k = sd.size
    d = Lam.shape[0] - k
    keep = sd > 0
    if not keep.any():
        return Lam[:d, :d].copy(), eta[:d].copy()
    r = d + np.flatnonzero(keep)
    C = Lam[np.ix_(r, r)] + np.diag(1.0 / sd[keep] ** 2)
    B = Lam[:d, r]
    return sym(Lam[:d, :d] - B @ np.linalg.solve(C, B.T)), eta[:d] - B @ np.linalg.solve(C, eta[r])


def marginal_under_reference(post_m, post_c, prior_m, prior_c, n_keep: int, swap: dict):
    """The first ``n_keep`` coordinates' posterior and prior (mean, cov, prior mean, prior cov) under a
    reference prior: the analysis's own prior (``prior_m``, ``prior_c``; ``post_*`` its posterior,
    (d,), (d, d)) with each coordinate i in ``swap`` ({i: sd}) made independent of the rest and
    N(0, sd^2). Their ratio is the likelihood of the kept coordinates with the swapped ones
    integrated out against N(0, sd^2), the others against the analysis prior's conditional.
    (The joint likelihood is posterior / prior, :func:`likelihood_terms`; exact for a
    linear-Gaussian model.)"""
    Lj, ej, _, _ = likelihood_terms(np.asarray(post_m)[None], np.asarray(post_c)[None], np.asarray(prior_m)[None],
                                    np.asarray(prior_c)[None])
    Rm, Rc = np.array(prior_m, dtype=np.float64), np.array(prior_c, dtype=np.float64)
    for i, sd in swap.items():
        Rc[i, :] = 0.0
        Rc[:, i] = 0.0
        Rc[i, i] = float(sd) ** 2
        Rm[i] = 0.0
    Rci = np.linalg.inv(Rc)
    P = np.linalg.inv(Rci + Lj[0])
    p = P @ (Rci @ Rm + ej[0])
    k = int(n_keep)
    return p[:k], sym(P[:k, :k]), Rm[:k], sym(Rc[:k, :k])


def fuse_likelihoods(post_m, post_c, prior_m, prior_c, chain_m, chain_c) -> Fusion:
    """Fuse experiments through their likelihoods: posterior / the prior each was computed from.

    post_m (N, n), post_c (N, n, n): each experiment's posterior; prior_m, prior_c: the prior that
    experiment's analysis started from (its ensemble's moments); chain_m (n,), chain_c (n, n): the
    shared prior of the fused result. Each likelihood is Lambda_n = S_n^-1 - Q_n^-1,
    eta_n = S_n^-1 m_n - Q_n^-1 q_n (PSD by construction for the ensemble Gauss–Newton, as H >= I;
    clipped to PSD against round-off, reported), and

        Sigma^-1 = C^-1 + sum_n Lambda_n,   mu = Sigma (C^-1 c + sum_n eta_n).

    When every experiment started from the shared prior (Q_n = C, q_n = c) this is exactly the
    prior-corrected product rule of :func:`fuse` (methods.md §3). It differs when the analyses
    started from other priors: En4D-Var's restarts (the last cycle's prior is the inflated
    previous posterior) and MIEnKS windows (each experiment's own inflated chain); there the
    original prior divided out N - 1 times is not what the posteriors contain.
    """
    C_inv = np.linalg.inv(sym(chain_c))
    Ls, etas, _, clipped = likelihood_terms(post_m, post_c, prior_m, prior_c, ridge=0.0)
    cov = sym(np.linalg.inv(sym(C_inv + Ls.sum(axis=0))))
    notes = [f"{clipped} negative eigenvalue(s) of window likelihoods clipped to 0"] if clipped else []
    return Fusion(cov @ (C_inv @ chain_m + etas.sum(axis=0)), cov, 1.0, clipped == 0, notes)


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
    res = optimize.minimize_scalar(width, bounds=(1e-12, 1.0 - prob - 1e-12), method="bounded",
                                   options={"xatol": 1e-10})
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
