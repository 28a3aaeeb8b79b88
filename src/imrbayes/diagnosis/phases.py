"""Phases of a record from the measured minima: to the first collapse, then each rebound + collapse.

A minimum is a local minimum of the resampled R* with prominence >= ``prominence`` (R*), at least
``min_sep`` samples from the previous one. The prominence is each record's own: 4 noise sd
(``Observations.noise_sd``), at least 0.02 R*; 0.1 R* where the noise is unknown. (A fixed 0.1 R*
missed the rebounds of viscous or damaged bubbles, 0.05-0.09 R* high at 2 µm camera noise, and
even some first collapses: with one minimum found, "to the 2nd collapse" became "just past the
1st", the forecast scheme fitted the first collapse alone and the damage model got one break
instead of three -- measured on camera-style damage data, where the damage candidate then
forecast 40 % worse than the baseline.) The phase boundaries of the dataset are the medians
over experiments of the k-th minimum; each experiment also keeps its own minima (used as the break
times of the damage model).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import find_peaks

__all__ = ["Phases", "find_minima", "phases_of"]

PHASE_NAMES = ("first-collapse", "second-collapse", "third-collapse", "fourth-collapse", "fifth-collapse")


def find_minima(R, prominence: float = 0.1, min_sep: int = 6) -> np.ndarray:
    """Sample indices of the collapses (local minima) of one resampled curve: minima of the
    3-point running mean with the given prominence, later minima at least 0.4 x (first-collapse
    index) apart, each moved to the lowest raw sample within +-3."""
    R = np.asarray(R, dtype=float)
    Rs = np.convolve(np.pad(R, 1, mode="edge"), np.ones(3) / 3, mode="valid")
    first, _ = find_peaks(-Rs, prominence=prominence, distance=min_sep)
    if first.size == 0:
        return first.astype(int)
    sep = max(min_sep, int(0.4 * first[0]))
    idx, _ = find_peaks(-Rs, prominence=prominence, distance=sep)
    out = []
    for i in idx:
        a, b = max(0, i - 3), min(R.size, i + 4)
        out.append(a + int(np.argmin(R[a:b])))
    return np.array(out, dtype=int)


@dataclass
class Phases:
    """``minima`` (n_exp, n_min) per-experiment minimum indices (median-filled); ``bounds`` the
    sample-index boundaries of the phases, phase j covering samples (bounds[j], bounds[j+1]]."""

    minima: np.ndarray
    bounds: list
    names: list
    t_star: np.ndarray

    def minima_t(self) -> np.ndarray:
        return self.t_star[self.minima]

    def collapse_index(self, k: int) -> int:
        """Last sample of the window "to the k-th collapse" (k = 1, 2, ...): the median k-th
        minimum plus two samples (so the minimum itself is inside)."""
        k = min(k, self.minima.shape[1])
        return int(min(len(self.t_star) - 1, np.median(self.minima[:, k - 1]) + 2))

    def masks(self) -> list:
        n = len(self.t_star)
        out = []
        for a, b in zip(self.bounds[:-1], self.bounds[1:]):
            m = np.zeros(n, dtype=bool)
            m[a + 1 : b + 1] = True
            out.append(m)
        return out

    def to_list(self) -> list:
        return [
            {"phase": nm, "t_star": [float(self.t_star[a]), float(self.t_star[b])]}
            for nm, a, b in zip(self.names, self.bounds[:-1], self.bounds[1:])
        ]


#: prominence of a collapse [R*]: NOISE_PROMINENCE record noise sds, at least MIN_PROMINENCE;
#: FALLBACK_PROMINENCE when the record's noise is unknown
NOISE_PROMINENCE, MIN_PROMINENCE, FALLBACK_PROMINENCE = 4.0, 0.02, 0.1


def prominences(obs) -> np.ndarray:
    """Per experiment, the prominence a minimum needs (module doc) [R*]."""
    sd = np.asarray(obs.noise_sd, dtype=float)  # NaN where unknown (Observations fills it)
    return np.where(np.isfinite(sd) & (sd > 0), np.maximum(MIN_PROMINENCE, NOISE_PROMINENCE * sd), FALLBACK_PROMINENCE)


def phases_of(obs, max_collapses: int = 3, prominence: float | None = None) -> Phases:
    """Phases of the observations ``obs`` (Observations) from the measured minima; ``prominence``
    [R*] overrides the per-record default (:func:`prominences`)."""
    n = obs.n_samples
    prom = prominences(obs) if prominence is None else np.full(obs.n_exp, float(prominence))
    found = [find_minima(r, p) for r, p in zip(obs.R_star, prom)]
    n_min = max(1, min(max_collapses, max(len(f) for f in found)))
    M = np.full((obs.n_exp, n_min), -1, dtype=int)
    for i, f in enumerate(found):
        k = min(n_min, len(f))
        M[i, :k] = f[:k]
    for j in range(n_min):
        ok = M[:, j] >= 0
        if not ok.any():  # nobody has this minimum: extrapolate by the previous spacing
            prev = M[:, j - 1] if j else np.zeros(obs.n_exp, dtype=int)
            step = (M[:, j - 1] - (M[:, j - 2] if j > 1 else 0)) if j else np.full(obs.n_exp, n // 3)
            M[:, j] = np.minimum(n - 1, prev + step)
        else:
            M[~ok, j] = int(np.median(M[ok, j]))
    med = [int(np.median(M[:, j])) for j in range(n_min)]
    bounds = [0]
    for m in med:
        if m > bounds[-1] and m < n - 1:
            bounds.append(m)
    if bounds[-1] < n - 1:
        bounds.append(n - 1)
    names = (
        list(PHASE_NAMES[: len(bounds) - 2]) + ["late"]
        if len(bounds) - 1 > len(med)
        else list(PHASE_NAMES[: len(bounds) - 1])
    )
    return Phases(M, bounds, names[: len(bounds) - 1], np.asarray(obs.t_star))
