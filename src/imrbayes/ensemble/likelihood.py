"""The observation model of the default likelihood (methods.md §7.1-7.3): each sample once, noise
estimated per record, geometry and alignment inferred as nuisances, residual correlation tempered.

For experiment n with samples y (K,) = R_meas / Rmax_hat at t*_k = k dt* from the estimated
maximum, the forward prediction at parameters theta and the *true* geometry is

    y_k = (1 + a) R*(|t*_k - delta| / (1 + a); theta, Rmax_hat (1 + a), Req_hat e^rho),

with a the relative error of Rmax (it also stretches the time scale t_c = Rmax sqrt(rho/p8)),
delta the time of the true maximum on the data's clock [t*] (samples before it are read from the
mirror image of the collapse, exact to second order at the maximum) and rho the log error of Req.
The nuisances nu = (a, delta, rho) have the preprocessing prior N(0, diag(s^2))
(``Observations.nuisance_sd``: standard errors of the local fit of the maximum and of Req) and are
inferred with the material parameters, nonlinearly (each experiment's augmented ensemble; the
MCMC check samples them too): a timing error of a frame near the collapse, where dR*/dt* is large,
is far outside any linear model, and left fixed it is read as material physics.

``sigma_n^2`` is the record's own noise (fourth differences), raised to the mean squared residual
at the current fit when the model does not reach the noise (model error counts as noise, never as
information). Residuals of a fitted curve are correlated in time; the likelihood is tempered by
alpha_n = n_eff / K with n_eff = K / tau, tau the integrated autocorrelation time of the residual
(``emcee.autocorr.integrated_time``), so that each *independent* observation counts once:

    log L_n = -alpha_n / (2 sigma_n^2) sum_k (y_k - f_k)^2 = -1/2 ||W_n (y - f)||^2,  W_n = sqrt(alpha_n) / sigma_n I.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "LIKELIHOODS",
    "NUISANCES",
    "check_choice",
    "record_noise_sd",
    "simulate_shifted",
    "frame_operator",
    "predict",
    "whitening",
    "effective_samples",
    "observation_model",
    "nuisance_summary",
    "nuisance_prior_sd",
]

#: ``default``: this module; ``paper``: the paper's averaged cost, sample-variance P_k, prior-corrected fusion.
LIKELIHOODS = ("default", "paper")
#: The nuisance quantities (a, delta, rho): relative Rmax error, time of the maximum [t*], log Req error.
NUISANCES = ("rmax_rel", "t0_offset", "log_req")


def check_choice(likelihood: str, fusion, obs_weight) -> None:
    """The likelihood setting of a method, and that ``fusion``/``obs_weight`` (the paper's knobs)
    are only set with ``likelihood="paper"``."""
    from imrbayes.errors import InputError

    if likelihood not in LIKELIHOODS:
        raise InputError("likelihood", f"must be one of {', '.join(LIKELIHOODS)}, got {likelihood!r}")
    if likelihood == "default" and (fusion or obs_weight):
        raise InputError(
            "fusion/obs_weight",
            "apply to --likelihood paper only (the default likelihood counts "
            "each sample once and fuses through a between-bubble layer)",
        )


def nuisance_prior_sd(obs, n: int) -> np.ndarray:
    """Experiment n's prior sds of (a, delta [t*], rho = log Req error) from ``obs.nuisance_sd``."""
    s = np.asarray(obs.nuisance_sd[n], dtype=np.float64)
    return np.array([s[0], s[1], s[2] / float(obs.req_m[n])])


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
    """R* at |t_eval - offset| per member: theta (M, d) SI, rmax_m, req_m, offset (M,), t_eval (K,)
    or (M, K).
    The maximum of member m is at t* = offset_m on the data's clock; samples before it are read
    from the mirror image of the collapse (R*(-s) = R*(s), exact to second order at the maximum).
    Returns (R (M, K), failed (M,))."""
    t = np.asarray(t_eval, dtype=np.float64)
    rows = np.abs(np.atleast_2d(t) - np.asarray(offset, dtype=np.float64)[:, None])
    order = np.argsort(rows, axis=1, kind="stable")
    srt = np.take_along_axis(rows, order, axis=1)
    out = runner.simulate(theta, rmax_m, req_m, srt)
    R = np.empty_like(out.R_star)
    np.put_along_axis(R, order, out.R_star, axis=1)
    return R, out.failed | ~np.all(np.isfinite(R), axis=1)


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


def frame_operator(frame_t, t_grid) -> tuple:
    """How grid values were made from frames by linear interpolation: (tf (F,), ia (K,), w (K,))
    with value_k = (1 - w_k) x[ia_k] + w_k x[ia_k + 1] for x on the frame times tf (only the frames
    the grid needs). ``frame_t`` (increasing, t*), ``t_grid`` (K,) inside its range."""
    tf = np.asarray(frame_t, dtype=np.float64)
    tg = np.asarray(t_grid, dtype=np.float64)
    ia = np.clip(np.searchsorted(tf, tg, side="right") - 1, 0, tf.size - 2)
    w = np.clip((tg - tf[ia]) / (tf[ia + 1] - tf[ia]), 0.0, 1.0)
    last = int(ia.max()) + 2
    return tf[:last], ia, w


def predict(runner, theta, rmax_m: float, req_m: float, t_eval, nu, frames=None) -> tuple:
    """R* at the data's samples for M members: theta (M, d) SI, nu (M, 3) = (a, delta, rho) (module
    doc), t_eval (K,) the data's t*. ``frames`` (:func:`frame_operator`): the data are a linear
    interpolation of camera frames, so the prediction is made at the frame times and interpolated
    the same way (a chord across a sharp collapse is not a point value). Returns (R (M, K), failed (M,))."""
    if frames is not None:
        tf, ia, w = frames
        Rf, failed = predict(runner, theta, rmax_m, req_m, tf, nu)
        return (1.0 - w) * Rf[:, ia] + w * Rf[:, ia + 1], failed
    nu = np.atleast_2d(np.asarray(nu, dtype=np.float64))
    a, delta, rho = nu[:, 0], nu[:, 1], nu[:, 2]
    scale = 1.0 + a
    bad = ~(scale > 0.5) | ~np.all(np.isfinite(nu), axis=1)
    scale = np.where(bad, 1.0, scale)
    req = req_m * np.exp(np.where(bad, 0.0, rho))
    # a member whose Req reaches its Rmax (a wide Req prior's tail) fails; it is not an input error
    bad |= ~(req < rmax_m * scale)
    req = np.where(bad, 0.5 * rmax_m * scale, req)
    R, failed = simulate_shifted(
        runner,
        theta,
        rmax_m * scale,
        req,
        np.asarray(t_eval, dtype=np.float64)[None, :] / scale[:, None],
        delta / scale,
    )
    return R * scale[:, None], failed | bad


def observation_model(y, f, noise_var: float, adapt: bool = True) -> dict:
    """The noise level and tempering of one experiment from its residual y - f (K,) at the current
    fit (``adapt``: raise the variance to the residual's mean square and temper by n_eff / K; else the
    record's noise alone). Returns {"var", "alpha", "effective_samples", "tau", "resid_rms", "noise_sd",
    "W"}; W (K, K) is the whitening sqrt(alpha / var) I."""
    r = np.asarray(y, dtype=np.float64) - np.asarray(f, dtype=np.float64)
    K = r.size
    ok = bool(np.all(np.isfinite(r)))
    rms = float(np.sqrt(np.mean(r * r))) if ok else float("nan")
    var, alpha, n_eff, tau = float(noise_var), 1.0, float(K), 1.0
    if adapt and ok:
        var = max(var, rms * rms)
        n_eff, tau = effective_samples(r)
        alpha = min(1.0, n_eff / K)
    return {
        "var": var,
        "alpha": alpha,
        "effective_samples": n_eff,
        "autocorrelation_time": tau,
        "resid_rms": rms,
        "noise_sd": math.sqrt(noise_var),
        "sd_used": math.sqrt(var),
        "W": whitening(var, np.zeros((K, 0)), alpha),
    }


def nuisance_summary(mean, sd_post, sd_prior, rmax_m: float, req_m: float, t0_s: float, tc_s: float) -> dict:
    """``per_experiment[].nuisance`` in SI from the posterior mean and sd of (a, delta, rho) and
    their prior sds: Rmax [m], the time of the maximum [s] (NaN when the file's clock is unknown),
    Req [m]."""
    m, s, p = (np.asarray(x, dtype=np.float64) for x in (mean, sd_post, sd_prior))
    req = req_m * math.exp(m[2])
    return {
        "rmax_m": {"prior_mean": rmax_m, "prior_sd": rmax_m * p[0], "mean": rmax_m * (1.0 + m[0]), "sd": rmax_m * s[0]},
        "t0_s": {
            "prior_mean": t0_s,
            "prior_sd": tc_s * p[1],
            "mean": t0_s + tc_s * m[1],
            "sd": tc_s * s[1],
            "offset_star": float(m[1]),
            "offset_sd_star": float(s[1]),
            "prior_sd_star": float(p[1]),
        },
        "req_m": {"prior_mean": req_m, "prior_sd": req_m * p[2], "mean": req, "sd": req * s[2]},
        "treatment": "inferred with the material parameters (augmented ensemble); a prior sd of 0 means the "
        "quantity was taken as known",
    }
