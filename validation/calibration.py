"""Interval coverage of the gel-level 95 % intervals per synthetic family, over seeds.

Each seed draws a fresh data set with ``imrbayes simulate`` and fits it with ``imrbayes fit`` (the
default likelihood; nothing of the truth is passed to the fit). Families:

* ``verification``: the paper's verification design (5 bubbles, Rmax 263 um, Rmax/Req 7.58,
  G 7.29 kPa, mu 0.088 Pa s, the paper's noise on the dt* grid, Req given);
* ``camera``: data as a camera records them (6 bubbles, Rmax 320 +- 45 um, Rmax/Req 7.9 +- 0.45,
  1 Mfps with a random sub-frame phase, records from 5 us before the maximum, noise 0.02 R*, Req
  estimated from the tail), generated with tight solver tolerances (G 5.2 kPa, mu 0.065 Pa s);
* ``scatter``: the camera family with each bubble's G and mu drawn log-normally (15 % relative sd)
  around the truth, which the gel-level interval is scored against.

Table: per family, method and parameter the coverage with its 95 % Wilson interval and the mean
relative error of the posterior mean, and how often the fit check said NHKV describes the records
(on these data it does: every miss is a false alarm). ``--quick``: 2 seeds per family, the polytropic bubble.
"""

from __future__ import annotations

from pathlib import Path

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
    write_table,
)

NAME = "calibration"
FAMILIES = {
    "verification": {"truth": {"G": 7.29e3, "mu": 0.088}, "simulate": []},
    "camera": {
        "truth": {"G": 5.2e3, "mu": 0.065},
        "simulate": [
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
            "--phase",
            "random",
            "--pre-max-s",
            "5e-6",
            "--no-req-in-meta",
            "--t-end",
            "3.6",
            "--forward",
            "rtol=1e-9",
            "--forward",
            "atol=1e-11",
        ],
    },
}
FAMILIES["scatter"] = {
    "truth": FAMILIES["camera"]["truth"],
    "simulate": FAMILIES["camera"]["simulate"] + ["--scatter", "G=0.15", "--scatter", "mu=0.15"],
}
FIRST_SEED = 100


def fit_case(family: str, method: str, seed: int, bubble: str) -> callable:
    """The case: simulate one seed's data set of ``family``, fit it with ``method``; row of scores."""
    spec = FAMILIES[family]

    def run(work: Path) -> dict:
        params = [a for n, v in spec["truth"].items() for a in ("--param", f"{n}={v}")]
        imrbayes(
            "simulate",
            "--model",
            "nhkv",
            *params,
            *spec["simulate"],
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
            method,
            "--forward",
            f"bubble={bubble}",
            "--seed",
            seed,
            "--out",
            work / "fit",
            "--quiet",
        )
        return {
            "family": family,
            "method": method,
            "seed": seed,
            "bubble": bubble,
            "truth": spec["truth"],
            **estimate_of(work / "fit", spec["truth"]),
        }

    return run


def describe(row: dict) -> str:
    return "; ".join(
        f"{n} {e['mean']:.4g} [{e['hdi95'][0]:.4g}, {e['hdi95'][1]:.4g}] (truth {row['truth'][n]:.4g})"
        for n, e in row["estimate"].items()
    )


def main(argv=None) -> None:
    ap = parser(NAME, __doc__)
    ap.add_argument("--families", default=",".join(FAMILIES), help="comma-separated families [default: all]")
    ap.add_argument("--methods", default="en4dvar", help="comma-separated fit methods [default: en4dvar]")
    ap.add_argument("--seeds", type=int, default=None, help="seeds per family [default: 40; --quick: 2]")
    add_bubble_option(ap)
    a = ap.parse_args(argv)
    families = [f for f in a.families.split(",") if f]
    unknown = sorted(set(families) - set(FAMILIES))
    if unknown:
        ap.error(f"--families: unknown {unknown}; known: {list(FAMILIES)}")
    n_seeds = a.seeds or (2 if a.quick else 40)
    bubble = bubble_of(a)
    methods = [m for m in a.methods.split(",") if m]
    cases = [
        (f"{fam}_{m}_{bubble}_seed{s}", fit_case(fam, m, s, bubble))
        for fam in families
        for m in methods
        for s in range(FIRST_SEED, FIRST_SEED + n_seeds)
    ]
    rows = run_cases(a.out, cases, a.resume, describe)
    table = coverage_rows(rows, ("family", "method"))
    meta = {"bubble": bubble, "seeds_per_family": n_seeds, "quick": a.quick, "failed_cases": failures(rows)}
    write_table(
        a.out,
        "coverage",
        "Coverage of the gel-level 95 % intervals on synthetic data",
        {
            "family": "family",
            "method": "method",
            "parameter": "parameter",
            "n_seeds": "seeds",
            "said_unidentifiable": "said not identifiable",
            "coverage": "coverage",
            "wilson95": "Wilson 95 %",
            "mean_rel_error": "mean relative error",
        },
        table,
        meta,
    )
    write_table(
        a.out,
        "fit_check",
        "The fit check on data from the fitted model: false alarms",
        {
            "family": "family",
            "method": "method",
            "n_seeds": "seeds",
            "described": "described",
            "false_alarms": "false alarms",
            "wilson95_false_alarm": "Wilson 95 %",
            "max_ratio": "largest ratio",
        },
        fit_check_rows(rows, ("family", "method")),
        meta,
    )
    if table:
        coverage_figure(a.out / "coverage.png", table, lambda r: f"{r['family']}, {r['method']}")


if __name__ == "__main__":
    main()
