"""Re-score stored diagnoses under the cause-naming rule (``imrbayes.diagnosis.run.name_cause``).

Since session 49 ``diagnose`` names a cause only when the top candidate's held-out gain over the
baseline is >= 2 paired SE on at least one held-out scheme (else ``unexplained``). The rule reads
only what a diagnosis stores -- the verdict, the ranking, each scheme's paired difference -- so
every stored result can be re-scored without refitting:

* ``docs/figures/diagnosis/*_diagnosis.json`` (the real records and other single runs);
* the confusion-matrix rows ``docs/figures/diagnosis/confusion_camera*_classes.json`` that store
  each candidate's per-scheme z (rows made since session 31; older rows store only the named
  candidate's gain on its first scheme and are reported as "not re-scorable" when that is < 2 SE).

Prints every result whose cause the rule changes and writes the table as JSON.

Usage: python validation/cause_naming_rescore.py [--json OUT]
"""

from __future__ import annotations

import argparse
import glob
import json
import os

from imrbayes.diagnosis.candidates import spec_of
from imrbayes.diagnosis.run import name_cause

HERE = os.path.dirname(os.path.abspath(__file__))
FIG = os.path.join(HERE, "..", "docs", "figures", "diagnosis")
NAMED = {"none", "unexplained", "ambiguous"}


def _mech(key):
    try:
        return spec_of(key).mechanism
    except (KeyError, ValueError):
        return key


def rescore_full(d: dict) -> tuple:
    """(old cause, new cause, note) of a full diagnosis.json."""
    verdict = d["constant_parameter_check"]["verdict"]
    cands = d.get("candidates") or []
    mech = {c["key"]: c["mechanism"] for c in cands}
    tied = list(d.get("candidates_tied") or [])
    top = None
    if d.get("cause") not in NAMED and d.get("cause") is not None:
        # the named one (a tie settled by the signature may name a candidate below rank 1)
        top = next((c for c in cands if c["mechanism"] == d["cause"] and c.get("model") == d.get("extended_model")),
                   None)
    if top is None and cands:
        top = cands[0]
    if top is not None and d.get("cause") == "ambiguous" and tied:
        top = next((c for c in cands if c["key"] == tied[0]), top)
    if top is not None:   # results older than the consistency rule (2026-11-25) lack its field
        top = {**top, "consistent": top.get("consistent", True)}
    new, _, _, note = name_cause(verdict, top, tied, mech)
    return d.get("cause"), new, note


def rescore_row(r: dict, forecast_only: bool = False) -> tuple:
    """(old cause, new cause, note) of a compact confusion-matrix row; new is None when the row
    does not store what the rule reads. ``forecast_only``: the matrix ran without leave-one-out, so
    the named candidate's stored gain is its only scheme."""
    old = r.get("cause")
    if r.get("verdict") == "adequate" or old in ("none", "unexplained"):
        return old, old, ""
    cands = [c for c in (r.get("candidates") or []) if not c.get("ruled_out")]
    if not cands:
        g = (r.get("gain") or {}).get("paired_difference") or {}
        z = g["mean_diff"] / g["se"] if g.get("se") else None
        if z is not None and forecast_only:
            return old, (old if z >= 2.0 else "unexplained"), f"forecast only (no leave-one-out run): {z:.2f} SE"
        return old, (old if z is not None and z >= 2.0 else None), (
            f"first scheme only: {z:.2f} SE" if z is not None else "no paired SE stored")
    top = next((c for c in cands if _mech(c["key"]) == old), cands[0])
    top = {"key": top["key"], "model": top["key"], "mechanism": _mech(top["key"]), "score": 1.0, "consistent": True,
           "heldout": {k: {"paired_vs_baseline": {"mean_diff": v["z"], "se": 1.0}}
                       for k, v in top.items() if isinstance(v, dict) and v.get("z") is not None}}
    tied = list(r.get("candidates_tied") or [])
    new, _, _, note = name_cause("inadequate", top, tied, {c["key"]: _mech(c["key"]) for c in r["candidates"]})
    return old, new, note


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", help="write the table here")
    a = ap.parse_args(argv)
    table = []
    for f in sorted(glob.glob(os.path.join(FIG, "*_diagnosis.json"))):
        d = json.load(open(f))
        if "candidates" not in d or "constant_parameter_check" not in d:
            continue
        old, new, note = rescore_full(d)
        table.append({"file": os.path.basename(f), "old": old, "new": new, "note": note})
    for f in sorted(glob.glob(os.path.join(FIG, "confusion_camera*_classes.json"))):
        doc = json.load(open(f))
        forecast_only = "--no-loeo" in (doc.get("command") or "")
        for r in doc["rows"]:
            old, new, note = rescore_row(r, forecast_only)
            table.append({"file": os.path.basename(f), "row": f"{r['class']} {r['seed']}", "old": old, "new": new,
                          "note": note})
    changed = [t for t in table if t["new"] != t["old"]]
    print(f"{len(table)} stored results; the rule changes {sum(t['new'] is not None for t in changed)}, "
          f"cannot re-score {sum(t['new'] is None for t in changed)}:")
    for t in changed:
        print(f"  {t['file']:<58s} {t.get('row', ''):<28s} {t['old']} -> {t['new'] or '(not re-scorable)'}: {t['note']}")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(table, fh, indent=1)
            fh.write("\n")


if __name__ == "__main__":
    main()
