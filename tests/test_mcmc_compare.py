"""Gaussian-vs-MCMC comparison: closed forms against analytic cases, a linear-Gaussian toy with a
known posterior (agreement), a shifted ensemble and a banana-shaped posterior (disagreement),
unconverged chains (undecided), and the compare.json structure."""

import json
import math

import numpy as np
import pytest
from scipy import integrate, stats

from imrbayes.mcmc.compare import (
    THRESHOLDS,
    compare_window,
    compare_windows,
    energy_distance,
    energy_shift_reference,
    gaussian_kl,
    gaussian_w2,
    knn_entropy,
    mardia,
    negentropy,
    sample_w1,
)


def test_gaussian_kl_closed_form():
    # 1-D: KL = log(s1/s0) + (s0^2 + (m0 - m1)^2) / (2 s1^2) - 1/2; checked by quadrature too
    m0, s0, m1, s1 = 0.3, 0.7, -0.2, 1.3
    exact = math.log(s1 / s0) + (s0**2 + (m0 - m1) ** 2) / (2 * s1**2) - 0.5
    p, q = stats.norm(m0, s0), stats.norm(m1, s1)
    quad, _ = integrate.quad(lambda x: p.pdf(x) * (p.logpdf(x) - q.logpdf(x)), -15, 15)
    assert gaussian_kl([m0], [[s0**2]], [m1], [[s1**2]]) == pytest.approx(exact, rel=1e-12)
    assert quad == pytest.approx(exact, rel=1e-8)
    # d-dim: invariant under an affine map; zero for equal Gaussians; asymmetric
    rng = np.random.default_rng(0)
    A = rng.normal(size=(3, 3))
    S0, S1 = A @ A.T + np.eye(3), np.diag([1.0, 2.0, 0.5])
    m0, m1 = rng.normal(size=3), rng.normal(size=3)
    T, b = rng.normal(size=(3, 3)) + 3 * np.eye(3), rng.normal(size=3)
    kl = gaussian_kl(m0, S0, m1, S1)
    assert gaussian_kl(T @ m0 + b, T @ S0 @ T.T, T @ m1 + b, T @ S1 @ T.T) == pytest.approx(kl, rel=1e-10)
    assert gaussian_kl(m0, S0, m0, S0) == pytest.approx(0.0, abs=1e-12)
    assert gaussian_kl(m1, S1, m0, S0) != pytest.approx(kl)
    # Monte Carlo check of the d-dim formula
    x = rng.multivariate_normal(m0, S0, size=400_000)
    mc = np.mean(stats.multivariate_normal(m0, S0).logpdf(x) - stats.multivariate_normal(m1, S1).logpdf(x))
    assert mc == pytest.approx(kl, rel=0.02)


def test_gaussian_w2_closed_form():
    # 1-D: W2^2 = (m0 - m1)^2 + (s0 - s1)^2; commuting covariances: per axis
    assert gaussian_w2([0.0], [[4.0]], [3.0], [[1.0]]) == pytest.approx(math.sqrt(9 + 1))
    assert gaussian_w2([0, 0], np.diag([4.0, 9.0]), [1, 1], np.diag([1.0, 1.0])) == pytest.approx(math.sqrt(2 + 1 + 4))
    rng = np.random.default_rng(1)
    A = rng.normal(size=(3, 3))
    S = A @ A.T + np.eye(3)
    assert gaussian_w2(np.zeros(3), S, np.zeros(3), S) == pytest.approx(0.0, abs=1e-6)
    # a rotation of an anisotropic Gaussian: W2^2 = tr(S0 + S1 - 2 (S1^1/2 S0 S1^1/2)^1/2); for 2-D
    # diag(a, b) vs diag(b, a): (sqrt a - sqrt b)^2 * 2
    a, b = 4.0, 1.0
    assert gaussian_w2([0, 0], np.diag([a, b]), [0, 0], np.diag([b, a])) == pytest.approx(
        math.sqrt(2 * (math.sqrt(a) - math.sqrt(b)) ** 2)
    )


