"""How rough may req_tail=model's first pass be? Theta, Rmax and the Req factors from the full first
pass (3 cycles) against a 1-cycle one, on thermal camera seeds."""
import json, sys, time, tempfile
from dataclasses import replace
from pathlib import Path
import numpy as np
sys.path.insert(0, "/work/main/validation")
import camera_calibration as cc
from imrbayes.data import load_dataset, preprocess_dataset
from imrbayes.ensemble import En4DVarSettings, Observations, ParamSpace, fit_en4dvar
from imrbayes.ensemble.req_tail import model_tail_req
from imrbayes.forward import ForwardModel, Runner

out = []
for seed in [int(a) for a in sys.argv[1:]]:
    fm = ForwardModel("nhkv", options={"bubble": "thermal"})
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "data"
        truth = cc.simulate(folder, seed, "camera", "thermal")
        pre = preprocess_dataset(load_dataset(folder), skip_failed=True)
    obs = Observations.from_preprocessed(pre)
    space = ParamSpace.for_model(fm.constitutive)
    true_req = np.array([e["req_m"] for e in truth["experiments"]]) if "req_m" in truth["experiments"][0] else None
    row = {"seed": seed}
    for runs in (3, 1):
        runner = Runner(fm)
        s = En4DVarSettings(n_runs=runs, n_draws=1, loglik=False)
        t0 = time.perf_counter()
        res = fit_en4dvar(fm, obs, space, s, seed=seed, runner=runner)
        dt = time.perf_counter() - t0
        theta = np.array([res.estimate[n]["mean"] for n in space.names])
        rmax = np.array([p["nuisance"]["rmax_m"]["mean"] for p in res.per_experiment])
        _, factor = model_tail_req(runner, obs, theta, rmax)
        row[f"runs{runs}"] = {"time_s": dt, "theta": theta.tolist(), "factor": factor.tolist(),
                              "members": res.details.get("member_runs")}
        print(seed, runs, f"{dt:.0f}s", theta, np.round(factor, 5), flush=True)
    if true_req is not None:
        row["true_req"] = true_req.tolist()
    row["req_hat"] = obs.req_m.tolist()
    out.append(row)
    Path(f"/tmp/probe52/first_pass_{seed}.json").write_text(json.dumps(out, indent=1))
