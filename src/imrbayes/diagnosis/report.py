"""Self-contained ``report.html`` of a diagnosis (the shared page skeleton of :mod:`imrbayes.html`;
figures embedded as base64 PNG)."""

from __future__ import annotations

from pathlib import Path

from imrbayes.html import embed_png, esc, fmt, table, write_page

__all__ = ["write_report"]


def write_report(result: dict, figures: list, path, title: str = "imrbayes diagnose") -> Path:
    """Write the diagnosis ``result`` (diagnosis.json's object) and the PNG ``figures`` to ``path``
    (atomically); returns ``path``."""
    r = result
    chk = r["constant_parameter_check"]
    ev = chk["evidence"]
    candidates = table(
        ["rank", "model", "mechanism", "RMSE (fit)", "held-out RMSE", "relative held-out reduction",
         "ELPD diff ± SE", "estimate (median)"],
        [[c["rank"], esc(c["model"]), esc(c["mechanism"]), fmt(c["rmse"]), fmt(c["heldout_rmse"]),
          ", ".join(f"{k}: {fmt(v, '+.1%')}" for k, v in c["relative_reduction"].items()),
          f"{fmt(c['elpd_diff'], '.1f')} ± {fmt(c['elpd_se'], '.1f')}",
          esc(", ".join(f"{k}={fmt(v['median'])}" for k, v in c["estimate"].items()))]
         for c in r["candidates"]])
    phases = table(["phase", "t*", "RMSE", "chi2/n"],
                   [[esc(p["phase"]), f"{fmt(p['t_star'][0], '.3f')}–{fmt(p['t_star'][1], '.3f')}", fmt(p["rmse"]),
                     fmt(p["chi2_norm"], ".2f")] for p in r["baseline"]["misfit_by_phase"]])
    stats = table(["statistic", "observed", "bootstrap 5/50/95 %", "p"],
                  [[k, fmt(v["observed"]), ", ".join(fmt(q) for q in v["bootstrap_q05_q50_q95"]),
                    fmt(v["p_value"], ".3f")] for k, v in ev["statistics"].items()])
    est = ", ".join(f"{k} = {fmt(v['mean'])} ± {fmt(v['sd'], '.2g')}" for k, v in r["baseline"]["estimate"].items())
    g = r.get("gain") or {}
    gains = "".join(f"<li>{esc(v['scheme'])}: baseline {fmt(v['baseline'])}, extended {fmt(v['extended'])} "
                    f"({fmt(v['relative_reduction'], '+.1%')}; paired difference "
                    f"{fmt(v['paired_vs_baseline']['mean_diff'])} ± {fmt(v['paired_vs_baseline']['se'])} SE)</li>"
                    for v in g.get("by_scheme", {}).values())
    imgs = "".join(embed_png(p, title=Path(p).stem) for p in figures)
    body = f"""<h1>{esc(title)}</h1>
<p><b>Cause:</b> {esc(r['cause'])} &nbsp; <b>extended model:</b> {esc(r['extended_model'])}
&nbsp; <b>constant-parameter check:</b> {esc(chk['verdict'])} (bootstrap p = {fmt(ev['p_value'], '.3f')},
{ev['n_bootstrap']} replicates)</p>
<h2>Baseline ({esc(r['baseline']['model'])}, {esc(r['baseline']['method'])})</h2><p>{est}; RMSE {fmt(r['baseline']['rmse'])}</p>
{phases}
<h2>Constant-parameter check</h2><p>{esc(ev['rule'])}</p>
{stats}
<h2>Candidates (ranked by held-out score)</h2>
{candidates}
<h2>Gain of {esc(g.get('candidate'))} on unseen data</h2><ul>{gains}
<li>ELPD difference {fmt(g.get('elpd_diff'), '.1f')} ± {fmt(g.get('elpd_se'), '.1f')}: {esc(g.get('elpd_scheme'))}</li></ul>
{imgs}
<p class='note'>runtime {fmt(r.get('runtime_s'), '.0f')} s; seed {r.get('seed')}</p>"""
    return write_page(path, title, body)
