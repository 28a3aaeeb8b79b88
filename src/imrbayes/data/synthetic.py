"""Synthetic datasets from the forward model (``imrbayes simulate``), in the format of interfaces.md §1.

Random draws, in this order, all from one ``numpy.random.default_rng(seed)``: Rmax for every
experiment (if given as ``MEAN:SD``), Rmax/Req for every experiment (if ``MEAN:SD``), then the
noise of experiment 1, 2, ... Draws from ``MEAN:SD`` are normal, redrawn while non-physical
(Rmax <= 0 or Rmax/Req <= 1). Noise is added to R* independently per sample; a noisy radius <= 0 is
redrawn (a truncated Gaussian, counted in ``truth.json``).
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

__all__ = ["Spec", "parse_spec", "parse_noise", "draw_values", "noisy", "simulate_dataset", "write_dataset"]


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


def parse_noise(text: str) -> dict:
    """``paper`` | ``none`` | a number (sd in R*) -> a description dict."""
    t = str(text).strip().lower()
    if t == "paper":
        return {"kind": "paper", "sigma": "|R*-1|/20 + (1-exp(-t*/10))/30 (methods.md §5)"}
    if t == "none":
        return {"kind": "none"}
    try:
        sd = float(t)
    except ValueError:
        raise InputError("--noise", f"expected paper, none or a number (sd in R*), got {text!r}")
    if not math.isfinite(sd) or sd < 0:
        raise InputError("--noise", f"sd must be a finite number >= 0, got {text!r}")
    return {"kind": "gaussian", "sd": sd} if sd > 0 else {"kind": "none"}


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


def noisy(t_star, R_star, noise: dict, rng) -> tuple:
    """``(R_star + noise, n_redrawn)``; noisy values <= 0 are redrawn (at most 100 rounds)."""
    R = np.asarray(R_star, dtype=float)
    if noise["kind"] == "none":
        return R.copy(), 0
    sd = paper_sigma(t_star, R) if noise["kind"] == "paper" else np.full(R.shape, float(noise["sd"]))
    out = R + sd * rng.standard_normal(R.shape)
    redrawn = 0
    for _ in range(100):
        bad = out <= 0.0
        if not bad.any():
            return out, redrawn
        redrawn += int(bad.sum())
        out[bad] = R[bad] + sd[bad] * rng.standard_normal(int(bad.sum()))
    raise InputError("--noise", "noise this large makes radii negative; use a smaller sd")


def simulate_dataset(fm, params: dict, rmax_m, req_m, t_star_list) -> list:
    """Noise-free R* for every experiment: ``fm.simulate_radius`` on each experiment's t* grid."""
    return [np.asarray(fm.simulate_radius(params, rmax_m=float(rmax), req_m=float(req), t_star=ts), dtype=float)
            for rmax, req, ts in zip(rmax_m, req_m, t_star_list)]


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
