"""``imrbayes study`` end to end on a tiny synthetic study: two gels made with ``imrbayes
simulate`` (polytropic, 2 bubbles, short records, G three times apart, the same mu), En4D-Var only."""

import json

import pandas as pd
import pytest
from click.testing import CliRunner

import imrbayes
from imrbayes.cli import main

TRUE_G = {"soft": 3000.0, "stiff": 9000.0}
TRUE_MU = 0.05


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    root = tmp_path_factory.mktemp("study")
    run = CliRunner().invoke
    for name, g in TRUE_G.items():
        res = run(
            main,
            [
                "simulate",
                "--model",
                "nhkv",
                "--param",
                f"G={g}",
                "--param",
                f"mu={TRUE_MU}",
                "--n-exp",
                "2",
                "--forward",
                "bubble=polytropic",
                "--t-end",
                "1.5",
                "--noise",
                "0.01",
                "--seed",
                "1",
                "--out",
                str(root / name),
                "--quiet",
            ],
        )
        assert res.exit_code == 0, res.output
    args = [
        "study",
        str(root / "soft"),
        str(root / "stiff"),
        "--label",
        "concentration=1%,3%",
        "--label",
        "material=agarose",
        "--method",
        "en4dvar",
        "--forward",
        "bubble=polytropic",
        "--n-steps",
        "60",
        "--out",
        str(root / "out"),
    ]
    res = run(main, args)
    assert res.exit_code == 0, res.output
    return root, args, res.output


def test_files_and_table(study):
    root, _, output = study
    out = root / "out"
    for f in (
        "study.csv",
        "study.json",
        "study.nc",
        "study.html",
        "figures/parameters_concentration.png",
        "runs/soft/en4dvar/summary.json",
        "runs/stiff/en4dvar/posterior.nc",
    ):
        assert (out / f).is_file(), f
    table = imrbayes.load_study(out)
    assert list(table.index) == ["soft", "stiff"] and list(table["n_bubbles"]) == [2, 2]
    summaries = {n: json.loads((out / "runs" / n / "en4dvar" / "summary.json").read_text()) for n in TRUE_G}
    for name, s in summaries.items():  # the table carries each run's own gel-level estimate
        assert table.loc[name, "G_mean"] == pytest.approx(s["estimate"]["G"]["mean"])
        assert [table.loc[name, "mu_lo"], table.loc[name, "mu_hi"]] == pytest.approx(s["estimate"]["mu"]["hdi95"])
        assert table.loc[name, "G_lo"] < TRUE_G[name] < table.loc[name, "G_hi"]
    assert pd.isna(table.loc["soft", "diagnose_verdict"])
    html = (out / "study.html").read_text()
    assert html.index("G rises with concentration") < html.index("<h2>Conditions</h2>")
    assert "\nG rises with concentration: 3 % / 1 % = " in output


def test_differences_hold_the_true_ratio(study):
    root, _, _ = study
    s = json.loads((root / "out" / "study.json").read_text())
    (d,) = s["differences"]
    assert (d["a"], d["b"]) == ("stiff", "soft")
    assert d["G"]["interval"][0] < 3.0 < d["G"]["interval"][1] and d["G"]["p_greater"] > 0.975
    assert d["mu"]["interval"][0] < 1.0 < d["mu"]["interval"][1]
    assert s["labels"] == {"concentration": "%", "material": None}


def test_rerun_reuses_and_a_changed_option_is_refused(study):
    root, args, _ = study
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 0 and "soft/en4dvar: reused" in res.output
    changed = [*args, "--seed", "2"]
    res = CliRunner().invoke(main, changed)
    assert res.exit_code == 0, res.output  # a failed dataset is reported; the study still writes its files
    assert "soft/en4dvar: failed" in res.output and "another configuration" in res.output
    assert "Runs failed for soft (en4dvar); stiff (en4dvar)" in res.output
