"""En4D-Var over the range of gels two labs measure: coverage, bias and G = 0 on camera-style data.

A grid of truths G in {0, 300, 3e3, 3e4, 3e5} Pa x mu in {0.005, 0.05, 0.5} Pa s, each drawn as the
records of two labs (``imrbayes simulate``, NHKV, thermal bubble, 5 bubbles, noise 0.02 R*, a random
sub-frame phase, records from 5 us before the maximum, Req estimated from the tail):

* ``lab-a``: Rmax 325 +- 40 um (about 250-400 um), a frame rate drawn per seed between 270 kfps and
  1 Mfps;
* ``lab-b``: Rmax 175 +- 40 um (about 100-250 um), 2 Mfps.

Each seed is fitted by ``imrbayes fit --method en4dvar`` (defaults). Scores per (lab, G, mu) cell:
the gel-level 95 % coverage of G and mu with Wilson intervals, the relative bias of the posterior
mean (none for G = 0), and for G = 0 the fraction of seeds whose summary reports G "consistent with
0" (``summary.json["estimate"]["G"]["consistent_with_zero"]``; seeds whose summary lacks the field
are counted as missing).

Full: 20 seeds per cell (600 thermal fits). ``--quick``: G in {0, 3e3} x mu 0.05, one seed per lab,
the polytropic bubble.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from validation._common import (
    add_bubble_option,
    bubble_of,
    coverage_figure,
    coverage_rows,
    estimate_of,
    failures,
    fit_check_rows,
    imrbayes,
    parser,
    run_cases,
    wilson,
    write_table,
)

NAME = "range"
G_VALUES = (0.0, 300.0, 3e3, 3e4, 3e5)
MU_VALUES = (0.005, 0.05, 0.5)
LABS = {"lab-a": {"rmax": "325e-6:40e-6", "fps": (270e3, 1e6)}, "lab-b": {"rmax": "175e-6:40e-6", "fps": (2e6, 2e6)}}


def frame_interval(lab: str, seed: int) -> float:
    """The camera's frame interval [s] of ``lab`` for ``seed`` (drawn uniformly in frame rate)."""
    lo, hi = LABS[lab]["fps"]
    return 1.0 / np.random.default_rng(seed).uniform(lo, hi)


def range_case(lab: str, G: float, mu: float, seed: int, bubble: str) -> callable:
    def run(work: Path) -> dict:
        frame_s = frame_interval(lab, seed)
        imrbayes(
            "simulate",
            "--model",
            "nhkv",
            "--param",
            f"G={G}",
            "--param",
            f"mu={mu}",
            "--rmax",
            LABS[lab]["rmax"],
            "--ratio",
            "7.9:0.45",
            "--n-exp",
            "5",
            "--noise",
            "0.02",
            "--frame-s",
            frame_s,
            "--phase",
            "random",
            "--pre-max-s",
            "5e-6",
            "--no-req-in-meta",
            "--t-end",
            "3.6",
            "--forward",
            f"bubble={bubble}",
            "--seed",
            seed,
            "--out",
            work / "data",
            "--quiet",
        )
        imrbayes(
            "fit",
            work / "data",
            "--method",
            "en4dvar",
            "--forward",
            f"bubble={bubble}",
            "--seed",
            seed,
            "--out",
            work / "fit",
            "--quiet",
        )
        return {
            "lab": lab,
            "G_true": G,
            "mu_true": mu,
            "seed": seed,
            "frame_s": frame_s,
            "bubble": bubble,
            "truth": {"G": G, "mu": mu},
            **estimate_of(work / "fit"),
        }

    return run


