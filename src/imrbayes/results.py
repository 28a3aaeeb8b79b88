"""A fit's results as data: :func:`load_run` (``imrbayes.load_run``) reads a run directory written by
``imrbayes fit`` into a :class:`Run` (the estimates, the ArviZ posterior, G(t) and mu(t) as a
DataFrame, the per-experiment table), and :func:`write_tables` writes the same tables as CSV
(``estimate.csv``, ``time_resolved.csv``) beside ``summary.json``.

Every number is in SI units (G [Pa], mu [Pa s], Rmax and Req [m], time origin [s]); the column
names carry the unit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

__all__ = ["Run", "load_run", "estimate_table", "time_resolved_table", "per_experiment_table", "write_tables"]

#: SI unit of each nuisance quantity of ``per_experiment[].nuisance`` (column name prefix, unit)
_NUISANCE = {"rmax_m": ("Rmax", "m"), "req_m": ("Req", "m"), "t0_s": ("t0", "s")}


def _units(summary: dict) -> dict:
    """{parameter: SI unit} of the run's constitutive model (G, mu: Pa, Pa s when unknown)."""
    out = {"G": "Pa", "mu": "Pa s"}
    try:
        from imrbayes.forward.constitutive.base import get_model

        out.update({p.name: p.unit for p in get_model(summary.get("model", "")).parameters})
    except Exception:  # a model this version does not know: the common units
        pass
    return out


def _num(x) -> float:
    try:
        return float(x)
    except (TypeError, ValueError):
        return math.nan


def _hdi(e: dict) -> tuple:
    hdi = e.get("hdi95") or [None, None]
    return (_num(hdi[0]), _num(hdi[1])) if len(hdi) == 2 else (math.nan, math.nan)


def estimate_table(summary: dict) -> pd.DataFrame:
    """One row per parameter: ``parameter``, ``unit`` (SI), ``mean``, ``sd``, ``hdi95_low``,
    ``hdi95_high`` (the 95 % highest-density interval), all in that unit; NaN where the method gives
    no value."""
    units = _units(summary)
    rows = []
    for p in summary.get("parameters", []):
        e = (summary.get("estimate") or {}).get(p) or {}
        lo, hi = _hdi(e)
        rows.append(
            {
                "parameter": p,
                "unit": units.get(p, ""),
                "mean": _num(e.get("mean")),
                "sd": _num(e.get("sd")),
                "hdi95_low": lo,
                "hdi95_high": hi,
            }
        )
    return pd.DataFrame(rows, columns=["parameter", "unit", "mean", "sd", "hdi95_low", "hdi95_high"])


def time_resolved_table(summary: dict) -> pd.DataFrame | None:
    """MIEnKS-MDA's G(t), mu(t): one row per covered sample, ``t_star [-]``, ``sample`` and per
    parameter ``{p}_mean``, ``{p}_sd``, ``{p}_hdi95_low``, ``{p}_hdi95_high`` with the SI unit in
    brackets; None when the method does not resolve time."""
    entries = summary.get("time_resolved")
    if not entries:
        return None
    units = _units(summary)
    rows = []
    for x in entries:
        row = {"t_star [-]": _num(x.get("t_star")), "sample": x.get("sample")}
        for p in summary.get("parameters", []):
            e = x.get(p) or {}
            u = units.get(p, "")
            lo, hi = _hdi(e)
            row.update(
                {
                    f"{p}_mean [{u}]": _num(e.get("mean")),
                    f"{p}_sd [{u}]": _num(e.get("sd")),
                    f"{p}_hdi95_low [{u}]": lo,
                    f"{p}_hdi95_high [{u}]": hi,
                }
            )
        rows.append(row)
    return pd.DataFrame(rows)


def per_experiment_table(summary: dict) -> pd.DataFrame:
    """One row per experiment: ``experiment``, its own ``{p}_mean``/``{p}_sd`` [SI] where the method
    estimates each bubble, the nuisance estimates (``Rmax``, ``Req`` [m], ``t0`` [s]: mean and sd)
    where it infers them, and ``failed``."""
    units = _units(summary)
    params = summary.get("parameters", [])
    rows = []
    for i, x in enumerate(summary.get("per_experiment") or []):
        if not isinstance(x, dict):
            continue
        row = {"experiment": x.get("name", str(i))}
        est = x.get("estimate")
        if isinstance(est, dict):
            for p in params:
                e = est.get(p) or {}
                row[f"{p}_mean [{units.get(p, '')}]"] = _num(e.get("mean"))
                row[f"{p}_sd [{units.get(p, '')}]"] = _num(e.get("sd"))
        for key, v in (x.get("nuisance") or {}).items():
            if isinstance(v, dict):
                label, unit = _NUISANCE.get(key, (key, ""))
                row[f"{label}_mean [{unit}]"] = _num(v.get("mean"))
                row[f"{label}_sd [{unit}]"] = _num(v.get("sd"))
        row["failed"] = bool(x.get("failed", False))
        rows.append(row)
    return pd.DataFrame(rows)


@dataclass
class Run:
    """A run directory written by ``imrbayes fit``, as data (SI units throughout).

    Attributes
    ----------
    path : Path
        The run directory.
    summary : dict
        ``summary.json`` as written.
    estimates : dict
        ``{parameter: {"mean", "sd", "hdi95_low", "hdi95_high", "unit"}}`` (SI).
    posterior : xarray.DataTree or None
        ``posterior.nc`` (ArviZ groups ``posterior``, ``observed_data``, ...); None when absent.
    time_resolved : pandas.DataFrame or None
        G(t), mu(t) (:func:`time_resolved_table`), MIEnKS-MDA only.
    per_experiment : pandas.DataFrame
        :func:`per_experiment_table`.
    """

    path: Path
    summary: dict
    estimates: dict
    posterior: Any
    time_resolved: pd.DataFrame | None
    per_experiment: pd.DataFrame

    @property
    def method(self) -> str:
        return self.summary.get("method", "")

    @property
    def model(self) -> str:
        return self.summary.get("model", "")


def load_run(path) -> Run:
    """Read the run directory ``path`` written by ``imrbayes fit``.

    Raises :class:`~imrbayes.errors.InputError` naming the file for a missing directory, a missing
    or invalid ``summary.json`` or an unreadable ``posterior.nc``.
    """
    from imrbayes.report import read_run_dir

    parts = read_run_dir(path)
    s = parts["summary"]
    table = estimate_table(s)
    estimates = {
        r["parameter"]: {k: r[k] for k in ("mean", "sd", "hdi95_low", "hdi95_high", "unit")}
        for r in table.to_dict("records")
    }
    return Run(
        path=parts["run_dir"],
        summary=s,
        estimates=estimates,
        posterior=parts["posterior"],
        time_resolved=time_resolved_table(s),
        per_experiment=per_experiment_table(s),
    )


def write_tables(out, summary: dict) -> list:
    """``estimate.csv`` and, where the method resolves time, ``time_resolved.csv`` under ``out``;
    returns the paths written."""
    out = Path(out)
    paths = [out / "estimate.csv"]
    estimate_table(summary).to_csv(paths[0], index=False)
    tr = time_resolved_table(summary)
    if tr is not None:
        paths.append(out / "time_resolved.csv")
        tr.to_csv(paths[-1], index=False)
    return paths
