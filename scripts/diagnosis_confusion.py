"""Confusion matrix and false-alarm rate of ``imrbayes diagnose`` on camera-style synthetic data.

    .venv/bin/python scripts/diagnosis_confusion.py --seeds 5 --nulls 20 --out runs/confusion
    .venv/bin/python scripts/diagnosis_confusion.py --out runs/confusion --summarize-only
    .venv/bin/python scripts/diagnosis_confusion.py --rescore-from runs/old --out runs/new --summarize-only
    .venv/bin/python scripts/diagnosis_confusion.py --classes none --seeds 1 --nulls 0 --quick \\
        --forward bubble=polytropic --out /tmp/conf      # a smoke test

Data: :func:`imrbayes.diagnosis.synthetic.camera_obs`: records made like a camera's (frames, a
random sub-frame phase, noise at every frame, growth before the maximum, bubble-to-bubble scatter of
Rmax and Rmax/Req), by a finer forward model than the fitted one, then preprocessed exactly as
measured data (Rmax, time of the maximum and Req estimated from the noisy frames).

* Classes (rows of the matrix): ``none``, every material mechanism with a generator
  (:data:`imrbayes.diagnosis.synthetic.GENERATORS`) and the bubble classes (``bubble-thermal``,
  ``bubble-compressibility``: baseline NHKV gel, another bubble model than the fitted one). Seed of
  run s of class c: 1000 * (index of c in ``camera_mechanisms()``) + s; design ``--design``.
* Nulls: ``--nulls N`` constant-NHKV datasets cycling through :data:`DESIGNS` (seed 900000 + i):
  the false-alarm rate is (verdict ``inadequate``) / N.
* Scoring: the right answer of a class is its mechanism when ``diagnose`` can name it (a ``cause`` in
  :data:`imrbayes.diagnosis.MECHANISMS`), else ``unexplained`` (a bubble class before the diagnosis
  has bubble candidates). A run scores 1 when ``cause`` is right, 1/2 when ``cause`` is
  ``ambiguous`` and the right mechanism is among ``candidates_tied``, else 0. Hit rates carry Wilson
  95 % intervals (the score form, which accepts the half credits; equal to
  ``scipy.stats.binomtest(k, n).proportion_ci(method="wilson")`` for whole k).

Resumable: each run is written to ``OUT/runs/<class>__s<seed>.json`` or
``OUT/nulls/null__<i>__<design>.json`` as soon as it finishes; a rerun skips finished runs (runs that
raised are written with ``status: error`` and retried). A run in progress keeps its finished units
(baseline fits, bootstrap replicates, candidate and held-out fits) in a run folder beside its row
(``OUT/runs/<class>__s<seed>/``, a :class:`imrbayes.execution.RunStore`), so an interrupted run
(a class row takes 15-40 min) resumes from them; a folder another configuration or imrbayes version
made is set aside (renamed ``*.stale-<n>``), not reused. Each row records the code it was finished
with (``code``: :func:`imrbayes.io.code_version`) and how many sessions its run folder saw
(``checkpoint.sessions``; ``runtime_s`` of a row that took several is its last session's part). The summary (``OUT/summary.json``,
``OUT/summary.md``) is written at the end, or alone with ``--summarize-only``.

``--resume-from PREFIX``: the compact rows committed by an earlier ``--export PREFIX`` (another
session's, whose OUT folder is gone) are written into OUT as finished runs, so a rerun with the same
settings computes only the runs still missing and the summary counts them all. Rows whose export
was made with other diagnosis settings (``--forward``, ``--quick``, ``--loeo``, ``--n-bootstrap``,
``--mienks-drift``: each row's own record, or for rows made before rows kept one, the export's
command) are refused with a one-line error.

``--rescore-from DIR``: rows of an earlier run whose diagnosis code differs only in how the check's
p-values are combined (the statistics and their bootstrap replicates, stored in every row, are the
same) get the current verdict (:func:`imrbayes.diagnosis.check.combined_p_value`) and are written to
OUT. A verdict that becomes ``adequate`` makes the cause ``none`` (what ``diagnose`` does: exact); one
that becomes ``inadequate`` cannot be completed from the row (the candidates' comparison was not
run): the row is written as an error, which the next run of OUT recomputes.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import math
import os
import shlex
import sys
import time
import traceback
from pathlib import Path

NULL_SEED = 900_000


def _classes():
    from imrbayes.diagnosis.synthetic import camera_mechanisms

    return list(camera_mechanisms())


def _mechanisms():
    from imrbayes.diagnosis import MECHANISMS

    return tuple(MECHANISMS)


def expected_cause(cls: str, mechanisms=None) -> str:
    """The right ``cause`` for data of class ``cls`` (module docstring)."""
    mechanisms = _mechanisms() if mechanisms is None else mechanisms
    return cls if cls in mechanisms else "unexplained"


def _tied_mechanisms(tied) -> list:
    """``candidates_tied`` as mechanisms (entries may be candidate keys or mechanisms)."""
    from imrbayes.diagnosis.candidates import BASELINE, CANDIDATES

    keys = {BASELINE.key: BASELINE.mechanism, **{k: c.mechanism for k, c in CANDIDATES.items()}}
    out = []
    for t in tied or []:
        if isinstance(t, dict):
            t = t.get("mechanism") or t.get("candidate") or t.get("key")
        out.append(keys.get(t, t))
    return out


def score(row: dict, mechanisms=None) -> float:
    """1 right, 1/2 ambiguous with the right mechanism among the tied, else 0."""
    want = expected_cause(row["class"], mechanisms)
    if row.get("cause") == want:
        return 1.0
    if row.get("cause") == "ambiguous" and want in _tied_mechanisms(row.get("candidates_tied")):
        return 0.5
    return 0.0


def is_alarm(row: dict) -> bool:
    """A null run raised an alarm: the constant-parameter check says ``inadequate`` (or, with no
    verdict recorded, a cause other than ``none``)."""
    v = row.get("verdict")
    return v == "inadequate" if v is not None else row.get("cause") != "none"


def wilson(k: float, n: int, conf: float = 0.95) -> tuple:
    """Wilson score interval of a proportion k/n (k may carry half credits)."""
    from scipy.stats import norm

    if n <= 0:
        return (math.nan, math.nan)
    z = float(norm.ppf(0.5 + conf / 2))
    p = k / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z / den * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return (max(0.0, centre - half), min(1.0, centre + half))


# ------------------------------------------------------------------ one run

def _jsonable(x):
    from imrbayes.io import jsonable

    return jsonable(x)


def open_checkpoint(folder: Path, config: dict):
    """The run store of one row's diagnosis (module doc): ``folder`` reopened when it holds this
    ``config`` and imrbayes version, else created (an unusable folder is renamed aside first)."""
    from imrbayes.errors import InputError
    from imrbayes.execution import RunStore

    try:
        return RunStore.open(folder, config, resume=True)
    except InputError:
        n = 0
        while folder.with_name(f"{folder.name}.stale-{n}").exists():
            n += 1
        folder.rename(folder.with_name(f"{folder.name}.stale-{n}"))
        return RunStore.open(folder, config, resume=False)


def run_one(job: dict) -> dict:
    """Generate, diagnose (checkpointed in the row's run folder), write ``job["path"]``; returns the row."""
    t0 = time.perf_counter()
    row = {k: job[k] for k in ("kind", "class", "seed", "design", "forward")}
    gen = job.get("generator", "imrbayes")
    if gen != "imrbayes":
        row["generator"] = gen
    row["settings"] = {k: job.get(k) for k in ("quick", "loeo", "n_bootstrap", "mienks_drift", "stop_when_adequate")}
    try:
        from imrbayes.cli.options import data_fingerprint
        from imrbayes.diagnosis import DiagnoseSettings, diagnose
        from imrbayes.diagnosis.synthetic import camera_obs
        from imrbayes.execution import Execution
        from imrbayes.forward import ForwardOptions
        from imrbayes.io import code_version

        opts = ForwardOptions.from_dict(job["forward"], source="--forward")
        obs, truth = camera_obs(job["class"], job["seed"], opts, design=job["design"],
                                **({"generator": gen} if gen != "imrbayes" else {}))
        kw = {"loeo": job["loeo"]}
        if job.get("stop_when_adequate"):
            kw["compare_when_adequate"] = False
        if job.get("mienks_drift") is not None:
            kw["mienks_drift"] = job["mienks_drift"]
        if job.get("n_bootstrap"):
            kw["n_bootstrap"] = job["n_bootstrap"]
        settings = DiagnoseSettings.quick(**kw) if job["quick"] else DiagnoseSettings(**kw)
        config = {"row": {k: row[k] for k in ("class", "seed", "design", "forward", "generator") if k in row},
                  "settings": row["settings"],
                  "data": data_fingerprint(obs.t_star, obs.R_star, obs.P, obs.rmax_m, obs.req_m, names=obs.names)}
        with open_checkpoint(Path(job["path"]).with_suffix(""), _jsonable(config)) as store:
            r = diagnose(obs, opts, settings=settings, seed=job["seed"],
                         execution=Execution(store=store, progress=False)).result
            row["checkpoint"] = {"folder": str(store.path), "sessions": len(store.info.get("sessions", []))}
        row["code"] = code_version()
        check = r.get("constant_parameter_check") or {}
        row.update(status="ok", cause=r.get("cause"), candidates_tied=r.get("candidates_tied"),
                   verdict=check.get("verdict"), p_value=(check.get("evidence") or {}).get("p_value"),
                   gain=r.get("gain"), truth=truth, result=r)
    except Exception as exc:  # recorded, retried on the next run
        row.update(status="error", cause="error", error=f"{type(exc).__name__}: {exc}",
                   traceback=traceback.format_exc())
    row["runtime_s"] = time.perf_counter() - t0
    path = Path(job["path"])
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(_jsonable(row), indent=1) + "\n")
    os.replace(tmp, path)
    return row


