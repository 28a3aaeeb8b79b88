#!/usr/bin/env bash
# Install imrbayes into .venv and run the bundled example: the paper's verification case
# (Rmax 263 um, Rmax/Req 7.58, NHKV G = 7.29 kPa, mu = 0.088 Pa s, five experiments with the
# paper's noise), simulated with the full forward model, then inspected (table + figure).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh
OUT="${1:-imrbayes-runs/example}"
rm -rf "$OUT"
.venv/bin/imrbayes simulate --model nhkv --param G=7.29e3 --param mu=0.088 --rmax 263e-6 --ratio 7.58 \
    --n-exp 5 --noise paper --seed 0 --out "$OUT/data"
.venv/bin/imrbayes inspect "$OUT/data" --out "$OUT/inspect"
echo "example done: data in $OUT/data (truth.json holds the true parameters), figure $OUT/inspect/figures/radius.png"
