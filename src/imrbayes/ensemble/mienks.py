"""MIEnKS-MDA: sliding-window ensemble smoother with state hand-off (methods.md §4, §7).

Windows of L samples shifted by h (:mod:`imrbayes.ensemble.windows`). For every experiment an
ensemble of N_En augmented members [state q (forward-model state vector), z (internal
parameters: log G, log mu)] is carried through the windows:

1. window j starts at sample s_j = j h with the ensemble at t*_{s_j} (window 0: the state at the
   maximum radius, parameters drawn from the prior);
2. ensemble-space Gauss–Newton (:mod:`imrbayes.ensemble.gn`, N_iter iterations, transform variant)
   on the augmented members, the forward model run from t*_{s_j} over the window's L samples, cost
   1/2 sum_k c_nk (y_k - <Y_k> - Y'_k w)^2 + 1/2 w^T w with the observation weights c_nk of the
   likelihood (below);
3. the experiments' parameter posteriors (the z-block of each augmented posterior) are combined
   (below) -> the window's estimate N(mu_j, Sigma_j);
4. RTPS (factor a) on the parameter spread (the state's is left alone);
5. **hand-off**: the posterior ensemble is propagated from t*_{s_j} to t*_{s_j + h}; its full
   evolved state (R, Rdot, p_b, stress and thermal/vapour fields) and its parameters form window
   j+1's prior ensemble. Members whose propagation failed (or whose analysed state is not
   physical, :meth:`ForwardModel.state_is_valid`: R* <= 0, p_b <= 0, vapour fraction outside
   [0, 1], non-finite) are redrawn from the Gaussian of the valid members (counted; per window,
   ``handoff_failures`` says how many analysed members per experiment had an unphysical state
   and how many failed in all).
   If fewer than a quarter of an experiment's members survive, its analysis is rejected for that
   window: the window's prior ensemble is handed on instead (reported in ``analysis_rejected``).

The window combination never feeds back into the experiments' ensembles (each carries its own
parameters), so it is computed after the sweep over the windows.

Likelihood ``default`` (methods.md §7)
--------------------------------------
* **Each sample counts once** (§7.1): c_nk = beta_jk alpha_n / sigma_n^2 with the MDA coefficients
  beta_jk = 1/|I(k)| (the weights of sample k over the windows holding it sum to one; no 1/L).
  Sample 0 (the maximum, R* = 1 by construction) has weight 0, as in En4D-Var.
* **Noise estimated** (§7.2): sigma_n is experiment n's own noise sd
  (:func:`imrbayes.ensemble.likelihood.record_noise_sd`). A *pilot pass* (the whole sweep with
  sigma_n and alpha_n = 1; units ``pass=pilot/...``) gives a fitted curve; its residual sets
  sigma_n^2 = max(record noise^2, mean squared residual) (model error counts as noise, never as
  information) and the tempering alpha_n = n_eff / K, n_eff from the residual's integrated
  autocorrelation time (:func:`imrbayes.ensemble.likelihood.effective_samples`), so each
  *independent* observation counts once. The reported pass uses these (``adapt=False``: no pilot,
  the record noise and alpha = 1). One noise level and one tempering per experiment over the whole
  record (a window of 35 correlated samples is too short to estimate an autocorrelation time).
  The pilot runs with half the members (``pilot_n_ens`` 24: docs/validation.md, "A cheaper
  pilot"), so it costs about half the reported pass. An experiment
  whose pilot residual stands out from the others' (:func:`pilot_outliers`) is named in the
  warnings: the smoother may have lost track of it, and the reported pass would then weight it
  far less; its pilot is run once more, alone, on other random streams and with the reported
  pass's members, and the closer fit is used (``pilot_retry``). Windows stop iterating once their
  cost settles (``min_iter``).
* **Geometry and alignment** (§7.3): inferred, not fixed. Window 0's members carry the nuisances
  of :mod:`imrbayes.ensemble.likelihood`: the relative Rmax error a, the time of the maximum delta
  (t*) and rho = log(Req / Req_hat), drawn from the preprocessing prior and analysed with the
  parameters (En4D-Var's observation model: member m is a bubble of maximum radius
  Rmax_hat (1 + a_m) whose maximum is at data time delta_m; before it, the mirror image). Each
  member is handed off with its state at data time t_h, converted to the data's units (R* times
  1 + a_m; every other state variable is scaled by p8 or sqrt(p8/rho), not by Rmax, so the
  conversion is exact), and every later window runs all members on the data's clock with their
  own Req: a and delta live on in the state (later analyses update them as state), rho stays an
  augmented column analysed in every window (it sets the elastic equilibrium). Inferring them in
  the ensemble rather than to first order: an offset of a frame near the collapse is far outside a
  linear model, and a fixed Rmax or Req that is off by a few per cent is read as material physics
  (with them fixed, the per-bubble estimates scattered more than their sds allowed: a spurious
  between-bubble sd). The posteriors are reported as ``per_experiment[].nuisance``.
  With the default likelihood (``req_prior="en4dvar"``, :data:`DEFAULT_REQ_PRIOR`) each estimated
  Req's prior (the record's tail mean) is replaced by its whole-record En4D-Var posterior, fitted
  first (:func:`req_prior_from_en4dvar`; no fit when every Req is given): the windows see the tail,
  where Req is decided, only at the end, and an uncertain Req lets the early windows' mu slide along
  the Req-mu ridge. Measured (docs/validation.md, 20 camera seeds each): the aggregate's bias G +13.9 ->
  +4.7 %, mu +9.7 -> +4.0 % (thermal), G +9.9 -> +3.6 %, mu +7.5 -> +2.2 % (polytropic); the price is
  an En4D-Var fit and Req's information used twice (``preprocessing``: the method before).
* **Across bubbles** (§7.4), in every window: each experiment's window likelihood (its posterior
  divided by the prior its window started from,
  :func:`imrbayes.ensemble.hierarchical.likelihood_terms`) enters the random-effects layer
  (:func:`imrbayes.ensemble.hierarchical.random_effects`) with the gel mean's prior chained from
  the previous window (its gel-level posterior after RTPS; window 0: the parameter prior). The
  window's estimate is the gel-level mean; every window entry carries ``between_experiments`` and
  ``predictive``. For the whole record, each experiment's window likelihoods are summed (each
  sample counted once, constant parameters) and the same layer gives the top-level
  ``between_experiments``; ``predictive`` is the aggregate estimate widened by that scatter;
  ``per_experiment[].estimate`` is the prior times that experiment's summed likelihood.
  ``details["alternative_estimates"]["record_shared_req"]``: the same record-level estimate with each
  experiment's log Req shared by its windows (every window's likelihood of (parameters, rho)
  summed, rho integrated out once against its preprocessing prior) rather than integrated out per
  window against that window's chained prior; on the camera family (20 seeds) mu's bias +10.7 ->
  +8.3 %, coverage 0.45 -> 0.70 (docs/validation.md, "Req shared by the windows"): reported beside
  the default, not in its place.
* ``FitResult.window_posteriors`` (what ``--mcmc`` samples): the window's density with no
  between-bubble scatter (the pooled, product-rule Gaussian ``pooled_mean_internal``): the chained
  prior and ``whiten`` W_n = diag(sqrt(beta_jk alpha_n / sigma_n^2)), each experiment started from
  its mean handed-off state and Req (``start_req_m``); in window 0 the density fixes the geometry
  and the time of the maximum at the preprocessing estimates (the ensemble's z-marginal integrates
  them: a difference of the same kind as En4D-Var's).

Likelihood ``paper`` (the paper's settings, reproduced exactly)
----------------------------------------------------------------
Cost 1/(2L) sum_k beta_jk ||y_k - <Y_k> - Y'_k w||^2_{P_k} (``obs_weight="mean"``; ``mda``: no
1/L) with P_k the preprocessing's noise variance, the window fusion ``fusion="chain"``
(:func:`imrbayes.ensemble.gaussian.fuse_likelihoods`): the product rule with the window's prior,
i.e. every experiment's window likelihood (its posterior divided by its own window prior) times
the fused chain's prior. ``fusion="prior"`` applies methods.md §3's rule with the original prior
N(m0, S0) in every window. The two agree without RTPS; with RTPS each experiment's posterior has
partly forgotten the original prior, and dividing it out N_exp - 1 times extrapolates away from the
data: on the §5 verification case (5 experiments, paper noise) ``prior`` drove G to ~0.2 kPa and
mu to ~0.002 Pa s in the late windows, ``chain`` stays at the truth. Its window posteriors record
the weights beta_jk / L (beta_jk with ``mda``) and the chained (``chain``) or original prior.

Time-resolved estimate: normalised precision weighting of the windows' estimates holding each
sample; aggregate estimate: the same over all windows with equal weights (its mean).

Aggregate covariance (``aggregate_cov``, default likelihood): ``weighting`` is methods.md §4's,
the normalised precision weighting's (sum_j w_j Sigma_j^-1)^-1, which treats the windows as one:
with RTPS every window forgets most of the windows before it, so this is about one window's
covariance, 2-4x the aggregate's own scatter on constant-parameter data. ``chain`` propagates the
covariance of the same mean through the window chain (:mod:`imrbayes.ensemble.aggregate`): every
window mean is linear in the previous one and in the experiments' window likelihoods, each sample
counted once, each bubble's deviation from the gel (the record's between-bubble sd) shared by its
windows; ``predictive`` then adds the record's between-bubble variance with tau's uncertainty
integrated. The paper's likelihood keeps ``weighting``. The windows' likelihoods still carry less
information on G than En4D-Var's on the same data (per-bubble sd 0.10 against 0.07 with RTPS off,
one verification seed), so ``chain`` is conservative for G. The fitted curve is the
ensemble-mean R* of the handed-off posterior ensembles (samples s_j .. s_j + h - 1 of every window,
the whole last window).
"""

from __future__ import annotations

import hashlib
import math
import time
import warnings as _warnings
from dataclasses import asdict, dataclass, replace

import numpy as np

from imrbayes.ensemble.aggregate import chain_aggregate_cov
from imrbayes.ensemble.fusion import (
    BubbleFusion,
    fuse,
    fuse_bubbles,
    fuse_likelihoods,
    integrate_out_trailing,
    likelihood_terms,
)
from imrbayes.ensemble.gaussian import draw, marginal_summary, precision_weighted, rtps_factors
from imrbayes.ensemble.gn import gauss_newton
from imrbayes.ensemble.likelihood import (
    check_choice,
    effective_samples,
    nuisance_prior_sd,
    nuisance_summary,
    predict,
    record_noise_sd,
)
from imrbayes.ensemble.method import InferenceMethod
from imrbayes.ensemble.req_tail import REQ_CONFLICT_Z, alignment_shift_z, req_shift_z
from imrbayes.ensemble.result import FitResult, WindowPosterior, gaussian_estimate, rmse, si_covariance
from imrbayes.ensemble.windows import (
    PRIOR_WEIGHT_LIMIT,
    chained_prior_weight,
    mda_weights,
    n_windows,
    prior_dominated_note,
    time_resolved,
    window_spans,
)
from imrbayes.errors import InputError
from imrbayes.execution import Execution, Unit, unit_id
from imrbayes.forward import BatchState, Runner, fm_spec, register_runner, runner_for

