"""Figures of the ensemble-vs-MCMC comparison (:mod:`imrbayes.plotting`: object API, Agg canvas).

* :func:`forest_figure` -- per parameter, every window's ensemble Gaussian and MCMC posterior
  (median and 95 % interval, SI units) against the window's time span;
* :func:`divergence_figure` -- KL (Gaussian, symmetrised, and sample-based) and W2 per window
  against t*, with the agreement thresholds, under the measured R*(t*);
* :func:`pair_figure` -- one window: MCMC draws in kPa and Pa s (log axes) with the ensemble
  Gaussian's and the MCMC Gaussian's 1- and 2-sd ellipses, and both marginals; where the window has
  its exact grid posterior (``entry["quadrature"]``), its 95 % highest-density region and marginal
  95 % intervals in green (the forest plot shows its 95 % intervals too).

Inputs are ``compare.json`` window entries (:func:`imrbayes.mcmc.compare.compare_window`) and, for
the MCMC quantiles and draws, the ``mcmc.nc`` tree (:func:`imrbayes.mcmc.windows.mcmc_tree`) or a
window's own tree.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scipy import stats

from imrbayes.plotting import figure, label, plain_log_axis, save, scale

__all__ = ["forest_figure", "divergence_figure", "pair_figure", "comparison_figures"]

_ENS, _MC, _QD = "tab:blue", "tab:red", "tab:green"


def _window_node(tree, index):
    if tree is None:
        return None
    key = f"window_{int(index):02d}"
    return tree[key] if key in tree.children else (tree if "posterior" in tree.children else None)


def _mcmc_draws(node, var):
    return np.asarray(node["posterior"][var].values, float).ravel()


def forest_figure(entries, path, tree=None, prob: float = 0.95):
    """Per parameter: ensemble (blue) and MCMC (red) median and ``prob`` interval of every window,
    plotted against the window's time span (a horizontal bar marks [t_start, t_end])."""
    entries = list(entries)
    names = entries[0]["parameters"]
    fig = figure(4.2 * len(names), 3.6)
    axes = np.atleast_1d(fig.subplots(1, len(names), squeeze=False)).ravel()
    q = stats.norm.ppf(0.5 + prob / 2)
    for ax, name in zip(axes, names):
        sc, lab = scale(name), label(name)
        i = names.index(name)
        iname = entries[0]["internal"][i]
        log = iname != name
        for k, e in enumerate(entries):
            ts = e["t_star"] or [e["index"], e["index"] + 1]
            tc = 0.5 * (ts[0] + ts[1])
            m, s = e["ensemble"]["mean_internal"][iname], e["ensemble"]["sd_internal"][iname]
            lo, med, hi = m - q * s, m, m + q * s
            if log:
                lo, med, hi = math.exp(lo), math.exp(med), math.exp(hi)
            dx = 0.006 * (entries[-1]["t_star"][1] if entries[-1]["t_star"] else len(entries))
            ax.plot([tc - dx] * 2, [lo * sc, hi * sc], color=_ENS, lw=2, alpha=0.8)
            ax.plot(tc - dx, med * sc, "o", color=_ENS, ms=4, label="ensemble" if k == 0 else None)
            node = _window_node(tree, e["index"])
            if node is not None:
                x = _mcmc_draws(node, name)
                lo, med, hi = np.quantile(x, [0.5 - prob / 2, 0.5, 0.5 + prob / 2])
            else:
                m, s = e["mcmc"]["mean_internal"][iname], e["mcmc"]["sd_internal"][iname]
                lo, med, hi = np.exp([m - q * s, m, m + q * s]) if log else (m - q * s, m, m + q * s)
            ax.plot([tc + dx] * 2, [lo * sc, hi * sc], color=_MC, lw=2, alpha=0.8)
            ax.plot(tc + dx, med * sc, "s", color=_MC, ms=4, label="MCMC" if k == 0 else None)
            qi = (e.get("quadrature") or {}).get("eti95", {}).get(name)
            if qi is not None and prob == 0.95:
                ax.plot(
                    [tc] * 2,
                    [qi[0] * sc, qi[1] * sc],
                    color=_QD,
                    lw=1.2,
                    alpha=0.9,
                    label="quadrature (exact)"
                    if not any((x.get("quadrature") or {}).get("eti95") for x in entries[:k])
                    else None,
                )
            ax.plot(ts, [med * sc] * 2, color=_MC, lw=0.6, alpha=0.4)
            if e.get("agree") is False:
                ax.plot(tc, hi * sc, "v", color="k", ms=4)
        ax.set_xlabel("t* (window)")
        ax.set_ylabel(lab)
        if log:
            ax.set_yscale("log")
            plain_log_axis(ax, "y")
        ax.grid(alpha=0.3)
    axes[0].legend(
        fontsize=8, title=f"median, {int(prob * 100)}% interval ($\\blacktriangledown$: disagree)", title_fontsize=7
    )
    return save(fig, path)


