"""emcee moves for a window with per-experiment nuisances: blocks and the ridge.

With the default likelihood each experiment carries its own nuisances nu_e (Rmax error, time of the
maximum, Req error: :mod:`imrbayes.ensemble.likelihood`), so En4D-Var's window on six camera records
has d = 2 + 18 coordinates. Moves over all d coordinates at once (DE, stretch) take steps that shrink
like 1/sqrt(d) and need tau of 150-360 steps there (docs/methods.md). The structure helps twice:

* given the parameters theta, the target factorises over experiments, so **every experiment's block
  can be updated on its own, all in one forward batch**: :class:`BlockMove` proposes a new nu_e for
  every experiment of a walker and accepts each block separately
  (:meth:`~imrbayes.mcmc.target.WindowTarget.accept_blocks`) -- N_exp Metropolis steps of dimension
  <= 3 for the cost of one evaluation;
* when theta moves, the nuisances' conditional moves with it (the alignment follows G): the
  **ridge** move (:class:`RidgeMove`) proposes a differential-evolution step Delta in theta alone and
  carries the nuisances along the ensemble's linear regression of nu on theta, ``nu + B Delta``.

Both are symmetric proposals built from the complementary half of the ensemble only (emcee's
red-blue scheme), so they leave the target invariant whatever B is; B decides only the efficiency.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

__all__ = ["BlockMove", "RidgeMove", "regression_on_params"]


def regression_on_params(c, n_params: int) -> np.ndarray:
    """(n_c, d) complementary walkers -> B (d - n_params, n_params): the least-squares slope of the
    other coordinates on the first ``n_params`` (zero when the walkers cannot determine it)."""
    c = np.asarray(c, dtype=np.float64)
    x = c[:, :n_params] - c[:, :n_params].mean(axis=0)
    y = c[:, n_params:] - c[:, n_params:].mean(axis=0)
    if y.shape[1] == 0 or c.shape[0] <= n_params + 1:
        return np.zeros((y.shape[1], n_params))
    sol, *_ = np.linalg.lstsq(x, y, rcond=None)
    return np.where(np.isfinite(sol), sol, 0.0).T


def _pairs(n_c: int, size, random) -> tuple:
    """Two distinct complementary walkers for every draw (indices of shape ``size``)."""
    i = random.randint(n_c, size=size)
    j = (i + 1 + random.randint(n_c - 1, size=size)) % n_c
    return i, j


@lru_cache(maxsize=1)
def _move_class():
    import emcee

    class _Blocks(emcee.moves.RedBlueMove):
        def __init__(self, target, gamma0=None, sigma=1e-5):
            super().__init__(nsplits=2, live_dangerously=True)
            self.target, self.sigma = target, float(sigma)
            self.blocks = [np.asarray(b, dtype=int) for b in target.nuisance_blocks]
            self.n_params = int(target.prior.n)
            self.gamma0 = gamma0

        def _proposal(self, s, c, random):
            """Each block moves by gamma times a difference of two complementary walkers' residuals
            from the regression on the parameters (the conditional spread, not the marginal one)."""
            B = regression_on_params(c, self.n_params)
            r = c[:, self.n_params :] - c[:, : self.n_params] @ B.T
            q = s.copy()
            for cols in self.blocks:
                if not cols.size:
                    continue
                g0 = self.gamma0 if self.gamma0 is not None else 2.38 / np.sqrt(2 * cols.size)
                i, j = _pairs(c.shape[0], s.shape[0], random)
                k = cols - self.n_params
                gamma = g0 * (1 + self.sigma * random.randn(s.shape[0], 1))
                q[:, cols] = s[:, cols] + gamma * (r[i][:, k] - r[j][:, k])
            return q

        def propose(self, model, state):
            n_w = state.coords.shape[0]
            accepted = np.zeros(n_w, dtype=bool)
            inds = np.arange(n_w) % 2
            model.random.shuffle(inds)
            for split in range(2):
                s1 = inds == split
                s, c = state.coords[s1], state.coords[~s1]
                q = self._proposal(s, c, model.random)
                model.compute_log_prob_fn(q)  # the forward batch (memo filled)
                z, lp, acc = self.target.accept_blocks(s, q, model.random)
                accepted[s1] = acc.any(axis=1)
                state = self.update(state, emcee.State(z, log_prob=lp), accepted, s1)
            return state, accepted

    class _Ridge(emcee.moves.RedBlueMove):
        def __init__(self, n_params, gamma0=None, sigma=1e-5):
            super().__init__(nsplits=2, live_dangerously=True)
            self.n_params, self.gamma0, self.sigma = int(n_params), gamma0, float(sigma)

        def get_proposal(self, s, c, random):
            c = np.concatenate(c, axis=0)
            p = self.n_params
            B = regression_on_params(c, p)
            i, j = _pairs(c.shape[0], s.shape[0], random)
            g0 = self.gamma0 if self.gamma0 is not None else 2.38 / np.sqrt(2 * p)
            delta = g0 * (1 + self.sigma * random.randn(s.shape[0], 1)) * (c[i, :p] - c[j, :p])
            q = s.copy()
            q[:, :p] += delta
            q[:, p:] += delta @ B.T
            return q, np.zeros(s.shape[0])

    return _Blocks, _Ridge


def BlockMove(target, gamma0=None):  # noqa: N802 - a class factory (emcee is imported lazily)
    """Each experiment's nuisance block updated on its own, all blocks in one forward batch (module
    docstring). ``target``: a :class:`~imrbayes.mcmc.target.WindowTarget` with sampled nuisances;
    ``gamma0``: DE step factor per block (default 2.38 / sqrt(2 k), k the block's size). emcee's
    acceptance fraction counts a walker as accepted when any of its blocks was."""
    return _move_class()[0](target, gamma0)


def RidgeMove(n_params: int, gamma0=None):  # noqa: N802
    """DE in the first ``n_params`` coordinates (the parameters), the others carried along the
    complementary walkers' regression on them (module docstring). Without nuisances: DE in theta."""
    return _move_class()[1](n_params, gamma0)
