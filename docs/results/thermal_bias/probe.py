"""Where does the thermal camera design's mu (and G) bias come from? (issue #19, docs/results.md)

For each seed, the camera family's data exactly as validation/camera_calibration.py draws them
(thermal bubble, rtol 1e-9), then En4D-Var with the default settings under variants that hand the
fit one piece of the truth at a time:

  default     nothing of the truth (the calibration's row)
  req         each experiment's true Req in place of the preprocessing's estimate (same stated sd)
  req_fixed   true Req, its sd ~0 (Req not a free nuisance)
  quiet       the same design with 10x less noise (0.002 R*): a deterministic bias survives it

Usage: python docs/results/thermal_bias/probe.py SEED [SEED ...] [--variants a,b] [--json OUT]
"""

from __future__ import annotations

import argparse
import math
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "validation"))
import camera_calibration as cc  # noqa: E402

from imrbayes.data import load_dataset, preprocess_dataset  # noqa: E402
from imrbayes.diagnosis.lsq import ObsModel, fit_map, predict  # noqa: E402
from imrbayes.diagnosis.phases import phases_of  # noqa: E402
from imrbayes.ensemble import En4DVarSettings, Observations, ParamSpace, fit_en4dvar  # noqa: E402
from imrbayes.forward import ForwardModel  # noqa: E402


def simulate(folder: Path, seed: int, noise: float) -> dict:
    import subprocess
    cmd = [sys.executable, "-m", "imrbayes.cli", "simulate", "--model", "nhkv",
           "--param", f"G={cc.TRUTH['G']}", "--param", f"mu={cc.TRUTH['mu']}", "--rmax", "320e-6:45e-6",
           "--ratio", "7.9:0.45", "--n-exp", "6", "--noise", str(noise) if noise > 0 else "none", "--frame-s", "1e-6", "--phase", "random",
           "--pre-max-s", "5e-6", "--no-req-in-meta", "--t-end", "3.6", "--seed", str(seed), "--out", str(folder),
           "--forward", "bubble=thermal", "--forward", "rtol=1e-9", "--forward", "atol=1e-11"]
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    return json.loads((folder / "truth.json").read_text())


def records(seed: int, noise: float, with_pre: bool = False):
    """The calibration's six records for ``seed`` at ``noise`` [R*], preprocessed as ``fit`` does:
    (Observations, truth.json, the raw Dataset, K = the last sample at t* <= 3), and the
    Preprocessed last if ``with_pre``."""
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "data"
        truth = simulate(folder, seed, noise)
        ds = load_dataset(folder)
        pre = preprocess_dataset(ds, skip_failed=True)
    obs = Observations.from_preprocessed(pre)
    out = (obs, truth, ds, int(np.searchsorted(obs.t_star, 3.0 + 1e-9)) - 1)
    return out + (pre,) if with_pre else out


def thermal_candidate(prior=None):
    """The baseline (NHKV) on the default thermal forward model; ``prior``: (G, mu) overrides."""
    from imrbayes.diagnosis.models import make_candidate
    from imrbayes.forward import ForwardOptions

    return make_candidate("nhkv", ForwardOptions(bubble="thermal"), prior=dict(prior) if prior else None)


def run(seed: int, variant: str) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "data"
        truth = simulate(folder, seed, 0.002 if variant == "quiet" else 0.02)
        pre = preprocess_dataset(load_dataset(folder), skip_failed=True)
    obs = Observations.from_preprocessed(pre)
    true_req = np.array([e["req_m"] for e in truth["experiments"]])
    req_err = obs.req_m / true_req - 1
    if variant in ("req", "req_fixed"):
        obs.req_m = true_req.copy()
    if variant == "req_fixed":
        obs.nuisance_sd[:, 2] = 0.0
    fm = ForwardModel("nhkv", options={"bubble": "thermal"})
    space = ParamSpace.for_model(fm.constitutive)
    t0 = time.perf_counter()
    res = fit_en4dvar(fm, obs, space, En4DVarSettings(n_draws=1, loglik=False), seed=seed)
    row = {"seed": seed, "variant": variant, "runtime_s": time.perf_counter() - t0,
           "req_preprocessing_rel_error": req_err.tolist()}
    for n, true in cc.TRUTH.items():
        e = res.estimate[n]
        row[n] = {"rel_error": e["mean"] / true - 1, "rel_sd": e["sd"] / true,
                  "covers": bool(e["hdi95"][0] <= true <= e["hdi95"][1])}
    nu = res.per_experiment or []
    row["req_fitted_rel_error"] = [p["nuisance"]["req_m"]["mean"] / r - 1
                                   for p, r in zip(nu, true_req) if "nuisance" in p]
    return row


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("seeds", type=int, nargs="+")
    ap.add_argument("--variants", default="default,req,req_fixed,quiet")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    rows = json.loads(a.json.read_text()) if a.json and a.json.exists() else []
    done = {(r["seed"], r["variant"]) for r in rows}
    for seed in a.seeds:
        for v in a.variants.split(","):
            if (seed, v) in done:
                continue
            r = run(seed, v)
            rows.append(r)
            print(f"seed {seed} {v:10s} G {r['G']['rel_error']:+.3f} ({r['G']['rel_sd']:.3f}) "
                  f"mu {r['mu']['rel_error']:+.3f} ({r['mu']['rel_sd']:.3f})  Req pre "
                  f"{np.mean(r['req_preprocessing_rel_error']):+.3f} fit "
                  f"{np.mean(r['req_fitted_rel_error']) if r['req_fitted_rel_error'] else float('nan'):+.3f}"
                  f"  {r['runtime_s']:.0f} s", flush=True)
            if a.json:
                a.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()


