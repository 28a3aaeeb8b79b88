"""``imrbayes simulate``: with a fake forward model (fast, exact truth) and one real end-to-end run."""

import json
import math

import numpy as np
import pytest
from _data_synth import curve
from _fake_forward import FakeModel
from click.testing import CliRunner

import imrbayes.forward as fwd
from imrbayes.cli import main
from imrbayes.data import load_dataset, preprocess_dataset
from imrbayes.data.noise import paper_sigma


def sim(*args):
    return CliRunner().invoke(main, ["simulate", *[str(a) for a in args]])


BASE = ["--model", "nhkv", "--param", "G=7.29e3", "--param", "mu=0.088"]


def read(out):
    meta = json.loads((out / "meta.json").read_text())
    truth = json.loads((out / "truth.json").read_text())
    data = [np.loadtxt(p, delimiter=",", skiprows=1) for p in sorted(out.glob("exp_*.csv"))]
    return meta, truth, data


def test_simulate_writes_dataset_and_truth(fake, tmp_path):
    out = tmp_path / "syn"
    res = sim(
        *BASE,
        "--rmax",
        "263e-6",
        "--ratio",
        "7.58",
        "--n-exp",
        "3",
        "--noise",
        "none",
        "--seed",
        "1",
        "--forward",
        "bubble=polytropic",
        "--forward",
        "vapor=false",
        "--out",
        out,
    )
    assert res.exit_code == 0, res.output + res.stderr
    meta, truth, data = read(out)
    assert len(data) == 3 and meta["material"] == "synthetic (nhkv)"
    assert meta["forward"] == {"radial": "km", "bubble": "polytropic", "vapor": "false"}  # strings passed on
    assert meta["physics"]["rho"] == 1064.0
    assert meta["experiments"]["exp_002.csv"]["Req_m"] == pytest.approx(263e-6 / 7.58, rel=1e-15)
    assert truth["parameters"] == {"G": 7290.0, "mu": 0.088} and truth["seed"] == 1
    assert truth["noise"]["kind"] == "none" and truth["model"] == "nhkv"
    assert [e["rmax_m"] for e in truth["experiments"]] == [263e-6] * 3
    tc = 263e-6 / math.sqrt(101325 / 1064)
    t_star = np.arange(121) * 0.025
    for d in data:
        np.testing.assert_allclose(d[:, 0], t_star * tc, rtol=1e-15, atol=0)
        np.testing.assert_allclose(d[:, 1], curve(t_star, q=1 / 7.58) * 263e-6, rtol=1e-15)
    assert fake[0][0] == {"G": 7290.0, "mu": 0.088}


def test_simulate_roundtrip_through_loader(fake, tmp_path):
    out = tmp_path / "syn"
    assert sim(*BASE, "--noise", "none", "--n-exp", "2", "--t-end", "3.2", "--out", out).exit_code == 0
    pre = preprocess_dataset(load_dataset(out))
    np.testing.assert_allclose(pre.rmax_m, 263e-6, rtol=1e-12)
    np.testing.assert_allclose(pre.req_m, 263e-6 / 7.58, rtol=1e-12)
    np.testing.assert_allclose(pre.t_collapse_star, 0.9, atol=1e-3)
    np.testing.assert_allclose(pre.R_star[0], curve(pre.t_star, q=1 / 7.58), atol=1e-12)
    assert not any("growth phase" in w for w in pre.warnings)  # meta.json says synthetic


def test_simulate_is_seeded_and_batch_draws_follow_documented_order(fake, tmp_path):
    args = [*BASE, "--rmax", "300e-6:30e-6", "--ratio", "7:0.5", "--n-exp", "4", "--noise", "paper"]
    assert sim(*args, "--seed", "5", "--out", tmp_path / "a").exit_code == 0
    assert sim(*args, "--seed", "5", "--out", tmp_path / "b").exit_code == 0
    assert sim(*args, "--seed", "6", "--out", tmp_path / "c").exit_code == 0
    a, b, c = (sorted((tmp_path / k).glob("*.csv")) for k in "abc")
    assert [p.read_bytes() for p in a] == [p.read_bytes() for p in b]
    assert [p.read_bytes() for p in a] != [p.read_bytes() for p in c]
    _, truth, _ = read(tmp_path / "a")
    rng = np.random.default_rng(5)
    rmax = rng.normal(300e-6, 30e-6, 4)
    ratio = rng.normal(7, 0.5, 4)
    np.testing.assert_allclose([e["rmax_m"] for e in truth["experiments"]], rmax, rtol=1e-15)
    np.testing.assert_allclose([e["rmax_over_req"] for e in truth["experiments"]], ratio, rtol=1e-15)


def test_simulate_paper_noise_statistics(fake, tmp_path):
    out = tmp_path / "syn"
    assert sim(*BASE, "--noise", "paper", "--n-exp", "40", "--seed", "3", "--out", out).exit_code == 0
    _, truth, data = read(out)
    t_star = np.arange(121) * 0.025
    clean = curve(t_star, q=1 / 7.58)
    z = []
    for d in data:
        Rs = d[:, 1] / 263e-6
        sd = paper_sigma(t_star, clean)
        assert Rs[0] == 1.0  # sigma(0) = 0
        z.append((Rs[1:] - clean[1:]) / sd[1:])
    z = np.concatenate(z)
    assert abs(z.mean()) < 0.05 and abs(z.std() - 1.0) < 0.05
    assert truth["noise"]["kind"] == "paper"


