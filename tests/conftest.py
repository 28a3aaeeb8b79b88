"""Shared fixtures."""

import pytest

import _fake_forward


@pytest.fixture
def fake(monkeypatch):
    """The fake forward model (tests/_fake_forward.py) in place of the real one; yields its call log."""
    return _fake_forward.install(monkeypatch)
