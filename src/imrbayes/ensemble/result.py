"""The common result of every method (what ``imrbayes fit`` writes) and small shared helpers."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from imrbayes.ensemble.gaussian import marginal_summary

__all__ = ["FitResult", "WindowPosterior", "gaussian_estimate", "si_covariance", "rmse", "loglik_pointwise"]


@dataclass
class WindowPosterior:
    """One window's Gaussian posterior and the density it approximates, recorded by the method as
    it used them (what :mod:`imrbayes.mcmc` samples to check the Gaussian; nothing is re-derived).

    The density is ``-1/2 sum_n sum_k weight_k (y_nk - R_nk(z))^2 / P_k + log N(z; prior_mean,
    prior_cov)`` over samples ``samples[0]..samples[1]`` of the observation grid, every experiment
    n run from ``start_state[n]`` at sample ``start`` with constant parameters z.

    Attributes
    ----------
    index : int
        Window number (0 for a method with one fitting window).
    start : int
        Sample at which the forward runs start (the state's time t*[start]).
    samples : (int, int)
        First and last (inclusive) sample whose observations the window's cost holds.
    mean, cov : (d,), (d, d)
        The method's (fused) Gaussian posterior, internal coordinates (:class:`ParamSpace`).
    prior_mean, prior_cov : (d,), (d, d)
        The parameter prior of the window, internal coordinates (MIEnKS-MDA ``fusion="chain"``:
        the previous window's fused posterior after RTPS).
    weight : (samples[1] - samples[0] + 1,)
        Observation weight c_k (En4D-Var 1/N_t; MIEnKS-MDA beta_jk / L).
    start_state : (n_exp, n_state)
        Each experiment's dimensionless forward state at t*[start] (MIEnKS-MDA: the mean of its
        handed-off ensemble); NaN rows: experiments left out of the window.
    description : dict
        How the density is stated (kind, weight rule, ``state`` = where the start state comes from),
        carried into the MCMC target's description.
    whiten : (n_exp, m, m) or None
        The default likelihood (:mod:`imrbayes.ensemble.likelihood`): the density's likelihood is
        ``-1/2 sum_n ||W_n (y_n - R_n(z))||^2`` over the window's samples instead of the weighted
        sum above (NaN rows: experiments left out).
    nuisance_sd, nuisance_mean, nuisance_post_sd : (n_exp, 3) or None
        Each experiment's nuisances (a, delta, rho) of :mod:`imrbayes.ensemble.likelihood`, sampled
        with the parameters: prior sd (0: not sampled), and the method's posterior mean and sd (to
        start MCMC walkers).
    frames : list or None
        Per experiment, how the grid values interpolate camera frames
        (:func:`imrbayes.ensemble.likelihood.frame_operator`); the prediction is interpolated alike.
    start_req_m : (n_exp,) or None
        The equilibrium radius [m] each experiment's start state goes with (MIEnKS-MDA's default
        likelihood analyses Req: the handed-off ensemble's mean); None: the preprocessing's.
    """

    index: int
    start: int
    samples: tuple
    mean: np.ndarray
    cov: np.ndarray
    prior_mean: np.ndarray
    prior_cov: np.ndarray
    weight: np.ndarray
    start_state: np.ndarray
    description: dict = field(default_factory=dict)
    whiten: np.ndarray | None = None
    nuisance_sd: np.ndarray | None = None
    nuisance_mean: np.ndarray | None = None
    nuisance_post_sd: np.ndarray | None = None
    frames: list | None = None
    start_req_m: np.ndarray | None = None

    def start_gaussian(self, prior: bool = False):
        """(mean, cov) over the sampled coordinates: the parameters' Gaussian (or prior), then every
        experiment's sampled nuisances (posterior or prior), independent."""
        m, C = (self.prior_mean, self.prior_cov) if prior else (self.mean, self.cov)
        m, C = np.asarray(m, float), np.asarray(C, float)
        if self.nuisance_sd is None:
            return m, C
        sd0 = np.asarray(self.nuisance_sd, float)
        use = np.isfinite(sd0) & (sd0 > 0)
        om = np.zeros(int(use.sum())) if prior else np.nan_to_num(np.asarray(self.nuisance_mean, float)[use])
        osd = sd0[use] if prior else np.asarray(self.nuisance_post_sd, float)[use]
        osd = np.where(np.isfinite(osd) & (osd > 0), osd, sd0[use])
        d = m.size
        full = np.zeros((d + om.size, d + om.size))
        full[:d, :d] = C
        full[d:, d:] = np.diag(osd**2)
        return np.concatenate([m, om]), full


