"""``run_study``: every dataset's runs, then the table, differences, figures and page."""

from __future__ import annotations

from pathlib import Path

from imrbayes.study.analysis import conclusion, condition_draws, differences, table_rows, trends
from imrbayes.study.jobs import plan_jobs, run_jobs
from imrbayes.study.outputs import write_figures, write_html, write_table, write_tree
from imrbayes.study.results import read_condition
from imrbayes.study.spec import numeric_labels

__all__ = ["run_study", "summarise_study"]


def run_study(spec, out, *, workers=None, scheduler=None, replace: bool = False, report=None) -> dict:
    """Run (or reuse, or resume) every job of ``spec`` under ``out/runs``, then write the study's
    files (:func:`summarise_study`). A failed job is reported through ``report(line)`` and the rest
    goes on. Returns the ``study.json`` object."""
    out = Path(out)
    jobs = plan_jobs(spec, out)
    runs = run_jobs(jobs, seed=spec.seed, workers=workers, scheduler=scheduler, replace=replace, report=report)
    return summarise_study(spec, out, jobs, runs)


def summarise_study(spec, out: Path, jobs, runs: dict) -> dict:
    """``study.csv``, ``study.json``, ``study.nc``, ``figures/`` and ``study.html`` from the finished
    runs ``{unit id: {"status", "error"}}`` of ``jobs``."""
    results = []
    for c in spec.conditions:
        mine = [j for j in jobs if j.condition == c.name]
        ok = {j.name: j.folder for j in mine if runs.get(j.unit_id, {}).get("status") not in (None, "failed")}
        errors = {j.name: runs[j.unit_id]["error"] for j in mine if runs.get(j.unit_id, {}).get("status") == "failed"}
        results.append(read_condition(c, ok, errors))
    keys = spec.label_keys()
    numeric = numeric_labels(spec)
    rows = table_rows(results, keys)
    draws = condition_draws(results, spec.seed)
    diffs = differences(results, draws)
    trend_list = trends(results, draws, numeric)
    study = {
        "labels": {k: numeric.get(k) for k in keys},
        "differences": diffs,
        "trends": trend_list,
        "conclusion": conclusion(results, diffs, trend_list),
        "method": "gel-level posteriors as Gaussians in log space; conditions independent; ratios and "
        "least-squares slopes of log G, log mu computed draw by draw (central 95 % intervals)",
        "runs": runs,
    }
    write_table(out, rows, study)
    write_tree(out, results, draws)
    figs = write_figures(out, rows, results, numeric)
    write_html(out, rows, study, figs, keys)
    return {"conditions": rows, **study}
