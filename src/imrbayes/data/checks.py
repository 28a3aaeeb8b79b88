"""Sanity checks on one measured record ``(t_s, R_m)`` before any preprocessing.

Each failed check raises :class:`~imrbayes.errors.InputError` naming the file and, where there is
one, the line. The unit checks catch the usual slips (µm or mm for metres, µs or ms or frame
numbers for seconds); they are deliberately loose so that no real IMR record trips them.
"""

from __future__ import annotations

import numpy as np

from imrbayes.errors import InputError

__all__ = ["check_record", "MAX_RADIUS_M", "MIN_RADIUS_M", "MAX_SPAN_S", "MAX_FRAME_INTERVAL_S", "MIN_SAMPLES"]

#: A bubble radius above 1 cm is not an IMR record: the values are almost surely µm or mm.
MAX_RADIUS_M = 0.01
#: A maximum radius below 0.1 µm cannot be imaged: the values are not in metres.
MIN_RADIUS_M = 1e-7
#: A record spanning more than 1 s is in µs (or frame numbers), not seconds.
MAX_SPAN_S = 1.0
#: A median frame interval above 1 ms (below 1000 frames/s) cannot resolve a collapse; times in ms?
MAX_FRAME_INTERVAL_S = 1e-3
#: Fewer samples than this cannot hold a maximum, a collapse and a rebound.
MIN_SAMPLES = 5


def _where(lines, i) -> str:
    return f"line {int(lines[i])}" if lines is not None else f"sample {i + 1}"


def check_record(t_s, R_m, source, lines=None, label: str = "") -> None:
    """Refuse a record that is not a plausible SI radius history.

    Parameters
    ----------
    t_s, R_m : array_like, shape (n,)
        Time [s] and radius [m], NaN rows already removed.
    source : str or path
        Starts the error message.
    lines : array_like of int, shape (n,), optional
        File line of each sample, for messages.
    label : str
        Prefix for messages (e.g. ``"experiment exp01: "``).
    """
    t = np.asarray(t_s, dtype=float)
    R = np.asarray(R_m, dtype=float)
    if t.shape != R.shape or t.ndim != 1:
        raise InputError(source, f"{label}time and radius have different lengths")
    n = t.size
    if n < MIN_SAMPLES:
        raise InputError(
            source,
            f"{label}only {n} valid sample(s); a record needs at least {MIN_SAMPLES} "
            f"(maximum, first collapse and rebound)",
        )
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(R))):
        raise InputError(source, f"{label}contains non-finite values")
    nonpos = np.flatnonzero(R <= 0.0)
    if nonpos.size:
        i = nonpos[0]
        more = f" ({nonpos.size} such samples)" if nonpos.size > 1 else ""
        raise InputError(source, f"{label}radius must be positive: R_m = {R[i]:g} at {_where(lines, i)}{more}")
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0.0)
    if bad.size:
        i = bad[0] + 1
        more = f" ({bad.size} such steps)" if bad.size > 1 else ""
        raise InputError(
            source,
            f"{label}time must increase strictly: t_s = {t[i]:.6g} at {_where(lines, i)} "
            f"follows t_s = {t[i - 1]:.6g}{more}",
        )
    rmax = float(R.max())
    if rmax > MAX_RADIUS_M:
        raise InputError(
            source,
            f"{label}radii up to {rmax:g} are too large for metres (over "
            f"{MAX_RADIUS_M:g} m); they look like µm or mm; R_m must be in metres",
        )
    if rmax < MIN_RADIUS_M:
        raise InputError(
            source, f"{label}the largest radius is {rmax:g} m, below {MIN_RADIUS_M:g} m; R_m must be in metres"
        )
    span = float(t[-1] - t[0])
    if span > MAX_SPAN_S:
        raise InputError(
            source,
            f"{label}times span {span:g}, over {MAX_SPAN_S:g} s; they look like µs or "
            f"frame numbers; t_s must be in seconds",
        )
    dt_med = float(np.median(dt))
    if dt_med > MAX_FRAME_INTERVAL_S:
        raise InputError(
            source,
            f"{label}median sampling interval {dt_med:g} s is too coarse for a bubble "
            f"record (over {MAX_FRAME_INTERVAL_S:g} s); are the times in ms? t_s must "
            f"be in seconds",
        )
