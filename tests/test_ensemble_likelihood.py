"""The default likelihood's pieces, each against an exact answer: the random-effects layer on a
linear-Gaussian toy (coverage over many replicates), the whitening, the autocorrelation time of an
AR(1) series, and the nuisance directions of the real forward model against an independent
finite difference."""

import numpy as np
import pytest

from imrbayes.ensemble.fusion import fuse_likelihoods, likelihood_terms, random_effects
from imrbayes.ensemble.likelihood import effective_samples, observation_model, predict, whitening


def _toy(rng, tau, N=6, se=(0.05, 0.03)):
    mu = np.array([np.log(5200.0), np.log(0.065)])
    theta = mu + np.asarray(tau) * rng.standard_normal((N, 2))
    se = np.asarray(se)
    m = theta + se * rng.standard_normal((N, 2))
    Lam = np.stack([np.diag(1.0 / se**2)] * N)
    return mu, theta, Lam, np.einsum("nij,nj->ni", Lam, m)


@pytest.mark.slow
@pytest.mark.parametrize("tau", [0.15, 0.0])
def test_random_effects_covers_on_a_linear_gaussian_toy(tau):
    """Between-bubble sd interval and the gel-level mean cover the truth in most of 60 replicates;
    the predictive interval holds ~95 % of the bubbles."""
    rng = np.random.default_rng(7)
    cov_tau = cov_mu = 0
    held = []
    n = 60
    for _ in range(n):
        mu, theta, Lam, eta = _toy(rng, [tau, tau])
        r = random_effects(Lam, eta, mu + 0.3, np.eye(2))
        cov_tau += r.tau_ci[0, 0] - 1e-12 <= tau <= r.tau_ci[0, 1] + 1e-12
        cov_mu += abs(r.mean[0] - mu[0]) <= 1.96 * np.sqrt(r.cov[0, 0])
        sd = np.sqrt(r.predictive_cov[0, 0])
        held.append(np.mean(np.abs(theta[:, 0] - r.mean[0]) <= 1.96 * sd))
    assert cov_tau / n >= 0.85
    assert cov_mu / n >= 0.85
    assert 0.85 <= np.mean(held) <= 1.0


def test_random_effects_without_scatter_is_the_product_rule():
    rng = np.random.default_rng(3)
    mu, _, Lam, eta = _toy(rng, [0.0, 0.0], se=(0.2, 0.1))
    m0, C0 = mu + 0.1, np.diag([0.5, 0.4])
    r = random_effects(Lam, eta, m0, C0)
    P = np.linalg.inv(C0) + Lam.sum(axis=0)
    exact = np.linalg.solve(P, np.linalg.solve(C0, m0) + eta.sum(axis=0))
    np.testing.assert_allclose(r.pooled_mean, exact, rtol=0, atol=1e-10)
    np.testing.assert_allclose(r.pooled_cov, np.linalg.inv(P), rtol=1e-10)
    one = random_effects(Lam[:1], eta[:1], m0, C0)
    assert np.all(np.isnan(one.tau)) and one.notes  # one bubble: scatter unknown, said so


def test_likelihood_terms_recover_the_likelihood_of_a_gaussian_update():
    rng = np.random.default_rng(5)
    d = 2
    A = rng.standard_normal((d, d))
    Lam = A @ A.T + np.eye(d)
    m = rng.standard_normal(d)
    q, Q = np.zeros(d), np.diag([2.0, 3.0])
    S = np.linalg.inv(np.linalg.inv(Q) + Lam)
    post = S @ (np.linalg.solve(Q, q) + Lam @ m)
    L, eta, centre, clipped = likelihood_terms(post[None], S[None], q[None], Q[None], ridge=0.0)
    np.testing.assert_allclose(L[0], Lam, rtol=1e-9)
    np.testing.assert_allclose(centre[0], m, rtol=1e-8)
    f = fuse_likelihoods(post[None], S[None], q[None], Q[None], q, Q)
    np.testing.assert_allclose(f.mean, post, rtol=1e-9)
    assert clipped == 0


def test_whitening_is_the_inverse_square_root():
    rng = np.random.default_rng(1)
    U = rng.standard_normal((40, 3)) * 0.05
    var, alpha = 4e-4, 0.4
    W = whitening(var, U, alpha)
    R = var * np.eye(40) + U @ U.T
    np.testing.assert_allclose(W @ R @ W.T, alpha * np.eye(40), atol=1e-10)
    np.testing.assert_allclose(W, W.T, atol=1e-14)


def test_effective_samples_of_ar1_series():
    rng = np.random.default_rng(11)
    rho, n = 0.5, 4000
    x = np.empty(n)
    x[0] = rng.standard_normal()
    for k in range(1, n):
        x[k] = rho * x[k - 1] + np.sqrt(1 - rho**2) * rng.standard_normal()
    n_eff, tau = effective_samples(x)
    assert tau == pytest.approx((1 + rho) / (1 - rho), rel=0.2)
    _, tau_white = effective_samples(rng.standard_normal(n))
    assert tau_white == pytest.approx(1.0, abs=0.2)


