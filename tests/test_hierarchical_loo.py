"""Leave-one-bubble-out check of the random-effects predictive (ensemble.fusion.leave_one_out)
on per-bubble Gaussian likelihoods drawn from a known gel: the bubbles' own estimates fall in the
others' 95 % predictive about 95 % of the time, and a bubble from another gel is flagged."""

import numpy as np
import pytest
from scipy.stats import binomtest

from imrbayes.ensemble.fusion import leave_one_out


def _bubbles(rng, n, mu, tau, se):
    """Each bubble's likelihood (precision, information) around a noisy reading of its own theta."""
    d = mu.size
    theta = mu + tau * rng.standard_normal((n, d))
    m = theta + se * rng.standard_normal((n, d))
    Lam = np.repeat(np.diag(1.0 / se**2)[None], n, axis=0)
    eta = np.einsum("nij,nj->ni", Lam, m)
    return Lam, eta


@pytest.mark.slow
def test_coverage_on_a_known_gel():
    rng = np.random.default_rng(7)
    mu, tau, se = np.array([9.0, -2.3]), np.array([0.2, 0.3]), np.array([0.08, 0.1])
    prior_mean, prior_cov = np.array([9.0, -2.0]), np.diag([1.0, 1.0])
    k, n = np.zeros(2, int), 0
    for _ in range(4):
        Lam, eta = _bubbles(rng, 20, mu, tau, se)
        r = leave_one_out(Lam, eta, prior_mean, prior_cov, names=["G", "mu"])
        k += np.array([r["n_inside"]["G"], r["n_inside"]["mu"]])
        n += r["n"]
    for ki in k:  # 80 bubbles per parameter: the nominal 95 % inside the Wilson interval
        ci = binomtest(int(ki), n).proportion_ci(method="wilson")
        assert ci.low <= 0.95 <= ci.high + 0.03, (k, n)


def test_a_bubble_of_another_gel_is_outside():
    rng = np.random.default_rng(3)
    mu, tau, se = np.array([9.0, -2.3]), np.array([0.1, 0.1]), np.array([0.05, 0.05])
    Lam, eta = _bubbles(rng, 12, mu, tau, se)
    eta[5] = Lam[5] @ (mu + np.array([1.5, 0.0]))  # G e^1.5 = 4.5x the gel's, 15 tau away
    r = leave_one_out(Lam, eta, np.array([9.0, -2.0]), np.diag([1.0, 1.0]), names=["G", "mu"])
    assert not r["inside"][5][0] and r["z"][5][0] > 5
    assert r["inside"][5][1]
    assert leave_one_out(Lam[:2], eta[:2], np.zeros(2), np.eye(2)) is None