def jobs_for(a, classes, designs) -> list:
    runs, nulls = Path(a.out) / "runs", Path(a.out) / "nulls"
    all_classes = _classes()
    fwd = dict(kv.split("=", 1) for kv in a.forward)
    common = {"forward": fwd, "quick": a.quick, "loeo": a.loeo, "n_bootstrap": a.n_bootstrap,
              "mienks_drift": getattr(a, "mienks_drift", None),
              "stop_when_adequate": bool(getattr(a, "stop_when_adequate", False)),
              "generator": getattr(a, "generator", "imrbayes")}
    jobs = []
    for c in classes:
        for s in range(a.seed_offset, a.seed_offset + a.seeds):
            seed = 1000 * all_classes.index(c) + s
            jobs.append({"kind": "class", "class": c, "seed": seed, "design": a.design,
                         "path": str(runs / f"{c}__s{seed}.json"), **common})
    for i in range(a.nulls):
        d = designs[i % len(designs)]
        jobs.append({"kind": "null", "class": "none", "seed": NULL_SEED + i, "design": d,
                     "path": str(nulls / f"null__{i:03d}__{d}.json"), **common})
    return jobs


def _finished(path: str) -> bool:
    try:
        return json.loads(Path(path).read_text()).get("status") == "ok"
    except (OSError, ValueError):
        return False


