"""The wide prior, the global search and the fit check: a start where the data are, G = 0 reachable,
and a headline that never outruns the fit (docs/methods.md, "Priors", "Global start", "Fit check")."""

import json
import math

import numpy as np
import pytest
from _ens_synth import model, observations

from imrbayes.ensemble import Observations, ParamSpace
from imrbayes.ensemble.adequacy import FIT_CHECK_THRESHOLD, annotate_estimate, fit_check
from imrbayes.ensemble.imr import grid_axis
from imrbayes.ensemble.problem import PAPER_PRIOR, lognormal_moments
from imrbayes.ensemble.result import FitResult
from imrbayes.ensemble.search import global_search
from imrbayes.errors import InputError
from imrbayes.forward import Runner


def noisy(truth, sd=3e-3, seed=0, n_exp=3):
    fm, obs = observations(n_exp=n_exp, truth=truth)
    rng = np.random.default_rng(seed)
    Y = obs.R_star + sd * rng.standard_normal(obs.R_star.shape)
    Y[:, 0] = 1.0
    return fm, Observations(obs.t_star, Y, obs.P, obs.rmax_m, obs.req_m, noise_sd=np.full(obs.n_exp, sd))


def test_wide_prior_has_the_stated_median_and_log_sd():
    fm = model()
    sp = ParamSpace.for_model(fm.constitutive, base="wide")
    assert sp.prior_name == "wide"
    np.testing.assert_allclose(sp.prior_mean, [math.log(3e3), math.log(0.03)], rtol=1e-12)
    np.testing.assert_allclose(np.sqrt(np.diag(sp.prior_cov)), [2.9, 2.9], rtol=1e-12)
    lo, hi = sp.describe()["central_95_si"]["G"]
    assert lo < 20.0 and hi > 5e5  # 10 Pa .. 0.9 MPa: liquids to stiff gels
    paper = ParamSpace.for_model(fm.constitutive, base="paper")
    assert paper.prior_si["G"] == PAPER_PRIOR["G"] and paper.prior_name == "paper"
    assert ParamSpace.for_model(fm.constitutive, {"G": (1e4, 1e3)}, base="wide").prior_name == "custom"
    with pytest.raises(InputError):
        ParamSpace.for_model(fm.constitutive, base="narrow")


def test_lognormal_moments_round_trip():
    mean, sd = lognormal_moments(0.03, 2.9)
    s2 = math.log1p((sd / mean) ** 2)
    assert math.isclose(math.sqrt(s2), 2.9, rel_tol=1e-12)
    assert math.isclose(math.log(mean) - 0.5 * s2, math.log(0.03), rel_tol=1e-12)


def test_start_is_separate_from_the_prior():
    fm = model()
    sp = ParamSpace.for_model(fm.constitutive, base="wide")
    st = sp.with_start([math.log(2e5), math.log(0.5)], np.diag([0.5, 0.5]))
    np.testing.assert_array_equal(st.prior_mean, sp.prior_mean)
    np.testing.assert_array_equal(st.prior_cov, sp.prior_cov)
    np.testing.assert_allclose(st.start_mean, [math.log(2e5), math.log(0.5)])
    assert st.data_share(np.diag([2.9**2, 0.29**2])) == pytest.approx({"G": 0.0, "mu": 0.99})


@pytest.mark.parametrize("truth", [{"G": 3e3, "mu": 0.05}, {"G": 1e5, "mu": 0.02}])
def test_search_finds_a_gel_far_from_the_paper_prior(truth):
    fm, obs = noisy(truth)
    with Runner(fm) as run:
        res = global_search(fm, obs, run)
    # within one grid step (half a decade) of the truth on both axes
    assert abs(math.log10(res.best["G"] / truth["G"])) <= 0.5 + 1e-9
    assert abs(math.log10(res.best["mu"] / truth["mu"])) <= 0.5 + 1e-9
    assert not res.zero_modulus["consistent_with_zero"]
    mean, cov = res.start(ParamSpace.for_model(fm.constitutive, base="wide"))
    assert abs(mean[0] - math.log(truth["G"])) < 1.2


