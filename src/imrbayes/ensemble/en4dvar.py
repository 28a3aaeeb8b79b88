"""Ensemble 4D-Var with constant parameters over one window (methods.md §3).

Per experiment n (all experiments in one forward batch per iteration):

1. draw N_En members z ~ N(m, C) in the internal coordinates (log G, log mu), with exactly that
   sample mean and covariance: the prior in cycle 1, the RTPS-inflated posterior in later cycles;
2. N_iter ensemble-space Gauss–Newton iterations (:mod:`imrbayes.ensemble.gn`) on
   J(w) = 1/(2 N_t) sum_k ||y_k - <Y_k> - Y'_k w||^2_{P_k} + 1/2 w^T w over samples k = 1..N_t
   (sample 0, R* = 1 by construction, carries no information);
3. RTPS, sigma = sigma_post + a (sigma_prior - sigma_post) per parameter, correlations kept;
4. repeat from 1 for N_runs cycles.

Screened start (``screen``, default likelihood only): before cycle 1, the prior mean and ``screen``
prior draws are run once (:func:`screened_start`); when a draw has a lower posterior cost, cycle 1
runs from both and goes on from the end with the lower posterior cost under the original prior
(:func:`posterior_cost`). Iterations to convergence (``max_iter``, default likelihood only): every
cycle iterates past its ``n_iter`` while the Gauss-Newton cost still falls by 1 % per iteration.
The cycles after the first run at least ``n_iter_later`` iterations (evidence: docs/validation.md).

Fusion of the experiments (:mod:`imrbayes.ensemble.fusion`). Default likelihood: each
experiment's likelihood (last posterior / the prior its last cycle started from, log Req
integrated against its preprocessing prior) enters the random-effects layer. Paper's likelihood
(``fusion``): ``prior``, the prior-corrected product rule with the original prior, or
``likelihood``, each last cycle's likelihood times the original prior. ``obs_weight``: ``mean``
averages the misfit over the N_t samples (methods.md §3), ``sum`` counts every sample.

Positive parameters live in log space throughout, so nothing is clipped; the reported SI
estimate is the log-normal marginal of the fused Gaussian.

Stages: :func:`fit_en4dvar` (Req's prior by the model's tail, then) :func:`en4dvar_pass`, which
runs :func:`en4dvar_unit` per experiment (draws its members: :func:`run_cycles`), fuses, and runs
:func:`en4dvar_post_unit` per experiment for the fitted curves.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, fields, replace

import numpy as np

from imrbayes.ensemble.fusion import fuse, fuse_bubbles, fuse_likelihoods, marginal_under_reference
from imrbayes.ensemble.gaussian import draw, rtps
from imrbayes.ensemble.gn import gauss_newton
from imrbayes.ensemble.likelihood import (
    check_choice,
    frame_operator,
    nuisance_prior_sd,
    nuisance_summary,
    observation_model,
    predict,
    record_noise_sd,
)
from imrbayes.ensemble.method import InferenceMethod
from imrbayes.ensemble.req_tail import REQ_CONFLICT_Z, ReqTailStart, model_tail_req, tail_req, with_req
from imrbayes.ensemble.result import (
    FitResult,
    WindowPosterior,
    gaussian_estimate,
    loglik_pointwise,
    rmse,
    si_covariance,
)
from imrbayes.errors import InputError
from imrbayes.execution import Execution, Unit, unit_id
from imrbayes.forward import Runner, fm_spec, register_runner, runner_for

__all__ = [
    "En4DVar",
    "En4DVarSettings",
    "fit_en4dvar",
    "en4dvar_pass",
    "en4dvar_unit",
    "en4dvar_post_unit",
    "run_cycles",
    "fitting_window_posterior",
]


#: members per experiment: the default likelihood's, and the paper's (``likelihood="paper"``)
DEFAULT_N_ENS, PAPER_N_ENS = 24, 48
#: Gauss-Newton iterations (at least) of the cycles after the first with the default likelihood:
#: they start near the optimum (docs/validation.md, "Fewer iterations after the first cycle")
DEFAULT_N_ITER_LATER = 3
REQ_TAILS = ("auto", "mean", "inline")


@dataclass
class En4DVarSettings:
    """En4D-Var settings (``--set KEY=VALUE``); the paper's values with ``likelihood="paper"``."""

    n_ens: int | None = None
    """Members per experiment; None: 24 (the paper's 48 with ``likelihood="paper"``)."""
    n_iter: int = 5
    """Gauss–Newton iterations of the first cycle (at least, with the default likelihood); 5."""
    n_iter_later: int | None = None
    """Gauss–Newton iterations of the later cycles; None: 3 (``n_iter`` with the paper's likelihood)."""
    n_runs: int = 3
    """Cycles (restarts from the inflated posterior); 3."""
    rtps: float = 0.7
    """Relaxation-to-prior-spread factor a in [0, 1] between cycles; 0.7."""
    t_end: float | None = None
    """Last fitted t*; None: the whole record."""
    n_draws: int = 48
    """Draws of the reported posterior written to posterior.nc; 48."""
    loglik: bool = True
    """Write each draw's pointwise log-likelihood to posterior.nc; true."""
    fusion: str | None = None
    """Paper's likelihood: ``prior`` (product rule with the original prior) or ``likelihood``; None: ``prior``."""
    obs_weight: str | None = None
    """Paper's likelihood: the misfit averaged over the samples (``mean``) or summed (``sum``); None: ``mean``."""
    likelihood: str = "default"
    """``default`` (methods.md §7: estimated noise, nuisances, random effects) or ``paper``; default."""
    screen: int = 96
    """Prior draws screened for the first cycle's start (0: the prior mean; default likelihood); 96."""
    max_iter: int = 15
    """Most Gauss–Newton iterations of a cycle whose cost still falls by 1 % (default likelihood); 15."""
    req_tail: str = "auto"
    """Req's prior centre: ``mean`` (the record's tail), ``inline`` (moved by the model's tail after cycle 1) or ``auto`` (inline with the thermal bubble); auto."""
    req_conflict_stop: float | None = None
    """Skip an experiment's later cycles once its Req lies this many prior sd from its record's; None: never."""

    def resolved(self) -> En4DVarSettings:
        """The settings with the likelihood's own choices filled in (``paper``: averaged cost and the
        prior-corrected fusion unless set) and the members per experiment (24; the paper's 48)."""
        if self.likelihood == "paper":
            return replace(
                self,
                fusion=self.fusion or "prior",
                obs_weight=self.obs_weight or "mean",
                n_ens=PAPER_N_ENS if self.n_ens is None else self.n_ens,
                n_iter_later=self.n_iter if self.n_iter_later is None else self.n_iter_later,
            )
        return replace(
            self,
            n_ens=DEFAULT_N_ENS if self.n_ens is None else self.n_ens,
            n_iter_later=(min(DEFAULT_N_ITER_LATER, self.n_iter) if self.n_iter_later is None else self.n_iter_later),
        )

    def check(self):
        """Raise :class:`~imrbayes.errors.InputError` naming the first setting out of range."""
        check_choice(self.likelihood, self.fusion, self.obs_weight)
        s = self.resolved()
        if s.n_ens < 3:
            raise InputError("n_ens", f"needs at least 3 members, got {s.n_ens}")
        if self.n_iter < 1 or self.n_runs < 1:
            raise InputError("n_iter/n_runs", "must be at least 1")
        if self.n_iter_later is not None and not 1 <= self.n_iter_later <= self.n_iter:
            raise InputError("n_iter_later", f"must lie between 1 and n_iter ({self.n_iter}), got {self.n_iter_later}")
        if not 0.0 <= self.rtps <= 1.0:
            raise InputError("rtps", f"the RTPS factor must lie in [0, 1], got {self.rtps}")
        if s.likelihood == "paper" and s.fusion not in ("likelihood", "prior"):
            raise InputError("fusion", f"must be 'likelihood' or 'prior', got {s.fusion!r}")
        if s.likelihood == "paper" and s.obs_weight not in ("mean", "sum"):
            raise InputError("obs_weight", f"must be 'mean' or 'sum', got {s.obs_weight!r}")
        if self.n_draws < 1:
            raise InputError("n_draws", f"needs at least one posterior draw, got {self.n_draws}")
        if self.max_iter < self.n_iter and self.likelihood == "default":
            raise InputError("max_iter", f"must be at least n_iter ({self.n_iter}), got {self.max_iter}")
        if self.screen < 0:
            raise InputError("screen", f"must be 0 (off) or a number of prior draws, got {self.screen}")
        if self.req_tail not in REQ_TAILS:
            raise InputError("req_tail", f"must be 'auto', 'mean' or 'inline', got {self.req_tail!r}")
        if self.req_tail == "inline" and s.likelihood != "default":
            raise InputError("req_tail", "'inline' needs the default likelihood (the paper's takes Req as known)")
        if self.req_conflict_stop is not None and not (
            np.isfinite(self.req_conflict_stop) and self.req_conflict_stop > 0
        ):
            raise InputError(
                "req_conflict_stop", f"must be a positive number of prior sd or None, got {self.req_conflict_stop!r}"
            )


