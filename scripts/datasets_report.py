"""Regenerate the numbers and figures of docs/datasets.md.

Runs ``imrbayes inspect`` on every R(t) dataset in ../shared/data/lic (and on each camera view of the
dual-camera set), copies the figures to docs/figures/datasets/, compares the UMich PA10 records with
the pIMR per-bubble summaries, measures the sub-frame estimators on forward-model curves, and prints
the markdown tables on stdout.

    .venv/bin/python scripts/datasets_report.py > /tmp/tables.md
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
LIC = REPO / ".." / "shared" / "data" / "lic"
FIG = REPO / "docs" / "figures" / "datasets"
EXE = Path(sys.executable).parent / "imrbayes"
RHO, P8 = 1064.0, 101325.0

RUNS = [  # (label, path, extra args)
    ("estrada2018_stiffPA_270kfps", LIC / "estrada2018_stiffPA_270kfps", []),
    ("estrada2018_stiffPA_xy002_refit", LIC / "estrada2018_stiffPA_xy002_refit", []),
    ("franck_lab_A_E2_002_1.59Mfps", LIC / "franck_lab_A_E2_002_1.59Mfps", []),
    ("umich_PA10 (both views)", LIC / "umich_PA10_bis0.06_1Mfps_dualcam", []),
    ("umich_PA10 cam0deg", LIC / "umich_PA10_bis0.06_1Mfps_dualcam", ["--camera", "cam0deg"]),
    ("umich_PA10 cam90deg", LIC / "umich_PA10_bis0.06_1Mfps_dualcam", ["--camera", "cam90deg"]),
]
MATS = ["estrada2018_stiffPA_RofT_shifted.mat", "estrada2018_stiffPA_xy002_RofT.mat", "franck_lab_A_E2_002.mat",
        "umich_PA10_PolyAcry_12_28_04_updated.mat"]


def inspect(path, extra, out, *more) -> dict:
    cmd = [str(EXE), "inspect", str(path), "--out", str(out), "--force", "--json", *extra, *more]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=True)
    return json.loads(proc.stdout)


def pm(s, key, digits):
    m, sd = s[key]["mean"], s[key]["sd"]
    return f"{m:.{digits}f}" if sd is None else f"{m:.{digits}f} ± {sd:.{digits}f}"


def rng_(s, key, digits):
    return f"{s[key]['min']:.{digits}f}–{s[key]['max']:.{digits}f}"


def main():
    FIG.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp())
    tables = {}
    print("## Per dataset (mean ± sd over experiments; range below)\n")
    print("| dataset | n | Rmax [µm] | Req [µm] | Rmax/Req | t_c* | t_c* (sample max/min) | median √P_k | floor √P |")
    print("|---|---|---|---|---|---|---|---|---|")
    for label, path, extra in RUNS:
        slug = label.replace(" ", "_").replace("(", "").replace(")", "")
        t = inspect(path, extra, tmp / slug)
        ts = inspect(path, extra, tmp / (slug + "_s"), "--rmax-method", "sample", "--collapse-method", "sample")
        tables[label] = t
        shutil.copy(tmp / slug / "figures" / "radius.png", FIG / f"{slug}.png")
        s, ss = t["summary"], ts["summary"]
        n = t["n_experiments"]
        grid = json.loads((tmp / slug / "dataset.json").read_text())["grid"]
        sqrt_p = np.sqrt(np.asarray(grid["P"]))
        kind = "model" if t["choices"]["noise"]["method"] == "paper-noise-model" else "data"
        print(f"| {label} | {n} | {pm(s, 'rmax_um', 1)} | {pm(s, 'req_um', 2)} | {pm(s, 'rmax_over_req', 2)} | "
              f"{pm(s, 't_collapse_star', 3)} | {pm(ss, 't_collapse_star', 3)} | {np.median(sqrt_p):.4f} ({kind}) | "
              f"{math.sqrt(t['choices']['noise']['floor']):.4f} |")
        if n > 1:
            print(f"| | | {rng_(s, 'rmax_um', 1)} | {rng_(s, 'req_um', 2)} | {rng_(s, 'rmax_over_req', 2)} | "
                  f"{rng_(s, 't_collapse_star', 3)} | {rng_(ss, 't_collapse_star', 3)} | | |")
    print("\n## Per experiment\n")
    for label in ("estrada2018_stiffPA_270kfps", "estrada2018_stiffPA_xy002_refit", "franck_lab_A_E2_002_1.59Mfps",
                  "umich_PA10 (both views)"):
        print(f"\n**{label}**\n")
        print("| experiment | Rmax [µm] | Req [µm] (± sd of tail) | Rmax/Req | t_c* | t_c [µs] |")
        print("|---|---|---|---|---|---|")
        for e in tables[label]["experiments"]:
            sd = "" if e["req_sd_um"] is None else f" ± {e['req_sd_um']:.2f}"
            print(f"| {e['name']} | {e['rmax_um']:.2f} | {e['req_um']:.2f}{sd} | {e['rmax_over_req']:.3f} | "
                  f"{e['t_collapse_star']:.4f} | {e['t_collapse_us']:.2f} |")
    print("\n## .mat originals (same numbers through the .mat loader)\n")
    print("| file | layout found | n | Rmax [µm] | Req [µm] | t_c* |")
    print("|---|---|---|---|---|---|")
    for m in MATS:
        t = inspect(LIC / "mat_originals" / m, [], tmp / m)
        s = t["summary"]
        print(f"| {m} | {t['format']} | {t['n_experiments']} | {pm(s, 'rmax_um', 2)} | {pm(s, 'req_um', 2)} | "
              f"{pm(s, 't_collapse_star', 4)} |")
    compare_pimr(tables)
    subframe_study()


def compare_pimr(tables):
    import pandas as pd
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    uc = math.sqrt(P8 / RHO)
    summ = {}
    for key in ("PA05_bis0.03", "PA10_bis0.06"):
        s = pd.read_csv(LIC / "umich_pIMR_PA_summaries" / f"{key}_summary.csv")
        s["tcs"] = s.t_collapse_s / (s.Rmax_m / uc)
        s["rmax_um"] = s.Rmax_m * 1e6
        summ[key] = s
    ours = {cam: tables[f"umich_PA10 {cam}"]["experiments"] for cam in ("cam0deg", "cam90deg")}
    print("\n## pIMR summaries (t_c* = t_collapse_s / (Rmax_m / sqrt(p8/rho)), rho = 1064, p8 = 101325)\n")
    print("| set | n | Rmax [µm] | Rmax/Req | t_c* | t_c* range |")
    print("|---|---|---|---|---|---|")
    for key, s in summ.items():
        print(f"| pIMR {key} | {len(s)} | {s.rmax_um.mean():.1f} ± {s.rmax_um.std():.1f} | "
              f"{s.Lmax_Rmax_over_Req.mean():.2f} ± {s.Lmax_Rmax_over_Req.std():.2f} | "
              f"{s.tcs.mean():.3f} ± {s.tcs.std():.3f} | {s.tcs.min():.3f}–{s.tcs.max():.3f} |")
    for cam, ex in ours.items():
        r = np.array([e["rmax_um"] for e in ex])
        L = np.array([e["rmax_over_req"] for e in ex])
        tc = np.array([e["t_collapse_star"] for e in ex])
        print(f"| ours umich_PA10 {cam} | {len(ex)} | {r.mean():.1f} ± {r.std(ddof=1):.1f} | "
              f"{L.mean():.2f} ± {L.std(ddof=1):.2f} | {tc.mean():.3f} ± {tc.std(ddof=1):.3f} | "
              f"{tc.min():.3f}–{tc.max():.3f} |")
    print("\nResidual of our t_c* from each pIMR set's linear trend t_c*(Rmax), in units of that set's "
          "residual sd (cam0deg / cam90deg):\n")
    print("| bubble | Rmax [µm] | t_c* cam0 / cam90 | z vs PA05_bis0.03 | z vs PA10_bis0.06 |")
    print("|---|---|---|---|---|")
    fits = {}
    for key, s in summ.items():
        b = np.polyfit(s.rmax_um, s.tcs, 1)
        sd = float(np.std(s.tcs - np.polyval(b, s.rmax_um), ddof=2))
        fits[key] = (b, sd)
    for e0, e9 in zip(ours["cam0deg"], ours["cam90deg"]):
        zs = []
        for key in ("PA05_bis0.03", "PA10_bis0.06"):
            b, sd = fits[key]
            zs.append(" / ".join(f"{(e['t_collapse_star'] - np.polyval(b, e['rmax_um'])) / sd:+.1f}" for e in (e0, e9)))
        name = e0["name"].replace("_cam0deg", "")
        print(f"| {name} | {e0['rmax_um']:.1f} | {e0['t_collapse_star']:.3f} / {e9['t_collapse_star']:.3f} | "
              f"{zs[0]} | {zs[1]} |")
    fig = Figure(figsize=(10, 4), layout="constrained")
    FigureCanvasAgg(fig)
    ax1, ax2 = fig.subplots(1, 2)
    for key, color in (("PA05_bis0.03", "tab:blue"), ("PA10_bis0.06", "tab:red")):
        s = summ[key]
        ax1.plot(s.rmax_um, s.tcs, "o", ms=4, color=color, alpha=0.6, label=f"pIMR {key} (n={len(s)})")
        ax2.plot(s.rmax_um, s.Lmax_Rmax_over_Req, "o", ms=4, color=color, alpha=0.6, label=f"pIMR {key}")
    for cam, marker in (("cam0deg", "k^"), ("cam90deg", "ks")):
        ex = ours[cam]
        ax1.plot([e["rmax_um"] for e in ex], [e["t_collapse_star"] for e in ex], marker, ms=7, mfc="none",
                 label=f"ours umich_PA10 {cam}")
        ax2.plot([e["rmax_um"] for e in ex], [e["rmax_over_req"] for e in ex], marker, ms=7, mfc="none",
                 label=f"ours {cam}")
    ax1.set_xlabel("Rmax [µm]")
    ax1.set_ylabel("first-collapse time t_c*")
    ax2.set_xlabel("Rmax [µm]")
    ax2.set_ylabel("Rmax/Req")
    ax1.legend(fontsize=7)
    ax2.legend(fontsize=7)
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
    fig.savefig(FIG / "umich_vs_pimr.png", dpi=110)


def subframe_study():
    """Bias and rms of the first-collapse time from sampled Keller-Miksis curves (NHKV)."""
    try:
        from imrbayes.forward import ForwardModel
    except Exception as exc:  # forward model not available
        print(f"\n(sub-frame study skipped: {exc})")
        return
    from imrbayes.data import preprocess as pp

    fm = ForwardModel("nhkv")
    tf = np.arange(0, 3.0, 0.0005)
    print("\n## Sub-frame estimators on NHKV curves (error of t_c*, 200 random sampling phases)\n")
    print("| G [Pa], mu [Pa s], Rmax/Req | frame step h* | parabola bias / rms | sample bias / rms | "
          "Rmax time error, parabola (max) |")
    print("|---|---|---|---|---|")
    rng = np.random.default_rng(0)
    for G, mu, ratio in ((7290.0, 0.088, 7.58), (2000.0, 0.1, 7.5), (15000.0, 0.05, 6.0)):
        R = fm.simulate_radius({"G": G, "mu": mu}, rmax_m=390e-6, req_m=390e-6 / ratio, t_star=tf)
        i = int(np.argmax(np.diff(np.sign(np.diff(R))) > 0)) + 1
        truth = pp.parabola_vertex(tf[i - 1:i + 2], R[i - 1:i + 2])[0]
        t_all = np.concatenate((-tf[::-1][:-1], tf))
        R_all = np.concatenate((R[::-1][:-1], R))  # growth taken as the mirror image of the collapse
        for h in (0.025, 0.093):
            ep, es, e0 = [], [], []
            for _ in range(200):
                ts = np.arange(-0.3 + rng.uniform(0, h), 2.95, h)
                Rs = np.interp(ts, t_all, R_all)
                m = pp.locate_rmax(ts, Rs)
                ep.append(pp.first_collapse(ts, Rs, m.index).t_s - m.t_s - truth)
                es.append(pp.first_collapse(ts, Rs, m.index, "sample").t_s - m.t_s - truth)
                e0.append(abs(m.t_s))
            ep, es = np.array(ep), np.array(es)
            print(f"| {G:.0f}, {mu}, {ratio} | {h} | {ep.mean():+.4f} / {np.sqrt(np.mean(ep**2)):.4f} | "
                  f"{es.mean():+.4f} / {np.sqrt(np.mean(es**2)):.4f} | {max(e0):.1e} |")


if __name__ == "__main__":
    main()
