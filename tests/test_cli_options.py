"""The command-line options shared by the commands: ``--config``, ``--experiments``, ``--out``,
``--help``, docs/cli.md, and fuzzing of the options."""

from __future__ import annotations

import dataclasses
import json
import re
import tempfile
from pathlib import Path

import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings, strategies as st
from test_data_simulate import BASE

from imrbayes.cli import main
from imrbayes.cli.docs import cli_markdown, field_docs
from imrbayes.cli.options import select_experiments
from imrbayes.data import load_dataset
from imrbayes.ensemble import METHODS
from imrbayes.errors import InputError
from imrbayes.forward.constitutive.base import available_models

# ``--config FILE.toml``: one loader (:func:`imrbayes.cli.read_config`) for every command; a
# command's table with its sub-tables (``[diagnose.forward]``) applied, a sub-table the command does
# not understand refused with one line naming the file and the key.


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


# ``--experiments`` (fit and diagnose): a subset of a dataset's records by 1-based position, chosen
# before preprocessing, so that the result is the one a dataset of only those files would give.


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


# ``--out`` never mixes or overwrites silently: a non-empty folder is refused unless ``--force``
# (or ``--resume`` for a run), and every command that writes a folder says so in one line.


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


# ``--help``: required options marked, defaults shown, the models and methods listed (not
# "see the error"), and the expected runtime of the long commands.


def _raw(*cmd):
    r = CliRunner().invoke(main, [*cmd, "--help"], terminal_width=100)
    assert r.exit_code == 0, r.output
    return r.output


def _help(*cmd):
    return " ".join(_raw(*cmd).split())  # one line: click wraps the help text


def _option(text, name):
    """The help of one option (``text``: the raw help): its first line to the next option's."""
    lines = text.splitlines()
    i = next(k for k, ln in enumerate(lines) if re.match(rf"\s+{re.escape(name)}\b", ln))
    j = next((k for k in range(i + 1, len(lines)) if re.match(r"\s+-", lines[k])), len(lines))
    return " ".join(" ".join(lines[i:j]).split())


def test_fit_help_marks_required_and_shows_defaults():
    raw, text = _raw("fit"), _help("fit")
    assert "[required]" in _option(raw, "--method")
    assert "[default: auto]" in _option(raw, "--noise")
    assert "[default: nhkv]" in _option(raw, "--model")
    assert "convergence" in _option(raw, "--mcmc") and "min on 2 cores" in _option(raw, "--mcmc")  # its cost
    assert "Runtime:" in text


@pytest.mark.parametrize("cmd", [("fit",), ("simulate",), ()])
def test_help_lists_models_and_methods(cmd):
    text = _help(*cmd)
    assert "see the error" not in text
    assert "Constitutive models (--model):" in text
    for name in available_models():
        assert f" {name} " in text, name
    assert "nhkv G [Pa], mu [Pa s]" in text
    if cmd != ("simulate",):
        assert "Inference methods (--method):" in text
        for m in METHODS.values():
            assert f"{m.name} {m.label}" in text, m.name


def test_long_commands_say_how_long():
    text = _help("diagnose")
    # measured runtimes, stated with their settings, not a promise
    assert re.search(r"Runtime \(measured on 2 cores\): 5 bubbles .*~\d+\s+min", text)
    assert "--no-loeo" in text and "--workers" in text
    top = _help()
    assert "Runtimes:" in top and "hours with the thermal bubble" in top


# docs/cli.md is generated from the code (``python -m imrbayes.cli.docs``): it must be current, and
# name every command, option and ``--set`` key; ``fit --help`` keeps ``--set`` to one line per method.


DOC = Path(__file__).resolve().parents[1] / "docs" / "cli.md"


def test_docs_cli_md_is_current():
    assert DOC.read_text(encoding="utf-8") == cli_markdown(), (
        "docs/cli.md is stale: regenerate it with `python -m imrbayes.cli.docs > docs/cli.md`"
    )


def test_docs_name_every_command_option_and_setting():
    text = cli_markdown()
    for name in main.list_commands(None):
        assert f"## `imrbayes {name}`" in text
        for prm in main.get_command(None, name).params:
            for opt in getattr(prm, "opts", []):
                if opt.startswith("--"):
                    assert f"`{opt}`" in text, (name, opt)
    for meth in METHODS.values():
        for f in dataclasses.fields(meth.settings_class):
            assert f"| `{f.name}` |" in text, (meth.name, f.name)