def req_tail_mode(settings: En4DVarSettings, fm) -> str:
    """``mean`` or ``inline``: what ``settings.req_tail`` means for forward model ``fm``. ``auto`` is
    ``inline`` with the thermal bubble and the default likelihood (its record's tail mean is high,
    docs/validation.md), ``mean`` otherwise. (:func:`fit_en4dvar` runs ``inline`` as the two-pass
    ``model`` when given a start or one cycle.)"""
    s = settings.resolved()
    if s.req_tail != "auto":
        return s.req_tail
    thermal = getattr(getattr(fm, "options", None), "bubble", "thermal") == "thermal"
    return "inline" if thermal and s.likelihood == "default" else "mean"


#: the first pass that places the material for the model's tail when ``inline`` cannot run in one
#: pass (one cycle, no start given): one cycle from the prior mean (docs/validation.md)
REQ_TAIL_FIRST_PASS = {"n_runs": 1, "screen": 0, "n_draws": 1, "loglik": False}


def fit_window(obs, K: int, obs_weight: str = "mean"):
    """Samples 1..K (inclusive) of the grid: observation vector (n_exp, K) and weights 1/(K P_k)
    (``obs_weight="mean"``, methods.md's averaged cost) or 1/P_k (``"sum"``, every sample a full
    independent observation)."""
    y = obs.R_star[:, 1 : K + 1]
    weight = 1.0 / ((K if obs_weight == "mean" else 1.0) * obs.P[1 : K + 1])
    return y, weight


def last_index(obs, t_end) -> int:
    """Index K of the last fitted sample (t* <= ``t_end``; None: the record's last)."""
    if t_end is None:
        return obs.n_samples - 1
    K = int(np.searchsorted(obs.t_star, float(t_end) + 1e-9, side="right") - 1)
    if K < 2:
        raise InputError("t_end", f"fitting window t* <= {t_end} holds fewer than two samples")
    return K


class _Bubble:
    """One experiment's forward map from internal coordinates (parameters, then the active
    nuisances (a, delta, rho) with the default likelihood) to R* at samples 1..K.

    ``req`` may move (``req_tail=inline``); every evaluation after the move runs at the new Req."""

    def __init__(self, d, runner, default: bool):
        self.runner, self.space, self.default = runner, d["space"], default
        self.rmax, self.req, self.t_eval, self.frames = d["rmax"], d["req"], d["t_eval"], d.get("frames")
        self.n_p = self.space.n
        self.nu_sd = np.asarray(d["nuisance_sd"], dtype=np.float64) if default else None
        self.active = np.flatnonzero(self.nu_sd > 0) if default else np.array([], dtype=int)
        self.k = self.active.size
        # log Req's coordinate, when Req is estimated
        self.j_rho = self.n_p + int(np.flatnonzero(self.active == 2)[0]) if 2 in self.active else None

    def start_prior(self) -> tuple:
        """Cycle 1's prior (mean (d,), cov (d, d)): the parameters' start (the global search's best
        point where ``fit`` made one, else the prior; the fusion divides it out again), augmented by
        the active nuisances' preprocessing prior N(0, nu_sd^2) with the default likelihood."""
        mean, cov = self.space.start_mean.copy(), self.space.start_cov.copy()
        if not self.default:
            return mean, cov
        n_p, k = self.n_p, self.k
        mean = np.concatenate([mean, np.zeros(k)])
        cov = np.block([[cov, np.zeros((n_p, k))], [np.zeros((k, n_p)), np.diag(self.nu_sd[self.active] ** 2)]])
        return mean, cov

    def nuisances(self, Z):
        """(M, 3) nuisances (a, delta, rho) of members Z (M, d); 0 where not active."""
        nu = np.zeros((Z.shape[0], 3))
        nu[:, self.active] = Z[:, self.n_p :]
        return nu

    def predict(self, Z):
        """R* (M, K) and failed (M,) of members Z (M, d), through the default likelihood's
        observation model."""
        return predict(
            self.runner,
            self.space.to_si(Z[:, : self.n_p]),
            self.rmax,
            self.req,
            self.t_eval[1:],
            self.nuisances(Z),
            self.frames,
        )

    def evaluate(self, groups, Z):
        """The Gauss–Newton forward map: R* at samples 1..K (M, K) and failed (M,)."""
        if self.default:
            return self.predict(Z)
        out = self.runner.simulate(
            self.space.to_si(Z), np.full(len(Z), self.rmax), np.full(len(Z), self.req), self.t_eval
        )
        return out.R_star[:, 1:], out.failed | ~np.all(np.isfinite(out.R_star), axis=1)


def en4dvar_unit(unit: Unit, rng) -> dict:
    """Every restart cycle of one experiment (methods.md §3), then its likelihood of the parameters.

    Takes the unit's data (space, settings, record ``y``, weights, noise, nuisance prior sds,
    Rmax, Req, frames); returns the parameters' last posterior (``mean``, ``cov``) and the prior it
    is divided by (``prior_mean``, ``prior_cov``), the cycles' records, the moved Req, and with the
    default likelihood the observation model and the nuisances' posterior."""
    d = unit.data
    s = d["settings"]
    runner = runner_for(d)
    before = (runner.n_member_runs, runner.n_failed)
    bubble = _Bubble(d, runner, s.likelihood == "default")
    res, cycles, lik, req_factor = run_cycles(bubble, d, s, rng)
    return {**_unit_likelihood(bubble, s, res, cycles, lik, req_factor), **runner.counts_since(before)}


