"""``--out`` never mixes or overwrites silently: a non-empty folder is refused unless ``--force``
(or ``--resume`` for a run), and every command that writes a folder says so in one line."""

import json

from click.testing import CliRunner
from test_data_simulate import BASE

from imrbayes.cli import main


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_inspect_twice_into_one_folder_is_refused_then_forced(fake, tmp_path):
    data, out = tmp_path / "data", tmp_path / "insp"
    assert run("simulate", *BASE, "--noise", "none", "--n-exp", "2", "--out", data).exit_code == 0
    assert run("inspect", data, "--out", out).exit_code == 0
    first = (out / "dataset.json").read_text()
    again = run("inspect", data, "--out", out)
    assert again.exit_code == 2
    assert "--out" in again.output and "already holds" in again.output and "--force" in again.output
    assert (out / "dataset.json").read_text() == first  # nothing touched
    forced = run("inspect", data, "--out", out, "--force")
    assert forced.exit_code == 0 and json.loads((out / "dataset.json").read_text())


def test_simulate_into_a_folder_with_a_users_file_is_refused(fake, tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("my notes")
    res = run("simulate", *BASE, "--out", out)
    assert res.exit_code == 2 and "notes.txt" in res.output
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    assert run("simulate", *BASE, "--out", out, "--force").exit_code == 0
    assert (out / "notes.txt").read_text() == "my notes"  # --force replaces only its own names
    assert run("simulate", *BASE, "--out", out, "--force").exit_code == 2  # but never mixes two datasets


def test_fit_into_a_non_empty_folder_needs_force_or_resume(tmp_path):
    data, out = tmp_path / "data", tmp_path / "fit"
    out.mkdir()
    (out / "other.csv").write_text("t_s,R_m\n")
    assert (
        run(
            "simulate", *BASE, "--noise", "none", "--n-exp", "2", "--forward", "bubble=polytropic", "--out", data
        ).exit_code
        == 0
    )
    res = run("fit", data, "--method", "pimr", "--forward", "bubble=polytropic", "--out", out)
    assert res.exit_code == 2 and "already holds" in res.output and "other.csv" in res.output
    assert sorted(p.name for p in out.iterdir()) == ["other.csv"]


def test_an_empty_or_new_folder_needs_nothing(fake, tmp_path):
    (tmp_path / "empty").mkdir()
    assert run("simulate", *BASE, "--out", tmp_path / "empty").exit_code == 0
    assert run("simulate", *BASE, "--out", tmp_path / "new" / "deep").exit_code == 0
