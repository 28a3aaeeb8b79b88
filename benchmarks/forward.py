"""Forward-model benchmark: prints a table and writes JSON (``--json FILE``).

Rows, each for the converged default resolution (stretch 2.75, nt 96), the previous default grid (stretch 1.5, nt 64) and IMRv2's Nt = 25:
  (a) one 48-member batch of the full-physics LIC case (Rmax 263 um, Rmax/Req 7.58, NHKV,
      G 7.29 kPa +- 40 %, mu 0.088 Pa s +- 40 %) over t* in [0, 3] on the dt* = 0.025 grid;
  (b) the same batch over one window (35 samples) starting mid-trajectory across the first collapse;
  (c) the polytropic model for both;
  (d) the max relative error in R (pointwise |dR|/R and max |dR*|) vs a tight-tolerance solve of the
      same discretisation;
  (e) compile time (fresh cache, separate process), load time from the cache, peak memory.
Beside the default (Radau IIA) the table has the previous default integrator (ARK5(4)8L, IMEX)
on the previous grid, for comparison (a machine-speed reference across hosts). ``--grid-study`` adds the cost of grid convergence: for
wall-clustered grids up to the grid limit (stretch 3, nt 512, rtol 1e-8), relative L2 distance
of R* to the limit, steps and ms per member at the default tolerance (8 members, mass transfer).

``--peers`` adds PyIMR (``pyimr`` on the package index; ``pip install imrbayes[peers]``), the other
Python IMR solver (JAX/diffrax, Chebyshev collocation of the bubble's fields), on the same case in the
same run: a single solve, and per member of a batch (``solve_sweep`` over G and mu), at its
defaults; and the two codes' R* against each other at their grid limits (ours: stretch 3, nt 2048,
rtol 1e-9; PyIMR's: spectral, ``--peer-limit-nt`` points, rtol 1e-10), with PyIMR's own constants
and with ours (PyIMR's polytropic exponent 1.4 against IMRv2's 1.47). Without pyimr it prints one
line saying so.

Speed is reported as ratios measured in the same run: every time also as a multiple of the host
yardstick (``_machine.host_yardstick``, ``*_per_yardstick``), and with ``--peers`` ours against
PyIMR's (``*_over_pyimr``); the absolute times are kept in the JSON as facts of the host named there.

Usage: python benchmarks/forward.py [--json results/forward.json] [--repeat 5] [--grid-study] [--peers]
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
from _machine import add_yardstick_ratios, cpu_label, host_yardstick, machine_info, results_path

from imrbayes.forward import ForwardModel, ForwardOptions

RMAX, RATIO = 263e-6, 7.58
T_STAR = np.arange(121) * 0.025
WINDOW_START = 0.6  # t*; 35 samples to 1.45 cover the first collapse (t* ~ 0.9)
N_MEMBERS = 48


def _params(seed=0):
    rng = np.random.default_rng(seed)
    return {
        "G": 7290.0 * (1 + 0.4 * rng.uniform(-1, 1, N_MEMBERS)),
        "mu": 0.088 * (1 + 0.4 * rng.uniform(-1, 1, N_MEMBERS)),
    }


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
    return {
        "label": label,
        "options": fm.options.to_dict(),
        "n_state": fm.n_state,
        "full_ms": 1e3 * t_full,
        "window_ms": 1e3 * t_win,
        "steps_per_member_full": float(full.n_steps.mean()),
        "steps_per_member_window": float(win.n_steps.mean()),
        "failed": int(full.failed.sum() + win.failed.sum()),
        "max_rel_err_R_full": rel_full,
        "max_abs_err_Rstar_full": abs_full,
        "max_rel_err_R_window": rel_win,
        "max_abs_err_Rstar_window": abs_win,
    }


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
        first = float(
            subprocess.run(
                [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
            ).stdout.split()[-1]
        )
        second = float(
            subprocess.run(
                [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
            ).stdout.split()[-1]
        )
    return {"first_process_s": first, "cached_process_s": second}


GRIDS = [(1.5, 64), (1.5, 128), (2.0, 64), (2.5, 64), (2.75, 96), (3.0, 64), (3.0, 96), (3.0, 128)]


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
        l2 = np.sqrt(np.sum((out.R_star - limit) ** 2, axis=1) / np.sum(limit**2, axis=1))
        rows.append(
            {
                "stretch": stretch,
                "nt": nt,
                "rel_l2_to_limit_max": float(l2.max()),
                "max_abs_err_Rstar": float(np.max(np.abs(out.R_star - limit))),
                "steps_per_member": float(out.n_steps.mean()),
                "ms_per_member": 1e3 * dt / n_members,
                "failed": int(out.failed.sum()),
            }
        )
    return rows


def _peer_case():
    """The LIC case as PyIMR's SimulationConfig arguments (KM, thermal bubble, vapour, mass transfer, cold medium)."""
    return dict(R0=RMAX, Req=RMAX / RATIO, radial=2, vapor=1, bubtherm=1, masstrans=1, medtherm=0)


