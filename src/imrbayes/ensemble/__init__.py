"""Inference methods on ensembles of forward runs (methods.md §1-4).

Each method takes a forward model, the preprocessed observations and a parameter space, and
returns a :class:`FitResult`; none of them knows the physics beyond ``imrbayes.forward``'s API.
Every method is one module declaring an :class:`InferenceMethod` (name, label, settings, ``fit``,
forward-run count, figures, whether MCMC can check its posterior); :data:`METHODS` is the registry
that the CLI, the report and the MCMC layer ask. Adding a method: one module, one line below.

>>> obs = Observations.from_preprocessed(pre)
>>> space = ParamSpace.for_model(fm.constitutive)          # paper prior, log G / log mu
>>> res = fit_en4dvar(fm, obs, space, En4DVarSettings(), seed=0)
>>> res = METHODS["en4dvar"].fit(fm, obs, space, En4DVarSettings(), seed=0)     # the same, by name
"""

from imrbayes.ensemble.en4dvar import En4DVar, En4DVarSettings, fit_en4dvar
from imrbayes.ensemble.imr import IMR, IMRSettings, fit_imr
from imrbayes.ensemble.method import InferenceMethod
from imrbayes.ensemble.mienks import MIEnKS, MIEnKSSettings, fit_mienks
from imrbayes.ensemble.pimr import PIMR, PIMRSettings, fit_pimr
from imrbayes.ensemble.problem import PAPER_PRIOR, Observations, ParamSpace
from imrbayes.ensemble.result import FitResult, WindowPosterior

#: name -> method (:class:`InferenceMethod` subclass), in the order the CLI lists them
METHODS = {m.name: m for m in (IMR, PIMR, En4DVar, MIEnKS)}

__all__ = [
    "METHODS",
    "InferenceMethod",
    "Observations",
    "ParamSpace",
    "PAPER_PRIOR",
    "FitResult",
    "WindowPosterior",
    "fit_imr",
    "fit_pimr",
    "fit_en4dvar",
    "fit_mienks",
    "IMR",
    "PIMR",
    "En4DVar",
    "MIEnKS",
    "IMRSettings",
    "PIMRSettings",
    "En4DVarSettings",
    "MIEnKSSettings",
]