def map_fit(seed: int, noise: float = 0.02, random_effects=None) -> dict:
    """The deterministic MAP (diagnose's Levenberg–Marquardt, same nuisances, no tempering, no
    random effects by default) on the same data: is the bias the likelihood's or the ensemble's?"""
    obs, truth, ds, K = records(seed, noise)
    cand = thermal_candidate()
    om = ObsModel.of(obs, random_effects=random_effects)
    t0 = time.perf_counter()
    f = fit_map(cand, obs, K=K, minima=phases_of(obs).minima, om=om)
    true_req = np.array([e["req_m"] for e in truth["experiments"]])
    row = {"seed": seed, "variant": f"map_noise{noise}", "runtime_s": time.perf_counter() - t0,
           "z": f.z.tolist(), "cov": f.cov.tolist(), "converged": bool(f.converged),
           "req_fitted_rel_error": (obs.req_m * np.exp(f.nu[:, 2]) / true_req - 1).tolist()}
    G, mu = float(np.exp(f.z[0])), float(np.exp(f.z[1]))
    row["G"] = {"rel_error": G / cc.TRUTH["G"] - 1, "rel_sd": float(np.sqrt(f.cov[0, 0]))}
    row["mu"] = {"rel_error": mu / cc.TRUTH["mu"] - 1, "rel_sd": float(np.sqrt(f.cov[1, 1]))}
    return row


def profile_grid(seed: int, noise: float = 0.02, g_rel=(0.8, 1.5, 11), mu_rel=(0.85, 1.25, 9)) -> dict:
    """The (G, mu) posterior on a grid, nuisances profiled out (refitted at every point), the
    paper prior added: its mean and 95 % region against the MAP's Laplace interval."""
    obs, truth, ds, K = records(seed, noise)
    cand = thermal_candidate()
    om = ObsModel.of(obs, random_effects=None)
    minima = phases_of(obs).minima
    gs = np.log(cc.TRUTH["G"] * np.linspace(*g_rel))
    ms = np.log(cc.TRUTH["mu"] * np.linspace(*mu_rel))
    m0, s0 = cand.prior_mean, cand.prior_sd
    logp = np.zeros((gs.size, ms.size))
    nu = None
    for i, lg in enumerate(gs):
        for j, lm in enumerate(ms):
            z = np.array([lg, lm])
            f = fit_map(cand, obs, K=K, minima=minima, om=om, starts=[z], fix_material=True, nu0=nu)
            logp[i, j] = -f.cost - 0.5 * float(np.sum(((z - m0) / s0) ** 2))
    p = np.exp(logp - logp.max())
    p /= p.sum()
    G, M = np.meshgrid(np.exp(gs), np.exp(ms), indexing="ij")
    mean = {"G": float((p * G).sum()), "mu": float((p * M).sum())}
    # the highest-density region holding 95 %: is the truth's cell inside it?
    order = np.sort(p.ravel())[::-1]
    level = order[np.searchsorted(np.cumsum(order), 0.95)]
    ti, tj = int(np.argmin(np.abs(gs - np.log(cc.TRUTH["G"])))), int(np.argmin(np.abs(ms - np.log(cc.TRUTH["mu"]))))
    return {"seed": seed, "noise": noise, "G_grid": np.exp(gs).tolist(), "mu_grid": np.exp(ms).tolist(),
            "logp": logp.tolist(), "mean": mean, "truth_in_hpd95": bool(p[ti, tj] >= level),
            "mean_rel_error": {k: mean[k] / cc.TRUTH[k] - 1 for k in mean},
            "delta_logp_truth": float(logp.max() - logp[ti, tj])}


