"""MCMC of a finished fit, window by window, as execution units: what ``imrbayes fit --mcmc`` runs.

:func:`fit_window_specs` turns a :class:`~imrbayes.ensemble.result.FitResult` of a method with a
Gaussian posterior (``InferenceMethod.gaussian_posterior``) into the densities its Gaussians
approximate, as the method recorded them (``FitResult.window_posteriors``: prior, observation
weights, start states; :func:`imrbayes.mcmc.windows.window_specs`):

* ``mienks``: every window j -- chained prior, MDA weights beta_jk / L, each experiment started
  from the smoother's **handed-off ensemble mean state**, compared with the window's fused Gaussian;
* ``en4dvar``: the fitting window from the maximum to ``t_end`` with En4D-Var's 1/N_t weights
  (weight 1 with ``obs_weight=sum``) and the parameter prior, compared with the fused En4D-Var
  Gaussian (one "window", index 0).

:func:`run_fit_mcmc` samples each window as one unit of the execution layer
(:mod:`imrbayes.execution`; id ``mcmc=004``): windows are independent given the fit, so they run in
parallel with ``--workers``/``--scheduler``; a finished window is checkpointed (its ArviZ tree in
``mcmc_chains/window_004.nc``, its compare entry in the unit store) and an interrupted window
resumes from its HDF5 file (``mcmc_chains/window_004.h5``). A window whose sampling fails is left
out, counted and named in ``compare.json["overall"]["failed_windows"]``; the others are written.
Seeds: window j uses :func:`imrbayes.mcmc.windows.window_seed` (run seed, j) whatever the backend.

With ``MCMCSettings.quadrature`` (default) a 2-parameter window also gets its exact grid posterior
(:mod:`imrbayes.mcmc.quadrature`; stored with the window's tree as ``quadrature_json`` and in its
compare entry as ``quadrature``): ensemble Gaussian, MCMC and quadrature side by side.
"""

from __future__ import annotations

import os
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np

from imrbayes.ensemble import METHODS, ParamSpace
from imrbayes.errors import InputError
from imrbayes.execution import Execution, Unit, unit_id
from imrbayes.forward import BatchState, fm_spec, register_runner, runner_for
from imrbayes.mcmc.compare import compare_window
from imrbayes.mcmc.sampler import (
    LAPLACE_MAX_BLOCK,
    LAPLACE_MAX_RESIDUAL,
    PLACE_ROUNDS,
    MCMCSettings,
    nuisances_per_experiment,
    parse_moves,
    resolve_moves,
    run_mcmc,
)
from imrbayes.mcmc.target import WindowTarget
from imrbayes.mcmc.windows import WindowMCMC, mcmc_tree, start_gaussian, window_seed, window_specs, write_compare

__all__ = ["fit_window_specs", "mcmc_window_unit", "run_fit_mcmc"]


def fit_window_specs(fm, obs, space, res, *, runner=None, windows=None, box_sd: float = 10.0) -> list:
    """[WindowSpec] the targets of ``res`` (module docstring); ``windows``: indices (default all)."""
    method = METHODS.get(res.method)
    if method is None or not method.gaussian_posterior or res.window_posteriors is None:
        checkable = " or ".join(m.name for m in METHODS.values() if m.gaussian_posterior)
        raise InputError("--mcmc", f"needs --method {checkable} (a Gaussian posterior to check), got {res.method!r}")
    n = len(res.window_posteriors)
    idx = list(range(n)) if windows is None else sorted(set(int(j) for j in windows))
    bad = [j for j in idx if not 0 <= j < n]
    if bad:
        raise InputError(
            "--mcmc-windows",
            f"window(s) {bad} do not exist; this fit has " + ("one window (0)" if n == 1 else f"windows 0-{n - 1}"),
        )
    return window_specs(runner or fm, obs, space, res.window_posteriors, indices=idx, box_sd=box_sd)


def _target_data(tg: WindowTarget) -> dict:
    """What a worker needs to rebuild ``tg`` on its own forward model (plain arrays)."""
    p = tg.prior
    return {
        "y0": tg.start.y,
        "t0": tg.t0,
        "rmax": tg.start.rmax_m,
        "req": tg.start.req_m,
        "t_eval": tg.t_eval,
        "y": tg.y,
        "P": tg.P,
        "weight": tg.weight,
        "names": list(tg.names),
        "whiten": tg.whiten,
        "nuisance_sd": tg.nuisance_sd,
        "frames": tg.frames,
        "description": {k: v for k, v in tg.description.items() if isinstance(v, (str, int, float, list))},
        "prior": {
            "mean": p.prior_mean,
            "cov": p.prior_cov,
            "positive": np.asarray(p.positive, bool),
            "names": list(p.names),
            "scale": p.scale,
            "box_sd": float(p.box_sd),
        },
    }


