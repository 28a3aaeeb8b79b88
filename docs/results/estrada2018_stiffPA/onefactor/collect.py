"""Table and JSON of the one-factor study (run.sh): pooled IMR optimum and per-bubble optima."""
import json
import os
import sys

import numpy as np

ROWS = [("base", "our defaults (IMRv2 constants, thermal bubble, whole record t* <= 3)"),
        ("v1const", "IMR v1's constants: rho 998.2, S 0.056, kappa 1.4"),
        ("rho", "rho 998.2 kg/m^3 alone"), ("S", "S 0.056 N/m alone"), ("kappa", "kappa 1.4 alone"),
        ("v1req", "IMR v1's Req (median of frames 62-101)"),
        ("win3", "frames through the 2nd collapse"), ("rtol3", "solver rtol 1e-3, atol 1e-6"),
        ("poly", "polytropic bubble"), ("v1all_win3", "IMR v1's constants + Req + frames")]
out = {"published": {"G_kPa": [7.69, 1.12], "mu_Pa_s": [0.101, 0.023]}, "rows": []}
print("| variant | pooled G [kPa] | pooled mu [Pa s] | per-bubble G [kPa], mean ± sd | per-bubble mu [Pa s] |")
print("|---|---|---|---|---|")
for name, what in ROWS:
    f = f"/tmp/s19/of_{name}/summary.json"
    if not os.path.exists(f):
        continue
    d = json.load(open(f))
    G = np.array([p["optimum"]["G"] for p in d["per_experiment"]]) / 1e3
    mu = np.array([p["optimum"]["mu"] for p in d["per_experiment"]])
    row = {"variant": name, "what": what, "command": d.get("command"), "pooled_G_kPa": d["estimate"]["G"]["mean"] / 1e3,
           "pooled_mu": d["estimate"]["mu"]["mean"], "per_bubble_G_kPa": G.tolist(), "per_bubble_mu": mu.tolist(),
           "G_mean_kPa": G.mean(), "G_sd_kPa": G.std(ddof=1), "mu_mean": mu.mean(), "mu_sd": mu.std(ddof=1),
           "runtime_s": d.get("total_runtime_s")}
    out["rows"].append(row)
    print(f"| {what} | {row['pooled_G_kPa']:.2f} | {row['pooled_mu']:.3f} | {G.mean():.2f} ± {G.std(ddof=1):.2f} | "
          f"{mu.mean():.3f} ± {mu.std(ddof=1):.3f} |")
for extra in ("v1cost_ours", "rmax_sample"):
    f = f"/tmp/s19/{extra}.json"
    if os.path.exists(f):
        d = json.load(open(f))
        out[extra] = d.get("summary", d)
if len(sys.argv) > 1:
    json.dump(out, open(sys.argv[1], "w"), indent=1)
