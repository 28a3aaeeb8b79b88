"""The aggregate's covariance propagated through the window chain (imrbayes.ensemble.aggregate),
checked against exact linear-Gaussian truth: a chain of windows whose gel-level means are the
random-effects update with the chained, RTPS-relaxed prior, and the aggregate their normalised
precision-weighted average."""

import numpy as np

from imrbayes.ensemble.aggregate import chain_aggregate_cov
from imrbayes.ensemble.gaussian import precision_weighted
from imrbayes.ensemble.mienks import rtps_cov


def _chain(rng, J, G, d, T, rtps, S0):
    """Window likelihood precisions (J, G, d, d) and the chain's deterministic pieces."""
    Lam = np.empty((J, G, d, d))
    for j in range(J):
        for g in range(G):
            A = rng.standard_normal((d, d))
            Lam[j, g] = A @ A.T + 0.5 * np.eye(d)
    F, D, L, C = [], [], [], []
    prior_c = S0.copy()
    for j in range(J):
        P = np.linalg.inv(prior_c)
        A = [np.linalg.inv(np.linalg.inv(Lam[j, g]) + T) for g in range(G)]
        cov = np.linalg.inv(P + sum(A))
        F.append(cov @ P)
        D.append({g: cov @ np.linalg.inv(np.eye(d) + Lam[j, g] @ T) for g in range(G)})
        L.append({g: Lam[j, g] for g in range(G)})
        C.append(cov)
        prior_c = rtps_cov(prior_c, cov, rtps)
    return Lam, F, D, L, np.array(C)


def _simulate(rng, z, Lam, F, D, C, T, S0, n):
    """n draws of the aggregate mean under the module's model (prior mean, bubbles, noise drawn)."""
    J, G, d = Lam.shape[0], Lam.shape[1], z.size
    out = np.empty((n, d))
    for k in range(n):
        m = rng.multivariate_normal(z, S0)
        u = rng.multivariate_normal(np.zeros(d), T, size=G) if T.any() else np.zeros((G, d))
        means = []
        for j in range(J):
            eta = [Lam[j, g] @ (z + u[g]) + rng.multivariate_normal(np.zeros(d), Lam[j, g]) for g in range(G)]
            m = F[j] @ m + sum(D[j][g] @ eta[g] for g in range(G))
            means.append(m)
        out[k] = precision_weighted(np.array(means), C)[0]
    return out


def test_no_inflation_no_scatter_last_window_is_the_posterior():
    rng = np.random.default_rng(3)
    d, S0 = 2, np.diag([0.5, 0.8])
    Lam, F, D, L, C = _chain(rng, J=6, G=3, d=d, T=np.zeros((d, d)), rtps=0.0, S0=S0)
    Q = np.zeros((6, d, d))
    Q[-1] = np.eye(d)
    got = chain_aggregate_cov(F, D, L, Q, S0)
    # the last window of an uninflated chain is the posterior of all the data: its covariance
    post = np.linalg.inv(np.linalg.inv(S0) + Lam.sum(axis=(0, 1)))
    np.testing.assert_allclose(got, post, rtol=1e-10)
    np.testing.assert_allclose(C[-1], post, rtol=1e-10)


def test_matches_monte_carlo_with_rtps_and_scatter():
    rng = np.random.default_rng(11)
    d, J, G = 2, 8, 4
    S0, T = np.diag([0.6, 0.9]), np.diag([0.05, 0.02])
    Lam, F, D, L, C = _chain(rng, J, G, d, T, rtps=0.7, S0=S0)
    agg_c = precision_weighted(np.zeros((J, d)), C)[1]
    Q = np.stack([agg_c @ np.linalg.inv(c) / J for c in C])
    got = chain_aggregate_cov(F, D, L, Q, S0, T)
    draws = _simulate(rng, np.array([0.3, -0.2]), Lam, F, D, C, T, S0, 2000)
    emp = np.cov(draws.T)
    # 2000 draws: a variance's relative Monte-Carlo sd is sqrt(2/2000) = 3.2 %
    np.testing.assert_allclose(np.diag(emp), np.diag(got), rtol=0.12)
    assert abs(emp[0, 1] - got[0, 1]) < 0.1 * np.sqrt(got[0, 0] * got[1, 1])
    # the estimator is unbiased (weights on the truth sum to the identity)
    assert np.all(np.abs(draws.mean(axis=0) - [0.3, -0.2]) < 4 * np.sqrt(np.diag(got) / 2000))
    # and its variance is well below what the normalised precision weighting states
    assert np.all(np.diag(got) < 0.6 * np.diag(agg_c))


def test_window_mean_is_the_linear_map_fit_mienks_records():
    """fit_mienks records F = C P and D_g = C (I + Lambda_g T)^-1 per window: with them the
    random-effects gel mean (tau estimated from the data) is exactly F m_prior + sum_g D_g eta_g."""
    from imrbayes.ensemble.fusion import random_effects

    rng = np.random.default_rng(5)
    d, G = 2, 6
    Lam = np.empty((G, d, d))
    for g in range(G):
        A = rng.standard_normal((d, d))
        Lam[g] = 40.0 * (A @ A.T + 0.5 * np.eye(d))
    theta = np.array([0.2, -0.1]) + 0.3 * rng.standard_normal((G, d))  # real scatter: tau > 0
    eta = np.stack([Lam[g] @ theta[g] + rng.multivariate_normal(np.zeros(d), Lam[g]) for g in range(G)])
    prior_m, prior_c = np.array([0.0, 0.3]), np.diag([0.8, 0.5])
    hier = random_effects(Lam, eta, prior_m, prior_c, intervals=False)
    assert np.all(hier.tau > 0)
    T = np.diag(hier.tau**2)
    F = hier.cov @ np.linalg.inv(prior_c)
    D = [hier.cov @ np.linalg.inv(np.eye(d) + Lam[g] @ T) for g in range(G)]
    np.testing.assert_allclose(F @ prior_m + sum(D[g] @ eta[g] for g in range(G)), hier.mean, rtol=1e-9, atol=1e-12)
