"""emcee benchmark: the whole ``fit --mcmc`` run (headline), the move/walker sweep, one window.

**Headline** (``--whole-run DATA OUT [--method mienks|en4dvar]``): ``imrbayes fit DATA --method M
--mcmc`` with the default settings (stop on convergence, the default moves, 4 x 8 walkers, quadrature),
its wall time, the CPU time of the process tree and the load average during it (the 2-core machine
is shared), and per window: steps, evaluations, stop reason, R-hat, bulk/tail ESS, ESS per second,
quadrature cost. This replaces the 18-window projection of earlier versions with the measurement.
``--collect RUN_DIR`` gives the same per-window rows for a run that was interrupted (from its
checkpointed units, with each unit's wall time).

**Sweep** (``--sweep MOVES@WALKERS ... --sweep-windows 0 6 12 --fit-cache fit.pkl``): each move
mixture x walker count sampled to convergence on the targets ``fit --mcmc`` builds from a MIEnKS-MDA
fit of the verification case; evaluations (forward solves of all experiments) to convergence,
tau, ESS per evaluation (docs/methods.md).

**One window** (the default mode, below):

Window j (default 0) of L = 35 samples shifted by h = 5 (the paper's windows) over the 5 noisy
experiments, weights beta_jk / L, the paper prior on (log G, log mu), each experiment started from
its true state at t*_{jh} (the truth propagated from the maximum: the state an ideal hand-off would
give). ``n_chains`` independent ensembles of ``n_walkers`` walkers, ``n_steps`` steps each, started
from the prior; all ensembles' walkers x experiments share one forward batch per emcee half-step.

For each forward setting: wall time, log-prob evaluations, forward member-runs and the time per
member-run, steps per second, emcee's autocorrelation time tau and n_steps / tau (rule: >= 50),
max R-hat, min bulk/tail ESS (one chain per ensemble), ESS per second, acceptance, and the posterior
of G and mu against the truth. ``--json FILE`` writes the rows. The brief's default (32 walkers x
2000 steps x 4 ensembles x 5 experiments = 1.28 M member-runs) takes hours with the thermal bubble
on a laptop: use ``--steps``/``--chains`` to scale it down; the table's ``proj_default_h`` column
gives the projected time of the default run from the measured cost per member-run, and
``one_ens_s`` the time of the target's unit -- one ensemble of 32 walkers x 2000 steps over all
experiments -- from the same cost (sampling only: the wall time excludes the pointwise
log-likelihood recompute, reported as ``loglik_recompute_s``).

``--window-costs`` also times one log-probability batch in each of the 18 windows: windows across
a collapse take several times more steps than window 0, and the 18-window projection sums them.

Every mode that times something in this run also times the host yardstick
(``_machine.host_yardstick``) and writes each time as a multiple of it (``*_per_yardstick``; printed
as ``x yard``): the number that compares across hosts. The absolute times stay in the JSON as facts
of the host named there. ``--collect`` reads times from an earlier run and adds no ratio.

Usage: python benchmarks/mcmc.py [--forward converged imrv2-fd polytropic] [--walkers 32] [--steps 2000]
                                 [--chains 4] [--window 0] [--seed 0] [--window-costs] [--json results/mcmc_window.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from _machine import add_yardstick_ratios, host_yardstick, machine_info, results_path

from imrbayes.ensemble import ParamSpace
from imrbayes.ensemble.windows import mda_weights, window_spans
from imrbayes.forward import ForwardModel
from imrbayes.io import jsonable
from imrbayes.mcmc import MCMCSettings, WindowTarget, run_mcmc
from imrbayes.validation.suite import TRUTH, verification_data

FORWARD = {"converged": {}, "imrv2-fd": {"scheme": "imrv2-fd"}, "polytropic": {"bubble": "polytropic"}}
DEFAULT_RUNS = 32 * 2000 * 4 * 5  # member-runs of the default benchmark (5 experiments)
ENSEMBLE_RUNS = 32 * 2000 * 5  # one ensemble of 32 walkers x 2000 steps (the speed target's unit)


def window_target(fm, obs, j: int, L: int = 35, h: int = 5):
    """Window j's target with the experiments' true states at its start (see module doc)."""
    n_steps = obs.t_star.size - 1
    a, b = window_spans(n_steps, L, h)[j]
    beta = mda_weights(n_steps, L, h)[j, a : b + 1]
    st = fm.initial_state(obs.rmax_m, obs.req_m)
    if a > 0:
        ne = obs.rmax_m.size
        out = fm.propagate(st, {"G": np.full(ne, TRUTH["G"]), "mu": np.full(ne, TRUTH["mu"])}, float(obs.t_star[a]))
        st = out.end
    prior = ParamSpace.for_model(fm.constitutive)
    tg = WindowTarget(
        fm,
        st,
        obs.t_star[a : b + 1],
        obs.R_star[:, a : b + 1],
        obs.P[a : b + 1],
        prior,
        beta / L,
        list(obs.names),
        description={
            "kind": "verification window",
            "index": int(j),
            "L": L,
            "h": h,
            "state": "truth propagated to the window start",
        },
    )
    return tg, (float(obs.t_star[a]), float(obs.t_star[b]))


def window_costs(fm, obs, n_draws: int = 64, seed: int = 0, repeat: int = 3) -> list[dict]:
    """Cost of one log-probability batch in every window (no sampling): ``n_draws`` parameter sets
    from the window prior x N_exp experiments, best of ``repeat``. Windows across a collapse take
    several times more integrator steps than window 0, so the 18-window time is the sum of these
    costs, not 18 times window 0's."""
    n_steps = obs.t_star.size - 1
    out = []
    for j in range(len(window_spans(n_steps, 35, 5))):
        tg, span = window_target(fm, obs, j)
        rng = np.random.default_rng(seed + j)
        Z = tg.prior.prior_mean + rng.standard_normal((n_draws, tg.ndim)) @ np.linalg.cholesky(tg.prior.prior_cov).T
        tg.log_prob(Z[:2])
        best = np.inf
        for _ in range(repeat):
            t0 = time.perf_counter()
            tg.log_prob(Z)
            best = min(best, time.perf_counter() - t0)
        ms = 1e3 * best / (n_draws * tg.n_exp)
        out.append(
            {"window": j, "t_star": span, "ms_per_member_run": ms, "projected_default_h": DEFAULT_RUNS * ms / 3.6e6}
        )
    return out


