"""``imrbayes report RUN_DIR``: one self-contained report.html for runs of every kind (pIMR, MIEnKS-MDA
without and with ``--mcmc``), the flagged-window list, and one-line errors for bad run directories.

Small and fast: a 2-experiment polytropic dataset to t* = 1, tiny ensembles and a 60-step emcee run
on two windows (undecided by construction: too short to converge).
"""

import json
import re
import shutil

import arviz as az
import numpy as np
import pandas as pd
import pytest
import xarray as xr
from click.testing import CliRunner

from imrbayes.cli import main
from imrbayes.mcmc.compare import THRESHOLDS

TINY_MIENKS = [
    "--method",
    "mienks",
    "--forward",
    "bubble=polytropic",
    "--set",
    "n_ens=8",
    "--set",
    "n_iter=2",
    "--set",
    "L=10",
    "--set",
    "h=5",
    "--n-steps",
    "40",
    "--quiet",
]


def _run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("report")
    ds = base / "ds"
    r = _run(
        "simulate",
        "--model",
        "nhkv",
        "--param",
        "G=7.29e3",
        "--param",
        "mu=0.088",
        "--n-exp",
        "2",
        "--forward",
        "bubble=polytropic",
        "--t-end",
        "1.0",
        "--seed",
        "0",
        "--out",
        ds,
        "--quiet",
    )
    assert r.exit_code == 0, r.output
    out = {"ds": ds}
    r = _run("fit", ds, "--method", "pimr", "--out", base / "pimr", "--quiet")
    assert r.exit_code == 0, r.output
    out["pimr"] = base / "pimr"
    r = _run("fit", ds, *TINY_MIENKS, "--out", base / "mienks")
    assert r.exit_code == 0, r.output
    out["mienks"] = base / "mienks"
    # a tiny run to report on, started at the prior mean with exactly two iterations (screen=0,
    # max_iter=2): with 8 members the converged, screened fit leaves the two bubbles' mu apart and the
    # two-bubble gel level outside both, which the flag test below must not see
    r = _run(
        "fit",
        ds,
        "--method",
        "en4dvar",
        "--forward",
        "bubble=polytropic",
        "--set",
        "n_ens=8",
        "--set",
        "n_iter=2",
        "--set",
        "max_iter=2",
        "--set",
        "screen=0",
        "--set",
        "n_runs=1",
        "--n-steps",
        "40",
        "--out",
        base / "en4dvar",
        "--quiet",
    )
    assert r.exit_code == 0, r.output
    out["en4dvar"] = base / "en4dvar"
    r = _run(
        "fit",
        ds,
        *TINY_MIENKS,
        "--out",
        base / "mcmc",
        "--mcmc",
        "--mcmc-set",
        "n_walkers=8",
        "--mcmc-set",
        "n_steps=60",
        "--mcmc-set",
        "n_chains=2",
        "--mcmc-windows",
        "0,6",
    )
    assert r.exit_code == 0, r.output
    out["mcmc"] = base / "mcmc"
    return out


def _report(run_dir, *extra):
    r = _run("report", run_dir, *extra)
    assert r.exit_code == 0, r.output
    return r


def _section(html, anchor):
    """The HTML from <h2 id='anchor'> to the next <h2."""
    i = html.index(f"<h2 id='{anchor}'>")
    j = html.find("<h2", i + 4)
    return html[i : j if j > 0 else None]


def _text(fragment):
    import html as _h

    return _h.unescape(re.sub(r"<[^>]+>", "", fragment)).replace("\xa0", " ")


def _self_contained(html):
    low = html.lower()
    for bad in ('src="http', "src='http", 'href="http', "href='http", "<script", "<link", "@import", "url("):
        assert bad not in low, bad


