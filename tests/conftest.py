"""Shared fixtures."""

import _fake_forward
import pytest


@pytest.fixture
def fake(monkeypatch):
    """The fake forward model (tests/_fake_forward.py) in place of the real one; yields its call log."""
    return _fake_forward.install(monkeypatch)


def pytest_sessionstart(session):
    """Compile every model's forward kernel first, one child per CPU: on an empty kernel cache (a
    fresh CI machine) the first compiles take ~1 CPU-minute each, and run one after the other by
    the tests that first need them while the other core idles."""
    from imrbayes.forward.codegen import precompile

    precompile()
