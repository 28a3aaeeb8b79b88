"""Each preprocessing function against independent truth (synthetic curves, known answers)."""

import math

import numpy as np
import pytest
from _data_synth import P8, RHO, curve, make_dataset, record

from imrbayes.data import load_dataset, preprocess as pp, preprocess_dataset
from imrbayes.data.noise import P_FLOOR_ABS, P_FLOOR_REL, noise_variance, paper_sigma
from imrbayes.errors import InputError


# ----------------------------------------------------------------------------- parabola_vertex
def test_parabola_vertex_exact_on_uneven_spacing():
    a, x0, y0 = -3.7, 0.413, 2.5
    x = np.array([0.1, 0.35, 0.9])
    y = a * (x - x0) ** 2 + y0
    xv, yv = pp.parabola_vertex(x, y)
    assert xv == pytest.approx(x0, rel=1e-12)
    assert yv == pytest.approx(y0, rel=1e-12)


def test_parabola_vertex_collinear_is_none():
    assert pp.parabola_vertex([0, 1, 2], [1, 2, 3]) is None


# ----------------------------------------------------------------------------- locate_rmax
def test_locate_rmax_exact_on_parabola_off_grid():
    t = np.arange(10) * 1e-6 + 0.37e-6
    R = 300e-6 - 2e3 * (t - 4.81e-6) ** 2
    m = pp.locate_rmax(t, R)
    assert m.method == "parabola"
    assert m.t_s == pytest.approx(4.81e-6, rel=1e-9)
    assert m.rmax_m == pytest.approx(300e-6, rel=1e-12)
    assert m.rmax_sample_m == R.max() and m.index == int(np.argmax(R))


@pytest.mark.parametrize("offset", np.linspace(0.0, 0.95, 9))
def test_locate_rmax_subframe_on_cosine(offset):
    # 270 kfps-like sampling: h* = 0.09. Stated tolerance: |t0 error| < 0.01 h (sample max: up to 0.5 h).
    h = 0.09
    t = -0.3 + (np.arange(40) + offset) * h
    R = curve(t)
    m = pp.locate_rmax(t, R)
    assert abs(m.t_s) < 0.01 * h
    assert abs(m.rmax_m - 1.0) < 5e-4
    s = pp.locate_rmax(t, R, "sample")
    assert abs(s.t_s) <= 0.5 * h + 1e-12
    assert s.rmax_m <= m.rmax_m


def test_locate_rmax_at_record_start_falls_back_to_sample():
    t = np.arange(6.0)
    R = np.array([5.0, 4, 3, 2, 3, 4])
    m = pp.locate_rmax(t, R)
    assert m.index == 0 and m.t_s == 0.0 and m.method.startswith("sample")


# ----------------------------------------------------------------------------- first_collapse
@pytest.mark.parametrize("offset", np.linspace(0.0, 0.95, 9))
def test_first_collapse_subframe(offset):
    # curve() has its first minimum at t* = 0.9 exactly. Stated tolerance: < 0.1 h for the parabola.
    h = 0.09
    t = -0.3 + (np.arange(40) + offset) * h
    R = curve(t)
    m = pp.locate_rmax(t, R)
    c = pp.first_collapse(t, R, m.index)
    assert abs(c.t_s - 0.9) < 0.1 * h
    assert c.r_m <= R[c.index] and c.r_m == pytest.approx(0.14, abs=2e-3)
    s = pp.first_collapse(t, R, m.index, "sample")
    assert abs(s.t_s - 0.9) <= 0.5 * h + 1e-12


def test_first_collapse_exact_on_parabolic_minimum():
    # linear fall, then an exact parabola (vertex t = 0.52, R = 0.2) over the samples around the minimum
    t = 0.013 + 0.05 * np.arange(21)
    R = np.where(t < 0.45, 1 - 1.6 * t, 0.2 + 3.0 * (t - 0.52) ** 2)
    c = pp.first_collapse(t, R, 0)
    assert c.index == int(np.argmin(R)) and c.method == "parabola"
    assert c.t_s == pytest.approx(0.52, abs=1e-12)
    assert c.r_m == pytest.approx(0.2, abs=1e-12)


def test_first_collapse_ignores_small_wiggles_on_the_way_down():
    t = np.linspace(-0.3, 3.0, 200)
    R = curve(t)
    i = int(np.searchsorted(t, 0.4))
    R[i] += 0.02  # a 2 % bump (below the 5 % rebound threshold) during the collapse
    m = pp.locate_rmax(t, R)
    c = pp.first_collapse(t, R, m.index)
    assert abs(c.t_s - 0.9) < 0.02


