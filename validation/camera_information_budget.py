"""Where G's information in a camera record goes, and whether the fit's likelihood loses it.

On the camera family (6 bubbles, 1 Mfps, random phase, noise 0.02 R*) the exact En4D-Var posterior
of G is ~10 % wide and has a right-hand error tail (``camera_mcmc_calibration.py``). This script
asks, per seed of that script's folder, two questions with the truth in hand:

1. **How much does each bubble's geometry cost?** The Fisher (Laplace) sd of log G at the truth,
   with the nuisances (Rmax, time of the maximum, Req) known, inferred with the preprocessing's
   priors, and each kind known in turn -- for the *ideal* likelihood (the camera frames themselves
   as data, the true noise sd, no tempering) and for the *fit's* (the frames resampled on the dt*
   grid, predicted through the same frame operator, each record's variance and tempering from the
   fit's summary.json). A local measure: it says where the information sits, not how wide the
   posterior is.
2. **Is the tail the data's or the likelihood's?** The profile log-likelihood of log G at the true
   mu, each bubble's three nuisances maximised out (with their prior), for both likelihoods. If the
   ideal likelihood also peaks far from the truth on the seeds where the fit does, the grid
   resampling, the noise level and the tempering are not what moves G: the noise draw is.

    python validation/camera_information_budget.py --folder runs/mcmc-cal --seeds 100-119 \
        --calibration validation/results/camera_mcmc_calibration_20261129.json \
        --json validation/results/camera_information_budget_20261129.json

Every seed is appended to the JSON as it finishes (a rerun skips the seeds already there).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))       # camera_calibration (--simulate)

NUISANCE_KINDS = ("rmax", "t0", "req")          # the likelihood module's (a, delta, rho)


def load_seed(folder: Path):
    """(truth.json, a runner of the generating forward model, one dict per record) of a seed folder:
    ``data/`` and, if there is one, ``fit/summary.json`` (which records the fit kept, and each
    one's noise variance and tempering). Each record holds its preprocessing geometry, the truth in
    the likelihood's nuisance coordinates, their prior sds and the two observation models
    (``"ideal"``, ``"grid"``: times t*, data y, frame operator or None, weight w = 1 / variance)."""
    import pandas as pd

    from imrbayes.data import load_dataset, preprocess_dataset
    from imrbayes.ensemble import Observations
    from imrbayes.ensemble.likelihood import frame_operator, nuisance_prior_sd
    from imrbayes.forward import ForwardModel
    from imrbayes.forward.runner import Runner

    truth = json.loads((folder / "data" / "truth.json").read_text())
    summary_file = folder / "fit" / "summary.json"
    fitted = None                               # no fit: the ideal likelihood only, every record
    if summary_file.is_file():
        fitted = {p["name"]: p["likelihood"] for p in json.loads(summary_file.read_text())["per_experiment"]}
    pre = preprocess_dataset(load_dataset(folder / "data"), skip_failed=True)
    obs = Observations.from_preprocessed(pre)
    runner = Runner(ForwardModel(truth["model"], options=truth["forward"]))
    t_eval = obs.t_star[1:]
    by_file = {e["file"].rsplit(".", 1)[0]: e for e in truth["experiments"]}
    records = []
    for n, ex in enumerate(pre.experiments):
        if fitted is not None and ex.name not in fitted:      # a record the fit left out
            continue
        e = by_file[ex.name]
        frames = pd.read_csv(folder / "data" / e["file"])
        t = (frames["t_s"].to_numpy() - ex.t0_s) / ex.tc_s
        keep = (t >= 0.0) & (t <= t_eval[-1])   # the span the fit sees
        rmax, req = float(obs.rmax_m[n]), float(obs.req_m[n])
        records.append({
            "name": ex.name, "rmax": rmax, "req": req,
            # the truth in the likelihood's nuisance coordinates
            "nu_true": np.array([e["rmax_m"] / rmax - 1.0, (e["t_max_s"] - ex.t0_s) / ex.tc_s, math.log(e["req_m"] / req)]),
            "prior_sd": nuisance_prior_sd(obs, n),
            "grid": None if fitted is None else {
                "t": t_eval, "y": np.asarray(obs.R_star[n][1:]), "frames": frame_operator(obs.frame_t[n], t_eval),
                "w": fitted[ex.name]["alpha"] / fitted[ex.name]["var"]},
            # the generator's noise sd is in R* of the true Rmax; the data here are scaled by the estimate
            "ideal": {"t": t[keep], "y": frames["R_m"].to_numpy()[keep] / rmax, "frames": None,
                      "w": 1.0 / (truth["noise"]["sd"] * e["rmax_m"] / rmax) ** 2},
        })
    return truth, runner, records


def _predict(runner, rec, kind, theta, nu):
    from imrbayes.ensemble.likelihood import predict
    d = rec[kind]
    return predict(runner, theta, rec["rmax"], rec["req"], d["t"], nu, d["frames"])


def fisher_sd(runner, records, theta_true, kind: str, h: float = 1e-3) -> dict:
    """Laplace sd of (log G, log mu) at the truth: nuisances known, inferred, each kind known."""
    n_rec = len(records)
    n_par = 2 + 3 * n_rec
    info = np.zeros((n_par, n_par))
    prior_prec = np.zeros(n_par)
    steps = np.zeros((11, 5))
    for k in range(5):
        steps[1 + 2 * k, k], steps[2 + 2 * k, k] = h, -h
    for i, rec in enumerate(records):
        theta = theta_true[None] * np.exp(steps[:, :2])
        R, failed = _predict(runner, rec, kind, theta, rec["nu_true"][None] + steps[:, 2:])
        if failed.any():
            raise RuntimeError(f"{rec['name']}: a forward solve failed at the truth")
        J = np.stack([(R[1 + 2 * k] - R[2 + 2 * k]) / (2 * h) for k in range(5)], axis=1)
        idx = [0, 1] + [2 + 3 * i + j for j in range(3)]
        info[np.ix_(idx, idx)] += rec[kind]["w"] * J.T @ J
        prior_prec[2 + 3 * i:5 + 3 * i] = 1.0 / rec["prior_sd"] ** 2

    def sd(known=()):
        prec = prior_prec.copy()
        for j in known:
            prec[2 + j::3] = 1e12
        return np.sqrt(np.diag(np.linalg.inv(info + np.diag(prec)))[:2])

    out = {"known": np.sqrt(np.diag(np.linalg.inv(info[:2, :2]))).tolist(), "inferred": sd().tolist()}
    for j, name in enumerate(NUISANCE_KINDS):
        out[f"{name}_known"] = sd((j,)).tolist()
    return out


def _starts(runner, rec, kind, theta, last, n_best: int = 3, half_width_sd: float = 3.0, n_scan: int = 121) -> list:
    """Starting nuisances for one record's optimisation: the previous G's optimum and the ``n_best``
    deepest local minima of the cost along a scan of the time of the maximum over +-``half_width_sd``
    prior sd (Rmax and Req at the previous optimum). The alignment's basins lie a fraction of a
    frame apart, so one local start lands in whichever basin is nearest."""
    d, ps = rec[kind], rec["prior_sd"]
    base = np.zeros(3) if last is None else np.asarray(last, dtype=np.float64)
    delta = np.linspace(-half_width_sd, half_width_sd, n_scan) * ps[1]
    nu = np.repeat(base[None], n_scan, axis=0)
    nu[:, 1] = delta
    R, failed = _predict(runner, rec, kind, np.repeat(theta, n_scan, axis=0), nu)
    cost = 0.5 * d["w"] * np.sum((d["y"][None] - R) ** 2, axis=1) + 0.5 * np.sum((nu / ps) ** 2, axis=1)
    cost = np.where(failed | ~np.isfinite(cost), np.inf, cost)
    interior = np.r_[False, (cost[1:-1] <= cost[:-2]) & (cost[1:-1] <= cost[2:]), False]
    order = [k for k in np.argsort(cost) if interior[k] and np.isfinite(cost[k])][:n_best]
    return [nu[k] for k in order] + ([base] if last is not None else [np.zeros(3)])


def information_by_frame(runner, records, theta_true, h: float = 1e-3, top: int = 3) -> list:
    """Where G's information sits with the geometry known (ideal likelihood): per record, the share
    of sum_k w (dR_k/d log G)^2 carried by its ``top`` frames, their t* and R*."""
    out = []
    for rec in records:
        d = rec["ideal"]
        theta = theta_true[None] * np.exp(np.array([[h, 0.0], [-h, 0.0], [0.0, 0.0]]))
        R, _ = _predict(runner, rec, "ideal", theta, np.repeat(rec["nu_true"][None], 3, axis=0))
        info = d["w"] * ((R[0] - R[1]) / (2 * h)) ** 2
        k = np.argsort(info)[::-1][:top]
        out.append({"record": rec["name"], "share": float(info[k].sum() / info.sum()),
                    "t_star": d["t"][k].round(3).tolist(), "R_star": R[2][k].round(3).tolist()})
    return out


def profile(runner, records, theta_true, kind: str, log_g) -> np.ndarray:
    """(len(log_g), n_records) log-likelihood + nuisance log-prior, maximised over each record's
    nuisances, at G = G_true e^log_g and the true mu. The alignment has basins: a sweep up in G starts
    each point from the previous optimum and from the deepest minima of a scan of the time of the
    maximum; a sweep back down restarts each point from its upper neighbour's optimum and keeps the
    better (a basin found at one G is then never lost at the next)."""
    from scipy.optimize import least_squares

    out = np.zeros((len(log_g), len(records)))
    for i, rec in enumerate(records):
        d, ps = rec[kind], rec["prior_sd"]

        def fit(theta, starts):
            def resid(nu):
                R, failed = _predict(runner, rec, kind, theta, nu[None])
                if failed.any():
                    return np.full(d["t"].size + 3, 1e3)
                return np.concatenate([math.sqrt(d["w"]) * (d["y"] - R[0]), nu / ps])
            return min((least_squares(resid, x0, x_scale=ps, diff_step=1e-4) for x0 in starts), key=lambda r: r.cost)

        thetas = [np.array([[theta_true[0] * math.exp(g), theta_true[1]]]) for g in log_g]
        cost, best = np.zeros(len(log_g)), [None] * len(log_g)
        for j, theta in enumerate(thetas):
            r = fit(theta, _starts(runner, rec, kind, theta, best[j - 1] if j else None))
            cost[j], best[j] = r.cost, r.x
        for j in range(len(log_g) - 2, -1, -1):
            r = fit(thetas[j], [best[j + 1]])
            if r.cost < cost[j]:
                cost[j], best[j] = r.cost, r.x
        out[:, i] = -cost
    return out


def peak(log_g, total) -> float:
    """The profile's maximum, refined by a parabola through the best point and its neighbours."""
    k = int(np.argmax(total))
    if 0 < k < len(log_g) - 1:
        x, y = log_g[k - 1:k + 2], total[k - 1:k + 2]
        a, b, _ = np.polyfit(x, y, 2)
        if a < 0:
            return float(np.clip(-b / (2 * a), x[0], x[-1]))
    return float(log_g[k])


def profile_sd(log_g, prof, within: float = 4.0) -> float:
    """The width of a profile as a Gaussian would have it: 1/sqrt(-2a) of the parabola a x^2 + ...
    fitted to the points within ``within`` log-units of its maximum (the posterior sd of log G the
    data imply beyond the truth's neighbourhood, where the Fisher information is local)."""
    x, y = np.asarray(log_g, dtype=np.float64), np.asarray(prof, dtype=np.float64)
    near = y >= y.max() - within
    if near.sum() < 3:
        return float("nan")
    a = np.polyfit(x[near], y[near], 2)[0]
    return float((-2.0 * a) ** -0.5) if a < 0 else float("inf")


def run_seed(folder: Path, log_g) -> dict:
    truth, runner, records = load_seed(folder)
    theta_true = np.array([truth["parameters"]["G"], truth["parameters"]["mu"]])
    row = {"seed": truth["seed"], "records": [r["name"] for r in records]}
    for kind in ("ideal", "grid"):
        if records[0][kind] is None:
            continue
        prof = profile(runner, records, theta_true, kind, log_g).sum(axis=1)
        row[kind] = {"fisher_sd_log": fisher_sd(runner, records, theta_true, kind),
                     "profile": (prof - prof.max()).tolist(),
                     "profile_peak_log_g": peak(log_g, prof),
                     "profile_drop_at_truth": float(prof.max() - np.interp(0.0, log_g, prof))}
    return row


def parse_seeds(text: str) -> list:
    a, _, b = text.partition("-")
    return list(range(int(a), int(b) + 1)) if b else [int(x) for x in text.split(",")]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--folder", type=Path, required=True, help="camera_mcmc_calibration.py's --out (seed_S/data, seed_S/fit)")
    ap.add_argument("--seeds", required=True, help="e.g. 100-119 or 103,111")
    ap.add_argument("--calibration", type=Path, help="camera_mcmc_calibration.py's JSON (the MCMC's G, for the table)")
    ap.add_argument("--json", type=Path, required=True)
    ap.add_argument("--simulate", action="store_true",
                    help="write a seed's camera data set (camera_calibration.py's family) where the folder has none; "
                         "without a fit only the ideal likelihood is scored")
    ap.add_argument("--bubble", default="polytropic", help="bubble model of --simulate's data")
    ap.add_argument("--frames-report", action="store_true",
                    help="print where G's information sits in each record of --seeds (nothing is written)")
    a = ap.parse_args(argv)
    if a.frames_report:
        for seed in parse_seeds(a.seeds):
            truth, runner, records = load_seed(a.folder / f"seed_{seed}")
            theta = np.array([truth["parameters"]["G"], truth["parameters"]["mu"]])
            for r in information_by_frame(runner, records, theta):
                print(f"seed {seed} {r['record']}: top frames hold {r['share']:.0%} of G's information "
                      f"(geometry known); t* {r['t_star']}, R* {r['R_star']}")
        return
    log_g = np.linspace(-0.3, 0.6, 13)
    res = json.loads(a.json.read_text()) if a.json.is_file() else {
        "command": "python validation/camera_information_budget.py " + " ".join(sys.argv[1:] if argv is None else argv),
        "log_g": log_g.tolist(), "rows": []}
    log_g = np.asarray(res["log_g"], dtype=np.float64)
    done = {r["seed"] for r in res["rows"]}
    mcmc = {}
    if a.calibration:
        mcmc = {r["seed"]: r["G"]["mcmc"] for r in json.loads(a.calibration.read_text())["rows"]}
    for seed in parse_seeds(a.seeds):
        if seed not in done:
            if a.simulate and not (a.folder / f"seed_{seed}" / "data" / "truth.json").is_file():
                from camera_calibration import simulate
                simulate(a.folder / f"seed_{seed}" / "data", seed, "camera", a.bubble)
            res["rows"].append(run_seed(a.folder / f"seed_{seed}", log_g))
            a.json.write_text(json.dumps(res, indent=1))
    print("seed | Fisher sd log G: ideal known / inferred / t0 known | grid inferred | profile's sd: ideal, grid "
          "| profile peak log G: ideal, grid "
          "| 2 x profile drop at the truth: ideal, grid | MCMC: G error, sd")
    rows = sorted(res["rows"], key=lambda r: r["seed"])
    for r in rows:
        fi = r["ideal"]["fisher_sd_log"]
        g = r.get("grid")
        m = mcmc.get(r["seed"])
        tail = f"{m['rel_error']:+.3f}, {m['sd'] / m['mean']:.3f}" if m else "-"
        print(f"{r['seed']} | {fi['known'][0]:.3f} / {fi['inferred'][0]:.3f} / {fi['t0_known'][0]:.3f} | "
              f"{g['fisher_sd_log']['inferred'][0] if g else float('nan'):.3f} | "
              f"{profile_sd(log_g, r['ideal']['profile']):.3f}, {profile_sd(log_g, g['profile']) if g else float('nan'):.3f} | "
              f"{r['ideal']['profile_peak_log_g']:+.3f}, {g['profile_peak_log_g'] if g else float('nan'):+.3f} | "
              f"{2 * r['ideal']['profile_drop_at_truth']:.2f}, {2 * g['profile_drop_at_truth'] if g else float('nan'):.2f} | {tail}")
    for kind in ("ideal", "grid"):
        have = [r[kind] for r in rows if r.get(kind)]
        if len(have) < 3:
            continue
        pk = np.array([h["profile_peak_log_g"] for h in have])
        lr = np.array([2 * h["profile_drop_at_truth"] for h in have])
        k = int(np.sum(lr > 3.841))
        wid = np.array([profile_sd(log_g, h["profile"]) for h in have])
        fis = np.array([h["fisher_sd_log"]["inferred"][0] for h in have])
        print(f"{kind}: {len(have)} seeds; profile peak log G mean {pk.mean():+.3f} (SE {pk.std(ddof=1) / np.sqrt(pk.size):.3f}, "
              f"sd {pk.std(ddof=1):.3f}, skewness {float(np.mean(((pk - pk.mean()) / pk.std()) ** 3)):+.2f}); "
              f"the truth outside the 95 % profile interval (2 x drop > 3.84) in {k}; profile's sd median "
              f"{np.median(wid):.3f} [{wid.min():.3f}, {wid.max():.3f}]; Fisher sd at the truth median {np.median(fis):.3f} "
              f"[{fis.min():.3f}, {fis.max():.3f}]")
    both = [r for r in rows if r.get("grid")]
    if len(both) > 2:
        pi = np.array([r["ideal"]["profile_peak_log_g"] for r in both])
        pg = np.array([r["grid"]["profile_peak_log_g"] for r in both])
        print(f"ideal and grid peaks on the same {len(both)} seeds: correlation {np.corrcoef(pi, pg)[0, 1]:.2f}, "
              f"mean difference {np.mean(pg - pi):+.3f}")
    scored = [r for r in both if r["seed"] in mcmc]
    if len(scored) > 2:
        pg = np.array([r["grid"]["profile_peak_log_g"] for r in scored])
        lm = np.log1p([mcmc[r["seed"]]["rel_error"] for r in scored])
        print(f"the MCMC posterior mean's log G error against the grid profile's peak on {len(scored)} seeds: "
              f"correlation {np.corrcoef(pg, lm)[0, 1]:.2f}, mean difference {np.mean(lm - pg):+.3f} "
              f"(SE {np.std(lm - pg, ddof=1) / np.sqrt(len(scored)):.3f}; the prior, mu integrated out, the skew)")

if __name__ == "__main__":
    main()