def rescore_row(row: dict) -> dict:
    """``row`` with the check's verdict recomputed by the current combination (module doc)."""
    from imrbayes.diagnosis.check import combined_p_value

    if row.get("status") != "ok":
        return row
    check = row["result"]["constant_parameter_check"]
    ev = check["evidence"]
    st = ev["statistics"]
    if ev.get("p_value_kind") == "bound":     # decided after the first batch by a bound, not by ranks
        return {**row, "rescored": {"p_value_before": row.get("p_value"), "verdict_before": row.get("verdict"),
                                    "cause_before": row.get("cause"),
                                    "rule": "kept: decided inadequate early (check.inadequate_already)"}}
    keys = list(st)
    p, p_each = combined_p_value([st[k]["observed"] for k in keys], [st[k]["bootstrap"] for k in keys])
    verdict = "inadequate" if p <= ev["alpha"] else "adequate"
    out = {**row, "p_value": p, "verdict": verdict,
           "rescored": {"p_value_before": row.get("p_value"), "verdict_before": row.get("verdict"),
                        "cause_before": row.get("cause"), "rule": "combined_p_value (Fisher, pool of data and "
                                                                  "replicates)"}}
    if verdict == row.get("verdict"):
        return out
    if verdict == "adequate":
        out.update(cause="none", candidates_tied=[])
        return out
    out.update(status="error", cause="error",
               error="rescoring turned the verdict to inadequate; the candidates' comparison needs a rerun")
    return out


def rescore(src: Path, out: Path) -> int:
    """Rescore every row of ``src`` into ``out`` (rows already finished in ``out`` are kept)."""
    n = 0
    for folder in ("runs", "nulls"):
        (out / folder).mkdir(parents=True, exist_ok=True)
        for path in sorted((src / folder).glob("*.json")):
            dest = out / folder / path.name
            if _finished(str(dest)):
                continue
            row = rescore_row(json.loads(path.read_text()))
            dest.write_text(json.dumps(_jsonable(row), indent=1) + "\n")
            n += 1
    return n


