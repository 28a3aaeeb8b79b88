"""The diagnosis on camera-style records: the synthetic records with a hidden mechanism, and
finding that mechanism (or none) with ``imrbayes diagnose``."""

import numpy as np
import pytest

from imrbayes.diagnosis import DiagnoseSettings, diagnose
from imrbayes.diagnosis.synthetic import (
    BUBBLE_GENERATORS,
    DESIGNS,
    GENERATORS,
    Design,
    bubble_effect,
    camera_mechanisms,
    camera_obs,
    clean_curves,
    data_options,
    fine_options,
)
from imrbayes.forward import ForwardOptions

# diagnosis.synthetic.camera_obs: camera-style records with a hidden mechanism, processed as
# measured data; the bubble classes; the data-generating forward options.


POLY = ForwardOptions(bubble="polytropic")


def test_camera_obs_estimates_like_measured_data():
    obs, truth = camera_obs("none", 3, POLY)
    n = obs.n_exp
    assert n == 5 and truth["names"] == obs.names
    rmax, req, tmax = (np.array(truth[k]) for k in ("rmax_m", "req_m", "t_max_s"))
    # estimated from noisy frames: close to the truth, not equal to it
    assert np.all(np.abs(obs.rmax_m / rmax - 1) < 0.03)
    assert np.all(np.abs(obs.req_m / req - 1) < 0.08)
    assert np.all(np.abs(obs.t0_s - tmax) < 1.5e-6)  # within 1.5 frames
    assert np.max(np.abs(obs.rmax_m - rmax)) > 1e-9 and np.max(np.abs(obs.req_m - req)) > 1e-9
    # what a CSV read from disk carries
    assert obs.frame_t is not None and len(obs.frame_t) == n
    assert np.all(np.isfinite(obs.tc_s)) and np.all(np.isfinite(obs.t0_s))
    assert np.all(obs.nuisance_sd[:, 0] > 0) and np.all(obs.nuisance_sd[:, 2] > 0)
    sd_true = np.array([e["noise_sd_at_max_r_star"] for e in truth["experiments"]])
    assert np.all(obs.noise_sd / sd_true > 0.6) and np.all(obs.noise_sd / sd_true < 1.5)
    # frames 1 µs apart in the record's own t*; the grid reaches t* = 3
    dt = np.diff(obs.frame_t[0][1:])
    assert np.allclose(dt, 1e-6 / obs.tc_s[0], rtol=1e-6)
    assert obs.t_star[-1] == pytest.approx(3.0)
    # truth: geometry, design, forward options of the data (finer than the fit's)
    assert truth["design"]["frame_s"] == 1e-6 and truth["noise"] == {"kind": "gaussian_um", "sd_um": 2.0}
    assert truth["data_forward"]["rtol"] < POLY.rtol
    assert truth["mechanism"] == "none" and set(truth["theta"]) == {"G", "mu"}


def test_camera_obs_is_reproducible_and_seeded():
    a, ta = camera_obs("none", 5, POLY, n_exp=2)
    b, _ = camera_obs("none", 5, POLY, n_exp=2)
    c, _ = camera_obs("none", 6, POLY, n_exp=2)
    assert np.array_equal(a.R_star, b.R_star) and not np.array_equal(a.R_star, c.R_star)
    assert ta["design"]["n_exp"] == 2


def test_designs_and_scatter():
    assert len(DESIGNS) >= 3 and all(isinstance(d, Design) for d in DESIGNS.values())
    obs, truth = camera_obs("none", 1, POLY, design="270kfps-2um-3")
    assert obs.n_exp == 3
    # at 270 kfps a damped bubble's rebound can fall between frames: the preprocessing refuses the
    # record and another bubble is recorded (numbered on)
    assert len(truth["discarded"]) >= 1 and "first collapse" in truth["discarded"][0]["error"]
    assert set(obs.names) == {e["name"] for e in truth["experiments"]}
    assert max(int(nm[4:]) for nm in obs.names) == 3 + len(truth["discarded"])
    assert np.allclose(np.diff(obs.frame_t[0][1:]), (1 / 270e3) / obs.tc_s[0], rtol=1e-6)
    obs, truth = camera_obs("none", 1, POLY, n_exp=4, scatter={"G": 0.2})
    Gs = [e["parameters"]["G"] for e in truth["experiments"]]
    assert len(set(Gs)) == 4 and all(e["parameters"]["mu"] == truth["theta"]["mu"] for e in truth["experiments"])


def test_damage_breaks_at_the_true_collapses():
    obs, truth = camera_obs("damage-softening", 2, POLY, n_exp=2)
    for e in truth["experiments"]:
        assert len(e["breaks_star"]) >= 1 and 0.85 < e["breaks_star"][0] < 1.0


def test_every_class_is_generated():
    classes = camera_mechanisms()
    assert list(classes)[: len(GENERATORS)] == list(GENERATORS)
    assert set(BUBBLE_GENERATORS) <= set(classes)


