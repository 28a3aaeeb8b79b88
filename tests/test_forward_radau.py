"""The Radau IIA integrator (default for the thermal bubble in a cold medium): accuracy against an
independent integrator, the structured Jacobian against a dense finite-difference one, and its
option checks."""

import numpy as np
import pytest

from imrbayes.errors import InputError
from imrbayes.forward import ForwardModel, ForwardOptions
from imrbayes.forward.constants import group_matrix

RMAX, RATIO = 263e-6, 7.58
T = np.arange(121) * 0.025


def _batch(n=8, seed=3):
    rng = np.random.default_rng(seed)
    return {"G": 7290.0 * rng.uniform(0.6, 1.4, n), "mu": 0.088 * rng.uniform(0.6, 1.4, n)}


def test_radau_is_the_default_for_the_cold_thermal_bubble_only():
    assert ForwardOptions().method == "radau5"
    assert ForwardOptions(bubble="polytropic").method == "dop853"
    assert ForwardOptions(medium="warm").method == "ark548"
    with pytest.raises(InputError):
        ForwardOptions(integrator="radau5", medium="warm")
    with pytest.raises(InputError):
        ForwardOptions(integrator="radau5", bubble="polytropic")


@pytest.mark.parametrize("model", ["nhkv", pytest.param("zener", marks=pytest.mark.slow)])
def test_default_tolerance_is_within_1e4_of_an_independent_tight_solve(model):
    """The default Radau run against the ARK (IMEX) integrator at rtol 1e-10 over three collapses:
    two different integrators, so agreement is not a shared bias. Tight Radau and tight ARK agree
    to ~1e-8 (checked too). ARK's step count grows as 1/(wall cell), so this comparison runs on the
    previous default grid (stretch 1.5, nt 64): on the default grid (stretch 2.75, nt 96) tight ARK
    runs out of steps. There the default run is checked against tight Radau (measured 3.9e-5 on
    this batch; 1.1e-4 at one instant of the forward benchmark's 48 members, relative L2 2.5e-6)."""
    params = _batch()
    if model == "zener":
        params["lambda1"] = np.full(8, 1e-6)
    grid = dict(stretch=1.5, nt=64, mt=64)
    fm = ForwardModel(model, options=ForwardOptions(**grid))
    tight_ark = ForwardModel(model, options=ForwardOptions(integrator="ark548", rtol=1e-10, atol=1e-12, **grid))
    tight_radau = ForwardModel(model, options=ForwardOptions(integrator="radau5", rtol=1e-10, atol=1e-12, **grid))
    ref = tight_ark.simulate(params, RMAX, RMAX / RATIO, T)
    ours = fm.simulate(params, RMAX, RMAX / RATIO, T)
    tight = tight_radau.simulate(params, RMAX, RMAX / RATIO, T)
    assert not (ref.failed.any() or ours.failed.any() or tight.failed.any())
    assert np.max(np.abs(tight.R_star / ref.R_star - 1)) < 1e-7
    assert np.max(np.abs(ours.R_star / ref.R_star - 1)) < 1e-4
    # the point of Radau: far fewer steps than the IMEX scheme at the same tolerance
    ark = ForwardModel(
        model, options=ForwardOptions(integrator="ark548", rtol=fm.options.rtol, atol=fm.options.atol, **grid)
    ).simulate(params, RMAX, RMAX / RATIO, T)
    assert ours.n_steps.mean() < 0.4 * ark.n_steps.mean()
    # the default grid: default tolerance against tight Radau
    default = ForwardModel(model).simulate(params, RMAX, RMAX / RATIO, T)
    tight_default = ForwardModel(model, options=ForwardOptions(rtol=1e-10, atol=1e-12)).simulate(
        params, RMAX, RMAX / RATIO, T
    )
    assert not (default.failed.any() or tight_default.failed.any())
    assert np.max(np.abs(default.R_star / tight_default.R_star - 1)) < 1e-4