# ------------------------------------------------------------------ summary

def load_rows(out: Path) -> tuple:
    def read(folder):
        rows = []
        for p in sorted((out / folder).glob("*.json")):
            try:
                rows.append(json.loads(p.read_text()))
            except ValueError:
                continue
        return rows
    return read("runs"), read("nulls")


def summarize(rows: list, nulls: list, mechanisms=None, command: str = "") -> dict:
    """Confusion matrix, per-class hit rates and the false-alarm rate (module docstring)."""
    mechanisms = tuple(_mechanisms() if mechanisms is None else mechanisms)
    done = [r for r in rows if r.get("status") == "ok"]
    classes = list(dict.fromkeys(r["class"] for r in done))
    found = list(mechanisms)
    for extra in ("ambiguous", "unexplained"):
        if extra not in found:
            found.append(extra)
    for r in done:
        if r.get("cause") not in found:
            found.append(r.get("cause"))
    matrix = {c: {f: sum(r.get("cause") == f for r in done if r["class"] == c) for f in found} for c in classes}
    per_class = {}
    for c in classes:
        rr = [r for r in done if r["class"] == c]
        k = sum(score(r, mechanisms) for r in rr)
        per_class[c] = {"expected": expected_cause(c, mechanisms), "n": len(rr), "score": k,
                        "hit_rate": k / len(rr), "wilson95": list(wilson(k, len(rr))),
                        "n_half_credit": sum(score(r, mechanisms) == 0.5 for r in rr)}
    nd = [r for r in nulls if r.get("status") == "ok"]
    alarms = sum(is_alarm(r) for r in nd)
    by_design = {}
    for r in nd:
        b = by_design.setdefault(r["design"], {"n": 0, "alarms": 0})
        b["n"] += 1
        b["alarms"] += int(is_alarm(r))
    return {"command": command, "found_columns": found, "matrix": matrix, "per_class": per_class,
            "nulls": {"n": len(nd), "alarms": alarms, "false_alarm_rate": alarms / len(nd) if nd else None,
                      "wilson95": list(wilson(alarms, len(nd))) if nd else None, "by_design": by_design,
                      "causes": {c: sum(r.get("cause") == c for r in nd) for c in dict.fromkeys(r.get("cause") for r in nd)}},
            "errors": [{"class": r["class"], "seed": r["seed"], "error": r.get("error")}
                       for r in rows + nulls if r.get("status") != "ok"],
            "scoring": "1 if cause is the expected one; 1/2 if cause is 'ambiguous' and the expected mechanism is "
                       "among candidates_tied; else 0. Expected: the class's mechanism if diagnose can name it, "
                       "else 'unexplained'. Wilson 95 % score intervals."}


def markdown(s: dict) -> str:
    f = s["found_columns"]
    out = ["# diagnose: confusion matrix on camera-style synthetic data", "",
           f"Command: `{s['command']}`", "", "Rows: hidden class; columns: the diagnosis's `cause`.", "",
           "| truth \\ found | " + " | ".join(f) + " | expected | hit rate [Wilson 95 %] |",
           "|---" * (len(f) + 3) + "|"]
    for c, row in s["matrix"].items():
        pc = s["per_class"][c]
        lo, hi = pc["wilson95"]
        out.append(f"| {c} | " + " | ".join(str(row[x]) for x in f) +
                   f" | {pc['expected']} | {pc['score']:g}/{pc['n']} = {pc['hit_rate']:.2f} [{lo:.2f}, {hi:.2f}] |")
    n = s["nulls"]
    out += ["", f"Scoring: {s['scoring']}", ""]
    if n["n"]:
        lo, hi = n["wilson95"]
        out.append(f"False alarms on constant-NHKV nulls: {n['alarms']}/{n['n']} = {n['false_alarm_rate']:.2f} "
                   f"[{lo:.2f}, {hi:.2f}] (Wilson 95 %).")
        out += ["", "| design | nulls | alarms |", "|---|---|---|"]
        out += [f"| {d} | {b['n']} | {b['alarms']} |" for d, b in n["by_design"].items()]
    else:
        out.append("No null runs.")
    if s["errors"]:
        out += ["", f"Runs that raised ({len(s['errors'])}):", ""]
        out += [f"- {e['class']} seed {e['seed']}: {e['error']}" for e in s["errors"]]
    return "\n".join(out) + "\n"


