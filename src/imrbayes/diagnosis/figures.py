"""Figures of a diagnosis (:mod:`imrbayes.plotting`: object API, Agg canvas): residuals by phase,
bootstrap check, candidates, and -- when the result carries them -- the absorption matrix and the
G(t), mu(t) signature of the candidates.

Every figure is sized for a report column of ~1000 px (:data:`WIDTH` inches at
:data:`imrbayes.plotting.DPI`): panels sit in a grid of at most two columns (no 1 x N strips), every
axis says its quantity and unit, every panel title says what it shows."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

from imrbayes.plotting import figure, save

__all__ = [
    "write_figures",
    "residuals_figure",
    "check_figure",
    "candidates_figure",
    "absorption_figure",
    "signature_figure",
    "WIDTH",
    "STAT_LABELS",
]

WIDTH = 9.0
"""Width [in] of every diagnosis figure (990 px at 110 dpi; two columns of ~450 px panels)."""

#: statistic of the constant-parameter check -> (axis label, what it measures)
STAT_LABELS = {
    "drift": ("window drift [-]", "largest squared Mahalanobis distance of (log G, log mu) between window fits"),
    "misfit": (r"whole-record $\chi^2/n$ [-]", "normalised chi-square of the whole record"),
    "phase_misfit": (r"worst-phase $\chi^2/n$ [-]", "largest normalised chi-square of one phase"),
    "mienks_drift": (r"MIEnKS drift $\Sigma$(slope/SE)$^2$ [-]", "slopes of MIEnKS window log G, log mu vs t*"),
}
_PARAM_AXIS = {"G": (1e-3, "G [kPa]"), "mu": (1.0, "mu [Pa s]")}


def _baseline_key(result) -> str:
    b = result.get("baseline", {})
    return b.get("key") or b.get("model") or "nhkv"


def _labels(result) -> dict:
    """key -> name shown in figures: the baseline's model, and each candidate's key with its model
    beside it where the two differ (damage is fitted as ``nhkv-piecewise``: the key is what the
    report's verdict names)."""
    out = {_baseline_key(result): result.get("baseline", {}).get("model", _baseline_key(result))}
    for c in result.get("candidates", []):
        key, model = c.get("key", c.get("model")), c.get("model", c.get("key"))
        out[key] = key if model == key else f"{key} ({model})"
    return out


def _grid(n: int, row_height: float = 3.3, ncols: int = 2):
    """A figure of ``n`` panels in rows of ``ncols`` (unused cells removed); (fig, flat axes)."""
    ncols = max(1, min(ncols, n))
    nrows = math.ceil(n / ncols)
    fig = figure(WIDTH, row_height * nrows + 0.5)
    ax = np.atleast_1d(fig.subplots(nrows, ncols, squeeze=False).ravel())
    for a in ax[n:]:
        a.remove()
    return fig, ax[:n]


def residuals_figure(d, path):
    obs, ph = d.obs, d.phases
    t = obs.t_star
    r = d.result
    bkey = _baseline_key(r)
    model = r["baseline"].get("model", bkey)
    fig = figure(WIDTH, 6.8)
    ax = fig.subplots(2, 1, sharex=True)
    for i in range(obs.n_exp):
        ax[0].plot(t, obs.R_star[i], ".", ms=2.5, color=f"C{i % 10}")
        ax[0].plot(t, d.curves[bkey][i], "-", lw=1, color=f"C{i % 10}", label=f"exp {i + 1}")
        ax[1].plot(
            t[1:], (obs.R_star[i, 1:] - d.curves[bkey][i, 1:]) / np.sqrt(obs.P[1:]), "-", lw=0.7, color=f"C{i % 10}"
        )
    for b in ph.bounds[1:-1]:
        for a in ax:
            a.axvline(t[b], color="0.5", ls=":")
    ax[0].set_ylabel(r"$R^* = R/R_{max}$ [-]")
    ax[0].set_title(f"data (dots) and whole-record {model} fit (lines); dotted: phase boundaries", fontsize=10)
    if obs.n_exp <= 10:
        ax[0].legend(fontsize=8, ncol=min(obs.n_exp, 5), loc="upper right")
    ax[1].set_ylabel(r"$(y - \mathrm{fit})/\sqrt{P_k}$ [noise sd]")
    ax[1].set_xlabel(r"$t^*$ [-]")
    ax[1].set_title(r"normalised residuals by phase ($\chi^2/n \approx 1$: fit at the noise level)", fontsize=10)
    ax[1].axhline(0, color="k", lw=0.5)
    top = ax[1].get_ylim()[1]
    for info, a, b in zip(r["baseline"]["misfit_by_phase"], ph.bounds[:-1], ph.bounds[1:]):
        ax[1].text(
            0.5 * (t[a] + t[b - 1]),
            top * 0.95,
            f"{info['phase']}\nRMSE {info['rmse']:.3f}\n"
            rf"$\chi^2/n$ {info['chi2_norm']:.2f}",
            ha="center",
            va="top",
            fontsize=8,
            bbox={"fc": "white", "ec": "none", "alpha": 0.7},
        )
    save(fig, path)


def check_figure(d, path):
    chk = d.result["constant_parameter_check"]
    ev = chk["evidence"]
    st = ev["statistics"]
    mw = ev.get("mienks_windows") or {}
    we = ev.get("window_estimates") or {}
    extra = [p for p, ok in (("mienks", bool(mw.get("t_star_windows"))), ("windows", bool(we))) if ok]
    fig, ax = _grid(len(st) + len(extra), row_height=3.2)
    for a, (k, v) in zip(ax, st.items()):
        b = np.asarray(v.get("bootstrap") or [], dtype=float)
        b = b[np.isfinite(b)]
        nb = max(5, min(20, len(b) // 2 or 1))
        o = v.get("observed")
        # data tens to thousands of times the replicates' values (real records): on a linear axis the
        # replicates' bars are thinner than a pixel, so the axis becomes logarithmic
        far = o is not None and b.size and np.all(b > 0) and np.isfinite(o) and float(o) > 10.0 * float(b.max())
        if far:
            a.set_xscale("log")
            nb = np.geomspace(b.min() / 1.2, b.max() * 1.2, nb + 1)
        a.hist(b, bins=nb, color="0.7", label=f"bootstrap (B = {len(b)})")
        if v.get("observed") is not None:
            a.axvline(v["observed"], color="C3", lw=2, label="observed")
        xl, what = STAT_LABELS.get(k, (f"{k} [-]", k))
        a.set_xlabel(xl + (" (log axis)" if far else ""))
        a.set_ylabel("replicates [count]")
        z = ((ev.get("sequential") or {}).get("z_first_batch") or {}).get(k)
        a.set_title(
            f"{k}: observed vs bootstrap, p = {float(v.get('p_value', np.nan)):.3f}"
            + (
                f"\n{z:.3g} sd of the first replicates beyond their mean"
                if z is not None and np.isfinite(z) and z > 3
                else ""
            ),
            fontsize=10,
        )
        a.legend(fontsize=7, loc="best")
    rest = list(ax[len(st) :])
    if "mienks" in extra:
        a = rest.pop(0)
        tw = mw["t_star_windows"]
        a.plot(tw, np.asarray(mw["G_windows"], float) * 1e-3, "o-", color="C0", ms=3)
        a.set_ylabel("G [kPa]", color="C0")
        a2 = a.twinx()
        a2.plot(tw, mw["mu_windows"], "s-", color="C1", ms=3)
        a2.set_ylabel("mu [Pa s]", color="C1")
        a.set_xlabel(r"window centre $t^*$ [-]")
        a.set_title("MIEnKS-MDA window means G(t) (o), mu(t) (s)", fontsize=10)
    if "windows" in extra:
        a = rest.pop(0)
        names = list(we)
        x = np.arange(len(names))
        axes = (a, a.twinx())
        for j, p in enumerate(("G", "mu")):
            f, lab = _PARAM_AXIS[p]
            vals = np.array([we[n][p]["median"] for n in names], float) * f
            sds = np.array([we[n][p]["sd_log"] for n in names], float)
            axes[j].errorbar(
                x + 0.12 * (2 * j - 1),
                vals,
                yerr=[vals * (1 - np.exp(-sds)), vals * (np.exp(sds) - 1)],
                fmt="os"[j],
                color=f"C{j}",
                ms=4,
                capsize=2,
            )
            axes[j].set_ylabel(lab, color=f"C{j}")
        a.set_xticks(x)
        a.set_xticklabels([f"{n}\n(t* ≤ {we[n].get('t_star_end', float('nan')):.2f})" for n in names], fontsize=8)
        a.set_xlabel("fitted window")
        a.set_title(f"{d.result['baseline'].get('model', 'baseline')} fit per window (±1 sd)", fontsize=10)
    from imrbayes.diagnosis.check import p_value_text

    pv = (
        f"combined bootstrap p = {ev['p_value']:.3f}, B = {ev.get('n_bootstrap', '?')}"
        if ev.get("p_value_kind") != "bound"
        else p_value_text(ev)
    )
    fig.suptitle(f"constant-parameter check: {chk['verdict']} ({pv})", fontsize=11)
    save(fig, path)


def candidates_figure(d, path):
    obs = d.obs
    t = obs.t_star
    r = d.result
    names = _labels(r)
    bkey = _baseline_key(r)
    fig = figure(WIDTH, 4.6)
    ax = fig.subplots(1, 2, width_ratios=[1.1, 1])
    for j, k in enumerate(d.curves):
        rm = np.sqrt(np.nanmean((obs.R_star - d.curves[k]) ** 2, axis=0))
        ax[0].plot(t[1:], rm[1:], label=names.get(k, k), color=f"C{j}", lw=2.0 if k == bkey else 1.0)
    ax[0].set_xlabel(r"$t^*$ [-]")
    ax[0].set_ylabel(r"RMSE over experiments [$R^*$]")
    ax[0].set_title("misfit of each whole-record fit along t*", fontsize=10)
    ax[0].legend(fontsize=8)
    cands = r["candidates"]
    schemes = sorted({s for c in cands for s in c.get("relative_reduction", {})}, key=lambda s: (s != "forecast", s))
    y = np.arange(len(cands))
    h = 0.8 / max(1, len(schemes))
    for s_i, sch in enumerate(schemes):
        vals = np.array([c["relative_reduction"].get(sch, np.nan) for c in cands], float) * 100
        ax[1].barh(y + h * s_i, vals, height=h, color=f"C{s_i}", label=sch)
        for yi, v in zip(y + h * s_i, vals):
            if np.isfinite(v):
                ax[1].annotate(
                    f"{v:+.1f} %",
                    (v, yi),
                    xytext=(3 if v >= 0 else -3, 0),
                    textcoords="offset points",
                    ha="left" if v >= 0 else "right",
                    va="center",
                    fontsize=8,
                )
    allv = np.array([c["relative_reduction"].get(sch, np.nan) for c in cands for sch in schemes], float) * 100
    allv = allv[np.isfinite(allv)]
    if allv.size:  # room for the value labels at both bar ends
        lo, hi = min(0.0, allv.min()), max(0.0, allv.max())
        span = (hi - lo) or 1.0
        ax[1].set_xlim(lo - 0.3 * span * (lo < 0), hi + 0.3 * span * (hi > 0) + 0.05 * span)
    ax[1].set_yticks(y + h * (len(schemes) - 1) / 2)
    ax[1].set_yticklabels(
        [
            names.get(c.get("key", c["model"]), c["model"]) + ("\n(ruled out)" if c.get("ruled_out") else "")
            for c in cands
        ],
        fontsize=8,
    )
    ax[1].invert_yaxis()
    ax[1].axvline(0, color="k", lw=0.6)
    ax[1].set_xlabel("held-out RMSE reduction vs baseline [%]")
    ax[1].set_title("gain on unseen data (> 0: better)", fontsize=10)
    fig.suptitle(f"candidates against the {names.get(bkey, bkey)} baseline (cause: {r['cause']})", fontsize=11)
    if schemes:
        ax[1].legend(fontsize=8, title="held-out scheme", title_fontsize=8, loc="best")
    save(fig, path)


def absorption_figure(result, path):
    """Heat map of ``result["absorption"]``: row A = data simulated with A's fit, column B = refit
    with B; cell = residual RMS / noise sd (~1: B absorbs A's effect)."""
    ab = result["absorption"]
    keys = list(ab["keys"])
    m = np.asarray(ab["matrix"], dtype=float)
    n = len(keys)
    side = min(WIDTH, 4.0 + 0.7 * n)
    fig = figure(side + 1.2, side)
    a = fig.subplots()
    im = a.imshow(m, cmap="viridis", vmin=min(1.0, np.nanmin(m)) if np.isfinite(m).any() else None)
    cb = fig.colorbar(im, ax=a, shrink=0.85)
    cb.set_label("residual RMS / noise sd [-]")
    hi = np.nanmax(m) if np.isfinite(m).any() else 1.0
    lo = np.nanmin(m) if np.isfinite(m).any() else 0.0
    for i in range(n):
        for j in range(n):
            v = m[i, j]
            light = np.isfinite(v) and (v - lo) > 0.6 * (hi - lo)
            a.text(
                j,
                i,
                "–" if not np.isfinite(v) else f"{v:.2f}",
                ha="center",
                va="center",
                fontsize=10,
                color="k" if light else "w",
            )
    names = _labels(result)
    a.set_xticks(range(n))
    a.set_xticklabels([names.get(k, k) for k in keys], rotation=30, ha="right")
    a.set_yticks(range(n))
    a.set_yticklabels([names.get(k, k) for k in keys])
    a.set_xlabel("refit with candidate B")
    a.set_ylabel("data simulated with candidate A")
    a.set_title("can B absorb A's effect? (≈ 1: yes, to within the noise)", fontsize=10)
    save(fig, path)


def signature_figure(result, path):
    """G(t), mu(t) of the data (MIEnKS windows, error bars) against each candidate's predicted band."""
    sig = result["signature"]
    ob = sig.get("observed") or {}
    pred = sig.get("predicted") or {}
    names = _labels(result)
    fig = figure(WIDTH, 4.6)
    ax = fig.subplots(1, 2)
    for a, p in zip(ax, ("G", "mu")):
        f, lab = _PARAM_AXIS[p]
        for j, (k, pr) in enumerate(pred.items()):
            tt = np.asarray(pr["t_star"], float)
            c = f"C{(j + 1) % 10}"
            a.fill_between(
                tt, np.asarray(pr[f"{p}_lo"], float) * f, np.asarray(pr[f"{p}_hi"], float) * f, color=c, alpha=0.2, lw=0
            )
            a.plot(
                tt,
                np.asarray(pr[f"{p}_mean"], float) * f,
                "-",
                color=c,
                lw=1.5,
                label=f"{names.get(k, k)}: predicted" if p == "G" else None,
            )
        if ob.get(p) is not None:
            yv = np.asarray(ob[p], float) * f
            err = np.asarray(ob.get(f"{p}_sd"), float) * f if ob.get(f"{p}_sd") is not None else None
            a.errorbar(
                ob["t_star"],
                yv,
                yerr=err,
                fmt="o",
                color="k",
                ms=4,
                capsize=2,
                label="data: MIEnKS windows" if p == "G" else None,
            )
        a.set_xlabel(r"window centre $t^*$ [-]")
        a.set_ylabel(lab)
        a.set_title(f"{'shear modulus G' if p == 'G' else 'viscosity mu'}(t*): data vs candidates", fontsize=10)
    fig.legend(
        loc="outside lower center",
        ncol=min(3, len(pred) + 1),
        fontsize=8,
        title="lines, bands: each fit's replicates through the smoother (geometric mean, 80 % prediction band)",
        title_fontsize=8,
    )
    save(fig, path)


def _result_figures(result) -> list:
    out = []
    if (result.get("absorption") or {}).get("keys"):
        out.append(("absorption.png", absorption_figure))
    if (result.get("signature") or {}).get("predicted"):
        out.append(("signature.png", signature_figure))
    return out


def write_figures(d, fdir) -> list:
    """``residuals.png``, ``check.png``, ``candidates.png`` and, when the result has them,
    ``absorption.png`` and ``signature.png`` under ``fdir`` (created); returns the paths written.
    A figure that fails is left out with a warning (the report is still written)."""
    fdir = Path(fdir)
    out = []
    own = [("residuals.png", residuals_figure), ("check.png", check_figure)]
    if d.result.get("candidates"):  # none compared when the check ended the diagnosis
        own.append(("candidates.png", candidates_figure))
    jobs = [(name, lambda p, fn=fn: fn(d, p)) for name, fn in own]
    jobs += [(name, lambda p, fn=fn: fn(d.result, p)) for name, fn in _result_figures(d.result)]
    for name, job in jobs:
        try:
            job(fdir / name)
        except Exception as e:  # noqa: BLE001 -- a figure must not cost the diagnosis
            warnings.warn(f"diagnose: figure {name} not written: {type(e).__name__}: {e}", stacklevel=2)
            continue
        out.append(fdir / name)
    return out
