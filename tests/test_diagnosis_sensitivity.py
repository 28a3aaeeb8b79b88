"""The bubble-model sensitivity of the material estimate (diagnosis/sensitivity.py): the rule on
hand-made candidates, the report's sentence and section, and the key a real diagnosis writes."""

import pytest

from imrbayes.diagnosis import DiagnoseSettings, diagnose
from imrbayes.diagnosis.report import _bubble_section, verdict_sentences
from imrbayes.diagnosis.sensitivity import bubble_model_sensitivity
from imrbayes.diagnosis.synthetic import synthetic_obs
from imrbayes.forward import ForwardOptions

BASE = {"G": {"median": 5000.0, "sd": 200.0}, "mu": {"median": 0.05, "sd": 0.002}}


def _cand(key, kind, G, mu, diffs):
    """A candidate entry with held-out paired differences (mean_diff, se) per scheme."""
    return {
        "key": key,
        "kind": kind,
        "mechanism": {"bubble": "bubble-thermal"}.get(kind, "strain-stiffening"),
        "estimate": {"G": {"median": G, "sd": 100.0}, "mu": {"median": mu, "sd": 0.001}},
        "heldout": {k: {"paired_vs_baseline": {"mean_diff": d, "se": se}} for k, (d, se) in diffs.items()},
    }


def test_an_alternative_the_data_cannot_separate_that_moves_the_material_is_flagged():
    same = _cand("bubble-thermal", "bubble", 6500.0, 0.05, {"forecast": (1e-4, 2e-4), "loeo": (-3e-4, 2e-4)})
    s = bubble_model_sensitivity(
        [same, _cand("qkv", "material", 9000.0, 0.1, {"forecast": (0.0, 1.0)})],
        BASE,
        overrides={"bubble-thermal": {"mass_transfer": False}},
    )
    (a,) = s["alternatives"]  # material candidates are not alternatives
    assert a["shift"] == pytest.approx({"G": 0.3, "mu": 0.0})
    assert a["shift_sd"] == pytest.approx({"G": 7.5, "mu": 0.0})
    assert a["separation_se"] == pytest.approx(1.5)  # the larger of 0.5 and 1.5 SE
    assert a["indistinguishable"] and a["material_moves"] == ["G"]
    assert a["bubble_options"] == {"mass_transfer": False}
    assert s["material_depends_on_bubble_model"]


@pytest.mark.parametrize(
    "G, diffs",
    [
        (6500.0, {"forecast": (1e-3, 2e-4)}),  # the data separate them (5 SE): the bubble model is decided
        (5300.0, {"forecast": (0.0, 2e-4)}),  # 6 %: inside the relative threshold
        (5150.0, {"forecast": (0.0, 2e-4)}),  # 0.75 sd: inside the sd threshold
        (6500.0, {}),  # no held-out scheme: nothing says they are alike
    ],
)
def test_no_flag_when_the_data_decide_or_the_material_barely_moves(G, diffs):
    s = bubble_model_sensitivity([_cand("bubble-thermal", "bubble", G, 0.05, diffs)], BASE)
    assert not s["material_depends_on_bubble_model"]


def test_report_says_it_in_the_verdict_and_a_section():
    r = {
        "constant_parameter_check": {
            "verdict": "adequate",
            "evidence": {"p_value": 0.9, "n_bootstrap": 10, "alpha": 0.05, "statistics": {}},
        },
        "baseline": {"model": "nhkv", "misfit_by_phase": []},
        "cause": "none",
        "candidates": [],
        "gain": {},
    }
    assert not any("bubble model" in x for x in verdict_sentences(r))
    same = _cand("bubble-thermal", "bubble", 6500.0, 0.05, {"forecast": (1e-4, 2e-4)})
    r["bubble_model_sensitivity"] = bubble_model_sensitivity(
        [same], BASE, overrides={"bubble-thermal": {"mass_transfer": False}}
    )
    last = verdict_sentences(r)[-1]
    assert "depends on the bubble model" in last and "mass_transfer=False" in last and "G = 6.5 kPa (+30 %" in last
    html = _bubble_section(r)
    assert "Does the material estimate depend on the bubble model?" in html and "G = 5 kPa" in html


def test_a_diagnosis_with_a_bubble_candidate_reports_it():
    opts = ForwardOptions(bubble="polytropic")
    s = DiagnoseSettings.quick(n_bootstrap=2, candidates=("bubble-gilmore",), loeo=False, n_draws=20)
    r = diagnose(synthetic_obs("none", 11, opts, n_exp=3, noise_scale=0.5)[0], opts, settings=s, seed=0).result
    (a,) = r["bubble_model_sensitivity"]["alternatives"]
    (c,) = [c for c in r["candidates"] if c["key"] == "bubble-gilmore"]
    base = r["baseline"].get("estimate_map", r["baseline"]["estimate"])
    assert a["bubble_options"] == {"radial": "gilmore"}
    assert a["shift"]["G"] == pytest.approx(c["estimate"]["G"]["median"] / base["G"]["median"] - 1.0)
    pd = c["heldout"]["forecast"]["paired_vs_baseline"]
    assert a["separation_se"] == pytest.approx(abs(pd["mean_diff"]) / pd["se"])
