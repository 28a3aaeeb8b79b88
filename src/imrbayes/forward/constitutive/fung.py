"""Fung-type exponential strain stiffening, Kelvin-Voigt: G [Pa], mu [Pa s], alpha [-].

Strain energy W = G/(2 alpha) (exp(alpha (I1 - 3)) - 1), I1 = 2 lam^2 + lam^-4 (lam = r/r0, the
hoop stretch of an incompressible shell). The elastic part of the stress integral is
S_e = -(2 G/p8) int_{u_w}^{1} exp(alpha (2/u^2 + u^4 - 3)) (1 + u^3) du with u = 1/lam and
u_w = Req/R (32-point Gauss-Legendre, 1e-8 relative up to lam = 7, alpha = 0.08; exact for alpha = 0, where it is neo-Hookean). Its rate
has the closed form S_e' = -(2G/p8) exp(alpha (I1_w - 3)) (lam_w^-2 + lam_w^-5) Rdot/Req.
p = [G/p8, 1/Re, alpha]; alpha = 0 is NHKV.
"""

import numpy as np
from numba import njit

from imrbayes.forward.constitutive.base import ConstitutiveModel, Parameter
from imrbayes.forward.constitutive.qkv import MODEL as QKV  # same parameters, same scaling

N_AUX = 0
_X, _W = np.polynomial.legendre.leggauss(32)


@njit(cache=True, error_model="numpy")
def stress(R, Rdot, z, p, req, zdot):
    a = p[2]
    uw = req / R
    half = 0.5 * (1.0 - uw)
    mid = 0.5 * (1.0 + uw)
    acc = 0.0
    for k in range(_X.shape[0]):
        u = mid + half * _X[k]
        acc += _W[k] * np.exp(a * (2.0 / (u * u) + u ** 4 - 3.0)) * (1.0 + u * u * u)
    ur = Rdot / R
    S = -2.0 * p[0] * half * acc - 4.0 * p[1] * ur
    i1w = 2.0 / (uw * uw) + uw ** 4
    Sdot = -2.0 * p[0] * np.exp(a * (i1w - 3.0)) * (uw * uw + uw ** 5) * Rdot / req + 4.0 * p[1] * ur * ur
    return S, Sdot, 4.0 * p[1]


@njit(cache=True, error_model="numpy")
def dissipation_q(x, y, p):
    return 1.0


MODEL = ConstitutiveModel(
    name="fung", description="Fung-type exponential strain-stiffening Kelvin-Voigt solid (G, mu, alpha)",
    parameters=(Parameter("G", "Pa", 7.29e3, description="small-strain shear modulus"),
                Parameter("mu", "Pa s", 0.088, description="viscosity"),
                Parameter("alpha", "-", 0.05, positive=False, description="exponential stiffening coefficient")),
    n_aux=N_AUX, module=__name__, imrv2_stress=None, _nondim=QKV.nondimensionalise)
