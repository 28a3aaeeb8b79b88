"""Preprocessing steps, one pure function each (no I/O, inputs never modified).

Conventions: ``t_s`` [s] and ``R_m`` [m] are 1-D float arrays of one length ``n``, time strictly
increasing. Dimensionless time ``t* = t / t_c`` with ``t_c = Rmax / sqrt(p8/rho)``; ``R* = R/Rmax``.

Choices and why (written to every run's output by :func:`imrbayes.data.pipeline.preprocess_dataset`):

* **Maximum** (:func:`locate_rmax`): default ``"parabola"``, the vertex of the parabola through the
  largest sample and its two neighbours. The sample maximum puts t = 0 up to half a frame from the
  true peak: 0.05 in t* at 270 000 frames/s, i.e. 5 % of a collapse time and two steps of the
  dt* = 0.025 grid, different for every experiment. That jitter biases the collapse time and
  inflates the across-experiment variance P_k where R* changes fastest. Near a maximum R(t) is
  smooth and close to symmetric (R' = 0), which a parabola captures: on forward-model curves the
  refined maximum is within 1e-4 in t* of the truth. On the 20 stiff-PA records it halves the spread
  of t_c* across bubbles (docs/datasets.md). ``"sample"`` (the discrete argmax, which the shared
  CSVs use for their t = 0) is available. The parabola falls back to it when the maximum is the
  first or last sample.
* **First collapse** (:func:`first_collapse`): the smallest radius between the maximum and the first
  rebound, where a rebound is a rise of more than ``rebound_frac`` (default 5 %) of Rmax above the
  running minimum (so sub-pixel wiggles on the way down are not taken for a collapse), refined by a
  parabola through the minimum sample and its neighbours. A record with no rebound after its
  minimum is too short and is refused. On Keller-Miksis curves the parabola has the lower rms
  error of the two estimators at every frame rate tried. Both are biased late, because the collapse
  is steeper than the rebound: by about 0.2 frame intervals (docs/datasets.md).
* **Req** (:func:`estimate_req`): the mean of the last ``n_tail`` = 20 samples after the first
  collapse (the peer codes' choice), with the sample standard deviation of those samples as its
  uncertainty (the late radius oscillates, so the sd, not the standard error, says how well Req is
  known); the standard error is reported as well.
* **Resampling** (:func:`resample`): linear interpolation (no overshoot near the collapse, where a
  spline can undershoot below the measured minimum) of the samples at t* > 0 plus the point
  (t* = 0, R* = 1) at the refined maximum, so R*(0) = 1 as the forward model assumes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["parabola_vertex", "locate_rmax", "first_collapse", "estimate_req", "time_scale_s",
           "nondimensionalise", "resample", "RmaxResult", "CollapseResult", "ReqResult", "RecordTooShort"]


class RecordTooShort(ValueError):
    """The record ends before the first collapse has rebounded (message says where)."""


def parabola_vertex(x, y) -> tuple:
    """Vertex ``(x_v, y_v)`` of the parabola through three points (any spacing).

    Parameters
    ----------
    x, y : array_like, shape (3,)
        Distinct abscissae (increasing) and ordinates.

    Returns
    -------
    (float, float), or None if the three points are collinear (no vertex).
    """
    x0, x1, x2 = (float(v) for v in x)
    y0, y1, y2 = (float(v) for v in y)
    # Newton form y = y0 + d01 (x - x0) + a (x - x0)(x - x1), rewritten about x1 for accuracy:
    d01 = (y1 - y0) / (x1 - x0)
    d12 = (y2 - y1) / (x2 - x1)
    a = (d12 - d01) / (x2 - x0)
    if a == 0.0 or not math.isfinite(a):
        return None
    # y = y1 + b (x - x1) + a (x - x1)^2 with b = d01 + a (x1 - x0)
    b = d01 + a * (x1 - x0)
    dx = -b / (2.0 * a)
    return x1 + dx, y1 + b * dx + a * dx * dx


@dataclass(frozen=True)
class RmaxResult:
    """``index`` of the largest sample; ``t_s``, ``rmax_m``: the maximum's time [s] and radius [m]
    (refined or sample); ``rmax_sample_m``: the largest sample [m]; ``method``: what was used."""

    index: int
    t_s: float
    rmax_m: float
    rmax_sample_m: float
    method: str


def locate_rmax(t_s, R_m, method: str = "parabola") -> RmaxResult:
    """Find the radius maximum, optionally refined below the frame interval.

    ``method="parabola"`` returns the vertex of the parabola through the largest sample and its two
    neighbours (the vertex lies between them, and its radius is at least the largest sample);
    ``"sample"`` returns the largest sample. The parabola falls back to the sample at either end
    of the record (``method`` then reads ``"sample (at record end)"``).
    """
    if method not in ("parabola", "sample"):
        raise ValueError(f"method must be 'parabola' or 'sample', got {method!r}")
    t = np.asarray(t_s, dtype=float)
    R = np.asarray(R_m, dtype=float)
    i = int(np.argmax(R))
    sample = RmaxResult(i, float(t[i]), float(R[i]), float(R[i]), "sample")
    if method == "sample":
        return sample
    if i == 0 or i == R.size - 1:
        return RmaxResult(i, float(t[i]), float(R[i]), float(R[i]), "sample (at record end)")
    v = parabola_vertex(t[i - 1:i + 2], R[i - 1:i + 2])
    if v is None or not (t[i - 1] < v[0] < t[i + 1]) or v[1] < R[i]:
        return RmaxResult(i, float(t[i]), float(R[i]), float(R[i]), "sample (flat top)")
    return RmaxResult(i, float(v[0]), float(v[1]), float(R[i]), "parabola")


@dataclass(frozen=True)
class CollapseResult:
    """``index`` of the smallest sample of the first collapse; ``t_s`` [s] and ``r_m`` [m] of the
    (refined) minimum; ``rebound_index`` the first sample of the rebound; ``method`` used."""

    index: int
    t_s: float
    r_m: float
    rebound_index: int
    method: str


def first_collapse(t_s, R_m, i_max: int, method: str = "parabola", rebound_frac: float = 0.05) -> CollapseResult:
    """The first radius minimum after the maximum at index ``i_max``.

    Walks forward from ``i_max`` keeping the running minimum; the collapse is that minimum once the
    radius has risen more than ``rebound_frac * R[i_max]`` above it. ``method="parabola"`` refines
    the minimum with the parabola through it and its two neighbours (the vertex lies between them
    and not above the smallest sample); ``"sample"`` keeps the smallest sample.

    Raises
    ------
    RecordTooShort
        If the record ends before such a rebound.
    """
    if method not in ("parabola", "sample"):
        raise ValueError(f"method must be 'parabola' or 'sample', got {method!r}")
    t = np.asarray(t_s, dtype=float)
    R = np.asarray(R_m, dtype=float)
    rise = rebound_frac * R[i_max]
    im, m = i_max, R[i_max]
    rebound = None
    for j in range(i_max + 1, R.size):
        if R[j] < m:
            im, m = j, R[j]
        elif R[j] - m > rise:
            rebound = j
            break
    if rebound is None:
        where = "at its minimum" if im == R.size - 1 else "before the radius rebounds"
        raise RecordTooShort(f"record too short to reach the first collapse: it ends {where} "
                             f"(last sample t = {(t[-1] - t[i_max]) * 1e6:.4g} µs after the maximum, "
                             f"R = {R[-1] / R[i_max]:.3g} Rmax)")
    if method == "sample":
        return CollapseResult(im, float(t[im]), float(R[im]), rebound, "sample")
    v = parabola_vertex(t[im - 1:im + 2], R[im - 1:im + 2])
    if v is None or not (t[im - 1] < v[0] < t[im + 1]) or v[1] > R[im] or v[1] <= 0.0:
        return CollapseResult(im, float(t[im]), float(R[im]), rebound, "sample (parabola not usable)")
    return CollapseResult(im, float(v[0]), float(v[1]), rebound, "parabola")


@dataclass(frozen=True)
class ReqResult:
    """Equilibrium radius estimate: ``req_m`` [m], ``sd_m`` (sample sd of the tail) [m], ``se_m``
    (standard error of the mean) [m], ``n`` samples used, ``start_index`` of the tail, ``warning``."""

    req_m: float
    sd_m: float
    se_m: float
    n: int
    start_index: int
    warning: str | None = None


def estimate_req(R_m, i_collapse: int, n_tail: int = 20) -> ReqResult:
    """Mean of the last ``n_tail`` samples, restricted to samples after the first collapse.

    Parameters
    ----------
    R_m : array_like, shape (n,)
        Radius [m].
    i_collapse : int
        Index of the first-collapse sample; the tail never reaches back to it.
    n_tail : int
        Number of samples to average (default 20).

    A warning is set when fewer than ``n_tail`` samples follow the collapse (the tail then includes
    the first rebound) or when the tail still varies by more than 10 % (sd/mean).
    """
    R = np.asarray(R_m, dtype=float)
    start = max(R.size - int(n_tail), i_collapse + 1)
    tail = R[start:]
    n = tail.size
    warning = None
    if n == 0:
        raise ValueError("no samples after the first collapse")
    mean = float(tail.mean())
    sd = float(tail.std(ddof=1)) if n > 1 else float("nan")
    se = sd / math.sqrt(n) if n > 1 else float("nan")
    if n < n_tail:
        warning = (f"only {n} sample(s) after the first collapse; Req from them includes the rebound "
                   f"and is unreliable")
    elif sd > 0.1 * mean:
        warning = (f"late-time radius still varies by {100 * sd / mean:.0f}% (sd/mean) over the last {n} "
                   f"samples; Req is uncertain")
    return ReqResult(mean, sd, se, n, start, warning)


def time_scale_s(rmax_m, rho: float, p8: float):
    """``t_c = Rmax / sqrt(p8/rho)`` [s] (scalar or array like ``rmax_m`` [m])."""
    uc = math.sqrt(p8 / rho)
    return np.asarray(rmax_m, dtype=float) / uc if np.ndim(rmax_m) else float(rmax_m) / uc


def nondimensionalise(t_s, R_m, t0_s: float, rmax_m: float, tc_s: float) -> tuple:
    """``(t*, R*) = ((t - t0)/t_c, R/Rmax)``, arrays shaped like the inputs."""
    return ((np.asarray(t_s, dtype=float) - t0_s) / tc_s, np.asarray(R_m, dtype=float) / rmax_m)


def resample(t_star, R_star, dt_star: float = 0.025, n_steps: int = 120, method: str = "linear",
             anchor: bool = True) -> tuple:
    """Interpolate one record onto ``t*_k = k dt*``, k = 0..n (n <= ``n_steps``).

    Parameters
    ----------
    t_star, R_star : array_like, shape (m,)
        Dimensionless record, t* = 0 at the maximum (earlier samples are ignored).
    dt_star : float
        Grid step (default 0.025).
    n_steps : int
        Steps wanted (default 120, i.e. 121 samples).
    method : ``"linear"`` or ``"pchip"``
        Interpolant (both are local and do not overshoot the samples).
    anchor : bool
        Add the point (0, 1), the maximum itself, before the samples at t* > 0 (default). Without
        it the samples at t* >= 0 are used as they are, and one of them must lie at t* = 0.

    Returns
    -------
    grid : ndarray (n + 1,), values : ndarray (n + 1,), n : int
        ``n < n_steps`` when the record ends before ``n_steps * dt_star``.
    """
    t = np.asarray(t_star, dtype=float)
    R = np.asarray(R_star, dtype=float)
    if anchor:
        keep = t > 0.0
        t = np.concatenate(([0.0], t[keep]))
        R = np.concatenate(([1.0], R[keep]))
    else:
        keep = t >= 0.0
        t, R = t[keep], R[keep]
        if t.size == 0 or t[0] != 0.0:
            raise ValueError("without anchor the record must have a sample at t* = 0")
    n_avail = int(math.floor(t[-1] / dt_star + 1e-9)) if t.size > 1 else 0
    n = min(int(n_steps), n_avail)
    grid = np.arange(n + 1) * dt_star
    if method == "linear":
        values = np.interp(grid, t, R)
    elif method == "pchip":
        from scipy.interpolate import PchipInterpolator

        values = PchipInterpolator(t, R)(grid) if t.size > 1 else np.interp(grid, t, R)
    else:
        raise ValueError(f"method must be 'linear' or 'pchip', got {method!r}")
    return grid, values, n
