"""Preprocessing: each function against independent truth, camera-style records and ``--camera
mean``."""

import json
import math

import numpy as np
import pytest
from _data_synth import LIC, P8, RHO, curve, make_dataset, record, write_csv
from click.testing import CliRunner

from imrbayes.cli import main
from imrbayes.data import load_dataset, preprocess as pp, preprocess_dataset
from imrbayes.data.loaders import MEAN_OF_VIEWS
from imrbayes.data.noise import P_FLOOR_ABS, P_FLOOR_REL, noise_variance, paper_sigma
from imrbayes.data.preprocess import estimate_noise_sd
from imrbayes.errors import InputError

# Each preprocessing function against independent truth (synthetic curves, known answers).


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


# ``--camera mean``: one experiment per bubble from its camera views, averaged frame by frame.
#
# Independent truth: synthetic views of a known curve, made non-round by a known factor (the views'
# mean is the curve itself) and given independent noise of a known sd (the mean's is sd / sqrt 2).


needs_shared = pytest.mark.skipif(not LIC.is_dir(), reason="shared data (../shared/data/lic) not present")


def two_views(d, n_exp=2, ovality=0.0, noise_m=0.0, drop=(), seed=0):
    """Views cam0deg / cam90deg of ``n_exp`` bubbles: R (1 - e) and R (1 + e), e rising from 0 at the
    maximum to ``ovality`` at the end; independent noise; frames ``drop`` removed from cam90deg."""
    rng = np.random.default_rng(seed)
    d.mkdir(parents=True, exist_ok=True)
    truths = []
    for i in range(n_exp):
        t, R, truth = record(rmax_m=(300 + 40 * i) * 1e-6, offset=0.2 + 0.3 * i, h_star=0.03)
        e = ovality * np.clip((t - t[0]) / (t[-1] - t[0]), 0, 1)
        for cam, sign in (("cam0deg", -1.0), ("cam90deg", 1.0)):
            Rv = R * (1.0 + sign * e) + noise_m * rng.standard_normal(R.size)
            keep = np.ones(R.size, bool)
            if cam == "cam90deg":
                keep[list(drop)] = False
            write_csv(d / f"bubble_{i + 1:02d}_{cam}.csv", t[keep], Rv[keep])
        truths.append((t, R, truth))
    (d / "meta.json").write_text('{"material": "synthetic"}')
    return truths


def test_mean_of_views_is_one_bubble_each_and_their_mean(tmp_path):
    truths = two_views(tmp_path / "ds", ovality=0.08)
    both = load_dataset(tmp_path / "ds")
    assert len(both.experiments) == 4 and any("not independent" in w for w in both.warnings)
    ds = load_dataset(tmp_path / "ds", camera=MEAN_OF_VIEWS)
    assert ds.names == ["bubble_01", "bubble_02"]
    assert not any("not independent" in w for w in ds.warnings)
    for e, (t, R, truth) in zip(ds.experiments, truths):
        np.testing.assert_allclose(e.t_s, t, rtol=0, atol=1e-15)
        np.testing.assert_allclose(e.R_m, R, rtol=1e-12)  # (1 - e) and (1 + e) average out
        assert e.info["views"] == [f"{e.name}_cam0deg", f"{e.name}_cam90deg"]
        # the tail views differ by ~2 x 0.08 x Req: half of it is the spread
        assert e.info["view_req_spread_m"] == pytest.approx(0.08 * truth["req_m"], rel=0.1)
    assert any("disagree late" in w and "bubble_01" in w for w in ds.warnings)


def test_round_bubble_views_raise_no_warning_and_halve_the_noise_variance(tmp_path):
    sd = 2e-6
    two_views(tmp_path / "ds", n_exp=1, noise_m=sd, seed=3)
    ds = load_dataset(tmp_path / "ds", camera=MEAN_OF_VIEWS)
    assert not any("disagree late" in w for w in ds.warnings)
    one = load_dataset(tmp_path / "ds", camera="cam0deg").experiments[0]
    # the noise estimate (fourth differences) of one view and of the mean, against the known sd
    assert estimate_noise_sd(one.R_m) == pytest.approx(sd, rel=0.25)
    assert estimate_noise_sd(ds.experiments[0].R_m) == pytest.approx(sd / math.sqrt(2), rel=0.25)


