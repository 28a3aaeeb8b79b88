"""Exact reference posterior of a two-parameter window: the target density on a fine grid (quadrature).

For a window with d = 2 parameters (G, mu of the neo-Hookean Kelvin-Voigt model) the posterior can
be computed without sampling: evaluate the (unnormalised) log-posterior of the target on a grid in
the internal coordinates z = (log G, log mu), normalise, and take mean, covariance, marginal
quantiles and the 95 % highest-density region from the grid weights. The forward runs are batched
as IMR's grid search batches them (all grid points x experiments of a chunk in one ``propagate``).
The target is a black box: anything with ``log_prob(Z (n, d)) -> (n,)``, ``ndim`` and ``prior``
(``names``, ``positive``) -- the same density emcee samples.

Grid
----
The grid lives in an affine frame z = m + L u (L L^T = C) of a reference Gaussian (m, C), so a
correlated posterior is covered by a square grid in u. Two stages:

1. **coarse** (``n_coarse`` points per axis over u in [-``k_coarse``, ``k_coarse``]): starting from
   the given Gaussian (the ensemble's), the grid moments give the next frame; a frame is widened
   (x 2 in sd) while the outer tenth of the grid holds more than 1e-3 of the mass and
   refined (to the grid moments plus the within-cell variance h^2/12) while the posterior's
   smallest principal sd spans less than half a cell; at most ``max_rounds`` rounds;
2. **fine** (``n`` points per axis over u in [-``k``, ``k``] in the frame of the coarse moments),
   re-framed on its own moments and widened by 1.5 (same spacing, at most 4 times) while the outer
   tenth of the grid's half-width holds more than ``edge_tol``;
   ``edge_ok`` says whether it ended below. Mass beyond the grid is lost: a tail at r sd holding a
   fraction e of the mass biases the variance by about e r^2 (a banana whose arms reach 10 sd: 1e-3).

Quadrature rule: equal weights on the uniform grid (the trapezoidal rule with a negligible edge),
which converges spectrally for smooth, rapidly decaying densities; ``resolution_error`` compares
mean and sd with the every-other-point subgrid (spacing 2h), in posterior sd -- a conservative
bound on the fine grid's own error.

Outputs (:class:`GridPosterior`): ``mean``/``cov`` (internal), ``mean_si``/``cov_si``, marginal 95 %
equal-tailed intervals (internal and SI), the 95 % highest-density region (its log-density level,
area in z and the contour polylines in z), ``edge_mass``, ``n_evals`` and ``n_failed`` (grid points
with log-density -inf: failed solves or outside the prior's support, zero weight as for emcee).

:func:`compare_to_mcmc` says whether MCMC draws agree with the grid within their Monte-Carlo error
(difference of means and sds in units of the ArviZ MCSE).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from imrbayes.errors import InputError

__all__ = ["GridPosterior", "grid_posterior", "compare_to_mcmc", "grid_moments"]


@dataclass
class GridPosterior:
    """The grid posterior of a 2-parameter target (module docstring). Arrays in internal coordinates."""

    names: tuple
    internal_names: list
    positive: np.ndarray
    center: np.ndarray  # frame: z = center + basis @ u
    basis: np.ndarray
    u: np.ndarray  # (n,) grid of each frame axis
    Z: np.ndarray  # (n, n, 2) grid points (z)
    log_prob: np.ndarray  # (n, n)
    weight: np.ndarray  # (n, n) normalised masses
    mean: np.ndarray
    cov: np.ndarray
    mean_si: np.ndarray
    cov_si: np.ndarray
    eti95: np.ndarray  # (2, 2) [lo, hi] per parameter, internal
    hdr95_level: float  # log-density (as the target returns it) bounding the 95 % HDR
    hdr95_area: float  # area of the HDR in z
    hdr95_contour: list  # [(k, 2) polyline in z, ...]
    edge_mass: float
    resolution_error: dict
    n_evals: int
    n_failed: int
    rounds: list = field(default_factory=list)
    edge_tol: float = 1e-5

    @property
    def sd(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov))

    def to_dict(self, contour: bool = True) -> dict:
        """JSON-able summary (the ``quadrature`` block of a compare.json window)."""
        iv = {n: v for n, v in zip(self.internal_names, self.eti95.tolist())}
        si = {n: (np.exp(v) if p else v).tolist() for n, v, p in zip(self.names, self.eti95, self.positive)}
        out = {
            "method": "grid quadrature of the window's target density (exact up to resolution_error)",
            "mean_internal": dict(zip(self.internal_names, self.mean.tolist())),
            "sd_internal": dict(zip(self.internal_names, self.sd.tolist())),
            "cov_internal": self.cov.tolist(),
            "mean": dict(zip(self.names, self.mean_si.tolist())),
            "sd": dict(zip(self.names, np.sqrt(np.diag(self.cov_si)).tolist())),
            "cov": self.cov_si.tolist(),
            "corr_internal": float(self.cov[0, 1] / math.sqrt(self.cov[0, 0] * self.cov[1, 1])),
            "eti95_internal": iv,
            "eti95": si,
            "hdr95": {"level_log_prob": self.hdr95_level, "area_internal": self.hdr95_area},
            "grid": {
                "n": int(self.u.size),
                "k_sd": float(self.u[-1]),
                "spacing_sd": float(self.u[1] - self.u[0]),
                "center": self.center.tolist(),
                "basis": self.basis.tolist(),
            },
            "edge_mass": self.edge_mass,
            "edge_ok": bool(self.edge_mass <= self.edge_tol),
            "resolution_error": self.resolution_error,
            "n_evals": self.n_evals,
            "n_failed": self.n_failed,
            "rounds": self.rounds,
        }
        if contour:
            out["hdr95"]["contour_internal"] = [np.round(c, 6).tolist() for c in self.hdr95_contour]
        return out


def _evaluate(target, Z, batch: int) -> np.ndarray:
    out = np.empty(Z.shape[0])
    for a in range(0, Z.shape[0], batch):
        out[a : a + batch] = np.asarray(target.log_prob(Z[a : a + batch]), dtype=np.float64)
    out[~np.isfinite(out)] = -np.inf
    return out


def _grid(center, basis, k, n):
    u = np.linspace(-k, k, n)
    U = np.stack(np.meshgrid(u, u, indexing="ij"), axis=-1)  # (n, n, 2)
    return u, center + U @ basis.T


def _weights(lp):
    top = np.max(lp)
    if not np.isfinite(top):
        raise RuntimeError("the log-posterior is -inf on every grid point (failed solves or outside the prior)")
    w = np.exp(lp - top)
    return w / w.sum()


def _edge(w, frac: float = 0.1):
    """Mass in the grid's outer band (the outer ``frac`` of its half-width, at least one cell): a
    proxy for the mass beyond it (a single ring of cells understates a long tail)."""
    n = w.shape[0]
    b = max(1, int(round(frac * (n - 1) / 2)))
    inner = np.zeros(w.shape, bool)
    inner[b : n - b, b : n - b] = True
    return float(w[~inner].sum())


def grid_moments(Z, w):
    """Mean and covariance of grid points Z (..., d) with masses w (...)."""
    z = Z.reshape(-1, Z.shape[-1])
    p = w.reshape(-1)
    m = p @ z
    r = z - m
    return m, (r * p[:, None]).T @ r


def _refined(u, lp, refine: int | None = None):
    """The log-density interpolated (bicubic spline in the frame coordinates, smooth where the mass
    is) onto a grid ``refine`` times finer (default: cells of <= 0.06 frame sd): ``(uf, f, w)`` with f = log-density - max on the fine grid
    and w its normalised masses. Used for the marginal quantiles and the HDR, whose values on the
    quadrature grid itself are off by up to half a cell."""
    from scipy.interpolate import RectBivariateSpline

    top = float(np.max(lp))
    f = np.maximum(np.where(np.isfinite(lp), lp - top, -80.0), -80.0)
    spl = RectBivariateSpline(u, u, f, kx=3, ky=3)
    refine = refine or max(4, math.ceil((u[1] - u[0]) / 0.06))  # fine cells of <= 0.06 frame sd
    uf = np.linspace(u[0], u[-1], refine * (u.size - 1) + 1)
    ff = np.minimum(spl(uf, uf), 0.0)
    w = np.exp(ff)
    w[w < 1e-30] = 0.0
    return uf, ff, w / w.sum()


def _marginal_intervals(uf, L, m, w, q=(0.025, 0.975)) -> np.ndarray:
    """(2, 2) marginal quantiles ``q`` of each z_i from the refined masses, each spread over its cell
    (a Gaussian of 0.6 fine cells along z_i: smooth, adding ~1e-3 of the variance)."""
    U = np.stack(np.meshgrid(uf, uf, indexing="ij"), axis=-1).reshape(-1, 2)
    Zf = m + U @ L.T
    pf = w.reshape(-1)
    keep = pf > 1e-14
    s = 0.6 * (uf[1] - uf[0]) * np.sqrt(np.sum(L**2, axis=1))
    return np.array([[_quantile(Zf[keep, i], pf[keep], qq, s[i]) for qq in q] for i in range(2)])


def _hdr(uf, L, m, f, w, mass: float = 0.95):
    """Level (log-density - max), area in z and contour of the ``mass`` highest-density region."""
    pf = w.reshape(-1)
    order = np.argsort(pf)[::-1]
    cum = np.cumsum(pf[order])
    j = min(int(np.searchsorted(cum, mass)), pf.size - 1)
    lo = cum[j - 1] if j > 0 else 0.0
    frac = (mass - lo) / max(cum[j] - lo, 1e-300)
    fo = f.reshape(-1)[order]
    level = float(fo[j - 1] + frac * (fo[j] - fo[j - 1])) if j > 0 else float(fo[0])
    cell = abs(float(np.linalg.det(L))) * (uf[1] - uf[0]) ** 2
    return level, float((j + frac) * cell), _contour(uf, L, m, f, level)


def _quantile(x, p, q, s):
    """q-quantile of masses p at values x, each spread as a Gaussian of sd ``s`` (binned at s/4, then
    convolved with the sampled Gaussian)."""
    step = s / 4.0
    lo, hi = float(np.min(x) - 8 * s), float(np.max(x) + 8 * s)
    nb = int(math.ceil((hi - lo) / step))
    hist, edges = np.histogram(x, bins=nb, range=(lo, lo + nb * step), weights=p)
    taps = np.arange(-24, 25) * step
    kern = np.exp(-0.5 * (taps / s) ** 2)
    dens = np.convolve(hist, kern / kern.sum(), mode="same")
    cdf = np.concatenate([[0.0], np.cumsum(dens)])
    cdf /= cdf[-1]
    return float(np.interp(q, cdf, edges))


def grid_posterior(
    target,
    center=None,
    cov=None,
    *,
    n: int = 33,
    k: float = 6.0,
    n_coarse: int = 13,
    k_coarse: float = 8.0,
    edge_tol: float = 1e-5,
    max_rounds: int = 6,
    batch: int = 512,
    locate: bool = True,
) -> GridPosterior:
    """The posterior of a two-parameter ``target`` on a grid (module docstring).

    center, cov : a Gaussian roughly where the posterior is (e.g. the ensemble's, in internal
        coordinates; default: the target's prior). It only places the grid.
    n, k : fine grid points per axis and half-width in sd of the coarse posterior.
    locate : run the coarse stage; False starts the fine stage in the frame of (center, cov) --
        for a Gaussian already close to the posterior's moments, e.g. converged MCMC draws'.
    n_coarse, k_coarse : the same for the coarse stage (in sd of the frame's Gaussian).
    edge_tol : most mass allowed in the outer tenth of the fine grid's half-width.
    batch : parameter sets per ``log_prob`` call (times the experiments per forward batch).
    """
    d = int(target.ndim)
    if d != 2:
        raise InputError("quadrature", f"the grid reference needs 2 parameters, this target has {d}")
    prior = target.prior
    if center is None:
        center, cov = prior.prior_mean, prior.prior_cov
    m = np.asarray(center, dtype=np.float64).reshape(2)
    C = np.asarray(cov, dtype=np.float64).reshape(2, 2)
    C = 0.5 * (C + C.T)
    evals = failed = 0
    rounds = []

    def run(m, C, kk, nn):
        nonlocal evals, failed
        L = np.linalg.cholesky(C)
        u, Z = _grid(m, L, kk, nn)
        lp = _evaluate(target, Z.reshape(-1, 2), batch).reshape(nn, nn)
        evals += lp.size
        failed += int(np.sum(~np.isfinite(lp)))
        return L, u, Z, lp

    # ---- coarse stage: find and resolve the posterior
    for _ in range(max_rounds if locate else 0):
        L, u, Z, lp = run(m, C, k_coarse, n_coarse)
        w = _weights(lp)
        mc, Cc = grid_moments(Z, w)
        h = u[1] - u[0]
        Li = np.linalg.inv(L)
        s_min = math.sqrt(max(0.0, float(np.linalg.eigvalsh(Li @ Cc @ Li.T)[0])))
        edge = _edge(w)
        rounds.append(
            {
                "stage": "coarse",
                "k_sd": float(k_coarse),
                "n": int(n_coarse),
                "edge_mass": edge,
                "cells_per_sd": s_min / h,
            }
        )
        if edge > 1e-3:  # locating only: the fine stage checks edge_tol
            m, C = mc, 4.0 * (Cc + (h * h / 12.0) * (L @ L.T))
            continue
        if s_min < 0.5 * h:
            m, C = mc, Cc + (h * h / 12.0) * (L @ L.T)
            continue
        m, C = mc, Cc
        break
    else:
        if locate:
            raise RuntimeError(
                f"quadrature: the coarse grid did not settle in {max_rounds} rounds "
                f"(edge mass {edge:.2g}, {s_min / h:.2f} cells per sd)"
            )

    # ---- fine stage in the frame of the coarse moments
    kk, nn = float(k), int(n)
    for _ in range(5):
        L, u, Z, lp = run(m, C, kk, nn)
        w = _weights(lp)
        edge = _edge(w)
        rounds.append({"stage": "fine", "k_sd": kk, "n": nn, "edge_mass": edge})
        if edge <= edge_tol:
            break
        # re-frame on this grid's (accurate) moments, then widen by 1.5 at the same spacing
        m, C = grid_moments(Z, w)
        kk, nn = 1.5 * kk, int(round(1.5 * (nn - 1) / 2)) * 2 + 1
    mean, cov = grid_moments(Z, w)

    # ---- resolution: every-other-point subgrid (spacing 2h)
    w2 = _weights(lp[::2, ::2])
    m2, c2 = grid_moments(Z[::2, ::2], w2)
    sd = np.sqrt(np.diag(cov))
    res_err = {
        "mean_sd": float(np.max(np.abs(m2 - mean) / sd)),
        "sd_rel": float(np.max(np.abs(np.sqrt(np.diag(c2)) / sd - 1.0))),
    }

    # ---- SI moments, marginal intervals, 95 % HDR
    positive = np.asarray(prior.positive, bool)
    theta = np.where(positive, np.exp(np.where(positive, Z, 0.0)), Z)
    mean_si, cov_si = grid_moments(theta, w)
    uf, f, wf = _refined(u, lp)
    eti = _marginal_intervals(uf, L, m, wf)
    level_f, area, contour = _hdr(uf, L, m, f, wf)
    level = float(np.max(lp) + level_f)
    names = tuple(prior.names)
    internal = list(getattr(target, "internal_names", [f"log_{a}" if p else a for a, p in zip(names, positive)]))
    return GridPosterior(
        names=names,
        internal_names=internal,
        positive=positive,
        center=m,
        basis=L,
        u=u,
        Z=Z,
        log_prob=lp,
        weight=w,
        mean=mean,
        cov=cov,
        mean_si=mean_si,
        cov_si=cov_si,
        eti95=eti,
        hdr95_level=level,
        hdr95_area=area,
        hdr95_contour=contour,
        edge_mass=edge,
        resolution_error=res_err,
        n_evals=evals,
        n_failed=failed,
        rounds=rounds,
        edge_tol=float(edge_tol),
    )


def _contour(u, L, m, f, level):
    """Polylines (in z) of the grid log-density ``f`` at ``level`` (contourpy, a matplotlib
    dependency; the log-density interpolates far better than the density, being about quadratic)."""
    try:
        import contourpy
    except ImportError:  # pragma: no cover
        return []
    U0, U1 = np.meshgrid(u, u, indexing="ij")
    gen = contourpy.contour_generator(U0, U1, f)
    out = []
    for line in gen.lines(float(level)):
        line = np.asarray(line, float)
        if line.shape[0] >= 2:
            out.append(m + line @ L.T)
    return out


def compare_to_mcmc(grid, draws, mcse_mean=None, mcse_sd=None, z_max: float = 4.0) -> dict:
    """Do MCMC draws (chain, draw, 2) (internal) agree with the grid posterior within Monte-Carlo error?

    grid : :class:`GridPosterior` or its :meth:`~GridPosterior.to_dict`.
    ``mcse_mean``/``mcse_sd``: (2,) ArviZ MCSE of mean and sd of the draws (computed here when None).
    Returns the differences of means and sds in MCSE units (``mean_z``, ``sd_z``), the same in
    posterior sd, and ``within_mc_error`` = every |z| <= ``z_max`` (and the grid's resolution
    error -- a conservative bound: the change on the every-other-point subgrid -- below half the MCSE).
    """
    if isinstance(grid, dict):
        names = list(grid["mean_internal"])
        g_mean = np.array([grid["mean_internal"][n] for n in names])
        g_sd = np.array([grid["sd_internal"][n] for n in names])
        res_err = grid["resolution_error"]
    else:
        names, g_mean, g_sd, res_err = list(grid.internal_names), grid.mean, grid.sd, grid.resolution_error
    x = np.asarray(draws, dtype=np.float64)
    if x.ndim == 2:
        x = x[None]
    if mcse_mean is None or mcse_sd is None:
        import arviz as az

        dt = az.from_dict({"posterior": {f"x{i}": x[:, :, i] for i in range(2)}})
        mm = az.mcse(dt, method="mean")
        ms = az.mcse(dt, method="sd")
        mcse_mean = np.array([float(mm[f"x{i}"]) for i in range(2)])
        mcse_sd = np.array([float(ms[f"x{i}"]) for i in range(2)])
    mcse_mean, mcse_sd = np.asarray(mcse_mean, float), np.asarray(mcse_sd, float)
    flat = x.reshape(-1, 2)
    m, s = flat.mean(axis=0), flat.std(axis=0, ddof=1)
    zm = (m - g_mean) / mcse_mean
    zs = (s - g_sd) / mcse_sd
    res_ok = res_err["mean_sd"] * float(np.max(g_sd / mcse_mean)) < 0.5
    return {
        "mean_z": dict(zip(names, zm.tolist())),
        "sd_z": dict(zip(names, zs.tolist())),
        "mean_diff_sd": dict(zip(names, ((m - g_mean) / g_sd).tolist())),
        "sd_ratio": dict(zip(names, (s / g_sd).tolist())),
        "mcse_mean": dict(zip(names, mcse_mean.tolist())),
        "mcse_sd": dict(zip(names, mcse_sd.tolist())),
        "z_max": z_max,
        "grid_resolution_ok": bool(res_ok),
        "grid_resolution_error": res_err,
        "within_mc_error": bool(np.all(np.abs(zm) <= z_max) and np.all(np.abs(zs) <= z_max) and res_ok),
    }
