"""``imrbayes fit --mcmc`` and ``imrbayes compare``: window posteriors sampled as execution units,
mcmc.nc / compare.json / figures, agreement where the target is exact, resume, and bad input."""

import json

import numpy as np
import pytest
import xarray as xr
from click.testing import CliRunner

from imrbayes.cli import main

FWD = ["--forward", "bubble=polytropic"]
# the paper's density: the MCMC target does not use the default likelihood's ``whiten`` yet
MIENKS = [
    "--method",
    "mienks",
    "--n-steps",
    60,
    "--set",
    "n_ens=32",
    "--set",
    "n_iter=5",
    "--set",
    "L=20",
    "--set",
    "h=10",
    "--set",
    "likelihood=paper",
]


def _run(*args, expect=0):
    res = CliRunner().invoke(main, [str(a) for a in args])
    assert res.exit_code == expect, res.output
    return res


@pytest.fixture(scope="module")
def syn(tmp_path_factory):
    d = tmp_path_factory.mktemp("mcmc") / "syn"
    _run(
        "simulate",
        "--model",
        "nhkv",
        "--param",
        "G=7.29e3",
        "--param",
        "mu=0.088",
        "--rmax",
        "263e-6",
        "--ratio",
        "7.58",
        "--n-exp",
        2,
        "--noise",
        "paper",
        "--seed",
        0,
        *FWD,
        "--t-end",
        1.5,
        "--out",
        d,
    )
    return d


@pytest.fixture(scope="module")
def window0(syn, tmp_path_factory):
    """MIEnKS-MDA and MCMC of its window 0 (exact target: every member starts at the maximum)."""
    out = tmp_path_factory.mktemp("mcmc") / "run"
    res = _run(
        "fit",
        syn,
        *MIENKS,
        *FWD,
        "--mcmc",
        "--mcmc-windows",
        "0",
        "--mcmc-set",
        "n_walkers=16",
        "--mcmc-set",
        "n_steps=2000",
        "--mcmc-set",
        "n_chains=4",
        "--mcmc-set",
        "quadrature=true",
        "--out",
        out,
        "--seed",
        1,
    )
    return out, res


@pytest.mark.slow
def test_window0_ensemble_and_mcmc_agree(window0):
    out, res = window0
    assert "ensemble vs MCMC: 1 window(s) agree" in res.output
    summary = json.loads((out / "summary.json").read_text())
    comp = json.loads((out / "compare.json").read_text())
    assert summary["mcmc"]["overall"]["n_agree"] == 1 and len(comp["windows"]) == 1
    e = comp["windows"][0]
    assert e["index"] == 0 and e["state_source"] == "handed-off ensemble mean"
    assert e["mcmc"]["converged"] and e["agree"] is True
    assert e["kl_sym"] < 0.1 and e["w2"] < 0.5
    # the ensemble side is the fit's window-0 Gaussian, and the MCMC draws in mcmc.nc give the MCMC moments
    w0 = summary["windows"][0]
    np.testing.assert_allclose(list(e["ensemble"]["mean_internal"].values()), w0["mean_internal"], rtol=1e-12)
    with xr.open_datatree(out / "mcmc.nc") as dt:
        post = dt["window_00"]["posterior"].to_dataset()
        assert post.sizes["chain"] == 4
        assert float(post["log_G"].mean()) == pytest.approx(e["mcmc"]["mean_internal"]["log_G"], abs=1e-9)
        assert dt["posterior"].sizes["window"] == 1
        assert "log_likelihood" in dt["window_00"].children
    for f in ("mcmc_forest.png", "mcmc_divergence.png", "mcmc_pair_window_00.png"):
        assert (out / "figures" / f).stat().st_size > 10_000
    # stopped on convergence under the cap, and the exact grid posterior agrees with it
    s = e["mcmc"]["sampler"]
    assert s["stop_reason"] == "converged" and not s["cap_hit"] and s["n_steps"] < 2000
    q = e["quadrature"]
    assert q["vs_mcmc"]["within_mc_error"], q["vs_mcmc"]
    assert q["edge_ok"] and q["n_evals"] > 0 and q["vs_ensemble"]["kl_sym"] < 0.1
    with xr.open_datatree(out / "mcmc.nc") as dt:
        assert "quadrature_json" in dt["window_00"].attrs


