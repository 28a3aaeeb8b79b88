"""Is the likelihood itself calibrated? The exact (MCMC) En4D-Var posterior on camera data, per seed.

``camera_calibration.py`` scores the ensemble's Gaussian. When it under-covers, either the ensemble
approximates a calibrated density badly, or the density (the default likelihood with its nuisances)
is itself off. This script answers the second: for each seed it writes the same data set as
``camera_calibration.py --family camera`` (6 bubbles, 1 Mfps, random phase, noise 0.02 R*, Req not
given; polytropic by default, for cost) and runs

    imrbayes fit DATA --method en4dvar --forward bubble=B --mcmc --seed 0 --out OUT/seed_S/fit --resume

(the window's density sampled to convergence with the default moves: since session 43 the block and
ridge moves, ~170-200 k evaluations per seed polytropic), then scores, against the truth, both the
MCMC posterior (equal-tailed 95 % interval of the draws) and the ensemble's estimate of the same
fit. Every seed's fit is its own checkpointed run folder: rerunning the command resumes and skips
finished seeds; ``--collect`` only reads what is there.

    python validation/camera_mcmc_calibration.py --first-seed 100 --seeds 20 --out runs/mcmc-cal \
        --json validation/results/camera_mcmc_calibration.json
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from camera_calibration import TRUTH, simulate, wilson  # noqa: E402


def run_seed(out: Path, seed: int, bubble: str) -> Path:
    """Data and the fit with its MCMC check for one seed (resumed where it stopped)."""
    folder = out / f"seed_{seed}"
    data, fit = folder / "data", folder / "fit"
    if not (data / "truth.json").is_file():
        simulate(data, seed, "camera", bubble)
    if not (fit / "compare.json").is_file():
        cmd = [sys.executable, "-m", "imrbayes.cli", "fit", str(data), "--method", "en4dvar", "--forward",
               f"bubble={bubble}", "--mcmc", "--seed", "0", "--out", str(fit), "--resume", "--quiet"]
        subprocess.run(cmd, check=True)
    return folder


def score_seed(folder: Path) -> dict | None:
    """The MCMC and ensemble posteriors of a finished seed against the truth (None if unfinished)."""
    import xarray as xr

    fit = folder / "fit"
    if not (fit / "compare.json").is_file():
        return None
    summary = json.loads((fit / "summary.json").read_text())
    entry = json.loads((fit / "compare.json").read_text())["windows"][0]
    with xr.open_datatree(fit / "mcmc.nc") as dt:
        post = dt["window_00"]["posterior"]
        draws = {n: np.asarray(post[n]).ravel() for n in TRUTH}
        nuisance = score_nuisances(json.loads((folder / "data" / "truth.json").read_text()), summary, post)
    row = {"seed": int(folder.name.split("_")[1]), "agree": entry.get("agree"),
           "n_evals": entry.get("n_evals"), "converged": entry["mcmc"]["sampler"].get("stop_reason") == "converged",
           "nuisance": nuisance}
    for n, true in TRUTH.items():
        lo, hi = np.quantile(draws[n], [0.025, 0.975])
        e = summary["estimate"][n]
        row[n] = {"mcmc": {"mean": float(draws[n].mean()), "sd": float(draws[n].std()), "ci95": [float(lo), float(hi)],
                           "covers": bool(lo <= true <= hi), "rel_error": float(draws[n].mean() / true - 1),
                           "median_rel_error": float(np.median(draws[n]) / true - 1),
                           "pit": float(np.mean(draws[n] < true))},
                  "ensemble": {"mean": e["mean"], "sd": e["sd"], "hdi95": e["hdi95"],
                               "covers": bool(e["hdi95"][0] <= true <= e["hdi95"][1]),
                               "rel_error": e["mean"] / true - 1},
                  "sd_ratio_ensemble_to_mcmc": e["sd"] / float(draws[n].std())}
    return row


def score_nuisances(truth: dict, summary: dict, post) -> list:
    """Each experiment's MCMC posterior of Rmax, Req (relative errors) and the time of the maximum
    (error in t*) against its truth (``truth.json``).

    ``z``: (posterior mean - truth) / posterior sd; ``z_at_truth``: the same for the posterior
    *conditional* on the true (G, mu), from the linear regression of the nuisance on (log G, log mu)
    over the draws -- a nuisance that is off only because it trades with a missed material along a
    ridge is off in ``z`` and not in ``z_at_truth``."""
    lg, lm = (np.log(np.asarray(post[n]).ravel()) for n in ("G", "mu"))
    X = np.column_stack([np.ones_like(lg), lg - lg.mean(), lm - lm.mean()])
    x_true = np.array([1.0, math.log(TRUTH["G"]) - lg.mean(), math.log(TRUTH["mu"]) - lm.mean()])
    out = []
    per_experiment = {pe["name"]: pe for pe in summary["per_experiment"]}     # a record left out has none
    phys = truth.get("physics", {})
    sqrt_rho_p8 = math.sqrt(phys.get("rho", 1064.0) / phys.get("p8", 101325.0))
    for e in truth["experiments"]:
        name = Path(e["file"]).stem
        if name not in per_experiment:
            continue
        nu = per_experiment[name]["nuisance"]
        tc = nu["rmax_m"]["prior_mean"] * sqrt_rho_p8           # the preprocessing's t_c, the offset's unit
        row = {"experiment": name}
        # (draw of the sampled coordinate -> SI value, truth, error): Req and Rmax relative, t0 in t* (t_c)
        quantities = {"req": (f"log_req_{name}", lambda v: nu["req_m"]["prior_mean"] * np.exp(v), e["req_m"]),
                      "rmax": (f"rmax_rel_{name}", lambda v: nu["rmax_m"]["prior_mean"] * (1 + v), e["rmax_m"])}
        if "t0_s" in nu and e.get("t_max_s") is not None:
            quantities["t0"] = (f"t0_offset_{name}", lambda v: nu["t0_s"]["prior_mean"] + tc * v, e["t_max_s"])
        for key, (var, to_si, true) in quantities.items():
            if var not in post:
                continue
            error = (lambda x: (x - true) / tc) if key == "t0" else (lambda x: x / true - 1.0)
            y = error(to_si(np.asarray(post[var]).ravel()))
            prior = error(to_si(0.0))                   # the preprocessing's estimate: every coordinate at 0
            b, *_ = np.linalg.lstsq(X, y, rcond=None)
            resid_sd = float(np.std(y - X @ b))
            lo, hi = np.quantile(y, [0.025, 0.975])
            row[key] = {"prior_rel_error": float(prior), "rel_error": float(y.mean()), "sd": float(y.std()),
                        "covers": bool(lo <= 0.0 <= hi), "z": float(y.mean() / y.std()),
                        "z_at_truth": float(x_true @ b / resid_sd) if resid_sd > 0 else float("nan")}
        out.append(row)
    return out


def summarise_nuisances(rows: list) -> dict:
    """Coverage of every bubble's nuisance interval over the seeds, and its z-scores marginal and at the true material."""
    out = {}
    for key in ("req", "rmax", "t0"):
        items = [n[key] for r in rows for n in r.get("nuisance", []) if key in n]
        if not items:
            continue
        k = sum(i["covers"] for i in items)
        z, zt = np.array([i["z"] for i in items]), np.array([i["z_at_truth"] for i in items])
        out[key] = {"n_bubbles": len(items), "covered": k, "coverage": k / len(items), "wilson95": wilson(k, len(items)),
                    "bias": float(np.mean([i["rel_error"] for i in items])),
                    "prior_bias": float(np.mean([i["prior_rel_error"] for i in items])),
                    "z_mean": float(z.mean()), "z_sd": float(z.std(ddof=1)) if z.size > 1 else None,
                    "z_at_truth_mean": float(np.nanmean(zt)),
                    "z_at_truth_sd": float(np.nanstd(zt, ddof=1)) if zt.size > 1 else None}
    return out


