"""The inference methods end to end: recovery of known parameters, pIMR's closed-form collapse
time, and ``imrbayes fit`` for every method."""

import json
import math

import numpy as np
import pytest
from _ens_synth import RATIO, RMAX, TRUTH, model, observations, space
from click.testing import CliRunner

from imrbayes.cli import main
from imrbayes.ensemble import (
    En4DVarSettings,
    IMRSettings,
    MIEnKSSettings,
    Observations,
    PIMRSettings,
    fit_en4dvar,
    fit_imr,
    fit_mienks,
    fit_pimr,
)
from imrbayes.ensemble.imr import collapse_indices, fit_indices
from imrbayes.ensemble.pimr import T_RC, collapse_time, contents_factor
from imrbayes.errors import InputError
from imrbayes.forward import ForwardModel, Runner

# Recovery of known parameters from noise-free synthetic data (polytropic forward model).


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


# pIMR's closed-form collapse time against simulated first-collapse times, term by term and over
# the prior range (methods.md §2).


DT = 0.002


def simulated_tc(fm, G, mu, rmax, req):
    """First-collapse time t* (first local minimum of R*, parabolic refinement) of each member."""
    t = np.arange(0.0, 1.6, DT)
    G, mu, rmax, req = np.broadcast_arrays(*(np.atleast_1d(np.asarray(a, dtype=float)) for a in (G, mu, rmax, req)))
    out = fm.simulate({"G": G, "mu": mu}, rmax, req, t)
    tc = np.full(G.size, np.nan)
    for i, r in enumerate(out.R_star):
        k = np.flatnonzero((r[1:-1] <= r[:-2]) & (r[1:-1] <= r[2:]))
        if out.failed[i] or k.size == 0:
            continue
        k = k[0] + 1
        den = r[k - 1] - 2 * r[k] + r[k + 1]
        tc[i] = t[k] + (0.5 * (r[k - 1] - r[k + 1]) / den * DT if den > 0 else 0.0)
    return tc


def test_constants():
    assert T_RC == pytest.approx(0.9147, abs=5e-5)
    assert contents_factor(1.0) == pytest.approx(1.494, abs=5e-4)
    assert contents_factor(1.4) == pytest.approx(2.184, abs=1e-3)  # 2.18349 (paper: 2.184)


@pytest.mark.parametrize(
    "term,fm_on,fm_off,p_on,p_off",
    [
        # each physical effect switched on alone against a baseline without it (polytropic, RP, no vapour,
        # surface tension ~0); the formula's change must have the simulated change's sign and size
        ("elastic", None, None, (8e3, 0.0), (0.0, 0.0)),
        ("viscous", None, None, (0.0, 0.1), (0.0, 0.0)),
        ("surface tension", dict(surface=True), None, (0.0, 0.0), (0.0, 0.0)),
        ("vapour", dict(vapor=True), None, (0.0, 0.0), (0.0, 0.0)),
        ("compressibility", dict(radial="km"), None, (0.0, 0.0), (0.0, 0.0)),
    ],
)
def test_term_signs_against_simulation(term, fm_on, fm_off, p_on, p_off):
    def make(over):
        over = dict(over or {})
        surface = over.pop("surface", False)
        opts = {"bubble": "polytropic", "vapor": False, "radial": "rp", **over}
        return ForwardModel("nhkv", options=opts, physics_overrides=None if surface else {"surface_tension": 1e-12})

    rmax, req = 300e-6, 300e-6 / 7.5
    on, off = make(fm_on), make(fm_off)
    sim = simulated_tc(on, *p_on, rmax, req)[0] - simulated_tc(off, *p_off, rmax, req)[0]
    pred = float(collapse_time(on, *p_on, rmax, req) - collapse_time(off, *p_off, rmax, req))
    assert np.sign(pred) == np.sign(sim), (term, pred, sim)
    assert abs(pred - sim) < 0.5 * abs(sim) + 1e-3, (term, pred, sim)


@pytest.mark.parametrize("bubble,tol", [("polytropic", 0.015), ("thermal", 0.025)])
def test_collapse_time_across_prior_range(bubble, tol):
    """Max relative error of the formula over the prior range (G 0.4-11.6 kPa, mu 0.03-0.39 Pa s,
    Rmax 250-400 µm, Rmax/Req 6.8-8.4). Measured: 0.9 % (polytropic), 1.7 % (thermal, imrv2-fd)."""
    rng = np.random.default_rng(1)
    n = 120 if bubble == "polytropic" else 60
    G, mu = rng.uniform(0.4e3, 11.6e3, n), rng.uniform(0.033, 0.385, n)
    rmax, ratio = rng.uniform(250e-6, 400e-6, n), rng.uniform(6.8, 8.4, n)
    fm = model(bubble)
    sim = simulated_tc(fm, G, mu, rmax, rmax / ratio)
    pred = collapse_time(fm, G, mu, rmax, rmax / ratio)
    err = np.abs(pred - sim) / sim
    assert np.all(np.isfinite(err))
    print(f"pIMR vs {bubble} forward model: max relative error {err.max():.4f}, mean {err.mean():.4f}")
    assert err.max() < tol


