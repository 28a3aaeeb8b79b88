"""`imrbayes diagnose` end to end on a small synthetic dataset (polytropic, few replicates)."""

import json

from click.testing import CliRunner

from imrbayes.cli import main


def test_diagnose_cli_writes_contract(tmp_path):
    data = tmp_path / "gel"
    r = CliRunner().invoke(
        main,
        [
            "simulate",
            "--model",
            "nhkv",
            "--param",
            "G=6e3",
            "--param",
            "mu=0.08",
            "--rmax",
            "300e-6:20e-6",
            "--ratio",
            "7.5:0.3",
            "--n-exp",
            "3",
            "--noise",
            "paper",
            "--seed",
            "1",
            "--forward",
            "bubble=polytropic",
            "--out",
            str(data),
        ],
    )
    assert r.exit_code == 0, r.output
    out = tmp_path / "run"
    r = CliRunner().invoke(
        main,
        [
            "diagnose",
            str(data),
            "--out",
            str(out),
            "--quick",
            "--n-bootstrap",
            "2",
            "--candidates",
            "qkv",
            "--no-loeo",
            "--forward",
            "bubble=polytropic",
        ],
    )
    assert r.exit_code == 0, r.output
    d = json.loads((out / "diagnosis.json").read_text())
    for key in ("baseline", "constant_parameter_check", "candidates", "cause", "extended_model", "gain", "warnings"):
        assert key in d
    assert d["baseline"]["model"] == "nhkv" and d["baseline"]["misfit_by_phase"]
    assert d["constant_parameter_check"]["verdict"] == "adequate"  # 2 replicates cannot reject ...
    assert "--n-bootstrap 2: fewer than 19 replicates cannot reject" in r.output  # ... said up front
    assert any("cannot find the constant-parameter model inadequate" in w for w in d["warnings"])
    assert d["candidates"][0]["mechanism"] == "strain-stiffening"
    assert [s["stage"].split(" ")[0] for s in d["stage_seconds"]][:3] == [
        "baseline",
        "constant-parameter",
        "candidates",
    ]
    for k in ("heldout_rmse", "elpd_diff", "elpd_se", "estimate"):
        assert k in d["candidates"][0]
    html = (out / "report.html").read_text()
    assert "data:image/png;base64," in html
    assert (out / "figures" / "residuals.png").exists()


def test_diagnose_bad_input(tmp_path):
    r = CliRunner().invoke(main, ["diagnose", str(tmp_path / "missing"), "--out", str(tmp_path / "o")])
    assert r.exit_code == 2
    assert "error" in r.output


def test_diagnose_cli_names_a_bubble_model_sensitivity(tmp_path, monkeypatch):
    """When the result flags a bubble-model alternative, the terminal says so in one line (the run
    itself is real; only its sensitivity entry is replaced by a flagged one)."""
    import imrbayes.diagnosis as diag

    real = diag.diagnose

    def flagged(*args, **kwargs):
        d = real(*args, **kwargs)
        d.result["bubble_model_sensitivity"] = {
            "material_depends_on_bubble_model": True,
            "alternatives": [
                {
                    "key": "bubble-thermal",
                    "bubble_options": {"mass_transfer": False},
                    "indistinguishable": True,
                    "material_moves": ["G"],
                    "shift": {"G": -0.23, "mu": 0.31},
                    "shift_sd": {"G": -3.1, "mu": 4.5},
                    "separation_se": 0.16,
                    "mechanism": "bubble-thermal",
                    "estimate": {"G": 4180.0, "mu": 0.070},
                    "baseline": {"G": 5420.0, "mu": 0.0536},
                }
            ],
        }
        return d

    monkeypatch.setattr(diag, "diagnose", flagged)
    data = tmp_path / "gel"
    r = CliRunner().invoke(
        main,
        [
            "simulate",
            "--model",
            "nhkv",
            "--param",
            "G=6e3",
            "--param",
            "mu=0.08",
            "--rmax",
            "300e-6:20e-6",
            "--ratio",
            "7.5:0.3",
            "--n-exp",
            "2",
            "--noise",
            "paper",
            "--seed",
            "1",
            "--forward",
            "bubble=polytropic",
            "--out",
            str(data),
        ],
    )
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(
        main,
        [
            "diagnose",
            str(data),
            "--out",
            str(tmp_path / "run"),
            "--quick",
            "--n-bootstrap",
            "2",
            "--candidates",
            "qkv",
            "--no-loeo",
            "--forward",
            "bubble=polytropic",
        ],
    )
    assert r.exit_code == 0, r.output
    assert (
        "bubble-model sensitivity: with mass_transfer=False (not separated by the held-out data, 0.2 SE) "
        "the material estimate moves: G -23%"
    ) in r.output
    assert "depends on the bubble model" in (tmp_path / "run" / "report.html").read_text()
