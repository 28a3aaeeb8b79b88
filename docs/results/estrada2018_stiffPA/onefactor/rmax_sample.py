"""Stiff PA, standard IMR with Rmax and the time of the maximum from the largest sample (no local fit)."""
import json
import numpy as np
from imrbayes.data import load_dataset, preprocess_dataset
from imrbayes.ensemble import Observations, ParamSpace
from imrbayes.ensemble.imr import IMRSettings, fit_imr
from imrbayes.forward import ForwardModel
out = {}
for method in ("sample", "local-fit"):
    pre = preprocess_dataset(load_dataset("../shared/data/lic/estrada2018_stiffPA_270kfps"), rmax_method=method,
                             skip_failed=True)
    fm = ForwardModel("nhkv")
    obs = Observations.from_preprocessed(pre)
    res = fit_imr(fm, obs, ParamSpace.for_model(fm.constitutive), IMRSettings(n_G=61, n_mu=38))
    G = np.array([p["optimum"]["G"] for p in res.per_experiment]) / 1e3
    mu = np.array([p["optimum"]["mu"] for p in res.per_experiment])
    out[method] = {"rmax_um": (pre.rmax_m * 1e6).tolist(), "pooled_G": res.estimate["G"]["mean"],
                   "pooled_mu": res.estimate["mu"]["mean"], "G_mean": G.mean(), "G_sd": G.std(ddof=1),
                   "mu_mean": mu.mean(), "mu_sd": mu.std(ddof=1)}
    print(method, f"Rmax mean {pre.rmax_m.mean()*1e6:.2f} um; pooled G {res.estimate['G']['mean']/1e3:.2f} kPa; "
          f"per-bubble G {G.mean():.2f} ± {G.std(ddof=1):.2f}, mu {mu.mean():.3f} ± {mu.std(ddof=1):.3f}", flush=True)
    if method == "sample":
        pass
json.dump(out, open("/tmp/s19/rmax_sample.json", "w"), indent=1)
