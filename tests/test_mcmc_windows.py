"""MCMC of MIEnKS-MDA windows: the recorded window posteriors (chained priors, MDA weights,
handed-off start states), mcmc.nc layout and compare.json from the run files."""

import dataclasses
import json

import arviz as az
import numpy as np
import pytest
import xarray as xr
from _mcmc_synth import observations

from imrbayes.ensemble import MIEnKSSettings, Observations, ParamSpace, fit_mienks
from imrbayes.ensemble.mienks import rtps_cov
from imrbayes.ensemble.output import summary_dict
from imrbayes.ensemble.windows import mda_weights
from imrbayes.mcmc import MCMCSettings
from imrbayes.mcmc.fit import fit_window_specs
from imrbayes.mcmc.windows import (
    compare_from_tree,
    sample_windows,
    window_seed,
    window_specs,
    write_compare,
    write_mcmc,
)


@pytest.fixture(scope="module")
def fitted():
    fm, o = observations(n_exp=2, n_steps=40, noise=0.01, seed=2)
    obs = Observations(o.t_star, o.R_star, o.P, o.rmax_m, o.req_m)
    space = ParamSpace.for_model(fm.constitutive)
    # the paper's density (weights beta_jk / L, P_k): these tests are about its recorded priors,
    # weights and start states; the default likelihood's windows carry ``whiten`` instead
    res = fit_mienks(
        fm, obs, space, MIEnKSSettings(n_ens=12, n_iter=3, L=15, h=5, n_draws=5, likelihood="paper"), seed=0
    )
    return fm, obs, space, res


def rederived_priors(windows, prior_mean, prior_cov, rtps, fusion):
    """The window priors as the MCMC layer re-derived them from summary.json's windows before the
    fit recorded them: RTPS of the previous window's fused covariance, chained from the prior."""
    m, C = np.asarray(prior_mean, float), np.asarray(prior_cov, float)
    out = []
    for w in windows:
        out.append((m.copy(), C.copy()))
        if fusion == "chain":
            m, C = np.asarray(w["mean_internal"], float), rtps_cov(C, np.asarray(w["cov_internal"], float), rtps)
    return out


def test_window_specs(fitted):
    fm, obs, space, res = fitted
    s = res.details["settings"]
    specs = fit_window_specs(fm, obs, space, res)
    assert [sp.index for sp in specs] == list(range(len(res.windows))) == list(range(6))
    # window 0: the state at the maximum, the parameter prior, weights beta/L
    sp0 = specs[0]
    np.testing.assert_array_equal(sp0.target.start.y, fm.initial_state(obs.rmax_m, obs.req_m).y)
    np.testing.assert_allclose(sp0.prior_mean, space.prior_mean)
    assert sp0.target.weight[0, 0] == pytest.approx(1.0 / 15)  # sample 0: only window 0 holds it
    assert sp0.target.weight[0, 5] == pytest.approx(0.5 / 15)  # sample 5: windows 0 and 1
    # chained priors: window j+1's prior mean is window j's fused mean; sds relaxed towards the prior
    for j in range(1, 6):
        np.testing.assert_allclose(specs[j].prior_mean, res.windows[j - 1]["mean_internal"])
        post_sd = np.sqrt(np.diag(res.windows[j - 1]["cov_internal"]))
        assert np.all(np.sqrt(np.diag(specs[j].prior_cov)) >= post_sd - 1e-15)
    # the recorded priors and weights are exactly what the MCMC layer used to re-derive from summary.json
    beta = mda_weights(obs.t_star.size - 1, s["L"], s["h"])
    for (m, C), sp, w in zip(
        rederived_priors(res.windows, space.prior_mean, space.prior_cov, s["rtps"], "chain"),
        specs,
        res.window_posteriors,
    ):
        np.testing.assert_array_equal(sp.prior_mean, m)
        np.testing.assert_array_equal(sp.prior_cov, C)
        np.testing.assert_array_equal(sp.target.prior.prior_cov, C)
        a, b = w.samples
        np.testing.assert_array_equal(w.weight, beta[w.index, a : b + 1] / s["L"])
        assert sp.state_source == "handed-off ensemble mean"
    # window 1 starts from the handed-off mean state, close to experiment n's window-0 mean propagated over [0, t_5]
    z = np.array([p["mean_internal"] for p in res.windows[0]["per_experiment"]])
    out = fm.propagate(fm.initial_state(obs.rmax_m, obs.req_m), np.exp(z), obs.t_star[5])
    np.testing.assert_allclose(specs[1].target.start.R, out.end.R, rtol=0.05)
    assert specs[1].target.t0 == pytest.approx(obs.t_star[5])
    assert window_seed(0, 1) != window_seed(0, 2) and window_seed(0, 1) == window_seed(0, 1)


