"""The MIEnKS-MDA signature (imrbayes.diagnosis.signature): polytropic bubble, 3
experiments, 61 samples, windows L = 20, h = 5 (9 windows), 16 members, 2 iterations."""

import json
import math

import numpy as np
import pytest

from imrbayes.data.noise import noise_variance, paper_sigma
from imrbayes.diagnosis.signature import (
    SignatureSettings,
    observed_signature,
    predicted_signature,
    signature_result,
    signature_score,
    signature_tail,
)
from imrbayes.ensemble import Observations, ParamSpace
from imrbayes.errors import InputError
from imrbayes.forward import ForwardModel, ForwardOptions

TRUTH = np.array([6.0e3, 0.08])  # G [Pa], mu [Pa s]
N_EXP, N_STEPS, DT = 3, 60, 0.025
SETTINGS = SignatureSettings(L=20, h=5, n_rep=3)


@pytest.fixture(scope="module")
def fm():
    return ForwardModel("nhkv", ForwardOptions(bubble="polytropic"))


@pytest.fixture(scope="module")
def design():
    rng = np.random.default_rng(1)
    rmax = np.clip(rng.normal(300e-6, 30e-6, N_EXP), 220e-6, 400e-6)
    return np.arange(N_STEPS + 1) * DT, rmax, rmax / 7.5


def synthetic(fm, design, theta, rng):
    """Constant-parameter NHKV curves on the design with the paper's verification noise, P_k the
    across-experiment sample variance (as imrbayes.diagnosis.synthetic makes data)."""
    t, rmax, req = design
    out = fm.simulate(np.tile(np.asarray(theta, dtype=float), (N_EXP, 1)), rmax, req, t)
    assert not out.failed.any()
    R = out.R_star
    Y = R + paper_sigma(t, R) * rng.standard_normal(R.shape)
    Y[:, 0] = 1.0
    Y = np.maximum(Y, 1e-3)
    P, _ = noise_variance(t, Y)
    return Observations(t, Y, P, rmax, req)


@pytest.fixture(scope="module")
def obs(fm, design):
    return synthetic(fm, design, TRUTH, np.random.default_rng(2))


@pytest.fixture(scope="module")
def observed(fm, obs):
    return observed_signature(fm, obs, SETTINGS, seed=0)


@pytest.fixture(scope="module")
def predicted(fm, design):
    out = {}
    for key, theta in (("truth", TRUTH), ("G_x3", TRUTH * [3.0, 1.0])):
        out[key] = predicted_signature(lambda rng, th=theta: synthetic(fm, design, th, rng), fm, SETTINGS, seed=5)
    return out


def test_observed_signature_of_constant_parameters(fm, obs, observed):
    o = observed
    nw = (N_STEPS - SETTINGS.L + 1) // SETTINGS.h + 1
    for k in ("t_star", "log_G", "log_mu", "sd_log_G", "sd_log_mu", "G", "G_sd", "mu", "mu_sd"):
        assert np.shape(o[k]) == (nw,) and np.all(np.isfinite(o[k])), k
    assert np.all(np.diff(o["t_star"]) > 0)
    np.testing.assert_allclose(o["G"], np.exp(o["log_G"]))
    # the paper prior (mu 0.209 Pa s) is far from the truth: the chain walks from it, so only the
    # last windows are held to the truth
    assert np.all(np.abs(np.log(o["G"][-3:] / TRUTH[0])) < math.log(1.5))
    assert np.all(np.abs(np.log(o["mu"][-3:] / TRUTH[1])) < math.log(1.5))
    assert np.all(np.abs(np.log(o["G"] / TRUTH[0])) < math.log(2.0))
    # with a prior centred on the truth there is no walk: the signature is flat (measured |slope| x span
    # <= 0.24 over three noise seeds; the paper prior's walk gives 0.5 in log G, 1.1 in log mu)
    sp = ParamSpace.for_model(fm.constitutive, prior={"G": (6.0e3, 2.8e3), "mu": (0.08, 0.035)})
    flat = observed_signature(fm, obs, SETTINGS, seed=0, space=sp)
    span = flat["t_star"][-1] - flat["t_star"][0]
    for p in ("G", "mu"):
        assert abs(flat["slopes"][f"log_{p}"]) * span < 0.4, flat["slopes"]
        assert np.all(np.abs(np.log(flat[p] / TRUTH[["G", "mu"].index(p)])) < math.log(1.5))


def test_truth_reproduces_the_signature_better_than_a_wrong_candidate(observed, predicted):
    for pr in predicted.values():
        assert pr["n_ok"] == SETTINGS.n_rep and not pr["failures"]
        assert pr["log_G_reps"].shape == (SETTINGS.n_rep, observed["t_star"].size)
        assert np.all(pr["G_lo"] < pr["G_mean"]) and np.all(pr["G_mean"] < pr["G_hi"])
        assert np.all(pr["mu_lo"] < pr["mu_mean"]) and np.all(pr["mu_mean"] < pr["mu_hi"])
    good, bad = (signature_score(observed, predicted[k]) for k in ("truth", "G_x3"))
    assert good < 1.0 < bad and bad > 5 * good, (good, bad)
    # the wrong candidate's predicted G(t) lies well above the observed one
    assert np.median(predicted["G_x3"]["G_mean"] / observed["G"]) > 2.0
    p_good, p_bad = (signature_tail(observed, predicted[k]) for k in ("truth", "G_x3"))
    assert 0.0 < p_bad <= p_good <= 1.0


def test_signature_result_layout(observed, predicted):
    res = signature_result(observed, predicted)
    assert set(res) == {"observed", "predicted", "score", "note"}
    assert set(res["observed"]) == {"t_star", "G", "G_sd", "mu", "mu_sd"}
    for k in ("truth", "G_x3"):
        assert set(res["predicted"][k]) == {"t_star", "G_mean", "G_lo", "G_hi", "mu_mean", "mu_lo", "mu_hi"}
        assert all(len(v) == len(res["observed"]["t_star"]) for v in res["predicted"][k].values())
        assert res["score"][k] == pytest.approx(signature_score(observed, predicted[k]))
    assert res["score"]["truth"] < res["score"]["G_x3"]
    assert 1e3 < res["observed"]["G"][-1] < 1e5  # SI
    assert "paper" in res["note"] and "L = 20" in res["note"]
    json.dumps(res, allow_nan=False)


def test_failed_replicates_and_skip(fm, design, observed):
    calls = []

    def simulate(rng):
        calls.append(1)
        raise RuntimeError("forward solve failed\nsecond line")

    pr = predicted_signature(simulate, fm, SETTINGS, n_rep=2, seed=0)
    assert (
        len(calls) == 2
        and pr["n_ok"] == 0
        and "simulate failed (RuntimeError: forward solve failed)" in pr["failures"][0]
    )
    assert math.isnan(signature_score(observed, pr))
    res = signature_result(observed, {"broken": pr})
    assert res["score"]["broken"] is None and res["predicted"]["broken"]["G_mean"] == []
    json.dumps(res, allow_nan=False)
    t, rmax, req = design
    short = Observations(t[:15], np.ones((N_EXP, 15)), np.ones(15), rmax, req)
    assert "longer than the record" in SETTINGS.skip_reason(short)
    assert SETTINGS.skip_reason(Observations(t, np.ones((N_EXP, t.size)), np.ones(t.size), rmax, req)) is None
    with pytest.raises(InputError, match="signature skipped"):
        observed_signature(fm, short, SETTINGS)