def fitted_windows(fm, seed: int = 0, cache: str | None = None):
    """(obs, space, FitResult) of MIEnKS-MDA (default settings, n_draws=1) on the verification case;
    ``cache``: a pickle file reused across invocations (the fit takes ~40 s with the thermal bubble)."""
    import pickle

    from imrbayes.ensemble import MIEnKSSettings, fit_mienks

    obs = verification_data(fm, seed)
    space = ParamSpace.for_model(fm.constitutive)
    if cache and Path(cache).is_file():
        with open(cache, "rb") as fh:
            return obs, space, pickle.load(fh)
    res = fit_mienks(fm, obs, space, MIEnKSSettings(n_draws=1), seed=seed)
    if cache:
        with open(cache, "wb") as fh:
            pickle.dump(res, fh)
    return obs, space, res


def _max_abs_z(vs: dict) -> float:
    """Largest |z| of a ``compare_to_mcmc`` result's means and sds."""
    return max(abs(v) for v in [*vs["mean_z"].values(), *vs["sd_z"].values()])


def _setting_values(pairs) -> dict | None:
    """``["indep_adapt=50", "indep_scale=2"]`` -> ``{"indep_adapt": 50, "indep_scale": 2.0}``."""
    if not pairs:
        return None
    return {k: (int(v) if v.isdigit() else float(v)) for k, v in (kv.split("=", 1) for kv in pairs)}


