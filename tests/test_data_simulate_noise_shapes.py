"""``imrbayes simulate --noise`` shapes that are not constant: proportional to the radius (``0.02R``)
and larger near collapses (``0.01C``). A fake forward model with a known curve of two deep collapses
gives exact truth; the sample sd of the noise in bins of R* must follow the stated shape."""

import math

import numpy as np
import pytest
from _fake_forward import FakeModel
from test_data_simulate import BASE, read, sim

from imrbayes.data.synthetic import parse_noise

RMAX = 263e-6
TC = RMAX / math.sqrt(101325 / 1064)  # the fake model's physics
Q = 0.15  # R* at both collapses of the curve below


def two_collapses(t_star):
    """R* with its maximum 1 at t* = 0 and collapses to exactly Q at t* = 0.9 and 2.7 (rebound to ~0.5)."""
    t = np.abs(np.asarray(t_star, dtype=float))
    return Q + (1 - Q) * np.exp(-t / 2) * np.cos(np.pi * t / 1.8) ** 2


@pytest.fixture
def collapsing(fake, monkeypatch):
    monkeypatch.setattr(FakeModel, "simulate_radius", lambda self, p, rmax_m, req_m, t_star: two_collapses(t_star))
    return fake


def noise_by_bin(out, edges):
    """Per R* bin of the noise-free curve: (mean clean R*, sample sd of the noise, count)."""
    _, truth, data = read(out)
    clean, resid = [], []
    for e, d in zip(truth["experiments"], data):
        t_star = (d[:, 0] - e["t_max_s"]) / TC
        c = two_collapses(t_star)
        clean.append(c)
        resid.append(d[:, 1] / RMAX - c)
    clean, resid = np.concatenate(clean), np.concatenate(resid)
    rows = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (clean >= lo) & (clean < hi)
        rows.append((clean[m].mean(), resid[m].std(ddof=1), int(m.sum()), clean[m]))
    return truth, rows


def test_new_noise_terms_parse_and_combine():
    assert parse_noise("0.02R") == {"kind": "proportional", "fraction": 0.02, "sigma": "0.02 R*"}
    c = parse_noise("0.01c")
    assert c["kind"] == "collapse" and c["sd"] == 0.01 and c["peak"] == 4.0 and c["width_r_star"] == 0.05
    s = parse_noise("0.02R+0.01C+1um")
    assert [t["kind"] for t in s["terms"]] == ["proportional", "collapse", "gaussian_um"]
    assert parse_noise("0R") == {"kind": "none"}


@pytest.mark.parametrize("bad", ["xR", "-0.01R", "0.01Q", "R"])
def test_bad_shape_is_one_line_error(fake, tmp_path, bad):
    res = sim(*BASE, "--noise", bad, "--out", tmp_path / "o")
    assert res.exit_code == 2 and res.stderr.strip().startswith("imrbayes: error: --noise")
    assert "\n" not in res.stderr.strip()


def test_proportional_noise_grows_with_the_radius(collapsing, tmp_path):
    out = tmp_path / "syn"
    res = sim(
        *BASE,
        "--noise",
        "0.02R",
        "--n-exp",
        "40",
        "--frame-s",
        "2e-7",
        "--phase",
        "random",
        "--seed",
        "7",
        "--out",
        out,
    )
    assert res.exit_code == 0, res.output
    truth, rows = noise_by_bin(out, [0.15, 0.25, 0.4, 0.6, 0.8, 1.01])
    assert truth["noise"]["kind"] == "proportional" and truth["noise"]["fraction"] == 0.02
    for e in truth["experiments"]:
        assert e["noise_sd_at_max_r_star"] == pytest.approx(0.02)
    for _, sd, n, c in rows:
        want = 0.02 * np.sqrt(np.mean(c**2))  # the rms of the stated sd over the bin's samples
        assert n > 300 and sd == pytest.approx(want, rel=0.1)
    assert rows[-1][1] > 3 * rows[0][1]  # the sd at R* ~ 0.9 is ~5x the one at ~0.2


def test_collapse_noise_is_five_times_larger_at_the_collapses(collapsing, tmp_path):
    out = tmp_path / "syn"
    res = sim(
        *BASE,
        "--noise",
        "0.01C",
        "--n-exp",
        "40",
        "--frame-s",
        "2e-7",
        "--phase",
        "random",
        "--seed",
        "8",
        "--out",
        out,
    )
    assert res.exit_code == 0, res.output
    truth, rows = noise_by_bin(out, [Q, Q + 0.02, Q + 0.05, Q + 0.1, 0.4, 1.01])
    assert truth["noise"]["kind"] == "collapse"
    for _, sd, n, c in rows:
        # both collapses bottom out at Q, so the nearest collapse's radius is Q for every sample
        want = 0.01 * np.sqrt(np.mean((1 + 4 * np.exp(-(((c - Q) / 0.05) ** 2))) ** 2))
        assert n > 150 and sd == pytest.approx(want, rel=0.12)
    assert rows[0][1] > 4 * rows[-1][1] and rows[-1][1] == pytest.approx(0.01, rel=0.1)


def test_sum_of_shapes_adds_variances(collapsing, tmp_path):
    out = tmp_path / "syn"
    assert (
        sim(
            *BASE, "--noise", "0.02R+0.005", "--n-exp", "40", "--frame-s", "2e-7", "--seed", "9", "--out", out
        ).exit_code
        == 0
    )
    truth, rows = noise_by_bin(out, [0.15, 0.3, 0.6, 1.01])
    assert [t["kind"] for t in truth["noise"]["terms"]] == ["proportional", "gaussian"]
    for _, sd, _n, c in rows:
        assert sd == pytest.approx(np.sqrt(np.mean((0.02 * c) ** 2 + 0.005**2)), rel=0.1)
