"""Stress benchmark: ``imrbayes fit --method mienks`` on 60 synthetic experiments, peak memory.

Writes a synthetic dataset with ``imrbayes simulate`` (``--n-exp`` experiments, NHKV at the §5 truth,
Rmax and Rmax/Req drawn per experiment, the paper's noise), then runs the full MIEnKS-MDA (every
window, default L, h, iterations; a reduced ensemble ``--n-ens``) as a child process through the
execution layer (units = windows x experiments, each checkpointed), and reports the wall time, the
units, the member runs and the peak resident memory of the fit process (``wait4`` rusage
``ru_maxrss``: the fit process and its waited-for descendants, the largest single process).
With ``--workers N`` the peak of a worker process is counted in the same maximum; the total at any
moment is at most the fit process plus N workers, each below that maximum.

The bubble model is ``--bubble polytropic`` by default (seconds); ``--bubble imrv2-fd`` is the thermal
bubble on IMRv2's coarse finite-difference scheme (~5 ms per member and window: minutes);
``--bubble thermal`` the grid-converged thermal default (hours for 60 experiments on two shared
cores).

The wall time is also printed as a multiple of the host yardstick timed in the same run
(``_machine.host_yardstick``, ``*_per_yardstick``); the JSON keeps the absolute times as facts of the
host named there.

Usage: python benchmarks/stress.py [--n-exp 60] [--n-ens 16] [--workers 1] [--bubble polytropic]
                                   [--keep DIR] [--json results/stress.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _machine import add_yardstick_ratios, host_yardstick, machine_info, results_path

TARGET_GB = 4.0


def _cli() -> list[str]:
    return [sys.executable, "-c", "import sys; from imrbayes.cli import main; sys.exit(main())"]


def _parse_args(argv):
    """The command line (see the module docstring) as an ``argparse.Namespace``."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n-exp", type=int, default=60)
    ap.add_argument("--n-ens", type=int, default=16)
    ap.add_argument("--n-iter", type=int, default=None, help="Gauss-Newton iterations [default: the method's, 5]")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--bubble", choices=["polytropic", "imrv2-fd", "thermal"], default="polytropic")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--keep", default=None, help="keep the dataset and the run directory here")
    ap.add_argument("--json", default=results_path("stress"))
    args = ap.parse_args(argv)
    return args


def _simulate(args, data: Path, fwd: list[str]) -> float | None:
    """Write the synthetic dataset to ``data`` with ``imrbayes simulate``; its wall time [s], or None
    (stderr printed) when it fails."""
    t0 = time.perf_counter()
    sim = subprocess.run(
        _cli()
        + [
            "simulate",
            "--model",
            "nhkv",
            "--param",
            "G=7.29e3",
            "--param",
            "mu=0.088",
            "--rmax",
            "263e-6:25e-6",
            "--ratio",
            "7.58:0.5",
            "--n-exp",
            str(args.n_exp),
            "--noise",
            "paper",
            "--seed",
            str(args.seed),
            *fwd,
            "--out",
            str(data),
            "--quiet",
        ],
        capture_output=True,
        text=True,
    )
    if sim.returncode != 0:
        print(sim.stderr, file=sys.stderr)
        return None
    t_sim = time.perf_counter() - t0
    return t_sim


def _fit(args, data: Path, out: Path, tmp: Path, fwd: list[str]):
    """Run the MIEnKS-MDA fit as a child process (log in ``tmp/fit.log``).

    Returns ``(exit status, wall time [s], the child's rusage)``.
    """
    fit_args = [
        "fit",
        str(data),
        "--method",
        "mienks",
        "--out",
        str(out),
        "--seed",
        str(args.seed),
        "--set",
        f"n_ens={args.n_ens}",
        "--workers",
        str(args.workers),
        "--quiet",
        *fwd,
    ]
    if args.n_iter is not None:
        fit_args += ["--set", f"n_iter={args.n_iter}"]
    t0 = time.perf_counter()
    with open(tmp / "fit.log", "w") as log:
        proc = subprocess.Popen(_cli() + fit_args, stdout=log, stderr=subprocess.STDOUT)
        # wait4: this child's own rusage (including its waited-for worker processes)
        _, status, ru = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - t0
    return proc.returncode, wall, ru


