"""validation/record_estimate_rescore.py: the log-normal moments are inverted exactly, and a
predictive interval holds the bubbles it should (checked against scipy's log-normal quantiles)."""

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
from scipy import stats

from imrbayes.ensemble.gaussian import marginal_summary

VALIDATION = Path(__file__).resolve().parents[1] / "validation"


def rescore():
    sys.path.insert(0, str(VALIDATION))             # it imports camera_calibration beside it
    try:
        spec = importlib.util.spec_from_file_location("record_estimate_rescore", VALIDATION / "record_estimate_rescore.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
    finally:
        sys.path.remove(str(VALIDATION))
    return mod


def test_log_moments_invert_the_marginal_summary():
    mod = rescore()
    for m, s in ((math.log(5200.0), 0.12), (math.log(0.065), 0.4), (0.0, 1e-3)):
        est = marginal_summary(m, s, True)
        m2, s2 = mod.log_moments(est)
        assert abs(m2 - m) < 1e-12 and abs(s2 - s) < 1e-9


def test_predictive_holds_counts_bubbles_inside_the_widened_interval():
    mod = rescore()
    m, s, tau = math.log(5000.0), 0.1, 0.15
    est = marginal_summary(m, s, True)
    sd = math.hypot(s, tau)
    lo, hi = marginal_summary(m, sd, True)["hdi95"]
    # the HDI of a log-normal holds 95 % of it
    dist = stats.lognorm(sd, scale=math.exp(m))
    assert abs(dist.cdf(hi) - dist.cdf(lo) - 0.95) < 1e-6
    truths = np.array([lo * 0.99, lo * 1.01, math.exp(m), hi * 0.99, hi * 1.01])
    assert mod.predictive_holds(est, tau, truths) == 3 / 5
    # no scatter: the interval is the estimate's own
    lo0, hi0 = est["hdi95"]
    assert mod.predictive_holds(est, 0.0, np.array([lo0 * 1.001, hi0 * 1.001])) == 0.5
