"""The En4D-Var check's sampler, one configuration at a time (docs/mcmc.md, "The start placed on the target").

Fits En4D-Var to DATA (cached beside it as ``probe_fit_BUBBLE.pkl``), builds the window target
``fit --mcmc`` builds, and runs :func:`imrbayes.mcmc.sampler.run_mcmc` once per configuration
(``;``-separated ``MCMCSettings`` fields), printing one JSON line each: evaluations to the stop,
steps, tau, acceptance, R-hat and ESS at the stop, the draws' mean and sd of (log G, log mu) and the
placement's rounds. Counts of evaluations are the measure; seconds depend on the host's load.

    python benchmarks/mcmc_placement.py DATA polytropic "n_steps=5000" "place=start;moves=ridge:0.5,blocks:0.5"
"""
import sys, json, time, pickle, numpy as np
from dataclasses import replace
from pathlib import Path
from imrbayes.data import load_dataset, preprocess_dataset
from imrbayes.ensemble import En4DVarSettings, Observations, ParamSpace, fit_en4dvar
from imrbayes.forward import ForwardModel
from imrbayes.mcmc.fit import fit_window_specs
from imrbayes.mcmc.windows import start_gaussian
from imrbayes.mcmc.sampler import MCMCSettings, run_mcmc
data, bubble = sys.argv[1], sys.argv[2]
fm = ForwardModel("nhkv", options={"bubble": bubble})
cache = Path(data) / f"probe_fit_{bubble}.pkl"
obs = Observations.from_preprocessed(preprocess_dataset(load_dataset(data), skip_failed=True))
space = ParamSpace.for_model(fm.constitutive)
if cache.exists():
    res = pickle.loads(cache.read_bytes())
else:
    t = time.perf_counter(); res = fit_en4dvar(fm, obs, space, En4DVarSettings(), seed=0); print("fit", time.perf_counter() - t, flush=True)
    cache.write_bytes(pickle.dumps(res))
sp = fit_window_specs(fm, obs, space, res)[0]
m0, C0 = start_gaussian(sp, "ensemble")
tg = sp.target
for cfg in sys.argv[3:]:
    settings = MCMCSettings()
    for kv in [x for x in cfg.split(";") if x]:
        k, v = kv.split("="); f = type(getattr(settings, k)); settings = replace(settings, **{k: (v if f is str else f(v))})
    t = time.perf_counter()
    run = run_mcmc(tg, m0, C0, settings, seed=1)
    dg = run.diagnostics()
    draws = run.chain[:, run.burn::run.thin].reshape(-1, tg.ndim)
    ck = dg["checks"][-1] if dg["checks"] else {}
    print(json.dumps({"cfg": cfg, "d": tg.ndim, "evals": run.n_evals, "steps": run.n_steps, "tau": round(run.tau_max, 2),
        "acc": np.round(run.acceptance, 3).tolist(), "stop": dg["stop_reason"], "rhat": ck.get("rhat_max"), "ess": ck.get("ess_bulk_min"),
        "s": round(time.perf_counter() - t, 1), "mean": draws.mean(0)[:2].round(4).tolist(), "sd": draws.std(0)[:2].round(4).tolist(),
        "placement": [{k: (round(v, 3) if isinstance(v, float) else v) for k, v in r.items()} for r in dg.get("placement", {}).get("rounds", [])]}), flush=True)
