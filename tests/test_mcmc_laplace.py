"""The Laplace placement (``MCMCSettings.place = "laplace"``): a quadratic fit of the target's own
log-density moves the start Gaussian and the independence proposal before the first step."""

import numpy as np
import pytest
from _mcmc_synth import GaussianTarget, Interrupted

from imrbayes.errors import InputError
from imrbayes.mcmc.laplace import quadratic_placement
from imrbayes.mcmc.sampler import MCMCSettings, independent_walkers, run_mcmc

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
COV = 0.01 * _A @ _A.T
MEAN = np.array([0.5, -1.0, 2.0, 0.0, 0.3])
SD = np.sqrt(np.diag(COV))


def _wrong_start():
    """2 sd off in every coordinate, 3x too wide in some and 0.4x in others, no correlation."""
    return MEAN + 2.0 * SD, np.diag((SD * np.array([3.0, 0.4, 1.0, 2.0, 0.5])) ** 2)


def test_a_quadratic_log_density_is_placed_exactly():
    """The first round's optimum lies 6.9 start sd away, beyond the 3-spread cap: it moves to the cap,
    and the second round (a quadratic is fitted exactly wherever the cloud is) lands on the target."""
    m0, c0 = _wrong_start()
    m, c, info = quadratic_placement(GaussianTarget(MEAN, COV).log_prob, m0, c0, rounds=2)
    np.testing.assert_allclose(m, MEAN, atol=1e-9)
    np.testing.assert_allclose(c, COV, rtol=1e-7, atol=1e-12)
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
    tg = GaussianTarget(MEAN, COV)

    def logp(Z):
        v = tg.log_prob(Z)
        return np.where(np.atleast_2d(Z)[:, 0] > MEAN[0] + 3 * SD[0], -np.inf, v)

    m, c, _ = quadratic_placement(logp, *_wrong_start(), rounds=2)
    np.testing.assert_allclose(m, MEAN, atol=1e-8)


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
    run = run_mcmc(GaussianTarget(MEAN, COV), m0, c0, _laplace(), seed=2)
    assert run.stop["reason"] == "converged" and run.n_steps <= 150, run.n_steps
    assert np.all(run.acceptance > 0.7) and run.tau_max < 2.5
    assert run.settings["placement"]["rounds"][0]["fitted"]
    np.testing.assert_allclose(run.settings["given_mean"], m0)
    np.testing.assert_allclose(run.settings["start_mean"], MEAN, atol=1e-8)
    long = run_mcmc(GaussianTarget(MEAN, COV), m0, c0, _laplace(n_steps=1500, stop="fixed", n_walkers=8), seed=3)
    x = long.chain[:, 100:].reshape(-1, MEAN.size)
    np.testing.assert_allclose((x.mean(axis=0) - MEAN) / SD, 0.0, atol=0.05)
    np.testing.assert_allclose(x.std(axis=0) / SD, 1.0, atol=0.03)
    np.testing.assert_allclose(np.corrcoef(x.T), COV / np.outer(SD, SD), atol=0.03)


def test_placement_is_seeded_so_a_resumed_run_gives_the_same_chains(tmp_path):
    m0, c0 = _wrong_start()
    ref = run_mcmc(GaussianTarget(MEAN, COV), m0, c0, _laplace(), seed=4, backend=tmp_path / "ref.h5", name="w")
    path = tmp_path / "cut.h5"
    with pytest.raises(Interrupted):
        run_mcmc(GaussianTarget(MEAN, COV, fail_after=10), m0, c0, _laplace(), seed=4, backend=path, name="w")
    res = run_mcmc(GaussianTarget(MEAN, COV), m0, c0, _laplace(), seed=4, backend=path, name="w")
    np.testing.assert_array_equal(res.chain, ref.chain)


def test_the_walker_rule_depends_on_the_moves():
    assert independent_walkers("indep") and not independent_walkers("indep:0.7,de:0.3")
    assert not independent_walkers("auto")
    MCMCSettings(moves="indep", n_walkers=2).check(7)
    with pytest.raises(InputError, match="2 x 7"):
        MCMCSettings(moves="indep:0.7,de:0.3", n_walkers=8).check(7)
    with pytest.raises(InputError, match="place"):
        MCMCSettings(place="mode").check(2)
