"""MCMC of the windows of a fit, ``mcmc.nc`` and ``compare.json`` (interfaces.md §2-3).

A method with a Gaussian posterior records, per window, the density its Gaussian approximates
(:class:`imrbayes.ensemble.WindowPosterior` in ``FitResult.window_posteriors``): the parameter
prior it used, the observation weights and each experiment's start state. :func:`window_specs`
turns those records into MCMC targets (:class:`imrbayes.mcmc.target.WindowTarget`) without
re-deriving anything:

* MIEnKS-MDA window j: prior (m_j, C_j) -- with ``fusion="chain"`` the previous window's fused
  posterior after RTPS, chained from the parameter prior --, weights beta_jk / L (beta_jk with
  ``obs_weight="mda"``), each experiment started from the mean of its handed-off ensemble at
  t*_{jh} (experiments left out of the window have NaN start states and are left out);
* En4D-Var: one window from the maximum over samples 1..N_t with the parameter prior and weight
  1/N_t (1 with ``obs_weight="sum"``).

:func:`sample_windows` runs :func:`imrbayes.mcmc.sampler.run_mcmc` window by window (HDF5 group
``window_XX``, so an interrupted run resumes window by window) and compares each with its
Gaussian (:func:`imrbayes.mcmc.compare.compare_window`). :func:`mcmc_tree` assembles ``mcmc.nc``:
one child node ``window_XX`` per window holding that window's full ArviZ tree (posterior,
sample_stats, log_likelihood, observed_data, constant_data), plus top-level ``posterior`` and
``sample_stats`` groups with a ``window`` dimension (every window thinned evenly to the smallest
draw count) so that ``az.summary``/``az.plot_forest`` see all windows at once.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from imrbayes.errors import InputError
from imrbayes.forward import BatchState
from imrbayes.mcmc.compare import compare_window, compare_windows
from imrbayes.mcmc.sampler import MCMCRun, MCMCSettings, run_mcmc
from imrbayes.mcmc.target import WindowTarget

__all__ = [
    "start_gaussian",
    "WindowSpec",
    "WindowMCMC",
    "window_specs",
    "sample_windows",
    "mcmc_tree",
    "write_mcmc",
    "write_compare",
    "compare_from_tree",
    "window_seed",
]


@dataclass
class WindowSpec:
    """One window to sample: its target, the ensemble's Gaussian (internal coordinates), its prior."""

    index: int
    t_star: tuple
    target: WindowTarget
    ens_mean: np.ndarray
    ens_cov: np.ndarray
    prior_mean: np.ndarray
    prior_cov: np.ndarray
    state_source: str = ""
    start: tuple | None = None  # (mean, cov) over all sampled coordinates (walker starts)
    prior_start: tuple | None = None  # the same from the prior


