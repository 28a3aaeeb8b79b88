"""Calibration of the 95 % intervals over many seeds (issue: inference, item 6).

The cheaper case: the methods.md §5 verification design (5 experiments, Rmax 263 µm,
Rmax/Req 7.58, G0 = 7.29 kPa, mu0 = 0.088 Pa s, the paper's noise) with the polytropic bubble,
paper method settings. For every seed a fresh noisy data set is drawn and fitted by En4D-Var,
MIEnKS-MDA and IMR (40 x 25 grid); we count how often each 95 % interval holds the truth: the
MIEnKS aggregate and every window, En4D-Var (the paper's averaged cost; the plain likelihood
``obs_weight=sum`` with the estimated P_k; the same with the true noise variance), and IMR's region
(its G and mu extents); and with the pooled noise variance (``--noise pooled``) En4D-Var with
``obs_weight=sum`` and MIEnKS-MDA with ``obs_weight=mda`` (each observation's weights summing to
one). Per interval also: mean relative error of the estimate, its scatter over
seeds, the mean posterior sd (relative) and how many seeds land within 5 % of the truth. Coverage is
reported with a 95 % Wilson interval. Windows of one data set are not independent, so the
per-window coverage's interval is too narrow; the per-seed fraction is reported beside it.

``--methods en4dvar_default mienks_default`` runs the realistic-data default likelihood instead
(methods.md §7: every sample once, record noise, nuisances inferred, residual tempering,
random-effects fusion) on the same design: the issue-#19 check "the paper's verification design:
coverage 90-99 %". The other methods are the paper's settings.

Usage: python validation/calibration.py [--seeds 20] [--methods M ...] [--json out.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

import numpy as np

from imrbayes.ensemble import (En4DVarSettings, IMRSettings, MIEnKSSettings, ParamSpace, fit_en4dvar, fit_imr,
                               fit_mienks)
from imrbayes.data.noise import noise_variance, paper_sigma
from imrbayes.forward import ForwardModel
from imrbayes.validation.suite import TRUTH, verification_data


METHODS = ("en4dvar", "en4dvar_sum", "en4dvar_sum_known_noise", "en4dvar_sum_pooled", "mienks",
           "mienks_mda_pooled", "imr", "en4dvar_default", "mienks_default")
PAPER_METHODS = METHODS[:7]


def wilson(k: int, n: int, z: float = 1.959964) -> tuple:
    """95 % Wilson score interval of a binomial proportion k/n."""
    if n == 0:
        return (float("nan"), float("nan"))
    p = k / n
    den = 1 + z * z / n
    c = (p + z * z / (2 * n)) / den
    h = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (float(c - h), float(c + h))


def covers(est: dict, name: str) -> bool:
    lo, hi = est[name]["hdi95"]
    return bool(lo <= TRUTH[name] <= hi)


def one_seed(fm, space, seed: int, methods=PAPER_METHODS, mienks_set: dict | None = None) -> dict:
    obs = verification_data(fm, seed)
    row, fits = {"seed": seed}, []

    def en4dvar(data, **kw):
        return fit_en4dvar(fm, data, space, En4DVarSettings(n_draws=1, loglik=False, **kw), seed=seed)

    def mienks(name, data, **kw):
        res = fit_mienks(fm, data, space, MIEnKSSettings(n_draws=1, **{**kw, **(mienks_set or {})}), seed=seed)
        row[f"{name}_windows"] = {n: [covers(w, n) for w in res.windows] for n in TRUTH}
        return res

    for m in methods:
        if m == "en4dvar":
            res = en4dvar(obs, likelihood="paper")
        elif m == "en4dvar_sum":     # the plain likelihood (obs_weight=sum) with the estimated P_k
            res = en4dvar(obs, obs_weight="sum", likelihood="paper")
        elif m == "en4dvar_sum_known_noise":
            clean = verification_data(fm, seed, noise=False)
            known = dataclasses.replace(obs, P=np.maximum(paper_sigma(clean.t_star, clean.R_star[0]) ** 2, obs.P.min()))
            res = en4dvar(known, obs_weight="sum", likelihood="paper")
        elif m == "en4dvar_sum_pooled":
            pooled = dataclasses.replace(obs, P=noise_variance(obs.t_star, obs.R_star, method="pooled")[0])
            res = en4dvar(pooled, obs_weight="sum", likelihood="paper")
        elif m == "mienks_mda_pooled":
            pooled = dataclasses.replace(obs, P=noise_variance(obs.t_star, obs.R_star, method="pooled")[0])
            res = mienks(m, pooled, obs_weight="mda", likelihood="paper")
        elif m == "mienks":
            res = mienks(m, obs, likelihood="paper")
        elif m == "imr":
            res = fit_imr(fm, obs, space, IMRSettings(n_G=40, n_mu=25), seed=seed)
        elif m == "en4dvar_default":
            res = en4dvar(obs, likelihood="default")
        elif m == "mienks_default":
            res = mienks(m, obs, likelihood="default")
        else:
            raise SystemExit(f"unknown method {m!r}; choose from {', '.join(METHODS)}")
        row[m] = {n: covers(res.estimate, n) for n in TRUTH}
        fits.append((m, res.estimate))
        record = (res.details.get("record_random_effects") or {}).get("estimate")
        if m.startswith("mienks") and record:
            # MIEnKS-MDA's record-level estimate (each experiment's window likelihoods summed over the
            # record, the prior once, random effects), reported beside the aggregate
            row[f"{m}_record"] = {n: covers(record, n) for n in TRUTH}
            fits.append((f"{m}_record", record))
        chain = (res.details.get("alternative_estimates") or {}).get("aggregate_chain_cov")
        if m.startswith("mienks") and chain:
            # the aggregate's mean with its covariance propagated through the window chain
            row[f"{m}_chain"] = {n: covers(chain, n) for n in TRUTH}
            fits.append((f"{m}_chain", chain))
    row["estimates"] = {m: {n: e[n]["mean"] for n in TRUTH} for m, e in fits}
    row["sds"] = {m: {n: e[n]["sd"] for n in TRUTH} for m, e in fits}
    return row


def summarise(rows: list) -> dict:
    out = {}
    for method in [*METHODS, *(f"{m}_record" for m in METHODS), *(f"{m}_chain" for m in METHODS)]:
        if method not in rows[0]:
            continue
        for n in TRUTH:
            k = sum(r[method][n] for r in rows)
            out[f"{method}:{n}"] = {"covered": k, "n": len(rows), "coverage": k / len(rows),
                                    "wilson95": wilson(k, len(rows))}
            if "estimates" in rows[0]:
                rel = np.array([r["estimates"][method][n] / TRUTH[n] - 1.0 for r in rows])
                out[f"{method}:{n}"].update(
                    mean_relative_error=float(rel.mean()), scatter_relative=float(rel.std(ddof=1)),
                    mean_sd_relative=float(np.mean([r["sds"][method][n] / TRUTH[n] for r in rows])),
                    within_5_percent=int(np.sum(np.abs(rel) < 0.05)))
    for key, n in [(k, n) for k in ("mienks_windows", "mienks_mda_pooled_windows", "mienks_default_windows")
                   for n in TRUTH]:
        if key not in rows[0]:
            continue
        flags = [c for r in rows for c in r[key][n]]
        per_seed = [float(np.mean(r[key][n])) for r in rows]
        out[f"{key}:{n}"] = {"covered": int(sum(flags)), "n": len(flags), "coverage": float(np.mean(flags)),
                                      "wilson95": wilson(int(sum(flags)), len(flags)),
                                      "per_seed_min": min(per_seed), "per_seed_median": float(np.median(per_seed)),
                                      "seeds_with_at_least_90pct": int(sum(p >= 0.9 for p in per_seed))}
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=100, help="seeds first-seed .. first-seed + seeds - 1")
    ap.add_argument("--methods", nargs="+", default=list(PAPER_METHODS), choices=list(METHODS))
    ap.add_argument("--json", default=None)
    ap.add_argument("--mienks-set", action="append", default=[], metavar="KEY=VALUE",
                    help="a MIEnKSSettings field for the MIEnKS-MDA rows (JSON value), e.g. rtps_regress=true")
    args = ap.parse_args(argv)
    mienks_set = {}
    for item in args.mienks_set:
        key, _, value = item.partition("=")
        if key not in {f.name for f in dataclasses.fields(MIEnKSSettings)}:
            raise SystemExit(f"--mienks-set: {key!r} is not a MIEnKSSettings field")
        try:
            mienks_set[key] = json.loads(value)
        except json.JSONDecodeError:
            mienks_set[key] = value
    args.mienks_settings = mienks_set
    fm = ForwardModel("nhkv", options={"bubble": "polytropic"})
    space = ParamSpace.for_model(fm.constitutive)
    rows, t0 = [], time.perf_counter()
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        rows.append(one_seed(fm, space, seed, args.methods, mienks_set))
        print(f"seed {seed}: " + " ".join(f"{m}:{''.join('y' if rows[-1][m][n] else 'n' for n in TRUTH)}"
                                           for m in args.methods)
              + "".join(f" {k} G {np.mean(rows[-1][k]['G']):.2f} mu {np.mean(rows[-1][k]['mu']):.2f}"
                        for k in rows[-1] if k.endswith("_windows")), flush=True)
        _write(args, rows, t0)
    summary = summarise(rows)
    print(f"\n{'interval':<28} {'covered':>8} {'coverage':>9} {'95 % (Wilson)':>16} {'bias':>7} {'scatter':>8} "
          f"{'mean sd':>8} {'<5 %':>5}")
    for key, v in summary.items():
        extra = (f" {v['mean_relative_error']:+7.3f} {v['scatter_relative']:8.3f} {v['mean_sd_relative']:8.3f} "
                 f"{v['within_5_percent']:5d}") if "scatter_relative" in v else ""
        print(f"{key:<28} {v['covered']:>4}/{v['n']:<4} {v['coverage']:9.3f}   [{v['wilson95'][0]:.3f}, "
              f"{v['wilson95'][1]:.3f}]" + extra)
    return _write(args, rows, t0)


def _write(args, rows, t0) -> dict:
    """The result so far (written after every seed: an interrupted run keeps the seeds it finished)."""
    result = {"case": "methods.md §5 design, polytropic bubble, paper noise; paper settings unless the method's "
                      "name ends in _default (the default likelihood); IMR 40 x 25 grid", "methods": args.methods,
              "truth": TRUTH, "mienks_settings": getattr(args, "mienks_settings", {}), "seeds": [r["seed"] for r in rows], "runtime_s": time.perf_counter() - t0,
              "summary": summarise(rows), "rows": rows}
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(result, fh, indent=1)
    return result


if __name__ == "__main__":
    main()