def test_first_collapse_record_too_short():
    t = np.linspace(-0.3, 0.85, 30)
    with pytest.raises(pp.RecordTooShort, match="too short"):
        pp.first_collapse(t, curve(t), int(np.argmax(curve(t))))


def test_first_collapse_ends_at_minimum_is_too_short():
    t = np.linspace(-0.3, 0.9, 30)
    with pytest.raises(pp.RecordTooShort, match="ends at its minimum"):
        pp.first_collapse(t, curve(t), int(np.argmax(curve(t))))


# ----------------------------------------------------------------------------- estimate_req
def test_estimate_req_mean_and_sd_of_tail():
    rng = np.random.default_rng(3)
    R = np.concatenate([np.linspace(1, 0.1, 30), 0.2 + 0.01 * rng.standard_normal(50)])
    res = pp.estimate_req(R, i_collapse=29, n_tail=20)
    tail = R[-20:]
    assert res.req_m == pytest.approx(tail.mean(), rel=1e-14)
    assert res.sd_m == pytest.approx(tail.std(ddof=1), rel=1e-14)
    assert res.se_m == pytest.approx(tail.std(ddof=1) / math.sqrt(20), rel=1e-14)
    assert res.n == 20 and res.warning is None
    assert abs(res.req_m - 0.2) < 4 * res.se_m


def test_estimate_req_never_reaches_back_to_collapse():
    R = np.concatenate([np.linspace(1, 0.1, 30), np.full(8, 0.2)])
    res = pp.estimate_req(R, i_collapse=29, n_tail=20)
    assert res.n == 8 and res.req_m == pytest.approx(0.2) and "only 8" in res.warning


def test_estimate_req_warns_when_tail_oscillates():
    R = np.concatenate([np.linspace(1, 0.1, 30), 0.2 * (1 + 0.3 * np.sin(np.arange(40)))])
    assert "varies" in pp.estimate_req(R, 29).warning


# ----------------------------------------------------------------------------- scaling, resampling
def test_time_scale_and_nondimensionalise():
    rmax = 263e-6
    tc = pp.time_scale_s(rmax, RHO, P8)
    assert tc == pytest.approx(263e-6 / math.sqrt(101325 / 1064), rel=1e-15)
    ts, Rs = pp.nondimensionalise([1e-6, 2e-6], [263e-6, 100e-6], 1e-6, rmax, tc)
    np.testing.assert_allclose(ts, [0.0, 1e-6 / tc], rtol=1e-15)
    np.testing.assert_allclose(Rs, [1.0, 100 / 263], rtol=1e-15)
    np.testing.assert_allclose(
        pp.time_scale_s(np.array([1e-4, 2e-4]), RHO, P8), [1e-4 / 9.7586, 2e-4 / 9.7586], rtol=1e-4
    )


def test_resample_linear_exact_on_linear_data_and_anchor():
    t = np.array([-0.1, 0.013, 0.5, 1.7, 3.2])
    R = 1.0 - 0.1 * t
    R[0] = 0.9  # before the maximum: ignored
    grid, values, n = pp.resample(t, R, 0.025, 120)
    assert n == 120 and grid.shape == (121,) and values.shape == (121,)
    np.testing.assert_allclose(grid, np.arange(121) * 0.025, rtol=0, atol=1e-15)
    assert values[0] == 1.0
    np.testing.assert_allclose(values[1:], 1.0 - 0.1 * grid[1:], rtol=1e-13)


def test_resample_truncates_short_record():
    t = np.linspace(0, 2.01, 50)
    grid, values, n = pp.resample(t, 1 - 0.1 * t, 0.025, 120)
    assert n == 80 and grid[-1] == pytest.approx(2.0) and values.size == 81


def test_resample_pchip_no_overshoot():
    t = np.linspace(0, 3.1, 35)
    R = curve(t)
    _, v, _ = pp.resample(t, R, 0.025, 120, method="pchip")
    assert v.min() >= R.min() - 1e-12 and v.max() <= 1.0 + 1e-12


def test_resample_accuracy_against_truth():
    t = np.arange(0, 3.3, 0.02)
    grid, v, _ = pp.resample(t, curve(t), 0.025, 120)
    assert np.max(np.abs(v - curve(grid))) < 2e-3


