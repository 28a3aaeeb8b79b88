"""Parsimonious IMR (pIMR): the first-collapse time in closed form and its inference (methods.md §2).

``t_c(theta) = t_RC (1 - fbar)^(-1/2)``, ``t_RC = sqrt(6 pi) Gamma(11/6) / (5 Gamma(4/3)) = 0.91468``,
``fbar = fbar_bc + fbar_wc + fbar_We + fbar_KV`` (each a time-averaged effective pressure over p8;
positive terms slow the collapse):

* bubble contents ``fbar_bc = B(kappa) p_go* R0*^(3 kappa) + p_v*`` with
  ``p_go* = 1 + 2 S/(p8 Req) - p_v*`` the equilibrium gas pressure at Req, ``p_v*`` the vapour
  pressure (0 without vapour), ``R0* = Req/Rmax``. ``B(1) = 1.494``, ``B(1.4) = 2.184``; other
  kappa by :func:`contents_factor`, the quadrature that reproduces both (energy-weighted time
  average of the polytropic pressure over the Rayleigh collapse);
* weak compressibility ``fbar_wc = 2 Mc / (Mc + sqrt(Mc^2 + 4 t_RC^2))``, ``Mc = 1/c* = sqrt(p8/rho)/c8``
  (0 with the incompressible Rayleigh–Plesset equation, ``radial=rp``);
* surface tension ``fbar_We = -pi / (sqrt(6) t_RC We)`` with ``1/We = 2 S/(p8 Rmax)`` (the
  coefficient of 1/R* in the dimensionless Laplace pressure; pi/(sqrt 6 t_RC) is the time average
  of 1/R* over the Rayleigh collapse);
* Kelvin–Voigt ``fbar_KV = 4 C / (2 C + sqrt(Re^2 t_RC^2 + 4 C^2)) + (1/Ca)(sqrt(2/3) R0* pi / t_RC - 5/2)``,
  ``C = 0.4638 + 0.5639/Re + 5.749/Re^2``, ``Re = rho Uc Rmax/mu``, ``1/Ca = G/p8``.

Which kappa: the polytropic bubble uses the forward model's kappa (its gas starts at
p_go* R0*^(3 kappa)); the thermal bubble starts isothermal (p_go* R0*^3) and we use kappa = 1
(override with ``kappa``). tests/test_ensemble_methods.py compares the formula with simulated
first-collapse times across the prior range.

Inference: ``J(theta) = (1/N_exp) sum_n [(t_c,meas^(n) / t_c(theta))^2 - 1]^2``, minimised in log J on
the (G, mu) grid and then by Nelder–Mead in (log G, log mu) from the best grid point.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from functools import lru_cache

import numpy as np

from imrbayes.ensemble.imr import grid_axis
from imrbayes.ensemble.method import InferenceMethod
from imrbayes.ensemble.result import FitResult, rmse
from imrbayes.errors import InputError

__all__ = ["PIMR", "T_RC", "contents_factor", "PIMRSettings", "collapse_terms", "collapse_time", "fit_pimr"]

T_RC = math.sqrt(6.0 * math.pi) * math.gamma(11.0 / 6.0) / (5.0 * math.gamma(4.0 / 3.0))


@lru_cache(maxsize=64)
def contents_factor(kappa: float) -> float:
    """B(kappa): the energy-weighted time average of R*^(-3 kappa) over the Rayleigh collapse.

    With the perturbation f(R) of the driving pressure, the first-order collapse time is
    t_RC (1 - fbar)^(-1/2) with fbar the time average over the Rayleigh collapse of
    F(R) = 3 int_R^1 f(s) s^2 ds / (1 - R^3). For f = R^(-3 kappa) this gives B(1) = 1.4942 and
    B(1.4) = 2.1835, the constants of Zhu et al.; finite for kappa < 11/6.
    """
    # scipy is imported where it is used: the method registry (imported when the CLI starts) stays cheap
    from scipy import integrate

    k = float(kappa)
    if not 0.5 <= k < 11.0 / 6.0:
        raise InputError("kappa", f"the contents factor needs 0.5 <= kappa < 11/6, got {k}")

    def F(R):
        I = -math.log(R) if abs(k - 1.0) < 1e-12 else (R ** (3.0 - 3.0 * k) - 1.0) / (3.0 * k - 3.0)
        return 3.0 * I / (1.0 - R**3)

    def integrand(R):
        return F(R) / math.sqrt(2.0 * (1.0 - R**3) / (3.0 * R**3))

    val = integrate.quad(integrand, 0.0, 0.5, limit=200)[0] + integrate.quad(integrand, 0.5, 1.0, limit=200)[0]
    return val / T_RC


@dataclass
class PIMRSettings:
    """pIMR settings. ``kappa``: None = automatic (see module doc). Grid as in IMR (for the
    landscape and the starting point)."""

    kappa: float | None = None
    G_min: float = 0.0  #: lowest G [Pa] (0: a liquid)
    G_max: float = 1e6  #: highest G [Pa]
    mu_min: float = 1e-4  #: lowest mu [Pa s]
    mu_max: float = 10.0  #: highest mu [Pa s]
    n_G: int = 120  #: grid points in G
    n_mu: int = 74  #: grid points in mu
    spacing: str = "log"  #: as IMR's (:func:`imrbayes.ensemble.imr.grid_axis`)
    refine: bool = True
    level: float = 0.95


def _groups(fm, rmax_m, req_m, kappa=None) -> dict:
    """Per-bubble quantities of the formula from the forward model's groups (arrays (n_exp,))."""
    g = fm.groups(np.asarray(rmax_m, dtype=float), np.asarray(req_m, dtype=float))
    ph = fm.physics
    if kappa is None:
        kappa = 1.0 if fm.options.thermal else ph.kappa
    r0 = np.asarray(g["req"], dtype=float)
    pv = float(g["pv"]) if np.ndim(g["pv"]) == 0 else np.asarray(g["pv"], dtype=float)
    inv_we = np.asarray(g["inv_we"], dtype=float)
    return {
        "r0": r0,
        "pv": pv,
        "pgo": 1.0 + inv_we / r0 - pv,
        "inv_we": inv_we,
        "mc": 0.0 if fm.options.radial == "rp" else 1.0 / float(g["cstar"]),
        "kappa": float(kappa),
        "B": contents_factor(float(kappa)),
        "p8": ph.p8,
        "inv_re_per_mu": 1.0 / (ph.rho * ph.velocity_scale * np.asarray(rmax_m, dtype=float)),
    }


