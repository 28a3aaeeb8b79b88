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

__all__ = ["Observations", "ParamSpace", "PAPER_PRIOR"]

#: Prior of methods.md §3 (mean, sd) in SI units; parameters not listed use the model default
#: with a 50 % sd.
PAPER_PRIOR = {"G": (6.0e3, 2.8e3), "mu": (0.209, 0.088)}


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
    """

    t_star: np.ndarray
    R_star: np.ndarray
    P: np.ndarray
    rmax_m: np.ndarray
    req_m: np.ndarray
    t_collapse_star: np.ndarray | None = None
    names: list = field(default_factory=list)

    def __post_init__(self):
        self.t_star = np.asarray(self.t_star, dtype=np.float64)
        self.R_star = np.atleast_2d(np.asarray(self.R_star, dtype=np.float64))
        self.P = np.broadcast_to(np.asarray(self.P, dtype=np.float64), self.t_star.shape).copy()
        n_exp, n = self.R_star.shape
        self.rmax_m = np.broadcast_to(np.asarray(self.rmax_m, dtype=np.float64), (n_exp,)).copy()
        self.req_m = np.broadcast_to(np.asarray(self.req_m, dtype=np.float64), (n_exp,)).copy()
        if self.t_collapse_star is None:
            self.t_collapse_star = np.full(n_exp, np.nan)
        self.t_collapse_star = np.broadcast_to(np.asarray(self.t_collapse_star, dtype=np.float64),
                                               (n_exp,)).copy()
        if not self.names:
            self.names = [f"exp_{i + 1:03d}" for i in range(n_exp)]
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
    def from_preprocessed(cls, pre) -> "Observations":
        """From :class:`imrbayes.data.Preprocessed`."""
        return cls(pre.t_star, pre.R_star, pre.P, pre.rmax_m, pre.req_m, pre.t_collapse_star, list(pre.names))

    @property
    def n_exp(self) -> int:
        return int(self.R_star.shape[0])

    @property
    def n_samples(self) -> int:
        return int(self.t_star.size)

    @property
    def dt_star(self) -> float:
        return float(self.t_star[1] - self.t_star[0])

    def take(self, index) -> "Observations":
        """The experiments ``index`` (list/array of ints)."""
        idx = np.atleast_1d(np.asarray(index, dtype=int))
        return Observations(self.t_star, self.R_star[idx], self.P, self.rmax_m[idx], self.req_m[idx],
                            self.t_collapse_star[idx], [self.names[i] for i in idx])


@dataclass
class ParamSpace:
    """Parameter names, the log transform, and a Gaussian prior in the internal coordinates.

    Attributes
    ----------
    names : tuple of str
    positive : ndarray of bool (n_p,)
        True: internal coordinate is log(theta).
    prior_mean, prior_cov : ndarray (n_p,), (n_p, n_p)
        Gaussian prior of the internal coordinates z.
    prior_si : dict name -> (mean, sd)
        The prior as given, in SI units.
    """

    names: tuple
    positive: np.ndarray
    prior_mean: np.ndarray
    prior_cov: np.ndarray
    prior_si: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        return len(self.names)

    @classmethod
    def for_model(cls, constitutive, prior: dict | None = None) -> "ParamSpace":
        """From a ``ConstitutiveModel``; ``prior`` maps name -> (mean, sd) in SI (default
        :data:`PAPER_PRIOR`, else the model default with a 50 % sd), uncorrelated."""
        prior = {**PAPER_PRIOR, **(prior or {})}
        names, pos, means, sds, si = [], [], [], [], {}
        for p in constitutive.parameters:
            mean, sd = prior.get(p.name, (p.default, 0.5 * abs(p.default) if p.default else 1.0))
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
        return cls(tuple(names), np.array(pos), np.array(means), np.diag(np.square(sds)), si)

    def to_internal(self, theta):
        """(..., n_p) SI -> internal z (log for positive parameters)."""
        theta = np.asarray(theta, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.positive, np.log(np.where(self.positive, theta, 1.0)), theta)

    def to_si(self, z):
        """(..., n_p) internal -> SI."""
        z = np.asarray(z, dtype=np.float64)
        return np.where(self.positive, np.exp(np.where(self.positive, z, 0.0)), z)

    def describe(self) -> dict:
        return {"names": list(self.names), "log_space": {n: bool(p) for n, p in zip(self.names, self.positive)},
                "prior_si": {k: {"mean": v[0], "sd": v[1]} for k, v in self.prior_si.items()},
                "prior_internal_mean": self.prior_mean.tolist(), "prior_internal_cov": self.prior_cov.tolist(),
                "prior_rule": "positive parameters: log-normal with the given SI mean and sd "
                              "(s^2 = log(1 + (sd/mean)^2), m = log(mean) - s^2/2); others Gaussian"}