def _row(args, out: Path, wall: float, t_sim: float, ru) -> dict:
    """The result row: settings, counts, times [s], peak memory [MiB] and the estimate from ``out``."""
    scale = 1024.0 if sys.platform != "darwin" else 1024.0 * 1024.0  # ru_maxrss: KiB (Linux), bytes (macOS)
    peak_mib = ru.ru_maxrss / scale
    s = json.loads((out / "summary.json").read_text())
    d, ex = s["details"], s["execution"]
    units_bytes = sum(p.stat().st_size for p in (out / "units").iterdir())
    return {
        "n_experiments": s["n_experiments"],
        "bubble": args.bubble,
        "n_ens": args.n_ens,
        "n_iter": d["settings"]["n_iter"],
        "L": d["settings"]["L"],
        "h": d["settings"]["h"],
        "n_windows": d["n_windows"],
        "workers": args.workers,
        "units": ex["n_units"],
        "units_failed": ex["n_failed"],
        "member_runs": d["member_runs"],
        "failed_member_runs": d["failed_member_runs"],
        "redrawn_members": d["redrawn_members"],
        "wall_s": wall,
        "simulate_s": t_sim,
        "peak_rss_mib": peak_mib,
        "peak_rss_target_gb": TARGET_GB,
        "within_target": peak_mib / 1024 <= TARGET_GB,
        "checkpoints_mib": units_bytes / 2**20,
        "cpu_user_s": ru.ru_utime,
        "cpu_sys_s": ru.ru_stime,
        "estimate": {k: {"mean": v["mean"], "sd": v["sd"]} for k, v in s["estimate"].items()},
        "rmse": s["fit"]["rmse"],
    }


def _print_row(row: dict, args, load) -> None:
    """Print the row as a short table (times as multiples of the host yardstick) and the estimate."""
    print(
        f"MIEnKS-MDA stress: {row['n_experiments']} experiments, {args.bubble} bubble, N_En = {args.n_ens}, "
        f"{row['n_iter']} iterations, L = {row['L']}, h = {row['h']}; {os.cpu_count()} CPUs"
        + (f"; load average {load[0]:.1f}" if load else "")
    )
    cols = [
        ("experiments", "n_experiments", "d"),
        ("windows", "n_windows", "d"),
        ("units", "units", "d"),
        ("workers", "workers", "d"),
        ("member runs", "member_runs", "d"),
        ("wall x yard", "wall_s_per_yardstick", ".0f"),
        ("CPU x yard", "cpu_user_s_per_yardstick", ".0f"),
        ("peak RSS MiB", "peak_rss_mib", ".0f"),
        ("checkpoints MiB", "checkpoints_mib", ".1f"),
    ]
    print("  ".join(f"{c[0]:>{max(len(c[0]), 8)}}" for c in cols))
    print("  ".join(f"{row[c[1]]:>{max(len(c[0]), 8)}{c[2]}}" for c in cols))
    e = row["estimate"]
    print(
        f"G = {e['G']['mean']:.4g} ± {e['G']['sd']:.2g} Pa, mu = {e['mu']['mean']:.4g} ± {e['mu']['sd']:.2g} Pa s "
        f"(truth 7290, 0.088); rmse {row['rmse']:.4g}; failed units {row['units_failed']}; "
        f"peak memory {'within' if row['within_target'] else 'ABOVE'} the {TARGET_GB:g} GB target"
    )


def _meta(yard: dict, load) -> dict:
    """The JSON's ``meta``: the host, its yardstick and load, and how the peak memory is measured."""
    return {
        "cpus": os.cpu_count(),
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "machine": machine_info(),
        "host_yardstick": yard,
        "load_average_1_5_15": list(load) if load else None,
        "peak_rss": "wait4 ru_maxrss of the fit process (max over it and its waited-for descendants)",
    }


def main(argv=None) -> int:
    args = _parse_args(argv)
    tmp = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="imrbayes-stress-"))
    tmp.mkdir(parents=True, exist_ok=True)
    data, out = tmp / "data", tmp / "fit"
    for p in (data, out):
        if p.exists():
            shutil.rmtree(p)
    fwd = {
        "polytropic": ["--forward", "bubble=polytropic"],
        "imrv2-fd": ["--forward", "scheme=imrv2-fd"],
        "thermal": [],
    }[args.bubble]
    t_sim = _simulate(args, data, fwd)
    if t_sim is None:
        return 1
    rc, wall, ru = _fit(args, data, out, tmp, fwd)
    if rc != 0:
        print((tmp / "fit.log").read_text(), file=sys.stderr)
        return 1
    row = _row(args, out, wall, t_sim, ru)
    yard = host_yardstick()
    add_yardstick_ratios(row, yard, seconds_keys=("wall_s", "simulate_s", "cpu_user_s"))
    load = os.getloadavg() if hasattr(os, "getloadavg") else None
    _print_row(row, args, load)
    if args.json:
        Path(args.json).write_text(json.dumps({"meta": _meta(yard, load), "rows": [row]}, indent=2) + "\n")
    if not args.keep:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0 if row["within_target"] and row["units_failed"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
