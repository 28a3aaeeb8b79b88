"""The ensemble layer's algebra and bookkeeping: Gaussian algebra, ensemble-space Gauss-Newton,
the default likelihood, windows, the method registry, posterior.nc, the leave-one-bubble-out
check and the aggregate's window chain."""

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy import stats
from scipy.stats import binomtest

from imrbayes.ensemble import METHODS, InferenceMethod, Observations
from imrbayes.ensemble.aggregate import chain_aggregate_cov
from imrbayes.ensemble.fusion import fuse, fuse_likelihoods, leave_one_out, likelihood_terms, random_effects
from imrbayes.ensemble.gaussian import draw, marginal_summary, precision_weighted, rtps, rtps_factors
from imrbayes.ensemble.gn import gauss_newton, linearise
from imrbayes.ensemble.likelihood import effective_samples, observation_model, predict, whitening
from imrbayes.ensemble.mienks import rtps_cov
from imrbayes.ensemble.output import write_posterior
from imrbayes.ensemble.problem import ParamSpace
from imrbayes.ensemble.result import FitResult
from imrbayes.ensemble.windows import coverage, mda_weights, n_windows, time_resolved, window_spans
from imrbayes.errors import InputError
from imrbayes.forward import get_model

# Gaussian algebra against hand-computed linear-Gaussian cases (exact answers known).


def _posterior(m0, S0, H, R, y):
    """Exact linear-Gaussian posterior of theta given y = H theta + e, e ~ N(0, R)."""
    P = np.linalg.inv(np.linalg.inv(S0) + H.T @ np.linalg.solve(R, H))
    return P @ (np.linalg.solve(S0, m0) + H.T @ np.linalg.solve(R, y)), P


