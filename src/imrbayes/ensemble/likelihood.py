"""The observation model of the default likelihood (methods.md §7.1-7.3): each sample once, noise
estimated per record, alignment and geometry as nuisances, residual correlation tempered.

For experiment n with samples y (K,) = R_meas / Rmax_hat at t*_k = k dt* from the estimated
maximum, the forward prediction at parameters theta and the *true* geometry is

    y_k = (1 + a) R*(t*_k - delta) / (1 + a))  [Rmax = Rmax_hat (1 + a), maximum at delta t*],

with Req also uncertain. The nuisance vector nu = (a, delta, Req) has the preprocessing prior
N(nu_hat, diag(s^2)) (``Observations.nuisance_sd``). It is integrated out to first order
(the "propagate their uncertainty" option of §7.3): with U = d y / d nu diag(s) (K, 3) by finite
differences at the current parameters,

    y ~ N(f(theta), R),   R = sigma_n^2 I + U U^T,

so a timing error near the collapse (where dR*/dt* is large) is not read as material physics, and an
Rmax error is one correlated shift, not K independent ones. ``sigma_n^2`` is the record's own noise
(fourth differences), raised to the mean squared residual at the current fit when the model does
not reach the noise (model error counts as noise, never as information). Residuals of a fitted
curve are correlated in time; the likelihood is tempered by alpha_n = n_eff / K with n_eff = K / tau
and tau the integrated autocorrelation time of the nuisance-corrected residuals
(``emcee.autocorr.integrated_time``), so each *independent* observation counts once.

Every method with this likelihood minimises ``1/2 ||W_n (y_n - f_n(theta))||^2`` per experiment with
the whitening ``W_n = sqrt(alpha_n) R_n^(-1/2)`` (K, K): the same density the MCMC check samples
(:class:`imrbayes.mcmc.target.WindowTarget` ``whiten``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["LIKELIHOODS", "NUISANCES", "ExperimentLikelihood", "record_noise_sd", "simulate_shifted", "nuisance_directions",
           "whitening", "effective_samples", "experiment_likelihood", "nuisance_summary"]

#: ``default``: this module; ``paper``: the paper's averaged cost, sample-variance P_k, prior-corrected fusion.
LIKELIHOODS = ("default", "paper")
#: The nuisance quantities, in the order of ``Observations.nuisance_sd``.
NUISANCES = ("rmax", "t0", "req")
#: Finite-difference steps: relative Rmax, t*, relative Req.
_STEP = (1e-3, 1e-3, 1e-2)


def record_noise_sd(obs, n: int) -> float:
    """Experiment n's measurement-noise sd in R*: the preprocessing estimate, else one from the
    grid itself (fourth differences of the resampled record)."""
    s = float(obs.noise_sd[n])
    if math.isfinite(s) and s > 0:
        return s
    from imrbayes.data.preprocess import estimate_noise_sd
    s = float(estimate_noise_sd(np.asarray(obs.R_star[n], dtype=np.float64)))
    return s if math.isfinite(s) and s > 0 else 1e-3


def simulate_shifted(runner, theta, rmax_m, req_m, t_eval, offset):
    """R* at |t_eval - offset| per member: theta (M, d) SI, rmax_m, req_m, offset (M,), t_eval (K,).
    The maximum of member m is at t* = offset_m on the data's clock; samples before it are read
    from the mirror image of the collapse (R*(-s) = R*(s), exact to second order at the maximum).
    Returns (R (M, K), failed (M,))."""
    t = np.asarray(t_eval, dtype=np.float64)
    rows = np.abs(t[None, :] - np.asarray(offset, dtype=np.float64)[:, None])
    order = np.argsort(rows, axis=1, kind="stable")
    srt = np.take_along_axis(rows, order, axis=1)
    out = runner.simulate(theta, rmax_m, req_m, srt)
    R = np.empty_like(out.R_star)
    np.put_along_axis(R, order, out.R_star, axis=1)
    return R, out.failed | ~np.all(np.isfinite(R), axis=1)


def nuisance_directions(runner, theta, rmax_m: float, req_m: float, t_eval, sd, offset: float = 0.0) -> tuple:
    """Prediction f (K,) at ``theta`` (d,) SI and U = df/dnu diag(sd) (K, 3) at samples ``t_eval``
    (K,) > 0 with the maximum at t* = ``offset``, in one batch of four forward runs (per-member
    output times). Columns whose sd is 0 are 0. Returns (f, U, ok)."""
    t = np.asarray(t_eval, dtype=np.float64)
    ha, hd, hr = _STEP
    rmax = np.array([rmax_m, rmax_m * (1.0 + ha), rmax_m, rmax_m])
    req = np.array([req_m, req_m, req_m, req_m * (1.0 + hr)])
    # Rmax (1 + a) stretches the time scale: the data's t* are t* / (1 + a) for that member
    times = np.stack([t, t / (1.0 + ha), t, t]) - np.array([0.0, 0.0, hd, 0.0])[:, None] - offset
    R = np.empty((4, t.size))
    failed = np.zeros(4, dtype=bool)
    for i in range(4):       # rows differ in their shift; each is sorted on its own
        R[i:i + 1], failed[i:i + 1] = simulate_shifted(runner, np.asarray(theta, dtype=np.float64)[None], rmax[i:i + 1],
                                                       req[i:i + 1], times[i], np.zeros(1))
    ok = (not np.any(failed)) and bool(np.all(np.isfinite(R)))
    f = R[0]
    sd = np.asarray(sd, dtype=np.float64)
    U = np.zeros((t.size, 3))
    if ok:
        U[:, 0] = ((1.0 + ha) * R[1] - f) / ha * sd[0]
        U[:, 1] = (R[2] - f) / hd * sd[1]
        U[:, 2] = (R[3] - f) / (hr * req_m) * sd[2]
    return f, U, ok


def whitening(var: float, U, alpha: float = 1.0) -> np.ndarray:
    """W = sqrt(alpha) (var I + U U^T)^(-1/2) (K, K), symmetric, from the thin SVD of U (K, r)."""
    U = np.asarray(U, dtype=np.float64)
    K = U.shape[0]
    Q, s, _ = np.linalg.svd(U, full_matrices=False)
    shrink = 1.0 - 1.0 / np.sqrt(1.0 + s * s / var)
    W = np.eye(K) - (Q * shrink) @ Q.T
    return math.sqrt(alpha / var) * W


def effective_samples(resid) -> tuple:
    """(n_eff, tau) of a residual series (K,): tau its integrated autocorrelation time (emcee's
    estimator with Sokal's window; at least 1), n_eff = K / tau."""
    from emcee.autocorr import integrated_time
    r = np.asarray(resid, dtype=np.float64)
    r = r[np.isfinite(r)]
    if r.size < 8 or not np.any(r != r.mean()):
        return float(r.size), 1.0
    tau = float(integrated_time(r - r.mean(), c=5, tol=0, quiet=True)[0])
    tau = max(1.0, tau) if math.isfinite(tau) else float(r.size)
    return r.size / tau, tau


@dataclass
class ExperimentLikelihood:
    """One experiment's observation model at a parameter point (see module doc).

    W (K, K) whitening; var: the noise variance used [R*^2]; noise_var: the record's own estimate;
    alpha: tempering n_eff / K; n_eff, tau; U (K, 3) nuisance directions; f (K,) prediction at
    the point; resid_rms: RMS of the nuisance-corrected residual; nu_mean (3,), nu_cov (3, 3): the
    standardised nuisances' conditional posterior at the point; ok: the four runs succeeded.
    """

    W: np.ndarray
    var: float
    noise_var: float
    alpha: float
    n_eff: float
    tau: float
    U: np.ndarray
    f: np.ndarray
    resid_rms: float
    nu_mean: np.ndarray
    nu_cov: np.ndarray
    ok: bool

    def to_dict(self) -> dict:
        return {"noise_sd": math.sqrt(self.noise_var), "sd_used": math.sqrt(self.var), "alpha": self.alpha,
                "effective_samples": self.n_eff, "autocorrelation_time": self.tau, "resid_rms": self.resid_rms}


def experiment_likelihood(runner, theta, rmax_m, req_m, t_eval, y, sd, noise_var: float,
                          adapt: bool = True, offset: float = 0.0) -> ExperimentLikelihood:
    """The observation model of one experiment at ``theta`` (SI, d): nuisance directions, the noise
    variance (``adapt``: raised to the corrected residual's mean square), the tempering from the
    residual's autocorrelation (``adapt``; else alpha = 1) and the whitening."""
    y = np.asarray(y, dtype=np.float64)
    K = y.size
    f, U, ok = nuisance_directions(runner, theta, rmax_m, req_m, t_eval, sd, offset)
    if not ok:
        U = np.zeros((K, 3))
        f = np.full(K, np.nan)
    r = y - f
    var = float(noise_var)
    nu_cov = np.linalg.inv(np.eye(3) + U.T @ U / var)
    nu_mean = nu_cov @ (U.T @ np.nan_to_num(r) / var)
    rc = r - U @ nu_mean
    rms = float(np.sqrt(np.mean(rc ** 2))) if ok else float("nan")
    alpha, n_eff, tau = 1.0, float(K), 1.0
    if adapt and ok:
        var = max(var, rms ** 2)
        n_eff, tau = effective_samples(rc)
        alpha = min(1.0, n_eff / K)
        nu_cov = np.linalg.inv(np.eye(3) + alpha * U.T @ U / var)
        nu_mean = nu_cov @ (alpha * U.T @ r / var)
    return ExperimentLikelihood(whitening(var, U, alpha), var, float(noise_var), alpha, n_eff, tau, U, f, rms,
                                nu_mean, nu_cov, ok)


def nuisance_summary(lik: ExperimentLikelihood, sd, rmax_m: float, req_m: float, t0_s: float, tc_s: float) -> dict:
    """``per_experiment[].nuisance`` (SI): prior and conditional posterior of Rmax [m], the time of
    the maximum [s] (NaN when the file's clock is unknown) and Req [m]."""
    sd = np.asarray(sd, dtype=np.float64)
    m, C = lik.nu_mean, lik.nu_cov
    post_sd = np.sqrt(np.clip(np.diag(C), 0.0, None)) * sd
    shift = m * sd
    out = {"rmax_m": {"prior_mean": rmax_m, "prior_sd": rmax_m * sd[0], "mean": rmax_m * (1.0 + shift[0]),
                      "sd": rmax_m * post_sd[0]},
           "t0_s": {"prior_mean": t0_s, "prior_sd": tc_s * sd[1], "mean": t0_s + tc_s * shift[1],
                    "sd": tc_s * post_sd[1], "offset_star": float(shift[1])},
           "req_m": {"prior_mean": req_m, "prior_sd": sd[2], "mean": req_m + shift[2], "sd": post_sd[2]},
           "treatment": "integrated out to first order about the preprocessing estimate (conditional posterior "
                        "at the experiment's fitted parameters); a prior sd of 0 means the quantity was not "
                        "uncertain in the data"}
    return out
