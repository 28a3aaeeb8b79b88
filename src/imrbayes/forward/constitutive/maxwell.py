"""Linear Maxwell (lambda2 = 0) or Jeffreys (lambda2 > 0) liquid: IMRv2 stress 3 with G = 0.

Parameters mu [Pa s], lambda1 [s], lambda2 [s].
"""

import numpy as np

from imrbayes.forward.constitutive.base import ConstitutiveModel, Parameter, inv_re
from imrbayes.forward.constitutive.zener import dissipation_q, stress  # noqa: F401

N_AUX = 1


def _nondim(theta, *, rho, p8, uc, rmax_m):
    lam1 = theta[..., 1]
    mu = theta[..., 0]
    return np.stack([np.zeros_like(mu), inv_re(mu, rho=rho, uc=uc, rmax_m=rmax_m),
                     lam1 * uc / rmax_m, theta[..., 2] / lam1], axis=-1)


MODEL = ConstitutiveModel(
    name="maxwell", description="linear Maxwell / Jeffreys liquid (mu, lambda1, lambda2)",
    parameters=(Parameter("mu", "Pa s", 0.088, description="viscosity"),
                Parameter("lambda1", "s", 1e-6, description="relaxation time"),
                Parameter("lambda2", "s", 0.0, positive=False, description="retardation time",
                          prior_sd=5e-7)),
    n_aux=N_AUX, module=__name__, imrv2_stress=3, _nondim=_nondim)
