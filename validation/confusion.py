"""Confusion matrix and false-alarm rate of the diagnosis on camera-style synthetic data.

Data: :func:`imrbayes.diagnosis.synthetic.camera_obs` -- records made as a camera takes them
(frames, a random sub-frame phase, noise at every frame, growth before the maximum, bubble-to-bubble
scatter of Rmax and Rmax/Req) by a finer forward model than the fitted one, preprocessed exactly as
measured data.

* Classes (rows): ``none``, every material mechanism with a generator and the bubble classes
  (another bubble model than the fitted one). Seed of run s of class c: 1000 * (index of c in
  ``camera_mechanisms()``) + s.
* Nulls: constant-NHKV data sets cycling through the recording designs of
  :data:`imrbayes.diagnosis.synthetic.DESIGNS` (seed 900000 + i); false-alarm rate = (verdict
  ``inadequate``) / nulls.
* Scoring: the right ``cause`` of a class is its mechanism when the diagnosis can name it, else
  ``unexplained``. A run is a hit when ``cause`` is right; an ``ambiguous`` cause with the right
  mechanism among ``candidates_tied`` is counted apart (a half credit in the score column).
  Hit and false-alarm rates carry 95 % Wilson intervals.

``--quick``: 1 run of ``none`` and 2 nulls, quick diagnosis settings, the polytropic bubble.
"""

from __future__ import annotations

from pathlib import Path

from validation._common import failures, parser, run_cases, wilson, write_table

NAME = "confusion"
NULL_SEED = 900_000


def expected_cause(cls: str) -> str:
    """The right ``cause`` for data of class ``cls``: its mechanism if the diagnosis can name it."""
    from imrbayes.diagnosis import MECHANISMS

    return cls if cls in MECHANISMS else "unexplained"


def tied_mechanisms(tied) -> list[str]:
    """``candidates_tied`` (candidate keys, mechanisms or dicts naming either) as mechanisms."""
    from imrbayes.diagnosis.candidates import BASELINE, CANDIDATES

    keys = {BASELINE.key: BASELINE.mechanism, **{k: c.mechanism for k, c in CANDIDATES.items()}}
    out = []
    for t in tied or []:
        if isinstance(t, dict):
            t = t.get("mechanism") or t.get("candidate") or t.get("key")
        out.append(keys.get(t, t))
    return out


def diagnose_case(cls: str, seed: int, design: str, forward: dict, quick: bool) -> callable:
    """The case: one synthetic data set of class ``cls`` diagnosed; row with verdict and cause."""

    def run(work: Path) -> dict:
        from imrbayes.diagnosis import DiagnoseSettings, diagnose
        from imrbayes.diagnosis.synthetic import camera_obs
        from imrbayes.forward import ForwardOptions

        opts = ForwardOptions.from_dict(forward, source="--forward")
        obs, truth = camera_obs(cls, seed, opts, design=design)
        settings = DiagnoseSettings.quick() if quick else DiagnoseSettings()
        r = diagnose(obs, opts, settings=settings, seed=seed).result
        check = r.get("constant_parameter_check") or {}
        return {
            "class": cls,
            "seed": seed,
            "design": design,
            "cause": r.get("cause"),
            "candidates_tied": tied_mechanisms(r.get("candidates_tied")),
            "verdict": check.get("verdict"),
            "p_value": (check.get("evidence") or {}).get("p_value"),
            "truth": truth,
        }

    return run


def class_rows(rows: list[dict]) -> list[dict]:
    """Per class: counts of every cause found, hits with their Wilson interval, half credits."""
    table = []
    for cls in dict.fromkeys(r["class"] for r in rows):
        rr = [r for r in rows if r["class"] == cls]
        want = expected_cause(cls)
        hits = sum(r["cause"] == want for r in rr)
        half = sum(r["cause"] == "ambiguous" and want in r["candidates_tied"] for r in rr)
        found = {}
        for r in rr:
            found[r["cause"]] = found.get(r["cause"], 0) + 1
        table.append(
            {
                "class": cls,
                "expected": want,
                "n": len(rr),
                "found": found,
                "found_text": ", ".join(f"{c} {k}" for c, k in found.items()),
                "hits": hits,
                "hit_rate": hits / len(rr),
                "wilson95": wilson(hits, len(rr)),
                "ambiguous_with_right": half,
                "score": hits + 0.5 * half,
            }
        )
    return table


