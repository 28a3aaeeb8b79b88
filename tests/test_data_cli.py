"""``imrbayes inspect``: outputs, and one test per class of bad input (interfaces.md §1): exit status
2, one line on stderr naming the file, no traceback, the user's files unchanged."""

import hashlib
import json
import os
import subprocess
import sys
import traceback
from pathlib import Path

import numpy as np
import pytest
import scipy.io
from _data_synth import LIC, make_dataset, record, write_csv
from click.testing import CliRunner

from imrbayes.cli import main


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=True)


def digest(folder: Path) -> dict:
    folder = Path(folder)
    files = [folder] if folder.is_file() else sorted(p for p in folder.rglob("*") if p.is_file())
    return {str(p): hashlib.sha256(p.read_bytes()).hexdigest() for p in files}


def assert_bad_input(result, name: str, problem: str | None = None):
    # first: no exception escaped the command (a bug, not bad input); if one did, show its traceback
    escaped = None if isinstance(result.exception, (SystemExit, type(None))) else result.exception
    assert escaped is None, "".join(traceback.format_exception(escaped))
    assert result.exit_code == 2, (result.exit_code, result.output, result.exception)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("imrbayes: error: ")
    assert name in lines[0]
    if problem:
        assert problem in lines[0], lines[0]
    assert "Traceback" not in result.output and "Traceback" not in result.stderr


# ----------------------------------------------------------------------------- success paths
def test_inspect_writes_outputs(tmp_path):
    make_dataset(tmp_path / "ds", n_exp=3)
    before = digest(tmp_path / "ds")
    res = run("inspect", tmp_path / "ds", "--out", tmp_path / "out")
    assert res.exit_code == 0, res.output + res.stderr
    assert "exp_002" in res.stdout and "Rmax/Req" in res.stdout and "mean ± sd" in res.stdout
    d = json.loads((tmp_path / "out" / "dataset.json").read_text())
    assert d["n_experiments"] == 3 and len(d["grid"]["t_star"]) == 121
    assert d["choices"]["rmax_method"] == "local-fit" and d["choices"]["noise"]["method"] == "sample-variance"
    png = tmp_path / "out" / "figures" / "radius.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert digest(tmp_path / "ds") == before


def test_inspect_json_stdout(tmp_path):
    make_dataset(tmp_path / "ds", n_exp=2, h_star=0.03)
    res = run("inspect", tmp_path / "ds", "--out", tmp_path / "o", "--json", "--n-steps", "60", "--dt-star", "0.05")
    assert res.exit_code == 0
    table = json.loads(res.stdout)
    assert [e["name"] for e in table["experiments"]] == ["exp_001", "exp_002"]
    assert table["choices"]["n_steps"] == 60 and table["choices"]["dt_star"] == 0.05
    e = table["experiments"][0]
    assert e["t_collapse_star"] == pytest.approx(0.9, abs=0.01)
    assert e["rmax_over_req"] == pytest.approx(1 / 0.14, rel=0.01)


def test_inspect_default_out_under_imrbayes_runs(tmp_path, monkeypatch):
    make_dataset(tmp_path / "ds", n_exp=2)
    monkeypatch.chdir(tmp_path)
    res = run("inspect", "ds", "--quiet")
    assert res.exit_code == 0 and res.stdout == ""
    runs = list((tmp_path / "imrbayes-runs").iterdir())
    assert len(runs) == 1 and runs[0].name.startswith("inspect-ds-")
    assert (runs[0] / "dataset.json").is_file()


def test_inspect_nan_rows_dropped_with_warning(tmp_path):
    make_dataset(tmp_path / "ds", n_exp=2)
    p = tmp_path / "ds" / "exp_001.csv"
    lines = p.read_text().splitlines()
    lines[10] = "nan,nan"
    lines[11] = lines[11].split(",")[0] + ",NaN"
    p.write_text("\n".join(lines) + "\n")
    before = digest(tmp_path / "ds")
    res = run("inspect", tmp_path / "ds", "--out", tmp_path / "o")
    assert res.exit_code == 0
    assert "exp_001.csv: dropped 2 row(s)" in res.stderr and "line 11-12" in res.stderr
    assert digest(tmp_path / "ds") == before