def sweep(
    fm,
    windows,
    configs,
    seed: int = 0,
    cap: int = 5000,
    fit_cache=None,
    n_chains: int = 4,
    init_scale: float = 2.0,
    quadrature: bool = False,
    settings: dict | None = None,
) -> list[dict]:
    """Move mixture x walker count by the cost of a converged run: each configuration samples the
    MIEnKS window's exact target (started from the window's ensemble Gaussian, over-dispersed by
    ``init_scale``) with the stop rule; reported: steps and evaluations to convergence, tau, min
    bulk/tail ESS at the stop and ESS per evaluation (= per forward solve of all experiments),
    wall time and the load average around it (the machine is shared). ``quadrature``: also the
    window's exact grid posterior (once per window) and, per row, whether the draws agree with it
    within their Monte-Carlo error (``quadrature.compare_to_mcmc``) -- a cheap move that samples the
    wrong density would show here. ``settings``: further :class:`MCMCSettings` fields."""
    from imrbayes.mcmc.fit import fit_window_specs
    from imrbayes.mcmc.quadrature import compare_to_mcmc, grid_posterior
    from imrbayes.mcmc.sampler import walker_major

    obs, space, res = fitted_windows(fm, seed, fit_cache)
    rows = []
    for j in windows:
        (sp,) = fit_window_specs(fm, obs, space, res, windows=[j])
        grid = grid_posterior(sp.target, sp.ens_mean, sp.ens_cov) if quadrature and sp.target.ndim == 2 else None
        for moves, W in configs:
            tg = sp.target
            s = MCMCSettings(
                **{
                    "n_walkers": W,
                    "n_steps": cap,
                    "n_chains": n_chains,
                    "moves": moves,
                    "init_scale": init_scale,
                    "loglik": False,
                    **(settings or {}),
                }
            )
            load0 = os.getloadavg()
            e0, t0 = tg.n_evals, time.perf_counter()
            run = run_mcmc(tg, sp.ens_mean, sp.ens_cov, s, seed=seed)
            wall = time.perf_counter() - t0
            evals = tg.n_evals - e0
            last = run.stop["checks"][-1] if run.stop["checks"] else {}
            ess = min(last.get("ess_bulk_min", 0.0), last.get("ess_tail_min", 0.0))
            row = {
                "window": j,
                "t_star": list(sp.t_star),
                "moves": moves,
                "walkers": W,
                "chains": n_chains,
                "stop_reason": run.stop["reason"],
                "n_steps": run.n_steps,
                "n_checks": len(run.stop["checks"]),
                "evals": evals,
                "member_runs": evals * tg.n_exp,
                "tau_max": run.tau_max,
                "tau_mean": float(np.mean(run.tau)),
                "walkers_x_tau": W * run.tau_max,
                "rhat_max": last.get("rhat_max"),
                "ess_bulk_min": last.get("ess_bulk_min"),
                "ess_tail_min": last.get("ess_tail_min"),
                "ess_per_1k_evals": 1e3 * ess / max(1, evals),
                "acceptance": float(run.acceptance.mean()),
                "wall_s": wall,
                "ms_per_member_run": 1e3 * wall / max(1, evals * tg.n_exp),
                "loadavg_before": list(load0),
                "loadavg_after": list(os.getloadavg()),
                "settings": settings or {},
            }
            if grid is not None:
                vs = compare_to_mcmc(grid, walker_major(run.chain, run.burn, run.thin))
                row["quadrature"] = {
                    "within_mc_error": vs["within_mc_error"],
                    "mean_z": vs["mean_z"],
                    "sd_z": vs["sd_z"],
                    "sd_ratio": vs["sd_ratio"],
                }
            rows.append(row)
            print(
                f"w{j:02d} {moves:<22} W={W:<3} {row['stop_reason']:<9} n={run.n_steps:<5} evals={evals:<7} "
                f"tau={run.tau_max:6.1f} Wtau={row['walkers_x_tau']:6.0f} R={row['rhat_max']:.4f} "
                f"ESS b/t={row['ess_bulk_min']:.0f}/{row['ess_tail_min']:.0f} ESS/1k={row['ess_per_1k_evals']:.1f} "
                f"acc={row['acceptance']:.2f} wall={wall:.1f}s load={load0[0]:.2f}"
                + (
                    f" quad ok={row['quadrature']['within_mc_error']} z={_max_abs_z(row['quadrature']):.1f}"
                    if "quadrature" in row
                    else ""
                ),
                flush=True,
            )
    return rows


