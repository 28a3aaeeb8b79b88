"""Figures of a diagnosis (:mod:`imrbayes.plotting`: object API, Agg canvas): residuals by phase,
bootstrap check, candidates."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from imrbayes.diagnosis.candidates import BASELINE, spec_of
from imrbayes.plotting import figure, save

__all__ = ["write_figures"]


def residuals_figure(d, path):
    obs, ph = d.obs, d.phases
    t = obs.t_star
    fig = figure(8, 6, layout=None)
    ax = fig.subplots(2, 1, sharex=True)
    for i in range(obs.n_exp):
        ax[0].plot(t, obs.R_star[i], ".", ms=2, color=f"C{i % 10}")
        ax[0].plot(t, d.curves[BASELINE.key][i], "-", lw=1, color=f"C{i % 10}")
        ax[1].plot(t[1:], (obs.R_star[i, 1:] - d.curves[BASELINE.key][i, 1:]) / np.sqrt(obs.P[1:]), "-", lw=0.7,
                   color=f"C{i % 10}")
    for b in ph.bounds[1:-1]:
        for a in ax:
            a.axvline(t[b], color="0.6", ls=":")
    ax[0].set_ylabel(f"R* (dots: data, lines: {BASELINE.model} fit)")
    ax[1].set_ylabel("(y - fit) / sqrt(P_k)")
    ax[1].set_xlabel("t*")
    ax[1].axhline(0, color="k", lw=0.5)
    for info, a, b in zip(d.result["baseline"]["misfit_by_phase"], ph.bounds[:-1], ph.bounds[1:]):
        ax[1].text(0.5 * (t[a] + t[b]), ax[1].get_ylim()[1] * 0.85, f"{info['phase']}\nrmse {info['rmse']:.3f}\n"
                   f"chi2 {info['chi2_norm']:.2f}", ha="center", va="top", fontsize=7)
    fig.tight_layout()
    save(fig, path)


def check_figure(d, path):
    ev = d.result["constant_parameter_check"]["evidence"]
    st = ev["statistics"]
    mw = ev.get("mienks_windows") or {}
    n_extra = 2 if mw.get("t_star_windows") else 1
    fig = figure(3.2 * (len(st) + n_extra), 3.2, layout=None)
    ax = fig.subplots(1, len(st) + n_extra)
    for a, (k, v) in zip(ax, st.items()):
        b = np.asarray(v["bootstrap"], dtype=float)
        a.hist(b[np.isfinite(b)], bins=12, color="0.7")
        a.axvline(v["observed"], color="C3", lw=2)
        a.set_title(f"{k}: p = {v['p_value']:.3f}", fontsize=9)
    if n_extra == 2:
        a = ax[-2]
        tw = mw["t_star_windows"]
        a.plot(tw, mw["G_windows"], "o-", color="C0", ms=3)
        a.set_ylabel("G [Pa]", color="C0")
        a2 = a.twinx()
        a2.plot(tw, mw["mu_windows"], "s-", color="C1", ms=3)
        a2.set_ylabel("mu [Pa s]", color="C1")
        a.set_xlabel("window centre t*")
        a.set_title("MIEnKS-MDA G(t), mu(t)", fontsize=9)
    we = ev["window_estimates"]
    names = list(we)
    for j, p in enumerate(("G", "mu")):
        vals = [we[n][p]["median"] for n in names]
        sds = [we[n][p]["sd_log"] for n in names]
        x = np.arange(len(names)) + 0.1 * j
        a = ax[-1] if j == 0 else ax[-1].twinx()
        a.errorbar(x, vals, yerr=[np.array(vals) * (1 - np.exp(-np.array(sds))),
                                  np.array(vals) * (np.exp(np.array(sds)) - 1)], fmt="o", color=f"C{j}", label=p)
        a.set_ylabel(f"{p} [{'Pa' if p == 'G' else 'Pa s'}]", color=f"C{j}")
    ax[-1].set_xticks(np.arange(len(names)))
    ax[-1].set_xticklabels(names, fontsize=7)
    ax[-1].set_title(f"window estimates ({BASELINE.model})", fontsize=9)
    fig.suptitle(f"constant-parameter check: {d.result['constant_parameter_check']['verdict']} "
                 f"(p = {ev['p_value']:.3f})", fontsize=10)
    fig.tight_layout()
    save(fig, path)


def candidates_figure(d, path):
    obs = d.obs
    t = obs.t_star
    keys = list(d.curves)
    fig = figure(12, 4, layout=None)
    ax = fig.subplots(1, 2)
    for j, k in enumerate(keys):
        r = np.sqrt(np.nanmean((obs.R_star - d.curves[k]) ** 2, axis=0))
        ax[0].plot(t[1:], r[1:], label=spec_of(k).model, color=f"C{j}", lw=1.8 if k == BASELINE.key else 1.0)
    ax[0].set_xlabel("t*")
    ax[0].set_ylabel("RMSE over experiments (whole-record fit)")
    ax[0].legend(fontsize=8)
    cands = d.result["candidates"]
    names = [c["model"] for c in cands]
    y = np.arange(len(cands))
    for s_i, sch in enumerate(("forecast", "loeo")):
        vals = [c["relative_reduction"].get(sch, np.nan) for c in cands]
        ax[1].barh(y + 0.35 * s_i, vals, height=0.35, label=f"{sch}: relative held-out RMSE reduction")
    ax[1].set_yticks(y + 0.17)
    ax[1].set_yticklabels(names)
    ax[1].axvline(0, color="k", lw=0.5)
    ax[1].legend(fontsize=7)
    ax[1].set_title(f"cause: {d.result['cause']}", fontsize=10)
    fig.tight_layout()
    save(fig, path)


def write_figures(d, fdir) -> list:
    """``residuals.png``, ``check.png`` and ``candidates.png`` under ``fdir`` (created); returns their paths."""
    fdir = Path(fdir)
    out = []
    for name, fn in (("residuals.png", residuals_figure), ("check.png", check_figure),
                     ("candidates.png", candidates_figure)):
        fn(d, fdir / name)
        out.append(fdir / name)
    return out