def candidate_gains(result: dict) -> list:
    """Every compared candidate's held-out gain by scheme, for rules calibrated on the matrix later
    (e.g. whether a candidate's gain should overrule an adequate check: relaxation seed 2001's zener
    had a LOEO gain of 4.2 SE while the check said adequate): ``[{"key", "rank", "ruled_out",
    "<scheme>": {"relative_reduction", "z"}}]``, z = paired mean RMSE difference / its SE, both
    against the baseline; empty when the candidates were not compared."""
    base = {}
    for sch, v in ((result.get("gain") or {}).get("by_scheme") or {}).items():
        base[sch] = v.get("baseline")
    out = []
    for c in result.get("candidates") or []:
        d = {"key": c.get("key"), "rank": c.get("rank"), "ruled_out": c.get("ruled_out")}
        for sch, h in (c.get("heldout") or {}).items():
            pd_ = h.get("paired_vs_baseline") or {}
            se, rb, rc = pd_.get("se"), base.get(sch), h.get("rmse")
            d[sch] = {"relative_reduction": (1.0 - rc / rb) if rb and rc is not None else None,
                      "z": (pd_["mean_diff"] / se) if se else None}
        out.append(d)
    return out


def compact_row(row: dict) -> dict:
    """One run as committed under docs/figures/diagnosis/ (the check's statistics with every replicate's
    value, so the combination can be recomputed; the verdict, cause, tie, gain and truth). A row taken
    from an export (``--resume-from``) is already compact and is kept as it is."""
    if "result" not in row and "statistics" in row:
        return {k: v for k, v in row.items() if k != "kind"}
    r = row.get("result") or {}
    ev = (r.get("constant_parameter_check") or {}).get("evidence") or {}
    st = {k: {"observed": v["observed"], "bootstrap": v.get("bootstrap"), "p": v.get("p_value"),
              "q05_q50_q95": v.get("bootstrap_q05_q50_q95")} for k, v in (ev.get("statistics") or {}).items()}
    g = row.get("gain") or {}
    held = candidate_gains(r)
    return {"class": row["class"], "seed": row["seed"], "design": row["design"], "status": row.get("status"),
            "forward": row.get("forward"), "settings": row.get("settings"),
            "verdict": row.get("verdict"), "cause": row.get("cause"), "p_value": row.get("p_value"),
            "candidates_tied": row.get("candidates_tied"), "score": score(row) if row.get("status") == "ok" else None,
            "truth": {"theta": (row.get("truth") or {}).get("theta")},
            "gain": {k: g.get(k) for k in ("candidate", "relative_reduction", "paired_difference", "elpd_diff", "elpd_se") if k in g},
            **({"candidates": held} if held else {}),
            "statistics": st, "sequential": ev.get("sequential"), "runtime_s": row.get("runtime_s"),
            **({"code": row["code"]} if "code" in row else {}),
            **({"generator": row["generator"]} if "generator" in row else {}),
            **({"sessions": row["checkpoint"]["sessions"]} if "checkpoint" in row else {}),
            **({"rescored": row["rescored"]} if "rescored" in row else {}),
            **({"error": row.get("error")} if row.get("status") != "ok" else {})}


def export(out: Path, dest: Path, command: str, code: str) -> None:
    """Write OUT's class and null rows, compact, to ``dest``_{classes,nulls}.json."""
    rows, nulls = load_rows(out)
    for kind, rr in (("classes", rows), ("nulls", nulls)):
        if rr:
            Path(f"{dest}_{kind}.json").write_text(json.dumps(
                {"command": command, "code": code, "rows": [compact_row(r) for r in rr]}, indent=1) + "\n")


SETTING_KEYS = ("forward", "quick", "loeo", "n_bootstrap", "mienks_drift", "generator")


def _settings(forward, quick, loeo, n_bootstrap, mienks_drift, generator="imrbayes") -> dict:
    return {"forward": sorted(forward), "quick": bool(quick), "loeo": bool(loeo), "n_bootstrap": n_bootstrap,
            "mienks_drift": mienks_drift, "generator": generator or "imrbayes"}


