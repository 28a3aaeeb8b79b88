"""MCMC reference posteriors for the ensemble methods.

* :mod:`~imrbayes.mcmc.target` -- the log-posterior of constant parameters over a window
  (Gaussian likelihood with the methods' observation weights, the Gaussian prior of a
  :class:`~imrbayes.ensemble.ParamSpace` on log parameters), batched for emcee's ``vectorize=True``;
* :mod:`~imrbayes.mcmc.sampler` -- independent seeded emcee ensembles with an HDF5 backend
  (resumable), autocorrelation diagnostics, an ArviZ DataTree with the pointwise log-likelihood;
* :mod:`~imrbayes.mcmc.compare` -- ensemble Gaussian vs MCMC per window (``compare.json``);
* :mod:`~imrbayes.mcmc.windows` -- the windows a fit recorded (``FitResult.window_posteriors``):
  targets, sampling, ``mcmc.nc``;
* :mod:`~imrbayes.mcmc.fit` -- ``imrbayes fit --mcmc``: every window as an execution unit;
* :mod:`~imrbayes.mcmc.figures` -- forest, KL/W2 against t*, pair plots.

Design, agreement rule and numbers: ``docs/methods.md``.

>>> space = ParamSpace.for_model(fm.constitutive)                 # names, log transform, prior (box_sd=10)
>>> target = fitting_window_target(fm, obs, space, weight="en4dvar")
>>> run = run_mcmc(target, fused_mean, fused_cov, MCMCSettings(), seed=0, backend="mcmc.h5", name="window_00")
>>> dt = run.to_datatree(target)                                   # posterior, log_likelihood, observed_data
>>> entry = compare_window(fused_mean, fused_cov, dt, space.names, space.positive, diagnostics=run.diagnostics())
"""

from imrbayes.mcmc.compare import THRESHOLDS, compare_window, compare_windows, gaussian_kl, gaussian_w2
from imrbayes.mcmc.sampler import MCMCRun, MCMCSettings, run_mcmc
from imrbayes.mcmc.target import WindowTarget, fitting_window_target, window_target_from_ensemble
from imrbayes.mcmc.windows import compare_from_tree, mcmc_tree, sample_windows, window_specs, write_compare, write_mcmc

__all__ = [
    "WindowTarget",
    "fitting_window_target",
    "window_target_from_ensemble",
    "MCMCSettings",
    "MCMCRun",
    "run_mcmc",
    "THRESHOLDS",
    "compare_window",
    "compare_windows",
    "gaussian_kl",
    "gaussian_w2",
    "window_specs",
    "sample_windows",
    "mcmc_tree",
    "write_mcmc",
    "write_compare",
    "compare_from_tree",
]