def cpu_costs(fm, run_dir, fit_cache=None, seed: int = 0, n_draws: int = 64, repeat: int = 3) -> list[dict]:
    """CPU time per log-posterior evaluation in every window, at parameter sets drawn from that
    window's MCMC posterior of a finished ``fit --mcmc`` run (``run_dir/mcmc_chains/window_XXX.nc``),
    on the targets of the verification case's MIEnKS fit (:func:`fitted_windows`). Process CPU time
    (``time.process_time``), best of ``repeat``: run with ``NUMBA_NUM_THREADS=1`` it is the cost of
    one core whatever else the shared machine runs (up to cache/SMT contention), so
    sum(evaluations x CPU per evaluation) / cores projects the idle wall time of a run."""
    import xarray as xr

    from imrbayes.mcmc.fit import fit_window_specs

    obs, space, res = fitted_windows(fm, seed, fit_cache)
    out = []
    for sp in fit_window_specs(fm, obs, space, res):
        path = Path(run_dir) / "mcmc_chains" / f"window_{sp.index:03d}.nc"
        if not path.is_file():
            continue
        with xr.open_datatree(path) as dt:
            Z = np.stack([dt["posterior"][v].values.ravel() for v in sp.target.internal_names], axis=1)
        Z = Z[np.linspace(0, Z.shape[0] - 1, n_draws).round().astype(int)]
        tg = sp.target
        tg.log_prob(Z[:2])
        best_cpu, best_wall = np.inf, np.inf
        for _ in range(repeat):
            c0, t0 = time.process_time(), time.perf_counter()
            tg.log_prob(Z)
            best_cpu = min(best_cpu, time.process_time() - c0)
            best_wall = min(best_wall, time.perf_counter() - t0)
        out.append(
            {
                "window": sp.index,
                "t_star": list(sp.t_star),
                "cpu_ms_per_eval": 1e3 * best_cpu / n_draws,
                "wall_ms_per_eval": 1e3 * best_wall / n_draws,
                "n_exp": tg.n_exp,
                "loadavg": list(os.getloadavg()),
                "numba_threads": os.environ.get("NUMBA_NUM_THREADS"),
            }
        )
        print(out[-1], flush=True)
    return out


def whole_run(data, out, method: str = "mienks", extra=(), load_every: float = 30.0) -> dict:
    """The headline row: ``imrbayes fit DATA --method METHOD --mcmc`` as a subprocess (default
    settings unless ``extra`` says otherwise), its wall time, the CPU time of the process tree
    (user + sys: less sensitive than the wall time to other jobs on a shared machine; on an idle
    2-core machine wall ~ CPU / 2 when both numba threads are busy), the load average sampled every
    ``load_every`` s, and per window from compare.json: steps, evaluations, stop reason, R-hat,
    bulk/tail ESS, ESS per second, quadrature cost."""
    import resource
    import subprocess
    import threading

    cmd = [
        sys.executable,
        "-m",
        "imrbayes.cli",
        "fit",
        str(data),
        "--method",
        method,
        "--mcmc",
        "--out",
        str(out),
        "--quiet",
        *map(str, extra),
    ]
    loads, stop = [], threading.Event()

    def sample():
        while not stop.wait(load_every):
            loads.append(os.getloadavg()[0])

    th = threading.Thread(target=sample, daemon=True)
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    th.start()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    stop.set()
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    row = {
        "command": " ".join(cmd[1:]),
        "returncode": proc.returncode,
        "stderr_tail": proc.stderr[-2000:],
        "wall_s": wall,
        "cpu_s": cpu,
        "loadavg_start": list(load0),
        "loadavg_samples": loads,
        "loadavg_mean": float(np.mean(loads)) if loads else load0[0],
        "cpu": machine_info(),
    }
    summ = Path(out) / "summary.json"
    comp = Path(out) / "compare.json"
    if summ.is_file():
        s = json.loads(summ.read_text())
        row["fit_runtime_s"] = s.get("runtime_s")
        row["total_runtime_s"] = s.get("total_runtime_s")
    if comp.is_file():
        c = json.loads(comp.read_text())
        row["windows"] = [_window_row(e) for e in c["windows"]]
        row["overall"] = {
            k: c["overall"].get(k) for k in ("n_windows", "n_agree", "n_disagree", "n_undecided", "all_converged")
        }
    else:  # an interrupted run: the windows it finished, from their checkpointed units
        row.update(collect_units(out))
    if row.get("windows"):
        row["mcmc_evals"] = int(sum(w["n_evals"] or 0 for w in row["windows"]))
        row["quadrature_evals"] = int(sum(w["quadrature_evals"] or 0 for w in row["windows"]))
    return row


