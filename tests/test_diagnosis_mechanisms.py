"""imrbayes diagnose on camera-style data: hide an effect and require finding it; hide nothing and
require no alarm.

Each dataset comes from :func:`imrbayes.diagnosis.synthetic.camera_obs`: frames at a camera rate
with a random sub-frame phase, noise on every frame (the maximum included), Rmax, the time of the
maximum and Req *estimated* by the preprocessing, and data made by a finer forward model than the
fitted one. The material and the hidden mechanism's parameters are drawn inside (seeded) from the
realistic ranges of :mod:`imrbayes.diagnosis.candidates`. Quick settings (19 bootstrap replicates,
no LOEO, no MIEnKS drift). The full classes x seeds confusion matrix and the 20-dataset false-alarm
rate are ``python -m validation confusion`` (docs/diagnosis.md).
"""

import numpy as np
import pytest

from imrbayes.diagnosis import DiagnoseSettings, diagnose
from imrbayes.diagnosis.synthetic import camera_obs
from imrbayes.forward import ForwardOptions

# Each test is a full diagnose run (minutes): the default tier's diagnose is test_diagnosis_cli.py.
pytestmark = pytest.mark.slow

OPTS = ForwardOptions(bubble="polytropic")


def _run(mechanism, seed, design=None, **kw):
    obs, truth = camera_obs(mechanism, seed, OPTS, design=design)
    s = DiagnoseSettings.quick(loeo=False, mienks_drift=False, **kw)
    d = diagnose(obs, OPTS, settings=s, seed=seed)
    return d.result, truth


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


# each hidden cause against the alternatives it is most often taken for (docs/diagnosis.md: damage and
# zener tie with stiffening; zener with lambda1 -> 0 and Gilmore stand in for missing bubble physics);
# every candidate against every class is the confusion matrix's job (validation/confusion.py)
RIVALS = {
    "strain-stiffening": ("qkv", "zener", "damage"),
    "bubble-thermal": ("bubble-thermal", "bubble-gilmore", "zener", "qkv"),
}


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


@pytest.mark.parametrize(
    "mechanism,seed", [("viscoelastic-relaxation", 7), ("rate-dependent-viscosity", 9), ("damage-softening", 5)]
)
def test_hidden_mechanism_is_found_more(mechanism, seed):
    r, truth = _run(mechanism, seed)
    assert r["cause"] == mechanism, [(c["mechanism"], c["score"]) for c in r["candidates"]]
    assert r["gain"]["relative_reduction"] > 0