def run_settings(a) -> dict:
    """The settings a row depends on (besides class, seed and design), from parsed arguments."""
    return _settings(a.forward, a.quick, (not a.quick) if a.loeo is None else a.loeo, a.n_bootstrap, a.mienks_drift,
                     getattr(a, "generator", "imrbayes"))


def row_settings(row: dict, fallback: dict) -> dict:
    """The settings a row was made with: its own record (rows since 2026-11-27), else ``fallback``
    (those of the command that exported it)."""
    st = row.get("settings")
    if not st or row.get("forward") is None:
        return {**fallback, "generator": row.get("generator", fallback.get("generator", "imrbayes"))}
    return _settings([f"{k}={v}" for k, v in row["forward"].items()], st.get("quick"), st.get("loeo"),
                     st.get("n_bootstrap"), st.get("mienks_drift"), row.get("generator", "imrbayes"))


class ResumeError(Exception):
    """An --resume-from file that cannot be used (one line; the script exits 2)."""


def resume_from_export(prefix: Path, out: Path, settings: dict, parser) -> int:
    """Write the compact rows of ``prefix``_{classes,nulls}.json into OUT as finished runs (module
    doc); rows already finished in OUT are kept. Returns the number of rows written."""
    files = [(kind, Path(f"{prefix}_{kind}.json")) for kind in ("classes", "nulls")]
    files = [(k, f) for k, f in files if f.exists()]
    if not files:
        raise ResumeError(f"--resume-from {prefix}: neither {prefix}_classes.json nor {prefix}_nulls.json exists")
    n = 0
    for kind, f in files:
        try:
            doc = json.loads(f.read_text())
            made = run_settings(parser.parse_args(shlex.split(doc["command"])[1:]))
        except (ValueError, KeyError, SystemExit) as exc:
            raise ResumeError(f"{f}: not an --export file of this script ({type(exc).__name__})") from None
        folder = out / ("runs" if kind == "classes" else "nulls")
        folder.mkdir(parents=True, exist_ok=True)
        for row in doc["rows"]:
            if row.get("status") != "ok":
                continue                      # recomputed, as an errored run would be
            had = row_settings(row, made)
            if had != settings:
                diff = {k: (had[k], settings[k]) for k in SETTING_KEYS if had[k] != settings[k]}
                raise ResumeError(f"{f}: {row['class']} seed {row['seed']} was made with other settings "
                                 f"(then, now): {diff}")
            if kind == "classes":
                dest = folder / f"{row['class']}__s{row['seed']}.json"
            else:
                dest = folder / f"null__{row['seed'] - NULL_SEED:03d}__{row['design']}.json"
            if _finished(str(dest)):
                continue
            dest.write_text(json.dumps({**row, "kind": "class" if kind == "classes" else "null",
                                        "resumed_from": {"file": str(f), "code": doc.get("code")}}, indent=1) + "\n")
            n += 1
    return n


def write_summary(out: Path, command: str) -> dict:
    rows, nulls = load_rows(out)
    s = summarize(rows, nulls, command=command)
    (out / "summary.json").write_text(json.dumps(s, indent=1) + "\n")
    md = markdown(s)
    (out / "summary.md").write_text(md)
    print(md)
    return s