def test_data_options_of_the_bubble_classes():
    thermal = ForwardOptions()
    assert data_options(POLY, "bubble-thermal").bubble == "thermal"
    assert data_options(POLY, "bubble-thermal").method == "radau5"
    w = data_options(thermal, "bubble-thermal")  # the candidate's alternative: mass transfer switched
    assert (w.bubble, w.medium, w.mass_transfer) == ("thermal", "cold", not thermal.mass_transfer)
    assert data_options(thermal, "bubble-compressibility").radial == "gilmore"
    assert data_options(thermal, "bubble-compressibility").resolution == fine_options(thermal).resolution
    assert data_options(ForwardOptions(radial="gilmore"), "bubble-compressibility").radial == "km"
    # the fit's own discretisation is never the data's
    f = fine_options(thermal)
    assert f.resolution[0] > thermal.resolution[0] and f.rtol < thermal.rtol
    same = data_options(thermal, "none", truth_options=thermal)
    assert same == thermal


def test_bubble_classes_change_the_curves():
    t = np.linspace(0.0, 3.0, 301)
    R0, rmax = clean_curves("none", 0, POLY, t, n_exp=2)
    Rt, _ = clean_curves("bubble-thermal", 0, POLY, t, n_exp=2)
    Rc, _ = clean_curves("bubble-compressibility", 0, POLY, t, n_exp=2)
    um = rmax[:, None] * 1e6
    assert np.sqrt(np.mean(((Rt - R0) * um) ** 2)) > 20.0  # measured ~100 µm (module comment)
    assert np.sqrt(np.mean(((Rc - R0) * um) ** 2)) > 1.0  # measured ~4 µm
    e = bubble_effect("bubble-compressibility", 0, POLY)
    assert e["rms_over_noise"] == pytest.approx(e["rms_um"] / 2.0) and e["rms_um"] > 1.0


def test_strength_design_draws_violent_bubbles_and_leaves_the_others_alone():
    """A STRENGTH_DESIGNS entry replaces the baseline's mu range and the geometry; the varied DESIGNS
    (and so the committed matrix rows, e.g. thermal class none seed 0: G 7.25 kPa, mu 0.057 Pa s)
    draw what they drew before."""

    from imrbayes.diagnosis.synthetic import STRENGTH_DESIGNS, design_of

    assert not set(STRENGTH_DESIGNS) & set(DESIGNS)  # never in the null cycle
    with pytest.raises(KeyError, match="unknown design"):
        design_of("no-such-design")
    mus, ratios = [], []
    for seed in range(6100, 6106):
        obs, truth = camera_obs("bubble-compressibility", seed, POLY, n_exp=2, design="1Mfps-1um-5-violent")
        mus.append(truth["theta"]["mu"])
        ratios += [a / b for a, b in zip(truth["rmax_m"], truth["req_m"])]
        assert truth["noise"] == {"kind": "gaussian_um", "sd_um": 1.0}
    assert min(mus) >= 0.02 and max(mus) <= 0.05
    assert min(ratios) >= 9.5 - 3 * 0.3 and max(ratios) <= 9.5 + 3 * 0.3
    # the null cycle's draws are the seed's alone: the same seed gives the same truth
    _, truth = camera_obs("none", 0, POLY, n_exp=2)
    _, again = camera_obs("none", 0, POLY, n_exp=2)
    assert truth["theta"] == again["theta"] and truth["rmax_m"] == again["rmax_m"]


# imrbayes diagnose on camera-style data: hide an effect and require finding it; hide nothing and
# require no alarm.
#
# Each dataset comes from :func:`imrbayes.diagnosis.synthetic.camera_obs`: frames at a camera rate
# with a random sub-frame phase, noise on every frame (the maximum included), Rmax, the time of the
# maximum and Req *estimated* by the preprocessing, and data made by a finer forward model than the
# fitted one. The material and the hidden mechanism's parameters are drawn inside (seeded) from the
# realistic ranges of :mod:`imrbayes.diagnosis.candidates`. Quick settings (19 bootstrap replicates,
# no LOEO, no MIEnKS drift). The full classes x seeds confusion matrix and the 20-dataset false-alarm
# rate are ``python -m validation confusion`` (docs/methods.md).


# Each test is a full diagnose run (minutes): the default tier's diagnose is test_diagnosis_cli.py.

OPTS = ForwardOptions(bubble="polytropic")


def _run(mechanism, seed, design=None, **kw):
    obs, truth = camera_obs(mechanism, seed, OPTS, design=design)
    s = DiagnoseSettings.quick(loeo=False, mienks_drift=False, **kw)
    d = diagnose(obs, OPTS, settings=s, seed=seed)
    return d.result, truth


