#!/usr/bin/env bash
# Stiff PA (20 bubbles): standard IMR (grid least squares, 61 x 38, per-bubble optima), one of
# IMR v1's choices at a time (docs/results.md, "2a''"). Run from the repository root; ~45 min on
# 2 cores, with the virtual environment active (. .venv/bin/activate). Writes /tmp/s19/of_<variant>/
# and the table of collect.py.
set -euo pipefail
mkdir -p /tmp/s19
python docs/results/estrada2018_stiffPA/onefactor/make_variants.py
D=../shared/data/lic/estrada2018_stiffPA_270kfps
G="--set n_G=61 --set n_mu=38"
run() { name=$1; shift; imrbayes fit "$@" --method imr --model nhkv $G --seed 0 --out /tmp/s19/of_$name --force; }
run base $D
run v1const /tmp/s19/pa_v1const            # rho 998.2, S 0.056, kappa 1.4 together
run rho /tmp/s19/pa_rho
run S /tmp/s19/pa_S
run kappa /tmp/s19/pa_kappa
run v1req /tmp/s19/pa_v1req                # Req = median of frames 62-101 (IMR v1)
run win3 $D --set window=collapse:2        # through the second collapse (IMR v1: before the third)
run poly $D --forward bubble=polytropic    # the bubble model
run rtol3 $D --forward rtol=1e-3 --forward atol=1e-6
run v1all_win3 /tmp/s19/pa_v1all --set window=collapse:2
python docs/results/estrada2018_stiffPA/onefactor/v1cost.py ours $D     # IMR v1's cost, box and frames
python docs/results/estrada2018_stiffPA/onefactor/rmax_sample.py        # Rmax from the largest sample
python docs/results/estrada2018_stiffPA/onefactor/collect.py docs/results/estrada2018_stiffPA/onefactor/onefactor_20261125.json
