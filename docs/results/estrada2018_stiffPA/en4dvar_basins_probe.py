"""Usage (repository root): python docs/results/estrada2018_stiffPA/en4dvar_basins_probe.py thermal N_ITER N_RUNS [N_ENS] [--no-map]
[--screen=S (default 0: start at the prior mean)] [--seed=K].

Per experiment: En4D-Var's own posterior mean (material + Rmax, t0, Req) vs a single-bubble MAP
with nuisance restarts, both scored by the nuisance-corrected RMSE to the record."""
import sys, time, numpy as np
from imrbayes.data import load_dataset, preprocess_dataset
from imrbayes.ensemble import Observations, En4DVarSettings, fit_en4dvar
from imrbayes.forward import ForwardOptions
from imrbayes.diagnosis.phases import phases_of
from imrbayes.diagnosis.models import make_candidate, BASELINE
from imrbayes.diagnosis.lsq import fit_map, ObsModel, predict
from imrbayes.data.noise import noise_variance
ds = load_dataset("../shared/data/lic/estrada2018_stiffPA_270kfps")  # from the repository root
obs = Observations.from_preprocessed(preprocess_dataset(ds, skip_failed=True)).take([0, 1, 2, 3, 4])
obs.P = noise_variance(obs.t_star, obs.R_star)[0]
opts = ForwardOptions.from_dict({"bubble": sys.argv[1]})
phases = phases_of(obs, 3)
base = make_candidate(BASELINE.key, opts)
t = time.time()
en = fit_en4dvar(base.fm, obs, base.space, En4DVarSettings(n_ens=int(sys.argv[4]) if len(sys.argv)>4 else 48, n_iter=int(sys.argv[2]), n_runs=int(sys.argv[3]), loglik=False, n_draws=1, screen=int(next((a.split("=")[1] for a in sys.argv if a.startswith("--screen=")), 0))), seed=int(next((a.split("=")[1] for a in sys.argv if a.startswith("--seed=")), 0)))
print("en4dvar", round(time.time() - t, 1), "s", {k: round(v["median"], 4) for k, v in en.estimate.items()}, flush=True)
om = ObsModel.of(obs, random_effects=None)
K = obs.n_samples - 1
def rmse(R, n): return float(np.sqrt(np.nanmean((R[1:] - obs.R_star[n, 1:]) ** 2)))
for i, pe in enumerate(en.per_experiment):
    n = i
    G, mu = pe["estimate"]["G"]["median"], pe["estimate"]["mu"]["median"]
    nz = pe["nuisance"]
    a = nz["rmax_m"]["mean"] / nz["rmax_m"]["prior_mean"] - 1
    dl = nz["t0_s"]["offset_star"]
    rho = np.log(nz["req_m"]["mean"] / nz["req_m"]["prior_mean"])
    z = base.to_internal([G, mu])
    R_en = predict(base, z[None], obs, [n], phases.minima, K, np.array([[a, dl, rho]]), om.frames)[0, 0]
    R_en0 = predict(base, z[None], obs, [n], phases.minima, K, None, om.frames)[0, 0]
    if "--no-map" in sys.argv:
        print(f"exp{n+1}: en4dvar G {G/1e3:.2f} kPa mu {mu:.4f} rmse {rmse(R_en, n):.4f}", flush=True); continue
    t = time.time()
    f = fit_map(base, obs, idx=[n], minima=phases.minima, om=om, restarts=True)
    Gm, mum = base.to_si(f.z)
    f2 = fit_map(base, obs, idx=[n], minima=phases.minima, om=om, starts=[z], nu0=np.tile([a, dl, rho], (obs.n_exp, 1)))
    Gm2, mum2 = base.to_si(f2.z)
    sd = om.nu_sd[n, :3]
    print(f"exp{n+1}: en4dvar G {G/1e3:.2f} kPa mu {mu:.4f} nu/sd {np.round(np.array([a, dl, rho]) / sd, 1)} "
          f"rmse {rmse(R_en, n):.4f} (no nu {rmse(R_en0, n):.4f}) | MAP+restarts G {Gm/1e3:.2f} mu {mum:.4f} "
          f"nu/sd {np.round(f.nu[0, :3] / sd, 1)} rmse {rmse(f.fitted[0], n):.4f} cost {f.cost:.1f} | "
          f"MAP from en4dvar point: G {Gm2/1e3:.2f} mu {mum2:.4f} rmse {rmse(f2.fitted[0], n):.4f} cost {f2.cost:.1f} "
          f"({time.time()-t:.0f}s)", flush=True)
