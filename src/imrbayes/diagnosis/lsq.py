"""Joint weighted least squares (MAP) of one candidate over several experiments, with a Laplace
posterior: minimise 1/2 sum_n sum_{k=1..K} (y_nk - R*_nk(z))^2 / P_k + 1/2 ||(z - m0)/s0||^2
by Levenberg–Marquardt (forward-difference Jacobian in z, all members of an iteration in one
forward batch). The Laplace covariance is (J^T J)^-1 of the whitened residuals at the optimum
(sample 0, R* = 1 by construction, is never fitted). Residuals of a curve are correlated in time,
so this posterior is optimistic; the diagnosis calibrates what it compares by a parametric
bootstrap or by held-out prediction, not by these widths.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["predict", "fit_map", "MapFit"]

FAIL_RESIDUAL = 1.0  # R* error assigned to a failed solve (per sample)
MAX_STEPS = 20_000  # a member needing more integrator steps counts as failed (stiff corners of the prior)


def predict(cand, z, obs, idx, minima, K: int) -> np.ndarray:
    """R* (M, len(idx), K+1) on samples 0..K for parameter sets z (M, d); NaN where a solve failed."""
    z = np.atleast_2d(np.asarray(z, dtype=float))
    idx = np.atleast_1d(np.asarray(idx, dtype=int))
    M, E = z.shape[0], idx.size
    t = obs.t_star[:K + 1]
    out = np.full((M, E, K + 1), np.nan)
    fm = cand.fm
    if not cand.piecewise:
        P = cand.forward_params(z)                                   # (M, 1, np)
        P = np.repeat(P, E, axis=0)                                   # member m*E + e
        rmax = np.tile(obs.rmax_m[idx], M)
        req = np.tile(obs.req_m[idx], M)
        with np.errstate(all="ignore"):
            o = fm.simulate(P, rmax, req, t, max_steps=MAX_STEPS)
        R = np.where(o.failed[:, None], np.nan, o.R_star)
        out[:] = R.reshape(M, E, K + 1)
        return out
    # piecewise: each experiment breaks at its own collapses -> one batch with per-member break times
    # (breaks_star (M*E, n_breaks)); experiments with fewer collapses inside the window are padded
    # with breaks after the last output time, where the extra pieces never act.
    brs = [[float(obs.t_star[m]) for m in minima[e] if 0 < m < K] for e in idx]
    nb = max(len(b) for b in brs)
    t_end = float(t[-1])
    B = np.array([b + [t_end + 1.0 + i for i in range(nb - len(b))] for b in brs], dtype=float).reshape(E, nb)
    P = np.repeat(cand.forward_params(z, n_pieces=nb + 1), E, axis=0)   # member m*E + e
    rmax = np.tile(obs.rmax_m[idx], M)
    req = np.tile(obs.req_m[idx], M)
    with np.errstate(all="ignore"):
        o = fm.simulate(P, rmax, req, t, breaks_star=np.tile(B, (M, 1)), max_steps=MAX_STEPS)
    R = np.where(o.failed[:, None], np.nan, o.R_star)
    out[:] = R.reshape(M, E, K + 1)
    return out


@dataclass
class MapFit:
    key: str
    z: np.ndarray
    cov: np.ndarray
    cost: float
    chi2: float          # data part of 2 * cost
    n_data: int
    fitted: np.ndarray   # (E, K+1)
    K: int
    idx: np.ndarray
    n_iter: int
    converged: bool


def _residuals(R, y, wsq):
    r = (y[None] - R[..., 1:]) * wsq[None, None, :]
    bad = ~np.isfinite(r)
    r[bad] = FAIL_RESIDUAL * np.broadcast_to(wsq[None, None, :], r.shape)[bad]
    return r.reshape(r.shape[0], -1)


def grid_starts(cand, obs, idx, K, minima, P, extra_starts=(), n_best: int = 2, n_grid: int = 8,
                n_random: int = 48, seed: int = 0) -> list:
    """Starting points: the best ``n_best`` of a log grid over (G, mu) (other parameters at their
    prior mean), random prior draws (sd doubled) and ``extra_starts``, by the MAP cost."""
    rng = np.random.default_rng(seed)
    Gs = np.log(np.geomspace(300.0, 6e4, n_grid))
    mus = np.log(np.geomspace(0.005, 1.0, n_grid))
    gg, mm = np.meshgrid(Gs, mus, indexing="ij")
    Z = np.repeat(cand.prior_mean[None], gg.size, axis=0)
    Z[:, 0], Z[:, 1] = gg.ravel(), mm.ravel()
    parts = [Z, cand.prior_mean + 1.5 * cand.prior_sd * rng.standard_normal((n_random, cand.d))]
    if len(extra_starts):
        parts.append(np.atleast_2d(np.asarray(extra_starts, dtype=float)))
    Z = np.vstack(parts)
    y = obs.R_star[idx, 1:K + 1]
    wsq = 1.0 / np.sqrt(P[1:K + 1])
    r = _residuals(predict(cand, Z, obs, idx, minima, K), y, wsq)
    cost = 0.5 * np.sum(r * r, axis=1) + 0.5 * np.sum(((Z - cand.prior_mean) / cand.prior_sd) ** 2, axis=1)
    order = np.argsort(cost)
    out = [Z[order[0]]]
    for i in order[1:]:
        if len(out) >= n_best:
            break
        if np.max(np.abs(Z[i, :2] - out[0][:2])) > 0.3:   # a different basin in (G, mu)
            out.append(Z[i])
    for s in extra_starts:        # always try the given starts (e.g. the baseline optimum)
        out.append(np.asarray(s, dtype=float))
    return out


def fit_map(cand, obs, idx=None, K=None, minima=None, P=None, starts=None, max_iter: int = 40,
            h: float = 0.01, tol: float = 1e-6, extra_starts=()) -> MapFit:
    """MAP + Laplace fit of ``cand`` to experiments ``idx`` over samples 1..K (see module doc).

    starts : list of internal starting points (default: the prior mean); the best optimum wins.
    P : noise variances (n,) (default ``obs.P``).
    """
    idx = np.arange(obs.n_exp) if idx is None else np.atleast_1d(np.asarray(idx, dtype=int))
    K = obs.n_samples - 1 if K is None else int(K)
    P = obs.P if P is None else np.asarray(P, dtype=float)
    y = obs.R_star[idx, 1:K + 1]
    wsq = 1.0 / np.sqrt(P[1:K + 1])
    m0, s0 = cand.prior_mean, cand.prior_sd
    d = cand.d
    if starts is None:
        starts = grid_starts(cand, obs, idx, K, minima, P, extra_starts)
    starts = [np.asarray(s, dtype=float) for s in starts]

    def full_res(Z):
        R = predict(cand, Z, obs, idx, minima, K)
        return np.hstack([_residuals(R, y, wsq), (Z - m0) / s0]), R

    def lm(z, r, cost, Rz, lam, n_iter):
        conv, it = False, 0
        for it in range(1, n_iter + 1):
            Zp = z[None] + h * np.eye(d)
            rp, _ = full_res(Zp)
            J = (rp - r[None]).T / h                                     # (n_res, d)
            A, g = J.T @ J, J.T @ r
            lams = lam * np.array([0.1, 1.0, 10.0])
            steps = []
            for lm_ in lams:
                try:
                    steps.append(-np.linalg.solve(A + lm_ * np.diag(np.diag(A) + 1e-9), g))
                except np.linalg.LinAlgError:
                    steps.append(np.zeros(d))
            steps = np.array(steps)
            rt, Rt = full_res(z[None] + steps)
            costs = 0.5 * np.einsum("ij,ij->i", rt, rt)
            k = int(np.argmin(costs))
            if costs[k] < cost:
                rel = (cost - costs[k]) / max(cost, 1e-300)
                z, r, cost, Rz = z + steps[k], rt[k], float(costs[k]), Rt[k]
                lam = max(lams[k] * 0.3, 1e-7)
                if rel < tol or np.max(np.abs(steps[k])) < 1e-5:
                    conv = True
                    break
            else:
                lam *= 100.0
                if lam > 1e8:
                    conv = True
                    break
        return [z, r, cost, Rz, lam, conv, it]

    # every start a few iterations, then only the best one to convergence
    states = []
    for z0 in starts:
        r_all, R = full_res(z0[None])
        st = lm(z0.copy(), r_all[0], 0.5 * float(r_all[0] @ r_all[0]), R[0], 1e-2,
                max_iter if len(starts) == 1 else min(6, max_iter))
        states.append(st)
    best = min(states, key=lambda q: q[2])
    if len(starts) > 1 and not best[5]:
        it0 = best[6]
        best = lm(best[0], best[1], best[2], best[3], best[4], max(1, max_iter - it0))
        best[6] += it0
    z, r, cost, Rz, _, conv, it = best
    rp, _ = full_res(z[None] + h * np.eye(d))
    J = (rp - r[None]).T / h
    try:
        cov = np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        cov = np.diag(s0 ** 2)
    chi2 = float(np.sum(r[:-d] ** 2))
    return MapFit(cand.key, z, cov, cost, chi2, int(y.size), Rz, K, idx, it, conv)