def test_fit_pimr_reproduces_collapse_times():
    fm = model("polytropic")
    rmax = np.array([220e-6, 280e-6, 340e-6, 400e-6, 450e-6])
    req = rmax / np.array([6.8, 7.6, 8.4, 7.2, 8.0])
    truth = (7.29e3, 0.088)
    tc = collapse_time(fm, *truth, rmax, req)  # measured = the formula's own prediction
    t = np.arange(121) * 0.025
    obs = Observations(t, np.ones((5, t.size)), np.full(t.size, 1e-4), rmax, req, tc)
    res = fit_pimr(fm, obs, space(fm), PIMRSettings(n_G=60, n_mu=40))
    assert res.details["collapse_rmse"] < 1e-4
    fitted = collapse_time(fm, res.details["optimum"]["G"], res.details["optimum"]["mu"], rmax, req)
    np.testing.assert_allclose(fitted, tc, rtol=1e-4)
    assert res.extra_groups["landscape"]["log_J"].shape == (60, 40)
    assert math.isnan(res.rmse)  # no forward run without a runner
    res2 = fit_pimr(fm, obs, space(fm), PIMRSettings(n_G=30, n_mu=20), runner=Runner(fm))
    assert np.all(np.isfinite(res2.fitted[:, 1:]))


def test_fit_pimr_says_when_the_grid_bounds_the_answer():
    """Collapse times made with G 7.29 kPa, fitted on a grid that stops at 4 kPa: the optimum sits on
    the grid's upper end, and the fit says the estimate is a bound; on the default grid it does not."""
    fm = model("polytropic")
    rmax = np.array([220e-6, 280e-6, 340e-6, 400e-6, 450e-6])
    req = rmax / np.array([6.8, 7.6, 8.4, 7.2, 8.0])
    tc = collapse_time(fm, 7.29e3, 0.088, rmax, req)
    t = np.arange(3) * 0.025
    obs = Observations(t, np.ones((5, t.size)), np.full(t.size, 1e-4), rmax, req, tc)
    bounded = fit_pimr(fm, obs, space(fm), PIMRSettings(G_max=4e3, n_G=30, n_mu=20))
    assert any(w.startswith("pIMR optimum: G at the grid's upper end") for w in bounded.warnings)
    free = fit_pimr(fm, obs, space(fm), PIMRSettings(n_G=60, n_mu=40))
    assert not any("grid's" in w for w in free.warnings)


def test_fit_pimr_on_one_bubble_reports_the_ridge_not_nan():
    """One collapse time fixes a curve in (G, mu): every reported ridge point reproduces it, the
    truth lies on it, and the estimate says so instead of printing NaN."""
    from imrbayes.cli.options import estimate_text

    fm = model("polytropic")
    rmax, req = np.array([263e-6]), np.array([263e-6 / 7.58])
    tc = collapse_time(fm, 7.29e3, 0.088, rmax, req)
    t = np.arange(121) * 0.025
    obs = Observations(t, np.ones((1, t.size)), np.full(t.size, 1e-4), rmax, req, tc)
    # the paper's linear grid: the ridge is linear in mu between its nodes
    res = fit_pimr(
        fm, obs, space(fm), PIMRSettings(n_G=60, n_mu=40, G_max=25e3, mu_min=0.0, mu_max=0.5, spacing="linear")
    )
    ridge = res.details["ridge"]
    assert len(ridge["G"]) >= 10
    pred = collapse_time(fm, np.array(ridge["G"]), np.array(ridge["mu"]), rmax[0], req[0])
    np.testing.assert_allclose(pred, tc[0], rtol=2e-3)  # on the ridge (linear in mu between nodes)
    mu_at_truth = np.interp(7.29e3, ridge["G"], ridge["mu"])  # the truth is one of its points
    assert mu_at_truth == pytest.approx(0.088, rel=0.05)
    for name in ("G", "mu"):
        lo, hi = res.estimate[name]["ridge"]
        assert lo < hi
    assert any("ridge" in w for w in res.warnings)
    text = estimate_text(res.estimate)
    assert "nan" not in text.lower() and "on a ridge" in text and "kPa" in text


