#!/usr/bin/env bash
# Install imrbayes into .venv and run the bundled example: the paper's verification case
# (Rmax 263 um, Rmax/Req 7.58, NHKV G = 7.29 kPa, mu = 0.088 Pa s, five experiments with the
# paper's noise), simulated, inspected (table + figure) and fitted with ensemble 4D-Var.
# The example uses the polytropic bubble so that it runs in well under a minute; drop
# `--forward bubble=polytropic` for the full thermal model (minutes per fit).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh
OUT="${1:-imrbayes-runs/example}"
rm -rf "$OUT"
.venv/bin/imrbayes simulate --model nhkv --param G=7.29e3 --param mu=0.088 --rmax 263e-6 --ratio 7.58 \
    --n-exp 5 --noise paper --seed 0 --forward bubble=polytropic --out "$OUT/data"
.venv/bin/imrbayes inspect "$OUT/data" --out "$OUT/inspect"
.venv/bin/imrbayes fit "$OUT/data" --method en4dvar --seed 0 --out "$OUT/fit"
.venv/bin/python - "$OUT" <<'PY'
import json, sys
out = sys.argv[1]
est = json.load(open(f"{out}/fit/summary.json"))["estimate"]
truth = json.load(open(f"{out}/data/truth.json"))["parameters"]
for name in ("G", "mu"):
    e = est[name]
    print(f"{name}: {e['mean']:.4g} +- {e['sd']:.2g} (95% {e['hdi95'][0]:.4g}..{e['hdi95'][1]:.4g}); truth {truth[name]:.4g}")
PY
echo "example done: $OUT/inspect/figures/radius.png, $OUT/fit/summary.json, $OUT/fit/figures/"
