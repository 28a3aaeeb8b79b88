"""What each condition's runs say: the gel-level posterior of the constant estimate (a Gaussian in
log space), the between-bubble spread, the fit check, G(t) and mu(t), the diagnose verdict -- read
from the run folders' ``summary.json`` / ``diagnosis.json`` only."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from imrbayes.io import read_json

__all__ = ["ConditionResult", "read_condition", "log_gaussian", "CONSTANT_METHODS"]

#: which run gives a condition's constant estimate, in order of preference
CONSTANT_METHODS = ("en4dvar", "mienks", "imr", "pimr")
_Z95 = 1.959963984540054


@dataclass
class ConditionResult:
    """One condition's numbers. ``log_mean`` (n_par,) and ``log_cov`` (n_par, n_par): the gel-level
    posterior of the log parameters (SI units inside the log); None when no run finished."""

    name: str
    labels: dict
    method: str | None = None
    params: tuple = ()
    estimate: dict = field(default_factory=dict)
    between: dict = field(default_factory=dict)
    n_bubbles: int | None = None
    described: bool | None = None
    log_mean: np.ndarray | None = None
    log_cov: np.ndarray | None = None
    time_resolved: list = field(default_factory=list)
    diagnose: dict = field(default_factory=dict)
    folders: dict = field(default_factory=dict)
    errors: dict = field(default_factory=dict)


def log_gaussian(summary: dict):
    """(names, mean (n_par,), cov (n_par, n_par)) of the gel-level posterior of the log parameters.

    The method's own random-effects Gaussian when it is one in log space; otherwise the log-normal
    that matches each parameter's reported median and 95 % interval (independent parameters). None
    for a parameter that is not positive (a liquid's G = 0 has no log)."""
    names = list(summary.get("parameters") or summary.get("estimate", {}).keys())
    det = summary.get("details") or {}
    re_ = det.get("random_effects") or {}
    logs = (det.get("parameter_space") or {}).get("log_space") or {}
    if re_.get("mean_internal") is not None and names and all(logs.get(n) for n in names):
        return names, np.asarray(re_["mean_internal"], float), np.asarray(re_["cov_internal"], float)
    mean, var = [], []
    for n in names:
        e = summary["estimate"].get(n) or {}
        lo, hi = e.get("hdi95") or [None, None]
        med = e.get("median", e.get("mean"))
        if not all(v is not None and math.isfinite(v) and v > 0 for v in (lo, hi, med)):
            return None
        mean.append(math.log(med))
        var.append(((math.log(hi) - math.log(lo)) / (2 * _Z95)) ** 2)
    return names, np.asarray(mean), np.diag(var)


def read_condition(cond, folders: dict, errors: dict) -> ConditionResult:
    """A :class:`ConditionResult` from the condition's finished run folders ``{job name: folder}``;
    ``errors``: ``{job name: one-line error}`` of the runs that failed."""
    res = ConditionResult(
        cond.name, dict(cond.labels), folders={k: str(v) for k, v in folders.items()}, errors=dict(errors)
    )
    summaries = {k: read_json(Path(f) / "summary.json") for k, f in folders.items() if k != "diagnose"}
    for m in CONSTANT_METHODS:
        s = summaries.get(m)
        if s is None:
            continue
        g = log_gaussian(s)
        res.method, res.estimate = m, s.get("estimate", {})
        res.params = tuple(s.get("parameters") or res.estimate)
        res.between = s.get("between_experiments") or {}
        res.n_bubbles = s.get("n_experiments")
        described = (s.get("fit_check") or {}).get("described")
        res.described = None if described is None else bool(described)
        if g is not None:
            res.log_mean, res.log_cov = g[1], g[2]
        break
    if "mienks" in summaries:
        res.time_resolved = list(summaries["mienks"].get("time_resolved") or [])
    if "diagnose" in folders:
        d = read_json(Path(folders["diagnose"]) / "diagnosis.json")
        res.diagnose = {"verdict": (d.get("constant_parameter_check") or {}).get("verdict"), "cause": d.get("cause")}
    return res
