"""Recovery of known parameters from noise-free synthetic data (polytropic forward model)."""

import numpy as np
import pytest
from _ens_synth import TRUTH, observations, space

from imrbayes.ensemble import En4DVarSettings, IMRSettings, MIEnKSSettings, fit_en4dvar, fit_imr, fit_mienks
from imrbayes.ensemble.imr import collapse_indices, fit_indices
from imrbayes.errors import InputError
from imrbayes.forward import Runner


def test_imr_optimum_within_one_grid_cell():
    fm, obs = observations()
    # a grid that does not hold the truth on a node: dG = 200 Pa, dmu = 0.004 Pa s
    s = IMRSettings(G_min=5.13e3, G_max=9.93e3, n_G=25, mu_min=0.0612, mu_max=0.1212, n_mu=16)
    res = fit_imr(fm, obs, space(fm), s)
    dG, dm = 200.0, 0.004
    grid = res.details["grid_optimum"]
    assert abs(grid["G"] - TRUTH["G"]) <= dG and abs(grid["mu"] - TRUTH["mu"]) <= dm
    opt = res.details["optimum"]  # sub-grid quadratic refinement
    assert abs(opt["G"] - TRUTH["G"]) < 0.5 * dG and abs(opt["mu"] - TRUTH["mu"]) < 0.5 * dm
    for p in res.per_experiment:
        assert abs(p["grid_optimum"]["G"] - TRUTH["G"]) <= dG
        assert abs(p["grid_optimum"]["mu"] - TRUTH["mu"]) <= dm
    J = res.extra_groups["landscape"]["J"]
    assert J.shape == (25, 16) and np.nanmin(J) == pytest.approx(res.details["J_min"])
    assert res.details["confidence"]["J_level"] > res.details["J_min"]
    assert res.rmse < 1e-3
    assert res.posterior["G"].shape == (1, s.n_draws)


def test_imr_says_when_the_grid_bounds_the_answer():
    """A grid that stops below the truth (G_max 5 kPa, truth 7.29) puts the optimum on its upper
    edge: the estimate is a bound and the fit says so; a grid holding the truth says nothing."""
    fm, obs = observations(n_exp=2)
    s = IMRSettings(G_min=1e3, G_max=5e3, n_G=9, mu_min=0.0612, mu_max=0.1212, n_mu=7, spacing="linear")
    res = fit_imr(fm, obs, space(fm), s)
    assert res.details["grid_optimum"]["G"] == 5e3
    assert any("G at the grid's upper end" in w and "G_max" in w for w in res.warnings)
    assert any("2 of 2 experiments have their own optimum on the grid's edge" in w for w in res.warnings)
    # the pseudo-posterior sits inside one cell (grid sd 3e-11 Pa) and the edge leaves no quadratic to
    # refine it: the reported sd is a uniform cell's, not the grid's zero, and a warning says so
    assert not res.details["refined"] and res.estimate["G"]["sd_grid"] < 1.0
    assert res.estimate["G"]["sd"] == pytest.approx(500.0 / np.sqrt(12.0))
    assert res.estimate["mu"]["sd"] >= 0.01 / np.sqrt(12.0) * (1 - 1e-12)
    assert any("inside one grid cell" in w for w in res.warnings)
    ok = fit_imr(
        fm, obs, space(fm), IMRSettings(G_min=5.13e3, G_max=9.93e3, n_G=9, mu_min=0.0612, mu_max=0.1212, n_mu=7)
    )
    assert not any("edge" in w or "end (" in w for w in ok.warnings)


def test_imr_windows():
    fm, obs = observations(n_exp=2)
    K1 = fit_indices(obs, "collapse:1")
    K2 = fit_indices(obs, "collapse:2")
    assert np.all(K2 > K1)
    # the first collapse of the noise-free curves is near t* = 0.9-1.0
    assert np.all((obs.t_star[K1] > 0.8) & (obs.t_star[K1] < 1.1))
    assert fit_indices(obs, "t:1.5").tolist() == [60, 60]
    assert fit_indices(obs, "all").tolist() == [120, 120]
    assert collapse_indices(obs.R_star[0]).size >= 2
    for bad in ("collapse:9", "t:x", "first", "collapse:0"):
        with pytest.raises(InputError):
            fit_indices(obs, bad)


