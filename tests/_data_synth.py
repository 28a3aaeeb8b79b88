"""Synthetic radius curves with known maximum, first collapse and equilibrium radius (for tests).

``curve(t*) = q + (1 - q) exp(-g t*^2) (1 + cos(pi t*/tc)) / 2`` is symmetric about t* = 0, where it
has its global maximum 1 with zero slope; its first minimum is exactly at t* = tc with value q (the
cosine factor has a double zero there); it settles to q (Req/Rmax) at late times.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

RHO, P8 = 1064.0, 101325.0
SHARED = Path(__file__).resolve().parents[1] / ".." / "shared"
LIC = SHARED / "data" / "lic"


def curve(t_star, q=0.14, tc=0.9, g=1.0):
    t = np.asarray(t_star, dtype=float)
    return q + (1.0 - q) * np.exp(-g * t**2) * (1.0 + np.cos(np.pi * t / tc)) / 2.0


def record(
    rmax_m=400e-6,
    q=0.14,
    tc_star=0.9,
    h_star=0.09,
    offset=0.3,
    t_start=-0.3,
    t_end=3.3,
    clock_s=1.234e-5,
    rho=RHO,
    p8=P8,
):
    """(t_s, R_m, truth) sampled every h_star (in t*) with sample phase ``offset`` (fraction of h)."""
    tcs = rmax_m / math.sqrt(p8 / rho)
    ts = t_start + offset * h_star + np.arange(int((t_end - t_start) / h_star)) * h_star
    R = rmax_m * curve(ts, q, tc_star)
    truth = {"rmax_m": rmax_m, "req_m": q * rmax_m, "tc_s": tcs, "t_collapse_star": tc_star, "t0_s": clock_s}
    return ts * tcs + clock_s, R, truth


def write_csv(path, t_s, R_m, header="t_s,R_m"):
    with open(path, "w") as fh:
        fh.write(header + "\n")
        for t, r in zip(t_s, R_m):
            fh.write(f"{float(t)!r},{float(r)!r}\n")


def make_dataset(dirpath, n_exp=3, meta=None, **kw):
    """A dataset directory with ``n_exp`` synthetic experiments (different Rmax and sample phase)."""
    dirpath = Path(dirpath)
    dirpath.mkdir(parents=True, exist_ok=True)
    truths = []
    for i in range(n_exp):
        args = dict(rmax_m=(350 + 25 * i) * 1e-6, offset=(0.13 + 0.31 * i) % 1.0)
        args.update(kw)
        t, R, truth = record(**args)
        write_csv(dirpath / f"exp_{i + 1:03d}.csv", t, R)
        truths.append(truth)
    (dirpath / "meta.json").write_text(json.dumps(meta if meta is not None else {"material": "synthetic"}))
    return truths