def peer_rows(repeat: int = 3, batch: int = 8, limit_nt: int = 65) -> dict:
    """PyIMR on the LIC case: timings at its defaults and R* at both codes' grid limits (module doc)."""
    try:
        import pyimr
    except ImportError:
        return {"installed": False}
    from pyimr import NeoHookeanKelvinVoigt, PhysicalParameters, SimulationConfig, prepare

    ours_physics = ForwardModel("nhkv").physics
    tc = RMAX / np.sqrt(ours_physics.p8 / ours_physics.rho)
    tv = T_STAR * tc
    mat = NeoHookeanKelvinVoigt(7290.0, 0.088)
    res = {
        "installed": True,
        "version": pyimr.__version__,
        "case": "LIC, KM, thermal, vapour, mass transfer, cold medium",
    }
    cfg = SimulationConfig(material=mat, **_peer_case())
    res["defaults"] = {
        "thermal": cfg.thermal,
        "Nt": cfg.Nt,
        "rtol": cfg.rtol,
        "atol": cfg.atol,
        "polytropic_exponent": cfg.physics.polytropic_exponent,
    }
    t0 = time.perf_counter()
    prob = prepare(cfg)
    first = prob.solve(tv)
    res["first_solve_s"] = time.perf_counter() - t0  # includes JAX tracing and compilation
    t_single, _ = _time(lambda: prob.solve(tv), repeat, min_total_s=0.0, max_repeat=repeat)
    res["single_ms"] = 1e3 * t_single
    res["single_success"] = bool(first.stats.success)
    # per member of a batch: solve_sweep over (G, mu), the benchmark batch's first members
    p = _params()
    vals = np.column_stack([p["G"][:batch], p["mu"][:batch]])
    paths = ["material.shear_modulus_pa", "material.viscosity_pa_s"]
    prob.solve_sweep(tv, paths, vals)  # trace/compile at this width
    t_batch, _ = _time(lambda: prob.solve_sweep(tv, paths, vals), 1, min_total_s=0.0, max_repeat=1)
    res["batch"] = batch
    res["batch_ms_per_member"] = 1e3 * t_batch / batch
    # ours on the same single case and batch, same run, default options
    fm = ForwardModel("nhkv")
    fm.simulate({"G": 7290.0, "mu": 0.088}, RMAX, RMAX / RATIO, T_STAR[:3])
    t_ours, ours_default = _time(lambda: fm.simulate({"G": 7290.0, "mu": 0.088}, RMAX, RMAX / RATIO, T_STAR), repeat)
    res["ours_single_ms"] = 1e3 * t_ours
    pb = {"G": p["G"][:batch], "mu": p["mu"][:batch]}
    t_ours_b, _ = _time(lambda: fm.simulate(pb, RMAX, RMAX / RATIO, T_STAR), repeat)
    res["ours_batch_ms_per_member"] = 1e3 * t_ours_b / batch
    res["single_over_pyimr"] = res["ours_single_ms"] / res["single_ms"]
    res["batch_per_member_over_pyimr"] = res["ours_batch_ms_per_member"] / res["batch_ms_per_member"]
    # grid limits
    lim = ForwardModel("nhkv", options=ForwardOptions(nt=2048, mt=2048, stretch=3.0, rtol=1e-9, atol=1e-11))
    R_lim = lim.simulate({"G": 7290.0, "mu": 0.088}, RMAX, RMAX / RATIO, T_STAR, max_steps=50_000_000).R_star[0]
    rel = lambda a, b: float(np.linalg.norm(a - b) / np.linalg.norm(b))  # noqa: E731
    res["ours_default_to_our_limit"] = rel(ours_default.R_star[0], R_lim)
    res["peer_default_to_our_limit"] = rel(np.asarray(first.radius_ratio), R_lim)
    comparisons = {}
    for label, phys in (
        ("pyimr_constants", PhysicalParameters()),
        ("our_constants", PhysicalParameters(polytropic_exponent=ours_physics.kappa)),
    ):
        rows = {}
        for nt in (limit_nt // 2 + 1, limit_nt):
            c = SimulationConfig(material=mat, Nt=nt, rtol=1e-10, atol=1e-12, physics=phys, **_peer_case())
            rows[nt] = np.asarray(prepare(c).solve(tv).radius_ratio)
        lo, hi = sorted(rows)
        comparisons[label] = {
            "peer_nt": hi,
            "peer_self_refinement": rel(rows[lo], rows[hi]),
            "to_our_limit": rel(rows[hi], R_lim),
            "max_abs_Rstar": float(np.max(np.abs(rows[hi] - R_lim))),
        }
    res["limits"] = comparisons
    return res


def _print_peers(pr: dict) -> None:
    if not pr.get("installed"):
        print("\npeer PyIMR: not installed (pip install 'imrbayes[peers]' or pip install pyimr); no peer row")
        return
    d = pr["defaults"]
    print(f"\npeer PyIMR {pr['version']} ({d['thermal']}, Nt {d['Nt']}, rtol {d['rtol']:g}), {pr['case']}:")
    print(
        f"  imrbayes time / PyIMR time, same run: single solve {pr['single_over_pyimr']:.3f}; per member of a "
        f"{pr['batch']}-member batch {pr['batch_per_member_over_pyimr']:.3f} (PyIMR's first solve, JAX compile "
        f"included: {pr['first_solve_s']:.1f} s)"
    )
    print(
        f"  rel. L2 in R* to our grid limit: PyIMR default {pr['peer_default_to_our_limit']:.1e}, "
        f"imrbayes default {pr['ours_default_to_our_limit']:.1e}"
    )
    for label, c in pr["limits"].items():
        print(
            f"  at the grid limits ({label}): PyIMR Nt {c['peer_nt']} vs imrbayes stretch 3 nt 2048: "
            f"rel. L2 {c['to_our_limit']:.1e}, max |dR*| {c['max_abs_Rstar']:.1e} "
            f"(PyIMR's own Nt refinement {c['peer_self_refinement']:.1e})"
        )


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", default=results_path("forward"), help="write the results here")
    ap.add_argument("--repeat", type=int, default=5, help="timing repeats (best is reported)")
    ap.add_argument("--no-compile", action="store_true", help="skip the compile-time measurement")
    ap.add_argument("--grid-study", action="store_true", help="add the grid-convergence cost table")
    ap.add_argument("--peers", action="store_true", help="add PyIMR (if installed) on the same case")
    ap.add_argument("--peer-batch", type=int, default=8, help="members of PyIMR's batch row")
    ap.add_argument("--peer-limit-nt", type=int, default=65, help="PyIMR's collocation points at its grid limit")
    ap.add_argument("--only-peers", action="store_true", help="run only the peer rows")
    args = ap.parse_args(argv)
    cases = [
        ("full physics, converged (default)", {}),
        ("  previous default grid (1.5, nt 64)", {"stretch": 1.5, "nt": 64, "mt": 64}),
        ("  same, previous integrator ARK548", {"integrator": "ark548", "stretch": 1.5, "nt": 64, "mt": 64}),
        ("full physics, IMRv2 grid Nt=25", {"scheme": "imrv2-fd"}),
        ("polytropic + vapour", {"bubble": "polytropic"}),
    ]
    load_before = os.getloadavg()  # other jobs on the machine inflate every timing: recorded beside them
    yard = host_yardstick(args.repeat)
    rows = [] if args.only_peers else [bench_case(label, opts, args.repeat) for label, opts in cases]
    for r in rows:
        add_yardstick_ratios(r, yard, ms_keys=("full_ms", "window_ms"))
    result = {
        "machine": machine_info(),
        "host_yardstick": yard,
        "n_members": N_MEMBERS,
        "rows": rows,
        "load_average_before": load_before,
    }
    if not args.no_compile and not args.only_peers:
        result["compile"] = add_yardstick_ratios(
            compile_times({}), yard, seconds_keys=("first_process_s", "cached_process_s")
        )
    print(
        f"CPU: {cpu_label(result['machine'])}, {result['machine']['cpus']} cores; load average "
        f"{', '.join(f'{x:.2f}' for x in result['load_average_before'])}"
    )
    print(f"times in host yardsticks (x yard): {yard['row']}, {yard['ms']:.1f} ms in this run")
    if rows:
        hdr = (
            f"{'case':36s} {'(a) x yard':>10s} {'(b) x yard':>10s} {'steps/mbr':>9s} {'(d) rel err':>11s} "
            f"{'abs err':>8s} {'fail':>4s}"
        )
        print(hdr)
        print("-" * len(hdr))
        for r in rows:
            err = max(r["max_rel_err_R_full"], r["max_rel_err_R_window"])
            aerr = max(r["max_abs_err_Rstar_full"], r["max_abs_err_Rstar_window"])
            print(
                f"{r['label']:36s} {r['full_ms_per_yardstick']:10.3g} {r['window_ms_per_yardstick']:10.3g} "
                f"{r['steps_per_member_full']:9.0f} {err:11.1e} {aerr:8.1e} {r['failed']:4d}"
            )
    if args.grid_study:
        result["grid_study"] = [add_yardstick_ratios(g, yard, ms_keys=("ms_per_member",)) for g in grid_study()]
        print(
            f"\n{'grid (mass transfer)':22s} {'L2 to limit':>11s} {'max|dR*|':>9s} {'steps':>6s} {'member x yard':>13s}"
        )
        for g in result["grid_study"]:
            print(
                f"stretch {g['stretch']:.1f}, nt {g['nt']:<5d}   {g['rel_l2_to_limit_max']:11.1e} "
                f"{g['max_abs_err_Rstar']:9.1e} {g['steps_per_member']:6.0f} {g['ms_per_member_per_yardstick']:13.3g}"
            )
    if "compile" in result:
        c = result["compile"]
        print(
            f"(e) first process (compile) {c['first_process_s_per_yardstick']:.3g} x yard; cached process "
            f"{c['cached_process_s_per_yardstick']:.3g} x yard; "
            f"peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0:.0f} MB"
        )
    if args.peers or args.only_peers:
        result["peers"] = {"pyimr": peer_rows(batch=args.peer_batch, limit_nt=args.peer_limit_nt)}
        _print_peers(result["peers"]["pyimr"])
    result["load_average_after"] = os.getloadavg()
    result["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f"load average after: {', '.join(f'{x:.2f}' for x in result['load_average_after'])}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(result, fh, indent=2)
    return result


if __name__ == "__main__":
    main()