def where_it_wins(seed: int, noise: float = 0.02) -> dict:
    """Weighted residual sums of squares at the MAP and at the truth (nuisances refitted, with
    restarts), by phase of the record: where do the data prefer the biased material?"""
    obs, truth, ds, K = records(seed, noise)
    cand = thermal_candidate()
    om = ObsModel.of(obs, random_effects=None)
    ph = phases_of(obs)
    fmap = fit_map(cand, obs, K=K, minima=ph.minima, om=om, restarts=True)
    zt = np.log([cc.TRUTH["G"], cc.TRUTH["mu"]])
    ftru = fit_map(cand, obs, K=K, minima=ph.minima, om=om, starts=[zt], fix_material=True, nu0=fmap.nu,
                   restarts=True)
    y = obs.R_star[:, 1:K + 1]
    w = om.weight[:, None]
    t = obs.t_star[1:K + 1]
    edges = [0.0, 0.8, 1.0, 1.5, 2.0, 3.0 + 1e-9]
    out = {"seed": seed, "map_rel": (np.exp(fmap.z) / np.array([cc.TRUTH["G"], cc.TRUTH["mu"]]) - 1).tolist(),
           "cost_map": fmap.cost, "cost_truth": ftru.cost, "by_phase": []}
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (t >= lo) & (t < hi)
        rm = ((y - fmap.fitted[:, 1:]) * w)[:, sel]
        rt = ((y - ftru.fitted[:, 1:]) * w)[:, sel]
        out["by_phase"].append({"t_star": [lo, hi], "ssr_map": float(np.sum(rm ** 2)),
                                "ssr_truth": float(np.sum(rt ** 2)),
                                "mean_resid_map": float(np.mean(rm / w)), "mean_resid_truth": float(np.mean(rt / w))})
    out["nu_map"] = fmap.nu.tolist()
    out["nu_truth"] = ftru.nu.tolist()
    return out


def frames_vs_grid(seed: int, noise: float = 0.02, prior=None, frames: bool = True) -> list:
    """Each experiment alone, MAP (G, mu and its three nuisances) on (a) the pipeline's grid (frames
    interpolated onto dt* = 0.025, the model put through the same interpolation) and (b) the camera
    frames themselves as point values: does the grid's interpolation bias the material?"""
    from imrbayes.diagnosis.models import make_candidate
    from imrbayes.forward import ForwardOptions

    obs, truth, ds, K = records(seed, noise)
    cand = make_candidate("nhkv", ForwardOptions(bubble="thermal"), prior=prior)
    truth = np.array([cc.TRUTH["G"], cc.TRUTH["mu"]])
    out = []
    for n, ex in enumerate(ds.experiments):
        grid_obs = obs.take([n])
        f_grid = fit_map(cand, grid_obs, K=K, minima=phases_of(grid_obs).minima, om=ObsModel.of(grid_obs))
        if not frames:
            out.append({"seed": seed, "exp": n, "grid": (np.exp(f_grid.z) / truth - 1).tolist(),
                        "grid_sd": np.sqrt(np.diag(f_grid.cov)).tolist()})
            print(seed, n, "grid", np.round(out[-1]["grid"], 3), np.round(out[-1]["grid_sd"], 3), flush=True)
            continue
        tau = (ex.t_s - obs.t0_s[n]) / obs.tc_s[n]
        keep = (tau > 0) & (tau <= obs.t_star[K] + 1e-9)
        t_pts = np.concatenate([[0.0], tau[keep]])
        r_pts = np.concatenate([[1.0], ex.R_m[keep] / obs.rmax_m[n]])
        pts = Observations(t_pts, r_pts[None], obs.P[0], obs.rmax_m[[n]], obs.req_m[[n]], None, [obs.names[n]],
                           obs.noise_sd[[n]], obs.nuisance_sd[[n]], obs.t0_s[[n]], obs.tc_s[[n]], None)
        f_pts = fit_map(cand, pts, minima=phases_of(pts).minima, om=ObsModel.of(pts))
        out.append({"seed": seed, "exp": n, "grid": (np.exp(f_grid.z) / truth - 1).tolist(),
                    "frames": (np.exp(f_pts.z) / truth - 1).tolist(),
                    "grid_sd": np.sqrt(np.diag(f_grid.cov)).tolist(), "frames_sd": np.sqrt(np.diag(f_pts.cov)).tolist()})
        print(seed, n, "grid", np.round(out[-1]["grid"], 3), "frames", np.round(out[-1]["frames"], 3), flush=True)
    return out


