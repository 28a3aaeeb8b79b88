"""MIEnKS-MDA's gel-level estimate: the windows' aggregate against the record-level estimate, from
stored camera-calibration rows (``validation/camera_calibration.py --method mienks``), no new fits.

Until session 70 ``fit --method mienks`` reported the windows' equal-weight precision-weighted
aggregate (methods.md §4) as its estimate and widened that aggregate by the between-bubble sd for
``predictive``; the rows also store the record-level random-effects estimate (``record``: each
experiment's window likelihoods summed over the record, the prior once) and its between-bubble sd.
Rows that carry ``alternatives.aggregate_chain_cov`` (session 72: the aggregate's mean with its
covariance propagated through the window chain, :mod:`imrbayes.ensemble.aggregate`) are scored as a
third rule, ``chain``. This script scores them on the same fits: coverage with a Wilson interval, bias, scatter, mean
posterior sd, and the fraction of the bubbles' true parameters inside each rule's 95 % predictive
interval (the bubbles' truths are regenerated from each seed with ``imrbayes simulate``, as the
calibration drew them; the curves are not needed but come with it).

    python validation/record_estimate_rescore.py validation/results/A.json [B.json ...] --json out.json
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from camera_calibration import SCATTER, TRUTH, simulate, wilson  # noqa: E402

from imrbayes.ensemble.gaussian import marginal_summary  # noqa: E402


def log_moments(est: dict) -> tuple:
    """(m, s) of the log-normal whose mean and sd ``est`` gives (marginal_summary inverted)."""
    s2 = math.log1p((est["sd"] / est["mean"]) ** 2)
    return math.log(est["mean"]) - 0.5 * s2, math.sqrt(s2)


def predictive_holds(est: dict, tau_log: float, truths: np.ndarray) -> float:
    m, s = log_moments(est)
    lo, hi = marginal_summary(m, math.sqrt(s * s + tau_log ** 2), True)["hdi95"]
    return float(np.mean((truths >= lo) & (truths <= hi)))


def rescore(path: Path, cache: dict) -> dict:
    d = json.loads(path.read_text())
    family, bubble = d["family"], d["bubble"]
    per_seed = []
    for row in d["rows"]:
        r = row.get("default")
        if not r or "record" not in r:
            continue
        key = (family, bubble, row["seed"])
        if key not in cache:
            with tempfile.TemporaryDirectory() as tmp:
                truth = simulate(Path(tmp) / "data", row["seed"], family, bubble)
            cache[key] = {n: [e["parameters"][n] for e in truth["experiments"]] for n in TRUTH}
        bub = {n: np.array(v) for n, v in cache[key].items()}
        entry = {"seed": row["seed"]}
        rules = [("aggregate", r), ("record", r["record"])]
        chain = (r.get("alternatives") or {}).get("aggregate_chain_cov")
        if chain:       # the aggregate's mean with its covariance propagated through the window chain
            rules.append(("chain", chain))
        for n in TRUTH:
            tau = r[n].get("between_sd_log") or 0.0
            entry[n] = {rule: {"covers": est[n]["covers"], "rel_error": est[n]["rel_error"],
                               "rel_sd": est[n]["sd"] / TRUTH[n],
                               "predictive_holds": predictive_holds(est[n], tau, bub[n])}
                        for rule, est in rules}
            entry[n]["between_covers"] = r[n].get("between_covers")
            # the fit's own (aggregate) predictive, as stored: the regenerated truths must reproduce it
            entry[n]["stored_predictive_holds"] = r[n].get("predictive_holds")
        per_seed.append(entry)
    check = [abs(e[n]["aggregate"]["predictive_holds"] - e[n]["stored_predictive_holds"])
             for e in per_seed for n in TRUTH if e[n]["stored_predictive_holds"] is not None]
    summary = {"max_abs_diff_to_stored_predictive": max(check) if check else None}
    for n in TRUTH:
        for rule in ("aggregate", "record", "chain"):
            xs = [e[n][rule] for e in per_seed if rule in e[n]]
            if not xs:
                continue
            k = sum(x["covers"] for x in xs)
            err = np.array([x["rel_error"] for x in xs])
            summary[f"{n}:{rule}"] = {
                "covered": k, "n": len(xs), "coverage": k / len(xs), "wilson95": wilson(k, len(xs)),
                "bias": float(err.mean()), "scatter": float(err.std(ddof=1)),
                "mean_rel_sd": float(np.mean([x["rel_sd"] for x in xs])),
                "predictive_holds": float(np.mean([x["predictive_holds"] for x in xs]))}
    return {"file": str(path), "family": family, "bubble": bubble, "seeds": [e["seed"] for e in per_seed],
            "true_between_sd_log": SCATTER if family == "scatter" else 0.0, "summary": summary, "rows": per_seed}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="+", type=Path)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    cache, out = {}, []
    for f in args.files:
        res = rescore(f, cache)
        out.append(res)
        print(f"\n{f.name} ({res['family']}, {res['bubble']}, {len(res['seeds'])} seeds)")
        print(f"{'':10} {'coverage [Wilson]':>22} {'bias':>7} {'scatter':>8} {'mean sd':>8} {'predictive holds':>17}")
        print(f"aggregate predictive recomputed against the stored one: max |diff| "
              f"{res['summary']['max_abs_diff_to_stored_predictive']}")
        for key, v in res["summary"].items():
            if not isinstance(v, dict):
                continue
            print(f"{key:<12} {v['covered']:>3}/{v['n']:<3} [{v['wilson95'][0]:.2f}, {v['wilson95'][1]:.2f}] "
                  f"{v['bias']:+7.3f} {v['scatter']:8.3f} {v['mean_rel_sd']:8.3f} {v['predictive_holds']:17.3f}")
        if args.json:
            args.json.write_text(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