def test_estimate_text_units():
    from imrbayes.cli.options import estimate_text

    assert (
        estimate_text({"G": {"mean": 13500.0, "sd": 600.0}, "mu": {"mean": 0.101, "sd": 0.023}})
        == "G = 13.5 kPa ± 0.6 kPa, mu = 0.101 Pa s ± 0.023 Pa s"
    )
    assert (
        estimate_text({"G": {"mean": 7.3e3, "sd": 9e3, "hdi95": [66.5, 5.66e7]}})
        == "G not bounded by the data (best fit 7.3 kPa)"
    )
    assert estimate_text({"alpha": {"mean": 2.0, "sd": float("nan")}}) == "alpha = 2 (no interval)"


# ``imrbayes fit``: every method end to end on a small synthetic dataset; outputs and errors.


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """Three noise-free polytropic bubbles as CSV files (t_s, R_m) with a meta.json."""
    d = tmp_path_factory.mktemp("synthetic")
    fm = model("polytropic")
    t = np.arange(-4, 135) * 0.025
    rmax, req = RMAX[:3], RMAX[:3] / RATIO[:3]
    out = fm.simulate({"G": np.full(3, TRUTH["G"]), "mu": np.full(3, TRUTH["mu"])}, rmax, req, np.abs(t[4:]))
    meta = {"material": "synthetic nhkv", "forward": {"bubble": "polytropic"}, "experiments": {}}
    tc = rmax / np.sqrt(101325.0 / 1064.0)
    for i in range(3):
        R = np.concatenate([out.R_star[i, 4:0:-1], out.R_star[i]]) * rmax[i]  # mirrored growth frames
        name = f"exp_{i + 1:03d}.csv"
        with open(d / name, "w") as fh:
            fh.write("t_s,R_m\n")
            for a, b in zip(t * tc[i] + 1e-5, R):
                fh.write(f"{float(a)!r},{float(b)!r}\n")
        meta["experiments"][name] = {"Req_m": float(req[i])}
    (d / "meta.json").write_text(json.dumps(meta))
    return d


def _fit(args, expect=0):
    res = CliRunner().invoke(main, ["fit", *map(str, args)])
    assert res.exit_code == expect, res.output
    return res


@pytest.mark.parametrize(
    "method,sets",
    [
        ("imr", ["n_G=31", "n_mu=21", "G_max=15e3", "mu_max=0.2"]),
        ("pimr", ["n_G=40", "n_mu=30"]),
        ("en4dvar", ["n_ens=16", "n_runs=2", "n_iter=3", "n_draws=6"]),
        ("mienks", ["n_ens=16", "n_iter=3", "L=40", "h=20", "n_draws=20"]),
    ],
)
def test_fit_every_method(dataset, tmp_path, method, sets):
    import arviz as az

    out = tmp_path / method
    args = [dataset, "--method", method, "--model", "nhkv", "--out", out, "--seed", 3]
    for s in sets:
        args += ["--set", s]
    res = _fit(args)
    assert "%|" not in res.output  # no progress bar off a terminal
    summary = json.loads((out / "summary.json").read_text())
    for key in ("method", "model", "parameters", "seed", "n_experiments", "runtime_s", "estimate", "fit"):
        assert key in summary
    assert summary["method"] == method and summary["seed"] == 3 and summary["n_experiments"] == 3
    assert summary["parameters"] == ["G", "mu"]
    for p in ("G", "mu"):
        e = summary["estimate"][p]
        assert set(e) >= {"mean", "sd", "hdi95"} and len(e["hdi95"]) == 2
    assert summary["forward"]["options"]["bubble"] == "polytropic"  # meta.json's forward block
    assert summary["fit"]["n_samples"] > 0
    if method in ("imr", "en4dvar"):
        assert summary["estimate"]["G"]["mean"] == pytest.approx(TRUTH["G"], rel=0.1)
        assert summary["estimate"]["mu"]["mean"] == pytest.approx(TRUTH["mu"], rel=0.1)
    if method == "mienks":
        assert len(summary["windows"]) == 5
        w = summary["windows"][0]
        assert set(w) >= {"index", "t_star", "G", "mu", "cov", "prior_weight", "prior_dominated"}
        assert np.shape(w["cov"]) == (2, 2)
        # the prior's share of each window mean: in [0, 1], and the warning names exactly the flagged windows
        from imrbayes.ensemble.windows import PRIOR_WEIGHT_LIMIT

        for x in summary["windows"]:
            # a share of the prior mean's offset (the diagonal of a product of gains: a correlated pair can
            # make it slightly negative, never above 1)
            assert all(-0.05 <= v <= 1.0 for v in x["prior_weight"].values()), x["prior_weight"]
            assert x["prior_dominated"] == (max(x["prior_weight"].values()) > PRIOR_WEIGHT_LIMIT)
        flagged = [x["index"] for x in summary["windows"] if x["prior_dominated"]]
        assert summary["details"]["prior_dominated_windows"] == flagged
        assert ("prior-dominated" in res.output) == bool(flagged)
        assert summary["time_resolved"][0]["t_star"] == 0.0 and "G" in summary["time_resolved"][0]
    dt = az.from_netcdf(out / "posterior.nc")
    assert {"posterior", "observed_data"} <= set(dt.children)
    s = az.summary(dt, kind="stats", round_to="none")
    assert np.all(np.isfinite(s["mean"]))
    if method == "mienks":  # each window's first t*, a coordinate of the posterior's windows
        starts = dt["posterior"]["window_start"]
        assert starts.dims == ("window",) and list(starts.values) == [w["t_star"][0] for w in summary["windows"]]
    if method == "en4dvar":
        assert "log_likelihood" in dt.children
        assert dict(dt["log_likelihood"].sizes) == {"chain": 1, "draw": 6, "experiment": 3, "time": 120}
    figs = {p.name for p in (out / "figures").iterdir()}
    assert "fit.png" in figs
    assert {"imr": "landscape.png", "pimr": "landscape.png", "en4dvar": "experiments.png", "mienks": "parameters.png"}[
        method
    ] in figs


