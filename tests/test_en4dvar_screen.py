"""The screened start of En4D-Var's first cycle (``En4DVarSettings.screen``)."""

import numpy as np
import pytest

from imrbayes.ensemble.en4dvar import En4DVarSettings, screened_start
from imrbayes.errors import InputError


def double_well(groups, Z):
    """h(z) = 10 (z0^2 - 1)^2 with y = 0: two equal optima at z0 = +-1, the prior mean 0 between."""
    return 10.0 * (Z[:, :1] ** 2 - 1.0) ** 2, np.zeros(len(Z), bool)


def test_screen_leaves_the_basin_of_the_prior_mean():
    rng = np.random.default_rng(3)
    centre, info = screened_start(rng, double_well, np.zeros(1), np.zeros(2), np.eye(2), 64)
    assert info["moved"] and info["n"] == 64
    assert info["cost_prior_mean"] == pytest.approx(50.0)  # 1/2 * 10^2, prior term 0
    assert info["cost_best"] < 2.0
    assert abs(abs(centre[0]) - 1.0) < 0.25


def test_screen_keeps_the_prior_mean_when_it_is_best_and_skips_failed_members():
    def bowl(groups, Z):
        failed = Z[:, 0] > 0.5  # some draws fail: never chosen
        Y = np.where(failed[:, None], 0.0, 5.0 * Z[:, :1])
        return Y, failed

    centre, info = screened_start(np.random.default_rng(0), bowl, np.zeros(1), np.array([0.0, 0.0]), np.eye(2), 32)
    assert not info["moved"]
    np.testing.assert_array_equal(centre, [0.0, 0.0])


def test_screen_setting_is_checked():
    with pytest.raises(InputError):
        En4DVarSettings(screen=-1).check()


def test_posterior_cost_and_take_group():
    from imrbayes.ensemble.en4dvar import posterior_cost, take_group
    from imrbayes.ensemble.gn import gauss_newton

    Z = np.array([[0.0, 0.0], [1.0, 0.5], [2.0, 0.0]])
    J = posterior_cost(double_well, np.zeros(1), Z, np.zeros(2), np.eye(2))
    np.testing.assert_allclose(J, [50.0, 0.5 * (1.0 + 0.25), 0.5 * 90.0**2 + 2.0])

    def linear(groups, Z):  # y = 2 z0, two groups with their own data
        return 2.0 * Z[:, :1], np.zeros(len(Z), bool)

    rng = np.random.default_rng(1)
    E0 = rng.normal(size=(2, 12, 2))
    res = gauss_newton(E0, linear, np.array([[1.0], [-1.0]]), np.ones((2, 1)), n_iter=3, rng=rng)
    one = take_group(res, 1)
    assert one.mean.shape == (1, 2) and one.cov.shape == (1, 2, 2) and one.ensemble.shape == (1, 12, 2)
    np.testing.assert_array_equal(one.mean[0], res.mean[1])
    np.testing.assert_array_equal(one.prior_anoms[0], res.prior_anoms[1])


def test_gauss_newton_iterates_to_convergence_past_n_iter():
    """A stiff exponential model (data 1e-3 noise) that five iterations leave short of the optimum:
    with ``max_iter`` the group iterates on until its cost stops falling by 1 %, ends nearer the
    truth, and the unused cost columns are NaN; without it exactly ``n_iter`` evaluations."""
    from imrbayes.ensemble.gn import gauss_newton

    t = np.linspace(0.0, 1.0, 40)
    truth = np.array([1.2, -0.4])

    def model(groups, Z):
        return np.exp(Z[:, :1] * t[None]) + Z[:, 1:2], np.zeros(len(Z), bool)

    y = model(None, truth[None])[0]
    E0 = np.random.default_rng(5).normal(0.0, 0.6, size=(1, 16, 2))
    fixed = gauss_newton(E0, model, y, np.full(t.size, 1e6), n_iter=3, rng=np.random.default_rng(0))
    more = gauss_newton(E0, model, y, np.full(t.size, 1e6), n_iter=3, rng=np.random.default_rng(0), max_iter=30)
    assert fixed.cost.shape == (1, 3) and np.all(np.isfinite(fixed.cost))
    assert more.cost.shape == (1, 30)
    n_used = int(np.isfinite(more.cost[0]).sum())
    assert 3 < n_used < 30  # went on, and stopped on its own
    assert np.all(np.isnan(more.cost[0, n_used:]))
    np.testing.assert_allclose(more.cost[0, :3], fixed.cost[0])  # the same first iterations
    assert np.linalg.norm(more.mean[0] - truth) < 0.1 * np.linalg.norm(fixed.mean[0] - truth)


def test_patience_halves_an_overshooting_first_step_before_giving_up():
    """With few iterations (3, as in En4D-Var's later cycles) a first step that overshoots is
    rejected and halved; without patience the group stops after two rejections, at its start.
    Over 40 prior draws of a stiff exponential model, every group that stopped so ends at least as
    low with ``patience=6`` and most end at the truth; groups with an accepted step are untouched."""
    from imrbayes.ensemble.gn import gauss_newton

    t = np.linspace(0.0, 1.0, 40)
    truth = np.array([1.2, -0.4])

    def model(groups, Z):
        return np.exp(3.0 * Z[:, :1] * t[None]) + Z[:, 1:2], np.zeros(len(Z), bool)

    y = model(None, truth[None])[0]
    stuck, fixed = 0, 0
    for seed in range(40):
        E0 = np.random.default_rng(seed).normal(0.0, 0.6, size=(1, 16, 2))
        kw = dict(n_iter=3, rng=np.random.default_rng(0), max_iter=15)
        short = gauss_newton(E0, model, y, np.full(t.size, 1e4), patience=3, **kw)
        kw["rng"] = np.random.default_rng(0)
        patient = gauss_newton(E0, model, y, np.full(t.size, 1e4), patience=6, **kw)
        c = short.cost[0][np.isfinite(short.cost[0])]
        if all(c[i] > c[0] for i in range(1, c.size)):  # no step accepted: stopped at its start
            stuck += 1
            assert c.size == 3
            assert np.nanmin(patient.cost[0]) <= c[0]
            fixed += np.linalg.norm(patient.mean[0] - truth) < 0.1 * np.linalg.norm(short.mean[0] - truth)
        else:
            np.testing.assert_array_equal(patient.cost[0][: c.size], c)
            np.testing.assert_allclose(patient.mean, short.mean, rtol=1e-12, atol=1e-12)
    assert stuck >= 10 and fixed >= 0.7 * stuck, (stuck, fixed)