def _rebuild_target(d: dict, model) -> WindowTarget:
    p = d["prior"]
    prior = ParamSpace(
        tuple(p["names"]),
        np.asarray(p["positive"], bool),
        np.asarray(p["mean"]),
        np.asarray(p["cov"]),
        {},
        p["scale"],
        float(p["box_sd"]),
    )
    start = BatchState(
        np.array(d["y0"], dtype=np.float64), float(d["t0"]), np.asarray(d["rmax"], float), np.asarray(d["req"], float)
    )
    return WindowTarget(
        model,
        start,
        d["t_eval"],
        d["y"],
        d["P"],
        prior,
        d["weight"],
        d["names"],
        description=d["description"],
        whiten=d.get("whiten"),
        nuisance_sd=d.get("nuisance_sd"),
        frames=d.get("frames"),
    )


def _atomic_netcdf(tree, path: Path) -> None:
    tmp = path.with_name(path.name + f".tmp{os.getpid()}")
    tree.to_netcdf(tmp)
    os.replace(tmp, path)


def mcmc_window_unit(unit, rng) -> dict:
    """One window: emcee (:func:`run_mcmc`), its ArviZ tree written to ``node_path``, its compare
    entry returned. ``rng`` is not used: the window's seed is ``window_seed(seed, index)``."""
    d = unit.data
    notes = _check_backend(Path(d["backend"]))
    target = _rebuild_target(d["target"], runner_for(d))
    settings = MCMCSettings(**d["settings"])
    j = int(d["index"])
    log = None
    if d.get("log"):  # no terminal for a bar: one line per convergence check

        def log(line):
            print(f"imrbayes: emcee {line}", file=sys.stderr, flush=True)

    run = run_mcmc(
        target,
        d["start_mean"],
        d["start_cov"],
        settings,
        seed=window_seed(int(d["seed"]), j),
        backend=d["backend"],
        name=f"window_{j:02d}",
        progress=d["progress"],
        log=log,
    )
    tree = run.to_datatree(target, loglik=settings.loglik)
    tree.attrs["ensemble_json"] = _json(
        {
            "mean_internal": d["ens_mean"],
            "cov_internal": d["ens_cov"],
            "t_star": list(d["t_star"]),
            "state_source": d["state_source"],
        }
    )
    target.forget()
    if settings.quadrature and target.ndim == 2:
        tree.attrs["quadrature_json"] = _json(_quadrature(target, d["ens_mean"], d["ens_cov"], run))
    entry = compare_window(
        d["ens_mean"],
        d["ens_cov"],
        tree,
        list(target.prior.names),
        target.prior.positive,
        index=j,
        t_star=d["t_star"],
        diagnostics=run.diagnostics(),
        seed=j,
    )
    entry["state_source"] = d["state_source"]
    entry["runtime_s"] = float(run.runtime_s)
    entry["n_evals"] = int(run.n_evals)
    if notes:
        entry["notes"] = entry["notes"] + "; " + notes
    path = Path(d["node_path"])
    _atomic_netcdf(tree, path)
    return {"entry": _plain(entry), "node_path": str(path)}


def _quadrature(target, mean, cov, run=None) -> dict:
    """The window's grid posterior (:func:`imrbayes.mcmc.quadrature.grid_posterior`) as a dict with
    its cost; a failure is recorded, never fatal to the window.

    Placement only decides where the grid's points go, not what they are worth (the grid's edge and
    resolution checks guard it). After a converged ``run`` the fine grid starts in the frame of the
    draws' moments, 7.5 sd wide at the usual spacing (0.375 sd): one pass of 41 x 41 evaluations,
    where the ensemble Gaussian's frame needed a coarse search and often a widened second pass
    (window 1 of the verification case: 3659 evaluations, same moments to 1e-5 sd). Otherwise the
    coarse stage locates the posterior from the ensemble Gaussian."""
    import time

    from imrbayes.mcmc.quadrature import grid_posterior

    t0, e0 = time.perf_counter(), int(getattr(target, "n_evals", 0))
    placed = "ensemble Gaussian, coarse search"
    kw = {"center": mean, "cov": cov}
    if run is not None and run.stop.get("reason") == "converged":
        x = run.draws()[0].reshape(-1, run.chain.shape[-1])
        kw = {"center": x.mean(axis=0), "cov": np.cov(x.T), "locate": False, "k": 7.5, "n": 41}
        placed = "MCMC draws' moments"
    try:
        out = grid_posterior(target, **kw).to_dict()
        out["placed_by"] = placed
    except Exception as exc:  # noqa: BLE001 - the MCMC result stands without its reference
        out = {"error": f"{type(exc).__name__}: {exc}"}
    out["runtime_s"] = time.perf_counter() - t0
    out["n_evals"] = int(getattr(target, "n_evals", 0)) - e0
    return out


