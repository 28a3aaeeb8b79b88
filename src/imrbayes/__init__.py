"""imrbayes: Bayesian, time-resolved inertial microcavitation rheometry."""

__version__ = "0.1.0"

__all__ = ["load_run", "load_study", "__version__"]


def load_run(path):
    """A fit's run directory as data: :func:`imrbayes.results.load_run` (imported on first use, so
    that ``import imrbayes`` stays cheap)."""
    from imrbayes.results import load_run as _load_run

    return _load_run(path)


def load_study(path):
    """The table of a study folder written by ``imrbayes study`` as a pandas DataFrame
    (:func:`imrbayes.study.load_study`)."""
    from imrbayes.study.load import load_study as _load

    return _load(path)
