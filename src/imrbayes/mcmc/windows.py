"""MCMC of every MIEnKS-MDA window, ``mcmc.nc`` and ``compare.json`` (interfaces.md §2-3).

Given a MIEnKS-MDA fit -- its window list (``FitResult.windows`` or ``summary.json["windows"]``)
and its settings (L, h, RTPS factor a, fusion) -- :func:`mienks_window_specs` builds, for every
window j, the target density the window's analysis approximates
(:func:`imrbayes.mcmc.target.window_target_from_ensemble`) and the ensemble's fused Gaussian to
compare with:

* **prior** (m_j, C_j) of the window's parameters: with ``fusion="chain"`` (the default of
  ``fit_mienks``) the previous window's fused posterior after RTPS of the standard deviations
  (correlations kept), chained from the parameter prior at window 0 --
  ``m_{j+1} = mu_j``, ``C_{j+1} = rtps_cov(C_j, Sigma_j, a)``; with ``fusion="prior"`` the
  parameter prior in every window;
* **observation weight** beta_jk / L (:func:`imrbayes.ensemble.windows.mda_weights`;
  ``obs_weight="mean"``, fit_mienks' default), or beta_jk (``obs_weight="mda"``);
* **start state** of each experiment at t*_{jh}: the smoother's handed-off ensemble mean when it
  is given (``start_states``; ``fit_mienks`` exposes it as ``FitResult.window_start_states``, and
  ``imrbayes fit --mcmc`` uses it). Without it (e.g. from a summary.json alone) the state is
  *reconstructed* by propagating each experiment from its maximum with piecewise-constant
  parameters: experiment n's posterior mean of window k (``per_experiment[n]["mean_internal"]``)
  over [t*_{kh}, t*_{(k+1)h}] -- the interval over which the smoother hands that window's
  posterior on. The reconstruction ignores the smoother's state updates and the ensemble spread;
  its effect shows as a shift of the MCMC posterior in late windows, so read late-window
  disagreements with this in mind (``spec.state_source`` says which was used).

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
from imrbayes.mcmc.target import GaussianPrior, WindowTarget, window_target_from_ensemble

__all__ = ["WindowSpec", "WindowMCMC", "chain_priors", "reconstruct_start_states", "mienks_window_specs",
           "sample_windows", "mcmc_tree", "write_mcmc", "write_compare", "compare_from_tree", "window_seed"]


def _rtps_cov(prior_c, post_c, a):
    """RTPS of a covariance: sd -> sd_post + a (sd_prior - sd_post), correlations kept (as fit_mienks)."""
    sp, sa = np.sqrt(np.diag(prior_c)), np.sqrt(np.diag(post_c))
    f = np.where(sa > 0, ((1.0 - a) * sa + a * sp) / np.where(sa > 0, sa, 1.0), 1.0)
    return post_c * np.outer(f, f)


def chain_priors(windows, prior_mean, prior_cov, rtps: float, fusion: str = "chain"):
    """[(m_j, C_j)] the parameter prior of every window (module docstring), internal coordinates."""
    m, C = np.asarray(prior_mean, float), np.asarray(prior_cov, float)
    out = []
    for w in windows:
        out.append((m.copy(), C.copy()))
        if fusion == "chain":
            mu, S = np.asarray(w["mean_internal"], float), np.asarray(w["cov_internal"], float)
            m, C = mu, _rtps_cov(C, S, float(rtps))
        elif fusion != "prior":
            raise InputError("fusion", f"must be 'chain' or 'prior', got {fusion!r}")
    return out


def reconstruct_start_states(fm, obs, windows, h: int, positive) -> list:
    """[BatchState (N_exp,)] the state of every experiment at each window start, propagated from its
    maximum with experiment n's window-k posterior mean over [t*_{kh}, t*_{(k+1)h}] (module docstring).
    Raises if a propagation fails."""
    positive = np.asarray(positive, bool)
    t = np.asarray(obs.t_star, float)
    state = fm.initial_state(obs.rmax_m, obs.req_m)
    states = []
    for j, w in enumerate(windows):
        a = int(w["samples"][0]) if "samples" in w else j * h
        if abs(state.t_star - t[a]) > 1e-12:
            raise InputError("windows", f"window {j} starts at sample {a}, not at {state.t_star:g} + h")
        states.append(state.copy())
        if j == len(windows) - 1:
            break
        z = np.array([p["mean_internal"] for p in w["per_experiment"]], dtype=float)
        theta = np.where(positive, np.exp(np.where(positive, z, 0.0)), z)
        out = fm.propagate(state, theta, float(t[a + h]))
        if np.any(out.failed):
            raise RuntimeError(f"reconstructing the start of window {j + 1}: forward solve failed for "
                               f"{int(out.failed.sum())} experiment(s)")
        state = out.end
    return states


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
    state_source: str = "reconstructed"


def mienks_window_specs(fm, obs, space, windows, settings: dict, *, start_states=None, indices=None,
                        box_sd: float = 10.0, model=None) -> list:
    """Window targets of a MIEnKS-MDA fit (module docstring).

    fm : ForwardModel; obs : Observations (t_star, R_star, P, rmax_m, req_m, names);
    space : ParamSpace (names, positive, prior_mean, prior_cov);
    windows : list of window dicts (``FitResult.windows`` / ``summary.json["windows"]``) with
        ``index``, ``t_star``, ``samples``, ``mean_internal``, ``cov_internal``, ``per_experiment``;
    settings : the fit's MIEnKS settings (``L``, ``h``, ``rtps``, ``fusion``, ``obs_weight``);
    start_states : optional list (one per window) of the smoother's handed-off ensembles
        (BatchState of N_exp x N_En members, experiment-major) or of their mean states ((N_exp,
        n_state) arrays, ``FitResult.window_start_states``; experiments with a NaN row are left out of
        that window) -- used instead of the reconstruction;
    indices : windows to build (default all); model : ForwardModel or Runner for the targets (default fm).
    """
    from imrbayes.ensemble.windows import mda_weights

    L, h = int(settings["L"]), int(settings["h"])
    rtps, fusion = float(settings.get("rtps", 0.7)), settings.get("fusion", "chain")
    obs_weight = settings.get("obs_weight", "mean")
    if obs_weight not in ("mean", "mda"):
        raise InputError("obs_weight", f"must be 'mean' or 'mda', got {obs_weight!r}")
    average = L if obs_weight == "mean" else 1          # weight beta_jk / average
    n_steps = obs.t_star.size - 1
    beta = mda_weights(n_steps, L, h)
    if len(windows) != beta.shape[0]:
        raise InputError("windows", f"{len(windows)} windows, but L = {L}, h = {h} over {n_steps} steps give "
                                    f"{beta.shape[0]}")
    priors = chain_priors(windows, space.prior_mean, space.prior_cov, rtps, fusion)
    positive = np.asarray(space.positive, bool)
    recon = reconstruct_start_states(fm, obs, windows, h, positive) if start_states is None else None
    specs = []
    for j in (range(len(windows)) if indices is None else indices):
        w = windows[j]
        a, b = (int(w["samples"][0]), int(w["samples"][1])) if "samples" in w else (j * h, j * h + L - 1)
        m, C = priors[j]
        prior = GaussianPrior(m, C, positive, tuple(space.names), "internal", box_sd)
        rows = np.arange(obs.R_star.shape[0])
        if start_states is None:
            ens = recon[j]
        elif isinstance(start_states[j], BatchState):
            ens = start_states[j]
        else:                   # (N_exp, n_state) mean states (FitResult.window_start_states); NaN rows: left out
            q = np.asarray(start_states[j], dtype=np.float64)
            rows = np.flatnonzero(np.all(np.isfinite(q), axis=1))
            if rows.size == 0:
                raise InputError("start_states", f"window {j}: no experiment has a valid start state")
            ens = BatchState(q[rows].copy(), float(obs.t_star[a]), np.asarray(obs.rmax_m, float)[rows],
                             np.asarray(obs.req_m, float)[rows])
        tg = window_target_from_ensemble(model or fm, ens, obs.t_star[a:b + 1], obs.R_star[rows, a:b + 1],
                                         obs.P[a:b + 1], prior, mda_weight=beta[j, a:b + 1], L=average,
                                         n_exp=rows.size, names=[obs.names[i] for i in rows], index=j)
        src = "reconstructed" if start_states is None else "handed-off ensemble mean"
        tg.description["state"] = src
        specs.append(WindowSpec(j, (float(obs.t_star[a]), float(obs.t_star[b])), tg,
                                np.asarray(w["mean_internal"], float), np.asarray(w["cov_internal"], float),
                                m, C, src))
    return specs


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


def sample_windows(specs, settings: MCMCSettings | None = None, seed: int = 0, backend=None, progress=None,
                   start: str = "ensemble", loglik: bool = True, callback=None) -> list:
    """MCMC of every window spec, then its comparison with the ensemble Gaussian.

    start : ``"ensemble"`` (walkers start from the window's fused Gaussian, the default) or
        ``"prior"`` (from the window's prior: an independent start, slower to converge).
    backend : HDF5 file (one group per window, ``window_XX/chain_c``; a rerun resumes).
    callback(result) after each window.
    """
    out = []
    for sp in specs:
        m, C = (sp.ens_mean, sp.ens_cov) if start == "ensemble" else (sp.prior_mean, sp.prior_cov)
        run = run_mcmc(sp.target, m, C, settings, seed=window_seed(seed, sp.index), backend=backend,
                       name=f"window_{sp.index:02d}", progress=progress)
        tree = run.to_datatree(sp.target, loglik=loglik)
        entry = compare_window(sp.ens_mean, sp.ens_cov, tree, sp.target.param_names, sp.target.prior.positive,
                               index=sp.index, t_star=sp.t_star, diagnostics=run.diagnostics(), seed=sp.index)
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
        nodes[name] = xr.Dataset(attrs=dict(r.tree.attrs))              # diagnostics_json, target_json, ...
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
    tree.attrs.update({"inference_library": "emcee", "sampler": "imrbayes.mcmc", "n_windows": len(results),
                       "layout": "window_XX/{posterior,sample_stats,log_likelihood,observed_data,constant_data} "
                                 "per window; top-level posterior/sample_stats with a window dimension "
                                 f"(every window thinned evenly to {D} draws)",
                       **(attrs or {})})
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
        e = compare_window(ens["mean_internal"], ens["cov_internal"], node, names, positive, index=j,
                           t_star=ens.get("t_star"), diagnostics=diag, seed=j)
        if ens.get("state_source"):
            e["state_source"] = ens["state_source"]
        entries.append(e)
    return compare_windows(entries)
