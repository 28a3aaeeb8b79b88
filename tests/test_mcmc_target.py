"""The MCMC target density: likelihood, weights, prior (with and without the Jacobian), failures,
the window target built from a handed-off ensemble."""

import numpy as np
import pytest
from _mcmc_synth import TRUTH, model, observations, paper_prior
from scipy import integrate

from imrbayes.ensemble import ParamSpace
from imrbayes.errors import InputError
from imrbayes.forward import BatchState, Propagation
from imrbayes.mcmc.target import WindowTarget, fitting_window_target, loglik_pointwise, window_target_from_ensemble

Z_TRUE = np.log([TRUTH["G"], TRUTH["mu"]])


def test_truth_has_zero_misfit_on_noise_free_data():
    fm, obs = observations(n_exp=2, n_steps=30)
    prior = paper_prior()
    tg = fitting_window_target(fm, obs, prior, weight="plain")
    assert tg.t_eval.tolist() == obs.t_star[1:].tolist()  # sample 0 (R* = 1) is not fitted
    Z = np.vstack([Z_TRUE, Z_TRUE + [0.3, 0.0], Z_TRUE])
    lp = tg.log_prob(Z)
    assert lp[0] == pytest.approx(prior.log_prob(Z_TRUE[None])[0], abs=1e-9)
    assert lp[2] == lp[0] and lp[1] < lp[0] - 1.0
    assert tg.log_likelihood(Z_TRUE[None])[0] == pytest.approx(0.0, abs=1e-9)
    assert tg.n_evals == 4 and tg.n_failed == 0


def test_likelihood_matches_direct_simulation_and_weights():
    fm, obs = observations(n_exp=2, n_steps=30, noise=0.01, seed=3)
    prior = paper_prior()
    rng = np.random.default_rng(0)
    Z = Z_TRUE + rng.normal(0, 0.1, (5, 2))
    plain = fitting_window_target(fm, obs, prior, weight="plain")
    avg = fitting_window_target(fm, obs, prior, weight="en4dvar")
    K = obs.t_star.size - 1
    expect = []
    for z in Z:
        th = np.exp(z)
        R = fm.simulate({"G": np.full(2, th[0]), "mu": np.full(2, th[1])}, obs.rmax_m, obs.req_m, obs.t_star).R_star
        expect.append(-0.5 * np.sum((obs.R_star[:, 1:] - R[:, 1:]) ** 2 / obs.P[1:]))
    ll = plain.log_likelihood(Z)
    np.testing.assert_allclose(ll, expect, rtol=1e-9)
    np.testing.assert_allclose(avg.log_likelihood(Z), ll / K, rtol=1e-12)  # c_k = 1/N_t
    np.testing.assert_allclose(plain.log_prob(Z), ll + prior.log_prob(Z), rtol=1e-12)
    # pointwise: Gaussian with variance P/c; sums to the likelihood plus a constant
    pw = avg.pointwise(Z)
    assert pw.shape == (5, 2, K)
    const = -0.5 * np.sum(np.log(2 * np.pi * obs.P[1:] * K)) * 2
    np.testing.assert_allclose(pw.sum(axis=(1, 2)), ll / K + const, rtol=1e-10)
    np.testing.assert_allclose(loglik_pointwise(1.0, 1.0, 2.0, 0.5), -0.5 * np.log(2 * np.pi * 4.0))


class _FakeModel:
    """Returns R* = theta_0 / 1e4 + t, fails members whose G > 9e3; records the batch."""

    def propagate(self, state, params, t_end, t_eval):
        self.last = (state, params)
        n = state.n
        R = params[:, :1] / 1e4 + np.asarray(t_eval)[None, :]
        failed = params[:, 0] > 9e3
        R[failed, 1:] = np.nan
        end = BatchState(state.y.copy(), t_end, state.rmax_m, state.req_m)
        return Propagation(np.asarray(t_eval), R, end, failed.astype(np.int64), np.zeros(n, int), np.zeros(n, int))


