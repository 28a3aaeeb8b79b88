"""The shared leaves: imrbayes.io (JSON, atomic writes, run folders), imrbayes.plotting, imrbayes.html."""

import json
import math

import numpy as np
import pytest

from imrbayes.errors import InputError
from imrbayes.html import is_png, write_page
from imrbayes.io import atomic_write, jsonable, new_run_dir, prepare_out, write_json
from imrbayes.plotting import figure, label, save, scale


def test_jsonable_plain_types():
    obj = {
        "a": np.float64(1.5),
        2: (np.int64(3), np.bool_(True)),
        "nan": math.nan,
        "inf": np.float32("inf"),
        "arr": np.array([[1.0, np.nan], [2.0, 3.0]]),
        "ints": np.arange(2),
        "s": "x",
        "none": None,
    }
    assert jsonable(obj) == {
        "a": 1.5,
        "2": [3, True],
        "nan": None,
        "inf": None,
        "arr": [[1.0, None], [2.0, 3.0]],
        "ints": [0, 1],
        "s": "x",
        "none": None,
    }
    out = jsonable(obj)
    assert type(out["a"]) is float and type(out["2"][0]) is int and type(out["2"][1]) is bool


def test_write_json_is_strict_and_atomic(tmp_path, monkeypatch):
    p = write_json(tmp_path / "x.json", {"v": np.nan, "t": (1, 2)})
    assert p.read_text() == '{\n "v": null,\n "t": [\n  1,\n  2\n ]\n}\n'
    assert json.loads(p.read_text()) == {"v": None, "t": [1, 2]}

    def boom(fh):
        fh.write(b"partial")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        atomic_write(p, boom)
    assert json.loads(p.read_text()) == {"v": None, "t": [1, 2]}  # the old file, whole
    assert sorted(q.name for q in tmp_path.iterdir()) == ["x.json"]  # no temporary left


def test_run_folders(tmp_path):
    a = new_run_dir("fit", "my data/1", base=tmp_path)
    assert a.parent == tmp_path and a.name.startswith("fit-my_data_1-") and not a.exists()
    assert prepare_out(a, "fit", "x").is_dir()
    with pytest.raises(InputError, match="data folder"):
        prepare_out(tmp_path, "fit", "x", protect=tmp_path)
    (tmp_path / "f").write_text("")
    with pytest.raises(InputError, match="not a directory"):
        prepare_out(tmp_path / "f", "fit", "x")


def test_plotting_and_page(tmp_path):
    assert (scale("G"), label("G")) == (1e-3, "G [kPa]")
    assert (scale("mu"), label("mu")) == (1.0, r"$\mu$ [Pa s]")
    assert (scale("alpha"), label("alpha")) == (1.0, "alpha")
    fig = figure(2.0, 1.5)
    fig.subplots().plot([0, 1], [0, 1])
    png = save(fig, tmp_path / "figs" / "a.png")
    assert is_png(png) and not is_png(tmp_path / "missing.png")
    page = write_page(tmp_path / "r.html", "t<1>", "<p>body</p>").read_text()
    assert page.startswith("<!doctype html>") and "<title>t&lt;1&gt;</title>" in page and "<p>body</p>" in page
