"""imrbayes: Bayesian, time-resolved inertial microcavitation rheometry."""

__version__ = "0.1.0"