def test_batching_order_and_failures_give_minus_inf():
    fm = model()
    start = fm.initial_state([263e-6, 250e-6, 240e-6], [35e-6, 34e-6, 33e-6])
    t = np.array([0.1, 0.2, 0.3])
    fake = _FakeModel()
    tg = WindowTarget(fake, start, t, np.full((3, 3), 0.8) + t, 1e-2, paper_prior(), 1.0)
    Z = np.log([[7e3, 0.1], [9.5e3, 0.1], [8e3, 0.09], [np.nan, 0.1], [7e3, 1e-12]])
    lp = tg.log_prob(Z)
    assert np.isfinite(lp[[0, 2]]).all() and np.isneginf(lp[[1, 3, 4]]).all()
    assert not np.isnan(lp).any()
    st, params = fake.last
    # only the three in-support parameter sets were simulated, member = i * N_exp + e
    assert st.n == 9 and params.shape == (9, 2)
    np.testing.assert_allclose(params[:3, 0], 7e3) and np.testing.assert_allclose(params[3:6, 0], 9.5e3)
    np.testing.assert_allclose(st.rmax_m, np.tile(start.rmax_m, 3))
    assert tg.n_failed == 1 and tg.n_evals == 3  # non-finite / out-of-box never reach the model
    # a pointwise array stays finite for failed draws
    assert np.isfinite(tg.pointwise(Z[:3])).all()


def test_prior_natural_scale_has_the_jacobian():
    """A Gaussian stated on theta > 0 and sampled in z = log theta integrates to one over z."""
    pr = ParamSpace(("a",), [True], [5.0], [[1.0]], scale="natural")
    f = lambda z: np.exp(pr.log_prob(np.array([[z]]))[0])  # noqa: E731
    total, _ = integrate.quad(f, pr.lower[0], pr.upper[0], limit=200)
    from scipy import stats

    inside = stats.norm(5, 1).cdf(np.exp(pr.upper[0])) - stats.norm(5, 1).cdf(np.exp(pr.lower[0]))
    assert total == pytest.approx(inside, abs=1e-8) and inside > 1 - 1e-5  # the box cuts < 1e-5
    zi = np.log(4.0)
    assert pr.log_prob([[zi]])[0] == pytest.approx(stats.norm(5, 1).logpdf(4.0) + zi)
    pi = ParamSpace(("a",), [True], [1.5], [[0.04]])  # internal: no Jacobian
    total, _ = integrate.quad(lambda z: np.exp(pi.log_prob(np.array([[z]]))[0]), 0.0, 3.0)
    assert total == pytest.approx(1.0, abs=1e-6)
    assert np.isneginf(pi.log_prob([[1.5 + 11 * 0.2]])[0])  # outside the 10-sd box
    with pytest.raises(InputError):
        ParamSpace((), [True, True], [1.0, 2.0], [[1.0, 2.0], [2.0, 1.0]])


def test_window_target_from_handed_off_ensemble():
    fm, obs = observations(n_exp=2, n_steps=40)
    N, a, b = 3, 10, 30
    st0 = fm.initial_state(np.repeat(obs.rmax_m, N), np.repeat(obs.req_m, N))
    th = np.tile([TRUTH["G"], TRUTH["mu"]], (2 * N, 1))
    handed = fm.propagate(st0, th, obs.t_star[a]).end  # the state at window start
    prior = paper_prior()
    beta = np.linspace(0.2, 1.0, b - a + 1)
    tg = window_target_from_ensemble(
        fm, handed, obs.t_star[a : b + 1], obs.R_star[:, a : b + 1], 1e-6, prior, mda_weight=beta, L=b - a + 1, index=2
    )
    assert tg.t0 == pytest.approx(obs.t_star[a]) and tg.n_exp == 2
    np.testing.assert_allclose(tg.weight[0], beta / (b - a + 1))
    assert not tg.use_time[0] and tg.use_time[1:].all()  # R*(t0) is the given state
    ll = tg.log_likelihood(np.vstack([Z_TRUE, Z_TRUE + [0.1, 0.0]]))
    assert ll[0] > -1e-6 and ll[1] < -0.5
    # members with different states: the target starts from each experiment's mean state
    jit = handed.copy()
    jit.y[:, 1] += np.array([-1, 0, 1, -2, 0, 2]) * 1e-3
    tg2 = window_target_from_ensemble(fm, jit, obs.t_star[a : b + 1], obs.R_star[:, a : b + 1], obs.P[a : b + 1], prior)
    np.testing.assert_allclose(tg2.start.y, handed.y[[0, 3]], atol=1e-15)
    np.testing.assert_allclose(tg2.description["R_spread_at_start"], 0.0, atol=1e-12)
    with pytest.raises(InputError):
        window_target_from_ensemble(
            fm, handed.take(np.arange(5)), obs.t_star[a : b + 1], obs.R_star[:, a : b + 1], obs.P[a : b + 1], prior
        )