def test_report_mienks_with_mcmc(runs):
    run = runs["mcmc"]
    r = _report(run)
    path = run / "report.html"
    assert r.output.strip() == f"wrote {path}"
    html = path.read_text()
    _self_contained(html)
    summary = json.loads((run / "summary.json").read_text())
    compare = json.loads((run / "compare.json").read_text())

    # dataset: Rmax 263 µm, Rmax/Req 7.58, the first-collapse time of each experiment
    ds = _text(_section(html, "dataset"))
    assert "Rmax [µm]" in ds and "Req [µm]" in ds and "Rmax/Req" in ds and "first collapse t*" in ds
    for e in summary["preprocessing"]["experiments"]:
        assert e["name"] in ds
        assert f"title='{float(e['t_collapse_star'])!r}'" in html
    assert "263" in ds and "7.58" in ds
    cfg = _text(_section(html, "config"))
    for needed in ("mienks", "nhkv", "polytropic", "n_ens = 8", "imrbayes version", "0.1.0", "Prior"):
        assert needed in cfg, needed

    # estimate (SI units, raw value in the tooltip) and the per-window table
    est = _section(html, "estimate")
    assert "Pa s" in est
    for p in ("G", "mu"):
        for k in ("mean", "sd"):
            assert f"title='{summary['estimate'][p][k]!r}'" in est
    win = _section(html, "windows")
    assert len(summary["windows"]) == 7
    for w in summary["windows"]:
        assert f"title='{w['mu']['mean']!r}'" in win

    # ArviZ summaries (round_to="none": raw numbers) of posterior.nc (diagnostics only: the estimate is the
    # Estimate/Windows tables') and of each MCMC window
    for col in ("mean", "sd", "hdi95_lb", "hdi95_ub", "ess_bulk", "ess_tail", "r_hat", "mcse_mean", "mcse_sd"):
        assert f"<th>{col}</th>" in _section(html, "mcmc"), col
    assert "<th>r_hat</th>" in _section(html, "posterior") and "G[6]" in _section(html, "posterior")
    for col in ("mean", "sd", "hdi95_lb", "hdi95_ub"):
        assert f"<th>{col}</th>" not in _section(html, "posterior"), col
    with xr.open_datatree(run / "mcmc.nc") as tree:
        s6 = az.summary(tree["window_06"], round_to="none", ci_kind="hdi", ci_prob=0.95)
    mc = _section(html, "mcmc")
    assert "Window 0" in mc and "Window 6" in mc
    assert f"title='{float(s6.loc['mu', 'r_hat'])!r}'" in mc
    assert f"title='{float(s6.loc['log_G', 'ess_bulk'])!r}'" in mc

    # compare table: both windows with KL both ways, W2 and the verdict
    cmp_ = _section(html, "compare")
    for e in compare["windows"]:
        assert f"title='{e['kl_gauss']!r}'" in cmp_ and f"title='{e['kl_gauss_reverse']!r}'" in cmp_
        assert f"title='{e['w2']!r}'" in cmp_
    assert [e["agree"] for e in compare["windows"]] == [None, None]  # 60 steps: never converged
    flagged = _text(_section(html, "flagged"))
    for e in compare["windows"]:
        t0, t1 = e["t_star"]
        assert f"Window {e['index']} (t* {t0:.3g}–{t1:.3g}" in flagged
    assert flagged.count("undecided") == 2 and flagged.count("--mcmc-set n_steps=") == 2
    # each undecided window names exactly the convergence criteria its compare entry fails (which of
    # them a 60-step run fails depends on the draws: R-hat passed with one ArviZ release, not another)
    for e, para in zip(compare["windows"], re.split(r"(?=Window \d+ \(t\*)", flagged)[1:]):
        m = e["mcmc"]
        rhat, ess = max(m["rhat"].values()), min(m["ess_bulk"].values())
        failing = {
            "max R-hat": rhat > THRESHOLDS["rhat"],
            "min bulk ESS": ess < THRESHOLDS["ess_bulk"],
            "autocorrelation times long": m["sampler"]["all_tau_ok"] is False,
        }
        assert any(failing.values())
        for words, fails in failing.items():
            assert (words in para) == fails, (words, fails, para)
    assert "around the first collapse" in flagged  # window 6 ends at t* 0.975
    assert "Not sampled by MCMC (no comparison): windows 1, 2, 3, 4, 5" in flagged

    # every figure embedded, with a caption naming its file
    pngs = sorted(p.name for p in (run / "figures").glob("*.png"))
    assert {"fit.png", "parameters.png", "mcmc_forest.png", "mcmc_divergence.png"} <= set(pngs)
    assert html.count("data:image/png;base64,") == len(pngs)
    for name in pngs:
        assert f"figures/{name}</code>" in html


