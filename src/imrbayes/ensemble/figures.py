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


def _time_scale(result, obs=None):
    """Per-experiment time scale t_c [s] (t = t* t_c): ``time_scale_s`` set on the result (or the
    observations) by ``imrbayes fit`` from the preprocessing; None when unknown."""
    for src in (result, obs):
        tc = getattr(src, "time_scale_s", None)
        if tc is not None:
            tc = np.asarray(tc, dtype=float).ravel()
            if tc.size and np.all(np.isfinite(tc)) and np.all(tc > 0):
                return tc
    return None


def fit_figure(obs, result, path, max_panels: int = 20):
    """Measured vs fitted R*(t*) per experiment (a µs axis on top when the time scale is known); the
    samples the method did not fit shaded grey; the legend below the panels, off the data. pIMR's
    curve is labelled as what it is: fitted to the collapse time only (measured and fitted collapse
    times marked)."""
    n = min(obs.n_exp, max_panels)
    ncol = min(4, n)
    nrow = math.ceil(n / ncol)
    w = min(3.4, 10.0 / ncol)  # at most ~10 in wide: fits a screen at the report's width
    fig = figure(w * ncol, 2.4 * nrow + 1.0)
    axes = np.atleast_1d(fig.subplots(nrow, ncol, sharex=True, sharey=True, squeeze=False)).ravel()
    pimr = result.method == "pimr"
    tc = _time_scale(result, obs)
    fitted_tc = [p.get("t_collapse_fitted") for p in result.per_experiment] if pimr else []
    for e in range(n):
        ax = axes[e]
        ax.plot(obs.t_star, obs.R_star[e], ".", ms=3, color="0.3", label="measured")
        ax.plot(
            obs.t_star,
            result.fitted[e],
            "-",
            lw=1.3,
            color="tab:red",
            label="curve at the estimate (collapse time fitted)" if pimr else "fitted",
        )
        m = result.fit_mask[e]
        if m.any():
            last = obs.t_star[np.flatnonzero(m)[-1]]
            if last < obs.t_star[-1]:
                ax.axvspan(last, obs.t_star[-1], color="0.9", zorder=0, label="not fitted" if e == 0 else None)
        if pimr:
            tm = obs.t_collapse_star[e] if obs.t_collapse_star is not None else np.nan
            if np.isfinite(tm):
                ax.axvline(tm, color="0.3", ls=":", lw=1, label="measured collapse time" if e == 0 else None)
            if e < len(fitted_tc) and fitted_tc[e] is not None and np.isfinite(fitted_tc[e]):
                ax.axvline(
                    fitted_tc[e], color="tab:red", ls="--", lw=1, label="fitted collapse time" if e == 0 else None
                )
        ax.set_title(obs.names[e], fontsize=8)
        ax.grid(alpha=0.3)
        if tc is not None and e < ncol:
            from imrbayes.plotting import time_axis_us

            time_axis_us(ax, float(tc[e] if e < tc.size else tc.mean()))
    for ax in axes[n:]:
        ax.set_visible(False)
    for k, ax in enumerate(axes[:n]):
        if k >= n - ncol:  # the bottom panel of each column
            ax.set_xlabel(label("t_star"), fontsize=9)
    handles, labels = axes[0].get_legend_handles_labels()
    wide = sum(len(x) for x in labels) > 60
    fig.legend(
        handles, labels, loc="outside lower center", ncol=2 if wide else min(len(labels), 4), fontsize=8, frameon=False
    )
    fig.supylabel(label("R_star"), fontsize=9)
    extra = f" (first {n} of {obs.n_exp})" if obs.n_exp > n else ""
    what = (
        "pIMR: collapse time only — the curve at the estimate, not a fit of R(t)"
        if pimr
        else f"{result.method}: measured vs fitted"
    )
    fig.suptitle(f"{what}, rmse {result.rmse:.3g}{extra}", fontsize=10)
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
            ax.plot(
                p["optimum"]["G"] * scale("G"),
                p["optimum"]["mu"] * scale("mu"),
                "o",
                ms=4,
                mfc="none",
                mec="orange",
                label="per-experiment optima" if i == 0 else None,
            )
    opt = det["optimum"]
    ax.plot(opt["G"] * scale("G"), opt["mu"] * scale("mu"), "*", ms=12, color="red", mec="k", label="optimum")
    ax.set_xlabel(label("G"))
    ax.set_ylabel(label("mu"))
    ax.legend(fontsize=8, loc="upper right", facecolor="0.8")
    ax.set_title(f"{result.method}: G = {opt['G'] * 1e-3:.3g} kPa, mu = {opt['mu']:.3g} Pa s", fontsize=10)
    return save(fig, path)


def _prior_band(result, names):
    """{name: (lo, hi)} 95 % prior band in SI units from ``details["parameter_space"]``."""
    ps = (result.details or {}).get("parameter_space") or {}
    m, C = ps.get("prior_internal_mean"), ps.get("prior_internal_cov")
    ls = ps.get("log_space") or {}
    out = {}
    try:
        for i, nm in enumerate(ps.get("names") or names):
            mu, sd = float(m[i]), math.sqrt(float(C[i][i]))
            lo, hi = mu - 1.96 * sd, mu + 1.96 * sd
            out[nm] = (math.exp(lo), math.exp(hi)) if ls.get(nm, True) else (lo, hi)
    except (TypeError, IndexError, ValueError):
        return {}
    return out