def run_cycles(bubble: _Bubble, d: dict, s: En4DVarSettings, rng) -> tuple:
    """The restart cycles of one experiment; where its initial ensemble members are drawn (cycle
    1: around the prior mean or the screened start, :func:`screened_start`; later cycles: the
    inflated posterior).

    Takes the experiment, its unit data ``d`` and the resolved settings; returns (the last cycle's
    :class:`~imrbayes.ensemble.gn.GNResult`, the cycles' records [dict], the last observation model
    (dict, None with the paper's likelihood), Req's factor from ``inline``)."""
    mean, cov = bubble.start_prior()
    default = bubble.default
    y, weight = d["y"], d["weight"]
    lik = None
    cycles, res, req_factor = [], None, 1.0
    max_iter = s.max_iter if default else None
    screen_info = None
    for r in range(s.n_runs):
        n_iter = s.n_iter if r == 0 else s.n_iter_later
        ev = bubble.evaluate
        if default:
            # the observation model at the current centre: cycle 1 with the record's noise alone, later
            # cycles also with the residual's level and autocorrelation
            f, _ = bubble.predict(mean[None])
            lik = observation_model(d["y"], f[0], d["noise_var"], adapt=r > 0)
            W = lik["W"]
            y, weight = W @ d["y"], np.ones(d["y"].size)
            ev = _whitened(bubble.evaluate, W)
        centre = mean
        if r == 0 and default and s.screen:
            centre, screen_info = screened_start(rng, ev, y, mean, cov, s.screen)
        res = _cycle(rng, ev, y, weight, mean, cov, centre, s, n_iter, max_iter, screen_info)
        infl = rtps(res.prior_anoms, res.anoms, s.rtps)
        mean = res.mean[0].copy()
        cov = np.einsum("gnd,gne->gde", infl, infl)[0]
        req_z = None
        if bubble.j_rho is not None:
            # this cycle's Req against the preprocessing's, in its prior sd (req_tail.req_shift_z's z)
            req_z = float((bubble.req * np.exp(mean[bubble.j_rho]) - d["req"]) / (d["req"] * bubble.nu_sd[2]))
        # a decided conflict ends the fit before Req's origin moves (the reported Req stays this cycle's)
        stop = (
            s.req_conflict_stop is not None
            and req_z is not None
            and abs(req_z) > s.req_conflict_stop
            and r < s.n_runs - 1
        )
        if r == 0 and not stop and d.get("req_tail_t") is not None and bubble.j_rho is not None and s.n_runs > 1:
            req_factor = _move_req_inline(bubble, d, mean, res.cov[0], req_factor)
        used = np.isfinite(res.cost[0])
        cycles.append(
            {
                "cycle": r + 1,
                "cost": res.cost[0][used],
                "n_failed": res.n_failed[0][used],
                "n_redrawn": int(res.n_redrawn[0]),
                "stopped": bool(res.stopped[0]),
                "req_z": req_z,
                **({"likelihood": {k_: v for k_, v in lik.items() if k_ != "W"}} if default else {}),
            }
        )
        if stop:
            break
    if default and s.screen:
        cycles[0]["screen"] = screen_info
    return res, cycles, lik, req_factor


def _cycle(rng, ev, y, weight, mean, cov, centre, s, n_iter, max_iter, screen_info):
    """One cycle's members drawn from N(mean, cov) (and, when the screen moved the start, from
    N(centre, cov) in the same forward batch) and their Gauss–Newton iterations; returns the
    one-group result (the start with the lower posterior cost; ``screen_info`` records which)."""
    if centre is mean:
        E0 = draw(rng, mean, cov, s.n_ens)[None]
        return gauss_newton(E0, ev, y[None], weight[None], n_iter=n_iter, rng=rng, max_iter=max_iter, patience=s.n_iter)
    # both starts, one forward batch per iteration; the cycle goes on from the better end
    E0 = np.stack([draw(rng, c, cov, s.n_ens) for c in (mean, centre)])
    both = gauss_newton(
        E0,
        ev,
        np.stack([y, y]),
        np.stack([weight, weight]),
        n_iter=n_iter,
        rng=rng,
        max_iter=max_iter,
        patience=s.n_iter,
    )
    J = posterior_cost(ev, y, both.mean, mean, cov)
    g = int(np.argmin(J))
    screen_info.update(
        {
            "cost_end": [float(c) if np.isfinite(c) else None for c in J],
            "cost_paths": [[float(c) for c in row if np.isfinite(c)] for row in both.cost],
            "kept": ["prior mean", "screened"][g],
        }
    )
    return take_group(both, g)


def _move_req_inline(bubble: _Bubble, d: dict, mean, post_cov, req_factor: float) -> float:
    """``req_tail=inline`` after cycle 1: Req's origin moves to Req_hat / c, c the model's tail at
    this bubble's cycle-1 posterior mean; ``mean`` (d,) is shifted in place as a linear-Gaussian
    posterior would be by the shift of Req's prior centre (m' = m + C[:, rho] dm0 / sd0^2).
    Returns Req's factor c (``req_factor`` unchanged when the tail could not be computed)."""
    n_p, active = bubble.n_p, bubble.active
    a = mean[n_p + int(np.flatnonzero(active == 0)[0])] if 0 in active else 0.0
    new_req, c = tail_req(
        bubble.runner,
        bubble.space.to_si(mean[None, :n_p]),
        np.array([bubble.rmax * (1.0 + a)]),
        np.array([bubble.req]),
        [np.asarray(d["req_tail_t"], dtype=np.float64)],
    )
    if c[0] == 1.0:
        return req_factor
    shift = float(np.log(bubble.req / new_req[0]))  # rho' = rho + log(req / req')
    mean[bubble.j_rho] += shift
    mean -= post_cov[:, bubble.j_rho] * shift / bubble.nu_sd[2] ** 2
    bubble.req = float(new_req[0])
    return float(c[0])