def zero_rows(rows: list[dict]) -> list[dict]:
    """Per G = 0 cell: how many seeds report G consistent with 0, and how many lack the field."""
    out = []
    for key in dict.fromkeys((r["lab"], r["mu_true"]) for r in rows if r["G_true"] == 0):
        rr = [r for r in rows if (r["lab"], r["mu_true"]) == key and r["G_true"] == 0]
        flags = [r["estimate"]["G"].get("consistent_with_zero") for r in rr]
        present = [bool(f) for f in flags if f is not None]
        out.append(
            {
                "lab": key[0],
                "mu_true": key[1],
                "n_seeds": len(rr),
                "missing": len(rr) - len(present),
                "consistent_with_zero": sum(present),
                "fraction": sum(present) / len(present) if present else None,
                "wilson95": wilson(sum(present), len(present)) if present else None,
            }
        )
    return out


def main(argv=None) -> None:
    ap = parser(NAME, __doc__)
    ap.add_argument("--seeds", type=int, default=None, help="seeds per cell [default: 20; --quick: 1]")
    ap.add_argument("--labs", default=",".join(LABS), help="comma-separated labs [default: all]")
    add_bubble_option(ap)
    a = ap.parse_args(argv)
    labs = [x for x in a.labs.split(",") if x]
    unknown = sorted(set(labs) - set(LABS))
    if unknown:
        ap.error(f"--labs: unknown {unknown}; known: {list(LABS)}")
    n_seeds = a.seeds or (1 if a.quick else 20)
    bubble = bubble_of(a)
    grid = [(G, mu) for G in ((0.0, 3e3) if a.quick else G_VALUES) for mu in ((0.05,) if a.quick else MU_VALUES)]
    cases = [
        (f"{lab}_G{G:g}_mu{mu:g}_{bubble}_seed{s}", range_case(lab, G, mu, s, bubble))
        for lab in labs
        for G, mu in grid
        for s in range(n_seeds)
    ]
    rows = run_cases(
        a.out,
        cases,
        a.resume,
        lambda r: "; ".join(
            f"{n} {e['mean']:.4g} [{e['hdi95'][0]:.4g}, {e['hdi95'][1]:.4g}] (truth {r['truth'][n]:g})"
            for n, e in r["estimate"].items()
        ),
    )
    ok = [r for r in rows if r["status"] == "ok"]
    table = coverage_rows(ok, ("lab", "G_true", "mu_true"))
    meta = {"bubble": bubble, "seeds_per_cell": n_seeds, "quick": a.quick, "failed_cases": failures(rows)}
    write_table(
        a.out,
        "coverage",
        "En4D-Var over the range of gels: gel-level 95 % coverage and relative bias",
        {
            "lab": "lab",
            "G_true": "G [Pa]",
            "mu_true": "mu [Pa s]",
            "parameter": "parameter",
            "n_seeds": "seeds",
            "said_unidentifiable": "said not identifiable",
            "coverage": "coverage",
            "wilson95": "Wilson 95 %",
            "mean_rel_error": "relative bias",
        },
        table,
        meta,
    )
    write_table(
        a.out,
        "fit_check",
        "The fit check on data from the fitted model: false alarms",
        {
            "lab": "lab",
            "G_true": "G [Pa]",
            "mu_true": "mu [Pa s]",
            "n_seeds": "seeds",
            "described": "described",
            "false_alarms": "false alarms",
            "wilson95_false_alarm": "Wilson 95 %",
            "max_ratio": "largest ratio",
        },
        fit_check_rows(ok, ("lab", "G_true", "mu_true")),
        meta,
    )
    write_table(
        a.out,
        "zero_modulus",
        "G = 0: seeds reporting G consistent with 0",
        {
            "lab": "lab",
            "mu_true": "mu [Pa s]",
            "n_seeds": "seeds",
            "missing": "field missing",
            "consistent_with_zero": "consistent with 0",
            "fraction": "fraction",
            "wilson95": "Wilson 95 %",
        },
        zero_rows(ok),
        meta,
    )
    if table:
        coverage_figure(a.out / "coverage.png", table, lambda r: f"{r['lab']}, G {r['G_true']:g}, mu {r['mu_true']:g}")


if __name__ == "__main__":
    main()