def test_field_docs_reads_defaults_and_attribute_docstrings():
    @dataclasses.dataclass
    class Toy:
        n_ens: int = 24
        """members per bubble"""
        #: window shift [samples]
        h: int = 5
        rtps: float = 0.7  # relaxation to prior spread

    assert field_docs(Toy) == [
        ("n_ens", "int", "24", "members per bubble"),
        ("h", "int", "5", "window shift [samples]"),
        ("rtps", "float", "0.7", "relaxation to prior spread"),
    ]


def test_fit_help_gives_set_one_line_per_method():
    out = CliRunner().invoke(main, ["fit", "--help"]).output
    block = out[out.index("--set KEY=VALUE") : out.index("--prior")]
    lines = [ln for ln in block.splitlines() if ln.strip()]
    assert "docs/cli.md" in block
    assert len(lines) <= len(METHODS) + 3, block
    for name in METHODS:
        assert sum(ln.strip().startswith(f"{name}:") for ln in lines) == 1, (name, block)


# Fuzzing the options of ``fit``, ``diagnose`` and ``validate``: whatever the values, the command
# either accepts them or stops with one line ``imrbayes: error: ...`` and exit status 2 - never a
# traceback, never another status. The computation itself is replaced by a stub that is reached
# only when every option was accepted (the fits are tested elsewhere), so the budget is seconds.


FUZZ = settings(max_examples=100, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)


class Reached(Exception):
    """The stub stands where the computation would start: every option was accepted."""


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    d = tmp_path_factory.mktemp("fuzz") / "data"
    res = CliRunner().invoke(
        main,
        [
            "simulate",
            "--model",
            "nhkv",
            "--param",
            "G=7e3",
            "--param",
            "mu=0.09",
            "--n-exp",
            "2",
            "--t-end",
            "2.0",
            "--forward",
            "bubble=polytropic",
            "--out",
            str(d),
            "--quiet",
        ],
    )
    assert res.exit_code == 0, res.output
    return d


@pytest.fixture(scope="module")
def stubs():
    """Replace the methods, the diagnosis and the validation suite by :class:`Reached`, after the
    method settings are checked as the real ones check them."""
    import imrbayes.diagnosis as diagnosis
    import imrbayes.validation as validation
    from imrbayes.ensemble import METHODS

    saved = (dict(METHODS), diagnosis.diagnose, validation.run_suite)

    def stub_for(cls):
        def fit(fm, obs, space, s, **kw):
            try:
                s.check(obs.n_samples - 1)
            except TypeError:
                s.check()
            raise Reached()

        return fit

    for name, meth in list(METHODS.items()):
        cls = meth.settings_class
        fit = stub_for(cls) if hasattr(cls, "check") else (lambda *a, **k: (_ for _ in ()).throw(Reached()))
        METHODS[name] = type(meth.__name__, (meth,), {"fit": staticmethod(fit)})
    diagnosis.diagnose = lambda *a, **k: (_ for _ in ()).throw(Reached())
    validation.run_suite = lambda *a, **k: (_ for _ in ()).throw(Reached())
    yield
    METHODS.clear()
    METHODS.update(saved[0])
    diagnosis.diagnose, validation.run_suite = saved[1], saved[2]


def check(args):
    with tempfile.TemporaryDirectory() as tmp:
        res = CliRunner().invoke(main, [str(a) for a in args] + ["--out", str(Path(tmp) / "out")])
    text = res.output  # stdout and stderr, as a terminal shows them
    # first: no exception escaped the command (CliRunner gives any escaped one exit status 1); if one
    # did -- a programming error above all -- the failure names it
    assert res.exception is None or isinstance(res.exception, SystemExit), repr(res.exception)
    assert "Traceback" not in text, text
    # nor was one caught and printed as a status-1 line (the CLI's catch-all): whatever the options,
    # a programming error is never how the command ends
    internal = ("AssertionError", "TypeError", "KeyError", "AttributeError", "IndexError")
    assert not any(f"imrbayes: error: {name}:" in text for name in internal), text
    if res.exit_code == 1:
        assert "Reached" in text, text  # the only status-1 path: the stubbed computation
    else:
        assert res.exit_code in (0, 2), (res.exit_code, text, res.exception)
    if res.exit_code == 2:
        errors = [ln for ln in text.splitlines() if ln.startswith("imrbayes: error:")]
        assert len(errors) == 1 and len(errors[0]) > len("imrbayes: error: "), text
    return res.exit_code