def _window_row(e: dict) -> dict:
    """One window of compare.json (or of its checkpointed unit) as a benchmark row."""
    m = e["mcmc"]
    smp = m.get("sampler", {})
    ess = min(min(m["ess_bulk"].values()), min(m["ess_tail"].values()))
    q = e.get("quadrature") or {}
    return {
        "window": e["index"],
        "t_star": e["t_star"],
        "agree": e["agree"],
        "converged": m["converged"],
        "stop_reason": smp.get("stop_reason"),
        "n_steps": smp.get("n_steps"),
        "n_evals": e.get("n_evals"),
        "runtime_s": e.get("runtime_s"),
        "tau_max": smp.get("tau_max"),
        "n_over_tau": smp.get("n_steps_over_tau"),
        "rhat_max": max(m["rhat"].values()),
        "ess_bulk_min": min(m["ess_bulk"].values()),
        "ess_tail_min": min(m["ess_tail"].values()),
        "ess_per_s": ess / e["runtime_s"] if e.get("runtime_s") else None,
        "kl_sym": e.get("kl_sym"),
        "w2": e.get("w2"),
        "kl_sample": e.get("kl_sample"),
        "ensemble_mean": (e.get("ensemble") or {}).get("mean"),
        "ensemble_sd": (e.get("ensemble") or {}).get("sd"),
        "mcmc_mean": m.get("mean"),
        "mcmc_sd": m.get("sd"),
        "quadrature_mean": q.get("mean"),
        "quadrature_sd": q.get("sd"),
        "quadrature_evals": q.get("n_evals"),
        "quadrature_s": q.get("runtime_s"),
        "quadrature_within_mc_error": (q.get("vs_mcmc") or {}).get("within_mc_error"),
    }


def collect_units(out) -> dict:
    """What an interrupted ``fit --mcmc`` run finished: the fit's runtime (summary.json) and, per
    finished window, its row from the checkpointed unit ``mcmc=NNN`` (with the unit's own wall
    time, ``unit_s``). ``python benchmarks/mcmc.py --collect RUN_DIR``."""
    from imrbayes.execution.store import decode_value

    out = Path(out)
    res = {"interrupted": not (out / "compare.json").is_file()}
    if (out / "summary.json").is_file():
        res["fit_runtime_s"] = json.loads((out / "summary.json").read_text()).get("runtime_s")
    wins = []
    for f in sorted((out / "units").glob("mcmc=*.npz")):
        with np.load(f, allow_pickle=False) as npz:
            doc = json.loads(str(npz["__json__"][()]))
            value = decode_value(doc["value"], npz)
        w = _window_row(value["entry"])
        w["unit_s"] = doc["meta"]["seconds"]
        wins.append(w)
    res["windows"] = wins
    res["mcmc_unit_s_total"] = float(sum(w["unit_s"] for w in wins))
    return res


