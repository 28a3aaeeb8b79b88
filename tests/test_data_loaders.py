"""Loaders, ``imrbayes inspect`` and fuzzing of the loaders and preprocessing."""

import glob
import hashlib
import json
import math
import os
import subprocess
import sys
import tempfile
import traceback
from pathlib import Path

import numpy as np
import pytest
import scipy.io
from _data_synth import LIC, curve, make_dataset, record, write_csv
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings, strategies as st

from imrbayes.cli import main
from imrbayes.data import load_dataset, preprocess_dataset
from imrbayes.data.csvio import read_table
from imrbayes.data.loaders import load_mat
from imrbayes.errors import InputError

# Loaders: dataset directories, single and long CSVs, meta.json, the four IMR .mat layouts.


needs_shared = pytest.mark.skipif(not LIC.is_dir(), reason="shared data (../shared/data/lic) not present")

# .mat original -> (converted CSV folder, CSV name prefix)
MAT_TO_CSV = {
    "estrada2018_stiffPA_RofT_shifted.mat": ("estrada2018_stiffPA_270kfps", ""),
    "estrada2018_stiffPA_xy002_RofT.mat": ("estrada2018_stiffPA_xy002_refit", ""),
    "franck_lab_A_E2_002.mat": ("franck_lab_A_E2_002_1.59Mfps", ""),
    "umich_PA10_PolyAcry_12_28_04_updated.mat": ("umich_PA10_bis0.06_1Mfps_dualcam", "PolyAcry_12_28_04_"),
}
LAYOUT = {
    "estrada2018_stiffPA_RofT_shifted.mat": "estrada-shifted",
    "estrada2018_stiffPA_xy002_RofT.mat": "circlefit-pixels",
    "franck_lab_A_E2_002.mat": "franck-RofT",
    "umich_PA10_PolyAcry_12_28_04_updated.mat": "umich-dualcam",
}


def _rel(a, b):
    return abs(a - b) / abs(b) if b != 0 else abs(a)


# ----------------------------------------------------------------------------- .mat reproduction
@needs_shared
@pytest.mark.parametrize("mat", sorted(MAT_TO_CSV))
def test_mat_reproduces_converted_csvs(mat):
    """The converted CSVs print 11 significant digits (%.10e), so a CSV value carries a relative
    rounding error of up to 5e-11 and a 1e-12 comparison against the CSV text is impossible. We check
    (1) our values printed the same way reproduce every CSV line character for character, (2) they
    differ from the parsed CSV by at most half a unit of the 11th digit, and (3) the full-precision
    numbers the converters stored in meta.json (first/last time, Rmax, mean of the last 10 radii,
    source time of t = 0, stored Rmax, Req and collapse times) agree to 1e-12 relative."""
    folder, prefix = MAT_TO_CSV[mat]
    layout, exps = load_mat(LIC / "mat_originals" / mat)
    assert layout == LAYOUT[mat]
    csvs = sorted(glob.glob(str(LIC / folder / f"{prefix}*.csv")))
    assert len(csvs) == len(exps) and len(exps) >= 1
    meta = json.loads((LIC / folder / "meta.json").read_text())
    entries = {e["file"]: e for e in meta["experiments"]}
    for exp, csv_path in zip(exps, csvs):
        lines = Path(csv_path).read_text().split()
        assert lines[0] == "t_s,R_m"
        mine = [f"{t:.10e},{r:.10e}" for t, r in zip(exp.t_s, exp.R_m)]
        assert mine == lines[1:], f"{csv_path}: text differs"
        table = read_table(csv_path)
        for ours, theirs in ((exp.t_s, table.columns["t_s"]), (exp.R_m, table.columns["R_m"])):
            half_ulp = 0.5e-10 * 10.0 ** np.floor(np.log10(np.abs(np.where(theirs == 0, 1, theirs))))
            assert np.all(np.abs(ours - theirs) <= half_ulp * (1 + 1e-9))
        entry = entries[Path(csv_path).name]
        checks = {
            "n_samples": exp.t_s.size,
            "t_first_s": exp.t_s[0],
            "t_last_s": exp.t_s[-1],
            "Rmax_sample_m": exp.R_m.max(),
            "R_last10_mean_m": exp.R_m[-10:].mean(),
            "t_at_Rmax_s": exp.t_s[np.argmax(exp.R_m)],
            "source_time_of_t0_s": exp.info.get("source_time_of_t0_s"),
            "Rmax_stored_um": exp.info.get("Rmax_stored_um"),
        }
        compared = 0
        for key, value in checks.items():
            if key in entry and value is not None:
                assert _rel(float(value), float(entry[key])) <= 1e-12, (csv_path, key)
                compared += 1
        assert compared >= 5
    if "Req_stored_m" in meta:
        assert _rel(exps[0].req_m, meta["Req_stored_m"]) <= 1e-12
        got = exps[0].info["collapse_times_from_file_s"]
        assert all(_rel(a, b) <= 1e-12 for a, b in zip(got, meta["collapse_times_from_tloc_s"]))


