"""Ensemble 4D-Var with constant parameters over one window (methods.md §3).

Per experiment n (all experiments in one forward batch per iteration):

1. draw N_En members z ~ N(m, C) in the internal coordinates (log G, log mu): the prior in cycle 1,
   the RTPS-inflated posterior in later cycles (``exact_moments``: the draw is affinely corrected
   to have exactly that sample mean and covariance);
2. N_iter ensemble-space Gauss–Newton iterations (:mod:`imrbayes.ensemble.gn`) on
   J(w) = 1/(2 N_t) sum_k ||y_k - <Y_k> - Y'_k w||^2_{P_k} + 1/2 w^T w over samples k = 1..N_t
   (sample 0, R* = 1 by construction, carries no information);
3. RTPS, sigma = sigma_post + a (sigma_prior - sigma_post) per parameter, correlations kept;
4. repeat from 1 for N_runs cycles.

Fusion of the experiments (``fusion``). ``prior`` (default, methods.md §3): the last cycle's
(un-inflated) posteriors N(m_n, S_n) by the prior-corrected product rule with the original prior
N(m0, S0) (:func:`imrbayes.ensemble.gaussian.fuse`, with its positive-definiteness guard), i.e.
each posterior's whole gain over the prior (all cycles) counts as that experiment's likelihood.
``likelihood``: only the last cycle's likelihood (its posterior divided by the prior that cycle
started from) times the original prior (:func:`imrbayes.ensemble.gaussian.fuse_likelihoods`).
With one cycle the two are identical. They differ with restarts, and with many experiments the
``prior`` rule can extrapolate: on the 20 Estrada et al. records it gave G = 12.6 kPa,
mu = 0.019 Pa s, outside the range of every experiment's own posterior (G 5.6-12.5 kPa,
mu 0.023-0.088 Pa s), where ``likelihood`` gave 9.3 kPa, 0.043 Pa s (the IMR least-squares optimum
is 9.7 kPa, 0.032 Pa s). On the §5 verification case (weak, tempered data) ``prior`` is closer to
the truth (7.0 kPa, 0.091 Pa s vs 8.0 kPa, 0.135 Pa s), since ``likelihood`` keeps a single
tempered copy of each likelihood. docs/results.md reports both.

Positive parameters live in log space throughout, so nothing is clipped; the reported SI
estimate is the log-normal marginal of the fused Gaussian.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from imrbayes.ensemble.gaussian import draw, fuse, fuse_likelihoods, rtps
from imrbayes.ensemble.gn import gauss_newton
from imrbayes.ensemble.result import FitResult, gaussian_estimate, loglik_pointwise, rmse, si_covariance
from imrbayes.ensemble.runner import Runner
from imrbayes.errors import InputError

__all__ = ["En4DVarSettings", "fit_en4dvar"]


@dataclass
class En4DVarSettings:
    """En4D-Var settings (paper values by default).

    n_ens: members per experiment; n_iter: Gauss–Newton iterations per cycle; n_runs: cycles
    (restarts); rtps: relaxation-to-prior-spread factor a; t_end: last fitted t* (None = whole
    record); exact_moments: see module doc; n_draws: draws of the fused posterior written to
    posterior.nc (with their pointwise log-likelihood if ``loglik``).
    """

    n_ens: int = 48
    n_iter: int = 5
    n_runs: int = 3
    rtps: float = 0.7
    t_end: float | None = None
    exact_moments: bool = True
    n_draws: int = 48
    loglik: bool = True
    fusion: str = "prior"

    def check(self):
        if self.n_ens < 3:
            raise InputError("n_ens", f"needs at least 3 members, got {self.n_ens}")
        if self.n_iter < 1 or self.n_runs < 1:
            raise InputError("n_iter/n_runs", "must be at least 1")
        if not 0.0 <= self.rtps <= 1.0:
            raise InputError("rtps", f"the RTPS factor must lie in [0, 1], got {self.rtps}")
        if self.fusion not in ("likelihood", "prior"):
            raise InputError("fusion", f"must be 'likelihood' or 'prior', got {self.fusion!r}")
        if self.n_draws < 1:
            raise InputError("n_draws", f"needs at least one posterior draw, got {self.n_draws}")


def fit_window(obs, K: int):
    """Samples 1..K (inclusive) of the grid: observation vector (n_exp, K) and weights 1/(K P_k)."""
    y = obs.R_star[:, 1:K + 1]
    weight = 1.0 / (K * obs.P[1:K + 1])
    return y, weight


def last_index(obs, t_end) -> int:
    if t_end is None:
        return obs.n_samples - 1
    K = int(np.searchsorted(obs.t_star, float(t_end) + 1e-9, side="right") - 1)
    if K < 2:
        raise InputError("t_end", f"fitting window t* <= {t_end} holds fewer than two samples")
    return K


def fit_en4dvar(fm, obs, space, settings: En4DVarSettings | None = None, seed: int = 0,
                runner: Runner | None = None, progress=None) -> FitResult:
    """Fit constant parameters to every experiment and fuse (see module doc).

    fm : ForwardModel; obs : Observations; space : ParamSpace; seed: numpy default_rng seed.
    Returns a :class:`FitResult` with per-experiment posteriors in ``per_experiment``.
    """
    s = settings or En4DVarSettings()
    s.check()
    t0 = time.perf_counter()
    runner = runner or Runner(fm)
    rng = np.random.default_rng(seed)
    K = last_index(obs, s.t_end)
    t_eval = obs.t_star[:K + 1]
    y, weight = fit_window(obs, K)
    n_exp, N, d = obs.n_exp, s.n_ens, space.n

    def evaluate(groups, Z):
        params = space.to_si(Z)
        out = runner.simulate(params, obs.rmax_m[groups], obs.req_m[groups], t_eval)
        return out.R_star[:, 1:], out.failed | ~np.all(np.isfinite(out.R_star), axis=1)

    mean = np.broadcast_to(space.prior_mean, (n_exp, d)).copy()
    cov = np.broadcast_to(space.prior_cov, (n_exp, d, d)).copy()
    cycles = []
    res = None
    for r in range(s.n_runs):
        E0 = np.stack([draw(rng, mean[n], cov[n], N, exact=s.exact_moments) for n in range(n_exp)])
        res = gauss_newton(E0, evaluate, y, weight, n_iter=s.n_iter, rng=rng)
        infl = rtps(res.prior_anoms, res.anoms, s.rtps)
        mean = res.mean.copy()
        cov = np.einsum("gnd,gne->gde", infl, infl)
        cycles.append({"cycle": r + 1, "cost": res.cost.tolist(), "n_failed": res.n_failed.tolist(),
                       "n_redrawn": res.n_redrawn.tolist(), "stopped": res.stopped.tolist()})
        if progress is not None:
            progress(r + 1)
    post_mean, post_cov = res.mean, res.cov
    if s.fusion == "prior":
        fus = fuse(post_mean, post_cov, space.prior_mean, space.prior_cov)
    else:
        qa = res.prior_anoms
        fus = fuse_likelihoods(post_mean, post_cov, res.prior_ensemble.mean(axis=1),
                               np.einsum("gnd,gne->gde", qa, qa), space.prior_mean, space.prior_cov)
    warnings = []
    if fus.notes:
        warnings.extend(fus.notes)
    if np.any(res.stopped):
        warnings.append(f"{int(res.stopped.sum())} experiment(s) stopped early: too many failed members")
    # fitted curves at the fused median (exp of the fused mean) and at each experiment's own mean
    pts = np.vstack([np.repeat(space.to_si(fus.mean)[None, :], n_exp, axis=0), space.to_si(post_mean)])
    out = runner.simulate(pts, np.tile(obs.rmax_m, 2), np.tile(obs.req_m, 2), t_eval)
    fitted = np.full_like(obs.R_star, np.nan)
    fitted[:, :K + 1] = out.R_star[:n_exp]
    own = np.full_like(obs.R_star, np.nan)
    own[:, :K + 1] = out.R_star[n_exp:]
    mask = np.zeros(obs.R_star.shape, dtype=bool)
    mask[:, 1:K + 1] = True
    per = []
    for n in range(n_exp):
        per.append({"name": obs.names[n], "estimate": gaussian_estimate(space, post_mean[n], post_cov[n]),
                    "mean_internal": post_mean[n].tolist(), "cov_internal": post_cov[n].tolist(),
                    "rmse_own": rmse(own[n], obs.R_star[n], mask[n])})
    # posterior draws (1 chain) of the fused Gaussian, with their pointwise log-likelihood
    Zd = draw(rng, fus.mean, fus.cov, s.n_draws, exact=False)
    post = {nm: space.to_si(Zd)[None, :, i] for i, nm in enumerate(space.names)}
    ll = None
    if s.loglik and s.n_draws > 0:
        th = np.repeat(space.to_si(Zd), n_exp, axis=0)
        o = runner.simulate(th, np.tile(obs.rmax_m, s.n_draws), np.tile(obs.req_m, s.n_draws), t_eval)
        Yd = o.R_star[:, 1:].reshape(s.n_draws, n_exp, K)
        lp = loglik_pointwise(Yd, y[None], obs.P[1:K + 1])
        ll = {"R": np.where(np.isfinite(lp), lp, -1e300)[None]}
    details = {"settings": asdict(s), "n_fit_steps": K, "t_end_star": float(obs.t_star[K]),
               "cycles": cycles, "fusion": fus.to_dict(), "rmse": rmse(fitted, obs.R_star, mask),
               "fused_mean_internal": fus.mean.tolist(), "fused_cov_internal": fus.cov.tolist(),
               "fused_cov_si": si_covariance(space, fus.mean, fus.cov).tolist(),
               "parameter_space": space.describe(),
               "member_runs": runner.n_member_runs, "failed_member_runs": runner.n_failed,
               "gauss_newton": "normalised anomalies: H = I + (1/N_t) sum Y'^T P^-1 Y', grad = w - ...; identical "
                               "iterates to methods.md's (N_En - 1) form with unnormalised anomalies",
               "fitted_curve": "forward run at the fused posterior median exp(mean of log parameters)"}
    return FitResult(
        method="en4dvar", model=fm.constitutive.name, param_names=tuple(space.names),
        estimate=gaussian_estimate(space, fus.mean, fus.cov), fitted=fitted, fit_mask=mask,
        mean_internal=fus.mean, cov_internal=fus.cov, per_experiment=per, details=details,
        posterior=post, log_likelihood=ll, posterior_dims={"R": ["experiment", "time"]},
        coords={"experiment": list(obs.names), "time": obs.t_star[1:K + 1]},
        runtime_s=time.perf_counter() - t0, warnings=warnings)
