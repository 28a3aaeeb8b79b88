"""MATLAB ``.mat`` files of the public IMR pipelines (shared/data/lic/mat_originals/README.md).

Four layouts are recognised from their variable names and shapes; each is converted to SI exactly
as the shared CSVs were (t = 0 at the frame of the largest measured radius; frames with R = 0 or NaN,
which these pipelines use for "no bubble", dropped). Anything else is refused with a list of the
variables found: a unit is never guessed.

=====================  ==========================================================================
layout                 variables
=====================  ==========================================================================
``estrada-shifted``    ``shift_normRnew`` (n_exp, n) R/Rmax; ``Rmax`` (n_exp,) µm; ``t`` (n,) s
``circlefit-pixels``   ``Rnew`` (n,) pixels; ``deltax`` m/pixel; ``deltat`` s/frame
``franck-RofT``        ``t`` (n,) s; ``R`` (n,) µm; optional ``Req`` µm, ``tloc1..6`` 1-based indices
``umich-dualcam``      a single (n, 3) array: t [s], R camera 0° [µm], R camera 90° [µm]
=====================  ==========================================================================
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from imrbayes.data.records import Experiment
from imrbayes.errors import InputError

__all__ = ["read_mat", "LAYOUTS"]

LAYOUTS = {
    "estrada-shifted": "shift_normRnew (R/Rmax, rows circularly shifted), Rmax [µm], t [s]",
    "circlefit-pixels": "Rnew [pixels], deltax [m/pixel], deltat [s/frame]",
    "franck-RofT": "t [s], R [µm], optional Req [µm] and tloc1..6 [1-based collapse indices]",
    "umich-dualcam": "one (n, 3) array: t [s], R camera 0° [µm], R camera 90° [µm]",
}
_KEYS = {
    "estrada-shifted": ("shift_normRnew", "Rmax", "t"),
    "circlefit-pixels": ("Rnew", "deltax", "deltat"),
    "franck-RofT": ("t", "R"),
    "umich-dualcam": ("a single n x 3 array",),
}
# Plausible magnitudes for the documented units; outside them the file is refused.
_UM_RANGE = (0.1, 1e4)  # a radius in µm
_PX_SIZE_RANGE = (1e-9, 1e-3)  # metres per pixel
_FRAME_RANGE = (1e-10, 1e-2)  # seconds per frame


def _describe(name, value) -> str:
    if isinstance(value, np.ndarray):
        kind = {"float64": "double", "float32": "single", "object": "cell"}.get(value.dtype.name, value.dtype.name)
        if value.dtype.names:
            kind = "struct"
        elif value.dtype.kind == "U":
            kind = "char"
        return f"{name} ({'x'.join(str(s) for s in value.shape)} {kind})"
    return f"{name} ({type(value).__name__})"


def _variables(path: Path) -> dict:
    import scipy.io

    try:
        data = scipy.io.loadmat(str(path), squeeze_me=False)
    except NotImplementedError:
        raise InputError(path, "is a MATLAB v7.3 (HDF5) file, which is not supported; re-save it with save(..., '-v7')")
    except FileNotFoundError:
        raise InputError(path, "no such file")
    except Exception as exc:  # scipy raises many types on foreign bytes
        msg = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
        raise InputError(path, f"cannot be read as a MATLAB .mat file ({msg})")
    return {k: v for k, v in data.items() if not k.startswith("__")}


def _numeric(path, variables, name, *, ndim_max=2) -> np.ndarray:
    value = variables[name]
    if not isinstance(value, np.ndarray) or value.dtype.kind not in "biuf" or value.dtype.names:
        raise InputError(path, f"variable {_describe(name, value)} is not a numeric array")
    if value.ndim > ndim_max:
        raise InputError(path, f"variable {_describe(name, value)} has too many dimensions")
    return np.asarray(value, dtype=np.float64)


def _vector(path, variables, name) -> np.ndarray:
    a = _numeric(path, variables, name)
    if a.ndim == 2 and 1 not in a.shape:
        raise InputError(path, f"variable {_describe(name, variables[name])} should be a vector")
    return a.ravel()


def _scalar(path, variables, name) -> float:
    a = _vector(path, variables, name)
    if a.size != 1 or not np.isfinite(a[0]):
        raise InputError(path, f"variable {_describe(name, variables[name])} should be one finite number")
    return float(a[0])


def _check_um(path, name, values):
    finite = values[np.isfinite(values) & (values != 0)]
    if finite.size == 0:
        raise InputError(path, f"variable {name} holds no radius (all NaN or 0)")
    top = float(np.max(np.abs(finite)))
    if not (_UM_RANGE[0] <= top <= _UM_RANGE[1]):
        raise InputError(
            path,
            f"variable {name} should be in µm for this layout but its largest value is "
            f"{top:g}; refusing to guess the unit",
        )


def _valid(R) -> np.ndarray:
    return np.isfinite(R) & (R != 0.0)


def _estrada(path, v):
    S = _numeric(path, v, "shift_normRnew")
    rmax_um = _vector(path, v, "Rmax")
    t = _vector(path, v, "t")
    if S.ndim != 2 or S.shape[0] != rmax_um.size or S.shape[1] != t.size:
        raise InputError(
            path,
            f"estrada-shifted layout: shapes do not agree: shift_normRnew {S.shape}, Rmax {rmax_um.size}, t {t.size}",
        )
    _check_um(path, "Rmax", rmax_um)
    top = np.nanmax(np.where(np.isfinite(S), S, -np.inf), axis=1)
    if not np.all((top > 0.5) & (top < 1.5)):
        raise InputError(
            path,
            "variable shift_normRnew should hold R/Rmax (row maxima near 1), found row "
            f"maxima from {np.min(top):g} to {np.max(top):g}",
        )
    exps = []
    for i in range(S.shape[0]):
        keep = _valid(S[i])
        R_m = S[i] * rmax_um[i] * 1e-6
        j = int(np.argmax(np.where(keep, S[i], -np.inf)))
        t_s = t - t[j]
        exps.append(
            Experiment(
                f"exp{i + 1:02d}",
                t_s[keep],
                R_m[keep],
                str(path),
                info={
                    "layout": "estrada-shifted",
                    "row": i + 1,
                    "Rmax_stored_um": float(rmax_um[i]),
                    "source_time_of_t0_s": float(t[j]),
                },
            )
        )
    return exps


def _circlefit(path, v):
    px = _vector(path, v, "Rnew")
    dx = _scalar(path, v, "deltax")
    dt = _scalar(path, v, "deltat")
    if not (_PX_SIZE_RANGE[0] <= dx <= _PX_SIZE_RANGE[1]):
        raise InputError(path, f"deltax = {dx:g} is not a pixel size in metres")
    if not (_FRAME_RANGE[0] <= dt <= _FRAME_RANGE[1]):
        raise InputError(path, f"deltat = {dt:g} is not a frame interval in seconds")
    keep = _valid(px)
    if not keep.any():
        raise InputError(path, "variable Rnew holds no radius (all NaN or 0)")
    j = int(np.argmax(np.where(keep, px, -np.inf)))
    frames = np.arange(px.size)
    t_s = (frames - j) * dt
    R_m = px * dx
    return [
        Experiment(
            path.stem,
            t_s[keep],
            R_m[keep],
            str(path),
            info={"layout": "circlefit-pixels", "pixel_size_m": dx, "frame_interval_s": dt, "Rmax_px": float(px[j])},
        )
    ]


def _franck(path, v):
    t = _vector(path, v, "t")
    R = _vector(path, v, "R")
    if t.size != R.size:
        raise InputError(path, f"franck-RofT layout: t has {t.size} values but R has {R.size}")
    _check_um(path, "R", R)
    keep = _valid(R) & np.isfinite(t)
    j = int(np.argmax(np.where(keep, R, -np.inf)))
    t0 = t[j]
    info = {"layout": "franck-RofT", "source_time_of_t0_s": float(t0)}
    req_m = None
    if "Req" in v:
        req_um = _scalar(path, v, "Req")
        _check_um(path, "Req", np.array([req_um]))
        req_m = req_um * 1e-6
    tlocs = sorted((k for k in v if k.startswith("tloc") and k[4:].isdigit()), key=lambda k: int(k[4:]))
    if tlocs:
        idx = [int(_scalar(path, v, k)) for k in tlocs]
        if all(1 <= i <= t.size for i in idx):
            info["collapse_times_from_file_s"] = [float(t[i - 1] - t0) for i in idx]
    return [
        Experiment(
            path.stem,
            (t - t0)[keep],
            (R * 1e-6)[keep],
            str(path),
            req_m=req_m,
            req_source="file" if req_m is not None else None,
            info=info,
        )
    ]


def _umich(path, v, name):
    A = _numeric(path, v, name)
    t = A[:, 0]
    exps = []
    _check_um(path, f"{name}[:, 1]", A[:, 1])
    keep0 = _valid(A[:, 1]) & np.isfinite(t)
    j = int(np.argmax(np.where(keep0, A[:, 1], -np.inf)))
    t_s = t - t[j]
    for col, cam in ((1, "cam0deg"), (2, "cam90deg")):
        R = A[:, col]
        _check_um(path, f"{name}[:, {col}]", R)
        keep = _valid(R) & np.isfinite(t)
        exps.append(
            Experiment(
                f"{name}_{cam}",
                t_s[keep],
                (R * 1e-6)[keep],
                str(path),
                info={
                    "layout": "umich-dualcam",
                    "camera": cam,
                    "column": col + 1,
                    "source_time_of_t0_s": float(t[j]),
                    "time_origin": "argmax of camera 0° radius (both views share it)",
                },
            )
        )
    return exps


def read_mat(path) -> tuple:
    """Read an IMR .mat file: returns ``(layout, experiments)``; raises InputError if unrecognised."""
    path = Path(path)
    v = _variables(path)
    names = set(v)
    if {"shift_normRnew", "Rmax", "t"} <= names:
        return "estrada-shifted", _estrada(path, v)
    if {"Rnew", "deltax", "deltat"} <= names:
        return "circlefit-pixels", _circlefit(path, v)
    if {"t", "R"} <= names:
        return "franck-RofT", _franck(path, v)
    arrays = [
        k
        for k, a in v.items()
        if isinstance(a, np.ndarray)
        and a.dtype.kind in "biuf"
        and not a.dtype.names
        and a.ndim == 2
        and a.shape[1] == 3
        and a.shape[0] >= 5
    ]
    if len(v) == 1 and len(arrays) == 1:
        return "umich-dualcam", _umich(path, v, arrays[0])
    found = ", ".join(_describe(k, a) for k, a in sorted(v.items())) or "no variables"
    known = "; ".join(f"{k} ({', '.join(v)})" for k, v in _KEYS.items())
    raise InputError(path, f"not a recognised IMR .mat layout; found {found}. Known layouts: {known}")