def _unit_likelihood(bubble: _Bubble, s: En4DVarSettings, res, cycles: list, lik, req_factor: float) -> dict:
    """The unit's result from its last cycle: the parameters' posterior and the prior it is divided
    by -- with the default likelihood log Req integrated against its preprocessing prior, unless
    the fitted Req conflicts with its record (beyond REQ_CONFLICT_Z prior sd: the Gaussian algebra
    would then move the material along the Req ridge far from any point the fit visited,
    docs/validation.md, "A Req in conflict is not extrapolated") -- and the nuisances' posterior."""
    n_p, active = bubble.n_p, bubble.active
    qa = res.prior_anoms[0]
    pm, pc, qm, qc = res.mean[0], res.cov[0], res.prior_ensemble[0].mean(axis=0), qa.T @ qa
    lik_pm, lik_pc, lik_qm, lik_qc = pm[:n_p], pc[:n_p, :n_p], qm[:n_p], qc[:n_p, :n_p]
    last_z = cycles[-1]["req_z"]
    integral_used, conflict_kept = "req", False
    if bubble.default and bubble.k:
        conflict_kept = last_z is not None and abs(last_z) > REQ_CONFLICT_Z
        # the joint likelihood (last posterior / last prior) under a reference prior that is the
        # cycle's with log Req's coordinate replaced by its preprocessing prior, then the
        # parameter marginals' ratio
        swap = {n_p + j: bubble.nu_sd[which] for j, which in enumerate(active) if which == 2 and not conflict_kept}
        if conflict_kept:
            integral_used = "cycle"
        if swap:
            lik_pm, lik_pc, lik_qm, lik_qc = marginal_under_reference(pm, pc, qm, qc, n_p, swap)
    out = {
        "mean": lik_pm,
        "cov": lik_pc,
        "prior_mean": lik_qm,
        "prior_cov": lik_qc,
        "stopped": bool(res.stopped[0]),
        "cycles": cycles,
        "req_m": float(bubble.req),
        "req_factor": req_factor,
        "req_conflict": bool(conflict_kept),
        "nuisance_integral": integral_used,
    }
    if bubble.default:
        nu_mean, nu_sd_post = np.zeros(3), np.zeros(3)
        nu_mean[active] = pm[n_p:]
        nu_sd_post[active] = np.sqrt(np.diag(pc)[n_p:])
        out.update(
            {
                "whiten": lik["W"],
                "likelihood": {k_: v for k_, v in lik.items() if k_ != "W"},
                "var": lik["var"],
                "alpha": lik["alpha"],
                "nu_mean": nu_mean,
                "nu_sd": nu_sd_post,
            }
        )
    return out


def posterior_cost(evaluate, y, Z, mean, cov):
    """1/2 ||y - h(z)||^2 + 1/2 (z - m)^T C^-1 (z - m) for every row of Z (M, d) (``y``, ``evaluate``
    whitened); inf where the forward run fails."""
    Y, failed = evaluate(None, Z)
    dz = Z - mean
    J = 0.5 * np.sum((y[None] - Y) ** 2, axis=1) + 0.5 * np.einsum("nd,nd->n", dz, np.linalg.solve(cov, dz.T).T)
    J[np.asarray(failed, bool) | ~np.isfinite(J)] = np.inf
    return J


def take_group(res, g: int):
    """Group g of a :class:`~imrbayes.ensemble.gn.GNResult`, as a one-group result."""
    return replace(
        res, **{f.name: getattr(res, f.name)[g : g + 1] for f in fields(res) if getattr(res, f.name) is not None}
    )


def screened_start(rng, evaluate, y, mean, cov, n: int):
    """The first cycle's centre: the best of the prior mean and ``n`` prior draws (parameters and
    nuisances together) by the posterior cost 1/2 ||y - h(z)||^2 + 1/2 (z - m)^T C^-1 (z - m)
    (``y`` and ``evaluate`` whitened). Why: the Gauss-Newton iterate stays in the basin its
    starting centre lies in, and on measured records the objective is multimodal along the G-mu
    ridge jointly with the alignment (docs/validation.md 2a'). The cycle's prior is then N(best, C):
    its likelihood is still recovered exactly (posterior / cycle prior) and fused with the
    original prior. Returns (centre (d,) -- ``mean`` itself when it is the best, {"n",
    "cost_prior_mean", "cost_best", "moved"})."""
    Z = np.vstack([mean[None], draw(rng, mean, cov, n, exact=False)])
    J = posterior_cost(evaluate, y, Z, mean, cov)
    best = int(np.argmin(J))
    info = {"n": int(n), "cost_prior_mean": float(J[0]), "cost_best": float(J[best]), "moved": best != 0}
    return (Z[best].copy() if best else mean), info


def _whitened(evaluate, W):
    def ev(groups, Z):
        Y, failed = evaluate(groups, Z)
        return Y @ W.T, failed

    return ev


def en4dvar_post_unit(unit: Unit, rng) -> dict:
    """After the fusion, one experiment: R* at the fused median and at its own posterior mean, and
    at every posterior draw (for the pointwise log-likelihood) -- with the default likelihood at the
    experiment's inferred Rmax, time of the maximum and Req (``nu``, their posterior mean) and
    through its camera frames, as the fit saw the record; else at the preprocessing geometry."""
    d = unit.data
    runner = runner_for(d)
    before = (runner.n_member_runs, runner.n_failed)
    pts = d["points"]
    n = pts.shape[0]
    if d.get("nu") is None:
        out = runner.simulate(pts, np.full(n, d["rmax"]), np.full(n, d["req"]), d["t_eval"])
        R = out.R_star
    else:
        nu = np.tile(np.asarray(d["nu"], dtype=np.float64), (n, 1))
        t = d["t_eval"]
        R0, _ = predict(runner, pts, d["rmax"], d["req"], t[:1], nu)
        R1, _ = predict(runner, pts, d["rmax"], d["req"], t[1:], nu, d.get("frames"))
        R = np.hstack([R0, R1])
    return {"R_star": R, **runner.counts_since(before)}


def fit_en4dvar(
    fm,
    obs,
    space,
    settings: En4DVarSettings | None = None,
    seed: int = 0,
    runner: Runner | None = None,
    progress=None,
    execution=None,
    req_tail_start: ReqTailStart | None = None,
) -> FitResult:
    """Fit constant parameters to every experiment and fuse (see module doc).

    fm : ForwardModel; obs : Observations; space : ParamSpace; seed: the run seed (each experiment
    draws from its own stream, from the seed and its unit id). Units: one per experiment
    (:func:`en4dvar_unit`, ``exp=003``: every cycle), then one per experiment after the fusion
    (:func:`en4dvar_post_unit`, ``post=fit/exp=003``: fitted curves, draws' log-likelihood);
    ``execution`` (:class:`~imrbayes.execution.Execution`) says where they run and are checkpointed
    (default: this process, with ``runner``). ``req_tail_start``
    (:class:`~imrbayes.ensemble.req_tail.ReqTailStart`): with ``req_tail`` ``inline`` (or ``auto``
    on the thermal bubble), the material and Rmax of an existing fit of the same records at which
    the model's tail is evaluated once, before one pass; ignored otherwise.
    An experiment whose unit fails is left out of the fusion (counted, reported in
    ``details["failed_units"]`` and the warnings).
    Returns a :class:`FitResult` with per-experiment posteriors in ``per_experiment`` and the
    fused Gaussian with the density it approximates in ``window_posteriors`` (one window).
    """
    s = settings or En4DVarSettings()
    s.check()
    s = s.resolved()
    ex = execution or Execution(progress=False)
    runner = runner or Runner(fm)
    mode = req_tail_mode(s, fm)
    tails = any(t.size > 0 for t in (obs.req_tail_t or []))
    if mode == "inline" and (req_tail_start is not None or s.n_runs < 2):
        # a given start already places Req in one pass; one cycle leaves no cycle to move Req before
        mode = "model"
    if mode == "inline" and tails:
        res = en4dvar_pass(fm, obs, space, s, seed, runner, progress, ex, tag={"req": "inline"}, inline=True)
        res.details["req_tail"] = {
            "method": "inline",
            "setting": s.req_tail,
            "factor": res.details.pop("req_factor"),
            "req_tail_mean_m": obs.req_m.tolist(),
            "req_prior_mean_m": res.details.pop("req_prior_mean_m"),
            "note": "each Req's origin moved after cycle 1 to where the model's mean over the frames the preprocessing "
            "averaged equals the data's (model at that bubble's cycle-1 posterior mean), that posterior "
            "shifted as a linear-Gaussian one would be; one pass",
        }
        return res
    if mode != "model" or not tails:
        res = en4dvar_pass(fm, obs, space, s, seed, runner, progress, ex)
        note = (
            "each Req's prior centred on the preprocessing's value"
            if mode == "mean"
            else "no experiment's Req came from its record's tail (given, or no tail measured): nothing to re-centre, "
            "one pass"
        )
        res.details["req_tail"] = {"method": mode, "setting": s.req_tail, "factor": [1.0] * obs.n_exp, "note": note}
        return res
    return _fit_with_model_tail(fm, obs, space, s, seed, runner, progress, ex, req_tail_start)


