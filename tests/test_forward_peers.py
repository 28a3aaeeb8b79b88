"""Data from another code: PyIMR behind ``simulate_radius`` (``forward/peers.py``) and
``imrbayes simulate --generator pyimr``. PyIMR is the optional ``peers`` extra; without it these
tests skip, except the one that checks the error a user gets."""

import json
import sys

import numpy as np
import pytest
from click.testing import CliRunner

from imrbayes.cli import main
from imrbayes.forward import ForwardModel

T = np.linspace(0.0, 3.0, 121)


def test_generator_pyimr_without_pyimr_is_a_one_line_error(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "pyimr", None)  # import pyimr raises ImportError
    res = CliRunner().invoke(
        main,
        [
            "simulate",
            "--model",
            "nhkv",
            "--param",
            "G=5e3",
            "--param",
            "mu=0.05",
            "--generator",
            "pyimr",
            "--forward",
            "bubble=polytropic",
            "--out",
            str(tmp_path / "d"),
        ],
    )
    assert res.exit_code == 2
    msg = res.output.strip()
    assert "\n" not in msg and "Traceback" not in msg
    assert "--generator" in msg and "peers" in msg
    assert not (tmp_path / "d" / "truth.json").exists()


@pytest.mark.parametrize(
    "model,params", [("nhkv", {"G": 5200.0, "mu": 0.065}), ("qkv", {"G": 5200.0, "mu": 0.065, "alpha": 0.3})]
)
def test_polytropic_bubble_agrees_with_pyimr_to_the_tolerances(model, params):
    """Same equations (IMRv2's stress models 1 and 2, Keller-Miksis, polytropic gas with vapour),
    two integrators: agreement at the level of the tolerances (measured 4.8e-7 relative L2)."""
    pytest.importorskip("pyimr")
    from imrbayes.forward.peers import PyIMRModel

    fm = ForwardModel(model, options={"bubble": "polytropic"})
    ours = fm.simulate_radius(params, 320e-6, 320e-6 / 7.9, T)
    peer = PyIMRModel(fm).simulate_radius(params, 320e-6, 320e-6 / 7.9, T)
    assert np.linalg.norm(peer - ours) / np.linalg.norm(ours) < 1e-5
    assert peer[0] == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("lambda2", [0.0, 1.5e-6])
def test_zener_agrees_with_pyimr_with_the_consistent_coefficient(lambda2):
    """Zener (IMRv2's stress 3) at Lambda < 1: PyIMR's Keller-Miksis coefficient of Rddot is the
    stress's instantaneous viscosity 4 Lambda/Re, ours too by default (``zener_j=consistent``);
    IMRv2's 4/Re (``zener_j=imrv2``) is 2.7e-2 away at Lambda = 0 (docs/methods.md)."""
    pytest.importorskip("pyimr")
    from imrbayes.forward.peers import PyIMRModel

    params = {"G": 5200.0, "mu": 0.065, "lambda1": 3e-6, "lambda2": lambda2}
    fm = ForwardModel("zener", options={"bubble": "polytropic"})
    ours = fm.simulate_radius(params, 320e-6, 320e-6 / 7.9, T)
    peer = PyIMRModel(fm).simulate_radius(params, 320e-6, 320e-6 / 7.9, T)
    assert np.linalg.norm(peer - ours) / np.linalg.norm(ours) < 1e-5
    quirk = ForwardModel("zener", options={"bubble": "polytropic", "zener_j": "imrv2"})
    other = quirk.simulate_radius(params, 320e-6, 320e-6 / 7.9, T)
    assert np.linalg.norm(peer - other) / np.linalg.norm(ours) > 1e-3


@pytest.mark.slow
def test_thermal_bubble_agrees_with_pyimr_within_the_grid_bound():
    """Thermal bubble with vapour and mass transfer (LIC case): our default grid against PyIMR's
    spectral Nt = 65, both near their grid limits: within the converged grid's 1.5e-3 bound (measured 6.8e-4)."""
    pytest.importorskip("pyimr")
    from imrbayes.forward.peers import PyIMRModel

    fm = ForwardModel("nhkv")
    p = {"G": 7290.0, "mu": 0.088}
    ours = fm.simulate_radius(p, 263e-6, 263e-6 / 7.58, T)
    peer = PyIMRModel(fm).simulate_radius(p, 263e-6, 263e-6 / 7.58, T)
    assert np.linalg.norm(peer - ours) / np.linalg.norm(ours) < 1.5e-3


def test_simulate_with_pyimr_records_the_generator(tmp_path):
    pytest.importorskip("pyimr")
    out = tmp_path / "d"
    args = [
        "simulate",
        "--model",
        "nhkv",
        "--param",
        "G=5200",
        "--param",
        "mu=0.065",
        "--n-exp",
        "2",
        "--noise",
        "none",
        "--frame-s",
        "1e-6",
        "--t-end",
        "2",
        "--forward",
        "bubble=polytropic",
        "--seed",
        "3",
        "--out",
    ]
    assert CliRunner().invoke(main, [*args, str(out), "--generator", "pyimr", "--quiet"]).exit_code == 0
    assert CliRunner().invoke(main, [*args, str(tmp_path / "o"), "--quiet"]).exit_code == 0
    truth = json.loads((out / "truth.json").read_text())
    assert truth["generator"]["code"] == "pyimr" and truth["generator"]["Nt"] == 65
    assert json.loads((tmp_path / "o" / "truth.json").read_text())["generator"]["code"] == "imrbayes"
    a = np.loadtxt(out / "exp_001.csv", delimiter=",", skiprows=1)
    b = np.loadtxt(tmp_path / "o" / "exp_001.csv", delimiter=",", skiprows=1)
    assert a.shape == b.shape and np.allclose(a[:, 0], b[:, 0])  # same frames, other code
    assert np.max(np.abs(a[:, 1] - b[:, 1])) / 263e-6 < 1e-4


def test_camera_obs_from_pyimr_draws_the_same_records_with_another_code():
    """The diagnosis test bed (``camera_obs``) with ``generator="pyimr"``: the same draws (material,
    bubbles, phases, noise), curves from PyIMR; a piecewise truth has no PyIMR counterpart."""
    pytest.importorskip("pyimr")
    from imrbayes.diagnosis.synthetic import camera_obs
    from imrbayes.forward import ForwardOptions

    opts = ForwardOptions(bubble="polytropic")
    a, ta = camera_obs("none", 5, opts, n_exp=2, generator="pyimr")
    b, tb = camera_obs("none", 5, opts, n_exp=2)
    assert ta["generator"]["code"] == "pyimr" and tb["generator"]["code"] == "imrbayes"
    assert ta["theta"] == tb["theta"] and ta["rmax_m"] == tb["rmax_m"]
    assert a.R_star.shape == b.R_star.shape
    assert 0 < np.nanmax(np.abs(a.R_star - b.R_star)) < 1e-4
    with pytest.raises(ValueError, match="piecewise"):
        camera_obs("damage-softening", 5, opts, n_exp=1, generator="pyimr")


def test_zener_with_imrv2_coefficient_has_no_pyimr_counterpart():
    pytest.importorskip("pyimr")
    from imrbayes.errors import InputError
    from imrbayes.forward.peers import PyIMRModel

    with pytest.raises(InputError, match="zener_j"):
        PyIMRModel(ForwardModel("zener", options={"bubble": "polytropic", "zener_j": "imrv2"}))