def test_report_lists_a_disagreeing_window_in_words(runs, tmp_path):
    """A window whose (converged) MCMC posterior is a skewed banana, against a Gaussian shifted by
    one sd: compare_window says agree = False; the report says why, in words, with its t* span."""
    from imrbayes.mcmc.compare import compare_window
    from imrbayes.mcmc.windows import write_compare

    run = tmp_path / "run"
    shutil.copytree(runs["mcmc"], run)
    old = json.loads((run / "compare.json").read_text())
    w6 = next(w for w in old["windows"] if w["index"] == 6)
    rng = np.random.default_rng(0)
    x1 = rng.standard_normal((2, 1000))
    x2 = 0.6 * (x1**2 - 1.0) + 0.5 * rng.standard_normal((2, 1000))
    draws = np.stack([8.9 + 0.3 * x1, -2.0 + 0.3 * x2], axis=-1)  # (chain, draw, [log_G, log_mu])
    flat = draws.reshape(-1, 2)
    m, C = flat.mean(axis=0), np.cov(flat, rowvar=False)
    bad = compare_window(
        m + np.array([np.sqrt(C[0, 0]), 0.0]),
        C,
        draws,
        ["G", "mu"],
        [True, True],
        index=6,
        t_star=w6["t_star"],
        n_max=400,
        n_null=20,
    )
    assert bad["agree"] is False and bad["mcmc"]["converged"]
    write_compare(run / "compare.json", [old["windows"][0], bad])
    _report(run, "--quiet")
    flagged = _section((run / "report.html").read_text(), "flagged")
    items = [_text(li) for li in re.findall(r"<li>(.*?)</li>", flagged)]
    t0, t1 = w6["t_star"]
    line = next(i for i in items if i.startswith("Window 6 "))
    assert line.startswith(f"Window 6 (t* {t0:.3g}–{t1:.3g}, around the first collapse")
    assert "disagrees" in line and "skewed" in line and "symmetric KL" in line and "> 0.1" in line
    assert "the ensemble mean of G lies 1 MCMC posterior sd above" in line
    assert line.endswith("the Gaussian ensemble approximation is not adequate here.")
    assert any(i.startswith("Window 0 ") and "undecided" in i for i in items)
    table = _text(_section((run / "report.html").read_text(), "compare"))
    assert "1 disagree, 1 undecided" in table
    concl = _text(_section((run / "report.html").read_text(), "conclusion"))  # the numbers to believe instead
    g = bad["mcmc"]["mean"]["G"]
    assert (
        f"disagrees in window 6: believe the MCMC posterior there, not the Gaussian (emcee: window 6: G = "
        f"{g * 1e-3:.3g} kPa ±" in concl
    )


def test_report_without_mcmc_says_so(runs, tmp_path):
    # pIMR: no windows, no uncertainty from the closed form; --out elsewhere
    out = tmp_path / "sub" / "pimr.html"
    r = _report(runs["pimr"], "--out", out)
    assert r.output.strip() == f"wrote {out}"
    assert not (runs["pimr"] / "report.html").exists()
    html = out.read_text()
    _self_contained(html)
    summary = json.loads((runs["pimr"] / "summary.json").read_text())
    assert f"title='{summary['estimate']['G']['mean']!r}'" in html
    assert "<h2 id='windows'>" not in html
    assert html.count("data:image/png;base64,") == len(list((runs["pimr"] / "figures").glob("*.png"))) == 2
    text = _text(html)
    assert "MCMC check: not applicable" in text
    # MIEnKS-MDA without --mcmc: the windows are there, the comparison is not (and says how to add it)
    _report(runs["mienks"], "--quiet")
    html = (runs["mienks"] / "report.html").read_text()
    assert "<h2 id='windows'>Windows (7)</h2>" in html
    assert "MCMC check: not run" in _text(_section(html, "compare"))
    assert "imrbayes fit DATA --method mienks --mcmc" in _text(_section(html, "compare"))
    assert "<h2 id='mcmc'>" not in html and "<h2 id='flagged'>" not in html


