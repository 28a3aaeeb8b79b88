"""Noise-free synthetic observations from the forward model (polytropic bubble: fast) for the
ensemble-method tests."""

from __future__ import annotations

from functools import cache

import numpy as np

from imrbayes.ensemble import Observations, ParamSpace
from imrbayes.forward import ForwardModel

TRUTH = {"G": 7.29e3, "mu": 0.088}
RMAX = np.array([263e-6, 250e-6, 280e-6, 300e-6, 240e-6])
RATIO = np.array([7.58, 7.2, 7.9, 7.4, 7.7])


@cache
def model(bubble: str = "polytropic") -> ForwardModel:
    return ForwardModel("nhkv", options={"bubble": bubble} if bubble == "polytropic" else {"scheme": "imrv2-fd"})


def observations(n_exp: int = 5, n_steps: int = 120, P: float = 4e-6, truth=None, bubble="polytropic"):
    """R*(t*) of ``n_exp`` bubbles with the truth, on dt* = 0.025; constant noise variance P."""
    truth = truth or TRUTH
    fm = model(bubble)
    t = np.arange(n_steps + 1) * 0.025
    rmax, req = RMAX[:n_exp], RMAX[:n_exp] / RATIO[:n_exp]
    Y = fm.simulate({"G": np.full(n_exp, truth["G"]), "mu": np.full(n_exp, truth["mu"])}, rmax, req, t).R_star
    assert np.all(np.isfinite(Y))
    return fm, Observations(t, Y, np.full(t.size, P), rmax, req)


def space(fm):
    return ParamSpace.for_model(fm.constitutive)
