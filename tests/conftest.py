"""Shared fixtures."""

import importlib.util
from pathlib import Path

import pytest

import _fake_forward

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def fake(monkeypatch):
    """The fake forward model (tests/_fake_forward.py) in place of the real one; yields its call log."""
    return _fake_forward.install(monkeypatch)


@pytest.fixture(scope="module")
def confusion_script():
    """scripts/diagnosis_confusion.py as a module (a script, not part of the package)."""
    spec = importlib.util.spec_from_file_location("diagnosis_confusion", ROOT / "scripts" / "diagnosis_confusion.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def pytest_sessionstart(session):
    """Compile every model's forward kernel first, one child per CPU: on an empty kernel cache (a
    fresh CI machine) the first compiles take ~1 CPU-minute each, and run one after the other by
    the tests that first need them while the other core idles."""
    from imrbayes.forward.codegen import precompile

    precompile()