def single_lr(seed: int, noise: float = 0.02, prior=(("G", (6000.0, 60000.0)), ("mu", (0.209, 2.09)))) -> list:
    """Each experiment alone, nearly flat material prior: the MAP, its Laplace sd, and the cost at
    the true material (nuisances refitted with restarts from the MAP's): 2 * (cost(truth) -
    cost(MAP)) against chi2(2) says whether the truth is inside the likelihood-ratio region even
    when it is many Laplace sds from the MAP (a likelihood far from quadratic)."""
    obs, truth, ds, K = records(seed, noise)
    cand = thermal_candidate(prior)
    truth = np.array([cc.TRUTH["G"], cc.TRUTH["mu"]])
    zt = np.log(truth)
    out = []
    for n in range(obs.n_exp):
        o = obs.take([n])
        om, mi = ObsModel.of(o), phases_of(o).minima
        fm = fit_map(cand, o, K=K, minima=mi, om=om, restarts=True)
        ft = fit_map(cand, o, K=K, minima=mi, om=om, starts=[zt], fix_material=True, nu0=fm.nu, restarts=True)
        prior_t = 0.5 * float(np.sum(((zt - cand.prior_mean[:2]) / cand.prior_sd[:2]) ** 2))
        sd = np.sqrt(np.diag(fm.cov))
        row = {"seed": seed, "exp": n, "map_rel": (np.exp(fm.z) / truth - 1).tolist(), "laplace_sd_log": sd.tolist(),
               "z_truth": ((fm.z - zt) / sd).tolist(), "lr_chi2": 2.0 * (ft.cost + prior_t - fm.cost)}
        out.append(row)
        print(seed, n, "MAP", np.round(row["map_rel"], 3), "Laplace sd", np.round(sd, 3), "truth at",
              np.round(row["z_truth"], 1), "Laplace sd; 2 dcost", round(row["lr_chi2"], 2), flush=True)
    return out


def single_is(seed: int, noise: float = 0.02, n_draws: int = 1000, rounds: int = 4, df: float = 5.0,
              prior=(("G", (6000.0, 60000.0)), ("mu", (0.209, 2.09))), save: Path | None = None) -> list:
    """Each experiment alone: the posterior of x = (log G, log mu, Rmax, t0, Req nuisances in prior-sd
    units) by adaptive importance sampling (population Monte Carlo): a multivariate t (``df``)
    proposal, first at the MAP with its Laplace sds (material block with its correlation), then
    refitted ``rounds`` times to the weighted draws (all rounds' draws pooled at the end, each with
    its own proposal density). Posterior mean and 95 % equal-tailed intervals of G and mu against the
    Laplace ones: does the non-Gaussian posterior cover the truth where the Gaussian does not?
    ``save``: an .npz with every experiment's weighted (log G, log mu) draws and the material prior,
    for :func:`fused_is`."""
    obs, truth, ds, K = records(seed, noise)
    cand = thermal_candidate(prior)
    truth = np.array([cc.TRUTH["G"], cc.TRUTH["mu"]])
    rng = np.random.default_rng(seed)
    out, kept = [], {}
    for n in range(obs.n_exp):
        o = obs.take([n])
        om, mi = ObsModel.of(o), phases_of(o).minima
        f = fit_map(cand, o, K=K, minima=mi, om=om, restarts=True)
        s_nu = om.nu_sd[0, :3]
        act = s_nu > 0

        def log_post(x):
            nu = np.zeros((x.shape[0], 1, om.nu_sd.shape[1]))
            nu[:, 0, :3] = x[:, 2:] * s_nu
            R = predict(cand, x[:, :2], o, np.array([0]), mi, K, nu=nu, frames=om.frames)[:, 0, 1:]
            r = (o.R_star[0, 1:K + 1][None] - R) * om.weight[0]
            lp = (-0.5 * np.sum(r ** 2, axis=1)
                  - 0.5 * np.sum(((x[:, :2] - cand.prior_mean[:2]) / cand.prior_sd[:2]) ** 2, axis=1)
                  - 0.5 * np.sum(x[:, 2:][:, act] ** 2, axis=1))
            return np.where(np.isfinite(lp), lp, -np.inf)

        def t_logpdf(x, m, L):
            dev = np.linalg.solve(L, (x - m).T).T
            return -0.5 * (df + 5) * np.log1p(np.sum(dev ** 2, axis=1) / df) - np.sum(np.log(np.diag(L)))

        mean = np.concatenate([f.z, np.where(act, f.nu[0, :3] / np.where(act, s_nu, 1), 0.0)])
        cov = np.zeros((5, 5))
        cov[:2, :2] = f.cov
        cov[2:, 2:] = np.diag(np.where(act, (f.nu_sd[0, :3] / np.where(act, s_nu, 1)) ** 2, 1e-12))
        props, xs, lps = [], [], []
        for _ in range(rounds):
            L = np.linalg.cholesky(cov + 1e-12 * np.eye(5))
            x = mean + (rng.standard_normal((n_draws, 5)) @ L.T) / np.sqrt(rng.chisquare(df, n_draws) / df)[:, None]
            props.append((mean.copy(), L))
            xs.append(x)
            lps.append(log_post(x))
            X, LP = np.vstack(xs), np.concatenate(lps)
            # deterministic mixture weights over every proposal so far
            lq = np.logaddexp.reduce(np.stack([t_logpdf(X, m, Lm) for m, Lm in props]), axis=0) - np.log(len(props))
            lw = LP - lq
            w = np.exp(lw - np.max(lw))
            w /= w.sum()
            mean = w @ X
            cov = np.cov(X.T, aweights=w) + 1e-10 * np.eye(5)
        ess = float(1.0 / np.sum(w ** 2))
        row = {"seed": seed, "exp": n, "ess": ess, "n_draws": int(X.shape[0]), "laplace": {}, "is": {}}
        for j, name in enumerate(("G", "mu")):
            zt = math.log(truth[j])
            sd = math.sqrt(f.cov[j, j])
            row["laplace"][name] = {"rel_error": math.exp(f.z[j]) / truth[j] - 1,
                                    "covers": bool(abs(f.z[j] - zt) <= 1.96 * sd)}
            order = np.argsort(X[:, j])
            cw = np.cumsum(w[order])
            lo = X[order, j][min(np.searchsorted(cw, 0.025), X.shape[0] - 1)]
            hi = X[order, j][min(np.searchsorted(cw, 0.975), X.shape[0] - 1)]
            pm = float(np.sum(w * np.exp(X[:, j])))
            row["is"][name] = {"rel_error": pm / truth[j] - 1, "covers": bool(lo <= zt <= hi),
                               "ci95_rel": [math.exp(lo) / truth[j] - 1, math.exp(hi) / truth[j] - 1]}
        out.append(row)
        kept[f"x{n}"], kept[f"w{n}"] = X[:, :2], w
        if save is not None:
            np.savez_compressed(save, prior_mean=cand.prior_mean[:2], prior_sd=cand.prior_sd[:2],
                                z_truth=np.log(truth), **kept)
        print(seed, n, f"ESS {ess:.0f}", "Laplace", {k: (round(v["rel_error"], 3), v["covers"]) for k, v in row["laplace"].items()},
              "IS", {k: (round(v["rel_error"], 3), v["covers"]) for k, v in row["is"].items()}, flush=True)
    return out


