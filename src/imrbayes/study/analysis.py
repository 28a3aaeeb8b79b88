"""The study's table, its differences and trends, and its conclusion in words."""

from __future__ import annotations

import itertools

import numpy as np

from imrbayes.study.contrasts import log_draws, ratio_summary, trend_summary
from imrbayes.study.spec import parse_label_value

__all__ = ["table_rows", "condition_draws", "differences", "trends", "conclusion", "N_DRAWS"]

#: draws per condition for the differences: the 95 % bounds' Monte Carlo error is ~1 % of their width
N_DRAWS = 20000
_PARAMS = ("G", "mu")


def table_rows(results, label_keys) -> list:
    """One row per condition (dict): labels, gel-level G and mu [SI] with 95 % intervals, the
    between-bubble sd [SI] with its interval, the number of bubbles, whether the model describes the
    records (None: not checked), the diagnose verdict, the runs that failed."""
    rows = []
    for r in results:
        row = {
            "condition": r.name,
            **{k: r.labels.get(k) for k in label_keys},
            "method": r.method,
            "n_bubbles": r.n_bubbles,
        }
        for p in _PARAMS:
            e, b = r.estimate.get(p) or {}, r.between.get(p) or {}
            lo, hi = e.get("hdi95") or (None, None)
            blo, bhi = b.get("hdi95") or (None, None)
            row.update(
                {
                    f"{p}_mean": e.get("mean"),
                    f"{p}_lo": lo,
                    f"{p}_hi": hi,
                    f"{p}_between_sd": b.get("sd"),
                    f"{p}_between_lo": blo,
                    f"{p}_between_hi": bhi,
                }
            )
        row["described"] = r.described
        row["diagnose_verdict"] = r.diagnose.get("verdict")
        row["diagnose_cause"] = r.diagnose.get("cause")
        row["failed"] = "; ".join(f"{k}: {v}" for k, v in r.errors.items()) or None
        rows.append(row)
    return rows


def condition_draws(results, seed: int) -> dict:
    """{condition: {param: log draws (N_DRAWS,)}} for the conditions with a gel-level posterior; the
    draws of each condition come from its own stream of ``seed``."""
    out = {}
    for i, r in enumerate(results):
        if r.log_mean is None:
            continue
        rng = np.random.default_rng([seed, i])
        d = log_draws(r.log_mean, r.log_cov, N_DRAWS, rng)
        out[r.name] = {p: d[:, r.params.index(p)] for p in _PARAMS if p in r.params}
    return out


def differences(results, draws: dict) -> list:
    """Every pair (a, b) of conditions (b after a in the study's order): the ratio a / b of G and of
    mu with its 95 % interval and P(a > b)."""
    names = [r.name for r in results if r.name in draws]
    out = []
    for b, a in itertools.combinations(names, 2):
        entry = {"a": a, "b": b}
        for p in _PARAMS:
            if p in draws[a] and p in draws[b]:
                entry[p] = ratio_summary(draws[a][p], draws[b][p])
        out.append(entry)
    return out


def trends(results, draws: dict, numeric: dict) -> list:
    """For each numeric label ``{key: unit}``: the slope of log G and of log mu on the label, over the
    conditions with a posterior (at least two distinct label values)."""
    out = []
    for key, unit in numeric.items():
        rs = [r for r in results if r.name in draws]
        x = np.array([parse_label_value(r.labels[key])[0] for r in rs])
        if len(set(x)) < 2:
            continue
        entry = {"label": key, "unit": unit, "conditions": [r.name for r in rs], "x": x.tolist()}
        for p in _PARAMS:
            if all(p in draws[r.name] for r in rs):
                entry[p] = trend_summary(x, np.stack([draws[r.name][p] for r in rs]))
        out.append(entry)
    return out


def _bounds(iv, spec=".3g") -> str:
    return f"[{iv[0]:{spec}}, {iv[1]:{spec}}]"


def _direction(p_positive: float) -> str | None:
    if p_positive >= 0.975:
        return "rises"
    if p_positive <= 0.025:
        return "falls"
    return None


def conclusion(results, diffs, trend_list) -> list:
    """The study's findings as plain sentences, caveats first (methods.md §8: the headline never
    outruns the fit): records the model does not describe, failed runs; then, per numeric label, the
    direction of G and mu with the ratio of the extreme conditions, else the pairwise ratios."""
    lines = []
    wrong = [r.name for r in results if r.described is False]
    if wrong:
        lines.append(
            f"The model does not describe the records of {', '.join(wrong)}: their numbers are the best "
            "fit of a wrong model, and differences involving them compare such fits."
        )
    failed = [f"{r.name} ({', '.join(r.errors)})" for r in results if r.errors]
    if failed:
        lines.append(f"Runs failed for {'; '.join(failed)}; see the table.")
    by_pair = {(d["a"], d["b"]): d for d in diffs}
    for t in trend_list:
        unit = f" {t['unit']}" if t["unit"] else ""
        lo_i, hi_i = int(np.argmin(t["x"])), int(np.argmax(t["x"]))
        a, b = t["conditions"][hi_i], t["conditions"][lo_i]
        pair = by_pair.get((a, b)) or by_pair.get((b, a))
        parts = []
        for p in _PARAMS:
            if p not in t:
                continue
            d = _direction(t[p]["p_positive"])
            name = "mu" if p == "mu" else "G"
            if pair is None or p not in pair:
                ratio = ""
            else:
                r = (
                    pair[p]
                    if pair["a"] == a
                    else {
                        "ratio": 1 / pair[p]["ratio"],
                        "interval": [1 / pair[p]["interval"][1], 1 / pair[p]["interval"][0]],
                    }
                )
                ratio = f": {t['x'][hi_i]:g}{unit} / {t['x'][lo_i]:g}{unit} = {r['ratio']:.3g} {_bounds(r['interval'])}"
            if d is None:
                parts.append(
                    f"{name} does not differ detectably along {t['label']}{ratio} (slope of ln {name} "
                    f"{t[p]['slope']:.3g} per{unit or ' unit'} {_bounds(t[p]['interval'])})"
                )
            else:
                parts.append(
                    f"{name} {d} with {t['label']}{ratio} (slope of ln {name} {t[p]['slope']:.3g} per"
                    f"{unit or ' unit'} {_bounds(t[p]['interval'])}, P(slope > 0) = "
                    f"{t[p]['p_positive']:.3f})"
                )
        lines.append("; ".join(parts) + ".")
    if not trend_list:
        for d in diffs:
            parts = []
            for p in _PARAMS:
                if p in d:
                    s = d[p]
                    verb = (
                        "differs" if min(s["p_greater"], 1 - s["p_greater"]) <= 0.025 else "does not differ detectably"
                    )
                    parts.append(
                        f"{p} {verb}: {d['a']} / {d['b']} = {s['ratio']:.3g} {_bounds(s['interval'])}, "
                        f"P({d['a']} > {d['b']}) = {s['p_greater']:.3f}"
                    )
            lines.append("; ".join(parts) + ".")
    if not lines:
        lines.append("No condition has a posterior to compare.")
    return lines