def test_fusion_equals_joint_posterior():
    rng = np.random.default_rng(3)
    m0 = np.array([1.0, -0.5])
    S0 = np.array([[2.0, 0.3], [0.3, 0.5]])
    means, covs, Hs, Rs, ys = [], [], [], [], []
    for _n in range(4):
        H = rng.normal(size=(3, 2))
        R = np.diag(rng.uniform(0.1, 1.0, 3))
        y = rng.normal(size=3)
        m, P = _posterior(m0, S0, H, R, y)
        means.append(m), covs.append(P), Hs.append(H), Rs.append(R), ys.append(y)
    # the joint posterior given every experiment (shared prior, independent noise)
    from scipy.linalg import block_diag

    mj, Pj = _posterior(m0, S0, np.vstack(Hs), block_diag(*Rs), np.concatenate(ys))
    f = fuse(np.array(means), np.array(covs), m0, S0)
    assert f.c == 1.0 and f.pd and not f.notes
    np.testing.assert_allclose(f.mean, mj, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(f.cov, Pj, rtol=1e-10, atol=1e-12)


def test_fusion_single_experiment_is_identity():
    m, P = np.array([0.2, 0.1]), np.array([[0.3, 0.05], [0.05, 0.2]])
    f = fuse(m[None], P[None], np.zeros(2), np.eye(2))
    np.testing.assert_allclose(f.mean, m)
    np.testing.assert_allclose(f.cov, P)


def test_fusion_guard_reports_non_positive_definite():
    # three "posteriors" wider than the prior: sum S_n^-1 - 2 S0^-1 = 3 * 0.5 - 2 < 0
    S0 = np.eye(2)
    covs = np.stack([2.0 * np.eye(2)] * 3)
    f = fuse(np.zeros((3, 2)), covs, np.zeros(2), S0)
    assert not f.pd and f.c < 1.0 and f.notes
    assert np.all(np.linalg.eigvalsh(f.cov) > 0)
    # c is the largest value keeping the precision positive: 1.5 - 2c > 0 -> c < 0.75
    assert f.c == pytest.approx(0.75, rel=1e-4)


def test_rtps_hand_computed_and_keeps_correlation():
    rng = np.random.default_rng(0)
    prior = rng.normal(size=(200, 2)) * [2.0, 0.5]
    C = np.array([[1.0, 0.8], [0.8, 1.0]])
    post = rng.normal(size=(200, 2)) @ np.linalg.cholesky(C).T * [0.2, 0.1]
    post -= post.mean(axis=0)
    prior -= prior.mean(axis=0)
    a = 0.7
    out = rtps(prior, post, a)
    sp, sa = prior.std(axis=0), post.std(axis=0)
    np.testing.assert_allclose(out.std(axis=0), sa + a * (sp - sa), rtol=1e-12)
    np.testing.assert_allclose(np.corrcoef(out.T), np.corrcoef(post.T), atol=1e-12)
    # a = 0 leaves the posterior alone, a = 1 restores the prior spread
    np.testing.assert_allclose(rtps(prior, post, 0.0), post)
    np.testing.assert_allclose(rtps(prior, post, 1.0).std(axis=0), sp)
    # a component without posterior spread is left alone (no division by zero)
    f = rtps_factors(prior, np.column_stack([post[:, 0], np.zeros(200)]), a)
    assert f[1] == 1.0


def test_precision_weighted_does_not_overcount():
    m, P = np.array([1.0, 2.0]), np.array([[0.5, 0.1], [0.1, 0.3]])
    mean, cov = precision_weighted(np.stack([m] * 5), np.stack([P] * 5))
    np.testing.assert_allclose(mean, m)
    np.testing.assert_allclose(cov, P)
    # two windows, hand-computed 1-D case: precision (1/1 + 1/4)/2, mean weighted 1:1/4
    mean, cov = precision_weighted(np.array([[0.0], [5.0]]), np.array([[[1.0]], [[4.0]]]))
    assert cov[0, 0] == pytest.approx(1.0 / ((1.0 + 0.25) / 2))
    assert mean[0] == pytest.approx((0.0 * 1.0 + 5.0 * 0.25) / 1.25)


def test_draw_exact_moments():
    rng = np.random.default_rng(1)
    mean, cov = np.array([1.0, -2.0]), np.array([[0.4, -0.1], [-0.1, 0.2]])
    x = draw(rng, mean, cov, 48)
    np.testing.assert_allclose(x.mean(axis=0), mean, atol=1e-12)
    np.testing.assert_allclose(np.cov(x, rowvar=False), cov, atol=1e-12)


def test_lognormal_summary():
    m, s = math.log(7000.0), 0.2
    out = marginal_summary(m, s, log=True)
    assert out["mean"] == pytest.approx(math.exp(m + s * s / 2))
    assert out["sd"] == pytest.approx(out["mean"] * math.sqrt(math.expm1(s * s)))
    lo, hi = out["hdi95"]
    mass = stats.norm.cdf((math.log(hi) - m) / s) - stats.norm.cdf((math.log(lo) - m) / s)
    assert mass == pytest.approx(0.95, abs=1e-6)
    eti = np.exp(m + s * stats.norm.ppf([0.025, 0.975]))
    assert hi - lo < eti[1] - eti[0]
    g = marginal_summary(1.0, 0.5, log=False)
    assert g["hdi95"] == pytest.approx([1.0 - 1.959964 * 0.5, 1.0 + 1.959964 * 0.5], rel=1e-6)


def test_paper_prior_moment_matched():
    sp = ParamSpace.for_model(get_model("nhkv"))
    assert sp.names == ("G", "mu") and sp.positive.all()
    for i, (mean, sd) in enumerate([(6e3, 2.8e3), (0.209, 0.088)]):
        m, v = sp.prior_mean[i], sp.prior_cov[i, i]
        assert math.exp(m + v / 2) == pytest.approx(mean)
        assert math.exp(m + v / 2) * math.sqrt(math.expm1(v)) == pytest.approx(sd)
    assert sp.prior_cov[0, 1] == 0.0
    np.testing.assert_allclose(sp.to_si(sp.to_internal([7.29e3, 0.088])), [7.29e3, 0.088])


def test_fuse_likelihoods_exact_with_other_priors():
    """Posteriors computed from different priors (restarts, windows): dividing each by its own
    prior and multiplying the likelihoods into the shared prior gives the joint posterior."""
    from imrbayes.ensemble.fusion import fuse_likelihoods

    rng = np.random.default_rng(5)
    m0, S0 = np.array([0.3, -0.2]), np.array([[1.5, 0.2], [0.2, 0.7]])
    post_m, post_c, q_m, q_c, Ls, bs = [], [], [], [], [], []
    for _ in range(4):
        H = rng.normal(size=(3, 2))
        Rinv = np.diag(1.0 / rng.uniform(0.2, 1.0, 3))
        y = rng.normal(size=3)
        L, b = H.T @ Rinv @ H, H.T @ Rinv @ y
        A = rng.normal(size=(2, 2))
        Q = A @ A.T + 0.3 * np.eye(2)  # this experiment's own prior
        q = rng.normal(size=2)
        C = np.linalg.inv(np.linalg.inv(Q) + L)
        post_m.append(C @ (np.linalg.solve(Q, q) + b)), post_c.append(C), q_m.append(q), q_c.append(Q)
        Ls.append(L), bs.append(b)
    Cj = np.linalg.inv(np.linalg.inv(S0) + sum(Ls))
    mj = Cj @ (np.linalg.solve(S0, m0) + sum(bs))
    f = fuse_likelihoods(np.array(post_m), np.array(post_c), np.array(q_m), np.array(q_c), m0, S0)
    np.testing.assert_allclose(f.mean, mj, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(f.cov, Cj, rtol=1e-9, atol=1e-12)
    # with the shared prior as every experiment's prior it is the prior-corrected product rule
    shared = [np.linalg.inv(np.linalg.inv(S0) + L) for L in Ls]
    sm = [C @ (np.linalg.solve(S0, m0) + b) for C, b in zip(shared, bs)]
    f1 = fuse_likelihoods(np.array(sm), np.array(shared), np.tile(m0, (4, 1)), np.stack([S0] * 4), m0, S0)
    f2 = fuse(np.array(sm), np.array(shared), m0, S0)
    np.testing.assert_allclose(f1.mean, f2.mean, rtol=1e-9)
    np.testing.assert_allclose(f1.cov, f2.cov, rtol=1e-9)


def test_integrate_out_trailing_and_the_reference_prior_give_the_marginal_likelihood():
    """A linear-Gaussian model y = H x + e, x = (z, a, r) (2 + 2 + 1 coordinates), analysed under a
    *correlated, data-informed* prior Q (what En4D-Var's last cycle has). (1) r integrated out
    against N(0, s^2) and a against Q's conditional given z (``marginal_under_reference``, swap r)
    is the likelihood of y given z with a ~ Q(a | z), r ~ N(0, s^2) -- computed here in closed
    form; (2) swapping every nuisance equals the Schur complement of the joint likelihood against
    N(0, diag(s^2)) (``integrate_out_trailing``), and both differ from the ratio of the z marginals."""
    from imrbayes.ensemble.fusion import integrate_out_trailing, likelihood_terms, marginal_under_reference

    rng = np.random.default_rng(3)
    d, m = 5, 9
    H = rng.standard_normal((m, d))
    Rn = np.diag(rng.uniform(0.5, 2.0, m))
    y = rng.standard_normal(m)
    s = np.array([0.4, 0.7, 1.5])  # prior sds of a (2) and r (1)
    Lam, eta = H.T @ np.linalg.solve(Rn, H), H.T @ np.linalg.solve(Rn, y)
    A = rng.standard_normal((d, d))
    Q = A @ A.T + np.eye(d)
    q = rng.standard_normal(d)
    P = np.linalg.inv(np.linalg.inv(Q) + Lam)
    p = P @ (np.linalg.solve(Q, q) + eta)

    def info(pm, pc, qm, qc):
        Si, Qi = np.linalg.inv(pc), np.linalg.inv(qc)
        return Si - Qi, Si @ pm - Qi @ qm

    # (1) r swapped: a | z from Q, r from N(0, s_r^2)
    z, a_, r_ = slice(0, 2), slice(2, 4), slice(4, 5)
    K = Q[a_, z] @ np.linalg.inv(Q[z, z])
    Ca = Q[a_, a_] - K @ Q[z, a_]
    Hp = H[:, z] + H[:, a_] @ K
    yp = y - H[:, a_] @ (q[a_] - K @ q[z])
    Sig = Rn + H[:, a_] @ Ca @ H[:, a_].T + s[2] ** 2 * H[:, r_] @ H[:, r_].T
    L_ref, e_ref = Hp.T @ np.linalg.solve(Sig, Hp), Hp.T @ np.linalg.solve(Sig, yp)
    L1, e1 = info(*marginal_under_reference(p, P, q, Q, 2, {4: s[2]}))
    assert np.allclose(L1, L_ref, atol=1e-9) and np.allclose(e1, e_ref, atol=1e-9)
    # (2) every nuisance swapped: the Schur complement against N(0, diag(s^2)), itself checked
    Hz, Hn = H[:, z], H[:, 2:]
    Sig0 = Rn + Hn @ np.diag(s**2) @ Hn.T
    L0, e0 = Hz.T @ np.linalg.solve(Sig0, Hz), Hz.T @ np.linalg.solve(Sig0, y)
    Lj, ej, _, _ = likelihood_terms(p[None], P[None], q[None], Q[None], ridge=0.0)
    Lt, et = integrate_out_trailing(Lj[0], ej[0], s)
    assert np.allclose(Lt, L0, atol=1e-9) and np.allclose(et, e0, atol=1e-9)
    L2, e2 = info(*marginal_under_reference(p, P, q, Q, 2, {2: s[0], 3: s[1], 4: s[2]}))
    assert np.allclose(L2, L0, atol=1e-9) and np.allclose(e2, e0, atol=1e-9)
    # the marginals' ratio integrates every nuisance against Q's conditional: neither of the above
    Lm, _ = info(p[z], P[z, z], q[z], Q[z, z])
    assert not np.allclose(Lm, L0, rtol=0.05) and not np.allclose(Lm, L_ref, rtol=0.05)


def test_likelihood_terms_do_not_depend_on_the_units_of_a_coordinate():
    """The likelihood recovered from (posterior, prior) is the same whatever unit a coordinate is
    stated in: with a third parameter in seconds (prior sd 5e-7 s, a Zener's retardation time) its
    centre is the scaled copy of the one in microseconds. A ridge sized by the largest prior
    precision (1e-9 x 4e12) swamped the other coordinates and put their centre near 0 (G = 1 Pa on
    real data) -- the test fails on that version."""
    from imrbayes.ensemble.fusion import likelihood_terms

    rng = np.random.default_rng(4)
    q, Q = np.array([8.6, -1.6, 0.0]), np.diag([0.2, 0.16, 0.25])  # the third in us
    A = rng.standard_normal((3, 3))
    Lam0 = A @ A.T * 20.0 + np.eye(3)
    m0 = q + rng.standard_normal(3) * 0.3
    S = np.linalg.inv(np.linalg.inv(Q) + Lam0)
    p = S @ (np.linalg.solve(Q, q) + Lam0 @ m0)
    _, _, centre_us, _ = likelihood_terms(p[None], S[None], q[None], Q[None])
    np.testing.assert_allclose(centre_us[0], m0, rtol=1e-6, atol=1e-8)
    D = np.diag([1.0, 1.0, 1e-6])  # the same in s
    _, _, centre_s, _ = likelihood_terms((D @ p)[None], (D @ S @ D)[None], (D @ q)[None], (D @ Q @ D)[None])
    np.testing.assert_allclose(centre_s[0], D @ m0, rtol=1e-6, atol=1e-14)


def test_a_zero_default_parameter_gets_its_own_prior_scale():
    """A Zener-family retardation time (default 0) gets the prior 0 +- 0.5 us, not 0 +- 1 s (with
    which every member of `fit --model zener` failed on stiff PA)."""
    for name in ("zener", "qzener", "maxwell", "oldroyd-b"):
        sp = ParamSpace.for_model(get_model(name))
        i = sp.names.index("lambda2")
        assert not sp.positive[i] and sp.prior_mean[i] == 0.0
        assert math.sqrt(sp.prior_cov[i, i]) == pytest.approx(5e-7)
    sp = ParamSpace.for_model(get_model("carreau"))  # no scale given: 1 SI unit
    assert math.sqrt(sp.prior_cov[sp.names.index("mu_inf")][sp.names.index("mu_inf")]) == pytest.approx(1.0)


# Ensemble-space Gauss–Newton against the exact linear-Gaussian posterior.


def _linear_problem(seed=0, d=2, m=30, G=3):
    rng = np.random.default_rng(seed)
    M = rng.normal(size=(G, m, d))
    truth = np.array([0.5, -1.0, 0.3][:d])
    P = rng.uniform(0.05, 0.2, m)
    c = np.full(m, 1.0 / m)  # 1/N_t averaging as in methods.md
    y = np.einsum("gmd,d->gm", M, truth) + rng.normal(size=(G, m)) * np.sqrt(P)
    m0, S0 = np.zeros(d), np.diag(np.full(d, 0.8))
    return rng, M, P, c, y, m0, S0


def _exact(M, P, c, y, m0, S0):
    W = c / P
    prec = np.linalg.inv(S0) + M.T @ (W[:, None] * M)
    cov = np.linalg.inv(prec)
    return cov @ (np.linalg.solve(S0, m0) + M.T @ (W * y)), cov


@pytest.mark.parametrize("transform", [True, False])
@pytest.mark.parametrize("project", [True, False])
def test_linear_gaussian_exact(transform, project):
    rng, M, P, c, y, m0, S0 = _linear_problem()
    G, N = M.shape[0], 20
    E0 = np.stack([draw(rng, m0, S0, N) for _ in range(G)])  # exact prior sample moments
    calls = []

    def evaluate(groups, Z):
        calls.append(len(groups))
        return np.einsum("kmd,kd->km", M[groups], Z), np.zeros(len(groups), dtype=bool)

    res = gauss_newton(E0, evaluate, y, c / P, n_iter=3, transform=transform, project=project)
    assert calls == [G * N] * 3  # one batch per iteration
    for g in range(G):
        mean, cov = _exact(M[g], P, c, y[g], m0, S0)
        np.testing.assert_allclose(res.mean[g], mean, rtol=1e-8, atol=1e-10)
        np.testing.assert_allclose(res.cov[g], cov, rtol=1e-8, atol=1e-12)
        np.testing.assert_allclose(res.ensemble[g].mean(axis=0), mean, atol=1e-10)
        np.testing.assert_allclose(np.cov(res.ensemble[g], rowvar=False), cov, rtol=1e-8, atol=1e-12)
    assert np.all(np.diff(res.cost, axis=1) <= 1e-9)


def test_failed_prior_members_are_redrawn():
    rng, M, P, c, y, m0, S0 = _linear_problem(seed=1, G=1)
    E0 = draw(rng, m0, S0, 24)[None]
    E0[0, :3] = 50.0  # three members the "model" cannot run

    def evaluate(groups, Z):
        bad = np.abs(Z[:, 0]) > 10.0
        Y = np.einsum("kmd,kd->km", M[groups], Z)
        Y[bad] = np.nan
        return Y, bad

    res = gauss_newton(E0, evaluate, y, c / P, n_iter=3, rng=np.random.default_rng(0))
    assert res.n_redrawn[0] == 3
    assert res.n_failed[0].sum() == 0
    assert np.all(np.abs(res.prior_ensemble[0, :3, 0]) < 10.0)
    assert np.all(np.isfinite(res.mean))


def test_linearise_regression_handles_failures_and_nonlinearity():
    rng = np.random.default_rng(2)
    N, d = 30, 2
    A = rng.normal(size=(N, d))
    A -= A.mean(axis=0)
    A /= np.sqrt(N - 1.0)
    S = rng.normal(size=(d, 5))
    Yhat = 3.0 + np.sqrt(N - 1.0) * A @ S + 0.01 * rng.normal(size=(N, 5))
    ok = np.ones(N, dtype=bool)
    ok[[4, 9]] = False
    Yhat[~ok] = np.nan
    ybar, Yp = linearise(A, Yhat, ok, np.sqrt(N - 1.0))
    assert np.all(np.isfinite(Yp)) and np.all(np.isfinite(ybar))
    np.testing.assert_allclose(Yp, A @ S, atol=0.01)
    np.testing.assert_allclose(ybar, 3.0, atol=0.01)
    # the sensitivities lie in the span of the anomalies: w along the null space has no effect
    assert np.linalg.matrix_rank(Yp, tol=1e-10) <= d


@pytest.mark.parametrize("N", [7, 24, 48])
def test_exact_for_any_ensemble_size_above_the_state_dimension(N):
    # En4D-Var's state: two material parameters and three nuisances (d = 5); its default 24
    # members (the paper's 48) rest on this: with exact prior moments the linear-Gaussian posterior
    # does not depend on N once N > d + 1
    rng, M, P, c, y, m0, S0 = _linear_problem(seed=3, d=3, m=40, G=2)
    M = np.concatenate([M, rng.normal(size=(2, 40, 2))], axis=2)
    m0, S0 = np.zeros(5), np.diag([0.8, 0.5, 0.3, 0.2, 0.1])
    E0 = np.stack([draw(rng, m0, S0, N) for _ in range(2)])

    def evaluate(groups, Z):
        return np.einsum("kmd,kd->km", M[groups], Z), np.zeros(len(groups), dtype=bool)

    res = gauss_newton(E0, evaluate, y, c / P, n_iter=3)
    for g in range(2):
        mean, cov = _exact(M[g], P, c, y[g], m0, S0)
        np.testing.assert_allclose(res.mean[g], mean, rtol=1e-8, atol=1e-10)
        np.testing.assert_allclose(res.cov[g], cov, rtol=1e-8, atol=1e-12)


def test_a_mildly_nonlinear_posterior_hardly_depends_on_the_ensemble_size():
    # y = exp(M z): the regression averages the Jacobian over the (posterior-sized, transform
    # variant) ensemble, so N moves the answer only through that average. Across draws, 24
    # members must sit where 48 do, within a tenth of a posterior sd, with the same spread
    # (measured: 24 members 0.061 sd at most, 48 0.055, 12 0.086, 7 0.109)
    rng = np.random.default_rng(11)
    d, m = 5, 20
    M = rng.normal(size=(m, d))
    truth = rng.normal(size=d) * 0.5
    P = np.full(m, 0.3**2)
    y = np.exp(M @ truth) + rng.normal(size=m) * 0.3
    m0, S0 = np.zeros(d), np.eye(d) * 0.5**2

    def evaluate(groups, Z):
        return np.exp(Z @ M.T), np.zeros(len(groups), dtype=bool)

    def fit(N, seed):
        r = np.random.default_rng(seed)
        E0 = draw(r, m0, S0, N)[None]
        res = gauss_newton(E0, evaluate, y[None], (1.0 / P)[None], n_iter=8, rng=r)
        return res.mean[0], res.cov[0]

    ref = [fit(48, s) for s in range(8)]
    half = [fit(24, s) for s in range(100, 108)]
    sd = np.sqrt(np.diag(ref[0][1]))
    ref_mean = np.mean([m_ for m_, _ in ref], axis=0)
    for m_, C in half:
        assert np.all(np.abs(m_ - ref_mean) / sd < 0.1)
        np.testing.assert_allclose(np.sqrt(np.diag(C)), sd, rtol=0.1)
    # and not trivially: the posterior is far narrower than the prior and away from its mean
    assert np.all(sd < 0.25 * 0.5) and np.any(np.abs(ref_mean) / sd > 3)


def _counted_linear(seed):
    """A linear problem, its prior ensembles and an evaluate that logs each batch's size."""
    rng, M, P, c, y, m0, S0 = _linear_problem(seed=seed)
    G, N = M.shape[0], 20
    E0 = np.stack([draw(rng, m0, S0, N) for _ in range(G)])
    calls = []

    def evaluate(groups, Z):
        calls.append(len(groups))
        return np.einsum("kmd,kd->km", M[groups], Z), np.zeros(len(groups), dtype=bool)

    return E0, evaluate, calls, (M, P, c, y, m0, S0)


def _exp_problem():
    """y = exp(M z) for six groups, the prior far from the optimum (several falling iterations)."""
    rng = np.random.default_rng(5)
    d, m, G = 3, 25, 6
    M = rng.normal(size=(G, m, d)) * 0.7
    truth = rng.normal(size=(G, d)) * 0.8
    y = np.exp(np.einsum("gmd,gd->gm", M, truth)) + rng.normal(size=(G, m)) * 0.05
    E0 = np.stack([draw(rng, np.zeros(d), np.eye(d), 24) for _ in range(G)])

    def evaluate(groups, Z):
        return np.exp(np.einsum("kmd,kd->km", M[groups], Z)), np.zeros(len(groups), dtype=bool)

    return E0, evaluate, y, np.full(m, 1 / 0.05**2)


def _assert_exact(res, problem):
    M, P, c, y, m0, S0 = problem
    for g in range(M.shape[0]):
        mean, cov = _exact(M[g], P, c, y[g], m0, S0)
        np.testing.assert_allclose(res.mean[g], mean, rtol=1e-8, atol=1e-10)
        np.testing.assert_allclose(res.cov[g], cov, rtol=1e-8, atol=1e-12)


def test_min_iter_stops_a_converged_group_early_with_the_same_posterior():
    # linear: the first Gauss-Newton step lands on the optimum (evaluation 1: the cost falls), the
    # next repeats its cost, so with min_iter=2 every group stops after three of its five
    # evaluations, with the exact posterior
    E0, evaluate, calls, problem = _counted_linear(3)
    res = gauss_newton(E0, evaluate, problem[3], problem[2] / problem[1], n_iter=5, min_iter=2)
    assert calls == [E0.shape[0] * E0.shape[1]] * 3
    assert np.all(np.isnan(res.cost[:, 3:])) and np.all(np.isfinite(res.cost[:, :3]))
    _assert_exact(res, problem)


def test_min_iter_on_a_nonlinear_posterior_stops_only_once_the_cost_settles():
    # the cost falls over several iterations, so a group may not stop at min_iter; where it stops,
    # the posterior is the fully iterated one to a hundredth of its sd, and every group's
    # evaluations lie between min_iter and n_iter
    E0, evaluate, y, W = _exp_problem()
    G = E0.shape[0]
    full = gauss_newton(E0, evaluate, y, W, n_iter=10)
    early = gauss_newton(E0, evaluate, y, W, n_iter=10, min_iter=3)
    n_eval = np.sum(np.isfinite(early.cost), axis=1)
    assert np.all((n_eval >= 3) & (n_eval <= 10)) and n_eval.sum() < 10 * G and n_eval.max() > 3
    for g in range(G):
        sd = np.sqrt(np.diag(full.cov[g]))
        assert np.all(np.abs(early.mean[g] - full.mean[g]) / sd < 0.01)
        np.testing.assert_allclose(np.sqrt(np.diag(early.cov[g])), sd, rtol=0.01)


def test_step_tol_stops_once_the_next_step_is_shorter_than_a_fraction_of_an_sd():
    # linear: after the first step (evaluation 1, at the optimum) the next step is zero, so with
    # step_tol the group stops there, one evaluation before the cost rule would, exactly right
    E0, evaluate, calls, problem = _counted_linear(4)
    res = gauss_newton(E0, evaluate, problem[3], problem[2] / problem[1], n_iter=5, min_iter=2, step_tol=0.1)
    assert calls == [E0.shape[0] * E0.shape[1]] * 2
    _assert_exact(res, problem)
    # nonlinear: stopped where the next step is under 0.05 sd, the posterior mean lies within
    # 0.05 sd of the fully iterated one, with fewer evaluations
    E0, evaluate, y, W = _exp_problem()
    full = gauss_newton(E0, evaluate, y, W, n_iter=10)
    early = gauss_newton(E0, evaluate, y, W, n_iter=10, min_iter=2, step_tol=0.05)
    assert np.sum(np.isfinite(early.cost)) < np.sum(np.isfinite(full.cost))
    for g in range(E0.shape[0]):
        sd = np.sqrt(np.diag(full.cov[g]))
        assert np.all(np.abs(early.mean[g] - full.mean[g]) / sd < 0.05)


def test_a_step_into_failing_parameters_is_halved_not_the_end():
    """y = exp(x) observed at x = 1 (tiny noise), the model failing beyond x = 1.5, the prior
    N(0, 0.1^2) widened by the data: the first Gauss-Newton step from x ~ 0 (linearised slope 1)
    lands near 1.7, where every member fails. Before: the group stopped there with the prior as
    its answer. Now the step is halved like a cost increase and the iterations reach x = 1."""
    rng = np.random.default_rng(3)
    N, m = 16, 5
    E0 = draw(rng, np.zeros(1), np.array([[0.01]]), N)[None]
    y = np.full((1, m), np.e)

    def evaluate(groups, Z):
        bad = Z[:, 0] > 1.5
        Y = np.repeat(np.exp(Z[:, :1]), m, axis=1)
        Y[bad] = np.nan
        return Y, bad

    res = gauss_newton(E0, evaluate, y, np.full(m, 1e4), n_iter=5, rng=rng, max_iter=15)
    assert res.n_failed[0, 1] == N  # the full first step failed
    assert not res.stopped[0] and res.n_backtracked[0] >= 1
    assert abs(res.mean[0, 0] - 1.0) < 1e-3, res.mean
    old = gauss_newton(E0, evaluate, y, np.full(m, 1e4), n_iter=5, rng=rng, max_iter=15, backtrack=False)
    assert old.stopped[0] and abs(old.mean[0, 0] - 1.0) > 0.1  # the old behaviour: stopped, far away


# The default likelihood's pieces, each against an exact answer: the random-effects layer on a
# linear-Gaussian toy (coverage over many replicates), the whitening, the autocorrelation time of an
# AR(1) series, and the nuisance directions of the real forward model against an independent
# finite difference.


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


# Window count, spans, MDA weights and the time-resolved weighting (methods.md §4).


@pytest.mark.parametrize("L,h,expected", [(35, 5, 18), (30, 3, 31), (35, 1, 87)])
def test_paper_window_counts(L, h, expected):
    assert n_windows(120, L, h) == expected
    spans = window_spans(120, L, h)
    assert spans.shape == (expected, 2)
    assert spans[0, 0] == 0 and spans[-1, 1] <= 120
    assert np.all(spans[:, 1] - spans[:, 0] == L - 1)
    assert np.all(np.diff(spans[:, 0]) == h)
    # one more window would run past the record
    assert spans[-1, 0] + h + L - 1 > 120


@given(st.integers(10, 200), st.integers(2, 60), st.integers(1, 20))
@settings(max_examples=200, deadline=None)
def test_formula_and_mda_weights(n_steps, L, h):
    if L > n_steps + 1:
        with pytest.raises(InputError):
            n_windows(n_steps, L, h)
        return
    nw = n_windows(n_steps, L, h)
    assert nw == (n_steps - L + 1) // h + 1
    # brute force: every start j*h whose window ends inside the record
    assert nw == sum(1 for j in range(n_steps + 1) if j * h + L - 1 <= n_steps)
    beta = mda_weights(n_steps, L, h)
    cov = coverage(n_steps, L, h)
    total = beta.sum(axis=0)
    np.testing.assert_allclose(total[cov.any(axis=0)], 1.0, rtol=0, atol=1e-12)
    assert np.all(total[~cov.any(axis=0)] == 0.0)
    assert np.all(beta[~cov] == 0.0)


def test_time_resolved_weights():
    # three windows of length 4, shift 2, over 8 steps (9 samples): sample 2 lies in windows 0 and 1
    means = np.array([[0.0], [2.0], [4.0]])
    covs = np.array([[[1.0]], [[0.5]], [[0.25]]])
    m, c, covered = time_resolved(means, covs, 8, 4, 2)
    assert covered.tolist() == [True] * 8 + [False]
    assert np.isnan(m[8]).all()
    np.testing.assert_allclose(m[0], 0.0)
    np.testing.assert_allclose(c[0], 1.0)
    prec = 0.5 * (1.0 + 2.0)
    np.testing.assert_allclose(c[2, 0, 0], 1.0 / prec)
    np.testing.assert_allclose(m[2, 0], (0.5 * 1.0 * 0.0 + 0.5 * 2.0 * 2.0) / prec)


def test_bad_windows():
    with pytest.raises(InputError):
        n_windows(120, 1, 5)
    with pytest.raises(InputError):
        n_windows(120, 35, 0)
    with pytest.raises(InputError):
        n_windows(20, 35, 5)


def test_chained_prior_weight_is_the_prior_means_exact_share_in_a_linear_gaussian_chain():
    """Three chained Gaussian updates of a 2-parameter state with direct observations y_j ~ N(theta,
    R_j) (each window's prior = the previous posterior, inflated as RTPS would): the posterior mean
    is linear in the parameter prior's mean, and its derivative is the product of C_post C_prior^-1
    that :func:`chained_prior_weight` accumulates -- checked by moving the prior mean."""
    from imrbayes.ensemble.windows import chained_prior_weight

    rng = np.random.default_rng(3)
    P0 = np.array([[1.0, 0.3], [0.3, 2.0]])
    Rs = [np.diag([0.5, 4.0]), np.diag([0.2, 1.0]), np.diag([1.0, 0.3])]
    ys = [rng.normal(size=2) for _ in Rs]

    def run(m0):
        m, P, infl = m0, P0, np.eye(2)
        for y, R in zip(ys, Rs):
            C = np.linalg.inv(np.linalg.inv(P) + np.linalg.inv(R))
            m_new = C @ (np.linalg.solve(P, m) + np.linalg.solve(R, y))
            infl = chained_prior_weight(infl, C, P)
            m, P = m_new, 1.5 * C  # the next window's prior: this posterior, inflated
        return m, infl

    m_a, infl = run(np.zeros(2))
    for e in np.eye(2):
        m_b, _ = run(e)
        assert np.allclose(m_b - m_a, infl @ e, atol=1e-12)
    assert np.all(np.diag(infl) > 0) and np.all(np.diag(infl) < 1)


# The inference-method protocol: every registered method declares what the CLI, the report and
# the MCMC layer ask of it, and those ask the registry, not the method's name.


def test_every_method_declares_the_protocol():
    assert list(METHODS) == ["imr", "pimr", "en4dvar", "mienks"]
    for name, m in METHODS.items():
        assert issubclass(m, InferenceMethod) and m.name == name and m.label
        assert dataclasses.is_dataclass(m.settings_class) and callable(m.fit)
        assert m.n_forward_runs(m.settings_class(), 3, 120) > 0
    assert {m.name for m in METHODS.values() if m.gaussian_posterior} == {"en4dvar", "mienks"}
    paper = METHODS["en4dvar"].settings_class(likelihood="paper")
    assert METHODS["en4dvar"].n_forward_runs(paper, 2, 120) == 3 * 5 * 48 * 2 + 4 + 96
    # the default likelihood adds one run per experiment per cycle (the residual at the centre) and the
    # screened start (the prior mean and 96 draws per experiment; at most one more start in cycle 1)
    # (and 24 members, not the paper's 48; at least 3 iterations in cycles 2-3, not 5)
    e4 = METHODS["en4dvar"].settings_class
    assert (
        METHODS["en4dvar"].n_forward_runs(e4(req_tail="mean"), 2, 120)
        == (5 + 2 * 3) * 24 * 2 + 4 + 96 + 6 + (97 + 5 * 24 + 2) * 2
    )
    # auto (thermal: inline): the model's tail after cycle 1
    assert (
        METHODS["en4dvar"].n_forward_runs(e4(), 2, 120)
        == (5 + 2 * 3) * 24 * 2 + 4 + 96 + 6 + (97 + 5 * 24 + 2) * 2 + 3 * 2
    )
    assert (
        METHODS["en4dvar"].n_forward_runs(e4(n_ens=48, n_iter_later=5, req_tail="mean"), 2, 120)
        == 3 * 5 * 48 * 2 + 4 + 96 + 6 + (97 + 5 * 48 + 2) * 2
    )
    assert e4().resolved().n_ens == 24 and e4(likelihood="paper").resolved().n_ens == 48
    assert e4(n_ens=12, likelihood="paper").resolved().n_ens == 12
    assert e4().resolved().n_iter_later == 3 and e4(likelihood="paper").resolved().n_iter_later == 5
    assert e4(n_iter=2).resolved().n_iter_later == 2 and e4(n_iter_later=5).resolved().n_iter_later == 5
    with pytest.raises(InputError, match="n_ens"):
        e4(n_ens=0).check()
    cls = METHODS["mienks"].settings_class  # default likelihood: a pilot pass, then the reported one
    # the default likelihood: the pilot (24 members) and the reported pass (48); an upper bound,
    # windows whose cost settles stop before n_iter (min_iter)
    assert METHODS["mienks"].n_forward_runs(cls(), 2, 120) == 18 * 6 * (48 + 24) * 2
    assert METHODS["mienks"].n_forward_runs(cls(pilot_n_ens=None), 2, 120) == 2 * 18 * 6 * 48 * 2
    assert METHODS["mienks"].n_forward_runs(cls(likelihood="paper"), 2, 120) == 18 * 6 * 48 * 2


def test_cli_choices_come_from_the_registry():
    from imrbayes.cli.fit import fit_cmd

    opt = next(p for p in fit_cmd.params if p.name == "method")
    assert list(opt.type.choices) == list(METHODS)


def test_mcmc_refuses_a_method_without_gaussian_posterior():
    from imrbayes.ensemble import FitResult
    from imrbayes.mcmc.fit import fit_window_specs

    res = FitResult("imr", "nhkv", ("G", "mu"), {}, None, None)
    with pytest.raises(InputError, match="en4dvar or mienks"):
        fit_window_specs(None, None, None, res)


# posterior.nc (``imrbayes.ensemble.output.posterior_tree``): every coordinate of a FitResult, the
# tuple ones (``(dims, values)``, e.g. MIEnKS's ``window_start``) included, survives netCDF.


def _windowed_result(n_win=4, n_draw=5):
    """A hand-made time-resolved result shaped like ``fit_mienks``'s."""
    rng = np.random.default_rng(0)
    t = np.arange(41) * 0.025
    starts = t[np.arange(n_win) * 10]
    return (
        FitResult(
            method="mienks",
            model="nhkv",
            param_names=("G", "mu"),
            estimate={},
            fitted=np.zeros((2, t.size)),
            fit_mask=np.ones((2, t.size), bool),
            posterior={"G": rng.normal(size=(1, n_draw, n_win)), "mu": rng.normal(size=(1, n_draw, n_win))},
            posterior_dims={"G": ["window"], "mu": ["window"]},
            coords={
                "window": np.arange(n_win),
                "bound": ["lower", "upper"],
                "window_start": ("window", starts),
                "window_span": (("window", "bound"), np.stack([starts, starts + 0.5], axis=1)),
            },
        ),
        t,
        starts,
    )


def test_tuple_coordinates_round_trip_through_posterior_nc(tmp_path):
    import xarray as xr

    res, t, starts = _windowed_result()
    obs = Observations(
        t, np.ones((2, t.size)), np.full(t.size, 1e-4), np.full(2, 300e-6), np.full(2, 40e-6), names=["a", "b"]
    )
    path = write_posterior(tmp_path / "posterior.nc", res, obs)
    post = xr.open_datatree(path)["posterior"]
    assert post["window_start"].dims == ("window",)
    np.testing.assert_array_equal(post["window_start"].values, starts)
    assert post["window_span"].dims == ("window", "bound")
    np.testing.assert_array_equal(post["window_span"].values[:, 1], starts + 0.5)
    assert list(post["bound"].values) == ["lower", "upper"]
    assert post["G"].dims == ("chain", "draw", "window")
    import arviz as az

    s = az.summary(az.from_netcdf(path), kind="stats", round_to="none")  # ArviZ still reads it
    assert np.all(np.isfinite(s["mean"]))


# Leave-one-bubble-out check of the random-effects predictive (ensemble.fusion.leave_one_out)
# on per-bubble Gaussian likelihoods drawn from a known gel: the bubbles' own estimates fall in the
# others' 95 % predictive about 95 % of the time, and a bubble from another gel is flagged.


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


# The aggregate's covariance propagated through the window chain (imrbayes.ensemble.aggregate),
# checked against exact linear-Gaussian truth: a chain of windows whose gel-level means are the
# random-effects update with the chained, RTPS-relaxed prior, and the aggregate their normalised
# precision-weighted average.


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