__all__ = [
    "MIEnKS",
    "MIEnKSSettings",
    "fit_mienks",
    "mienks_unit",
    "initial_members",
    "noise_pass",
    "fuse_windows",
    "record_level",
    "req_prior_from_en4dvar",
    "rtps_cov",
]


#: the default likelihood's early stop of a window's Gauss-Newton iterations (MIEnKSSettings.resolved)
DEFAULT_MIN_ITER = 2
DEFAULT_STEP_TOL = 0.1
#: the default likelihood's start of window 0's members: mu's prior sd x 3 (docs/validation.md)
DEFAULT_PRIOR_WIDEN = "mu:3"
#: where each estimated Req's prior comes from (``req_prior``); ``en4dvar`` fits En4D-Var first
REQ_PRIORS = ("preprocessing", "en4dvar")
#: the default likelihood's ``req_prior`` (docs/validation.md, "Req's prior from a whole-record fit: the default")
DEFAULT_REQ_PRIOR = "en4dvar"
#: a whole-record Req further than this many preprocessing prior sd from the record's own Req is a
#: conflict between the model and the measured tail: that experiment keeps the preprocessing prior
REQ_PRIOR_CONFLICT_Z = REQ_CONFLICT_Z
#: the Req-prior fit skips an experiment's later cycles once a cycle leaves its Req this many
#: preprocessing sd from the record's (En4DVarSettings.req_conflict_stop): a conflict the later
#: cycles do not undo (docs/validation.md, "The Req-prior fit stops on a decided conflict")
REQ_PRIOR_STOP_Z = 6.0


@dataclass
class MIEnKSSettings:
    """MIEnKS-MDA settings (``--set KEY=VALUE``); unset (None) fields take their likelihood's value
    (:meth:`resolved`)."""

    n_ens: int = 48
    """Members per experiment; 48."""
    n_iter: int = 5
    """Gauss–Newton iterations per window (at most); 5."""
    L: int = 35
    """Window length [samples]; 35."""
    h: int = 5
    """Window shift [samples]; 5."""
    rtps: float = 0.7
    """Relaxation-to-prior-spread factor a in [0, 1] on the parameters' spread; 0.7."""
    aggregate_cov: str | None = None
    """The aggregate's covariance, ``chain`` or ``weighting`` (module doc); None: chain (paper: weighting)."""
    max_redraw: int = 5
    """Redraw rounds for members whose forward run failed; 5."""
    n_draws: int = 500
    """Draws per window written to posterior.nc; 500."""
    transform: bool = True
    """Gauss–Newton in the transform variant; true."""
    fusion: str | None = None
    """Paper's likelihood: window fusion ``chain`` or ``prior`` (methods.md's rule); None: chain."""
    obs_weight: str | None = None
    """Paper's likelihood: weight ``mean`` (beta_jk / L) or ``mda`` (beta_jk); None: mean."""
    likelihood: str = "default"
    """``default`` (methods.md §7, module doc) or ``paper``; default."""
    adapt: bool = True
    """Default likelihood: a pilot pass sets each record's noise level and tempering; true."""
    req_prior: str | None = None
    """Default likelihood: each estimated Req's prior from ``preprocessing`` or a whole-record ``en4dvar`` fit; None: en4dvar."""
    pilot_n_ens: int | None = 24
    """Members of the pilot pass (at most ``n_ens``; None: ``n_ens``); 24."""
    pilot_retry: bool = True
    """A bubble whose pilot residual stands out gets a second pilot of its own; true."""
    min_iter: int | None = None
    """A window may stop iterating after this many evaluations once its cost settles; None: 2 (paper: n_iter)."""
    step_tol: float | None = None
    """From ``min_iter`` on, stop once the next step is shorter than this many posterior sd; None: 0.1 (paper: never)."""
    prior_widen: float | str | None = None
    """Window 0's members drawn with the prior sd times K (a number, or ``NAME:K[,NAME:K]``); None: mu:3 (paper: 1)."""

    def pilot(self) -> MIEnKSSettings:
        """The pilot pass's settings: the reported pass's with at most ``pilot_n_ens`` members."""
        return replace(self, n_ens=min(self.pilot_n_ens or self.n_ens, self.n_ens))

    def resolved(self) -> MIEnKSSettings:
        """The settings with the likelihood's own choices filled in (``paper``: ``chain`` fusion and
        the ``mean`` weight unless set, every window ``n_iter`` iterations; ``default``: windows
        stop once settled, ``min_iter`` 2 and ``step_tol`` 0.1 unless set, ``prior_widen`` ``"mu:3"``
        unless set; paper: ``prior_widen`` 1)."""
        if self.likelihood == "paper":
            return replace(
                self,
                fusion=self.fusion or "chain",
                obs_weight=self.obs_weight or "mean",
                prior_widen=self.prior_widen or 1.0,
                req_prior=self.req_prior or "preprocessing",
                aggregate_cov=self.aggregate_cov or "weighting",
            )
        return replace(
            self,
            aggregate_cov=self.aggregate_cov or DEFAULT_AGGREGATE_COV,
            min_iter=DEFAULT_MIN_ITER if self.min_iter is None else self.min_iter,
            step_tol=DEFAULT_STEP_TOL if self.step_tol is None else self.step_tol,
            prior_widen=DEFAULT_PRIOR_WIDEN if self.prior_widen is None else self.prior_widen,
            req_prior=self.req_prior or DEFAULT_REQ_PRIOR,
        )

    def check(self, n_steps: int):
        """Raise :class:`~imrbayes.errors.InputError` naming the first setting out of range for a
        record of ``n_steps`` steps."""
        check_choice(self.likelihood, self.fusion, self.obs_weight)
        s = self.resolved()
        if self.n_ens < 3:
            raise InputError("n_ens", f"needs at least 3 members, got {self.n_ens}")
        if self.n_iter < 1:
            raise InputError("n_iter", "must be at least 1")
        if not 0.0 <= self.rtps <= 1.0:
            raise InputError("rtps", f"the RTPS factor must lie in [0, 1], got {self.rtps}")
        if self.n_draws < 1:
            raise InputError("n_draws", f"needs at least one posterior draw per window, got {self.n_draws}")
        if s.likelihood == "paper" and s.fusion not in ("chain", "prior"):
            raise InputError("fusion", f"must be 'chain' or 'prior', got {s.fusion!r}")
        if s.likelihood == "paper" and s.obs_weight not in ("mean", "mda"):
            raise InputError("obs_weight", f"must be 'mean' or 'mda', got {s.obs_weight!r}")
        if s.req_prior not in REQ_PRIORS:
            raise InputError("req_prior", f"must be 'preprocessing' or 'en4dvar', got {self.req_prior!r}")
        if s.req_prior != "preprocessing" and s.likelihood != "default":
            raise InputError("req_prior", "applies to the default likelihood only (the paper's has no Req nuisance)")
        if self.h > self.L:
            raise InputError(
                "h", f"the shift h = {self.h} exceeds the window length L = {self.L}: samples would be skipped"
            )
        v = self.pilot_n_ens
        if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < 3):
            raise InputError("pilot_n_ens", f"must be an integer >= 3 or unset, got {v!r}")
        if self.min_iter is not None and (
            isinstance(self.min_iter, bool) or not isinstance(self.min_iter, int) or self.min_iter < 1
        ):
            raise InputError(
                "min_iter", f"must be a positive integer (n_iter or more: never early) or unset, got {self.min_iter!r}"
            )
        if self.step_tol is not None and not (
            isinstance(self.step_tol, (int, float))
            and not isinstance(self.step_tol, bool)
            and math.isfinite(self.step_tol)
            and self.step_tol > 0
        ):
            raise InputError("step_tol", f"must be a positive number of posterior sd or unset, got {self.step_tol!r}")
        widen_factors(self.prior_widen, None)
        if self.prior_widen not in (None, 1, 1.0) and s.likelihood != "default":
            raise InputError(
                "prior_widen",
                "applies to the default likelihood only (the paper's members start from the parameter prior)",
            )
        if s.aggregate_cov not in AGGREGATE_COVS:
            raise InputError(
                "aggregate_cov", f"must be one of {', '.join(AGGREGATE_COVS)} or unset, got {self.aggregate_cov!r}"
            )
        if s.aggregate_cov == "chain" and s.likelihood != "default":
            raise InputError(
                "aggregate_cov", "'chain' needs the default likelihood (the paper's keeps methods.md §4's weighting)"
            )
        n_windows(n_steps, self.L, self.h)


AGGREGATE_COVS = ("chain", "weighting")
DEFAULT_AGGREGATE_COV = "chain"


def widen_factors(value, names, strict: bool = True) -> np.ndarray | None:
    """``prior_widen`` as a factor per parameter: a number K >= 1 (every parameter) or text
    ``"NAME:K[,NAME:K]"`` (the parameters named; the others 1), None or 1 for none. ``names``: the
    parameter names (None: check the form only, return None)."""
    if value is None:
        return None if names is None else np.ones(len(names))
    pairs = None
    if isinstance(value, str):
        try:
            pairs = [(k.strip(), float(v)) for k, v in (p.split(":") for p in value.split(","))]
        except ValueError:
            raise InputError("prior_widen", f"must be a number >= 1 or 'NAME:K[,NAME:K]', got {value!r}")
        ks = [k for _, k in pairs]
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        ks = [float(value)]
    else:
        raise InputError("prior_widen", f"must be a number >= 1 or 'NAME:K[,NAME:K]', got {value!r}")
    if not all(math.isfinite(k) and k >= 1.0 for k in ks):
        raise InputError("prior_widen", f"every factor must be a finite number >= 1, got {value!r}")
    if names is None:
        return None
    if pairs is None:
        return np.full(len(names), ks[0])
    unknown = [k for k, _ in pairs if k not in names]
    pairs = [(k, v) for k, v in pairs if k in names]
    if unknown and strict:
        raise InputError("prior_widen", f"unknown parameter(s) {', '.join(unknown)}; the model's: {', '.join(names)}")
    out = np.ones(len(names))
    for k, v in pairs:
        out[list(names).index(k)] = v
    return out


def _redraw_failed(E, bad, rng):
    """Replace rows ``bad`` (n_exp, N) of E (n_exp, N, D) by draws from the Gaussian of the valid rows."""
    n = 0
    for g in np.flatnonzero(bad.any(axis=1)):
        ok = ~bad[g]
        if ok.sum() < 2:
            raise RuntimeError(f"experiment {g}: fewer than two ensemble members survived the hand-off")
        mu = E[g, ok].mean(axis=0)
        A = (E[g, ok] - mu) / np.sqrt(ok.sum() - 1.0)
        idx = np.flatnonzero(bad[g])
        E[g, idx] = mu + rng.standard_normal((idx.size, ok.sum())) @ A
        n += idx.size
    return n


