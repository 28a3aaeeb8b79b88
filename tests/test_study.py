"""``imrbayes study``: its file, its contrasts against closed-form truth, and end to end."""

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner
from scipy import stats

import imrbayes
from imrbayes.cli import main
from imrbayes.study.analysis import N_DRAWS, conclusion, condition_draws, differences, trends
from imrbayes.study.results import ConditionResult, log_gaussian

# ``imrbayes study``: bad study files and short forms end in one line and exit status 2.


def _dataset(root: Path, name: str) -> Path:
    d = root / name
    d.mkdir()
    (d / "exp_001.csv").write_text("t_s,R_m\n0,1e-4\n")
    return d


def _run(args):
    res = CliRunner().invoke(main, ["study", *map(str, args)])
    return res.exit_code, res.output.strip()


def _one_line_error(code, text, *needles):
    assert code == 2, text
    assert len(text.splitlines()) == 1 and text.startswith("imrbayes: error:"), text
    for n in needles:
        assert n in text, text


def test_missing_dataset(tmp_path):
    _dataset(tmp_path, "a")
    f = tmp_path / "s.toml"
    f.write_text('[[dataset]]\ndata = "a"\nlabels = {c = 1}\n[[dataset]]\ndata = "nowhere"\nlabels = {c = 2}\n')
    _one_line_error(*_run([f, "--out", tmp_path / "o"]), str(f), "nowhere", "does not exist")


def test_label_on_one_dataset_only(tmp_path):
    _dataset(tmp_path, "a"), _dataset(tmp_path, "b")
    f = tmp_path / "s.toml"
    f.write_text('[[dataset]]\ndata = "a"\nlabels = {c = 1, lab = "UT"}\n[[dataset]]\ndata = "b"\nlabels = {c = 2}\n')
    _one_line_error(*_run([f, "--out", tmp_path / "o"]), "'lab'", "missing on dataset(s) b")


def test_two_datasets_with_one_name(tmp_path):
    _dataset(tmp_path, "a"), _dataset(tmp_path, "b")
    f = tmp_path / "s.toml"
    f.write_text(
        '[[dataset]]\nname = "x"\ndata = "a"\nlabels = {c = 1}\n[[dataset]]\nname = "x"\ndata = "b"\nlabels = {c = 2}\n'
    )
    _one_line_error(*_run([f, "--out", tmp_path / "o"]), "two datasets are named 'x'")


@pytest.mark.parametrize(
    "text, needle",
    [
        ("", "no [[dataset]]"),
        ('[[dataset]]\ndata = "a"\ncolour = 1\n', "unknown key(s) ['colour']"),
        ('methods = ["nope"]\n[[dataset]]\ndata = "a"\n', "unknown method(s) ['nope']"),
        ('seed = -1\n[[dataset]]\ndata = "a"\n', "seed must be a non-negative integer"),
        ("[[dataset]\n", "not valid TOML"),
    ],
)
def test_other_bad_files(tmp_path, text, needle):
    _dataset(tmp_path, "a")
    f = tmp_path / "s.toml"
    f.write_text(text)
    _one_line_error(*_run([f, "--out", tmp_path / "o"]), needle)
    assert not (tmp_path / "o").exists()  # refused before anything is written


def test_short_form_label_count(tmp_path):
    a, b = _dataset(tmp_path, "a"), _dataset(tmp_path, "b")
    _one_line_error(*_run([a, b, "--label", "c=1,2,3", "--out", tmp_path / "o"]), "--label", "3 value(s) for 2")


def test_short_form_same_folder_names(tmp_path):
    (tmp_path / "x").mkdir(), (tmp_path / "y").mkdir()
    a, b = _dataset(tmp_path / "x", "data"), _dataset(tmp_path / "y", "data")
    _one_line_error(*_run([a, b, "--label", "c=1,2", "--out", tmp_path / "o"]), "two datasets are named 'data'")


def test_out_holding_other_files(tmp_path):
    a, b = _dataset(tmp_path, "a"), _dataset(tmp_path, "b")
    (tmp_path / "o").mkdir()
    (tmp_path / "o" / "notes.txt").write_text("mine")
    _one_line_error(*_run([a, b, "--label", "c=1,2", "--out", tmp_path / "o"]), "holds files but no study")


# The study's differences and trends against closed-form truth on synthetic Gaussian posteriors
# (no forward runs): with independent log-normal posteriors, a ratio's log is Gaussian with the
# difference of the means and the sum of the variances, and a least-squares slope is Gaussian with
# weights (x - mean x) / Sxx.


