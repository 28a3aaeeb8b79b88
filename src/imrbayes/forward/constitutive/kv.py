"""Linear (Hookean, small-strain) Kelvin-Voigt solid: G [Pa], mu [Pa s].

Not in IMRv2. Elastic part of the stress integral for a linear-elastic shell around a cavity
of rest radius Req: S_e = -(4/(3 Ca)) (1 - (Req/R)^3). The medium-energy dissipation uses the
neo-Hookean form (IMRv2 has no linear model to copy); it only matters with a warm medium.
"""

from numba import njit

from imrbayes.forward.constitutive.base import ConstitutiveModel, Parameter
from imrbayes.forward.constitutive.nhkv import MODEL as NHKV  # same parameters, same scaling

N_AUX = 0


@njit(cache=True, error_model="numpy")
def stress(R, Rdot, z, p, req, zdot):
    rs3 = (req / R) ** 3
    ur = Rdot / R
    S = -4.0 * p[1] * ur - 4.0 / 3.0 * p[0] * (1.0 - rs3)
    Sdot = -4.0 * p[0] * ur * rs3 + 4.0 * p[1] * ur * ur
    return S, Sdot, 4.0 * p[1]


@njit(cache=True, error_model="numpy")
def dissipation_q(x, y, p):
    return 1.0


MODEL = ConstitutiveModel(
    name="kv", description="linear (Hookean) Kelvin-Voigt solid (G, mu)",
    parameters=(Parameter("G", "Pa", 7.29e3, description="shear modulus"),
                Parameter("mu", "Pa s", 0.088, description="viscosity")),
    n_aux=N_AUX, module=__name__, imrv2_stress=None, _nondim=NHKV.nondimensionalise)
