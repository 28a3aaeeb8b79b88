"""Figures of a fit (:mod:`imrbayes.plotting`: matplotlib object API on the Agg canvas, no pyplot).

* :func:`fit_figure` — measured (dots) vs fitted (line) R*(t*), one panel per experiment;
* :func:`landscape_figure` — IMR/pIMR cost landscape, 95 % contour, per-experiment and overall optima;
* :func:`time_resolved_figure` — MIEnKS G(t), mu(t): time-resolved mean with 95 % band and the
  per-window estimates;
* :func:`experiments_figure` — En4D-Var per-experiment posteriors and the fused estimate.
"""

from __future__ import annotations

import math

import numpy as np

from imrbayes.plotting import figure, label, save, scale

__all__ = ["fit_figure", "landscape_figure", "time_resolved_figure", "experiments_figure"]


def fit_figure(obs, result, path, max_panels: int = 20):
    """Measured vs fitted R*(t*) per experiment; the fitted samples are shaded grey outside."""
    n = min(obs.n_exp, max_panels)
    ncol = min(4, n)
    nrow = math.ceil(n / ncol)
    fig = figure(3.2 * ncol, 2.3 * nrow + 0.5)
    axes = np.atleast_1d(fig.subplots(nrow, ncol, sharex=True, sharey=True, squeeze=False)).ravel()
    for e in range(n):
        ax = axes[e]
        ax.plot(obs.t_star, obs.R_star[e], ".", ms=2.5, color="0.35", label="measured")
        ax.plot(obs.t_star, result.fitted[e], "-", lw=1.2, color="tab:red", label="fitted")
        m = result.fit_mask[e]
        if m.any():
            last = obs.t_star[np.flatnonzero(m)[-1]]
            if last < obs.t_star[-1]:
                ax.axvspan(last, obs.t_star[-1], color="0.9", zorder=0)
        ax.set_title(obs.names[e], fontsize=8)
        ax.grid(alpha=0.3)
    for ax in axes[n:]:
        ax.set_visible(False)
    axes[0].legend(fontsize=7, loc="upper right")
    fig.supxlabel(label("t_star"))
    fig.supylabel(label("R_star"))
    extra = f" (first {n} of {obs.n_exp})" if obs.n_exp > n else ""
    fig.suptitle(f"{result.method}: measured vs fitted, rmse {result.rmse:.4g}{extra}", fontsize=10)
    return save(fig, path)


def landscape_figure(result, path):
    """log10 of the IMR cost (or log J of pIMR) with the 95 % contour and the optima."""
    Gg = np.asarray(result.coords["G_grid"]) * scale("G")
    mg = np.asarray(result.coords["mu_grid"]) * scale("mu")
    fig = figure(6.4, 4.8)
    ax = fig.subplots()
    det = result.details
    if "J" in result.extra_groups.get("landscape", {}):
        J = np.asarray(result.extra_groups["landscape"]["J"])
        Z = np.log10(np.where(np.isfinite(J) & (J > 0), J, np.nan))
        lab = r"$\log_{10} J$"
        lvl = det["confidence"]["J_level"]
        lvl = math.log10(lvl) if lvl and lvl > 0 else None
    else:
        Z = np.asarray(result.extra_groups["landscape"]["log_J"]) / math.log(10.0)
        lab = r"$\log_{10} J_{pIMR}$"
        lvl = det.get("contour_level_J")
        lvl = math.log10(lvl) if lvl and lvl > 0 and math.isfinite(lvl) else None
    cs = ax.contourf(Gg, mg, Z.T, levels=30, cmap="viridis")
    fig.colorbar(cs, ax=ax, label=lab)
    if lvl is not None and np.nanmin(Z) < lvl < np.nanmax(Z):
        ax.contour(Gg, mg, Z.T, levels=[lvl], colors="w", linewidths=1.5, linestyles="solid")
        ax.plot([], [], "w-", label="95% region")
    for i, p in enumerate(result.per_experiment):
        if "optimum" in p:
            ax.plot(p["optimum"]["G"] * scale("G"), p["optimum"]["mu"] * scale("mu"), "o", ms=4, mfc="none",
                    mec="orange", label="per-experiment optima" if i == 0 else None)
    opt = det["optimum"]
    ax.plot(opt["G"] * scale("G"), opt["mu"] * scale("mu"), "*", ms=12, color="red", mec="k", label="optimum")
    ax.set_xlabel(label("G"))
    ax.set_ylabel(label("mu"))
    ax.legend(fontsize=8, loc="upper right", facecolor="0.8")
    ax.set_title(f"{result.method}: G = {opt['G'] * 1e-3:.3g} kPa, mu = {opt['mu']:.3g} Pa s", fontsize=10)
    return save(fig, path)


def time_resolved_figure(result, path):
    """Time-resolved G(t*), mu(t*) (mean, 95 % HDI band) and per-window estimates (mean ± 2 sd)."""
    names = list(result.param_names)
    fig = figure(7.0, 2.6 * len(names) + 0.4)
    axes = np.atleast_1d(fig.subplots(len(names), 1, sharex=True))
    tr = result.time_resolved
    t = np.array([x["t_star"] for x in tr])
    for ax, nm in zip(axes, names):
        sc, lab = scale(nm), label(nm)
        m = np.array([x[nm]["mean"] for x in tr]) * sc
        lo = np.array([x[nm]["hdi95"][0] for x in tr]) * sc
        hi = np.array([x[nm]["hdi95"][1] for x in tr]) * sc
        ax.fill_between(t, lo, hi, color="tab:blue", alpha=0.25, label="95% HDI (time-resolved)")
        ax.plot(t, m, color="tab:blue", lw=1.5, label="time-resolved mean")
        for i, w in enumerate(result.windows):
            a, b = w["t_star"]
            ax.plot([a, b], [w[nm]["mean"] * sc] * 2, color="tab:orange", lw=0.8, alpha=0.7,
                    label="per-window mean" if i == 0 else None)
            ax.errorbar(0.5 * (a + b), w[nm]["mean"] * sc, yerr=2 * w[nm]["sd"] * sc, fmt="none",
                        ecolor="tab:orange", alpha=0.5, lw=0.8)
        ax.set_ylabel(lab)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, loc="upper right")
    axes[-1].set_xlabel(label("t_star"))
    fig.suptitle("MIEnKS-MDA time-resolved parameters", fontsize=10)
    return save(fig, path)


def experiments_figure(result, path):
    """Per-experiment posterior mean ± 2 sd and the fused estimate (En4D-Var)."""
    names = list(result.param_names)
    fig = figure(4.0 * len(names), 0.25 * len(result.per_experiment) + 2.0)
    axes = np.atleast_1d(fig.subplots(1, len(names)))
    for ax, nm in zip(axes, names):
        sc, lab = scale(nm), label(nm)
        for i, p in enumerate(result.per_experiment):
            e = p["estimate"][nm]
            ax.errorbar(e["mean"] * sc, i, xerr=2 * e["sd"] * sc, fmt="o", ms=3, color="tab:blue")
        f = result.estimate[nm]
        ax.axvspan(f["hdi95"][0] * sc, f["hdi95"][1] * sc, color="tab:red", alpha=0.2, label="fused 95% HDI")
        ax.axvline(f["mean"] * sc, color="tab:red", label="fused mean")
        ax.set_yticks(range(len(result.per_experiment)), [p["name"] for p in result.per_experiment], fontsize=7)
        ax.set_xlabel(lab)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle("En4D-Var: per-experiment posteriors (mean ± 2 sd) and the fused estimate", fontsize=10)
    return save(fig, path)
