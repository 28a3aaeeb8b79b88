"""The report and the terminal in words: an interval the data do not bound said so, a model that
does not describe the records said first, the prior's share, a repeated warning said once, the truth
of synthetic data beside the estimate -- all from a hand-made summary.json (no fit needed)."""

import html
import json
import re

import pandas as pd
import pytest

import imrbayes
from imrbayes.cli.options import estimate_text
from imrbayes.report import bounds, grouped_warnings, write_run_report

UNITS = {"G": "Pa", "mu": "Pa s"}


def _summary(**extra):
    s = {
        "method": "en4dvar",
        "model": "nhkv",
        "parameters": ["G", "mu"],
        "n_experiments": 3,
        "seed": 0,
        "estimate": {
            "G": {"mean": 7300.0, "sd": 400.0, "hdi95": [6500.0, 8100.0]},
            "mu": {"mean": 0.09, "sd": 0.01, "hdi95": [0.07, 0.11]},
        },
        "fit": {"rmse": 0.01, "n_samples": 100},
        "per_experiment": [
            {"name": "exp_001", "estimate": {"G": {"mean": 7000.0, "sd": 500.0}, "mu": {"mean": 0.08, "sd": 0.02}}}
        ],
    }
    s.update(extra)
    return s


def _report(tmp_path, summary):
    run = tmp_path / "run"
    run.mkdir(exist_ok=True)
    (run / "summary.json").write_text(json.dumps(summary))
    text = write_run_report(run).read_text()
    return html.unescape(re.sub(r"<[^>]+>", " ", text)).replace("\xa0", " ")


@pytest.mark.parametrize(
    "hdi,expect",
    [
        ([6500.0, 8100.0], (True, True)),  # a factor 1.25: a measurement
        ([66.5, 5.66e7], (False, False)),  # 6.65e-2-5.66e+04 kPa
        ([0.025, 2.31e5], (False, False)),  # 2.5e-05-231 kPa
        ([-10.0, 9000.0], (False, False)),  # reaches zero
        ([100.0, 9999.0], (True, True)),
    ],
)  # just under a factor 100
def test_bounds_reads_the_width_of_the_interval(hdi, expect):
    assert bounds({"mean": 1000.0, "hdi95": hdi}) == expect


def test_bounds_prior_box_edge_and_the_fits_own_answer():
    s = {"details": {"settings": {"G_min": 0.0, "G_max": 25e3}}}
    assert bounds({"hdi95": [5e3, 25e3]}, "G", s) == (True, False)
    assert bounds({"hdi95": [5e3, 2e4]}, "G", s) == (True, True)
    assert bounds({"hdi95": [5e3, 2e4], "bounded": {"lower": False, "upper": True}}, "G", s) == (False, True)


def test_terminal_line_carries_units_and_says_unbounded():
    text = estimate_text(
        {
            "G": {"mean": 7300.0, "sd": 400.0, "hdi95": [6500.0, 8100.0]},
            "mu": {"mean": 0.09, "sd": 0.5, "hdi95": [2.5e-5, 0.231]},
        }
    )
    assert text == "G = 7.3 kPa ± 0.4 kPa (95 % 6.5-8.1 kPa), mu not bounded by the data (best fit 0.09 Pa s)"
    zero = estimate_text({"G": {"mean": 30.0, "consistent_with_zero": True, "upper95": 1200.0}})
    assert zero == "G consistent with 0 (95 % upper bound 1.2 kPa)"


def test_report_says_first_when_the_model_does_not_describe_the_records(tmp_path):
    s = _summary(
        fit_check={
            "described": False,
            "residual_to_noise": 30.0,
            "p_value": 1e-6,
            "message": "NHKV does not describe these records.",
        }
    )
    _report(tmp_path, s)
    raw = (tmp_path / "run" / "report.html").read_text()
    body = raw[raw.index("<h2 id='conclusion'>Conclusion</h2>") + len("<h2 id='conclusion'>Conclusion</h2>") :]
    first = html.unescape(re.sub(r"<[^>]+>", " ", body)).strip()
    assert first.startswith(
        "NHKV does not describe these records: the residual is 30x their noise; these numbers "
        "are the best NHKV fit, not the material's properties -- `imrbayes diagnose` looks"
    )
    assert "<b>Gel-level estimate</b>" not in raw  # the estimate is no bold headline