@pytest.mark.slow
def test_en4dvar_recovers_truth():
    fm, obs = observations()
    res = fit_en4dvar(fm, obs, space(fm), En4DVarSettings(n_draws=8), seed=0)
    for name in ("G", "mu"):
        est = res.estimate[name]
        assert est["mean"] == pytest.approx(TRUTH[name], rel=0.03)
        lo, hi = est["hdi95"]
        assert lo < TRUTH[name] < hi
        for p in res.per_experiment:
            assert p["estimate"][name]["mean"] == pytest.approx(TRUTH[name], rel=0.03)
    assert res.details["fusion"]["prior_correction_factor"] == 1.0
    assert res.rmse < 2e-3
    assert res.log_likelihood["R"].shape == (1, 8, 5, 120)
    assert res.details["failed_member_runs"] == 0
    # same seed, same answer
    res2 = fit_en4dvar(fm, obs, space(fm), En4DVarSettings(n_draws=8), seed=0)
    assert res2.estimate == res.estimate


def test_en4dvar_fit_window():
    fm, obs = observations(n_exp=2)
    res = fit_en4dvar(fm, obs, space(fm), En4DVarSettings(n_ens=16, n_runs=1, t_end=1.0, n_draws=1, loglik=False))
    assert res.details["n_fit_steps"] == 40
    assert res.fit_mask[:, 41:].sum() == 0 and np.all(np.isnan(res.fitted[:, 41:]))


def test_mienks_short_record():
    fm, obs = observations(n_exp=3, n_steps=60)
    s = MIEnKSSettings(n_ens=24, L=20, h=10, n_draws=50)
    res = fit_mienks(fm, obs, space(fm), s, seed=1)
    assert len(res.windows) == 5 == res.details["n_windows"]
    assert [w["samples"] for w in res.windows][-1] == [40, 59]
    # every window holds the truth in its 95% interval and stays near it (noise-free data, perfect
    # model); the windows before the first collapse (t* < 0.9) carry little information on G
    for w in res.windows:
        for name in ("G", "mu"):
            lo, hi = w[name]["hdi95"]
            assert lo < TRUTH[name] < hi, (w["index"], name, w[name])
    for w in res.windows[2:]:
        assert w["G"]["mean"] == pytest.approx(TRUTH["G"], rel=0.15)
        assert w["mu"]["mean"] == pytest.approx(TRUTH["mu"], rel=0.05)
    assert res.estimate["G"]["mean"] == pytest.approx(TRUTH["G"], rel=0.15)
    assert res.estimate["mu"]["mean"] == pytest.approx(TRUTH["mu"], rel=0.05)
    assert len(res.time_resolved) == 60  # samples 0..59 lie in some window
    assert res.posterior["G"].shape == (1, 50, 5)
    assert res.rmse < 5e-3
    assert np.all(np.isfinite(res.fitted[:, :60]))


def test_runner_chunks_match_single_call():
    fm, obs = observations(n_exp=2, n_steps=40)
    rng = np.random.default_rng(0)
    th = np.column_stack([rng.uniform(2e3, 12e3, 10), rng.uniform(0.03, 0.3, 10)])
    rm, rq = np.repeat(obs.rmax_m, 5), np.repeat(obs.req_m, 5)
    a = Runner(fm).simulate(th, rm, rq, obs.t_star).R_star
    done = []
    b = Runner(fm, chunk=3, progress=done.append).simulate(th, rm, rq, obs.t_star).R_star
    np.testing.assert_array_equal(a, b)
    assert done == [3, 3, 3, 1]


