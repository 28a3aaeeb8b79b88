"""Zener model with the quadratic-law spring (IMRv2 stress 4): G, mu, alpha, lambda1, lambda2.

p = [G/p8, 1/Re, De, Lambda, alpha].
"""

import numpy as np
from numba import njit

from imrbayes.forward.constitutive.base import ConstitutiveModel, Parameter, inv_re
from imrbayes.forward.constitutive.zener import relax

N_AUX = 1


@njit(cache=True, error_model="numpy")
def stress(R, Rdot, z, p, req, zdot):
    rs = req / R
    a = p[4]
    ze = R ** 3 * ((3.0 * a - 1.0) * 0.5 * p[0] * (5.0 - rs ** 4 - 4.0 * rs)
                   + 2.0 * a * p[0] * (0.675 + 0.125 * rs ** 8 + 0.2 * rs ** 5 + rs * rs - 2.0 / rs))
    return relax(R, Rdot, z, ze, p, zdot)


@njit(cache=True, error_model="numpy")
def dissipation_q(x, y, p):
    return 1.0 + p[4] * (x ** 4 / y ** 4 + 2.0 * y * y / (x * x) - 3.0)


def _nondim(theta, *, rho, p8, uc, rmax_m):
    lam1 = theta[..., 3]
    return np.stack([theta[..., 0] / p8, inv_re(theta[..., 1], rho=rho, uc=uc, rmax_m=rmax_m),
                     lam1 * uc / rmax_m, theta[..., 4] / lam1, theta[..., 2]], axis=-1)


MODEL = ConstitutiveModel(
    name="qzener", description="Zener model with quadratic-law neo-Hookean spring (G, mu, alpha, lambda1, lambda2)",
    parameters=(Parameter("G", "Pa", 7.29e3, description="shear modulus"),
                Parameter("mu", "Pa s", 0.088, description="viscosity"),
                Parameter("alpha", "-", 0.25, positive=False, description="strain-stiffening coefficient"),
                Parameter("lambda1", "s", 1e-6, description="relaxation time"),
                Parameter("lambda2", "s", 0.0, positive=False, description="retardation time",
                          prior_sd=5e-7)),
    n_aux=N_AUX, module=__name__, imrv2_stress=4, _nondim=_nondim)