@pytest.mark.slow
def test_compare_recomputes_from_the_files(window0, tmp_path):
    out, _ = window0
    before = json.loads((out / "compare.json").read_text())
    res = _run("compare", out, "--out", tmp_path / "again")
    again = json.loads((tmp_path / "again" / "compare.json").read_text())
    e0, e1 = before["windows"][0], again["windows"][0]
    for key in ("kl_sym", "kl_gauss", "w2", "kl_sample", "agree"):
        assert e0[key] == e1[key]
    assert e1["quadrature"]["vs_mcmc"] == e0["quadrature"]["vs_mcmc"]
    assert "1 window(s) agree" in res.output and (tmp_path / "again" / "figures" / "mcmc_forest.png").exists()


@pytest.mark.slow
def test_resume_reads_finished_windows_back(window0, syn, tmp_path):
    """A rerun with --resume computes nothing: fit units and the MCMC window come from checkpoints,
    and compare.json is the same."""
    out, _ = window0
    before = json.loads((out / "compare.json").read_text())
    res = _run(
        "fit",
        syn,
        *MIENKS,
        *FWD,
        "--mcmc",
        "--mcmc-windows",
        "0",
        "--mcmc-set",
        "n_walkers=16",
        "--mcmc-set",
        "n_steps=2000",
        "--mcmc-set",
        "n_chains=4",
        "--mcmc-set",
        "quadrature=true",
        "--out",
        out,
        "--seed",
        1,
        "--resume",
    )
    assert "0 computed" in res.output
    after = json.loads((out / "compare.json").read_text())
    assert after["windows"][0]["kl_sym"] == before["windows"][0]["kl_sym"]
    # other MCMC settings are another run: refused, not mixed
    bad = _run(
        "fit",
        syn,
        *MIENKS,
        *FWD,
        "--mcmc",
        "--mcmc-windows",
        "0",
        "--mcmc-set",
        "n_walkers=16",
        "--mcmc-set",
        "n_steps=2100",
        "--mcmc-set",
        "n_chains=4",
        "--mcmc-set",
        "quadrature=true",
        "--out",
        out,
        "--seed",
        1,
        "--resume",
        expect=2,
    )
    assert "n_steps" in bad.output


@pytest.mark.slow
def test_en4dvar_mcmc_one_exact_window(syn, tmp_path):
    out = tmp_path / "en"
    res = _run(
        "fit",
        syn,
        "--method",
        "en4dvar",
        "--n-steps",
        40,
        "--set",
        "n_ens=16",
        "--set",
        "n_runs=1",
        "--set",
        "n_iter=3",
        "--set",
        "n_draws=5",
        *FWD,
        "--mcmc",
        "--mcmc-set",
        "n_walkers=8",
        "--mcmc-set",
        "n_steps=60",
        "--mcmc-set",
        "n_chains=2",
        "--out",
        out,
    )
    comp = json.loads((out / "compare.json").read_text())
    (e,) = comp["windows"]
    assert e["index"] == 0 and e["state_source"] == "maximum radius (exact)"
    assert e["t_star"][0] == 0.0 and e["t_star"][1] == pytest.approx(1.0)
    assert e["agree"] is None  # 60 steps cannot meet the 50-tau rule: undecided, never "agree"
    assert "undecided" in res.output
    s = e["mcmc"]["sampler"]  # the hard cap is hit and says so
    assert s["cap_hit"] and s["stop_reason"] == "cap" and s["n_steps"] == 60 and "hard cap of 60 steps" in e["notes"]


@pytest.mark.slow
def test_en4dvar_plain_likelihood_mcmc_samples_the_same_density(syn, tmp_path):
    """With ``obs_weight=sum`` the MCMC target counts every sample once too (a 1/N_t target would
    be ~6x wider and the comparison would disagree)."""
    out = tmp_path / "sum"
    _run(
        "fit",
        syn,
        "--method",
        "en4dvar",
        "--n-steps",
        60,
        "--likelihood",
        "paper",
        "--set",
        "obs_weight=sum",
        "--set",
        "n_draws=5",
        *FWD,
        "--mcmc",
        "--mcmc-set",
        "n_walkers=16",
        "--mcmc-set",
        "n_steps=2500",
        "--mcmc-set",
        "n_chains=4",
        "--out",
        out,
    )
    summary = json.loads((out / "summary.json").read_text())
    assert summary["details"]["settings"]["obs_weight"] == "sum"
    (e,) = json.loads((out / "compare.json").read_text())["windows"]
    assert e["agree"] is True, e
    ens_sd, mc_sd = (np.array(list(e[k]["sd_internal"].values())) for k in ("ensemble", "mcmc"))
    np.testing.assert_allclose(ens_sd, mc_sd, rtol=0.1)


