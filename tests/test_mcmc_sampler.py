"""The MCMC sampler and its target: the emcee runner, the target density, the block moves and
the Laplace placement."""

import json

import arviz as az
import numpy as np
import pytest
from _mcmc_synth import TRUTH, GaussianTarget, Interrupted, model, model as model_poly, observations, paper_prior
from scipy import integrate

from imrbayes.ensemble import ParamSpace
from imrbayes.errors import InputError
from imrbayes.forward import BatchState, Propagation
from imrbayes.mcmc.laplace import quadratic_placement
from imrbayes.mcmc.sampler import MCMCSettings, emcee_moves, independent_walkers, run_mcmc
from imrbayes.mcmc.target import WindowTarget, fitting_window_target, loglik_pointwise, window_target_from_ensemble

# emcee runner: seeded independent ensembles, lockstep batching, HDF5 resume, DataTree output,
# and recovery of known parameters on a cheap polytropic window.


MEAN = np.array([1.0, -2.0])
COV = np.array([[0.04, 0.018], [0.018, 0.09]])


def _toy(n_steps=400, **kw):
    """The earlier settings (fixed length, stretch move, start at the given spread)."""
    return MCMCSettings(
        **{
            "n_walkers": 16,
            "n_steps": n_steps,
            "n_chains": 4,
            "stop": "fixed",
            "moves": "stretch",
            "init_scale": 1.0,
            **kw,
        }
    )


def test_gaussian_toy_posterior_and_datatree():
    tg = GaussianTarget(MEAN, COV)
    run = run_mcmc(tg, MEAN + 0.3, 4 * COV, _toy(1500), seed=3)
    assert run.chain.shape == (4, 1500, 16, 2) and run.n_chains == 4
    d = run.diagnostics()
    assert d["all_tau_ok"] and 1.0 < run.tau_max < 1500 / 50
    assert np.all((run.acceptance > 0.4) & (run.acceptance < 0.9))
    assert len(set(run.seeds)) == 4
    dt = run.to_datatree()
    post = dt["posterior"]
    assert post["x0"].dims == ("chain", "draw") and post.sizes["chain"] == 4
    assert post.sizes["draw"] <= 1000
    # walker-major draws: each walker's kept steps are contiguous
    w = dt["sample_stats"]["walker"].values[0]
    st = dt["sample_stats"]["step"].values[0]
    k = np.count_nonzero(w == 0)
    assert np.all(w[:k] == 0) and np.all(np.diff(st[:k]) == run.thin) and st[0] == run.burn + 0
    s = az.summary(dt, round_to="none")
    x = np.stack([post["x0"].values.ravel(), post["x1"].values.ravel()], axis=1)
    np.testing.assert_allclose(x.mean(axis=0), MEAN, atol=0.03)
    np.testing.assert_allclose(np.cov(x.T), COV, rtol=0.15, atol=0.004)
    assert s["r_hat"].max() < 1.01 and s["ess_bulk"].min() > 400
    # ESS of the ensemble chains agrees with emcee's tau: draws / (tau / thin), within a factor 2
    ess_tau = run.n_walkers * (run.n_steps - run.burn) / run.tau.mean() * 4
    assert 0.5 < s.loc["x0", "ess_bulk"] / ess_tau < 2.0
    json.loads(dt.attrs["diagnostics_json"])
    # end to end: the exact Gaussian agrees with this MCMC run
    from imrbayes.mcmc.compare import compare_window

    e = compare_window(MEAN, COV, dt, ["x0", "x1"], [False, False], diagnostics=d)
    assert e["agree"] is True, e["notes"]


def test_seeded_and_lockstep_identical_to_sequential():
    a = run_mcmc(GaussianTarget(MEAN, COV), MEAN, COV, _toy(60), seed=5)
    b = run_mcmc(GaussianTarget(MEAN, COV), MEAN, COV, _toy(60, lockstep=False), seed=5)
    c = run_mcmc(GaussianTarget(MEAN, COV), MEAN, COV, _toy(60), seed=6)
    np.testing.assert_array_equal(a.chain, b.chain)
    np.testing.assert_array_equal(a.log_prob, b.log_prob)
    assert not np.allclose(a.chain[:, -1], c.chain[:, -1])
    # different ensembles start differently
    assert not np.allclose(a.chain[0, 0], a.chain[1, 0])


@pytest.mark.parametrize("lockstep", [True, False])
def test_hdf5_resume_after_interruption_appends_and_continues(tmp_path, lockstep):
    path = tmp_path / "mcmc.h5"
    ref = run_mcmc(
        GaussianTarget(MEAN, COV),
        MEAN,
        COV,
        _toy(80, lockstep=lockstep),
        seed=1,
        backend=tmp_path / "ref.h5",
        name="window_00",
    )
    # interrupted after ~ 30 steps (log-prob calls: 2 per step per ensemble, or per round in lockstep)
    with pytest.raises(Interrupted):
        run_mcmc(
            GaussianTarget(MEAN, COV, fail_after=60),
            MEAN,
            COV,
            _toy(80, lockstep=lockstep),
            seed=1,
            backend=path,
            name="window_00",
        )
    import emcee

    saved = [
        emcee.backends.HDFBackend(str(path), name=f"window_00/chain_{c}", read_only=True).iteration for c in range(4)
    ]
    assert 0 < max(saved) < 80 and (min(saved) > 0 or not lockstep)  # one by one: later chains not started
    res = run_mcmc(
        GaussianTarget(MEAN, COV), MEAN, COV, _toy(80, lockstep=lockstep), seed=1, backend=path, name="window_00"
    )
    assert res.steps_run == [80 - n for n in saved]
    np.testing.assert_array_equal(res.chain, ref.chain)  # as if never interrupted
    # run_mcmc(None, n) semantics: a longer total appends to the same groups
    more = run_mcmc(
        GaussianTarget(MEAN, COV), MEAN, COV, _toy(100, lockstep=lockstep), seed=1, backend=path, name="window_00"
    )
    assert more.steps_run == [20] * 4 and more.chain.shape[1] == 100
    np.testing.assert_array_equal(more.chain[:, :80], ref.chain)
    assert more.backend == {"path": str(path), "name": "window_00"}
    with pytest.raises(InputError):  # other walkers: refuse, don't clobber
        run_mcmc(GaussianTarget(MEAN, COV), MEAN, COV, _toy(100, n_walkers=8), backend=path, name="window_00")


