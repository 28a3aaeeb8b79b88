"""Neo-Hookean Kelvin-Voigt (IMRv2 stress 1): the baseline model, parameters G [Pa], mu [Pa s]."""

import numpy as np
from numba import njit

from imrbayes.forward.constitutive.base import ConstitutiveModel, Parameter, inv_re

N_AUX = 0


@njit(cache=True, error_model="numpy")
def stress(R, Rdot, z, p, req, zdot):
    rs = req / R
    rs4 = rs * rs * rs * rs
    ur = Rdot / R
    S = -4.0 * p[1] * ur - 0.5 * p[0] * (5.0 - 4.0 * rs - rs4)
    Sdot = -2.0 * p[0] * ur * (rs + rs4) + 4.0 * p[1] * ur * ur
    return S, Sdot, 4.0 * p[1]


@njit(cache=True, error_model="numpy")
def dissipation_q(x, y, p):
    return 1.0


def _nondim(theta, *, rho, p8, uc, rmax_m):
    return np.stack([theta[..., 0] / p8, inv_re(theta[..., 1], rho=rho, uc=uc, rmax_m=rmax_m)], axis=-1)


MODEL = ConstitutiveModel(
    name="nhkv",
    description="neo-Hookean Kelvin-Voigt solid (shear modulus G, viscosity mu)",
    parameters=(Parameter("G", "Pa", 7.29e3, description="shear modulus"),
                Parameter("mu", "Pa s", 0.088, description="viscosity")),
    n_aux=N_AUX, module=__name__, imrv2_stress=1, _nondim=_nondim)