def _check_backend(path: Path) -> str:
    """An HDF5 chain file left unreadable (a kill mid-write) is moved aside, so the window starts
    afresh instead of failing; returns a note saying so ("" when the file is fine or absent)."""
    if not path.exists():
        return ""
    try:
        import h5py

        with h5py.File(path, "r") as f:
            for g in f.values():
                for c in g.values():
                    c.attrs.get("iteration")
        return ""
    except Exception as exc:  # noqa: BLE001 - any HDF5 error means the file cannot be resumed
        bad = path.with_name(path.name + ".corrupt")
        os.replace(path, bad)
        return f"chain file {path.name} was unreadable ({type(exc).__name__}); moved to {bad.name}, window restarted"


def _json(obj) -> str:
    import json

    from imrbayes.io import jsonable

    return json.dumps(jsonable(obj))


def _plain(obj):
    """compare entries as plain JSON types (the unit store keeps exact floats)."""
    import json

    from imrbayes.io import jsonable

    return json.loads(json.dumps(jsonable(obj)))


#: Above this many sampled coordinates a window's chains are slow to mix: a measured 19-coordinate
#: En4D-Var window (six camera bubbles' nuisances) had tau 149-358 steps with DE and independence
#: moves and stopped at the 5000- and 12000-step caps unconverged; with the block and ridge moves
#: (the default there) tau was 39-40 steps (docs/methods.md, "The MCMC check").
MANY_COORDINATES = 8


def cost_warnings(specs, s: MCMCSettings) -> list:
    """What to expect of windows with many sampled coordinates, before they are sampled."""
    out = []
    for sp in specs:
        tg = sp.target
        d, n_par = int(tg.ndim), int(tg.prior.n)
        W = max(s.n_walkers, 2 * d)
        if d < MANY_COORDINATES:
            continue
        structured = bool({n for n, _ in parse_moves(resolve_moves(s.moves, tg))} & {"blocks", "ridge"})
        if (
            structured
            and s.moves.strip().lower() == "auto"
            and s.place in ("auto", "laplace")
            and nuisances_per_experiment(tg) <= LAPLACE_MAX_BLOCK
        ):
            out.append(
                f"MCMC window {sp.index} samples {d} coordinates ({n_par} parameters and {d - n_par} "
                f"nuisances of {tg.n_exp} experiments: Rmax, time of the maximum, Req); its start is first "
                f"placed on the target by a quadratic fit ({3 * PLACE_ROUNDS * (d + 1) * (d + 2) // 2:,} "
                f"evaluations); if the fit is Gaussian to {LAPLACE_MAX_RESIDUAL:g} nat, {s.n_chains} x "
                f"{s.n_walkers} independent walkers sample it (measured on the 7-coordinate verification "
                f"window: tau ~3 steps, ~3 000 evaluations; docs/methods.md), else the block and ridge moves (tau 35-40 steps, about "
                f"2 000 steps of {s.n_chains} x {W} walkers); at most {s.n_chains * W * s.n_steps:,} "
                f"likelihood evaluations (the cap of {s.n_steps} steps)"
            )
            continue
        tau, steps = ("35-40", "about 2 000") if structured else ("150-360", "7 500-18 000")
        head = (
            f"MCMC window {sp.index} samples {d} coordinates ({n_par} parameters and {d - n_par} nuisances "
            f"of {tg.n_exp} experiments: Rmax, time of the maximum, Req); with these moves measured runs "
            f"needed {tau} steps per autocorrelation time, so {steps} steps for 50 of them (docs/methods.md), "
            f"each {s.n_chains} x {W} walkers"
        )
        n_cap = s.n_chains * W * s.n_steps
        tail = (
            f": at the cap of {s.n_steps} steps expect agree = null, after {n_cap:,} likelihood evaluations"
            if not structured and s.n_steps < 7500
            else f"; at most {n_cap:,} likelihood evaluations (the cap of {s.n_steps} steps)"
        )
        out.append(head + tail)
    return out


