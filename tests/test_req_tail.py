"""Req from the model's own tail (``req_tail=model``): a thermal bubble's record still settles from
above at its end, so the preprocessing's tail mean overstates Req; the forward model, run over the
same frames, says by how much."""

import numpy as np
import pytest

from imrbayes.diagnosis.models import BASELINE, make_candidate
from imrbayes.diagnosis.synthetic import camera_obs
from imrbayes.ensemble import En4DVarSettings, fit_en4dvar
from imrbayes.ensemble.req_tail import model_tail_req
from imrbayes.errors import InputError
from imrbayes.forward import ForwardOptions, Runner


def _truth(truth):
    ex = truth["experiments"]
    return (
        np.array([e["req_m"] for e in ex]),
        np.array([e["rmax_m"] for e in ex]),
        np.array([truth["theta"][k] for k in ("G", "mu")]),
    )


def test_model_tail_undoes_the_tail_means_bias_on_thermal_records():
    """Noise-free camera records of a thermal bubble (data on a finer grid than the fit's): the tail
    mean is 1.3-1.6 % above the true Req (measured); corrected by the model at the true material and
    Rmax it is within 0.2 %, and the factor is the tail's excess over Req (> 1)."""
    opts = ForwardOptions(bubble="thermal")
    obs, truth = camera_obs("none", 0, opts, n_exp=3, noise="none")
    req, rmax, theta = _truth(truth)
    assert [t.size for t in obs.req_tail_t] == [20, 20, 20]
    assert all(np.all(t > c) and np.all(np.diff(t) > 0) for t, c in zip(obs.req_tail_t, obs.t_collapse_star))
    before = obs.req_m / req - 1
    assert np.all(before > 0.005), before
    base = make_candidate(BASELINE.key, opts)
    obs2, factor = model_tail_req(Runner(base.fm), obs, theta, rmax)
    after = obs2.req_m / req - 1
    assert np.all(np.abs(after) < 0.002), after
    assert np.allclose(factor, obs.req_m / obs2.req_m) and np.all(factor > 1.005)
    # the Req prior keeps its relative sd; nothing else of the observations moves
    assert np.allclose(obs2.nuisance_sd[:, 2] / obs2.req_m, obs.nuisance_sd[:, 2] / obs.req_m)
    assert np.array_equal(obs2.R_star, obs.R_star) and np.array_equal(obs2.rmax_m, obs.rmax_m)


def test_records_without_a_measured_tail_keep_their_req():
    """Req given (no frames averaged): factor 1, Req unchanged."""
    opts = ForwardOptions(bubble="polytropic")
    obs, truth = camera_obs("none", 1, opts, n_exp=2, noise="none")
    req, rmax, theta = _truth(truth)
    obs.req_tail_t = [np.empty(0), obs.req_tail_t[1]]
    obs2, factor = model_tail_req(Runner(make_candidate(BASELINE.key, opts).fm), obs, theta, rmax)
    assert factor[0] == 1.0 and obs2.req_m[0] == obs.req_m[0]
    assert np.isfinite(factor[1])


