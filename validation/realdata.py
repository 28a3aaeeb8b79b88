"""Every measured data set with R(t) curves through ``fit`` with each method and through ``diagnose``.

Data: every folder of ``--data`` (default ``../shared/data/lic``) that loads as R(t) records
(folders of summaries or of original .mat files are listed as skipped). Each (data set, method)
is one ``imrbayes fit`` with the default settings; each data set is also one ``imrbayes
diagnose``. Table: data set, method, G and mu (posterior mean with the 95 % interval, SI units), rmse
of the fit in R*; a diagnosis row gives its verdict and cause instead.

``--quick``: the first data set only, methods pimr and en4dvar, a quick diagnosis, the polytropic
bubble.
"""

from __future__ import annotations

import json
from pathlib import Path

from validation._common import SHARED, estimate_of, failures, imrbayes, parser, run_cases, write_table

NAME = "realdata"
METHODS = ("imr", "pimr", "en4dvar", "mienks")


def datasets(root: Path) -> tuple[list[Path], list[str]]:
    """The folders under ``root`` that load as R(t) data sets, and one line per folder skipped."""
    from imrbayes.data import load_dataset
    from imrbayes.errors import InputError

    found, skipped = [], []
    for folder in sorted(p for p in root.iterdir() if p.is_dir()):
        try:
            load_dataset(folder)
            found.append(folder)
        except InputError as exc:
            skipped.append(f"{folder.name}: {exc}")
    return found, skipped


def data_options(folder: Path, experiments: str | None) -> list[str]:
    """Options every command needs for ``folder``: two camera views are averaged frame by frame;
    ``--experiments`` where given."""
    from imrbayes.data import load_dataset

    ds = load_dataset(folder)
    views = {e.camera for e in ds.experiments if getattr(e, "camera", None)}
    n = len(ds.experiments) // max(1, len(views))
    if experiments and "-" in experiments and experiments.split("-")[0] == "1":
        # "1-5": the first five, or all of a smaller data set
        experiments = f"1-{min(int(experiments.split('-')[1]), n)}"
    return (["--camera", "mean"] if len(views) > 1 else []) + (["--experiments", experiments] if experiments else [])


def fit_case(folder: Path, method: str, forward: list[str]) -> callable:
    def run(work: Path) -> dict:
        imrbayes("fit", folder, "--method", method, *forward, "--out", work / "fit", "--quiet")
        return {"dataset": folder.name, "method": method, **estimate_of(work / "fit")}

    return run


def diagnose_case(folder: Path, forward: list[str], quick: bool) -> callable:
    def run(work: Path) -> dict:
        imrbayes("diagnose", folder, *forward, *(["--quick"] if quick else []), "--out", work / "diagnosis", "--quiet")
        d = json.loads((work / "diagnosis" / "diagnosis.json").read_text())
        return {
            "dataset": folder.name,
            "method": "diagnose",
            "cause": d.get("cause"),
            "verdict": (d.get("constant_parameter_check") or {}).get("verdict"),
        }

    return run


def table_row(row: dict) -> dict:
    """A case row as the table shows it: G and mu as 'mean [lo, hi]' (or 'consistent with 0 (< up)'),
    whether the fit describes the records (residual / noise)."""
    out = {"dataset": row["dataset"], "method": row["method"], "rmse": row.get("rmse")}
    for name, est in (row.get("estimate") or {}).items():
        if est.get("consistent_with_zero"):
            up = est.get("upper95")
            out[name] = "consistent with 0" + (f" (< {up:.3g})" if up is not None else "")
        elif est.get("mean") is None:
            out[name] = "no estimate"
        elif None in (est.get("hdi95") or [None]):
            out[name] = f"{est['mean']:.4g} (no interval)"
        else:
            out[name] = f"{est['mean']:.4g} [{est['hdi95'][0]:.4g}, {est['hdi95'][1]:.4g}]"
    if row.get("residual_to_noise") is not None:
        out["fit"] = f"{'described' if row['described'] else 'NOT described'} ({row['residual_to_noise']:.3g}x noise)"
    if row["method"] == "diagnose":
        out["G"] = f"verdict {row['verdict']}, cause {row['cause']}"
    return out


#: what must hold whatever the numbers: (name, data sets in increasing concentration, what rises,
#: whether the 95 % intervals must also be separated)
ORDERINGS = (
    ("agarose G rises with concentration (intervals separated)", ("ut_agarose0p5pct", "ut_agarose5p0pct"), "G", True),
    (
        "PEG-8000 solutions: mu rises with the fraction",
        ("ut_PEG8K_020pct_1Mfps_from_nondim", "ut_PEG8K_060pct_1Mfps_from_nondim", "ut_PEG8K_100pct_1Mfps_from_nondim"),
        "mu",
        False,
    ),
)
LIQUIDS = (
    "ut_PEG8K_020pct_1Mfps_from_nondim",
    "ut_PEG8K_060pct_1Mfps_from_nondim",
    "ut_PEG8K_100pct_1Mfps_from_nondim",
)