def test_config_file_and_command_line_precedence(dataset, tmp_path):
    cfg = tmp_path / "run.toml"
    cfg.write_text(
        '[fit]\nmethod = "imr"\nseed = 5\nquiet = true\n[fit.imr]\nn_G = 9\nn_mu = 7\n'
        '[fit.forward]\nbubble = "polytropic"\n'
    )
    out = tmp_path / "o"
    res = _fit([dataset, "--config", cfg, "--out", out, "--seed", 7, "--set", "n_mu=8"])
    assert res.output == ""
    s = json.loads((out / "summary.json").read_text())
    assert s["seed"] == 7
    assert s["details"]["settings"]["n_G"] == 9 and s["details"]["settings"]["n_mu"] == 8


@pytest.mark.parametrize(
    "args,needle",
    [
        (["--method", "imr", "--set", "n_ens=3"], "unknown setting"),
        (["--method", "en4dvar", "--set", "n_ens=x"], "n_ens"),
        (["--method", "en4dvar", "--set", "rtps=2"], "rtps"),
        (["--method", "mienks", "--set", "L=500"], "window length"),
        (["--method", "mienks", "--set", "h=40"], "exceeds the window length"),
        (["--method", "en4dvar", "--set", "req_tail=bogus"], "req_tail"),
        (["--method", "en4dvar", "--set", "n_iter=0"], "n_iter"),
        (["--method", "en4dvar", "--set", "t_end=0.01"], "t_end"),
        (["--method", "pimr", "--set", "kappa=3"], "kappa"),
        (["--method", "imr", "--forward", "bubble=steam"], "bubble"),
        (["--method", "imr", "--prior", "G=6e3"], "--prior"),
        (["--method", "imr", "--model", "nosuchmodel"], "nosuchmodel"),
        (["--method", "imr", "--set", "window=collapse:7"], "collapse"),
        ([], "--method"),
    ],
)
def test_bad_input_exit_2(dataset, tmp_path, args, needle):
    res = CliRunner().invoke(main, ["fit", str(dataset), "--out", str(tmp_path / "x"), *args])
    assert res.exit_code == 2, res.output
    assert needle in res.output and "Traceback" not in res.output
    assert not (tmp_path / "x").exists(), "a refused run must leave no output folder behind"


def test_missing_data_exit_2(tmp_path):
    res = CliRunner().invoke(main, ["fit", str(tmp_path / "nope"), "--method", "imr"])
    assert res.exit_code == 2 and "Traceback" not in res.output


def test_validate_quick_cases(tmp_path):
    out = tmp_path / "val"
    res = CliRunner().invoke(
        main,
        [
            "validate",
            "--suite",
            "quick",
            "--case",
            "fusion-linear-gaussian",
            "--case",
            "imr-recovery",
            "--out",
            str(out),
        ],
    )
    assert res.exit_code == 0, res.output
    rep = json.loads((out / "validation.json").read_text())
    assert rep["passed"] and [c["name"] for c in rep["cases"]] == ["fusion-linear-gaussian", "imr-recovery"]
    assert (out / "figures" / "imr_landscape.png").exists()
    bad = CliRunner().invoke(main, ["validate", "--case", "nope", "--out", str(tmp_path / "v2")])
    assert bad.exit_code == 2 and "unknown case" in bad.output


