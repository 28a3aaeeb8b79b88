"""The inference-method protocol: what a method declares so that the CLI, the report and the MCMC
layer use it without knowing its name (``imrbayes.ensemble.METHODS`` is the registry).

A method is one module: its settings dataclass, its ``fit_*`` function, its units of work (run
by :mod:`imrbayes.execution`) and a subclass of :class:`InferenceMethod` that names them, in the
spirit of DAPPER's "a method is a class with its settings and ``assimilate(model, data)``" and
scipy's ``OdeSolver``. The class is never instantiated: its attributes are the declaration.

>>> m = METHODS["en4dvar"]
>>> s = m.settings_class(n_ens=32)
>>> res = m.fit(fm, obs, space, s, seed=0, runner=runner, execution=execution)   # FitResult
>>> m.check_settings(s, obs)                                                    # InputError if refused
>>> m.n_forward_runs(s, obs.n_exp, obs.n_samples - 1)                            # progress bar total
>>> m.n_units(s, obs.n_exp, obs.n_samples - 1, fm)                               # (units, in words)
>>> m.figures(obs, res, out / "figures")                                         # [Path, ...]
"""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

__all__ = ["InferenceMethod"]


class InferenceMethod:
    """Declaration of one inference method (subclass it; see the module docstring).

    Attributes
    ----------
    name : str
        ``--method`` value and ``FitResult.method``, e.g. ``"en4dvar"``.
    label : str
        Human name for reports, e.g. ``"ensemble 4D-Var (En4D-Var)"``.
    settings_class : type
        Settings dataclass (``--set KEY=VALUE`` and the ``[fit.<name>]`` table fill its fields;
        ``details["settings"]`` records them).
    gaussian_posterior : bool
        The fit records ``FitResult.window_posteriors`` (Gaussian posteriors with their priors,
        observation weights and start states), which ``--mcmc`` samples to check them.
    estimate_note : str
        What ``summary.json["estimate"]`` is, when it is not the obvious (shown by the report).
    """

    name: ClassVar[str]
    label: ClassVar[str]
    settings_class: ClassVar[type]
    gaussian_posterior: ClassVar[bool] = False
    estimate_note: ClassVar[str] = ""

    @staticmethod
    def fit(fm, obs, space, settings=None, seed: int = 0, runner=None, progress=None, execution=None):
        """``fit(fm: ForwardModel, obs: Observations, space: ParamSpace, settings, seed=, runner=,
        progress=, execution=) -> FitResult``; ``execution`` (:class:`imrbayes.execution.Execution`)
        says where its units run and are checkpointed."""
        raise NotImplementedError

    @staticmethod
    def check_settings(settings, obs) -> None:
        """Raise :class:`~imrbayes.errors.InputError` for settings the fit would refuse on these
        :class:`~imrbayes.ensemble.Observations` -- called by the CLI before it writes anything, so
        that a bad ``--set`` costs no output folder. Default: the settings' own ``check()``, if any."""
        check = getattr(settings, "check", None)
        if check is not None:
            check()

    @staticmethod
    def global_start(settings, space) -> bool:
        """Whether ``fit`` runs the global search (:mod:`imrbayes.ensemble.search`) first and
        starts this method at its best point (local methods with the default likelihood)."""
        return False

    @staticmethod
    def n_forward_runs(settings, n_exp: int, n_steps: int) -> int:
        """Forward member runs the fit will make for ``n_exp`` experiments of ``n_steps`` steps
        (the progress bar's total; an estimate where runs stop early)."""
        raise NotImplementedError

    @staticmethod
    def n_units(settings, n_exp: int, n_steps: int, fm=None) -> tuple:
        """(execution units the fit will run for ``n_exp`` experiments of ``n_steps`` steps with
        forward model ``fm``, what they are in words), e.g. ``(36, "2 passes x 18 windows x 1
        experiments")``; ``(None, "")`` when not known (the progress bar then grows batch by batch)."""
        return None, ""

    @staticmethod
    def figures(obs, res, fdir: Path) -> list:
        """The method's own figures (after ``fit.png``, which every method writes) under ``fdir``;
        returns their paths."""
        return []