def test_simulate_numeric_noise_and_frame_rate(fake, tmp_path):
    out = tmp_path / "syn"
    res = sim(*BASE, "--noise", "0.01", "--n-exp", "2", "--frame-s", "1e-6", "--t-end", "3", "--out", out)
    assert res.exit_code == 0, res.stderr
    _, truth, data = read(out)
    assert truth["noise"] == {
        "kind": "gaussian",
        "sd": 0.01,
        "applied_to": truth["noise"]["applied_to"],
        "n_redrawn_nonpositive": 0,
    }
    tc = 263e-6 / math.sqrt(101325 / 1064)
    k = np.round(data[0][:, 0] / 1e-6)
    np.testing.assert_allclose(data[0][:, 0], k * 1e-6, rtol=1e-12)
    assert k[-1] == math.floor(3 * tc / 1e-6)
    assert truth["sampling"] == {
        "frame_s": 1e-6,
        "phase": "0",
        "pre_max_s": 0.0,
        "before_maximum": "mirror of the collapse",
        "t_end_star": 3.0,
    }


@pytest.mark.parametrize(
    "args,where,problem",
    [
        (["--model", "nope", "--param", "G=1"], "--model", "available: nhkv, qkv"),
        (["--model", "nhkv", "--param", "G=1", "--param", "mu=0.1", "--param", "x=2"], "--param", "unknown parameter"),
        (["--model", "nhkv", "--param", "G=1"], "--param", "missing mu"),
        (["--model", "nhkv", "--param", "G"], "--param", "expected KEY=VALUE"),
        (["--model", "nhkv", "--param", "G=abc", "--param", "mu=1"], "--param", "G must be a number"),
        ([*BASE, "--rmax", "big"], "--rmax", "expected a number or MEAN:SD"),
        ([*BASE, "--rmax", "263"], "--rmax", "give Rmax in metres"),
        ([*BASE, "--ratio", "0.5"], "--ratio", "must exceed 1"),
        ([*BASE, "--noise", "loud"], "--noise", "expected paper, none, a number"),
        ([*BASE, "--n-exp", "0"], "--n-exp", "at least 1"),
        ([*BASE, "--frame-s", "2"], "--frame-s", "frame interval in seconds"),
        ([*BASE, "--forward", "bad=1"], "--forward", "unknown forward option"),
    ],
)
def test_simulate_bad_input(fake, tmp_path, args, where, problem):
    res = sim(*args, "--out", tmp_path / "o")
    assert res.exit_code == 2, (res.output, res.stderr)
    line = res.stderr.strip()
    assert "\n" not in line and line.startswith(f"imrbayes: error: {where}") and problem in line
    assert not (tmp_path / "o" / "meta.json").exists()


def test_simulate_refuses_existing_dataset(fake, tmp_path):
    assert sim(*BASE, "--out", tmp_path / "o").exit_code == 0
    before = (tmp_path / "o" / "exp_001.csv").read_bytes()
    res = sim(*BASE, "--seed", "9", "--out", tmp_path / "o")
    assert res.exit_code == 2 and "already holds" in res.stderr and "--force" in res.stderr
    res = sim(*BASE, "--seed", "9", "--out", tmp_path / "o", "--force")  # even forced: datasets never mix
    assert res.exit_code == 2 and "already holds a dataset" in res.stderr
    assert (tmp_path / "o" / "exp_001.csv").read_bytes() == before


def test_simulate_forward_failure_is_one_line_exit_1(fake, tmp_path):
    res = sim("--model", "nhkv", "--param", "G=-1", "--param", "mu=0.1", "--out", tmp_path / "o")
    assert res.exit_code == 1 and res.stderr.strip().count("\n") == 0
    assert "ForwardModelError: forward solve failed" in res.stderr


def test_simulate_real_forward_model_end_to_end(tmp_path):
    """The verification case of methods.md §5 through the real forward model, then inspect. Never
    skipped: the forward model is part of imrbayes, so its absence is a failure."""
    from imrbayes.forward.model import ForwardModel as real_model

    assert fwd.ForwardModel is real_model and fwd.ForwardModel is not FakeModel  # not the fixture's fake
    out = tmp_path / "syn"
    res = sim(
        *BASE,
        "--rmax",
        "263e-6",
        "--ratio",
        "7.58",
        "--n-exp",
        "2",
        "--noise",
        "paper",
        "--seed",
        "0",
        "--forward",
        "bubble=polytropic",
        "--out",
        out,
    )
    assert res.exit_code == 0, res.stderr
    meta, truth, data = read(out)
    assert meta["forward"]["bubble"] == "polytropic" and truth["forward"] == meta["forward"]
    assert all(d.shape == (121, 2) for d in data)
    ins = CliRunner().invoke(main, ["inspect", str(out), "--out", str(tmp_path / "ins"), "--json"])
    assert ins.exit_code == 0, ins.stderr
    table = json.loads(ins.stdout)
    for e in table["experiments"]:
        assert e["rmax_over_req"] == pytest.approx(7.58, rel=1e-3)  # Req from meta.json
        assert e["rmax_um"] == pytest.approx(263.0, rel=2e-3)
        assert 0.8 < e["t_collapse_star"] < 1.0