def _fit_with_model_tail(fm, obs, space, s, seed, runner, progress, ex, req_tail_start) -> FitResult:
    """Two stages: place the material (``req_tail_start``, else a quick first pass,
    :data:`REQ_TAIL_FIRST_PASS`), centre each Req's prior where the model's tail there matches the
    record's (:func:`~imrbayes.ensemble.req_tail.model_tail_req`), then :func:`en4dvar_pass`.
    Returns that pass's :class:`FitResult` with ``details["req_tail"]`` saying how Req was placed."""
    t0 = time.perf_counter()
    first = None
    if req_tail_start is not None:
        theta = np.asarray(req_tail_start.theta_si, dtype=np.float64)
        rmax = np.asarray(req_tail_start.rmax_m, dtype=np.float64)
        if theta.ndim not in (1, 2) or theta.shape[-1] != space.n or rmax.shape != (obs.n_exp,):
            raise ValueError(
                f"req_tail_start: theta_si {theta.shape} / rmax_m {rmax.shape} do not match "
                f"{space.n} parameters and {obs.n_exp} experiments"
            )
        where = f"the {req_tail_start.source}"
    else:
        first = en4dvar_pass(
            fm, obs, space, replace(s, **REQ_TAIL_FIRST_PASS), seed, runner, progress, ex, tag={"req": "first"}
        )
        theta = np.array([first.estimate[nm]["mean"] for nm in space.names])
        rmax = np.array(
            [
                p["nuisance"]["rmax_m"]["mean"] if "nuisance" in p else r
                for p, r in zip(first.per_experiment, obs.rmax_m)
            ]
        )
        where = "a quick first fit's estimate and Rmax: one cycle, no screening"
    obs2, factor = model_tail_req(runner, obs, theta, rmax)
    if np.all(factor == 1.0):  # every correction failed: the tail means stand
        obs2, tag = obs, None
        note = "the model's tail could not be computed for any experiment: Req's prior is the tail mean"
    else:
        # one tag whatever placed the material: the same unit seeds, so a given start and the first
        # pass differ only by their factors
        tag = {"req": "model"}
        note = (
            "each Req's prior centred where the model's mean over the frames the preprocessing averaged equals "
            f"the data's (model at {where}); the estimate is the full fit after it"
        )
    res = en4dvar_pass(fm, obs2, space, s, seed, runner, progress, ex, tag=tag)
    info = {
        "method": "model",
        "setting": s.req_tail,
        "factor": factor.tolist(),
        "req_tail_mean_m": obs.req_m.tolist(),
        "req_prior_mean_m": obs2.req_m.tolist(),
        "note": note,
    }
    if first is None:
        info["start"] = {"source": req_tail_start.source, "theta_si": theta.tolist(), "rmax_m": rmax.tolist()}
    else:
        info.update(
            {
                "first_pass_estimate": {nm: first.estimate[nm]["mean"] for nm in space.names},
                "first_pass_rmax_m": rmax.tolist(),
                "first_pass_settings": dict(REQ_TAIL_FIRST_PASS),
            }
        )
        # the quick first pass, for the record (not the tail-mean fit of the same data: that has three cycles)
        res.details.setdefault("alternative_estimates", {})["req_tail_first_pass"] = {
            nm: first.estimate[nm] for nm in space.names
        }
        res.details["member_runs"] += first.details["member_runs"]
    res.details["req_tail"] = info
    res.runtime_s = time.perf_counter() - t0
    return res


def en4dvar_pass(
    fm,
    obs,
    space,
    s: En4DVarSettings,
    seed: int,
    runner: Runner,
    progress,
    ex: Execution,
    tag: dict | None = None,
    inline: bool = False,
) -> FitResult:
    """One En4D-Var pass with Req's prior as ``obs`` has it: every experiment's cycles (units),
    the fusion, the fitted curves.

    Takes the forward model, observations, parameter space, *resolved* settings, the seed, the
    runner, ``progress(cycle)``, the execution, ``tag`` (a prefix of the unit ids: a second pass must
    not reuse the first's checkpoints) and ``inline`` (``req_tail=inline``: the units move Req).
    Returns the :class:`FitResult` (``details["req_factor"]`` and ``["req_prior_mean_m"]`` with
    ``inline``)."""
    tag = tag or {}
    default = s.likelihood == "default"
    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)  # the fused posterior's draws (units have their own)
    K = last_index(obs, s.t_end)
    y, _ = fit_window(obs, K, s.obs_weight or "sum")
    n_exp = obs.n_exp
    spec, token = fm_spec(fm), register_runner(runner)
    rep = ex.run(
        _experiment_units(obs, space, s, K, spec, token, tag, inline), en4dvar_unit, seed, desc="en4dvar experiments"
    )
    ok, R, failed_units, warnings = _collect_experiments(rep, obs, tag)
    req_factor = np.ones(n_exp)
    if inline:
        # the units moved Req's origin: every later step (reported nuisances, fitted curves, the
        # MCMC window) reads the moved Req
        req_new = obs.req_m.copy()
        for n, r in zip(ok, R):
            req_new[n], req_factor[n] = float(r.get("req_m", req_new[n])), float(r.get("req_factor", 1.0))
        obs = with_req(obs, req_new)
    member_runs = sum(int(r["member_runs"]) for r in R)
    failed_runs = sum(int(r["failed_member_runs"]) for r in R)
    cycles = _cycles_record(R, ok, obs, s, progress)
    fused = _fuse_experiments(space, R, s)
    warnings.extend(fused["warnings"])
    est_mean, est_cov = fused["estimate"]
    # posterior draws (1 chain) of the reported Gaussian
    Zd = draw(rng, est_mean, est_cov, s.n_draws, exact=False)
    post = {nm: space.to_si(Zd)[None, :, i] for i, nm in enumerate(space.names)}
    want_ll = s.loglik and s.n_draws > 0
    curves = _fitted_curves(ex, obs, space, s, K, spec, token, tag, ok, R, fused, Zd if want_ll else None, seed)
    failed_units += curves["failed_units"]
    warnings.extend(curves["warnings"])
    member_runs += curves["member_runs"]
    failed_runs += curves["failed_member_runs"]
    fitted, mask = curves["fitted"], curves["mask"]
    per = _per_experiment(obs, space, ok, R, fused, curves["own"], mask, failed_units, default)
    warnings.extend(_nuisance_warnings(obs, ok, R, default))
    ll = _log_likelihood(curves["draws"], y, obs, ok, R, K, default) if want_ll else None
    fus = fused["pooled"]
    details = {
        "settings": asdict(s),
        "n_fit_steps": K,
        "t_end_star": float(obs.t_star[K]),
        "likelihood": _likelihood_record(s, ok, R, K, n_exp),
        "cycles": cycles,
        "fusion": fus.to_dict(),
        "rmse": rmse(fitted, obs.R_star, mask),
        "fused_mean_internal": fus.mean.tolist(),
        "fused_cov_internal": fus.cov.tolist(),
        "fused_cov_si": si_covariance(space, fus.mean, fus.cov).tolist(),
        "parameter_space": space.describe(),
        "member_runs": member_runs,
        "failed_member_runs": failed_runs,
        **({"req_factor": req_factor.tolist(), "req_prior_mean_m": obs.req_m.tolist()} if inline else {}),
        "failed_units": failed_units,
        "experiments_used": [obs.names[n] for n in ok],
        "gauss_newton": "normalised anomalies: H = I + (1/N_t) sum Y'^T P^-1 Y', grad = w - ...; identical "
        "iterates to the paper's (N_En - 1) form with unnormalised anomalies",
        "fitted_curve": "forward run at the fused posterior median exp(mean of log parameters)"
        + (
            ", each experiment at its inferred Rmax, time of the maximum and Req (posterior "
            "mean) and through its camera frames"
            if default
            else ""
        ),
    }
    estimate = gaussian_estimate(space, est_mean, est_cov)
    if fused["bubbles"] is not None:
        estimate = _random_effects_details(fused["bubbles"], fus, details, warnings)
    whiten, offsets = _whitening(obs, ok, R, K, default)
    return FitResult(
        method="en4dvar",
        model=fm.constitutive.name,
        param_names=tuple(space.names),
        estimate=estimate,
        fitted=fitted,
        fit_mask=mask,
        mean_internal=est_mean,
        cov_internal=est_cov,
        per_experiment=per,
        details=details,
        posterior=post,
        log_likelihood=ll,
        posterior_dims={"R": ["experiment", "time"]},
        coords={"experiment": list(obs.names), "time": obs.t_star[1 : K + 1]},
        runtime_s=time.perf_counter() - t0,
        warnings=warnings,
        window_posteriors=[
            fitting_window_posterior(fm, obs, space, K, s.obs_weight or "sum", fus.mean, fus.cov, whiten, offsets)
        ],
    )


