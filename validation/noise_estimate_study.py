"""How good is the preprocessing's record-noise estimate at each camera design? (issues #19, #21)

The noise sd of every record (``imrbayes.data.preprocess.estimate_noise_sd``: 1.4826 MAD of the
fourth differences / sqrt(70)) sets the likelihood's measurement noise, the collapse detector's
prominence bar and the diagnosis check's chi-square scale. It assumes the smooth radius contributes
little to the fourth differences, which holds when a collapse spans many frames. This study records
constant-NHKV camera records of every diagnosis design (:data:`imrbayes.diagnosis.synthetic.DESIGNS`:
1-2 Mfps, 270 kfps, 500 kfps with small bubbles), runs the preprocessing exactly as ``diagnose``
does, and divides each record's estimate by the true noise sd. Also reported: the same scale from
the 25th and 35th percentiles of the absolute deviations instead of the median (robust to a larger
fraction of frames where the radius itself dominates the differences), and the median estimate on
the record's last 40 % of frames only.

    python validation/noise_estimate_study.py --seeds 5 --json validation/results/noise_estimate_study.json

Preprocessing only (the data generation solves the thermal model on a fine grid): ~1 min per
design and seed on a 2-core machine.
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
from scipy.stats import norm

import imrbayes.data.pipeline as pipeline
import imrbayes.data.preprocess as pp
from imrbayes.data import synthetic as syn
from imrbayes.diagnosis.synthetic import DESIGNS, camera_obs
from imrbayes.forward import ForwardOptions

QUANTILES = (0.25, 0.35)


def quantile_scale(R, q: float) -> float:
    """The fourth-difference noise sd from the q-quantile of |d4 - median| instead of the median."""
    d4 = np.diff(np.asarray(R, dtype=float), 4)
    a = np.abs(d4 - np.median(d4))
    return float(np.quantile(a, q) / norm.ppf(0.5 + q / 2) / math.sqrt(70.0))


def tail_scale(R, frac: float = 0.4) -> float:
    """The fourth-difference noise sd of the record's last ``frac`` of frames only (where a damped
    bubble moves least)."""
    R = np.asarray(R, dtype=float)
    return pp.estimate_noise_sd(R[int(round((1 - frac) * R.size)):])


def records_of(design: str, seed: int, opts) -> tuple:
    """(raw records [m] as the preprocessing saw them, truth) for the constant gel of ``seed``."""
    seen = []
    estimate = pp.estimate_noise_sd

    def record(R):
        seen.append(np.array(R, dtype=float))
        return estimate(R)

    pipeline.pp.estimate_noise_sd = record
    try:
        _, truth = camera_obs("none", seed, opts, design=design)
    finally:
        pipeline.pp.estimate_noise_sd = estimate
    return seen, truth


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--designs", nargs="+", default=list(DESIGNS), choices=list(DESIGNS))
    ap.add_argument("--json", type=Path, default=Path("validation/results/noise_estimate_study.json"))
    a = ap.parse_args(argv)
    opts = ForwardOptions()
    rows, table = [], {}
    for design in a.designs:
        for seed in range(a.seeds):
            records, truth = records_of(design, seed, opts)
            for R in records:
                rmax = float(R.max())
                true_sd = float(syn.noise_sd(np.zeros(1), np.ones(1), truth["noise"], rmax)[0]) * rmax
                r = {"design": design, "seed": seed, "frames": int(R.size),
                     "mad": pp.estimate_noise_sd(R) / true_sd,
                     **{f"q{int(q * 100)}": quantile_scale(R, q) / true_sd for q in QUANTILES},
                     "tail40": tail_scale(R) / true_sd}
                rows.append(r)
                table.setdefault(design, []).append(r)
    summary = {}
    print(f"{'design':>22} {'records':>7} {'frames':>6}  estimate / true noise sd: median [min, max]")
    for design, rs in table.items():
        s = {"records": len(rs), "frames_median": float(np.median([r["frames"] for r in rs]))}
        for k in ("mad", *(f"q{int(q * 100)}" for q in QUANTILES), "tail40"):
            v = np.array([r[k] for r in rs])
            s[k] = {"median": float(np.median(v)), "min": float(v.min()), "max": float(v.max()),
                    "mean": float(v.mean())}
        summary[design] = s
        print(f"{design:>22} {s['records']:7d} {s['frames_median']:6.0f}  " + "  ".join(
            f"{k} {s[k]['median']:.2f} [{s[k]['min']:.2f}, {s[k]['max']:.2f}]" for k in ("mad", "q25", "tail40")))
    a.json.parent.mkdir(parents=True, exist_ok=True)
    a.json.write_text(json.dumps({"command": "python validation/noise_estimate_study.py --seeds "
                                  f"{a.seeds}", "summary": summary, "rows": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