@pytest.mark.parametrize("mass_transfer", [True, False])
def test_structured_jacobian_equals_dense_finite_differences(mass_transfer):
    """blocks + U V^T built by the kernel reproduces every entry of a column-by-column FD Jacobian
    of the right-hand side, at a state inside the first collapse (where the coupling is strongest)."""
    fm = ForwardModel("nhkv", options=ForwardOptions(mass_transfer=mass_transfer))
    k = fm.kernel
    prm = {"G": np.array([7290.0]), "mu": np.array([0.088])}
    st = fm.propagate(fm.initial_state(RMAX, RMAX / RATIO), prm, 0.9).end
    y = st.y[0].copy()
    n = y.size
    g = group_matrix(fm.groups(st.rmax_m, st.req_m), 1)[0]
    pr = fm._parameter_table(prm, 1, st.rmax_m)[0, 0]
    flags, grid, mgrid, dense = fm._flags, fm._grid, fm._mgrid, fm._cols
    nt, mt = fm.nt, fm.mt
    bs = 2 if mass_transfer else 1
    m = nt - 1
    o1 = fm.layout()["kv"].start if mass_transfer else 3 + nt
    work, coef = np.zeros(7 * nt + 2 * mt + 2), np.zeros(2 * nt + mt + 1)
    f0 = np.zeros(n)
    k.rhs(0.9, y, g, pr, flags, grid, mgrid, f0, coef, work)
    nc = dense.size
    in_cols = np.zeros(n, dtype=bool)
    in_cols[dense] = True
    Jl, Jd, Ju = (np.zeros((m, bs, bs)) for _ in range(3))
    U = np.zeros((nc, n))
    vidx, vval, vcnt = np.zeros((nc, nc), dtype=np.int64), np.zeros((nc, nc)), np.zeros(nc, dtype=np.int64)
    kk = k._radau_jacobian(
        0.9,
        y,
        f0,
        g,
        pr,
        flags,
        grid,
        mgrid,
        dense,
        in_cols,
        o1,
        bs,
        m,
        Jl,
        Jd,
        Ju,
        U,
        vidx,
        vval,
        vcnt,
        np.zeros(n),
        np.zeros(n),
        coef,
        work,
    )
    J = np.zeros((n, n))
    offs = [3, o1][:bs]
    for i in range(m):
        for a in range(bs):
            for b in range(bs):
                J[offs[b] + i, offs[a] + i] += Jd[i, b, a]
                if i > 0:
                    J[offs[b] + i, offs[a] + i - 1] += Jl[i, b, a]
                if i + 1 < m:
                    J[offs[b] + i, offs[a] + i + 1] += Ju[i, b, a]
    for r in range(kk):
        for e in range(vcnt[r]):
            J[:, vidx[r, e]] += U[r] * vval[r, e]
    fd = np.zeros((n, n))
    fp = np.zeros(n)
    for j in range(n):
        yp = y.copy()
        yp[j] += 1.5e-8 * max(abs(y[j]), 1e-3)
        k.rhs(0.9, yp, g, pr, flags, grid, mgrid, fp, coef, work)
        fd[:, j] = (fp - f0) / (yp[j] - y[j])
    # the wall values are boundary data, not unknowns (their rates are identically zero): their
    # columns never enter the Newton iteration
    frozen = np.all(fd == 0, axis=1)
    walls = [3 + nt - 1] + ([o1 + nt - 1] if mass_transfer else [])
    assert list(np.nonzero(frozen)[0]) == walls
    live = np.ix_(~frozen, ~frozen)
    # entries of each row scaled by the row's largest entry: FD noise ~1e-7 of it (measured 8e-7)
    scale = np.abs(fd).max(axis=1, keepdims=True)[~frozen]
    assert np.max(np.abs(J[live] - fd[live]) / scale) < 1e-5
    assert kk == 4  # R, Rdot, p_b and one rank-one wall term (NHKV has no stress states)