_word = st.text(alphabet=st.characters(codec="utf-8", exclude_categories=("Cs", "Cc")), max_size=12)
_number = st.one_of(st.integers(-5, 10**6).map(str), st.floats(allow_nan=True, allow_infinity=True).map(repr), _word)
_scheduler = st.one_of(st.none(), st.just("localhost"), _word.filter(lambda s: "://" not in s and s.strip() != "local"))
_common = {
    "--seed": st.one_of(st.integers(-3, 2**40).map(str), _word),
    "--workers": st.one_of(st.integers(-2, 3).map(str), _word),
    "--scheduler": _scheduler,
    "--forward": st.one_of(
        st.sampled_from(
            [
                "bubble=polytropic",
                "bubble=thermal",
                "nt=3",
                "scheme=imrv2-fd",
                "radial=km",
                "radial=xx",
                "nt=-1",
                "bogus=1",
                "bubble",
            ]
        ),
        _word,
    ),
}
_flags = st.lists(st.sampled_from(["--resume", "--retry-failed", "--quiet"]), unique=True, max_size=3)


def _options(draw, table):
    args = []
    for opt, strat in table.items():
        if draw(st.integers(0, 2)) == 0:  # a third of the options at a time: some runs get through
            val = draw(strat)
            if val is not None:
                args += [opt, val]
    return args + draw(_flags)


_settings = {
    "imr": ["n_G", "n_mu", "G_max", "mu_max", "window", "weighting", "level", "n_draws"],
    "pimr": ["n_G", "n_mu", "kappa"],
    "en4dvar": ["n_ens", "n_iter", "n_runs", "rtps", "t_end", "fusion", "n_draws", "loglik"],
    "mienks": ["n_ens", "n_iter", "L", "h", "rtps", "obs_weight", "fusion", "n_draws", "bogus"],
}


@st.composite
def fit_args(draw):
    method = draw(st.sampled_from(["imr", "pimr", "en4dvar", "mienks", "bogus"]))
    args = ["fit", "DATA", "--method", method] + _options(
        draw,
        {
            **_common,
            "--model": st.sampled_from(["nhkv", "qkv", "zener", "bogus"]),
            "--dt-star": _number,
            "--n-steps": st.one_of(st.integers(-2, 400).map(str), _word),
            "--noise": st.sampled_from(["auto", "sample", "paper", "bogus"]),
            "--prior": st.one_of(st.sampled_from(["G=6e3:2e3", "mu=0.1:0", "G=-1:1", "G=1", "x=1:1"]), _word),
            "--camera": _word,
            "--experiments": st.one_of(st.sampled_from(["1", "1,2", "0", "2-1", "1-2", "a"]), _word),
        },
    )
    for _ in range(draw(st.integers(0, 3))):
        key = draw(st.sampled_from(_settings.get(method, ["n_ens"])))
        args += ["--set", f"{key}={draw(_number)}"]
    return args


@st.composite
def diagnose_args(draw):
    return (
        ["diagnose", "DATA"]
        + _options(
            draw,
            {
                **_common,
                "--n-bootstrap": st.one_of(st.integers(-2, 50).map(str), _word),
                "--candidates": st.one_of(st.sampled_from(["qkv", "qkv,zener", "nhkv", "", "damage,x"]), _word),
                "--experiments": st.one_of(st.sampled_from(["1", "1,2", "0", "3", "a"]), _word),
                "--dt-star": _number,
                "--n-steps": st.one_of(st.integers(-2, 400).map(str), _word),
            },
        )
        + draw(st.lists(st.sampled_from(["--quick", "--no-loeo"]), unique=True))
    )


@st.composite
def validate_args(draw):
    args = ["validate"] + _options(draw, {**_common, "--suite": st.sampled_from(["quick", "full", "x"])})
    for _ in range(draw(st.integers(0, 2))):
        args += ["--case", draw(st.sampled_from(["imr-recovery", "fusion-linear-gaussian", "nope"]))]
    return args


def _with_data(args, dataset):
    return [str(dataset) if a == "DATA" else a for a in args]


@FUZZ
@given(args=fit_args())
def test_fit_options(dataset, stubs, args):
    check(_with_data(args, dataset))


@FUZZ
@given(args=diagnose_args())
def test_diagnose_options(dataset, stubs, args):
    check(_with_data(args, dataset))


@FUZZ
@given(args=validate_args())
def test_validate_options(stubs, args):
    check(args)


def test_stubs_are_reached(dataset, stubs):
    """The fuzz is meaningful: plain options get through to the computation."""
    assert check(["fit", dataset, "--method", "mienks", "--set", "n_ens=8"]) == 1
    assert check(["diagnose", dataset, "--quick"]) == 1
    assert check(["validate", "--case", "imr-recovery"]) == 1
