"""Fuzzing the options of ``fit``, ``diagnose`` and ``validate``: whatever the values, the command
either accepts them or stops with one line ``imrbayes: error: ...`` and exit status 2 - never a
traceback, never another status. The computation itself is replaced by a stub that is reached
only when every option was accepted (the fits are tested elsewhere), so the budget is seconds."""

from __future__ import annotations

import tempfile
from pathlib import Path

import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings, strategies as st

from imrbayes.cli import main

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
