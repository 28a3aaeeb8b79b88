"""Upper-convected Maxwell (lambda2 = 0) / Oldroyd-B liquid (IMRv2 stress 5): mu, lambda1, lambda2.

p = [0, 1/Re, De, Lambda]; two auxiliary states, zero at t = 0; J = 4 Lambda/Re.
"""

from numba import njit

from imrbayes.forward.constitutive.base import ConstitutiveModel, Parameter
from imrbayes.forward.constitutive.maxwell import MODEL as MAXWELL  # same parameters, same scaling

N_AUX = 2


@njit(cache=True, error_model="numpy")
def stress(R, Rdot, z, p, req, zdot):
    de = p[2]
    lam = p[3]
    ur = Rdot / R
    src = 2.0 * (lam - 1.0) * p[1] / de * R * R * Rdot
    zdot[0] = -(1.0 / de - 2.0 * ur) * z[0] + src
    zdot[1] = -(1.0 / de + ur) * z[1] + src
    zs = z[0] + z[1]
    S = zs / R ** 3 - 4.0 * lam * p[1] * ur
    Sdot = (zdot[0] + zdot[1]) / R ** 3 - 3.0 * Rdot / R ** 4 * zs + 4.0 * lam * p[1] * ur * ur
    return S, Sdot, 4.0 * lam * p[1]


@njit(cache=True, error_model="numpy")
def dissipation_q(x, y, p):
    return 1.0


MODEL = ConstitutiveModel(
    name="oldroyd-b", description="upper-convected Maxwell / Oldroyd-B liquid (mu, lambda1, lambda2)",
    parameters=(Parameter("mu", "Pa s", 0.088, description="viscosity"),
                Parameter("lambda1", "s", 1e-6, description="relaxation time"),
                Parameter("lambda2", "s", 0.0, positive=False, description="retardation time",
                          prior_sd=5e-7)),
    n_aux=N_AUX, module=__name__, imrv2_stress=5, _nondim=MAXWELL.nondimensionalise)
