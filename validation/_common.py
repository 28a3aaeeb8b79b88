"""What every claim of the validation suite shares: options, the case loop with its checkpoints,
the package's command line called in-process, binomial intervals and the result tables."""

from __future__ import annotations

import argparse
import json
import math
import shutil
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from scipy.stats import binomtest

from imrbayes.io import jsonable, read_json, write_json

ROOT = Path(__file__).resolve().parents[1]
RESULTS = Path(__file__).resolve().parent / "results"
SHARED = ROOT.parent / "shared"


def parser(name: str, doc: str) -> argparse.ArgumentParser:
    """The options every claim takes (``--quick``, ``--resume``, ``--out``); claims add their own."""
    ap = argparse.ArgumentParser(
        prog=f"python -m validation {name}",
        description=doc.strip().splitlines()[0],
        epilog=doc,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--quick", action="store_true", help="a few cases (minutes): shows the claim runs, not a result")
    ap.add_argument(
        "--resume", action="store_true", help="keep the cases already finished under --out (failed ones are rerun)"
    )
    ap.add_argument(
        "--out", type=Path, default=RESULTS / name, help=f"results folder [default: validation/results/{name}]"
    )
    return ap


def add_bubble_option(ap: argparse.ArgumentParser) -> None:
    """``--bubble``: the bubble model of a claim's data and fits (thermal; polytropic with ``--quick``)."""
    ap.add_argument(
        "--bubble",
        choices=["polytropic", "thermal"],
        default=None,
        help="bubble model of data and fit [default: thermal; --quick: polytropic]",
    )


def bubble_of(args: argparse.Namespace) -> str:
    """The bubble model :func:`add_bubble_option` chose."""
    return args.bubble or ("polytropic" if args.quick else "thermal")


def imrbayes(*args: str) -> None:
    """Run one ``imrbayes`` command in this process (compiled kernels stay loaded between cases).

    Raises
    ------
    RuntimeError
        When the command exits with a non-zero status (its one-line error is already on stderr).
    """
    from imrbayes.cli import main

    status = main.main(args=[str(a) for a in args], prog_name="imrbayes", standalone_mode=False)
    if status not in (None, 0):
        raise RuntimeError(f"imrbayes {args[0]} exited with status {status}")


def wilson(k: int, n: int) -> list[float]:
    """95 % Wilson score interval of the proportion ``k / n`` (``[nan, nan]`` when ``n`` is 0)."""
    if n == 0:
        return [math.nan, math.nan]
    ci = binomtest(int(k), int(n)).proportion_ci(confidence_level=0.95, method="wilson")
    return [float(ci.low), float(ci.high)]


def run_cases(
    out: Path,
    cases: Sequence[tuple[str, Callable[[Path], dict]]],
    resume: bool,
    describe: Callable[[dict], str] = lambda row: "",
) -> list[dict]:
    """Run ``cases`` (``(case_id, run)`` pairs; ``run(work_dir)`` returns the case's row) one by one.

    Each finished row is written at once to ``out/cases/<case_id>.json``; with ``resume`` a row
    already there (and not failed) is read back instead of rerun. A case that raises gives a row
    ``{"case", "status": "error", "error"}``, so one failure never ends the run. One progress line
    per case with its elapsed time. ``run`` may use ``work_dir`` (``out/work/<case_id>``, emptied
    first) for data and run folders.

    Returns
    -------
    list of dict
        One row per case, in the order of ``cases``; every row has ``case`` and ``status``.
    """
    rows, t_start = [], time.perf_counter()
    (out / "cases").mkdir(parents=True, exist_ok=True)
    for i, (case_id, run) in enumerate(cases, 1):
        path = out / "cases" / f"{case_id}.json"
        if resume and path.exists():
            row = read_json(path)
            if row.get("status") == "ok":
                rows.append(row)
                print(f"[{i}/{len(cases)}] {case_id}: done before", flush=True)
                continue
        work = out / "work" / case_id
        shutil.rmtree(work, ignore_errors=True)
        work.mkdir(parents=True)
        t0 = time.perf_counter()
        try:
            row = {"case": case_id, "status": "ok", **run(work)}
        except Exception as exc:  # recorded and reported; the other cases go on
            row = {"case": case_id, "status": "error", "error": f"{type(exc).__name__}: {exc}"[:500]}
        row["runtime_s"] = time.perf_counter() - t0
        write_json(path, jsonable(row))
        rows.append(row)
        what = describe(row) if row["status"] == "ok" else f"FAILED ({row['error']})"
        print(
            f"[{i}/{len(cases)}] {case_id}: {what} ({row['runtime_s']:.0f} s; {time.perf_counter() - t_start:.0f} s "
            f"elapsed)",
            flush=True,
        )
    return rows


def _cell(value) -> str:
    if isinstance(value, float):
        return "nan" if math.isnan(value) else f"{value:.4g}"
    if isinstance(value, (list, tuple)) and len(value) == 2 and all(isinstance(v, (int, float)) for v in value):
        return f"[{_cell(float(value[0]))}, {_cell(float(value[1]))}]"
    return "" if value is None else str(value)


def write_table(out: Path, stem: str, title: str, columns: dict[str, str], rows: list[dict], meta: dict) -> Path:
    """Write ``out/<stem>.md`` (a markdown table of ``columns``: key -> heading) and ``out/<stem>.json``
    (``meta``, every row in full); print the markdown. Returns the markdown's path."""

    def pair(v) -> bool:
        return isinstance(v, (list, tuple)) and len(v) == 2 and all(isinstance(x, (int, float)) for x in v)

    shown = {k: v if pair(v) or not isinstance(v, (dict, list)) else f"{len(v)} (in the JSON)" for k, v in meta.items()}
    lines = [
        f"# {title}",
        "",
        *(f"- {k}: {_cell(v)}" for k, v in shown.items()),
        "",
        "| " + " | ".join(columns.values()) + " |",
        "|" + "---|" * len(columns),
    ]
    lines += ["| " + " | ".join(_cell(r.get(k)) for k in columns) + " |" for r in rows]
    text = "\n".join(lines) + "\n"
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{stem}.md").write_text(text)
    write_json(out / f"{stem}.json", jsonable({**meta, "rows": rows}))
    print(text, flush=True)
    return out / f"{stem}.md"


def coverage_rows(rows: list[dict], group: Sequence[str], truth_key: str = "truth") -> list[dict]:
    """Per group of finished case rows (same values of ``group`` keys) and per parameter: the
    coverage of the 95 % interval with its Wilson interval and the mean relative error.

    Each case row holds ``estimate`` (name -> ``{"mean", "hdi95"}``, SI) and ``truth`` (name -> value).
    A parameter whose truth is 0 is left out (scored on "consistent with 0"); seeds whose fit says the
    parameter is not identifiable (:func:`said_unidentifiable`) are counted, not scored on coverage.
    """
    ok = [r for r in rows if r["status"] == "ok"]
    keys = list(dict.fromkeys(tuple(r[g] for g in group) for r in ok))
    table = []
    for key in keys:
        rr = [r for r in ok if tuple(r[g] for g in group) == key]
        for name in rr[0][truth_key]:
            true = rr[0][truth_key][name]
            if true == 0:  # a zero truth is scored on "consistent with 0", not on an interval
                continue
            # a seed whose fit says the parameter is not identifiable is scored on saying so
            scored = [r for r in rr if not said_unidentifiable(r["estimate"][name])]
            hits = sum(r["estimate"][name]["hdi95"][0] <= true <= r["estimate"][name]["hdi95"][1] for r in scored)
            rel = [r["estimate"][name]["mean"] / true - 1 for r in scored]
            table.append(
                {
                    **dict(zip(group, key)),
                    "parameter": name,
                    "truth": true,
                    "n_seeds": len(rr),
                    "said_unidentifiable": len(rr) - len(scored),
                    "coverage": hits / len(scored) if scored else math.nan,
                    "wilson95": wilson(hits, len(scored)),
                    "mean_rel_error": sum(rel) / len(rel) if rel else math.nan,
                }
            )
    return table


def failures(rows: list[dict]) -> list[dict]:
    """The failed case rows, shortened to case and error."""
    return [{"case": r["case"], "error": r["error"]} for r in rows if r["status"] != "ok"]


def estimate_of(run_dir: Path, names: Sequence[str] = ("G", "mu")) -> dict:
    """A fit's gel-level estimate (name -> mean, sd, hdi95 in SI) and rmse from its ``summary.json``."""
    summary = json.loads((run_dir / "summary.json").read_text())
    est = summary["estimate"]
    check = summary.get("fit_check") or {}
    keys = ("mean", "sd", "hdi95", "consistent_with_zero", "upper95", "bounded")
    return {
        "estimate": {n: {k: est[n].get(k) for k in keys if k in est[n]} for n in names if n in est},
        "rmse": (summary.get("fit") or {}).get("rmse"),
        "described": check.get("described"),
        "residual_to_noise": check.get("residual_to_noise"),
    }


def said_unidentifiable(estimate: dict) -> bool:
    """Whether a fit said the data do not pin this parameter down: consistent with 0, or an end of
    its interval not bounded by the data."""
    b = estimate.get("bounded") or {}
    return bool(estimate.get("consistent_with_zero")) or (bool(b) and not (b.get("lower") and b.get("upper")))


def fit_check_rows(rows: list[dict], group: Sequence[str]) -> list[dict]:
    """Per group of finished case rows: how often the fit check said the (true) model describes the
    records, with its Wilson interval, and the largest residual-to-noise ratio seen -- on data made
    by the fitted model, its false-alarm rate."""
    ok = [r for r in rows if r["status"] == "ok" and r.get("described") is not None]
    out = []
    for key in dict.fromkeys(tuple(r[g] for g in group) for r in ok):
        rr = [r for r in ok if tuple(r[g] for g in group) == key]
        k = sum(bool(r["described"]) for r in rr)
        out.append(
            {
                **dict(zip(group, key)),
                "n_seeds": len(rr),
                "described": k,
                "false_alarms": len(rr) - k,
                "wilson95_false_alarm": wilson(len(rr) - k, len(rr)),
                "max_ratio": max(float(r["residual_to_noise"]) for r in rr),
            }
        )
    return out


def coverage_figure(path: Path, table: list[dict], label: Callable[[dict], str]) -> Path:
    """Coverage with its Wilson interval per row of a :func:`coverage_rows` table, against the
    nominal 95 %; one panel per parameter. Returns ``path`` (a PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(dict.fromkeys(r["parameter"] for r in table))
    fig, axes = plt.subplots(
        1, max(1, len(names)), figsize=(4.5 * max(1, len(names)), 0.35 * len(table) + 1.8), squeeze=False
    )
    for ax, name in zip(axes[0], names):
        rr = [r for r in table if r["parameter"] == name]
        y = range(len(rr))
        cov = [r["coverage"] for r in rr]
        err = [[c - r["wilson95"][0] for c, r in zip(cov, rr)], [r["wilson95"][1] - c for c, r in zip(cov, rr)]]
        ax.errorbar(cov, list(y), xerr=err, fmt="o", capsize=3)
        ax.axvline(0.95, color="k", ls="--", lw=1)
        ax.set_yticks(list(y), [label(r) for r in rr])
        ax.set_xlim(0, 1.02)
        ax.set_xlabel(f"coverage of {name}'s 95 % interval [-]")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