def _experiment_units(obs, space, s, K: int, spec, token, tag: dict, inline: bool) -> list:
    """The :func:`en4dvar_unit` of every experiment (its record, weights, noise, nuisance prior)."""
    t_eval = obs.t_star[: K + 1]
    y, weight = fit_window(obs, K, s.obs_weight or "sum")
    base = {"spec": spec, "runner": token, "space": space, "settings": s, "t_eval": t_eval}
    noise_var = [record_noise_sd(obs, n) ** 2 for n in range(obs.n_exp)]
    return [
        Unit(
            unit_id(**tag, exp=n),
            {
                **base,
                "rmax": float(obs.rmax_m[n]),
                "req": float(obs.req_m[n]),
                "y": y[n],
                "weight": weight,
                "noise_var": noise_var[n],
                "nuisance_sd": nuisance_prior_sd(obs, n),
                "req_tail_t": obs.req_tail_t[n] if inline and obs.req_tail_t else None,
                "frames": None if obs.frame_t is None else frame_operator(obs.frame_t[n], t_eval[1:]),
            },
        )
        for n in range(obs.n_exp)
    ]


def _collect_experiments(rep, obs, tag: dict) -> tuple:
    """(indices of the experiments whose unit finished, their results, failed units [dict],
    warnings [str]); RuntimeError when every experiment failed."""
    warnings, failed_units, ok = [], [], []
    for n in range(obs.n_exp):
        uid = unit_id(**tag, exp=n)
        if uid in rep.results:
            ok.append(n)
        else:
            err = rep.failures[uid].error
            failed_units.append({"unit": uid, "experiment": obs.names[n], "error": err})
            warnings.append(f"experiment {obs.names[n]!r} failed ({err}); left out of the fusion")
    if not ok:
        raise RuntimeError(f"every experiment failed (e.g. {failed_units[0]['error']})")
    return ok, [rep.results[unit_id(**tag, exp=n)] for n in ok], failed_units, warnings


def _cycles_record(R: list, ok: list, obs, s, progress) -> list:
    """``details["cycles"]``: per cycle, each experiment's costs, failures and Req z (an experiment
    stopped by ``req_conflict_stop`` is listed only in the cycles it ran); ``progress(c)`` after each."""
    cycles = []
    for c in range(s.n_runs):
        ran = [(n, r["cycles"][c]) for n, r in zip(ok, R) if len(r["cycles"]) > c]
        if not ran:
            break
        cyc = [x for _, x in ran]
        cycles.append(
            {
                "cycle": c + 1,
                "cost": [np.asarray(x["cost"]).tolist() for x in cyc],
                "n_failed": [np.asarray(x["n_failed"]).tolist() for x in cyc],
                "n_redrawn": [int(x["n_redrawn"]) for x in cyc],
                "stopped": [bool(x["stopped"]) for x in cyc],
                "req_z": [x.get("req_z") for x in cyc],
                "experiments": [obs.names[n] for n, _ in ran],
                **({"screen": [x["screen"] for x in cyc]} if all("screen" in x for x in cyc) else {}),
            }
        )
        if progress is not None:
            progress(c + 1)
    return cycles


def _fuse_experiments(space, R: list, s) -> dict:
    """The experiments fused (:mod:`imrbayes.ensemble.fusion`). Returns {"pooled": the product-rule
    :class:`~imrbayes.ensemble.fusion.Fusion`, "bubbles": the
    :class:`~imrbayes.ensemble.fusion.BubbleFusion` (default likelihood, else None), "post_mean"
    (n_ok, d), "post_cov" (n_ok, d, d): each experiment's reported posterior, "estimate": (mean,
    cov) of the reported Gaussian, "warnings"}."""
    post_mean = np.stack([r["mean"] for r in R])
    post_cov = np.stack([r["cov"] for r in R])
    start_mean, start_cov = np.stack([r["prior_mean"] for r in R]), np.stack([r["prior_cov"] for r in R])
    bubbles, warnings = None, []
    if s.likelihood == "default":
        bubbles = fuse_bubbles(space, post_mean, post_cov, start_mean, start_cov)
        pooled = fuse_likelihoods(post_mean, post_cov, start_mean, start_cov, space.prior_mean, space.prior_cov)
        warnings.extend(bubbles.random.notes)
        post_mean, post_cov = bubbles.own_posteriors()
    elif s.fusion == "prior":
        pooled = fuse(post_mean, post_cov, space.prior_mean, space.prior_cov)
    else:
        pooled = fuse_likelihoods(post_mean, post_cov, start_mean, start_cov, space.prior_mean, space.prior_cov)
    warnings.extend(pooled.notes)
    n_stopped = sum(bool(r["stopped"]) for r in R)
    if n_stopped:
        warnings.append(f"{n_stopped} experiment(s) stopped early: too many failed members")
    # the reported estimate: the gel-level mean (default likelihood), else the fused Gaussian
    estimate = (bubbles.random.mean, bubbles.random.cov) if bubbles is not None else (pooled.mean, pooled.cov)
    return {
        "pooled": pooled,
        "bubbles": bubbles,
        "post_mean": post_mean,
        "post_cov": post_cov,
        "estimate": estimate,
        "warnings": warnings,
    }