def _parse_args():
    """The command line (module docstring); ``args.json`` defaults to the mode's results file."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--forward", nargs="+", default=["converged", "imrv2-fd"], choices=list(FORWARD))
    ap.add_argument("--walkers", type=int, default=32)
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--chains", type=int, default=4)
    ap.add_argument("--window", type=int, default=0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--sequential", action="store_true", help="run the ensembles one by one (no shared batches)")
    ap.add_argument("--hdf5", default=None, help="HDF5 file for the chains (default: a temporary file)")
    ap.add_argument(
        "--window-costs",
        action="store_true",
        help="also time one log-probability batch in every window (projects all 18 windows)",
    )
    ap.add_argument(
        "--json",
        default=None,
        help="[default: results/mcmc_<mode>.json: window, sweep, whole_run, cpu_costs or collected_run]",
    )
    ap.add_argument(
        "--sweep",
        nargs="*",
        default=None,
        metavar="MOVES@WALKERS",
        help="measure move mixtures x walker counts to convergence on the fit's windows "
        "(--sweep-windows), e.g. stretch@8 de@8 'de:0.8,snooker:0.2'@16",
    )
    ap.add_argument("--sweep-windows", type=int, nargs="+", default=[0])
    ap.add_argument(
        "--sweep-quadrature",
        action="store_true",
        help="also compare each sweep row with the window's exact grid posterior",
    )
    ap.add_argument(
        "--sweep-set",
        nargs="*",
        default=None,
        metavar="FIELD=VALUE",
        help="further MCMCSettings for the sweep, e.g. indep_scale=2 (numbers only)",
    )
    ap.add_argument("--fit-cache", default=None, help="pickle of the MIEnKS fit (reused when present)")
    ap.add_argument("--cap", type=int, default=5000)
    ap.add_argument("--init-scale", type=float, default=2.0)
    ap.add_argument(
        "--whole-run",
        nargs=2,
        default=None,
        metavar=("DATA", "OUT"),
        help="time 'imrbayes fit DATA --method METHOD --mcmc --out OUT' (the headline row)",
    )
    ap.add_argument("--method", default="mienks")
    ap.add_argument("--fit-args", nargs="*", default=[], help="extra arguments for --whole-run's fit")
    ap.add_argument(
        "--collect",
        default=None,
        metavar="RUN_DIR",
        help="the windows an interrupted (or finished) fit --mcmc run finished, from its units",
    )
    ap.add_argument(
        "--cpu-costs",
        default=None,
        metavar="RUN_DIR",
        help="CPU time per evaluation in every window of a finished fit --mcmc run (NUMBA_NUM_THREADS=1)",
    )
    args = ap.parse_args()
    if args.json is None:
        mode = (
            "cpu_costs"
            if args.cpu_costs is not None
            else "collected_run"
            if args.collect is not None
            else "whole_run"
            if args.whole_run is not None
            else "sweep"
            if args.sweep is not None
            else "window"
        )
        args.json = results_path(f"mcmc_{mode}")
    return args


def _run_cpu_costs(args) -> None:
    """``--cpu-costs RUN_DIR``: CPU and wall time per evaluation in every window of a finished run."""
    fm = ForwardModel("nhkv", options=FORWARD[args.forward[0]])
    rows = cpu_costs(fm, args.cpu_costs, args.fit_cache, seed=args.seed)
    yard = host_yardstick()
    for r in rows:
        add_yardstick_ratios(r, yard, ms_keys=("cpu_ms_per_eval", "wall_ms_per_eval"))
        print(
            f"window {r['window']:>3}: CPU per evaluation {r['cpu_ms_per_eval_per_yardstick']:.3g} x yard, "
            f"wall {r['wall_ms_per_eval_per_yardstick']:.3g} x yard"
        )
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(
                jsonable({"meta": {"cpu": machine_info(), "host_yardstick": yard}, "cpu_costs": rows}), fh, indent=1
            )


def _run_collect(args) -> None:
    """``--collect RUN_DIR``: the windows a fit --mcmc run finished, from its units."""
    row = {"run": args.collect, **collect_units(args.collect), "cpu": machine_info()}
    print(
        f"fit {row.get('fit_runtime_s') or float('nan'):.0f} s; {len(row['windows'])} windows finished, "
        f"{row['mcmc_unit_s_total']:.0f} s of MCMC"
    )
    print(
        f"{'window':>6} {'t*':>13} {'s':>6} {'evals':>6} {'steps':>5} {'tau':>5} {'R-hat':>6} {'ESS':>5} "
        f"{'agree':>6} {'KL':>6} {'W2':>5}"
    )
    for w in row["windows"]:
        print(
            f"{w['window']:>6} {w['t_star'][0]:>6.3f}-{w['t_star'][1]:<6.3f} {w['unit_s']:>6.0f} {w['n_evals']:>6} "
            f"{w['n_steps']:>5} {w['tau_max']:>5.1f} {w['rhat_max']:>6.3f} "
            f"{min(w['ess_bulk_min'], w['ess_tail_min']):>5.0f} {str(w['agree']):>6} {w['kl_sym']:>6.2f} "
            f"{w['w2']:>5.2f}"
        )
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(jsonable({"meta": {"cpu": machine_info()}, "collected_run": row}), fh, indent=1)


def _run_whole(args) -> None:
    """``--whole-run DATA OUT``: time one whole ``imrbayes fit --mcmc`` (the headline row)."""
    row = whole_run(args.whole_run[0], args.whole_run[1], args.method, args.fit_args)
    yard = host_yardstick()
    add_yardstick_ratios(row, yard, seconds_keys=("wall_s", "cpu_s", "fit_runtime_s", "total_runtime_s"))
    row["host_yardstick"] = yard
    print(json.dumps({k: v for k, v in row.items() if k not in ("windows", "cpu")}, indent=1, default=str))
    for w in row.get("windows", []):
        print(w)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(jsonable({"meta": {"cpu": machine_info()}, "whole_run": row}), fh, indent=1)


def _run_sweep(args) -> None:
    """``--sweep``: move mixtures x walker counts to convergence on the fit's windows."""
    fkey = args.forward[0]
    fm = ForwardModel("nhkv", options=FORWARD[fkey])
    configs = [(c.rsplit("@", 1)[0], int(c.rsplit("@", 1)[1])) for c in args.sweep]
    rows = sweep(
        fm,
        args.sweep_windows,
        configs,
        seed=args.seed,
        cap=args.cap,
        fit_cache=args.fit_cache,
        n_chains=args.chains,
        init_scale=args.init_scale,
        quadrature=args.sweep_quadrature,
        settings=_setting_values(args.sweep_set),
    )
    yard = host_yardstick()
    for r in rows:
        add_yardstick_ratios(r, yard, seconds_keys=("wall_s",), ms_keys=("ms_per_member_run",))
        print(f"w{r['window']:02d} {r['moves']:<22} W={r['walkers']:<3} wall {r['wall_s_per_yardstick']:.3g} x yard")
    if args.json:
        meta = {
            "cpu": machine_info(),
            "host_yardstick": yard,
            "forward": fkey,
            "options": fm.options.to_dict(),
            "seed": args.seed,
            "case": "methods.md §5 verification, 5 experiments; MIEnKS-MDA default fit (n_draws=1), "
            "window targets as imrbayes fit --mcmc builds them, start = ensemble Gaussian x init_scale",
            "init_scale": args.init_scale,
            "cap": args.cap,
        }
        with open(args.json, "w") as fh:
            json.dump(jsonable({"meta": meta, "sweep": rows}), fh, indent=1)


