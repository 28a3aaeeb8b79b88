"""Grid convergence of the bubble fields (the converged default vs IMRv2's fine grids), and the
compiled-kernel cache."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from imrbayes.forward import ForwardModel, ForwardOptions, reference

REF = Path(__file__).resolve().parents[1] / ".." / "shared" / "reference" / "imrv2"
needs_ref = pytest.mark.skipif(not (REF / "index.csv").exists(), reason="shared/reference absent")


def _converged(case, **kw):
    opts = {**case.model.options.__dict__, "scheme": "converged", "nt": None, "mt": None, "stretch": None, **kw}
    return ForwardModel(case.model.constitutive, options=ForwardOptions(**opts))


@needs_ref
@pytest.mark.parametrize("physics", ["therm_vap", "therm_vap_mass"])
def test_default_resolution_is_within_2e3_of_imrv2_200_point_grid(physics):
    """IMRv2's own 25-point answer is 9 % (L2) off its 200-point one with mass transfer; our
    default (wall-clustered, nt = 64) must be within 2e-3 of the 200-point reference, which
    itself carries ~1e-3 discretisation error."""
    case = reference.load_case(REF, f"lic_grid_nt200_{physics}")
    coarse = reference.load_case(REF, f"nhkv_km_{physics}_m0")
    ours = _converged(case).simulate(case.params, case.rmax_m, case.req_m, case.t_star)
    err = reference.relative_l2(ours.R_star[0], case.R_star)
    assert err < 2e-3, err
    assert err < 0.25 * reference.relative_l2(coarse.R_star, case.R_star)


def test_refinement_before_first_collapse_is_second_order():
    """Up to the first collapse the default scheme converges at second order (measured ratios
    4.8, 4.6, 4.3 for 16->32->64->128->256 points) and the default grid changes R* by < 5e-5
    when doubled."""
    t = np.arange(35) * 0.025
    base = ForwardModel("nhkv", options=ForwardOptions(rtol=1e-10, atol=1e-12))
    sols = {}
    for nt in (32, 64, 128):
        sols[nt] = base.with_options(nt=nt, mt=nt).simulate({"G": 7290.0, "mu": 0.088}, 263e-6, 263e-6 / 7.58,
                                                            t).R_star[0]
    d1 = np.max(np.abs(sols[64] - sols[32]))
    d2 = np.max(np.abs(sols[128] - sols[64]))
    assert d2 < 5e-5
    assert d1 / d2 > 3.0   # second order gives 4


@pytest.mark.xfail(strict=True, reason="known: past the first collapse the late-time phase converges "
                   "slowly (64 -> 128 points changes R by ~7e-4 relative L2); see docs/forward-model.md")
def test_refinement_over_three_collapses_changes_less_than_1e4():
    t = np.arange(121) * 0.025
    base = ForwardModel("nhkv", options=ForwardOptions(mass_transfer=False, rtol=1e-9, atol=1e-11))
    a = base.simulate({"G": 7290.0, "mu": 0.088}, 263e-6, 263e-6 / 7.58, t).R_star[0]
    b = base.with_options(nt=128, mt=128).simulate({"G": 7290.0, "mu": 0.088}, 263e-6, 263e-6 / 7.58, t).R_star[0]
    assert reference.relative_l2(a, b) < 1e-4


_SNIPPET = """
import json, numpy as np
from imrbayes.forward import ForwardModel, ForwardOptions
fm = ForwardModel("nhkv", options=ForwardOptions(bubble="polytropic"))
fm.simulate({"G": 7290.0, "mu": 0.088}, 263e-6, 263e-6 / 7.58, np.arange(3) * 0.025)
st = fm.kernel.integrate_batch.stats
print(json.dumps({"hits": sum(st.cache_hits.values()), "misses": sum(st.cache_misses.values())}))
"""


def test_compiled_kernel_is_cached_across_processes(tmp_path):
    env = {**os.environ, "IMRBAYES_CACHE_DIR": str(tmp_path), "NUMBA_CACHE_DIR": str(tmp_path)}
    runs = [json.loads(subprocess.run([sys.executable, "-c", _SNIPPET], env=env, capture_output=True, text=True,
                                      check=True).stdout.strip().splitlines()[-1]) for _ in range(2)]
    assert runs[0]["misses"] >= 1
    assert runs[1] == {"hits": 1, "misses": 0}
    assert len(list((tmp_path / "kernels").glob("imrbayes_kernel_nhkv_*.py"))) == 1