@pytest.mark.parametrize(
    "args,needle",
    [
        (["--method", "imr", "--mcmc"], "--mcmc"),
        (["--method", "mienks", "--mcmc", "--mcmc-set", "n_walkers=3"], "n_walkers"),
        (["--method", "mienks", "--mcmc-set", "n_steps=10"], "needs --mcmc"),
        (["--method", "mienks", "--mcmc", "--mcmc-windows", "a,b"], "--mcmc-windows"),
        (["--method", "mienks", "--mcmc", "--mcmc-set", "bogus=1"], "bogus"),
        (["--method", "en4dvar", "--set", "req_tail=tail"], "req_tail"),
    ],
)
def test_bad_mcmc_options_fail_before_the_fit(syn, tmp_path, args, needle):
    res = _run("fit", syn, *args, *FWD, "--out", tmp_path / "x", expect=2)
    assert needle in res.output and len(res.output.strip().splitlines()) == 1
    assert not (tmp_path / "x" / "summary.json").exists()


@pytest.mark.slow
def test_window_out_of_range_is_a_clear_error(syn, tmp_path):
    res = _run("fit", syn, *MIENKS, *FWD, "--mcmc", "--mcmc-windows", "99", "--out", tmp_path / "x", expect=2)
    assert "window(s) [99] do not exist" in res.output


@pytest.mark.slow
def test_compare_bad_run_dirs(window0, tmp_path):
    out, _ = window0
    res = _run("compare", tmp_path / "nope", expect=2)
    assert "not a directory" in res.output
    (tmp_path / "empty").mkdir()
    assert "summary.json: not found" in _run("compare", tmp_path / "empty", expect=2).output
    d = tmp_path / "nomcmc"
    d.mkdir()
    (d / "summary.json").write_text((out / "summary.json").read_text())
    assert "mcmc.nc: not found" in _run("compare", d, expect=2).output
    (d / "mcmc.nc").write_bytes(b"not a netcdf file")
    res = _run("compare", d, expect=2)
    assert "mcmc.nc: cannot be read as netCDF" in res.output and len(res.output.strip().splitlines()) == 1
    (d / "summary.json").write_text("{broken")
    assert "summary.json: not valid JSON" in _run("compare", d, expect=2).output


def _mcmc_cmd(syn, out, *extra):
    import sys
    from pathlib import Path

    exe = Path(sys.executable).parent / "imrbayes"
    return [
        str(exe),
        "fit",
        str(syn),
        *map(str, MIENKS),
        *FWD,
        "--mcmc",
        "--mcmc-windows",
        "0,1",
        "--mcmc-set",
        "n_walkers=8",
        "--mcmc-set",
        "n_steps=1200",
        "--mcmc-set",
        "n_chains=2",
        "--out",
        str(out),
        "--seed",
        "4",
        "--quiet",
        *extra,
    ]


def _window_arrays(out):
    with xr.open_datatree(out / "mcmc.nc") as dt:
        return {k: dt[k]["posterior"]["log_G"].values.copy() for k in ("window_00", "window_01")}


@pytest.mark.slow
def test_sigkill_mid_window_then_resume_gives_the_uninterrupted_chains(syn, tmp_path):
    """Killed (SIGKILL) while window 0's emcee runs, resumed: the chains continue from the HDF5
    file and equal those of an uninterrupted run bit for bit; --workers 2 gives them too."""
    import signal
    import subprocess
    import time

    ref = tmp_path / "ref"
    subprocess.run(_mcmc_cmd(syn, ref), check=True, capture_output=True, text=True, timeout=600)
    out = tmp_path / "killed"
    proc = subprocess.Popen(_mcmc_cmd(syn, out), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    h5 = out / "mcmc_chains" / "window_000.h5"
    t0 = time.time()
    while time.time() - t0 < 300 and proc.poll() is None and not (h5.exists() and h5.stat().st_size > 60_000):
        time.sleep(0.05)
    assert proc.poll() is None, "the run finished before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=60)
    assert not (out / "compare.json").exists()
    try:  # the kill came mid-window (unless it left the file unreadable)
        import h5py

        with h5py.File(h5, "r") as f:
            its = [int(f[f"window_00/chain_{c}"].attrs["iteration"]) for c in range(2) if f"window_00/chain_{c}" in f]
        assert its and max(its) < 1200
    except (OSError, KeyError):  # h5py raises either for a file cut mid-write
        pass
    done = subprocess.run(_mcmc_cmd(syn, out, "--resume"), capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    a, b = _window_arrays(ref), _window_arrays(out)
    for k in a:
        assert a[k].tobytes() == b[k].tobytes(), k
    par = tmp_path / "workers"
    done = subprocess.run(_mcmc_cmd(syn, par, "--workers", "2"), capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    c = _window_arrays(par)
    for k in a:
        assert a[k].tobytes() == c[k].tobytes(), k
