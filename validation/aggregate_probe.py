"""Where MIEnKS-MDA's aggregate bias on camera data comes from: the same fits, summarised four ways.

For each seed of the camera family (``validation/camera_calibration.py``'s data, default settings
unless ``--set``), the gel-level estimate is formed from the windows' Gaussians (internal, log
coordinates) as (1) the aggregate ``fit`` reports (precision-weighted over every window), (2) the
same over the windows not flagged prior-dominated, (3) the last window alone, (4) the record-level
random-effects estimate (``details.record_random_effects``). Prints bias and 95 % coverage of each
over the seeds, writes JSON. Usage:

    python validation/aggregate_probe.py --seeds 20 --first-seed 100 [--bubble thermal] [--set KEY=VALUE] --json out.json
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from camera_calibration import TRUTH, simulate, wilson
from imrbayes.data import load_dataset, preprocess_dataset
from imrbayes.ensemble import MIEnKSSettings, Observations, ParamSpace, fit_mienks
from imrbayes.ensemble.gaussian import precision_weighted
from imrbayes.forward import ForwardModel

WAYS = ("aggregate", "decided_windows", "last_window", "record")


def summaries(res, space) -> dict:
    """The four gel-level estimates of one fit, each {name: (mean, lo95, hi95)} in SI units."""
    m = np.array([w["mean_internal"] for w in res.windows])
    c = np.array([w["cov_internal"] for w in res.windows])
    keep = np.array([not w["prior_dominated"] for w in res.windows])
    out = {}
    for way, (mm, cc) in {"aggregate": precision_weighted(m, c), "decided_windows": precision_weighted(m[keep], c[keep]),
                          "last_window": (m[-1], c[-1])}.items():
        sd = np.sqrt(np.diag(cc))
        out[way] = {n: [float(np.exp(mm[i])), float(np.exp(mm[i] - 1.96 * sd[i])), float(np.exp(mm[i] + 1.96 * sd[i]))]
                    for i, n in enumerate(space.names)}
    rec = res.details["record_random_effects"]["estimate"]
    out["record"] = {n: [rec[n]["mean"], *rec[n]["hdi95"]] for n in space.names}
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=100)
    ap.add_argument("--family", choices=["camera", "scatter"], default="camera")
    ap.add_argument("--bubble", choices=["polytropic", "thermal"], default="polytropic")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args()
    from imrbayes.cli.options import coerce_setting
    settings = {}
    for kv in a.set:
        k, _, v = kv.partition("=")
        settings[k] = coerce_setting(MIEnKSSettings, k, v, "--set")
    fm = ForwardModel("nhkv", options={"bubble": a.bubble})
    space = ParamSpace.for_model(fm.constitutive)
    rows = []
    for seed in range(a.first_seed, a.first_seed + a.seeds):
        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp) / "data"
            simulate(folder, seed, a.family, a.bubble)
            obs = Observations.from_preprocessed(preprocess_dataset(load_dataset(folder), skip_failed=True))
        res = fit_mienks(fm, obs, space, MIEnKSSettings(n_draws=1, **settings), seed=seed)
        s = summaries(res, space)
        rows.append({"seed": seed, **s})
        print(f"seed {seed}: " + "; ".join(f"{w} G {s[w]['G'][0]:.0f} mu {s[w]['mu'][0]:.4f}" for w in WAYS), flush=True)
    table = {}
    for w in WAYS:
        table[w] = {}
        for n, true in TRUTH.items():
            err = np.array([r[w][n][0] / true - 1 for r in rows])
            k = int(sum(r[w][n][1] <= true <= r[w][n][2] for r in rows))
            table[w][n] = {"bias": float(err.mean()), "se": float(err.std(ddof=1) / np.sqrt(len(err))) if len(err) > 1 else None,
                           "coverage": k / len(rows), "coverage_wilson95": wilson(k, len(rows))}
    print(f"\n{a.family} family, {a.bubble}, {len(rows)} seeds, settings {settings or 'default'}")
    print(f"{'estimate':16s} {'G bias':>8s} {'G cov':>6s} {'mu bias':>8s} {'mu cov':>6s}")
    for w in WAYS:
        t = table[w]
        print(f"{w:16s} {t['G']['bias']:+8.3f} {t['G']['coverage']:6.2f} {t['mu']['bias']:+8.3f} {t['mu']['coverage']:6.2f}")
    if a.json:
        a.json.write_text(json.dumps({"family": a.family, "bubble": a.bubble, "settings": settings, "truth": TRUTH,
                                      "rows": rows, "summary": table}, indent=1))


if __name__ == "__main__":
    main()
