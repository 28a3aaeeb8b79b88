"""Across bubbles: a random-effects layer on the experiments' likelihoods (methods.md §7.4).

Each experiment n contributes a Gaussian likelihood of its own parameters theta_n (internal
coordinates z; log for positive parameters): precision Lambda_n, information eta_n (from the
ensemble analysis: posterior / the prior it started from). The gel has a mean mu and a
between-bubble covariance T = diag(tau^2) (tau: the relative bubble-to-bubble sd on log axes):

    theta_n ~ N(mu, T),   mu ~ N(m0, C0)  (the parameter prior).

Integrating theta_n gives m_n ~ N(mu, Lambda_n^-1 + T), i.e. precision A_n(T) = Lambda_n (I + T Lambda_n)^-1.
tau is estimated by maximising the marginal likelihood p(data | tau) with mu integrated against its
prior (type-II maximum likelihood, so tau does not absorb the uncertainty of mu); its 95 % interval
per parameter is the profile-likelihood interval (2 Delta log L <= 3.84, the other tau
re-maximised). Given tau_hat: mu | data ~ N(mu_hat, (C0^-1 + sum A_n)^-1) (the gel-level estimate).
A new bubble's parameters (the predictive): N(mu(tau), cov_mu(tau) + T) mixed over each tau_i's
conditional posterior (flat prior), moment-matched -- not N(mu_hat, cov_mu + T_hat), which with a
handful of bubbles is too narrow. With tau = 0 the gel-level
estimate is the product rule: prior times every likelihood. One experiment: tau cannot be estimated
(reported as unknown).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from imrbayes.ensemble.gaussian import likelihood_terms, marginal_summary, sym

__all__ = ["RandomEffects", "random_effects", "likelihood_terms", "leave_one_out"]

_CHI2_95 = 3.841458820694124
_TAU_MAX = 3.0          # a between-bubble sd of e^3 (20x) on a log axis: beyond any gel


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
                between[name] = {"sd": None, "hdi95": None, "note": "one experiment: bubble-to-bubble scatter "
                                                                     "is unknown"}
                continue
            med = math.exp(self.mean[i]) if log else 1.0

            def to_sd(t):
                # the sd of a bubble's parameter around the gel median (log-normal for a log axis)
                return med * math.sqrt(math.expm1(t * t) * math.exp(t * t)) if log else float(t)
            lo, hi = self.tau_ci[i]
            between[name] = {"sd": to_sd(self.tau[i]), "hdi95": [to_sd(lo), to_sd(hi)],
                             "sd_log" if log else "sd_internal": float(self.tau[i]),
                             "ci95_log" if log else "ci95_internal": [float(lo), float(hi)],
                             "interval": "95 % profile-likelihood interval"}
        return {"estimate": est, "between_experiments": between, "predictive": pred}

    def to_dict(self) -> dict:
        return {"mean_internal": self.mean.tolist(), "cov_internal": self.cov.tolist(), "tau": self.tau.tolist(),
                "tau_ci95": self.tau_ci.tolist(), "predictive_cov_internal": self.predictive_cov.tolist(),
                "pooled_mean_internal": self.pooled_mean.tolist(), "pooled_cov_internal": self.pooled_cov.tolist(),
                "loglik_gain_vs_no_scatter": self.loglik_gain, "n_experiments": self.n_exp, "notes": self.notes,
                "model": "theta_n ~ N(mu, diag(tau^2)) on the internal axes, mu ~ the parameter prior; tau by type-II "
                         "maximum likelihood, 95 % profile intervals"}


def _conditional(Lam, m, T, m0, C0i):
    """mu | data, tau: (mean, cov, log marginal likelihood)."""
    d = m0.size
    A = np.empty_like(Lam)
    logdet = 0.0
    for n in range(Lam.shape[0]):
        M = np.eye(d) + T[:, None] * Lam[n]          # I + T Lambda_n (T diagonal)
        A[n] = sym(np.linalg.solve(M.T, Lam[n].T).T)     # Lambda_n (I + T Lambda_n)^-1 = (Lambda_n^-1 + T)^-1
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
        return RandomEffects(mu0, cov0, np.full(d, np.nan), np.full((d, 2), np.nan), cov0, mu0, cov0, 0.0, N,
                             ["one experiment: the between-bubble scatter cannot be estimated; the predictive "
                              "for another bubble is this bubble's posterior (scatter unknown)"])

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
    mu, cov, ll_hat = _conditional(Lam, m, tau ** 2, m0, C0i)
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
            notes.append(f"{label}: the data do not bound the between-bubble sd from above (too few bubbles "
                         f"or too little information per bubble)")
        else:
            hi_end = _crossing(excess, inner, _TAU_MAX)
        ci[i] = [lo_end, hi_end]
    pred = _predictive_cov(Lam, m, tau, cov, m0, C0i)
    return RandomEffects(mu, cov, tau, ci, pred, mu0, cov0, float(ll_hat - ll0), N, notes)


def _predictive_cov(Lam, m, tau, cov, m0, C0i, n_grid: int = 48, drop: float = 10.0) -> np.ndarray:
    """A new bubble's covariance with each tau_i integrated over its conditional posterior (flat
    prior on [0, _TAU_MAX], the other tau at their estimates), not plugged in at tau_hat.

    With 5-20 bubbles tau_hat is uncertain and biased low, and N(mu_hat, cov + tau_hat^2) held
    only 0.86-0.88 of synthetic bubbles' mu (docs/results.md, "The predictive with the scatter's
    uncertainty"). Per parameter: the variance of the mixture over tau_i of N(mu_i(tau), cov_ii(tau)
    + tau_i^2) (moment-matched: for the t-like tails of such a mixture the 95 % interval of the
    matched Gaussian is within a few per cent of the mixture's); the off-diagonal entries are the
    plug-in ones (the diagonal only grows, so the matrix stays positive definite)."""
    d = tau.size
    pred = sym(cov + np.diag(tau ** 2))
    for i in range(d):
        def cond(t, i=i):
            T = tau ** 2
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
        w[[0, -1]] *= 0.5                         # trapezoid rule on the uniform grid
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
    with little scatter (or few bubbles) the check flags more than 1 - ``prob`` (as #19 defines it:
    the own estimate, not its interval, against the others' predictive).

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
    return {"n": int(N), "level": prob, "n_inside": dict(zip(labels, inside.sum(axis=0).astype(int).tolist())),
            "inside": inside.tolist(), "z": z.tolist(), "parameters": labels,
            "note": f"each experiment's own estimate (prior x its likelihood) against the central {prob:.0%} "
                    "predictive interval of the random-effects fit of the others (internal axes)"}