def test_settings_are_checked():
    with pytest.raises(InputError):
        MCMCSettings(n_walkers=3).check(2)
    with pytest.raises(InputError):
        MCMCSettings(n_chains=1).check(2)


def test_polytropic_window_recovers_truth():
    """emcee on a synthetic window (2 experiments to t* = 1, sd 0.01 noise): the truth lies inside the
    99 % posterior interval of both parameters, and the DataTree carries the pointwise log-likelihood."""
    fm, obs = observations(n_exp=2, n_steps=40, noise=0.01, seed=11)
    tg = fitting_window_target(fm, obs, paper_prior(), weight="plain")
    z0 = np.log([6.5e3, 0.1])
    run = run_mcmc(
        tg, z0, np.diag([0.1, 0.1]) ** 2, MCMCSettings(n_walkers=8, n_steps=300, max_draws=240, stop="fixed"), seed=0
    )
    e0 = tg.n_evals
    dt = run.to_datatree(tg)
    assert tg.n_evals == e0  # every kept draw was evaluated by emcee: no forward solve
    # the remembered predictions give what a fresh target computes from scratch
    fresh = fitting_window_target(fm, obs, paper_prior(), weight="plain")
    draws = np.concatenate(
        [dt["posterior"]["log_G"].values[..., None], dt["posterior"]["log_mu"].values[..., None]], axis=-1
    ).reshape(-1, 2)
    np.testing.assert_allclose(
        dt["log_likelihood"]["R"].values.reshape(draws.shape[0], 2, 40), fresh.pointwise(draws), rtol=1e-12, atol=0
    )
    assert fresh.n_evals == draws.shape[0]
    # a memo too small for one batch still gives the same numbers (forward solves instead)
    fresh.forget()
    fresh.memo_bytes = 0
    np.testing.assert_array_equal(fresh.pointwise(draws[:10]), dt["log_likelihood"]["R"].values.reshape(-1, 2, 40)[:10])
    # a budget of five predictions keeps the last five, and the answer is the same
    fresh.memo_bytes = 5 * fresh.n_exp * fresh.t_eval.size * 8
    fresh.pointwise(draws[:10])
    assert len(fresh._memo) == 5
    np.testing.assert_array_equal(fresh.pointwise(draws[:10]), dt["log_likelihood"]["R"].values.reshape(-1, 2, 40)[:10])
    assert dt["log_likelihood"]["R"].dims == ("chain", "draw", "experiment", "time")
    assert dt["log_likelihood"]["R"].shape[2:] == (2, 40)
    assert dt["observed_data"]["R"].shape == (2, 40)
    s = az.summary(dt, var_names=["log_G", "log_mu"], ci_prob=0.99, round_to="none")
    for name, z in (("log_G", np.log(TRUTH["G"])), ("log_mu", np.log(TRUTH["mu"]))):
        assert s.loc[name, "eti99_lb"] < z < s.loc[name, "eti99_ub"], (name, s.loc[name].to_dict())
    assert s["r_hat"].max() < 1.05
    assert run.n_evals >= run.n_chains * 8 * 300
    loo = az.loo(dt)
    assert np.isfinite(loo.elpd)


@pytest.mark.slow
def test_en4dvar_fused_gaussian_matches_mcmc_on_verification_case():
    """methods.md §5 data (5 experiments, paper noise, polytropic bubble), fitting window to t* = 1:
    the fused En4D-Var Gaussian and emcee on the same density (weights 1/N_t) agree (KL < 0.1 nats,
    W2 < 0.5 sd) and the truth lies inside the MCMC 95 % interval. (Measured: KL 0.028 / 0.027, W2 0.21 sd,
    sample KL 0.071, 61 tau, agree; about 4 minutes on two cores.)"""
    from imrbayes.ensemble import En4DVarSettings, ParamSpace, fit_en4dvar
    from imrbayes.mcmc.compare import compare_window
    from imrbayes.validation.suite import verification_data

    fm = model_poly()
    obs = verification_data(fm, 0)
    space = ParamSpace.for_model(fm.constitutive)
    res = fit_en4dvar(fm, obs, space, En4DVarSettings(t_end=1.0, n_draws=1, loglik=False), seed=0)
    tg = fitting_window_target(fm, obs, paper_prior(), t_end=1.0, weight="en4dvar")
    run = run_mcmc(
        tg,
        res.mean_internal,
        res.cov_internal,
        MCMCSettings(n_walkers=16, n_steps=2000, stop="fixed", moves="stretch", init_scale=1.0),
        seed=0,
    )
    dt = run.to_datatree(tg, loglik=False)
    e = compare_window(
        res.mean_internal, res.cov_internal, dt, space.names, space.positive, diagnostics=run.diagnostics()
    )
    assert e["kl_sym"] < 0.1 and e["w2"] < 0.5, e["notes"]
    assert e["mcmc"]["converged"], e["notes"]
    s = az.summary(dt, var_names=["G", "mu"], ci_prob=0.95, round_to="none")
    for n in ("G", "mu"):
        assert s.loc[n, "eti95_lb"] < TRUTH[n] < s.loc[n, "eti95_ub"]


class _FailingTarget(GaussianTarget):
    """Raises ValueError on the log-prob calls in ``bad`` (1-based call numbers)."""

    def __init__(self, bad):
        super().__init__(MEAN, COV)
        self.bad = set(bad)

    def log_prob(self, Z):
        if self.n_calls + 1 in self.bad:
            self.n_calls += 1
            raise ValueError("solver exploded")
        return super().log_prob(Z)


