"""``--config FILE.toml``: one loader (:func:`imrbayes.cli.read_config`) for every command; a
command's table with its sub-tables (``[diagnose.forward]``) applied, a sub-table the command does
not understand refused with one line naming the file and the key."""

import json

import pytest
from click.testing import CliRunner

from imrbayes.cli import main


def _run(*args, expect=0):
    res = CliRunner().invoke(main, [str(a) for a in args])
    assert res.exit_code == expect, res.output
    return res


def _one_line_error(res, *needles):
    lines = res.stderr.strip().splitlines()
    assert res.exit_code == 2 and len(lines) == 1, res.output
    assert lines[0].startswith("imrbayes: error: ") and "Traceback" not in res.output
    for n in needles:
        assert n in lines[0], lines[0]


@pytest.fixture(scope="module")
def gel(tmp_path_factory):
    """Two polytropic bubbles (meta.json's forward block: bubble = polytropic)."""
    d = tmp_path_factory.mktemp("gel") / "data"
    _run(
        "simulate",
        "--model",
        "nhkv",
        "--param",
        "G=6e3",
        "--param",
        "mu=0.08",
        "--n-exp",
        "2",
        "--noise",
        "paper",
        "--forward",
        "bubble=polytropic",
        "--out",
        d,
        "--quiet",
    )
    return d


def test_read_config_gives_the_command_table_with_its_sub_tables(tmp_path):
    from imrbayes.cli import read_config

    cfg = tmp_path / "run.toml"
    cfg.write_text(
        '[fit]\nmethod = "imr"\nn-steps = 80\n[fit.forward]\nbubble = "polytropic"\n'
        "[prior]\nG = [6e3, 2e3]\n[simulate]\nn-exp = 2\n"
    )
    got = read_config(cfg, "fit", options={"method", "n_steps"}, tables={"forward", "prior"})
    # dashes read as underscores; a top-level table the command understands is used when its own lacks it
    assert got == {"method": "imr", "n_steps": 80, "forward": {"bubble": "polytropic"}, "prior": {"G": [6e3, 2e3]}}
    assert read_config(None, "fit", options=(), tables=()) == {}


@pytest.mark.parametrize(
    "text,needle",
    [
        ("[diagnose]\nseed = 1\n[diagnose.bogus]\nx = 1\n", "[diagnose.bogus]"),
        ("[diagnose]\nbogus = 1\n", "'bogus'"),
        ("[diagnose\n", "not valid TOML"),
    ],
)
def test_read_config_refuses_what_the_command_does_not_understand(tmp_path, text, needle):
    from imrbayes.cli import read_config
    from imrbayes.errors import InputError

    cfg = tmp_path / "run.toml"
    cfg.write_text(text)
    with pytest.raises(InputError, match="run.toml") as exc:
        read_config(cfg, "diagnose", options={"seed"}, tables={"forward"})
    assert needle in str(exc.value)


def test_simulate_sub_tables_are_applied_and_the_command_line_wins_per_key(tmp_path):
    cfg = tmp_path / "run.toml"
    cfg.write_text(
        '[simulate]\nmodel = "nhkv"\nn-exp = 1\nnoise = "none"\nt-end = 0.5\n'
        '[simulate.param]\nG = 4e3\nmu = 0.05\n[simulate.forward]\nbubble = "polytropic"\nvapor = false\n'
    )
    out = tmp_path / "d"
    _run("simulate", "--config", cfg, "--param", "G=5e3", "--out", out, "--quiet")
    truth = json.loads((out / "truth.json").read_text())
    assert truth["parameters"] == {"G": 5000.0, "mu": 0.05}
    assert truth["forward"]["bubble"] == "polytropic" and truth["forward"]["vapor"] is False


def test_diagnose_forward_sub_table_is_applied(gel, tmp_path):
    """[diagnose.forward] reaches the forward model: a bad value in it is refused (exit 2, naming it)
    before any solve (and before --out, a file here, is looked at); it used to be skipped silently."""
    cfg = tmp_path / "run.toml"
    cfg.write_text('[diagnose]\nquick = true\nquiet = true\n[diagnose.forward]\nbubble = "steam"\n')
    (tmp_path / "o").write_text("a file")
    res = CliRunner().invoke(main, ["diagnose", str(gel), "--config", str(cfg), "--out", str(tmp_path / "o")])
    _one_line_error(res, "bubble", "steam")


def test_validate_reads_its_table_and_forward_sub_table(tmp_path):
    cfg = tmp_path / "run.toml"
    cfg.write_text('[validate]\ncase = ["fusion-linear-gaussian"]\nquiet = true\n[validate.forward]\nvapor = false\n')
    out = tmp_path / "v"
    _run("validate", "--config", cfg, "--out", out)
    rep = json.loads((out / "validation.json").read_text())
    assert [c["name"] for c in rep["cases"]] == ["fusion-linear-gaussian"]
    assert rep["forward"]["options"]["vapor"] is False and rep["forward"]["options"]["bubble"] == "polytropic"


@pytest.mark.parametrize(
    "command,text,key",
    [
        ("simulate", '[simulate]\nmodel = "nhkv"\n[simulate.prior]\nG = 1\n', "[simulate.prior]"),
        ("diagnose", "[diagnose.bogus]\nx = 1\n", "[diagnose.bogus]"),
        ("fit", '[fit]\nmethod = "imr"\n[fit.bogus]\nx = 1\n', "[fit.bogus]"),
        ("inspect", "[inspect.forward]\nbubble = 'polytropic'\n", "[inspect.forward]"),
    ],
)
def test_a_sub_table_the_command_does_not_understand_is_one_line_naming_file_and_key(gel, tmp_path, command, text, key):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(text)
    (tmp_path / "o").write_text("a file")  # ignoring the table would end at --out, quickly
    args = (
        [command] + ([] if command == "simulate" else [str(gel)]) + ["--config", str(cfg), "--out", str(tmp_path / "o")]
    )
    _one_line_error(CliRunner().invoke(main, args), "bad.toml", key)


def test_a_sub_table_value_must_be_a_scalar(tmp_path):
    cfg = tmp_path / "bad.toml"
    cfg.write_text('[simulate]\nmodel = "nhkv"\n[simulate.forward]\nnt = [1, 2]\n')
    _one_line_error(CliRunner().invoke(main, ["simulate", "--config", str(cfg)]), "bad.toml", "forward.nt")
