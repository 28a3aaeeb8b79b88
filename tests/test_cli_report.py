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
import pytest
import xarray as xr
from click.testing import CliRunner

from imrbayes.cli import main

TINY_MIENKS = ["--method", "mienks", "--forward", "bubble=polytropic", "--set", "n_ens=8", "--set", "n_iter=2",
               "--set", "L=10", "--set", "h=5", "--n-steps", "40", "--quiet"]


def _run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("report")
    ds = base / "ds"
    r = _run("simulate", "--model", "nhkv", "--param", "G=7.29e3", "--param", "mu=0.088", "--n-exp", "2",
             "--forward", "bubble=polytropic", "--t-end", "1.0", "--seed", "0", "--out", ds, "--quiet")
    assert r.exit_code == 0, r.output
    out = {"ds": ds}
    r = _run("fit", ds, "--method", "pimr", "--out", base / "pimr", "--quiet")
    assert r.exit_code == 0, r.output
    out["pimr"] = base / "pimr"
    r = _run("fit", ds, *TINY_MIENKS, "--out", base / "mienks")
    assert r.exit_code == 0, r.output
    out["mienks"] = base / "mienks"
    r = _run("fit", ds, *TINY_MIENKS, "--out", base / "mcmc", "--mcmc", "--mcmc-set", "n_walkers=8",
             "--mcmc-set", "n_steps=60", "--mcmc-set", "n_chains=2", "--mcmc-windows", "0,6")
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
    return html[i:j if j > 0 else None]


def _text(fragment):
    import html as _h
    return _h.unescape(re.sub(r"<[^>]+>", "", fragment)).replace("\xa0", " ")


def _self_contained(html):
    low = html.lower()
    for bad in ("src=\"http", "src='http", "href=\"http", "href='http", "<script", "<link", "@import", "url("):
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

    # ArviZ summaries (round_to="none": raw numbers) of posterior.nc and of each MCMC window
    for col in ("mean", "sd", "hdi95_lb", "hdi95_ub", "ess_bulk", "ess_tail", "r_hat", "mcse_mean", "mcse_sd"):
        assert f"<th>{col}</th>" in _section(html, "mcmc"), col
    assert "<th>r_hat</th>" in _section(html, "posterior") and "G[6]" in _section(html, "posterior")
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
    assert [e["agree"] for e in compare["windows"]] == [None, None]     # 60 steps: never converged
    flagged = _text(_section(html, "flagged"))
    for e in compare["windows"]:
        t0, t1 = e["t_star"]
        assert f"Window {e['index']} (t* {t0:.3g}–{t1:.3g}" in flagged
    assert flagged.count("undecided") == 2 and "R-hat" in flagged and "--mcmc-set n_steps=" in flagged
    assert "around the first collapse" in flagged                       # window 6 ends at t* 0.975
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
    x2 = 0.6 * (x1 ** 2 - 1.0) + 0.5 * rng.standard_normal((2, 1000))
    draws = np.stack([8.9 + 0.3 * x1, -2.0 + 0.3 * x2], axis=-1)             # (chain, draw, [log_G, log_mu])
    flat = draws.reshape(-1, 2)
    m, C = flat.mean(axis=0), np.cov(flat, rowvar=False)
    bad = compare_window(m + np.array([np.sqrt(C[0, 0]), 0.0]), C, draws, ["G", "mu"], [True, True], index=6,
                         t_star=w6["t_star"], n_max=400, n_null=20)
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
    assert "The MCMC comparison is absent" in text
    assert "mcmc.nc" in text and "absent (the fit ran without --mcmc)" in text
    # MIEnKS-MDA without --mcmc: the windows are there, the comparison is not
    _report(runs["mienks"], "--quiet")
    html = (runs["mienks"] / "report.html").read_text()
    assert "<h2 id='windows'>Windows (7)</h2>" in html
    assert "Absent: no compare.json" in _text(_section(html, "flagged"))
    assert "Absent: this run directory has no mcmc.nc" in _text(_section(html, "mcmc"))


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
    (run / "report.html").unlink(missing_ok=True)         # from another test
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


@pytest.mark.parametrize("kind", ["missing", "file", "empty", "summary-garbage", "summary-list", "summary-keys",
                                  "posterior", "mcmc", "compare-garbage", "compare-layout"])
def test_report_bad_run_dir(runs, tmp_path, kind):
    path, name = _corrupt(kind, runs["mcmc"], tmp_path)
    r = CliRunner().invoke(main, ["report", str(path)])
    assert r.exit_code == 2, r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("imrbayes: error: ") and name in lines[0], r.stderr
    assert "Traceback" not in r.output
    assert not (tmp_path / "run" / "report.html").exists()