def fused_is(path: Path, n_grid: int = 241) -> dict:
    """The gel-level (common G, mu) posterior of one seed's six records from :func:`single_is`'s draws,
    without a Gaussian: each record's marginal likelihood of z = (log G, log mu) is its weighted
    kernel density (scipy's gaussian_kde, Scott's bandwidth) over the material prior it was drawn
    under; their product times that prior, on a grid. Beside it, the Gaussian fusion of the same
    draws' moments (what feeding IS moments into likelihood_terms would give). Returns, per
    parameter, the posterior mean's relative error and whether the equal-tailed 95 % interval holds
    the truth, for both."""
    from scipy.stats import gaussian_kde

    d = np.load(path)
    m0, s0, zt = d["prior_mean"], d["prior_sd"], d["z_truth"]
    n_exp = sum(1 for k in d.files if k.startswith("x"))
    X = [d[f"x{n}"] for n in range(n_exp)]
    W = [d[f"w{n}"] for n in range(n_exp)]
    allx = np.vstack(X)
    lo, hi = allx.min(axis=0), allx.max(axis=0)
    axes = [np.linspace(lo[j], hi[j], n_grid) for j in range(2)]
    gz = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 2)
    log_prior = -0.5 * np.sum(((gz - m0) / s0) ** 2, axis=1)
    lp = log_prior.copy()
    prec, eta = np.zeros((2, 2)), np.zeros(2)
    for x, w in zip(X, W):
        keep = w > 1e-12 * w.max()
        kde = gaussian_kde(x[keep].T, weights=w[keep])
        lp += kde.logpdf(gz.T) - log_prior
        mu_n = w @ x
        C = np.cov(x.T, aweights=w)
        # the record's Gaussian likelihood: posterior precision minus the prior's
        P = np.linalg.inv(C) - np.diag(1.0 / s0 ** 2)
        prec += P
        eta += np.linalg.inv(C) @ mu_n - m0 / s0 ** 2
    p = np.exp(lp - lp.max()).reshape(n_grid, n_grid)
    p /= p.sum()
    Cg = np.linalg.inv(prec + np.diag(1.0 / s0 ** 2))
    mg = Cg @ (eta + m0 / s0 ** 2)
    out = {"seed": int(path.stem.split("_")[-1]) if path.stem.split("_")[-1].isdigit() else None}
    for j, name in enumerate(("G", "mu")):
        marg = p.sum(axis=1 - j)
        cdf = np.cumsum(marg)
        a = axes[j]
        l95, h95 = a[np.searchsorted(cdf, 0.025)], a[min(np.searchsorted(cdf, 0.975), n_grid - 1)]
        mean = float(np.sum(marg * np.exp(a)))
        sdg = math.sqrt(Cg[j, j])
        out[name] = {"kde": {"rel_error": mean / math.exp(zt[j]) - 1, "covers": bool(l95 <= zt[j] <= h95),
                             "ci95_rel": [math.exp(l95 - zt[j]) - 1, math.exp(h95 - zt[j]) - 1],
                             "edge_mass": float(marg[0] + marg[-1])},
                     "gaussian": {"rel_error": math.exp(mg[j] - zt[j]) - 1, "covers": bool(abs(mg[j] - zt[j]) <= 1.96 * sdg),
                                  "sd_log": sdg}}
    return out


