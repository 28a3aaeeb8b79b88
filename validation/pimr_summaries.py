"""pIMR on the published collapse-time summaries, and on our UMich curves, with one method.

``../shared/data/lic/umich_pIMR_PA_summaries/`` holds, per bubble, Rmax, Rmax/Req and the first
collapse time of two polyacrylamide recipes (Zhu et al. 2025: PA 5 %/0.03 % bis, 52 bubbles; PA
10 %/0.06 % bis, 39 bubbles) -- no curves, so only pIMR can use them. Our UMich dual-camera records
are labelled PA10_bis0.06, but their collapse times sit in the PA05 cloud (docs/datasets.md). This
script puts all of them through the same estimator (``ensemble.pimr.fit_pimr``: the collapse-time
closed form, the default thermal bubble's kappa = 1, one set of constants) and asks where a
5-bubble pIMR estimate of each recipe falls: every 5-bubble subset's estimate is drawn (``--draws``
random subsets) and the UMich records' estimate is placed in those distributions.

Two constant sets: imrbayes's defaults (rho 1064 kg/m^3, as our fits use) and the pIMR code's
(rho 998.2 kg/m^3; ``zhirenruns/parsimonious_IMR`` run_pIMR.m). Seconds in all.

    python validation/pimr_summaries.py --json validation/results/pimr_summaries.json
    python validation/pimr_summaries.py --summary my_bubbles.csv      # pIMR on a summary file of your own
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from imrbayes.data import load_dataset, preprocess_dataset
from imrbayes.ensemble import Observations, ParamSpace
from imrbayes.ensemble.pimr import PIMRSettings, fit_pimr
from imrbayes.forward import ForwardModel

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "lic"
SUMMARIES = {"PA05_bis0.03": "PA05_bis0.03_summary.csv", "PA10_bis0.06": "PA10_bis0.06_summary.csv"}
UMICH = "umich_PA10_bis0.06_1Mfps_dualcam"
CONSTANTS = {"imrbayes defaults": {}, "pIMR code (rho 998.2)": {"rho": 998.2}}


def summary_bubbles(path: Path, physics) -> dict:
    """Rmax [m], Req [m], t_c* of a summary CSV (Rmax_m, Lmax_Rmax_over_Req, t_collapse_s)."""
    df = pd.read_csv(path)
    need = {"Rmax_m", "Lmax_Rmax_over_Req", "t_collapse_s"}
    if not need <= set(df.columns):
        sys.exit(f"pimr_summaries: error: {path}: needs columns {sorted(need)}, found {list(df.columns)}")
    rmax = df["Rmax_m"].to_numpy(float)
    return {"rmax_m": rmax, "req_m": rmax / df["Lmax_Rmax_over_Req"].to_numpy(float),
            "t_collapse_star": df["t_collapse_s"].to_numpy(float) / physics.time_scale(rmax)}


def curve_bubbles(folder: Path, camera: str, rho_override: dict) -> dict:
    """The same three numbers from our preprocessing of the UMich curves (one camera view)."""
    ds = load_dataset(folder, camera=camera)
    if rho_override:
        ds.physics = {**(ds.physics or {}), **rho_override}
    pre = preprocess_dataset(ds, skip_failed=True)
    return {"rmax_m": pre.rmax_m, "req_m": pre.req_m, "t_collapse_star": pre.t_collapse_star}


def pimr(fm, space, b: dict, idx=None) -> dict:
    """pIMR's (G, mu) from Rmax, Req and the collapse times alone. ``fit_pimr`` reads only those
    (its curves are for the fitted-curve figure, and ``runner=None`` skips it), so the records are
    given flat placeholder curves."""
    idx = np.arange(b["rmax_m"].size) if idx is None else np.asarray(idx)
    n = idx.size
    t = np.arange(3) * 0.025
    obs = Observations(t, np.ones((n, 3)), 1e-4, b["rmax_m"][idx], b["req_m"][idx], b["t_collapse_star"][idx],
                       [f"b{i}" for i in idx])
    res = fit_pimr(fm, obs, space, PIMRSettings(), runner=None)
    return {"G": res.estimate["G"]["mean"], "G_sd": res.estimate["G"]["sd"],
            "mu": res.estimate["mu"]["mean"], "mu_sd": res.estimate["mu"]["sd"],
            "collapse_rmse": res.details["collapse_rmse"]}


def _midrank(sample, x) -> float:
    """Fraction of ``sample`` below ``x``, ties counted half."""
    return float(np.mean(sample < x) + 0.5 * np.mean(sample == x))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--draws", type=int, default=300, help="random 5-bubble subsets per recipe")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--summary", type=Path, action="append", default=None, metavar="CSV",
                    help="a summary CSV of your own (Rmax_m, Lmax_Rmax_over_Req, t_collapse_s; repeatable) "
                         "instead of the published two and the UMich curves")
    a = ap.parse_args(argv)
    for f in a.summary or []:
        if not f.is_file():
            sys.exit(f"pimr_summaries: error: {f}: no such file")
    files = {f.stem: f for f in a.summary} if a.summary else {
        k: SHARED / "umich_pIMR_PA_summaries" / f for k, f in SUMMARIES.items()}
    rng = np.random.default_rng(a.seed)
    out = {"command": "python validation/pimr_summaries.py " + " ".join(argv or sys.argv[1:]), "sets": {}}
    for label, over in CONSTANTS.items():
        fm = ForwardModel("nhkv", physics_overrides=over or None)
        space = ParamSpace.for_model(fm.constitutive)
        rows = {}
        bubbles = {k: summary_bubbles(f, fm.physics) for k, f in files.items()}
        cams = [] if a.summary else ["UMich cam0deg", "UMich cam90deg"]
        for cam in cams:
            bubbles[cam] = curve_bubbles(SHARED / UMICH, cam.split()[1], over)
        for k, b in bubbles.items():
            r = pimr(fm, space, b)
            r.update(n=int(b["rmax_m"].size), rmax_over_req=float(np.mean(b["rmax_m"] / b["req_m"])),
                     t_collapse_star=float(np.mean(b["t_collapse_star"])))
            rows[k] = r
        subsets = {}
        for k in files:
            n = bubbles[k]["rmax_m"].size
            if n < 6:
                continue
            est = np.array([[pimr(fm, space, bubbles[k], rng.choice(n, 5, replace=False))[p] for p in ("G", "mu")]
                            for _ in range(a.draws)])
            subsets[k] = est
        for cam in cams:
            g, m = rows[cam]["G"], rows[cam]["mu"]
            # mid-rank: mu often sits on the grid's lower end (0) in the subsets too
            rows[cam]["percentile_in_5_bubble_subsets"] = {
                k: {"G": _midrank(e[:, 0], g), "mu": _midrank(e[:, 1], m)} for k, e in subsets.items()}
        summ = {k: {"G_median": float(np.median(e[:, 0])), "G_90": [float(x) for x in np.percentile(e[:, 0], [5, 95])],
                    "mu_median": float(np.median(e[:, 1])), "mu_90": [float(x) for x in np.percentile(e[:, 1], [5, 95])]}
                for k, e in subsets.items()}
        out["sets"][label] = {"rho": fm.physics.rho, "fits": rows, "five_bubble_subsets": summ}
        print(f"\n{label} (rho {fm.physics.rho:g} kg/m^3); pIMR, kappa 1 (thermal bubble):")
        print(f"{'set':<18} {'n':>3} {'Rmax/Req':>8} {'t_c*':>6} {'G [kPa]':>14} {'mu [Pa s]':>16} "
              f"{'5-bubble G 90% [kPa]':>22} {'5-bubble mu 90%':>18}")
        for k, r in rows.items():
            s5 = summ.get(k)
            extra = (f"{s5['G_90'][0] / 1e3:7.2f}-{s5['G_90'][1] / 1e3:<7.2f}      {s5['mu_90'][0]:.3f}-{s5['mu_90'][1]:.3f}"
                     if s5 else "" if k not in cams else "  percentiles: " + ", ".join(
                         f"{kk} G {v['G']:.2f} mu {v['mu']:.2f}" for kk, v in r["percentile_in_5_bubble_subsets"].items()))
            print(f"{k:<18} {r['n']:>3} {r['rmax_over_req']:8.2f} {r['t_collapse_star']:6.3f} "
                  f"{r['G'] / 1e3:7.2f} ± {r['G_sd'] / 1e3:4.2f} {r['mu']:8.4f} ± {r['mu_sd']:.4f}  {extra}")
    if a.json:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps(out, indent=1))
        print(f"\nwrote {a.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