def test_report_quiet_prints_nothing(runs, tmp_path):
    r = _run("report", runs["pimr"], "--out", tmp_path / "r.html", "--quiet")
    assert r.exit_code == 0 and r.output == ""
    assert (tmp_path / "r.html").read_text().startswith("<!doctype html>")


def _corrupt(kind, src, tmp_path):
    """A run directory (or path) broken in one way; returns (path to pass, file the error names)."""
    if kind == "missing":
        return tmp_path / "nope", "nope"
    if kind == "file":
        p = tmp_path / "afile"
        p.write_text("x")
        return p, "afile"
    run = tmp_path / "run"
    if kind == "empty":
        run.mkdir()
        return run, "summary.json"
    shutil.copytree(src, run)
    (run / "report.html").unlink(missing_ok=True)  # from another test
    if kind == "summary-garbage":
        (run / "summary.json").write_text("{not json")
        return run, "summary.json"
    if kind == "summary-list":
        (run / "summary.json").write_text("[1, 2]")
        return run, "summary.json"
    if kind == "summary-keys":
        (run / "summary.json").write_text('{"method": "mienks"}')
        return run, "summary.json"
    if kind == "posterior":
        (run / "posterior.nc").write_bytes(b"\x89HDF\r\n\x1a\ngarbage" * 10)
        return run, "posterior.nc"
    if kind == "mcmc":
        (run / "mcmc.nc").write_bytes(b"not a netcdf file at all")
        return run, "mcmc.nc"
    if kind == "compare-garbage":
        (run / "compare.json").write_text('{"windows": [')
        return run, "compare.json"
    if kind == "compare-layout":
        (run / "compare.json").write_text('{"windows": [{"kl_sym": 1}]}')
        return run, "compare.json"
    raise AssertionError(kind)


@pytest.mark.parametrize(
    "kind",
    [
        "missing",
        "file",
        "empty",
        "summary-garbage",
        "summary-list",
        "summary-keys",
        "posterior",
        "mcmc",
        "compare-garbage",
        "compare-layout",
    ],
)
def test_report_bad_run_dir(runs, tmp_path, kind):
    path, name = _corrupt(kind, runs["mcmc"], tmp_path)
    r = CliRunner().invoke(main, ["report", str(path)])
    assert r.exit_code == 2, r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("imrbayes: error: ") and name in lines[0], r.stderr
    assert "Traceback" not in r.output
    assert not (tmp_path / "run" / "report.html").exists()


# ------------------------------------------------------------------ what a rheologist sees
def _first_h2(html):
    return re.search(r"<h2 id='([^']+)'>", html).group(1)


def _copy(runs, kind, tmp_path):
    run = tmp_path / kind
    shutil.copytree(runs[kind], run)
    (run / "report.html").unlink(missing_ok=True)
    return run


def _edit_summary(run, fn):
    p = run / "summary.json"
    s = json.loads(p.read_text())
    fn(s)
    p.write_text(json.dumps(s))
    return s


def test_report_opens_with_a_conclusion_in_physical_units(runs):
    run = runs["mcmc"]
    html = _report(run, "--quiet") and (run / "report.html").read_text()
    assert _first_h2(html) == "conclusion"
    concl = _text(_section(html, "conclusion"))
    s = json.loads((run / "summary.json").read_text())
    g = s["estimate"]["G"]
    assert f"G = {g['mean'] * 1e-3:.4g} kPa ± {g['sd'] * 1e-3:.2g} kPa" in concl
    assert f"(95 % {g['hdi95'][0] * 1e-3:.3g}-{g['hdi95'][1] * 1e-3:.3g} kPa)" in concl
    assert " Pa s" in concl
    assert "MCMC check: undecided in windows 0, 6" in concl  # 60 emcee steps never converge
    assert "Caveats:" in concl
    # configuration and raw settings at the bottom
    order = re.findall(r"<h2 id='([^']+)'>", html)
    assert order.index("config") > order.index("figures") and order.index("posterior") > order.index("config")