def _sampled_window_row(args, fkey: str, fm, tg, span, run, wall: float, ll_wall: float, summ) -> dict:
    """The row of one sampled window: settings, times [s], per-member-run cost [ms], convergence
    (tau, R-hat, ESS) and the posterior from the ArviZ summary ``summ``, with the default run's
    projected hours."""
    runs = run.n_evals * tg.n_exp
    ms = 1e3 * wall / max(1, runs)
    ess = float(summ.loc[["log_G", "log_mu"], "ess_bulk"].min())
    inside = {n: bool(summ.loc[n, "eti95_lb"] <= TRUTH[n] <= summ.loc[n, "eti95_ub"]) for n in TRUTH}
    return {
        "forward": fkey,
        "options": fm.options.to_dict(),
        "window": args.window,
        "t_star": span,
        "walkers": args.walkers,
        "steps": args.steps,
        "chains": args.chains,
        "n_experiments": tg.n_exp,
        "wall_s": wall,
        "loglik_recompute_s": ll_wall,
        "evals": run.n_evals,
        "member_runs": runs,
        "failed_evals": tg.n_failed,
        "ms_per_member_run": ms,
        "steps_per_s": args.steps * args.chains / wall,
        "tau_max": run.tau_max,
        "n_steps_over_tau": args.steps / run.tau_max,
        "tau_ok": bool(np.all(run.tau_ok)),
        "rhat_max": float(summ.loc[["log_G", "log_mu"], "r_hat"].max()),
        "ess_bulk_min": ess,
        "ess_tail_min": float(summ.loc[["log_G", "log_mu"], "ess_tail"].min()),
        "ess_per_s": ess / wall,
        "acceptance": float(run.acceptance.mean()),
        "burn": run.burn,
        "thin": run.thin,
        "posterior": {
            n: {
                "mean": float(summ.loc[n, "mean"]),
                "sd": float(summ.loc[n, "sd"]),
                "eti95": [float(summ.loc[n, "eti95_lb"]), float(summ.loc[n, "eti95_ub"])],
            }
            for n in TRUTH
        },
        "truth_inside_eti95": inside,
        "projected_default_h": DEFAULT_RUNS * ms / 3.6e6,
        "one_ensemble_s": ENSEMBLE_RUNS * ms / 1e3,
    }


def _print_projections(rows: list[dict]) -> None:
    """Add each row's projection over every window (``--window-costs``) and print it."""
    for row in rows:
        if "window_costs" in row:
            # emcee's own cost and the log-likelihood recompute are per evaluation, not per integrator
            # step: carried over from the sampled window as a fixed overhead per member-run.
            wc = row["window_costs"]
            overhead = max(0.0, row["ms_per_member_run"] - wc[row["window"]]["ms_per_member_run"])
            row["overhead_ms_per_member_run"] = overhead
            row["projected_all_windows_h"] = sum(DEFAULT_RUNS * (w["ms_per_member_run"] + overhead) / 3.6e6 for w in wc)
            print(f"\n{row['forward']}: log-prob batch per window [ms per member-run]")
            print("  ".join(f"{w['window']}:{w['ms_per_member_run']:.2f}" for w in wc))
            print(
                f"all {len(wc)} windows, 32 x 2000 x 4 each: {row['projected_all_windows_h']:.2f} h (plus "
                f"{overhead:.3f} ms per member-run of sampling overhead measured on window {row['window']})"
            )