def test_en4dvar_req_tail_model_runs_two_passes_and_says_so():
    """``req_tail=inline`` with one cycle (no cycle to move Req before) runs as two passes: the estimate is the second pass's, ``details["req_tail"]`` gives each
    experiment's factor, the first pass's estimate and both Req prior centres; the paper's
    likelihood and unknown values are refused."""
    opts = ForwardOptions(bubble="polytropic")
    obs, truth = camera_obs("none", 2, opts, n_exp=2)
    base = make_candidate(BASELINE.key, opts)
    st = dict(n_ens=12, n_runs=1, n_iter=2, max_iter=2, screen=0, loglik=False, n_draws=1)
    res = fit_en4dvar(base.fm, obs, base.space, En4DVarSettings(**st, req_tail="inline"), seed=0)
    info = res.details["req_tail"]
    assert info["method"] == "model" and len(info["factor"]) == 2
    assert np.allclose(np.array(info["req_tail_mean_m"]) / np.array(info["req_prior_mean_m"]), info["factor"])
    assert set(info["first_pass_estimate"]) == {"G", "mu"}
    first = res.details["alternative_estimates"]["req_tail_first_pass"]
    assert {k: first[k]["mean"] for k in ("G", "mu")} == info["first_pass_estimate"]
    # the first pass is the quick one (one cycle, no screening), whatever the fit's own settings
    assert info["first_pass_settings"]["n_runs"] == 1 and info["first_pass_settings"]["screen"] == 0
    assert all(np.isfinite(res.estimate[k]["mean"]) for k in ("G", "mu"))
    # each experiment's reported Req prior is the corrected one
    for p, r in zip(res.per_experiment, info["req_prior_mean_m"]):
        assert p["nuisance"]["req_m"]["prior_mean"] == pytest.approx(r)
    with pytest.raises(InputError, match="'mean' or 'inline'"):
        En4DVarSettings(req_tail="fit").check()
    with pytest.raises(InputError, match="'mean' or 'inline'"):
        En4DVarSettings(req_tail="model").check()
    with pytest.raises(InputError, match="'inline' needs the default likelihood"):
        En4DVarSettings(likelihood="paper", req_tail="inline").check()


def test_a_given_start_replaces_the_first_pass():
    """``req_tail_start`` (diagnose's least-squares baseline): no first pass is run; the factors
    are the model's tail at the given material and Rmax (per bubble), and the record says where
    they came from; a start that does not match the records is refused."""
    from imrbayes.ensemble.req_tail import ReqTailStart

    opts = ForwardOptions(bubble="polytropic")
    obs, truth = camera_obs("none", 2, opts, n_exp=2)
    req, rmax, theta = _truth(truth)
    base = make_candidate(BASELINE.key, opts)
    st = dict(n_ens=12, n_runs=1, n_iter=2, max_iter=2, screen=0, loglik=False, n_draws=1)
    per_bubble = np.stack([theta, theta * [1.1, 0.9]])
    start = ReqTailStart(theta_si=per_bubble, rmax_m=rmax, source="test fit")
    given = fit_en4dvar(
        base.fm, obs, base.space, En4DVarSettings(**st, req_tail="inline"), seed=0, req_tail_start=start
    )
    two = fit_en4dvar(base.fm, obs, base.space, En4DVarSettings(**st, req_tail="inline"), seed=0)
    info = given.details["req_tail"]
    _, want = model_tail_req(Runner(base.fm), obs, per_bubble, rmax)
    assert np.allclose(info["factor"], want, rtol=0, atol=1e-12) and not np.allclose(want, 1.0)
    assert info["start"]["source"] == "test fit" and "test fit" in info["note"]
    assert "first_pass_estimate" not in info and "req_tail_first_pass" not in given.details.get(
        "alternative_estimates", {}
    )
    # one pass's member runs instead of two passes'
    assert given.details["member_runs"] < two.details["member_runs"]
    with pytest.raises(ValueError, match="do not match"):
        fit_en4dvar(
            base.fm,
            obs,
            base.space,
            En4DVarSettings(**st, req_tail="inline"),
            seed=0,
            req_tail_start=ReqTailStart(theta_si=theta, rmax_m=rmax[:1], source="bad"),
        )
    # given exactly where the first pass ended, the fit is the two-pass fit: the same factors, the
    # same unit seeds (one tag for both paths), the same estimate
    t2 = two.details["req_tail"]
    same = fit_en4dvar(
        base.fm,
        obs,
        base.space,
        En4DVarSettings(**st, req_tail="inline"),
        seed=0,
        req_tail_start=ReqTailStart(
            theta_si=[t2["first_pass_estimate"][k] for k in ("G", "mu")],
            rmax_m=np.array(t2["first_pass_rmax_m"]),
            source="first pass",
        ),
    )
    assert same.details["req_tail"]["factor"] == t2["factor"]
    assert all(same.estimate[k]["mean"] == two.estimate[k]["mean"] for k in ("G", "mu"))
    # req_tail=inline (the thermal default) with a start, or with one cycle (nothing to move Req
    # before), is this path: the same fits exactly
    inl = fit_en4dvar(base.fm, obs, base.space, En4DVarSettings(**st, req_tail="inline"), seed=0, req_tail_start=start)
    assert inl.details["req_tail"]["method"] == "model" and inl.details["req_tail"]["factor"] == info["factor"]
    assert all(inl.estimate[k]["mean"] == given.estimate[k]["mean"] for k in ("G", "mu"))
    one = fit_en4dvar(base.fm, obs, base.space, En4DVarSettings(**st, req_tail="inline"), seed=0)
    assert one.details["req_tail"]["factor"] == t2["factor"]
    assert all(one.estimate[k]["mean"] == two.estimate[k]["mean"] for k in ("G", "mu"))