def map_true_nuisances(seed: int, noise: float = 0.02, hold=("rmax", "t0", "req")) -> dict:
    """The joint MAP (shared G, mu; :func:`map_fit`) with the nuisances named in ``hold`` held at
    each experiment's *true* value (from truth.json) instead of inferred: is the noise-driven bias
    the material's own (it survives with every nuisance known) or the price of estimating the
    geometry per bubble (it goes when they are held at the truth)?"""
    from imrbayes.diagnosis import lsq

    obs, truth, ds, K = records(seed, noise)
    ex = truth["experiments"]
    rmax_t = np.array([e["rmax_m"] for e in ex])
    req_t = np.array([e["req_m"] for e in ex])
    tmax_t = np.array([e["t_max_s"] for e in ex])
    # the nuisance coordinates of lsq._predict at the truth: Rmax scale, t* shift, log Req ratio
    offset = np.stack([rmax_t / obs.rmax_m - 1.0, (tmax_t - obs.t0_s) / obs.tc_s, np.log(req_t / obs.req_m)], axis=1)
    cols = [j for j, name in enumerate(("rmax", "t0", "req")) if name in hold]
    keep = np.zeros_like(offset)
    keep[:, cols] = offset[:, cols]
    om = ObsModel.of(obs, random_effects=None)
    om.nu_sd[:, cols] = 0.0
    plain = lsq.predict

    def shifted(cand, z, o, idx, minima, K_, nu=None, frames=None):
        idx = np.atleast_1d(np.asarray(idx, dtype=int))
        M = np.atleast_2d(z).shape[0]
        base = np.zeros((M, idx.size, 3)) if nu is None else np.broadcast_to(np.asarray(nu, float), (M, idx.size, np.asarray(nu).shape[-1])).copy()
        base[..., :3] += keep[idx][None]
        return plain(cand, z, o, idx, minima, K_, base, frames)

    cand = thermal_candidate()
    t0 = time.perf_counter()
    lsq.predict = shifted
    try:
        f = fit_map(cand, obs, K=K, minima=phases_of(obs).minima, om=om)
    finally:
        lsq.predict = plain
    row = {"seed": seed, "variant": "map_true_" + "_".join(hold) if hold else "map_free", "noise": noise,
           "runtime_s": time.perf_counter() - t0, "z": f.z.tolist(), "converged": bool(f.converged),
           "preprocessing_offset": offset.tolist()}
    for j, name in enumerate(("G", "mu")):
        row[name] = {"rel_error": float(np.exp(f.z[j])) / cc.TRUTH[name] - 1, "rel_sd": float(np.sqrt(f.cov[j, j]))}
    return row


def map_req_prior(seed: int, noise: float = 0.02, widen: float = 3.0) -> dict:
    """The joint MAP (:func:`map_fit`) with each experiment's Req prior sd ``widen`` times the
    preprocessing's: does the data pull Req (and with it G) back when the prior lets it?"""
    obs, truth, ds, K = records(seed, noise)
    req_t = np.array([e["req_m"] for e in truth["experiments"]])
    om = ObsModel.of(obs, random_effects=None)
    om.nu_sd[:, 2] *= widen
    cand = thermal_candidate()
    t0 = time.perf_counter()
    f = fit_map(cand, obs, K=K, minima=phases_of(obs).minima, om=om)
    row = {"seed": seed, "variant": f"map_req_sd_x{widen:g}", "noise": noise, "runtime_s": time.perf_counter() - t0,
           "z": f.z.tolist(), "converged": bool(f.converged), "req_prior_sd_log": om.nu_sd[:, 2].tolist(),
           "req_preprocessing_rel_error": (obs.req_m / req_t - 1).tolist(),
           "req_fitted_rel_error": (obs.req_m * np.exp(f.nu[:, 2]) / req_t - 1).tolist()}
    for j, name in enumerate(("G", "mu")):
        row[name] = {"rel_error": float(np.exp(f.z[j])) / cc.TRUTH[name] - 1, "rel_sd": float(np.sqrt(f.cov[j, j]))}
    return row


