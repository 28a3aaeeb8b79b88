"""What every inference method consumes: the observations on the t* grid and the parameter space.

Methods never see physics: they get a forward model (``imrbayes.forward.ForwardModel``), an
:class:`Observations` (arrays from preprocessing) and a :class:`ParamSpace` (names, which
parameters are positive, the prior).

Conventions (all methods)
-------------------------
* Time ``t_star`` (n,) is dimensionless, sample k at k dt*; sample 0 is the radius maximum, where
  every curve is R* = 1 by construction (it carries no information about the parameters).
* ``R_star`` (n_exp, n) is R/Rmax per experiment; ``P`` (n,) the measurement-noise variance per
  sample in R*^2 (methods.md §3).
* Positive parameters (``Parameter.positive``; G and mu for NHKV) are inferred in **log space**:
  the internal coordinate is ``z = log(theta / 1 SI unit)``. Nothing is ever clipped; a Gaussian
  in z is a log-normal in theta. Parameters that may be negative are used as they are.
* The paper's priors are given as a mean and sd in SI units (G 6 +- 2.8 kPa, mu 0.209 +- 0.088
  Pa s). For a positive parameter they become the log-normal with that mean and sd:
  ``s^2 = log(1 + (sd/mean)^2)``, ``m = log(mean) - s^2/2`` (moment matching).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from imrbayes.errors import InputError

__all__ = ["Observations", "ParamSpace", "PAPER_PRIOR", "WIDE_PRIOR", "PRIORS", "lognormal_moments"]

#: Prior of methods.md §3 (mean, sd) in SI units; parameters not listed use the model default
#: with a 50 % sd. Set for the paper's gels: on other materials it decides the answer
#: (docs/methods.md, "Priors").
PAPER_PRIOR = {"G": (6.0e3, 2.8e3), "mu": (0.209, 0.088)}


def lognormal_moments(median: float, log_sd: float) -> tuple:
    """(mean, sd) in SI of the log-normal with this median and sd of the log: the form
    :meth:`ParamSpace.for_model` takes, which maps it back to exactly this median and log-sd."""
    s2 = log_sd**2
    mean = median * math.exp(0.5 * s2)
    return mean, mean * math.sqrt(math.expm1(s2))


#: The default prior: weakly informative over every material a user can bring. Log-normal with
#: median 3 kPa and log-sd 2.9 for G (95 %: 10 Pa to 0.9 MPa) and median 0.03 Pa s, log-sd 2.9
#: for mu (95 %: 1e-4 to 9 Pa s).
WIDE_PRIOR = {"G": lognormal_moments(3.0e3, 2.9), "mu": lognormal_moments(0.03, 2.9)}
#: Named priors (``fit --prior NAME``).
PRIORS = {"wide": WIDE_PRIOR, "paper": PAPER_PRIOR}


@dataclass
class Observations:
    """Preprocessed measurements of N_exp experiments on one t* grid.

    Attributes
    ----------
    t_star : ndarray (n,)
        Sample times k dt*, k = 0..n-1 (t*[0] = 0 at the maximum).
    R_star : ndarray (n_exp, n)
        Measured R/Rmax.
    P : ndarray (n,)
        Noise variance per sample [R*^2], > 0.
    rmax_m, req_m : ndarray (n_exp,)
        Maximum and equilibrium radius of each experiment [m].
    t_collapse_star : ndarray (n_exp,)
        Measured first-collapse time t* (pIMR); NaN if unknown.
    names : list of str
    noise_sd : ndarray (n_exp,)
        Each record's own measurement-noise sd in R* (its fourth differences / Rmax; NaN: unknown),
        what the default likelihood uses (:mod:`imrbayes.ensemble.likelihood`).
    nuisance_sd : ndarray (n_exp, 3)
        Preprocessing's standard errors of (Rmax / Rmax_hat - 1 [-], time of the maximum [t*],
        Req [m]); 0 where unknown (the quantity is then treated as known).
    t0_s, tc_s : ndarray (n_exp,)
        Time of the maximum in the file's clock [s] and the time scale Rmax sqrt(rho/p8) [s]
        (to state the time offset in seconds; NaN if unknown).
    frame_t : list of ndarray or None
        Per experiment, the camera frame times t* whose linear interpolation gave ``R_star``
        (:attr:`imrbayes.data.Preprocessed.frame_t_star`); None: the grid values are point values.
    req_tail_t : list of ndarray or None
        Per experiment, t* of the frames whose mean is ``req_m`` (empty: Req given, not measured);
        None: unknown.
    """

    t_star: np.ndarray
    R_star: np.ndarray
    P: np.ndarray
    rmax_m: np.ndarray
    req_m: np.ndarray
    t_collapse_star: np.ndarray | None = None
    names: list = field(default_factory=list)
    noise_sd: np.ndarray | None = None
    nuisance_sd: np.ndarray | None = None
    t0_s: np.ndarray | None = None
    tc_s: np.ndarray | None = None
    frame_t: list | None = None
    req_tail_t: list | None = None

    def __post_init__(self):
        self.t_star = np.asarray(self.t_star, dtype=np.float64)
        self.R_star = np.atleast_2d(np.asarray(self.R_star, dtype=np.float64))
        self.P = np.broadcast_to(np.asarray(self.P, dtype=np.float64), self.t_star.shape).copy()
        n_exp, n = self.R_star.shape
        self.rmax_m = np.broadcast_to(np.asarray(self.rmax_m, dtype=np.float64), (n_exp,)).copy()
        self.req_m = np.broadcast_to(np.asarray(self.req_m, dtype=np.float64), (n_exp,)).copy()
        if self.t_collapse_star is None:
            self.t_collapse_star = np.full(n_exp, np.nan)
        self.t_collapse_star = np.broadcast_to(np.asarray(self.t_collapse_star, dtype=np.float64), (n_exp,)).copy()
        if not self.names:
            self.names = [f"exp_{i + 1:03d}" for i in range(n_exp)]

        def per_exp(a, shape, fill):
            return np.full(shape, fill) if a is None else np.broadcast_to(np.asarray(a, np.float64), shape).copy()

        self.noise_sd = per_exp(self.noise_sd, (n_exp,), np.nan)
        self.nuisance_sd = per_exp(self.nuisance_sd, (n_exp, 3), 0.0)
        self.nuisance_sd = np.where(np.isfinite(self.nuisance_sd) & (self.nuisance_sd > 0), self.nuisance_sd, 0.0)
        self.t0_s = per_exp(self.t0_s, (n_exp,), np.nan)
        self.tc_s = per_exp(self.tc_s, (n_exp,), np.nan)
        if self.frame_t is not None:
            self.frame_t = [np.asarray(f, dtype=np.float64) for f in self.frame_t]
            if len(self.frame_t) != n_exp or any(f.size < 2 or np.any(np.diff(f) <= 0) for f in self.frame_t):
                raise InputError("observations", "frame_t needs increasing frame times for every experiment")
        if self.req_tail_t is not None:
            self.req_tail_t = [np.asarray(f, dtype=np.float64).reshape(-1) for f in self.req_tail_t]
            if len(self.req_tail_t) != n_exp:
                raise InputError("observations", "req_tail_t needs one entry per experiment")
        if n != self.t_star.size:
            raise InputError("observations", f"R_star has {n} samples per experiment, t_star {self.t_star.size}")
        if n < 2 or np.any(np.diff(self.t_star) <= 0):
            raise InputError("observations", "t_star must hold at least two increasing samples")
        if not np.all(np.isfinite(self.R_star)):
            raise InputError("observations", "measured radii must be finite")
        if not (np.all(np.isfinite(self.P)) and np.all(self.P > 0)):
            raise InputError("observations", "the noise variances P_k must be finite and positive")
        if not (np.all(self.rmax_m > 0) and np.all(self.req_m > 0) and np.all(self.req_m < self.rmax_m)):
            raise InputError("observations", "need 0 < Req < Rmax for every experiment")

    @classmethod
    def from_preprocessed(cls, pre) -> Observations:
        """From :class:`imrbayes.data.Preprocessed`."""
        ex = list(getattr(pre, "experiments", []) or [])
        if not ex:
            return cls(pre.t_star, pre.R_star, pre.P, pre.rmax_m, pre.req_m, pre.t_collapse_star, list(pre.names))

        def col(key):
            return np.array([float(getattr(e, key, np.nan)) for e in ex])

        rmax = np.asarray(pre.rmax_m, dtype=np.float64)
        noise_m, tc = col("noise_sd_m"), col("tc_s")
        # the maximum's radius: the local fit's standard error, else one noise sd (a max sample)
        rmax_se = np.where(np.isfinite(col("rmax_sd_m")), col("rmax_sd_m"), noise_m)
        nuis = np.stack([rmax_se / rmax, col("t0_sd_s") / tc, col("req_sd_m")], axis=1)
        return cls(
            pre.t_star,
            pre.R_star,
            pre.P,
            rmax,
            pre.req_m,
            pre.t_collapse_star,
            list(pre.names),
            noise_sd=noise_m / rmax,
            nuisance_sd=nuis,
            t0_s=col("t0_s"),
            tc_s=tc,
            frame_t=list(getattr(pre, "frame_t_star", []) or []) or None,
            req_tail_t=[list(getattr(e, "req_tail_t_star", []) or []) for e in ex],
        )

    @property
    def n_exp(self) -> int:
        return int(self.R_star.shape[0])

    @property
    def n_samples(self) -> int:
        return int(self.t_star.size)

    @property
    def dt_star(self) -> float:
        return float(self.t_star[1] - self.t_star[0])

    def take(self, index) -> Observations:
        """The experiments ``index`` (list/array of ints)."""
        idx = np.atleast_1d(np.asarray(index, dtype=int))
        return Observations(
            self.t_star,
            self.R_star[idx],
            self.P,
            self.rmax_m[idx],
            self.req_m[idx],
            self.t_collapse_star[idx],
            [self.names[i] for i in idx],
            self.noise_sd[idx],
            self.nuisance_sd[idx],
            self.t0_s[idx],
            self.tc_s[idx],
            None if self.frame_t is None else [self.frame_t[i] for i in idx],
            None if self.req_tail_t is None else [self.req_tail_t[i] for i in idx],
        )


def _sym(a):
    a = np.asarray(a, dtype=np.float64)
    return 0.5 * (a + np.swapaxes(a, -1, -2))


@dataclass
class ParamSpace:
    """Parameter names, the log transform, and a Gaussian prior: the one parameter-space type of
    the methods, the MCMC targets and the diagnosis.

    Attributes
    ----------
    names : tuple of str
        Parameter names (SI), e.g. ``("G", "mu")``.
    positive : ndarray of bool (n_p,)
        True: internal coordinate is z = log(theta / 1 SI unit).
    prior_mean, prior_cov : ndarray (n_p,), (n_p, n_p)
        Gaussian prior of the internal coordinates z (``scale="internal"``, the methods'
        convention), or of theta in SI units (``scale="natural"``). The covariance is symmetrised
        and must be positive definite.
    prior_si : dict name -> (mean, sd)
        The prior as given, in SI units ({} for a prior stated directly in z, e.g. a window's).
    prior_name : str
        ``"wide"``, ``"paper"`` or ``"custom"`` (what the report names).
    start_mean, start_cov : ndarray (n_p,), (n_p, n_p) or None
        Where the local methods start and the working spread of their first ensemble (internal
        coordinates), e.g. the global search's best point (:mod:`imrbayes.ensemble.search`); None:
        the prior's. The prior itself stays the prior of every fused estimate.
    scale : ``"internal"`` | ``"natural"``
        Where the Gaussian is stated. ``natural`` (MCMC only): theta ~ N(prior_mean, prior_cov)
        truncated to theta > 0 for positive parameters, sampled in z with the Jacobian
        log |d theta / d z| = sum_{positive i} z_i (:meth:`log_prob`).
    box_sd : float
        Support of :meth:`log_prob`: a box of ``box_sd`` prior standard deviations of z around the
        prior mean (for ``natural``, of the log-normal with the same moments); ``inf``: no box.
        Keeps MCMC walkers away from absurd parameters where the stiff forward solve takes very
        long (the prior density at the box edge is below e^-50 of its peak).
    lower, upper : ndarray (n_p,)
        The box in z (derived).
    """

    names: tuple
    positive: np.ndarray
    prior_mean: np.ndarray
    prior_cov: np.ndarray
    prior_si: dict = field(default_factory=dict)
    scale: str = "internal"
    box_sd: float = 10.0
    prior_name: str = "custom"
    start_mean: np.ndarray | None = None
    start_cov: np.ndarray | None = None
    lower: np.ndarray = field(init=False, repr=False)
    upper: np.ndarray = field(init=False, repr=False)
    _prec: np.ndarray = field(init=False, repr=False)
    _logdet: float = field(init=False, repr=False)

    def __post_init__(self):
        self.prior_mean = np.atleast_1d(np.asarray(self.prior_mean, dtype=np.float64))
        d = self.prior_mean.size
        self.prior_cov = _sym(np.asarray(self.prior_cov, dtype=np.float64).reshape(d, d))
        self.positive = np.broadcast_to(np.asarray(self.positive, dtype=bool), (d,)).copy()
        self.names = tuple(self.names) or tuple(f"theta{i}" for i in range(d))
        if len(self.names) != d:
            raise InputError("prior", f"{len(self.names)} names for {d} parameters")
        if self.scale not in ("internal", "natural"):
            raise InputError("prior", f"scale must be 'internal' or 'natural', got {self.scale!r}")
        try:
            L = np.linalg.cholesky(self.prior_cov)
        except np.linalg.LinAlgError:
            raise InputError("prior", "the prior covariance must be symmetric positive definite")
        self._prec = np.linalg.inv(self.prior_cov)
        self._logdet = 2.0 * float(np.sum(np.log(np.diag(L))))
        m, s = self.prior_mean.copy(), np.sqrt(np.diag(self.prior_cov))
        if self.scale == "natural":
            if np.any(self.positive & (self.prior_mean <= 0)):
                raise InputError("prior", "positive parameters need a positive prior mean")
            s2 = np.log1p(np.square(s / np.where(self.positive, self.prior_mean, 1.0)))
            m = np.where(self.positive, np.log(np.where(self.positive, self.prior_mean, 1.0)) - 0.5 * s2, m)
            s = np.where(self.positive, np.sqrt(s2), s)
        self.lower = m - self.box_sd * s
        self.upper = m + self.box_sd * s
        self.start_mean = (
            self.prior_mean.copy()
            if self.start_mean is None
            else np.asarray(self.start_mean, dtype=np.float64).reshape(d)
        )
        self.start_cov = (
            self.prior_cov.copy()
            if self.start_cov is None
            else _sym(np.asarray(self.start_cov, dtype=np.float64).reshape(d, d))
        )

    @property
    def n(self) -> int:
        return len(self.names)

    @classmethod
    def for_model(
        cls, constitutive, prior: dict | None = None, box_sd: float = 10.0, base: str = "paper"
    ) -> ParamSpace:
        """From a ``ConstitutiveModel``; ``prior`` maps name -> (mean, sd) in SI over the named
        ``base`` prior (:data:`PRIORS`: ``"paper"``, the default of the library's internal callers,
        or ``"wide"``, ``fit``'s default); other parameters get the model default with a 50 % sd, or
        the parameter's own ``prior_sd`` where the default is 0 (a Zener's retardation time 0 +- 0.5
        us), uncorrelated."""
        if base not in PRIORS:
            raise InputError("--prior", f"unknown prior {base!r}; choose one of {', '.join(PRIORS)}")
        name = base if not prior else "custom"
        prior = {**PRIORS[base], **(prior or {})}
        names, pos, means, sds, si = [], [], [], [], {}
        for p in constitutive.parameters:
            fallback = 0.5 * abs(p.default) if p.default else (p.prior_sd or 1.0)
            mean, sd = prior.get(p.name, (p.default, fallback))
            mean, sd = float(mean), float(sd)
            if not (math.isfinite(mean) and math.isfinite(sd) and sd > 0):
                raise InputError("prior", f"{p.name}: need a finite mean and a positive sd, got {mean}, {sd}")
            if p.positive and mean <= 0:
                raise InputError("prior", f"{p.name} is positive; its prior mean must be > 0, got {mean}")
            names.append(p.name)
            pos.append(bool(p.positive))
            si[p.name] = (mean, sd)
            if p.positive:
                s2 = math.log1p((sd / mean) ** 2)
                means.append(math.log(mean) - 0.5 * s2)
                sds.append(math.sqrt(s2))
            else:
                means.append(mean)
                sds.append(sd)
        return cls(
            tuple(names), np.array(pos), np.array(means), np.diag(np.square(sds)), si, box_sd=box_sd, prior_name=name
        )

    def with_prior(self, mean, cov, box_sd: float | None = None) -> ParamSpace:
        """The same parameters with the prior N(mean, cov) stated on z (e.g. a window's chained
        prior), and ``box_sd`` (default: this space's)."""
        return ParamSpace(
            self.names, self.positive, mean, cov, {}, "internal", self.box_sd if box_sd is None else float(box_sd)
        )

    def with_start(self, mean, cov) -> ParamSpace:
        """The same prior, with the methods' start N(mean, cov) on z (see ``start_mean``)."""
        return ParamSpace(
            self.names,
            self.positive,
            self.prior_mean,
            self.prior_cov,
            dict(self.prior_si),
            self.scale,
            self.box_sd,
            self.prior_name,
            mean,
            cov,
        )

    def data_share(self, post_cov) -> dict:
        """How much of the posterior is the data's, per parameter: ``1 - var_post / var_prior`` of
        the internal coordinate (0: the prior unchanged; 1: the data alone)."""
        v = np.diag(np.asarray(post_cov, dtype=np.float64).reshape(self.n, self.n))
        return {nm: float(np.clip(1.0 - v[i] / self.prior_cov[i, i], 0.0, 1.0)) for i, nm in enumerate(self.names)}

    def to_internal(self, theta):
        """(..., n_p) SI -> internal z (log for positive parameters)."""
        theta = np.asarray(theta, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.positive, np.log(np.where(self.positive, theta, 1.0)), theta)

    def to_si(self, z):
        """(..., n_p) internal -> SI."""
        z = np.asarray(z, dtype=np.float64)
        with np.errstate(over="ignore"):
            return np.where(self.positive, np.exp(np.where(self.positive, z, 0.0)), z)

    def log_prob(self, Z) -> np.ndarray:
        """(n, n_p) z -> (n,) log prior density of z (normalised, up to the box truncation); -inf
        outside the box or where z is not finite."""
        Z = np.atleast_2d(np.asarray(Z, dtype=np.float64))
        d = self.n
        out = np.full(Z.shape[0], -np.inf)
        ok = np.all(np.isfinite(Z), axis=1) & np.all((Z >= self.lower) & (Z <= self.upper), axis=1)
        if not ok.any():
            return out
        z = Z[ok]
        x = z if self.scale == "internal" else self.to_si(z)
        r = x - self.prior_mean
        lp = -0.5 * np.einsum("ni,ij,nj->n", r, self._prec, r) - 0.5 * (d * np.log(2 * np.pi) + self._logdet)
        if self.scale == "natural":
            lp = lp + np.sum(np.where(self.positive, z, 0.0), axis=1)  # Jacobian of theta = exp(z)
        out[ok] = np.where(np.isfinite(lp), lp, -np.inf)
        return out

    def describe(self) -> dict:
        """The parameter space as the methods use it (``summary.json["prior"]``, the run config)."""
        sd = np.sqrt(np.diag(self.prior_cov))
        return {
            "name": self.prior_name,
            "names": list(self.names),
            "log_space": {n: bool(p) for n, p in zip(self.names, self.positive)},
            "prior_si": {k: {"mean": v[0], "sd": v[1]} for k, v in self.prior_si.items()},
            "central_95_si": {
                n: self.to_si(np.array([self.prior_mean[i] - 1.96 * sd[i], self.prior_mean[i] + 1.96 * sd[i]])).tolist()
                if self.positive[i]
                else [self.prior_mean[i] - 1.96 * sd[i], self.prior_mean[i] + 1.96 * sd[i]]
                for i, n in enumerate(self.names)
            },
            "start_internal_mean": self.start_mean.tolist(),
            "start_internal_cov": self.start_cov.tolist(),
            "prior_internal_mean": self.prior_mean.tolist(),
            "prior_internal_cov": self.prior_cov.tolist(),
            "prior_rule": "positive parameters: log-normal with the given SI mean and sd "
            "(s^2 = log(1 + (sd/mean)^2), m = log(mean) - s^2/2); others Gaussian",
        }

    def describe_density(self) -> dict:
        """The prior density as :meth:`log_prob` evaluates it (scale, box; an MCMC target's ``prior``)."""
        return {
            "names": list(self.names),
            "mean": self.prior_mean.tolist(),
            "cov": self.prior_cov.tolist(),
            "log_space": {n: bool(p) for n, p in zip(self.names, self.positive)},
            "scale": self.scale,
            "box_sd": float(self.box_sd),
            "box_lower": self.lower.tolist(),
            "box_upper": self.upper.tolist(),
            "rule": (
                "Gaussian on z (log for positive parameters); no Jacobian"
                if self.scale == "internal"
                else "Gaussian on theta [SI], sampled in z = log(theta) with the Jacobian sum(z_positive)"
            ),
        }