def _fitted_curves(
    ex, obs, space, s, K: int, spec, token, tag: dict, ok: list, R: list, fused: dict, Zd, seed: int
) -> dict:
    """The :func:`en4dvar_post_unit` of every fused experiment: R* at the reported estimate, at its
    own posterior mean and (``Zd`` (n_draws, d), None: none) at every posterior draw. Returns
    {"fitted", "own" (n_exp, n_samples), "mask" (fitted samples), "draws" (n_draws, n_exp, K),
    "failed_units", "warnings", "member_runs", "failed_member_runs"}."""
    default = s.likelihood == "default"
    t_eval = obs.t_star[: K + 1]
    fused_si = space.to_si(fused["estimate"][0])[None, :]
    units = []
    for i, n in enumerate(ok):
        pts = [fused_si, space.to_si(fused["post_mean"][i])[None, :]] + ([space.to_si(Zd)] if Zd is not None else [])
        units.append(
            Unit(
                unit_id(**tag, post="fit", exp=n),
                {
                    "spec": spec,
                    "runner": token,
                    "t_eval": t_eval,
                    "rmax": float(obs.rmax_m[n]),
                    "req": float(obs.req_m[n]),
                    "points": np.vstack(pts),
                    "nu": R[i]["nu_mean"] if default else None,
                    "frames": None
                    if obs.frame_t is None or not default
                    else frame_operator(obs.frame_t[n], t_eval[1:]),
                },
            )
        )
    prep = ex.run(units, en4dvar_post_unit, seed, desc="en4dvar fitted curves")
    out = {
        "fitted": np.full_like(obs.R_star, np.nan),
        "own": np.full_like(obs.R_star, np.nan),
        "draws": np.full((s.n_draws, obs.n_exp, K), np.nan),
        "failed_units": [],
        "warnings": [],
        "member_runs": 0,
        "failed_member_runs": 0,
    }
    for n in ok:
        uid = unit_id(**tag, post="fit", exp=n)
        if uid not in prep.results:
            err = prep.failures[uid].error
            out["failed_units"].append({"unit": uid, "experiment": obs.names[n], "error": err})
            out["warnings"].append(f"experiment {obs.names[n]!r}: fitted curves failed ({err})")
            continue
        r = prep.results[uid]
        out["member_runs"] += int(r["member_runs"])
        out["failed_member_runs"] += int(r["failed_member_runs"])
        out["fitted"][n, : K + 1] = r["R_star"][0]
        out["own"][n, : K + 1] = r["R_star"][1]
        if Zd is not None:
            out["draws"][:, n] = r["R_star"][2:, 1:]
    mask = np.zeros(obs.R_star.shape, dtype=bool)
    mask[:, 1 : K + 1] = True
    mask[[n for n in range(obs.n_exp) if not np.isfinite(out["fitted"][n, 1 : K + 1]).any()]] = False
    out["mask"] = mask
    return out


def _per_experiment(obs, space, ok: list, R: list, fused: dict, own, mask, failed_units: list, default: bool) -> list:
    """``per_experiment``: each experiment's own estimate, fit and (default likelihood) nuisances
    and likelihood; a failed one with its error."""
    per = []
    for n in range(obs.n_exp):
        if n not in ok:
            per.append(
                {
                    "name": obs.names[n],
                    "failed": True,
                    "error": next(f["error"] for f in failed_units if f["experiment"] == obs.names[n]),
                }
            )
            continue
        i = ok.index(n)
        pm, pc = fused["post_mean"][i], fused["post_cov"][i]
        entry = {
            "name": obs.names[n],
            "estimate": gaussian_estimate(space, pm, pc),
            "mean_internal": pm.tolist(),
            "cov_internal": pc.tolist(),
            "rmse_own": rmse(own[n], obs.R_star[n], mask[n]) if mask[n].any() else float("nan"),
        }
        if default:
            r = R[i]
            entry["nuisance"] = nuisance_summary(
                r["nu_mean"],
                r["nu_sd"],
                nuisance_prior_sd(obs, n),
                float(obs.rmax_m[n]),
                float(obs.req_m[n]),
                float(obs.t0_s[n]),
                float(obs.tc_s[n]),
            )
            entry["likelihood"] = {
                **r["likelihood"],
                "nuisance_integral": r.get("nuisance_integral", "req"),
                "req_conflict": bool(r.get("req_conflict", False)),
            }
        per.append(entry)
    return per


def _nuisance_warnings(obs, ok: list, R: list, default: bool) -> list:
    """Warnings naming the experiments whose Req conflicts with their record, and (default
    likelihood) those whose nuisances moved more than 3 prior sd from what preprocessing measured."""
    warnings = []
    conflicted = [obs.names[n] for i, n in enumerate(ok) if R[i].get("req_conflict")]
    if conflicted:
        warnings.append(
            f"{len(conflicted)} of {len(ok)} experiment(s) fit a Req more than {REQ_CONFLICT_Z:g} prior sd "
            f"from the record's: {', '.join(conflicted[:5])}{' ...' if len(conflicted) > 5 else ''}. Their "
            f"likelihood keeps the fit's Req (the last cycle's prior) instead of integrating Req against "
            f"the record's, which would extrapolate the material along the Req ridge "
            f"(per_experiment[].likelihood.nuisance_integral)"
        )
    if not default:
        return warnings
    far = []
    for i, n in enumerate(ok):
        prior_sd = nuisance_prior_sd(obs, n)
        z = np.where(prior_sd > 0, np.abs(R[i]["nu_mean"]) / np.where(prior_sd > 0, prior_sd, 1.0), 0.0)
        moved = [("Rmax", "the time of the maximum", "Req")[j] for j in np.flatnonzero(z > 3.0)]
        if moved:
            far.append(f"{obs.names[n]} ({', '.join(moved)})")
    if far:
        warnings.append(
            f"{len(far)} of {len(ok)} experiment(s) need nuisances more than 3 prior sd from what "
            f"preprocessing measured: {'; '.join(far[:5])}{' ...' if len(far) > 5 else ''}. The "
            f"model is absorbing misfit into the geometry; read the material estimate with care "
            f"(per_experiment[].nuisance)"
        )
    return warnings


def _log_likelihood(Yd, y, obs, ok: list, R: list, K: int, default: bool) -> dict:
    """posterior.nc's pointwise log-likelihood {"R": (1, n_draws, n_exp, K)} of the draws' curves
    ``Yd``: with the default likelihood a per-sample Gaussian of each experiment's tempered variance
    (the nuisances' correlation left out), else P_k."""
    if default:
        var = np.full(obs.n_exp, np.nan)
        for i, n in enumerate(ok):
            var[n] = R[i]["var"] / R[i]["alpha"]
        lp = loglik_pointwise(Yd, y[None], var[None, :, None])
    else:
        lp = loglik_pointwise(Yd, y[None], obs.P[1 : K + 1])
    return {"R": np.where(np.isfinite(lp), lp, -1e300)[None]}


