"""Loaders: dataset directories, single and long CSVs, meta.json, the four IMR .mat layouts."""

import glob
import json
from pathlib import Path

import numpy as np
import pytest
import scipy.io
from _data_synth import LIC, make_dataset, record, write_csv

from imrbayes.data import load_dataset
from imrbayes.data.csvio import read_table
from imrbayes.data.loaders import load_mat
from imrbayes.errors import InputError

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