def barely_moved(result, names, threshold: float = 0.8) -> list:
    """Per window: True where the data barely moved the prior (the window posterior's sd is at least
    ``threshold`` of the prior's, in the internal coordinates, for some parameter)."""
    ps = (result.details or {}).get("parameter_space") or {}
    C = ps.get("prior_internal_cov")
    out = []
    for w in result.windows or []:
        cov = w.get("cov_internal")
        try:
            r = [math.sqrt(float(cov[i][i])) / math.sqrt(float(C[i][i])) for i in range(len(names))]
            out.append(max(r) >= threshold)
        except (TypeError, IndexError, ValueError, ZeroDivisionError):
            out.append(False)
    return out


def _merged_spans(spans) -> list:
    """Overlapping [a, b] spans merged (windows overlap by L - h samples)."""
    out = []
    for a, b in sorted((float(a), float(b)) for a, b in spans):
        if out and a <= out[-1][1]:
            out[-1][1] = max(out[-1][1], b)
        else:
            out.append([a, b])
    return out


def time_resolved_figure(result, path, obs=None):
    """Time-resolved G(t), mu(t): mean and 95 % band against t* (a µs axis on top when the time scale
    is known), the per-window estimates (mean ± 2 sd), the prior's 95 % band, prior-dominated windows
    hatched (``windows[].prior_dominated``; older results: windows the data barely moved); below, the wall strain rate |-2Ṙ/R| [1/s] of the fitted curves on a log
    axis, which maps every time to the rate the gel saw then."""
    names = list(result.param_names)
    tc = _time_scale(result, obs)
    fitted = np.asarray(result.fitted, dtype=float) if result.fitted is not None else None
    t_obs = getattr(obs, "t_star", None)
    if (
        t_obs is None
        and result.time_resolved
        and len(result.time_resolved) > 1
        and fitted is not None
        and fitted.ndim == 2
    ):  # the observation grid: the time-resolved points are its samples
        t0, t1 = result.time_resolved[0]["t_star"], result.time_resolved[1]["t_star"]
        t_obs = t0 + (t1 - t0) * np.arange(fitted.shape[1])
    show_rate = tc is not None and t_obs is not None and fitted is not None and fitted.ndim == 2
    heights = [1.0] * len(names) + ([0.7] if show_rate else [])
    fig = figure(8.0, 2.3 * sum(heights) + 0.9)
    axes = np.atleast_1d(fig.subplots(len(heights), 1, sharex=True, gridspec_kw={"height_ratios": heights}))
    tr = result.time_resolved
    t = np.array([x["t_star"] for x in tr])
    prior = _prior_band(result, names)
    windows = result.windows or []
    if windows and all("prior_dominated" in w for w in windows):
        from imrbayes.ensemble.windows import PRIOR_WEIGHT_LIMIT

        moved = [bool(w["prior_dominated"]) for w in windows]
        hatch_label = f"prior-dominated window (prior weight > {PRIOR_WEIGHT_LIMIT:.0%})"
    else:  # results written before windows reported their prior weight
        moved, hatch_label = barely_moved(result, names), "data barely moved the prior"
    for ax, nm in zip(axes, names):
        sc, lab = scale(nm), label(nm)
        if nm in prior:
            ax.axhspan(prior[nm][0] * sc, prior[nm][1] * sc, color="0.85", alpha=0.6, zorder=0, lw=0, label="prior 95%")
        for k, (a, b) in enumerate(
            _merged_spans([w["t_star"] for w, little in zip(result.windows or [], moved) if little])
        ):
            ax.axvspan(
                a,
                b,
                facecolor="none",
                edgecolor="0.7",
                hatch="//",
                lw=0,
                zorder=0,
                label=hatch_label if k == 0 else None,
            )
        m = np.array([x[nm]["mean"] for x in tr]) * sc
        lo = np.array([x[nm]["hdi95"][0] for x in tr]) * sc
        hi = np.array([x[nm]["hdi95"][1] for x in tr]) * sc
        ax.fill_between(t, lo, hi, color="tab:blue", alpha=0.25, label="95% HDI (time-resolved)")
        ax.plot(t, m, color="tab:blue", lw=1.5, label="time-resolved mean")
        for i, w in enumerate(result.windows):
            a, b = w["t_star"]
            ax.plot(
                [a, b],
                [w[nm]["mean"] * sc] * 2,
                color="tab:orange",
                lw=0.8,
                alpha=0.7,
                label="per-window mean ± 2 sd" if i == 0 else None,
            )
            ax.errorbar(
                0.5 * (a + b),
                w[nm]["mean"] * sc,
                yerr=2 * w[nm]["sd"] * sc,
                fmt="none",
                ecolor="tab:orange",
                alpha=0.5,
                lw=0.8,
            )
        ax.set_ylabel(lab)
        ax.grid(alpha=0.3)
    if tc is not None:
        from imrbayes.plotting import time_axis_us

        time_axis_us(axes[0], float(np.mean(tc)), "t [µs] (mean time scale of the experiments)")
    if show_rate:
        ax = axes[-1]
        dt = np.gradient(np.asarray(t_obs, dtype=float))
        for e in range(fitted.shape[0]):
            R = fitted[e]
            rate = np.abs(-2.0 * np.gradient(R) / dt / R) / float(tc[e] if e < tc.size else tc.mean())
            ax.plot(t_obs, np.where(np.isfinite(rate) & (rate > 0), rate, np.nan), lw=0.8, color="0.3", alpha=0.7)
        ax.set_yscale("log")
        ax.set_ylim(1e2, 1e9)
        ax.set_ylabel(r"$|-2\dot R/R|$ [1/s]", fontsize=8)
        ax.grid(alpha=0.3, which="both")
        ax.text(0.01, 0.92, "wall strain rate of the fitted curves", transform=ax.transAxes, fontsize=7, va="top")
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=3, fontsize=7, frameon=False)
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