Z = stats.norm.ppf(0.975)


def _cond(name, x, log_g, sd_g, log_mu, sd_mu, described=None):
    return ConditionResult(
        name,
        {"concentration": f"{x} %"},
        method="en4dvar",
        params=("G", "mu"),
        log_mean=np.array([log_g, log_mu]),
        log_cov=np.diag([sd_g**2, sd_mu**2]),
        described=described,
    )


def test_ratio_matches_closed_form():
    a, b = (
        _cond("a", 5, math.log(9000), 0.10, math.log(0.05), 0.20),
        _cond("b", 0.5, math.log(3000), 0.15, math.log(0.06), 0.25),
    )
    d = differences([b, a], condition_draws([b, a], seed=3))
    assert len(d) == 1 and (d[0]["a"], d[0]["b"]) == ("a", "b")
    s = math.hypot(0.10, 0.15)
    g = d[0]["G"]
    assert g["ratio"] == pytest.approx(3.0, rel=0.01)
    assert g["interval"] == pytest.approx([3 * math.exp(-Z * s), 3 * math.exp(Z * s)], rel=0.02)
    assert g["p_greater"] == pytest.approx(stats.norm.cdf(math.log(3) / s), abs=1e-3)
    s_mu = math.hypot(0.20, 0.25)
    p_true = stats.norm.cdf(math.log(0.05 / 0.06) / s_mu)
    se = math.sqrt(p_true * (1 - p_true) / N_DRAWS)  # Monte Carlo error of a probability
    assert d[0]["mu"]["p_greater"] == pytest.approx(p_true, abs=4 * se)


def test_trend_matches_closed_form():
    x = np.array([0.5, 1.0, 2.0, 5.0])
    sd = np.array([0.1, 0.2, 0.1, 0.3])
    slope = 0.3
    conds = [_cond(f"c{i}", xi, 8.0 + slope * xi, s, -3.0, s) for i, (xi, s) in enumerate(zip(x, sd))]
    t = trends(conds, condition_draws(conds, seed=0), {"concentration": "%"})
    assert len(t) == 1 and t[0]["unit"] == "%"
    w = (x - x.mean()) / np.sum((x - x.mean()) ** 2)
    s_slope = math.sqrt(np.sum(w**2 * sd**2))
    g, mu = t[0]["G"], t[0]["mu"]
    assert g["slope"] == pytest.approx(slope, abs=5 * s_slope / math.sqrt(N_DRAWS))  # Monte Carlo error
    assert g["interval"] == pytest.approx([slope - Z * s_slope, slope + Z * s_slope], abs=0.03 * s_slope)
    assert g["p_positive"] == pytest.approx(stats.norm.cdf(slope / s_slope), abs=1e-3)
    assert g["factor_over_range"] == pytest.approx(math.exp(slope * 4.5), rel=0.02)
    assert mu["interval"][0] < 0 < mu["interval"][1]
    lines = conclusion(conds, differences(conds, condition_draws(conds, seed=0)), t)
    assert lines[0].startswith("G rises with concentration: 5 % / 0.5 % = ")
    assert "mu does not differ detectably along concentration" in lines[0]


def test_conclusion_puts_the_fit_check_first():
    conds = [_cond("a", 1, 8.0, 0.1, -3, 0.1, described=False), _cond("b", 2, 8.0, 0.1, -3, 0.1, described=True)]
    lines = conclusion(
        conds,
        differences(conds, condition_draws(conds, 0)),
        trends(conds, condition_draws(conds, 0), {"concentration": "%"}),
    )
    assert lines[0].startswith("The model does not describe the records of a:")
    assert "G does not differ detectably" in lines[1]


def test_log_gaussian_from_interval_when_no_random_effects():
    med, lo, hi = 5000.0, 4000.0, 6250.0  # a log-symmetric 95 % interval: sd = ln(1.25) / 1.96
    names, m, c = log_gaussian({"parameters": ["G"], "estimate": {"G": {"median": med, "hdi95": [lo, hi]}}})
    assert names == ["G"] and m[0] == pytest.approx(math.log(med))
    assert math.sqrt(c[0, 0]) == pytest.approx(math.log(1.25) / Z)
    assert log_gaussian({"parameters": ["G"], "estimate": {"G": {"median": 0.0, "hdi95": [0.0, 10.0]}}}) is None


# ``imrbayes study`` end to end on a tiny synthetic study: two gels made with ``imrbayes
# simulate`` (polytropic, 2 bubbles, short records, G three times apart, the same mu), En4D-Var only.


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
