"""``imrbayes simulate`` camera-style records (interfaces.md §4): frame phase, frames before the
maximum, noise in µm and sums, per-bubble scatter, Req left out of meta.json. A fake forward model
with a known curve gives exact truth (see test_data_simulate.py)."""

import math

import numpy as np
import pytest
from _data_synth import curve
from test_data_simulate import BASE, read, sim

from imrbayes.data import load_dataset, preprocess_dataset
from imrbayes.data.synthetic import camera_times, parse_noise

RMAX = 263e-6
TC = RMAX / math.sqrt(101325 / 1064)  # the fake model's physics


def test_noise_terms_parse_and_sum():
    assert parse_noise("0.02") == {"kind": "gaussian", "sd": 0.02}
    assert parse_noise("3um") == {"kind": "gaussian_um", "sd_um": 3.0}
    assert parse_noise("none+0") == {"kind": "none"}
    assert parse_noise("paper+2um+0.01")["terms"] == [
        parse_noise("paper"),
        {"kind": "gaussian_um", "sd_um": 2.0},
        {"kind": "gaussian", "sd": 0.01},
    ]


def test_noise_in_um_plus_r_star_has_the_summed_sd_at_the_maximum(fake, tmp_path):
    out = tmp_path / "syn"
    res = sim(
        *BASE,
        "--noise",
        "2um+0.01",
        "--n-exp",
        "30",
        "--frame-s",
        "2e-7",
        "--phase",
        "random",
        "--seed",
        "4",
        "--out",
        out,
    )
    assert res.exit_code == 0, res.output
    _, truth, data = read(out)
    sd = math.hypot(2e-6 / RMAX, 0.01)
    z = []
    for e, d in zip(truth["experiments"], data):
        assert e["noise_sd_at_max_r_star"] == pytest.approx(sd, rel=1e-12)
        t_star = (d[:, 0] - e["t_max_s"]) / TC
        z.append((d[:, 1] / RMAX - curve(t_star, q=1 / 7.58)) / sd)
    z = np.concatenate(z)
    assert z.size > 5000 and abs(z.mean()) < 0.05 and abs(z.std() - 1.0) < 0.05


def test_random_phase_and_frames_before_the_maximum(fake, tmp_path):
    out = tmp_path / "syn"
    frame = 1e-6
    res = sim(
        *BASE,
        "--noise",
        "none",
        "--n-exp",
        "6",
        "--frame-s",
        frame,
        "--phase",
        "random",
        "--pre-max-s",
        "5e-6",
        "--seed",
        "2",
        "--out",
        out,
    )
    assert res.exit_code == 0, res.output
    _, truth, data = read(out)
    phases = [e["phase_s"] for e in truth["experiments"]]
    assert len(set(phases)) == 6 and all(0 <= p < frame for p in phases)
    for e, d in zip(truth["experiments"], data):
        assert d[0, 0] == 0.0  # camera clock starts at the first frame
        assert 5e-6 <= e["t_max_s"] < 5e-6 + frame  # the maximum falls inside the record
        frac = ((d[:, 0] - e["t_max_s"]) / frame) % 1.0  # every frame keeps the same sub-frame phase
        np.testing.assert_allclose(
            np.minimum(frac, 1 - frac), min(e["phase_s"] / frame, 1 - e["phase_s"] / frame), atol=1e-6
        )
        t_star = (d[:, 0] - e["t_max_s"]) / TC
        np.testing.assert_allclose(d[:, 1], RMAX * curve(t_star, q=1 / 7.58), rtol=1e-12)
    assert all(np.all(call[3] >= 0) for call in fake)  # the model only ever runs forward from Rmax
    again = tmp_path / "again"
    assert (
        sim(
            *BASE,
            "--noise",
            "none",
            "--n-exp",
            "6",
            "--frame-s",
            frame,
            "--phase",
            "random",
            "--pre-max-s",
            "5e-6",
            "--seed",
            "2",
            "--out",
            again,
        ).exit_code
        == 0
    )
    assert [e["phase_s"] for e in read(again)[1]["experiments"]] == phases


def test_mirror_before_the_maximum_with_phase_zero():
    t = camera_times(TC, 1e-6, 1.0, pre_max_s=4e-6)
    assert t[0] == pytest.approx(-4e-6 / TC) and np.count_nonzero(t == 0) == 1
    np.testing.assert_allclose(t[:4], -t[5:9][::-1])


def test_scatter_draws_log_normal_per_bubble_values(fake, tmp_path):
    out = tmp_path / "syn"
    res = sim(
        *BASE, "--noise", "none", "--n-exp", "300", "--scatter", "G=0.15", "--t-end", "1", "--seed", "9", "--out", out
    )
    assert res.exit_code == 0, res.output
    _, truth, _ = read(out)
    G = np.array([e["parameters"]["G"] for e in truth["experiments"]])
    mu = np.array([e["parameters"]["mu"] for e in truth["experiments"]])
    assert np.all(mu == 0.088)
    logG = np.log(G / 7290.0)
    assert abs(logG.mean()) < 3 * 0.15 / math.sqrt(300) and abs(logG.std(ddof=1) / 0.15 - 1) < 0.15
    assert [c[0]["G"] for c in fake] == pytest.approx(list(G), rel=1e-15)  # each bubble simulated with its own


def test_req_left_out_of_meta_is_estimated_from_the_tail(fake, tmp_path):
    out = tmp_path / "syn"
    assert (
        sim(*BASE, "--noise", "none", "--n-exp", "2", "--t-end", "6", "--no-req-in-meta", "--out", out).exit_code == 0
    )
    meta, truth, _ = read(out)
    assert meta["experiments"] == {} and truth["req_in_meta"] is False
    pre = preprocess_dataset(load_dataset(out))
    assert all(e.req_source != "meta.json" for e in pre.experiments)
    np.testing.assert_allclose(pre.req_m, RMAX / 7.58, rtol=0.02)


@pytest.mark.parametrize(
    "args,where,problem",
    [
        (["--phase", "random"], "--phase", "needs --frame-s"),
        (["--pre-max-s", "1e-6"], "--pre-max-s", "needs --frame-s"),
        (["--frame-s", "1e-6", "--pre-max-s", "-1"], "--pre-max-s", "0 <= S"),
        (["--scatter", "x=0.1"], "--scatter", "unknown parameter"),
        (["--scatter", "G=5"], "--scatter", "in [0, 2]"),
        (["--noise", "3mm"], "--noise", "expected paper"),
    ],
)
def test_camera_options_bad_input(fake, tmp_path, args, where, problem):
    res = sim(*BASE, *args, "--out", tmp_path / "o")
    assert res.exit_code == 2
    assert where in res.output and problem in res.output
