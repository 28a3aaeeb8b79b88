"""The calibration script's statistics (validation/calibration.py)."""

import importlib.util
from pathlib import Path

import numpy as np
from scipy import stats

_spec = importlib.util.spec_from_file_location("calibration", Path(__file__).resolve().parents[1] / "validation" / "calibration.py")
calibration = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(calibration)


def test_wilson_interval_matches_scipy():
    for k, n in ((18, 20), (0, 30), (30, 30), (540, 600)):
        ci = stats.binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
        np.testing.assert_allclose(calibration.wilson(k, n), (ci.low, ci.high), atol=1e-6)


def test_summary_counts_intervals_and_windows():
    rows = [{"seed": s, "en4dvar": {"G": s % 2 == 0, "mu": True}, "mienks": {"G": True, "mu": s != 1},
             "imr": {"G": False, "mu": True}, "mienks_windows": {"G": [True, True, s != 2], "mu": [True] * 3}}
            for s in range(4)]
    out = calibration.summarise(rows)
    assert out["en4dvar:G"]["covered"] == 2 and out["en4dvar:G"]["n"] == 4
    assert out["mienks:mu"]["coverage"] == 0.75 and out["imr:G"]["coverage"] == 0.0
    w = out["mienks_windows:G"]
    assert (w["covered"], w["n"], w["seeds_with_at_least_90pct"]) == (11, 12, 3)
    assert abs(w["per_seed_min"] - 2 / 3) < 1e-12
