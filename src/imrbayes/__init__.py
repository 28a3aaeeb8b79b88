"""imrbayes: Bayesian, time-resolved inertial microcavitation rheometry."""

__version__ = "0.1.0"


def load_study(path):
    """The table of a study folder written by ``imrbayes study`` as a pandas DataFrame
    (:func:`imrbayes.study.load_study`)."""
    from imrbayes.study.load import load_study as _load

    return _load(path)
