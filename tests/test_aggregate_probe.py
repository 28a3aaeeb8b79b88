"""validation/aggregate_probe.py's four gel-level summaries on hand-made windows: the reported
aggregate (equal-weight precision average of every window), the same over the decided windows, the
last window, and the record-level estimate, checked against scalar arithmetic."""

import importlib.util
import math
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

VALIDATION = Path(__file__).resolve().parents[1] / "validation"


def probe():
    sys.path.insert(0, str(VALIDATION))             # the probe imports camera_calibration beside it
    try:
        spec = importlib.util.spec_from_file_location("aggregate_probe", VALIDATION / "aggregate_probe.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
    finally:
        sys.path.remove(str(VALIDATION))
    return mod


def test_four_summaries_of_hand_made_windows():
    mod = probe()
    # two uncorrelated log-parameters; window 0 prior-dominated and far off, windows 1-2 decided
    m = [(math.log(9000.0), math.log(0.15)), (math.log(5500.0), math.log(0.07)), (math.log(5000.0), math.log(0.064))]
    sd = [(0.6, 0.8), (0.2, 0.1), (0.1, 0.05)]
    windows = [{"mean_internal": list(mm), "cov_internal": np.diag(np.square(ss)).tolist(), "prior_dominated": j == 0}
               for j, (mm, ss) in enumerate(zip(m, sd))]
    rec = {"G": {"mean": 5100.0, "hdi95": [4000.0, 6300.0]}, "mu": {"mean": 0.066, "hdi95": [0.06, 0.072]}}
    res = SimpleNamespace(windows=windows, details={"record_random_effects": {"estimate": rec}})
    space = SimpleNamespace(names=("G", "mu"))
    out = mod.summaries(res, space)

    def pw(idx, i):                                 # equal weights 1/J: mean = sum(m/s^2)/sum(1/s^2), var = J/sum(1/s^2)
        p = [1.0 / sd[j][i] ** 2 for j in idx]
        mean = sum(pj * m[j][i] for pj, j in zip(p, idx)) / sum(p)
        return mean, math.sqrt(len(idx) / sum(p))
    for way, idx in (("aggregate", [0, 1, 2]), ("decided_windows", [1, 2]), ("last_window", [2])):
        for i, name in enumerate(("G", "mu")):
            mean, s = pw(idx, i)
            assert out[way][name][0] == pytest.approx(math.exp(mean), rel=1e-12)
            assert out[way][name][1] == pytest.approx(math.exp(mean - 1.96 * s), rel=1e-12)
            assert out[way][name][2] == pytest.approx(math.exp(mean + 1.96 * s), rel=1e-12)
    assert out["record"]["G"] == [5100.0, 4000.0, 6300.0]
    # leaving the prior-dominated window out moves the estimate towards the decided windows
    assert out["decided_windows"]["G"][0] < out["aggregate"]["G"][0]
