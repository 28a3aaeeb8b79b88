"""No viscosity, no elasticity (IMRv2 stress 0): an inviscid liquid; no parameters."""

import numpy as np
from numba import njit

from imrbayes.forward.constitutive.base import ConstitutiveModel

N_AUX = 0


@njit(cache=True, error_model="numpy")
def stress(R, Rdot, z, p, req, zdot):
    return 0.0, 0.0, 0.0


@njit(cache=True, error_model="numpy")
def dissipation_q(x, y, p):
    return 0.0


def _nondim(theta, *, rho, p8, uc, rmax_m):
    return np.zeros(theta.shape[:-1] + (2,))


MODEL = ConstitutiveModel(name="none", description="inviscid liquid, no elasticity", parameters=(),
                          n_aux=N_AUX, module=__name__, imrv2_stress=0, _nondim=_nondim)
