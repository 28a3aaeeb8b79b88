"""Small synthetic problems for the MCMC tests: the polytropic forward model (fast) and an
analytic Gaussian target with the interface of :class:`imrbayes.mcmc.target.WindowTarget`."""

from __future__ import annotations

from functools import cache

import numpy as np

from imrbayes.data.noise import paper_sigma
from imrbayes.ensemble import ParamSpace
from imrbayes.forward import ForwardModel, ForwardOptions

TRUTH = {"G": 7.29e3, "mu": 0.088}
RMAX = np.array([263e-6, 250e-6, 280e-6])
RATIO = np.array([7.58, 7.2, 7.9])
#: paper prior (G 6 +- 2.8 kPa, mu 0.209 +- 0.088 Pa s) as the log-normal of ParamSpace
PAPER_PRIOR_SI = {"G": (6.0e3, 2.8e3), "mu": (0.209, 0.088)}


@cache
def model() -> ForwardModel:
    return ForwardModel("nhkv", options=ForwardOptions(bubble="polytropic"))


def paper_prior(box_sd=10.0) -> ParamSpace:
    m, s = [], []
    for name in ("G", "mu"):
        mean, sd = PAPER_PRIOR_SI[name]
        s2 = np.log1p((sd / mean) ** 2)
        m.append(np.log(mean) - 0.5 * s2)
        s.append(np.sqrt(s2))
    return ParamSpace(("G", "mu"), [True, True], np.array(m), np.diag(np.square(s)), box_sd=box_sd)


class Obs:
    """Duck-typed observations (t_star, R_star, P, rmax_m, req_m, names)."""

    def __init__(self, t, R, P, rmax, req):
        self.t_star, self.R_star, self.P, self.rmax_m, self.req_m = t, R, P, rmax, req
        self.names = [f"exp_{i + 1:03d}" for i in range(R.shape[0])]


def observations(n_exp=1, n_steps=40, noise=None, seed=0, truth=None):
    """R* of ``n_exp`` bubbles on dt* = 0.025 with the truth. ``noise``: None (noise-free, P = 1e-4),
    a number (sd), or ``"paper"`` (methods.md §5 noise; P from the model)."""
    truth = truth or TRUTH
    fm = model()
    t = np.arange(n_steps + 1) * 0.025
    rmax, req = RMAX[:n_exp], RMAX[:n_exp] / RATIO[:n_exp]
    Y = fm.simulate({"G": np.full(n_exp, truth["G"]), "mu": np.full(n_exp, truth["mu"])}, rmax, req, t).R_star
    assert np.all(np.isfinite(Y))
    rng = np.random.default_rng(seed)
    if noise is None:
        P = np.full(t.size, 1e-4)
    elif noise == "paper":
        sd = paper_sigma(t, Y.mean(axis=0))
        P = np.maximum(sd**2, 1e-8)
        Y = Y + rng.standard_normal(Y.shape) * sd
    else:
        P = np.full(t.size, float(noise) ** 2)
        Y = Y + rng.standard_normal(Y.shape) * float(noise)
    Y[:, 0] = 1.0
    return fm, Obs(t, Y, P, rmax, req)


class GaussianTarget:
    """log N(z; mean, cov) with the attributes run_mcmc reads (ndim, prior, internal_names, log_prob)."""

    def __init__(self, mean, cov, fail_after=None):
        self.mean = np.asarray(mean, float)
        self.cov = np.asarray(cov, float)
        self.prec = np.linalg.inv(self.cov)
        d = self.mean.size
        self.prior = ParamSpace(tuple(f"x{i}" for i in range(d)), [False] * d, self.mean, 25.0 * self.cov)
        self.internal_names = list(self.prior.names)
        self.ndim = d
        self.n_evals = 0
        self.n_calls = 0
        self.fail_after = fail_after

    def log_prob(self, Z):
        self.n_calls += 1
        if self.fail_after is not None and self.n_calls > self.fail_after:
            raise Interrupted("simulated interruption")
        Z = np.atleast_2d(Z)
        self.n_evals += Z.shape[0]
        r = Z - self.mean
        return -0.5 * np.einsum("ni,ij,nj->n", r, self.prec, r)


class Interrupted(BaseException):
    pass