# ----------------------------------------------------------------------------- noise variance
def test_paper_sigma_values():
    assert paper_sigma(0.0, 1.0) == 0.0
    assert paper_sigma(1.0, 0.5) == pytest.approx(0.5 / 20 + (1 - math.exp(-0.1)) / 30, rel=1e-15)
    assert paper_sigma(np.zeros(3), np.array([1.0, 0.0, 2.0])).tolist() == [0.0, 0.05, 0.05]


def test_noise_variance_sample_variance_with_floor():
    t = np.arange(5) * 0.025
    Y = np.array([[1.0, 0.99, 0.9, 0.5, 0.3], [1.0, 0.99, 0.8, 0.6, 0.1], [1.0, 0.99, 0.7, 0.4, 0.2]])
    P, info = noise_variance(t, Y)
    raw = Y.var(axis=0, ddof=1)
    floor = max(P_FLOOR_ABS, P_FLOOR_REL * np.median(raw))
    assert info["method"] == "sample-variance" and info["floor"] == pytest.approx(floor)
    np.testing.assert_allclose(P, np.maximum(raw, floor), rtol=1e-14)
    assert P[0] == floor and P[1] == floor and info["n_floored"] == 2
    assert np.all(np.isfinite(1 / P))


def test_noise_variance_single_experiment_uses_paper_model():
    t = np.arange(121) * 0.025
    y = curve(t)
    P, info = noise_variance(t, y[None, :])
    assert info["method"] == "paper-noise-model"
    raw = paper_sigma(t, y) ** 2
    np.testing.assert_allclose(P, np.maximum(raw, info["floor"]), rtol=1e-14)
    assert P[0] == info["floor"] > 0


def test_noise_variance_relative_floor_dominates_for_noisy_data():
    rng = np.random.default_rng(0)
    t = np.arange(50) * 0.025
    Y = 1 + 0.1 * rng.standard_normal((5, 50))
    Y[:, 0] = 1.0
    P, info = noise_variance(t, Y)
    assert info["floor"] == pytest.approx(P_FLOOR_REL * np.median(Y.var(axis=0, ddof=1)))
    assert P[0] == info["floor"]


def test_noise_variance_pooled_is_the_running_mean_of_the_sample_variance():
    rng = np.random.default_rng(3)
    t = np.arange(121) * 0.025
    Y = curve(t)[None, :] + 0.02 * rng.standard_normal((5, 121))
    P, info = noise_variance(t, Y, method="pooled")
    raw = Y.var(axis=0, ddof=1)
    padded = np.concatenate([np.full(5, raw[0]), raw, np.full(5, raw[-1])])  # edges: nearest value
    pooled = np.array([padded[k : k + 11].mean() for k in range(121)])
    assert info["method"] == "pooled-sample-variance"
    np.testing.assert_allclose(P, np.maximum(pooled, info["floor"]), rtol=1e-12)


def test_pooled_noise_weights_are_nearly_unbiased_where_the_sample_variance_doubles_them():
    """Five records, sd 0.02: the per-step 1/var has mean 2/sigma^2 (4 degrees of freedom);
    pooled over 11 steps it is within 10 % of 1/sigma^2."""
    rng = np.random.default_rng(11)
    t = np.arange(401) * 0.025
    Y = 0.5 + 0.02 * rng.standard_normal((5, 401))
    inv = {
        m: np.mean(1.0 / noise_variance(t, Y, floor_abs=0.0, floor_rel=0.0, method=m)[0]) * 0.02**2
        for m in ("sample", "pooled")
    }
    assert inv["sample"] > 1.6
    assert abs(inv["pooled"] - 1.0) < 0.1


def test_noise_method_is_checked():
    with pytest.raises(ValueError, match="pooled"):
        noise_variance(np.arange(3) * 0.025, np.ones((1, 3)), method="pooled")
    with pytest.raises(ValueError, match="must be"):
        noise_variance(np.arange(3) * 0.025, np.ones((2, 3)), method="median")


# ----------------------------------------------------------------------------- whole pipeline
def test_preprocess_dataset_recovers_truth(tmp_path):
    truths = make_dataset(tmp_path / "ds", n_exp=4, h_star=0.03)
    pre = preprocess_dataset(load_dataset(tmp_path / "ds"))
    assert pre.t_star.shape == (121,) and pre.R_star.shape == (4, 121) and pre.P.shape == (121,)
    assert pre.rmax_m.shape == (4,) and pre.req_m.shape == (4,)
    for i, tr in enumerate(truths):
        assert pre.rmax_m[i] == pytest.approx(tr["rmax_m"], rel=1e-5)
        assert pre.req_m[i] == pytest.approx(tr["req_m"], rel=1e-3)
        assert pre.t_collapse_star[i] == pytest.approx(0.9, abs=0.003)
        assert pre.experiments[i].t0_s == pytest.approx(tr["t0_s"], abs=1e-3 * tr["tc_s"])
        np.testing.assert_allclose(pre.R_star[i], curve(pre.t_star), atol=3e-3)
    assert pre.R_star[:, 0].tolist() == [1.0] * 4
    assert pre.choices["n_steps"] == 120 and pre.choices["noise"]["method"] == "sample-variance"
    d = pre.to_dict()
    assert set(d) >= {"dataset", "choices", "experiments", "summary", "warnings", "grid"}


