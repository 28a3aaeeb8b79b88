import sys, json, numpy as np
from imrbayes.forward import ForwardModel
from imrbayes.ensemble import MIEnKSSettings, ParamSpace, fit_mienks
from imrbayes.validation.suite import verification_data, TRUTH, TRUTH_2, RATIO_2
case, rtps_state, seeds = sys.argv[1], sys.argv[2] == "1", int(sys.argv[3])
fm = ForwardModel("nhkv", options={"bubble": "polytropic"})
space = ParamSpace.for_model(fm.constitutive)
truth = TRUTH if case == "verif" else TRUTH_2
rows = []
for seed in range(seeds):
    obs = verification_data(fm, seed) if case == "verif" else verification_data(fm, seed, truth=TRUTH_2, ratio=RATIO_2)
    res = fit_mienks(fm, obs, space, MIEnKSSettings(n_draws=1, rtps_state=rtps_state), seed=seed)
    r = {"seed": seed}
    for n in truth:
        e = res.estimate[n]
        r[n] = {"rel": e["mean"] / truth[n] - 1, "covers": bool(e["hdi95"][0] <= truth[n] <= e["hdi95"][1]),
                "rel_sd": e["sd"] / e["mean"],
                "win_med": [w[n]["median"] / truth[n] - 1 for w in res.windows],
                "win_cov": [bool(w[n]["hdi95"][0] <= truth[n] <= w[n]["hdi95"][1]) for w in res.windows]}
    rows.append(r)
    print(seed, {n: (round(r[n]["rel"], 3), r[n]["covers"]) for n in truth}, flush=True)
for n in truth:
    rel = np.array([r[n]["rel"] for r in rows]); cov = np.mean([r[n]["covers"] for r in rows])
    W = np.array([r[n]["win_med"] for r in rows]); WC = np.array([r[n]["win_cov"] for r in rows], float)
    print(f"{case} rtps_state={rtps_state} {n}: agg bias {rel.mean():+.3f} scatter {rel.std(ddof=1):.3f} coverage {cov:.2f} "
          f"within10 {int(np.sum(abs(rel) < 0.1))}/{len(rel)} rel sd {np.mean([r[n]['rel_sd'] for r in rows]):.3f}; "
          f"windows cov {WC.mean():.2f} min {WC.mean(0).min():.2f}; win medians " + ", ".join(f"{x:+.2f}" for x in W.mean(0)))
json.dump(rows, open(f"/tmp/cal25out/rtps_{case}_{int(rtps_state)}.json", "w"))