def _run_window(args) -> None:
    """The default mode: sample one window with each ``--forward`` and time it."""
    import arviz as az

    rows = []
    yard = host_yardstick()
    print(f"host yardstick (x yard): {yard['row']}, {yard['ms']:.1f} ms in this run")
    print(
        f"{'forward':<11} {'x yard':>9} {'evals':>8} {'run/yard':>9} {'steps/s':>8} {'tau':>6} {'n/tau':>6} "
        f"{'R-hat':>6} {'ESS':>6} {'ESS/s':>7} {'acc':>5} {'G [kPa]':>15} {'mu [Pa s]':>17} {'proj_default_h':>14} "
        f"{'one_ens_s':>9}"
    )
    tmp = tempfile.TemporaryDirectory()
    for fkey in args.forward:
        fm = ForwardModel("nhkv", options=FORWARD[fkey])
        fm.simulate({"G": [7e3, 7e3], "mu": [0.1, 0.1]}, 263e-6, 263e-6 / 7.58, [0.0, 0.1])  # compile/load
        obs = verification_data(fm, args.seed)
        tg, span = window_target(fm, obs, args.window)
        s = MCMCSettings(n_walkers=args.walkers, n_steps=args.steps, n_chains=args.chains, lockstep=not args.sequential)
        h5 = Path(args.hdf5) if args.hdf5 else Path(tmp.name) / f"{fkey}.h5"
        t0 = time.perf_counter()
        run = run_mcmc(
            tg, settings=s, seed=args.seed, backend=h5, name=f"{fkey}/window_{args.window:02d}", resume=False
        )
        wall = time.perf_counter() - t0
        t1 = time.perf_counter()
        dt = run.to_datatree(tg)
        ll_wall = time.perf_counter() - t1
        summ = az.summary(dt, var_names=["log_G", "log_mu", "G", "mu"], ci_prob=0.95, round_to="none")
        row = _sampled_window_row(args, fkey, fm, tg, span, run, wall, ll_wall, summ)
        ess = row["ess_bulk_min"]
        add_yardstick_ratios(
            row, yard, seconds_keys=("wall_s", "loglik_recompute_s", "one_ensemble_s"), ms_keys=("ms_per_member_run",)
        )
        if args.window_costs:
            row["window_costs"] = window_costs(fm, obs, seed=args.seed)
        rows.append(row)
        p = row["posterior"]
        print(
            f"{fkey:<11} {row['wall_s_per_yardstick']:9.3g} {run.n_evals:8d} {row['ms_per_member_run_per_yardstick']:9.3g} "
            f"{row['steps_per_s']:8.1f} {run.tau_max:6.1f} "
            f"{row['n_steps_over_tau']:6.1f} {row['rhat_max']:6.3f} {ess:6.0f} {row['ess_per_s']:7.2f} "
            f"{row['acceptance']:5.2f} {p['G']['mean'] / 1e3:7.3f}±{p['G']['sd'] / 1e3:6.3f} "
            f"{p['mu']['mean']:8.4f}±{p['mu']['sd']:7.4f} {row['projected_default_h']:14.2f} {row['one_ensemble_s']:9.1f}",
            flush=True,
        )
    _print_projections(rows)
    meta = {
        "machine": platform.platform(),
        "cpus": os.cpu_count(),
        "numba_threads": os.environ.get("NUMBA_NUM_THREADS"),
        "cpu": machine_info(),
        "host_yardstick": yard,
        "case": "methods.md §5 verification, 5 experiments, paper noise; MIEnKS window (L=35, h=5), weights "
        "beta/L, paper prior, true start state",
        "truth": TRUTH,
        "seed": args.seed,
        "lockstep": not args.sequential,
    }
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(jsonable({"meta": meta, "rows": rows}), fh, indent=1)


def main():
    args = _parse_args()
    if args.cpu_costs is not None:
        _run_cpu_costs(args)
    elif args.collect is not None:
        _run_collect(args)
    elif args.whole_run is not None:
        _run_whole(args)
    elif args.sweep is not None:
        _run_sweep(args)
    else:
        _run_window(args)


if __name__ == "__main__":
    main()