def rtps_cov(prior_c, post_c, a):
    """RTPS of a covariance: sd -> sd_post + a (sd_prior - sd_post), correlations kept."""
    sp, sa = np.sqrt(np.diag(prior_c)), np.sqrt(np.diag(post_c))
    f = np.where(sa > 0, ((1.0 - a) * sa + a * sp) / np.where(sa > 0, sa, 1.0), 1.0)
    return post_c * np.outer(f, f)


class _WindowRun:
    """One experiment's forward runs in one window: members Z in the analysis coordinates
    [state (log p_b in place of p_b), parameters, [rho], [a, delta (window 0)]].

    The analysis sees log p_b instead of p_b: near a collapse the members' p_b spans orders of
    magnitude, and a linear update of p_b itself drives most of them negative."""

    def __init__(self, runner, space, rmax: float, req: float, ns: int, carry: bool):
        self.runner, self.space, self.rmax, self.req = runner, space, rmax, req
        self.ns, self.dp, self.carry = ns, space.n, carry
        self.ipb = runner.fm.layout()["pb"].start

    def to_analysis(self, Z):
        """Members in the analysis coordinates (log p_b)."""
        Z = np.array(Z, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            Z[:, self.ipb] = np.log(Z[:, self.ipb])
        return Z

    def from_analysis(self, Z):
        """Members with their physical state (p_b)."""
        Z = np.array(Z, dtype=np.float64)
        with np.errstate(over="ignore"):
            Z[:, self.ipb] = np.exp(Z[:, self.ipb])
        return Z

    def propagate(self, Z, t0, t1, t_ev):
        """R* (M, len(t_ev)), end state (M, ns, physical), failed (M,) of members Z (M, ns + d, analysis
        coordinates). A member whose state is not physical (ForwardModel.state_is_valid: R* <= 0,
        p_b <= 0, vapour fraction outside [0, 1], ...) or whose parameters are not finite is failed
        without a solve."""
        ns, dp, runner = self.ns, self.dp, self.runner
        Z = self.from_analysis(Z)
        ok = np.all(np.isfinite(Z[:, ns:]), axis=1) & runner.fm.state_is_valid(Z[:, :ns])
        R = np.full((Z.shape[0], len(t_ev)), np.nan)
        Y = Z[:, :ns].copy()
        failed = ~ok
        if ok.any():
            m = int(ok.sum())
            reqs = self.req * np.exp(Z[ok, ns + dp]) if self.carry else np.full(m, self.req)
            st = BatchState(Z[ok, :ns].copy(), t0, np.full(m, self.rmax), reqs)
            out = runner.propagate(st, self.space.to_si(Z[ok, ns : ns + dp]), t1, t_ev)
            R[ok], Y[ok] = out.R_star, out.end.y
            failed[ok] = out.failed | ~np.all(np.isfinite(out.R_star), axis=1) | ~np.all(np.isfinite(out.end.y), axis=1)
        return R, Y, failed

    def propagate_window0(self, Z, t_ev, t_hand=None):
        """Window 0 with the nuisances augmented: member m is a bubble of maximum radius
        Rmax_hat (1 + a_m) and Req_hat e^rho_m whose maximum is at t* = delta_m on the data's clock.
        R* at ``t_ev`` (:func:`imrbayes.ensemble.likelihood.predict`, En4D-Var's observation model),
        and with ``t_hand`` each member's state at data time t_hand, in the data's units (its own
        run to (t_hand - delta_m) / (1 + a_m), then R* times 1 + a_m: every other state variable
        is scaled by p8 or sqrt(p8/rho), not by Rmax, so later windows run all members on one
        clock with their own Req)."""
        ns, dp, runner, rmax, req = self.ns, self.dp, self.runner, self.rmax, self.req
        Z = self.from_analysis(Z)
        M = Z.shape[0]
        k = ns + dp
        nu = np.stack([Z[:, k + 1], Z[:, k + 2], Z[:, k]], axis=1)  # (a, delta, rho)
        ok = np.all(np.isfinite(Z[:, ns:]), axis=1) & (1.0 + nu[:, 0] > 0.5)
        R = np.full((M, len(t_ev)), np.nan)
        Y = Z[:, :ns].copy()
        failed = ~ok
        if ok.any():
            idx = np.flatnonzero(ok)
            th = self.space.to_si(Z[idx, ns : ns + dp])
            Rk, fk = predict(runner, th, rmax, req, t_ev, nu[idx])
            R[idx] = Rk
            failed[idx] = fk
            if t_hand is not None:
                self._hand_off_window0(Y, failed, idx, th, nu, t_hand)
        return R, Y, failed

    def _hand_off_window0(self, Y, failed, idx, th, nu, t_hand):
        """Each member's state at data time ``t_hand`` (window 0, nuisances augmented) written into
        ``Y`` (M, ns) in the data's units; ``failed`` (M,) updated in place."""
        rmax, req = self.rmax, self.req
        scale, req_m = 1.0 + nu[idx, 0], req * np.exp(nu[idx, 2])
        T = np.maximum((float(t_hand) - nu[idx, 1]) / scale, 0.0)
        groups = (
            [np.arange(idx.size)] if np.ptp(nu[idx], axis=0).max() == 0 else [np.array([i]) for i in range(idx.size)]
        )  # one batch when the members share the geometry
        for grp in groups:
            i0 = int(grp[0])
            if req_m[i0] >= rmax * scale[i0]:
                failed[idx[grp]] = True
                continue
            st0 = self.runner.fm.initial_state(np.full(grp.size, rmax * scale[i0]), np.full(grp.size, req_m[i0]))
            out = self.runner.propagate(st0, th[grp], float(T[i0]), np.array([T[i0]]))
            y = np.array(out.end.y, dtype=np.float64)
            y[:, 0] *= scale[i0]
            Y[idx[grp]] = y
            failed[idx[grp]] |= out.failed | ~np.all(np.isfinite(y), axis=1)


def initial_members(runner, space, s, d: dict, rng, carry: bool) -> np.ndarray:
    """Window 0's prior ensemble of one experiment (N, ns + d + [rho, a, delta]): the state at the
    maximum radius, parameters drawn around the start (``space.start_mean``: the global search's best
    point, else the prior mean) with its sd times ``prior_widen``
    (:func:`widen_factors`), and (``carry``) the nuisances (rho, a, delta) from N(0, nuis_sd^2)."""
    N, dp = int(s.n_ens), space.n
    st0 = runner.fm.initial_state(np.full(N, float(d["rmax"])), np.full(N, float(d["req"])))
    ns = st0.y.shape[1]
    E = np.zeros((N, ns + dp + (3 if carry else 0)))
    E[:, :ns] = st0.y
    f = widen_factors(getattr(s, "prior_widen", None), space.names, strict=False)
    # around the global search's best point where ``fit`` made one, else the prior
    E[:, ns : ns + dp] = draw(rng, space.start_mean, space.start_cov * np.outer(f, f), N)
    if carry:
        sd_a, sd_delta, sd_rho = np.asarray(d.get("nuis_sd", (0.0, 0.0, 0.0)), dtype=np.float64)
        E[:, ns + dp] = sd_rho * rng.standard_normal(N)
        E[:, ns + dp + 1] = sd_a * rng.standard_normal(N)
        E[:, ns + dp + 2] = sd_delta * rng.standard_normal(N)
    return E


def mienks_unit(unit: Unit, rng) -> dict:
    """One window of one experiment (methods.md §4, steps 2, 4, 5): Gauss–Newton analysis of the
    augmented ensemble, RTPS on the parameters, hand-off to the next window (failed members
    redrawn; the analysis is rejected, and the window prior handed on, when too few members
    survive). Window 0 starts from :func:`initial_members`.

    Default likelihood (``carry_req``): every member also carries rho = log(Req / Req_hat), analysed
    with the parameters in every window, and window 0's members carry the relative Rmax error a and
    the time of the maximum delta (t*) (module doc). Columns: state, parameters, [rho], [a, delta
    (window 0)]; a and delta are dropped after the hand-off, where they live on in the state.
    Returns the hand-off ensemble ``E``, the fitted segment, the parameters' posterior and prior
    moments, failure counts and (default likelihood) the nuisances' posteriors."""
    d = unit.data
    space, s = d["space"], d["settings"]
    runner = runner_for(d)
    before = (runner.n_member_runs, runner.n_failed)
    t, a, b, a2, last = d["t"], int(d["a"]), int(d["b"]), int(d["a2"]), bool(d["last"])
    N, dp = int(s.n_ens), space.n
    carry = bool(d.get("carry_req", False))
    n_carry = 1 if carry else 0  # rho after the parameters (default likelihood)
    E = d["E"]
    n_aug = 0  # window 0 (default likelihood): a and delta after rho
    if E is None:
        E = initial_members(runner, space, s, d, rng, carry)
        n_aug = 2 if carry else 0
    E = np.array(E, dtype=np.float64)
    ns = E.shape[1] - dp - n_carry - n_aug
    t_eval = t[a : b + 1]
    run = _WindowRun(runner, space, float(d["rmax"]), float(d["req"]), ns, carry)
    E = run.to_analysis(E)
    if n_aug:

        def evaluate(groups, Z):
            R, _, failed = run.propagate_window0(np.asarray(Z, dtype=np.float64), t_eval)
            return R, failed

        def handoff(Z):
            return run.propagate_window0(Z, t[a : a2 + 1], t[a2])
    else:

        def evaluate(groups, Z):
            R, _, failed = run.propagate(np.asarray(Z, dtype=np.float64), t[a], t[b], t_eval)
            return R, failed

        def handoff(Z):
            return run.propagate(Z, t[a], t[a2], t[a : a2 + 1])

    res = gauss_newton(
        E[None],
        evaluate,
        d["y"][None],
        d["weight"][None],
        n_iter=s.n_iter,
        rng=rng,
        max_redraw=s.max_redraw,
        transform=s.transform,
        min_iter=s.min_iter,
        step_tol=s.step_tol,
    )
    f = rtps_factors(res.prior_anoms, res.anoms, s.rtps)[0]
    f[:ns] = 1.0  # RTPS on the parameters (and nuisances), not the state
    Ea = res.mean[0][None, :] + np.sqrt(N - 1.0) * res.anoms[0] * f[None, :]
    problems = runner.fm.state_problems(run.from_analysis(Ea)[:, :ns])  # analysed states that are not physical
    n_invalid = int(np.any(np.stack(list(problems.values())), axis=0).sum())
    invalid_why = {k: int(v.sum()) for k, v in problems.items() if v.any()}
    Rseg, Ynew, failed = handoff(Ea)
    n_failed_analysed = int(failed.sum())
    rejected = False
    if (~failed).sum() < max(2, N // 4):
        # too few analysed members survived the hand-off: hand on the window's prior ensemble
        # instead (analysis rejected for this window, reported), propagated the same way
        Ep = res.prior_ensemble[0]
        Rseg, Ynew, failed = handoff(Ep)
        if (~failed).sum() < 2:
            raise RuntimeError(
                f"fewer than two ensemble members survived window t* {t[a]:.3g}-{t[b]:.3g}, "
                f"with and without the analysis"
            )
        Ea = Ep.copy()
        rejected = True
    with np.errstate(invalid="ignore"):
        seg = np.nanmean(np.where(failed[:, None], np.nan, Rseg), axis=0)
    E_next = run.to_analysis(
        np.concatenate([Ynew, Ea[:, ns : ns + dp + n_carry]], axis=1)
    )  # a, delta are not handed on
    n_fail = int(failed.sum())
    n_red = _redraw_failed(E_next[None], failed[None], rng) if (n_fail and not last) else 0
    E_next = run.from_analysis(E_next)  # handed on as physical states
    out = {
        "E": None if last else E_next,
        "seg": seg,
        "n_failed_iter": res.n_failed[0],
        "n_redrawn_prior": int(res.n_redrawn[0]),
        "n_failed_handoff": n_fail,
        "n_redrawn_handoff": int(n_red),
        "stopped": bool(res.stopped[0]),
        "rejected": rejected,
        "n_invalid_analysed": n_invalid,
        "n_failed_analysed": n_failed_analysed,
        "invalid_why": invalid_why,
        "cost": res.cost[0],
        "state_size": int(ns),
        **_window_moments(res, ns, dp, carry, n_aug, rejected),
        **runner.counts_since(before),
    }
    return out


def _window_moments(res, ns: int, dp: int, carry: bool, n_aug: int, rejected: bool) -> dict:
    """The parameters' posterior (``pm``, ``pc``) and prior (``qm``, ``qc``) moments of a window's
    analysis, and with the nuisances carried: rho's posterior (``log_req``), the joint moments of
    (parameters, rho) (``joint``) and in window 0 those of a and delta (``rmax_rel``, ``offset``)."""
    P = slice(ns, ns + dp)
    qa = res.prior_anoms[0, :, P]
    out = {
        "pm": res.mean[0, P],
        "pc": res.cov[0, P, P],
        "qm": res.prior_ensemble[0, :, P].mean(axis=0),
        "qc": qa.T @ qa,
    }
    if carry:
        k = ns + dp
        sd = np.sqrt(np.maximum(np.diag(res.cov[0]), 0.0))
        out["log_req"] = {"mean": float(res.mean[0, k]), "sd": float(sd[k]), "rejected": rejected}
        # the parameters and rho together: the record-level estimate with Req shared by the windows
        J = slice(ns, ns + dp + 1)
        qj = res.prior_anoms[0, :, J]
        out["joint"] = {
            "pm": res.mean[0, J],
            "pc": res.cov[0, J, J],
            "qm": res.prior_ensemble[0, :, J].mean(axis=0),
            "qc": qj.T @ qj,
        }
        if n_aug:
            out["offset"] = {"mean": float(res.mean[0, k + 2]), "sd": float(sd[k + 2]), "rejected": rejected}
            out["rmax_rel"] = {"mean": float(res.mean[0, k + 1]), "sd": float(sd[k + 1]), "rejected": rejected}
    return out


def _sweep(ex, base, obs, s, spans, seed, weight_for, nuis_sd, tag, progress, nw, stream_tag=None):
    """Run every window's units in order (one per alive experiment, :func:`mienks_unit`) and collect
    their results; ``weight_for(j, g, a, b)`` gives experiment g's observation weights in window j;
    ``nuis_sd`` (n_exp, 3): prior sds of each experiment's nuisances (a, delta, rho) (default likelihood;
    None: the paper's, no nuisances).
    The fusion does not feed back into the ensembles, so it is done afterwards
    (:func:`fit_mienks`). ``tag``: leading parts of the unit ids (e.g. ``{"pass": "pilot"}``);
    ``stream_tag``: those of the units' random streams when they differ (default ``tag``).
    Returns a dict of per-window lists."""
    n_exp = obs.n_exp
    t = obs.t_star
    alive = list(range(n_exp))
    handoff = {g: None for g in range(n_exp)}  # each experiment's ensemble entering the next window
    failed_units = []
    ns = None
    dp = base["space"].n
    out = {
        "results": [],
        "ok": [],
        "lost": [],
        "start_means": [],
        "start_req": [],
        "warnings": [],
        "failed_units": failed_units,
        "alive": alive,
    }
    stag = tag if stream_tag is None else stream_tag
    for j, (a, b) in enumerate(spans):
        last = j == nw - 1
        warn = []
        if j == 0:
            out["start_means"].append(np.array(base["fm"].initial_state(obs.rmax_m, obs.req_m).y, dtype=np.float64))
            out["start_req"].append(np.asarray(obs.req_m, dtype=np.float64).copy())
        else:
            q = np.full((n_exp, ns), np.nan)
            rq = np.full(n_exp, np.nan)
            for g in alive:
                Eg = np.asarray(handoff[g], dtype=np.float64)
                q[g] = Eg[:, :ns].mean(axis=0)
                rq[g] = obs.req_m[g] * (np.exp(Eg[:, ns + dp].mean()) if nuis_sd is not None else 1.0)
            out["start_means"].append(q)
            out["start_req"].append(rq)
        a2 = b if last else a + s.h
        units = [
            Unit(
                unit_id(**tag, window=j, exp=g),
                {
                    "spec": base["spec"],
                    "runner": base["runner"],
                    "space": base["space"],
                    "settings": s,
                    "t": t,
                    "a": int(a),
                    "b": int(b),
                    "a2": int(a2),
                    "last": last,
                    "rmax": float(obs.rmax_m[g]),
                    "req": float(obs.req_m[g]),
                    "y": obs.R_star[g, a : b + 1],
                    "weight": weight_for(j, g, a, b),
                    "E": handoff[g],
                    **({"carry_req": True} if nuis_sd is not None else {}),
                    **({"nuis_sd": [float(x) for x in nuis_sd[g]]} if j == 0 and nuis_sd is not None else {}),
                },
                stream=unit_id(**stag, window=j, exp=g),
            )
            for g in alive
        ]
        label = "".join(f" ({v})" for v in tag.values())
        desc = f"mienks window {j + 1}/{nw}{label}"
        rep = ex.run(units, mienks_unit, seed, desc=desc)
        ok, lost = [], []
        for g in alive:
            uid = unit_id(**tag, window=j, exp=g)
            if uid in rep.results:
                ok.append(g)
            else:
                err = rep.failures[uid].error
                lost.append(obs.names[g])
                failed_units.append({"unit": uid, "experiment": obs.names[g], "window": j, "error": err, **tag})
                warn.append(
                    f"window {j}{label}: experiment {obs.names[g]!r} failed ({err}); left out from this window on"
                )
        if not ok:
            raise RuntimeError(f"window {j}: every experiment failed (e.g. {failed_units[-1]['error']})")
        alive[:] = ok
        R = [rep.results[unit_id(**tag, window=j, exp=g)] for g in ok]
        ns = int(R[0]["state_size"])
        for g, r in zip(ok, R):
            handoff[g] = r["E"]
        out["results"].append(R)
        out["ok"].append(list(ok))
        out["lost"].append(lost)
        out["warnings"].append(warn)
        if progress is not None:
            progress(j + 1)
    out["state_size"] = ns
    return out


def _fitted(obs, spans, sw, nw, h):
    """The fitted curve of a sweep: each window's hand-off segment (samples a .. a+h-1, the whole last window)."""
    fitted = np.full(obs.R_star.shape, np.nan)
    for j, (a, b) in enumerate(spans):
        stop = b + 1 if j == nw - 1 else a + h
        for g, r in zip(sw["ok"][j], sw["results"][j]):
            fitted[g, a:stop] = r["seg"][: stop - a]
    return fitted


def _noise_model(obs, fitted, noise_var):
    """Per experiment, from a pilot's fitted curve: the noise variance used (the record's own,
    raised to the residual's mean square where the model does not reach it), the tempering
    alpha = n_eff / K with n_eff from the residual's integrated autocorrelation time, and what was
    found ({noise_sd, sd_used, alpha, effective_samples, autocorrelation_time, n_samples, resid_rms})."""
    var, alpha, info = [], [], []
    for g in range(obs.n_exp):
        r = (obs.R_star[g] - fitted[g])[1:]
        r = r[np.isfinite(r)]
        nv = float(noise_var[g])
        if r.size < 8:
            var.append(nv)
            alpha.append(1.0)
            info.append(
                {
                    "noise_sd": float(np.sqrt(nv)),
                    "sd_used": float(np.sqrt(nv)),
                    "alpha": 1.0,
                    "effective_samples": None,
                    "autocorrelation_time": None,
                    "n_samples": int(r.size),
                    "resid_rms": None,
                    "note": "too few fitted samples in the pilot: record noise, no tempering",
                }
            )
            continue
        rms = float(np.sqrt(np.mean(r * r)))
        v = max(nv, rms * rms)
        n_eff, tau = effective_samples(r)
        al = min(1.0, n_eff / r.size)
        var.append(v)
        alpha.append(al)
        info.append(
            {
                "noise_sd": float(np.sqrt(nv)),
                "sd_used": float(np.sqrt(v)),
                "alpha": al,
                "effective_samples": float(n_eff),
                "autocorrelation_time": float(tau),
                "n_samples": int(r.size),
                "resid_rms": rms,
            }
        )
    return np.array(var), np.array(alpha), info


#: a bubble whose pilot residual exceeds this many times the median of the other bubbles' is flagged
PILOT_OUTLIER_FACTOR = 3.0


def pilot_outliers(lik_info: list, names, factor: float = PILOT_OUTLIER_FACTOR) -> list:
    """Warnings for experiments whose pilot residual RMS is more than ``factor`` times the median of
    the other experiments' (three or more with a residual); marks their ``lik_info`` entry
    ``pilot_outlier``. Why: the reported pass weights a bubble by alpha / sd^2 from that residual, so
    a bubble the pilot lost track of (stiff PA 1-5, seed 1: exp03 at 0.072 R* against 0.019-0.024)
    counts ~1/10 as much as its neighbours -- a large, silent change of the gel-level estimate."""
    rms = np.array([x.get("resid_rms") if x.get("resid_rms") is not None else np.nan for x in lik_info], dtype=float)
    out = []
    if np.isfinite(rms).sum() < 3:
        return out
    for g, r in enumerate(rms):
        others = np.delete(rms, g)
        ref = float(np.nanmedian(others))
        if np.isfinite(r) and ref > 0 and r > factor * ref:
            lik_info[g]["pilot_outlier"] = True
            w = lik_info[g]["alpha"] / lik_info[g]["sd_used"] ** 2
            w_ref = np.nanmedian([x["alpha"] / x["sd_used"] ** 2 for i, x in enumerate(lik_info) if i != g])
            out.append(
                f"experiment {names[g]!r}: the pilot pass's residual ({r:.3g} R*) is {r / ref:.1f}x the median of "
                f"the other experiments' ({ref:.3g}), so the reported pass would weight it {w / w_ref:.2g}x as much "
                f"as them; the smoother may have lost track of it (compare its fitted curve with the data; "
                f"summary.json likelihood)"
            )
    return out


def _retry_lost_pilots(ex, base, obs, s, sp, spans_p, seed, w_pilot, nuis_sd, noise_var, var, alpha, lik_info):
    """One more pilot for each experiment :func:`pilot_outliers` flagged, that bubble alone on its own
    random streams (units ``pass=pilot/retry=<g>/...``) with the reported pass's members and
    iterations (``s``; the pilot's windows ``sp``); the closer of the two fits sets its noise
    model (``var``, ``alpha`` and ``lik_info`` updated in place, ``lik_info[g]["pilot_retry"]`` says
    which). Why: a pilot that lost track of a bubble is a Monte-Carlo failure of the smoother (the
    reported pass fits it), and it would weight that bubble down for good; a cheaper pilot's retry
    at its own size lost the same bubble again (stiff PA 1-5, seed 1: 0.235 -> 0.071 R* with 24
    members and 3 iterations, 0.021 with 48 and 5). A retry that fails keeps the first. Returns
    (warnings, the retry sweeps, their failed units)."""
    notes, sweeps, failed = [], [], []
    nw_p = spans_p.shape[0]
    sr = replace(sp, n_ens=s.n_ens, n_iter=s.n_iter)
    for g in [g for g, x in enumerate(lik_info) if x.get("pilot_outlier")]:
        sub = obs.take([g])
        first = lik_info[g]["resid_rms"]
        try:
            pr = _sweep(
                ex,
                base,
                sub,
                sr,
                spans_p,
                seed,
                lambda j, _, a, b, g=g: w_pilot(j, g, a, b),
                nuis_sd[[g]],
                {"pass": "pilot", "retry": g},
                None,
                nw_p,
            )
        except RuntimeError as exc:  # the bubble failed in some window of the retry
            lik_info[g]["pilot_retry"] = {
                "resid_rms_first": first,
                "resid_rms_retry": None,
                "kept": "first",
                "error": str(exc),
            }
            notes.append(f"experiment {obs.names[g]!r}: a second pilot of it alone failed ({exc}); the first is kept")
            continue
        failed += pr["failed_units"]
        pr["experiment"] = g
        sweeps.append(pr)
        v2, a2, i2 = _noise_model(sub, _fitted(sub, spans_p, pr, nw_p, sp.h), noise_var[[g]])
        second = i2[0]["resid_rms"]
        keep = second is not None and second < first
        if keep:
            var[g], alpha[g] = v2[0], a2[0]
            lik_info[g] = {**i2[0], "pilot_outlier": True}
        lik_info[g]["pilot_retry"] = {
            "resid_rms_first": first,
            "resid_rms_retry": second,
            "kept": "retry" if keep else "first",
        }
        got = f"a residual of {second:.3g} R*" if second is not None else "no residual (too few fitted samples)"
        notes.append(
            f"experiment {obs.names[g]!r}: a second pilot of it alone (other random draws) gave {got} "
            f"against {first:.3g}; " + ("the second is used" if keep else "the first is kept")
        )
    return notes, sweeps, failed


def req_prior_from_en4dvar(
    fm,
    obs,
    space,
    seed,
    runner,
    execution,
    conflict_z: float = REQ_PRIOR_CONFLICT_Z,
    stop_z: float | None = REQ_PRIOR_STOP_Z,
):
    """(Observations with each estimated Req's prior replaced by its whole-record En4D-Var posterior
    [mean, sd], details). Why: the smoother's windows see Req only through the data before them and
    its prior, while the record's tail, where Req is decided, comes last (docs/validation.md). The
    data inform Req twice (the En4D-Var fit, then the windows): an empirical-Bayes approximation,
    measured rather than exact. A Req given in meta.json (prior sd 0) is kept. An experiment whose
    En4D-Var Req lies more than ``conflict_z`` preprocessing sd from its preprocessing Req keeps the
    preprocessing prior, and a warning names it (``details["req_prior"]["conflicts"]``): model
    error absorbed by the geometry, which the measured tail contradicts. ``stop_z`` (None: off): an
    experiment whose Req lies beyond it after a restart cycle skips its later cycles -- its
    conflict is decided, only the comparison is used (``details["req_prior"]["stopped_early"]``)."""
    from imrbayes.ensemble.en4dvar import En4DVarSettings, en4dvar_pass

    stop = max(stop_z, conflict_z) if stop_z else None  # never below the conflict bound; inf: no stop
    e4s = En4DVarSettings(
        n_draws=1, loglik=False, req_conflict_stop=stop if stop is not None and np.isfinite(stop) else None
    )
    e4s.check()
    e4 = en4dvar_pass(fm, obs, space, e4s.resolved(), seed, runner, None, execution, tag={"req_prior": "en4dvar"})
    req = np.array(obs.req_m, dtype=np.float64).copy()
    sd = np.array(obs.nuisance_sd, dtype=np.float64).copy()
    names = list(obs.names)
    used, conflicts, warns = [], [], []
    for q in req_shift_z(obs, e4.per_experiment):
        g = names.index(q["experiment"])
        if abs(q["z"]) > conflict_z:
            conflicts.append(
                {
                    "experiment": names[g],
                    "z": q["z"],
                    "en4dvar_req_m": q["fitted_req_m"],
                    "en4dvar_req_sd_m": q["fitted_req_sd_m"],
                    "preprocessing_req_m": float(req[g]),
                }
            )
            continue
        req[g] = q["fitted_req_m"]
        sd[g, 2] = q["fitted_req_sd_m"]
        used.append(names[g])
    if conflicts:
        each = ", ".join(
            f"{c['experiment']} {1e6 * c['en4dvar_req_m']:.1f} um against {1e6 * c['preprocessing_req_m']:.1f} "
            f"({c['z']:+.1f} sd)"
            for c in conflicts
        )
        warns.append(
            f"{len(conflicts)} of {len(names)} experiments: the whole-record En4D-Var fit puts Req more than "
            f"{conflict_z:g} prior sd from the record's own ({each}); the model fits the collapses with a Req "
            f"the measured tail contradicts (model error absorbed by the geometry: see diagnose), so the "
            f"smoother keeps their Req prior from the record"
        )
    last = {}  # the last cycle each experiment ran
    for c in e4.details.get("cycles", []):
        for nm in c["experiments"]:
            last[nm] = c["cycle"]
    info = {
        "method": "en4dvar",
        "experiments": used,
        "conflicts": conflicts,
        "conflict_z": conflict_z,
        "warnings": warns,
        "preprocessing_req_m": np.asarray(obs.req_m).tolist(),
        "preprocessing_req_sd_m": np.asarray(obs.nuisance_sd)[:, 2].tolist(),
        "req_m": req.tolist(),
        "req_sd_m": sd[:, 2].tolist(),
        "en4dvar_estimate": {nm: e4.estimate[nm]["mean"] for nm in space.names},
        "en4dvar_member_runs": int(e4.details.get("member_runs", 0)),
        "en4dvar_rmse_own": [p.get("rmse_own") for p in e4.per_experiment],
        "en4dvar_alignment_z": alignment_shift_z(e4.per_experiment),
        "stop_z": e4s.req_conflict_stop,
        "stopped_early": [
            {"experiment": nm, "after_cycle": last[nm]} for nm in names if 0 < last.get(nm, 0) < e4s.n_runs
        ],
        "note": "each estimated Req's prior is its whole-record En4D-Var posterior (mean, sd), run first",
    }
    return replace(obs, req_m=req, nuisance_sd=sd), info


def fit_mienks(
    fm,
    obs,
    space,
    settings: MIEnKSSettings | None = None,
    seed: int = 0,
    runner: Runner | None = None,
    progress=None,
    execution=None,
) -> FitResult:
    """Run MIEnKS-MDA over every window (see module doc); ``progress(j)`` after window j (of each pass).

    Units (:func:`mienks_unit`): one per window and experiment (``window=004/exp=003``, its own
    random stream; the default likelihood's pilot pass: ``pass=pilot/window=004/exp=003``, and its
    reported pass ``noise=<digest of the noise model>/window=004/exp=003``), windows in order, the
    experiments of a window independent; each unit's result holds the experiment's hand-off
    ensemble. ``execution`` (:class:`~imrbayes.execution.Execution`) says where they run and are
    checkpointed (default: this process, with ``runner``). An experiment whose unit fails is left
    out of this and every later window of that pass (counted, reported in
    ``details["failed_units"]`` and the warnings).

    Stages: Req's prior (:func:`req_prior_from_en4dvar`), the noise model (:func:`noise_pass`), the
    reported sweep (:func:`_sweep`), the windows' fusion (:func:`fuse_windows`), the aggregate and
    the time-resolved estimate, and with the default likelihood the record level
    (:func:`record_level`)."""
    s = settings or MIEnKSSettings()
    n_steps = obs.n_samples - 1
    s.check(n_steps)
    widen_factors(s.prior_widen, space.names)  # unknown parameter names refused before any run
    s = s.resolved()
    default = s.likelihood == "default"
    t0c = time.perf_counter()
    ex = execution or Execution(progress=False)
    runner = runner or Runner(fm)
    rng = np.random.default_rng(seed)  # the posterior draws at the end (units have their own)
    spans = window_spans(n_steps, s.L, s.h)
    beta = mda_weights(n_steps, s.L, s.h)
    nw = spans.shape[0]
    req_info = None
    if default and s.req_prior != "preprocessing" and np.any(obs.nuisance_sd[:, 2] > 0):  # some Req estimated
        obs, req_info = req_prior_from_en4dvar(fm, obs, space, seed, runner, ex)
    base = {"spec": fm_spec(fm), "runner": register_runner(runner), "space": space, "fm": fm}
    warnings = list(req_info["warnings"]) if req_info else []
    if default:
        beta = beta.copy()
        beta[:, 0] = 0.0  # sample 0 is R* = 1 by construction (the maximum): no information
        noise = noise_pass(ex, base, obs, s, n_steps, seed, progress)
        warnings.extend(noise["warnings"])
        var, alpha = noise["var"], noise["alpha"]

        def weight_for(j, g, a, b):
            return beta[j, a : b + 1] * alpha[g] / var[g]

        # the reported pass's units depend on the pilot's outcome: their ids carry a digest of the
        # noise model, so a resume after the pilot changed (e.g. --retry-failed) recomputes them;
        # their random streams do not (window and experiment only), or a last-bit change of the
        # pilot's fit would redraw every ensemble
        tag = (
            {"noise": hashlib.sha1(np.concatenate([var, alpha]).astype("<f8").tobytes()).hexdigest()[:8]}
            if s.adapt
            else {}
        )
        sw = _sweep(ex, base, obs, s, spans, seed, weight_for, noise["nuis_sd"], tag, progress, nw, stream_tag={})
    else:
        noise = None

        def weight_for(j, g, a, b):
            return beta[j, a : b + 1] / ((s.L if s.obs_weight == "mean" else 1.0) * obs.P[a : b + 1])

        sw = _sweep(ex, base, obs, s, spans, seed, weight_for, None, {}, progress, nw)
    fw = fuse_windows(obs, space, s, spans, sw, beta, noise)
    warnings.extend(fw["warnings"])
    fitted = _fitted(obs, spans, sw, nw, s.h)
    agg = _aggregate(obs, space, s, fw, n_steps, rng)
    member_runs, failed_runs = fw["member_runs"], fw["failed_member_runs"]
    if noise is not None:
        member_runs += noise["member_runs"]
        failed_runs += noise["failed_member_runs"]
    details = {
        "settings": asdict(s),
        "n_windows": nw,
        "spans": spans.tolist(),
        "prior_dominated_windows": [w["index"] for w in fw["windows"] if w["prior_dominated"]],
        "member_runs": member_runs,
        "failed_member_runs": failed_runs,
        "failed_units": (noise["failed_units"] if noise is not None else []) + sw["failed_units"],
        "experiments_used": [obs.names[g] for g in sw["alive"]],
        "failed_members": fw["total_fail"],
        "redrawn_members": fw["total_redraw"],
        "state_size": sw["state_size"],
        "aggregate_mean_internal": agg["mean"].tolist(),
        "aggregate_cov_internal": agg["cov"].tolist(),
        "parameter_space": space.describe(),
        "rmse": rmse(fitted, obs.R_star, agg["mask"](fitted)),
        "mda": "beta_jk = 1/|I(k)|, window cost 1/(2L) sum_k beta_jk ||.||^2_{P_k}",
        "fitted_curve": "ensemble-mean R* of the handed-off (RTPS-inflated) posterior ensembles",
    }
    if req_info is not None:
        details["req_prior"] = req_info
        details["member_runs"] += req_info["en4dvar_member_runs"]
    per = []
    agg_c = agg["cov"]
    if default:
        details.update(_default_likelihood_record(s, noise["lik_info"]))
        agg_c, per = record_level(obs, space, s, sw, fw, noise, agg["mean"], agg["cov"], details)
    else:
        details["likelihood"] = {
            "name": "paper",
            "noise": f"P_k of preprocessing (beta_jk / {fw['average']} cost)",
            "fusion": str(s.fusion),
            "effective_samples": None,
        }
    t = obs.t_star
    return FitResult(
        method="mienks",
        model=fm.constitutive.name,
        param_names=tuple(space.names),
        estimate=gaussian_estimate(space, agg["mean"], agg_c),
        fitted=fitted,
        fit_mask=agg["mask"](fitted),
        mean_internal=agg["mean"],
        cov_internal=agg_c,
        windows=fw["windows"],
        time_resolved=agg["time_resolved"],
        details=details,
        per_experiment=per,
        posterior=agg["posterior"],
        posterior_dims={nm: ["window"] for nm in space.names},
        extra_groups={"time_resolved": agg["time_resolved_group"]},
        extra_dims={
            **{f"{nm}_mean": ["time"] for nm in space.names},
            **{f"{nm}_sd": ["time"] for nm in space.names},
            **{f"{nm}_hdi95": ["time", "bound"] for nm in space.names},
        },
        coords={
            "window": np.arange(nw),
            "time": t[agg["covered"]],
            "bound": ["lower", "upper"],
            "window_start": ("window", t[spans[:, 0]]),
        },
        runtime_s=time.perf_counter() - t0c,
        warnings=warnings,
        window_posteriors=fw["posteriors"],
    )


def noise_pass(ex, base, obs, s, n_steps: int, seed: int, progress) -> dict:
    """The default likelihood's noise model: each record's noise variance and tempering, from a
    pilot pass (``adapt``; the record's noise and no tempering otherwise), with a second pilot for
    a bubble whose pilot residual stands out (``pilot_retry``, :func:`_retry_lost_pilots`).

    Returns {"var" (n_exp,), "alpha" (n_exp,), "lik_info" [dict], "nuis_sd" (n_exp, 3): the
    nuisances' prior sds, "failed_units", "warnings", "member_runs", "failed_member_runs"}."""
    n_exp = obs.n_exp
    noise_var = np.array([record_noise_sd(obs, g) ** 2 for g in range(n_exp)])
    nuis_sd = np.stack([nuisance_prior_sd(obs, g) for g in range(n_exp)])  # (a, delta, rho)
    out = {
        "var": noise_var.copy(),
        "alpha": np.ones(n_exp),
        "nuis_sd": nuis_sd,
        "failed_units": [],
        "warnings": [],
        "member_runs": 0,
        "failed_member_runs": 0,
    }
    if not s.adapt:
        out["lik_info"] = [
            {
                "noise_sd": float(np.sqrt(v)),
                "sd_used": float(np.sqrt(v)),
                "alpha": 1.0,
                "effective_samples": None,
                "autocorrelation_time": None,
                "note": "adapt=False: the record's noise, no tempering",
            }
            for v in noise_var
        ]
        return out
    # pilot pass: the record's noise, no tempering; its fitted curve sets each experiment's
    # noise level and tempering for the pass that is reported (module doc)
    sp = s.pilot()
    spans_p = window_spans(n_steps, sp.L, sp.h)
    nw_p = spans_p.shape[0]
    beta_p = mda_weights(n_steps, sp.L, sp.h)
    beta_p[:, 0] = 0.0

    def w_pilot(j, g, a, b):
        return beta_p[j, a : b + 1] / noise_var[g]

    pil = _sweep(ex, base, obs, sp, spans_p, seed, w_pilot, nuis_sd, {"pass": "pilot"}, progress, nw_p)
    for w in pil["warnings"]:
        out["warnings"].extend(w)
    failed = pil["failed_units"]
    var, alpha, lik_info = _noise_model(obs, _fitted(obs, spans_p, pil, nw_p, sp.h), noise_var)
    flagged = pilot_outliers(lik_info, obs.names)
    retry_sweeps = []
    if s.pilot_retry:
        more, retry_sweeps, retry_failed = _retry_lost_pilots(
            ex, base, obs, s, sp, spans_p, seed, w_pilot, nuis_sd, noise_var, var, alpha, lik_info
        )
        flagged += more
        failed = failed + retry_failed
    out["warnings"].extend(flagged)
    for sweep in [pil, *retry_sweeps]:
        out["member_runs"] += sum(int(r["member_runs"]) for R in sweep["results"] for r in R)
        out["failed_member_runs"] += sum(int(r["failed_member_runs"]) for R in sweep["results"] for r in R)
    out.update({"var": var, "alpha": alpha, "lik_info": lik_info, "failed_units": failed})
    return out


def fuse_windows(obs, space, s, spans, sw: dict, beta, noise: dict | None) -> dict:
    """Every window's experiments fused (:func:`_window_fusion`) and recorded (:func:`_window_entry`).

    Takes the observations, space, resolved settings, the window spans, the reported sweep, the MDA
    weights and the noise model (None: the paper's likelihood). Returns {"windows" [dict],
    "posteriors" [WindowPosterior], "mean" (nw, d), "cov" (nw, d, d), "lik_terms" {experiment:
    [(Lambda, eta) per window]}, "lik_joint" [per window {experiment: (Lambda, eta) of (parameters,
    rho)}], "chain" (F, D, L lists for :func:`~imrbayes.ensemble.aggregate.chain_aggregate_cov`),
    "average", "warnings", "member_runs", "failed_member_runs", "total_fail", "total_redraw"}."""
    default = noise is not None
    out = {
        "windows": [],
        "posteriors": [],
        "mean": [],
        "cov": [],
        "lik_terms": {g: [] for g in range(obs.n_exp)},
        "lik_joint": [],
        "chain": ([], [], []),
        "average": s.L if s.obs_weight == "mean" else 1,
        "warnings": [],
        "member_runs": 0,
        "failed_member_runs": 0,
        "total_fail": 0,
        "total_redraw": 0,
    }
    chain = (space.prior_mean.copy(), space.prior_cov.copy())
    influence = np.eye(len(space.names))  # the parameter prior mean's weight in the window means
    for j, (a, b) in enumerate(spans):
        ok, R = sw["ok"][j], sw["results"][j]
        out["warnings"].extend(sw["warnings"][j])
        prior_m, prior_c = (space.prior_mean, space.prior_cov) if s.fusion == "prior" else chain
        wf = _window_fusion(space, s, R, ok, chain, noise, out)
        chain = wf["chain"]
        est_m, est_c = wf["estimate"]
        out["mean"].append(est_m)
        out["cov"].append(est_c)
        # prior_c is the prior this window used: the chain's, or the parameter prior when not chained
        influence = chained_prior_weight(influence if s.fusion != "prior" else np.eye(len(space.names)), est_c, prior_c)
        whiten = None
        if default:
            m = b - a + 1
            whiten = np.full((obs.n_exp, m, m), np.nan)
            for g in ok:
                whiten[g] = np.diag(np.sqrt(beta[j, a : b + 1] * noise["alpha"][g] / noise["var"][g]))
        out["posteriors"].append(
            _window_posterior(j, a, b, sw, wf["fusion"], prior_m, prior_c, beta, whiten, out["average"], default)
        )
        out["windows"].append(_window_entry(obs, space, j, a, b, sw, wf, influence, out))
    note = prior_dominated_note(out["windows"], space.names)
    if note:
        out["warnings"].append(note)
    out["mean"], out["cov"] = np.array(out["mean"]), np.array(out["cov"])
    return out


def _window_fusion(space, s, R: list, ok: list, chain: tuple, noise: dict | None, acc: dict) -> dict:
    """One window's experiments fused: default likelihood, random effects on their window
    likelihoods with the gel mean's prior chained from the previous window (RTPS); paper, the
    product rule (``fusion``). Appends the window's likelihood terms and chain weights to ``acc``
    (:func:`fuse_windows`). Returns {"fusion": the pooled :class:`~imrbayes.ensemble.fusion.Fusion`
    (what --mcmc checks), "estimate": (mean, cov), "chain": the next window's prior, "extra": the
    window entry's random-effects fields, "pm", "pc": each experiment's posterior}."""
    pm, pc = np.stack([r["pm"] for r in R]), np.stack([r["pc"] for r in R])
    qm, qc = np.stack([r["qm"] for r in R]), np.stack([r["qc"] for r in R])
    chain_m, chain_c = chain
    out = {"pm": pm, "pc": pc, "extra": {}}
    if noise is not None:
        bubbles = fuse_bubbles(space, pm, pc, qm, qc, prior=(chain_m, chain_c))
        hier = bubbles.random
        for i, g in enumerate(ok):
            acc["lik_terms"][g].append((bubbles.lam[i], bubbles.eta[i]))
        if all("joint" in r for r in R) and np.all(noise["nuis_sd"][np.asarray(ok), 2] > 0):  # rho analysed
            Lj, ej, _, _ = likelihood_terms(*(np.stack([r["joint"][x] for r in R]) for x in ("pm", "pc", "qm", "qc")))
            acc["lik_joint"].append({g: (Lj[i], ej[i]) for i, g in enumerate(ok)})
        else:
            acc["lik_joint"].append({})
        h = bubbles.summaries()
        out["extra"] = {
            "between_experiments": h["between_experiments"],
            "predictive": h["predictive"],
            "random_effects": hier.to_dict(),
            "pooled_mean_internal": hier.pooled_mean.tolist(),
            "pooled_cov_internal": hier.pooled_cov.tolist(),
        }
        out["notes"] = hier.notes
        # the window mean's linear weights (aggregate.chain_aggregate_cov)
        T_j = np.diag(np.where(np.isfinite(hier.tau), hier.tau, 0.0) ** 2)
        F, D, L = acc["chain"]
        F.append(hier.cov @ np.linalg.inv(chain_c))
        D.append(
            {g: hier.cov @ np.linalg.inv(np.eye(len(space.names)) + bubbles.lam[i] @ T_j) for i, g in enumerate(ok)}
        )
        L.append({g: bubbles.lam[i] for i, g in enumerate(ok)})
        out.update(
            {
                "fusion": bubbles.pooled(),
                "estimate": (hier.mean, hier.cov),
                "chain": (hier.mean, rtps_cov(chain_c, hier.cov, s.rtps)),
            }
        )
    elif s.fusion == "prior":
        fus = fuse(pm, pc, space.prior_mean, space.prior_cov)
        out.update({"fusion": fus, "estimate": (fus.mean, fus.cov), "chain": chain})
    else:
        fus = fuse_likelihoods(pm, pc, qm, qc, chain_m, chain_c)
        out.update(
            {"fusion": fus, "estimate": (fus.mean, fus.cov), "chain": (fus.mean, rtps_cov(chain_c, fus.cov, s.rtps))}
        )
    return out


def _window_posterior(j: int, a: int, b: int, sw: dict, fus, prior_m, prior_c, beta, whiten, average, default: bool):
    """The :class:`WindowPosterior` of window j (what ``--mcmc`` samples): the pooled Gaussian, the
    prior the window used, the observation weights and each experiment's handed-off start."""
    start_j = sw["start_means"][j]
    entering = np.isfinite(start_j).all(axis=1)
    if default:
        desc = {
            "kind": "MIEnKS-MDA window",
            "state": "handed-off ensemble mean",
            "weight_rule": "default likelihood: ||W_n (y_n - R_n)||^2 with W_n = diag(sqrt(beta_jk alpha_n / "
            "sigma_n^2)) (the MDA weights are inside W_n; weight holds beta_jk)",
            "gaussian": "pooled over experiments (no between-bubble scatter)",
            "L": 1,
            "R_spread_at_start": [0.0] * int(entering.sum()),
            "index": j,
        }
        if j == 0:
            desc["nuisance"] = (
                "the ensemble also analysed each experiment's Rmax, Req and time of the maximum; "
                "this density fixes them at the preprocessing estimates"
            )
        else:
            desc["nuisance"] = (
                "each experiment runs with its handed-off ensemble's mean Req (start_req_m); the "
                "ensemble kept analysing Req"
            )
        wpost = beta[j, a : b + 1]
    else:
        desc = {
            "kind": "MIEnKS-MDA window",
            "state": "handed-off ensemble mean",
            "weight_rule": f"beta_jk / L, L = {average}",
            "L": average,
            "R_spread_at_start": [0.0] * int(entering.sum()),
            "index": j,
        }
        wpost = beta[j, a : b + 1] / average
    return WindowPosterior(
        index=j,
        start=int(a),
        samples=(int(a), int(b)),
        mean=fus.mean,
        cov=fus.cov,
        prior_mean=prior_m,
        prior_cov=prior_c,
        weight=wpost,
        start_state=start_j,
        description=desc,
        whiten=whiten,
        start_req_m=sw["start_req"][j] if default else None,
    )


def _window_entry(obs, space, j: int, a: int, b: int, sw: dict, wf: dict, influence, acc: dict) -> dict:
    """``windows[j]`` of the result: the window's estimate, prior weight, failures and costs;
    adds the window's member runs, failures and warnings to ``acc`` (:func:`fuse_windows`)."""
    ok, R, lost = sw["ok"][j], sw["results"][j], sw["lost"][j]
    t = obs.t_star
    est_m, est_c = wf["estimate"]
    fus = wf["fusion"]
    if wf.get("notes"):
        acc["warnings"].append(f"window {j}: " + "; ".join(wf["notes"]))
    rejected = []
    for g, r in zip(ok, R):
        if r["rejected"]:
            rejected.append(obs.names[g])
        acc["member_runs"] += int(r["member_runs"])
        acc["failed_member_runs"] += int(r["failed_member_runs"])
    if rejected:
        acc["warnings"].append(
            f"window {j}: analysis rejected for {', '.join(rejected)} (too few analysed members "
            f"survived the hand-off; the window's prior ensemble was handed on)"
        )
    n_failed_iter = np.sum([r["n_failed_iter"] for r in R], axis=0)
    n_fail = sum(int(r["n_failed_handoff"]) for r in R)
    n_red = sum(int(r["n_redrawn_handoff"]) for r in R)
    n_red_prior = sum(int(r["n_redrawn_prior"]) for r in R)
    acc["total_redraw"] += n_red + n_red_prior
    acc["total_fail"] += n_fail + int(n_failed_iter.sum())
    if fus.notes:
        acc["warnings"].append(f"window {j}: " + "; ".join(fus.notes))
    with np.errstate(invalid="ignore"), _warnings.catch_warnings():
        _warnings.simplefilter("ignore", RuntimeWarning)
        cost = np.nanmean(np.stack([r["cost"] for r in R]), axis=0)
    weight = np.diag(influence)
    pm, pc = wf["pm"], wf["pc"]
    return {
        "index": j,
        "t_star": [float(t[a]), float(t[b])],
        "samples": [int(a), int(b)],
        **gaussian_estimate(space, est_m, est_c),
        "prior_weight": {nm: float(x) for nm, x in zip(space.names, weight)},
        "prior_dominated": bool(np.any(weight > PRIOR_WEIGHT_LIMIT)),
        "cov": si_covariance(space, est_m, est_c).tolist(),
        "mean_internal": est_m.tolist(),
        "cov_internal": est_c.tolist(),
        **wf["extra"],
        "fusion": fus.to_dict(),
        "n_failed_iterations": n_failed_iter.tolist(),
        "n_redrawn_prior": n_red_prior,
        "n_failed_handoff": n_fail,
        "n_redrawn_handoff": n_red,
        "stopped_experiments": sum(bool(r["stopped"]) for r in R),
        "handoff_failures": {
            obs.names[g]: {
                "analysed_invalid_state": int(r.get("n_invalid_analysed", 0)),
                "analysed_failed": int(r.get("n_failed_analysed", 0)),
                "invalid_why": dict(r.get("invalid_why", {})),
            }
            for g, r in zip(ok, R)
            if r.get("n_failed_analysed", 0)
        },
        "analysis_rejected": rejected,
        "failed_experiments": lost,
        "cost": [float(x) if np.isfinite(x) else None for x in cost],  # None: every bubble stopped
        "per_experiment": [
            {"name": obs.names[g], "mean_internal": pm[i].tolist(), "sd_internal": np.sqrt(np.diag(pc[i])).tolist()}
            for i, g in enumerate(ok)
        ],
    }


def _aggregate(obs, space, s, fw: dict, n_steps: int, rng) -> dict:
    """The time-resolved estimate (normalised precision weighting of the windows holding each
    sample), the aggregate (the same over all windows: its "mean", "cov") and posterior.nc's draws
    of every window's Gaussian. Returns those with "covered" (sample indices), "mask" (the fitted
    samples of a curve) and the time-resolved group."""
    win_mean, win_cov = fw["mean"], fw["cov"]
    nw = win_mean.shape[0]
    t = obs.t_star
    tr_m, tr_c, covered = time_resolved(win_mean, win_cov, n_steps, s.L, s.h)
    tr = [
        {"t_star": float(t[k]), "sample": int(k), **gaussian_estimate(space, tr_m[k], tr_c[k])}
        for k in np.flatnonzero(covered)
    ]
    agg_m, agg_c = precision_weighted(win_mean, win_cov)

    def mask(fitted):
        m = np.isfinite(fitted)
        m[:, 0] = False
        return m

    # posterior.nc: draws of every window's fused Gaussian (1 chain), the time-resolved moments
    draws = np.stack(
        [space.to_si(draw(rng, win_mean[j], win_cov[j], s.n_draws, exact=False)) for j in range(nw)], axis=-1
    )  # (n_draws, d, nw)
    tr_group = {}
    for nm in space.names:
        tr_group[f"{nm}_mean"] = np.array([x[nm]["mean"] for x in tr])
        tr_group[f"{nm}_sd"] = np.array([x[nm]["sd"] for x in tr])
        tr_group[f"{nm}_hdi95"] = np.array([x[nm]["hdi95"] for x in tr])
    return {
        "mean": agg_m,
        "cov": agg_c,
        "time_resolved": tr,
        "covered": np.flatnonzero(covered),
        "mask": mask,
        "posterior": {nm: draws[None, :, i, :] for i, nm in enumerate(space.names)},
        "time_resolved_group": tr_group,
    }


def _default_likelihood_record(s, lik_info: list) -> dict:
    """``details["mda"]`` and ``details["likelihood"]`` of the default likelihood, in words and numbers."""
    return {
        "mda": (
            "beta_jk = 1/|I(k)| (sample 0, the maximum, excluded), window cost 1/2 sum_k beta_jk "
            "alpha_n ||.||^2 / sigma_n^2: every sample counts once over the windows, no 1/L"
        ),
        "likelihood": {
            "name": "default",
            "effective_samples": [x["effective_samples"] for x in lik_info],
            "autocorrelation_time": [x["autocorrelation_time"] for x in lik_info],
            "noise_sd": [x["noise_sd"] for x in lik_info],
            "sd_used": [x["sd_used"] for x in lik_info],
            "alpha": [x["alpha"] for x in lik_info],
            "n_samples": [x.get("n_samples") for x in lik_info],
            "noise": (
                "each record's noise sd (preprocessing, else fourth differences), raised to the RMS of the "
                "pilot pass's residual where the model does not reach the noise; each experiment tempered "
                "by alpha = n_eff/K (integrated autocorrelation time of that residual)"
                if s.adapt
                else "each record's noise sd (preprocessing, else fourth differences); no tempering"
            ),
            "mda": "beta_jk = 1/|I(k)|: the weights of every sample over the windows holding it sum to one",
            "nuisances": "Rmax and the time of the maximum analysed in window 0's augmented ensemble, log Req in "
            "every window's (prior sds from preprocessing)",
            "fusion": "random effects across experiments in every window (gel-level mean, between-bubble sd, "
            "predictive); the gel mean's prior chained from the previous window (RTPS)",
        },
    }


def record_level(obs, space, s, sw: dict, fw: dict, noise: dict, agg_m, agg_c, details: dict) -> tuple:
    """The default likelihood's record level: each experiment's window likelihoods summed (each
    sample counted once; parameters constant over the record, like the aggregate estimate), random
    effects on those, the aggregate's covariance propagated through the window chain
    (:func:`~imrbayes.ensemble.aggregate.chain_aggregate_cov`) and the predictive.

    Takes the observations, space, resolved settings, the reported sweep, :func:`fuse_windows`'
    result, the noise model, the aggregate's mean and (weighting) covariance, and ``details``
    (updated in place). Returns (the reported aggregate covariance (d, d), ``per_experiment``)."""
    n_exp, nw = obs.n_exp, fw["mean"].shape[0]
    lik_terms = fw["lik_terms"]
    used = [g for g in range(n_exp) if lik_terms[g]]
    rec = BubbleFusion.from_likelihoods(
        space,
        np.stack([sum(x[0] for x in lik_terms[g]) for g in used]),
        np.stack([sum(x[1] for x in lik_terms[g]) for g in used]),
    )
    hr = rec.summaries()
    tau2 = np.diag(np.where(np.isfinite(rec.random.tau), rec.random.tau, 0.0) ** 2)
    # the aggregate's covariance propagated through the window chain (module doc, "Aggregate")
    Q = np.stack([agg_c @ np.linalg.inv(c) / nw for c in fw["cov"]])
    agg_chain = chain_aggregate_cov(*fw["chain"], Q, space.prior_cov, tau2)
    # a new bubble: the gel-level uncertainty plus the between-bubble variance with tau's
    # uncertainty integrated (the record's predictive less its gel-level covariance)
    between_var = np.maximum(np.diag(rec.random.predictive_cov) - np.diag(rec.random.cov), np.diag(tau2))
    agg_weighting = agg_c
    if s.aggregate_cov == "chain":
        agg_c = agg_chain
        pred_var, pred_rule = (
            between_var,
            (
                "the aggregate (covariance propagated through the window chain) "
                "widened by the between-bubble variance with tau's uncertainty "
                "integrated (record level)"
            ),
        )
    else:
        pred_var, pred_rule = np.diag(tau2), "the aggregate estimate widened by its between-bubble sd"
    pred = {
        nm: marginal_summary(agg_m[i], float(np.sqrt(max(agg_c[i, i] + pred_var[i], 0.0))), bool(space.positive[i]))
        for i, nm in enumerate(space.names)
    }
    alt = details.setdefault("alternative_estimates", {})
    other = "aggregate_precision_weighted" if s.aggregate_cov == "chain" else "aggregate_chain_cov"
    other_c = agg_weighting if s.aggregate_cov == "chain" else agg_chain
    alt[other] = {
        **gaussian_estimate(space, agg_m, other_c),
        "cov_internal": other_c.tolist(),
        "note": (
            "the aggregate's mean with methods.md §4's normalised precision weighting's "
            "covariance (about one window's: the windows treated as one)"
            if s.aggregate_cov == "chain"
            else "the aggregate's mean with its covariance propagated through the window chain "
            "(imrbayes.ensemble.aggregate)"
        ),
    }
    if s.aggregate_cov != "chain":
        details.setdefault("alternative_predictives", {})["aggregate_chain_cov"] = {
            nm: marginal_summary(
                agg_m[i], float(np.sqrt(max(agg_chain[i, i] + between_var[i], 0.0))), bool(space.positive[i])
            )
            for i, nm in enumerate(space.names)
        }
    details["aggregate_cov_rule"] = s.aggregate_cov
    details["aggregate_cov_internal"] = agg_c.tolist()
    details.update(
        {
            "between_experiments": hr["between_experiments"],
            "predictive": pred,
            "record_random_effects": {
                **rec.random.to_dict(),
                "estimate": hr["estimate"],
                "note": "each experiment's window likelihoods summed over the "
                "record (constant parameters) with the parameter prior; "
                "top-level between_experiments is this; predictive is " + pred_rule,
            },
        }
    )
    joint = _record_with_shared_req(fw["lik_joint"], used, noise["nuis_sd"], space)
    if joint is not None:
        details.setdefault("alternative_estimates", {})["record_shared_req"] = joint
    loo = rec.leave_one_out()
    if loo is not None:
        loo["note"] += "; each experiment's window likelihoods summed over the record"
        details["leave_one_bubble_out"] = loo
    return agg_c, _record_per_experiment(obs, space, sw, rec, used, noise["lik_info"])


def _record_per_experiment(obs, space, sw: dict, rec: BubbleFusion, used: list, lik_info: list) -> list:
    """``per_experiment``: each experiment's record-level estimate (the parameter prior times its
    window likelihoods), its likelihood and its nuisances."""
    nw = len(sw["ok"])
    Pi0 = np.linalg.inv(space.prior_cov)
    per = []
    for g in range(obs.n_exp):
        entry = {"name": obs.names[g]}
        if g in used:
            i = used.index(g)
            C = np.linalg.inv(Pi0 + rec.lam[i])
            mg = C @ (Pi0 @ space.prior_mean + rec.eta[i])
            entry.update(
                {
                    "estimate": gaussian_estimate(space, mg, C),
                    "mean_internal": mg.tolist(),
                    "cov_internal": C.tolist(),
                    "estimate_rule": "parameter prior times the experiment's window likelihoods over the record",
                }
            )
        else:
            entry["failed"] = True
        entry["likelihood"] = lik_info[g]
        w0 = sw["results"][0][sw["ok"][0].index(g)] if g in sw["ok"][0] else {}
        last_j = max((j for j in range(nw) if g in sw["ok"][j]), default=None)
        wl = sw["results"][last_j][sw["ok"][last_j].index(g)] if last_j is not None else {}
        entry["nuisance"] = _nuisance(obs, g, w0.get("rmax_rel"), w0.get("offset"), wl.get("log_req"))
        per.append(entry)
    return per


def _record_with_shared_req(lik_joint, used, nuis_sd, space):
    """The record-level estimate with each experiment's log Req shared by its windows: every window's
    likelihood of (parameters, rho) summed, rho integrated out against its preprocessing prior
    N(0, sd_rho^2) (a Schur complement), then the same random effects as the reported record-level
    estimate (whose windows each integrate rho out against their own chained prior). None when a
    window lacks the joint terms (e.g. a resumed run from before they were kept)."""
    if nuis_sd is None or not used or not lik_joint or any(g not in w for w in lik_joint for g in used):
        return None
    Lz, ez = [], []
    for g in used:
        L, e = integrate_out_last(
            sum(w[g][0] for w in lik_joint), sum(w[g][1] for w in lik_joint), float(nuis_sd[g][2])
        )
        Lz.append(L)
        ez.append(e)
    return BubbleFusion.from_likelihoods(space, np.stack(Lz), np.stack(ez)).summaries()["estimate"]


def integrate_out_last(Lam, eta, prior_sd: float):
    """A Gaussian likelihood exp(-x^T Lam x / 2 + eta^T x) of x = (z, r), (d+1, d+1) and (d+1,), times
    the prior N(0, prior_sd^2) of its last coordinate r, integrated over r: the likelihood of z,
    (Lam_z (d, d), eta_z (d,)) (a Schur complement). prior_sd <= 0: r fixed at 0."""
    return integrate_out_trailing(Lam, eta, [float(prior_sd)])


def _nuisance(obs, g: int, rmax_rel, offset, log_req) -> dict:
    """``per_experiment[].nuisance`` (SI, :func:`imrbayes.ensemble.likelihood.nuisance_summary`, as
    En4D-Var's): Rmax and the time of the maximum from window 0's augmented ensemble (``rmax_rel`` =
    a, ``offset`` = delta [t*]), Req from the last window the experiment took part in (``log_req`` =
    rho, analysed in every window); None: not analysed (the preprocessing estimate and its sd)."""
    prior = nuisance_prior_sd(obs, g)
    post = (rmax_rel, offset, log_req)
    mean = [0.0 if x is None else x["mean"] for x in post]
    sd = [p if x is None else x["sd"] for x, p in zip(post, prior)]
    out = nuisance_summary(
        mean, sd, prior, float(obs.rmax_m[g]), float(obs.req_m[g]), float(obs.t0_s[g]), float(obs.tc_s[g])
    )
    del out["treatment"]
    where = {
        "rmax_m": "analysed with the parameters in window 0's augmented ensemble",
        "t0_s": "analysed with the parameters in window 0's augmented ensemble",
        "req_m": "log Req analysed with the parameters in every window (the last one's posterior)",
    }
    for key, x in zip(("rmax_m", "t0_s", "req_m"), post):
        out[key]["treatment"] = (
            "not analysed (window 0 failed): the preprocessing estimate"
            if x is None
            else where[key] + (" (analysis rejected: the prior)" if x.get("rejected") else "")
        )
    return out


class MIEnKS(InferenceMethod):
    """MIEnKS-MDA as a plug-in (:class:`~imrbayes.ensemble.method.InferenceMethod`)."""

    name = "mienks"
    label = "MIEnKS-MDA (sliding-window smoother)"
    settings_class = MIEnKSSettings
    gaussian_posterior = True
    estimate_note = (
        "Aggregate over the whole record: the windows' precision-weighted mean, its sd propagated "
        "through the window chain (each sample counted once, each bubble's deviation from the gel "
        "shared by its windows; details.aggregate_cov_rule 'chain'; with the paper's likelihood "
        "the weighting's own covariance, 'weighting')."
    )
    fit = staticmethod(fit_mienks)

    @staticmethod
    def global_start(settings, space) -> bool:
        return settings.likelihood == "default" and {"G", "mu"} <= set(space.names)

    @staticmethod
    def check_settings(settings, obs):
        settings.check(obs.n_samples - 1)

    @staticmethod
    def n_forward_runs(settings, n_exp, n_steps):
        # per window: the Gauss-Newton iterations and the hand-off, every member -- at most: with
        # min_iter a window whose cost has settled stops early (stiff PA 1-5: ~75 % of this)
        s = settings
        n = n_windows(n_steps, s.L, s.h) * (s.n_iter + 1) * s.n_ens * n_exp
        if s.likelihood == "default" and s.adapt:  # the default likelihood's pilot pass
            p = s.pilot()
            n += n_windows(n_steps, p.L, p.h) * (p.n_iter + 1) * p.n_ens * n_exp
        return n

    @staticmethod
    def n_units(settings, n_exp, n_steps, fm=None):
        nw = n_windows(n_steps, settings.L, settings.h)
        if getattr(settings, "likelihood", "paper") == "default" and getattr(settings, "adapt", False):
            # the default likelihood's pilot pass sets the noise level, then the reported pass
            sp = settings.pilot()
            nwp = n_windows(n_steps, sp.L, sp.h)
            if nwp == nw:
                return 2 * nw * n_exp, f"2 passes x {nw} windows x {n_exp} experiments"
            return (nwp + nw) * n_exp, f"a pilot pass of {nwp} windows and {nw} windows, x {n_exp} experiments"
        return nw * n_exp, f"{nw} windows x {n_exp} experiments"

    @staticmethod
    def figures(obs, res, fdir):
        from imrbayes.ensemble.figures import time_resolved_figure

        return [time_resolved_figure(res, fdir / "parameters.png")]