def main(argv=None) -> None:
    from imrbayes.diagnosis.synthetic import DESIGNS, camera_mechanisms

    ap = parser(NAME, __doc__)
    classes_all = list(camera_mechanisms())
    ap.add_argument(
        "--classes",
        default=None,
        help=f"comma-separated classes [default: all: {', '.join(classes_all)}; --quick: none]",
    )
    ap.add_argument("--seeds", type=int, default=None, help="runs per class [default: 5; --quick: 1]")
    ap.add_argument("--nulls", type=int, default=None, help="constant-NHKV null data sets [default: 20; --quick: 2]")
    ap.add_argument("--design", default=next(iter(DESIGNS)), choices=list(DESIGNS), help="design of the class runs")
    ap.add_argument(
        "--forward",
        action="append",
        default=None,
        metavar="KEY=VALUE",
        help="fitted forward option, repeatable [default: the thermal default; --quick: bubble=polytropic]",
    )
    a = ap.parse_args(argv)
    classes = (a.classes or ("none" if a.quick else ",".join(classes_all))).split(",")
    unknown = sorted(set(classes) - set(classes_all))
    if unknown:
        ap.error(f"--classes: unknown {unknown}; known: {classes_all}")
    forward_args = a.forward if a.forward is not None else (["bubble=polytropic"] if a.quick else [])
    if any("=" not in kv for kv in forward_args):
        ap.error("--forward takes KEY=VALUE")
    forward = dict(kv.split("=", 1) for kv in forward_args)
    n_seeds = a.seeds if a.seeds is not None else (1 if a.quick else 5)
    n_nulls = a.nulls if a.nulls is not None else (2 if a.quick else 20)
    designs = list(DESIGNS)
    cases = [
        (
            f"{c}_seed{1000 * classes_all.index(c) + s}",
            diagnose_case(c, 1000 * classes_all.index(c) + s, a.design, forward, a.quick),
        )
        for c in classes
        for s in range(n_seeds)
    ]
    cases += [
        (
            f"null{i:03d}_{designs[i % len(designs)]}",
            diagnose_case("none", NULL_SEED + i, designs[i % len(designs)], forward, a.quick),
        )
        for i in range(n_nulls)
    ]
    rows = run_cases(a.out, cases, a.resume, lambda r: f"cause {r['cause']}, verdict {r['verdict']}, p {r['p_value']}")
    ok = [r for r in rows if r["status"] == "ok"]
    nulls = [r for r in ok if r["case"].startswith("null")]
    alarms = sum(r["verdict"] == "inadequate" for r in nulls)
    meta = {
        "forward": forward_args,
        "quick": a.quick,
        "design": a.design,
        "nulls": len(nulls),
        "false_alarms": alarms,
        "false_alarm_rate": alarms / len(nulls) if nulls else None,
        "false_alarm_wilson95": wilson(alarms, len(nulls)),
        "failed_cases": failures(rows),
    }
    write_table(
        a.out,
        "confusion_matrix",
        "Diagnosis on camera-style synthetic data: causes found per hidden class",
        {
            "class": "hidden class",
            "expected": "right cause",
            "n": "runs",
            "found_text": "causes found",
            "hit_rate": "hit rate",
            "wilson95": "Wilson 95 %",
            "ambiguous_with_right": "ambiguous, right among tied",
        },
        class_rows([r for r in ok if not r["case"].startswith("null")]),
        meta,
    )


if __name__ == "__main__":
    main()
