"""validation/camera_mcmc_calibration.py's summary on hand-made rows: coverage counts, Wilson
intervals, bias and the ensemble/MCMC sd ratio (the runs themselves are hours: docs/results.md)."""

import importlib.util
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "validation" / "camera_mcmc_calibration.py"


@pytest.fixture(scope="module")
def cal():
    sys.path.insert(0, str(SCRIPT.parent))
    spec = importlib.util.spec_from_file_location("camera_mcmc_calibration", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _row(seed, err_mcmc, err_ens, covers_mcmc, covers_ens, sd_ratio=0.6, pit=0.5):
    part = lambda e, c: {"mean": 1 + e, "sd": 0.1, "rel_error": e, "covers": c}  # noqa: E731
    one = {"mcmc": {**part(err_mcmc, covers_mcmc), "pit": pit}, "ensemble": part(err_ens, covers_ens),
           "sd_ratio_ensemble_to_mcmc": sd_ratio}
    return {"seed": seed, "G": one, "mu": one}


def test_summary_counts_coverage_per_posterior(cal):
    rows = [_row(0, 0.10, 0.12, True, False, pit=0.1), _row(1, -0.02, 0.00, True, True, pit=0.9),
            _row(2, 0.04, 0.06, False, False, pit=0.01)]
    s = cal.summarise(rows)
    assert s["n_seeds"] == 3
    assert s["G_mcmc"]["covered"] == 2 and s["G_ensemble"]["covered"] == 1
    assert s["G_mcmc"]["coverage"] == pytest.approx(2 / 3)
    assert s["G_mcmc"]["wilson95"] == pytest.approx(cal.wilson(2, 3))
    assert s["G_mcmc"]["bias"] == pytest.approx(0.04) and s["G_ensemble"]["bias"] == pytest.approx(0.06)
    assert s["mu_sd_ratio_ensemble_to_mcmc"] == pytest.approx(0.6)
    assert s["G_mcmc"]["pit"]["mean"] == pytest.approx(1.01 / 3) and s["G_mcmc"]["pit"]["below_0.5"] == 2
    assert 0.0 < s["G_mcmc"]["pit"]["ks_uniform_p"] <= 1.0
    assert cal.summarise([])["n_seeds"] == 0


def test_an_unfinished_seed_is_not_scored(cal, tmp_path):
    (tmp_path / "seed_7" / "fit").mkdir(parents=True)
    assert cal.score_seed(tmp_path / "seed_7") is None


def test_a_nuisance_off_only_along_the_ridge_is_on_target_at_the_true_material(cal):
    """Req drawn as truth x (1 + 0.5 (log G - log G_true)) + noise, with G's posterior 30 % high:
    the marginal Req is off by several sd, the conditional at the true G is not; Rmax exact."""
    import numpy as np

    rng = np.random.default_rng(3)
    n = 40000
    lg = np.log(cal.TRUTH["G"] * 1.3) + 0.1 * rng.standard_normal(n)
    lm = np.log(cal.TRUTH["mu"]) + 0.05 * rng.standard_normal(n)
    req_true, req_hat, rmax_true = 40e-6, 41e-6, 300e-6
    req = req_true * (1 + 0.5 * (lg - np.log(cal.TRUTH["G"])) + 0.004 * rng.standard_normal(n))
    tc = rmax_true * np.sqrt(1064.0 / 101325.0)
    post = {"G": np.exp(lg), "mu": np.exp(lm), "log_req_exp_001": np.log(req / req_hat),
            "rmax_rel_exp_001": 0.002 * rng.standard_normal(n),
            "t0_offset_exp_001": 0.05 + 0.01 * rng.standard_normal(n)}     # the maximum 0.05 t* after its prior
    truth = {"physics": {"rho": 1064.0, "p8": 101325.0},
             "experiments": [{"file": "exp_001.csv", "req_m": req_true, "rmax_m": rmax_true, "t_max_s": 6e-6},
                             {"file": "exp_002.csv", "req_m": req_true, "rmax_m": rmax_true, "t_max_s": 6e-6}]}
    summary = {"per_experiment": [{"name": "exp_001", "nuisance": {      # exp_002 left out by the fit
        "req_m": {"prior_mean": req_hat}, "rmax_m": {"prior_mean": rmax_true},
        "t0_s": {"prior_mean": 6e-6 - 0.05 * tc}}}]}
    (row,) = cal.score_nuisances(truth, summary, post)
    assert row["t0"]["prior_rel_error"] == pytest.approx(-0.05) and abs(row["t0"]["z"]) < 0.1
    assert row["req"]["prior_rel_error"] == pytest.approx(0.025)
    assert row["req"]["rel_error"] == pytest.approx(0.5 * np.log(1.3), rel=0.05)
    assert row["req"]["z"] > 2.0 and not row["req"]["covers"]
    assert abs(row["req"]["z_at_truth"]) < 0.1
    assert abs(row["rmax"]["z"]) < 0.1 and row["rmax"]["covers"]
    s = cal.summarise_nuisances([{"nuisance": [row]}, {"nuisance": [row]}])
    assert s["req"]["n_bubbles"] == 2 and s["req"]["covered"] == 0 and s["rmax"]["coverage"] == 1.0
