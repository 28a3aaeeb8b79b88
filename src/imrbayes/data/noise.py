"""Measurement-noise variance P_k of the resampled radius (methods.md §3) and the paper's
verification noise model (methods.md §5).

``P_k`` is the sample variance (ddof = 1) across experiments of R* at step k. All curves share
R*(0) = 1 and zero slope there, so the raw variance vanishes at t* = 0 and is tiny for a few steps:
used as is, those steps would get (near-)infinite weight. A floor keeps every weight finite:

    P_k = max(var_k, floor),  floor = max(P_FLOOR_ABS, P_FLOOR_REL * median_k var_k)

* ``P_FLOOR_ABS = (2e-3)**2``: a radius sd of 0.2 % of Rmax, about a fifth of a pixel at the
  optics of the shared datasets (2.76 µm pixels, Rmax 200-450 µm): no measurement is better.
* ``P_FLOOR_REL = 0.01``: no step is weighted more than 100 times the typical step, so the steps
  near t* = 0, where every curve is 1 by construction, cannot dominate a fit.

``pooled`` (an option, not methods.md's rule): the same sample variance averaged over a centred
window of ``POOL_SAMPLES`` = 11 neighbouring steps before the floors. With N_exp = 5 the per-step
variance has 4 degrees of freedom and E[1/var_k] = 2/sigma^2: every step is over-weighted twofold
on average, some far more, and the posteriors come out too narrow (docs/validation.md, calibration).
Pooling gives ~4 x 11 degrees of freedom where the noise level varies slowly in time.

With a single experiment there is no spread to measure; P_k then falls back to the verification
noise model sigma(t*) = |R* - 1|/20 + (1 - exp(-t*/10))/30 evaluated on the measured R*, squared,
with the same floor.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import uniform_filter1d

__all__ = ["paper_sigma", "noise_variance", "P_FLOOR_ABS", "P_FLOOR_REL", "POOL_SAMPLES"]

P_FLOOR_ABS = (2e-3) ** 2
P_FLOOR_REL = 0.01
POOL_SAMPLES = 11


def paper_sigma(t_star, R_star):
    """Verification noise sd in R*: ``|R* - 1|/20 + (1 - exp(-t*/10))/30`` (methods.md §5).

    ``t_star`` and ``R_star`` broadcast together; returns an array of their broadcast shape.
    """
    t = np.asarray(t_star, dtype=float)
    R = np.asarray(R_star, dtype=float)
    return np.abs(R - 1.0) / 20.0 + (1.0 - np.exp(-t / 10.0)) / 30.0


def noise_variance(
    t_star, R_star, floor_abs: float = P_FLOOR_ABS, floor_rel: float = P_FLOOR_REL, method: str = "auto"
) -> tuple:
    """Per-step noise variance P_k of resampled radii.

    Parameters
    ----------
    t_star : array_like, shape (n,)
        Grid.
    R_star : array_like, shape (n_exp, n)
        Resampled R* of every experiment.
    floor_abs, floor_rel : float
        Floor = ``max(floor_abs, floor_rel * median(var))`` (see module docstring).
    method : ``"auto"``, ``"sample"``, ``"pooled"`` or ``"paper"``
        ``auto``: sample variance with >= 2 experiments, else the noise model; ``pooled``: the
        sample variance averaged over ``POOL_SAMPLES`` neighbouring steps (module docstring);
        ``paper``: the noise model evaluated on the across-experiment mean R*.

    Returns
    -------
    P : ndarray (n,)
    info : dict
        ``method`` (``"sample-variance"`` or ``"paper-noise-model"``), ``floor``, ``floor_abs``,
        ``floor_rel``, ``n_floored`` (steps raised to the floor), ``n_experiments``.
    """
    t = np.asarray(t_star, dtype=float)
    Y = np.atleast_2d(np.asarray(R_star, dtype=float))
    if Y.shape[1] != t.size:
        raise ValueError(f"R_star has {Y.shape[1]} columns but t_star {t.size} values")
    if method not in ("auto", "sample", "pooled", "paper"):
        raise ValueError(f"method must be auto, sample, pooled or paper, got {method!r}")
    if method in ("sample", "pooled") and Y.shape[0] < 2:
        raise ValueError(f"the {method} sample variance needs at least two experiments")
    if method == "pooled":
        raw = uniform_filter1d(Y.var(axis=0, ddof=1), POOL_SAMPLES, mode="nearest")
        method = "pooled-sample-variance"
    elif method != "paper" and Y.shape[0] >= 2:
        raw = Y.var(axis=0, ddof=1)
        method = "sample-variance"
    else:
        raw = paper_sigma(t, Y.mean(axis=0)) ** 2
        method = "paper-noise-model"
    floor = max(float(floor_abs), float(floor_rel) * float(np.median(raw)))
    P = np.maximum(raw, floor)
    info = {
        "method": method,
        "floor": floor,
        "floor_abs": float(floor_abs),
        "floor_rel": float(floor_rel),
        "n_floored": int(np.count_nonzero(raw < floor)),
        "n_experiments": int(Y.shape[0]),
        "rule": "P_k = max(var_k, max(floor_abs, floor_rel * median_k var_k)); var_k = sample "
        "variance (ddof=1) across experiments (pooled: its running mean over "
        f"{POOL_SAMPLES} steps), or the paper's verification noise model squared for a single experiment",
    }
    return P, info
