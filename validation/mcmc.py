"""The ensemble Gaussian posterior against emcee on the paper's verification case.

Each seed simulates the verification design (``imrbayes simulate`` defaults: 5 bubbles, Rmax
263 um, Rmax/Req 7.58, G 7.29 kPa, mu 0.088 Pa s, the paper's noise) and runs ``imrbayes fit
--mcmc``; ``compare.json`` says, window by window, whether the ensemble Gaussian agrees with the
sampled posterior (symmetrised Gaussian KL, W2, sample KL against their thresholds) once the chains
have converged. Table: method, seed, window, agree, KL (symmetrised), W2.

``--quick``: En4D-Var, one seed, the polytropic bubble.
"""

from __future__ import annotations

import json
from pathlib import Path

from validation._common import add_bubble_option, bubble_of, failures, imrbayes, parser, run_cases, wilson, write_table

NAME = "mcmc"
TRUTH = {"G": 7.29e3, "mu": 0.088}


def mcmc_case(method: str, seed: int, bubble: str, windows: str) -> callable:
    def run(work: Path) -> dict:
        params = [a for n, v in TRUTH.items() for a in ("--param", f"{n}={v}")]
        imrbayes(
            "simulate",
            "--model",
            "nhkv",
            *params,
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
            "--mcmc",
            "--mcmc-windows",
            windows,
            "--forward",
            f"bubble={bubble}",
            "--seed",
            seed,
            "--out",
            work / "fit",
            "--quiet",
        )
        comp = json.loads((work / "fit" / "compare.json").read_text())
        return {
            "method": method,
            "seed": seed,
            "bubble": bubble,
            "windows": [
                {
                    "window": w.get("index"),
                    "agree": w.get("agree"),
                    "kl_sym": w.get("kl_sym"),
                    "w2": w.get("w2"),
                    "kl_sample": w.get("kl_sample"),
                    "notes": w.get("notes"),
                }
                for w in comp["windows"]
            ],
        }

    return run


def main(argv=None) -> None:
    ap = parser(NAME, __doc__)
    ap.add_argument("--methods", default=None, help="comma-separated [default: en4dvar,mienks; --quick: en4dvar]")
    ap.add_argument("--seeds", type=int, default=None, help="seeds per method [default: 5; --quick: 1]")
    ap.add_argument("--windows", default="all", help="windows to sample (fit --mcmc-windows) [default: all]")
    add_bubble_option(ap)
    a = ap.parse_args(argv)
    methods = (a.methods or ("en4dvar" if a.quick else "en4dvar,mienks")).split(",")
    n_seeds = a.seeds or (1 if a.quick else 5)
    bubble = bubble_of(a)
    cases = [(f"{m}_{bubble}_seed{s}", mcmc_case(m, s, bubble, a.windows)) for m in methods for s in range(n_seeds)]
    rows = run_cases(
        a.out,
        cases,
        a.resume,
        lambda r: f"agree in {sum(w['agree'] is True for w in r['windows'])} of {len(r['windows'])} windows",
    )
    table = [{"method": r["method"], "seed": r["seed"], **w} for r in rows if r["status"] == "ok" for w in r["windows"]]
    decided = [w for w in table if w["agree"] is not None]
    agree = sum(w["agree"] is True for w in decided)
    write_table(
        a.out,
        "agreement",
        "Ensemble Gaussian against emcee on the verification case",
        {
            "method": "method",
            "seed": "seed",
            "window": "window",
            "agree": "agree",
            "kl_sym": "KL sym [nats]",
            "w2": "W2 [sd]",
            "kl_sample": "sample KL [nats]",
        },
        table,
        {
            "bubble": bubble,
            "quick": a.quick,
            "decided_windows": len(decided),
            "agreeing_windows": agree,
            "agreement_wilson95": wilson(agree, len(decided)),
            "failed_cases": failures(rows),
        },
    )


if __name__ == "__main__":
    main()
