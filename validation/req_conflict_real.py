"""The Req conflict of ``imrbayes fit --method en4dvar`` runs on real data: each bubble's fitted Req
against its record's tail, in the tail's sd (the z of :func:`imrbayes.ensemble.req_tail.req_shift_z`).

    python validation/req_conflict_real.py OUT.json LABEL=RUN_FOLDER [LABEL=RUN_FOLDER ...]

Each RUN_FOLDER holds a fit's summary.json (its preprocessing and per-experiment nuisances); prints
one line per run and writes every bubble's z, shift and the estimate as JSON.
"""
import json
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from imrbayes.ensemble.req_tail import REQ_CONFLICT_Z, req_shift_z


def conflict_of(summary: dict) -> dict:
    pre = summary["preprocessing"]["experiments"]
    # the preprocessing's Req and its sd, as the fitted Observations carried them
    obs = SimpleNamespace(names=[e["name"] for e in pre], req_m=np.array([e["req_m"] for e in pre]),
                          nuisance_sd=np.array([[0.0, 0.0, e.get("req_sd_m") or 0.0] for e in pre]))
    t_last = {e["name"]: e.get("t_last_star") for e in pre}
    rows = [{**q, "shift": q["fitted_req_m"] / q["preprocessing_req_m"] - 1.0, "t_last_star": t_last[q["experiment"]]}
            for q in req_shift_z(obs, summary["per_experiment"])]
    z = np.array([r["z"] for r in rows])
    return {"model": summary["model"], "estimate": {k: v["mean"] for k, v in summary["estimate"].items()},
            "rmse": summary["details"].get("rmse"), "bubbles": rows, "n_conflict": int(np.sum(np.abs(z) > REQ_CONFLICT_Z)),
            "median_abs_z": float(np.median(np.abs(z))) if z.size else None,
            "data": summary["preprocessing"]["dataset"]["name"], "command": summary.get("command")}


def main(argv):
    out, runs = Path(argv[0]), dict(a.split("=", 1) for a in argv[1:])
    res = {}
    for label, folder in runs.items():
        c = conflict_of(json.loads((Path(folder) / "summary.json").read_text()))
        res[label] = c
        sh = [r["shift"] for r in c["bubbles"]]
        print(f"{label:24s} {c['model']:6s} {c['n_conflict']:2d} of {len(c['bubbles']):2d} beyond {REQ_CONFLICT_Z:g}, "
              f"median |z| {c['median_abs_z']:.1f}, shifts {100 * min(sh):+.0f} .. {100 * max(sh):+.0f} %")
    out.write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main(sys.argv[1:])
