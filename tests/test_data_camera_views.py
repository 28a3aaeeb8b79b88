"""``--camera mean``: one experiment per bubble from its camera views, averaged frame by frame.

Independent truth: synthetic views of a known curve, made non-round by a known factor (the views'
mean is the curve itself) and given independent noise of a known sd (the mean's is sd / sqrt 2).
"""

import json
import math

import numpy as np
import pytest
from _data_synth import LIC, make_dataset, record, write_csv
from click.testing import CliRunner

from imrbayes.cli import main
from imrbayes.data import load_dataset, preprocess_dataset
from imrbayes.data.loaders import MEAN_OF_VIEWS
from imrbayes.data.preprocess import estimate_noise_sd
from imrbayes.errors import InputError

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
