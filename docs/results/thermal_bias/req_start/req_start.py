"""Where diagnose's En4D-Var places Req (req_tail=model): the least-squares baseline against En4D-Var's
own quick first pass, on thermal camera records of a constant gel with known Req.

For each seed: camera_obs('none', seed, thermal, the default design), then
  * the least-squares baseline as diagnose fits it (check.statistics: whole record, tempered);
    the model's tail at its material (each bubble with its offsets) and fitted Rmax;
  * En4D-Var's quick first pass (REQ_TAIL_FIRST_PASS) and the model's tail at its estimate;
and each Req prior centre against the true Req (the tail mean's own error beside them).

    python docs/results/thermal_bias/req_start/req_start.py 300 301 302 > req_start.json
"""
import json
import sys
import time
from dataclasses import replace

import numpy as np

from imrbayes.diagnosis.check import statistics
from imrbayes.diagnosis.models import BASELINE, make_candidate
from imrbayes.diagnosis.phases import phases_of
from imrbayes.diagnosis.synthetic import camera_obs
from imrbayes.ensemble import En4DVarSettings
from imrbayes.ensemble.en4dvar import REQ_TAIL_FIRST_PASS, fit_en4dvar
from imrbayes.ensemble.req_tail import model_tail_req
from imrbayes.forward import ForwardOptions, Runner

opts = ForwardOptions(bubble="thermal")
base = make_candidate(BASELINE.key, opts)
rows = []
for seed in (int(a) for a in sys.argv[1:]):
    obs, truth = camera_obs("none", seed, opts)
    req_true = np.array([e["req_m"] for e in truth["experiments"]])
    t = time.perf_counter()
    full = statistics(base, obs, phases_of(obs, 3), seed=seed)["fits"]["all"]
    t_lsq = time.perf_counter() - t
    zz = np.repeat(full.z[None], obs.n_exp, axis=0)
    if full.nu.shape[1] > 3:
        zz[:, :2] += full.nu[:, 3:5]
    runner = Runner(base.fm)
    obs_l, f_l = model_tail_req(runner, obs, base.to_si(zz), obs.rmax_m * (1 + full.nu[:, 0]))
    t = time.perf_counter()
    first = fit_en4dvar(base.fm, obs, base.space, replace(En4DVarSettings(req_tail="mean"), **REQ_TAIL_FIRST_PASS),
                        seed=0)
    t_first = time.perf_counter() - t
    theta = np.array([first.estimate[k]["mean"] for k in ("G", "mu")])
    rmax = np.array([p["nuisance"]["rmax_m"]["mean"] for p in first.per_experiment])
    obs_f, f_f = model_tail_req(runner, obs, theta, rmax)
    row = {"seed": seed, "truth": truth["theta"], "lsq_material": base.to_si(zz).tolist(),
           "first_pass_material": theta.tolist(), "factor_lsq": f_l.tolist(), "factor_first": f_f.tolist(),
           "req_error_tail_mean": (obs.req_m / req_true - 1).tolist(),
           "req_error_lsq": (obs_l.req_m / req_true - 1).tolist(),
           "req_error_first": (obs_f.req_m / req_true - 1).tolist(),
           "req_prior_rel_sd": (obs.nuisance_sd[:, 2] / obs.req_m).tolist(),
           "seconds": {"lsq_baseline": t_lsq, "first_pass": t_first}}
    rows.append(row)
    print(json.dumps(row), file=sys.stderr, flush=True)
print(json.dumps(rows, indent=1))
