"""Quadratic-law neo-Hookean Kelvin-Voigt, strain stiffening (IMRv2 stress 2): G, mu, alpha.

alpha = 0 is NHKV. p = [G/p8, 1/Re, alpha].
"""

import numpy as np
from numba import njit

from imrbayes.forward.constitutive.base import ConstitutiveModel, Parameter, inv_re

N_AUX = 0


@njit(cache=True, error_model="numpy")
def stress(R, Rdot, z, p, req, zdot):
    rs = req / R
    ur = Rdot / R
    a = p[2]
    ic = p[0]
    S = (3.0 * a - 1.0) * 0.5 * ic * (5.0 - rs ** 4 - 4.0 * rs) - 4.0 * p[1] * ur \
        + 2.0 * a * ic * (27.0 / 40.0 + rs ** 8 / 8.0 + rs ** 5 / 5.0 + rs * rs - 2.0 / rs)
    Sdot = ur * (3.0 * a - 1.0) * 0.5 * ic * (4.0 * rs ** 4 + 4.0 * rs) + 4.0 * p[1] * ur * ur \
        - 2.0 * a * ic * ur * (rs ** 8 + rs ** 5 + 2.0 * rs * rs + 2.0 / rs)
    return S, Sdot, 4.0 * p[1]


@njit(cache=True, error_model="numpy")
def dissipation_q(x, y, p):
    return 1.0 + p[2] * (x ** 4 / y ** 4 + 2.0 * y * y / (x * x) - 3.0)


def _nondim(theta, *, rho, p8, uc, rmax_m):
    return np.stack([theta[..., 0] / p8, inv_re(theta[..., 1], rho=rho, uc=uc, rmax_m=rmax_m),
                     theta[..., 2]], axis=-1)


MODEL = ConstitutiveModel(
    name="qkv", description="quadratic-law (strain-stiffening) neo-Hookean Kelvin-Voigt (G, mu, alpha)",
    parameters=(Parameter("G", "Pa", 7.29e3, description="shear modulus"),
                Parameter("mu", "Pa s", 0.088, description="viscosity"),
                Parameter("alpha", "-", 0.25, positive=False, description="strain-stiffening coefficient")),
    n_aux=N_AUX, module=__name__, imrv2_stress=2, _nondim=_nondim)
