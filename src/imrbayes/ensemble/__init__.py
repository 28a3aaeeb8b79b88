"""Inference methods on ensembles of forward runs (methods.md §1-4).

Each method takes a forward model, the preprocessed observations and a parameter space, and
returns a :class:`FitResult`; none of them knows the physics beyond ``imrbayes.forward``'s API.

>>> obs = Observations.from_preprocessed(pre)
>>> space = ParamSpace.for_model(fm.constitutive)          # paper prior, log G / log mu
>>> res = fit_en4dvar(fm, obs, space, En4DVarSettings(), seed=0)
"""

from imrbayes.ensemble.en4dvar import En4DVarSettings, fit_en4dvar
from imrbayes.ensemble.imr import IMRSettings, fit_imr
from imrbayes.ensemble.mienks import MIEnKSSettings, fit_mienks
from imrbayes.ensemble.pimr import PIMRSettings, fit_pimr
from imrbayes.ensemble.problem import PAPER_PRIOR, Observations, ParamSpace
from imrbayes.ensemble.result import FitResult
from imrbayes.ensemble.runner import Runner

METHODS = {
    "imr": (fit_imr, IMRSettings),
    "pimr": (fit_pimr, PIMRSettings),
    "en4dvar": (fit_en4dvar, En4DVarSettings),
    "mienks": (fit_mienks, MIEnKSSettings),
}

__all__ = ["METHODS", "Observations", "ParamSpace", "PAPER_PRIOR", "FitResult", "Runner",
           "fit_imr", "fit_pimr", "fit_en4dvar", "fit_mienks",
           "IMRSettings", "PIMRSettings", "En4DVarSettings", "MIEnKSSettings"]
