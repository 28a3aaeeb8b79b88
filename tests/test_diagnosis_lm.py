"""The diagnosis fits' Levenberg-Marquardt (`lsq.fit_map`): the extension box, the Jacobian reuse, no trial twice.

A candidate's extension is fitted inside +-EXTENSION_BOX_SD prior sd of its prior mean.

Why (docs/diagnosis.md, Runtime): on a record the model misses by far, the first fit's likelihood
swamps the prior, and zener's lambda1 crawled towards its NHKV limit (lambda1 ~ 1e-14 s on UMich
PA10), where the thermal solves need up to 7x the steps for no change in R*. The fit's optimiser is
checked here on an exactly quadratic problem (a linear stand-in for the forward model) whose
unconstrained optimum lies 8 prior sd out along the extension.
"""

import numpy as np
import pytest

from imrbayes.diagnosis import lsq
from imrbayes.diagnosis.models import make_candidate
from imrbayes.diagnosis.phases import phases_of
from imrbayes.diagnosis.synthetic import camera_obs
from imrbayes.forward import ForwardOptions

POLY = ForwardOptions(bubble="polytropic")


@pytest.fixture(scope="module")
def problem():
    obs, _ = camera_obs("none", 0, POLY, design="1Mfps-2um-5")
    obs = obs.take(range(2))
    zener = make_candidate("zener", POLY)
    m, s = zener.prior_mean, zener.prior_sd
    target = np.array([m[0] + 0.3, m[1] - 0.2, m[2] - 8.0 * s[2]])  # lambda1 8 prior sd below 1 us
    return obs, zener, target


def _linear_model(target, scale):
    """R* = data + 0.02 * sum_i (z_i - target_i) / scale_i * b_i, b_i on disjoint thirds of the
    record: the cost is quadratic and its coordinates independent, whatever the nuisances."""

    def fake_predict(cand, Z, obs, idx, minima, K, nu=None, frames=None):
        Z = np.atleast_2d(np.asarray(Z, dtype=float))
        idx = np.atleast_1d(idx)
        y = obs.R_star[idx, : K + 1]
        b = np.zeros((3, K + 1))
        for i, part in enumerate(np.array_split(np.arange(1, K + 1), 3)):
            b[i, part] = 1.0
        dz = (Z - target) / scale  # (M, 3)
        return y[None] + 0.02 * np.einsum("mi,ik->mk", dz, b)[:, None, :]

    return fake_predict


def test_extension_held_at_its_box_and_the_rest_converges(problem, monkeypatch):
    obs, zener, target = problem
    m, s = zener.prior_mean, zener.prior_sd
    monkeypatch.setattr(lsq, "predict", _linear_model(target, np.array([0.1, 0.1, 1.0])))
    phases = phases_of(obs, 2)
    om = lsq.ObsModel.of(obs)
    f = lsq.fit_map(zener, obs, minima=phases.minima, om=om, options=lsq.MapOptions(tol=1e-10))
    floor = m[2] - lsq.EXTENSION_BOX_SD * s[2]
    assert f.z[2] == pytest.approx(floor, abs=1e-9)  # held at the bound, not 8 sd out
    assert f.converged and f.n_iter < 40
    # G and mu are independent of lambda1 here: they reach their own optimum (the data's pull on
    # each is ~1e3 times its prior's, so within 1e-2 of the target)
    np.testing.assert_allclose(f.z[:2], target[:2], atol=1e-2)


def test_without_the_box_the_same_fit_goes_out_of_it(problem, monkeypatch):
    # the problem above is one where the box binds: unbounded, the optimum is ~8 prior sd out
    obs, zener, target = problem
    m, s = zener.prior_mean, zener.prior_sd
    monkeypatch.setattr(lsq, "predict", _linear_model(target, np.array([0.1, 0.1, 1.0])))
    monkeypatch.setattr(lsq, "EXTENSION_BOX_SD", np.inf)
    phases = phases_of(obs, 2)
    f = lsq.fit_map(zener, obs, minima=phases.minima, om=lsq.ObsModel.of(obs), options=lsq.MapOptions(tol=1e-10))
    assert f.z[2] < m[2] - 7.0 * s[2]


