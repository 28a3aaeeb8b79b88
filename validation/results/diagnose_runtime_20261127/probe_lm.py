"""LM paths of the candidates' whole-record fits on stiff PA bubbles 1-5 (thermal, default)."""
import json, pickle, os, sys, time
from dataclasses import replace
import numpy as np
from imrbayes.data import load_dataset, preprocess_dataset
from imrbayes.data.noise import noise_variance
from imrbayes.ensemble import Observations
from imrbayes.forward import ForwardOptions
from imrbayes.forward.constants import Physics
from imrbayes.diagnosis.candidates import BASELINE
from imrbayes.diagnosis.models import make_candidate
from imrbayes.diagnosis.phases import phases_of
from imrbayes.diagnosis.check import statistics
from imrbayes.diagnosis.lsq import fit_map, grid_starts

ds = load_dataset("../shared/data/lic/estrada2018_stiffPA_270kfps")
pre = preprocess_dataset(ds, skip_failed=True)
obs = Observations.from_preprocessed(pre).take([0, 1, 2, 3, 4])
obs.P = noise_variance(obs.t_star, obs.R_star)[0]
options = ForwardOptions.from_dict(ds.forward or {})
physics = Physics.from_overrides(ds.physics or None)
phases = phases_of(obs, 3)
cache = os.environ.get("PROBE_CACHE", "probe_base.pkl")   # the baseline fit, reused across calls
base = make_candidate(BASELINE.key, options, physics, None)
if os.path.exists(cache):
    z_base, nu_base, om = pickle.load(open(cache, "rb"))
else:
    t = time.time()
    st = statistics(base, obs, phases)
    full = st["fits"]["all"]
    z_base, nu_base, om = full.z, full.nu, st["om"]
    pickle.dump((z_base, nu_base, om), open(cache, "wb"))
    print("baseline", time.time() - t, flush=True)
om0 = replace(om, sd_used=om.noise_sd.copy(), alpha=np.ones(obs.n_exp), n_eff=None, tau=None)
out = {}
for key in sys.argv[1:]:
    c = make_candidate(key, options, physics, None)
    extra = np.concatenate([z_base, c.prior_mean[2:]])
    t = time.time()
    tr1, tr2 = [], []
    f1 = fit_map(c, obs, minima=phases.minima, om=om0, extra_starts=[extra], nu0=nu_base, trace=tr1)
    t1 = time.time() - t
    omt = om0.tempered(obs, f1.fitted)
    f2 = fit_map(c, obs, minima=phases.minima, om=omt, starts=[f1.z], nu0=f1.nu, trace=tr2)
    t2 = time.time() - t - t1
    out[key] = {"t1": t1, "t2": t2, "trace1": tr1, "trace2": tr2, "z1": f1.z.tolist(), "z2": f2.z.tolist(),
                "cost2": f2.cost, "cov2": f2.cov.tolist()}
    print(key, "stage1 %.0f s %d it, stage2 %.0f s %d it" % (t1, len(tr1), t2, len(tr2)), flush=True)
    json.dump(out, open("probe_lm_%s.json" % "_".join(sys.argv[1:]), "w"), indent=1)
