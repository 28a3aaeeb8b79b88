"""``imrbayes fit``: every method end to end on a small synthetic dataset; outputs and errors."""

import json

import numpy as np
import pytest
from _ens_synth import RATIO, RMAX, TRUTH, model
from click.testing import CliRunner

from imrbayes.cli import main


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """Three noise-free polytropic bubbles as CSV files (t_s, R_m) with a meta.json."""
    d = tmp_path_factory.mktemp("synthetic")
    fm = model("polytropic")
    t = np.arange(-4, 135) * 0.025
    rmax, req = RMAX[:3], RMAX[:3] / RATIO[:3]
    out = fm.simulate({"G": np.full(3, TRUTH["G"]), "mu": np.full(3, TRUTH["mu"])}, rmax, req, np.abs(t[4:]))
    meta = {"material": "synthetic nhkv", "forward": {"bubble": "polytropic"}, "experiments": {}}
    tc = rmax / np.sqrt(101325.0 / 1064.0)
    for i in range(3):
        R = np.concatenate([out.R_star[i, 4:0:-1], out.R_star[i]]) * rmax[i]  # mirrored growth frames
        name = f"exp_{i + 1:03d}.csv"
        with open(d / name, "w") as fh:
            fh.write("t_s,R_m\n")
            for a, b in zip(t * tc[i] + 1e-5, R):
                fh.write(f"{float(a)!r},{float(b)!r}\n")
        meta["experiments"][name] = {"Req_m": float(req[i])}
    (d / "meta.json").write_text(json.dumps(meta))
    return d


def _fit(args, expect=0):
    res = CliRunner().invoke(main, ["fit", *map(str, args)])
    assert res.exit_code == expect, res.output
    return res


@pytest.mark.parametrize(
    "method,sets",
    [
        ("imr", ["n_G=31", "n_mu=21", "G_max=15e3", "mu_max=0.2"]),
        ("pimr", ["n_G=40", "n_mu=30"]),
        ("en4dvar", ["n_ens=16", "n_runs=2", "n_iter=3", "n_draws=6"]),
        ("mienks", ["n_ens=16", "n_iter=3", "L=40", "h=20", "n_draws=20"]),
    ],
)
def test_fit_every_method(dataset, tmp_path, method, sets):
    import arviz as az

    out = tmp_path / method
    args = [dataset, "--method", method, "--model", "nhkv", "--out", out, "--seed", 3]
    for s in sets:
        args += ["--set", s]
    res = _fit(args)
    assert "%|" not in res.output  # no progress bar off a terminal
    summary = json.loads((out / "summary.json").read_text())
    for key in ("method", "model", "parameters", "seed", "n_experiments", "runtime_s", "estimate", "fit"):
        assert key in summary
    assert summary["method"] == method and summary["seed"] == 3 and summary["n_experiments"] == 3
    assert summary["parameters"] == ["G", "mu"]
    for p in ("G", "mu"):
        e = summary["estimate"][p]
        assert set(e) >= {"mean", "sd", "hdi95"} and len(e["hdi95"]) == 2
    assert summary["forward"]["options"]["bubble"] == "polytropic"  # meta.json's forward block
    assert summary["fit"]["n_samples"] > 0
    if method in ("imr", "en4dvar"):
        assert summary["estimate"]["G"]["mean"] == pytest.approx(TRUTH["G"], rel=0.1)
        assert summary["estimate"]["mu"]["mean"] == pytest.approx(TRUTH["mu"], rel=0.1)
    if method == "mienks":
        assert len(summary["windows"]) == 5
        w = summary["windows"][0]
        assert set(w) >= {"index", "t_star", "G", "mu", "cov", "prior_weight", "prior_dominated"}
        assert np.shape(w["cov"]) == (2, 2)
        # the prior's share of each window mean: in [0, 1], and the warning names exactly the flagged windows
        from imrbayes.ensemble.windows import PRIOR_WEIGHT_LIMIT

        for x in summary["windows"]:
            # a share of the prior mean's offset (the diagonal of a product of gains: a correlated pair can
            # make it slightly negative, never above 1)
            assert all(-0.05 <= v <= 1.0 for v in x["prior_weight"].values()), x["prior_weight"]
            assert x["prior_dominated"] == (max(x["prior_weight"].values()) > PRIOR_WEIGHT_LIMIT)
        flagged = [x["index"] for x in summary["windows"] if x["prior_dominated"]]
        assert summary["details"]["prior_dominated_windows"] == flagged
        assert ("prior-dominated" in res.output) == bool(flagged)
        assert summary["time_resolved"][0]["t_star"] == 0.0 and "G" in summary["time_resolved"][0]
    dt = az.from_netcdf(out / "posterior.nc")
    assert {"posterior", "observed_data"} <= set(dt.children)
    s = az.summary(dt, kind="stats", round_to="none")
    assert np.all(np.isfinite(s["mean"]))
    if method == "mienks":  # each window's first t*, a coordinate of the posterior's windows
        starts = dt["posterior"]["window_start"]
        assert starts.dims == ("window",) and list(starts.values) == [w["t_star"][0] for w in summary["windows"]]
    if method == "en4dvar":
        assert "log_likelihood" in dt.children
        assert dict(dt["log_likelihood"].sizes) == {"chain": 1, "draw": 6, "experiment": 3, "time": 120}
    figs = {p.name for p in (out / "figures").iterdir()}
    assert "fit.png" in figs
    assert {"imr": "landscape.png", "pimr": "landscape.png", "en4dvar": "experiments.png", "mienks": "parameters.png"}[
        method
    ] in figs


