"""The study's files: ``study.csv``, ``study.json``, ``study.nc``, ``figures/*.png``, ``study.html``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from imrbayes.io import write_json

__all__ = ["write_table", "write_tree", "write_figures", "write_html"]

_PARAMS = ("G", "mu")


def write_table(out: Path, rows: list, study: dict) -> list:
    """``study.csv`` (one row per condition) and ``study.json`` (the rows plus ``study``: differences,
    trends, conclusion, runs); returns both paths."""
    import pandas as pd

    pd.DataFrame(rows).to_csv(out / "study.csv", index=False)
    write_json(out / "study.json", {"conditions": rows, **study})
    return [out / "study.csv", out / "study.json"]


def write_tree(out: Path, results, draws: dict) -> Path:
    """``study.nc``: an xarray DataTree with a group per condition (labels as attributes): ``gel``,
    the draws of G and mu [SI] from its gel-level posterior, each fit's own ``posterior`` group
    (named after the run: ``en4dvar``, ``mienks``, ...), and ``time_resolved``, G(t) and mu(t) from
    MIEnKS-MDA where it ran."""
    import xarray as xr

    groups = {}
    for r in results:
        attrs = {
            "labels": repr(r.labels),
            "method": r.method or "",
            **{f"label_{k}": str(v) for k, v in r.labels.items()},
        }
        groups[f"/{r.name}"] = xr.Dataset(attrs=attrs)
        if r.name in draws:
            groups[f"/{r.name}/gel"] = xr.Dataset(
                {p: ("draw", np.exp(v)) for p, v in draws[r.name].items()},
                attrs={"units": "G [Pa], mu [Pa s]", "source": f"{r.method} gel-level posterior (log-space Gaussian)"},
            )
        for job, folder in r.folders.items():
            post = Path(folder) / "posterior.nc"
            if job != "diagnose" and post.is_file():
                with xr.open_datatree(post) as tree:
                    groups[f"/{r.name}/{job}"] = tree["posterior"].to_dataset().load()
        if r.time_resolved:
            t = [e["t_star"] for e in r.time_resolved]
            data = {
                f"{p}_{s}": ("t_star", [(e.get(p) or {}).get(s, np.nan) for e in r.time_resolved])
                for p in _PARAMS
                for s in ("mean", "sd")
            }
            groups[f"/{r.name}/time_resolved"] = xr.Dataset(data, coords={"t_star": t})
    path = out / "study.nc"
    xr.DataTree.from_dict(groups).to_netcdf(path)
    return path


def _log_axis_wanted(lo, hi) -> bool:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    ok = np.isfinite(lo) & np.isfinite(hi) & (lo > 0)
    return bool(ok.any() and hi[ok].max() / lo[ok].min() >= 10)


def write_figures(out: Path, rows: list, results, numeric: dict) -> list:
    """G and mu against each numeric label (or per condition when there is none) with 95 %
    intervals, log axes where values span a decade or more; G(t), mu(t) overlaid per condition."""
    from imrbayes import plotting as pl

    fdir = out / "figures"
    written = []
    axes_x = [(k, u) for k, u in numeric.items()] or [(None, "")]
    from imrbayes.study.spec import parse_label_value

    have = [r for r in rows if r.get("G_mean") is not None]
    for key, unit in axes_x if have else ():
        fig = pl.figure(8.5, 3.4)
        axs = fig.subplots(1, 2)
        x = np.array([parse_label_value(r[key])[0] for r in have]) if key else np.arange(len(have))
        for ax, p in zip(axs, _PARAMS):
            s = pl.scale(p)
            m = np.array([r[f"{p}_mean"] for r in have], float) * s
            lo = np.array([r[f"{p}_lo"] for r in have], float) * s
            hi = np.array([r[f"{p}_hi"] for r in have], float) * s
            ax.errorbar(x, m, yerr=[m - lo, hi - m], fmt="o", capsize=3)
            ax.set_ylabel(pl.label(p))
            if _log_axis_wanted(lo, hi):
                ax.set_yscale("log")
                pl.plain_log_axis(ax, "y")
            if key:
                ax.set_xlabel(f"{key} [{unit}]" if unit else key)
                if np.all(x > 0) and x.max() / x.min() >= 10:
                    ax.set_xscale("log")
                    pl.plain_log_axis(ax, "x")
            else:
                ax.set_xticks(x, [r["condition"] for r in have], rotation=30, ha="right", fontsize=8)
        fig.suptitle("gel-level estimate with 95 % interval", fontsize=10)
        written.append(pl.save(fig, fdir / f"parameters_{key or 'by_condition'}.png"))
    tr = [r for r in results if r.time_resolved]
    if tr:
        fig = pl.figure(8.5, 3.4)
        axs = fig.subplots(1, 2)
        for r in tr:
            t = np.array([e["t_star"] for e in r.time_resolved], float)
            for ax, p in zip(axs, _PARAMS):
                s = pl.scale(p)
                est = [e.get(p) or {} for e in r.time_resolved]
                m = np.array([x.get("mean", np.nan) for x in est], float) * s
                band = np.array([x.get("hdi95") or [np.nan, np.nan] for x in est], float) * s
                (line,) = ax.plot(t, m, label=r.name)
                ax.fill_between(t, band[:, 0], band[:, 1], color=line.get_color(), alpha=0.2)
        for ax, p in zip(axs, _PARAMS):
            ax.set_xlabel(pl.label("t_star"))
            ax.set_ylabel(pl.label(p))
        axs[0].legend(fontsize=7)
        fig.suptitle("MIEnKS-MDA G(t), mu(t) per condition (band: 95 % interval)", fontsize=10)
        written.append(pl.save(fig, fdir / "time_resolved.png"))
    return written


def _cell(v, spec=".4g") -> str:
    from imrbayes.html import esc, num

    if isinstance(v, (int, float)) and not isinstance(v, bool):
        return num(v, spec)
    return "–" if v is None else esc(v)


def write_html(out: Path, rows: list, study: dict, figures: list, label_keys: list) -> Path:
    """``study.html``: the conclusion in words first, then the figures, the table, the differences
    and trends, the runs."""
    from imrbayes.html import embed_png, esc, table, write_page

    body = [
        "<h1>imrbayes study</h1>",
        "<div class='conclusion'><ul>" + "".join(f"<li>{esc(s)}</li>" for s in study["conclusion"]) + "</ul></div>",
    ]
    body += [embed_png(f, caption=esc(Path(f).stem.replace("_", " "))) for f in figures]
    heads = [
        "condition",
        *label_keys,
        "method",
        "bubbles",
        "G [kPa] (95 %)",
        "mu [Pa s] (95 %)",
        "between-bubble sd G [kPa]",
        "between-bubble sd mu [Pa s]",
        "described",
        "diagnose",
        "failed",
    ]

    def iv(r, p, s):
        if r.get(f"{p}_mean") is None:
            return "–"
        return f"{_cell(r[f'{p}_mean'] * s)} [{_cell(r[f'{p}_lo'] * s)}, {_cell(r[f'{p}_hi'] * s)}]"

    trows = [
        [
            esc(r["condition"]),
            *[_cell(r[k]) for k in label_keys],
            _cell(r["method"]),
            _cell(r["n_bubbles"]),
            iv(r, "G", 1e-3),
            iv(r, "mu", 1.0),
            _cell(None if r["G_between_sd"] is None else r["G_between_sd"] * 1e-3),
            _cell(r["mu_between_sd"]),
            _cell(r["described"]),
            _cell(" / ".join(str(v) for v in (r["diagnose_verdict"], r["diagnose_cause"]) if v) or None),
            _cell(r["failed"]),
        ]
        for r in rows
    ]
    body += ["<h2>Conditions</h2>", table(heads, trows)]
    drows = []
    for d in study["differences"]:
        for p in ("G", "mu"):
            if p in d:
                s = d[p]
                drows.append(
                    [
                        esc(f"{d['a']} / {d['b']}"),
                        p,
                        _cell(s["ratio"], ".3g"),
                        f"[{_cell(s['interval'][0], '.3g')}, {_cell(s['interval'][1], '.3g')}]",
                        _cell(s["p_greater"], ".3f"),
                    ]
                )
    if drows:
        body += [
            "<h2>Differences</h2>",
            table(["pair a / b", "parameter", "ratio (median)", "95 % interval", "P(a > b)"], drows),
        ]
    trs = []
    for t in study["trends"]:
        for p in ("G", "mu"):
            if p in t:
                s = t[p]
                trs.append(
                    [
                        esc(t["label"]),
                        p,
                        _cell(s["slope"], ".3g") + esc(f" per {t['unit'] or 'unit'}"),
                        f"[{_cell(s['interval'][0], '.3g')}, {_cell(s['interval'][1], '.3g')}]",
                        _cell(s["p_positive"], ".3f"),
                        _cell(s["factor_over_range"], ".3g"),
                    ]
                )
    if trs:
        body += [
            "<h2>Trends</h2>",
            "<p class='note'>slope of the natural log of the parameter on the label, "
            "least squares over the conditions, draw by draw from their posteriors</p>",
            table(["label", "parameter", "slope", "95 % interval", "P(slope > 0)", "factor over the range"], trs),
        ]
    runs = [[esc(k), esc(v.get("status")), esc(v.get("error") or "")] for k, v in study["runs"].items()]
    body += ["<h2>Runs</h2>", table(["run", "status", "error"], runs)]
    return write_page(out / "study.html", "imrbayes study", "\n".join(body))
