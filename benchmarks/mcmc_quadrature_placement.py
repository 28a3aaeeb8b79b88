"""Where the quadrature grid of a window starts, and what that costs (docs/mcmc.md, "Cheaper windows").

For windows J of the verification case's MIEnKS-MDA fit (the targets ``fit --mcmc`` builds, as in
``benchmarks/mcmc.py --sweep``): the grid posterior as placed before 2026-11-27 (coarse search from
the ensemble Gaussian, fine 33 x 33 over +-6 sd, widened while the edge holds > 1e-5), then the
fine stage alone (``locate=False``) in the frame of that result's moments -- what converged MCMC
draws give -- at +-6 sd (33 points) and +-7.5 sd (41 points, the same spacing), and in the frame of
the ensemble Gaussian. Per row: evaluations, seconds, edge mass, resolution error, and the moments'
difference from the first row in posterior sd.

Usage: python benchmarks/mcmc_quadrature_placement.py --fit-cache fit.pkl --windows 1 7 --json out.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mcmc import fitted_windows  # noqa: E402

from imrbayes.forward import ForwardModel  # noqa: E402
from imrbayes.mcmc.fit import fit_window_specs  # noqa: E402
from imrbayes.mcmc.quadrature import grid_posterior  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fit-cache", default=None, help="pickle of the MIEnKS fit (benchmarks/mcmc.py --fit-cache)")
    ap.add_argument("--windows", type=int, nargs="+", default=[1, 7])
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    fm = ForwardModel("nhkv", options={})
    obs, space, res = fitted_windows(fm, 0, args.fit_cache)
    out = []
    for j in args.windows:
        (sp,) = fit_window_specs(fm, obs, space, res, windows=[j])
        tg = sp.target

        def run(label, **kw):
            e0, t0 = tg.n_evals, time.perf_counter()
            g = grid_posterior(tg, **kw)
            row = {"window": j, "label": label, "evals": tg.n_evals - e0, "s": time.perf_counter() - t0,
                   "mean": g.mean.tolist(), "sd": g.sd.tolist(), "edge": g.edge_mass, "res": g.resolution_error,
                   "rounds": g.rounds}
            out.append(row)
            return g, row

        ref, row = run("coarse search from the ensemble Gaussian (before)", center=sp.ens_mean, cov=sp.ens_cov)
        print(json.dumps(row), flush=True)
        for label, kw in [("MCMC-moment frame, k 6, n 33", dict(center=ref.mean, cov=ref.cov, locate=False)),
                          ("ensemble frame, k 6, n 33", dict(center=sp.ens_mean, cov=sp.ens_cov, locate=False)),
                          ("MCMC-moment frame, k 7.5, n 41 (now)",
                           dict(center=ref.mean, cov=ref.cov, locate=False, k=7.5, n=41))]:
            g, row = run(label, **kw)
            row["dmean_sd"] = ((g.mean - ref.mean) / ref.sd).tolist()
            row["dsd_rel"] = (g.sd / ref.sd - 1).tolist()
            print(json.dumps({k: row[k] for k in ("window", "label", "evals", "s", "edge", "dmean_sd", "dsd_rel")}),
                  flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)


if __name__ == "__main__":
    main()