def test_config_file_and_command_line_precedence(dataset, tmp_path):
    cfg = tmp_path / "run.toml"
    cfg.write_text(
        '[fit]\nmethod = "imr"\nseed = 5\nquiet = true\n[fit.imr]\nn_G = 9\nn_mu = 7\n'
        '[fit.forward]\nbubble = "polytropic"\n'
    )
    out = tmp_path / "o"
    res = _fit([dataset, "--config", cfg, "--out", out, "--seed", 7, "--set", "n_mu=8"])
    assert res.output == ""
    s = json.loads((out / "summary.json").read_text())
    assert s["seed"] == 7
    assert s["details"]["settings"]["n_G"] == 9 and s["details"]["settings"]["n_mu"] == 8


@pytest.mark.parametrize(
    "args,needle",
    [
        (["--method", "imr", "--set", "n_ens=3"], "unknown setting"),
        (["--method", "en4dvar", "--set", "n_ens=x"], "n_ens"),
        (["--method", "en4dvar", "--set", "rtps=2"], "rtps"),
        (["--method", "mienks", "--set", "L=500"], "window length"),
        (["--method", "mienks", "--set", "h=40"], "exceeds the window length"),
        (["--method", "en4dvar", "--set", "req_tail=bogus"], "req_tail"),
        (["--method", "en4dvar", "--set", "n_iter=0"], "n_iter"),
        (["--method", "en4dvar", "--set", "t_end=0.01"], "t_end"),
        (["--method", "pimr", "--set", "kappa=3"], "kappa"),
        (["--method", "imr", "--forward", "bubble=steam"], "bubble"),
        (["--method", "imr", "--prior", "G=6e3"], "--prior"),
        (["--method", "imr", "--model", "nosuchmodel"], "nosuchmodel"),
        (["--method", "imr", "--set", "window=collapse:7"], "collapse"),
        ([], "--method"),
    ],
)
def test_bad_input_exit_2(dataset, tmp_path, args, needle):
    res = CliRunner().invoke(main, ["fit", str(dataset), "--out", str(tmp_path / "x"), *args])
    assert res.exit_code == 2, res.output
    assert needle in res.output and "Traceback" not in res.output
    assert not (tmp_path / "x").exists(), "a refused run must leave no output folder behind"


def test_missing_data_exit_2(tmp_path):
    res = CliRunner().invoke(main, ["fit", str(tmp_path / "nope"), "--method", "imr"])
    assert res.exit_code == 2 and "Traceback" not in res.output


def test_validate_quick_cases(tmp_path):
    out = tmp_path / "val"
    res = CliRunner().invoke(
        main,
        [
            "validate",
            "--suite",
            "quick",
            "--case",
            "fusion-linear-gaussian",
            "--case",
            "imr-recovery",
            "--out",
            str(out),
        ],
    )
    assert res.exit_code == 0, res.output
    rep = json.loads((out / "validation.json").read_text())
    assert rep["passed"] and [c["name"] for c in rep["cases"]] == ["fusion-linear-gaussian", "imr-recovery"]
    assert (out / "figures" / "imr_landscape.png").exists()
    bad = CliRunner().invoke(main, ["validate", "--case", "nope", "--out", str(tmp_path / "v2")])
    assert bad.exit_code == 2 and "unknown case" in bad.output