@pytest.mark.slow
@pytest.mark.parametrize("design,seed", [("1Mfps-2um-5", 11), ("270kfps-2um-3", 12), ("2Mfps-4um-8", 13)])
def test_constant_nhkv_is_adequate(design, seed):
    """No alarm on constant-parameter data of three different designs, and the baseline's estimate
    near the truth (the geometry is estimated, not given)."""
    r, truth = _run("none", seed, design, candidates=("qkv",))  # the verdict is the point: one candidate
    assert r["constant_parameter_check"]["verdict"] == "adequate", r["constant_parameter_check"]["evidence"]["p_value"]
    assert r["cause"] == "none"
    assert r["extended_model"] is None
    est = r["baseline"]["estimate"]
    assert abs(np.log(est["G"]["median"] / truth["theta"]["G"])) < 0.25
    assert abs(np.log(est["mu"]["median"] / truth["theta"]["mu"])) < 0.25


@pytest.mark.slow
def test_stop_when_adequate_keeps_the_verdict(tmp_path):
    """compare_when_adequate=False ends an adequate diagnosis after the check: the same verdict,
    p-value and cause as the full run, no candidate compared, and the figures without candidates.png."""
    from imrbayes.diagnosis.figures import write_figures

    full, _ = _run("none", 11, "1Mfps-2um-5", candidates=("qkv",))
    obs, _ = camera_obs("none", 11, OPTS, design="1Mfps-2um-5")
    d = diagnose(
        obs,
        OPTS,
        settings=DiagnoseSettings.quick(
            loeo=False, mienks_drift=False, candidates=("qkv",), compare_when_adequate=False
        ),
        seed=11,
    )
    short = d.result
    for key in ("verdict", "p_value"):
        a, b = full["constant_parameter_check"], short["constant_parameter_check"]
        assert (a.get(key) or a["evidence"][key]) == (b.get(key) or b["evidence"][key])
    assert short["cause"] == full["cause"] == "none" and short["candidates"] == [] and short["gain"] == {}
    assert short["baseline"]["estimate"] == full["baseline"]["estimate"]
    assert "not compared" in short["comparison_note"]
    assert [x["stage"].split(" (")[0] for x in short["stage_seconds"]][-1] == "constant-parameter check"
    figs = write_figures(d, tmp_path)
    assert sorted(p.name for p in figs) == ["check.png", "residuals.png"]
    from imrbayes.diagnosis.report import write_report

    page = write_report(short, figs, tmp_path / "report.html").read_text()
    assert "the candidates were not compared" in page


# each hidden cause against the alternatives it is most often taken for (docs/methods.md: damage and
# zener tie with stiffening; zener with lambda1 -> 0 and Gilmore stand in for missing bubble physics);
# every candidate against every class is the confusion matrix's job (validation/confusion.py)
RIVALS = {
    "strain-stiffening": ("qkv", "zener", "damage"),
    "bubble-thermal": ("bubble-thermal", "bubble-gilmore", "zener", "qkv"),
}


@pytest.mark.slow
@pytest.mark.parametrize("mechanism,seed", [("strain-stiffening", 3), ("bubble-thermal", 4)])
def test_hidden_cause_is_found(mechanism, seed):
    """A material mechanism and a bubble-model cause (thermal bubble behind a polytropic fit)."""
    r, truth = _run(mechanism, seed, candidates=RIVALS[mechanism])
    assert r["constant_parameter_check"]["verdict"] == "inadequate"
    assert r["cause"] == mechanism or (
        r["cause"] == "ambiguous"
        and any(c["mechanism"] == mechanism for c in r["candidates"] if c["key"] in r["candidates_tied"])
    ), [(c["key"], c["score"]) for c in r["candidates"]]
    sig = r["signature"]  # its units ran: the data's and every contender's signature
    assert sig["observed"]["t_star"] and "nhkv" in sig["score"] and set(sig["predicted"]) == set(sig["score"])
    g = r["gain"]
    assert g["heldout_rmse_extended"] < g["heldout_rmse_baseline"]
    assert g["relative_reduction"] > 0
    if mechanism == "bubble-thermal":  # the right bubble model gives back the material
        top = next(c for c in r["candidates"] if c["key"] == "bubble-thermal")
        assert abs(np.log(top["estimate"]["G"]["median"] / truth["theta"]["G"])) < 0.3
        assert abs(np.log(top["estimate"]["mu"]["median"] / truth["theta"]["mu"])) < 0.3


@pytest.mark.slow
@pytest.mark.parametrize(
    "mechanism,seed", [("viscoelastic-relaxation", 7), ("rate-dependent-viscosity", 9), ("damage-softening", 5)]
)
def test_hidden_mechanism_is_found_more(mechanism, seed):
    r, truth = _run(mechanism, seed)
    assert r["cause"] == mechanism, [(c["mechanism"], c["score"]) for c in r["candidates"]]
    assert r["gain"]["relative_reduction"] > 0