def test_inline_moves_req_after_the_first_cycle():
    """``req_tail=inline``: one pass; each unit moves its Req origin after cycle 1 by the model's
    tail at its own posterior, and the reported Req prior centres are the moved ones."""
    opts = ForwardOptions(bubble="thermal")
    obs, truth = camera_obs("none", 0, opts, n_exp=2, noise="none")
    req, rmax, theta = _truth(truth)
    base = make_candidate(BASELINE.key, opts)
    st = dict(n_ens=12, n_runs=2, n_iter=2, max_iter=2, screen=0, loglik=False, n_draws=1)
    res = fit_en4dvar(base.fm, obs, base.space, En4DVarSettings(**st, req_tail="inline"), seed=0)
    info = res.details["req_tail"]
    assert info["method"] == "inline" and all(f > 1.003 for f in info["factor"])
    assert np.allclose(np.array(info["req_tail_mean_m"]) / np.array(info["req_prior_mean_m"]), info["factor"])
    # the moved centres are nearer the truth than the tail means (noise-free thermal records)
    assert np.all(np.abs(np.array(info["req_prior_mean_m"]) / req - 1) < np.abs(obs.req_m / req - 1))
    for p, r in zip(res.per_experiment, info["req_prior_mean_m"]):
        assert p["nuisance"]["req_m"]["prior_mean"] == pytest.approx(r)
    # the MCMC check's bubbles start from the moved Req too
    from imrbayes.mcmc.fit import fit_window_specs

    (spec,) = fit_window_specs(base.fm, obs, base.space, res)
    np.testing.assert_allclose(spec.target.start.req_m, info["req_prior_mean_m"], rtol=1e-12)


def test_req_tail_model_without_measured_tails_is_one_pass():
    """Every Req given (no frames averaged): the first pass is the answer, and it says so."""
    opts = ForwardOptions(bubble="polytropic")
    obs, truth = camera_obs("none", 2, opts, n_exp=2)
    obs.req_tail_t = [np.empty(0), np.empty(0)]
    base = make_candidate(BASELINE.key, opts)
    st = dict(n_ens=12, n_runs=1, n_iter=2, max_iter=2, screen=0, loglik=False, n_draws=1)
    one = fit_en4dvar(base.fm, obs, base.space, En4DVarSettings(**st, req_tail="inline"), seed=0)
    plain = fit_en4dvar(base.fm, obs, base.space, En4DVarSettings(**st), seed=0)
    assert one.details["req_tail"]["factor"] == [1.0, 1.0] and "one pass" in one.details["req_tail"]["note"]
    assert one.estimate["G"]["mean"] == plain.estimate["G"]["mean"]
    assert one.details["member_runs"] == plain.details["member_runs"]


