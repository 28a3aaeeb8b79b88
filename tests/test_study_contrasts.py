"""The study's differences and trends against closed-form truth on synthetic Gaussian posteriors
(no forward runs): with independent log-normal posteriors, a ratio's log is Gaussian with the
difference of the means and the sum of the variances, and a least-squares slope is Gaussian with
weights (x - mean x) / Sxx."""

import math

import numpy as np
import pytest
from scipy import stats

from imrbayes.study.analysis import N_DRAWS, conclusion, condition_draws, differences, trends
from imrbayes.study.results import ConditionResult, log_gaussian

Z = stats.norm.ppf(0.975)


def _cond(name, x, log_g, sd_g, log_mu, sd_mu, described=None):
    return ConditionResult(
        name,
        {"concentration": f"{x} %"},
        method="en4dvar",
        params=("G", "mu"),
        log_mean=np.array([log_g, log_mu]),
        log_cov=np.diag([sd_g**2, sd_mu**2]),
        described=described,
    )


def test_ratio_matches_closed_form():
    a, b = (
        _cond("a", 5, math.log(9000), 0.10, math.log(0.05), 0.20),
        _cond("b", 0.5, math.log(3000), 0.15, math.log(0.06), 0.25),
    )
    d = differences([b, a], condition_draws([b, a], seed=3))
    assert len(d) == 1 and (d[0]["a"], d[0]["b"]) == ("a", "b")
    s = math.hypot(0.10, 0.15)
    g = d[0]["G"]
    assert g["ratio"] == pytest.approx(3.0, rel=0.01)
    assert g["interval"] == pytest.approx([3 * math.exp(-Z * s), 3 * math.exp(Z * s)], rel=0.02)
    assert g["p_greater"] == pytest.approx(stats.norm.cdf(math.log(3) / s), abs=1e-3)
    s_mu = math.hypot(0.20, 0.25)
    p_true = stats.norm.cdf(math.log(0.05 / 0.06) / s_mu)
    se = math.sqrt(p_true * (1 - p_true) / N_DRAWS)  # Monte Carlo error of a probability
    assert d[0]["mu"]["p_greater"] == pytest.approx(p_true, abs=4 * se)


def test_trend_matches_closed_form():
    x = np.array([0.5, 1.0, 2.0, 5.0])
    sd = np.array([0.1, 0.2, 0.1, 0.3])
    slope = 0.3
    conds = [_cond(f"c{i}", xi, 8.0 + slope * xi, s, -3.0, s) for i, (xi, s) in enumerate(zip(x, sd))]
    t = trends(conds, condition_draws(conds, seed=0), {"concentration": "%"})
    assert len(t) == 1 and t[0]["unit"] == "%"
    w = (x - x.mean()) / np.sum((x - x.mean()) ** 2)
    s_slope = math.sqrt(np.sum(w**2 * sd**2))
    g, mu = t[0]["G"], t[0]["mu"]
    assert g["slope"] == pytest.approx(slope, abs=5 * s_slope / math.sqrt(N_DRAWS))  # Monte Carlo error
    assert g["interval"] == pytest.approx([slope - Z * s_slope, slope + Z * s_slope], abs=0.03 * s_slope)
    assert g["p_positive"] == pytest.approx(stats.norm.cdf(slope / s_slope), abs=1e-3)
    assert g["factor_over_range"] == pytest.approx(math.exp(slope * 4.5), rel=0.02)
    assert mu["interval"][0] < 0 < mu["interval"][1]
    lines = conclusion(conds, differences(conds, condition_draws(conds, seed=0)), t)
    assert lines[0].startswith("G rises with concentration: 5 % / 0.5 % = ")
    assert "mu does not differ detectably along concentration" in lines[0]


def test_conclusion_puts_the_fit_check_first():
    conds = [_cond("a", 1, 8.0, 0.1, -3, 0.1, described=False), _cond("b", 2, 8.0, 0.1, -3, 0.1, described=True)]
    lines = conclusion(
        conds,
        differences(conds, condition_draws(conds, 0)),
        trends(conds, condition_draws(conds, 0), {"concentration": "%"}),
    )
    assert lines[0].startswith("The model does not describe the records of a:")
    assert "G does not differ detectably" in lines[1]


def test_log_gaussian_from_interval_when_no_random_effects():
    med, lo, hi = 5000.0, 4000.0, 6250.0  # a log-symmetric 95 % interval: sd = ln(1.25) / 1.96
    names, m, c = log_gaussian({"parameters": ["G"], "estimate": {"G": {"median": med, "hdi95": [lo, hi]}}})
    assert names == ["G"] and m[0] == pytest.approx(math.log(med))
    assert math.sqrt(c[0, 0]) == pytest.approx(math.log(1.25) / Z)
    assert log_gaussian({"parameters": ["G"], "estimate": {"G": {"median": 0.0, "hdi95": [0.0, 10.0]}}}) is None
