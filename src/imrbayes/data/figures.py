"""Figure of a preprocessed dataset (``imrbayes inspect``): raw R(t) and resampled R*(t*) with P_k.

Uses :mod:`imrbayes.plotting` (matplotlib's object API with the Agg canvas; no pyplot).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from imrbayes.data.pipeline import Preprocessed
from imrbayes.plotting import figure, label, save

__all__ = ["radius_figure"]


def radius_figure(pre: Preprocessed, path, title: str | None = None) -> Path:
    """Write a two-panel PNG to ``path`` and return it.

    Left: raw radius [µm] against time from the refined maximum [µs], collapse marked. Right:
    resampled R* against t*, each experiment thin, the mean thick, mean ± sqrt(P_k) shaded.
    """
    import matplotlib

    fig = figure(11.0, 4.2)
    ax1, ax2 = fig.subplots(1, 2)
    n = len(pre.experiments)
    cmap = matplotlib.colormaps["viridis"]
    colors = [cmap(x) for x in np.linspace(0.0, 0.9, max(n, 1))]
    exps = {e.name: e for e in pre.dataset.experiments}
    for i, s in enumerate(pre.experiments):
        e = exps[s.name]
        t_us = (e.t_s - s.t0_s) * 1e6
        ax1.plot(t_us, e.R_m * 1e6, ".-", ms=2.5, lw=0.7, color=colors[i], label=s.name if n <= 10 else None)
        ax1.plot([s.t_collapse_s * 1e6], [s.r_collapse_star * s.rmax_m * 1e6], "v", ms=4, color=colors[i])
        ax2.plot(pre.t_star, pre.R_star[i], lw=0.6, color=colors[i], alpha=0.8)
    mean = pre.R_star.mean(axis=0)
    sd = np.sqrt(pre.P)
    ax2.fill_between(
        pre.t_star, mean - sd, mean + sd, color="tab:orange", alpha=0.45, label=r"mean $\pm\sqrt{P_k}$", zorder=3
    )
    ax2.plot(pre.t_star, mean, color="k", lw=1.4, label="mean", zorder=4)
    ax1.set_xlabel("time from maximum t [µs]")
    ax1.set_ylabel("radius R [µm]")
    ax1.set_title("measured (▼ first collapse)")
    ax2.set_xlabel(r"$t^* = t\,\sqrt{p_\infty/\rho}\,/\,R_{max}$")
    ax2.set_ylabel(label("R_star"))
    ax2.set_title(
        f"resampled, dt* = {pre.choices['dt_star']:g}, {pre.n_steps} steps (P_k: {pre.choices['noise']['method']})",
        fontsize=9,
    )
    ax2.legend(loc="upper right", fontsize=8)
    if n <= 10:
        ax1.legend(loc="upper right", fontsize=7)
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
    fig.suptitle(title or f"{pre.dataset.name}: {n} experiment(s)", fontsize=11)
    return save(fig, path, dpi=120)
