"""Linear Maxwell-type model with a neo-Hookean spring (IMRv2 stress 3): Zener/SLS.

Parameters G [Pa], mu [Pa s], lambda1 (relaxation time) [s], lambda2 (retardation time) [s].
p = [G/p8, 1/Re, De = lambda1 Uc/Rmax, Lambda = lambda2/lambda1]. One auxiliary state Z1, zero at
t = 0 (IMRv2), so the elastic stress relaxes towards its neo-Hookean value over De.
J, the Keller-Miksis coefficient of Rddot, is the stress's instantaneous viscosity 4 Lambda/Re
(option ``zener_j=consistent``, the default) or IMRv2's 4/Re for every Lambda (``zener_j=imrv2``,
the default of the ``imrv2-fd`` scheme, for conformance; Oldroyd-B, IMRv2's stress 5, uses 4 Lambda/Re
in both codes). At Lambda = 0 the two differ by 2.7e-2 relative L2 in R* (docs/methods.md).
"""

import numpy as np
from numba import njit

from imrbayes.forward.constitutive.base import ConstitutiveModel, Parameter, inv_re

N_AUX = 1


@njit(cache=True, error_model="numpy")
def equilibrium_stress(R, rs, p):
    return -R ** 3 * 0.5 * p[0] * (5.0 - rs ** 4 - 4.0 * rs)


@njit(cache=True, error_model="numpy")
def relax(R, Rdot, z, ze, p, zdot):
    """Linear Maxwell-type relaxation of Z1 towards the elastic equilibrium ``ze`` (shared by the
    Zener-type models): returns (S, Sdot, J) and writes dZ1/dt. ``p[-1]`` selects J (module note)."""
    de = p[2]
    lam = p[3]
    zdot[0] = -(z[0] - ze) / de + 4.0 * (lam - 1.0) * p[1] / de * R * R * Rdot
    ur = Rdot / R
    S = z[0] / R ** 3 - 4.0 * lam * p[1] * ur
    Sdot = zdot[0] / R ** 3 - 3.0 * Rdot / R ** 4 * z[0] + 4.0 * lam * p[1] * ur * ur
    if p[p.shape[0] - 1] > 0.5:
        return S, Sdot, 4.0 * lam * p[1]
    return S, Sdot, 4.0 * p[1]


@njit(cache=True, error_model="numpy")
def stress(R, Rdot, z, p, req, zdot):
    return relax(R, Rdot, z, equilibrium_stress(R, req / R, p), p, zdot)


@njit(cache=True, error_model="numpy")
def dissipation_q(x, y, p):
    return 1.0


def _nondim(theta, *, rho, p8, uc, rmax_m):
    lam1 = theta[..., 2]
    return np.stack([theta[..., 0] / p8, inv_re(theta[..., 1], rho=rho, uc=uc, rmax_m=rmax_m),
                     lam1 * uc / rmax_m, theta[..., 3] / lam1], axis=-1)


MODEL = ConstitutiveModel(
    name="zener", description="Zener / standard linear solid with neo-Hookean spring (G, mu, lambda1, lambda2)",
    parameters=(Parameter("G", "Pa", 7.29e3, description="shear modulus"),
                Parameter("mu", "Pa s", 0.088, description="viscosity"),
                Parameter("lambda1", "s", 1e-6, description="relaxation time"),
                Parameter("lambda2", "s", 0.0, positive=False, description="retardation time",
                          prior_sd=5e-7)),
    n_aux=N_AUX, module=__name__, imrv2_stress=3, _nondim=_nondim)