def test_a_failed_ensemble_is_contained_and_reported():
    # one by one: call 1 starts every ensemble, then 2 calls per step; call 170 falls in ensemble 1
    run = run_mcmc(_FailingTarget({170}), MEAN, COV, _toy(80, lockstep=False), seed=1)
    assert run.n_chains == 3 and list(run.failed_chains) == [1]
    assert "solver exploded" in run.failed_chains[1]
    assert run.diagnostics()["failed_chains"] == {"1": run.failed_chains[1]}
    ref = run_mcmc(GaussianTarget(MEAN, COV), MEAN, COV, _toy(80, lockstep=False), seed=1)
    np.testing.assert_array_equal(run.chain, ref.chain[[0, 2, 3]])  # the others are untouched
    assert run.to_datatree()["posterior"].sizes["chain"] == 3
    from imrbayes.mcmc.compare import compare_window  # compare.json names the failure in its notes

    e = compare_window(MEAN, COV, run.to_datatree(), list(run.names), run.positive, diagnostics=run.diagnostics())
    assert e["mcmc"]["sampler"]["failed_chains"] == {"1": run.failed_chains[1]}
    assert "1 emcee ensemble(s) failed and were left out (ensemble 1: " in e["notes"]
    # when the shared batch fails every ensemble fails: a clear error, not a silent empty result
    with pytest.raises(RuntimeError, match="4 of 4 ensembles failed"):
        run_mcmc(_FailingTarget(range(30, 10_000)), MEAN, COV, _toy(80, lockstep=True), seed=1)


# ---------------------------------------------------------------- stop on convergence


def _conv(**kw):
    return MCMCSettings(**{"n_walkers": 8, "n_steps": 3000, **kw})


def test_stops_on_convergence_and_the_answer_is_right():
    """Default settings (independence t + DE, 8 walkers, over-dispersed start): sampling stops at the first
    check where R-hat, bulk/tail ESS and the tau rule hold -- well before the cap --, the stop point
    is trustworthy (50 tau by the tau of a 4x longer run), and the draws reproduce the exact
    Gaussian within their Monte-Carlo error."""
    from imrbayes.mcmc.compare import compare_window, mcmc_summary

    run = run_mcmc(GaussianTarget(MEAN, COV), MEAN + 0.3, 4 * COV, _conv(), seed=2)
    d = run.diagnostics()
    assert d["stop_reason"] == "converged" and not d["cap_hit"] and d["stop_rule"] == "converged"
    assert run.n_steps < 3000 and d["checks"][-1]["ok"] and d["checks"][-1]["n"] == run.n_steps
    assert all(not c["ok"] for c in d["checks"][:-1])
    assert d["moves"] == "indep:0.7,de:0.3"
    # the last check diagnosed exactly the draws compare.json sees
    dt = run.to_datatree()
    s = mcmc_summary(dt, ["x0", "x1"])
    assert max(s["r_hat"].values()) == pytest.approx(d["checks"][-1]["rhat_max"], rel=1e-12)
    assert min(s["ess_tail"].values()) == pytest.approx(d["checks"][-1]["ess_tail_min"], rel=1e-12)
    assert (
        max(s["r_hat"].values()) <= 1.01 and min(s["ess_bulk"].values()) >= 400 and min(s["ess_tail"].values()) >= 400
    )
    # not premature: the tau of a 4x longer run of the same ensembles says the chain is >= ~50 tau
    long = run_mcmc(
        GaussianTarget(MEAN, COV), MEAN + 0.3, 4 * COV, _conv(stop="fixed", n_steps=4 * run.n_steps), seed=2
    )
    np.testing.assert_array_equal(long.chain[:, : run.n_steps], run.chain)  # same chains, just longer
    assert run.n_steps >= 0.8 * 50 * long.tau_max, (run.n_steps, long.tau_max)
    # right answer within Monte-Carlo error (independent truth: the exact Gaussian)
    x = np.stack([dt["posterior"][v].values for v in ("x0", "x1")], axis=-1).reshape(-1, 2)
    mcse = np.array([s["mcse_mean"][v] for v in ("x0", "x1")])
    assert np.all(np.abs(x.mean(axis=0) - MEAN) < 4 * mcse), (x.mean(axis=0) - MEAN, mcse)
    np.testing.assert_allclose(np.cov(x.T), COV, rtol=0.2, atol=0.004)
    e = compare_window(MEAN, COV, dt, ["x0", "x1"], [False, False], diagnostics=d)
    assert e["mcmc"]["converged"] and e["agree"] is True, e["notes"]


def test_hard_cap_is_reported_and_makes_the_comparison_undecided():
    from imrbayes.mcmc.compare import compare_window

    run = run_mcmc(GaussianTarget(MEAN, COV), MEAN + 3.0, 25 * COV, _conv(n_steps=40, min_steps=20), seed=0)
    d = run.diagnostics()
    assert run.n_steps == 40 and d["stop_reason"] == "cap" and d["cap_hit"] and d["cap"] == 40
    assert [c["n"] for c in d["checks"]] == [20, 40] and not d["checks"][-1]["ok"]
    e = compare_window(MEAN, COV, run.to_datatree(), ["x0", "x1"], [False, False], diagnostics=d)
    assert e["agree"] is None and "hard cap of 40 steps" in e["notes"]
    # the same draws with a cap-hit flag but otherwise converged diagnostics are still undecided
    ok = run_mcmc(GaussianTarget(MEAN, COV), MEAN, COV, _conv(), seed=1)
    e = compare_window(
        MEAN,
        COV,
        ok.to_datatree(),
        ["x0", "x1"],
        [False, False],
        diagnostics={**ok.diagnostics(), "cap_hit": True, "cap": ok.n_steps},
    )
    assert e["agree"] is None


