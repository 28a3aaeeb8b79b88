"""A fake forward model for CLI tests (fast, exact truth): R*(t*) = curve(t*, q=Req/Rmax, tc=0.9).
The ``fake`` fixture (conftest.py) installs it in place of ``imrbayes.forward.ForwardModel``."""

from types import SimpleNamespace

import numpy as np
from _data_synth import curve

from imrbayes.errors import ForwardModelError, InputError

CALLS = []


class FakeOptions:
    def __init__(self, d):
        self.d = dict(d)

    @classmethod
    def from_dict(cls, d, source="forward options"):
        if "bad" in d:
            raise InputError(source, "unknown forward option 'bad'")
        return cls(d)

    def to_dict(self):
        return {"radial": "km", **self.d}


class FakeModel:
    """R*(t*) = curve(t*, q=Req/Rmax, tc=0.9); fails when G < 0."""

    def __init__(self, name, options=None, physics_overrides=None):
        if name not in ("nhkv", "qkv"):
            raise InputError("--model", f"unknown constitutive model {name!r}")
        self.constitutive = SimpleNamespace(param_names=("G", "mu") if name == "nhkv" else ("G", "mu", "alpha"))
        self.options = options
        ph = {"rho": 1064.0, "p8": 101325.0, "c8": 1484.0}
        ph.update(physics_overrides or {})
        self.physics = SimpleNamespace(to_dict=lambda: dict(ph))

    def simulate_radius(self, params, rmax_m, req_m, t_star):
        CALLS.append((dict(params), rmax_m, req_m, np.array(t_star)))
        if params["G"] < 0:
            raise ForwardModelError("forward solve failed: fake")
        return curve(np.asarray(t_star), q=req_m / rmax_m, tc=0.9)


def install(monkeypatch) -> list:
    """Replace the forward model by the fake; returns the list its calls are recorded in."""
    import imrbayes.forward as fwd

    CALLS.clear()
    monkeypatch.setattr(fwd, "ForwardModel", FakeModel, raising=False)
    monkeypatch.setattr(fwd, "ForwardOptions", FakeOptions, raising=False)
    monkeypatch.setattr(fwd, "available_models", lambda: ["nhkv", "qkv"], raising=False)
    return CALLS
