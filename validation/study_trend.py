"""Is ``imrbayes study``'s trend calibrated? G linear in a label, mu constant, camera-style records.

Each seed makes one study: three gels at concentrations 1, 2, 4 (%) with G = 2 kPa x concentration
+ 2 kPa and the same mu = 0.05 Pa s, each recorded as 3 bubbles by a 1 Mfps camera (random frame
phase, 2 µm noise, polytropic bubble), fitted by En4D-Var through ``imrbayes study``. Claims checked
over the seeds:

* the 95 % interval of the slope of ln G on the concentration holds the true slope (the
  least-squares slope of ln G_true on the concentration: what the study's slope estimates) in about
  95 % of the seeds, and P(slope > 0) is above 0.975 (G rises) in most;
* mu: the 95 % interval of its slope holds 0, and the extreme conditions' mu ratio holds 1, in
  about 95 % of the seeds (a false "mu differs" at about 5 %).

    python validation/study_trend.py --quick             # 2 seeds, shorter records: minutes
    python validation/study_trend.py --seeds 20           # the claim: ~1 min per seed on 2 cores

Writes one JSON (``--json``) with every seed's trend and the coverage counts.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

CONCENTRATIONS = (1.0, 2.0, 4.0)
MU = 0.05


def true_g(c: float) -> float:
    """The gel's shear modulus [Pa] at concentration ``c`` [%]."""
    return 2000.0 * c + 2000.0


def true_log_slope() -> float:
    """Least-squares slope of ln G_true on the concentrations: the study's estimand."""
    return float(np.polyfit(CONCENTRATIONS, np.log([true_g(c) for c in CONCENTRATIONS]), 1)[0])


def _invoke(args) -> None:
    from imrbayes.cli import main

    main.main([str(a) for a in args], prog_name="imrbayes", standalone_mode=False)


def one_seed(seed: int, root: Path, quick: bool) -> dict:
    """Simulate the seed's three gels, run the study, return its trends."""
    n_exp, t_end = (2, 1.5) if quick else (3, 3.0)
    data = []
    for c in CONCENTRATIONS:
        d = root / f"s{seed}_c{c:g}"
        _invoke(
            [
                "simulate",
                "--model",
                "nhkv",
                "--param",
                f"G={true_g(c)}",
                "--param",
                f"mu={MU}",
                "--n-exp",
                n_exp,
                "--forward",
                "bubble=polytropic",
                "--t-end",
                t_end,
                "--frame-s",
                "1e-6",
                "--phase",
                "random",
                "--noise",
                "2um",
                "--seed",
                1000 * seed + int(10 * c),
                "--out",
                d,
                "--quiet",
            ]
        )
        data.append(d)
    out = root / f"study_{seed}"
    labels = "concentration=" + ",".join(f"{c:g}%" for c in CONCENTRATIONS)
    _invoke(
        [
            "study",
            *data,
            "--label",
            labels,
            "--method",
            "en4dvar",
            "--forward",
            "bubble=polytropic",
            "--seed",
            seed,
            "--out",
            out,
            "--quiet",
        ]
    )
    s = json.loads((out / "study.json").read_text())
    (trend,) = s["trends"]
    lo_name, hi_name = data[0].name, data[-1].name
    pair = next(d for d in s["differences"] if {d["a"], d["b"]} == {lo_name, hi_name})
    return {
        "seed": seed,
        "G_slope": trend["G"],
        "mu_slope": trend["mu"],
        "mu_ratio_extremes": pair["mu"],
        "failed": [k for k, v in s["runs"].items() if v["status"] == "failed"],
    }


def summarise(rows: list) -> dict:
    """Coverage counts of the claims over the seeds."""
    b = true_log_slope()
    ok = [r for r in rows if not r["failed"]]
    inside = lambda iv, v: iv[0] <= v <= iv[1]  # noqa: E731
    return {
        "seeds": len(rows),
        "seeds_with_failed_runs": len(rows) - len(ok),
        "true_log_slope_G": b,
        "G_slope_interval_holds_truth": sum(inside(r["G_slope"]["interval"], b) for r in ok),
        "G_rises_detected": sum(r["G_slope"]["p_positive"] >= 0.975 for r in ok),
        "mu_slope_interval_holds_0": sum(inside(r["mu_slope"]["interval"], 0.0) for r in ok),
        "mu_ratio_interval_holds_1": sum(inside(r["mu_ratio_extremes"]["interval"], 1.0) for r in ok),
        "n_used": len(ok),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=20, help="Studies to make [-] (the claim: >= 20).")
    ap.add_argument("--quick", action="store_true", help="2 seeds, 2 bubbles per gel, records to t* = 1.5.")
    ap.add_argument(
        "--json",
        type=Path,
        default=None,
        help="Result file [default: validation/results/study_trend/trend[_quick].json].",
    )
    ap.add_argument("--workdir", type=Path, default=None, help="Keep the datasets and studies here.")
    a = ap.parse_args(argv)
    n_seeds = 2 if a.quick else a.seeds
    path = (
        a.json
        or Path(__file__).resolve().parent / "results" / "study_trend" / f"trend{'_quick' if a.quick else ''}.json"
    )
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        root = a.workdir or Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        for seed in range(n_seeds):
            r = one_seed(seed, root, a.quick)
            rows.append(r)
            g, mu = r["G_slope"], r["mu_slope"]
            print(
                f"seed {seed}: ln G slope {g['slope']:.3f} [{g['interval'][0]:.3f}, {g['interval'][1]:.3f}] "
                f"(truth {true_log_slope():.3f}); ln mu slope {mu['slope']:.3f} "
                f"[{mu['interval'][0]:.3f}, {mu['interval'][1]:.3f}]"
                + (f"; failed {r['failed']}" if r["failed"] else "")
            )
    summary = summarise(rows)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(
        json.dumps(
            {
                "summary": summary,
                "rows": rows,
                "quick": a.quick,
                "design": {
                    "concentrations": CONCENTRATIONS,
                    "G": "2000 c + 2000 Pa",
                    "mu": MU,
                    "camera": "1 Mfps, random phase, 2 um noise, polytropic",
                },
            },
            indent=1,
        )
    )
    n = summary["n_used"]
    print(
        f"{n} seed(s): ln G slope interval holds the truth in {summary['G_slope_interval_holds_truth']}, G rise "
        f"detected in {summary['G_rises_detected']}; mu slope interval holds 0 in "
        f"{summary['mu_slope_interval_holds_0']}, mu ratio interval holds 1 in {summary['mu_ratio_interval_holds_1']}"
        f"; wrote {path}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