def test_recorded_priors_with_prior_fusion_and_mda_weights(fitted):
    """fusion="prior": the parameter prior in every window; obs_weight="mda": weights beta_jk."""
    fm, obs, space, _ = fitted
    res = fit_mienks(
        fm,
        obs,
        space,
        MIEnKSSettings(n_ens=12, n_iter=3, L=15, h=5, n_draws=5, fusion="prior", obs_weight="mda", likelihood="paper"),
        seed=0,
    )
    specs = fit_window_specs(fm, obs, space, res, windows=[0, 2])
    priors = rederived_priors(res.windows, space.prior_mean, space.prior_cov, 0.7, "prior")
    for sp in specs:
        np.testing.assert_array_equal(sp.prior_mean, space.prior_mean)
        np.testing.assert_array_equal(sp.prior_cov, priors[sp.index][1])
    assert specs[0].target.weight[0, 5] == pytest.approx(0.5)  # obs_weight="mda": beta only


def test_sample_windows_write_and_compare_from_files(fitted, tmp_path):
    fm, obs, space, res = fitted
    specs = window_specs(fm, obs, space, res.window_posteriors, indices=[0, 3])
    out = sample_windows(
        specs, MCMCSettings(n_walkers=6, n_steps=60), seed=1, backend=tmp_path / "mcmc.h5", progress=False
    )
    assert [r.spec.index for r in out] == [0, 3]
    path = write_mcmc(tmp_path / "mcmc.nc", out)
    tree = xr.open_datatree(path)
    assert {"window_00", "window_03", "posterior", "sample_stats"} <= set(tree.children)
    assert tree["posterior"]["G"].dims == ("chain", "draw", "window")
    assert tree["posterior"]["window"].values.tolist() == [0, 3]
    ll = tree["window_03/log_likelihood"]["R"]
    assert ll.dims == ("chain", "draw", "experiment", "time") and ll.shape[2] == 2
    assert tree["window_03/observed_data"]["time"].values[0] > specs[1].t_star[0]  # R*(t0) not used
    s = az.summary(tree, var_names=["G"], round_to="none")
    assert list(s.index) == ["G[0]", "G[3]"]
    # compare.json from the run directory's files gives the entries computed in memory
    summ = json.loads(json.dumps(summary_dict(res, obs, seed=0)))
    back = compare_from_tree(summ, tree)
    assert [w["index"] for w in back["windows"]] == [0, 3]
    for w, r in zip(back["windows"], out):
        assert w["kl_sym"] == pytest.approx(r.entry["kl_sym"], rel=1e-9)
        assert w["mcmc"]["sampler"]["n_steps"] == 60
    data = write_compare(tmp_path / "compare.json", out)
    assert json.loads((tmp_path / "compare.json").read_text()) == data
    assert data["overall"]["n_windows"] == 2
    # figures: forest over windows, KL/W2 against t*, pair plots with both posteriors
    from imrbayes.mcmc.figures import comparison_figures

    figs = comparison_figures(data, tmp_path / "figures", tree, obs.t_star, obs.R_star, pairs="all")
    assert [p.rsplit("/", 1)[1] for p in figs] == [
        "mcmc_forest.png",
        "mcmc_divergence.png",
        "mcmc_pair_window_00.png",
        "mcmc_pair_window_03.png",
    ]
    for p in figs:
        with open(p, "rb") as fh:
            assert fh.read(8) == b"\x89PNG\r\n\x1a\n"
    # rerunning with the same HDF5 file resumes: nothing left to run, the same chains
    again = sample_windows(
        specs, MCMCSettings(n_walkers=6, n_steps=60), seed=1, backend=tmp_path / "mcmc.h5", progress=False
    )
    assert all(r.run.steps_run == [0] * r.run.n_chains for r in again)
    np.testing.assert_array_equal(again[1].run.chain, out[1].run.chain)


