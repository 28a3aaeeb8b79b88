"""The realistic fits' speed targets at today's defaults, timed as a user pays them: ``imrbayes fit`` end to end.

``benchmarks/methods.py`` times the methods on the paper's verification case (no nuisances, paper
noise). The speed targets are for realistic fits: **En4D-Var on 20 bubbles with nuisances
<= 3 min, MIEnKS-MDA on 5 <= 2 min**. This script runs the CLI on real data (and, with
``--cases``, on the camera design of the targets) with every default -- thermal bubble on the converged
grid, each experiment's Rmax, Req and time of the maximum inferred, the default likelihood -- in a
subprocess, and reports wall and CPU time, the load average around the run, and the estimate.

Cases (``--cases``; default: the two targets):

``en4dvar-stiffpa20``   En4D-Var, estrada2018_stiffPA_270kfps, all 20 bubbles (target 180 s)
``mienks-stiffpa5``     MIEnKS-MDA, the same data, bubbles 1-5 (target 120 s)
``en4dvar-camera6``     En4D-Var on that camera design (6 bubbles, 1 Mfps, random phase, noise 0.02 R*)
``mienks-camera5``      MIEnKS-MDA on the first 5 bubbles of that design

Usage: python benchmarks/methods_realistic.py [--cases ...] [--json results/methods_realistic.json]
Each case is timed once (a fit takes minutes); run it on a quiet machine -- the load average is
recorded so that a loaded run can be recognised. The 2-core VM lands on hosts up to ~2x apart, so
the run also times a host yardstick before and after the fits (``_machine.host_yardstick``: the
previous-default forward row, 113 ms on the host the targets were set on) and prints each wall
in yardsticks (the faster of the two) and divided by the host factor; the JSON keeps the raw times too.
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
from pathlib import Path

from _machine import add_yardstick_ratios, cpu_label, host_yardstick, machine_info, results_path

ROOT = Path(__file__).resolve().parents[1]
LIC = ROOT.parent / "shared" / "data" / "lic"
STIFF = LIC / "estrada2018_stiffPA_270kfps"
CAMERA = [
    "--model",
    "nhkv",
    "--param",
    "G=5200",
    "--param",
    "mu=0.065",
    "--rmax",
    "320e-6:45e-6",
    "--ratio",
    "7.9:0.45",
    "--n-exp",
    "6",
    "--noise",
    "0.02",
    "--frame-s",
    "1e-6",
    "--t-end",
    "3.6",
    "--seed",
    "11",
]
CASES = {  # name: (data, fit arguments, target [s])
    "en4dvar-stiffpa20": (STIFF, ["--method", "en4dvar"], 180.0),
    "mienks-stiffpa5": (STIFF, ["--method", "mienks", "--experiments", "1-5"], 120.0),
    "en4dvar-camera6": ("camera", ["--method", "en4dvar"], None),
    "mienks-camera5": ("camera", ["--method", "mienks", "--experiments", "1-5"], None),
}


def imrbayes() -> list:
    exe = Path(sys.executable).with_name("imrbayes")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "imrbayes.cli"]


def timed(cmd: list) -> dict:
    """Run ``cmd``; wall [s], children's CPU [s], load averages before and after, return code."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {
        "wall_s": wall,
        "cpu_s": cpu,
        "load_before": load0,
        "load_after": os.getloadavg()[0],
        "returncode": proc.returncode,
        "stderr_tail": proc.stderr[-2000:],
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", default=["en4dvar-stiffpa20", "mienks-stiffpa5"], choices=list(CASES))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default=results_path("methods_realistic"))
    a = ap.parse_args(argv)
    rows = []
    print(f"host: {cpu_label()}; load average now {os.getloadavg()[0]:.2f}")
    yard = [host_yardstick()]
    print(
        f"host yardstick: {yard[0]['row']}: {yard[0]['ms']:.1f} ms against {yard[0]['reference_ms']:.0f} ms on "
        f"the host the targets were set on (host factor {yard[0]['host_factor']:.2f})",
        flush=True,
    )
    print(
        f"{'case':<20} {'wall [s]':>9} {'target':>7} {'CPU [s]':>8} {'load':>10} {'bubbles':>7} "
        f"{'G [kPa]':>16} {'mu [Pa s]':>18}"
    )
    with tempfile.TemporaryDirectory() as tmp:
        camera = Path(tmp) / "camera"
        for name in a.cases:
            data, args, target = CASES[name]
            if data == "camera":
                if not camera.exists():
                    sim = subprocess.run(
                        imrbayes() + ["simulate", *CAMERA, "--out", str(camera), "--quiet"],
                        capture_output=True,
                        text=True,
                    )
                    if sim.returncode:
                        raise SystemExit(f"simulate failed: {sim.stderr.strip()}")
                data = camera
            out = Path(tmp) / name
            r = timed(imrbayes() + ["fit", str(data), *args, "--seed", str(a.seed), "--quiet", "--out", str(out)])
            row = {
                "case": name,
                "data": str(data if data != camera else "camera design of the speed targets"),
                "command": ["imrbayes", "fit", "DATA", *args, "--seed", str(a.seed)],
                "target_s": target,
                **r,
            }
            if r["returncode"] == 0:
                s = json.loads((out / "summary.json").read_text())
                row.update(
                    n_experiments=s.get("n_experiments"),
                    runtime_s=s.get("runtime_s"),
                    estimate={
                        k: {"median": v.get("median"), "hdi95": v.get("hdi95")} for k, v in s["estimate"].items()
                    },
                    forward=s.get("forward"),
                )
                e = row["estimate"]
                est = (
                    f"{e['G']['median'] / 1e3:7.2f} [{e['G']['hdi95'][0] / 1e3:.1f}, {e['G']['hdi95'][1] / 1e3:.1f}] "
                    f"{e['mu']['median']:7.4f} [{e['mu']['hdi95'][0]:.3f}, {e['mu']['hdi95'][1]:.3f}]"
                )
            else:
                est = "FAILED: " + r["stderr_tail"].strip().splitlines()[-1][:60]
            rows.append(row)
            tgt = f"{target:7.0f}" if target else "      -"
            print(
                f"{name:<20} {r['wall_s']:9.1f} {tgt} {r['cpu_s']:8.1f} {r['load_before']:4.2f}-{r['load_after']:4.2f} "
                f"{row.get('n_experiments', '-')!s:>7} {est}",
                flush=True,
            )
    yard.append(host_yardstick())
    fastest = min(yard, key=lambda y: y["ms"])
    factor = fastest["host_factor"]
    print(
        f"host yardstick after the fits: {yard[1]['ms']:.1f} ms; against the faster of the two ({fastest['ms']:.1f} ms) "
        "the walls above are, in yardsticks, and on the reference host (factor "
        f"{factor:.2f}):"
    )
    for r in rows:
        add_yardstick_ratios(r, fastest, seconds_keys=("wall_s", "cpu_s"))
        if r["target_s"]:
            r["target_s_per_yardstick"] = r["target_s"] / (1e-3 * fastest["reference_ms"])
        tgt = f" (target {r['target_s_per_yardstick']:.3g} x yard, {r['target_s']:.0f} s)" if r["target_s"] else ""
        print(f"  {r['case']:<20} {r['wall_s_per_yardstick']:7.3g} x yard, {r['wall_s'] / factor:7.1f} s{tgt}")
    if a.json:
        Path(a.json).write_text(
            json.dumps(
                {
                    "meta": {
                        "machine": machine_info(),
                        "seed": a.seed,
                        "host_yardstick": yard,
                        "note": "one timed run per case, imrbayes fit as a subprocess",
                    },
                    "rows": rows,
                },
                indent=1,
                default=str,
            )
        )
    return 0 if all(r["returncode"] == 0 for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