def nuisance_logdet(cand, obs, K, minima, om, z, nu) -> np.ndarray:
    """Per experiment, log det of the Gauss–Newton Hessian of the cost in the nuisances (prior-sd
    units, prior rows included) at material ``z`` and nuisances ``nu`` (E, q): what Laplace's
    integral over each bubble's geometry adds to -log p(data | z) beyond the profile cost."""
    from imrbayes.diagnosis.lsq import NU_STEP
    s_nu = om.nu_sd
    E, q = s_nu.shape
    act = [j for j in range(3) if np.any(s_nu[:, j] > 0)]
    u = np.where(s_nu > 0, nu / np.where(s_nu > 0, s_nu, 1.0), 0.0)
    w = om.weight
    def r_of(U):
        R = predict(cand, np.repeat(np.asarray(z)[None], U.shape[0], 0), obs, np.arange(E), minima, K, U * s_nu[None], om.frames)
        return (obs.R_star[None, :, 1:K + 1] - R[..., 1:]) * w[None, :, None]
    base = r_of(u[None])[0]
    Us = []
    for j in act:
        du = np.zeros((E, q))
        du[:, j] = NU_STEP
        Us.append(u + du)
    rp = r_of(np.array(Us))
    out = np.zeros(E)
    for e in range(E):
        J = np.stack([(rp[i, e] - base[e]) / NU_STEP for i in range(len(act))], axis=1)
        H = J.T @ J + np.eye(len(act))
        out[e] = np.linalg.slogdet(H)[1]
    return out


def laplace_points(seed: int, noise: float = 0.02, points=None) -> list:
    """Profile cost (nuisances refitted, from restarts) and its Laplace correction 0.5 sum_e log det
    H_e at the joint MAP and at the truth (or ``points``, relative (G, mu) factors): does
    integrating the geometry out, instead of maximising over it, move the preference?"""
    obs, truth, ds, K = records(seed, noise)
    cand = thermal_candidate()
    om = ObsModel.of(obs, random_effects=None)
    minima = phases_of(obs).minima
    f = fit_map(cand, obs, K=K, minima=minima, om=om, restarts=True)
    zt = np.log([cc.TRUTH["G"], cc.TRUTH["mu"]])
    pts = [("map", f.z)] + [("truth", zt)] + [(f"x{g:g},{m:g}", zt + np.log([g, m])) for g, m in (points or [])]
    rows = []
    for name, z in pts:
        fz = fit_map(cand, obs, K=K, minima=minima, om=om, starts=[z], fix_material=True, nu0=f.nu, restarts=True)
        ld = nuisance_logdet(cand, obs, K, minima, om, z, fz.nu)
        prior = 0.5 * float(np.sum(((z - cand.prior_mean[:2]) / cand.prior_sd[:2]) ** 2))
        rows.append({"seed": seed, "point": name, "rel": (np.exp(z - zt) - 1).tolist(), "profile_cost": fz.cost + prior,
                     "half_logdet": 0.5 * float(ld.sum()), "half_logdet_per_exp": (0.5 * ld).tolist(),
                     "adjusted_cost": fz.cost + prior + 0.5 * float(ld.sum())})
        print(seed, name, np.round(np.exp(z - zt) - 1, 3), f"profile {fz.cost + prior:.2f}  +0.5logdet {0.5 * ld.sum():.2f}  adjusted {rows[-1]['adjusted_cost']:.2f}", flush=True)
    return rows


def noise_draws(seed: int, draws=range(10), noise: float = 0.02, save: Path | None = None) -> list:
    """One design (seed ``seed``'s geometry, phases and truth, simulated without noise), ``draws``
    independent noise realisations of ``noise`` R* added to its frames: the joint MAP (:func:`map_fit`)
    of each. Their mean error is the design's bias, their scatter the estimator's real sd (against the
    Laplace sd each fit states): is a seed's large error its design's or its noise draw's?"""
    import pandas as pd

    rows = json.loads(save.read_text()) if save is not None and save.exists() else []
    done = {r["draw"] for r in rows if r["seed"] == seed and r["noise"] == noise}
    with tempfile.TemporaryDirectory() as tmp:
        clean = Path(tmp) / "clean"
        truth = simulate(clean, seed, 0.0)
        rmax_t = {e["file"] if "file" in e else f"exp_{i + 1:03d}.csv": e["rmax_m"] for i, e in enumerate(truth["experiments"])}
        cand = thermal_candidate()
        for d in draws:
            if d in done:
                continue
            rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(7, int(d))))
            noisy = Path(tmp) / f"noisy{d}"
            noisy.mkdir()
            for f in clean.iterdir():
                if f.suffix == ".csv":
                    df = pd.read_csv(f)
                    R = df["R_m"].to_numpy()
                    sd = noise * rmax_t[f.name]
                    out = R + sd * rng.standard_normal(R.size)
                    while np.any(out <= 0):
                        bad = out <= 0
                        out[bad] = R[bad] + sd * rng.standard_normal(int(bad.sum()))
                    df["R_m"] = out
                    df.to_csv(noisy / f.name, index=False)
                else:
                    (noisy / f.name).write_bytes(f.read_bytes())
            obs = Observations.from_preprocessed(preprocess_dataset(load_dataset(noisy), skip_failed=True))
            K = int(np.searchsorted(obs.t_star, 3.0 + 1e-9)) - 1
            t0 = time.perf_counter()
            fm = fit_map(cand, obs, K=K, minima=phases_of(obs).minima, om=ObsModel.of(obs, random_effects=None), restarts=True)
            row = {"seed": seed, "draw": int(d), "noise": noise, "runtime_s": time.perf_counter() - t0}
            for j, name in enumerate(("G", "mu")):
                row[name] = {"rel_error": float(np.exp(fm.z[j])) / cc.TRUTH[name] - 1, "rel_sd": float(np.sqrt(fm.cov[j, j]))}
            rows.append(row)
            print(seed, d, f"G {row['G']['rel_error']:+.3f} ({row['G']['rel_sd']:.3f}) mu {row['mu']['rel_error']:+.3f} ({row['mu']['rel_sd']:.3f})", flush=True)
            if save is not None:
                save.write_text(json.dumps(rows, indent=1))
    return rows