def test_specs_from_the_smoothers_handed_off_states(fitted):
    """fit_mienks records each window's entering mean state; the specs start from it, and an
    experiment with a NaN state is left out of that window's target."""
    fm, obs, space, res = fitted
    posts = res.window_posteriors
    assert len(posts) == len(res.windows)
    np.testing.assert_array_equal(posts[0].start_state, fm.initial_state(obs.rmax_m, obs.req_m).y)
    specs = window_specs(fm, obs, space, posts)
    for j, sp in enumerate(specs):
        assert sp.state_source == "handed-off ensemble mean"
        np.testing.assert_array_equal(sp.target.start.y, posts[j].start_state)
        assert sp.target.t0 == pytest.approx(obs.t_star[res.windows[j]["samples"][0]])
    q = posts[2].start_state.copy()
    q[0] = np.nan
    cut = list(posts)
    cut[2] = dataclasses.replace(posts[2], start_state=q)
    sp2 = window_specs(fm, obs, space, cut, indices=[2])[0]
    assert sp2.target.start.n == obs.R_star.shape[0] - 1 and sp2.target.y.shape[0] == obs.R_star.shape[0] - 1


def test_cost_warning_names_windows_with_many_coordinates():
    """Before sampling, a window with many sampled coordinates (each experiment's nuisances) is
    announced with its size and what the cap means; a two-parameter window is not."""
    from types import SimpleNamespace

    from imrbayes.mcmc.fit import MANY_COORDINATES, cost_warnings

    def spec(index, d, n_exp, blocks=None):
        tg = SimpleNamespace(ndim=d, prior=SimpleNamespace(n=2), n_exp=n_exp)
        if blocks is not None:
            tg.nuisance_blocks = blocks
        return SimpleNamespace(index=index, target=tg)

    s = MCMCSettings()
    out = cost_warnings([spec(0, 2, 5), spec(1, 19, 6), spec(2, MANY_COORDINATES - 1, 2)], s)
    assert len(out) == 1
    w = out[0]
    assert w.startswith("MCMC window 1 samples 19 coordinates (2 parameters and 17 nuisances of 6 experiments")
    assert "150-360 steps" in w and f"{s.n_chains} x 38 walkers" in w and "agree = null" in w
    assert f"after {s.n_chains * 38 * s.n_steps:,} likelihood evaluations" in w
    # the default moves on a window with nuisance blocks: the block and ridge moves, converging within the cap
    blocks = [np.arange(2 + 3 * e, 5 + 3 * e) for e in range(6)]
    (w,) = cost_warnings([spec(3, 20, 6, blocks)], s)
    assert "35-40 steps" in w and "about 2 000 steps" in w and "agree = null" not in w
    # one nuisance per experiment (Rmax alone): the start is placed and independent walkers may sample it
    (w,) = cost_warnings([spec(4, 20, 18, [np.array([2 + e]) for e in range(18)])], s)
    assert "placed on the target" in w and "independent walkers" in w and "agree = null" not in w
    assert "2,079 evaluations" in w  # 3 rounds x 3 points x (d + 1)(d + 2)/2 = 231 coefficients
    (w,) = cost_warnings([spec(3, 20, 6, blocks)], MCMCSettings(moves="indep:0.7,de:0.3"))
    assert "150-360 steps" in w
