"""Self-contained ``report.html`` of a diagnosis (figures embedded as base64 PNG)."""

from __future__ import annotations

import html
from pathlib import Path

from imrbayes.html import embed_png
from imrbayes.html import fmt as _f

__all__ = ["write_report"]


def write_report(result: dict, figures: list, path, title: str = "imrbayes diagnose") -> Path:
    r = result
    chk = r["constant_parameter_check"]
    ev = chk["evidence"]
    rows = []
    for c in r["candidates"]:
        rel = ", ".join(f"{k}: {_f(v, '+.1%')}" for k, v in c["relative_reduction"].items())
        rows.append(f"<tr><td>{c['rank']}</td><td>{html.escape(c['model'])}</td><td>{html.escape(c['mechanism'])}</td>"
                    f"<td>{_f(c['rmse'])}</td><td>{_f(c['heldout_rmse'])}</td><td>{rel}</td>"
                    f"<td>{_f(c['elpd_diff'], '.1f')} ± {_f(c['elpd_se'], '.1f')}</td>"
                    f"<td>{html.escape(', '.join(f'{k}={_f(v['median'])}' for k, v in c['estimate'].items()))}</td></tr>")
    phases = "".join(f"<tr><td>{html.escape(p['phase'])}</td><td>{_f(p['t_star'][0], '.3f')}–{_f(p['t_star'][1], '.3f')}"
                     f"</td><td>{_f(p['rmse'])}</td><td>{_f(p['chi2_norm'], '.2f')}</td></tr>"
                     for p in r["baseline"]["misfit_by_phase"])
    stats = "".join(f"<tr><td>{k}</td><td>{_f(v['observed'])}</td><td>{', '.join(_f(q) for q in v['bootstrap_q05_q50_q95'])}"
                    f"</td><td>{_f(v['p_value'], '.3f')}</td></tr>" for k, v in ev["statistics"].items())
    est = ", ".join(f"{k} = {_f(v['mean'])} ± {_f(v['sd'], '.2g')}" for k, v in r["baseline"]["estimate"].items())
    g = r.get("gain") or {}
    gains = "".join(f"<li>{html.escape(v['scheme'])}: baseline {_f(v['baseline'])}, extended {_f(v['extended'])} "
                    f"({_f(v['relative_reduction'], '+.1%')}; paired difference {_f(v['paired_vs_baseline']['mean_diff'])} "
                    f"± {_f(v['paired_vs_baseline']['se'])} SE)</li>" for v in g.get("by_scheme", {}).values())
    imgs = [f"<h3>{html.escape(Path(p).stem)}</h3>{embed_png(p)}" for p in figures]
    doc = f"""<!doctype html><html><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto}} td,th{{border:1px solid #ccc;padding:3px 6px}}
table{{border-collapse:collapse;font-size:13px}}</style></head><body>
<h1>{html.escape(title)}</h1>
<p><b>Cause:</b> {html.escape(str(r['cause']))} &nbsp; <b>extended model:</b> {html.escape(str(r['extended_model']))}
&nbsp; <b>constant-parameter check:</b> {html.escape(chk['verdict'])} (bootstrap p = {_f(ev['p_value'], '.3f')},
{ev['n_bootstrap']} replicates)</p>
<h2>Baseline ({html.escape(r['baseline']['model'])}, {html.escape(r['baseline']['method'])})</h2><p>{est}; RMSE {_f(r['baseline']['rmse'])}</p>
<table><tr><th>phase</th><th>t*</th><th>RMSE</th><th>chi2/n</th></tr>{phases}</table>
<h2>Constant-parameter check</h2><p>{html.escape(ev['rule'])}</p>
<table><tr><th>statistic</th><th>observed</th><th>bootstrap 5/50/95 %</th><th>p</th></tr>{stats}</table>
<h2>Candidates (ranked by held-out score)</h2>
<table><tr><th>rank</th><th>model</th><th>mechanism</th><th>RMSE (fit)</th><th>held-out RMSE</th>
<th>relative held-out reduction</th><th>ELPD diff ± SE</th><th>estimate (median)</th></tr>{''.join(rows)}</table>
<h2>Gain of {html.escape(str(g.get('candidate')))} on unseen data</h2><ul>{gains}
<li>ELPD difference {_f(g.get('elpd_diff'), '.1f')} ± {_f(g.get('elpd_se'), '.1f')}: {html.escape(str(g.get('elpd_scheme')))}</li></ul>
{''.join(imgs)}
<p style="font-size:11px">runtime {_f(r.get('runtime_s'), '.0f')} s; seed {r.get('seed')}</p></body></html>"""
    path = Path(path)
    path.write_text(doc)
    return path
