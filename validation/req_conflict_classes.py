"""Does the Req conflict separate model error from noise? The z that ``REQ_PRIOR_CONFLICT_Z`` bounds,
on ``diagnose``'s synthetic classes (issue #21).

For each dataset of ``scripts/diagnosis_confusion.py`` (the same seeds: 1000 x class index + s;
nulls 900000 + i cycling through the five null designs) the camera records are made and
preprocessed as ``diagnose`` sees them (:func:`imrbayes.diagnosis.synthetic.camera_obs`, the
default fitted model: thermal bubble, converged grid), the whole-record En4D-Var fit that MIEnKS-MDA
runs for its Req prior is made (:func:`imrbayes.ensemble.mienks.req_prior_from_en4dvar`, no bound),
and each bubble's z = (En4D-Var Req - preprocessing Req) / preprocessing sd is stored with the
preprocessing's Req, the true Req and the En4D-Var estimate of G and mu; since session 69 also the z
of the fit's Rmax and time of the maximum against the preprocessing's local fit (``z_rmax``, ``z_t0``).

    python validation/req_conflict_classes.py OUT.json [--classes none,bubble-thermal,...] [--seeds 5]
        [--seed-offset 0] [--design NAME] [--nulls 20] [--null-offset 0] [--model nhkv]

``--model`` is the constitutive model the En4D-Var fit uses (default NHKV, the baseline): with a
candidate's model it is the direct test of whether that candidate brings each Req back to its tail.

Rows are appended to OUT.json as each dataset finishes; a rerun skips the datasets already in it.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))


def jobs(classes, seeds, seed_offset, nulls, null_offset, design=None, model="nhkv"):
    from diagnosis_confusion import NULL_SEED, _classes
    from imrbayes.diagnosis.synthetic import DESIGNS

    all_classes, designs = _classes(), list(DESIGNS)
    out = [{"kind": "class", "class": c, "seed": 1000 * all_classes.index(c) + s,
            "design": design or designs[0], "model": model}
           for c in classes for s in range(seed_offset, seed_offset + seeds)]
    out += [{"kind": "null", "class": "none", "seed": NULL_SEED + i, "design": designs[i % len(designs)], "model": model}
            for i in range(null_offset, null_offset + nulls)]
    return out


def run(job: dict) -> dict:
    from imrbayes.diagnosis.synthetic import camera_obs
    from imrbayes.ensemble import ParamSpace
    from imrbayes.ensemble.mienks import req_prior_from_en4dvar
    from imrbayes.execution import Execution
    from imrbayes.forward import ForwardModel, ForwardOptions, Runner

    t0 = time.perf_counter()
    opts = ForwardOptions()
    obs, truth = camera_obs(job["class"], job["seed"], opts, design=job["design"])
    fm = ForwardModel(job.get("model", "nhkv"), options=opts)
    space = ParamSpace.for_model(fm.constitutive)
    # no bound: a conflicting bubble would otherwise keep its preprocessing Req and read z = 0
    _, info = req_prior_from_en4dvar(fm, obs, space, job["seed"], Runner(fm), Execution(progress=False),
                                     conflict_z=np.inf)
    pre, psd, post, qsd = (np.array(info[k]) for k in ("preprocessing_req_m", "preprocessing_req_sd_m", "req_m",
                                                        "req_sd_m"))
    true_req = np.array(truth["req_m"])
    return {**job, "z": ((post - pre) / psd).tolist(), "pre_m": pre.tolist(), "pre_sd_m": psd.tolist(),
            "en4dvar_m": post.tolist(), "en4dvar_sd_m": qsd.tolist(), "true_m": true_req.tolist(),
            "en4dvar_estimate": info["en4dvar_estimate"], "truth_theta": truth["theta"],
            "rmse_own": info.get("en4dvar_rmse_own"),
            # the fit's Rmax and time of the maximum against the preprocessing's local fit ("The alignment conflict")
            "z_rmax": [a["z_rmax"] for a in info["en4dvar_alignment_z"]],
            "z_t0": [a["z_t0"] for a in info["en4dvar_alignment_z"]],
            "runtime_s": time.perf_counter() - t0}


def main(argv=None):
    from diagnosis_confusion import _classes

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out")
    ap.add_argument("--classes", default="all", help="comma-separated classes, 'all' or 'none-only'")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--seed-offset", type=int, default=0)
    ap.add_argument("--design", default=None, help="design of the class datasets (default: diagnose's default design)")
    ap.add_argument("--nulls", type=int, default=0)
    ap.add_argument("--null-offset", type=int, default=0)
    ap.add_argument("--model", default="nhkv", help="constitutive model of the En4D-Var fit (default nhkv)")
    a = ap.parse_args(argv)
    classes = _classes() if a.classes == "all" else [c for c in a.classes.split(",") if c]
    unknown = sorted(set(classes) - set(_classes()))
    if unknown:
        sys.exit(f"req_conflict_classes: unknown class(es) {', '.join(unknown)}; known: {', '.join(_classes())}")
    out = Path(a.out)
    rows = json.loads(out.read_text()) if out.exists() else []
    done = {(r["kind"], r["seed"], r["design"], r.get("model", "nhkv")) for r in rows}
    for job in jobs(classes, a.seeds, a.seed_offset, a.nulls, a.null_offset, a.design, a.model):
        if (job["kind"], job["seed"], job["design"], job["model"]) in done:
            continue
        row = run(job)
        rows.append(row)
        out.write_text(json.dumps(rows, indent=1) + "\n")
        z = np.array(row["z"])
        print(f"{job['model']:6s} {job['kind']:5s} {job['class']:24s} {job['seed']:6d} {job['design']:22s} max|z| {np.max(np.abs(z)):6.2f} "
              f"z {np.round(z, 1).tolist()} Rmax z {np.round(np.array(row['z_rmax'], float), 1).tolist()} "
              f"t0 z {np.round(np.array(row['z_t0'], float), 1).tolist()} ({row['runtime_s']:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
