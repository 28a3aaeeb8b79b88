"""Analytic limits and the ensemble API of the forward model."""

import math

import numpy as np
import pytest

from imrbayes.errors import InputError
from imrbayes.forward import RAYLEIGH_COLLAPSE_TIME, ForwardModel, ForwardOptions
from imrbayes.forward.constants import Physics
from imrbayes.forward.tableaux import TABLEAUX

LIC = dict(rmax_m=263e-6, req_m=263e-6 / 7.58)
NHKV = {"G": 7290.0, "mu": 0.088}


def test_rayleigh_constant():
    exact = math.sqrt(6 * math.pi) * math.gamma(11 / 6) / (5 * math.gamma(4 / 3))
    assert abs(RAYLEIGH_COLLAPSE_TIME - exact) < 1e-9
    assert round(exact, 4) == 0.9147


def test_empty_inviscid_incompressible_cavity_collapses_at_rayleigh_time():
    """Rayleigh-Plesset, no gas to speak of (Req = Rmax/1000), no vapour, no viscosity, no
    elasticity, no surface tension: R reaches 5 % of Rmax at t* = 0.9147 within 0.1 %
    (the remaining time to R = 0 scales as R^(5/2): ~2e-4 here)."""
    fm = ForwardModel(
        "none",
        options=ForwardOptions(radial="rp", bubble="polytropic", vapor=False, rtol=1e-10, atol=1e-12),
        physics=Physics.from_overrides({"surface_tension": 0.0}),
    )
    t = np.linspace(0.85, 0.9146, 4000)
    t = np.concatenate([[0.0], t])
    out = fm.simulate({}, 1e-4, 1e-7, t)
    R = out.R_star[0]
    assert not out.failed[0]
    k = np.nonzero(R < 0.05)[0][0]
    t_cross = np.interp(0.05, [R[k], R[k - 1]], [t[k], t[k - 1]])
    assert abs(t_cross / RAYLEIGH_COLLAPSE_TIME - 1) < 1e-3


@pytest.mark.parametrize(
    "options",
    [
        dict(bubble="polytropic", vapor=False),
        dict(bubble="polytropic", vapor=True),
        dict(bubble="thermal", vapor=True, mass_transfer=True),
        dict(bubble="thermal", vapor=True, mass_transfer=False, medium="warm"),
        dict(scheme="imrv2-fd", bubble="thermal", vapor=True, mass_transfer=True, medium="warm"),
    ],
)
def test_bubble_at_equilibrium_stays_at_rest(options):
    fm = ForwardModel("nhkv", options=ForwardOptions(**options))
    out = fm.simulate(NHKV, 50e-6, 50e-6, np.linspace(0, 3, 13))
    assert not out.failed[0]
    assert np.max(np.abs(out.R_star[0] - 1.0)) < 1e-7  # far below the integrator tolerance (1e-6)


@pytest.mark.parametrize("G", [0.0, 5e3, 2e4])
def test_small_oscillations_ring_at_linear_natural_frequency(G):
    """Undamped (mu = 0) Rayleigh-Plesset bubble, polytropic gas, surface tension and NHKV
    elasticity: omega^2 = (3 kappa p_g,eq - 2S/Req + 4G) / (rho Req^2), p_g,eq = p8 + 2S/Req."""
    ph = Physics()
    req = 40e-6
    eps = 1e-3
    rmax = req * (1 + eps)
    fm = ForwardModel(
        "nhkv", options=ForwardOptions(radial="rp", bubble="polytropic", vapor=False, rtol=1e-10, atol=1e-13)
    )
    pg = ph.p8 + 2 * ph.surface_tension / req
    omega = math.sqrt((3 * ph.kappa * pg - 2 * ph.surface_tension / req + 4 * G) / (ph.rho * req**2))
    period_star = 2 * math.pi / omega / (rmax / ph.velocity_scale)
    t = np.linspace(0, 12 * period_star, 6001)
    R = fm.simulate({"G": G, "mu": 0.0}, rmax, req, t).R_star[0] - req / rmax
    up = np.nonzero((R[:-1] < 0) & (R[1:] >= 0))[0]
    crossings = t[up] - R[up] * (t[up + 1] - t[up]) / (R[up + 1] - R[up])
    measured = np.mean(np.diff(crossings))
    assert len(crossings) >= 10
    assert abs(measured / period_star - 1) < 0.01