@needs_shared
def test_mat_dataset_says_which_layout():
    ds = load_dataset(LIC / "mat_originals" / "franck_lab_A_E2_002.mat")
    assert ds.format == "mat:franck-RofT"
    assert any("franck-RofT" in n for n in ds.notes)
    assert ds.experiments[0].req_source == "file"


def test_mat_unrecognised_layout_lists_variables(tmp_path):
    p = tmp_path / "x.mat"
    scipy.io.savemat(p, {"foo": np.zeros((3, 4)), "bar": np.ones(2)})
    with pytest.raises(InputError, match=r"not a recognised IMR .mat layout; found bar \(1x2 double\), foo"):
        load_dataset(p)


def test_mat_refuses_wrong_unit(tmp_path):
    # franck layout but R in metres: the layout says µm, values are far too small -> refuse, no guess
    t = np.arange(100) * 1e-6
    R = 200e-6 * np.abs(np.cos(t / 30e-6)) + 2e-5
    p = tmp_path / "f.mat"
    scipy.io.savemat(p, {"t": t[None, :], "R": R[None, :]})
    with pytest.raises(InputError, match="should be in µm"):
        load_dataset(p)


def test_mat_garbage_bytes_refused(tmp_path):
    p = tmp_path / "g.mat"
    p.write_bytes(b"MATLAB 5.0 MAT-file" + bytes(range(256)) * 3)
    with pytest.raises(InputError, match="g.mat"):
        load_dataset(p)


def test_mat_umich_layout_synthetic(tmp_path):
    t, R, _ = record(rmax_m=250e-6, h_star=0.03)
    A = np.column_stack([t - t[0], R * 1e6, R * 1e6 * 1.01])
    A[:3, 1:] = np.nan
    p = tmp_path / "PolyAcry_01_02_03_updated.mat"
    scipy.io.savemat(p, {"PolyAcry_01_02_03": A})
    ds = load_dataset(p)
    assert ds.format == "mat:umich-dualcam" and len(ds.experiments) == 2
    assert [e.camera for e in ds.experiments] == ["cam0deg", "cam90deg"]
    assert ds.experiments[0].n_samples == len(t) - 3
    assert any("not independent" in w for w in ds.warnings)
    assert len(load_dataset(p, camera="cam90deg").experiments) == 1


# ----------------------------------------------------------------------------- directories, CSVs, meta
def test_directory_loads_with_meta_passthrough(tmp_path):
    meta = {
        "material": "gel",
        "temperature_C": 21.0,
        "physics": {"rho": 1000.0, "c8": 1500},
        "forward": {"radial": "km", "bubble": "polytropic", "vapor": False},
        "experiments": {"exp_002.csv": {"Req_m": 4.0e-5, "note": "kept"}},
        "x_my_key": [1, 2],
    }
    make_dataset(tmp_path / "ds", n_exp=3, meta=meta)
    ds = load_dataset(tmp_path / "ds")
    assert ds.format == "directory" and ds.names == ["exp_001", "exp_002", "exp_003"]
    assert ds.material == "gel" and ds.meta["x_my_key"] == [1, 2]
    assert ds.physics == {"rho": 1000.0, "c8": 1500.0} and ds.rho == 1000.0 and ds.p8 == 101325.0
    assert ds.forward == {"radial": "km", "bubble": "polytropic", "vapor": False}
    e2 = ds.experiments[1]
    assert e2.req_m == 4.0e-5 and e2.req_source == "meta.json" and e2.info["note"] == "kept"
    assert ds.experiments[0].req_m is None


def test_meta_experiments_as_list_like_shared_data(tmp_path):
    meta = {"material": "gel", "experiments": [{"file": "exp_001.csv", "Req_m": 3e-5}, {"file": "exp_002.csv"}]}
    make_dataset(tmp_path / "ds", n_exp=2, meta=meta)
    ds = load_dataset(tmp_path / "ds")
    assert ds.experiments[0].req_m == 3e-5 and ds.experiments[1].req_m is None