def window_specs(model, obs, space, posteriors, *, indices=None, box_sd: float = 10.0) -> list:
    """[WindowSpec] the MCMC targets of recorded window posteriors (module docstring).

    model : ForwardModel or Runner for the targets; obs : Observations (t_star, R_star, P, rmax_m,
    req_m, names); space : ParamSpace (names, positive); posteriors : list of
    :class:`imrbayes.ensemble.WindowPosterior` (``FitResult.window_posteriors``); indices : windows
    to build (default all); box_sd : support of each window's prior in its standard deviations.
    """
    t = np.asarray(obs.t_star, dtype=np.float64)
    specs = []
    for j in range(len(posteriors)) if indices is None else indices:
        w = posteriors[j]
        a, b = int(w.samples[0]), int(w.samples[1])
        q = np.asarray(w.start_state, dtype=np.float64)
        valid = np.all(np.isfinite(q), axis=1)
        if w.whiten is not None:  # experiments without a whitening (failed in the fit) are left out
            valid &= np.all(np.isfinite(np.asarray(w.whiten)), axis=(1, 2))
        rows = np.flatnonzero(valid)
        if rows.size == 0:
            raise InputError("start_state", f"window {w.index}: no experiment has a valid start state")
        req = np.asarray(obs.req_m if w.start_req_m is None else w.start_req_m, float)
        start = BatchState(q[rows].copy(), float(t[w.start]), np.asarray(obs.rmax_m, float)[rows], req[rows])
        prior = space.with_prior(w.prior_mean, w.prior_cov, box_sd)
        nuisance_sd = None if w.nuisance_sd is None else np.asarray(w.nuisance_sd, float)[rows]
        tg = WindowTarget(
            model,
            start,
            t[a : b + 1],
            np.asarray(obs.R_star)[rows, a : b + 1],
            np.asarray(obs.P)[a : b + 1],
            prior,
            w.weight,
            [obs.names[i] for i in rows],
            description=dict(w.description),
            whiten=None if w.whiten is None else np.asarray(w.whiten)[rows],
            nuisance_sd=nuisance_sd,
            frames=None if w.frames is None else [w.frames[i] for i in rows],
        )
        sub = w
        if w.nuisance_sd is not None:
            from dataclasses import replace

            sub = replace(
                w,
                nuisance_sd=nuisance_sd,
                nuisance_mean=np.asarray(w.nuisance_mean, float)[rows],
                nuisance_post_sd=np.asarray(w.nuisance_post_sd, float)[rows],
            )
        specs.append(
            WindowSpec(
                w.index,
                (float(t[w.start]), float(t[b])),
                tg,
                np.asarray(w.mean, float),
                np.asarray(w.cov, float),
                np.asarray(w.prior_mean, float),
                np.asarray(w.prior_cov, float),
                w.description.get("state", ""),
                sub.start_gaussian(),
                sub.start_gaussian(prior=True),
            )
        )
    return specs


def start_gaussian(sp, start: str):
    """The walkers' start Gaussian over every sampled coordinate (parameters, then time offsets)."""
    if start == "ensemble":
        return sp.start if sp.start is not None else (sp.ens_mean, sp.ens_cov)
    return sp.prior_start if sp.prior_start is not None else (sp.prior_mean, sp.prior_cov)


def window_seed(seed: int, index: int) -> int:
    """The sampler seed of window ``index`` of a run seeded ``seed`` (independent streams)."""
    return int(np.random.SeedSequence([int(seed), int(index)]).generate_state(1)[0])


@dataclass
class WindowMCMC:
    """A sampled window: its spec, the run, its DataTree and its compare.json entry."""

    spec: WindowSpec
    run: MCMCRun
    tree: object
    entry: dict = field(default_factory=dict)


def sample_windows(
    specs,
    settings: MCMCSettings | None = None,
    seed: int = 0,
    backend=None,
    progress=None,
    start: str = "ensemble",
    loglik: bool = True,
    callback=None,
) -> list:
    """MCMC of every window spec, then its comparison with the ensemble Gaussian.

    start : ``"ensemble"`` (walkers start from the window's fused Gaussian, the default) or
        ``"prior"`` (from the window's prior: an independent start, slower to converge).
    backend : HDF5 file (one group per window, ``window_XX/chain_c``; a rerun resumes).
    callback(result) after each window.
    """
    out = []
    for sp in specs:
        m, C = start_gaussian(sp, start)
        run = run_mcmc(
            sp.target,
            m,
            C,
            settings,
            seed=window_seed(seed, sp.index),
            backend=backend,
            name=f"window_{sp.index:02d}",
            progress=progress,
        )
        tree = run.to_datatree(sp.target, loglik=loglik)
        entry = compare_window(
            sp.ens_mean,
            sp.ens_cov,
            tree,
            sp.target.param_names,
            sp.target.prior.positive,
            index=sp.index,
            t_star=sp.t_star,
            diagnostics=run.diagnostics(),
            seed=sp.index,
        )
        entry["state_source"] = sp.state_source
        res = WindowMCMC(sp, run, tree, entry)
        out.append(res)
        if callback is not None:
            callback(res)
    return out


