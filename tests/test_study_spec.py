"""``imrbayes study``: bad study files and short forms end in one line and exit status 2."""

from pathlib import Path

import pytest
from click.testing import CliRunner

from imrbayes.cli import main


def _dataset(root: Path, name: str) -> Path:
    d = root / name
    d.mkdir()
    (d / "exp_001.csv").write_text("t_s,R_m\n0,1e-4\n")
    return d


def _run(args):
    res = CliRunner().invoke(main, ["study", *map(str, args)])
    return res.exit_code, res.output.strip()


def _one_line_error(code, text, *needles):
    assert code == 2, text
    assert len(text.splitlines()) == 1 and text.startswith("imrbayes: error:"), text
    for n in needles:
        assert n in text, text


def test_missing_dataset(tmp_path):
    _dataset(tmp_path, "a")
    f = tmp_path / "s.toml"
    f.write_text('[[dataset]]\ndata = "a"\nlabels = {c = 1}\n[[dataset]]\ndata = "nowhere"\nlabels = {c = 2}\n')
    _one_line_error(*_run([f, "--out", tmp_path / "o"]), str(f), "nowhere", "does not exist")


def test_label_on_one_dataset_only(tmp_path):
    _dataset(tmp_path, "a"), _dataset(tmp_path, "b")
    f = tmp_path / "s.toml"
    f.write_text('[[dataset]]\ndata = "a"\nlabels = {c = 1, lab = "UT"}\n[[dataset]]\ndata = "b"\nlabels = {c = 2}\n')
    _one_line_error(*_run([f, "--out", tmp_path / "o"]), "'lab'", "missing on dataset(s) b")


def test_two_datasets_with_one_name(tmp_path):
    _dataset(tmp_path, "a"), _dataset(tmp_path, "b")
    f = tmp_path / "s.toml"
    f.write_text(
        '[[dataset]]\nname = "x"\ndata = "a"\nlabels = {c = 1}\n[[dataset]]\nname = "x"\ndata = "b"\nlabels = {c = 2}\n'
    )
    _one_line_error(*_run([f, "--out", tmp_path / "o"]), "two datasets are named 'x'")


@pytest.mark.parametrize(
    "text, needle",
    [
        ("", "no [[dataset]]"),
        ('[[dataset]]\ndata = "a"\ncolour = 1\n', "unknown key(s) ['colour']"),
        ('methods = ["nope"]\n[[dataset]]\ndata = "a"\n', "unknown method(s) ['nope']"),
        ('seed = -1\n[[dataset]]\ndata = "a"\n', "seed must be a non-negative integer"),
        ("[[dataset]\n", "not valid TOML"),
    ],
)
def test_other_bad_files(tmp_path, text, needle):
    _dataset(tmp_path, "a")
    f = tmp_path / "s.toml"
    f.write_text(text)
    _one_line_error(*_run([f, "--out", tmp_path / "o"]), needle)
    assert not (tmp_path / "o").exists()  # refused before anything is written


def test_short_form_label_count(tmp_path):
    a, b = _dataset(tmp_path, "a"), _dataset(tmp_path, "b")
    _one_line_error(*_run([a, b, "--label", "c=1,2,3", "--out", tmp_path / "o"]), "--label", "3 value(s) for 2")


def test_short_form_same_folder_names(tmp_path):
    (tmp_path / "x").mkdir(), (tmp_path / "y").mkdir()
    a, b = _dataset(tmp_path / "x", "data"), _dataset(tmp_path / "y", "data")
    _one_line_error(*_run([a, b, "--label", "c=1,2", "--out", tmp_path / "o"]), "two datasets are named 'data'")


def test_out_holding_other_files(tmp_path):
    a, b = _dataset(tmp_path, "a"), _dataset(tmp_path, "b")
    (tmp_path / "o").mkdir()
    (tmp_path / "o" / "notes.txt").write_text("mine")
    _one_line_error(*_run([a, b, "--label", "c=1,2", "--out", tmp_path / "o"]), "holds files but no study")
