"""Scale-out benchmark of the execution layer: prints a table and writes JSON (``--json FILE``).

Workload: ``--units`` independent units of :func:`imrbayes.execution.toy.toy_bubble` (explicit RK4 of a
damped Rayleigh–Plesset-like oscillator in plain Python: CPU-bound and GIL-holding, a stand-in for
one forward solve per unit; ``--steps`` sets its cost). The real verification case (a ``fit`` on the
§5 verification data set, units = windows x experiments) runs with ``--fit``: MIEnKS-MDA
(``--fit-n-ens`` members, the method's windows and iterations) in this process with the serial
kernel (one core), in this process with numba threads (every core), on a process pool and on a
Dask LocalCluster; every row is checked bit-identical to the first (estimate, every window, the
fitted curves), and the table ends with the speed-up that the unit counts allow on a larger cluster
(windows run in order; within a window the N_exp experiments are independent: at most
N_exp / ceil(N_exp / W) with W workers).

Rows: in-process; a local process pool for each ``--workers`` value; a Dask ``LocalCluster`` with the
largest worker count (start-up timed separately); in-process with checkpoints to a run directory
(the cost of the atomic writes). Every row's results are checked bit-identical to the first row.

Speed is printed as ratios measured in the same run: the speed-up against the first row, and the
wall time as a multiple of the host yardstick (``_machine.host_yardstick``, ``wall_s_per_yardstick``);
the JSON keeps the absolute times as facts of the host named there.

Usage: python benchmarks/scale.py [--units 16] [--steps 60000] [--workers 1 2] [--repeat 1] [--json results/scale_toy_units.json]
       python benchmarks/scale.py --fit [--fit-n-ens 16] [--fit-bubble polytropic] [--workers 2] [--json results/scale_fit.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time

import numpy as np
from _machine import add_yardstick_ratios, host_yardstick, machine_info, results_path

from imrbayes.execution import DaskExecutor, InProcessExecutor, ProcessPoolExecutor, RunStore, run_units
from imrbayes.execution.toy import toy_bubble, toy_units


def _identical(a: dict, b: dict) -> bool:
    return list(a) == list(b) and all(
        all(np.array_equal(a[k][f], b[k][f]) and a[k][f].dtype == b[k][f].dtype for f in ("params", "R", "draws"))
        for k in a
    )


def _start(factory, seed):
    """Build an executor and start its workers (processes, imports) with near-empty units."""
    t0 = time.perf_counter()
    ex = factory()
    run_units(toy_units(max(1, ex.n_workers), steps=1), toy_bubble, seed=seed, executor=ex, progress=False)
    return ex, time.perf_counter() - t0


def _once(ex, units, seed, store_dir=None):
    if store_dir is None:
        t = time.perf_counter()
        rep = run_units(units, toy_bubble, seed=seed, executor=ex, progress=False)
        return time.perf_counter() - t, rep.results
    with RunStore.open(store_dir, {"bench": "scale", "seed": seed}) as store:
        t = time.perf_counter()
        rep = run_units(units, toy_bubble, seed=seed, executor=ex, store=store, progress=False)
        return time.perf_counter() - t, rep.results


def _fit_once(fm, obs, space, settings, seed, ex):
    from imrbayes.ensemble import fit_mienks
    from imrbayes.execution import Execution

    execution = Execution(executor=ex, progress=False)
    t = time.perf_counter()
    res = fit_mienks(fm, obs, space, settings, seed=seed, execution=execution)
    wall = time.perf_counter() - t
    numbers = json.dumps({"estimate": res.estimate, "windows": res.windows}, sort_keys=True, default=str)
    return wall, numbers + repr(res.fitted.tobytes()), execution.summary()


def expected_speedup(n_exp: int, workers: int) -> float:
    """Upper bound from the unit counts: per window, n_exp independent units in ceil(n_exp/W) rounds."""
    return n_exp / -(-n_exp // workers)


def fit_benchmark(args) -> dict:
    """The §5 verification case through MIEnKS-MDA on each backend (see module doc)."""
    from imrbayes.ensemble import MIEnKSSettings, ParamSpace
    from imrbayes.forward import ForwardModel
    from imrbayes.validation.suite import verification_data

    opts = {"bubble": "polytropic"} if args.fit_bubble == "polytropic" else {"scheme": "imrv2-fd"}
    fm_serial = ForwardModel("nhkv", options=opts, parallel=False)
    fm_threads = ForwardModel("nhkv", options=opts, parallel=True)
    obs = verification_data(fm_threads, seed=args.seed)
    space = ParamSpace.for_model(fm_threads.constitutive)
    st = MIEnKSSettings(n_ens=args.fit_n_ens, n_draws=10)
    w = max(args.workers)
    specs = [
        ("in-process, serial kernel", 1, fm_serial, InProcessExecutor),
        ("in-process, numba threads", os.cpu_count(), fm_threads, InProcessExecutor),
        ("process pool", w, fm_serial, lambda: ProcessPoolExecutor(w)),
    ]
    if not args.no_dask:
        specs.append(
            ("Dask LocalCluster", w, fm_serial, lambda: DaskExecutor("local", n_workers=w, threads_per_worker=1))
        )
    rows, ref = [], None
    tiny = MIEnKSSettings(n_ens=4, n_iter=1, n_draws=2)
    _fit_once(fm_serial, obs, space, tiny, args.seed, InProcessExecutor())  # compile (numba cache)
    for label, nw, fm, factory in specs:
        t0 = time.perf_counter()
        ex = factory()
        _fit_once(fm, obs, space, tiny, args.seed, ex)  # start the workers, load the kernels there
        start = time.perf_counter() - t0
        try:
            best, numbers, summ = np.inf, None, None
            for _ in range(args.repeat):
                wall, numbers, summ = _fit_once(fm, obs, space, st, args.seed, ex)
                best = min(best, wall)
        finally:
            ex.close()
        ref = numbers if ref is None else ref
        rows.append(
            {
                "backend": label,
                "workers": nw,
                "wall_s": best,
                "startup_s": start,
                "units": summ["n_units"],
                "identical": numbers == ref,
            }
        )
    yard = host_yardstick()
    for r in rows:
        r["speedup"] = rows[0]["wall_s"] / r["wall_s"]
        add_yardstick_ratios(r, yard, seconds_keys=("wall_s", "startup_s"))
    n_windows = rows[0]["units"] // obs.n_exp
    bound = {str(n): {str(k): expected_speedup(n, k) for k in (1, 2, 4, 5, 8, 16, 32, 64)} for n in (obs.n_exp, 60)}
    load = f"; load average {os.getloadavg()[0]:.1f}" if hasattr(os, "getloadavg") else ""
    print(
        f"MIEnKS-MDA on the §5 verification case ({obs.n_exp} experiments, {args.fit_bubble} bubble, N_En = "
        f"{args.fit_n_ens}, {n_windows} windows = {rows[0]['units']} units); {os.cpu_count()} CPUs; best of "
        f"{args.repeat}{load}"
    )
    print(f"{'backend':<28}{'workers':>8}{'x yard':>9}{'speedup':>9}{'start-up x yard':>16}{'identical':>11}")
    for r in rows:
        print(
            f"{r['backend']:<28}{r['workers']:>8}{r['wall_s_per_yardstick']:>9.3g}{r['speedup']:>9.2f}"
            f"{r['startup_s_per_yardstick']:>16.3g}{str(r['identical']):>11}"
        )
    print("speed-up bound from the unit counts (windows in order, experiments of a window in parallel):")
    for n, b in bound.items():
        print(f"  {n:>3} experiments: " + ", ".join(f"W={k}: {v:.2f}" for k, v in b.items()))
    return {
        "case": "methods.md §5 verification, MIEnKS-MDA",
        "n_experiments": obs.n_exp,
        "n_windows": n_windows,
        "n_ens": args.fit_n_ens,
        "bubble": args.fit_bubble,
        "rows": rows,
        "speedup_bound": bound,
        "host_yardstick": yard,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--units", type=int, default=16)
    ap.add_argument("--steps", type=int, default=60000, help="RK4 steps per unit (60000: ~0.5 s)")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-dask", action="store_true")
    ap.add_argument(
        "--json", default=None, help="[default: results/scale_toy_units.json, with --fit results/scale_fit.json]"
    )
    ap.add_argument(
        "--fit", action="store_true", help="the §5 verification case through MIEnKS-MDA instead of toy units"
    )
    ap.add_argument("--fit-n-ens", type=int, default=16)
    ap.add_argument("--fit-bubble", choices=["polytropic", "imrv2-fd"], default="polytropic")
    args = ap.parse_args(argv)
    if args.json is None:
        args.json = results_path("scale_fit" if args.fit else "scale_toy_units")
    if args.fit:
        res = fit_benchmark(args)
        if args.json:
            meta = {
                "cpus": os.cpu_count(),
                "python": sys.version.split()[0],
                "platform": platform.platform(),
                "machine": machine_info(),
                "numpy": np.__version__,
                "repeat": args.repeat,
                "load_average_1_5_15": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
            }
            with open(args.json, "w") as fh:
                json.dump({"meta": meta, **res}, fh, indent=2)
        return 0 if all(r["identical"] for r in res["rows"]) else 1

    units = toy_units(args.units, steps=args.steps)
    # (label, workers, executor factory, checkpoints?); all started first, then timed round-robin
    # (best of --repeat each), so that a change in background load hits every row alike
    specs = [("in-process", 1, InProcessExecutor, False)]
    specs += [("process-pool", w, (lambda w=w: ProcessPoolExecutor(w)), False) for w in args.workers if w > 1]
    if not args.no_dask:
        w = max(args.workers)
        specs.append(("dask-localcluster", w, lambda: DaskExecutor("local", n_workers=w, threads_per_worker=1), False))
    specs.append(("in-process + checkpoints", 1, InProcessExecutor, True))
    started = [_start(factory, args.seed) for _, _, factory, _ in specs]
    best = [np.inf] * len(specs)
    results = [None] * len(specs)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for r in range(args.repeat):
                for i, (spec, (ex, _)) in enumerate(zip(specs, started)):
                    store_dir = os.path.join(tmp, f"{i}-{r}") if spec[3] else None
                    t, results[i] = _once(ex, units, args.seed, store_dir)
                    best[i] = min(best[i], t)
    finally:
        for ex, _ in started:
            ex.close()
    base_t = best[0]
    yard = host_yardstick()
    rows = [
        {
            "backend": label,
            "workers": w,
            "wall_s": best[i],
            "startup_s": started[i][1],
            "identical": _identical(results[i], results[0]),
        }
        for i, (label, w, _, _) in enumerate(specs)
    ]
    for row in rows:
        row["speedup"] = base_t / row["wall_s"]
        row["per_unit_s"] = row["wall_s"] / args.units
        add_yardstick_ratios(row, yard, seconds_keys=("wall_s", "startup_s", "per_unit_s"))

    load = f"; load average {os.getloadavg()[0]:.1f}" if hasattr(os, "getloadavg") else ""
    print(f"{args.units} toy units x {args.steps} RK4 steps; {os.cpu_count()} CPUs; best of {args.repeat}{load}")
    print(f"{'backend':<26}{'workers':>8}{'x yard':>9}{'speedup':>9}{'start-up x yard':>16}{'identical':>11}")
    for r in rows:
        print(
            f"{r['backend']:<26}{r['workers']:>8}{r['wall_s_per_yardstick']:>9.3g}{r['speedup']:>9.2f}"
            f"{r['startup_s_per_yardstick']:>16.3g}{str(r['identical']):>11}"
        )
    if args.json:
        meta = {
            "units": args.units,
            "steps": args.steps,
            "repeat": args.repeat,
            "cpus": os.cpu_count(),
            "python": sys.version.split()[0],
            "platform": platform.platform(),
            "numpy": np.__version__,
            "machine": machine_info(),
            "host_yardstick": yard,
            "load_average_1_5_15": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        }
        with open(args.json, "w") as fh:
            json.dump({"meta": meta, "rows": rows}, fh, indent=2)
    return 0 if all(r["identical"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
