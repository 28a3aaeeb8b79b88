"""Simplified Gauss-Newton fits for the check's bootstrap replicates (``bootstrap_fits =
"linearised"``): one Jacobian, taken where the replicates were generated, reused by every fit of
every replicate (:mod:`imrbayes.diagnosis.lsq` takes one per Levenberg-Marquardt iteration).
Measured (docs/diagnosis.md): on the polytropic bubble the check's statistics of the full fits to
1e-3 in 1/12 of the time; on the thermal bubble the solver's tolerance puts a ~0.1-nat noise floor
in the objective where the iteration stops, up to 1 sd along the (G, mu) ridge -- opt-in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imrbayes.diagnosis.lsq import NU_STEP, MapFit, ObsModel, fit_map, predict

__all__ = ["Linearisation", "fit_linearised"]


@dataclass
class Linearisation:
    """A candidate's predictions and their Jacobian at one point (z, nu), every experiment, every
    sample 0..n-1 -- what :func:`fit_linearised` reuses in place of a Jacobian per iteration.

    ``F0`` (E, n) R*; ``Dz`` (E, n, d) dR*/dz (internal material coordinates); ``Dnu`` (E, n, q)
    dR*/dnu (nuisance units, :class:`ObsModel`; zero where the nuisance had no prior sd)."""

    z: np.ndarray
    nu: np.ndarray
    F0: np.ndarray
    Dz: np.ndarray
    Dnu: np.ndarray

    @classmethod
    def at(cls, cand, obs, minima, z, nu, om: ObsModel, h: float = 0.01, K=None) -> "Linearisation":
        """Forward differences at (z, nu) with fit_map's steps (h in z, NU_STEP prior sd in nu): one
        batch of 1 + d + (active nuisance coordinates) members per experiment, samples 0..K
        (default: all)."""
        z = np.asarray(z, dtype=float)
        E, q = obs.n_exp, om.nu_sd.shape[1]
        nu = np.zeros((E, q)) if nu is None else np.asarray(nu, dtype=float)[:, :q]
        active = om.nu_sd > 0
        jn = [j for j in range(q) if active[:, j].any()]
        Zs, Us = [z], [nu]
        for i in range(cand.d):
            Zs.append(z + h * np.eye(cand.d)[i])
            Us.append(nu)
        for j in jn:
            dn = np.zeros((E, q))
            dn[:, j] = NU_STEP * om.nu_sd[:, j]
            Zs.append(z)
            Us.append(nu + dn)
        K = obs.n_samples - 1 if K is None else int(K)
        R = predict(cand, np.array(Zs), obs, np.arange(E), minima, K, np.array(Us), om.frames)
        F0 = R[0]
        Dz = np.stack([(R[1 + i] - F0) / h for i in range(cand.d)], axis=-1)
        Dnu = np.zeros(F0.shape + (q,))
        for c, j in enumerate(jn):
            step = np.where(active[:, j], NU_STEP * om.nu_sd[:, j], 1.0)
            Dnu[..., j] = np.where(active[:, j, None], (R[1 + cand.d + c] - F0) / step[:, None], 0.0)
        return cls(z, nu, F0, Dz, Dnu)

    def usable(self) -> bool:
        return bool(np.all(np.isfinite(self.F0)) and np.all(np.isfinite(self.Dz)) and np.all(np.isfinite(self.Dnu)))


def fit_linearised(cand, obs, lin: Linearisation, K=None, minima=None, om: ObsModel | None = None, z=None, nu=None,
                   max_iter: int = 20, tol: float = 1e-4) -> MapFit:
    """:func:`fit_map`'s MAP and Laplace posterior by simplified Gauss-Newton: the Jacobian is
    ``lin``'s (taken once, at the point the data were generated from) instead of a new one per
    iteration, so an iteration costs one prediction (E members) instead of 1 + d + 5 per experiment
    and 3 trial steps. For data that lie near ``lin``'s point -- the parametric bootstrap's replicates,
    whose truth it is -- the fixed point J0^T r(x) = 0 differs from the optimum J(x)^T r(x) = 0 by
    second-order terms (the Jacobian's change over a posterior sd times the residual's projection).
    Starts at (z, nu) (default: ``lin``'s point); steps that do not lower the cost are halved twice.
    Converged when the Gauss-Newton model predicts less than ``tol`` nats of the objective left to
    gain with a Jacobian taken at the point itself (taken when the fixed one's prediction falls
    below ``tol`` or its steps stall; it also gives the Laplace covariance, as fit_map's does).
    A stall with that Jacobian (no step lowers the objective) is its noise floor and also ends the
    iteration, as in fit_map. Falls back to :func:`fit_map` from where it stands when a prediction
    fails or the iteration does not end in ``max_iter``."""
    E = obs.n_exp
    idx = np.arange(E)
    K = obs.n_samples - 1 if K is None else int(K)
    om = ObsModel.of(obs) if om is None else om
    w = om.weight
    s_nu = om.nu_sd
    q = s_nu.shape[1]
    active = s_nu > 0
    d = cand.d
    m0, s0 = cand.prior_mean, cand.prior_sd
    y = obs.R_star[:, 1:K + 1]
    n_y, n_a = E * K, int(active.sum())

    def jacobian(L):
        """The residual vector's Jacobian in (z, nuisances in prior sd) from a linearisation."""
        J = np.zeros((n_y + d + n_a, d + n_a))
        J[:n_y, :d] = -(w[:, None, None] * L.Dz[:, 1:K + 1, :]).reshape(n_y, d)
        c = d
        for e in range(E):
            for j in range(q):
                if active[e, j]:
                    J[e * K:(e + 1) * K, c] = -w[e] * s_nu[e, j] * L.Dnu[e, 1:K + 1, j]
                    c += 1
        J[n_y:n_y + d, :d] = np.diag(1.0 / s0)
        J[n_y + d:, d:] = np.eye(n_a)
        return J

    def unpack(x):
        """(material z, nuisances u in prior sd (E, q)) of the iterate x."""
        u = np.zeros((E, q))
        u[active] = x[d:]
        return x[:d], u

    def refresh(x):
        zz, u = unpack(x)
        L = Linearisation.at(cand, obs, minima, zz, u * s_nu, om, K=K)
        return jacobian(L) if L.usable() else None

    def res(x):
        zz, u = unpack(x)
        R = predict(cand, zz[None], obs, idx, minima, K, (u * s_nu)[None], om.frames)
        r = np.concatenate([((y - R[0, :, 1:]) * w[:, None]).ravel(), (zz - m0) / s0, u[active]])
        return r, R[0]

    z = lin.z if z is None else np.asarray(z, dtype=float)
    nu = lin.nu if nu is None else np.asarray(nu, dtype=float)
    u0 = np.where(active, nu[:, :q] / np.where(active, s_nu, 1.0), 0.0)
    x = np.concatenate([z, u0[active]])
    r, R = res(x)
    cost = 0.5 * float(r @ r)
    J = jacobian(lin)
    pinv = np.linalg.pinv(J)
    fresh = False                 # J was taken at x
    conv, it = False, 0
    if np.all(np.isfinite(r)):
        for it in range(1, max_iter + 1):
            step = -pinv @ r
            # done when the Gauss-Newton model predicts less than ``tol`` nats to gain, or no step
            # lowers the objective (its numerical noise floor: the thermal solver's tolerance leaves
            # ~0.1 nats; fit_map stops there too) -- each confirmed with a Jacobian taken here
            accepted = False
            if 0.5 * float(np.sum((J @ step) ** 2)) >= tol:
                for frac in (1.0, 0.5, 0.25):
                    rt, Rt = res(x + frac * step)
                    ct = 0.5 * float(rt @ rt)
                    if np.all(np.isfinite(rt)) and ct < cost:
                        x, r, R, cost, fresh, accepted = x + frac * step, rt, Rt, ct, False, True
                        break
            if accepted:
                continue
            if fresh:
                conv = True
                break
            J = refresh(x)
            if J is None:
                break
            pinv, fresh = np.linalg.pinv(J), True
    zz, u = unpack(x)
    if not conv:
        f = fit_map(cand, obs, K=K, minima=minima, om=om, starts=[zz], nu0=u * s_nu)
        f.n_iter += it
        return f
    # J was taken at the optimum: the Laplace covariance is fit_map's
    C = np.linalg.inv(J.T @ J)
    nu_sd = np.zeros((E, q))
    nu_sd[active] = np.sqrt(np.clip(np.diag(C)[d:], 0, None)) * s_nu[active]
    return MapFit(cand.key, zz.copy(), C[:d, :d], cost, float(np.sum(r[:n_y] ** 2)), int(y.size), R, K, idx, it, True,
                  u * s_nu, nu_sd)