def test_stop_rule_lockstep_equals_sequential_and_resume_stops_at_the_same_step(tmp_path):
    import emcee

    counted = GaussianTarget(MEAN, COV)
    ref = run_mcmc(counted, MEAN, COV, _conv(), seed=7, backend=tmp_path / "ref.h5", name="w")
    seq = run_mcmc(GaussianTarget(MEAN, COV), MEAN, COV, _conv(lockstep=False), seed=7)
    np.testing.assert_array_equal(ref.chain, seq.chain)
    assert ref.stop["reason"] == "converged" and len(ref.stop["checks"]) >= 2
    path = tmp_path / "cut.h5"
    with pytest.raises(Interrupted):  # one batched call per round: cut at 3/4 of the rounds
        run_mcmc(
            GaussianTarget(MEAN, COV, fail_after=3 * counted.n_calls // 4),
            MEAN,
            COV,
            _conv(),
            seed=7,
            backend=path,
            name="w",
        )
    cut = emcee.backends.HDFBackend(str(path), name="w/chain_0", read_only=True).iteration
    assert ref.stop["checks"][0]["n"] < cut < ref.n_steps  # after the first check, before the end
    lines = []
    res = run_mcmc(GaussianTarget(MEAN, COV), MEAN, COV, _conv(), seed=7, backend=path, name="w", log=lines.append)
    np.testing.assert_array_equal(res.chain, ref.chain)
    # the progress counts this call's evaluations, and says so: not the whole chain's
    assert [ln for ln in lines if "evaluations" in ln] and all(
        "evaluations since the resume" in ln for ln in lines if "evaluations" in ln
    )
    assert [c["n"] for c in res.stop["checks"]] == [c["n"] for c in ref.stop["checks"]]
    assert 0 < sum(res.steps_run) < sum(ref.steps_run)
    # a finished run read back: the replayed schedule stops at the same step, nothing is sampled
    again = GaussianTarget(MEAN, COV)
    res2 = run_mcmc(again, MEAN, COV, _conv(), seed=7, backend=tmp_path / "ref.h5", name="w")
    assert again.n_evals == 0 and res2.steps_run == [0] * res2.n_chains
    np.testing.assert_array_equal(res2.chain, ref.chain)


def test_moves_are_parsed_and_checked():
    from imrbayes.mcmc.sampler import parse_moves

    assert parse_moves("stretch") == [("stretch", 1.0)]
    assert parse_moves("de:3, snooker:1") == [("de", 0.75), ("snooker", 0.25)]
    for bad in ("", "gibbs", "de:-1", "de:x"):
        with pytest.raises(InputError):
            parse_moves(bad)
    with pytest.raises(InputError, match="moves"):
        MCMCSettings(moves="hmc").check(2)
    with pytest.raises(InputError, match="stop"):
        MCMCSettings(stop="never").check(2)
    with pytest.raises(InputError, match="6 walkers"):
        MCMCSettings(n_walkers=4).check(2)
    MCMCSettings(n_walkers=4, moves="stretch").check(2)
    MCMCSettings(n_walkers=6).check(2)
    assert parse_moves("indep:1,de:1") == [("indep", 0.5), ("de", 0.5)]
    for bad in ({"indep_scale": 0.0}, {"indep_dof": -1.0}, {"indep_scale": float("nan")}):
        with pytest.raises(InputError, match=next(iter(bad))):
            MCMCSettings(**bad).check(2)


# The default tier samples with DE (part of the default mixture); the other moves in the slow tier.
@pytest.mark.parametrize(
    "moves",
    [
        pytest.param("stretch", marks=pytest.mark.slow),
        "de",
        pytest.param("snooker", marks=pytest.mark.slow),
        pytest.param("de:0.8,snooker:0.2", marks=pytest.mark.slow),
        pytest.param("walk", marks=pytest.mark.slow),
    ],
)
def test_every_move_samples_the_target(moves):
    """Each selectable move leaves the target invariant: on a correlated 2-D Gaussian, 4 x 8 walkers
    x 3000 steps give the exact sds within 4 % (about 5 Monte-Carlo sd) and the mean within 0.1 sd.
    (emcee 3.1.6's own DESnookerMove fails this: next test.)"""
    run = run_mcmc(GaussianTarget(MEAN, COV), MEAN, COV, _conv(n_steps=3000, stop="fixed", moves=moves), seed=1)
    x = run.chain[:, 500:].reshape(-1, 2)
    sd = np.sqrt(np.diag(COV))
    np.testing.assert_allclose(x.std(axis=0) / sd, 1.0, atol=0.04)
    np.testing.assert_allclose((x.mean(axis=0) - MEAN) / sd, 0.0, atol=0.1)
    np.testing.assert_allclose(np.corrcoef(x.T)[0, 1], COV[0, 1] / sd.prod(), atol=0.03)


@pytest.mark.slow
def test_emcee_3_1_6_snooker_move_is_biased_and_ours_is_not():
    """Why ``snooker`` is our own move: emcee's DESnookerMove (before dfm/emcee#531) shrinks a 2-D
    Gaussian's sd to ~0.6-0.7; the same check passes with :func:`snooker_move`."""
    import inspect

    import emcee

    if "np.sqrt(norm)" not in inspect.getsource(emcee.moves.DESnookerMove.get_proposal):
        pytest.skip("this emcee has the corrected snooker move")
    tg = GaussianTarget(MEAN, COV)
    rng = np.random.default_rng(0)
    p0 = MEAN + rng.standard_normal((8, 2)) @ np.linalg.cholesky(COV).T
    sd = np.sqrt(np.diag(COV))
    from imrbayes.mcmc.sampler import snooker_move

    for move, ok in ((emcee.moves.DESnookerMove(), False), (snooker_move(), True)):
        s = emcee.EnsembleSampler(8, 2, tg.log_prob, vectorize=True, moves=move)
        s.run_mcmc(emcee.State(p0, random_state=np.random.RandomState(1).get_state()), 6000)
        ratio = s.get_chain(discard=1000).reshape(-1, 2).std(axis=0) / sd
        assert np.all(np.abs(ratio - 1) < 0.06) == ok, (move, ratio)


@pytest.mark.parametrize("moves", ["indep", pytest.param("indep:0.5,de:0.4,snooker:0.1", marks=pytest.mark.slow)])
def test_independence_move_samples_the_target_from_a_wrong_proposal(moves):
    """The ``indep`` move proposes from a Student-t on the start Gaussian; here that Gaussian is
    1.5 sd off-centre and half as wide as the target, so only a correct Hastings ratio gives the
    exact Gaussian back (without it the draws would lean towards the proposal): sds within 4 %,
    mean within 0.1 sd, correlation within 0.03."""
    sd = np.sqrt(np.diag(COV))
    run = run_mcmc(
        GaussianTarget(MEAN, COV), MEAN + 1.5 * sd, 0.5 * COV, _conv(n_steps=3000, stop="fixed", moves=moves), seed=1
    )
    x = run.chain[:, 500:].reshape(-1, 2)
    np.testing.assert_allclose(x.std(axis=0) / sd, 1.0, atol=0.04)
    np.testing.assert_allclose((x.mean(axis=0) - MEAN) / sd, 0.0, atol=0.1)
    np.testing.assert_allclose(np.corrcoef(x.T)[0, 1], COV[0, 1] / sd.prod(), atol=0.03)


def test_independence_move_ratio_is_the_student_t_density_ratio():
    """The Hastings factor returned with each proposal equals log q(x) - log q(x') for the
    multivariate t (scipy's density: independent truth for the normalisation-free formula)."""
    from scipy import stats

    from imrbayes.mcmc.sampler import independence_move

    C = np.array([[0.5, 0.1], [0.1, 0.3]])
    mv = independence_move(MEAN, C, scale=1.5, dof=4.0)
    x0 = MEAN + np.array([[0.3, -0.2], [2.0, 1.0], [-1.0, 0.5]])
    q, f = mv.get_proposal(x0, np.random.RandomState(0))
    t = stats.multivariate_t(loc=MEAN, shape=1.5**2 * C, df=4.0)
    np.testing.assert_allclose(f, t.logpdf(x0) - t.logpdf(q), rtol=1e-10, atol=1e-12)


@pytest.mark.slow
def test_adapted_independence_proposal_samples_the_target_and_resumes_identically(tmp_path):
    """``indep_adapt``: each ensemble re-places its proposal once, on its own draws, at a fixed step.
    From a start Gaussian 3 sd off and at 0.3 of the variance (where the fixed proposal is accepted
    ~7 % of the time), the adapted one converges in a few hundred steps, the draws of a long run are
    the exact Gaussian, and an interrupted run (cut before the adaptation) resumes to the same chains."""
    sd = np.sqrt(np.diag(COV))
    m0, c0 = MEAN + 3 * sd, 0.3 * COV
    kw = {"moves": "indep:0.7,de:0.3", "indep_adapt": 50}
    fixed = run_mcmc(GaussianTarget(MEAN, COV), m0, c0, _conv(moves="indep:0.7,de:0.3", indep_adapt=0), seed=1)
    run = run_mcmc(GaussianTarget(MEAN, COV), m0, c0, _conv(**kw), seed=1)
    assert run.stop["reason"] == "converged" and run.n_steps < 0.5 * fixed.n_steps, (run.n_steps, fixed.n_steps)
    long = run_mcmc(GaussianTarget(MEAN, COV), m0, c0, _conv(n_steps=3000, stop="fixed", **kw), seed=1)
    x = long.chain[:, 500:].reshape(-1, 2)
    np.testing.assert_allclose(x.std(axis=0) / sd, 1.0, atol=0.04)
    np.testing.assert_allclose((x.mean(axis=0) - MEAN) / sd, 0.0, atol=0.1)
    ref = run_mcmc(GaussianTarget(MEAN, COV), m0, c0, _conv(**kw), seed=4, backend=tmp_path / "ref.h5", name="w")
    path = tmp_path / "cut.h5"
    with pytest.raises(Interrupted):  # one batched call per round: cut before the adaptation
        run_mcmc(GaussianTarget(MEAN, COV, fail_after=40), m0, c0, _conv(**kw), seed=4, backend=path, name="w")
    import emcee

    assert 0 < emcee.backends.HDFBackend(str(path), name="w/chain_0", read_only=True).iteration < 50
    res = run_mcmc(GaussianTarget(MEAN, COV), m0, c0, _conv(**kw), seed=4, backend=path, name="w")
    np.testing.assert_array_equal(res.chain, ref.chain)


def test_a_coordinate_that_never_moved_has_infinite_tau_and_the_run_still_ends():
    """An ensemble none of whose proposals were accepted (a badly placed independence proposal in a
    short run) has a constant chain: tau is infinite (not NaN), burn-in keeps the second half."""
    from imrbayes.mcmc.sampler import burn_thin, integrated_tau

    chain = np.ones((40, 8, 2))
    chain[:, :, 1] += np.random.default_rng(0).standard_normal((40, 8))
    tau = integrated_tau(chain)
    assert np.isinf(tau[0]) and np.isfinite(tau[1])
    assert burn_thin(40, float(np.max(tau)), MCMCSettings(), 8) == (20, 1)


def test_log_reports_every_check_and_the_cap():
    """Without a terminal the run reports each convergence check (criteria against thresholds) and
    says when it stops at the cap unconverged."""
    lines = []
    s = MCMCSettings(n_walkers=8, n_steps=120, min_steps=40, ess_min=1e6)  # ESS can never be met: the cap
    run = run_mcmc(GaussianTarget(MEAN, COV), MEAN, COV, s, seed=1, name="window_00", log=lines.append)
    assert run.stop["reason"] == "cap"
    checks = [ln for ln in lines if "steps" in ln and "R-hat" in ln]
    assert len(checks) == len(run.stop["checks"]) >= 2
    assert checks[0].startswith("window_00: 40 steps") and "not yet:" in checks[0]
    assert all("ess_bulk" in ln.split("not yet:")[1] for ln in checks)
    assert "evaluations" in checks[0] and "(>= 1e+06)" in checks[0]
    assert lines[-1].startswith("window_00: stopped at the cap of 120 steps, not converged")
    from imrbayes.mcmc.sampler import check_line

    early = {
        "n": 100,
        "tau_max": float("inf"),
        "n_over_tau": 0.0,
        "rhat_max": float("inf"),
        "ess_bulk_min": 0.0,
        "ess_tail_min": 0.0,
        "criteria": {"rhat": False, "tau_rule": False},
        "ok": False,
    }
    assert check_line(early, s) == "100 steps: too short to estimate tau yet -- not yet: rhat, tau_rule"
    ok = []
    run = run_mcmc(GaussianTarget(MEAN, COV), MEAN, COV, MCMCSettings(n_walkers=8, n_steps=3000), seed=1, log=ok.append)
    assert run.stop["reason"] == "converged" and ok[-1].endswith("-- converged")


# The MCMC target density: likelihood, weights, prior (with and without the Jacobian), failures,
# the window target built from a handed-off ensemble.


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


# The nuisance-block and ridge moves (imrbayes.mcmc.blocks) sample the exact posterior.
#
# The target is a WindowTarget whose forward prediction is linear in (theta, nu): the posterior is an
# exact Gaussian, with the nuisances correlated with the parameters as the alignment is with G on
# camera data. Independent truth: the closed-form mean and covariance.


N_EXP, M = 3, 12


class LinearWindow(WindowTarget):
    """R_e(z) = theta_0 f + theta_1 g + nu_e0 (f + h) + nu_e1 g' + nu_e2 h, one design per experiment."""

    def __init__(self, seed=0, nuisance_sd=(0.3, 0.2, 0.25)):
        rng = np.random.default_rng(seed)
        t = np.linspace(0.1, 1.0, M)
        self.basis = np.stack([np.sin(3 * t), t**2, np.cos(2 * t), t, np.exp(-t)])  # (5, M)
        self.scale = 1.0 + 0.3 * rng.random(N_EXP)
        prior = ParamSpace(("a", "b"), [False, False], np.array([0.5, -0.2]), np.diag([0.5, 0.4]) ** 2)
        sd = np.tile(nuisance_sd, (N_EXP, 1)).astype(float)
        sd[1, 1] = 0.0  # one experiment with a nuisance fixed (not sampled)
        self.truth = np.array([0.8, -0.1])
        P = np.full(M, 0.05**2)
        nu_true = rng.normal(0.0, 1.0, (N_EXP, 3)) * sd
        y = self._R(self.truth[None], nu_true[None])[0] + rng.normal(0.0, 0.05, (N_EXP, M))
        start = BatchState(np.zeros((N_EXP, 3)), 0.0, np.full(N_EXP, 1e-4), np.full(N_EXP, 1e-5))
        super().__init__(None, start, t, y, P, prior, 1.0, nuisance_sd=sd)

    def _R(self, theta, nu):
        f, g, h, g2, k = self.basis
        R = (
            theta[:, None, 0, None] * f
            + theta[:, None, 1, None] * g
            + nu[:, :, 0, None] * (f + h)
            + nu[:, :, 1, None] * g2
            + nu[:, :, 2, None] * k
        )
        return R * self.scale[None, :, None]

    def predict(self, Z):
        Z = np.atleast_2d(np.asarray(Z, dtype=np.float64))
        nu = np.zeros((Z.shape[0], N_EXP, 3))
        nu[:, self.nuisance_used] = Z[:, 2:]
        R = self._R(Z[:, :2], nu)
        failed = np.zeros(Z.shape[0], dtype=bool)
        self.n_evals += Z.shape[0]
        self._remember(Z, R, failed)
        return R, failed

    def exact(self):
        """Closed-form posterior mean and covariance of z = (theta, sampled nu)."""
        d = self.ndim
        A = np.empty((N_EXP * M, d))
        base = self.predict(np.zeros((1, d)))[0].ravel()
        for i in range(d):
            e = np.zeros((1, d))
            e[0, i] = 1.0
            A[:, i] = self.predict(e)[0].ravel() - base
        prec0 = np.zeros((d, d))
        prec0[:2, :2] = np.linalg.inv(self.prior.prior_cov)
        sd = self.nuisance_sd[self.nuisance_used]
        prec0[2:, 2:] = np.diag(1.0 / sd**2)
        m0 = np.concatenate([self.prior.prior_mean, np.zeros(d - 2)])
        prec = A.T @ A / self.P[0, 0] + prec0
        cov = np.linalg.inv(prec)
        mean = cov @ (A.T @ (self.y.ravel() - base) / self.P[0, 0] + prec0 @ m0)
        return mean, cov


def test_blocks_split_the_log_posterior_by_experiment():
    tg = LinearWindow()
    assert [b.tolist() for b in tg.nuisance_blocks] == [[2, 3, 4], [5, 6], [7, 8, 9]]
    Z = tg.exact()[0] + 0.1 * np.random.default_rng(1).standard_normal((5, tg.ndim))
    lp0, T, R, failed = tg.block_terms(Z)
    np.testing.assert_allclose(lp0 + T.sum(axis=1), tg.log_prob(Z), rtol=1e-12, atol=1e-9)
    assert not failed.any() and T.shape == (5, N_EXP)


def test_accepted_blocks_carry_their_exact_log_density():
    """Mixed sets (some blocks from X, some from Q) get the log-density the target itself gives."""
    tg = LinearWindow()
    rng = np.random.default_rng(2)
    X = tg.exact()[0] + 0.05 * rng.standard_normal((40, tg.ndim))
    Q = X.copy()
    Q[:, 2:] += 0.2 * rng.standard_normal((40, tg.ndim - 2))
    tg.log_prob(Q)
    n0 = tg.n_evals
    Z, lp, acc = tg.accept_blocks(X, Q, np.random.RandomState(3))
    assert tg.n_evals - n0 == 40  # X from the memo would be free; X was never evaluated here
    assert acc.any() and not acc.all()  # a mixture of accepted and rejected blocks
    np.testing.assert_allclose(lp, tg.log_prob(Z), rtol=1e-12, atol=1e-9)
    n1 = tg.n_evals
    tg.block_terms(Z)  # the mixed sets are remembered: no new solve
    assert tg.n_evals == n1
    with pytest.raises(ValueError, match="same parameters"):
        Q2 = Q.copy()
        Q2[:, 0] += 1.0
        tg.accept_blocks(X, Q2, np.random.RandomState(0))


@pytest.mark.parametrize(
    "moves", [pytest.param("ridge:0.5,blocks:0.5", marks=pytest.mark.slow), "ridge:0.3,blocks:0.4,de:0.3"]
)
def test_block_and_ridge_moves_sample_the_exact_posterior(moves):
    tg = LinearWindow()
    mean, cov = tg.exact()
    sd = np.sqrt(np.diag(cov))
    corr = cov[0, 2:] / (sd[0] * sd[2:])
    assert np.max(np.abs(corr)) > 0.5  # the nuisances really are tied to the parameters
    s = MCMCSettings(n_walkers=2 * tg.ndim, n_steps=2500, n_chains=2, stop="fixed", moves=moves, init_scale=1.0)
    run = run_mcmc(tg, mean, cov, s, seed=4)
    x = run.chain[:, 500:].reshape(-1, tg.ndim)
    np.testing.assert_allclose((x.mean(axis=0) - mean) / sd, 0.0, atol=0.12)
    np.testing.assert_allclose(x.std(axis=0) / sd, 1.0, atol=0.07)
    np.testing.assert_allclose(np.corrcoef(x[:, [0, 2]].T)[0, 1], cov[0, 2] / (sd[0] * sd[2]), atol=0.05)
    lp_again = tg.log_prob(run.chain[:, -1].reshape(-1, tg.ndim))
    np.testing.assert_allclose(run.log_prob[:, -1].ravel(), lp_again, rtol=1e-10, atol=1e-8)


def test_block_moves_need_nuisances():
    tg = LinearWindow(nuisance_sd=(0.0, 0.0, 0.0))
    with pytest.raises(InputError, match="needs sampled nuisances"):
        emcee_moves("blocks", target=tg)
    with pytest.raises(InputError, match="needs a window target"):
        emcee_moves("ridge")
    assert len(emcee_moves("ridge", target=tg)) == 1


def test_auto_moves_follow_the_window():
    from _mcmc_synth import GaussianTarget

    from imrbayes.mcmc.sampler import AUTO_MOVES, resolve_moves

    assert resolve_moves("auto", LinearWindow()) == AUTO_MOVES["nuisances"] == "ridge:0.5,blocks:0.5"
    assert resolve_moves("auto", LinearWindow(nuisance_sd=(0.0, 0.0, 0.0))) == AUTO_MOVES["plain"]
    assert resolve_moves("auto", GaussianTarget([0.0, 1.0], np.eye(2))) == "indep:0.7,de:0.3"
    assert resolve_moves("de", LinearWindow()) == "de"
    # a window with one nuisance per experiment (Rmax alone): placed on the target first; this one is
    # linear-Gaussian, so the quadratic fit is exact and independent walkers sample it (8, fewer than 2 d)
    tg = LinearWindow(nuisance_sd=(0.3, 0.0, 0.0))
    run = run_mcmc(tg, *tg.exact(), MCMCSettings(n_steps=20, stop="fixed"), seed=0)
    assert run.settings["place"] == "laplace" and run.settings["moves"] == "indep" and run.n_walkers == 8 < 2 * tg.ndim
    assert run.settings["placement"]["rounds"][-1]["residual_sd_nats"] < 1e-6
    # the start as given: the block and ridge moves with 2 walkers per coordinate
    run = run_mcmc(tg, *tg.exact(), MCMCSettings(n_steps=20, stop="fixed", place="start"), seed=0)
    assert run.settings["moves"] == "ridge:0.5,blocks:0.5" and run.n_walkers == 2 * tg.ndim
    # three nuisances per experiment (camera records: Rmax, alignment, Req): placed, then the block moves
    tg = LinearWindow()
    run = run_mcmc(tg, *tg.exact(), MCMCSettings(n_steps=20, stop="fixed"), seed=0)
    assert run.settings["place"] == "laplace" and run.settings["moves"] == "ridge:0.5,blocks:0.5"
    assert run.n_walkers == 2 * tg.ndim and "3 nuisance(s) per experiment" in run.settings["placement"]["moves_rule"]


def test_auto_moves_fall_back_to_blocks_when_the_placed_fit_is_not_gaussian(monkeypatch):
    import imrbayes.mcmc.sampler as sampler

    monkeypatch.setattr(sampler, "LAPLACE_MAX_RESIDUAL", -1.0)  # any fit counts as not Gaussian
    tg = LinearWindow(nuisance_sd=(0.3, 0.0, 0.0))
    run = run_mcmc(tg, *tg.exact(), MCMCSettings(n_steps=20, stop="fixed"), seed=0)
    assert run.settings["place"] == "laplace" and run.settings["moves"] == "ridge:0.5,blocks:0.5"
    assert run.n_walkers == 2 * tg.ndim and "ridge" in run.settings["placement"]["moves_rule"]


# The Laplace placement (``MCMCSettings.place = "laplace"``): a quadratic fit of the target's own
# log-density moves the start Gaussian and the independence proposal before the first step.


# a correlated 5-D Gaussian (d > the 4 walkers used below, so the >= 2 d rule must not apply)
_A = np.array(
    [
        [1.0, 0.6, 0.0, 0.2, 0.0],
        [0.0, 1.0, -0.4, 0.0, 0.1],
        [0.0, 0.0, 1.0, 0.5, 0.0],
        [0.0, 0.0, 0.0, 1.0, -0.3],
        [0.0, 0.0, 0.0, 0.0, 1.0],
    ]
)
LAPLACE_COV = 0.01 * _A @ _A.T
LAPLACE_MEAN = np.array([0.5, -1.0, 2.0, 0.0, 0.3])
SD = np.sqrt(np.diag(LAPLACE_COV))


def _wrong_start():
    """2 sd off in every coordinate, 3x too wide in some and 0.4x in others, no correlation."""
    return LAPLACE_MEAN + 2.0 * SD, np.diag((SD * np.array([3.0, 0.4, 1.0, 2.0, 0.5])) ** 2)


def test_a_quadratic_log_density_is_placed_exactly():
    """The first round's optimum lies 6.9 start sd away, beyond the 3-spread cap: it moves to the cap,
    and the second round (a quadratic is fitted exactly wherever the cloud is) lands on the target."""
    m0, c0 = _wrong_start()
    m, c, info = quadratic_placement(GaussianTarget(LAPLACE_MEAN, LAPLACE_COV).log_prob, m0, c0, rounds=2)
    np.testing.assert_allclose(m, LAPLACE_MEAN, atol=1e-9)
    np.testing.assert_allclose(c, LAPLACE_COV, rtol=1e-7, atol=1e-12)
    first, second = info["rounds"]
    assert first["moved_sd"] > 6.0 and second["moved_sd"] < 3.0
    assert all(
        r["fitted"] and r["residual_sd_nats"] < 1e-9 and r["non_concave_directions"] == 0 for r in (first, second)
    )
    assert info["n_evals"] == 2 * int(np.ceil(3 * 21))  # 3 points per coefficient, (d + 1)(d + 2)/2 = 21


def test_a_flat_direction_keeps_the_previous_extent():
    """Where the density is flat (no curvature to fit) the Gaussian keeps the start's extent there
    rather than an infinite or negative variance."""
    prec = np.diag([100.0, 0.0])

    def logp(Z):
        r = np.atleast_2d(Z) - np.array([1.0, 0.0])
        return -0.5 * np.einsum("ni,ij,nj->n", r, prec, r)

    m, c, info = quadratic_placement(logp, np.array([1.2, 5.0]), np.diag([0.04, 9.0]), rounds=2)
    assert abs(m[0] - 1.0) < 1e-9 and c[0, 0] == pytest.approx(0.01, rel=1e-6)
    assert c[1, 1] == pytest.approx(9.0, rel=1e-6) and info["rounds"][0]["non_concave_directions"] == 1


def test_points_outside_the_support_are_left_out():
    tg = GaussianTarget(LAPLACE_MEAN, LAPLACE_COV)

    def logp(Z):
        v = tg.log_prob(Z)
        return np.where(np.atleast_2d(Z)[:, 0] > LAPLACE_MEAN[0] + 3 * SD[0], -np.inf, v)

    m, c, _ = quadratic_placement(logp, *_wrong_start(), rounds=2)
    np.testing.assert_allclose(m, LAPLACE_MEAN, atol=1e-8)


def _laplace(**kw):
    return MCMCSettings(
        **{
            "moves": "indep",
            "place": "laplace",
            "indep_dof": 20.0,
            "indep_scale": 1.1,
            "indep_adapt": 0,
            "n_walkers": 4,
            **kw,
        }
    )


def test_independence_sampler_on_the_placed_gaussian_converges_fast_and_samples_the_target():
    """From the wrong start, the placed proposal is accepted most of the time (tau of a step or two),
    the run stops at its first check, and a long run's draws are the exact Gaussian (mean within
    0.05 sd, sds within 3 %, correlations within 0.03) -- with 4 walkers for 5 coordinates."""
    m0, c0 = _wrong_start()
    run = run_mcmc(GaussianTarget(LAPLACE_MEAN, LAPLACE_COV), m0, c0, _laplace(), seed=2)
    assert run.stop["reason"] == "converged" and run.n_steps <= 150, run.n_steps
    assert np.all(run.acceptance > 0.7) and run.tau_max < 2.5
    assert run.settings["placement"]["rounds"][0]["fitted"]
    np.testing.assert_allclose(run.settings["given_mean"], m0)
    np.testing.assert_allclose(run.settings["start_mean"], LAPLACE_MEAN, atol=1e-8)
    long = run_mcmc(
        GaussianTarget(LAPLACE_MEAN, LAPLACE_COV), m0, c0, _laplace(n_steps=1500, stop="fixed", n_walkers=8), seed=3
    )
    x = long.chain[:, 100:].reshape(-1, LAPLACE_MEAN.size)
    np.testing.assert_allclose((x.mean(axis=0) - LAPLACE_MEAN) / SD, 0.0, atol=0.05)
    np.testing.assert_allclose(x.std(axis=0) / SD, 1.0, atol=0.03)
    np.testing.assert_allclose(np.corrcoef(x.T), LAPLACE_COV / np.outer(SD, SD), atol=0.03)


def test_placement_is_seeded_so_a_resumed_run_gives_the_same_chains(tmp_path):
    m0, c0 = _wrong_start()
    ref = run_mcmc(
        GaussianTarget(LAPLACE_MEAN, LAPLACE_COV), m0, c0, _laplace(), seed=4, backend=tmp_path / "ref.h5", name="w"
    )
    path = tmp_path / "cut.h5"
    with pytest.raises(Interrupted):
        run_mcmc(
            GaussianTarget(LAPLACE_MEAN, LAPLACE_COV, fail_after=10), m0, c0, _laplace(), seed=4, backend=path, name="w"
        )
    res = run_mcmc(GaussianTarget(LAPLACE_MEAN, LAPLACE_COV), m0, c0, _laplace(), seed=4, backend=path, name="w")
    np.testing.assert_array_equal(res.chain, ref.chain)


def test_the_walker_rule_depends_on_the_moves():
    assert independent_walkers("indep") and not independent_walkers("indep:0.7,de:0.3")
    assert not independent_walkers("auto")
    MCMCSettings(moves="indep", n_walkers=2).check(7)
    with pytest.raises(InputError, match="2 x 7"):
        MCMCSettings(moves="indep:0.7,de:0.3", n_walkers=8).check(7)
    with pytest.raises(InputError, match="place"):
        MCMCSettings(place="mode").check(2)