@pytest.mark.skipif(not LIC.is_dir(), reason="shared data not present")
def test_inspect_mat_file(tmp_path):
    res = run(
        "inspect", LIC / "mat_originals" / "estrada2018_stiffPA_RofT_shifted.mat", "--out", tmp_path / "o", "--json"
    )
    assert res.exit_code == 0
    t = json.loads(res.stdout)
    assert t["format"] == "mat:estrada-shifted" and t["n_experiments"] == 20


def test_inspect_refuses_out_equal_to_data(tmp_path):
    make_dataset(tmp_path / "ds", n_exp=2)
    before = digest(tmp_path / "ds")
    assert_bad_input(run("inspect", tmp_path / "ds", "--out", tmp_path / "ds"), "--out")
    assert digest(tmp_path / "ds") == before


# ----------------------------------------------------------------------------- bad input, one per class
def _csv_case(tmp_path, text: str) -> Path:
    d = tmp_path / "ds"
    d.mkdir()
    (d / "meta.json").write_text('{"material": "m"}')
    (d / "bad.csv").write_text(text)
    return d


def _good_rows(scale_t=1.0, scale_r=1.0, n=None):
    t, R, _ = record()
    rows = [f"{float(a) * scale_t!r},{float(b) * scale_r!r}" for a, b in zip(t, R)]
    return rows[:n] if n else rows


BAD_CSV = {
    "missing column": ("t_s\n1e-6\n2e-6\n", "missing column(s) R_m"),
    "extra column": ("t_s,R_m,x\n" + "\n".join(r + ",1" for r in _good_rows()), "unexpected column(s) 'x'"),
    "wrong names": ("time,radius\n" + "\n".join(_good_rows()), "missing column(s) t_s, R_m"),
    "collapse-time summary": (
        "Rmax_m,Lmax_Rmax_over_Req,t_collapse_s\n3.6e-4,6.1,3.1e-5\n",
        "collapse-time summaries (Rmax_m,Lmax_Rmax_over_Req,t_collapse_s), not R(t) curves",
    ),
    "unit in header": ("t_us,R_um\n" + "\n".join(_good_rows()), "suggests values in µs"),
    "semicolons": ("t_s;R_m\n1;2\n", "not comma-separated"),
    "non-numeric": (
        "t_s,R_m\n" + "\n".join(_good_rows()[:5] + ["1e-5,abc"] + _good_rows()[6:]),
        "line 7: R_m value 'abc' is not a number",
    ),
    "infinite": ("t_s,R_m\n" + "\n".join(_good_rows()[:5] + ["inf,1e-4"]), "is not a number"),
    "ragged row": ("t_s,R_m\n" + "\n".join(_good_rows()[:5] + ["1e-5"]), "line 7: 1 values, expected 2"),
    "non-increasing time": (
        "t_s,R_m\n" + "\n".join(_good_rows()[:5] + [_good_rows()[3]] + _good_rows()[6:]),
        "time must increase strictly",
    ),
    "negative radius": (
        "t_s,R_m\n" + "\n".join(_good_rows()[:5] + [_good_rows()[5].split(",")[0] + ",-1e-5"] + _good_rows()[6:]),
        "radius must be positive",
    ),
    "zero radius": (
        "t_s,R_m\n" + "\n".join(_good_rows()[:5] + [_good_rows()[5].split(",")[0] + ",0"] + _good_rows()[6:]),
        "radius must be positive: R_m = 0 at line 7",
    ),
    "radii in micrometres": ("t_s,R_m\n" + "\n".join(_good_rows(scale_r=1e6)), "look like µm or mm"),
    "times in microseconds": ("t_s,R_m\n" + "\n".join(_good_rows(scale_t=1e6)), "look like µs"),
    "times in milliseconds": ("t_s,R_m\n" + "\n".join(_good_rows(scale_t=1e3)), "are the times in ms?"),
    "too short for first collapse": (
        "t_s,R_m\n" + "\n".join(_good_rows(n=14)),
        "too short to reach the first collapse",
    ),
    "too few samples": ("t_s,R_m\n1e-6,1e-4\n2e-6,2e-4\n", "only 2 valid sample(s)"),
    "header only": ("t_s,R_m\n", "no data rows"),
    "empty file": ("", "is empty"),
    "all rows NaN": ("t_s,R_m\nnan,nan\nnan,1\n", "only 0 valid sample(s)"),
}


