"""Constitutive plug-ins: internal consistency of S, dS/dt and J, limits, and the quadratures."""

import importlib

import numpy as np
import pytest
from scipy.integrate import quad

from imrbayes.forward import ForwardModel, ForwardOptions, available_models, get_model

STATELESS = [m for m in available_models() if get_model(m).n_aux == 0]


def _p(name):
    model = get_model(name)
    theta = np.array([[model.defaults[k] if model.defaults[k] else 0.1 for k in model.param_names]])
    if name == "carreau":
        theta = np.array([[7.29e3, 0.088, 0.01, 2e-5, 0.4]])
    if name == "fung":
        theta = np.array([[7.29e3, 0.088, 0.08]])
    return model.nondimensionalise(theta, rho=1064.0, p8=101325.0, uc=9.7586, rmax_m=np.array([263e-6]))[0]


@pytest.mark.parametrize("name", STATELESS)
@pytest.mark.parametrize("R,U", [(0.8, -0.9), (0.05, -8.0), (0.3, 2.5), (0.13, 0.01)])
def test_rate_and_rddot_coefficient_are_the_derivatives_of_S(name, R, U):
    """For a model without memory S = S(R, Rdot): dS/dt = dS/dR Rdot + dS/dRdot Rddot, so the
    returned Sdot must equal dS/dR * Rdot and J must equal -R dS/dRdot."""
    mod = importlib.import_module(get_model(name).module)
    p = _p(name)
    req = 0.13
    z = np.zeros(0)
    S0, Sdot, J = mod.stress(R, U, z, p, req, z)
    h = 1e-6
    dSdR = (mod.stress(R * (1 + h), U, z, p, req, z)[0] - mod.stress(R * (1 - h), U, z, p, req, z)[0]) / (2 * R * h)
    dU = h * max(1.0, abs(U))
    dSdU = (mod.stress(R, U + dU, z, p, req, z)[0] - mod.stress(R, U - dU, z, p, req, z)[0]) / (2 * dU)
    scale = max(abs(Sdot), abs(dSdR * U), 1e-8)
    assert abs(Sdot - dSdR * U) < 1e-5 * scale
    assert abs(J + R * dSdU) < 1e-5 * max(abs(J), 1e-8)


WITH_MEMORY = [m for m in available_models() if get_model(m).n_aux > 0]


@pytest.mark.parametrize("name", WITH_MEMORY)
@pytest.mark.parametrize("R,U", [(0.8, -0.9), (0.05, -8.0), (0.3, 2.5)])
def test_consistent_j_and_rate_of_models_with_memory(name, R, U):
    """S = S(R, Rdot, z): dS/dt = dS/dR Rdot + dS/dz . zdot + dS/dRdot Rddot, so with the default
    ``zener_j=consistent`` (last entry of p = 1) Sdot must equal the first two terms and J must be
    -R dS/dRdot, as for the memoryless models; lambda2 = 0.3 lambda1 makes J differ from IMRv2's."""
    mod = importlib.import_module(get_model(name).module)
    model = get_model(name)
    theta = {k: (v if v else 0.1) for k, v in model.defaults.items()}
    theta.update({k: 3e-7 for k in ("lambda2",) if k in theta})
    p = model.nondimensionalise(
        np.array([[theta[k] for k in model.param_names]]), rho=1064.0, p8=101325.0, uc=9.7586, rmax_m=np.array([263e-6])
    )[0]
    req = 0.13
    z = np.linspace(0.02, -0.03, model.n_aux)
    for flag in (1.0, 0.0):
        pf = np.append(p, flag)
        zdot = np.zeros_like(z)
        S0, Sdot, J = mod.stress(R, U, z, pf, req, zdot)

        def S(r, u, zz):
            return mod.stress(r, u, zz, pf, req, np.zeros_like(zz))[0]

        h = 1e-6
        dSdR = (S(R * (1 + h), U, z) - S(R * (1 - h), U, z)) / (2 * R * h)
        dU = h * max(1.0, abs(U))
        dSdU = (S(R, U + dU, z) - S(R, U - dU, z)) / (2 * dU)
        dSdz = np.array([(S(R, U, z + h * e) - S(R, U, z - h * e)) / (2 * h) for e in np.eye(z.size)])
        expected = dSdR * U + dSdz @ zdot
        assert abs(Sdot - expected) < 1e-5 * max(abs(Sdot), abs(expected), 1e-8)
        if flag == 1.0 or name not in ("zener", "maxwell", "qzener"):
            assert abs(J + R * dSdU) < 1e-5 * max(abs(J), 1e-8)
        else:  # IMRv2's stress 3/4: J = 4/Re whatever Lambda
            assert J == pytest.approx(4.0 * p[1], rel=1e-12)
            assert abs(J + R * dSdU) > 0.5 * J


