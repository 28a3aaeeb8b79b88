"""Synthetic datasets from the forward model (``imrbayes simulate``), in the format of interfaces.md §1.

Random draws, in this order, all from one ``numpy.random.default_rng(seed)``: Rmax for every
experiment (if given as ``MEAN:SD``), Rmax/Req for every experiment (if ``MEAN:SD``), then the
noise of experiment 1, 2, ... Draws from ``MEAN:SD`` are normal, redrawn while non-physical
(Rmax <= 0 or Rmax/Req <= 1). Noise is added to R* independently per sample; a noisy radius <= 0 is
redrawn (a truncated Gaussian, counted in ``truth.json``).

Noise shapes (:func:`parse_noise`, evaluated on the noise-free record by :func:`noise_sd`): constant
in R* (``0.01``) or in µm (``2um``), the paper's verification noise (``paper``), proportional to the
radius (``0.02R``: sd = 0.02 R*, as an edge located to a fixed fraction of the bubble's size) and
larger near collapses (``0.01C``: sd = 0.01 (1 + 4 exp(-((R* - R*_c)/0.05)^2)), R*_c the radius at
the nearest collapse in time, a collapse being a local minimum of the noise-free R* of prominence
>= 0.05; a blurred, small bubble is located worst). Terms joined by ``+`` add their variances.

Camera-style records (interfaces.md §4) draw from two further streams of the same seed, so that a
dataset made without them is unchanged: the sub-frame phase of each experiment's first frame
(``SeedSequence(seed, spawn_key=(1,))``, uniform in one frame) and the per-bubble material scatter
(``SeedSequence(seed, spawn_key=(2,))``, log-normal around the given value). Frames before the
maximum (``pre_max_s``) are filled with the **mirror of the collapse**, R(t_max - s) = R(t_max + s):
the forward model starts at rest at Rmax, and the growth that precedes it is not modelled; near the
flat maximum the mirror is exact to second order, which is all the preprocessing looks at.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imrbayes.data.csvio import write_experiment_csv
from imrbayes.data.noise import paper_sigma
from imrbayes.errors import InputError
from imrbayes.io import write_json

__all__ = [
    "Spec",
    "parse_spec",
    "parse_noise",
    "noise_sd",
    "collapse_weight",
    "draw_values",
    "noisy",
    "simulate_dataset",
    "write_dataset",
    "camera_times",
    "draw_phases",
    "draw_scatter",
    "PHASE_STREAM",
    "SCATTER_STREAM",
    "COLLAPSE_PEAK",
    "COLLAPSE_WIDTH",
    "COLLAPSE_PROMINENCE",
]

#: spawn keys of the camera-phase and material-scatter streams (module docstring)
PHASE_STREAM, SCATTER_STREAM = (1,), (2,)
#: the collapse-weighted noise (``0.01C``): sd = s (1 + COLLAPSE_PEAK w), w = exp(-((R* - R*_c)/COLLAPSE_WIDTH)^2),
#: R*_c the nearest collapse's radius, a collapse a local minimum of prominence >= COLLAPSE_PROMINENCE [R*]
COLLAPSE_PEAK, COLLAPSE_WIDTH, COLLAPSE_PROMINENCE = 4.0, 0.05, 0.05


@dataclass(frozen=True)
class Spec:
    """A fixed value (``sd == 0``) or a normal distribution ``MEAN:SD``."""

    mean: float
    sd: float = 0.0

    def to_dict(self) -> dict:
        return {"mean": self.mean, "sd": self.sd}


def parse_spec(text: str, option: str) -> Spec:
    """``"263e-6"`` or ``"263e-6:20e-6"`` -> :class:`Spec` (finite, mean > 0, sd >= 0)."""
    parts = str(text).split(":")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise InputError(option, f"expected a number or MEAN:SD, got {text!r}")
    if len(values) > 2 or not all(math.isfinite(v) for v in values):
        raise InputError(option, f"expected a number or MEAN:SD, got {text!r}")
    mean, sd = values[0], (values[1] if len(values) == 2 else 0.0)
    if mean <= 0 or sd < 0:
        raise InputError(option, f"needs a positive mean and a non-negative sd, got {text!r}")
    return Spec(mean, sd)


_NOISE_SYNTAX = (
    "paper, none, a number (sd in R*), a number with um (sd in µm), a number with R (sd = that "
    "fraction of R*), a number with C (larger near collapses) or a sum of these joined by '+'"
)


def _noise_term(term: str, text: str) -> dict:
    t = term.strip().lower()
    if t == "paper":
        return {"kind": "paper", "sigma": "|R*-1|/20 + (1-exp(-t*/10))/30 (the paper's verification noise)"}
    if t == "none":
        return {"kind": "none"}
    suffix = next((u for u in ("um", "r", "c") if t.endswith(u)), "")
    try:
        sd = float(t[: len(t) - len(suffix)])
    except ValueError:
        raise InputError("--noise", f"expected {_NOISE_SYNTAX}, got {text!r}")
    if not math.isfinite(sd) or sd < 0:
        raise InputError("--noise", f"sd must be a finite number >= 0, got {text!r}")
    if sd == 0:
        return {"kind": "none"}
    if suffix == "r":
        return {"kind": "proportional", "fraction": sd, "sigma": f"{sd:g} R*"}
    if suffix == "c":
        return {
            "kind": "collapse",
            "sd": sd,
            "peak": COLLAPSE_PEAK,
            "width_r_star": COLLAPSE_WIDTH,
            "prominence_r_star": COLLAPSE_PROMINENCE,
            "sigma": f"{sd:g} (1 + {COLLAPSE_PEAK:g} exp(-((R* - R*_c)/{COLLAPSE_WIDTH:g})^2)), R*_c the radius "
            f"at the nearest collapse (local minimum of prominence >= {COLLAPSE_PROMINENCE:g})",
        }
    return {"kind": "gaussian_um", "sd_um": sd} if suffix == "um" else {"kind": "gaussian", "sd": sd}


def parse_noise(text: str) -> dict:
    """``paper`` | ``none`` | a number (sd in R*) | a number with ``um`` (sd in µm) | a number with
    ``R`` (sd = that fraction of R*) | a number with ``C`` (sd larger near collapses, module
    docstring) | a sum of these joined by ``+`` (independent terms: their variances add) -> a
    description dict."""
    terms = [_noise_term(term, text) for term in str(text).split("+")]
    terms = [t for t in terms if t["kind"] != "none"]
    if not terms:
        return {"kind": "none"}
    return terms[0] if len(terms) == 1 else {"kind": "sum", "terms": terms}


def collapse_weight(
    t_star, R_star, peak: float = COLLAPSE_PEAK, width: float = COLLAPSE_WIDTH, prominence: float = COLLAPSE_PROMINENCE
) -> np.ndarray:
    """The factor 1 + peak exp(-((R* - R*_c)/width)^2) of the collapse-weighted noise, per sample.

    Parameters
    ----------
    t_star : array (n,)
        Times of the samples [-] (t* from the maximum), in any order.
    R_star : array (n,)
        Noise-free R* = R/Rmax [-] at those times.
    peak, width, prominence : float
        Excess sd at a collapse [-], the R* width of the excess [-], and the prominence [R*] a local
        minimum needs to count as a collapse.

    Returns
    -------
    array (n,)
        The factor [-]; 1 everywhere when the record has no collapse.
    """
    from scipy.signal import find_peaks

    t = np.asarray(t_star, dtype=float)
    R = np.asarray(R_star, dtype=float)
    order = np.argsort(t, kind="stable")
    mins, _ = find_peaks(-R[order], prominence=prominence)
    if mins.size == 0:
        return np.ones(R.shape)
    tc, rc = t[order][mins], R[order][mins]
    nearest = np.abs(t[..., None] - tc).argmin(axis=-1)
    return 1.0 + peak * np.exp(-(((R - rc[nearest]) / width) ** 2))


def noise_sd(t_star, R_star, noise: dict, rmax_m: float) -> np.ndarray:
    """The noise sd [R*] of every sample of a record (R* = R/Rmax, noise-free; t* from the maximum:
    negative before it; the paper's model is evaluated at |t*|)."""
    R = np.asarray(R_star, dtype=float)
    terms = noise["terms"] if noise["kind"] == "sum" else [noise]
    sds = []
    for term in terms:
        if term["kind"] == "paper":
            sds.append(paper_sigma(np.abs(np.asarray(t_star, dtype=float)), R))
        elif term["kind"] == "gaussian":
            sds.append(np.full(R.shape, float(term["sd"])))
        elif term["kind"] == "gaussian_um":
            sds.append(np.full(R.shape, float(term["sd_um"]) * 1e-6 / float(rmax_m)))
        elif term["kind"] == "proportional":
            sds.append(float(term["fraction"]) * np.abs(R))
        elif term["kind"] == "collapse":
            sds.append(
                float(term["sd"])
                * collapse_weight(t_star, R, term["peak"], term["width_r_star"], term["prominence_r_star"])
            )
    if not sds:
        return np.zeros(R.shape)
    return sds[0] if len(sds) == 1 else np.sqrt(np.sum(np.square(sds), axis=0))


def draw_values(spec: Spec, n: int, rng, valid, option: str) -> np.ndarray:
    """``n`` values of ``spec``; normal draws redrawn (at most 1000 rounds) until ``valid(x)``."""
    if spec.sd == 0.0:
        return np.full(n, spec.mean)
    x = rng.normal(spec.mean, spec.sd, n)
    for _ in range(1000):
        bad = ~valid(x)
        if not bad.any():
            return x
        x[bad] = rng.normal(spec.mean, spec.sd, int(bad.sum()))
    raise InputError(option, f"{spec.mean}:{spec.sd} gives non-physical values too often")


def noisy(t_star, R_star, noise: dict, rng, rmax_m: float = 1.0) -> tuple:
    """``(R_star + noise, n_redrawn)``; noisy values <= 0 are redrawn (at most 100 rounds). ``rmax_m``
    [m] converts a noise given in µm to R*."""
    R = np.asarray(R_star, dtype=float)
    if noise["kind"] == "none":
        return R.copy(), 0
    sd = noise_sd(t_star, R, noise, rmax_m)
    out = R + sd * rng.standard_normal(R.shape)
    redrawn = 0
    for _ in range(100):
        bad = out <= 0.0
        if not bad.any():
            return out, redrawn
        redrawn += int(bad.sum())
        out[bad] = R[bad] + sd[bad] * rng.standard_normal(int(bad.sum()))
    raise InputError("--noise", "noise this large makes radii negative; use a smaller sd")


def simulate_dataset(fm, params, rmax_m, req_m, t_star_list) -> list:
    """Noise-free R* for every experiment on its own t* grid (t* from the maximum; samples before it,
    t* < 0, are the mirror of the collapse: R*(-s) = R*(s)). ``params``: one dict for every
    experiment, or a list of one dict per experiment."""
    per_exp = params if isinstance(params, (list, tuple)) else [params] * len(t_star_list)
    out = []
    for p, rmax, req, ts in zip(per_exp, rmax_m, req_m, t_star_list):
        ts = np.asarray(ts, dtype=float)
        t_abs, back = np.unique(np.abs(ts), return_inverse=True)
        R = np.asarray(fm.simulate_radius(p, rmax_m=float(rmax), req_m=float(req), t_star=t_abs), dtype=float)
        out.append(R[back] if R.shape == t_abs.shape else R)
    return out


def camera_times(
    tc_s: float, frame_s: float, t_end_star: float, pre_max_s: float = 0.0, phase_s: float = 0.0
) -> np.ndarray:
    """Frame times in t* from the maximum for a camera of interval ``frame_s`` [s]: the frames fall
    at ``phase_s + k frame_s`` [s] (0 <= phase_s < frame_s), from the last one at or before
    ``-pre_max_s`` [s] to ``t_end_star`` (t* units, ``tc_s`` = Rmax sqrt(rho/p8) [s] per unit)."""
    first = math.floor((-pre_max_s - phase_s) / frame_s + 1e-9)
    last = int(math.floor((t_end_star * tc_s - phase_s) / frame_s + 1e-9))
    return (phase_s + np.arange(first, last + 1) * frame_s) / tc_s


def draw_phases(seed: int, n: int, frame_s: float, random: bool) -> np.ndarray:
    """Each experiment's sub-frame phase [s]: uniform in [0, frame_s) from the phase stream, or 0."""
    if not random:
        return np.zeros(n)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=PHASE_STREAM))
    return rng.uniform(0.0, frame_s, n)


def draw_scatter(seed: int, params: dict, scatter: dict, n: int) -> list:
    """One parameter dict per experiment: ``params[name] * exp(sd z)`` (log-normal with median
    ``params[name]``, relative sd ~ ``sd``) for every ``name`` in ``scatter``, in the order of
    ``params``; the others as given."""
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=SCATTER_STREAM))
    z = rng.standard_normal((n, len(params)))
    return [
        {
            name: (float(v) * math.exp(float(scatter[name]) * z[i, j]) if name in scatter else float(v))
            for j, (name, v) in enumerate(params.items())
        }
        for i in range(n)
    ]


def write_dataset(out: Path, records: list, meta: dict, truth: dict) -> list:
    """Write ``exp_001.csv``... (``t_s,R_m``), ``meta.json`` and ``truth.json`` into ``out``.

    ``records`` is a list of ``(t_s, R_m)`` arrays. Returns the file names written.
    """
    out = Path(out)
    names = []
    for i, (t_s, R_m) in enumerate(records, start=1):
        name = f"exp_{i:03d}.csv"
        write_experiment_csv(out / name, t_s, R_m)
        names.append(name)
    write_json(out / "meta.json", meta, indent=2)
    write_json(out / "truth.json", truth, indent=2)
    return names