def divergence_figure(entries, path, t_star=None, R_star=None):
    """KL and W2 per window against t* (each window drawn over its span, a dot at its centre),
    threshold lines dashed; the measured R*(t*) (every experiment, grey) on top when given."""
    from imrbayes.mcmc.compare import THRESHOLDS

    entries = list(entries)
    top = t_star is not None and R_star is not None
    fig = figure(7.0, 6.2 if top else 4.4)
    axes = fig.subplots(3 if top else 2, 1, sharex=True)
    if top:
        ax = axes[0]
        for r in np.atleast_2d(R_star):
            ax.plot(t_star, r, "-", lw=0.7, color="0.5", alpha=0.6)
        ax.set_ylabel("R*")
        ax.grid(alpha=0.3)
        axes = axes[1:]
    spans = [e["t_star"] or [e["index"], e["index"] + 1] for e in entries]
    tc = [0.5 * (a + b) for a, b in spans]
    for key, col, lab in (("kl_sym", "tab:purple", "Gaussian KL (symm.)"), ("kl_sample", "tab:orange", "sample KL")):
        v = [e[key] for e in entries]
        axes[0].plot(tc, v, "o-", color=col, ms=3.5, lw=1, label=lab)
    axes[0].axhline(THRESHOLDS["kl_sym"], ls="--", color="k", lw=0.8)
    axes[0].set_ylabel("KL [nats]")
    axes[0].set_yscale("symlog", linthresh=1e-2)
    top_kl = max(
        [THRESHOLDS["kl_sym"]]
        + [float(e[k]) for e in entries for k in ("kl_sym", "kl_sample") if e.get(k) is not None and np.isfinite(e[k])]
    )
    axes[0].set_ylim(0.0, 2.0 * top_kl)  # KL >= 0: no negative half of the symlog axis
    axes[0].legend(fontsize=8)
    w2 = [e["w2"] for e in entries]
    axes[1].plot(tc, w2, "o-", color="tab:green", ms=3.5, lw=1)
    for (a, b), v in zip(spans, w2):
        axes[1].plot([a, b], [v, v], color="tab:green", lw=0.5, alpha=0.4)
    axes[1].axhline(THRESHOLDS["w2"], ls="--", color="k", lw=0.8)
    axes[1].set_ylabel("W2 [posterior sd]")
    for ax in axes:
        ax.grid(alpha=0.3)
        for e, t in zip(entries, tc):
            if e.get("agree") is None:
                ax.axvline(t, color="0.8", lw=4, zorder=0)
            elif e.get("agree") is False:
                ax.axvline(t, color="tab:red", lw=4, alpha=0.25, zorder=0)
    if top:
        for e, (a, b) in zip(entries, spans):
            if e.get("agree") is False:
                fig.axes[0].axvspan(a, b, color="tab:red", alpha=0.08, lw=0)
    axes[-1].set_xlabel("t* (window centre; red: ensemble and MCMC disagree; grey: MCMC undecided)")
    return save(fig, path)