def test_zener_j_option_defaults_follow_the_scheme():
    assert ForwardOptions().j_mode == "consistent"
    assert ForwardOptions(scheme="imrv2-fd").j_mode == "imrv2"
    assert ForwardOptions(scheme="imrv2-fd", zener_j="consistent").j_mode == "consistent"
    assert ForwardOptions.from_dict({"zener-j": "IMRv2"}).to_dict()["zener_j"] == "imrv2"
    with pytest.raises(Exception, match="zener_j"):
        ForwardOptions(zener_j="exact")


def test_zener_j_is_irrelevant_at_lambda2_equal_lambda1_and_moves_the_curve_at_lambda2_zero():
    """Lambda = 1 makes both coefficients 4/Re (identical curves); at Lambda = 0 the compressible
    term differs, a change in R* of order 1e-2 (docs/methods.md: 2.7e-2 against PyIMR)."""
    t = np.linspace(0.0, 3.0, 61)
    out = {}
    for lam2 in (1e-6, 0.0):
        for mode in ("consistent", "imrv2"):
            fm = ForwardModel(
                "zener", options=ForwardOptions(bubble="polytropic", zener_j=mode, rtol=1e-10, atol=1e-12)
            )
            out[lam2, mode] = fm.simulate_radius(
                {"G": 7290.0, "mu": 0.088, "lambda1": 1e-6, "lambda2": lam2}, 263e-6, 263e-6 / 7.58, t
            )
    np.testing.assert_array_equal(out[1e-6, "consistent"], out[1e-6, "imrv2"])
    d = out[0.0, "consistent"] - out[0.0, "imrv2"]
    assert 3e-3 < np.linalg.norm(d) / np.linalg.norm(out[0.0, "imrv2"]) < 1e-1


def test_zener_tends_to_nhkv_as_lambda1_vanishes_only_with_the_consistent_coefficient():
    """lambda2 = 0, lambda1 -> 0: Z1 follows its slow manifold (elastic stress - 4/Re R^2 Rdot), whose
    rate already carries the viscous Rddot term, so the limit is NHKV with J = 0 added (consistent,
    error ~ lambda1) and NHKV with the viscous J counted twice with IMRv2's J = 4/Re."""
    t = np.linspace(0.0, 3.0, 61)
    opts = dict(bubble="polytropic", rtol=1e-9, atol=1e-11)
    mat = {"G": 5200.0, "mu": 0.065}
    nh = ForwardModel("nhkv", options=ForwardOptions(**opts)).simulate_radius(mat, 320e-6, 320e-6 / 7.9, t)

    def dist(lam1, mode):
        fm = ForwardModel("zener", options=ForwardOptions(**opts, zener_j=mode))
        z = fm.simulate_radius({**mat, "lambda1": lam1, "lambda2": 0.0}, 320e-6, 320e-6 / 7.9, t)
        return np.linalg.norm(z - nh) / np.linalg.norm(nh)

    coarse, fine = dist(3e-8, "consistent"), dist(1e-8, "consistent")
    assert fine < coarse / 2.5 and fine < 5e-3  # first order in lambda1 (measured 3.7e-3)
    assert dist(1e-8, "imrv2") > 2.0 * fine  # measured 9.7e-3: an offset that stays