def main(argv=None):
    from imrbayes.diagnosis.synthetic import DESIGNS, STRENGTH_DESIGNS

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=5, help="runs per class (default 5)")
    ap.add_argument("--seed-offset", type=int, default=0, help="first run index s (seed = 1000 * class + s)")
    ap.add_argument("--classes", default="", help="comma-separated classes (default: all: "
                                                  + ", ".join(_classes()) + ")")
    ap.add_argument("--nulls", type=int, default=20, help="constant-NHKV null datasets cycling through DESIGNS")
    ap.add_argument("--design", default=next(iter(DESIGNS)), choices=[*DESIGNS, *STRENGTH_DESIGNS],
                    help="design of the class runs (the nulls cycle through the varied DESIGNS; STRENGTH_DESIGNS "
                         "make a mechanism that is at the noise level elsewhere strong enough to be found)")
    ap.add_argument("--out", type=Path, default=Path("runs/diagnosis-confusion"))
    ap.add_argument("--mienks-drift", action=argparse.BooleanOptionalAction, default=None,
                    help="the MIEnKS drift statistic in the check (default: DiagnoseSettings', off; on roughly "
                         "doubles the bootstrap)")
    ap.add_argument("--quick", action="store_true", help="DiagnoseSettings.quick (no LOEO unless --loeo)")
    ap.add_argument("--loeo", action=argparse.BooleanOptionalAction, default=None,
                    help="leave-one-experiment-out (default: on, off with --quick)")
    ap.add_argument("--n-bootstrap", type=int, default=None)
    ap.add_argument("--stop-when-adequate", action="store_true",
                    help="end a diagnosis after the check when it is adequate (diagnose --stop-when-adequate): the "
                         "verdict and the cause are the same, the run ~60 %% shorter; not a setting --resume-from "
                         "compares, since no score depends on it")
    ap.add_argument("--forward", action="append", default=[], metavar="KEY=VALUE",
                    help="fitted forward option (e.g. bubble=polytropic); repeatable")
    ap.add_argument("--generator", choices=["imrbayes", "pyimr"], default="imrbayes",
                    help="the code that makes the records (pyimr: another code, the 'peers' extra; keep its rows "
                         "in their own --out and --export)")
    ap.add_argument("--workers", type=int, default=1, help="processes (default 1)")
    ap.add_argument("--summarize-only", action="store_true")
    ap.add_argument("--export", type=Path, default=None, metavar="PREFIX",
                    help="also write the rows, compact, to PREFIX_classes.json and PREFIX_nulls.json")
    ap.add_argument("--code", default="", help="with --export: the code version of the rows that do not record "
                                               "their own (rows record it since 2026-11-27, session 31)")
    ap.add_argument("--resume-from", type=Path, default=None, metavar="PREFIX",
                    help="write the rows of an earlier --export PREFIX into OUT as finished runs (same settings only)")
    ap.add_argument("--rescore-from", type=Path, default=None, metavar="DIR",
                    help="copy DIR's rows into OUT with the check's verdict recomputed (module doc)")
    a = ap.parse_args(argv)
    command = shlex.join([Path(sys.argv[0]).name if argv is None else "diagnosis_confusion.py",
                          *(sys.argv[1:] if argv is None else argv)])
    if a.loeo is None:
        a.loeo = not a.quick
    if any("=" not in kv for kv in a.forward):
        ap.error("--forward takes KEY=VALUE")
    a.out.mkdir(parents=True, exist_ok=True)
    if a.summarize_only and a.rescore_from is None and (a.out / "summary.json").exists():
        # keep the command that made the rows (a summary alone does not change them)
        command = json.loads((a.out / "summary.json").read_text()).get("command") or command
    if a.resume_from is not None:
        try:
            n = resume_from_export(a.resume_from, a.out, run_settings(a), ap)
        except ResumeError as exc:
            print(f"diagnosis_confusion.py: error: {exc}", file=sys.stderr)
            raise SystemExit(2) from None
        print(f"{n} rows taken from {a.resume_from}", flush=True)
    if a.rescore_from is not None:
        print(f"rescored {rescore(a.rescore_from, a.out)} rows of {a.rescore_from}", flush=True)
    if not a.summarize_only:
        classes = [c.strip() for c in a.classes.split(",") if c.strip()] or _classes()
        bad = [c for c in classes if c not in _classes()]
        if bad:
            ap.error(f"unknown class(es) {bad}; known: {_classes()}")
        (a.out / "runs").mkdir(exist_ok=True)
        (a.out / "nulls").mkdir(exist_ok=True)
        jobs = jobs_for(a, classes, list(DESIGNS))
        todo = [j for j in jobs if not _finished(j["path"])]
        print(f"{len(jobs)} runs, {len(jobs) - len(todo)} already done, {len(todo)} to go", flush=True)

        def report(r):
            print(f"{r['kind']:>5} {r['class']:>26} seed {r['seed']:6d} {r['design']:>22}: "
                  f"{r.get('cause')!s:<24} verdict {r.get('verdict')} p={r.get('p_value')} ({r['runtime_s']:.0f} s)"
                  + (f" {r.get('error')}" if r.get("status") != "ok" else ""), flush=True)
        if a.workers <= 1:
            for j in todo:
                report(run_one(j))
        else:
            with cf.ProcessPoolExecutor(a.workers) as ex:
                for fut in cf.as_completed([ex.submit(run_one, j) for j in todo]):
                    report(fut.result())
    write_summary(a.out, command)
    if a.export is not None:
        export(a.out, a.export, command, a.code)


if __name__ == "__main__":
    main()
