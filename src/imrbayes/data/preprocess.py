"""Preprocessing steps, one pure function each (no I/O, inputs never modified).

Conventions: ``t_s`` [s] and ``R_m`` [m] are 1-D float arrays of one length ``n``, time strictly
increasing. Dimensionless time ``t* = t / t_c`` with ``t_c = Rmax / sqrt(p8/rho)``; ``R* = R/Rmax``.

Choices and why (written to every run's output by :func:`imrbayes.data.pipeline.preprocess_dataset`):

* **Noise** (:func:`estimate_noise_sd`): the radius noise sd of a record from the median absolute
  fourth difference of its samples (robust: the few large differences at a collapse do not
  move it). It sets the window and thresholds below and is reported with every experiment.
* **Maximum** (:func:`locate_rmax`): default ``"local-fit"``, the vertex of a least-squares parabola
  through every sample within 0.35 t_c of the peak (centred on the peak of a 5-sample running
  mean, then re-centred once on the first fit's vertex), with standard errors from the fit (delta
  method, residual variance from the fit itself). A camera samples a flat maximum with noise: the
  largest sample is biased high by about one noise sd and its time is uncertain by several frames;
  a fit over ~20 frames averages both down. Measured on camera-style records (1 Mfps, noise 2 % of
  Rmax, 5 µs before the maximum, 300 noise draws each): Rmax bias +0.2 to +0.6 µm (sd 2.0-2.5 µm)
  against +8.5 to +11.8 µm for the three-frame parabola; noise-free, 1.6e-4 relative (a degree-4 fit
  is 20× more accurate without noise but doubles the bias with it). The older estimators stay available: ``"parabola"``, the vertex of the parabola through the
  largest sample and its two neighbours. The sample maximum puts t = 0 up to half a frame from the
  true peak: 0.05 in t* at 270 000 frames/s, i.e. 5 % of a collapse time and two steps of the
  dt* = 0.025 grid, different for every experiment. That jitter biases the collapse time and
  inflates the across-experiment variance P_k where R* changes fastest. Near a maximum R(t) is
  smooth and close to symmetric (R' = 0), which a parabola captures: on forward-model curves the
  refined maximum is within 1e-4 in t* of the truth. On the 20 stiff-PA records it halves the spread
  of t_c* across bubbles (docs/guide.md). ``"sample"`` (the discrete argmax, which the shared
  CSVs use for their t = 0) is available. The parabola falls back to it when the maximum is the
  first or last sample.
* **First collapse** (:func:`first_collapse`): the smallest radius between the maximum and the first
  rebound, where a rebound is a rise above the running minimum of more than ``rebound_frac``
  (default 5 %) of Rmax and more than 4 noise sd (at most 8 % of Rmax) (so noise on the way down is not taken for a
  collapse; when the noise sets that bar two frames in a row must clear it), no earlier than
  ``t_min_s`` after the maximum (0.6 t_c: a gel, whose stress and contents slow the collapse,
  cannot collapse a bubble much faster than the Rayleigh time 0.915 t_c), refined by a
  parabola through the minimum sample and its neighbours. A record with no rebound after its
  minimum is too short and is refused. On Keller-Miksis curves the parabola has the lower rms
  error of the two estimators at every frame rate tried. Both are biased late, because the collapse
  is steeper than the rebound: by about 0.2 frame intervals (docs/guide.md).
* **Req** (:func:`estimate_req`): the mean of the last ``n_tail`` = 20 samples after the first
  collapse (the peer codes' choice). Its uncertainty: the part of the tail's spread that is not
  measurement noise (the late radius still oscillates, and where its centre lies is not averaged
  away) in full, plus the noise divided by the samples averaged; with no noise estimate, the
  tail's sample sd. The standard error of the mean is reported as well. A tail that has not
  settled (its spread beyond the noise over 10 % of its mean) is a nonlinear oscillation whose
  mean lies above Req (up to 2.8x on camera-style records to t* = 4, docs/methods.md) and whose
  lowest point lies at or below it: Req is then taken at the log-midpoint of the two, each end one
  sd away (the data of the fitted window decide where in between).
* **Resampling** (:func:`resample`): linear interpolation (no overshoot near the collapse, where a
  spline can undershoot below the measured minimum) of the samples at t* > 0 plus the point
  (t* = 0, R* = 1) at the refined maximum, so R*(0) = 1 as the forward model assumes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import norm

__all__ = [
    "parabola_vertex",
    "estimate_noise_sd",
    "locate_rmax",
    "first_collapse",
    "estimate_req",
    "time_scale_s",
    "nondimensionalise",
    "resample",
    "RmaxResult",
    "CollapseResult",
    "ReqResult",
    "RecordTooShort",
]


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


def estimate_noise_sd(R_m) -> float:
    """Noise sd [m] of a record from its fourth differences: 1.4826 MAD(d4 R) / sqrt(70) (white
    noise of sd s gives fourth differences of sd s sqrt(70), while a smooth radius contributes only
    h^4 times its fourth derivative; the median ignores the few frames around a collapse where that
    is large). 0 for fewer than 7 samples."""
    R = np.asarray(R_m, dtype=float)
    if R.size < 7:
        return 0.0
    d4 = np.diff(R, 4)
    return float(1.4826 * np.median(np.abs(d4 - np.median(d4))) / math.sqrt(70.0))


@dataclass(frozen=True)
class RmaxResult:
    """``index`` of the largest sample; ``t_s``, ``rmax_m``: the maximum's time [s] and radius [m]
    (refined or sample); ``rmax_sample_m``: the largest sample [m]; ``method``: what was used;
    ``t_sd_s``, ``rmax_sd_m``: their standard errors [s], [m] (``local-fit`` and, when it falls back
    to the three-point parabola or the largest sample of a noisy record, theirs: the parabola's by
    error propagation, capped by the width of the noise-hidden top; else NaN, taken as known);
    ``n_fit``: samples in the fit."""

    index: int
    t_s: float
    rmax_m: float
    rmax_sample_m: float
    method: str
    t_sd_s: float = float("nan")
    rmax_sd_m: float = float("nan")
    n_fit: int = 1


def locate_rmax(
    t_s, R_m, method: str = "parabola", u_c: float | None = None, half_width: float = 0.35, noise_sd_m: float = 0.0
) -> RmaxResult:
    """Find the radius maximum, refined below the frame interval.

    ``method="local-fit"`` (the pipeline's default; it needs ``u_c``) fits a parabola to every sample
    within ``half_width`` t_c of the peak at 2 % noise (narrower with less noise, down to 0.02 t_c) (t_c = R_peak / ``u_c``, ``u_c`` = sqrt(p8/rho) [m/s]; required); the maximum is its
    vertex, with standard errors (module docstring); ``noise_sd_m`` [m] (the record's noise sd)
    weights the curvature prior. ``"parabola"`` returns the vertex of the
    parabola through the largest sample and its two neighbours (this function's default); ``"sample"`` the largest sample.
    Every method falls back to the sample when the peak is at either end of the record (``method``
    then reads ``"sample (at record end)"``) or when no vertex lies inside the fitted samples.
    """
    if method not in ("local-fit", "parabola", "sample"):
        raise ValueError(f"method must be 'local-fit', 'parabola' or 'sample', got {method!r}")
    t = np.asarray(t_s, dtype=float)
    R = np.asarray(R_m, dtype=float)
    i = int(np.argmax(R))
    sample = RmaxResult(i, float(t[i]), float(R[i]), float(R[i]), "sample")
    if method == "sample":
        return sample
    if method == "local-fit":
        if u_c is None:
            raise ValueError("local-fit needs u_c = sqrt(p8/rho) [m/s] to size its window")
        # the window shrinks with the noise: a parabola's model error grows with its width and
        # only noise needs the averaging (0.35 t_c at 2 % noise, 0.06 t_c at 0.001 %; with fewer than
        # two samples each side of the vertex the three-point parabola takes over)
        rel_noise = max(float(noise_sd_m), 0.0) / R[i]
        width = float(np.clip(half_width * (rel_noise / 0.02) ** 0.25, 0.02, half_width))
        fit = _local_fit_vertex(t, R, i, width * R[i] / u_c, noise_sd_m, t_c=R[i] / u_c)
        if fit is not None:
            return fit
    if i == 0 or i == R.size - 1:
        return RmaxResult(i, float(t[i]), float(R[i]), float(R[i]), "sample (at record end)")
    v = parabola_vertex(t[i - 1 : i + 2], R[i - 1 : i + 2])
    flat_top = v is None or not (t[i - 1] < v[0] < t[i + 1]) or v[1] < R[i]
    t_sd = r_sd = float("nan")
    if method == "local-fit" and noise_sd_m > 0:
        # a fallback of the local fit keeps an honest uncertainty (once it had none, so
        # the time of the maximum was taken as known: a frame off on a camera record). Where the
        # noise hides the top, the time is capped by its half-width, the radius by two noise sd.
        flat = _flat_top_sd(R[i], noise_sd_m, R[i] / u_c)
        if flat_top:
            t_sd, r_sd = max(flat, float(t[i + 1] - t[i - 1]) / math.sqrt(24.0)), float(noise_sd_m)
        else:
            t_sd, r_sd = _three_point_vertex_sd(t[i - 1 : i + 2], R[i - 1 : i + 2], noise_sd_m, R[i] / u_c)
            t_sd, r_sd = min(t_sd, flat), min(r_sd, 2.0 * noise_sd_m)
    if flat_top:
        return RmaxResult(i, float(t[i]), float(R[i]), float(R[i]), "sample (flat top)", t_sd, r_sd)
    return RmaxResult(i, float(v[0]), float(v[1]), float(R[i]), "parabola", t_sd, r_sd)


def _flat_top_sd(rmax: float, noise_sd_m: float, t_c: float) -> float:
    """[s] Half-width of the top where the noise hides the maximum: R falls by 2 noise sd within
    t_c sqrt(4 sigma / (K R)) of it (R ~ Rmax (1 - K t*^2 / 2), K from ``CURVATURE_PRIOR``); half of
    that taken as a standard deviation of the time of the maximum."""
    return 0.5 * t_c * math.sqrt(4.0 * max(noise_sd_m, 0.0) / (CURVATURE_PRIOR[0] * rmax))


def _three_point_vertex_sd(t3, R3, noise_sd_m: float, t_c: float) -> tuple:
    """([s], [m]) Standard errors of the vertex of the parabola through three equally spaced samples
    with independent noise ``noise_sd_m``, by linear error propagation. The second difference D is
    taken as observed and as expected from the curvature prior (D = -K R (h / t_c)^2), the larger
    error kept: where the noise dominates D (a fast camera, 2 % noise), the observed D is mostly
    noise, and its size says nothing about how well the vertex is placed."""
    h = 0.5 * float(t3[2] - t3[0])
    rm, r0, rp = (float(x) for x in R3)
    N = rm - rp
    d_expected = -CURVATURE_PRIOR[0] * r0 * (h / t_c) ** 2
    out = []
    for D in (rm - 2.0 * r0 + rp, d_expected):
        if not D < 0.0:
            return float("inf"), float(noise_sd_m)
        gx = np.array([h / (2 * D) * (1 - N / D), h * N / D**2, -h / (2 * D) * (1 + N / D)])
        # R_v = r0 - N^2 / (8 D)
        gr = np.array(
            [-N / (4 * D) + N * N / (8 * D * D), 1.0 - 2.0 * N * N / (8 * D * D), N / (4 * D) + N * N / (8 * D * D)]
        )
        out.append((float(noise_sd_m * np.linalg.norm(gx)), float(noise_sd_m * np.linalg.norm(gr))))
    return max(o[0] for o in out), max(o[1] for o in out)


#: Curvature of R(t) at the maximum, R ~ Rmax (1 - K t*^2 / 2), as a prior for the local fit:
#: K = 1 - p_v/p8 + (elastic and surface stress)/p8 at Rmax, 1.0-1.5 for IMR gels (K = 1 for an
#: empty bubble in water; the NHKV stress at Rmax/Req ~ 8 adds ~2.5 G/p8).
CURVATURE_PRIOR = (1.2, 0.4)


def _local_fit_vertex(t, R, i: int, half_width_s: float, noise_sd_m: float, t_c: float):
    """The vertex of the least-squares parabola through the samples within ``half_width_s`` of a
    centre, with standard errors; None if unusable. The first centre is the peak of a 5-sample
    running mean (not the noisiest sample), the second the first fit's vertex. With noise, the
    curvature has a Gaussian prior (``CURVATURE_PRIOR``) so that a window with few frames before the
    maximum cannot bend the parabola the wrong way."""
    if R.size >= 5:
        smooth = np.convolve(R, np.ones(5) / 5.0, mode="same")
        smooth[:2], smooth[-2:] = -np.inf, -np.inf
        centre = float(t[int(np.argmax(smooth))])
    else:
        centre = float(t[i])
    k_mean, k_sd = CURVATURE_PRIOR
    c2_prior = -0.5 * k_mean * R[i] * (half_width_s / t_c) ** 2  # [m] per tau^2
    lam = (noise_sd_m / (k_sd / k_mean * abs(c2_prior))) ** 2 if noise_sd_m > 0 else 0.0
    for _attempt in range(2):
        sel = np.flatnonzero(np.abs(t - centre) <= half_width_s)
        if sel.size < 3:
            return None
        tau = (t[sel] - centre) / half_width_s
        X = np.vander(tau, 3, increasing=True)
        A = np.vstack([X, [0.0, 0.0, math.sqrt(lam)]])
        coef = np.linalg.lstsq(A, np.append(R[sel], math.sqrt(lam) * c2_prior), rcond=None)[0]
        if not coef[2] < 0.0:
            return None
        x = -coef[1] / (2.0 * coef[2])
        centre = centre + x * half_width_s
        # two samples on each side of the vertex at least: with fewer (a record that starts at its
        # maximum, as the paper's synthetic design does) the fit extrapolates, and the sample or
        # the three-point parabola is the better estimate
        if abs(x) > 1.0 or np.sum(t[sel] < centre) < 2 or np.sum(t[sel] > centre) < 2:
            return None
    rmax = float(coef[0] + coef[1] * x + coef[2] * x * x)
    dof = sel.size - 3
    resid = R[sel] - X @ coef
    if dof <= 0:
        return RmaxResult(i, centre, rmax, float(R[i]), "local-fit", float("nan"), float("nan"), int(sel.size))
    s2 = max(float(resid @ resid / dof), noise_sd_m**2)
    cov = s2 * np.linalg.pinv(A.T @ A)
    g_r = np.array([1.0, x, x * x])  # d p(x)/d coef at the vertex (p'(x) = 0)
    g_x = np.array([0.0, -1.0, -2.0 * x]) / (2.0 * coef[2])  # d x/d coef from p'(x) = c1 + 2 c2 x = 0
    rmax_sd = math.sqrt(max(float(g_r @ cov @ g_r), 0.0))
    t_sd = math.sqrt(max(float(g_x @ cov @ g_x), 0.0)) * half_width_s
    return RmaxResult(i, centre, rmax, float(R[i]), "local-fit", t_sd, rmax_sd, int(sel.size))


@dataclass(frozen=True)
class CollapseResult:
    """``index`` of the smallest sample of the first collapse; ``t_s`` [s] and ``r_m`` [m] of the
    (refined) minimum; ``rebound_index`` the first sample of the rebound; ``method`` used."""

    index: int
    t_s: float
    r_m: float
    rebound_index: int
    method: str


def first_collapse(
    t_s,
    R_m,
    i_max: int,
    method: str = "parabola",
    rebound_frac: float = 0.05,
    noise_sd_m: float = 0.0,
    t_min_s: float = 0.0,
    t_max_s: float | None = None,
    deep_frac: float = 0.5,
) -> CollapseResult:
    """The first radius minimum after the maximum at index ``i_max`` (at time ``t_max_s``, default
    the sample's).

    Walks forward from ``i_max`` keeping the running minimum; the collapse is that minimum once the
    radius has risen above it by more than ``rebound_frac * R[i_max]`` and more than 4
    ``noise_sd_m`` (capped at 0.08 R[i_max]: damped gels rebound by little more; when the noise sets
    that bar, two frames in a row must clear it), at least ``t_min_s`` after the maximum. A minimum
    below ``deep_frac * R[i_max]`` needs only 2 ``noise_sd_m``: no noise dip is that deep (on the
    way down the frames fall by more than the noise each), while a small bubble's sampled rebound at
    1 Mfps can rise only ~0.05-0.1 Rmax above its sampled minimum, at the 4-sd bar under 2 % noise.
    ``method="parabola"`` refines
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

    def bar(k_sd: float) -> tuple:
        noise_rise = min(k_sd * float(noise_sd_m), 0.08 * R[i_max])
        # noise sets the bar: one lucky frame is not enough
        return max(rebound_frac * R[i_max], noise_rise), noise_rise > rebound_frac * R[i_max]

    shallow, deep = bar(4.0), bar(2.0)
    t_earliest = (t[i_max] if t_max_s is None else float(t_max_s)) + float(t_min_s)
    im, m = i_max, R[i_max]
    rebound = None
    for j in range(i_max + 1, R.size):
        if R[j] < m:
            im, m = j, R[j]
            continue
        rise, confirm = deep if m < deep_frac * R[i_max] else shallow
        if R[j] - m > rise and t[j] >= t_earliest and (not confirm or j + 1 == R.size or R[j + 1] - m > rise):
            rebound = j
            break
    if rebound is None:
        where = "at its minimum" if im == R.size - 1 else "before the radius rebounds"
        raise RecordTooShort(
            f"record too short to reach the first collapse: it ends {where} "
            f"(last sample t = {(t[-1] - t[i_max]) * 1e6:.4g} µs after the maximum, "
            f"R = {R[-1] / R[i_max]:.3g} Rmax)"
        )
    if method == "sample":
        return CollapseResult(im, float(t[im]), float(R[im]), rebound, "sample")
    v = parabola_vertex(t[im - 1 : im + 2], R[im - 1 : im + 2])
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
    settled: bool = True


#: The tail's spread beyond the noise, over its mean, above which it has not settled
UNSETTLED = 0.1


def estimate_req(R_m, i_collapse: int, n_tail: int = 20, noise_sd_m: float | None = None) -> ReqResult:
    """Mean of the last ``n_tail`` samples, restricted to samples after the first collapse.

    Parameters
    ----------
    R_m : array_like, shape (n,)
        Radius [m].
    i_collapse : int
        Index of the first-collapse sample; the tail never reaches back to it.
    n_tail : int
        Number of samples to average (default 20).
    noise_sd_m : float, optional
        Measurement-noise sd [m] of the record. Given, ``sd_m`` is sqrt(max(s^2 - noise^2, 0) +
        noise^2 / n) with s the tail's sample sd: the oscillation counts in full, the noise averages
        down. Not given, ``sd_m`` is s.

    A warning is set when fewer than ``n_tail`` samples follow the collapse (the tail then includes
    the first rebound) or when the tail still varies by more than :data:`UNSETTLED` (10 %, its
    spread beyond the noise over its mean). Such a tail has not settled: ``req_m`` is then
    sqrt(low * mean), with ``low`` the tail's minimum raised by the expected least of ``n`` noise draws, and ``sd_m`` puts
    both at one sd in log, or the spread's sd if wider (``settled`` False). Why: the mean of a nonlinear oscillation lies
    above its equilibrium (the bubble lingers near its maxima) -- on camera-style relaxation
    records 1.3-2.2x the true Req, far outside the tail-spread sd -- while its lowest point lies
    at or below it; between the two the estimate was within 0.33 in log of the truth on every
    such record of the diagnosis matrix (docs/methods.md).
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
    spread = sd
    noise = float(noise_sd_m or 0.0)
    if noise_sd_m is not None and n > 1:
        sd = math.sqrt(max(spread * spread - noise * noise, 0.0) + noise * noise / n)
    if n < n_tail:
        warning = f"only {n} sample(s) after the first collapse; Req from them includes the rebound and is unreliable"
    elif math.sqrt(max(spread * spread - noise * noise, 0.0)) > UNSETTLED * mean:
        # the least of n noisy samples lies ~1.87 noise sd (n = 20; Blom's approximation) below its curve
        low = float(tail.min()) - noise * float(norm.ppf(0.625 / (n + 0.25)))
        if 0.0 < low < mean:
            req = math.sqrt(low * mean)
            sd_req = req * max(0.5 * math.log(mean / low), sd / mean)  # never narrower than the spread's
            warning = (
                f"late-time radius still varies by {100 * spread / mean:.0f}% (sd/mean) over the last {n} "
                f"samples: the tail has not settled; Req {req * 1e6:.4g} µm between its lowest point "
                f"({low * 1e6:.4g} µm) and its mean ({mean * 1e6:.4g} µm), sd {sd_req * 1e6:.3g} µm"
            )
            return ReqResult(req, sd_req, se, n, start, warning, settled=False)
        warning = (
            f"late-time radius still varies by {100 * spread / mean:.0f}% (sd/mean) over the last {n} "
            f"samples; Req is uncertain"
        )
    return ReqResult(mean, sd, se, n, start, warning)


def time_scale_s(rmax_m, rho: float, p8: float):
    """``t_c = Rmax / sqrt(p8/rho)`` [s] (scalar or array like ``rmax_m`` [m])."""
    uc = math.sqrt(p8 / rho)
    return np.asarray(rmax_m, dtype=float) / uc if np.ndim(rmax_m) else float(rmax_m) / uc


def nondimensionalise(t_s, R_m, t0_s: float, rmax_m: float, tc_s: float) -> tuple:
    """``(t*, R*) = ((t - t0)/t_c, R/Rmax)``, arrays shaped like the inputs."""
    return ((np.asarray(t_s, dtype=float) - t0_s) / tc_s, np.asarray(R_m, dtype=float) / rmax_m)


def resample(
    t_star, R_star, dt_star: float = 0.025, n_steps: int = 120, method: str = "linear", anchor: bool = True
) -> tuple:
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
