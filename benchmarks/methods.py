"""Inference-method benchmark on the methods.md §5 verification case (5 noisy experiments).

For each forward-model setting and method: wall time, forward member-runs, failed runs, and the
estimate against the truth (G0 = 7.29 kPa, mu0 = 0.088 Pa s). The wall time is printed as a
multiple of the host yardstick timed in the same run (``_machine.host_yardstick``; ``wall_s`` stays in
the JSON as a fact of the host named there). Prints a table; ``--json FILE`` writes the rows.

Usage: python benchmarks/methods.py [--forward polytropic imrv2-fd converged] [--methods imr pimr en4dvar mienks]
                                    [--imr-grid paper|coarse] [--seed 0] [--json results/methods.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np
from _machine import add_yardstick_ratios, host_yardstick, machine_info, results_path

from imrbayes.ensemble import METHODS, IMRSettings, ParamSpace
from imrbayes.forward import ForwardModel, Runner
from imrbayes.io import jsonable
from imrbayes.validation.suite import TRUTH, verification_data

FORWARD = {"polytropic": {"bubble": "polytropic"}, "imrv2-fd": {"scheme": "imrv2-fd"}, "converged": {}}


def _collapse_times(fm, obs):
    """First-collapse time of each noisy record: first local minimum of a parabola through the
    smallest sample and its neighbours (what preprocessing does on measured data)."""
    out = []
    for y in obs.R_star:
        k = int(np.argmin(y[: int(1.5 / 0.025)]))
        den = y[k - 1] - 2 * y[k] + y[k + 1]
        out.append(obs.t_star[k] + (0.5 * (y[k - 1] - y[k + 1]) / den * 0.025 if den > 0 else 0.0))
    return np.array(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--forward", nargs="+", default=["polytropic", "imrv2-fd"], choices=list(FORWARD))
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    ap.add_argument("--imr-grid", default="paper", choices=["paper", "coarse"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default=results_path("methods"))
    args = ap.parse_args()
    rows = []
    yard = host_yardstick()
    print(f"host yardstick (x yard): {yard['row']}, {yard['ms']:.1f} ms in this run")
    print(f"{'forward':<11} {'method':<8} {'x yard':>9} {'runs':>8} {'failed':>6} {'G [kPa]':>16} {'mu [Pa s]':>18}")
    for fkey in args.forward:
        fm = ForwardModel("nhkv", options=FORWARD[fkey])
        fm.simulate({"G": [7e3, 7e3], "mu": [0.1, 0.1]}, 263e-6, 263e-6 / 7.58, [0.0, 0.1])  # compile/load
        obs = verification_data(fm, args.seed)
        obs.t_collapse_star = _collapse_times(fm, obs)
        space = ParamSpace.for_model(fm.constitutive)
        for m in args.methods:
            s = METHODS[m].settings_class()
            if m == "imr" and args.imr_grid == "coarse":
                s = IMRSettings(n_G=40, n_mu=25)
            runner = Runner(fm)
            t0 = time.perf_counter()
            res = METHODS[m].fit(fm, obs, space, s, seed=args.seed, runner=runner)
            wall = time.perf_counter() - t0
            e = res.estimate
            row = {
                "forward": fkey,
                "method": m,
                "wall_s": wall,
                "member_runs": runner.n_member_runs,
                "failed_runs": runner.n_failed,
                "estimate": e,
                "relative_error": {n: e[n]["mean"] / TRUTH[n] - 1.0 for n in TRUTH},
                "rmse": res.rmse,
            }
            rows.append(add_yardstick_ratios(row, yard, seconds_keys=("wall_s",)))
            print(
                f"{fkey:<11} {m:<8} {row['wall_s_per_yardstick']:9.3g} {runner.n_member_runs:8d} {runner.n_failed:6d} "
                f"{e['G']['mean'] / 1e3:8.3f} ± {e['G']['sd'] / 1e3:5.3f} {e['mu']['mean']:8.4f} ± {e['mu']['sd']:6.4f}",
                flush=True,
            )
    meta = {
        "machine": platform.platform(),
        "cpus": os.cpu_count(),
        "numba_threads": os.environ.get("NUMBA_NUM_THREADS"),
        "cpu": machine_info(),
        "host_yardstick": yard,
        "case": "methods.md §5 verification, 5 experiments, paper noise",
        "truth": TRUTH,
        "seed": args.seed,
    }
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(jsonable({"meta": meta, "rows": rows}), fh, indent=1)


if __name__ == "__main__":
    main()
