"""Neo-Hookean elasticity with a shear-thinning Carreau viscosity (rate-dependent viscosity).

eta(s) = mu_inf + (mu - mu_inf) (1 + (lambda_c s)^2)^((n - 1)/2), s the local shear rate.
Around a spherical bubble s(r) = g (R/r)^3 with g = 2 sqrt(3) |Rdot|/R, and the viscous part of
the stress integral is S_v = -12 (Rdot/R) I(g), I(g) = (1/3) int_0^1 eta(g u) du (16-point
Gauss-Legendre, in units of rho Uc Rmax). Its time derivative carries Rddot with coefficient
J = 12 (I + g I'(g)) (= 4/Re for a Newtonian liquid). Parameters: G [Pa], mu (zero-shear
viscosity) [Pa s], mu_inf [Pa s], lambda_c [s], n [-]; n = 1 or lambda_c = 0 is NHKV.
p = [G/p8, mu/(rho Uc Rmax), mu_inf/(rho Uc Rmax), lambda_c Uc/Rmax, n].
"""

import math

import numpy as np
from numba import njit

from imrbayes.forward.constitutive.base import ConstitutiveModel, Parameter, inv_re

N_AUX = 0
_X, _W = np.polynomial.legendre.leggauss(16)
_U = 0.5 * (_X + 1.0)          # nodes on [0, 1]
_WU = 0.5 * _W


@njit(cache=True, error_model="numpy")
def _viscosity_integrals(g, p):
    """I(g) = (1/3) int_0^1 eta(g u) du and g I'(g) (dimensionless)."""
    e0 = p[1]
    einf = p[2]
    lc = p[3]
    n = p[4]
    I = 0.0
    gI = 0.0
    for k in range(_U.shape[0]):
        s = g * _U[k]
        q = 1.0 + (lc * s) ** 2
        eta = einf + (e0 - einf) * q ** (0.5 * (n - 1.0))
        deta = (e0 - einf) * (n - 1.0) * lc * lc * s * q ** (0.5 * (n - 3.0))
        I += _WU[k] * eta
        gI += _WU[k] * s * deta
    return I / 3.0, gI / 3.0


@njit(cache=True, error_model="numpy")
def stress(R, Rdot, z, p, req, zdot):
    rs = req / R
    rs4 = rs * rs * rs * rs
    ur = Rdot / R
    g = 2.0 * math.sqrt(3.0) * abs(ur)
    I, gI = _viscosity_integrals(g, p)
    S = -12.0 * ur * I - 0.5 * p[0] * (5.0 - 4.0 * rs - rs4)
    # d/dt of -12 (Rdot/R) I(g) without the Rddot part: -12 [-(Rdot/R)^2 I + (Rdot/R) I' dg/dt|_(Rddot=0)]
    # with dg/dt|_(Rddot=0) = -g Rdot/R, i.e. +12 ur^2 (I + g I').
    Sdot = -2.0 * p[0] * ur * (rs + rs4) + 12.0 * ur * ur * (I + gI)
    return S, Sdot, 12.0 * (I + gI)


@njit(cache=True, error_model="numpy")
def dissipation_q(x, y, p):
    return 1.0


def _nondim(theta, *, rho, p8, uc, rmax_m):
    return np.stack([theta[..., 0] / p8, inv_re(theta[..., 1], rho=rho, uc=uc, rmax_m=rmax_m),
                     inv_re(theta[..., 2], rho=rho, uc=uc, rmax_m=rmax_m), theta[..., 3] * uc / rmax_m,
                     theta[..., 4]], axis=-1)


MODEL = ConstitutiveModel(
    name="carreau", description="neo-Hookean solid with a shear-thinning Carreau viscosity (G, mu, mu_inf, lambda_c, n)",
    parameters=(Parameter("G", "Pa", 7.29e3, description="shear modulus"),
                Parameter("mu", "Pa s", 0.088, description="zero-shear viscosity"),
                Parameter("mu_inf", "Pa s", 0.0, positive=False, description="infinite-shear viscosity"),
                Parameter("lambda_c", "s", 1e-6, description="Carreau time constant"),
                Parameter("n", "-", 0.5, description="power-law index (< 1: shear thinning)")),
    n_aux=N_AUX, module=__name__, imrv2_stress=None, _nondim=_nondim)