def test_report_conclusion_shows_between_predictive_and_nuisance(runs, tmp_path):
    run = _copy(runs, "en4dvar", tmp_path)

    def add(s):
        s["between_experiments"] = {
            "G": {"sd": 1500.0, "hdi95": [400.0, 3100.0]},
            "mu": {"sd": 0.02, "hdi95": [0.004, 0.05]},
        }
        s["predictive"] = {
            "G": {"mean": 7300.0, "sd": 1600.0, "hdi95": [4200.0, 10900.0]},
            "mu": {"mean": 0.09, "sd": 0.03, "hdi95": [0.04, 0.16]},
        }
        for i, e in enumerate(s["per_experiment"]):
            e["nuisance"] = {
                "rmax_m": {"mean": 263e-6 + i * 1e-6, "sd": 0.8e-6},
                "req_m": {"mean": 34.7e-6, "sd": 0.3e-6},
                "t0_s": {"mean": 0.12e-6, "sd": 0.05e-6},
            }
        s["likelihood"] = {"name": "default", "noise": "x", "effective_samples": [31.5, 28.0]}

    _edit_summary(run, add)
    html = _report(run, "--quiet") and (run / "report.html").read_text()
    concl = _text(_section(html, "conclusion"))
    assert "Between bubbles (scatter of the gel from bubble to bubble): G sd 1.5 kPa (95 % 0.4–3.1 kPa)" in concl
    assert "A new bubble of this gel (95 % predictive range): G 4.2–10.9 kPa; mu 0.04–0.16 Pa s" in concl
    assert "nuisance" in concl
    exps = _text(_section(html, "experiments"))
    assert "Rmax mean [µm]" in exps and "264" in exps and "t0 mean [µs]" in exps and "0.12" in exps
    assert "effective samples" in exps and "31.5" in exps


def test_report_conclusion_one_bubble_and_absent_keys(runs, tmp_path):
    run = _copy(runs, "en4dvar", tmp_path)
    # a summary without the between-bubble layer (the paper likelihood, or an older run)
    _edit_summary(run, lambda s: [s.pop(k, None) for k in ("between_experiments", "predictive")])
    html = _report(run, "--quiet") and (run / "report.html").read_text()
    concl = _text(_section(html, "conclusion"))
    assert "Between bubbles: not estimated by this run; the per-experiment estimates span G " in concl
    assert "A new bubble" not in concl and "<h2 id='experiments'>" in html
    _edit_summary(run, lambda s: s.update(n_experiments=1, per_experiment=s["per_experiment"][:1]))
    html = _report(run, "--quiet") and (run / "report.html").read_text()
    assert "One experiment: bubble-to-bubble scatter unknown" in _text(_section(html, "conclusion"))


def test_report_says_when_the_data_say_little(runs, tmp_path):
    run = _copy(runs, "en4dvar", tmp_path)

    def wide(s):  # mu's posterior as wide as its prior (the paper's log-normal 0.209 +- 0.088 Pa s)
        from imrbayes.ensemble import ParamSpace
        from imrbayes.forward.constitutive import get_model

        s["prior"].update(ParamSpace.for_model(get_model("nhkv"), base="paper").describe())
        s["fit_check"]["described"] = True  # the tiny fit misses its records; here only the constraint is read
        s["estimate"]["mu"].update(mean=0.21, sd=0.085, hdi95=[0.09, 0.41])
        s["estimate"]["G"].update(mean=7.0e3, sd=3.0e2, hdi95=[6.4e3, 7.6e3])  # and G well inside its prior

    _edit_summary(run, wide)
    html = _report(run, "--quiet") and (run / "report.html").read_text()
    concl = _text(_section(html, "conclusion"))
    assert "mu: posterior as wide as the prior — the data say little" in concl
    assert "G: constrained by the data" in concl
    # MIEnKS windows the data barely moved are marked in the windows table
    html = _report(runs["mienks"], "--quiet") and (runs["mienks"] / "report.html").read_text()
    assert "(barely moved)" in _section(html, "windows")