def test_meta_without_material_warns(tmp_path):
    make_dataset(tmp_path / "ds", n_exp=1, meta={})
    ds = load_dataset(tmp_path / "ds")
    assert ds.material == "unknown" and any("material" in w for w in ds.warnings)


@pytest.mark.parametrize(
    "meta,match",
    [
        ("{not json", "not valid JSON: line 1"),
        ("[1, 2]", "must hold a JSON object"),
        ('{"material": "x", "physics": {"rho": -1}}', "physics.rho must be finite and positive"),
        ('{"material": "x", "physics": {"rho": "heavy"}}', "physics.rho must be a number"),
        ('{"material": "x", "forward": [1]}', "'forward' must be an object"),
        ('{"material": "x", "experiments": {"exp_001.csv": {"Req_m": 34.0}}}', "looks like µm"),
        ('{"material": 3}', "'material' must be a string"),
    ],
)
def test_bad_meta_refused(tmp_path, meta, match):
    make_dataset(tmp_path / "ds", n_exp=1)
    (tmp_path / "ds" / "meta.json").write_text(meta)
    with pytest.raises(InputError, match=match) as exc:
        load_dataset(tmp_path / "ds")
    assert "meta.json" in str(exc.value)


def test_single_csv_uses_sibling_meta(tmp_path):
    make_dataset(tmp_path / "ds", n_exp=2, meta={"material": "m", "physics": {"p8": 9e4}})
    ds = load_dataset(tmp_path / "ds" / "exp_002.csv")
    assert ds.format == "csv" and ds.names == ["exp_002"] and ds.p8 == 9e4 and ds.material == "m"


def test_single_csv_without_meta(tmp_path):
    t, R, _ = record()
    write_csv(tmp_path / "one.csv", t, R)
    ds = load_dataset(tmp_path / "one.csv")
    assert ds.names == ["one"] and ds.meta == {} and ds.material == "unknown"


def test_meta_json_path_means_directory(tmp_path):
    make_dataset(tmp_path / "ds", n_exp=2)
    assert load_dataset(tmp_path / "ds" / "meta.json").names == ["exp_001", "exp_002"]


def test_long_csv(tmp_path):
    rows = ["experiment,t_s,R_m"]
    truths = []
    for name, rmax in (("b", 300e-6), ("a", 350e-6)):
        t, R, tr = record(rmax_m=rmax)
        truths.append((name, t, R))
        rows += [f"{name},{x!r},{y!r}" for x, y in zip(t.tolist(), R.tolist())]
    rows.insert(5, "b,nan,1e-4")
    (tmp_path / "long.csv").write_text("\n".join(rows) + "\n")
    ds = load_dataset(tmp_path / "long.csv")
    assert ds.format == "long-csv" and ds.names == ["b", "a"]
    for (_name, t, R), e in zip(truths, ds.experiments):
        assert np.array_equal(e.t_s, t) and np.array_equal(e.R_m, R)
    assert any("dropped 1 row" in w and "line 6" in w for w in ds.warnings)


def test_csv_column_order_free_and_nan_rows_dropped(tmp_path):
    t, R, _ = record()
    lines = ["R_m,t_s"] + [f"{r!r},{x!r}" for x, r in zip(t.tolist(), R.tolist())]
    lines[3] = "NaN,NaN"
    lines[7] = f",{float(t[6])!r}"
    (tmp_path / "ds").mkdir()
    (tmp_path / "ds" / "e.csv").write_text("\n".join(lines) + "\n")
    (tmp_path / "ds" / "meta.json").write_text('{"material": "m"}')
    ds = load_dataset(tmp_path / "ds")
    e = ds.experiments[0]
    assert e.n_samples == len(t) - 2
    assert any("dropped 2 row(s)" in w and "line 4, 8" in w for w in ds.warnings)


def test_camera_filter_on_names(tmp_path):
    d = tmp_path / "ds"
    make_dataset(d, n_exp=2)
    for p in sorted(d.glob("*.csv")):
        (d / (p.stem + "_cam0deg.csv")).write_bytes(p.read_bytes())
        p.rename(d / (p.stem + "_cam90deg.csv"))
    ds = load_dataset(d)
    assert len(ds.experiments) == 4 and any("not independent" in w for w in ds.warnings)
    ds0 = load_dataset(d, camera="cam0deg")
    assert ds0.names == ["exp_001_cam0deg", "exp_002_cam0deg"]
    with pytest.raises(InputError, match="cameras found: cam0deg, cam90deg"):
        load_dataset(d, camera="cam45deg")


