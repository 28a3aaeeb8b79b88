"""How many points does a Chebyshev (spectral) treatment of the bubble's fields need, against our
clustered finite differences? Issue #20 names a spectral treatment as the lever left for the
forward-model rows; this measures it on the peer code that has one (PyIMR 0.1.1, the optional
``peers`` extra) before anyone builds it.

Case: the LIC case of ``benchmarks/forward.py`` (NHKV 7.29 kPa / 0.088 Pa s, Rmax 263 µm,
Rmax/Req 7.58, Keller-Miksis, thermal bubble with vapour and mass transfer, cold medium,
t* in [0, 3]), PyIMR run with our constants (the non-condensable gas's polytropic exponent is the
one constant that differs). Error: relative L2 in R* against our grid limit (stretch 3, nt 2048,
rtol 1e-9), for PyIMR at several Nt (rtol 1e-10) and for our finite differences at several nt
(stretch 2.75, the default's, rtol 1e-8, so that the columns measure the space discretisation).

    python benchmarks/spectral_probe.py --json benchmarks/results/spectral_probe_YYYYMMDD.json
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine_info  # noqa: E402
from forward import RATIO, RMAX, T_STAR, _peer_case  # noqa: E402

from imrbayes.forward import ForwardModel, ForwardOptions  # noqa: E402


def dense_lu_us(n: int, repeat: int = 400) -> dict:
    """Median time [µs] of one LU factorisation of a dense real and a dense complex n x n matrix
    (LAPACK through scipy): what each of Radau's Newton systems would cost if the bubble's fields
    were collocated (dense differentiation matrices) instead of finite-differenced (block
    tridiagonal plus low rank, O(n)). n: two fields (temperature, vapour) on the nodes plus R, Rdot, p."""
    from scipy.linalg import lu_factor
    rng = np.random.default_rng(0)
    out = {"dense_n": n}
    for kind, a in (("real", rng.normal(size=(n, n)) + n * np.eye(n)),
                    ("complex", rng.normal(size=(n, n)) + 1j * rng.normal(size=(n, n)) + n * np.eye(n))):
        ts = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            lu_factor(a, check_finite=False)
            ts.append(time.perf_counter() - t0)
        out[f"lu_{kind}_us"] = 1e6 * float(np.median(ts))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--peer-nt", default="17,25,33,41,49,65")
    ap.add_argument("--our-nt", default="24,32,48,64,96,128")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    try:
        from pyimr import NeoHookeanKelvinVoigt, PhysicalParameters, SimulationConfig, prepare
    except ImportError:
        print("spectral_probe: needs pyimr (pip install -e '.[peers]')", file=sys.stderr)
        return 2
    theta = {"G": 7290.0, "mu": 0.088}
    rows = []

    def save():
        if a.json:
            import pyimr
            out = {"machine": machine_info(), "pyimr": pyimr.__version__,
                   "case": "LIC, NHKV 7.29 kPa 0.088 Pa s, KM, thermal, vapour, mass transfer, cold medium, t* 0-3",
                   "limit": "imrbayes stretch 3, nt 2048, rtol 1e-9", "rows": rows}
            a.json.parent.mkdir(parents=True, exist_ok=True)
            a.json.write_text(json.dumps(out, indent=2))

    lim = ForwardModel("nhkv", options=ForwardOptions(nt=2048, mt=2048, stretch=3.0, rtol=1e-9, atol=1e-11))
    R_lim = lim.simulate(theta, RMAX, RMAX / RATIO, T_STAR, max_steps=50_000_000).R_star[0]
    rel = lambda a, b: float(np.linalg.norm(a - b) / np.linalg.norm(b))  # noqa: E731
    ours_kappa = ForwardModel("nhkv").physics.kappa
    tc = RMAX / np.sqrt(lim.physics.p8 / lim.physics.rho)
    for nt in [int(x) for x in a.our_nt.split(",")]:
        fm = ForwardModel("nhkv", options=ForwardOptions(nt=nt, mt=nt, stretch=2.75, rtol=1e-8, atol=1e-10))
        fm.simulate(theta, RMAX, RMAX / RATIO, T_STAR[:3])
        t0 = time.perf_counter()
        out = fm.simulate(theta, RMAX, RMAX / RATIO, T_STAR)
        ms = 1e3 * (time.perf_counter() - t0)
        R = out.R_star[0]
        rows.append({"code": "imrbayes FD, stretch 2.75", "points": nt, "rel_l2_to_limit": rel(R, R_lim),
                     "max_abs_Rstar": float(np.max(np.abs(R - R_lim))), "solve_ms": ms,
                     "steps": int(out.n_steps[0]), "us_per_step": 1e3 * ms / int(out.n_steps[0])})
        print(f"  imrbayes FD  nt {nt:4d}: {rows[-1]['rel_l2_to_limit']:.2e}", flush=True)
        save()
    mat = NeoHookeanKelvinVoigt(theta["G"], theta["mu"])
    phys = PhysicalParameters(polytropic_exponent=ours_kappa)
    for nt in [int(x) for x in a.peer_nt.split(",")]:
        c = SimulationConfig(material=mat, Nt=nt, rtol=1e-10, atol=1e-12, physics=phys, **_peer_case())
        prob = prepare(c)
        prob.solve(T_STAR * tc)                          # JAX trace and compile at this Nt
        t0 = time.perf_counter()
        R = np.asarray(prob.solve(T_STAR * tc).radius_ratio)
        rows.append({"code": "PyIMR Chebyshev", "points": nt, "rel_l2_to_limit": rel(R, R_lim),
                     "max_abs_Rstar": float(np.max(np.abs(R - R_lim))), "solve_ms": 1e3 * (time.perf_counter() - t0),
                     **dense_lu_us(2 * nt + 3)})
        print(f"  PyIMR cheb   Nt {nt:4d}: {rows[-1]['rel_l2_to_limit']:.2e}", flush=True)
        save()
    print("\n| code | points | rel. L2 to our limit | max abs dR* | one solve [ms] | per step [µs] "
          "| dense LU real + complex [µs] |\n|---|---|---|---|---|---|---|")
    for r in rows:
        step = f"{r['us_per_step']:.1f}" if "us_per_step" in r else "–"
        lu = f"{r['lu_real_us'] + r['lu_complex_us']:.0f} (n {r['dense_n']})" if "dense_n" in r else "–"
        print(f"| {r['code']} | {r['points']} | {r['rel_l2_to_limit']:.1e} | {r['max_abs_Rstar']:.1e} "
              f"| {r['solve_ms']:.0f} | {step} | {lu} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