@pytest.mark.parametrize("case", sorted(BAD_CSV))
def test_bad_csv(tmp_path, case):
    text, problem = BAD_CSV[case]
    d = _csv_case(tmp_path, text)
    before = digest(d)
    assert_bad_input(run("inspect", d, "--out", tmp_path / "o"), "bad.csv", problem)
    assert digest(d) == before


def test_binary_csv(tmp_path):
    d = tmp_path / "ds"
    d.mkdir()
    (d / "meta.json").write_text('{"material": "m"}')
    (d / "b.csv").write_bytes(bytes(range(256)))
    assert_bad_input(run("inspect", d), "b.csv", "binary")


def test_empty_directory(tmp_path):
    (tmp_path / "empty").mkdir()
    assert_bad_input(run("inspect", tmp_path / "empty"), "empty", "no experiment .csv files")


def test_missing_meta_json_is_accepted_with_one_warning(tmp_path):
    d = tmp_path / "ds"
    make_dataset(d, n_exp=2)
    (d / "meta.json").unlink()
    res = run("inspect", d, "--out", tmp_path / "out")
    assert res.exit_code == 0, res.output
    assert res.output.count("no meta.json") == 1
    record = json.loads((tmp_path / "out" / "dataset.json").read_text())
    assert record["dataset"]["material"] == "unknown"


def test_invalid_meta_json(tmp_path):
    d = tmp_path / "ds"
    make_dataset(d, n_exp=1)
    (d / "meta.json").write_text("{")
    assert_bad_input(run("inspect", d), "meta.json", "not valid JSON")


def test_missing_file(tmp_path):
    assert_bad_input(run("inspect", tmp_path / "nope.csv"), "nope.csv", "no such file")


def test_unrecognised_extension(tmp_path):
    p = tmp_path / "data.xlsx"
    p.write_bytes(b"PK\x03\x04")
    assert_bad_input(run("inspect", p), "data.xlsx", "unrecognised file type")


def test_unrecognised_mat(tmp_path):
    p = tmp_path / "other.mat"
    scipy.io.savemat(p, {"Y": np.arange(6.0).reshape(2, 3)})
    assert_bad_input(run("inspect", p), "other.mat", "not a recognised IMR .mat layout; found Y (2x3 double)")


def test_mat_v73_refused(tmp_path):
    h5py = pytest.importorskip("h5py")
    p = tmp_path / "v73.mat"
    with h5py.File(p, "w", userblock_size=512) as f:
        f["R"] = np.ones(3)
    with open(p, "r+b") as fh:
        fh.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 HDF5 schema 1.00 .")
        fh.seek(124)
        fh.write(b"\x00\x02IM")
    assert_bad_input(run("inspect", p), "v73.mat")


def test_bad_option_values(tmp_path):
    make_dataset(tmp_path / "ds", n_exp=2)
    assert_bad_input(run("inspect", tmp_path / "ds", "--dt-star", "-1"), "--dt-star")
    assert_bad_input(run("inspect", tmp_path / "ds", "--camera", "cam7"), "ds", "no experiment from camera")