def test_batch_equals_members_and_failures_are_contained():
    fm = ForwardModel("nhkv", options=ForwardOptions(scheme="imrv2-fd"))
    t = np.arange(41) * 0.025
    G = np.array([3e3, 7.29e3, 1.5e4])
    mu = np.array([0.05, 0.088, 0.2])
    batch = fm.simulate({"G": G, "mu": mu}, LIC["rmax_m"], LIC["req_m"], t)
    serial = ForwardModel("nhkv", options=ForwardOptions(scheme="imrv2-fd"), parallel=False)
    np.testing.assert_array_equal(
        serial.simulate({"G": G, "mu": mu}, LIC["rmax_m"], LIC["req_m"], t).R_star, batch.R_star
    )
    for i in range(3):
        single = fm.simulate({"G": G[i], "mu": mu[i]}, LIC["rmax_m"], LIC["req_m"], t)
        np.testing.assert_array_equal(batch.R_star[i], single.R_star[0])
    state = fm.initial_state(LIC["rmax_m"], LIC["req_m"], n=3)
    state.y[1, 3] = np.nan  # a corrupted member
    state.y[2, 0] = -0.1  # an unphysical one
    out = fm.propagate(state, {"G": G, "mu": mu}, t[-1], t)
    assert out.failed.tolist() == [False, True, True]
    np.testing.assert_array_equal(out.R_star[0], batch.R_star[0])
    assert np.all(np.isnan(out.R_star[1:, 1:]))
    assert sum(out.failure_summary().values()) == 2


@pytest.mark.parametrize("options", [dict(scheme="imrv2-fd"), dict(bubble="polytropic")])
def test_state_handoff_continues_the_same_trajectory(options):
    """Propagating 0 -> 1.3 -> 3 with the evolved state handed on equals 0 -> 3."""
    fm = ForwardModel("zener", options=ForwardOptions(**options, rtol=1e-9, atol=1e-11))
    params = {"G": 7290.0, "mu": 0.088, "lambda1": 1e-6, "lambda2": 0.0}
    t = np.arange(121) * 0.025
    whole = fm.simulate(params, LIC["rmax_m"], LIC["req_m"], t)
    first = fm.propagate(fm.initial_state(LIC["rmax_m"], LIC["req_m"]), params, 1.3, t[t <= 1.3])
    second = fm.propagate(first.end, params, 3.0, t[t >= 1.3])
    joined = np.concatenate([first.R_star[0], second.R_star[0][1:]])
    np.testing.assert_allclose(joined, whole.R_star[0], rtol=2e-6)
    assert second.end.t_star == 3.0


def test_piecewise_parameters_equal_handoff_between_constant_segments():
    fm = ForwardModel("nhkv", options=ForwardOptions(scheme="imrv2-fd", rtol=1e-9, atol=1e-11))
    t = np.arange(121) * 0.025
    table = np.array([[[9e3, 0.12], [5e3, 0.07], [4e3, 0.06]]])  # (1 member, 3 pieces, 2 params)
    breaks = [0.9, 1.6]
    piecewise = fm.simulate(table, LIC["rmax_m"], LIC["req_m"], t, breaks_star=breaks)
    st = fm.initial_state(LIC["rmax_m"], LIC["req_m"])
    parts, edges = [], [0.0, 0.9, 1.6, 3.0]
    for k in range(3):
        grid = t[(t >= edges[k] - 1e-12) & (t <= edges[k + 1] + 1e-12)]
        out = fm.propagate(st, {"G": table[0, k, 0], "mu": table[0, k, 1]}, edges[k + 1], grid)
        parts.append(out.R_star[0] if k == 0 else out.R_star[0][1:] if np.isclose(grid[0], edges[k]) else out.R_star[0])
        st = out.end
    np.testing.assert_allclose(np.concatenate(parts), piecewise.R_star[0], rtol=1e-5)
    constant = fm.simulate(NHKV, LIC["rmax_m"], LIC["req_m"], t)
    assert np.max(np.abs(constant.R_star[0] - piecewise.R_star[0])) > 1e-2  # the pieces matter


@pytest.mark.parametrize("bubble", ["polytropic", "thermal"])
def test_per_member_break_times_equal_one_call_per_member(bubble):
    """(N, n_breaks) break times: each member switches parameters at its own times, exactly as
    if it were propagated alone with those breaks (bubbles collapse at different times)."""
    scheme = "imrv2-fd" if bubble == "thermal" else "converged"
    fm = ForwardModel("nhkv", options=ForwardOptions(bubble=bubble, scheme=scheme, rtol=1e-9, atol=1e-11))
    t = np.arange(121) * 0.025
    table = np.array([[[9e3, 0.12], [5e3, 0.07]], [[8e3, 0.10], [4e3, 0.05]], [[7e3, 0.09], [6e3, 0.08]]])
    breaks = np.array([[0.9], [1.2], [2.05]])
    batch = fm.simulate(table, LIC["rmax_m"], LIC["req_m"], t, breaks_star=breaks)
    assert not batch.failed.any()
    for m in range(3):
        alone = fm.simulate(table[m : m + 1], LIC["rmax_m"], LIC["req_m"], t, breaks_star=breaks[m])
        np.testing.assert_array_equal(alone.R_star[0], batch.R_star[m])
    shared = fm.simulate(table, LIC["rmax_m"], LIC["req_m"], t, breaks_star=[0.9])
    assert np.max(np.abs(shared.R_star[2] - batch.R_star[2])) > 1e-3  # the member's own breaks matter
    with pytest.raises(InputError):
        fm.simulate(table, LIC["rmax_m"], LIC["req_m"], t, breaks_star=np.zeros((2, 1)))
    with pytest.raises(InputError):
        fm.simulate(table[:, [0, 1, 1]], LIC["rmax_m"], LIC["req_m"], t, breaks_star=[[1.0, 0.5]] * 3)


