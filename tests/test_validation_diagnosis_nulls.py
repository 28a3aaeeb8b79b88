"""validation/diagnosis_nulls.py's bookkeeping (the nulls themselves are the lead's full run):
the design grid, the best gain read from a diagnosis, and the summary's false alarms and percentile."""

import math

import numpy as np
import pytest

from validation import diagnosis_nulls as dn


def test_grid_covers_every_noise_shape_frame_rate_and_bubble():
    cells = dn.grid()
    assert len(cells) == len(set(cells)) == 18
    assert {c[0] for c in cells} == {"0.01", "0.02R", "0.01C"}
    assert {c[1] for c in cells} == {"270kfps", "1Mfps", "2Mfps"} and {c[2] for c in cells} == {"polytropic", "thermal"}


def test_best_gain_of_a_diagnosis():
    r = {"naming": {"best_candidate": "qkv", "best_gain": 0.005, "combined_z": 0.5}}
    assert dn.best_of(r) == ("qkv", 0.005, 0.5)
    assert dn.best_of({"naming": {"best_candidate": None, "best_gain": None}})[1] == 0.0
    older = {
        "candidates": [
            {"key": "zener", "rank": 2, "score": 0.2, "consistent": True},
            {"key": "qkv", "rank": 1, "score": 0.1, "consistent": True, "combined_vs_baseline": {"z": 1.5}},
            {"key": "damage", "rank": 3, "score": 0.5, "consistent": False},
        ]
    }
    assert dn.best_of(older) == ("qkv", 0.1, 1.5)
    key, gain, z = dn.best_of({"candidates": []})
    assert key is None and gain == 0.0 and math.isnan(z)


def test_summary_counts_named_causes_and_the_gain_percentile():
    gains = np.linspace(0.0, 0.19, 20)
    rows = [
        {"status": "ok", "named": i == 3, "verdict": "inadequate" if i < 5 else "adequate", "best_gain": g}
        for i, g in enumerate(gains)
    ] + [{"status": "error", "error": "x"}]
    s = dn.summary(rows)
    assert s["nulls"] == 20 and s["causes_named"] == 1 and s["inadequate"] == 5
    assert s["false_alarm_rate"] == pytest.approx(0.05)
    lo, hi = s["false_alarm_wilson95"]
    assert lo < 0.05 < hi and hi == pytest.approx(0.236, abs=0.002)  # Wilson, 1 of 20
    assert s["best_gain_q95"] == pytest.approx(0.1805)  # linear interpolation, 19 * 0.95
    assert s["best_gain_max"] == pytest.approx(0.19)