def test_req_uncertainty_carries_the_views_disagreement(tmp_path):
    two_views(tmp_path / "round", n_exp=1, noise_m=1e-7)
    two_views(tmp_path / "oval", n_exp=1, noise_m=1e-7, ovality=0.10)
    r = preprocess_dataset(load_dataset(tmp_path / "round", camera=MEAN_OF_VIEWS)).experiments[0]
    o = preprocess_dataset(load_dataset(tmp_path / "oval", camera=MEAN_OF_VIEWS)).experiments[0]
    spread = load_dataset(tmp_path / "oval", camera=MEAN_OF_VIEWS).experiments[0].info["view_req_spread_m"]
    assert o.req_m == pytest.approx(r.req_m, rel=1e-6)  # the mean itself is round
    assert o.req_sd_m == pytest.approx(math.hypot(r.req_sd_m, spread), rel=1e-4)
    assert o.req_sd_m > 5 * r.req_sd_m and "half-difference" in o.req_source


def test_frames_missing_from_one_view_are_dropped_with_a_warning(tmp_path):
    truths = two_views(tmp_path / "ds", n_exp=1, drop=(5, 40))
    ds = load_dataset(tmp_path / "ds", camera=MEAN_OF_VIEWS)
    e = ds.experiments[0]
    assert e.n_samples == truths[0][0].size - 2
    assert any("2 frame(s) missing" in w for w in e.warnings)


def test_nothing_to_average_is_a_clear_error(tmp_path):
    make_dataset(tmp_path / "plain", n_exp=2)
    with pytest.raises(InputError, match=r"plain.*has no camera view label"):
        load_dataset(tmp_path / "plain", camera=MEAN_OF_VIEWS)
    two_views(tmp_path / "ds", n_exp=2)
    (tmp_path / "ds" / "bubble_02_cam90deg.csv").unlink()
    with pytest.raises(InputError, match=r"bubble 'bubble_02' has one view only \(cam0deg\)"):
        load_dataset(tmp_path / "ds", camera=MEAN_OF_VIEWS)


@needs_shared
def test_umich_dual_camera_bubbles_averaged():
    """The UMich records: five bubbles, two views each on one time axis; the views' late
    difference (3-7 µm, 90° larger, on ~30 µm) widens Req's uncertainty on four of them."""
    folder = LIC / "umich_PA10_bis0.06_1Mfps_dualcam"
    views = load_dataset(folder)
    ds = load_dataset(folder, camera=MEAN_OF_VIEWS)
    assert len(ds.experiments) == 5 and len(views.experiments) == 10
    for e in ds.experiments:
        a, b = (v for v in views.experiments if v.name in e.info["views"])
        np.testing.assert_allclose(e.R_m, 0.5 * (a.R_m + b.R_m), rtol=1e-14)
    spreads = sorted(e.info["view_req_spread_m"] for e in ds.experiments)
    assert spreads[0] < 1e-6 and 1.5e-6 < spreads[-1] < 5e-6
    assert sum("% of the tail radius" in w for w in ds.warnings) == 1


def test_inspect_cli_with_mean_views(tmp_path):
    """The CLI passes ``--camera mean`` through: two bubbles in dataset.json; a dataset without
    camera labels is one line of bad input naming it."""
    two_views(tmp_path / "ds", n_exp=2)
    res = CliRunner().invoke(
        main,
        ["inspect", str(tmp_path / "ds"), "--camera", "mean", "--out", str(tmp_path / "out")],
        catch_exceptions=False,
    )
    assert res.exit_code == 0, res.output
    info = json.loads((tmp_path / "out" / "dataset.json").read_text())
    names = [e["name"] for e in info["experiments"]]
    assert names == ["bubble_01", "bubble_02"]
    make_dataset(tmp_path / "plain", n_exp=2)
    bad = CliRunner().invoke(main, ["inspect", str(tmp_path / "plain"), "--camera", "mean"])
    assert bad.exit_code == 2 and "no camera view label" in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1


def test_req_given_for_both_views_is_averaged(tmp_path):
    two_views(tmp_path / "ds", n_exp=1, ovality=0.1)
    meta = {
        "material": "synthetic",
        "experiments": {
            "bubble_01_cam0deg.csv": {"Req_m": 40e-6, "Req_sd_m": 1e-6},
            "bubble_01_cam90deg.csv": {"Req_m": 44e-6, "Req_sd_m": 3e-6},
        },
    }
    (tmp_path / "ds" / "meta.json").write_text(json.dumps(meta))
    e = load_dataset(tmp_path / "ds", camera=MEAN_OF_VIEWS).experiments[0]
    assert e.req_m == pytest.approx(42e-6) and e.req_sd_m == pytest.approx(2e-6)
    assert e.req_source == "meta.json"
    # a given Req is the user's: the views' spread is not added to it
    pre = preprocess_dataset(load_dataset(tmp_path / "ds", camera=MEAN_OF_VIEWS)).experiments[0]
    assert pre.req_m == pytest.approx(42e-6) and pre.req_sd_m == pytest.approx(2e-6)
