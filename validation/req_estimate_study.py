"""How good is preprocessing's Req on camera-style records? (issue #19, deliverable 2)

Each seed draws the camera design of ``camera_calibration.py`` (6 bubbles, 1 Mfps, random phase,
noise 0.02 R*, Req not given), preprocesses it with the defaults, and compares each bubble's Req
estimate and stated sd with the true Req in ``truth.json``. Preprocessing only: no fits, ~1 s per
seed. It also reports the mean of R/Req_true - 1 over three blocks of the tail (samples 40-20,
20-10 and 10-0 from the end) to show whether the tail has settled.

    python validation/req_estimate_study.py --bubble thermal --seeds 20 --json validation/results/req_thermal.json
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from camera_calibration import simulate  # noqa: E402

from imrbayes.data import load_dataset, preprocess_dataset  # noqa: E402


def one_seed(seed: int, bubble: str) -> list:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "data"
        truth = simulate(folder, seed, "camera", bubble)
        ds = load_dataset(folder)
        pre = preprocess_dataset(ds, skip_failed=True)
    names = [x.name for x in pre.experiments]
    records = {Path(e.source).stem: np.asarray(e.R_m) for e in ds.experiments}
    for e in truth["experiments"]:
        stem = Path(e["file"]).stem
        if stem not in names:
            continue
        i = names.index(stem)
        R = records[stem] / e["req_m"]
        rows.append({"seed": seed, "name": stem, "req_true_m": e["req_m"], "req_m": float(pre.req_m[i]),
                     "req_sd_m": float(pre.req_sd_m[i]), "rel_error": float(pre.req_m[i]) / e["req_m"] - 1,
                     "z": (float(pre.req_m[i]) - e["req_m"]) / float(pre.req_sd_m[i]),
                     "tail_excess": [float(R[-40:-20].mean() - 1), float(R[-20:-10].mean() - 1),
                                     float(R[-10:].mean() - 1)]})
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bubble", choices=["polytropic", "thermal"], default="thermal")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=100)
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    rows = [r for s in range(a.first_seed, a.first_seed + a.seeds) for r in one_seed(s, a.bubble)]
    err = np.array([r["rel_error"] for r in rows])
    z = np.array([r["z"] for r in rows])
    sd = np.array([r["req_sd_m"] / r["req_true_m"] for r in rows])
    tail = np.array([r["tail_excess"] for r in rows]).mean(axis=0)
    summary = {"bubble": a.bubble, "n_records": len(rows), "n_seeds": a.seeds, "bias": float(err.mean()),
               "error_sd": float(err.std(ddof=1)), "mean_stated_sd": float(sd.mean()), "z_mean": float(z.mean()),
               "z_sd": float(z.std(ddof=1)), "inside_2sd": float(np.mean(np.abs(z) <= 1.96)),
               "tail_excess_40_20_10": tail.tolist()}
    print(f"{a.bubble}: {len(rows)} records from {a.seeds} seeds; Req bias {100 * summary['bias']:+.1f} %, error sd "
          f"{100 * summary['error_sd']:.1f} %, stated sd {100 * summary['mean_stated_sd']:.1f} %; z mean "
          f"{summary['z_mean']:.2f}, sd {summary['z_sd']:.2f}; inside +-1.96 stated sd: {100 * summary['inside_2sd']:.0f} %")
    print("mean R/Req_true - 1 over samples 40-20, 20-10, 10-0 from the end: "
          + ", ".join(f"{100 * x:+.1f} %" for x in tail))
    if a.json:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps({"summary": summary, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
