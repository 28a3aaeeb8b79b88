"""Is there a recording design on which the thermal-bubble class (vapour mass transfer off in the
data, fitted with it on) is not absorbed by the baseline's refit?

On the default camera design the baseline (NHKV, thermal bubble with mass transfer) refits such
records to the noise level by moving G +25..+87 % (docs/diagnosis.md, the thermal matrix:
bubble-thermal 0/5). This probe fits the baseline exactly as ``diagnose``'s first stage does
(:func:`imrbayes.diagnosis.lsq.fit_tempered`, nuisances and all) to the class's records and to the
``none`` records of the same seed (same material, bubbles and noise draws) on several designs, and
reports the misfit each leaves in units of the frames' true noise: a design separates the class
when its misfit stands clear of ``none``'s. The misfit is the mean of
((data - fit) / true noise sd)^2 over the analysis grid, in total and per phase (the grid's
interpolation of the frames adds misfit beyond the noise, hence the comparison with ``none``).

    python validation/bubble_thermal_designs.py --seeds 5000 5001 --designs default long \\
        --json validation/results/bubble_thermal_designs.json

Each result is written as soon as it is done; a rerun with the same ``--json`` skips finished ones.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from imrbayes.data import synthetic as syn
from imrbayes.diagnosis.candidates import BASELINE
from imrbayes.diagnosis.lsq import ObsModel, fit_tempered
from imrbayes.diagnosis.models import make_candidate
from imrbayes.diagnosis.phases import phases_of
from imrbayes.diagnosis.synthetic import Design, camera_obs
from imrbayes.forward import ForwardOptions

#: the candidate designs: name -> Design (all 1 Mfps camera records unless said)
PROBE_DESIGNS = {
    # the thermal matrix's design: analysis grid t* <= 3, records to t* = 4
    "default": Design(),
    # the same bubbles filmed three times as long, all of it analysed (the slow settling of a bubble
    # whose vapour condenses against one whose vapour cannot)
    "long": Design("long", t_end_star=10.0, n_steps=360),
    # small bubbles: diffusion times scale as R^2, so mass transfer acts relatively faster (2 Mfps
    # keeps the frames per collapse, 1 um edge noise)
    "small": Design("small", frame_s=0.5e-6, noise="1um", rmax_um=(150.0, 15.0)),
    "small-long": Design("small-long", frame_s=0.5e-6, noise="1um", rmax_um=(150.0, 15.0),
                         t_end_star=10.0, n_steps=360),
}


def misfit(obs, fit, phases, truth) -> dict:
    """Mean squared residual in units of each record's true noise sd, in total and per phase."""
    sd = np.array([syn.noise_sd(np.zeros(1), np.ones(1), truth["noise"], float(r))[0] for r in obs.rmax_m])
    z2 = ((obs.R_star - fit.fitted) / sd[:, None]) ** 2
    out = {"total": float(np.nanmean(z2[:, 1:]))}
    for info, m in zip(phases.to_list(), phases.masks()):
        out[info["phase"]] = float(np.nanmean(z2[:, m]))
    return out


def run_one(cls: str, seed: int, dname: str, opts) -> dict:
    design = PROBE_DESIGNS[dname]
    t0 = time.perf_counter()
    obs, truth = camera_obs(cls, seed, opts, design=design)
    phases = phases_of(obs)
    base = make_candidate(BASELINE.key, opts)
    f, _ = fit_tempered(base, obs, phases.minima, ObsModel.of(obs))
    G, mu = (float(v) for v in base.to_si(f.z)[:2])
    th = truth["theta"]
    return {"class": cls, "seed": seed, "design": dname, "misfit": misfit(obs, f, phases, truth),
            "G_rel": G / th["G"] - 1, "mu_rel": mu / th["mu"] - 1,
            "req_rel": (np.asarray(obs.req_m) * np.exp(f.nu[:, 2]) / np.asarray(truth["req_m"]) - 1).tolist(),
            "n_exp": int(obs.n_exp), "seconds": time.perf_counter() - t0}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[5000, 5001])
    ap.add_argument("--designs", nargs="+", default=list(PROBE_DESIGNS), choices=list(PROBE_DESIGNS))
    ap.add_argument("--classes", nargs="+", default=["bubble-thermal", "none"])
    ap.add_argument("--json", type=Path, default=Path("validation/results/bubble_thermal_designs.json"))
    a = ap.parse_args(argv)
    opts = ForwardOptions()
    done = json.loads(a.json.read_text()) if a.json.exists() else {"rows": []}
    have = {(r["class"], r["seed"], r["design"]) for r in done["rows"]}
    for dname in a.designs:
        for seed in a.seeds:
            for cls in a.classes:
                if (cls, seed, dname) in have:
                    continue
                r = run_one(cls, seed, dname, opts)
                done["rows"].append(r)
                a.json.parent.mkdir(parents=True, exist_ok=True)
                a.json.write_text(json.dumps(done, indent=1) + "\n")
                print(f"{dname:>11} {cls:>15} {seed}: misfit {r['misfit']['total']:.2f} "
                      f"G {r['G_rel']:+.1%} mu {r['mu_rel']:+.1%} ({r['seconds']:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