def test_bad_inputs_are_refused():
    fm = ForwardModel("nhkv", options=ForwardOptions(bubble="polytropic"))
    with pytest.raises(InputError):
        fm.simulate({"G": 1e3, "bogus": 1.0}, 1e-4, 1e-5, [0, 1])
    with pytest.raises(InputError):
        fm.initial_state(1e-4, 2e-4)
    with pytest.raises(InputError):
        ForwardOptions(radial="nope")
    with pytest.raises(InputError):
        ForwardOptions.from_dict({"vapor": "maybe"})
    with pytest.raises(InputError):
        ForwardModel("not-a-model")
    assert ForwardOptions.from_dict({"bubble": "polytropic", "nt": "40", "vapor": "false"}).nt == 40


@pytest.mark.parametrize("name", sorted(TABLEAUX))
def test_runge_kutta_tableaux_satisfy_order_conditions(name):
    T = TABLEAUX[name]()
    c, b, order = T["c"], T["b"], 5 if name != "ark324" else 3
    mats = [T["AE"], T["AI"]] if T["gamma"] else [T["AE"]]
    for A in mats:
        np.testing.assert_allclose(A.sum(axis=1), c, atol=1e-14)
    conds = [(b.sum(), 1.0), (b @ c, 0.5), (b @ c**2, 1 / 3)]
    for A1 in mats:
        conds.append((b @ (A1 @ c), 1 / 6))
    if order >= 5:
        for A1 in mats:
            for A2 in mats:
                conds += [
                    (b @ c**3, 1 / 4),
                    (b @ (c * (A1 @ c)), 1 / 8),
                    (b @ (A1 @ c**2), 1 / 12),
                    (b @ (A1 @ A2 @ c), 1 / 24),
                    (b @ c**4, 1 / 5),
                    (b @ (c**2 * (A1 @ c)), 1 / 10),
                    (b @ ((A1 @ c) * (A2 @ c)), 1 / 20),
                    (b @ (A1 @ A2 @ c**2), 1 / 60),
                    (b @ (c * (A1 @ A2 @ c)), 1 / 30),
                    (b @ (A1 @ (c * (A2 @ c))), 1 / 40),
                ]
    for value, expected in conds:
        assert abs(value - expected) < 1e-13
    assert abs(T["bhat"].sum() - 1) < 1e-13 and abs(T["bhat"] @ c - 0.5) < 1e-13


@pytest.mark.parametrize("options", [{}, {"bubble": "polytropic"}, {"medium": "warm", "scheme": "imrv2-fd"}])
def test_state_is_valid_accepts_evolved_states_and_flags_unphysical_ones(options):
    fm = ForwardModel("nhkv", options=ForwardOptions(**options))
    start = fm.initial_state(LIC["rmax_m"], LIC["req_m"], n=4)
    end = fm.propagate(start, NHKV, 1.0).end
    assert fm.state_is_valid(start).all() and fm.state_is_valid(end).all()
    y = end.y.copy()
    y[0, 0] = -0.01  # negative radius
    y[1, 1] = np.nan
    if fm.options.thermal:
        y[2, 2] = -0.5  # negative bubble pressure
        y[3, fm.layout()["kv"].start if fm.options.mass_transfer else fm.layout()["theta"].start] = (
            1.5 if fm.options.mass_transfer else -1e6
        )  # vapour fraction > 1 / temperature < 0
    assert fm.state_is_valid(y).tolist() == [False, False] + [not fm.options.thermal] * 2
    why = fm.state_problems(y)  # each state fails the check it was built to fail
    assert why["radius"].tolist() == [True, False, False, False]
    assert why["non_finite"].tolist() == [False, True, False, False]
    if fm.options.thermal:
        assert why["pressure"].tolist() == [False, False, True, False]
        key = "vapour_fraction" if fm.options.mass_transfer else "temperature"
        assert why[key].tolist() == [False, False, False, True]
