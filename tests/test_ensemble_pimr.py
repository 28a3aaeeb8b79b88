"""pIMR's closed-form collapse time against simulated first-collapse times, term by term and over
the prior range (methods.md §2)."""

import math

import numpy as np
import pytest
from _ens_synth import model, space

from imrbayes.ensemble import Observations, PIMRSettings, fit_pimr
from imrbayes.ensemble.pimr import T_RC, collapse_time, contents_factor
from imrbayes.forward import ForwardModel, Runner

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
