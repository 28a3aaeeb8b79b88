"""Scale-out benchmark of the execution layer: prints a table and writes JSON (``--json FILE``).

Workload: ``--units`` independent units of :func:`imrbayes.execution.toy.toy_bubble` (explicit RK4 of a
damped Rayleigh–Plesset-like oscillator in plain Python: CPU-bound and GIL-holding, a stand-in for
one forward solve per unit; ``--steps`` sets its cost). The real verification case (a ``fit`` on the
LIC data set, units = experiments x windows) is to be wired here once ``imrbayes fit`` runs its
units through :func:`imrbayes.execution.run_units`.

Rows: in-process; a local process pool for each ``--workers`` value; a Dask ``LocalCluster`` with the
largest worker count (start-up timed separately); in-process with checkpoints to a run directory
(the cost of the atomic writes). Every row's results are checked bit-identical to the first row.

Usage: python benchmarks/scale.py [--units 16] [--steps 60000] [--workers 1 2] [--repeat 1] [--json out.json]
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

from imrbayes.execution import DaskExecutor, InProcessExecutor, ProcessPoolExecutor, RunStore, run_units
from imrbayes.execution.toy import toy_bubble, toy_units


def _identical(a: dict, b: dict) -> bool:
    return list(a) == list(b) and all(
        all(np.array_equal(a[k][f], b[k][f]) and a[k][f].dtype == b[k][f].dtype for f in ("params", "R", "draws"))
        for k in a)


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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--units", type=int, default=16)
    ap.add_argument("--steps", type=int, default=60000, help="RK4 steps per unit (60000: ~0.5 s)")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-dask", action="store_true")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)

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
    rows = [{"backend": label, "workers": w, "wall_s": best[i], "startup_s": started[i][1],
             "identical": _identical(results[i], results[0])} for i, (label, w, _, _) in enumerate(specs)]
    for row in rows:
        row["speedup"] = base_t / row["wall_s"]
        row["per_unit_s"] = row["wall_s"] / args.units

    load = f"; load average {os.getloadavg()[0]:.1f}" if hasattr(os, "getloadavg") else ""
    print(f"{args.units} toy units x {args.steps} RK4 steps; {os.cpu_count()} CPUs; best of {args.repeat}{load}")
    print(f"{'backend':<26}{'workers':>8}{'wall s':>9}{'speedup':>9}{'start-up s':>12}{'identical':>11}")
    for r in rows:
        print(f"{r['backend']:<26}{r['workers']:>8}{r['wall_s']:>9.2f}{r['speedup']:>9.2f}{r['startup_s']:>12.2f}"
              f"{str(r['identical']):>11}")
    if args.json:
        meta = {"units": args.units, "steps": args.steps, "repeat": args.repeat, "cpus": os.cpu_count(),
                "python": sys.version.split()[0], "platform": platform.platform(), "numpy": np.__version__,
                "load_average_1_5_15": list(os.getloadavg()) if hasattr(os, "getloadavg") else None}
        with open(args.json, "w") as fh:
            json.dump({"meta": meta, "rows": rows}, fh, indent=2)
    return 0 if all(r["identical"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
