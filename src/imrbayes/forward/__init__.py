"""The shared forward model: Keller-Miksis bubble dynamics, IMR bubble contents, constitutive
models. Physics: shared/docs/methods.md. Public API:

>>> fm = ForwardModel("nhkv")                      # KM, thermal bubble, vapour, mass transfer
>>> R = fm.simulate_radius({"G": 7.29e3, "mu": 0.088}, rmax_m=263e-6, req_m=263e-6 / 7.58,
...                        t_star=np.arange(121) * 0.025)
"""

from imrbayes.forward.constants import Physics, nondimensional_groups
from imrbayes.forward.constitutive import available_models, get_model
from imrbayes.forward.model import BatchState, ForwardModel, Propagation
from imrbayes.forward.options import ForwardOptions
from imrbayes.forward.runner import Runner, fm_spec, forward_model_from_spec, register_runner, runner_for

RAYLEIGH_COLLAPSE_TIME = 0.9146813565  # sqrt(6 pi) Gamma(11/6) / (5 Gamma(4/3)), in Rmax/Uc

__all__ = ["ForwardModel", "ForwardOptions", "BatchState", "Propagation", "Physics", "available_models",
           "get_model", "nondimensional_groups", "RAYLEIGH_COLLAPSE_TIME", "Runner", "fm_spec",
           "forward_model_from_spec", "register_runner", "runner_for"]
