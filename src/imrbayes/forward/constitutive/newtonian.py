"""Newtonian viscous liquid (IMRv2 stress 1 with G = 0): parameter mu [Pa s]."""

import numpy as np

from imrbayes.forward.constitutive.base import ConstitutiveModel, Parameter, inv_re
from imrbayes.forward.constitutive.nhkv import dissipation_q, stress  # noqa: F401  (same equations, G = 0)

N_AUX = 0


def _nondim(theta, *, rho, p8, uc, rmax_m):
    mu = theta[..., 0]
    return np.stack([np.zeros_like(mu), inv_re(mu, rho=rho, uc=uc, rmax_m=rmax_m)], axis=-1)


MODEL = ConstitutiveModel(
    name="newtonian", description="Newtonian liquid (viscosity mu)",
    parameters=(Parameter("mu", "Pa s", 0.088, description="viscosity"),),
    n_aux=N_AUX, module=__name__, imrv2_stress=1, _nondim=_nondim)
