"""Is a real record's maximum what our camera-style synthetic data assume?

``simulate`` fills the frames before the maximum with the mirror of the collapse (R(t_max - s) =
R(t_max + s), ``data.synthetic``): the growth is laser-driven and not modelled. Preprocessing places
the maximum by a parabola over a window of frames (``preprocess.locate_rmax``, ``local-fit``). Were
real growth not mirror-like, the parabola's vertex would move with the window's width (a cubic term
b s^3 shifts it by ~3 b w^2 / (10 a)), and the synthetic validation of the time of the maximum would
not carry over to real data. Per record this script reports

* the vertex's shift [µs] when the half-width is 0.1, 0.15, 0.2 or 0.3 t_c instead of the default
  (t_c = Rmax / sqrt(p8/rho));
* the asymmetry R(t_max - s) - R(t_max + s) at s = 0.1, 0.2, 0.3 t_c, in % of Rmax (linear
  interpolation between frames);
* the default vertex's standard error [µs].

Usage: python validation/maximum_symmetry.py [DATASET ...] [--json out.json]
(default: every curve dataset in ../shared/data/lic, the dual-camera one as ``--camera mean``).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from imrbayes.data import load_dataset
from imrbayes.data.preprocess import _local_fit_vertex, estimate_noise_sd, locate_rmax

LIC = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "lic"
DATASETS = ("estrada2018_stiffPA_270kfps", "estrada2018_stiffPA_xy002_refit", "franck_lab_A_E2_002_1.59Mfps",
            "umich_PA10_bis0.06_1Mfps_dualcam")
WIDTHS = (0.1, 0.15, 0.2, 0.3)           # half-widths of the local fit [t_c]
OFFSETS = (0.1, 0.2, 0.3)                # s at which the asymmetry is read [t_c]


def record_symmetry(t_s, R_m, rho: float, p8: float) -> dict:
    """Vertex shifts [s] per half-width, asymmetry [fraction of Rmax] per offset, the default
    vertex and its standard error [s] for one record (SI arrays)."""
    t, R = np.asarray(t_s, float), np.asarray(R_m, float)
    u_c = math.sqrt(p8 / rho)
    noise = estimate_noise_sd(R)
    i = int(np.argmax(R))
    t_c = R[i] / u_c
    mx = locate_rmax(t, R, "local-fit", u_c=u_c, noise_sd_m=noise)
    shifts = {}
    for w in WIDTHS:
        f = _local_fit_vertex(t, R, i, w * t_c, noise, t_c)
        shifts[w] = None if f is None else float(f.t_s - mx.t_s)
    asym = {}
    for s in OFFSETS:
        lo, hi = mx.t_s - s * t_c, mx.t_s + s * t_c
        asym[s] = (float((np.interp(lo, t, R) - np.interp(hi, t, R)) / mx.rmax_m)
                   if t[0] <= lo and hi <= t[-1] else None)
    return {"t_max_s": float(mx.t_s), "t_max_sd_s": float(mx.t_sd_s), "method": mx.method, "t_c_s": float(t_c),
            "frame_s": float(np.median(np.diff(t))), "frames_before_max": i, "noise_sd_m": float(noise),
            "vertex_shift_s": {str(k): v for k, v in shifts.items()},
            "asymmetry_of_rmax": {str(k): v for k, v in asym.items()}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("datasets", nargs="*", help="dataset paths (default: the shared curve datasets)")
    ap.add_argument("--json", help="write the rows here")
    a = ap.parse_args(argv)
    paths = [Path(p) for p in a.datasets] or [LIC / d for d in DATASETS]
    rows = []
    fmt = lambda v, k: "  -- " if v is None else f"{v * k:+.2f}"   # noqa: E731
    print(f"{'record':>32s} {'frame':>6s} {'pre':>4s} {'t_sd':>6s}  vertex shift [µs] at w/t_c "
          f"{', '.join(map(str, WIDTHS))}   asymmetry [% Rmax] at s/t_c {', '.join(map(str, OFFSETS))}")
    for p in paths:
        ds = load_dataset(p, camera="mean" if "dualcam" in p.name else None)
        for e in ds.experiments:
            r = record_symmetry(e.t_s, e.R_m, ds.rho, ds.p8)
            r.update(dataset=p.name, experiment=e.name)
            rows.append(r)
            print(f"{(p.name[:16] + '/' + e.name[-15:]):>32s} {r['frame_s'] * 1e6:5.2f}µs {r['frames_before_max']:4d} "
                  f"{r['t_max_sd_s'] * 1e6:6.3f}  "
                  + " ".join(fmt(v, 1e6) for v in r["vertex_shift_s"].values()) + "    "
                  + " ".join(fmt(v, 100) for v in r["asymmetry_of_rmax"].values()))
    if a.json:
        Path(a.json).write_text(json.dumps({"widths_tc": WIDTHS, "offsets_tc": OFFSETS, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