def test_auto_places_req_by_the_model_only_for_the_thermal_bubble():
    """``req_tail=auto`` (the default): ``inline`` with the thermal bubble and the default likelihood
    (its tail mean is high), ``mean`` with the polytropic bubble (settled) or the paper's likelihood
    (Req known); an explicit choice is kept."""
    from imrbayes.ensemble.en4dvar import req_tail_mode
    from imrbayes.forward import ForwardModel

    thermal, poly = ForwardModel("nhkv"), ForwardModel("nhkv", options={"bubble": "polytropic"})
    assert En4DVarSettings().req_tail == "auto"
    assert req_tail_mode(En4DVarSettings(), thermal) == "inline"
    assert req_tail_mode(En4DVarSettings(), poly) == "mean"
    assert req_tail_mode(En4DVarSettings(likelihood="paper"), thermal) == "mean"
    assert req_tail_mode(En4DVarSettings(req_tail="mean"), thermal) == "mean"
    assert req_tail_mode(En4DVarSettings(req_tail="inline"), poly) == "inline"


def test_the_mcmc_target_of_a_req_tail_fit_runs_at_the_moved_req():
    """The MCMC check samples the density the reported fit approximates: with the model's tail
    each experiment's Req prior is centred on the corrected value, so the target's bubbles start
    from that Req (not the preprocessing's tail mean) with the same nuisance prior sd."""
    from imrbayes.mcmc.fit import fit_window_specs

    opts = ForwardOptions(bubble="polytropic")
    obs, truth = camera_obs("none", 2, opts, n_exp=2)
    base = make_candidate(BASELINE.key, opts)
    st = dict(n_ens=12, n_runs=1, n_iter=2, max_iter=2, screen=0, loglik=False, n_draws=1)
    res = fit_en4dvar(base.fm, obs, base.space, En4DVarSettings(**st, req_tail="inline"), seed=0)
    moved = np.array(res.details["req_tail"]["req_prior_mean_m"])
    assert not np.allclose(moved, obs.req_m, rtol=1e-9, atol=0)
    (spec,) = fit_window_specs(base.fm, obs, base.space, res)
    np.testing.assert_allclose(spec.target.start.req_m, moved, rtol=1e-12)
    sd = np.array([p["nuisance"]["req_m"]["prior_sd"] for p in res.per_experiment])
    np.testing.assert_allclose(spec.target.nuisance_sd[:, 2], sd / moved, rtol=1e-9)


def test_req_shift_z_measures_the_fit_against_the_tail_in_tail_sd():
    """z = (fitted Req - tail Req) / tail sd per estimated experiment; an experiment whose Req was
    given (sd 0) or that the fit does not name is left out; the conflict bound is MIEnKS-MDA's."""
    from types import SimpleNamespace

    from imrbayes.ensemble.mienks import REQ_PRIOR_CONFLICT_Z
    from imrbayes.ensemble.req_tail import REQ_CONFLICT_Z, req_shift_z

    obs = SimpleNamespace(
        names=["a", "b", "c"],
        req_m=np.array([50e-6, 40e-6, 30e-6]),
        nuisance_sd=np.array([[0, 0, 0.5e-6], [0, 0, 0.0], [0, 0, 2e-6]]),
    )
    fit = [
        {"name": "a", "nuisance": {"req_m": {"mean": 52e-6, "sd": 0.3e-6}}},
        {"name": "b", "nuisance": {"req_m": {"mean": 41e-6, "sd": 0.3e-6}}},  # given: skipped
        {"name": "c", "nuisance": {"req_m": {"mean": 29e-6, "sd": 0.4e-6}}},
        {"name": "x", "nuisance": {"req_m": {"mean": 1e-6, "sd": 0.4e-6}}},
    ]  # not in obs
    rows = req_shift_z(obs, fit)
    assert [q["experiment"] for q in rows] == ["a", "c"]
    assert rows[0]["z"] == pytest.approx(4.0) and rows[1]["z"] == pytest.approx(-0.5)
    assert rows[0]["fitted_req_sd_m"] == 0.3e-6 and rows[1]["preprocessing_req_sd_m"] == 2e-6
    assert REQ_CONFLICT_Z == REQ_PRIOR_CONFLICT_Z == 3.0
