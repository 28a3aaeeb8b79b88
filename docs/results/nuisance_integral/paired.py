"""Paired comparison of two camera_calibration.py result files on their common seeds: python paired.py ref=REF.json NEW.json [NEW2.json ...]."""
import json, sys, numpy as np
REF = sys.argv.pop(1) if sys.argv[1].startswith("ref=") else "ref=validation/results/camera_thermal_later3_patience_60seeds_20261130.json"
ref = {r["seed"]: r["default"] for r in json.load(open(REF[4:]))["rows"]}
rows = []
for f in sys.argv[1:]:
    rows += json.load(open(f))["rows"]
new = {r["seed"]: r["default"] for r in rows}
seeds = sorted(set(new) & set(ref))
print(len(seeds), "seeds")
for k in ("G", "mu"):
    sh = np.array([(new[s][k]["mean"] - ref[s][k]["mean"]) / ref[s][k]["sd"] for s in seeds])
    sdr = np.array([new[s][k]["sd"] / ref[s][k]["sd"] for s in seeds])
    cov_n = sum(new[s][k]["covers"] for s in seeds); cov_r = sum(ref[s][k]["covers"] for s in seeds)
    bias_n = np.mean([new[s][k]["rel_error"] for s in seeds]); bias_r = np.mean([ref[s][k]["rel_error"] for s in seeds])
    print(f"{k}: shift mean {sh.mean():+.3f} (SE {sh.std(ddof=1)/np.sqrt(len(sh)):.3f}) |shift| mean {np.abs(sh).mean():.3f} max {np.abs(sh).max():.2f} (seed {seeds[int(np.argmax(np.abs(sh)))]}); sd ratio {sdr.mean():.3f}; covered {cov_n} vs {cov_r}; bias {bias_n*100:+.1f} vs {bias_r*100:+.1f} %")
    flips = [s for s in seeds if new[s][k]["covers"] != ref[s][k]["covers"]]
    print("   flips", flips)
rt_n = np.array([new[s]["runtime_s"] for s in seeds]); rt_r = np.array([ref[s]["runtime_s"] for s in seeds])
print(f"runtime median {np.median(rt_n):.0f} vs {np.median(rt_r):.0f} s; ratio median {np.median(rt_n/rt_r):.3f}, total ratio {rt_n.sum()/rt_r.sum():.3f}")
