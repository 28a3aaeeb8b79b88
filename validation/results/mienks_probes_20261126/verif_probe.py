import sys, json, numpy as np
from imrbayes.forward import ForwardModel
from imrbayes.ensemble import MIEnKSSettings, ParamSpace, fit_mienks
from imrbayes.validation.suite import verification_data, TRUTH
mode = sys.argv[1]
fm = ForwardModel("nhkv", options={"bubble": "polytropic"})
cv = {"G": 0.467, "mu": 0.421}
prior = None
if mode == "oracle":
    prior = {n: (TRUTH[n] * np.sqrt(1 + cv[n] ** 2), TRUTH[n] * np.sqrt(1 + cv[n] ** 2) * cv[n]) for n in TRUTH}
space = ParamSpace.for_model(fm.constitutive, prior=prior)
rows = []
for seed in range(10):
    obs = verification_data(fm, seed)
    res = fit_mienks(fm, obs, space, MIEnKSSettings(n_draws=1), seed=seed)
    rows.append({n: [w[n]["median"] / TRUTH[n] - 1 for w in res.windows] for n in TRUTH})
    rows[-1]["pooled"] = {n: [float(np.exp(w["pooled_mean_internal"][i]) / TRUTH[n] - 1) for w in res.windows] for i, n in enumerate(TRUTH)}
    print(seed, {n: round(res.estimate[n]["mean"] / TRUTH[n] - 1, 3) for n in TRUTH}, flush=True)
for n in TRUTH:
    E = np.array([r[n] for r in rows]); P = np.array([r["pooled"][n] for r in rows])
    print(mode, n, "medians:", ", ".join(f"{x:+.2f}" for x in E.mean(0)))
    print(mode, n, "pooled: ", ", ".join(f"{x:+.2f}" for x in P.mean(0)))
json.dump(rows, open(f"/tmp/cal25out/verif_{mode}.json", "w"))