def test_report_one_source_of_numbers(runs):
    """The estimate's mean, sd and interval appear once (summary.json); the ArviZ table of posterior.nc
    shows only the draws' diagnostics, so the report never gives two results for one posterior."""
    run = runs["en4dvar"]
    html = _report(run, "--quiet") and (run / "report.html").read_text()
    post = _section(html, "posterior")
    assert "<th>ess_bulk</th>" in post and "<th>sd</th>" not in post and "<th>hdi95_lb</th>" not in post
    s = json.loads((run / "summary.json").read_text())
    assert f"title='{s['estimate']['G']['sd']!r}'" in _section(html, "estimate")


def test_report_has_no_raw_json_escapes_or_empty_headers(runs, tmp_path):
    run = _copy(runs, "mienks", tmp_path)

    def odd(s):
        s["preprocessing"]["choices"]["noise_model"] = {
            "method": "paper",
            "ref": "methods.md §5",
            "levels": [1, 2],
            "nested": {"a": None},
        }
        s["details"]["uncertainty"] = {"why": "closed form §4"}

    _edit_summary(run, odd)
    html = _report(run, "--quiet") and (run / "report.html").read_text(encoding="utf-8")
    text = _text(html)
    assert "\\u00" not in html and "\\u00" not in text
    assert '{"' not in text and "{'" not in _text(_section(html, "dataset")).replace(
        json.loads((run / "summary.json").read_text())["preprocessing"]["dataset"]["meta"].get("description", ""), ""
    )
    assert "methods.md §5" in text and "paper" in _text(_section(html, "dataset"))
    assert "<tr><th></th><th></th></tr>" not in html and "<th></th>" not in html


def test_report_pimr_shows_no_sections_that_do_not_apply(runs):
    html = _report(runs["pimr"], "--quiet") and (runs["pimr"] / "report.html").read_text()
    text = _text(html[html.index("<body>") :])
    assert "Absent" not in text and "absent" not in text
    for anchor in ("flagged", "mcmc", "compare", "windows"):
        assert f"<h2 id='{anchor}'>" not in html, anchor
    assert "MCMC check: not applicable" in _text(_section(html, "conclusion"))
    assert "collapse time only" in _text(_section(html, "figures"))
    assert "mcmc.nc" not in _text(_section(html, "contents"))


def test_report_en4dvar_without_mcmc_suggests_its_own_method(runs):
    html = _report(runs["en4dvar"], "--quiet") and (runs["en4dvar"] / "report.html").read_text()
    text = _text(html)
    assert "--method mienks" not in text
    assert "imrbayes fit DATA --method en4dvar --mcmc" in _text(_section(html, "conclusion"))
    assert "evaluations" in _text(_section(html, "conclusion"))
    assert "minutes per window with this fit's polytropic bubble" in _text(_section(html, "conclusion"))


