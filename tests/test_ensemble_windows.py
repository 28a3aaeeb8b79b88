"""Window count, spans, MDA weights and the time-resolved weighting (methods.md §4)."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from imrbayes.ensemble.windows import coverage, mda_weights, n_windows, time_resolved, window_spans
from imrbayes.errors import InputError


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