def _qkv_fit_on_relaxation_data(monkeypatch):
    """Polytropic relaxation data, two camera-style bubbles, the qkv fit: its damping is raised
    after rejected steps several times. Returns (the forward batches it asked for: (Z, nu) each,
    the members of a Jacobian batch, the number of iterations after a rejected step, of all)."""
    obs, _ = camera_obs("viscoelastic-relaxation", 2001, POLY, design="1Mfps-2um-5")
    obs = obs.take(range(2))
    qkv = make_candidate("qkv", POLY)
    phases = phases_of(obs, 2)
    om = lsq.ObsModel.of(obs)
    batches = []
    predict = lsq.predict

    def recording(cand, Z, *a, **kw):
        batches.append((np.atleast_2d(Z).copy(), np.asarray(a[4] if len(a) > 4 else kw.get("nu")).copy()))
        return predict(cand, Z, *a, **kw)

    monkeypatch.setattr(lsq, "predict", recording)
    trace = []
    lsq.fit_map(qkv, obs, minima=phases.minima, om=om, options=lsq.MapOptions(trace=trace))
    its = [e for e in trace if "it" in e]
    rejected = sum(b["it"] == a["it"] + 1 and b["z"] == a["z"] and b["cost"] == a["cost"] for a, b in zip(its, its[1:]))
    assert rejected >= 1  # the situation under test occurs
    return batches, qkv.d + int((om.nu_sd > 0).any(axis=0).sum()), rejected, len(its)


def test_a_rejected_step_reuses_the_jacobian_of_the_unchanged_point(monkeypatch):
    # after a rejection the point is unchanged, and so is its Jacobian (d + 5 batched solves, the
    # bulk of an iteration): no Jacobian batch may be computed twice
    batches, n_jac, rejected, _ = _qkv_fit_on_relaxation_data(monkeypatch)
    jac = [Z.tobytes() + nu.tobytes() for Z, nu in batches if Z.shape[0] == n_jac]
    assert len(jac) > rejected
    assert len(set(jac)) == len(jac)


def test_a_rejected_trial_step_is_not_tried_again(monkeypatch):
    # After a rejection the damping rises 100-fold and LM tries 0.1x, 1x and 10x of it: the first
    # is the last iteration's largest trial, from the same point with the same Jacobian, and was
    # rejected. Every trial member (material and nuisances) must be new: none may repeat an
    # earlier one to 1e-9 (the damping of the repeat differs from the original in its last bits).
    batches, n_jac, _, n_its = _qkv_fit_on_relaxation_data(monkeypatch)
    M = np.array(
        [
            np.concatenate([Z[i], nu[i].ravel()])
            for Z, nu in batches
            if 1 < Z.shape[0] < n_jac
            for i in range(Z.shape[0])
        ]
    )
    assert len(M) >= n_its  # the trial batches were seen
    close = np.isclose(M[:, None, :], M[None, :, :], rtol=1e-9, atol=1e-12).all(axis=2)
    assert not np.triu(close, k=1).any()


def test_a_restart_that_does_not_pay_is_not_kept(monkeypatch):
    # nuisance restarts that report a "better" basin the joint refit cannot confirm (here: every
    # bubble's time of the maximum moved 3 prior sd): the fit must keep what it had before them and
    # not go on to a second round (on stiff PA 1-5 such a round cost 66 s and its refit ended
    # 1.5 nats above the first one's, which was lost)
    obs, _ = camera_obs("none", 0, POLY, design="1Mfps-2um-5")
    obs = obs.take(range(2))
    nhkv = make_candidate("nhkv", POLY)
    phases = phases_of(obs, 2)
    om = lsq.ObsModel.of(obs)
    plain = lsq.fit_map(nhkv, obs, minima=phases.minima, om=om)
    calls = []

    def misleading(cand, obs_, idx, K, minima, om_, z, nu, **kw):
        calls.append(np.array(nu))
        moved = np.array(nu, dtype=float)
        moved[:, 1] += 3.0 * om_.nu_sd[idx, 1]
        return moved, np.ones(len(idx), dtype=bool)

    monkeypatch.setattr(lsq, "nuisance_restarts", misleading)
    f = lsq.fit_map(nhkv, obs, minima=phases.minima, om=om, options=lsq.MapOptions(restarts=True))
    assert len(calls) == 1
    assert f.cost <= plain.cost * (1.0 + 1e-9)
    np.testing.assert_allclose(f.z, plain.z, atol=1e-3)
