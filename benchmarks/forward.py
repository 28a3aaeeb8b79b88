"""Forward-model benchmark: prints a table and writes JSON (``--json FILE``).

Rows (issue: Foundation, §4), each for the converged default resolution and for IMRv2's Nt = 25:
  (a) one 48-member batch of the full-physics LIC case (Rmax 263 um, Rmax/Req 7.58, NHKV,
      G 7.29 kPa +- 40 %, mu 0.088 Pa s +- 40 %) over t* in [0, 3] on the dt* = 0.025 grid;
  (b) the same batch over one window (35 samples) starting mid-trajectory across the first collapse;
  (c) the polytropic model for both;
  (d) the max relative error in R (pointwise |dR|/R and max |dR*|) vs a tight-tolerance solve of the
      same discretisation;
  (e) compile time (fresh cache, separate process), load time from the cache, peak memory.
Beside the default (Radau IIA) the table has the previous default integrator (ARK5(4)8L, IMEX)
on the same grid, for comparison. ``--grid-study`` adds the cost of grid convergence: for
wall-clustered grids up to the grid limit (stretch 3, nt 512, rtol 1e-8), relative L2 distance
of R* to the limit, steps and ms per member at the default tolerance (8 members, mass transfer).

Usage: python benchmarks/forward.py [--json out.json] [--repeat 5] [--grid-study]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

from imrbayes.forward import ForwardModel, ForwardOptions

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _machine import cpu_label, machine_info  # noqa: E402

RMAX, RATIO = 263e-6, 7.58
T_STAR = np.arange(121) * 0.025
WINDOW_START = 0.6          # t*; 35 samples to 1.45 cover the first collapse (t* ~ 0.9)
N_MEMBERS = 48


def _params(seed=0):
    rng = np.random.default_rng(seed)
    return {"G": 7290.0 * (1 + 0.4 * rng.uniform(-1, 1, N_MEMBERS)),
            "mu": 0.088 * (1 + 0.4 * rng.uniform(-1, 1, N_MEMBERS))}


def _time(fn, repeat, min_total_s=2.0, max_repeat=200):
    """Best wall time of at least ``repeat`` calls, more (up to ``max_repeat``) for fast rows
    until ``min_total_s`` has been spent: a millisecond row's best of 5 is at the mercy of
    whatever else runs on the machine."""
    best = np.inf
    out = None
    spent = 0.0
    count = 0
    while count < repeat or (spent < min_total_s and count < max_repeat):
        t0 = time.perf_counter()
        out = fn()
        dt = time.perf_counter() - t0
        best = min(best, dt)
        spent += dt
        count += 1
    return best, out


def _errors(R, R_tight):
    ok = np.isfinite(R) & np.isfinite(R_tight)
    return (float(np.max(np.abs(R - R_tight)[ok] / R_tight[ok])), float(np.max(np.abs(R - R_tight)[ok])))


def bench_case(label, options: dict, repeat: int) -> dict:
    params = _params()
    fm = ForwardModel("nhkv", options=ForwardOptions(**options))
    tight = ForwardModel("nhkv", options=ForwardOptions(**{**options, "rtol": 1e-11, "atol": 1e-13}))
    fm.simulate({"G": 7290.0, "mu": 0.088}, RMAX, RMAX / RATIO, T_STAR[:3])  # load/compile
    t_full, full = _time(lambda: fm.simulate(params, RMAX, RMAX / RATIO, T_STAR), repeat)
    ref_full = tight.simulate(params, RMAX, RMAX / RATIO, T_STAR)
    # Window: start from the (tightly) evolved states at WINDOW_START.
    state0 = tight.initial_state(RMAX, RMAX / RATIO, n=N_MEMBERS)
    start = tight.propagate(state0, params, WINDOW_START).end
    t_win_grid = WINDOW_START + np.arange(35) * 0.025
    t_win, win = _time(lambda: fm.propagate(start, params, t_win_grid[-1], t_win_grid), repeat)
    ref_win = tight.propagate(start, params, t_win_grid[-1], t_win_grid)
    rel_full, abs_full = _errors(full.R_star, ref_full.R_star)
    rel_win, abs_win = _errors(win.R_star, ref_win.R_star)
    return {"label": label, "options": fm.options.to_dict(), "n_state": fm.n_state,
            "full_ms": 1e3 * t_full, "window_ms": 1e3 * t_win,
            "steps_per_member_full": float(full.n_steps.mean()), "steps_per_member_window": float(win.n_steps.mean()),
            "failed": int(full.failed.sum() + win.failed.sum()),
            "max_rel_err_R_full": rel_full, "max_abs_err_Rstar_full": abs_full,
            "max_rel_err_R_window": rel_win, "max_abs_err_Rstar_window": abs_win}


_COMPILE_SNIPPET = """
import time, json, numpy as np
t0 = time.perf_counter()
from imrbayes.forward import ForwardModel, ForwardOptions
fm = ForwardModel("nhkv", options=ForwardOptions(**json.loads('{opts}')))
fm.simulate({{"G": 7290.0, "mu": 0.088}}, 263e-6, 263e-6 / 7.58, np.arange(3) * 0.025)
print(time.perf_counter() - t0)
"""


def compile_times(options: dict) -> dict:
    """Wall time of import + first solve in a fresh process: with an empty cache, then cached."""
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "IMRBAYES_CACHE_DIR": tmp, "NUMBA_CACHE_DIR": tmp}
        code = _COMPILE_SNIPPET.format(opts=json.dumps(options))
        first = float(subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                                     check=True).stdout.split()[-1])
        second = float(subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                                      check=True).stdout.split()[-1])
    return {"first_process_s": first, "cached_process_s": second}


GRIDS = [(1.5, 64), (1.5, 128), (2.0, 64), (2.5, 64), (3.0, 64), (3.0, 96), (3.0, 128)]


def grid_study(n_members: int = 8) -> list[dict]:
    """R* distance to the grid limit and cost per member for wall-clustered grids (module doc)."""
    params = {k: v[:n_members] for k, v in _params().items()}
    limit_fm = ForwardModel("nhkv", options=ForwardOptions(nt=512, mt=512, stretch=3.0, rtol=1e-8, atol=1e-10))
    limit = limit_fm.simulate(params, RMAX, RMAX / RATIO, T_STAR, max_steps=20_000_000).R_star
    rows = []
    for stretch, nt in GRIDS:
        fm = ForwardModel("nhkv", options=ForwardOptions(nt=nt, mt=nt, stretch=stretch))
        fm.simulate({"G": 7290.0, "mu": 0.088}, RMAX, RMAX / RATIO, T_STAR[:3])
        dt, out = _time(lambda: fm.simulate(params, RMAX, RMAX / RATIO, T_STAR), 3)
        l2 = np.sqrt(np.sum((out.R_star - limit) ** 2, axis=1) / np.sum(limit ** 2, axis=1))
        rows.append({"stretch": stretch, "nt": nt, "rel_l2_to_limit_max": float(l2.max()),
                     "max_abs_err_Rstar": float(np.max(np.abs(out.R_star - limit))),
                     "steps_per_member": float(out.n_steps.mean()), "ms_per_member": 1e3 * dt / n_members,
                     "failed": int(out.failed.sum())})
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", help="write the results here")
    ap.add_argument("--repeat", type=int, default=5, help="timing repeats (best is reported)")
    ap.add_argument("--no-compile", action="store_true", help="skip the compile-time measurement")
    ap.add_argument("--grid-study", action="store_true", help="add the grid-convergence cost table")
    args = ap.parse_args(argv)
    cases = [
        ("full physics, converged (default)", {}),
        ("  same, previous integrator ARK548", {"integrator": "ark548"}),
        ("full physics, IMRv2 grid Nt=25", {"scheme": "imrv2-fd"}),
        ("polytropic + vapour", {"bubble": "polytropic"}),
    ]
    rows = [bench_case(label, opts, args.repeat) for label, opts in cases]
    result = {"machine": machine_info(),
              "n_members": N_MEMBERS, "rows": rows, "load_average_after": os.getloadavg(),
              "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}
    if not args.no_compile:
        result["compile"] = compile_times({})
    print(f"CPU: {cpu_label(result['machine'])}, {result['machine']['cpus']} cores")
    hdr = f"{'case':36s} {'(a) 0-3 ms':>11s} {'(b) win ms':>10s} {'steps/mbr':>9s} {'(d) rel err':>11s} {'abs err':>8s} {'fail':>4s}"
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        err = max(r["max_rel_err_R_full"], r["max_rel_err_R_window"])
        aerr = max(r["max_abs_err_Rstar_full"], r["max_abs_err_Rstar_window"])
        print(f"{r['label']:36s} {r['full_ms']:11.1f} {r['window_ms']:10.1f} {r['steps_per_member_full']:9.0f} "
              f"{err:11.1e} {aerr:8.1e} {r['failed']:4d}")
    if args.grid_study:
        result["grid_study"] = grid_study()
        print(f"\n{'grid (mass transfer)':22s} {'L2 to limit':>11s} {'max|dR*|':>9s} {'steps':>6s} {'ms/member':>9s}")
        for g in result["grid_study"]:
            print(f"stretch {g['stretch']:.1f}, nt {g['nt']:<5d}   {g['rel_l2_to_limit_max']:11.1e} "
                  f"{g['max_abs_err_Rstar']:9.1e} {g['steps_per_member']:6.0f} {g['ms_per_member']:9.1f}")
    if "compile" in result:
        c = result["compile"]
        print(f"(e) first process (compile) {c['first_process_s']:.1f} s; cached process {c['cached_process_s']:.1f} s; "
              f"peak RSS {result['peak_rss_mb']:.0f} MB")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(result, fh, indent=2)
    return result


if __name__ == "__main__":
    main()
