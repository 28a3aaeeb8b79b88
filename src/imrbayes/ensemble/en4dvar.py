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

Screened start (``screen``, default likelihood only): before cycle 1, the prior mean and ``screen``
prior draws (material and nuisances) are run once (:func:`screened_start`). When a draw has a
lower posterior cost than the prior mean, cycle 1 runs from both (one forward batch per iteration)
and the later cycles go on from the end with the lower posterior cost under the original prior
(:func:`posterior_cost`); a cycle prior N(draw, C) is divided out again when the likelihood is
extracted. Why: on the stiff-PA records the ensemble Gauss-Newton stays in the basin its start lies
in, and the objective is multimodal along the G-mu ridge jointly with the alignment
(docs/results.md 2a'); a screened start alone found better optima for some bubbles and worse for
others, hence both starts.

Iterations to convergence (``max_iter``, default likelihood only): every cycle iterates past
``n_iter`` while the Gauss-Newton cost still falls by 1 % per iteration, up to ``max_iter``. With
the record's noise (cycle 1) the stiff-PA costs were still falling 20-80 % per iteration at the
fifth, and where the fit stopped depended on the draws (one bubble's rmse 0.020, 0.034, 0.048 R*
over three seeds). With both changes, bubbles 3-5 of the stiff-PA records reach the best optima
least squares found, the same on three seeds (docs/results.md 2a'); cost ~3.5x on those records,
little on data the model fits (synthetic camera data converge in a few iterations). The cycles after
the first start from the inflated posterior of the one before, near its optimum: they run at least
``n_iter_later`` (3) iterations, on by the same rule, and a group whose every step so far has raised
the cost keeps halving it up to ``n_iter`` evaluations (``patience``) -- on stiff PA every bubble's
later cycles had stopped at the minimum of 5; docs/results.md, "Fewer iterations after the first
cycle".

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

Observation weight (``obs_weight``). ``mean`` (default, methods.md §3): the misfit is averaged over
the N_t samples, so a whole record weighs about as much as one sample; the posterior is wide and
over-covers (100 % over 30 seeds, docs/results.md). ``sum``: every sample is an independent
observation of variance P_k (the plain Gaussian likelihood, as IMR's least squares and the MCMC
``plain`` target). On 20 seeds of the verification case (polytropic) ``sum`` puts G within 5 % in
17-18 of them (``mean``: 7-9), but its intervals under-cover (75 %) because P_k, the variance of
five records, is itself noisy (E[1/P_k] = 2/sigma^2 for four degrees of freedom); with the true
noise variance the coverage is 90 % (G) and 85 % (mu).

Sampled bubble posteriors (``bubble_posterior="sampled"``, default likelihood only): after the
last cycle, each experiment's posterior of its parameters and nuisances under the original prior is
sampled by adaptive importance sampling from the ensemble's Gaussian
(:func:`imrbayes.ensemble.sampled.adaptive_importance`, ``is_rounds`` x ``is_draws`` forward runs
per experiment), and the sampled moments replace the ensemble's in the fusion. Why: on thermal
camera records one bubble's posterior is a skewed ridge that the ensemble's Gaussian makes too
narrow and too high, so the fused estimate was confidently wrong (docs/results.md, "Why the
thermal rows miss"). ``details["alternative_estimates"]`` then also holds the ensembles' Gaussian
fusion and the samples fused as densities (:func:`imrbayes.ensemble.sampled.fuse_draws`).

Positive parameters live in log space throughout, so nothing is clipped; the reported SI
estimate is the log-normal marginal of the fused Gaussian.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, fields, replace

import numpy as np

from imrbayes.ensemble.gaussian import draw, fuse, fuse_likelihoods, marginal_under_reference, rtps
from imrbayes.ensemble.gn import gauss_newton
from imrbayes.ensemble.hierarchical import leave_one_out, likelihood_terms, random_effects
from imrbayes.ensemble.likelihood import (check_choice, frame_operator, nuisance_prior_sd, nuisance_summary, observation_model,
                                          predict, record_noise_sd)
from imrbayes.ensemble.method import InferenceMethod
from imrbayes.ensemble.req_tail import REQ_CONFLICT_Z, ReqTailStart, model_tail_req, tail_req, with_req
from imrbayes.ensemble.sampled import WeightedDraws, adaptive_importance, fuse_draws, weighted_quantiles
from imrbayes.ensemble.result import (FitResult, WindowPosterior, gaussian_estimate, loglik_pointwise, rmse,
                                      si_covariance)
from imrbayes.errors import InputError
from imrbayes.execution import Execution, Unit, unit_id
from imrbayes.forward import Runner, fm_spec, register_runner, runner_for

__all__ = ["En4DVar", "En4DVarSettings", "fit_en4dvar", "en4dvar_unit", "en4dvar_post_unit", "fitting_window_posterior"]


#: fewest effective importance draws per experiment before ``bubble_posterior="sampled"`` warns
MIN_SAMPLED_ESS = 50
#: members per experiment: the default likelihood's, and the paper's (``likelihood="paper"``)
DEFAULT_N_ENS, PAPER_N_ENS = 24, 48
#: Gauss-Newton iterations (at least; on to convergence up to ``max_iter``) of the cycles after the
#: first with the default likelihood: they start from the inflated posterior of the cycle before,
#: near its optimum (on stiff PA every bubble's later cycles stopped at the minimum of 5), and on 60
#: thermal camera seeds 3 moved the gel-level estimates by 0.001 sd on average, at most 0.35
#: (docs/results.md, "Fewer iterations after the first cycle"); the paper's fixed ``n_iter`` in
#: every cycle otherwise
DEFAULT_N_ITER_LATER = 3


@dataclass
class En4DVarSettings:
    """En4D-Var settings (the paper's values with ``likelihood="paper"``).

    n_ens: members per experiment (default: 24 with the default likelihood, the paper's 48 with
    ``likelihood="paper"``: the drawn ensembles have exact moments and the regression linearisation
    needs only N > d + 1, so halving N halves the cost and leaves each bubble's posterior where it
    was, docs/results.md "Half the members"); n_iter: Gauss–Newton iterations per cycle; n_iter_later:
    those of the cycles after the first (default: 3 with the default likelihood -- they start near
    the optimum and iterate on to convergence -- and ``n_iter`` with the paper's); n_runs: cycles
    (restarts; with 2 instead of 3 the thermal camera estimates sit 0.18-0.26 sd higher, a 4th or
    RTPS 1.0 moves nothing beyond its SE: docs/results.md, "Cycles, RTPS and the screen"); rtps:
    relaxation-to-prior-spread factor a; t_end: last fitted t* (None = whole
    record); exact_moments: see module doc; n_draws: draws of the fused posterior written to
    posterior.nc (with their pointwise log-likelihood if ``loglik``); fusion, obs_weight: see module doc;
    screen: prior draws screened for the first cycle's centre (0 = start at the prior mean);
    max_iter: Gauss-Newton iterations per cycle past ``n_iter`` while the cost still falls by 1 %
    (:func:`~imrbayes.ensemble.gn.gauss_newton`); both default likelihood only: ``paper`` keeps the
    paper's start and its fixed ``n_iter``. bubble_posterior (default likelihood only): ``gaussian``
    (the last cycle's ensemble) or ``sampled`` (each experiment's posterior of parameters and
    nuisances by adaptive importance sampling from that Gaussian, ``is_rounds`` x ``is_draws``
    forward runs per experiment; see the module doc); is_prior_widen: the sampling's working prior
    on the parameters is the parameter prior with its sd (in z) times this factor, divided out
    again before the fusion (which applies the parameter prior once). req_tail (default likelihood
    only): ``mean`` (each Req's prior centred on the preprocessing's tail mean), ``model`` (a quick
    first fit -- one cycle, no screening -- then each Req centred where the model's own mean over the
    same frames matches the data's at that fit's estimate, then the fit:
    :mod:`imrbayes.ensemble.req_tail`; ~1.25x the cost), ``inline`` (one pass: after cycle 1 each
    experiment moves its Req origin to where the model's tail at its own cycle-1 posterior mean
    matches the data's, shifting that posterior as a linear-Gaussian one would be, then cycles 2..;
    the same answers as ``model`` within 0.1 sd median on thermal camera records, docs/results.md)
    or ``auto`` (the default: ``inline`` with the thermal bubble, whose records still settle from
    above at their end, ``mean`` otherwise). nuisance_integral (default likelihood, Gaussian bubble
    posteriors): what each experiment's likelihood of the parameters integrates its nuisances
    against -- ``req`` (the default): log Req against its preprocessing prior, Rmax and the
    alignment against the last cycle's prior given the parameters; ``prior``: all three against
    their preprocessing prior; ``cycle``: all three against the last cycle's prior (the inflated
    posterior of the cycle before, which already holds the data's information on Req: counted
    twice, each bubble's mu too narrow and pulled along the Req ridge; thermal camera records,
    20 paired seeds: mu covered 15 -> 20 of 20 with ``req``, G unchanged; ``prior`` moved G up by
    0.7 sd on polytropic records, the alignment's effect being far from linear over its prior:
    docs/results.md, "Which prior the nuisances are integrated against"). An experiment whose fitted
    Req ends more than :data:`~imrbayes.ensemble.req_tail.REQ_CONFLICT_Z` prior sd from its record's
    keeps Req against the last cycle's prior whatever this says: the first-order integral would
    move the material along the Req ridge to a point tens of sd from anything the fit visited
    (docs/results.md, "A Req in conflict is not extrapolated"). req_conflict_stop
    (default likelihood, Req estimated): after a cycle that leaves an experiment's Req more than
    this many prior sd from its preprocessing value, that experiment's later cycles are skipped
    (None: never). For fits whose only use is that comparison -- MIEnKS-MDA's Req prior, which
    keeps the record's Req beyond :data:`~imrbayes.ensemble.req_tail.REQ_CONFLICT_Z` -- where
    more cycles cannot bring such a Req back within the bound (docs/results.md, "The Req-prior
    fit stops on a decided conflict"). Every cycle records its Req z (``cycles[].req_z``).
    """

    n_ens: int | None = None
    n_iter: int = 5
    n_iter_later: int | None = None
    n_runs: int = 3
    rtps: float = 0.7
    t_end: float | None = None
    exact_moments: bool = True
    n_draws: int = 48
    loglik: bool = True
    fusion: str | None = None
    obs_weight: str | None = None
    likelihood: str = "default"
    screen: int = 96
    max_iter: int = 15
    bubble_posterior: str = "gaussian"
    is_draws: int = 1000
    is_rounds: int = 4
    is_prior_widen: float = 3.0
    req_tail: str = "auto"
    nuisance_integral: str = "req"
    req_conflict_stop: float | None = None

    def resolved(self) -> "En4DVarSettings":
        """The settings with the likelihood's own choices filled in (``paper``: averaged cost and the
        prior-corrected fusion unless set) and the members per experiment (24; the paper's 48)."""
        if self.likelihood == "paper":
            return replace(self, fusion=self.fusion or "prior", obs_weight=self.obs_weight or "mean",
                           n_ens=PAPER_N_ENS if self.n_ens is None else self.n_ens,
                           n_iter_later=self.n_iter if self.n_iter_later is None else self.n_iter_later)
        return replace(self, n_ens=DEFAULT_N_ENS if self.n_ens is None else self.n_ens,
                       n_iter_later=(min(DEFAULT_N_ITER_LATER, self.n_iter) if self.n_iter_later is None
                                     else self.n_iter_later))

    def check(self):
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
        if self.bubble_posterior not in ("gaussian", "sampled"):
            raise InputError("bubble_posterior", f"must be 'gaussian' or 'sampled', got {self.bubble_posterior!r}")
        if self.bubble_posterior == "sampled" and s.likelihood != "default":
            raise InputError("bubble_posterior", "'sampled' needs the default likelihood (the paper's keeps the ensemble)")
        if self.req_tail not in ("auto", "mean", "model", "inline"):
            raise InputError("req_tail", f"must be 'auto', 'mean', 'model' or 'inline', got {self.req_tail!r}")
        if self.req_tail in ("model", "inline") and s.likelihood != "default":
            raise InputError("req_tail", f"'{self.req_tail}' needs the default likelihood (the paper's takes Req as known)")
        if self.nuisance_integral not in ("prior", "req", "cycle"):
            raise InputError("nuisance_integral", f"must be 'cycle', 'req' or 'prior', got {self.nuisance_integral!r}")
        if not (np.isfinite(self.is_prior_widen) and self.is_prior_widen >= 1.0):
            raise InputError("is_prior_widen", f"must be a number >= 1, got {self.is_prior_widen!r}")
        if self.req_conflict_stop is not None and not (np.isfinite(self.req_conflict_stop) and self.req_conflict_stop > 0):
            raise InputError("req_conflict_stop", f"must be a positive number of prior sd or None, got {self.req_conflict_stop!r}")
        if self.is_draws < 50 or self.is_rounds < 1:
            raise InputError("is_draws/is_rounds", f"need at least 50 draws and one round, got {self.is_draws}, "
                                                   f"{self.is_rounds}")


def req_tail_mode(settings: En4DVarSettings, fm) -> str:
    """``mean``, ``model`` or ``inline``: what ``settings.req_tail`` means for forward model ``fm``.
    ``auto`` is ``inline`` with the thermal bubble and the default likelihood: its record's tail mean
    is high (+2.3 % on 1 Mfps camera records to t* = 3.6, docs/results.md), while a polytropic bubble
    has settled (+0.3 %) and the paper's likelihood takes Req as known. (:func:`fit_en4dvar` runs
    ``inline`` as ``model`` when given a start or one cycle.)"""
    s = settings.resolved()
    if s.req_tail != "auto":
        return s.req_tail
    thermal = getattr(getattr(fm, "options", None), "bubble", "thermal") == "thermal"
    return "inline" if thermal and s.likelihood == "default" else "mean"


#: the first pass of ``req_tail=model``: it only has to place the material near the data's (the
#: correction moves by <= 0.16 % of Req between this and the full fit on thermal camera records,
#: against a Req prior sd of 4-6 %; docs/results.md), so one cycle from the prior mean
REQ_TAIL_FIRST_PASS = {"n_runs": 1, "screen": 0, "n_draws": 1, "loglik": False, "bubble_posterior": "gaussian"}


def fit_window(obs, K: int, obs_weight: str = "mean"):
    """Samples 1..K (inclusive) of the grid: observation vector (n_exp, K) and weights 1/(K P_k)
    (``obs_weight="mean"``, methods.md's averaged cost) or 1/P_k (``"sum"``, every sample a full
    independent observation)."""
    y = obs.R_star[:, 1:K + 1]
    weight = 1.0 / ((K if obs_weight == "mean" else 1.0) * obs.P[1:K + 1])
    return y, weight


def last_index(obs, t_end) -> int:
    if t_end is None:
        return obs.n_samples - 1
    K = int(np.searchsorted(obs.t_star, float(t_end) + 1e-9, side="right") - 1)
    if K < 2:
        raise InputError("t_end", f"fitting window t* <= {t_end} holds fewer than two samples")
    return K


def en4dvar_unit(unit: Unit, rng) -> dict:
    """Every restart cycle of one experiment (methods.md §3): its last posterior and the prior
    that cycle started from."""
    d = unit.data
    space, s = d["space"], d["settings"]
    runner = runner_for(d)
    before = (runner.n_member_runs, runner.n_failed)
    rmax, req, t_eval = d["rmax"], d["req"], d["t_eval"]

    def evaluate(groups, Z):
        out = runner.simulate(space.to_si(Z), np.full(len(Z), rmax), np.full(len(Z), req), t_eval)
        return out.R_star[:, 1:], out.failed | ~np.all(np.isfinite(out.R_star), axis=1)

    # the first cycle's ensemble: the global search's start where one was made, else the prior
    mean, cov = space.start_mean.copy(), space.start_cov.copy()
    cycles = []
    res = None
    req_factor = 1.0
    default = s.likelihood == "default"
    y, weight = d["y"], d["weight"]
    lik = W = None
    n_p = space.n
    if default:
        # Rmax, the time of the maximum and Req are inferred with the parameters: the ensemble is
        # augmented by (a, delta, rho) with the preprocessing prior (imrbayes.ensemble.likelihood)
        nu_sd = np.asarray(d["nuisance_sd"], dtype=np.float64)
        active = np.flatnonzero(nu_sd > 0)
        k = active.size
        j_rho = n_p + int(np.flatnonzero(active == 2)[0]) if 2 in active else None   # log Req's coordinate
        mean = np.concatenate([mean, np.zeros(k)])
        cov = np.block([[cov, np.zeros((n_p, k))], [np.zeros((k, n_p)), np.diag(nu_sd[active] ** 2)]])

        def nuisances(Z):
            nu = np.zeros((Z.shape[0], 3))
            nu[:, active] = Z[:, n_p:]
            return nu

        def evaluate(groups, Z):
            return predict(runner, space.to_si(Z[:, :n_p]), rmax, req, t_eval[1:], nuisances(Z), d.get("frames"))
    max_iter = s.max_iter if default else None
    for r in range(s.n_runs):
        n_iter = s.n_iter if r == 0 else s.n_iter_later
        if default:
            # the observation model at the current centre: cycle 1 with the record's noise alone, later
            # cycles also with the residual's level and autocorrelation
            f, _ = predict(runner, space.to_si(mean[None, :n_p]), rmax, req, t_eval[1:], nuisances(mean[None]),
                           d.get("frames"))
            lik = observation_model(d["y"], f[0], d["noise_var"], adapt=r > 0)
            W = lik["W"]
            y, weight = W @ d["y"], np.ones(d["y"].size)
            ev = _whitened(evaluate, W)
        else:
            ev = evaluate
        centre = mean
        if r == 0 and default and s.screen:
            centre, screen_info = screened_start(rng, ev, y, mean, cov, s.screen)
        if centre is mean:
            E0 = draw(rng, mean, cov, s.n_ens, exact=s.exact_moments)[None]
            res = gauss_newton(E0, ev, y[None], weight[None], n_iter=n_iter, rng=rng, max_iter=max_iter,
                               patience=s.n_iter)
        else:
            # both starts, one forward batch per iteration; the cycle goes on from the better end
            E0 = np.stack([draw(rng, c, cov, s.n_ens, exact=s.exact_moments) for c in (mean, centre)])
            both = gauss_newton(E0, ev, np.stack([y, y]), np.stack([weight, weight]), n_iter=n_iter, rng=rng,
                                max_iter=max_iter, patience=s.n_iter)
            J = posterior_cost(ev, y, both.mean, mean, cov)
            g = int(np.argmin(J))
            screen_info.update({"cost_end": [float(c) if np.isfinite(c) else None for c in J],
                                "cost_paths": [[float(c) for c in row if np.isfinite(c)] for row in both.cost],
                                "kept": ["prior mean", "screened"][g]})
            res = take_group(both, g)
        infl = rtps(res.prior_anoms, res.anoms, s.rtps)
        mean = res.mean[0].copy()
        cov = np.einsum("gnd,gne->gde", infl, infl)[0]
        req_z = None
        if default and 2 in active:
            # this cycle's Req against the preprocessing's, in its prior sd (req_tail.req_shift_z's z)
            req_z = float((req * np.exp(mean[j_rho]) - d["req"]) / (d["req"] * nu_sd[2]))
        # a decided conflict ends the fit before Req's origin moves (the reported Req stays this cycle's)
        stop = (s.req_conflict_stop is not None and req_z is not None and abs(req_z) > s.req_conflict_stop
                and r < s.n_runs - 1)
        if r == 0 and not stop and default and d.get("req_tail_t") is not None and 2 in active and s.n_runs > 1:
            # req_tail=inline: Req's origin moves to Req_hat / c, c the model's tail at this bubble's
            # cycle-1 posterior mean; that posterior is moved as a linear-Gaussian one would be by
            # the shift of Req's prior centre (m' = m + C[:, rho] dm0 / sd0^2), then cycles 2..
            a = mean[n_p + int(np.flatnonzero(active == 0)[0])] if 0 in active else 0.0
            new_req, c = tail_req(runner, space.to_si(mean[None, :n_p]), np.array([rmax * (1.0 + a)]),
                                  np.array([req]), [np.asarray(d["req_tail_t"], dtype=np.float64)])
            if c[0] != 1.0:
                shift = float(np.log(req / new_req[0]))        # rho' = rho + log(req / req')
                mean[j_rho] += shift
                mean -= res.cov[0][:, j_rho] * shift / nu_sd[2] ** 2
                req_factor, req = float(c[0]), float(new_req[0])
        used = np.isfinite(res.cost[0])
        cycles.append({"cycle": r + 1, "cost": res.cost[0][used], "n_failed": res.n_failed[0][used],
                       "n_redrawn": int(res.n_redrawn[0]), "stopped": bool(res.stopped[0]), "req_z": req_z,
                       **({"likelihood": {k_: v for k_, v in lik.items() if k_ != "W"}} if default else {})})
        if stop:
            break
    if default and s.screen:
        cycles[0]["screen"] = screen_info
    qa = res.prior_anoms[0]
    pm, pc, qm, qc = res.mean[0], res.cov[0], res.prior_ensemble[0].mean(axis=0), qa.T @ qa
    sampled = None
    if default and s.bubble_posterior == "sampled":
        # the posterior under a working prior (the parameter prior with its sd widened
        # is_prior_widen times, the nuisances' own), sampled from the ensemble's Gaussian; its
        # moments replace the ensemble's, and the fusion divides the working prior out again and
        # applies the parameter prior once. Why widened: a prior whose bulk is far from the truth
        # pulls each bubble's posterior along its likelihood ridge, a pull the Gaussian division
        # does not undo (camera records, paper prior: gel-level mu +2.6 %, G 80 % coverage with
        # the ensemble's Gaussians; docs/results.md)
        m0 = np.concatenate([space.prior_mean, np.zeros(k)])
        C0 = np.block([[space.prior_cov * s.is_prior_widen ** 2, np.zeros((n_p, k))],
                       [np.zeros((k, n_p)), np.diag(nu_sd[active] ** 2)]])
        ev_final = ev

        chunk = 4 * s.n_ens

        def log_target(Z):
            # in batches: a signal (Ctrl-C, SIGTERM) is handled between them, not after a whole
            # round of thermal solves (members are independent: the same numbers up to round-off,
            # ~1e-9 relative after the proposal refits)
            return np.concatenate([-posterior_cost(ev_final, y, Z[i:i + chunk], m0, C0)
                                   for i in range(0, Z.shape[0], chunk)])
        dr = adaptive_importance(log_target, pm, pc, rng, n_draws=s.is_draws, rounds=s.is_rounds)
        pm, pc, qm, qc = dr.mean, dr.cov, m0, C0
        thin = dr.thinned(2000, rng)
        sampled = {"ess": dr.ess, "n_draws": int(dr.x.shape[0]), "x": thin.x[:, :n_p], "w": thin.w}
    lik_pm, lik_pc, lik_qm, lik_qc = pm[:n_p], pc[:n_p, :n_p], qm[:n_p], qc[:n_p, :n_p]
    last_z = cycles[-1]["req_z"]
    # a Req in conflict with its record (beyond REQ_CONFLICT_Z prior sd) is not integrated against
    # the preprocessing prior: the Gaussian algebra would move the parameters linearly along the
    # Req ridge to where that prior sits, tens of sd from any point the fit visited (xy002: Req z
    # 57, G 13.0 kPa with the fit's own rmse 0.025 R* moved to 56 kPa, whose curve at the fitted
    # nuisances misses by 0.12 R*; docs/results.md, "A Req in conflict is not extrapolated")
    integral_used, conflict_kept = s.nuisance_integral, False
    if default and k and sampled is None and s.nuisance_integral != "cycle":
        conflict_kept = last_z is not None and abs(last_z) > REQ_CONFLICT_Z
        # the experiment's likelihood of the parameters with some nuisances integrated out against
        # their preprocessing prior N(0, nu_sd^2) instead of the last cycle's prior (the inflated
        # posterior of the cycle before, which already holds what the data say of them): the joint
        # likelihood (last posterior / last prior) under a reference prior that is the cycle's
        # with those coordinates replaced, then the parameter marginals' ratio
        swap = {n_p + j: nu_sd[which] for j, which in enumerate(active)
                if (s.nuisance_integral == "prior" and which != 2) or (which == 2 and not conflict_kept)}
        if conflict_kept:
            integral_used = "cycle" if not swap else "prior (Req: cycle)"
        if swap:                # (with Req known and nuisance_integral=req there is nothing to swap)
            lik_pm, lik_pc, lik_qm, lik_qc = marginal_under_reference(pm, pc, qm, qc, n_p, swap)
    # the parameters' marginals (the nuisances are reported per experiment)
    out = {"mean": lik_pm, "cov": lik_pc, "prior_mean": lik_qm, "prior_cov": lik_qc,
           "stopped": bool(res.stopped[0]), "cycles": cycles, "sampled": sampled, "req_m": float(req),
           "req_factor": req_factor, "req_conflict": bool(conflict_kept), "nuisance_integral": integral_used}

    if sampled is not None:
        out["ensemble_mean"], out["ensemble_cov"] = res.mean[0][:n_p], res.cov[0][:n_p, :n_p]
        out["ensemble_prior_mean"], out["ensemble_prior_cov"] = res.prior_ensemble[0].mean(axis=0)[:n_p], (qa.T @ qa)[:n_p, :n_p]
    if default:
        nu_mean, nu_sd_post = np.zeros(3), np.zeros(3)
        nu_mean[active] = pm[n_p:]
        nu_sd_post[active] = np.sqrt(np.diag(pc)[n_p:])
        out.update({"whiten": W, "likelihood": {k_: v for k_, v in lik.items() if k_ != "W"},
                    "var": lik["var"], "alpha": lik["alpha"], "nu_mean": nu_mean, "nu_sd": nu_sd_post})
    return {**out, **runner.counts_since(before)}


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
    return replace(res, **{f.name: getattr(res, f.name)[g:g + 1] for f in fields(res)
                           if getattr(res, f.name) is not None})


def screened_start(rng, evaluate, y, mean, cov, n: int):
    """The first cycle's centre: the best of the prior mean and ``n`` prior draws (parameters and
    nuisances together) by the posterior cost 1/2 ||y - h(z)||^2 + 1/2 (z - m)^T C^-1 (z - m)
    (``y`` and ``evaluate`` whitened). Why: the Gauss-Newton iterate stays in the basin its
    starting centre lies in, and on measured records the objective is multimodal along the G-mu
    ridge jointly with the alignment (docs/results.md 2a'). The cycle's prior is then N(best, C):
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


def fit_en4dvar(fm, obs, space, settings: En4DVarSettings | None = None, seed: int = 0,
                runner: Runner | None = None, progress=None, execution=None,
                req_tail_start: ReqTailStart | None = None) -> FitResult:
    """Fit constant parameters to every experiment and fuse (see module doc).

    fm : ForwardModel; obs : Observations; space : ParamSpace; seed: the run seed (each experiment
    draws from its own stream, from the seed and its unit id). Units: one per experiment
    (:func:`en4dvar_unit`, ``exp=003``: every cycle), then one per experiment after the fusion
    (:func:`en4dvar_post_unit`, ``post=fit/exp=003``: fitted curves, draws' log-likelihood);
    ``execution`` (:class:`~imrbayes.execution.Execution`) says where they run and are checkpointed
    (default: this process, with ``runner``). ``req_tail_start``
    (:class:`~imrbayes.ensemble.req_tail.ReqTailStart`): with ``req_tail=model`` or ``inline``, the
    material and Rmax of an existing fit of the same records at which the model's tail is evaluated
    once, before the one pass (instead of the quick first pass or the move after cycle 1); ignored
    otherwise.
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
        res = _fit_en4dvar(fm, obs, space, s, seed, runner, progress, ex, tag={"req": "inline"}, inline=True)
        res.details["req_tail"] = {
            "method": "inline", "setting": s.req_tail, "factor": res.details.pop("req_factor"),
            "req_tail_mean_m": obs.req_m.tolist(), "req_prior_mean_m": res.details.pop("req_prior_mean_m"),
            "note": "each Req's origin moved after cycle 1 to where the model's mean over the frames the preprocessing "
                    "averaged equals the data's (model at that bubble's cycle-1 posterior mean), that posterior "
                    "shifted as a linear-Gaussian one would be; one pass"}
        return res
    if mode not in ("model", "inline") or not tails:
        res = _fit_en4dvar(fm, obs, space, s, seed, runner, progress, ex)
        note = ("each Req's prior centred on the preprocessing's value" if mode == "mean" else
                "no experiment's Req came from its record's tail (given, or no tail measured): nothing to re-centre, "
                "one pass")
        res.details["req_tail"] = {"method": mode, "setting": s.req_tail, "factor": [1.0] * obs.n_exp, "note": note}
        return res
    t0 = time.perf_counter()
    first = None
    if req_tail_start is not None:
        theta = np.asarray(req_tail_start.theta_si, dtype=np.float64)
        rmax = np.asarray(req_tail_start.rmax_m, dtype=np.float64)
        if theta.ndim not in (1, 2) or theta.shape[-1] != space.n or rmax.shape != (obs.n_exp,):
            raise ValueError(f"req_tail_start: theta_si {theta.shape} / rmax_m {rmax.shape} do not match "
                             f"{space.n} parameters and {obs.n_exp} experiments")
        where = f"the {req_tail_start.source}"
    else:
        first = _fit_en4dvar(fm, obs, space, replace(s, **REQ_TAIL_FIRST_PASS), seed, runner, progress, ex,
                             tag={"req": "first"})
        theta = np.array([first.estimate[nm]["mean"] for nm in space.names])
        rmax = np.array([p["nuisance"]["rmax_m"]["mean"] if "nuisance" in p else r
                         for p, r in zip(first.per_experiment, obs.rmax_m)])
        where = "a quick first fit's estimate and Rmax: one cycle, no screening"
    obs2, factor = model_tail_req(runner, obs, theta, rmax)
    if np.all(factor == 1.0):        # every correction failed: the tail means stand
        obs2, tag = obs, None
        note = "the model's tail could not be computed for any experiment: Req's prior is the tail mean"
    else:
        # one tag whatever placed the material: the same unit seeds, so a given start and the first
        # pass differ only by their factors (stiff PA 1-5: G 10.29 against 10.32 kPa; with other
        # draws 8.2, another basin of these records)
        tag = {"req": "model"}
        note = ("each Req's prior centred where the model's mean over the frames the preprocessing averaged equals "
                f"the data's (model at {where}); the estimate is the full fit after it")
    res = _fit_en4dvar(fm, obs2, space, s, seed, runner, progress, ex, tag=tag)
    info = {"method": "model", "setting": s.req_tail, "factor": factor.tolist(), "req_tail_mean_m": obs.req_m.tolist(),
            "req_prior_mean_m": obs2.req_m.tolist(), "note": note}
    if first is None:
        info["start"] = {"source": req_tail_start.source, "theta_si": theta.tolist(), "rmax_m": rmax.tolist()}
    else:
        info.update({"first_pass_estimate": {nm: first.estimate[nm]["mean"] for nm in space.names},
                     "first_pass_rmax_m": rmax.tolist(), "first_pass_settings": dict(REQ_TAIL_FIRST_PASS)})
        # the quick first pass, for the record (not the tail-mean fit of the same data: that has three cycles)
        res.details.setdefault("alternative_estimates", {})["req_tail_first_pass"] = {
            nm: first.estimate[nm] for nm in space.names}
        res.details["member_runs"] += first.details["member_runs"]
    res.details["req_tail"] = info
    res.runtime_s = time.perf_counter() - t0
    return res


def _fit_en4dvar(fm, obs, space, s, seed, runner, progress, ex, tag=None, inline=False) -> FitResult:
    """:func:`fit_en4dvar` with Req's prior as ``obs`` has it; ``tag`` a prefix of the unit ids (a
    second pass must not reuse the first's checkpoints)."""
    tag = tag or {}
    default = s.likelihood == "default"
    t0 = time.perf_counter()
    spec, token = fm_spec(fm), register_runner(runner)
    rng = np.random.default_rng(seed)                   # the fused posterior's draws (units have their own)
    K = last_index(obs, s.t_end)
    t_eval = obs.t_star[:K + 1]
    y, weight = fit_window(obs, K, s.obs_weight or "sum")
    n_exp = obs.n_exp
    base = {"spec": spec, "runner": token, "space": space, "settings": s, "t_eval": t_eval}
    noise_var = [record_noise_sd(obs, n) ** 2 for n in range(n_exp)]
    rep = ex.run([Unit(unit_id(**tag, exp=n), {**base, "rmax": float(obs.rmax_m[n]), "req": float(obs.req_m[n]),
                                        "y": y[n], "weight": weight, "noise_var": noise_var[n],
                                        "nuisance_sd": nuisance_prior_sd(obs, n),
                                        "req_tail_t": obs.req_tail_t[n] if inline and obs.req_tail_t else None,
                                        "frames": None if obs.frame_t is None else
                                        frame_operator(obs.frame_t[n], t_eval[1:])})
                  for n in range(n_exp)], en4dvar_unit, seed, desc="en4dvar experiments")
    warnings = []
    failed_units = []
    ok = []
    for n in range(n_exp):
        uid = unit_id(**tag, exp=n)
        if uid in rep.results:
            ok.append(n)
        else:
            err = rep.failures[uid].error
            failed_units.append({"unit": uid, "experiment": obs.names[n], "error": err})
            warnings.append(f"experiment {obs.names[n]!r} failed ({err}); left out of the fusion")
    if not ok:
        raise RuntimeError(f"every experiment failed (e.g. {failed_units[0]['error']})")
    R = [rep.results[unit_id(**tag, exp=n)] for n in ok]
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
    cycles = []
    for c in range(s.n_runs):
        # an experiment stopped by req_conflict_stop has fewer cycles: each cycle lists those that ran it
        ran = [(n, r["cycles"][c]) for n, r in zip(ok, R) if len(r["cycles"]) > c]
        if not ran:
            break
        cyc = [x for _, x in ran]
        cycles.append({"cycle": c + 1, "cost": [np.asarray(x["cost"]).tolist() for x in cyc],
                       "n_failed": [np.asarray(x["n_failed"]).tolist() for x in cyc],
                       "n_redrawn": [int(x["n_redrawn"]) for x in cyc], "stopped": [bool(x["stopped"]) for x in cyc],
                       "req_z": [x.get("req_z") for x in cyc],
                       "experiments": [obs.names[n] for n, _ in ran],
                       **({"screen": [x["screen"] for x in cyc]} if all("screen" in x for x in cyc) else {})})
        if progress is not None:
            progress(c + 1)
    post_mean = np.stack([r["mean"] for r in R])
    post_cov = np.stack([r["cov"] for r in R])
    hier = alternatives = None
    if default:
        Lam, eta, _, n_clip = likelihood_terms(post_mean, post_cov, np.stack([r["prior_mean"] for r in R]),
                                               np.stack([r["prior_cov"] for r in R]))
        hier = random_effects(Lam, eta, space.prior_mean, space.prior_cov, names=space.names)
        fus = fuse_likelihoods(post_mean, post_cov, np.stack([r["prior_mean"] for r in R]),
                               np.stack([r["prior_cov"] for r in R]), space.prior_mean, space.prior_cov)
        warnings.extend(hier.notes)
        # each experiment's own posterior: the parameter prior times its likelihood
        own_cov = np.stack([np.linalg.inv(np.linalg.inv(space.prior_cov) + L) for L in Lam])
        own_mean = np.stack([C @ (np.linalg.solve(space.prior_cov, space.prior_mean) + e)
                             for C, e in zip(own_cov, eta)])
        post_mean, post_cov = own_mean, own_cov
        if s.bubble_posterior == "sampled":
            alternatives = _sampled_alternatives(R, space, hier, np.random.default_rng((seed, 19)))
            thin = [(obs.names[n], float(r["sampled"]["ess"])) for n, r in zip(ok, R)
                    if float(r["sampled"]["ess"]) < MIN_SAMPLED_ESS]
            if thin:
                # a few draws carry all the weight: the proposal missed the posterior, and its
                # "moments" are those draws' (UMich PA10: ESS 1.0-2.7 of 4000, two bubbles' sd 0)
                warnings.append(f"bubble_posterior=sampled: importance sampling degenerate for {len(thin)} of {len(ok)} "
                                f"experiment(s) ({', '.join(f'{nm} ESS {e:.1f}' for nm, e in thin[:5])}"
                                f"{' ...' if len(thin) > 5 else ''}, fewer than {MIN_SAMPLED_ESS} effective draws): "
                                f"their posteriors rest on a few draws and the gel-level estimate is not to be "
                                f"trusted; use the default bubble_posterior=gaussian (details['sampled'])")
    elif s.fusion == "prior":
        fus = fuse(post_mean, post_cov, space.prior_mean, space.prior_cov)
    else:
        fus = fuse_likelihoods(post_mean, post_cov, np.stack([r["prior_mean"] for r in R]),
                               np.stack([r["prior_cov"] for r in R]), space.prior_mean, space.prior_cov)
    if fus.notes:
        warnings.extend(fus.notes)
    n_stopped = sum(bool(r["stopped"]) for r in R)
    if n_stopped:
        warnings.append(f"{n_stopped} experiment(s) stopped early: too many failed members")
    # the reported estimate: the gel-level mean (default likelihood), else the fused Gaussian
    est_mean, est_cov = (hier.mean, hier.cov) if hier is not None else (fus.mean, fus.cov)
    # posterior draws (1 chain) of the reported Gaussian
    Zd = draw(rng, est_mean, est_cov, s.n_draws, exact=False)
    post = {nm: space.to_si(Zd)[None, :, i] for i, nm in enumerate(space.names)}
    want_ll = s.loglik and s.n_draws > 0
    # after the fusion, per experiment: R* at the fused median, at its own mean, at every draw
    fused_si = space.to_si(est_mean)[None, :]
    post_units = []
    for i, n in enumerate(ok):
        pts = [fused_si, space.to_si(post_mean[i])[None, :]] + ([space.to_si(Zd)] if want_ll else [])
        post_units.append(Unit(unit_id(**tag, post="fit", exp=n), {"spec": spec, "runner": token, "t_eval": t_eval,
                                                             "rmax": float(obs.rmax_m[n]), "req": float(obs.req_m[n]),
                                                             "points": np.vstack(pts),
                                                             "nu": R[i]["nu_mean"] if default else None,
                                                             "frames": None if obs.frame_t is None or not default
                                                             else frame_operator(obs.frame_t[n], t_eval[1:])}))
    prep = ex.run(post_units, en4dvar_post_unit, seed, desc="en4dvar fitted curves")
    fitted = np.full_like(obs.R_star, np.nan)
    own = np.full_like(obs.R_star, np.nan)
    Yd = np.full((s.n_draws, n_exp, K), np.nan)
    for n in ok:
        uid = unit_id(**tag, post="fit", exp=n)
        if uid not in prep.results:
            err = prep.failures[uid].error
            failed_units.append({"unit": uid, "experiment": obs.names[n], "error": err})
            warnings.append(f"experiment {obs.names[n]!r}: fitted curves failed ({err})")
            continue
        r = prep.results[uid]
        member_runs += int(r["member_runs"])
        failed_runs += int(r["failed_member_runs"])
        fitted[n, :K + 1] = r["R_star"][0]
        own[n, :K + 1] = r["R_star"][1]
        if want_ll:
            Yd[:, n] = r["R_star"][2:, 1:]
    mask = np.zeros(obs.R_star.shape, dtype=bool)
    mask[:, 1:K + 1] = True
    mask[[n for n in range(n_exp) if not np.isfinite(fitted[n, 1:K + 1]).any()]] = False
    per = []
    for n in range(n_exp):
        if n not in ok:
            per.append({"name": obs.names[n], "failed": True,
                        "error": next(f["error"] for f in failed_units if f["experiment"] == obs.names[n])})
            continue
        i = ok.index(n)
        entry = {"name": obs.names[n], "estimate": gaussian_estimate(space, post_mean[i], post_cov[i]),
                 "mean_internal": post_mean[i].tolist(), "cov_internal": post_cov[i].tolist(),
                 "rmse_own": rmse(own[n], obs.R_star[n], mask[n]) if mask[n].any() else float("nan")}
        if default:
            r = R[i]
            entry["nuisance"] = nuisance_summary(r["nu_mean"], r["nu_sd"], nuisance_prior_sd(obs, n),
                                                 float(obs.rmax_m[n]), float(obs.req_m[n]), float(obs.t0_s[n]),
                                                 float(obs.tc_s[n]))
            entry["likelihood"] = {**r["likelihood"], "nuisance_integral": r.get("nuisance_integral", s.nuisance_integral),
                                   "req_conflict": bool(r.get("req_conflict", False))}
        per.append(entry)
    conflicted = [obs.names[n] for i, n in enumerate(ok) if R[i].get("req_conflict")]
    if conflicted:
        warnings.append(f"{len(conflicted)} of {len(ok)} experiment(s) fit a Req more than {REQ_CONFLICT_Z:g} prior sd "
                        f"from the record's: {', '.join(conflicted[:5])}{' ...' if len(conflicted) > 5 else ''}. Their "
                        f"likelihood keeps the fit's Req (the last cycle's prior) instead of integrating Req against "
                        f"the record's, which would extrapolate the material along the Req ridge "
                        f"(per_experiment[].likelihood.nuisance_integral)")
    if default:
        # a nuisance pulled far outside what its record says absorbs model error: say so
        far = []
        for i, n in enumerate(ok):
            prior_sd = nuisance_prior_sd(obs, n)
            z = np.where(prior_sd > 0, np.abs(R[i]["nu_mean"]) / np.where(prior_sd > 0, prior_sd, 1.0), 0.0)
            moved = [("Rmax", "the time of the maximum", "Req")[j] for j in np.flatnonzero(z > 3.0)]
            if moved:
                far.append(f"{obs.names[n]} ({', '.join(moved)})")
        if far:
            warnings.append(f"{len(far)} of {len(ok)} experiment(s) need nuisances more than 3 prior sd from what "
                            f"preprocessing measured: {'; '.join(far[:5])}{' ...' if len(far) > 5 else ''}. The "
                            f"model is absorbing misfit into the geometry; read the material estimate with care "
                            f"(per_experiment[].nuisance)")
    ll = None
    if want_ll:
        if default:      # per-sample Gaussian with each experiment's tempered variance (nuisance correlation left out)
            var = np.full(n_exp, np.nan)
            for i, n in enumerate(ok):
                var[n] = R[i]["var"] / R[i]["alpha"]
            lp = loglik_pointwise(Yd, y[None], var[None, :, None])
        else:
            lp = loglik_pointwise(Yd, y[None], obs.P[1:K + 1])
        ll = {"R": np.where(np.isfinite(lp), lp, -1e300)[None]}
    if default:
        eff = [float(R[ok.index(n)]["likelihood"]["effective_samples"]) if n in ok else None for n in range(n_exp)]
        likelihood = {"name": "default", "effective_samples": eff, "n_samples": K,
                      "noise": "each record's fourth-difference noise sd, raised to the RMS of its nuisance-corrected "
                               "residual where the model does not reach the noise; each experiment tempered by "
                               "n_eff/K (integrated autocorrelation time of the residual); Rmax, the time of the "
                               "maximum and Req integrated out to first order",
                      "fusion": "random effects across experiments (gel-level mean, between-bubble sd, predictive)"}
    else:
        likelihood = {"name": "paper", "noise": "P_k of preprocessing (" + str(s.obs_weight) + " cost)",
                      "fusion": str(s.fusion), "effective_samples": None}
    details = {"settings": asdict(s), "n_fit_steps": K, "t_end_star": float(obs.t_star[K]), "likelihood": likelihood,
               "cycles": cycles, "fusion": fus.to_dict(), "rmse": rmse(fitted, obs.R_star, mask),
               "fused_mean_internal": fus.mean.tolist(), "fused_cov_internal": fus.cov.tolist(),
               "fused_cov_si": si_covariance(space, fus.mean, fus.cov).tolist(),
               "parameter_space": space.describe(),
               "member_runs": member_runs, "failed_member_runs": failed_runs,
               **({"req_factor": req_factor.tolist(), "req_prior_mean_m": obs.req_m.tolist()} if inline else {}),
               "failed_units": failed_units, "experiments_used": [obs.names[n] for n in ok],
               "gauss_newton": "normalised anomalies: H = I + (1/N_t) sum Y'^T P^-1 Y', grad = w - ...; identical "
                               "iterates to the paper's (N_En - 1) form with unnormalised anomalies",
               "fitted_curve": "forward run at the fused posterior median exp(mean of log parameters)"
                               + (", each experiment at its inferred Rmax, time of the maximum and Req (posterior "
                                  "mean) and through its camera frames" if default else "")}
    estimate = gaussian_estimate(space, est_mean, est_cov)
    if alternatives is not None:
        details["sampled"] = alternatives.pop("info")
        details["alternative_estimates"] = alternatives
    if hier is not None:
        h = hier.summaries(space)
        estimate = h["estimate"]
        details.update({"between_experiments": h["between_experiments"], "predictive": h["predictive"],
                        "random_effects": hier.to_dict(), "pooled_mean_internal": fus.mean.tolist(),
                        "pooled_cov_internal": fus.cov.tolist()})
        loo = leave_one_out(Lam, eta, space.prior_mean, space.prior_cov, names=space.names)
        if loo is not None:
            details["leave_one_bubble_out"] = loo
            from scipy.stats import binomtest
            for name, k in loo["n_inside"].items():
                if binomtest(k, loo["n"]).proportion_ci(method="wilson").high < loo["level"]:
                    warnings.append(f"{name}: leaving one bubble out, the others' {loo['level']:.0%} predictive "
                                    f"holds its own estimate in only {k} of {loo['n']} (the scatter model is too "
                                    "narrow for these bubbles; details['leave_one_bubble_out'])")
    whiten = offsets = None
    if default:
        whiten = np.full((n_exp, K, K), np.nan)
        offsets = np.zeros((3, n_exp, 3))        # prior sd, posterior mean, posterior sd of (a, delta, rho)
        for i, n in enumerate(ok):
            whiten[n] = R[i]["whiten"]
            offsets[:, n] = [nuisance_prior_sd(obs, n), R[i]["nu_mean"], R[i]["nu_sd"]]
    return FitResult(
        method="en4dvar", model=fm.constitutive.name, param_names=tuple(space.names),
        estimate=estimate, fitted=fitted, fit_mask=mask,
        mean_internal=est_mean, cov_internal=est_cov, per_experiment=per, details=details,
        posterior=post, log_likelihood=ll, posterior_dims={"R": ["experiment", "time"]},
        coords={"experiment": list(obs.names), "time": obs.t_star[1:K + 1]},
        runtime_s=time.perf_counter() - t0, warnings=warnings,
        window_posteriors=[fitting_window_posterior(fm, obs, space, K, s.obs_weight or "sum", fus.mean, fus.cov,
                                                    whiten, offsets)])


def _draws_estimate(space, dr: WeightedDraws) -> dict:
    """SI mean, sd and equal-tailed 95 % interval of each parameter from weighted draws of z."""
    out = {}
    for i, name in enumerate(space.names):
        v = np.exp(dr.x[:, i]) if space.positive[i] else dr.x[:, i]
        m = float(dr.w @ v)
        lo, hi = weighted_quantiles(v, dr.w, [0.025, 0.975])
        out[name] = {"mean": m, "sd": float(np.sqrt(dr.w @ (v - m) ** 2)), "hdi95": [float(lo), float(hi)],
                     "interval": "equal-tailed 95 %"}
    return out


def _sampled_alternatives(R, space, hier, rng) -> dict:
    """With ``bubble_posterior="sampled"``: the gel-level estimate two other ways, for comparison
    (details["alternative_estimates"]): from the ensembles' Gaussians (what ``gaussian`` reports),
    and from the sampled posteriors themselves (not their moments) at the fitted between-bubble sd
    (:func:`~imrbayes.ensemble.sampled.fuse_draws`)."""
    Lam_e, eta_e, _, _ = likelihood_terms(np.stack([r["ensemble_mean"] for r in R]), np.stack([r["ensemble_cov"] for r in R]),
                                          np.stack([r["ensemble_prior_mean"] for r in R]),
                                          np.stack([r["ensemble_prior_cov"] for r in R]))
    ens = random_effects(Lam_e, eta_e, space.prior_mean, space.prior_cov, names=space.names, intervals=False)
    draws = [WeightedDraws(r["sampled"]["x"], r["sampled"]["w"], float(r["sampled"]["ess"])) for r in R]
    T = np.nan_to_num(hier.tau) ** 2
    fused = fuse_draws(draws, space.prior_mean, space.prior_cov, T, hier.mean, hier.cov, rng,
                       draw_prior=(R[0]["prior_mean"], R[0]["prior_cov"]))
    return {"ensemble_gaussian": ens.summaries(space)["estimate"], "sampled_fusion": _draws_estimate(space, fused),
            "info": {"ess_per_experiment": [float(r["sampled"]["ess"]) for r in R],
                     "draws_per_experiment": [int(r["sampled"]["n_draws"]) for r in R], "fusion_ess": fused.ess,
                     "note": "each experiment's posterior of parameters and nuisances by adaptive importance "
                             "sampling (multivariate t proposals from the ensemble's Gaussian); the reported "
                             "estimate fuses these posteriors' moments; alternative_estimates: the ensembles' "
                             "Gaussians, and the sampled posteriors fused as kernel densities"}}


def fitting_window_posterior(fm, obs, space, K: int, obs_weight: str, mean, cov, whiten=None,
                             offsets=None) -> WindowPosterior:
    """The density the fused Gaussian approximates: every experiment from its maximum over samples
    1..K with the parameter prior and weight 1/K (``obs_weight="mean"``) or 1 (``"sum"``), or, with
    ``whiten`` (n_exp, K, K), the default likelihood's whitened residuals (no between-bubble
    scatter: the pooled, product-rule posterior, which ``mean``/``cov`` then are)."""
    c, rule = (1.0 / K, "1/N_t (En4D-Var averaging)") if obs_weight == "mean" else (1.0, "1 (plain likelihood)")
    desc = {"kind": "fitting window from the maximum", "samples": [1, K], "weight_rule": rule,
            "state": "maximum radius (exact)"}
    if whiten is not None:
        desc.update({"weight_rule": "default likelihood: ||W_n (y_n - R_n)||^2 per experiment (noise, nuisances, "
                                    "tempering)", "gaussian": "pooled over experiments (no between-bubble scatter)"})
    return WindowPosterior(
        index=0, start=0, samples=(1, K), mean=np.asarray(mean, float), cov=np.asarray(cov, float),
        prior_mean=space.prior_mean, prior_cov=space.prior_cov, weight=np.full(K, c),
        start_state=np.array(fm.initial_state(obs.rmax_m, obs.req_m).y, dtype=np.float64),
        # the Req each experiment's nuisance prior is centred on (req_tail=model moves it off the data's
        # tail mean): the MCMC target must run at the same one
        start_req_m=np.asarray(obs.req_m, dtype=np.float64).copy(),
        description=desc, whiten=whiten, **({} if offsets is None else
                                            {"nuisance_sd": offsets[0], "nuisance_mean": offsets[1],
                                             "nuisance_post_sd": offsets[2],
                                             "frames": None if obs.frame_t is None else
                                             [frame_operator(f, obs.t_star[1:K + 1]) for f in obs.frame_t]}))


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
        s = settings.resolved()     # cycles x iterations x members, then the fitted curves and the draws
        n = (s.n_iter + (s.n_runs - 1) * s.n_iter_later) * s.n_ens * n_exp + 2 * n_exp + (s.n_draws * n_exp if s.loglik else 0)
        if s.likelihood == "default":       # the observation model: one run per cycle
            n += s.n_runs * n_exp
            # (iterations past n_iter up to max_iter are not counted: the bar is an estimate)
            if s.screen:    # the screen, and at most one more start in cycle 1 (scored by one run per start)
                n += (s.screen + 1 + s.n_iter * s.n_ens + 2) * n_exp
        if s.likelihood == "default" and getattr(s, "req_tail", "mean") == "model":
            n += s.n_iter * s.n_ens * n_exp + 3 * n_exp     # req_tail's quick first pass
        elif s.likelihood == "default" and getattr(s, "req_tail", "mean") in ("inline", "auto"):
            n += 3 * n_exp      # the model's tail after cycle 1 (auto: thermal only)
        return n

    @staticmethod
    def figures(obs, res, fdir):
        from imrbayes.ensemble.figures import experiments_figure
        return [experiments_figure(res, fdir / "experiments.png")]