def test_report_renders_prior_share_zero_and_bounds(tmp_path):
    s = _summary(
        prior={"name": "wide", "data_share": {"G": 0.97, "mu": 0.12}},
        fit_check={
            "described": True,
            "residual_to_noise": 1.1,
            "p_value": 0.4,
            "message": "NHKV describes these records: the residual is 1.1x their noise.",
        },
    )
    s["estimate"]["mu"] = {
        "mean": 0.004,
        "sd": 0.003,
        "hdi95": [0.0, 0.01],
        "consistent_with_zero": True,
        "upper95": 0.011,
    }
    s["estimate"]["G"]["hdi95"] = [66.5, 5.66e7]
    text = _report(tmp_path, s)
    assert "Prior: the wide default prior; share of the posterior that comes from the data: G 97 %, mu 12 %" in text
    assert "mu consistent with 0 (95 % upper bound 0.011 Pa s)" in text
    assert "G not bounded by the data (best fit 7.3 kPa)" in text
    assert "NHKV describes these records" in text
    assert "5.66e+04" not in text and "6.65e-02" not in text


def test_report_without_the_new_keys_is_unchanged_in_kind(tmp_path):
    text = _report(tmp_path, _summary())
    assert "G = 7.3 kPa ± 0.4 kPa (95 % 6.5-8.1 kPa)" in text
    assert "Prior:" not in text and "describe these records" not in text


def test_a_warning_repeated_across_windows_is_said_once_with_its_count():
    warns = [f"window {j}: parameter 1 posterior sd {0.1 * j:.2f} above the prior's" for j in range(3, 17)]
    out = grouped_warnings(warns + ["Req estimated from the tail"], ["G", "mu"])
    assert len(out) == 2
    assert out[0].startswith("window 3: mu posterior sd") and "14 in all" in out[0]


def test_report_caveats_have_no_json_paths(tmp_path):
    s = _summary(warnings=["per_experiment[].likelihood.nuisance_integral is 'cycle': counted twice"])
    text = _report(tmp_path, s)
    assert "per_experiment[]" not in text and "nuisance integral is 'cycle'" in text


def test_truth_beside_the_estimate_on_synthetic_data(tmp_path):
    ds = tmp_path / "ds"
    ds.mkdir()
    (ds / "truth.json").write_text(json.dumps({"parameters": {"G": 7290.0, "mu": 0.088}}))
    text = _report(tmp_path, _summary(data=str(ds)))
    assert "(truth 7.29 kPa)" in text and "(truth 0.088 Pa s)" in text
    assert "truth (truth.json)" in text


def test_load_run_of_a_hand_made_run(tmp_path):
    s = _summary(
        time_resolved=[
            {
                "t_star": 0.1,
                "sample": 4,
                "G": {"mean": 7e3, "sd": 5e2, "hdi95": [6e3, 8e3]},
                "mu": {"mean": 0.1, "sd": 0.01, "hdi95": [0.08, 0.12]},
            }
        ]
    )
    _report(tmp_path, s)
    run = imrbayes.load_run(tmp_path / "run")
    assert run.estimates["G"] == {"mean": 7300.0, "sd": 400.0, "hdi95_low": 6500.0, "hdi95_high": 8100.0, "unit": "Pa"}
    assert run.posterior is None
    assert list(run.time_resolved["G_mean [Pa]"]) == [7e3]
    assert run.per_experiment.loc[0, "mu_sd [Pa s]"] == 0.02 and isinstance(run.per_experiment, pd.DataFrame)
