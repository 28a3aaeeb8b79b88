"""``--help``: required options marked, defaults shown, the models and methods listed (not
"see the error"), and the expected runtime of the long commands."""

import re

import pytest
from click.testing import CliRunner

from imrbayes.cli import main
from imrbayes.ensemble import METHODS
from imrbayes.forward.constitutive.base import available_models


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