@pytest.mark.slow
def test_validate_quick_suite(tmp_path):
    cases = [
        a
        for c in (
            "fusion-linear-gaussian",
            "pimr-collapse-time",
            "imr-recovery",
            "en4dvar-verification",
            "mienks-verification",
        )
        for a in ("--case", c)
    ]
    res = CliRunner().invoke(main, ["validate", "--suite", "quick", *cases, "--out", str(tmp_path / "val")])
    assert res.exit_code == 0, res.output


@pytest.mark.slow
def test_validate_second_truth_case(tmp_path):
    """G 2 kPa, mu 0.05 Pa s, Rmax/Req 9 (far in the paper prior's tail), default likelihood: both
    methods' gel-level estimates within 10 % with the truth inside their 95 % intervals, and
    MIEnKS-MDA's data-decided windows hold it (docs/validation.md, 'Second case'; about 2 minutes)."""
    out = tmp_path / "val"
    res = CliRunner().invoke(main, ["validate", "--suite", "quick", "--case", "second-truth", "--out", str(out)])
    assert res.exit_code == 0, res.output
    m = json.loads((out / "validation.json").read_text())["cases"][0]["metrics"]
    for method in ("en4dvar", "mienks"):
        for name, truth in m["truth"].items():
            est = m[method]["estimate"][name]
            assert abs(est["mean"] / truth - 1) < 0.10 and est["hdi95"][0] <= truth <= est["hdi95"][1], (method, name)
    mi = m["mienks"]
    assert mi["n_decided"] >= mi["n_windows"] // 2
    assert all(k >= 0.9 * mi["n_decided"] for k in mi["decided_windows_containing_truth"].values())


@pytest.mark.slow
def test_validate_mcmc_layer_can_fail(tmp_path):
    """The constructed non-Gaussian window (a curved ridge around the first collapse) is flagged
    against even its own moment-matched Gaussian (suite case ``mcmc-non-gaussian``). With the DE and
    stretch moves the window did not converge within its cap (R-hat 1.01-1.014, tail ESS 156-230:
    undecided, once an xfail); the adapted independence proposal converges on it."""
    out = tmp_path / "val"
    res = CliRunner().invoke(main, ["validate", "--suite", "quick", "--case", "mcmc-non-gaussian", "--out", str(out)])
    assert res.exit_code == 0, res.output
    m = json.loads((out / "validation.json").read_text())["cases"][0]["metrics"]
    assert m["agree"] is False and m["converged"] and abs(m["kl_sym"]) < 1e-9
    assert m["kl_sample"] > 0.1 and m["negentropy"]["estimate"] > m["negentropy"]["null_q99"]
    assert (out / "figures" / "mcmc_non_gaussian_pair.png").exists()


@pytest.mark.slow
def test_validate_mcmc_agreement_case(tmp_path):
    """Verification case: MIEnKS window Gaussians agree with MCMC wherever the window is decided and
    well identified (suite case ``mcmc-agreement``; about 5 minutes)."""
    out = tmp_path / "val"
    res = CliRunner().invoke(main, ["validate", "--suite", "quick", "--case", "mcmc-agreement", "--out", str(out)])
    assert res.exit_code == 0, res.output
    m = json.loads((out / "validation.json").read_text())["cases"][0]["metrics"]
    assert m["n_checked"] >= 3


def test_fit_names_the_constants_and_where_they_came_from(dataset, tmp_path):
    """G rests on the gel's density (docs/validation.md 2a''): the run says which constants it used."""
    args = ["--method", "imr", "--model", "nhkv", "--set", "n_G=11", "--set", "n_mu=9"]
    res = _fit([dataset, *args, "--out", tmp_path / "a"])
    assert "rho 1064 kg/m^3 (default)" in res.output and "kappa 1.47 (default)" in res.output
    d = tmp_path / "data"
    d.mkdir()
    for f in dataset.iterdir():
        (d / f.name).write_bytes(f.read_bytes())
    meta = json.loads((d / "meta.json").read_text())
    meta["physics"] = {"rho": 998.2}
    (d / "meta.json").write_text(json.dumps(meta))
    res = _fit([d, *args, "--out", tmp_path / "b"])
    assert "rho 998.2 kg/m^3 (meta.json)" in res.output and "S 0.07 N/m (default)" in res.output
    assert json.loads((tmp_path / "b" / "summary.json").read_text())["forward"]["physics"]["rho"] == 998.2
