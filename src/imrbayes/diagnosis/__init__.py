"""``imrbayes diagnose``: is a constant-parameter NHKV adequate, and if not, which mechanism?

>>> d = diagnose(obs, ForwardOptions(bubble="polytropic"), settings=DiagnoseSettings.quick())
>>> d.result["cause"]

Modules: :mod:`phases` (collapses from the measured minima), :mod:`models` (baseline and
candidates), :mod:`lsq` (joint MAP + Laplace fits), :mod:`check` (bootstrap-calibrated check),
:mod:`heldout` (forecast, leave-one-experiment-out, ELPD), :mod:`run` (the decision),
:mod:`figures`, :mod:`report`. Decisions and evidence: docs/diagnosis.md.
"""

from imrbayes.diagnosis.models import CANDIDATES, MECHANISMS, make_candidate
from imrbayes.diagnosis.run import DiagnoseSettings, Diagnosis, diagnose

__all__ = ["diagnose", "DiagnoseSettings", "Diagnosis", "CANDIDATES", "MECHANISMS", "make_candidate"]