def physics_checks(rows: list[dict]) -> list[dict]:
    """Per method: the orderings of the posterior means hold (with separated 95 % intervals where
    the check says so), and every liquid's G is consistent with 0 (data sets not run are left out)."""
    out = []
    for method in dict.fromkeys(r["method"] for r in rows if r["method"] != "diagnose"):
        by = {r["dataset"]: r["estimate"] for r in rows if r["method"] == method and r.get("estimate")}
        for name, series, par, separated in ORDERINGS:
            est = [
                by[d][par] for d in series if d in by and None not in ((by[d].get(par) or {}).get("hdi95") or [None])
            ]
            if len(est) < 2:
                continue
            holds = all(b["mean"] > a["mean"] for a, b in zip(est, est[1:]))
            if separated:
                holds = holds and all(b["hdi95"][0] > a["hdi95"][1] for a, b in zip(est, est[1:]))
            out.append(
                {
                    "check": name,
                    "method": method,
                    "holds": holds,
                    "evidence": "; ".join(f"{e['mean']:.3g} [{e['hdi95'][0]:.3g}, {e['hdi95'][1]:.3g}]" for e in est),
                }
            )
        for d in LIQUIDS:
            if d in by and "G" in by[d]:
                g = by[d]["G"]
                out.append(
                    {
                        "check": f"{d}: G consistent with 0",
                        "method": method,
                        "holds": bool(g.get("consistent_with_zero")),
                        "evidence": (
                            f"95 % upper bound {g['upper95']:.3g} Pa"
                            if g.get("consistent_with_zero") and g.get("upper95")
                            else f"G {g['mean']:.3g} [{(g.get('hdi95') or [0, 0])[0]:.3g}, "
                            f"{(g.get('hdi95') or [0, 0])[1]:.3g}] Pa"
                        ),
                    }
                )
    return out


def main(argv=None) -> None:
    ap = parser(NAME, __doc__)
    ap.add_argument("--data", type=Path, default=SHARED / "data" / "lic", help="folder of data set folders")
    ap.add_argument("--datasets", default=None, help="comma-separated folder names [default: all; --quick: the first]")
    ap.add_argument(
        "--methods", default=None, help=f"comma-separated [default: {','.join(METHODS)}; --quick: pimr,en4dvar]"
    )
    ap.add_argument("--no-diagnose", action="store_true", help="fits only")
    ap.add_argument("--experiments", default=None, help="experiments of every data set, e.g. 1-5 [default: all]")
    ap.add_argument(
        "--forward",
        action="append",
        default=None,
        metavar="KEY=VALUE",
        help="forward option for every run [default: the thermal default; --quick: bubble=polytropic]",
    )
    a = ap.parse_args(argv)
    if not a.data.is_dir():
        ap.error(f"--data {a.data}: no such folder")
    found, skipped = datasets(a.data)
    if a.datasets:
        names = a.datasets.split(",")
        missing = sorted(set(names) - {f.name for f in found})
        if missing:
            ap.error(f"--datasets: not R(t) data sets under {a.data}: {missing}")
        found = [f for f in found if f.name in names]
    elif a.quick:
        found = found[:1]
    methods = (a.methods or ("pimr,en4dvar" if a.quick else ",".join(METHODS))).split(",")
    fwd = [
        x
        for kv in (a.forward if a.forward is not None else (["bubble=polytropic"] if a.quick else []))
        for x in ("--forward", kv)
    ]
    cases = []
    for folder in found:
        opts = fwd + data_options(folder, a.experiments)
        cases += [(f"{folder.name}_{m}", fit_case(folder, m, opts)) for m in methods]
        if not a.no_diagnose:
            cases.append((f"{folder.name}_diagnose", diagnose_case(folder, opts, a.quick)))
    rows = run_cases(a.out, cases, a.resume, lambda r: str(table_row(r)))
    ok = [r for r in rows if r["status"] == "ok"]
    write_table(
        a.out,
        "physics",
        "What physics demands of the measured data sets",
        {"check": "check", "method": "method", "holds": "holds", "evidence": "evidence"},
        physics_checks(ok),
        {"data": str(a.data), "forward": fwd[1::2], "experiments": a.experiments},
    )
    write_table(
        a.out,
        "fits",
        "Measured data sets: every method's estimate and the diagnosis",
        {
            "dataset": "data set",
            "method": "method",
            "G": "G [Pa] mean [95 %]",
            "mu": "mu [Pa s] mean [95 %]",
            "rmse": "rmse [R*]",
            "fit": "fit check",
        },
        [table_row(r) for r in rows if r["status"] == "ok"],
        {
            "data": str(a.data),
            "forward": fwd[1::2],
            "quick": a.quick,
            "skipped": skipped,
            "failed_cases": failures(rows),
        },
    )


if __name__ == "__main__":
    main()