def test_search_calls_a_liquid_a_liquid():
    fm, obs = noisy({"G": 0.0, "mu": 0.05})
    with Runner(fm) as run:
        res = global_search(fm, obs, run)
    z = res.zero_modulus
    assert z["consistent_with_zero"] and z["lr"] <= z["threshold"]
    assert z["best_liquid"]["mu"] == pytest.approx(0.05, rel=0.05)
    assert 10.0 < z["upper95_pa"] < 1e3  # the data bound G from above, far below a gel's
    assert abs(math.log10(res.best["mu"] / 0.05)) <= 0.5 + 1e-9


def _result(obs, fitted):
    return FitResult("x", "nhkv", ("G", "mu"), {}, fitted, np.ones_like(fitted, dtype=bool))


def test_fit_check_reads_the_residual_against_the_noise():
    fm, obs = noisy({"G": 3e3, "mu": 0.05}, sd=2e-3)
    _, clean = observations(n_exp=3, truth={"G": 3e3, "mu": 0.05})
    ok = fit_check(_result(obs, clean.R_star), obs)
    assert ok["described"] and 0.7 < ok["residual_to_noise"] < 1.3  # the truth misses by the noise
    _, wrong = observations(n_exp=3, truth={"G": 3e4, "mu": 0.05})
    bad = fit_check(_result(obs, wrong.R_star), obs)
    assert not bad["described"] and bad["residual_to_noise"] > FIT_CHECK_THRESHOLD
    assert bad["message"].startswith("NHKV does not describe these records")


def test_annotate_says_consistent_with_zero_and_bounds():
    fm = model()
    sp = ParamSpace.for_model(fm.constitutive, base="wide")
    est = {"G": {"mean": 50.0, "sd": 40.0, "hdi95": [0.3, 120.0]}, "mu": {"mean": 0.05, "sd": 0.002}}
    search = {"zero_modulus": {"consistent_with_zero": True}}
    out = annotate_estimate(est, sp, np.diag([2.5**2, 0.04**2]), search)
    assert out["G"]["consistent_with_zero"] and out["G"]["upper95"] == 120.0
    assert out["G"]["bounded"] == {"lower": False, "upper": True}
    assert out["mu"]["bounded"] == {"lower": True, "upper": True}
    from imrbayes.cli.options import estimate_text

    assert estimate_text(out, {"estimate": out}).startswith("G consistent with 0 (95 % upper bound 0.12 kPa)")


def test_log_grid_keeps_zero_and_spans_the_range():
    g = grid_axis(0.0, 1e6, 12)
    assert g[0] == 0.0 and g[1] == pytest.approx(10.0) and g[-1] == pytest.approx(1e6)
    assert np.allclose(np.diff(np.log10(g[1:])), 0.5)
    m = grid_axis(1e-4, 10.0, 11)
    assert m[0] == pytest.approx(1e-4) and m[-1] == pytest.approx(10.0)
    np.testing.assert_allclose(grid_axis(0.0, 25e3, 5, "linear"), np.linspace(0, 25e3, 5))


def test_the_papers_likelihood_brings_the_papers_prior(tmp_path):
    """However the paper's likelihood is chosen, the default prior is the paper's and no global
    search runs (the paper's method, reproducible); the default likelihood gets the wide prior."""
    from click.testing import CliRunner

    from imrbayes.cli import main

    ds = tmp_path / "ds"
    sim = ["simulate", "--model", "nhkv", "--param", "G=7.29e3", "--param", "mu=0.088", "--n-exp", "2"]
    sim += ["--forward", "bubble=polytropic", "--t-end", "1.0", "--seed", "0", "--out", str(ds), "--quiet"]
    assert CliRunner().invoke(main, sim).exit_code == 0
    tiny = ["--forward", "bubble=polytropic", "--set", "n_ens=8", "--set", "n_runs=1", "--n-steps", "40", "--quiet"]
    names = {}
    for tag, extra in (("set", ["--set", "likelihood=paper"]), ("option", ["--likelihood", "paper"]), ("default", [])):
        out = tmp_path / tag
        res = CliRunner().invoke(main, ["fit", str(ds), "--method", "en4dvar", *tiny, *extra, "--out", str(out)])
        assert res.exit_code == 0, res.output
        summary = json.loads((out / "summary.json").read_text())
        names[tag] = (summary["prior"]["name"], "search" in summary)
    assert names == {"set": ("paper", False), "option": ("paper", False), "default": ("wide", True)}