def collapse_terms(G, mu, q: dict) -> dict:
    """The four fbar terms (arrays broadcasting G, mu (SI) against the bubbles in ``q``)."""
    G = np.asarray(G, dtype=float)
    mu = np.asarray(mu, dtype=float)
    bc = q["B"] * q["pgo"] * q["r0"] ** (3.0 * q["kappa"]) + q["pv"]
    mc = q["mc"]
    wc = 2.0 * mc / (mc + math.sqrt(mc * mc + 4.0 * T_RC**2)) if mc > 0 else 0.0
    we = -math.pi / (math.sqrt(6.0) * T_RC) * q["inv_we"]
    inv_re = mu * q["inv_re_per_mu"]
    C = 0.4638 + 0.5639 * inv_re + 5.749 * inv_re**2
    with np.errstate(divide="ignore", invalid="ignore"):
        re_t = np.where(inv_re > 0, T_RC / np.where(inv_re > 0, inv_re, 1.0), np.inf)
        visc = np.where(np.isfinite(re_t), 4.0 * C / (2.0 * C + np.sqrt(re_t**2 + 4.0 * C**2)), 0.0)
    elastic = (G / q["p8"]) * (math.sqrt(2.0 / 3.0) * q["r0"] * math.pi / T_RC - 2.5)
    shape = np.broadcast_shapes(np.shape(bc), np.shape(visc), np.shape(elastic))
    return {
        "contents": np.broadcast_to(bc, shape),
        "compressibility": np.broadcast_to(wc, shape),
        "surface_tension": np.broadcast_to(we, shape),
        "viscous": np.broadcast_to(visc, shape),
        "elastic": np.broadcast_to(elastic, shape),
    }


def collapse_time(fm, G, mu, rmax_m, req_m, kappa=None):
    """Predicted first-collapse time t_c* (inf where fbar >= 1); G [Pa], mu [Pa s], Rmax, Req [m]
    broadcast together."""
    G, mu, rmax, req = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (G, mu, rmax_m, req_m)))
    q = _groups(fm, rmax.ravel(), req.ravel(), kappa)
    return collapse_time_from_q(G.ravel(), mu.ravel(), q).reshape(G.shape)