def _likelihood_record(s, ok: list, R: list, K: int, n_exp: int) -> dict:
    """``details["likelihood"]``: which likelihood, its noise and fusion in words, the effective samples."""
    if s.likelihood != "default":
        return {
            "name": "paper",
            "noise": "P_k of preprocessing (" + str(s.obs_weight) + " cost)",
            "fusion": str(s.fusion),
            "effective_samples": None,
        }
    eff = [float(R[ok.index(n)]["likelihood"]["effective_samples"]) if n in ok else None for n in range(n_exp)]
    return {
        "name": "default",
        "effective_samples": eff,
        "n_samples": K,
        "noise": "each record's fourth-difference noise sd, raised to the RMS of its nuisance-corrected "
        "residual where the model does not reach the noise; each experiment tempered by "
        "n_eff/K (integrated autocorrelation time of the residual); Rmax, the time of the "
        "maximum and Req integrated out to first order",
        "fusion": "random effects across experiments (gel-level mean, between-bubble sd, predictive)",
    }


def _random_effects_details(bubbles, fus, details: dict, warnings: list) -> dict:
    """Adds the random-effects fusion (between-bubble sd, predictive, leave one bubble out) to
    ``details`` and its warnings to ``warnings``; returns the gel-level SI estimate."""
    from scipy.stats import binomtest

    h = bubbles.summaries()
    details.update(
        {
            "between_experiments": h["between_experiments"],
            "predictive": h["predictive"],
            "random_effects": bubbles.random.to_dict(),
            "pooled_mean_internal": fus.mean.tolist(),
            "pooled_cov_internal": fus.cov.tolist(),
        }
    )
    loo = bubbles.leave_one_out()
    if loo is not None:
        details["leave_one_bubble_out"] = loo
        for name, k in loo["n_inside"].items():
            if binomtest(k, loo["n"]).proportion_ci(method="wilson").high < loo["level"]:
                warnings.append(
                    f"{name}: leaving one bubble out, the others' {loo['level']:.0%} predictive "
                    f"holds its own estimate in only {k} of {loo['n']} (the scatter model is too "
                    "narrow for these bubbles; details['leave_one_bubble_out'])"
                )
    return h["estimate"]


def _whitening(obs, ok: list, R: list, K: int, default: bool) -> tuple:
    """The default likelihood's whitening (n_exp, K, K) and nuisance offsets (3, n_exp, 3: prior sd,
    posterior mean, posterior sd of (a, delta, rho)) for the MCMC density; (None, None) otherwise."""
    if not default:
        return None, None
    whiten = np.full((obs.n_exp, K, K), np.nan)
    offsets = np.zeros((3, obs.n_exp, 3))
    for i, n in enumerate(ok):
        whiten[n] = R[i]["whiten"]
        offsets[:, n] = [nuisance_prior_sd(obs, n), R[i]["nu_mean"], R[i]["nu_sd"]]
    return whiten, offsets


def fitting_window_posterior(
    fm, obs, space, K: int, obs_weight: str, mean, cov, whiten=None, offsets=None
) -> WindowPosterior:
    """The density the fused Gaussian approximates: every experiment from its maximum over samples
    1..K with the parameter prior and weight 1/K (``obs_weight="mean"``) or 1 (``"sum"``), or, with
    ``whiten`` (n_exp, K, K), the default likelihood's whitened residuals (no between-bubble
    scatter: the pooled, product-rule posterior, which ``mean``/``cov`` then are)."""
    c, rule = (1.0 / K, "1/N_t (En4D-Var averaging)") if obs_weight == "mean" else (1.0, "1 (plain likelihood)")
    desc = {
        "kind": "fitting window from the maximum",
        "samples": [1, K],
        "weight_rule": rule,
        "state": "maximum radius (exact)",
    }
    if whiten is not None:
        desc.update(
            {
                "weight_rule": "default likelihood: ||W_n (y_n - R_n)||^2 per experiment (noise, nuisances, tempering)",
                "gaussian": "pooled over experiments (no between-bubble scatter)",
            }
        )
    return WindowPosterior(
        index=0,
        start=0,
        samples=(1, K),
        mean=np.asarray(mean, float),
        cov=np.asarray(cov, float),
        prior_mean=space.prior_mean,
        prior_cov=space.prior_cov,
        weight=np.full(K, c),
        start_state=np.array(fm.initial_state(obs.rmax_m, obs.req_m).y, dtype=np.float64),
        # the Req each experiment's nuisance prior is centred on (req_tail moves it off the data's
        # tail mean): the MCMC target must run at the same one
        start_req_m=np.asarray(obs.req_m, dtype=np.float64).copy(),
        description=desc,
        whiten=whiten,
        **(
            {}
            if offsets is None
            else {
                "nuisance_sd": offsets[0],
                "nuisance_mean": offsets[1],
                "nuisance_post_sd": offsets[2],
                "frames": None
                if obs.frame_t is None
                else [frame_operator(f, obs.t_star[1 : K + 1]) for f in obs.frame_t],
            }
        ),
    )


class En4DVar(InferenceMethod):
    """En4D-Var as a plug-in (:class:`~imrbayes.ensemble.method.InferenceMethod`)."""

    name = "en4dvar"
    label = "ensemble 4D-Var (En4D-Var)"
    settings_class = En4DVarSettings
    gaussian_posterior = True
    fit = staticmethod(fit_en4dvar)

    @staticmethod
    def global_start(settings, space) -> bool:
        return settings.likelihood == "default" and {"G", "mu"} <= set(space.names)

    @staticmethod
    def check_settings(settings, obs):
        settings.check()
        last_index(obs, settings.t_end)

    @staticmethod
    def n_forward_runs(settings, n_exp, n_steps):
        s = settings.resolved()  # cycles x iterations x members, then the fitted curves and the draws
        n = (
            (s.n_iter + (s.n_runs - 1) * s.n_iter_later) * s.n_ens * n_exp
            + 2 * n_exp
            + (s.n_draws * n_exp if s.loglik else 0)
        )
        if s.likelihood == "default":  # the observation model: one run per cycle
            n += s.n_runs * n_exp
            # (iterations past n_iter up to max_iter are not counted: the bar is an estimate)
            if s.screen:  # the screen, and at most one more start in cycle 1 (scored by one run per start)
                n += (s.screen + 1 + s.n_iter * s.n_ens + 2) * n_exp
            if s.req_tail in ("inline", "auto"):
                n += 3 * n_exp  # the model's tail after cycle 1 (auto: thermal only)
        return n

    @staticmethod
    def n_units(settings, n_exp, n_steps, fm=None):
        # each experiment's cycles, then its fitted curves (fast)
        mode = req_tail_mode(settings, fm)
        if mode == "model" or (mode == "inline" and settings.n_runs < 2):  # inline runs as model then
            return 4 * n_exp, (
                f"a quick pass to place Req by the model's tail, then the fit: 2 x {n_exp} experiments "
                "and their fitted curves"
            )
        return 2 * n_exp, f"{n_exp} experiments, then their fitted curves"

    @staticmethod
    def figures(obs, res, fdir):
        from imrbayes.ensemble.figures import experiments_figure

        return [experiments_figure(res, fdir / "experiments.png")]
