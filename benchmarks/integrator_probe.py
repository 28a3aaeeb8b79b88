"""Would another implicit integrator pay? scipy's BDF and Radau on our compiled right-hand side.

Counts (steps, RHS evaluations, Jacobians, factorisations) and the error in R* against our own
solve at rtol 1e-9, on the LIC case (Rmax 263 um, Rmax/Req 7.58, NHKV 7.29 kPa / 0.088 Pa s,
thermal bubble with vapour and mass transfer, the default grid, t* in [0, 3]). The counts, not
scipy's wall time, are the evidence: scipy runs the linear algebra densely in Python.
docs/forward-model.md, Speed ("Tried 2026-11-27 ... a BDF integrator").

Usage: python benchmarks/integrator_probe.py [--json out.json] [METHOD:RTOL ...]
"""

from __future__ import annotations

import argparse
import json

import numpy as np
from scipy.integrate import BDF, Radau
from scipy.integrate._ivp.common import num_jac

from imrbayes.forward import ForwardModel
from imrbayes.forward.model import group_matrix

CASE = {"G": 7290.0, "mu": 0.088}
RMAX, RATIO = 263e-6, 7.58


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="*", default=["Radau:2e-5", "BDF:2e-6", "BDF:1e-6", "BDF:2e-7"])
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    fm = ForwardModel("nhkv")
    o = fm.options
    st = fm.initial_state(RMAX, RMAX / RATIO)
    P = fm._parameter_table(CASE, 1, st.rmax_m)
    G = group_matrix(fm.groups(st.rmax_m, st.req_m), 1)
    k = fm.kernel
    work, coef = np.zeros(7 * fm.nt + 2 * fm.mt + 2), np.zeros(2 * fm.nt + fm.mt + 1)

    def f(t, y):
        out = np.empty(y.shape[0])
        k.rhs(t, np.array(y, dtype=float), G[0], P[0, 0], fm._flags, fm._grid, fm._mgrid, out, coef, work)
        return out

    def fcols(t, Y):
        return f(t, Y) if Y.ndim == 1 else np.stack([f(t, Y[:, j]) for j in range(Y.shape[1])], axis=1)

    def jac(t, y):
        J, _ = num_jac(fcols, t, y, f(t, y), o.atol * np.ones_like(y), None, None)
        return np.where(np.isfinite(J), J, 0.0)

    t_ev = np.linspace(0.0, 3.0, 301)
    ours = fm.simulate(CASE, RMAX, RMAX / RATIO, t_ev)
    tight = fm.with_options(rtol=1e-9).simulate(CASE, RMAX, RMAX / RATIO, t_ev).R_star[0]
    norm = np.linalg.norm(tight)
    rows = [{"integrator": "ours (Radau IIA, kernel)", "rtol": o.rtol, "steps": int(ours.n_steps[0]),
             "l2_vs_tight": float(np.linalg.norm(ours.R_star[0] - tight) / norm)}]
    for spec in a.runs:
        meth, rtol = spec.split(":")
        s = {"BDF": BDF, "Radau": Radau}[meth](f, 0.0, st.y[0].copy(), 3.0, rtol=float(rtol), atol=o.atol, jac=jac)
        ts, dense = [], []
        while s.status == "running":
            s.step()
            ts.append(s.t)
            dense.append(s.dense_output())
        ts = np.array(ts)
        R = np.array([dense[min(int(np.searchsorted(ts, t)), len(ts) - 1)](t)[0] for t in t_ev[1:]])
        rows.append({"integrator": f"scipy {meth}", "rtol": float(rtol), "steps": len(ts), "rhs": int(s.nfev),
                     "jacobians": int(s.njev), "factorisations": int(s.nlu),
                     "l2_vs_tight": float(np.linalg.norm(R - tight[1:]) / norm)})
    print(f"{'integrator':28s} {'rtol':>8s} {'steps':>6s} {'RHS':>6s} {'jac':>5s} {'LU':>5s} {'L2 vs tight':>12s}")
    for r in rows:
        print(f"{r['integrator']:28s} {r['rtol']:8.1e} {r['steps']:6d} {r.get('rhs', 0):6d} {r.get('jacobians', 0):5d} "
              f"{r.get('factorisations', 0):5d} {r['l2_vs_tight']:12.2e}")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump({"case": {**CASE, "rmax_m": RMAX, "ratio": RATIO}, "rows": rows}, fh, indent=1)


if __name__ == "__main__":
    main()