def pair_figure(entry, node, path, max_points: int = 3000):
    """One window: MCMC draws in physical units (G [kPa], mu [Pa s]; log axes for the log-normal
    parameters, which the sampler works in) with the 1- and 2-sd ellipses of the ensemble Gaussian
    (blue) and of the MCMC draws' Gaussian (red, dashed); marginals on the diagonal."""
    names = entry["internal"]
    params = entry.get("parameters") or names
    d = len(names)
    logs = [iv != pv for iv, pv in zip(names, params)]
    scs = [scale(pv) for pv in params]

    def phys(k, v):  # internal coordinate k -> display unit
        v = np.asarray(v, dtype=float)
        return (np.exp(v) if logs[k] else v) * scs[k]

    x = np.stack([_mcmc_draws(node, v) for v in names], axis=1)
    if x.shape[0] > max_points:
        x = x[np.linspace(0, x.shape[0] - 1, max_points).round().astype(int)]
    mE = np.array([entry["ensemble"]["mean_internal"][v] for v in names])
    SE = np.asarray(entry["ensemble"]["cov_internal"], float)
    mM = np.array([entry["mcmc"]["mean_internal"][v] for v in names])
    SM = np.asarray(entry["mcmc"]["cov_internal"], float)
    quad = (
        entry.get("quadrature")
        if isinstance(entry.get("quadrature"), dict) and "mean_internal" in entry.get("quadrature", {})
        else None
    )
    fig = figure(2.7 * d + 0.6, 2.7 * d + 0.5)
    axes = fig.subplots(d, d, squeeze=False)
    for i in range(d):
        for j in range(d):
            ax = axes[i, j]
            if j > i:
                ax.set_visible(False)
                continue
            if i == j:
                dens, edges = np.histogram(x[:, i], bins=40, density=True)
                ax.stairs(dens, phys(i, edges), fill=True, color=_MC, alpha=0.35)
                g = np.linspace(
                    min(x[:, i].min(), mE[i] - 3 * math.sqrt(SE[i, i])),
                    max(x[:, i].max(), mE[i] + 3 * math.sqrt(SE[i, i])),
                    200,
                )
                ax.plot(phys(i, g), stats.norm.pdf(g, mE[i], math.sqrt(SE[i, i])), color=_ENS, lw=1.5)
                ax.plot(phys(i, g), stats.norm.pdf(g, mM[i], math.sqrt(SM[i, i])), color=_MC, lw=1, ls="--")
                if quad is not None:
                    for v in quad.get("eti95_internal", {}).get(names[i], []):
                        ax.axvline(phys(i, np.asarray(v, float)), color=_QD, lw=1, ls=":")
                ax.set_yticks([])
                if logs[i]:
                    ax.set_xscale("log")
                    plain_log_axis(ax, "x")
            else:
                ax.plot(phys(j, x[:, j]), phys(i, x[:, i]), ".", ms=1.2, color=_MC, alpha=0.25, rasterized=True)
                for k in (1, 2):
                    for m_, S_, kw in (
                        (mE, SE, {"color": _ENS, "lw": 1.4}),
                        (mM, SM, {"color": _MC, "lw": 1, "ls": "--"}),
                    ):
                        pts = _ellipse_points(m_[[j, i]], S_[np.ix_([j, i], [j, i])], k)
                        ax.plot(phys(j, pts[0]), phys(i, pts[1]), **kw)
                if quad is not None and d == 2:
                    for line in (quad.get("hdr95") or {}).get("contour_internal", []):
                        line = np.asarray(line, float)
                        ax.plot(phys(j, line[:, j]), phys(i, line[:, i]), color=_QD, lw=1.3)
                if logs[j]:
                    ax.set_xscale("log")
                    plain_log_axis(ax, "x")
                if logs[i]:
                    ax.set_yscale("log")
                    plain_log_axis(ax, "y")
            if i == d - 1:
                ax.set_xlabel(label(params[j]))
            if j == 0 and i > 0:
                ax.set_ylabel(label(params[i]))
            ax.grid(alpha=0.25)
    ts = entry.get("t_star")
    span = f", t* {ts[0]:.3g}-{ts[1]:.3g}" if ts else ""
    verdict = {True: "agree", False: "disagree", None: "undecided"}[entry.get("agree")]
    fig.suptitle(
        f"window {entry['index']}{span}: {verdict} (KL {entry['kl_sym']:.2g}, sample KL "
        f"{entry['kl_sample']:.2g}, W2 {entry['w2']:.2g} sd)\nblue: ensemble Gaussian; red: MCMC"
        + ("; green: quadrature 95 % region (exact)" if quad is not None else ""),
        fontsize=8,
    )
    return save(fig, path)


def _ellipse_points(m, S, k):
    lam, V = np.linalg.eigh(0.5 * (S + S.T))
    a = np.linspace(0, 2 * np.pi, 120)
    return m[:, None] + V @ (np.sqrt(np.maximum(lam, 0))[:, None] * k * np.vstack([np.cos(a), np.sin(a)]))


def comparison_figures(compare: dict, out_dir, tree=None, t_star=None, R_star=None, pairs="worst") -> list:
    """The standard set under ``out_dir``: ``mcmc_forest.png``, ``mcmc_divergence.png`` and pair plots
    (``pairs``: ``"worst"`` -- the window with the largest sample KL --, ``"all"`` or a list of indices)."""
    out_dir = Path(out_dir)
    entries = compare["windows"]
    paths = [
        forest_figure(entries, out_dir / "mcmc_forest.png", tree),
        divergence_figure(entries, out_dir / "mcmc_divergence.png", t_star, R_star),
    ]
    if tree is not None and entries:
        if pairs == "worst":
            pick = [max(entries, key=lambda e: e["kl_sample"])["index"]]
        elif pairs == "all":
            pick = [e["index"] for e in entries]
        else:
            pick = list(pairs)
        for e in entries:
            node = _window_node(tree, e["index"])
            if e["index"] in pick and node is not None:
                paths.append(pair_figure(e, node, out_dir / f"mcmc_pair_window_{e['index']:02d}.png"))
    return [str(p) for p in paths]
