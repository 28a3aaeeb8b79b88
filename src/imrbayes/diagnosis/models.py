"""A diagnosis candidate on a forward model: the map from internal coordinates z to forward-model
parameters, and the prior of z.

The candidates themselves are declared in :mod:`imrbayes.diagnosis.candidates`; this module turns
one declaration (and the user's prior of G, mu) into something the fits can use. Coordinates:
z = (log G, log mu, extension...), log for positive parameters (:class:`ParamSpace`'s convention).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imrbayes.diagnosis.candidates import BASELINE, CandidateSpec, spec_of
from imrbayes.ensemble.problem import ParamSpace
from imrbayes.forward import ForwardModel
from imrbayes.forward.constitutive import get_model

__all__ = ["Candidate", "make_candidate", "candidate_space", "applicable"]


def candidate_space(spec: CandidateSpec, prior: dict | None = None) -> ParamSpace:
    """(G, mu) as :meth:`ParamSpace.for_model` of the baseline gives them (``prior``: name -> (mean, sd) SI,
    default the paper's), then the spec's extension with its own prior (given in z, so it has no
    ``prior_si`` entry)."""
    base = ParamSpace.for_model(get_model(BASELINE.forward_model), prior)
    ext = spec.extension
    return ParamSpace(
        base.names + tuple(e.name for e in ext),
        np.concatenate([base.positive, np.array([e.log for e in ext], dtype=bool)]),
        np.concatenate([base.prior_mean, [float(e.mean) for e in ext]]),
        np.diag(np.concatenate([np.diag(base.prior_cov), [float(e.sd) ** 2 for e in ext]])),
        dict(base.prior_si),
    )


@dataclass
class Candidate:
    """``spec`` (the declaration), ``space`` (fitted names, log transform, Gaussian prior of z) and
    the forward model ``fm`` it runs on."""

    spec: CandidateSpec
    space: ParamSpace
    fm: ForwardModel

    @property
    def key(self) -> str:
        return self.spec.key

    @property
    def mechanism(self) -> str:
        return self.spec.mechanism

    @property
    def forward_name(self) -> str:
        return self.spec.forward_model

    @property
    def names(self) -> tuple:
        return self.space.names

    @property
    def log(self) -> np.ndarray:
        return self.space.positive

    @property
    def prior_mean(self) -> np.ndarray:
        return self.space.prior_mean

    @property
    def prior_sd(self) -> np.ndarray:
        return np.sqrt(np.diag(self.space.prior_cov))

    @property
    def d(self) -> int:
        return self.space.n

    @property
    def piecewise(self) -> bool:
        """Parameters change at every measured collapse (forward solves need the break times)."""
        return self.spec.pieces is not None

    # Clipped (unlike ParamSpace.to_si): Levenberg-Marquardt steps and Laplace draws may wander far.
    def to_si(self, z) -> np.ndarray:
        z = np.asarray(z, dtype=float)
        return np.where(np.asarray(self.log), np.exp(np.clip(z, -50, 50)), z)

    def to_internal(self, theta) -> np.ndarray:
        theta = np.asarray(theta, dtype=float)
        return np.where(np.asarray(self.log), np.log(np.abs(theta) + 1e-300), theta)

    def forward_params(self, z, n_pieces: int = 1) -> np.ndarray:
        """(M, d) internal -> SI forward parameters (M, P, n_params) in the forward model's order:
        P = n_pieces for a piecewise candidate, else 1."""
        th = np.atleast_2d(self.to_si(z))
        vals = dict(zip(self.names, th.T))
        if self.piecewise:
            per = self.spec.pieces(vals, n_pieces)
        else:
            per = {n: v[:, None] for n, v in vals.items()}
        pnames = self.fm.constitutive.param_names
        P = n_pieces if self.piecewise else 1
        out = np.empty((th.shape[0], P, len(pnames)))
        for i, p in enumerate(pnames):
            out[:, :, i] = per[p] if p in per else self.spec.fixed[p]
        return out

    def estimate(self, z, cov) -> dict:
        """SI summaries (median, mean, sd, 95 % interval) of the Laplace posterior N(z, cov)."""
        sd = np.sqrt(np.clip(np.diag(cov), 0, None))
        out = {}
        for i, n in enumerate(self.names):
            lo, hi = z[i] - 1.96 * sd[i], z[i] + 1.96 * sd[i]
            if self.log[i]:
                mean = float(np.exp(z[i] + 0.5 * sd[i] ** 2))
                out[n] = {
                    "mean": mean,
                    "median": float(np.exp(z[i])),
                    "sd": float(mean * np.sqrt(np.expm1(sd[i] ** 2))),
                    "hdi95": [float(np.exp(lo)), float(np.exp(hi))],
                }
            else:
                out[n] = {
                    "mean": float(z[i]),
                    "median": float(z[i]),
                    "sd": float(sd[i]),
                    "hdi95": [float(lo), float(hi)],
                }
        return out


def make_candidate(key: str, options, physics=None, prior: dict | None = None) -> Candidate:
    """The baseline (``nhkv``) or registered candidate ``key`` on a forward model with the baseline's
    ``options`` (ForwardOptions; a bubble-model candidate changes them) and ``physics``; ``prior``:
    (G, mu) prior overrides, name -> (mean, sd) SI. Raises ValueError when a bubble-model candidate
    does not apply to ``options`` (:meth:`CandidateSpec.options_for`)."""
    spec = spec_of(key)
    opts = spec.options_for(options)
    if opts is None:
        raise ValueError(f"candidate {key} does not apply to the baseline's forward options")
    return Candidate(
        spec, candidate_space(spec, prior), ForwardModel(spec.forward_model, options=opts, physics=physics)
    )


def applicable(key: str, options) -> bool:
    """Whether candidate ``key`` has a forward model for the baseline's ``options``."""
    return spec_of(key).options_for(options) is not None