def summarise(rows: list) -> dict:
    out = {"n_seeds": len(rows), "truth": TRUTH}
    for n in TRUTH:
        for kind in ("mcmc", "ensemble"):
            k = sum(r[n][kind]["covers"] for r in rows)
            err = np.array([r[n][kind]["rel_error"] for r in rows])
            out[f"{n}_{kind}"] = {"coverage": k / len(rows) if rows else float("nan"), "covered": k,
                                  "wilson95": wilson(k, len(rows)), "bias": float(err.mean()) if rows else None,
                                  "scatter": float(err.std(ddof=1)) if len(rows) > 1 else None}
        pit = np.array([r[n]["mcmc"]["pit"] for r in rows if "pit" in r[n]["mcmc"]])
        if pit.size:
            from scipy.stats import kstest
            # the truth's rank in a calibrated posterior is uniform over the seeds: a bias shows as a
            # mean away from 1/2, too narrow a posterior as PITs piled at 0 and 1
            out[f"{n}_mcmc"]["pit"] = {"values": pit.tolist(), "mean": float(pit.mean()),
                                       "ks_uniform_p": float(kstest(pit, "uniform").pvalue),
                                       "below_0.5": int(np.sum(pit < 0.5))}
        out[f"{n}_sd_ratio_ensemble_to_mcmc"] = float(np.mean([r[n]["sd_ratio_ensemble_to_mcmc"] for r in rows])) \
            if rows else None
    out["nuisance"] = summarise_nuisances(rows)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--first-seed", type=int, default=100)
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--bubble", choices=["polytropic", "thermal"], default="polytropic")
    ap.add_argument("--out", type=Path, required=True, help="folder of the per-seed runs (resumable)")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--collect", action="store_true", help="no runs: score the seeds that finished")
    args = ap.parse_args(argv)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    rows = []
    for s in seeds:
        folder = args.out / f"seed_{s}"
        if not args.collect:
            run_seed(args.out, s, args.bubble)
        row = score_seed(folder)
        if row is not None:
            rows.append(row)
            print(f"seed {s}: " + ", ".join(
                f"{n} MCMC {row[n]['mcmc']['rel_error']:+.3f} ({'in' if row[n]['mcmc']['covers'] else 'OUT'}) "
                f"ensemble {row[n]['ensemble']['rel_error']:+.3f} ({'in' if row[n]['ensemble']['covers'] else 'OUT'})"
                for n in TRUTH), flush=True)
    summ = summarise(rows)
    print(f"{len(rows)} of {len(seeds)} seeds finished")
    for n in TRUTH:
        for kind in ("mcmc", "ensemble"):
            t = summ[f"{n}_{kind}"]
            if rows:
                print(f"{n:>3} {kind:>8}: coverage {t['coverage']:.2f} [{t['wilson95'][0]:.2f}, {t['wilson95'][1]:.2f}], "
                      f"bias {t['bias']:+.3f}" + (f", truth's posterior rank (PIT) mean {t['pit']['mean']:.2f}, "
                                                  f"KS vs uniform p = {t['pit']['ks_uniform_p']:.2g}" if "pit" in t else ""))
    for key, t in summ["nuisance"].items():
        print(f"{key:>4} per bubble: coverage {t['coverage']:.2f} [{t['wilson95'][0]:.2f}, {t['wilson95'][1]:.2f}] "
              f"of {t['n_bubbles']}, bias {t['bias']:+.4f} (preprocessing {t['prior_bias']:+.4f}), z {t['z_mean']:+.2f} "
              f"(sd {t['z_sd']:.2f}), at the true material {t['z_at_truth_mean']:+.2f} (sd {t['z_at_truth_sd']:.2f})")
    if args.json:
        args.json.write_text(json.dumps({"command": " ".join(sys.argv), "bubble": args.bubble, "summary": summ,
                                         "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