def test_sample_statistics_against_known_values():
    rng = np.random.default_rng(2)
    X = rng.standard_normal((3000, 2))
    m = mardia(X)
    assert abs(m["b1"]) < 0.02 and m["b2"] == pytest.approx(8.0, abs=0.4) and m["skew_p"] > 1e-3
    # kNN entropy of a Gaussian: H = d/2 log(2 pi e) + 1/2 log det S
    S = np.array([[2.0, 0.5], [0.5, 1.0]])
    Y = rng.multivariate_normal([0, 0], S, size=4000)
    assert knn_entropy(Y) == pytest.approx(math.log(2 * math.pi * math.e) + 0.5 * math.log(np.linalg.det(S)), abs=0.05)
    assert negentropy(Y)["estimate"] < 0.05
    # energy distance: ~0 for one law, the population value for a shift
    Z = rng.standard_normal((1500, 2))
    assert abs(energy_distance(X[:1500], Z)) < 0.01
    ref = energy_shift_reference(2, 1.0)
    assert energy_distance(X[:1500], Z + [1.0, 0.0]) == pytest.approx(ref, rel=0.15)
    # sample W1 by assignment equals scipy's linear-programming wasserstein_distance_nd
    from scipy.stats import wasserstein_distance_nd

    assert sample_w1(X[:40], Z[:40] + 0.5) == pytest.approx(wasserstein_distance_nd(X[:40], Z[:40] + 0.5), rel=1e-6)