def _cost(tc_meas, tc_pred):
    """J = mean_n [(t_meas/t_c)^2 - 1]^2 over the last axis."""
    r = (tc_meas / tc_pred) ** 2 - 1.0
    return np.mean(r * r, axis=-1)


def fit_pimr(
    fm, obs, space, settings: PIMRSettings | None = None, seed: int = 0, runner=None, progress=None, execution=None
) -> FitResult:
    """Fit (G, mu) to the measured first-collapse times ``obs.t_collapse_star`` (n_exp,).

    Closed form on a grid, in this process: no units (``execution`` is accepted and unused; the run
    directory still records the configuration)."""
    from scipy import optimize

    s = settings or PIMRSettings()
    t0 = time.perf_counter()
    names = space.names
    if tuple(names[:2]) != ("G", "mu") or len(names) != 2:
        raise InputError(
            "--method pimr",
            f"pIMR's closed form is for Kelvin–Voigt models with (G, mu); model parameters are {list(names)}",
        )
    PIMR.check_settings(s, obs)
    tm = np.asarray(obs.t_collapse_star, dtype=float)
    q = _groups(fm, obs.rmax_m, obs.req_m, s.kappa)
    Gg = grid_axis(s.G_min, s.G_max, s.n_G, s.spacing)
    mg = grid_axis(s.mu_min, s.mu_max, s.n_mu, s.spacing)
    qq = {k: (v[None, None, :] if isinstance(v, np.ndarray) else v) for k, v in q.items()}
    terms = collapse_terms(Gg[:, None, None], mg[None, :, None], qq)
    fbar = sum(terms.values())
    with np.errstate(divide="ignore", invalid="ignore"):
        tc = np.where(fbar < 1.0, T_RC / np.sqrt(1.0 - fbar), np.inf)
    J = _cost(tm, tc)  # (n_G, n_mu)
    i, j = np.unravel_index(np.nanargmin(J), J.shape)
    best = np.array([Gg[i], mg[j]])
    logJ = np.log(np.maximum(J, 1e-300))

    def f(x):
        G, mu = np.exp(x)
        qv = {k: v for k, v in q.items()}
        t = collapse_time_from_q(G, mu, qv)
        return float(np.log(max(_cost(tm, t), 1e-300)))

    refined = best.copy()
    if s.refine:
        x0 = np.log(np.maximum(best, [0.5 * (Gg[1] - Gg[0]), 0.5 * (mg[1] - mg[0])]))
        res = optimize.minimize(f, x0, method="Nelder-Mead", options={"xatol": 1e-6, "fatol": 1e-10, "maxiter": 2000})
        if np.isfinite(res.fun) and res.fun <= logJ[i, j]:
            # inside the grid's box: below its lowest positive value the closed form is flat to the
            # data, and Nelder-Mead in log space would walk off towards 0 (mu 5e-15 Pa s)
            lo = np.array([Gg[Gg > 0].min() if Gg[0] > 0 else 0.0, mg[mg > 0].min() if mg[0] > 0 else 0.0])
            refined = np.clip(np.exp(res.x), lo, [Gg[-1], mg[-1]])
    Jmin = float(np.exp(f(np.log(np.maximum(refined, 1e-300)))))
    tc_fit = collapse_time_from_q(refined[0], refined[1], q)
    # pseudo-posterior on the grid: exp(-(n - p)/2 J/Jmin) (noise scale from the residuals)
    n, p = tm.size, 2
    est, contour_level = _grid_estimate(J, Jmin, n, p, Gg, mg, refined, s.level)
    terms_fit = collapse_terms(refined[0], refined[1], q)
    per = [
        {
            "name": nm,
            "t_collapse_measured": float(a),
            "t_collapse_fitted": float(b),
            "terms": {k: float(np.broadcast_to(v, tm.shape)[e]) for k, v in terms_fit.items()},
        }
        for e, (nm, a, b) in enumerate(zip(obs.names, tm, tc_fit))
    ]
    # fitted R(t) at the optimum (for the figure), if a forward run is affordable
    fitted = np.full_like(obs.R_star, np.nan)
    mask = np.zeros(obs.R_star.shape, dtype=bool)
    if runner is not None:
        out = runner.simulate(np.repeat(refined[None, :], obs.n_exp, axis=0), obs.rmax_m, obs.req_m, obs.t_star)
        fitted = out.R_star
        mask[:, 1:] = True
    details = {
        "settings": asdict(s),
        "kappa": q["kappa"],
        "B": q["B"],
        "grid_optimum": {"G": float(best[0]), "mu": float(best[1])},
        "optimum": {"G": float(refined[0]), "mu": float(refined[1])},
        "J_min": Jmin,
        "log_J_min": math.log(max(Jmin, 1e-300)),
        "contour_level_J": contour_level,
        "collapse_rmse": float(np.sqrt(np.mean((tc_fit - tm) ** 2))),
        "rmse": rmse(fitted, obs.R_star, mask) if runner is not None else float("nan"),
        "uncertainty": "pseudo-posterior on the grid, p ∝ exp(-(n-p)/2 J/J_min) with n = N_exp collapse "
        "times, p = 2 (F construction with the noise scale from the residuals); "
        "the 95% region is J <= J_min (1 + p/(n-p) F_{p,n-p}(0.95))",
        "note": "one collapse time per experiment constrains a ridge in (G, mu); only the spread of "
        "Rmax and Req across experiments breaks the degeneracy",
    }
    from imrbayes.ensemble.imr import grid_edge_warnings

    # the refined optimum, not the grid's; Nelder-Mead works in log space, so "at 0" means within
    # half a grid cell of it (1e-16 Pa s on the UMich records)
    def side(x, grid):
        half = 0.5 * (grid[1] - grid[0])
        return "low" if x <= grid[0] + half else "high" if x >= grid[-1] - half else None

    warnings = grid_edge_warnings(side(refined[0], Gg), side(refined[1], mg), Gg, mg, "pIMR")
    if n <= p:
        # one collapse time fixes a curve in (G, mu), two at most a point with no noise scale: no
        # interval can be given, but the set of (G, mu) that reproduce the data can
        ridge = _ridge(tc, tm, Gg, mg)
        details["ridge"] = ridge
        for name in ("G", "mu"):
            vals = ridge[name]
            est[name]["ridge"] = [float(min(vals)), float(max(vals))] if vals else None
        if n == 1 and ridge["G"]:
            warnings.append(
                f"one experiment: its collapse time fixes a ridge of (G, mu), not a point -- G "
                f"{min(ridge['G']) / 1e3:.3g}-{max(ridge['G']) / 1e3:.3g} kPa with mu "
                f"{min(ridge['mu']):.3g}-{max(ridge['mu']):.3g} Pa s along it reproduce it; the "
                f"estimate is one point on the ridge and has no interval (add experiments of "
                f"different Rmax/Req to break the degeneracy)"
            )
        else:
            warnings.append(
                f"{n} experiments for 2 parameters: no noise scale, so no interval; the estimate is the best fit only"
            )
    rng = np.random.default_rng(seed)
    draws = _grid_draws(J, Jmin, n, p, Gg, mg, rng)
    return FitResult(
        method="pimr",
        model=fm.constitutive.name,
        param_names=tuple(names),
        estimate=est,
        fitted=fitted,
        fit_mask=mask,
        per_experiment=per,
        details=details,
        posterior={"G": draws[None, :, 0], "mu": draws[None, :, 1]},
        extra_groups={"landscape": {"log_J": logJ, "t_collapse_measured": tm, "t_collapse_fitted": tc_fit}},
        extra_dims={
            "log_J": ["G_grid", "mu_grid"],
            "t_collapse_measured": ["experiment"],
            "t_collapse_fitted": ["experiment"],
        },
        coords={"G_grid": Gg, "mu_grid": mg, "experiment": list(obs.names)},
        runtime_s=time.perf_counter() - t0,
        warnings=warnings,
    )


