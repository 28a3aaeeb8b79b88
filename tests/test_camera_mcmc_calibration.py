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


def _row(seed, err_mcmc, err_ens, covers_mcmc, covers_ens, sd_ratio=0.6):
    part = lambda e, c: {"mean": 1 + e, "sd": 0.1, "rel_error": e, "covers": c}  # noqa: E731
    one = {"mcmc": part(err_mcmc, covers_mcmc), "ensemble": part(err_ens, covers_ens),
           "sd_ratio_ensemble_to_mcmc": sd_ratio}
    return {"seed": seed, "G": one, "mu": one}


def test_summary_counts_coverage_per_posterior(cal):
    rows = [_row(0, 0.10, 0.12, True, False), _row(1, -0.02, 0.00, True, True), _row(2, 0.04, 0.06, False, False)]
    s = cal.summarise(rows)
    assert s["n_seeds"] == 3
    assert s["G_mcmc"]["covered"] == 2 and s["G_ensemble"]["covered"] == 1
    assert s["G_mcmc"]["coverage"] == pytest.approx(2 / 3)
    assert s["G_mcmc"]["wilson95"] == pytest.approx(cal.wilson(2, 3))
    assert s["G_mcmc"]["bias"] == pytest.approx(0.04) and s["G_ensemble"]["bias"] == pytest.approx(0.06)
    assert s["mu_sd_ratio_ensemble_to_mcmc"] == pytest.approx(0.6)
    assert cal.summarise([])["n_seeds"] == 0


def test_an_unfinished_seed_is_not_scored(cal, tmp_path):
    (tmp_path / "seed_7" / "fit").mkdir(parents=True)
    assert cal.score_seed(tmp_path / "seed_7") is None