def _browser_check():
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "scripts" / "check_report_browser.py"
    spec = importlib.util.spec_from_file_location("check_report_browser", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("kind", ["pimr", "mcmc"])
def test_report_renders_in_a_headless_browser(runs, tmp_path, kind):
    """scripts/check_report_browser.py: Chromium renders report.html; every image loads, the visible
    text has no raw JSON and no escapes, and the page opens with the conclusion."""
    chk = _browser_check()
    if chk.find_browser() is None:
        pytest.skip("no Chromium/Chrome installed (apt-get install chromium)")
    run = _copy(runs, kind, tmp_path)
    _report(run, "--quiet")
    png = tmp_path / "page.png" if kind == "mcmc" else None
    res = chk.check(run / "report.html", png=png)
    assert res["ok"], res["problems"]
    assert res["n_images"] == len(list((run / "figures").glob("*.png"))) > 0
    if png is not None:
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_report_flags_a_gel_level_estimate_outside_the_experiments(runs, tmp_path):
    run = _copy(runs, "en4dvar", tmp_path)

    def far(s):
        s["estimate"]["G"].update(mean=26000.0, sd=1400.0, hdi95=[23200.0, 28800.0], median=25900.0)

    s = _edit_summary(run, far)
    html = _report(run, "--quiet") and (run / "report.html").read_text()
    concl = _text(_section(html, "conclusion"))
    assert "The gel-level G (26 kPa) lies outside every experiment's own 95 % interval" in concl
    assert "the gel-level mu" not in concl
    # just below the lowest experiment's mean, but inside its interval: no caveat
    low = min(e["estimate"]["G"]["mean"] - e["estimate"]["G"]["sd"] for e in s["per_experiment"])
    _edit_summary(run, lambda s: s["estimate"]["G"].update(mean=low))
    html = _report(run, "--quiet") and (run / "report.html").read_text()
    assert "outside every experiment" not in _text(_section(html, "conclusion"))


def test_report_warns_that_an_inferred_req_can_make_mu_windows_decline(runs, tmp_path):
    """MIEnKS-MDA with Req inferred from the tail (docs/validation.md: the mu windows of a constant gel fall
    and the aggregate is ~10 % high): the conclusion says so; with Req given (prior sd 0), or for a
    method with one window, it does not."""
    key = "Req was estimated from each record's tail and inferred window by window"
    run = _copy(runs, "mienks", tmp_path)
    s = json.loads((run / "summary.json").read_text())
    assert len(s["windows"]) > 1
    assert all(e["nuisance"]["req_m"]["prior_sd"] == 0 for e in s["per_experiment"])  # simulate gives Req
    html = _report(run, "--quiet") and (run / "report.html").read_text()
    assert key not in _text(_section(html, "conclusion"))

    def inferred(s):
        for e in s["per_experiment"]:
            e["nuisance"]["req_m"]["prior_sd"] = 0.04 * e["nuisance"]["req_m"]["prior_mean"]

    _edit_summary(run, inferred)
    html = _report(run, "--quiet") and (run / "report.html").read_text()
    assert key in _text(_section(html, "conclusion"))
    _edit_summary(run, lambda s: s.setdefault("details", {}).update(req_prior={"method": "en4dvar"}))
    html = _report(run, "--quiet") and (run / "report.html").read_text()
    concl = _text(_section(html, "conclusion"))
    assert key not in concl and "prior came from a whole-record En4D-Var fit" in concl
    assert "kept the record's Req prior" not in concl
    _edit_summary(run, lambda s: s["details"]["req_prior"].update(conflicts=[{"experiment": "exp02", "z": -40.9}]))
    html = _report(run, "--quiet") and (run / "report.html").read_text()
    concl = _text(_section(html, "conclusion"))
    assert "In 1 experiment (exp02)" in concl and "kept the record's Req prior" in concl
    one = _copy(runs, "en4dvar", tmp_path)
    _edit_summary(
        one,
        lambda s: [e.update(nuisance={"req_m": {"prior_mean": 3e-5, "prior_sd": 1e-6}}) for e in s["per_experiment"]],
    )
    html = _report(one, "--quiet") and (one / "report.html").read_text()
    assert key not in _text(_section(html, "conclusion"))


def test_report_says_when_reqs_prior_came_from_the_models_tail(runs, tmp_path):
    """A req_tail=model fit (the thermal default) moved each Req's prior: the conclusion says by how
    much and that the estimate is the fit after the quick first pass; a fit that moved nothing says nothing."""
    one = _copy(runs, "en4dvar", tmp_path)
    _edit_summary(
        one,
        lambda s: s.setdefault("details", {}).update(
            req_tail={"method": "model", "setting": "auto", "factor": [1.012, 1.0, 1.047]}
        ),
    )
    concl = _text(_section(_report(one, "--quiet") and (one / "report.html").read_text(), "conclusion"))
    assert "centred by the model's own tail" in concl and "1.2–4.7 % above Req in 2 of 3" in concl
    assert "default for the thermal bubble" in concl
    _edit_summary(
        one,
        lambda s: s["details"].update(req_tail={"method": "inline", "setting": "auto", "factor": [1.012, 1.0, 1.047]}),
    )
    concl = _text(_section(_report(one, "--quiet") and (one / "report.html").read_text(), "conclusion"))
    assert "req_tail=inline, the default for the thermal bubble" in concl and "1.2–4.7 % above Req in 2 of 3" in concl
    assert "first-cycle posterior placed the material" in concl and "quick first fit" not in concl
    _edit_summary(
        one, lambda s: s["details"].update(req_tail={"method": "mean", "setting": "auto", "factor": [1.0] * 3})
    )
    concl = _text(_section(_report(one, "--quiet") and (one / "report.html").read_text(), "conclusion"))
    assert "model's own tail" not in concl


def test_recorded_command_reruns_the_fit_exactly(runs, tmp_path):
    """The report's command row is the command as typed: run again (into a new folder) it gives the
    same estimate, --forward, --set and --n-steps included."""
    s = json.loads((runs["mienks"] / "summary.json").read_text())
    argv = s["command"]["argv"]
    assert argv[:2] == ["imrbayes", "fit"] and "--forward" in argv and "--set" in argv
    from imrbayes.html import esc

    _report(runs["mienks"], "--out", tmp_path / "r.html")
    assert esc(s["command"]["line"]) in (tmp_path / "r.html").read_text()
    i = argv.index("--out")
    again = argv[1 : i + 1] + [str(tmp_path / "again")] + argv[i + 2 :]
    r = _run(*again)
    assert r.exit_code == 0, r.output
    s2 = json.loads((tmp_path / "again" / "summary.json").read_text())
    for p in s["parameters"]:
        assert s2["estimate"][p]["mean"] == s["estimate"][p]["mean"]
        assert s2["estimate"][p]["sd"] == s["estimate"][p]["sd"]


def test_fit_writes_its_results_as_tables_and_load_run_reads_them(runs):
    import imrbayes

    for kind in ("pimr", "mienks"):
        s = json.loads((runs[kind] / "summary.json").read_text())
        est = pd.read_csv(runs[kind] / "estimate.csv")
        assert list(est.columns) == ["parameter", "unit", "mean", "sd", "hdi95_low", "hdi95_high"]
        assert list(est["unit"]) == ["Pa", "Pa s"]
        for _, row in est.iterrows():
            assert row["mean"] == pytest.approx(s["estimate"][row["parameter"]]["mean"], rel=1e-12)
        run = imrbayes.load_run(runs[kind])
        assert run.estimates["G"]["mean"] == pytest.approx(s["estimate"]["G"]["mean"], rel=1e-12)
        assert "posterior" in run.posterior.children
        assert list(run.per_experiment["experiment"]) == [x["name"] for x in s["per_experiment"]]
    assert not (runs["pimr"] / "time_resolved.csv").exists() and imrbayes.load_run(runs["pimr"]).time_resolved is None
    # G(t) as written to posterior.nc's time_resolved group, read independently of summary.json
    tr = pd.read_csv(runs["mienks"] / "time_resolved.csv")
    nc = imrbayes.load_run(runs["mienks"]).posterior["time_resolved"]
    np.testing.assert_allclose(tr["G_mean [Pa]"], np.asarray(nc["G_mean"]), rtol=1e-12)
    np.testing.assert_allclose(tr["mu_hdi95_high [Pa s]"], np.asarray(nc["mu_hdi95"])[:, 1], rtol=1e-12)
    assert imrbayes.load_run(runs["mienks"]).time_resolved.shape[0] == len(tr)
