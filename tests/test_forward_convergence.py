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


@pytest.mark.xfail(strict=True, reason="known: at the default wall clustering the collapse's wall layer is "
                   "under-resolved (64 -> 128 points changes R by ~7e-4 relative L2); stretch=3 converges "
                   "(test below); see docs/forward-model.md")
def test_refinement_over_three_collapses_changes_less_than_1e4():
    t = np.arange(121) * 0.025
    base = ForwardModel("nhkv", options=ForwardOptions(mass_transfer=False, rtol=1e-9, atol=1e-11))
    a = base.simulate({"G": 7290.0, "mu": 0.088}, 263e-6, 263e-6 / 7.58, t).R_star[0]
    b = base.with_options(nt=128, mt=128).simulate({"G": 7290.0, "mu": 0.088}, 263e-6, 263e-6 / 7.58, t).R_star[0]
    assert reference.relative_l2(a, b) < 1e-4


def _lic(nt, stretch, **kw):
    fm = ForwardModel("nhkv", options=ForwardOptions(nt=nt, mt=nt, stretch=stretch, rtol=1e-8, atol=1e-10, **kw))
    out = fm.propagate(fm.initial_state(263e-6, 263e-6 / 7.58), {"G": 7290.0, "mu": 0.088}, 3.0,
                       np.arange(121) * 0.025, max_steps=20_000_000)
    assert not out.failed[0]
    return out.R_star[0]


def test_wall_clustered_grid_converges_over_three_collapses():
    """The cause of the slow late-time convergence: at each collapse the cold wall's thermal layer
    becomes thinner than the default grid's wall cell (the gas there is cold and at high pressure,
    so its diffusivity is small). With the wall cell ~10x finer (stretch 3) the refinement study
    is second order over all three collapses (measured 5.6e-4, 1.5e-4, 3.7e-5 for 32->64->128->256;
    frozen vapour) and the 128 -> 256 change is below the issue's 1e-4."""
    sols = {nt: _lic(nt, 3.0, mass_transfer=False) for nt in (64, 128, 256)}
    d1 = reference.relative_l2(sols[64], sols[128])
    d2 = reference.relative_l2(sols[128], sols[256])
    assert d2 < 1e-4, d2
    assert d1 / d2 > 3.0, (d1, d2)


@pytest.mark.slow
def test_mass_transfer_grid_limit_and_imrv2_uniform_grids_approach_it():
    """With vapour mass transfer (the default physics) the stretched grid converges too
    (stretch 3: 128->256->512 change 1.6e-4, 3.7e-5), and IMRv2's uniform grids approach the same
    limit, slowly (200/400/800 points: 6.9e-3, 5.0e-3, 3.0e-3): the 200-point references carry
    ~7e-3 discretisation error, not ~1e-3. Our default grid sits 5.3e-3 from the limit."""
    fine = {nt: _lic(nt, 3.0) for nt in (256, 512)}
    assert reference.relative_l2(fine[256], fine[512]) < 1e-4
    limit = fine[512]
    errs = []
    for nt in (200, 400, 800):
        fm = ForwardModel("nhkv", options=ForwardOptions(scheme="imrv2-fd", nt=nt, mt=nt, rtol=1e-8, atol=1e-10))
        R = fm.simulate({"G": 7290.0, "mu": 0.088}, 263e-6, 263e-6 / 7.58, np.arange(121) * 0.025,
                        max_steps=20_000_000).R_star[0]
        errs.append(reference.relative_l2(R, limit))
    assert errs[0] > errs[1] > errs[2]
    assert 5e-3 < errs[0] < 1e-2
    case = reference.load_case(REF, "lic_grid_nt200_therm_vap_mass") if (REF / "index.csv").exists() else None
    if case is not None:
        assert reference.relative_l2(np.interp(np.arange(121) * 0.025, case.t_star, case.R_star), limit) > 5e-3


_SNIPPET = """
import json, numpy as np
from imrbayes.forward import ForwardModel, ForwardOptions
fm = ForwardModel("nhkv", options=ForwardOptions(bubble="polytropic"))
out = fm.simulate({"G": np.array([3e3, 7e3]), "mu": np.array([0.05, 0.1])}, 263e-6, 263e-6 / 7.58, np.arange(121) * 0.025)
st = fm.kernel.integrate_batch_parallel.stats
print(json.dumps({"hits": sum(st.cache_hits.values()), "misses": sum(st.cache_misses.values()),
                  "R": out.R_star.tolist()}))
"""


def test_compiled_kernel_is_cached_across_processes(tmp_path):
    """The kernel is compiled once, in a child process, and every process -- the first included --
    runs numba's cached machine code, so two processes give bit-identical trajectories (numba's
    in-memory code after a fresh compile differed from the cached code in the last bits)."""
    env = {**os.environ, "IMRBAYES_CACHE_DIR": str(tmp_path), "NUMBA_CACHE_DIR": str(tmp_path)}
    runs = [json.loads(subprocess.run([sys.executable, "-c", _SNIPPET], env=env, capture_output=True, text=True,
                                      check=True).stdout.strip().splitlines()[-1]) for _ in range(2)]
    for run in runs:
        assert (run["hits"], run["misses"]) == (1, 0)
    assert runs[0]["R"] == runs[1]["R"]
    assert len(list((tmp_path / "kernels").glob("imrbayes_kernel_nhkv_*.py"))) == 1
    assert len(list((tmp_path / "kernels").glob("imrbayes_kernel_nhkv_*.compiled"))) == 1
