"""Calibration on camera-style data: the "camera" case family (issue #19, deliverables 1 and 6).

Each seed draws a fresh data set the way real data arrive (``imrbayes simulate``): 6 bubbles,
Rmax 320 +- 45 µm, Rmax/Req 7.9 +- 0.45, a 1 Mfps camera with a random sub-frame phase, records
starting 5 µs before the maximum, Gaussian noise 0.02 R* at every sample (the maximum included),
Req not given. The data are generated with tight solver tolerances (rtol 1e-9) and fitted with the
default ones, so the fitted model is not the generating one bit for bit. Preprocessing is the
default (local fit of the maximum, estimated noise, Req from the tail); nothing of the truth is
passed to the fit.

For each seed and each likelihood (``default``, ``paper``) En4D-Var (``--method mienks``: MIEnKS-MDA,
its aggregate estimate, and also each window's) is fitted and we record
whether the 95 % interval of the gel-level estimate holds the truth (G, mu), the relative error,
and, for the ``scatter`` family (``--scatter G=SD --scatter mu=SD``), whether the between-bubble
sd's 95 % interval holds the true relative sd and the fraction of the bubbles' true parameters
inside the 95 % predictive interval. Coverage is given with a 95 % Wilson interval.

The bubble model is polytropic by default (``--bubble thermal`` for the thermal model: ~10x the
cost). Usage:

    python validation/camera_calibration.py --seeds 20 --family camera --json validation/results/camera.json
    python validation/camera_calibration.py --seeds 20 --family scatter --json validation/results/camera_scatter.json
    python validation/camera_calibration.py --seeds 20 --method mienks --likelihoods default --json validation/results/camera_mienks.json

Data from another code: ``--generator pyimr`` makes every curve with PyIMR (the optional ``peers``
extra; same physics, constants and camera sampling, its own discretisation and integrator), so the
fitted model is not the generating one at all.

Probes of the design (not the camera family itself): ``--req given`` writes the true Req into
meta.json, so the fit takes it as known (Rmax and the time of the maximum are estimated either
way); ``--phase 0`` puts a frame at every maximum.

Seed ranges can run in parallel processes (``--first-seed``, ``--seeds``, one ``--json`` each) and be
united afterwards: ``--merge a.json b.json --json all.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from imrbayes.data import load_dataset, preprocess_dataset
from imrbayes.ensemble import En4DVarSettings, MIEnKSSettings, Observations, ParamSpace, fit_en4dvar, fit_mienks
from imrbayes.forward import ForwardModel
from imrbayes.io import code_version

TRUTH = {"G": 5200.0, "mu": 0.065}
SCATTER = 0.15


def wilson(k: int, n: int, z: float = 1.959964) -> list:
    """95 % Wilson score interval of a binomial proportion k/n."""
    if n == 0:
        return [float("nan"), float("nan")]
    p = k / n
    den = 1 + z * z / n
    c = (p + z * z / (2 * n)) / den
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return [c - h, c + h]


def simulate(folder: Path, seed: int, family: str, bubble: str, design: dict | None = None) -> dict:
    """Write one seed's data set; ``design`` may give ``req="given"`` (the true Req in meta.json, so
    that the fit takes it as known; Rmax and the time of the maximum are estimated either way) and
    ``phase="0"`` (a frame at every maximum)."""
    design = design or {}
    cmd = [sys.executable, "-m", "imrbayes.cli", "simulate", "--model", "nhkv",
           "--param", f"G={TRUTH['G']}", "--param", f"mu={TRUTH['mu']}", "--rmax", "320e-6:45e-6",
           "--ratio", "7.9:0.45", "--n-exp", "6", "--noise", "0.02", "--frame-s", "1e-6",
           "--phase", design.get("phase", "random"), "--pre-max-s", "5e-6",
           "--req-in-meta" if design.get("req") == "given" else "--no-req-in-meta", "--t-end", "3.6", "--seed", str(seed), "--out", str(folder),
           "--forward", f"bubble={bubble}", "--forward", "rtol=1e-9", "--forward", "atol=1e-11"]
    if design.get("generator", "imrbayes") != "imrbayes":      # curves from another code (PyIMR)
        cmd += ["--generator", design["generator"]]
    if family == "scatter":
        cmd += ["--scatter", f"G={SCATTER}", "--scatter", f"mu={SCATTER}"]
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    return json.loads((folder / "truth.json").read_text())


def one_seed(seed: int, family: str, bubble: str, likelihoods, settings=None, method: str = "en4dvar",
             prior: dict | None = None, design: dict | None = None) -> dict:
    fm = ForwardModel("nhkv", options={"bubble": bubble})
    row = {"seed": seed, "code": code_version()}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "data"
        truth = simulate(folder, seed, family, bubble, design)
        pre = preprocess_dataset(load_dataset(folder), skip_failed=True)
    obs = Observations.from_preprocessed(pre)
    space = ParamSpace.for_model(fm.constitutive, prior=prior)
    bubbles = {n: np.array([e["parameters"][n] for e in truth["experiments"]]) for n in TRUTH}
    for lk in likelihoods:
        t0 = time.perf_counter()
        if method == "mienks":
            res = fit_mienks(fm, obs, space, MIEnKSSettings(**{"likelihood": lk, "n_draws": 1, **(settings or {})}),
                             seed=seed)
        else:
            res = fit_en4dvar(fm, obs, space, En4DVarSettings(**{"likelihood": lk, "n_draws": 1, "loglik": False,
                                                                 **(settings or {})}), seed=seed)
        r = {"runtime_s": time.perf_counter() - t0}
        if res.windows and len(res.windows) > 1:     # MIEnKS-MDA: does each window's estimate hold the truth?
            r["windows"] = {n: [bool(w[n]["hdi95"][0] <= true <= w[n]["hdi95"][1]) for w in res.windows]
                            for n, true in TRUTH.items()}
            # the window means themselves: a constant truth must not come back as a trend
            r["window_rel_error"] = {n: [w[n]["mean"] / true - 1 for w in res.windows] for n, true in TRUTH.items()}
            # and their medians: a log-normal window's mean exceeds its median by exp(s^2/2) - 1, which
            # shrinks as the windows sharpen -- a decline of the means that is not in the medians
            r["window_rel_error_median"] = {n: [w[n]["median"] / true - 1 for w in res.windows]
                                            for n, true in TRUTH.items()}
            # the pooled (no between-bubble scatter) window estimate and the mean of the bubbles' own
            # chains: which part of a window's error the combination of the bubbles adds
            r["window_rel_error_pooled"] = {n: [math.exp(w["pooled_mean_internal"][i]) / true - 1 for w in res.windows]
                                            for i, (n, true) in enumerate(TRUTH.items()) if "pooled_mean_internal" in res.windows[0]}
            r["window_rel_error_bubbles"] = {
                n: [float(np.mean([math.exp(e["mean_internal"][i]) for e in w["per_experiment"]])) / true - 1
                    for w in res.windows] for i, (n, true) in enumerate(TRUTH.items())}
            # each window's sd (relative to the truth) and its mean's distance from the aggregate in its own
            # sd: the validation suite's no-spurious-trend criterion (every window within 2 sd of the aggregate)
            r["window_rel_sd"] = {n: [w[n]["sd"] / true for w in res.windows] for n, true in TRUTH.items()}
            r["window_dev_sd"] = {n: [(w[n]["mean"] - res.estimate[n]["mean"]) / w[n]["sd"] for w in res.windows]
                                  for n in TRUTH}
            r["window_prior_dominated"] = [bool(w.get("prior_dominated", False)) for w in res.windows]
            r["window_prior_weight"] = {n: [w["prior_weight"][n] for w in res.windows if "prior_weight" in w]
                                        for n in TRUTH}
        for n, true in TRUTH.items():
            e = res.estimate[n]
            r[n] = {"mean": e["mean"], "sd": e["sd"], "hdi95": e["hdi95"],
                    "covers": bool(e["hdi95"][0] <= true <= e["hdi95"][1]), "rel_error": e["mean"] / true - 1}
            between = res.details.get("between_experiments", {}).get(n)
            if between and between.get("ci95_log") is not None:
                lo, hi = between["ci95_log"]
                true_sd = SCATTER if family == "scatter" else 0.0
                r[n]["between_sd_log"] = between["sd_log"]
                r[n]["between_covers"] = bool(lo <= true_sd + 1e-12 and true_sd <= hi + 1e-12)
            pred = res.details.get("predictive", {}).get(n)
            if pred:
                lo, hi = pred["hdi95"]
                r[n]["predictive_holds"] = float(np.mean((bubbles[n] >= lo) & (bubbles[n] <= hi)))
        rec = (res.details.get("record_random_effects") or {}).get("estimate")
        if rec:          # MIEnKS-MDA: the record-level estimate beside the window aggregate
            r["record"] = _scored(rec)
        alts = res.details.get("alternative_estimates") or {}
        if alts:         # e.g. bubble_posterior=sampled: the ensembles' Gaussians, the sampled fusion
            r["alternatives"] = {name: _scored(est) for name, est in alts.items()}
        for name, pr in (res.details.get("alternative_predictives") or {}).items():
            for n in TRUTH:      # e.g. the chain-propagated aggregate widened by the integrated scatter
                lo, hi = pr[n]["hdi95"]
                r.setdefault("alternatives", {}).setdefault(name, {}).setdefault(n, {})["predictive_holds"] = \
                    float(np.mean((bubbles[n] >= lo) & (bubbles[n] <= hi)))
        r["effective_samples"] = res.details.get("likelihood", {}).get("effective_samples")
        if res.method == "mienks":      # bubbles whose pilot residual stood out (a warning in fit)
            r["pilot_outliers"] = [e["name"] for e in res.per_experiment if (e.get("likelihood") or {}).get("pilot_outlier")]
        row[lk] = r
    return row


def _scored(est: dict) -> dict:
    """An estimate (name -> {mean, sd, hdi95}) against the truth."""
    return {n: {"mean": est[n]["mean"], "sd": est[n]["sd"], "hdi95": est[n]["hdi95"],
                "covers": bool(est[n]["hdi95"][0] <= true <= est[n]["hdi95"][1]),
                "rel_error": est[n]["mean"] / true - 1} for n, true in TRUTH.items()}


def _coverage_table(rec: list) -> dict:
    out = {}
    for n in TRUTH:
        k = sum(x[n]["covers"] for x in rec)
        err = np.array([x[n]["rel_error"] for x in rec])
        out[n] = {"coverage": k / len(rec), "coverage_wilson95": wilson(k, len(rec)), "n_seeds": len(rec),
                  "mean_rel_error": float(err.mean()), "sd_rel_error": float(err.std(ddof=1)) if len(rec) > 1 else None,
                  "mean_rel_sd": float(np.mean([x[n]["sd"] / x[n]["mean"] for x in rec])),
                  "within_10pct": int(np.sum(np.abs(err) <= 0.10))}
    return out


def _trend(errs):
    """Per-seed window errors (lists, truncated to the fewest windows) -> (array (seeds, windows),
    the mean trajectory, first third - last third with its standard error over seeds)."""
    n_w = min(len(e) for e in errs)
    E = np.array([e[:n_w] for e in errs])
    third = max(1, n_w // 3)
    drop = E[:, :third].mean(axis=1) - E[:, -third:].mean(axis=1)
    return E, E.mean(axis=0).tolist(), {"mean": float(drop.mean()), "windows_per_third": third,
                                        "se": float(drop.std(ddof=1) / np.sqrt(len(drop))) if len(drop) > 1 else None}


def _trend_test(rows, lk, bound: float = 2.0) -> dict | None:
    """The validation suite's no-spurious-trend criterion per seed (``validation/suite.py``,
    ``case_mienks``): every window's mean within ``bound`` of its own posterior sd from the aggregate
    estimate, for G and mu -- over all windows, and over the windows not flagged prior-dominated.
    On constant-parameter data a seed failing it is a trend a user would read into the windows: the
    fraction failing is the false-trend rate (with its Wilson interval). Also the decided windows'
    first - last third in units of their own mean sd."""
    rs = [r[lk] for r in rows if "window_dev_sd" in r[lk]]
    if not rs:
        return None
    out = {"bound_sd": bound, "n_seeds": len(rs)}
    for scope in ("all", "decided"):
        ok = []
        for r in rs:
            dom = np.array(r["window_prior_dominated"], dtype=bool)
            keep = ~dom if scope == "decided" else np.ones(dom.size, dtype=bool)
            ok.append(all(np.all(np.abs(np.array(r["window_dev_sd"][n])[keep]) < bound) for n in TRUTH))
        k = int(len(ok) - np.sum(ok))
        out[scope] = {"seeds_with_a_trend": k, "false_trend_rate": k / len(ok), "wilson95": wilson(k, len(ok)),
                      "max_abs_dev_sd": {n: float(np.median([np.max(np.abs(np.array(r["window_dev_sd"][n])[
                          ~np.array(r["window_prior_dominated"], bool) if scope == "decided" else slice(None)]))
                          for r in rs])) for n in TRUTH}}
    drops = {n: [] for n in TRUTH}
    for r in rs:
        dom = np.array(r["window_prior_dominated"], dtype=bool)
        for n in TRUTH:
            e = np.array(r["window_rel_error"][n])[~dom]
            sd = np.array(r["window_rel_sd"][n])[~dom]
            if e.size >= 2:
                k3 = max(1, e.size // 3)
                drops[n].append((e[:k3].mean() - e[-k3:].mean()) / sd.mean())
    out["decided_early_minus_late_in_window_sd"] = {
        n: {"mean": float(np.mean(v)), "se": float(np.std(v, ddof=1) / np.sqrt(len(v)))} for n, v in drops.items()
        if len(v) > 1}
    return out


def summarise(rows, likelihoods) -> dict:
    out = {}
    for lk in likelihoods:
        s = {}
        for n in TRUTH:
            k = sum(r[lk][n]["covers"] for r in rows)
            err = np.array([r[lk][n]["rel_error"] for r in rows])
            s[n] = {"coverage": k / len(rows), "coverage_wilson95": wilson(k, len(rows)), "n_seeds": len(rows),
                    "mean_rel_error": float(err.mean()), "sd_rel_error": float(err.std(ddof=1)) if len(rows) > 1 else None,
                    "mean_rel_sd": float(np.mean([r[lk][n]["sd"] / r[lk][n]["mean"] for r in rows])),
                    "within_10pct": int(np.sum(np.abs(err) <= 0.10))}
            b = [r[lk][n]["between_covers"] for r in rows if "between_covers" in r[lk][n]]
            if b:
                s[n]["between_coverage"] = sum(b) / len(b)
                s[n]["between_coverage_wilson95"] = wilson(sum(b), len(b))
            p = [r[lk][n]["predictive_holds"] for r in rows if "predictive_holds" in r[lk][n]]
            if p:
                s[n]["predictive_fraction"] = float(np.mean(p))
            wins = [r[lk]["windows"][n] for r in rows if "windows" in r[lk]]
            if wins:       # per window index, over the seeds (records of a seed may hold a window more or less)
                n_w = min(len(w) for w in wins)
                cov_w = np.mean(np.array([w[:n_w] for w in wins], dtype=float), axis=0)
                s[n]["window_coverage"] = cov_w.tolist()
                s[n]["window_coverage_min"] = float(cov_w.min())
                flat = [c for w in wins for c in w]
                s[n]["window_coverage_all"] = float(np.mean(flat))
                s[n]["window_coverage_all_wilson95"] = wilson(int(np.sum(flat)), len(flat))
            for kind in ("pooled", "bubbles"):
                E = [r[lk][f"window_rel_error_{kind}"][n] for r in rows if n in r[lk].get(f"window_rel_error_{kind}", {})]
                if E:
                    s[n][f"window_{kind}_rel_error_mean"] = _trend(E)[1]
            med = [r[lk]["window_rel_error_median"][n] for r in rows if "window_rel_error_median" in r[lk]]
            if med:        # the same trajectory and trend for the window medians
                _, s[n]["window_median_rel_error_mean"], s[n]["median_early_minus_late"] = _trend(med)
            errs = [r[lk]["window_rel_error"][n] for r in rows if "window_rel_error" in r[lk]]
            if errs:       # the mean window trajectory over seeds, and its apparent trend (truth: none)
                E, s[n]["window_rel_error_mean"], s[n]["early_minus_late"] = _trend(errs)
                n_w = E.shape[1]
                doms = [r[lk]["window_prior_dominated"][:n_w] for r in rows if "window_prior_dominated" in r[lk]]
                if len(doms) == len(errs):     # the same over the windows not flagged prior-dominated
                    D = np.array(doms, dtype=bool)
                    drops = []
                    for e, d in zip(E, D):
                        dec = e[~d]
                        if dec.size >= 2:
                            k = max(1, dec.size // 3)
                            drops.append(dec[:k].mean() - dec[-k:].mean())
                    s[n]["prior_dominated_fraction"] = D.mean(axis=0).tolist()
                    s[n]["decided_rel_error_mean"] = float(E[~D].mean()) if (~D).any() else None
                    s[n]["dominated_rel_error_mean"] = float(E[D].mean()) if D.any() else None
                    if len(drops) > 1:
                        s[n]["decided_early_minus_late"] = {"mean": float(np.mean(drops)), "n_seeds": len(drops),
                                                            "se": float(np.std(drops, ddof=1) / np.sqrt(len(drops)))}
        trend = _trend_test(rows, lk)
        if trend:
            s["trend_test"] = trend
        rec = [r[lk]["record"] for r in rows if "record" in r[lk]]
        if rec:          # MIEnKS-MDA's record-level estimate (each experiment's window likelihoods summed)
            s["record"] = _coverage_table(rec)
        names = sorted({a for r in rows for a in r[lk].get("alternatives", {})})
        if names:
            s["alternatives"] = {a: _coverage_table([r[lk]["alternatives"][a] for r in rows
                                                    if a in r[lk].get("alternatives", {})]) for a in names}
        s["mean_runtime_s"] = float(np.mean([r[lk]["runtime_s"] for r in rows]))
        out[lk] = s
    return out


def _setting(kv: str):
    key, sep, val = kv.partition("=")
    if not sep or not key:
        raise SystemExit(f"--set {kv!r}: expected KEY=VALUE")
    if val.lower() in ("none", "null"):       # unset, as `imrbayes fit --set` reads it
        return key, None
    if val.lower() in ("true", "false"):
        return key, val.lower() == "true"
    for cast in (int, float):
        try:
            return key, cast(val)
        except ValueError:
            pass
    return key, val


def _write(path: Path, meta: dict, rows: list, failures: list, lks) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({**meta, "truth": TRUTH, "rows": rows, "failures": failures,
                                "summary": summarise(rows, lks)}, indent=1))


def merge(paths, out: Path | None) -> dict:
    """One calibration file from several runs of the same design (e.g. seed ranges run in parallel
    processes): rows united by seed. Runs of another family, bubble, method or settings are refused,
    and so is a seed that two files report differently."""
    meta, rows, failures, lks = None, {}, [], None
    for p in paths:
        try:
            d = json.loads(Path(p).read_text())
            m = {"family": d["family"], "bubble": d["bubble"], "method": d.get("method", "en4dvar"),
                 "settings": d.get("settings", {}), **({"design": d["design"]} if d.get("design") else {})}
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise SystemExit(f"{p}: not a calibration result file ({type(exc).__name__}: {exc})")
        if meta is None:
            meta, lks = m, [k for k in d["summary"]]
        elif m != meta:
            raise SystemExit(f"{p}: another design than the first file ({m} vs {meta})")
        for r in d["rows"]:
            if r["seed"] in rows and rows[r["seed"]] != r:
                raise SystemExit(f"{p}: seed {r['seed']} differs from another file's")
            rows[r["seed"]] = r
        failures += d.get("failures", [])
    # a seed that failed in one run and finished in another counts as finished
    failures = list({f["seed"]: f for f in failures if f["seed"] not in rows}.values())
    merged = [rows[k] for k in sorted(rows)]
    if out is not None:
        _write(out, meta, merged, failures, lks)
    _print_table(meta["family"], meta["method"], meta["bubble"], merged, failures, lks)
    return {"meta": meta, "rows": merged, "failures": failures, "likelihoods": lks}


def _print_table(family, method, bubble, rows, failures, lks) -> None:
    summ = summarise(rows, lks)
    print(f"\n{family} family, {method}, {len(rows)} seeds ({len(failures)} failed), bubble {bubble}")
    print(f"{'likelihood':<10} {'param':<5} {'coverage':>9} {'Wilson 95%':>15} {'bias':>8} {'scatter':>8} "
          f"{'post sd':>8} {'between cov':>12} {'pred frac':>10}")
    for lk in lks:
        for n in TRUTH:
            s = summ[lk][n]
            w = s["coverage_wilson95"]
            print(f"{lk:<10} {n:<5} {s['coverage']:>9.2f} {f'[{w[0]:.2f}, {w[1]:.2f}]':>15} {s['mean_rel_error']:>+8.3f} "
                  f"{(s['sd_rel_error'] or float('nan')):>8.3f} {s['mean_rel_sd']:>8.3f} "
                  f"{s.get('between_coverage', float('nan')):>12.2f} {s.get('predictive_fraction', float('nan')):>10.2f}")
            if "window_coverage" in s:
                w = s["window_coverage_all_wilson95"]
                print(f"{'':<16} windows: coverage {s['window_coverage_all']:.2f} [{w[0]:.2f}, {w[1]:.2f}] over all, "
                      f"lowest window {s['window_coverage_min']:.2f} ({len(s['window_coverage'])} windows)")
            if "early_minus_late" in s:
                d = s["early_minus_late"]
                traj = ", ".join(f"{x:+.2f}" for x in s["window_rel_error_mean"])
                print(f"{'':<16} window means / truth - 1: {traj}; first third - last third "
                      f"{d['mean']:+.3f} +- {(d['se'] or float('nan')):.3f} (truth: constant)")
            for kind, label in (("pooled", "pooled window medians"), ("bubbles", "bubbles' own chains (mean)")):
                if f"window_{kind}_rel_error_mean" in s:
                    traj = ", ".join(f"{x:+.2f}" for x in s[f"window_{kind}_rel_error_mean"])
                    print(f"{'':<16} {label} / truth - 1: {traj}")
            if "median_early_minus_late" in s:
                d = s["median_early_minus_late"]
                traj = ", ".join(f"{x:+.2f}" for x in s["window_median_rel_error_mean"])
                print(f"{'':<16} window medians / truth - 1: {traj}; first third - last third "
                      f"{d['mean']:+.3f} +- {(d['se'] or float('nan')):.3f}")
            if "prior_dominated_fraction" in s:
                dd = s.get("decided_early_minus_late") or {}
                frac = ", ".join(f"{x:.2f}" for x in s["prior_dominated_fraction"])
                print(f"{'':<16} prior-dominated (per window, fraction of seeds): {frac}; mean error decided "
                      f"{(s['decided_rel_error_mean'] if s['decided_rel_error_mean'] is not None else float('nan')):+.3f}, "
                      f"dominated {(s['dominated_rel_error_mean'] if s['dominated_rel_error_mean'] is not None else float('nan')):+.3f}; "
                      f"decided windows' first - last third {dd.get('mean', float('nan')):+.3f} +- {dd.get('se', float('nan')):.3f}")
            others = ([("record-level", summ[lk]["record"])] if "record" in summ[lk] else []) + \
                list(summ[lk].get("alternatives", {}).items())
            for label, tab in others:
                x = tab[n]
                w = x["coverage_wilson95"]
                print(f"{'':<16} {label}: coverage {x['coverage']:.2f} [{w[0]:.2f}, {w[1]:.2f}], bias "
                      f"{x['mean_rel_error']:+.3f}, scatter {(x['sd_rel_error'] or float('nan')):.3f}, post sd {x['mean_rel_sd']:.3f}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=100)
    ap.add_argument("--family", choices=["camera", "scatter"], default="camera")
    ap.add_argument("--bubble", choices=["polytropic", "thermal"], default="polytropic")
    ap.add_argument("--likelihoods", default="default,paper")
    ap.add_argument("--method", choices=["en4dvar", "mienks"], default="en4dvar")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a settings field of the method (integer, float or text), e.g. screen=0; repeatable")
    ap.add_argument("--prior", action="append", default=[], metavar="NAME=MEAN:SD",
                    help="a parameter prior other than the paper's (SI), e.g. mu=0.209:2; repeatable")
    ap.add_argument("--req", choices=["estimated", "given"], default="estimated",
                    help="given: the true Req in meta.json (the fit takes it as known)")
    ap.add_argument("--phase", choices=["random", "0"], default="random",
                    help="the camera's sub-frame phase (0: a frame at every maximum)")
    ap.add_argument("--generator", choices=["imrbayes", "pyimr"], default="imrbayes",
                    help="the code that makes the data (pyimr: another code, the 'peers' extra; the fit is ours)")
    ap.add_argument("--merge", nargs="+", type=Path, default=None, metavar="FILE",
                    help="no fits: unite the rows of these result files (the same design, e.g. seed ranges run in "
                         "parallel) into --json and print the table")
    a = ap.parse_args(argv)
    if a.merge:
        merge(a.merge, a.json)
        return
    prior = {}
    for kv in a.prior:
        name, _, ms = kv.partition("=")
        try:
            m, sd = (float(x) for x in ms.split(":"))
        except ValueError:
            raise SystemExit(f"--prior {kv!r}: expected NAME=MEAN:SD")
        prior[name] = (m, sd)
    lks = [x for x in a.likelihoods.split(",") if x]
    settings = dict(_setting(kv) for kv in a.set)
    if prior:
        settings = {**settings, "prior": {k: list(v) for k, v in prior.items()}}     # kept apart in the JSON
    design = {k: v for k, v in {"req": a.req, "phase": a.phase, "generator": a.generator}.items()
              if v != {"req": "estimated", "phase": "random", "generator": "imrbayes"}[k]}
    meta = {"family": a.family, "bubble": a.bubble, "method": a.method, "settings": settings,
            **({"design": design} if design else {})}
    rows, failures = [], []
    prev = json.loads(a.json.read_text()) if a.json and a.json.exists() else {}
    done = {r["seed"]: r for r in prev.get("rows", []) if prev.get("family") == a.family and prev.get("bubble") == a.bubble
            and prev.get("settings", {}) == settings and prev.get("method", "en4dvar") == a.method
            and prev.get("design", {}) == design
            and all(lk in r for lk in lks)}
    for seed in range(a.first_seed, a.first_seed + a.seeds):
        if seed in done:                 # an interrupted run loses nothing it finished
            rows.append(done[seed])
            continue
        try:
            rows.append(one_seed(seed, a.family, a.bubble, lks, {k: v for k, v in settings.items() if k != "prior"},
                                 a.method, prior or None, design))
        except Exception as exc:        # a failed seed is reported, never silently dropped
            failures.append({"seed": seed, "error": f"{type(exc).__name__}: {exc}"[:300]})
            print(f"seed {seed}: FAILED ({failures[-1]['error']})", flush=True)
            continue
        r = rows[-1]
        print(f"seed {seed}: " + "; ".join(
            f"{lk}: G {r[lk]['G']['mean']:.0f} [{r[lk]['G']['hdi95'][0]:.0f}, {r[lk]['G']['hdi95'][1]:.0f}] "
            f"mu {r[lk]['mu']['mean']:.4f} [{r[lk]['mu']['hdi95'][0]:.4f}, {r[lk]['mu']['hdi95'][1]:.4f}]"
            for lk in lks), flush=True)
        if a.json:
            _write(a.json, meta, rows, failures, lks)
    _print_table(a.family, a.method, a.bubble, rows, failures, lks)
    versions = sorted({r.get("code", "not recorded") for r in rows})
    if len(versions) > 1:
        print(f"note: the rows come from {len(versions)} code versions ({', '.join(versions)}): a resumed file "
              f"mixes what each version computed", flush=True)
    if a.json:
        _write(a.json, meta, rows, failures, lks)


if __name__ == "__main__":
    main()