@dataclass
class FitResult:
    """What a method found.

    Attributes
    ----------
    method, model : str
    param_names : tuple of str
    estimate : dict name -> {"mean", "sd", "hdi95", ...} in SI units (interfaces.md §3)
    mean_internal, cov_internal : (n_p,), (n_p, n_p) Gaussian in the internal coordinates
        (log for positive parameters), or None for methods without one.
    fitted : (n_exp, n) fitted R* on the observation grid (NaN where not fitted)
    fit_mask : (n_exp, n) bool, the samples the method fitted
    rmse : root-mean-square of fitted - measured R* over the fitted samples
    n_fit_samples : number of (experiment, sample) pairs fitted
    per_experiment : list of dicts (name, estimate or optimum, ...)
    windows, time_resolved : lists for ``mienks`` (interfaces.md §3), else None
    details : method settings, diagnostics, failure counts (JSON-able)
    posterior : dict var -> array (chain, draw, ...) for posterior.nc; ``posterior_dims`` its dims
    log_likelihood : dict var -> array (chain, draw, experiment, time) or None
    extra_groups : dict group -> {var: array}; ``extra_dims`` dims of those variables
    coords : coordinates for posterior.nc
    runtime_s : wall time of the method [s]
    warnings : list of str
    window_posteriors : list of :class:`WindowPosterior` or None, not written to summary.json:
        the Gaussian posterior of every window with the prior, observation weights and start
        states the method used (methods with ``gaussian_posterior``: what ``--mcmc`` checks)
    """

    method: str
    model: str
    param_names: tuple
    estimate: dict
    fitted: np.ndarray
    fit_mask: np.ndarray
    mean_internal: np.ndarray | None = None
    cov_internal: np.ndarray | None = None
    per_experiment: list = field(default_factory=list)
    windows: list | None = None
    time_resolved: list | None = None
    details: dict = field(default_factory=dict)
    posterior: dict = field(default_factory=dict)
    posterior_dims: dict = field(default_factory=dict)
    log_likelihood: dict | None = None
    extra_groups: dict = field(default_factory=dict)
    extra_dims: dict = field(default_factory=dict)
    coords: dict = field(default_factory=dict)
    runtime_s: float = float("nan")
    warnings: list = field(default_factory=list)
    window_posteriors: list | None = None

    @property
    def rmse(self) -> float:
        return float(self.details.get("rmse", float("nan")))

    @property
    def n_fit_samples(self) -> int:
        return int(np.count_nonzero(self.fit_mask))


def gaussian_estimate(space, mean, cov) -> dict:
    """SI summaries of the marginals of N(mean, cov) in internal coordinates (see ParamSpace)."""
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return {n: marginal_summary(mean[i], sd[i], bool(space.positive[i])) for i, n in enumerate(space.names)}


def si_covariance(space, mean, cov) -> np.ndarray:
    """SI covariance of theta when z = (log-)theta ~ N(mean, cov) (log-normal moments for log axes)."""
    mean, cov = np.asarray(mean, dtype=np.float64), np.asarray(cov, dtype=np.float64)
    n = mean.size
    out = np.empty((n, n))
    lg = space.positive
    E = np.where(lg, np.exp(mean + 0.5 * np.diag(cov)), mean)
    for i in range(n):
        for j in range(n):
            if lg[i] and lg[j]:
                out[i, j] = E[i] * E[j] * math.expm1(cov[i, j])
            elif lg[i] or lg[j]:
                k = i if lg[i] else j
                out[i, j] = E[k] * cov[i, j]  # Cov(exp(a), b) = E[exp a] Cov(a, b) for a Gaussian pair
            else:
                out[i, j] = cov[i, j]
    return out


def rmse(fitted, measured, mask) -> float:
    r = (np.asarray(fitted) - np.asarray(measured))[mask]
    r = r[np.isfinite(r)]
    return float(np.sqrt(np.mean(r * r))) if r.size else float("nan")


def loglik_pointwise(Yhat, y, P):
    """Gaussian log-likelihood per sample: -1/2 [log(2 pi P_k) + (y - Yhat)^2 / P_k] (broadcasts)."""
    return -0.5 * (np.log(2.0 * np.pi * P) + (y - Yhat) ** 2 / P)