def _linear_gaussian(seed=0):
    """y = A theta + e, e ~ N(0, s^2 I), theta ~ N(m0, S0): the exact posterior N(m, S)."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(30, 2))
    m0, S0, s = np.array([1.0, -1.0]), np.diag([1.0, 0.25]), 0.5
    theta = np.array([1.4, -0.7])
    y = A @ theta + s * rng.standard_normal(30)
    P = np.linalg.inv(np.linalg.inv(S0) + A.T @ A / s**2)
    m = P @ (np.linalg.inv(S0) @ m0 + A.T @ y / s**2)
    return m, P, rng


def test_linear_gaussian_toy_agrees_and_shift_disagrees():
    m, S, rng = _linear_gaussian()
    draws = rng.multivariate_normal(m, S, size=(4, 1000))  # exact posterior, 4 "chains"
    e = compare_window(m, S, draws, ["a", "b"], [False, False], index=3, t_star=[0.1, 0.95])
    assert e["agree"] is True, e["notes"]
    assert e["kl_gauss"] < 0.01 and e["kl_gauss_reverse"] < 0.01 and e["w2"] < 0.1 and e["kl_sample"] < 0.05
    assert e["mcmc"]["converged"] and max(e["mcmc"]["rhat"].values()) < 1.01
    assert min(e["mcmc"]["ess_bulk"].values()) > 3000
    assert set(e["mcmc"]["mcse_mean"]) == {"a", "b"}
    np.testing.assert_allclose(e["ensemble"]["cov_internal"], S)
    assert e["index"] == 3 and e["t_star"] == [0.1, 0.95]
    # an ensemble mean one marginal sd off along the first axis, same covariance: in whitened
    # coordinates the shift is |r|_S = sqrt(r^T S^-1 r), so w2 = |r|_S and KL = |r|_S^2 / 2 both ways
    sd = math.sqrt(S[0, 0])
    r = np.array([sd, 0.0])
    shift = math.sqrt(r @ np.linalg.solve(S, r))
    shifted = compare_window(m + r, S, draws, ["a", "b"], [False, False])
    assert shifted["agree"] is False
    assert shifted["w2"] == pytest.approx(shift, rel=0.05)
    assert shifted["kl_sym"] == pytest.approx(0.5 * shift**2, rel=0.1)
    assert "W2" in shifted["notes"] and "Gaussian KL" in shifted["notes"]
    # an ensemble 1.6 times too wide: the covariance part alone fails
    wide = compare_window(m, 1.6**2 * S, draws, ["a", "b"], [False, False])
    assert wide["agree"] is False and not wide["criteria"]["kl_sym"]


def test_banana_posterior_is_flagged_although_moments_agree():
    """A curved posterior whose ensemble Gaussian has exactly the MCMC mean and covariance: every
    moment metric is zero, the sample-based check still fails -- the check can fail."""
    rng = np.random.default_rng(4)
    x1 = rng.standard_normal(4000)
    x2 = 0.6 * (x1**2 - 1) + 0.5 * rng.standard_normal(4000)  # negentropy 0.5 log(1 + 8 b^2)
    X = np.c_[x1, x2]
    e = compare_window(X.mean(axis=0), np.cov(X.T), X.reshape(4, 1000, 2), ["a", "b"], [False, False])
    assert e["kl_sym"] < 1e-9 and e["w2"] < 1e-6  # the Gaussian part sees nothing
    assert e["criteria"] == {"kl_sym": True, "w2": True, "kl_sample": False}
    assert e["agree"] is False
    assert e["negentropy"]["estimate"] == pytest.approx(0.5 * math.log(1 + 8 * 0.36), abs=0.1)
    assert e["mardia"]["skew_p"] < 1e-6 and "non-Gaussian" in e["notes"]
    assert e["sample_check"]["p_value"] < 0.05  # the energy test rejects too
    # the same check passes on a Gaussian sample with those moments
    G = rng.multivariate_normal(X.mean(axis=0), np.cov(X.T), size=(4, 1000))
    assert compare_window(X.mean(axis=0), np.cov(X.T), G, ["a", "b"], [False, False])["agree"] is True


def test_unconverged_chains_are_undecided_and_json(tmp_path):
    m, S, rng = _linear_gaussian(1)
    draws = rng.multivariate_normal(m, S, size=(4, 500))
    draws[0] += 3 * np.sqrt(np.diag(S))  # one chain elsewhere
    bad = compare_window(m, S, draws, ["G", "mu"], [True, True], index=1, t_star=[0.0, 0.85])
    assert bad["agree"] is None and not bad["mcmc"]["converged"]
    assert max(bad["mcmc"]["rhat"].values()) > THRESHOLDS["rhat"] and "R-hat" in bad["notes"]
    # log-parameters: SI means are log-normal moments; internal names log_G, log_mu
    assert bad["internal"] == ["log_G", "log_mu"]
    assert bad["ensemble"]["mean"]["G"] == pytest.approx(math.exp(m[0] + S[0, 0] / 2))
    good = compare_window(
        m,
        S,
        rng.multivariate_normal(m, S, size=(4, 500)),
        ["G", "mu"],
        [True, True],
        index=0,
        t_star=[0.0, 0.85],
        diagnostics={"all_tau_ok": True, "tau_rule": 50},
    )
    short = compare_window(
        m,
        S,
        rng.multivariate_normal(m, S, size=(4, 500)),
        ["G", "mu"],
        [True, True],
        diagnostics={"all_tau_ok": False, "tau_rule": 50, "n_steps_over_tau": 12.0},
    )
    assert good["agree"] is True and short["agree"] is None and "tau" in short["notes"]
    out = compare_windows([good, bad])
    text = json.dumps(out, allow_nan=False)
    back = json.loads(text)
    w = back["windows"][0]
    for key in ("index", "t_star", "ensemble", "mcmc", "kl_gauss", "w2", "agree", "notes"):
        assert key in w
    assert set(w["ensemble"]) >= {"mean", "cov"} and set(w["mcmc"]) >= {"mean", "cov", "rhat", "ess_bulk"}
    ov = back["overall"]
    assert ov["n_windows"] == 2 and ov["n_agree"] == 1 and ov["n_undecided"] == 1 and ov["all_agree"] is False
    assert "kl_sym <= 0.1" in ov["agree_rule"]