@needs_shared
@pytest.mark.parametrize(
    "folder",
    [
        "estrada2018_stiffPA_270kfps",
        "estrada2018_stiffPA_xy002_refit",
        "franck_lab_A_E2_002_1.59Mfps",
        "umich_PA10_bis0.06_1Mfps_dualcam",
    ],
)
def test_shared_datasets_load(folder):
    ds = load_dataset(LIC / folder)
    meta = json.loads((LIC / folder / "meta.json").read_text())
    assert len(ds.experiments) == len(meta["experiments"])
    for e, m in zip(ds.experiments, meta["experiments"]):
        assert e.n_samples == m["n_samples"]
        assert _rel(e.R_m.max(), m["Rmax_sample_m"]) < 1e-10


@needs_shared
@pytest.mark.parametrize(
    "folder",
    [
        "estrada2018_stiffPA_270kfps",
        "estrada2018_stiffPA_xy002_refit",
        "franck_lab_A_E2_002_1.59Mfps",
        "umich_PA10_bis0.06_1Mfps_dualcam",
    ],
)
def test_no_measured_maximum_is_taken_as_exact(folder):
    """Every real record's Rmax and time of the maximum reach the fits with a positive uncertainty
    (a nuisance prior sd of 0 means 'known'): three stiff-PA bubbles fall back to the three-point
    parabola, whose time once had none (bubble 18's fit then sat in a wrong basin)."""
    from imrbayes.data import preprocess_dataset
    from imrbayes.ensemble import Observations

    ds = load_dataset(LIC / folder, camera="cam0deg" if folder.startswith("umich") else None)
    pre = preprocess_dataset(ds, skip_failed=True)
    obs = Observations.from_preprocessed(pre)
    sd = np.asarray(obs.nuisance_sd)
    assert sd.shape == (len(pre.experiments), 3)
    assert np.all(sd[:, :2] > 0), [e.name for e, s in zip(pre.experiments, sd) if not np.all(s[:2] > 0)]
    methods = {e.rmax_method for e in pre.experiments}
    if folder == "estrada2018_stiffPA_270kfps":
        assert "parabola" in methods  # the fallback is exercised on real data
        tc = np.array([e.tc_s for e in pre.experiments])
        fb = np.array([e.rmax_method == "parabola" for e in pre.experiments])
        assert np.all((sd[fb, 1] > 0.005) & (sd[fb, 1] < 0.05)), sd[fb, 1]  # t*: a fraction of a frame to ~2
        assert np.all(np.isfinite(tc))


# ``imrbayes inspect``: outputs, and one test per class of bad input (interfaces.md §1): exit status
# 2, one line on stderr naming the file, no traceback, the user's files unchanged.


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


# Fuzzing the loaders, preprocessing and ``inspect``: whatever the input, either success or an
# InputError (exit status 2, one line, no traceback) - never another exception.


FUZZ = settings(max_examples=120, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)


def load_and_process(path):
    """True on success, False on InputError; any other exception fails the test."""
    try:
        preprocess_dataset(load_dataset(path))
        return True
    except InputError as exc:
        assert str(exc) and "\n" not in str(exc)
        return False


def in_dataset(write):
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp) / "ds"
        d.mkdir()
        (d / "meta.json").write_text('{"material": "fuzz"}')
        write(d)
        before = {p.name: p.read_bytes() for p in d.iterdir()}
        ok_dir = load_and_process(d)
        csvs = sorted(d.glob("*.csv")) + sorted(d.glob("*.mat"))
        ok_file = [load_and_process(p) for p in csvs]
        after = {p.name: p.read_bytes() for p in d.iterdir()}
        assert before == after  # nothing the user gave is modified
        return ok_dir, ok_file


# ----------------------------------------------------------------------------- raw bytes
@FUZZ
@given(data=st.binary(max_size=3000), header=st.booleans())
def test_random_bytes_csv(data, header):
    prefix = b"t_s,R_m\n" if header else b""
    in_dataset(lambda d: (d / "x.csv").write_bytes(prefix + data))


@FUZZ
@given(data=st.binary(max_size=3000), header=st.sampled_from([b"", b"MATLAB 5.0 MAT-file" + b" " * 97 + b"\x00\x01IM"]))
def test_random_bytes_mat(data, header):
    in_dataset(lambda d: (d / "x.mat").write_bytes(header + data))