def run_fit_mcmc(
    fm,
    obs,
    space,
    res,
    out,
    settings: MCMCSettings | None = None,
    seed: int = 0,
    *,
    execution=None,
    runner=None,
    windows=None,
    start: str = "ensemble",
    progress=None,
    figures: bool = True,
    warn=None,
) -> dict:
    """Sample the windows of fit ``res`` and write ``out/mcmc.nc``, ``out/compare.json`` and the
    comparison figures (``out/figures/mcmc_*.png``). Returns the compare dict.

    settings : MCMCSettings (default: its defaults -- 2 ensembles x 8 walkers, stopped on convergence);
    execution : :class:`imrbayes.execution.Execution` (default: this process, no checkpoints);
    windows : indices to sample (default all); start : ``"ensemble"`` (walkers start from the
    window's ensemble Gaussian) or ``"prior"``; progress : emcee progress bars (None: on a terminal,
    in this process only); warn : None or a callable taking one line, told before sampling what
    windows with many sampled coordinates will cost (:func:`cost_warnings`).
    """
    import xarray as xr

    s = settings or MCMCSettings()
    s.check(space.n)
    if start not in ("ensemble", "prior"):
        raise InputError("start", f"must be 'ensemble' or 'prior', got {start!r}")
    out = Path(out)
    chains = out / "mcmc_chains"
    chains.mkdir(parents=True, exist_ok=True)
    specs = fit_window_specs(fm, obs, space, res, runner=runner, windows=windows)
    if warn is not None:
        for line in cost_warnings(specs, s):
            warn(line)
    ex = execution or Execution(progress=False)
    spec, token = fm_spec(fm), register_runner(runner or fm)
    local = ex.executor is None or type(ex.executor).__name__ == "InProcessExecutor"
    units = []
    for sp in specs:
        m, C = start_gaussian(sp, start)
        units.append(
            Unit(
                unit_id(mcmc=sp.index),
                {
                    "spec": spec,
                    "runner": token,
                    "target": _target_data(sp.target),
                    "settings": asdict(s),
                    "index": sp.index,
                    "t_star": list(sp.t_star),
                    "seed": int(seed),
                    "start_mean": m,
                    "start_cov": C,
                    "ens_mean": sp.ens_mean,
                    "ens_cov": sp.ens_cov,
                    "state_source": sp.state_source,
                    "backend": str(chains / f"window_{sp.index:03d}.h5"),
                    "node_path": str(chains / f"window_{sp.index:03d}.nc"),
                    "progress": progress if local else False,
                    "log": bool(local and progress is not True and not sys.stderr.isatty()),
                },
            )
        )
    rep = ex.run(units, mcmc_window_unit, seed, desc=f"mcmc of {len(units)} window(s)")
    results, failed = [], []
    for sp in specs:
        uid = unit_id(mcmc=sp.index)
        if uid in rep.results:
            r = rep.results[uid]
            p = Path(r["node_path"])
            if not p.is_file():  # a checkpoint from another machine's run directory
                p = chains / p.name
            with xr.open_datatree(p) as dt:
                tree = dt.load()
            results.append(WindowMCMC(sp, None, tree, r["entry"]))
        else:
            failed.append({"window": sp.index, "t_star": list(sp.t_star), "error": rep.failures[uid].error})
    if not results:
        raise RuntimeError(f"MCMC failed in every window (e.g. window {failed[0]['window']}: {failed[0]['error']})")
    write_mcmc_tree(
        out / "mcmc.nc",
        results,
        {
            "method": res.method,
            "model": res.model,
            "seed": int(seed),
            "mcmc_settings_json": _json(asdict(s)),
            "start": start,
        },
    )
    compare = write_compare(out / "compare.json", results)
    if failed:
        compare["overall"]["failed_windows"] = failed
        from imrbayes.io import write_json

        write_json(out / "compare.json", compare)
    if figures:
        from imrbayes.mcmc.figures import comparison_figures

        with xr.open_datatree(out / "mcmc.nc") as tree:
            compare["figures"] = comparison_figures(
                compare, out / "figures", tree, obs.t_star, np.nanmean(obs.R_star, axis=0)
            )
    return compare


def write_mcmc_tree(path, results, attrs: dict) -> Path:
    """``mcmc.nc`` (:func:`imrbayes.mcmc.windows.mcmc_tree`) written atomically."""
    path = Path(path)
    _atomic_netcdf(mcmc_tree(results, attrs), path)
    return path
