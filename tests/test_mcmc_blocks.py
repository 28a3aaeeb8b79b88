"""The nuisance-block and ridge moves (imrbayes.mcmc.blocks) sample the exact posterior.

The target is a WindowTarget whose forward prediction is linear in (theta, nu): the posterior is an
exact Gaussian, with the nuisances correlated with the parameters as the alignment is with G on
camera data. Independent truth: the closed-form mean and covariance.
"""

import numpy as np
import pytest

from imrbayes.ensemble.problem import ParamSpace
from imrbayes.errors import InputError
from imrbayes.forward import BatchState
from imrbayes.mcmc.sampler import MCMCSettings, emcee_moves, run_mcmc
from imrbayes.mcmc.target import WindowTarget

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
