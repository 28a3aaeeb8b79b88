"""``imrbayes diagnose``: is a constant-parameter NHKV adequate, and if not, which mechanism?

>>> d = diagnose(obs, ForwardOptions(bubble="polytropic"), settings=DiagnoseSettings.quick())
>>> d.result["cause"]

Modules: :mod:`candidates` (the candidate mechanisms: one declaration each, one registry),
:mod:`phases` (collapses from the measured minima), :mod:`models` (a candidate on a forward model),
:mod:`lsq` (joint MAP + Laplace fits), :mod:`check` (bootstrap-calibrated check), :mod:`heldout`
(forecast, leave-one-experiment-out, ELPD), :mod:`run` (the decision), :mod:`synthetic` (data with
a hidden mechanism), :mod:`figures`, :mod:`report`. Decisions and evidence: docs/methods.md.
"""

from imrbayes.diagnosis.candidates import BASELINE, CANDIDATES, DEFAULT_CANDIDATES, MECHANISMS, CandidateSpec

__all__ = [
    "diagnose",
    "DiagnoseSettings",
    "Diagnosis",
    "make_candidate",
    "CandidateSpec",
    "BASELINE",
    "CANDIDATES",
    "DEFAULT_CANDIDATES",
    "MECHANISMS",
]

# The registry is imported eagerly (the command line lists the candidates at start-up); the fits
# pull in scipy and arviz (~4 s), so they load on first use.
_LAZY = {"diagnose": "run", "DiagnoseSettings": "run", "Diagnosis": "run", "make_candidate": "models"}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f"imrbayes.diagnosis.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'imrbayes.diagnosis' has no attribute {name!r}")
