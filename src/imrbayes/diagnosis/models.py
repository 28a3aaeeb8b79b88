"""Baseline and candidate models for the diagnosis, each a map from internal coordinates z to
forward-model parameters.

Every candidate nests the baseline (NHKV): ``strain-stiffening`` (qkv: alpha = 0; fung: alpha = 0),
``viscoelastic-relaxation`` (zener with lambda2 = 0,
so elastic and viscous stress relax over lambda1; lambda1 -> 0 is NHKV), ``rate-dependent-viscosity`` (carreau,
mu_inf = 0: n = 1 or lambda_c -> 0), ``damage-softening`` (NHKV whose G and mu are multiplied by
retention factors a_G, a_mu at every measured collapse of that experiment: piece j, after j
collapses, has G a_G^j, mu a_mu^j; a = 1 is NHKV). Positive parameters are fitted in log space.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imrbayes.ensemble.problem import PAPER_PRIOR
from imrbayes.forward import ForwardModel

__all__ = ["Candidate", "CANDIDATES", "MECHANISMS", "make_candidate"]

MECHANISMS = ("none", "strain-stiffening", "viscoelastic-relaxation", "rate-dependent-viscosity",
              "damage-softening", "unexplained")


def _lognormal(mean, sd):
    s2 = np.log1p((sd / mean) ** 2)
    return float(np.log(mean) - 0.5 * s2), float(np.sqrt(s2))


@dataclass
class Candidate:
    """A model to fit: ``names`` of the fitted parameters, which are log-transformed, the prior
    (internal mean, sd), fixed forward parameters, and the forward model."""

    key: str
    mechanism: str
    forward_name: str
    names: tuple
    log: tuple
    prior_mean: np.ndarray
    prior_sd: np.ndarray
    fixed: dict = field(default_factory=dict)
    damage: bool = False
    fm: ForwardModel | None = None

    @property
    def d(self) -> int:
        return len(self.names)

    def to_si(self, z) -> np.ndarray:
        z = np.asarray(z, dtype=float)
        return np.where(np.asarray(self.log), np.exp(np.clip(z, -50, 50)), z)

    def to_internal(self, theta) -> np.ndarray:
        theta = np.asarray(theta, dtype=float)
        return np.where(np.asarray(self.log), np.log(np.abs(theta) + 1e-300), theta)

    def forward_params(self, z, n_pieces: int = 1) -> np.ndarray:
        """(M, d) internal -> (M, n_pieces, n_params) SI forward parameters."""
        th = np.atleast_2d(self.to_si(z))
        M = th.shape[0]
        pnames = self.fm.constitutive.param_names
        vals = dict(zip(self.names, th.T))
        if self.damage:
            pieces = np.empty((M, n_pieces, 2))
            j = np.arange(n_pieces)[None, :]
            pieces[:, :, 0] = vals["G"][:, None] * vals["a_G"][:, None] ** j
            pieces[:, :, 1] = vals["mu"][:, None] * vals["a_mu"][:, None] ** j
            return pieces
        out = np.empty((M, 1, len(pnames)))
        for i, p in enumerate(pnames):
            if p in vals:
                out[:, 0, i] = vals[p]
            elif p == "lambda2" and "Lambda" in vals:
                out[:, 0, i] = vals["Lambda"] * vals["lambda1"]
            else:
                out[:, 0, i] = self.fixed[p]
        return out

    def estimate(self, z, cov) -> dict:
        """SI summaries (median, mean, sd, 95 % interval) of the Laplace posterior N(z, cov)."""
        sd = np.sqrt(np.clip(np.diag(cov), 0, None))
        out = {}
        for i, n in enumerate(self.names):
            lo, hi = z[i] - 1.96 * sd[i], z[i] + 1.96 * sd[i]
            if self.log[i]:
                mean = float(np.exp(z[i] + 0.5 * sd[i] ** 2))
                out[n] = {"mean": mean, "median": float(np.exp(z[i])),
                          "sd": float(mean * np.sqrt(np.expm1(sd[i] ** 2))),
                          "hdi95": [float(np.exp(lo)), float(np.exp(hi))]}
            else:
                out[n] = {"mean": float(z[i]), "median": float(z[i]), "sd": float(sd[i]),
                          "hdi95": [float(lo), float(hi)]}
        return out


# key: (mechanism, forward model, [(name, log, prior mean SI or internal, prior sd)], fixed)
_SPECS = {
    "nhkv": ("none", "nhkv", [], {}),
    "qkv": ("strain-stiffening", "qkv", [("alpha", False, 0.0, 0.5)], {}),
    "fung": ("strain-stiffening", "fung", [("alpha", False, 0.0, 0.3)], {}),
    "zener": ("viscoelastic-relaxation", "zener",
              [("lambda1", True, np.log(1e-6), 1.5)], {"lambda2": 0.0}),
    "carreau": ("rate-dependent-viscosity", "carreau",
                [("lambda_c", True, np.log(1e-6), 2.0), ("n", True, np.log(0.7), 0.6)], {"mu_inf": 0.0}),
    "damage": ("damage-softening", "nhkv", [("a_G", True, 0.0, 0.7), ("a_mu", True, 0.0, 0.7)], {}),
}
CANDIDATES = ("qkv", "zener", "carreau", "damage")


def make_candidate(key: str, options, physics=None, prior: dict | None = None) -> Candidate:
    """The candidate ``key`` on a forward model with ``options`` (ForwardOptions)."""
    mech, fwd, extra, fixed = _SPECS[key]
    pr = {**PAPER_PRIOR, **(prior or {})}
    names, log, pm, ps = [], [], [], []
    for n in ("G", "mu"):
        m, s = _lognormal(*pr[n])
        names.append(n), log.append(True), pm.append(m), ps.append(s)
    for n, lg, m, s in extra:
        names.append(n), log.append(lg), pm.append(float(m)), ps.append(float(s))
    fm = ForwardModel(fwd, options=options, physics=physics)
    return Candidate(key, mech, fwd, tuple(names), tuple(log), np.array(pm), np.array(ps), dict(fixed),
                     damage=(key == "damage"), fm=fm)
