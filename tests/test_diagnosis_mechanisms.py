"""imrbayes diagnose: hide an effect in synthetic polytropic data and require finding it.

Each dataset: 5 experiments, parameters drawn (seeded) from realistic ranges
(imrbayes.diagnosis.synthetic), paper noise times 0.5; quick settings (19 bootstrap replicates).
The full mechanisms x seeds confusion matrix is ``scripts/diagnosis_confusion.py`` (slow test below).
"""

import numpy as np
import pytest

from imrbayes.diagnosis import DiagnoseSettings, diagnose
from imrbayes.diagnosis.synthetic import synthetic_obs
from imrbayes.forward import ForwardOptions

OPTS = ForwardOptions(bubble="polytropic")
NOISE = 0.5


def _run(mechanism, seed, **kw):
    obs, truth = synthetic_obs(mechanism, seed, OPTS, noise_scale=NOISE)
    d = diagnose(obs, OPTS, settings=DiagnoseSettings.quick(loeo=False, **kw), seed=seed)
    return d.result, truth


def test_constant_nhkv_is_adequate():
    r, truth = _run("none", 11)
    assert r["constant_parameter_check"]["verdict"] == "adequate", r["constant_parameter_check"]["evidence"]["p_value"]
    assert r["cause"] == "none"
    assert r["extended_model"] is None
    est = r["baseline"]["estimate"]
    assert abs(np.log(est["G"]["median"] / truth["theta"]["G"])) < 0.5
    assert abs(np.log(est["mu"]["median"] / truth["theta"]["mu"])) < 0.5


@pytest.mark.parametrize("mechanism,seed", [("strain-stiffening", 3), ("damage-softening", 5)])
def test_hidden_mechanism_is_found(mechanism, seed):
    r, truth = _run(mechanism, seed)
    assert r["constant_parameter_check"]["verdict"] == "inadequate"
    assert r["cause"] == mechanism, [(c["mechanism"], c["score"]) for c in r["candidates"]]
    g = r["gain"]
    assert g["heldout_rmse_extended"] < g["heldout_rmse_baseline"]
    assert g["relative_reduction"] > 0
    assert g["elpd_diff"] > 0


@pytest.mark.slow
@pytest.mark.parametrize("mechanism,seed", [("viscoelastic-relaxation", 7), ("rate-dependent-viscosity", 9)])
def test_hidden_mechanism_is_found_more(mechanism, seed):
    r, truth = _run(mechanism, seed)
    assert r["cause"] == mechanism, [(c["mechanism"], c["score"]) for c in r["candidates"]]
    assert r["gain"]["relative_reduction"] > 0
