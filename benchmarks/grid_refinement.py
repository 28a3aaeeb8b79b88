"""Grid-refinement study of the converged scheme (issue #20, part 1): which bubble grid is within
1.5e-3 (relative L2 in R*, t* in [0, 3]) of the grid limit, at least cost.

Cases (NHKV, Keller-Miksis, thermal bubble with vapour, cold medium; each with and without mass
transfer):
  lic   -- the verification case (methods.md §5): Rmax 263 um, Rmax/Req 7.58, G 7.29 kPa, mu 0.088 Pa s;
  stiff -- G 20 kPa, mu 0.11 Pa s, Rmax 350 um, Rmax/Req 7;
  soft  -- G 1 kPa, mu 0.02 Pa s, Rmax 300 um, Rmax/Req 8.5 (violent collapses, several rebounds);
  lic8  -- the 8 first members of the forward benchmark's batch (G, mu +- 40 % around LIC), worst member;
  wide16 -- held out from the selection (``--cases wide16 --grids ...``): 16 bubbles drawn log-uniformly
      over G 0.5-30 kPa, mu 0.01-0.3 Pa s, Rmax 150-450 um, Rmax/Req 5-10; worst member.

The grid limit of each case is the wall-clustered grid at stretch 3 with nt = 2048 points, integrated
at rtol 1e-9; printed beside it, its distance to nt = 1024 (same clustering) and to stretch 2.5 at
nt = 2048 (another clustering converging, more slowly, to the same limit). Each candidate
(stretch, nt) is integrated at the default tolerance of the scheme (what a user gets: grid plus time
error) and at rtol 1e-9 (grid error alone). Cost: mean Radau steps per member and nt (the cost of a
step is linear in nt); wall times of the 48-member batch are in benchmarks/forward.py.

Usage: python benchmarks/grid_refinement.py [--json benchmarks/results/grid_refinement.json]
       [--cases lic,stiff,...] [--stretches 2,2.5,3] [--nts 32,48,64] [--no-tight]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

from imrbayes.forward import ForwardModel, ForwardOptions

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _machine import cpu_label, machine_info  # noqa: E402

T_STAR = np.arange(121) * 0.025
BOUND = 1.5e-3

CASES = {
    "lic": dict(G=7290.0, mu=0.088, rmax=263e-6, ratio=7.58),
    "stiff": dict(G=20e3, mu=0.11, rmax=350e-6, ratio=7.0),
    "soft": dict(G=1e3, mu=0.02, rmax=300e-6, ratio=8.5),
}


def case_setup(name):
    """(params, rmax, req) of a case name (``lic8`` is a batch)."""
    if name == "lic8":
        rng = np.random.default_rng(0)
        G = 7290.0 * (1 + 0.4 * rng.uniform(-1, 1, 48))
        mu = 0.088 * (1 + 0.4 * rng.uniform(-1, 1, 48))
        return {"G": G[:8], "mu": mu[:8]}, 263e-6, 263e-6 / 7.58
    if name == "wide16":
        # held out from the selection: 16 bubbles drawn over the range of gels and bubbles
        rng = np.random.default_rng(20)
        rmax = rng.uniform(150e-6, 450e-6, 16)
        return ({"G": 10 ** rng.uniform(np.log10(500.0), np.log10(30e3), 16),
                 "mu": 10 ** rng.uniform(-2, np.log10(0.3), 16)}, rmax, rmax / rng.uniform(5.0, 10.0, 16))
    c = CASES[name]
    return {"G": c["G"], "mu": c["mu"]}, c["rmax"], c["rmax"] / c["ratio"]


def solve(name, mass_transfer, nt, stretch, rtol=None):
    """R* (members, 121), mean Radau steps, failed count, wall time of the solve (one run; the
    48-member batch timings are benchmarks/forward.py's)."""
    kw = {} if rtol is None else {"rtol": rtol, "atol": rtol * 1e-2}
    fm = ForwardModel("nhkv", options=ForwardOptions(nt=nt, mt=nt, stretch=stretch, mass_transfer=mass_transfer,
                                                     **kw))
    params, rmax, req = case_setup(name)
    fm.simulate(params, rmax, req, T_STAR[:2])          # load the kernel
    t0 = time.perf_counter()
    out = fm.simulate(params, rmax, req, T_STAR, max_steps=50_000_000)
    return np.atleast_2d(out.R_star), float(out.n_steps.mean()), int(out.failed.sum()), time.perf_counter() - t0


def rel_l2(a, b):
    """Worst member's ||a - b|| / ||b|| (rows are members)."""
    return float(np.max(np.linalg.norm(a - b, axis=1) / np.linalg.norm(b, axis=1)))


def study(cases, grids, tight=True, limit=(3.0, 2048), log=print):
    rows, limits = [], {}
    for name in cases:
        for mass in (True, False):
            key = f"{name}{'' if mass else '_nomass'}"
            t0 = time.perf_counter()
            lim, lsteps, lfail, _ = solve(name, mass, limit[1], limit[0], rtol=1e-9)
            half, _, _, _ = solve(name, mass, limit[1] // 2, limit[0], rtol=1e-9)
            # another clustering at the limit's resolution
            other, _, _, _ = solve(name, mass, limit[1], 2.5, rtol=1e-9)
            limits[key] = {"stretch": limit[0], "nt": limit[1], "steps": lsteps, "failed": lfail,
                           "rel_l2_half_to_limit": rel_l2(half, lim), "rel_l2_stretch2.5_to_limit": rel_l2(other, lim),
                           "seconds": time.perf_counter() - t0}
            log(f"{key}: limit (stretch {limit[0]}, nt {limit[1]}): nt/2 is {limits[key]['rel_l2_half_to_limit']:.1e} "
                f"from it, stretch 2.5 at nt {limit[1]} {limits[key]['rel_l2_stretch2.5_to_limit']:.1e}; "
                f"{lsteps:.0f} steps, {lfail} failed")
            for stretch, nt in grids:
                R, steps, fail, wall = solve(name, mass, nt, stretch)
                row = {"case": key, "stretch": stretch, "nt": nt, "rel_l2": rel_l2(R, lim),
                       "max_abs": float(np.max(np.abs(R - lim))), "steps": steps, "failed": fail,
                       "ms_per_member": 1e3 * wall / R.shape[0]}
                if tight:
                    Rt, _, _, _ = solve(name, mass, nt, stretch, rtol=1e-9)
                    row["rel_l2_grid_only"] = rel_l2(Rt, lim)
                rows.append(row)
                log(f"  {key:12s} stretch {stretch:4.2f} nt {nt:4d}: L2 {row['rel_l2']:.2e} "
                    f"(grid only {row.get('rel_l2_grid_only', np.nan):.2e}) max|dR*| {row['max_abs']:.1e} "
                    f"steps {steps:6.0f} {row['ms_per_member']:6.1f} ms/member fail {fail}  "
                    f"load {os.getloadavg()[0]:.2f}")
    return rows, limits


def summary(rows, log=print):
    """Per (stretch, nt): the worst case and whether it meets the bound; cheapest first (nt x steps)."""
    grids = sorted({(r["stretch"], r["nt"]) for r in rows})
    table = []
    for s, n in grids:
        sel = [r for r in rows if (r["stretch"], r["nt"]) == (s, n)]
        worst = max(sel, key=lambda r: r["rel_l2"])
        cost = n * float(np.mean([r["steps"] for r in sel if r["case"].startswith("lic8")] or
                                 [r["steps"] for r in sel]))
        table.append({"stretch": s, "nt": n, "worst_rel_l2": worst["rel_l2"], "worst_case": worst["case"],
                      "meets_bound": bool(worst["rel_l2"] <= BOUND and all(r["failed"] == 0 for r in sel)),
                      "cost_nt_x_steps": cost})
    table.sort(key=lambda t: t["cost_nt_x_steps"])
    log(f"\n{'stretch':>7s} {'nt':>5s} {'worst L2':>9s} {'worst case':>14s} {'nt*steps':>9s}  meets {BOUND:g}")
    for t in table:
        log(f"{t['stretch']:7.2f} {t['nt']:5d} {t['worst_rel_l2']:9.2e} {t['worst_case']:>14s} "
            f"{t['cost_nt_x_steps']:9.0f}  {'yes' if t['meets_bound'] else 'no'}")
    return table


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", default=None)
    ap.add_argument("--cases", default="lic,stiff,soft,lic8")
    ap.add_argument("--stretches", default="1.5,2,2.5,2.75,3,3.5")
    ap.add_argument("--nts", default="32,40,48,56,64,80,96")
    ap.add_argument("--grids", default=None, help="explicit STRETCH:NT list (overrides --stretches/--nts)")
    ap.add_argument("--limit-nt", type=int, default=2048)
    ap.add_argument("--no-tight", action="store_true", help="skip the tight-tolerance (grid error only) solves")
    args = ap.parse_args(argv)
    cases = [c.strip() for c in args.cases.split(",") if c.strip()]
    stretches = [float(s) for s in args.stretches.split(",")]
    nts = [int(n) for n in args.nts.split(",")]
    machine = machine_info()
    print(f"CPU: {cpu_label(machine)}, {machine['cpus']} cores; load {os.getloadavg()}", flush=True)
    grids = ([(float(g.split(":")[0]), int(g.split(":")[1])) for g in args.grids.split(",")] if args.grids
             else [(s, n) for s in stretches for n in nts])
    rows, limits = study(cases, grids, tight=not args.no_tight, limit=(3.0, args.limit_nt),
                         log=lambda s: print(s, flush=True))
    table = summary(rows)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"machine": machine, "bound": BOUND, "t_star_max": float(T_STAR[-1]), "cases": CASES,
                       "limits": limits, "rows": rows, "summary": table,
                       "load_average_after": os.getloadavg()}, fh, indent=2)


if __name__ == "__main__":
    main()
