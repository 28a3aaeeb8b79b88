"""``--experiments`` (fit and diagnose): a subset of a dataset's records by 1-based position, chosen
before preprocessing, so that the result is the one a dataset of only those files would give."""

import json

import pytest
from click.testing import CliRunner
from test_data_simulate import BASE

from imrbayes.cli import main
from imrbayes.cli.options import select_experiments
from imrbayes.data import load_dataset
from imrbayes.errors import InputError


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    d = tmp_path_factory.mktemp("sel") / "data"
    res = CliRunner().invoke(
        main,
        [
            "simulate",
            *BASE,
            "--n-exp",
            "4",
            "--noise",
            "0.005",
            "--t-end",
            "2.0",
            "--forward",
            "bubble=polytropic",
            "--seed",
            "3",
            "--out",
            str(d),
            "--quiet",
        ],
    )
    assert res.exit_code == 0, res.output
    return d


def test_positions_and_ranges_keep_the_datasets_order(data):
    ds = load_dataset(data)
    names = [e.name for e in ds.experiments]
    assert select_experiments(ds, None) is ds and select_experiments(ds, " ") is ds
    sub = select_experiments(ds, "4,1-2")
    assert [e.name for e in sub.experiments] == [names[0], names[1], names[3]]
    assert any("kept experiments 4,1-2 of 4" in n for n in sub.notes)
    assert len(ds.experiments) == 4  # the original is untouched


@pytest.mark.parametrize(
    "spec, words",
    [
        ("0", "1..4"),
        ("2,5", "1..4"),
        ("3-1", "backwards"),
        ("a", "positions or ranges"),
        ("1-b", "positions or ranges"),
        (",", "no experiment"),
    ],
)
def test_bad_selections_say_what_is_wrong(data, spec, words):
    with pytest.raises(InputError, match="--experiments") as exc:
        select_experiments(load_dataset(data), spec)
    assert words in str(exc.value) and "\n" not in str(exc.value)


def test_fit_on_a_subset_equals_a_fit_on_a_dataset_of_those_files(data, tmp_path):
    """pIMR (closed-form per experiment) on experiments 1 and 3 against a copy of the dataset that
    holds only those two files: the same numbers, because the selection happens before
    preprocessing (the across-experiment noise estimate sees the same records)."""
    import shutil

    ds = load_dataset(data)
    keep = [ds.experiments[0].name, ds.experiments[2].name]
    copy = tmp_path / "two"
    shutil.copytree(data, copy)
    for e in ds.experiments:
        if e.name not in keep:
            for f in copy.glob(f"{e.name}.*"):
                f.unlink()
    assert len(load_dataset(copy).experiments) == 2
    common = ["--method", "pimr", "--forward", "bubble=polytropic", "--quiet"]
    a = CliRunner().invoke(main, ["fit", str(data), "--experiments", "1,3", *common, "--out", str(tmp_path / "a")])
    b = CliRunner().invoke(main, ["fit", str(copy), *common, "--out", str(tmp_path / "b")])
    assert a.exit_code == 0 and b.exit_code == 0, a.output + b.output
    sa, sb = (json.loads((tmp_path / x / "summary.json").read_text()) for x in "ab")
    assert sa["n_experiments"] == 2 and [e["name"] for e in sa["per_experiment"]] == keep
    assert sa["estimate"] == sb["estimate"]
    assert json.loads((tmp_path / "a" / "run.json").read_text())["config"]["preprocessing"]["experiments"] == "1,3"


def test_a_bad_selection_is_one_line_and_exit_2(data, tmp_path):
    for cmd in ("fit", "diagnose"):
        extra = ["--method", "pimr"] if cmd == "fit" else []
        res = CliRunner().invoke(main, [cmd, str(data), *extra, "--experiments", "7", "--out", str(tmp_path / cmd)])
        assert res.exit_code == 2, res.output
        assert res.output.strip().count("\n") == 0 and "--experiments" in res.output and "1..4" in res.output