# ----------------------------------------------------------------------------- odd CSVs
NUM = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.floats(min_value=-1e-3, max_value=1e-3).map(repr),
    st.integers(min_value=-(10**30), max_value=10**400).map(str),
    st.sampled_from(
        [
            "",
            "nan",
            "NaN",
            "NA",
            "inf",
            "-inf",
            "1e-400",
            "1e400",
            "1_000",
            "0x10",
            " 1e-4 ",
            '"1e-5"',
            "1,5",
            "١٢",
            "1e",
            ".",
            "-",
            "+.5e-3",
            "null",
        ]
    ),
    st.text(max_size=8),
)
HEADERS = st.sampled_from(
    [
        "t_s,R_m",
        "R_m,t_s",
        "experiment,t_s,R_m",
        "t_s,R_m,",
        "t_s",
        "t_s;R_m",
        "\ufefft_s,R_m",
        "T_S,R_M",
        "t_s , R_m",
        "t_s,R_m,t_s",
        "",
    ]
)


@FUZZ
@given(header=HEADERS, rows=st.lists(st.lists(NUM, min_size=0, max_size=4), max_size=40))
def test_odd_csv(header, rows):
    text = header + "\n" + "\n".join(",".join(r) for r in rows) + "\n"
    if _encodable(text):
        in_dataset(lambda d: (d / "x.csv").write_text(text, encoding="utf-8"))


def _encodable(text):
    try:
        text.encode("utf-8")
        return True
    except UnicodeEncodeError:
        return False


# ----------------------------------------------------------------------------- plausible records, extreme values
@FUZZ
@given(
    log_rmax=st.floats(-8.0, -1.0),
    log_tfac=st.floats(-3.0, 3.0),
    n=st.one_of(st.integers(1, 400), st.integers(60, 400), st.integers(60, 400)),
    q=st.one_of(st.floats(0.0, 1.2), st.floats(0.05, 0.5), st.floats(0.05, 0.5)),
    tc=st.floats(0.01, 5.0),
    noise=st.sampled_from([0.0, 0.0, 1e-3, 1e-3, 0.05, 0.5]),
    seed=st.integers(0, 2**16),
    start=st.floats(-1.0, 0.5),
    end=st.floats(0.1, 5.0),
    n_exp=st.integers(1, 3),
    offset=st.sampled_from([0.0, 1e-6, 1e3, -5.0]),
)
def test_extreme_records(log_rmax, log_tfac, n, q, tc, noise, seed, start, end, n_exp, offset):
    """Realistic-to-absurd sizes, durations, sampling, noise and clock offsets."""
    rng = np.random.default_rng(seed)
    rmax = 10.0**log_rmax
    tscale = rmax / math.sqrt(101325 / 1064) * 10.0 ** (log_tfac if seed % 2 else 0.0)

    def write(d):
        for i in range(n_exp):
            ts = np.sort(rng.uniform(start, start + end, n))
            R = rmax * (curve(ts, q=q, tc=tc) + noise * rng.standard_normal(n))
            lines = ["t_s,R_m"] + [f"{t * tscale + offset!r},{r!r}" for t, r in zip(ts.tolist(), R.tolist())]
            (d / f"e{i}.csv").write_text("\n".join(lines) + "\n")

    in_dataset(write)


@FUZZ
@given(
    rmax=st.floats(1e-5, 1e-3),
    n=st.integers(40, 400),
    q=st.floats(0.05, 0.5),
    tc=st.floats(0.6, 1.3),
    noise=st.floats(0.0, 0.02),
    seed=st.integers(0, 2**16),
    start=st.floats(-0.5, 0.0),
    end=st.floats(2.0, 5.0),
    n_exp=st.integers(1, 4),
)
def test_plausible_records(rmax, n, q, tc, noise, seed, start, end, n_exp):
    """Noisy, unevenly sampled but plausible records: mostly loadable; never a crash."""
    rng = np.random.default_rng(seed)
    tscale = rmax / math.sqrt(101325 / 1064)

    def write(d):
        for i in range(n_exp):
            ts = np.unique(rng.uniform(start, start + end, n))
            R = rmax * np.abs(curve(ts, q=q, tc=tc) + noise * rng.standard_normal(ts.size)) + 1e-9
            lines = ["t_s,R_m"] + [f"{t * tscale!r},{r!r}" for t, r in zip(ts.tolist(), R.tolist())]
            (d / f"e{i}.csv").write_text("\n".join(lines) + "\n")

    in_dataset(write)


