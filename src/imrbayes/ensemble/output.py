"""Writing a fit: ``summary.json`` (interfaces.md §3) and ``posterior.nc`` (ArviZ DataTree)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from imrbayes.io import jsonable, write_json

__all__ = ["summary_dict", "posterior_tree", "write_summary", "write_posterior"]


def summary_dict(result, obs, *, seed: int, extra: dict | None = None) -> dict:
    """The summary.json object: the stable keys of interfaces.md §3 plus method details."""
    out = {
        "method": result.method,
        "model": result.model,
        "parameters": list(result.param_names),
        "seed": int(seed),
        "n_experiments": int(obs.n_exp),
        "runtime_s": float(result.runtime_s),
        "estimate": result.estimate,
        "fit": {
            "rmse": result.rmse,
            "n_samples": result.n_fit_samples,
            "rmse_definition": "sqrt(mean((fitted R* - measured R*)^2)) over the fitted (experiment, sample) pairs",
        },
    }
    for key in ("between_experiments", "predictive", "likelihood"):  # interfaces.md §4
        if key in result.details:
            out[key] = result.details[key]
    if result.windows is not None:
        out["windows"] = result.windows
    if result.time_resolved is not None:
        out["time_resolved"] = result.time_resolved
    out["per_experiment"] = result.per_experiment
    out["details"] = result.details
    out["warnings"] = list(result.warnings)
    if extra:
        out.update(extra)
    return jsonable(out)


def write_summary(path, summary: dict) -> Path:
    """``summary.json`` (:func:`imrbayes.io.write_json`: atomic, indent 1, strict JSON)."""
    return write_json(path, summary)


def posterior_tree(result, obs):
    """ArviZ DataTree: ``posterior`` (chain, draw[, window]), ``observed_data`` R (experiment, time),
    ``log_likelihood`` R (chain, draw, experiment, time) where the method gives one, plus the
    method's extra groups (``landscape``, ``time_resolved``) as plain datasets."""
    import arviz as az
    import xarray as xr

    # plain coordinates index a dimension; (dims, values) tuples (window_start) are attached below
    coords = {k: v for k, v in result.coords.items() if not isinstance(v, tuple)}
    coords.setdefault("experiment", list(obs.names))
    data = {"posterior": dict(result.posterior), "observed_data": {"R_obs": obs.R_star}}
    dims = dict(result.posterior_dims)
    dims["R_obs"] = ["experiment", "t_obs"]
    coords["t_obs"] = obs.t_star
    if result.log_likelihood is not None:
        data["log_likelihood"] = dict(result.log_likelihood)
    used = set()
    for v in dims.values():
        used.update(v)
    dt = az.from_dict(
        data,
        dims=dims,
        coords={k: v for k, v in coords.items() if k in used},
        attrs={"/": {"method": result.method, "model": result.model, "inference_library": "imrbayes"}},
    )
    for group, variables in result.extra_groups.items():
        ds = xr.Dataset(
            {
                k: (result.extra_dims.get(k, [f"{k}_dim_{i}" for i in range(np.ndim(v))]), np.asarray(v))
                for k, v in variables.items()
            }
        )
        for dim in ds.dims:
            if dim in result.coords and not isinstance(result.coords[dim], tuple):
                ds = ds.assign_coords({dim: np.asarray(result.coords[dim])})
        dt[group] = xr.DataTree(ds)
    _attach_tuple_coords(dt, result.coords)
    return dt


def _attach_tuple_coords(dt, coords: dict) -> None:
    """Put each ``(dims, values)`` coordinate (e.g. MIEnKS's ``window_start``: ``("window", t0)``,
    or a 2-column ``(("window", "bound"), spans)``) on every group of ``dt`` that has its first
    dimension, with the plain coordinates of its other dimensions; netCDF stores them as
    non-index coordinates, so they round-trip."""
    import xarray as xr

    tupled = {
        k: (((v[0],) if isinstance(v[0], str) else tuple(v[0])), np.asarray(v[1]))
        for k, v in coords.items()
        if isinstance(v, tuple)
    }
    for group in list(dt.children):
        ds = dt[group].to_dataset()
        add = {k: v for k, v in tupled.items() if v[0][0] in ds.dims}
        if not add:
            continue
        others = {
            d: np.asarray(coords[d])
            for dims, _ in add.values()
            for d in dims[1:]
            if d not in ds.coords and d in coords and not isinstance(coords[d], tuple)
        }
        dt[group] = xr.DataTree(ds.assign_coords({**others, **add}))


def write_posterior(path, result, obs) -> Path:
    path = Path(path)
    posterior_tree(result, obs).to_netcdf(path)
    return path
