"""How often the diagnosis names a cause on constant-material data it did not make itself, and how
large the best candidate's held-out gain is on such data (the calibration of the naming rule's
effect-size floor, :data:`imrbayes.diagnosis.run.MIN_GAIN`).

Data: constant-parameter NHKV datasets written by ``imrbayes simulate`` with IMRv2's numerics
(``--forward scheme=imrv2-fd --forward nt=25``: a coarse uniform grid, another code's discretisation
error) and camera-style sampling (a random sub-frame phase, bubble-to-bubble scatter of Rmax and
Rmax/Req). The generator's numerical options are removed from meta.json, so that ``diagnose`` fits
with its own default numerics as it would another lab's records. The nulls cycle through a grid of

* noise shapes: constant (``0.01`` in R*), growing with the radius (``0.02R``) and larger near the
  collapses (``0.01C``; :mod:`imrbayes.data.synthetic`),
* frame rates 270 kfps, 1 Mfps and 2 Mfps,
* the polytropic and the thermal bubble (each fitted with the bubble it was made with);

null i has the i-th grid cell (cyclically) and seed 700000 + i. Each goes through ``imrbayes
diagnose`` at default settings (``--quick``: quick settings).

Table: per null the verdict, the cause, the best (top-ranked consistent) candidate and its gain
(mean relative held-out RMSE reduction), the combined paired z, and the residual-to-noise ratio of
the constant model. Summary: false alarms (a cause named: not ``none`` nor ``unexplained``) and
inadequate verdicts with 95 % Wilson intervals, and the 95th percentile of the nulls' best gains
(a null whose candidates are all inconsistent counts as a gain of 0) -- the value ``MIN_GAIN`` should
take so that at most 1 in 20 such nulls clears the floor.

``--quick``: 2 polytropic nulls of 3 bubbles at 1 Mfps (noise ``0.02R`` and ``0.01C``), quick
diagnosis settings: shows the claim runs, not a result.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from validation._common import failures, imrbayes, parser, run_cases, wilson, write_table

NAME = "diagnosis_nulls"
NULL_SEED = 700_000
NOISES = ("0.01", "0.02R", "0.01C")
FRAME_S = {"270kfps": 1 / 270e3, "1Mfps": 1e-6, "2Mfps": 5e-7}
BUBBLES = ("polytropic", "thermal")
#: the generator's numerics (another code's): written by simulate, removed before the diagnosis
GENERATOR_NUMERICS = ("scheme", "nt", "mt", "stretch", "polytropic_pdot", "zener_j", "rtol", "atol", "integrator")
TRUTH = {"G": 7.29e3, "mu": 0.088}


def grid() -> list[tuple[str, str, str]]:
    """Every (noise, frame rate, bubble) cell of the nulls, polytropic first (the cheaper)."""
    return [(n, f, b) for b in BUBBLES for f in FRAME_S for n in NOISES]


def make_null(work: Path, seed: int, noise: str, fps: str, bubble: str, n_exp: int) -> Path:
    """A constant-NHKV dataset made with IMRv2's numerics under ``work/data``; its meta.json keeps
    only the physical forward options. Returns the dataset folder."""
    data = work / "data"
    imrbayes(
        "simulate",
        "--model",
        "nhkv",
        "--param",
        f"G={TRUTH['G']}",
        "--param",
        f"mu={TRUTH['mu']}",
        "--rmax",
        "263e-6:20e-6",
        "--ratio",
        "7.58:0.5",
        "--n-exp",
        n_exp,
        "--noise",
        noise,
        "--frame-s",
        repr(FRAME_S[fps]),
        "--phase",
        "random",
        "--t-end",
        "3.2",
        "--seed",
        seed,
        "--forward",
        "scheme=imrv2-fd",
        "--forward",
        "nt=25",
        "--forward",
        f"bubble={bubble}",
        "--out",
        data,
        "--quiet",
    )
    meta_path = data / "meta.json"
    meta = json.loads(meta_path.read_text())
    meta["forward"] = {k: v for k, v in meta["forward"].items() if k not in GENERATOR_NUMERICS}
    meta_path.write_text(json.dumps(meta, indent=2))
    return data


def best_of(r: dict) -> tuple:
    """(best candidate key, its gain, combined z) of a diagnosis result: the top-ranked consistent
    candidate (``naming`` where the result has it); (None, 0.0, nan) when none is consistent."""
    nm = r.get("naming") or {}
    if "best_gain" in nm:
        gain = nm["best_gain"]
        return nm.get("best_candidate"), (0.0 if gain is None else float(gain)), nm.get("combined_z")
    ok = [c for c in r.get("candidates") or [] if c.get("consistent")]
    if not ok:
        return None, 0.0, math.nan
    top = min(ok, key=lambda c: c.get("rank", 1e9))
    return top["key"], float(top["score"]), (top.get("combined_vs_baseline") or {}).get("z")


def null_case(seed: int, noise: str, fps: str, bubble: str, n_exp: int, quick: bool):
    """The case: one null made and diagnosed; its row."""

    def run(work: Path) -> dict:
        data = make_null(work, seed, noise, fps, bubble, n_exp)
        out = work / "diagnose"
        imrbayes("diagnose", data, "--out", out, "--seed", seed, "--quiet", *(["--quick"] if quick else []))
        r = json.loads((out / "diagnosis.json").read_text())
        check = r.get("constant_parameter_check") or {}
        key, gain, z = best_of(r)
        return {
            "seed": seed,
            "noise": noise,
            "fps": fps,
            "bubble": bubble,
            "n_exp": n_exp,
            "verdict": check.get("verdict"),
            "p_value": (check.get("evidence") or {}).get("p_value"),
            "cause": r.get("cause"),
            "cause_note": r.get("cause_note"),
            "best_candidate": key,
            "best_gain": gain,
            "combined_z": z,
            "residual_to_noise": (r.get("misfit") or {}).get("residual_to_noise"),
            "named": r.get("cause") not in ("none", "unexplained"),
        }

    return run


def summary(rows: list[dict]) -> dict:
    """False alarms and inadequate verdicts with Wilson intervals, and the 95th percentile of the
    best gains, over the finished rows."""
    ok = [r for r in rows if r["status"] == "ok"]
    named = sum(bool(r["named"]) for r in ok)
    inadequate = sum(r["verdict"] == "inadequate" for r in ok)
    gains = np.array([r["best_gain"] for r in ok], dtype=float)
    return {
        "nulls": len(ok),
        "causes_named": named,
        "false_alarm_rate": named / len(ok) if ok else None,
        "false_alarm_wilson95": wilson(named, len(ok)),
        "inadequate": inadequate,
        "inadequate_wilson95": wilson(inadequate, len(ok)),
        "best_gain_q95": float(np.percentile(gains, 95)) if gains.size else None,
        "best_gain_max": float(gains.max()) if gains.size else None,
    }


def main(argv=None) -> None:
    from imrbayes.diagnosis.run import MIN_GAIN

    ap = parser(NAME, __doc__)
    ap.add_argument("--nulls", type=int, default=None, help="null datasets [default: 24; --quick: 2]")
    ap.add_argument("--n-exp", type=int, default=None, help="bubbles per null [default: 5; --quick: 3]")
    a = ap.parse_args(argv)
    n_nulls = a.nulls if a.nulls is not None else (2 if a.quick else 24)
    n_exp = a.n_exp if a.n_exp is not None else (3 if a.quick else 5)
    cells = [("0.02R", "1Mfps", "polytropic"), ("0.01C", "1Mfps", "polytropic")] if a.quick else grid()
    cases = []
    for i in range(n_nulls):
        noise, fps, bubble = cells[i % len(cells)]
        cases.append(
            (f"null{i:03d}_{bubble}_{fps}_{noise}", null_case(NULL_SEED + i, noise, fps, bubble, n_exp, a.quick))
        )
    rows = run_cases(
        a.out, cases, a.resume, lambda r: f"verdict {r['verdict']}, cause {r['cause']}, best gain {r['best_gain']:.3g}"
    )
    meta = {
        "quick": a.quick,
        "generator": "imrbayes simulate, scheme=imrv2-fd nt=25",
        "n_exp": n_exp,
        "min_gain_in_use": MIN_GAIN,
        **summary(rows),
        "failed_cases": failures(rows),
    }
    write_table(
        a.out,
        "diagnosis_nulls",
        "Diagnosis on constant-NHKV nulls made with other numerics and noise shapes",
        {
            "case": "null",
            "bubble": "bubble",
            "fps": "frames",
            "noise": "noise",
            "verdict": "verdict",
            "p_value": "p",
            "cause": "cause",
            "best_candidate": "best candidate",
            "best_gain": "its gain",
            "combined_z": "combined z [SE]",
            "residual_to_noise": "misfit / noise",
        },
        [r for r in rows if r["status"] == "ok"],
        meta,
    )


if __name__ == "__main__":
    main()