# ----------------------------------------------------------------------------- .mat files with layout-like variables
ARR = st.one_of(
    st.integers(0, 3).flatmap(lambda k: st.just(np.full((1, k), 1.0))),
    st.tuples(st.integers(1, 30), st.integers(1, 4), st.floats(-1e3, 1e3), st.integers(0, 1000)).map(
        lambda a: np.random.default_rng(a[3]).uniform(0, abs(a[2]) + 1e-9, (a[0], a[1]))
    ),
    st.just(np.array([[np.nan, 0.0, 1.0]])),
    st.just(np.array(["text"])),
    st.just(np.zeros((2, 2, 2))),
)


@FUZZ
@given(
    vars_=st.dictionaries(
        st.sampled_from(
            ["t", "R", "Req", "tloc1", "Rnew", "deltax", "deltat", "Rmax", "shift_normRnew", "PolyAcry_1", "other"]
        ),
        ARR,
        max_size=5,
    )
)
def test_fuzz_mat_layouts(vars_):
    def write(d):
        scipy.io.savemat(d / "f.mat", vars_)

    in_dataset(write)


@FUZZ
@given(
    rows=st.integers(5, 200),
    seed=st.integers(0, 10**6),
    scale=st.sampled_from([1.0, 1e-6, 1e6]),
    nan_rows=st.integers(0, 10),
)
def test_fuzz_umich_like_mat(rows, seed, scale, nan_rows):
    rng = np.random.default_rng(seed)
    t = np.arange(rows) * 1e-6
    A = np.column_stack(
        [t, scale * 250 * curve(t / 25e-6 - 0.3) + rng.normal(0, 2, rows), scale * 250 * curve(t / 25e-6 - 0.3)]
    )
    A[:nan_rows, 1:] = np.nan
    in_dataset(lambda d: scipy.io.savemat(d / "PolyAcry_00_00_00.mat", {"PolyAcry_00_00_00": A}))


# ----------------------------------------------------------------------------- meta.json
JSON = st.recursive(
    st.none() | st.booleans() | st.floats() | st.integers() | st.text(max_size=5),
    lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=5), c, max_size=3),
    max_leaves=10,
)
META = st.fixed_dictionaries(
    {},
    optional={
        "material": JSON,
        "physics": st.dictionaries(st.sampled_from(["rho", "p8", "P8", "c8", "x"]), JSON),
        "forward": JSON,
        "experiments": st.one_of(
            JSON,
            st.dictionaries(
                st.sampled_from(["e0.csv", "e0", "zz"]),
                st.dictionaries(st.sampled_from(["Req_m", "Req_sd_m", "k"]), JSON),
            ),
        ),
    },
)


@FUZZ
@given(meta=st.one_of(META, JSON))
def test_fuzz_meta(meta):
    t = np.linspace(-0.3, 3.3, 120)

    def write(d):
        (d / "meta.json").write_text(json.dumps(meta))
        (d / "e0.csv").write_text(
            "t_s,R_m\n" + "\n".join(f"{a * 4e-5!r},{b * 4e-4!r}" for a, b in zip(t.tolist(), curve(t).tolist()))
        )

    in_dataset(write)


# ----------------------------------------------------------------------------- the command
@settings(max_examples=25, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(header=HEADERS, rows=st.lists(st.lists(NUM, min_size=2, max_size=2), max_size=30), good=st.booleans())
def test_fuzz_inspect_command(header, rows, good):
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp) / "ds"
        d.mkdir()
        (d / "meta.json").write_text('{"material": "fuzz"}')
        if good:
            t = np.linspace(-0.3, 3.3, 100)
            rows = rows + [[repr(a * 4e-5), repr(b * 4e-4)] for a, b in zip(t.tolist(), curve(t).tolist())]
        text = header + "\n" + "\n".join(",".join(r) for r in rows) + "\n"
        if not _encodable(text):
            return
        (d / "x.csv").write_text(text)
        res = CliRunner().invoke(main, ["inspect", str(d), "--out", str(Path(tmp) / "out")])
        assert res.exit_code in (0, 2), (res.exit_code, res.stderr, res.exception)
        assert "Traceback" not in res.stderr and "Traceback" not in res.output
        if res.exit_code == 2:
            assert len(res.stderr.strip().splitlines()) == 1 and "x.csv" in res.stderr
