"""Can En4D-Var's emcee check integrate the nuisances out instead of sampling them?

With the default likelihood, ``fit --method en4dvar --mcmc`` samples the parameters with every
experiment's nuisances nu_n = (Rmax error a, time of the maximum delta, log Req error rho):
d = 2 + 3 N_exp (19 on six camera bubbles). The target factorises over experiments given the
parameters z, so p(z | y) = p0(z) prod_n int p(y_n | z, nu_n) N(nu_n; 0, S_n) dnu_n, and a 2-D
sampler would do if that integral were cheap and right. This script evaluates it along a line in
log G (mu at the fit's mean) three ways, per experiment, summed:

* **linearised**: the prediction linear in nu_n around the fit's posterior mean nu_bar_n, J_n a
  central secant over +-(the fit's posterior sd) at the fit's parameters, computed once; the
  Gaussian integral is exact for that linear model (one forward solve per experiment and z);
* **Laplace**: a Levenberg-Marquardt search of each experiment's nu_n at this z (from nu_bar_n
  and from 0, the better kept), Gauss-Newton Hessian, Laplace's formula (~10-30 solves);
* **importance sampling**: M draws from a Student-t (4 dof, 1.5x the Laplace sd) around the
  Laplace mode -- unbiased for the integral; its effective sample size says how far the
  conditional posterior of nu_n is from one Gaussian bump.

docs/mcmc.md ("Nuisances integrated out: tried, not kept") has the table and what it means.

Usage: python benchmarks/mcmc_nuisance_marginal.py DATA [--forward bubble=polytropic] [--draws 1500]
           [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np
from scipy.stats import multivariate_t

from imrbayes.data import load_dataset, preprocess_dataset
from imrbayes.ensemble import METHODS, Observations, ParamSpace
from imrbayes.ensemble.likelihood import predict as predict_nuisance
from imrbayes.forward import ForwardModel, ForwardOptions, Runner
from imrbayes.mcmc.fit import fit_window_specs

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _machine import machine_info  # noqa: E402


class Experiment:
    """Experiment e of a sampled-nuisance window target: whitened residuals at (z, nu)."""

    def __init__(self, tg, space, e):
        self.tg, self.space, self.e = tg, space, e
        self.q = np.flatnonzero(tg.nuisance_used[e])
        self.Pm = 1.0 / tg.nuisance_sd[e, self.q] ** 2
        self.solves = 0

    def resid(self, z, x):
        """x (M, q) nuisances -> whitened residuals (M, m), failed (M,)."""
        tg, e = self.tg, self.e
        x = np.atleast_2d(x)
        nu = np.zeros((x.shape[0], 3))
        nu[:, self.q] = x
        th = np.repeat(self.space.to_si(np.asarray(z)[None]), x.shape[0], axis=0)
        R, bad = predict_nuisance(tg.model, th, float(tg.start.rmax_m[e]), float(tg.start.req_m[e]), tg.t_eval, nu,
                                  None if tg.frames is None else tg.frames[e])
        self.solves += x.shape[0]
        r = np.einsum("ij,nj->ni", tg.whiten[e], np.where(tg.use[e][None], tg.y[e] - R, 0.0))
        return r, bad | ~np.all(np.isfinite(r), axis=1)

    def log_joint(self, z, x):
        r, bad = self.resid(z, x)
        x = np.atleast_2d(x)
        ll = (-0.5 * np.sum(r * r, axis=1) - 0.5 * np.sum(x * x * self.Pm, axis=1)
              + 0.5 * np.sum(np.log(self.Pm)) - 0.5 * self.q.size * np.log(2 * np.pi))
        return np.where(bad, -np.inf, ll)

    def jacobian(self, z, x, h):
        """d(prediction)/d(nu) in whitened units, central secant of half-width h (q,)."""
        X = np.repeat(x[None], 2 * self.q.size, axis=0)
        for i in range(self.q.size):
            X[2 * i, i] += h[i]
            X[2 * i + 1, i] -= h[i]
        r, _ = self.resid(z, X)
        return np.stack([-(r[2 * i] - r[2 * i + 1]) / (2 * h[i]) for i in range(self.q.size)], axis=1)

    def linearised(self, z, xbar, J):
        """The Gaussian integral with the prediction linear in nu around xbar (J fixed)."""
        r, bad = self.resid(z, xbar)
        H = J.T @ J + np.diag(self.Pm)
        b = J.T @ r[0] - self.Pm * xbar
        val = -0.5 * (r[0] @ r[0] + self.Pm @ xbar ** 2 - b @ np.linalg.solve(H, b)) \
            - 0.5 * (np.linalg.slogdet(H)[1] - np.sum(np.log(self.Pm)))
        return -np.inf if bad[0] else float(val)

    def laplace(self, z, starts, iters=12):
        best = None
        for x in starts:
            x = np.array(x, dtype=float)
            r, bad = self.resid(z, x)
            f = 0.5 * (r[0] @ r[0] + self.Pm @ x ** 2) if not bad[0] else np.inf
            lam = 1e-3
            for _ in range(iters):
                J = self.jacobian(z, x, 1e-2 / np.sqrt(self.Pm))
                H = J.T @ J + np.diag(self.Pm)
                g = -J.T @ r[0] + self.Pm * x
                moved = False
                for _ in range(10):
                    step = -np.linalg.solve(H + lam * np.diag(np.diag(H)), g)
                    rn, bn = self.resid(z, x + step)
                    fn = 0.5 * (rn[0] @ rn[0] + self.Pm @ (x + step) ** 2) if not bn[0] else np.inf
                    if fn < f:
                        x, f, r, lam, moved = x + step, fn, rn, lam / 3, True
                        break
                    lam *= 5
                if not moved or np.max(np.abs(step) * np.sqrt(self.Pm)) < 1e-3:
                    break
            val = -f - 0.5 * (np.linalg.slogdet(H)[1] - np.sum(np.log(self.Pm)))
            if best is None or val > best[0]:
                best = (float(val), x, np.linalg.inv(H))
        return best

    def importance(self, z, mode, cov, n, rng):
        prop = multivariate_t(loc=mode, shape=2.25 * cov, df=4)
        x = prop.rvs(n, random_state=rng).reshape(n, -1)
        lw = self.log_joint(z, x) - prop.logpdf(x)
        m = np.max(lw)
        w = np.exp(lw - m)
        return float(m + np.log(np.mean(w))), float(w.sum() ** 2 / (w * w).sum())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data")
    ap.add_argument("--forward", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--draws", type=int, default=1500)
    ap.add_argument("--offsets", type=float, nargs="*", default=list(np.linspace(-0.6, 0.15, 7)),
                    help="points along log G, relative to the fit's mean")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    ds = load_dataset(a.data)
    pre = preprocess_dataset(ds, skip_failed=True)
    fm = ForwardModel("nhkv", options=ForwardOptions.from_dict(dict(kv.split("=", 1) for kv in a.forward)),
                      physics_overrides=ds.physics or None)
    obs = Observations.from_preprocessed(pre)
    space = ParamSpace.for_model(fm.constitutive)
    meth = METHODS["en4dvar"]
    res = meth.fit(fm, obs, space, meth.settings_class(), seed=0, runner=Runner(fm))
    wp = res.window_posteriors[0]
    tg = fit_window_specs(fm, obs, space, res)[0].target
    if not tg.nuisance_used.any():
        raise SystemExit(f"{a.data}: this fit has no nuisances to integrate out")
    exps = [Experiment(tg, space, e) for e in range(tg.n_exp)]
    zc = np.asarray(res.mean_internal, float)
    lin = []
    for ex in exps:
        xbar = np.nan_to_num(np.asarray(wp.nuisance_mean, float)[ex.e, ex.q])
        h = np.asarray(wp.nuisance_post_sd, float)[ex.e, ex.q]
        h = np.where(np.isfinite(h) & (h > 0), h, 0.5 / np.sqrt(ex.Pm))
        lin.append((xbar, ex.jacobian(zc, xbar, h)))
    rng = np.random.default_rng(1)
    rows = []
    print(f"{'G [Pa]':>8s} {'linearised':>11s} {'Laplace':>9s} {'IS':>9s} {'IS-Laplace':>10s} {'IS-lin.':>8s} {'min ESS':>8s}")
    for off in a.offsets:
        z = zc + np.array([off] + [0.0] * (zc.size - 1))
        tl = tla = tis = 0.0
        ess = []
        for ex, (xbar, J) in zip(exps, lin):
            tl += ex.linearised(z, xbar, J)
            v, mode, cov = ex.laplace(z, [xbar, np.zeros(ex.q.size)])
            tla += v
            w, e = ex.importance(z, mode, cov, a.draws, rng)
            tis += w
            ess.append(e)
        row = {"G": float(np.exp(z[0])), "linearised": tl, "laplace": tla, "importance": tis, "min_ess": min(ess),
               "ess": ess}
        rows.append(row)
        print(f"{row['G']:8.0f} {tl:11.2f} {tla:9.2f} {tis:9.2f} {tis - tla:10.2f} {tis - tl:8.2f} {min(ess):8.0f}",
              flush=True)
    out = {"data": a.data, "forward": fm.describe()["options"], "fit_mean": np.exp(zc).tolist(),
           "nuisance_mean": np.asarray(wp.nuisance_mean, float).tolist(),
           "nuisance_post_sd": np.asarray(wp.nuisance_post_sd, float).tolist(), "draws": a.draws, "rows": rows,
           "solves": sum(ex.solves for ex in exps), "machine": machine_info()}
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=1)


if __name__ == "__main__":
    main()
