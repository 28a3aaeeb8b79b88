"""The fusion of bubbles: each experiment's Gaussian posterior turned into a likelihood, then
combined across experiments (methods.md §3, §7.4), all in the internal coordinates z.

Public API:

* :func:`likelihood_terms` -- each experiment's likelihood (precision, information) = its
  posterior divided by the prior its analysis started from;
* :func:`fuse` -- the prior-corrected product rule of methods.md §3 (the paper's), with a
  positive-definiteness guard; :func:`fuse_likelihoods` -- the product of the likelihoods with one
  shared prior (a chained one in MIEnKS-MDA);
* :func:`random_effects` -- the gel-level mean, the between-bubble sd and the predictive for a new
  bubble (:class:`RandomEffects`); :func:`leave_one_out` -- the check of that predictive;
* :class:`BubbleFusion` (:func:`fuse_bubbles`, :meth:`BubbleFusion.from_likelihoods`) -- the
  above for one parameter space: its prior, its names and its SI summaries in one place;
* :func:`integrate_out_trailing`, :func:`marginal_under_reference` -- nuisance coordinates
  integrated out of a likelihood.

Random effects. Each experiment n contributes a Gaussian likelihood of its own parameters theta_n
(precision Lambda_n, information eta_n). The gel has a mean mu and a between-bubble covariance
T = diag(tau^2) (tau: the bubble-to-bubble sd on the internal axes):

    theta_n ~ N(mu, T),   mu ~ N(m0, C0)  (the parameter prior).

Integrating theta_n gives m_n ~ N(mu, Lambda_n^-1 + T). tau is estimated by maximising the
marginal likelihood p(data | tau) with mu integrated against its prior (type-II maximum
likelihood); its 95 % interval per parameter is the profile-likelihood interval. Given tau_hat:
mu | data ~ N(mu_hat, (C0^-1 + sum A_n)^-1), A_n = (Lambda_n^-1 + T)^-1. A new bubble's parameters
(the predictive): N(mu(tau), cov_mu(tau) + T) mixed over each tau_i's conditional posterior,
moment-matched. With tau = 0 the gel-level estimate is the product rule. One experiment: tau
cannot be estimated (reported as unknown).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from imrbayes.ensemble.gaussian import is_pd, marginal_summary, sym

__all__ = [
    "BubbleFusion",
    "fuse_bubbles",
    "Fusion",
    "fuse",
    "fuse_likelihoods",
    "likelihood_terms",
    "RandomEffects",
    "random_effects",
    "leave_one_out",
    "integrate_out_trailing",
    "marginal_under_reference",
]


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
        notes.append(
            f"the exact prior-corrected product was not positive definite (largest generalised "
            f"eigenvalue {lam:.4g}); prior correction scaled by c = {c:.4g}"
        )
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
    measured on stiff PA and synthetic Zener records). Returns (Lam, eta, m_n,
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
    Lj, ej, _, _ = likelihood_terms(
        np.asarray(post_m)[None], np.asarray(post_c)[None], np.asarray(prior_m)[None], np.asarray(prior_c)[None]
    )
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


_CHI2_95 = 3.841458820694124
_TAU_MAX = 3.0  # a between-bubble sd of e^3 (20x) on a log axis: beyond any gel


@dataclass
class RandomEffects:
    """Result of :func:`random_effects` (internal coordinates).

    mean, cov : gel-level mu | data; tau (d,) between-bubble sd on the internal axes; tau_ci (d, 2)
    95 % profile interval (NaN for one experiment); predictive_cov = cov + diag(tau^2) with its
    diagonal integrated over tau's uncertainty (:func:`_predictive_cov`);
    pooled_mean, pooled_cov: the tau = 0 (product rule) result; loglik_gain: log L(tau_hat) -
    log L(0) (how much the data favour scatter over none); n_exp.
    """

    mean: np.ndarray
    cov: np.ndarray
    tau: np.ndarray
    tau_ci: np.ndarray
    predictive_cov: np.ndarray
    pooled_mean: np.ndarray
    pooled_cov: np.ndarray
    loglik_gain: float
    n_exp: int
    notes: list = field(default_factory=list)

    def summaries(self, space) -> dict:
        """``estimate``, ``between_experiments`` and ``predictive`` (SI units; interfaces.md §4)."""
        est, between, pred = {}, {}, {}
        for i, name in enumerate(space.names):
            log = bool(space.positive[i])
            est[name] = marginal_summary(self.mean[i], math.sqrt(max(self.cov[i, i], 0.0)), log)
            pred[name] = marginal_summary(self.mean[i], math.sqrt(max(self.predictive_cov[i, i], 0.0)), log)
            if self.n_exp < 2:
                between[name] = {
                    "sd": None,
                    "hdi95": None,
                    "note": "one experiment: bubble-to-bubble scatter is unknown",
                }
                continue
            med = math.exp(self.mean[i]) if log else 1.0

            def to_sd(t):
                # the sd of a bubble's parameter around the gel median (log-normal for a log axis)
                return med * math.sqrt(math.expm1(t * t) * math.exp(t * t)) if log else float(t)

            lo, hi = self.tau_ci[i]
            between[name] = {
                "sd": to_sd(self.tau[i]),
                "hdi95": [to_sd(lo), to_sd(hi)],
                "sd_log" if log else "sd_internal": float(self.tau[i]),
                "ci95_log" if log else "ci95_internal": [float(lo), float(hi)],
                "interval": "95 % profile-likelihood interval",
            }
        return {"estimate": est, "between_experiments": between, "predictive": pred}

    def to_dict(self) -> dict:
        return {
            "mean_internal": self.mean.tolist(),
            "cov_internal": self.cov.tolist(),
            "tau": self.tau.tolist(),
            "tau_ci95": self.tau_ci.tolist(),
            "predictive_cov_internal": self.predictive_cov.tolist(),
            "pooled_mean_internal": self.pooled_mean.tolist(),
            "pooled_cov_internal": self.pooled_cov.tolist(),
            "loglik_gain_vs_no_scatter": self.loglik_gain,
            "n_experiments": self.n_exp,
            "notes": self.notes,
            "model": "theta_n ~ N(mu, diag(tau^2)) on the internal axes, mu ~ the parameter prior; tau by type-II "
            "maximum likelihood, 95 % profile intervals",
        }


def _conditional(Lam, m, T, m0, C0i):
    """mu | data, tau: (mean, cov, log marginal likelihood)."""
    d = m0.size
    A = np.empty_like(Lam)
    logdet = 0.0
    for n in range(Lam.shape[0]):
        M = np.eye(d) + T[:, None] * Lam[n]  # I + T Lambda_n (T diagonal)
        A[n] = sym(np.linalg.solve(M.T, Lam[n].T).T)  # Lambda_n (I + T Lambda_n)^-1 = (Lambda_n^-1 + T)^-1
        logdet += math.log(abs(np.linalg.det(M)))
    P = sym(C0i + A.sum(axis=0))
    b = C0i @ m0 + np.einsum("nij,nj->i", A, m)
    cov = sym(np.linalg.inv(P))
    mu = cov @ b
    # log p(m_1..m_N | T) up to a T-free constant: Gaussian in the stacked m with mu integrated out
    quad = float(m0 @ C0i @ m0 + np.einsum("ni,nij,nj->", m, A, m) - mu @ P @ mu)
    ll = -0.5 * (logdet + math.log(np.linalg.det(P)) + quad)
    return mu, cov, ll


def _crossing(f, a: float, b: float) -> float:
    """Where f changes sign between a and b: brentq on the bracket, or (when the inner end is not
    quite inside the interval: the optimiser's tau_hat is approximate) the first sign change on a
    scan from a to b; a when there is none."""
    from scipy import optimize

    fa, fb = f(a), f(b)
    if fa * fb < 0:
        return float(optimize.brentq(f, a, b, xtol=1e-4))
    pts = np.concatenate([[a], np.geomspace(max(a, 1e-4), b, 40)])
    vals = np.array([f(x) for x in pts])
    change = np.flatnonzero(np.sign(vals[:-1]) != np.sign(vals[1:]))
    if change.size == 0:
        return float(a)
    j = int(change[0])
    return float(optimize.brentq(f, pts[j], pts[j + 1], xtol=1e-4))


def random_effects(Lam, eta, prior_mean, prior_cov, m=None, names=None, intervals: bool = True) -> RandomEffects:
    """Gel-level mean, between-bubble sd and predictive from per-experiment likelihoods (module doc).

    Lam (N, d, d), eta (N, d): each experiment's likelihood precision and information (internal
    coordinates); m (N, d) its centre (default Lam^-1 eta); prior_mean (d,), prior_cov (d, d);
    names: parameter names for the notes; ``intervals=False`` skips tau's profile intervals (NaN),
    most of the cost.
    """
    from scipy import optimize

    Lam = np.asarray(Lam, dtype=np.float64)
    N, d = Lam.shape[0], Lam.shape[1]
    m = np.linalg.solve(Lam, np.asarray(eta, dtype=np.float64)[..., None])[..., 0] if m is None else np.asarray(m)
    m0 = np.asarray(prior_mean, dtype=np.float64)
    C0i = np.linalg.inv(sym(prior_cov))
    mu0, cov0, ll0 = _conditional(Lam, m, np.zeros(d), m0, C0i)
    if N < 2:
        return RandomEffects(
            mu0,
            cov0,
            np.full(d, np.nan),
            np.full((d, 2), np.nan),
            cov0,
            mu0,
            cov0,
            0.0,
            N,
            [
                "one experiment: the between-bubble scatter cannot be estimated; the predictive "
                "for another bubble is this bubble's posterior (scatter unknown)"
            ],
        )

    def negll(logtau):
        return -_conditional(Lam, m, np.exp(2.0 * np.asarray(logtau)), m0, C0i)[2]

    lo, hi = math.log(1e-4), math.log(_TAU_MAX)
    best = None
    for start in (math.log(0.03), math.log(0.3)):
        r = optimize.minimize(negll, np.full(d, start), method="L-BFGS-B", bounds=[(lo, hi)] * d)
        if best is None or r.fun < best.fun:
            best = r
    tau = np.exp(best.x)
    tau[tau <= 1.5e-4] = 0.0
    mu, cov, ll_hat = _conditional(Lam, m, tau**2, m0, C0i)
    ll_hat = max(ll_hat, ll0)

    def profile(i, t):
        """max over the other tau of log L with tau_i = t."""
        if d == 1:
            return _conditional(Lam, m, np.array([t * t]), m0, C0i)[2]
        others = [j for j in range(d) if j != i]

        def f(x):
            T = np.empty(d)
            T[i] = t * t
            T[others] = np.exp(2.0 * np.asarray(x))
            return -_conditional(Lam, m, T, m0, C0i)[2]

        x0 = np.log(np.maximum(tau[others], 1e-3))
        return -optimize.minimize(f, x0, method="L-BFGS-B", bounds=[(lo, hi)] * len(others)).fun

    ci = np.full((d, 2), np.nan)
    notes = []
    for i in range(d if intervals else 0):
        # the interval's ends: where the profile drops 3.84/2 below its maximum, each side of tau_hat
        def excess(t, i=i):
            return 2.0 * (ll_hat - profile(i, t)) - _CHI2_95

        inner = max(tau[i], 1e-6)
        lo_end = 0.0 if excess(0.0) <= 0 else _crossing(excess, 0.0, inner)
        if excess(_TAU_MAX) <= 0:
            hi_end = _TAU_MAX
            label = names[i] if names is not None else f"parameter {i}"
            notes.append(
                f"{label}: the data do not bound the between-bubble sd from above (too few bubbles "
                f"or too little information per bubble)"
            )
        else:
            hi_end = _crossing(excess, inner, _TAU_MAX)
        ci[i] = [lo_end, hi_end]
    pred = _predictive_cov(Lam, m, tau, cov, m0, C0i)
    return RandomEffects(mu, cov, tau, ci, pred, mu0, cov0, float(ll_hat - ll0), N, notes)


def _predictive_cov(Lam, m, tau, cov, m0, C0i, n_grid: int = 48, drop: float = 10.0) -> np.ndarray:
    """A new bubble's covariance with each tau_i integrated over its conditional posterior (flat
    prior on [0, _TAU_MAX], the other tau at their estimates), not plugged in at tau_hat.

    With 5-20 bubbles tau_hat is uncertain and biased low, and N(mu_hat, cov + tau_hat^2) held
    only 0.86-0.88 of synthetic bubbles' mu (docs/validation.md, "The predictive with the scatter's
    uncertainty"). Per parameter: the variance of the mixture over tau_i of N(mu_i(tau), cov_ii(tau)
    + tau_i^2) (moment-matched: for the t-like tails of such a mixture the 95 % interval of the
    matched Gaussian is within a few per cent of the mixture's); the off-diagonal entries are the
    plug-in ones (the diagonal only grows, so the matrix stays positive definite)."""
    d = tau.size
    pred = sym(cov + np.diag(tau**2))
    for i in range(d):

        def cond(t, i=i):
            T = tau**2
            T[i] = t * t
            return _conditional(Lam, m, T, m0, C0i)

        ll_top = cond(tau[i])[2]
        hi = max(2.0 * tau[i], 0.02)
        while hi < _TAU_MAX and cond(hi)[2] > ll_top - drop:
            hi = min(2.0 * hi, _TAU_MAX)
        grid = np.linspace(0.0, hi, n_grid)
        mus, variances, lls = np.empty(n_grid), np.empty(n_grid), np.empty(n_grid)
        for k, t in enumerate(grid):
            mu_t, cov_t, ll_t = cond(t)
            mus[k], variances[k], lls[k] = mu_t[i], cov_t[i, i] + t * t, ll_t
        w = np.exp(lls - lls.max())
        w[[0, -1]] *= 0.5  # trapezoid rule on the uniform grid
        w /= w.sum()
        mean_i = float(w @ mus)
        var_i = float(w @ variances + w @ (mus - mean_i) ** 2)
        pred[i, i] = max(pred[i, i], var_i)
    return pred


def leave_one_out(Lam, eta, prior_mean, prior_cov, names=None, prob: float = 0.95) -> dict | None:
    """Leave-one-bubble-out check of the predictive for a new bubble: for every experiment n, the
    random-effects fit of the others, and whether n's own estimate -- the mean of the prior times
    its likelihood, what that bubble alone would report -- lies in the others' central ``prob``
    predictive interval (per parameter, on the internal axes: log for positive parameters). If the
    model of the scatter is right, about ``prob`` of the bubbles do when the scatter is large
    against each bubble's own uncertainty; the predictive does not include that uncertainty, so
    with little scatter (or few bubbles) the check flags more than 1 - ``prob`` (the own estimate,
    not its interval, is held against the others' predictive).

    Lam (N, d, d), eta (N, d) as in :func:`random_effects`; needs N >= 3 (the others must estimate
    a scatter). Returns {"n", "n_inside" (per parameter), "inside" (N lists), "z" (N lists: own
    estimate minus the others' predictive mean, in predictive sd), "level", "note"} or None."""
    from scipy import stats

    Lam = np.asarray(Lam, dtype=np.float64)
    eta = np.asarray(eta, dtype=np.float64)
    N, d = eta.shape
    if N < 3:
        return None
    m0 = np.asarray(prior_mean, dtype=np.float64)
    C0i = np.linalg.inv(sym(prior_cov))
    z = np.empty((N, d))
    for n in range(N):
        keep = [j for j in range(N) if j != n]
        re = random_effects(Lam[keep], eta[keep], m0, prior_cov, intervals=False)
        own_cov = np.linalg.inv(sym(C0i + Lam[n]))
        own = own_cov @ (C0i @ m0 + eta[n])
        z[n] = (own - re.mean) / np.sqrt(np.maximum(np.diag(re.predictive_cov), 1e-300))
    q = float(stats.norm.ppf(0.5 + prob / 2.0))
    inside = np.abs(z) <= q
    labels = list(names) if names is not None else [f"p{i}" for i in range(d)]
    return {
        "n": int(N),
        "level": prob,
        "n_inside": dict(zip(labels, inside.sum(axis=0).astype(int).tolist())),
        "inside": inside.tolist(),
        "z": z.tolist(),
        "parameters": labels,
        "note": f"each experiment's own estimate (prior x its likelihood) against the central {prob:.0%} "
        "predictive interval of the random-effects fit of the others (internal axes)",
    }


@dataclass
class BubbleFusion:
    """The experiments' likelihoods of one parameter space and their random-effects fusion.

    Attributes
    ----------
    space : ParamSpace
        The parameter space (names, log axes, the parameter prior N(m0, C0)).
    lam : ndarray, (n_exp, d, d)
        Each experiment's likelihood precision (internal coordinates).
    eta : ndarray, (n_exp, d)
        Each experiment's likelihood information.
    n_clipped : int
        Negative eigenvalues of the posterior-over-prior precisions clipped to 0 (round-off).
    random : RandomEffects
        Gel-level mean, between-bubble sd and predictive (with the prior the fusion was given).
    """

    space: object
    lam: np.ndarray
    eta: np.ndarray
    n_clipped: int
    random: RandomEffects

    @classmethod
    def from_likelihoods(cls, space, lam, eta, prior=None, n_clipped: int = 0) -> BubbleFusion:
        """Random effects on given likelihoods ``lam`` (n_exp, d, d), ``eta`` (n_exp, d) with the
        gel mean's prior ``prior`` = (mean (d,), cov (d, d)) (None: the parameter prior)."""
        m0, c0 = (space.prior_mean, space.prior_cov) if prior is None else prior
        re = random_effects(lam, eta, m0, c0, names=space.names)
        return cls(space, np.asarray(lam), np.asarray(eta), int(n_clipped), re)

    def own_posteriors(self) -> tuple:
        """Each experiment alone: the parameter prior times its likelihood, (mean (n_exp, d),
        cov (n_exp, d, d))."""
        m0, c0 = self.space.prior_mean, self.space.prior_cov
        cov = np.stack([np.linalg.inv(np.linalg.inv(c0) + L) for L in self.lam])
        mean = np.stack([C @ (np.linalg.solve(c0, m0) + e) for C, e in zip(cov, self.eta)])
        return mean, cov

    def pooled(self) -> Fusion:
        """The product rule (no between-bubble scatter) with the fusion's prior, as a :class:`Fusion`
        whose note counts the clipped eigenvalues."""
        notes = (
            [f"{self.n_clipped} negative eigenvalue(s) of window likelihoods clipped to 0"] if self.n_clipped else []
        )
        return Fusion(self.random.pooled_mean, self.random.pooled_cov, 1.0, self.n_clipped == 0, notes)

    def summaries(self) -> dict:
        """SI ``estimate``, ``between_experiments`` and ``predictive`` (:meth:`RandomEffects.summaries`)."""
        return self.random.summaries(self.space)

    def leave_one_out(self) -> dict | None:
        """:func:`leave_one_out` of these likelihoods under the parameter prior (None: fewer than 3)."""
        return leave_one_out(self.lam, self.eta, self.space.prior_mean, self.space.prior_cov, names=self.space.names)


def fuse_bubbles(space, post_mean, post_cov, start_mean, start_cov, prior=None) -> BubbleFusion:
    """:class:`BubbleFusion` of experiments' posteriors N(post_mean, post_cov) ((n_exp, d),
    (n_exp, d, d)) whose analyses started from N(start_mean, start_cov) (same shapes); ``prior`` =
    (mean, cov): the gel mean's prior (None: the parameter prior)."""
    lam, eta, _, n_clipped = likelihood_terms(post_mean, post_cov, start_mean, start_cov)
    return BubbleFusion.from_likelihoods(space, lam, eta, prior, n_clipped)