def test_preprocess_dataset_truncates_with_warning(tmp_path):
    make_dataset(tmp_path / "ds", n_exp=2, t_end=2.2)
    pre = preprocess_dataset(load_dataset(tmp_path / "ds"))
    assert pre.n_steps < 120 and pre.t_star[-1] <= 2.2
    assert any("truncated" in w for w in pre.warnings)


def test_preprocess_dataset_physics_override_changes_time_scale(tmp_path):
    make_dataset(tmp_path / "a", n_exp=2)
    make_dataset(tmp_path / "b", n_exp=2, meta={"material": "x", "physics": {"rho": 998.0, "P8": 90000.0}})
    # the three-point maximum, whose Rmax does not depend on the physics (local-fit sizes its window in t_c)
    a = preprocess_dataset(load_dataset(tmp_path / "a"), rmax_method="parabola")
    b = preprocess_dataset(load_dataset(tmp_path / "b"), rmax_method="parabola")
    ratio = b.experiments[0].tc_s / a.experiments[0].tc_s
    assert ratio == pytest.approx(math.sqrt(998.0 / 1064.0 * 101325.0 / 90000.0), rel=1e-12)
    assert b.choices["rho_kg_m3"] == 998.0 and b.choices["p8_Pa"] == 90000.0


def test_preprocess_dataset_uses_meta_req(tmp_path):
    meta = {"material": "x", "experiments": {"exp_001.csv": {"Req_m": 5.0e-5, "Req_sd_m": 1e-6}}}
    make_dataset(tmp_path / "ds", n_exp=2, meta=meta)
    pre = preprocess_dataset(load_dataset(tmp_path / "ds"))
    assert pre.req_m[0] == 5.0e-5 and pre.req_sd_m[0] == 1e-6
    assert pre.experiments[0].req_source == "meta.json"
    assert "last 20 samples" in pre.experiments[1].req_source  # from the record's own tail


def test_preprocess_single_experiment_fallback(tmp_path):
    make_dataset(tmp_path / "ds", n_exp=1)
    pre = preprocess_dataset(load_dataset(tmp_path / "ds"))
    assert pre.choices["noise"]["method"] == "paper-noise-model"
    assert any("one experiment" in w for w in pre.warnings)


def test_preprocess_short_record_refused(tmp_path):
    make_dataset(tmp_path / "ds", n_exp=2, t_end=0.8)
    with pytest.raises(InputError, match="too short to reach the first collapse"):
        preprocess_dataset(load_dataset(tmp_path / "ds"))


def test_preprocess_does_not_modify_dataset(tmp_path):
    make_dataset(tmp_path / "ds", n_exp=2)
    ds = load_dataset(tmp_path / "ds")
    before = [(e.t_s.copy(), e.R_m.copy()) for e in ds.experiments]
    preprocess_dataset(ds)
    for (t, R), e in zip(before, ds.experiments):
        assert np.array_equal(t, e.t_s) and np.array_equal(R, e.R_m)


def test_record_helper_consistency():
    t, R, truth = record()
    assert R.max() <= truth["rmax_m"]


def test_unsettled_tail_is_labelled_and_gives_no_tail_frames_to_rescale(tmp_path):
    """The fixture's records still decay towards Req at their end (their last 20 samples vary by
    more than 10 %): the summary says Req is not a tail mean, `req_tail=model` (which rescales a
    tail *mean*) is given no frames for it, and Req stays at or above the true one (a decaying tail's
    lowest point is above Req)."""
    truths = make_dataset(tmp_path / "ds", n_exp=2)
    pre = preprocess_dataset(load_dataset(tmp_path / "ds"))
    for e, tr in zip(pre.experiments, truths):
        assert "not settled" in e.req_source and e.req_tail_t_star == []
        assert tr["req_m"] <= e.req_m * 1.001 and e.req_sd_m > 0
