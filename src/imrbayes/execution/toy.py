"""Toy workloads for the execution layer's tests and benchmark, and a small command line.

:func:`toy_bubble` stands in for a forward solve: it draws a stiffness and a viscosity from the
unit's generator and integrates a damped, nondimensional Rayleigh–Plesset-like oscillator with
explicit RK4 in plain Python floats (CPU-bound, holds the GIL, bit-reproducible), then returns the
samples, the parameters and a few extra draws.

    python -m imrbayes.execution.toy --out DIR --units 20 --sleep 0.2 [--workers 2 | --scheduler local]
                                     [--seed 0] [--resume] [--fail ID ...] [--steps 2000]

prints the run's report as one JSON line; SIGTERM/SIGINT exit with status 128 + signal number after
leaving the run directory resumable.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np

from imrbayes.execution.units import Unit, unit_id

__all__ = ["toy_bubble", "toy_units"]


def toy_bubble(unit, rng) -> dict:
    """One toy unit; ``unit.data``: ``steps`` (RK4 steps, default 2000), ``sleep`` (seconds to wait
    first, default 0), ``fail`` (raise ``ValueError`` if true)."""
    data = (unit.data if isinstance(unit, Unit) else unit.get("data")) or {}
    uid = unit.unit_id if isinstance(unit, Unit) else unit["unit_id"]
    if data.get("sleep"):
        time.sleep(float(data["sleep"]))
    if data.get("fail"):
        raise ValueError(f"toy failure in {uid}")
    steps = int(data.get("steps", 2000))
    G = 1e-2 * math.exp(0.3 * rng.standard_normal())  # nondimensional stiffness
    mu = 5e-3 * math.exp(0.3 * rng.standard_normal())  # nondimensional viscosity
    pg0, kappa = 0.02, 1.4

    def rhs(R, V):
        R = max(R, 0.05)
        pg = pg0 * R ** (-3 * kappa)
        acc = (pg - 1.0 - 4 * mu * V / R - G * (5 - 4 / R - 1 / R**4) / 2 - 1.5 * V * V) / R
        return V, acc

    R, V, h = 1.0, 0.0, 1e-3
    out = np.empty(max(steps // 20, 1))
    k = 0
    for i in range(steps):
        k1r, k1v = rhs(R, V)
        k2r, k2v = rhs(R + 0.5 * h * k1r, V + 0.5 * h * k1v)
        k3r, k3v = rhs(R + 0.5 * h * k2r, V + 0.5 * h * k2v)
        k4r, k4v = rhs(R + h * k3r, V + h * k3v)
        R += h / 6 * (k1r + 2 * k2r + 2 * k3r + k4r)
        V += h / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
        R = max(R, 0.05)
        if i % 20 == 0 and k < out.size:
            out[k] = R
            k += 1
    return {"params": np.array([G, mu]), "R": out[:k], "draws": rng.standard_normal(8), "n_steps": steps, "label": uid}


def toy_units(n: int, *, steps: int = 2000, sleep: float = 0.0, fail=(), windows: int = 1) -> list[Unit]:
    """``n`` experiments x ``windows`` windows of :func:`toy_bubble` units, ids ``exp=000/window=000``;
    ids listed in ``fail`` raise."""
    fail = set(fail)
    units = []
    for e in range(n):
        for w in range(windows):
            uid = unit_id(exp=e, window=w)
            units.append(Unit(uid, {"steps": steps, "sleep": sleep, "fail": uid in fail}))
    return units


def main(argv=None) -> int:
    from imrbayes.errors import InputError
    from imrbayes.execution.backends import make_executor
    from imrbayes.execution.driver import RunInterrupted, run_units
    from imrbayes.execution.store import RunStore

    ap = argparse.ArgumentParser(prog="python -m imrbayes.execution.toy", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="run directory")
    ap.add_argument("--units", type=int, default=20, help="number of experiments (units)")
    ap.add_argument("--windows", type=int, default=1, help="windows per experiment")
    ap.add_argument("--steps", type=int, default=2000, help="RK4 steps per unit")
    ap.add_argument("--sleep", type=float, default=0.0, help="seconds each unit waits first")
    ap.add_argument("--fail", nargs="*", default=[], help="unit ids that raise")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--scheduler", default=None)
    ap.add_argument("--resume", action="store_true")
    ap.add_argument("--retry-failed", action="store_true")
    args = ap.parse_args(argv)

    units = toy_units(args.units, steps=args.steps, sleep=args.sleep, fail=args.fail, windows=args.windows)
    config = {
        "workload": "toy_bubble",
        "units": args.units,
        "windows": args.windows,
        "steps": args.steps,
        "fail": sorted(args.fail),
        "seed": args.seed,
    }
    try:
        with (
            RunStore.open(args.out, config, resume=args.resume) as store,
            make_executor(args.workers, args.scheduler) as ex,
        ):
            report = run_units(
                units, toy_bubble, seed=args.seed, store=store, executor=ex, retry_failed=args.retry_failed
            )
    except RunInterrupted as exc:
        print(f"toy: {exc}", file=sys.stderr)
        return 128 + exc.signum
    except InputError as exc:
        print(f"toy: error: {exc}", file=sys.stderr)
        return 2
    print(
        json.dumps(
            {
                "n_units": report.n_units,
                "n_computed": report.n_computed,
                "n_resumed": report.n_resumed,
                "n_failed": report.n_failed,
                "failed": list(report.failures),
                "wall_s": report.wall_s,
            }
        )
    )
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