@pytest.mark.slow
def test_validate_quick_suite(tmp_path):
    cases = [
        a
        for c in (
            "fusion-linear-gaussian",
            "pimr-collapse-time",
            "imr-recovery",
            "en4dvar-verification",
            "mienks-verification",
        )
        for a in ("--case", c)
    ]
    res = CliRunner().invoke(main, ["validate", "--suite", "quick", *cases, "--out", str(tmp_path / "val")])
    assert res.exit_code == 0, res.output


@pytest.mark.slow
def test_validate_second_truth_case(tmp_path):
    """G 2 kPa, mu 0.05 Pa s, Rmax/Req 9 (far in the paper prior's tail), default likelihood: both
    methods' gel-level estimates within 10 % with the truth inside their 95 % intervals, and
    MIEnKS-MDA's data-decided windows hold it (docs/results.md, 'Second case'; about 2 minutes)."""
    out = tmp_path / "val"
    res = CliRunner().invoke(main, ["validate", "--suite", "quick", "--case", "second-truth", "--out", str(out)])
    assert res.exit_code == 0, res.output
    m = json.loads((out / "validation.json").read_text())["cases"][0]["metrics"]
    for method in ("en4dvar", "mienks"):
        for name, truth in m["truth"].items():
            est = m[method]["estimate"][name]
            assert abs(est["mean"] / truth - 1) < 0.10 and est["hdi95"][0] <= truth <= est["hdi95"][1], (method, name)
    mi = m["mienks"]
    assert mi["n_decided"] >= mi["n_windows"] // 2
    assert all(k >= 0.9 * mi["n_decided"] for k in mi["decided_windows_containing_truth"].values())


@pytest.mark.slow
def test_validate_mcmc_layer_can_fail(tmp_path):
    """The constructed non-Gaussian window (a curved ridge around the first collapse) is flagged
    against even its own moment-matched Gaussian (suite case ``mcmc-non-gaussian``). With the DE and
    stretch moves the window did not converge within its cap (R-hat 1.01-1.014, tail ESS 156-230:
    undecided, once an xfail); the adapted independence proposal converges on it."""
    out = tmp_path / "val"
    res = CliRunner().invoke(main, ["validate", "--suite", "quick", "--case", "mcmc-non-gaussian", "--out", str(out)])
    assert res.exit_code == 0, res.output
    m = json.loads((out / "validation.json").read_text())["cases"][0]["metrics"]
    assert m["agree"] is False and m["converged"] and abs(m["kl_sym"]) < 1e-9
    assert m["kl_sample"] > 0.1 and m["negentropy"]["estimate"] > m["negentropy"]["null_q99"]
    assert (out / "figures" / "mcmc_non_gaussian_pair.png").exists()


@pytest.mark.slow
def test_validate_mcmc_agreement_case(tmp_path):
    """Verification case: MIEnKS window Gaussians agree with MCMC wherever the window is decided and
    well identified (suite case ``mcmc-agreement``; about 5 minutes)."""
    out = tmp_path / "val"
    res = CliRunner().invoke(main, ["validate", "--suite", "quick", "--case", "mcmc-agreement", "--out", str(out)])
    assert res.exit_code == 0, res.output
    m = json.loads((out / "validation.json").read_text())["cases"][0]["metrics"]
    assert m["n_checked"] >= 3


def test_fit_names_the_constants_and_where_they_came_from(dataset, tmp_path):
    """G rests on the gel's density (docs/results.md 2a''): the run says which constants it used."""
    args = ["--method", "imr", "--model", "nhkv", "--set", "n_G=11", "--set", "n_mu=9"]
    res = _fit([dataset, *args, "--out", tmp_path / "a"])
    assert "rho 1064 kg/m^3 (default)" in res.output and "kappa 1.47 (default)" in res.output
    d = tmp_path / "data"
    d.mkdir()
    for f in dataset.iterdir():
        (d / f.name).write_bytes(f.read_bytes())
    meta = json.loads((d / "meta.json").read_text())
    meta["physics"] = {"rho": 998.2}
    (d / "meta.json").write_text(json.dumps(meta))
    res = _fit([d, *args, "--out", tmp_path / "b"])
    assert "rho 998.2 kg/m^3 (meta.json)" in res.output and "S 0.07 N/m (default)" in res.output
    assert json.loads((tmp_path / "b" / "summary.json").read_text())["forward"]["physics"]["rho"] == 998.2