def collapse_time_from_q(G, mu, q):
    terms = collapse_terms(G, mu, q)
    fbar = sum(terms.values())
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(fbar < 1.0, T_RC / np.sqrt(1.0 - fbar), np.inf)


def _ridge(tc, tm, Gg, mg) -> dict:
    """The (G, mu) [Pa, Pa s] on the grid where the predicted collapse time of the first experiment
    crosses its measured one: for each G, the mu (linear between grid points) where tc - tm changes
    sign. ``tc`` is (n_G, n_mu, n_exp)."""
    r = tc[:, :, 0] - tm[0]
    G_out, mu_out = [], []
    for i, G in enumerate(Gg):
        row = r[i]
        for j in np.flatnonzero(np.isfinite(row[:-1]) & np.isfinite(row[1:]) & (np.sign(row[:-1]) != np.sign(row[1:]))):
            f = row[j] / (row[j] - row[j + 1])
            G_out.append(float(G))
            mu_out.append(float(mg[j] + f * (mg[j + 1] - mg[j])))
    return {
        "G": G_out,
        "mu": mu_out,
        "note": "(G, mu) on the grid whose predicted first-collapse time equals the measured one",
    }


def _pseudo_logpost(J, Jmin, n, p):
    if n <= p or not Jmin > 0:
        return None
    with np.errstate(invalid="ignore", over="ignore"):
        lp = -0.5 * (n - p) * J / Jmin
    return np.where(np.isfinite(lp), lp, -np.inf)


