"""The information-budget script (validation/camera_information_budget.py) on a small camera data set
with little noise, where the truth must sit where the script puts it."""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

_spec = importlib.util.spec_from_file_location(
    "camera_information_budget", Path(__file__).resolve().parents[1] / "validation" / "camera_information_budget.py")
budget = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(budget)

NOISE = 0.002


@pytest.fixture(scope="module")
def seed_folder(tmp_path_factory):
    folder = tmp_path_factory.mktemp("budget") / "seed_7"
    cmd = [sys.executable, "-m", "imrbayes.cli", "simulate", "--model", "nhkv", "--param", "G=5200",
           "--param", "mu=0.065", "--rmax", "320e-6:30e-6", "--ratio", "7.9:0.3", "--n-exp", "2",
           "--noise", str(NOISE), "--frame-s", "1e-6", "--phase", "random", "--pre-max-s", "5e-6",
           "--no-req-in-meta", "--t-end", "3.6", "--seed", "7", "--out", str(folder / "data"),
           "--forward", "bubble=polytropic"]
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    names = [e["file"].rsplit(".", 1)[0] for e in json.loads((folder / "data" / "truth.json").read_text())["experiments"]]
    (folder / "fit").mkdir()
    # what the script reads of a fit: which records it kept and each one's variance and tempering
    (folder / "fit" / "summary.json").write_text(json.dumps(
        {"per_experiment": [{"name": n, "likelihood": {"alpha": 1.0, "var": NOISE ** 2}} for n in names]}))
    return folder


def test_the_truth_in_nuisance_coordinates_reproduces_the_frames(seed_folder):
    truth, runner, records = budget.load_seed(seed_folder)
    theta = np.array([[truth["parameters"]["G"], truth["parameters"]["mu"]]])
    assert len(records) == 2
    for rec in records:
        for kind in ("ideal", "grid"):
            R, failed = budget._predict(runner, rec, kind, theta, rec["nu_true"][None])
            rms = float(np.sqrt(np.mean((rec[kind]["y"] - R[0]) ** 2)))
            assert not failed.any()
            assert 0.3 * NOISE < rms < 1.5 * NOISE, (rec["name"], kind, rms)
        # the preprocessing's guess is off by more than the noise allows: the test can fail
        R0, _ = budget._predict(runner, rec, "ideal", theta, np.zeros((1, 3)))
        assert np.sqrt(np.mean((rec["ideal"]["y"] - R0[0]) ** 2)) > 1.5 * NOISE


def test_profile_peaks_at_the_truth_and_the_geometry_costs_information(seed_folder):
    truth, runner, records = budget.load_seed(seed_folder)
    theta = np.array([truth["parameters"]["G"], truth["parameters"]["mu"]])
    log_g = np.array([-0.15, -0.05, 0.05, 0.15])
    for kind in ("ideal", "grid"):
        prof = budget.profile(runner, records, theta, kind, log_g).sum(axis=1)
        assert abs(budget.peak(log_g, prof)) < 0.05, (kind, prof)
        sd = budget.fisher_sd(runner, records, theta, kind)
        assert sd["known"][0] < sd["t0_known"][0] <= sd["inferred"][0] * 1.0001
        assert sd["known"][0] < sd["req_known"][0] <= sd["inferred"][0] * 1.0001


def test_peak_refines_by_a_parabola():
    x = np.linspace(-0.3, 0.6, 13)
    assert abs(budget.peak(x, -(x - 0.1234) ** 2) - 0.1234) < 1e-9
    assert budget.peak(x, x) == pytest.approx(0.6)          # at the edge: the edge


def test_without_a_fit_every_record_is_scored_with_the_ideal_likelihood_only(seed_folder, tmp_path):
    (tmp_path / "seed_7").mkdir()
    (tmp_path / "seed_7" / "data").symlink_to(seed_folder / "data")
    truth, runner, records = budget.load_seed(tmp_path / "seed_7")
    assert len(records) == truth["n_experiments"] and all(r["grid"] is None for r in records)
    row = budget.run_seed(tmp_path / "seed_7", np.array([-0.1, 0.0, 0.1]))
    assert "grid" not in row and abs(row["ideal"]["profile_peak_log_g"]) < 0.05


def test_profile_sd_of_a_gaussian_profile():
    x = np.linspace(-0.3, 0.6, 13)
    assert budget.profile_sd(x, -0.5 * ((x - 0.1) / 0.12) ** 2) == pytest.approx(0.12, rel=1e-9)


def test_gs_information_sits_on_the_collapse(seed_folder):
    truth, runner, records = budget.load_seed(seed_folder)
    theta = np.array([truth["parameters"]["G"], truth["parameters"]["mu"]])
    for r in budget.information_by_frame(runner, records, theta):
        assert 0.0 < r["share"] <= 1.0 and len(r["t_star"]) == 3
        # the first collapse (t* ~ 0.9) holds the most informative frame, not the flat maximum
        assert 0.7 < r["t_star"][0] < 1.6, r