def test_subprocess_exit_code_and_single_line(tmp_path):
    d = _csv_case(tmp_path, BAD_CSV["radii in micrometres"][0])
    exe = Path(sys.executable).parent / "imrbayes"
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "imrbayes.cli"]
    env = {k: v for k, v in os.environ.items() if k != "IMRBAYES_DEBUG"}
    proc = subprocess.run(cmd + ["inspect", str(d)], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "bad.csv" in proc.stderr and "Traceback" not in proc.stderr


def test_long_csv_via_cli(tmp_path):
    rows = ["experiment,t_s,R_m"]
    for name, rmax in (("a", 3e-4), ("b", 3.3e-4)):
        t, R, _ = record(rmax_m=rmax)
        rows += [f"{name},{float(x)!r},{float(y)!r}" for x, y in zip(t, R)]
    (tmp_path / "long.csv").write_text("\n".join(rows) + "\n")
    res = run("inspect", tmp_path / "long.csv", "--out", tmp_path / "o", "--json")
    assert res.exit_code == 0 and json.loads(res.stdout)["format"] == "long-csv"
    # a long CSV whose second experiment has a unit problem names the experiment
    rows.append("c,1,2")
    rows.append("c,2,3")
    (tmp_path / "long2.csv").write_text("\n".join(rows) + "\n")
    assert_bad_input(run("inspect", tmp_path / "long2.csv"), "long2.csv", "experiment 'c'")


def test_single_experiment_csv_path(tmp_path):
    t, R, _ = record()
    write_csv(tmp_path / "one.csv", t, R)
    res = run("inspect", tmp_path / "one.csv", "--out", tmp_path / "o", "--json")
    assert res.exit_code == 0
    assert "noise model" in res.stderr and "no meta" not in res.stderr


def test_options_from_toml_config_and_command_line_wins(tmp_path):
    """Every option can come from --config FILE.toml; the command line overrides it."""
    from click.testing import CliRunner

    from imrbayes.cli import main

    cfg = tmp_path / "run.toml"
    cfg.write_text(
        '[simulate]\nmodel = "nhkv"\nparam = ["G=4e3", "mu=0.05"]\nn-exp = 2\nnoise = "none"\n'
        'forward = ["bubble=polytropic"]\nt-end = 1.0\n'
    )
    out = tmp_path / "d"
    res = CliRunner().invoke(main, ["simulate", "--config", str(cfg), "--n-exp", "3", "--out", str(out), "--quiet"])
    assert res.exit_code == 0, res.output
    truth = json.loads((out / "truth.json").read_text())
    assert truth["parameters"] == {"G": 4000.0, "mu": 0.05}
    assert truth["n_experiments"] == 3
    bad = tmp_path / "bad.toml"
    bad.write_text("[simulate]\nbogus = 1\n")
    res = CliRunner().invoke(main, ["simulate", "--config", str(bad)])
    assert res.exit_code == 2 and "unknown option 'bogus'" in res.output
    res = CliRunner().invoke(main, ["simulate", "--config", str(tmp_path / "missing.toml")])
    assert res.exit_code == 2 and "config file not found" in res.output


@pytest.mark.parametrize(
    "meta,problem",
    [
        ({"material": "gel", "phisics": {"rho": 1000.0}}, "unknown key 'phisics' (did you mean 'physics'?)"),
        ({"material": "gel", "physics": {"rhoo": 1000.0}}, "unknown physics key 'rhoo' (did you mean 'rho'?)"),
    ],
)
@pytest.mark.parametrize("command", [["inspect"], ["fit", "--method", "pimr"], ["diagnose", "--quick"]])
def test_every_command_refuses_an_unknown_meta_key_naming_the_file(tmp_path, meta, problem, command):
    make_dataset(tmp_path / "ds", n_exp=2, meta=meta)
    r = run(command[0], tmp_path / "ds", *command[1:], "--out", tmp_path / "out")
    assert_bad_input(r, "meta.json", problem)
    assert not (tmp_path / "out").exists()
