"""How rough may req_tail=model's first pass be? Theta and the Req factors c from first passes of
different cost, on thermal camera seeds (the calibration's data).

    python first_pass.py 100 103                                   # full (3 cycles) and r1 -> fp.log
    python first_pass.py 100 103 --variants r1s0,r1e24,r1e24s0    # -> fpb.log
"""
import argparse, json, sys, time, tempfile
from pathlib import Path
import numpy as np
sys.path.insert(0, str(Path(__file__).resolve().parents[4] / "validation"))
import camera_calibration as cc
from imrbayes.data import load_dataset, preprocess_dataset
from imrbayes.ensemble import En4DVarSettings, Observations, ParamSpace, fit_en4dvar
from imrbayes.ensemble.req_tail import model_tail_req
from imrbayes.forward import ForwardModel, Runner

VARIANTS = {"full": {}, "r1": dict(n_runs=1), "r1s0": dict(n_runs=1, screen=0), "r1e24": dict(n_runs=1, n_ens=24),
            "r1e24s0": dict(n_runs=1, n_ens=24, screen=0)}
ap = argparse.ArgumentParser()
ap.add_argument("seeds", type=int, nargs="+")
ap.add_argument("--variants", default="full,r1")
ap.add_argument("--json", default="first_pass.json")
a = ap.parse_args()
out = []
for seed in a.seeds:
    fm = ForwardModel("nhkv", options={"bubble": "thermal"})
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "data"
        truth = cc.simulate(folder, seed, "camera", "thermal")
        pre = preprocess_dataset(load_dataset(folder), skip_failed=True)
    obs = Observations.from_preprocessed(pre)
    space = ParamSpace.for_model(fm.constitutive)
    row = {"seed": seed, "req_hat": obs.req_m.tolist()}
    for tag in a.variants.split(","):
        runner = Runner(fm)
        # req_tail=mean: these are the first passes themselves
        s = En4DVarSettings(n_draws=1, loglik=False, req_tail="mean", **VARIANTS[tag])
        t0 = time.perf_counter()
        res = fit_en4dvar(fm, obs, space, s, seed=seed, runner=runner)
        dt = time.perf_counter() - t0
        theta = np.array([res.estimate[n]["mean"] for n in space.names])
        rmax = np.array([p["nuisance"]["rmax_m"]["mean"] for p in res.per_experiment])
        _, factor = model_tail_req(runner, obs, theta, rmax)
        row[tag] = {"time_s": dt, "theta": theta.tolist(), "factor": factor.tolist(),
                    "members": res.details.get("member_runs")}
        print(seed, tag, f"{dt:.0f}s", theta, np.round(factor, 5), flush=True)
    out.append(row)
    Path(a.json).write_text(json.dumps(out, indent=1))