def model_tail_req(fm, ds, pre, obs, params: dict, rmax_m=None, n_tail: int = 20, iterations: int = 3) -> np.ndarray:
    """Each experiment's Req corrected by the forward model's own tail: the preprocessing's Req is
    the mean of the record's last ``n_tail`` frames, and a thermal bubble's tail still lies above
    its Req there; Req_hat / c with c = (model's mean R over the same frames) / (its Req), iterated
    (c depends on Req a little). ``params`` the material (SI), ``rmax_m`` per experiment (default
    the preprocessing's). Returns (E,) [m]."""
    out = np.empty(obs.n_exp)
    rmax = obs.rmax_m if rmax_m is None else np.asarray(rmax_m, dtype=float)
    for i, (exp, e) in enumerate(zip(ds.experiments, pre.experiments)):
        tail_t = (exp.t_s[exp.t_s.size - n_tail:] - e.t0_s) / e.tc_s
        req = e.req_m
        for _ in range(iterations):
            R = fm.simulate_radius(params, rmax_m=float(rmax[i]), req_m=req, t_star=tail_t)
            req = e.req_m / float(np.mean(R) * rmax[i] / req)
        out[i] = req
    return out


def two_pass_req(seed: int, noise: float = 0.02) -> dict:
    """The joint MAP (:func:`map_fit`), then each Req corrected by the model's tail at that MAP's
    material and Rmax (:func:`model_tail_req`), then the MAP again from the first one's optimum:
    what the model-tail Req buys without knowing the truth."""
    from imrbayes.forward import ForwardModel
    obs, truth, ds, K, pre = records(seed, noise, with_pre=True)
    req_t = np.array([e["req_m"] for e in truth["experiments"]])
    cand = thermal_candidate()
    minima = phases_of(obs).minima
    fm = ForwardModel("nhkv", options={"bubble": "thermal"})
    t0 = time.perf_counter()
    f1 = fit_map(cand, obs, K=K, minima=minima, om=ObsModel.of(obs, random_effects=None), restarts=True)
    G1, mu1 = np.exp(f1.z)
    req2 = model_tail_req(fm, ds, pre, obs, {"G": float(G1), "mu": float(mu1)}, rmax_m=obs.rmax_m * (1 + f1.nu[:, 0]))
    o2 = obs.take(np.arange(obs.n_exp))
    o2.req_m = req2
    nu0 = f1.nu.copy()
    nu0[:, 2] = np.log(obs.req_m / req2) + f1.nu[:, 2]       # the same fitted Req, in the new prior's coordinate
    f2 = fit_map(cand, o2, K=K, minima=minima, om=ObsModel.of(o2, random_effects=None), starts=[f1.z], nu0=nu0, restarts=True)
    row = {"seed": seed, "noise": noise, "runtime_s": time.perf_counter() - t0,
           "req_pre_rel_error": (obs.req_m / req_t - 1).tolist(), "req_model_tail_rel_error": (req2 / req_t - 1).tolist()}
    for tag, f, o in (("pass1", f1, obs), ("pass2", f2, o2)):
        row[tag] = {"req_fit_rel_error": (o.req_m * np.exp(f.nu[:, 2]) / req_t - 1).tolist()}
        for j, name in enumerate(("G", "mu")):
            row[tag][name] = {"rel_error": float(np.exp(f.z[j])) / cc.TRUTH[name] - 1, "rel_sd": float(np.sqrt(f.cov[j, j]))}
    return row
