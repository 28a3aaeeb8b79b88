"""Differences between conditions, from their posteriors (never from point estimates).

Each condition's gel-level posterior is a set of draws of the log parameters; conditions are
independent experiments, so draws of a ratio are ratios of independent draws, and a trend along a
numeric label is the least-squares slope of the log parameter on the label, draw by draw.
"""

from __future__ import annotations

import numpy as np

__all__ = ["log_draws", "ratio_summary", "trend_summary", "LEVEL"]

#: the level of every interval the study reports
LEVEL = 0.95


def log_draws(mean, cov, n_draws: int, rng) -> np.ndarray:
    """Draws (n_draws, n_par) of the log parameters from the Gaussian ``mean`` (n_par,), ``cov``
    (n_par, n_par) in log space."""
    return rng.multivariate_normal(np.asarray(mean, float), np.asarray(cov, float), size=n_draws, method="cholesky")


def _interval(x: np.ndarray) -> list:
    q = (1 - LEVEL) / 2
    return np.quantile(x, [q, 1 - q]).tolist()


def ratio_summary(log_a: np.ndarray, log_b: np.ndarray) -> dict:
    """The ratio a / b of one parameter between two conditions from their log draws (n_draws,) each:
    ``ratio`` (posterior median), ``interval`` (central 95 %), ``p_greater`` = P(a > b)."""
    d = np.asarray(log_a, float) - np.asarray(log_b, float)
    return {
        "ratio": float(np.exp(np.median(d))),
        "interval": np.exp(_interval(d)).tolist(),
        "p_greater": float(np.mean(d > 0)),
    }


def trend_summary(x, log_draws_by_condition: np.ndarray) -> dict:
    """The slope of the log parameter on a numeric label ``x`` (n_cond,), from draws
    (n_cond, n_draws) of each condition's log parameter: ``slope`` (posterior median, per label
    unit), ``interval`` (central 95 %), ``p_positive`` = P(slope > 0), ``factor_over_range`` =
    exp(slope (max x - min x)), the change the trend implies across the labels studied."""
    x = np.asarray(x, float)
    y = np.asarray(log_draws_by_condition, float)
    slope = np.polyfit(x, y, 1)[0]  # one least-squares line per draw
    span = float(x.max() - x.min())
    return {
        "slope": float(np.median(slope)),
        "interval": _interval(slope),
        "p_positive": float(np.mean(slope > 0)),
        "factor_over_range": float(np.exp(np.median(slope) * span)),
        "factor_interval": np.exp(np.asarray(_interval(slope)) * span).tolist(),
    }