@pytest.mark.slow
def test_mienks_rejects_analysis_when_handoff_fails():
    """Every analysed member of one experiment fails its hand-off: that window's analysis is
    rejected for it (prior ensemble handed on, reported) and the run goes on."""
    fm, obs = observations(n_exp=2, n_steps=60)

    class Flaky(Runner):
        hit = 0

        def propagate(self, state, params, t_end, t_eval=None):
            out = super().propagate(state, params, t_end, t_eval)
            # one experiment per batch (a unit per window and experiment): exp_002's hand-off of window 2
            if (
                np.size(t_eval) == 6
                and state.t_star == 0.25
                and state.n == 16
                and not Flaky.hit
                and np.all(state.rmax_m == obs.rmax_m[1])
            ):
                Flaky.hit = 1
                out.status[:] = 3
                out.R_star[:] = np.nan
            return out

    # one pass (adapt=False): the default likelihood's pilot would meet the failure first
    res = fit_mienks(
        fm, obs, space(fm), MIEnKSSettings(n_ens=16, L=20, h=5, n_draws=5, adapt=False), seed=0, runner=Flaky(fm)
    )
    assert Flaky.hit == 1
    assert [w["analysis_rejected"] for w in res.windows][2] == ["exp_002"]
    assert sum(len(w["analysis_rejected"]) for w in res.windows) == 1
    assert any("analysis rejected" in w for w in res.warnings)
    assert np.isfinite(res.estimate["G"]["mean"])


def _laplace_sd(fm, obs, sp, truth, weight):
    """Posterior sd of (log G, log mu) from the Gauss–Newton (Laplace) approximation at the truth:
    Jacobian of R* by central differences, precision J^T diag(weight) J + prior precision."""
    z0 = np.log([truth["G"], truth["mu"]])
    n = obs.rmax_m.size
    cols = []
    for i in range(2):
        dz = np.zeros(2)
        dz[i] = 1e-4
        R = [
            fm.simulate(
                {"G": np.full(n, np.exp(z[0])), "mu": np.full(n, np.exp(z[1]))}, obs.rmax_m, obs.req_m, obs.t_star
            ).R_star[:, 1:]
            for z in (z0 + dz, z0 - dz)
        ]
        cols.append(((R[0] - R[1]) / 2e-4).ravel())
    J = np.stack(cols, axis=1)
    w = np.tile(weight, n)
    prec = J.T @ (w[:, None] * J) + np.linalg.inv(sp.prior_cov)
    return np.sqrt(np.diag(np.linalg.inv(prec)))


@pytest.mark.parametrize("obs_weight", ["mean", "sum"])
def test_en4dvar_obs_weight_matches_laplace_posterior(obs_weight):
    """The fused posterior's spread is the Gauss–Newton posterior of the chosen likelihood weight
    (1/(N_t P_k) or 1/P_k), computed independently from finite-difference Jacobians."""
    fm, obs = observations()
    sp = space(fm)
    K = obs.t_star.size - 1
    res = fit_en4dvar(
        fm,
        obs,
        sp,
        En4DVarSettings(n_draws=1, loglik=False, n_runs=1, obs_weight=obs_weight, likelihood="paper"),
        seed=0,
    )
    weight = 1.0 / ((K if obs_weight == "mean" else 1.0) * obs.P[1:])
    sd_ref = _laplace_sd(fm, obs, sp, TRUTH, weight)
    sd = np.sqrt(np.diag(res.cov_internal))
    np.testing.assert_allclose(sd, sd_ref, rtol=0.25)
    if obs_weight == "sum":  # the averaged likelihood leaves the prior's pull (6 kPa) in the mean
        for name in ("G", "mu"):
            assert res.estimate[name]["mean"] == pytest.approx(TRUTH[name], rel=0.02)


def test_en4dvar_obs_weight_is_checked():
    with pytest.raises(InputError, match="obs_weight"):
        En4DVarSettings(obs_weight="median").check()


@pytest.mark.slow
def test_mienks_mda_weights_recover_the_truth_in_every_late_window():
    """Each observation counted once in total (obs_weight=mda) on noise-free records: after the
    first collapse every window's mean is within 5 % of the truth and inside its 95 % HDI."""
    fm, obs = observations()
    res = fit_mienks(fm, obs, space(fm), MIEnKSSettings(n_draws=1, obs_weight="mda", likelihood="paper"), seed=0)
    late = [w for w in res.windows if w["t_star"][0] >= 0.9]
    assert len(late) >= 10
    for w in late:
        for name in ("G", "mu"):
            assert w[name]["mean"] == pytest.approx(TRUTH[name], rel=0.05), (w["t_star"], name, w[name]["mean"])
            lo, hi = w[name]["hdi95"]
            assert lo < TRUTH[name] < hi