def mcmc_tree(results, attrs: dict | None = None):
    """``mcmc.nc`` as one DataTree: child node ``window_XX`` per window, plus top-level
    ``posterior``/``sample_stats`` with a ``window`` dimension (module docstring)."""
    import xarray as xr

    nodes = {}
    D = min(r.tree["posterior"].sizes["draw"] for r in results)
    post, stats = [], []
    for r in results:
        name = f"window_{r.spec.index:02d}"
        nodes[name] = xr.Dataset(attrs=dict(r.tree.attrs))  # diagnostics_json, target_json, ...
        for group in r.tree.children:
            nodes[f"{name}/{group}"] = r.tree[group].to_dataset()
        n = r.tree["posterior"].sizes["draw"]
        pick = np.unique(np.linspace(0, n - 1, D).round().astype(int))
        post.append(r.tree["posterior"].to_dataset().isel(draw=pick).assign_coords(draw=np.arange(D)))
        stats.append(r.tree["sample_stats"].to_dataset().isel(draw=pick).assign_coords(draw=np.arange(D)))
    idx = [r.spec.index for r in results]
    t0 = [r.spec.t_star[0] for r in results]
    t1 = [r.spec.t_star[1] for r in results]
    for key, parts in (("posterior", post), ("sample_stats", stats)):
        ds = xr.concat(parts, dim="window", join="override", coords="minimal", compat="override")
        ds = ds.assign_coords(window=idx, window_start=("window", t0), window_end=("window", t1))
        nodes[key] = ds.transpose("chain", "draw", "window", ...)
    tree = xr.DataTree.from_dict(nodes)
    tree["posterior"].attrs["sample_dims"] = ["chain", "draw"]
    tree.attrs.update(
        {
            "inference_library": "emcee",
            "sampler": "imrbayes.mcmc",
            "n_windows": len(results),
            "layout": "window_XX/{posterior,sample_stats,log_likelihood,observed_data,constant_data} "
            "per window; top-level posterior/sample_stats with a window dimension "
            f"(every window thinned evenly to {D} draws)",
            **(attrs or {}),
        }
    )
    return tree


def write_mcmc(path, results, attrs: dict | None = None) -> Path:
    """Write :func:`mcmc_tree` to ``path`` (netCDF, one group per node)."""
    path = Path(path)
    mcmc_tree(results, attrs).to_netcdf(path)
    return path


def write_compare(path, results_or_entries) -> dict:
    """Write ``compare.json`` (interfaces.md §3) from WindowMCMC results or entries; returns the dict."""
    from imrbayes.io import jsonable, write_json

    entries = [r.entry if isinstance(r, WindowMCMC) else r for r in results_or_entries]
    data = jsonable(compare_windows(entries))
    write_json(path, data)
    return data


def compare_from_tree(summary: dict, tree) -> dict:
    """``compare.json`` from a run directory's files: the ``mcmc.nc`` tree (``window_XX`` nodes) and
    the ensemble Gaussians -- stored with each node (``ensemble_json``, written by ``fit --mcmc``) or
    else taken from ``summary.json``'s windows (``mean_internal``/``cov_internal``); what
    ``imrbayes compare RUN_DIR`` needs. Windows without an MCMC node are skipped."""
    names = list(summary["parameters"])
    space = summary.get("details", {}).get("parameter_space", {})
    log_space = space.get("log_space", {n: True for n in names})
    positive = np.array([bool(log_space.get(n, True)) for n in names])
    from_summary = {int(w["index"]): w for w in summary.get("windows") or []}
    nodes = {}
    for key in tree.children:
        if key.startswith("window_"):
            try:
                nodes[int(key.split("_", 1)[1])] = key
            except ValueError:
                continue
    entries = []
    for j in sorted(nodes):
        node = tree[nodes[j]]
        ens = json.loads(node.attrs.get("ensemble_json", "null")) or from_summary.get(j)
        if ens is None:
            continue
        diag = json.loads(node.attrs.get("diagnostics_json", "null"))
        e = compare_window(
            ens["mean_internal"],
            ens["cov_internal"],
            node,
            names,
            positive,
            index=j,
            t_star=ens.get("t_star"),
            diagnostics=diag,
            seed=j,
        )
        if ens.get("state_source"):
            e["state_source"] = ens["state_source"]
        entries.append(e)
    return compare_windows(entries)