def test_fung_elastic_integral_matches_hyperelastic_formula():
    """p_e = int_1^lam W'(lam)/(lam^3 - 1) dlam with W = G/(2a)(exp(a(I1-3)) - 1), I1 = 2lam^2 + lam^-4."""
    mod = importlib.import_module("imrbayes.forward.constitutive.fung")
    a, G = 0.08, 0.07
    for lam_w in (0.35, 0.9, 2.0, 7.0):

        def integrand(lam):
            i1 = 2 * lam**2 + lam**-4
            return 0.5 * G * np.exp(a * (i1 - 3)) * (4 * lam - 4 * lam**-5) / (lam**3 - 1)

        pe, _ = quad(integrand, 1.0, lam_w, limit=200)
        S, _, _ = mod.stress(1.0, 0.0, np.zeros(0), np.array([G, 0.0, a]), 1.0 / lam_w, np.zeros(0))
        assert abs(S + pe) < 1e-8 * max(1.0, abs(pe))


def test_carreau_viscosity_integral_matches_quadrature():
    mod = importlib.import_module("imrbayes.forward.constitutive.carreau")
    p = np.array([0.0, 0.03, 0.002, 0.05, 0.4])
    for g in (0.0, 0.5, 30.0, 400.0):
        eta = lambda s: p[2] + (p[1] - p[2]) * (1 + (p[3] * s) ** 2) ** ((p[4] - 1) / 2)
        ref = quad(lambda u: eta(g * u), 0, 1, limit=200)[0] / 3
        I, _ = mod._viscosity_integrals(g, p)
        assert abs(I - ref) < 2e-4 * ref


@pytest.mark.parametrize(
    "name,params",
    [
        ("fung", {"G": 7290.0, "mu": 0.088, "alpha": 0.0}),
        ("carreau", {"G": 7290.0, "mu": 0.088, "mu_inf": 0.0, "lambda_c": 1e-6, "n": 1.0}),
        ("qkv", {"G": 7290.0, "mu": 0.088, "alpha": 0.0}),
        ("kv", {"G": 0.0, "mu": 0.088}),
    ],
)
def test_extended_models_reduce_to_nhkv(name, params):
    opts = ForwardOptions(scheme="imrv2-fd", rtol=1e-9, atol=1e-11)
    t = np.arange(121) * 0.025
    base = {"G": params["G"], "mu": params["mu"]}
    ref = ForwardModel("nhkv", options=opts).simulate(base, 263e-6, 263e-6 / 7.58, t).R_star[0]
    ext = ForwardModel(name, options=opts).simulate(params, 263e-6, 263e-6 / 7.58, t).R_star[0]
    np.testing.assert_allclose(ext, ref, rtol=1e-6)


def test_shear_thinning_and_stiffening_change_the_dynamics():
    """Sanity of direction: a thinner liquid damps less (higher first rebound); a stiffer gel
    collapses earlier."""
    opts = ForwardOptions(bubble="polytropic")
    t = np.arange(121) * 0.025
    nh = ForwardModel("nhkv", options=opts).simulate({"G": 7290.0, "mu": 0.088}, 263e-6, 263e-6 / 7.58, t).R_star[0]
    thin = (
        ForwardModel("carreau", options=opts)
        .simulate({"G": 7290.0, "mu": 0.088, "mu_inf": 0.0, "lambda_c": 1e-5, "n": 0.3}, 263e-6, 263e-6 / 7.58, t)
        .R_star[0]
    )
    stiff = (
        ForwardModel("fung", options=opts)
        .simulate({"G": 7290.0, "mu": 0.088, "alpha": 0.3}, 263e-6, 263e-6 / 7.58, t)
        .R_star[0]
    )
    rebound = slice(38, 60)
    assert thin[rebound].max() > nh[rebound].max() + 0.01
    assert np.argmin(stiff[:45]) < np.argmin(nh[:45]) or stiff[30] < nh[30] - 1e-3
