"""IMR v1's fit on stiff PA, emulated factor by factor on one set of forward runs per constants set.

Per bubble, a log grid G 10^3.0..10^4.5, mu 10^-2.0..10^-0.5 (step 0.05, IMR v1's spacing), thermal
bubble (our default forward), and four choices crossed: cost (our squared R* residual vs IMR v1's
unsquared closest distance in (t [us], R [um])), box (full vs IMR v1's stiff-PA box G 10^3.65..4.15,
mu 10^-1.4..-0.9), frames (max to just before the third collapse, IMR v1's rule, vs the whole record
to t* 3). Per-bubble optimum, then mean ± sd over the 20 bubbles (as published).
usage: v1cost.py NAME DATA_DIR
"""
import json, sys, time
import numpy as np
from scipy.signal import find_peaks
from imrbayes.data import load_dataset, preprocess_dataset
from imrbayes.forward import ForwardModel, Runner

name, folder = sys.argv[1], sys.argv[2]
ds = load_dataset(folder)
pre = preprocess_dataset(ds)
fm = ForwardModel("nhkv", physics_overrides=ds.physics or None) if ds.physics else ForwardModel("nhkv")
run = Runner(fm)
lg = np.round(np.arange(3.0, 4.5001, 0.05), 4); lm = np.round(np.arange(-2.0, -0.4999, 0.05), 4)
GG, MM = np.meshgrid(10 ** lg, 10 ** lm, indexing="ij")
theta = np.stack([GG.ravel(), MM.ravel()], axis=1)
box = ((lg[:, None] >= 3.65 - 1e-9) & (lg[:, None] <= 4.15 + 1e-9) & (lm[None, :] >= -1.4 - 1e-9)
       & (lm[None, :] <= -0.9 + 1e-9)).ravel()
tfine = np.arange(0.0, 3.0001, 0.005)
out = {"grid_log10G": lg.tolist(), "grid_log10mu": lm.tolist(), "bubbles": []}
t0c = time.time()
for i, (exp, summ) in enumerate(zip(pre.dataset.experiments, pre.experiments)):
    t_s = np.asarray(exp.t_s); R_m = np.asarray(exp.R_m)
    ts = (t_s - summ.t0_s) / summ.tc_s
    keep = (ts >= 0) & (ts <= 3.0)
    ts, Rs = ts[keep], R_m[keep] / summ.rmax_m
    mins, _ = find_peaks(-Rs, prominence=0.05)
    last3 = mins[2] if mins.size >= 3 else ts.size      # IMR v1: up to just before the third collapse
    sets = {"v1frames": np.arange(ts.size) < last3, "whole": np.ones(ts.size, bool)}
    M = theta.shape[0]
    sim = run.simulate(theta, np.full(M, summ.rmax_m), np.full(M, summ.req_m), tfine).R_star   # (M, F)
    ok = np.all(np.isfinite(sim), axis=1)
    # squared R* residual at the frames (linear interpolation of the fine curve)
    Rsim_at = np.array([np.interp(ts, tfine, s) for s in sim])                                   # (M, n)
    res = {}
    for fr, m in sets.items():
        sq = np.sum((Rsim_at[:, m] - Rs[m]) ** 2, axis=1)
        # closest distance in (t [us], R [um]) from each frame to the fine simulated curve
        tu, Ru = ts[m] * summ.tc_s * 1e6, Rs[m] * summ.rmax_m * 1e6
        tf, Rf = tfine * summ.tc_s * 1e6, sim * summ.rmax_m * 1e6
        d = np.sqrt((tu[None, :, None] - tf[None, None, :]) ** 2 + (Ru[None, :, None] - Rf[:, None, :]) ** 2)
        cd = d.min(axis=2).sum(axis=1)
        for cname, c in (("squared", sq), ("closest", cd)):
            c = np.where(ok, c, np.inf)
            for bname, b in (("full", np.ones(M, bool)), ("v1box", box)):
                j = int(np.argmin(np.where(b, c, np.inf)))
                res[f"{cname}|{bname}|{fr}"] = [float(theta[j, 0]), float(theta[j, 1])]
    out["bubbles"].append({"name": summ.name, "n_v1frames": int(last3), "optima": res})
    print(i, summ.name, round(time.time() - t0c), flush=True)
keys = out["bubbles"][0]["optima"].keys()
out["summary"] = {}
for k in keys:
    A = np.array([b["optima"][k] for b in out["bubbles"]])
    out["summary"][k] = {"G_mean": A[:, 0].mean(), "G_sd": A[:, 0].std(ddof=1), "mu_mean": A[:, 1].mean(),
                         "mu_sd": A[:, 1].std(ddof=1), "G_median": float(np.median(A[:, 0]))}
    print(f"{k:28s} G {A[:,0].mean()/1e3:6.2f} ± {A[:,0].std(ddof=1)/1e3:5.2f} kPa   mu {A[:,1].mean():.3f} ± {A[:,1].std(ddof=1):.3f}")
out["runtime_s"] = time.time() - t0c
json.dump(out, open(f"/tmp/s19/v1cost_{name}.json", "w"), indent=1)