def test_nuisance_prediction_is_the_true_geometry_seen_on_the_data_clock():
    """y_k = (1 + a) R*(|t_k - delta| / (1 + a)) for Rmax (1 + a), Req e^rho: checked against direct
    runs with that geometry (and, before the maximum, the mirror image)."""
    from imrbayes.forward import ForwardModel

    fm = ForwardModel("nhkv", options={"bubble": "polytropic"})
    theta, rmax, req = np.array([5e3, 0.06]), 3e-4, 3e-4 / 8
    t = np.linspace(0.025, 2.0, 30)
    nu = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.04, 0.0], [0.0, 0.0, 0.05]])
    R, failed = predict(fm, np.tile(theta, (4, 1)), rmax, req, t, nu)
    assert not failed.any()
    plain = fm.simulate(theta[None], [rmax], [req], t).R_star[0]
    np.testing.assert_allclose(R[0], plain, atol=1e-9)
    big = fm.simulate(theta[None], [rmax * 1.01], [req], t / 1.01).R_star[0] * 1.01
    np.testing.assert_allclose(R[1], big, atol=1e-7)  # a batch ends at its latest output time: last-step rounding
    shifted = np.abs(t - 0.04)
    order = np.argsort(shifted)
    direct = np.empty_like(t)
    direct[order] = fm.simulate(theta[None], [rmax], [req], shifted[order]).R_star[0]
    np.testing.assert_allclose(R[2], direct, atol=1e-9)
    mirror, _ = predict(fm, theta[None], rmax, req, np.array([0.03, 0.05]), nu[2:3])
    assert mirror[0, 0] == pytest.approx(mirror[0, 1], abs=1e-6)  # either side of the maximum at 0.04
    wide = fm.simulate(theta[None], [rmax], [req * np.exp(0.05)], t).R_star[0]
    np.testing.assert_allclose(R[3], wide, atol=1e-9)


def test_observation_model_raises_the_noise_to_the_residual_and_tempers():
    rng = np.random.default_rng(2)
    y = rng.standard_normal(400) * 0.02
    white = observation_model(y, np.zeros(400), 0.02**2)
    assert white["alpha"] == pytest.approx(1.0, abs=0.25) and white["sd_used"] == pytest.approx(0.02, rel=0.1)
    smooth = np.convolve(rng.standard_normal(420), np.ones(8) / np.sqrt(8), mode="valid")[:400] * 0.05
    red = observation_model(smooth, np.zeros(400), 0.02**2)
    assert red["sd_used"] > 0.04 and red["alpha"] < 0.4  # model error: louder and fewer independent samples
    cold = observation_model(smooth, np.zeros(400), 0.02**2, adapt=False)
    assert cold["alpha"] == 1.0 and cold["sd_used"] == pytest.approx(0.02)


def test_member_whose_req_reaches_rmax_fails_instead_of_raising():
    """A wide Req prior (an unsettled tail) can draw a member with Req >= Rmax: that member fails
    (the ensemble drops it), the others are untouched."""
    from imrbayes.forward import ForwardModel

    fm = ForwardModel("nhkv", options={"bubble": "polytropic"})
    theta, rmax, req = np.array([5e3, 0.06]), 3e-4, 3e-4 / 2
    t = np.linspace(0.025, 1.0, 10)
    nu = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, np.log(2.5)]])
    R, failed = predict(fm, np.tile(theta, (2, 1)), rmax, req, t, nu)
    assert failed.tolist() == [False, True]
    np.testing.assert_allclose(R[0], fm.simulate(theta[None], [rmax], [req], t).R_star[0], atol=1e-9)


@pytest.mark.slow
def test_predictive_with_the_scatters_uncertainty_holds_a_new_bubble():
    """Linear-Gaussian toy, 6 bubbles with 15 % scatter: a *new* bubble lies in the 95 % predictive
    interval at about the nominal rate once tau's uncertainty is integrated; the plug-in
    N(mu_hat, cov + tau_hat^2) holds it less often (tau_hat from six bubbles is biased low)."""
    rng = np.random.default_rng(11)
    n, N, tau, se = 120, 6, 0.15, 0.08
    plug = marg = 0
    for _ in range(n):
        mu, theta, Lam, eta = _toy(rng, [tau, tau], se=(se, se), N=N)
        r = random_effects(Lam, eta, mu + 0.3, np.eye(2), intervals=False)
        new = mu[0] + tau * rng.standard_normal()
        plug += abs(new - r.mean[0]) <= 1.96 * np.sqrt(r.cov[0, 0] + r.tau[0] ** 2)
        marg += abs(new - r.mean[0]) <= 1.96 * np.sqrt(r.predictive_cov[0, 0])
        assert r.predictive_cov[0, 0] >= r.cov[0, 0] + r.tau[0] ** 2 - 1e-15
    assert marg / n >= 0.90
    assert marg / n - plug / n >= 0.03