def _grid_estimate(J, Jmin, n, p, Gg, mg, opt, level):
    """SI estimate from the grid pseudo-posterior; mean = optimum, sd and 95% HDI from the marginals."""
    from scipy import stats

    lp = _pseudo_logpost(J, Jmin, n, p)
    level_J = float(Jmin * (1.0 + p / (n - p) * stats.f.ppf(level, p, n - p))) if n > p else float("nan")
    out = {}
    for ax, (name, grid) in enumerate((("G", Gg), ("mu", mg))):
        if lp is None:
            out[name] = {"mean": float(opt[ax]), "sd": float("nan"), "hdi95": [float("nan")] * 2}
            continue
        w = np.exp(lp - lp.max())
        marg = w.sum(axis=1 - ax)
        marg = marg / marg.sum()
        mean = float(np.sum(marg * grid))
        sd = float(np.sqrt(np.sum(marg * (grid - mean) ** 2)))
        hdi = _hdi_grid(grid, marg, 0.95)
        # on a log grid one cell at G = 0 carries little mass: an interval that leaves out the optimum
        # itself is widened to hold it (a ridge of equal cost, not a located parameter)
        hdi = [min(hdi[0], float(opt[ax])), max(hdi[1], float(opt[ax]))]
        out[name] = {"mean": float(opt[ax]), "sd": sd, "hdi95": hdi, "posterior_mean": mean}
    return out, level_J


def _hdi_grid(grid, pmf, prob):
    """Smallest set of grid cells holding ``prob`` of the mass, reported as [min, max]."""
    order = np.argsort(pmf)[::-1]
    k = int(np.searchsorted(np.cumsum(pmf[order]), prob)) + 1
    sel = grid[order[:k]]
    h = 0.5 * (grid[1] - grid[0])
    return [float(max(grid[0], sel.min() - h)), float(min(grid[-1], sel.max() + h))]


def _grid_draws(J, Jmin, n, p, Gg, mg, rng, n_draws=1000):
    """Draws from the grid pseudo-posterior, uniform within the cell (1 chain)."""
    lp = _pseudo_logpost(J, Jmin, n, p)
    if lp is None:
        lp = np.where(J <= np.nanmin(J), 0.0, -np.inf)
    w = np.exp(lp - lp.max()).ravel()
    w = w / w.sum()
    idx = rng.choice(w.size, size=n_draws, p=w)
    i, j = np.unravel_index(idx, J.shape)
    dG, dm = Gg[1] - Gg[0], mg[1] - mg[0]
    G = np.clip(Gg[i] + (rng.random(n_draws) - 0.5) * dG, Gg[0], Gg[-1])
    mu = np.clip(mg[j] + (rng.random(n_draws) - 0.5) * dm, mg[0], mg[-1])
    return np.column_stack([G, mu])


class PIMR(InferenceMethod):
    """pIMR as a plug-in (:class:`~imrbayes.ensemble.method.InferenceMethod`)."""

    name = "pimr"
    label = "pIMR (collapse-time closed form)"
    settings_class = PIMRSettings
    fit = staticmethod(fit_pimr)

    @staticmethod
    def check_settings(settings, obs):
        tm = np.asarray(obs.t_collapse_star, dtype=float)
        if not np.all(np.isfinite(tm) & (tm > 0)):
            raise InputError("data", "pIMR needs the measured first-collapse time of every experiment")
        if settings.kappa is not None and not 0.5 <= float(settings.kappa) < 11.0 / 6.0:
            raise InputError("kappa", f"the contents factor needs 0.5 <= kappa < 11/6, got {settings.kappa}")

    @staticmethod
    def n_forward_runs(settings, n_exp, n_steps):
        return n_exp  # closed form; one run per experiment for the fitted curves

    @staticmethod
    def figures(obs, res, fdir):
        from imrbayes.ensemble.figures import landscape_figure

        return [landscape_figure(res, fdir / "landscape.png")]
