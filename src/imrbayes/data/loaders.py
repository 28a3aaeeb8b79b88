"""Load a dataset from what a user points at (interfaces.md §1).

:func:`load_dataset` accepts

* a dataset directory: one ``*.csv`` per experiment (``t_s,R_m``) and a ``meta.json`` (optional: without
  it the material is "unknown", the default physics is used and a warning says so);
* a single experiment CSV (``t_s,R_m``) or a long CSV (``experiment,t_s,R_m``); a ``meta.json``
  next to the file is used when present;
* a MATLAB ``.mat`` file in one of the layouts of :mod:`imrbayes.data.matfile`;
* the path of a dataset's ``meta.json`` (= its directory).

Files are only read, never written. Every problem raises :class:`~imrbayes.errors.InputError`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from imrbayes.data.checks import check_record
from imrbayes.data.csvio import format_lines, read_table
from imrbayes.data.matfile import LAYOUTS, read_mat
from imrbayes.data.meta import Meta, read_meta
from imrbayes.data.records import Dataset, Experiment
from imrbayes.errors import InputError

__all__ = [
    "MEAN_OF_VIEWS",
    "mean_of_views",
    "load_dataset",
    "load_experiment_csv",
    "load_long_csv",
    "load_mat",
    "load_directory",
]


def _apply_meta(exp: Experiment, meta: Meta) -> Experiment:
    entry = meta.entry(exp.name)
    if entry:
        exp.info = {**exp.info, **entry}
        if entry.get("Req_m") is not None:
            exp.req_m = float(entry["Req_m"])
            exp.req_sd_m = None if entry.get("Req_sd_m") is None else float(entry["Req_sd_m"])
            exp.req_source = "meta.json"
    return exp


def _dropped_warning(dropped, path, label="") -> list:
    if not dropped:
        return []
    return [f"{path}: {label}dropped {len(dropped)} row(s) with a missing or NaN value (line {format_lines(dropped)})"]


def _single(path: Path, table, name: str | None = None) -> Experiment:
    t, R = table.columns["t_s"], table.columns["R_m"]
    check_record(t, R, path, table.lines)
    return Experiment(name or path.stem, t, R, str(path), warnings=_dropped_warning(table.dropped_lines, path))


def _long(path: Path, table) -> list:
    labels = table.labels
    exps = []
    for name in dict.fromkeys(labels):
        rows = [i for i, lab in enumerate(labels) if lab == name]
        t = table.columns["t_s"][rows]
        R = table.columns["R_m"][rows]
        check_record(t, R, path, table.lines[rows], label=f"experiment {name!r}: ")
        exps.append(Experiment(name, t, R, str(path)))
    if not exps:
        raise InputError(path, "has no valid data rows (every row had a missing value)")
    exps[0].warnings.extend(_dropped_warning(table.dropped_lines, path))
    return exps


def load_experiment_csv(path, name: str | None = None) -> Experiment:
    """One experiment from a ``t_s,R_m`` CSV (checked; NaN rows dropped with a warning)."""
    path = Path(path)
    table = read_table(path)
    if table.labels is not None:
        raise InputError(path, "is a long CSV (experiment,t_s,R_m); expected one experiment (t_s,R_m)")
    return _single(path, table, name)


def load_long_csv(path) -> list:
    """Experiments of a long CSV (``experiment,t_s,R_m``), in order of first appearance."""
    path = Path(path)
    table = read_table(path)
    if table.labels is None:
        raise InputError(path, "has no 'experiment' column; expected experiment,t_s,R_m")
    return _long(path, table)


def load_mat(path) -> tuple:
    """``(layout, experiments)`` from an IMR .mat file, each experiment checked like a CSV."""
    path = Path(path)
    layout, exps = read_mat(path)
    for e in exps:
        check_record(e.t_s, e.R_m, path, label=f"{layout} layout, experiment {e.name!r}: ")
    return layout, exps


def _sibling_meta(path: Path) -> Meta:
    meta_path = path.parent / "meta.json"
    if meta_path.is_file():
        return read_meta(meta_path)
    return Meta()


def _dataset(name, path, fmt, exps, meta: Meta, notes) -> Dataset:
    exps = [_apply_meta(e, meta) for e in exps]
    warnings = list(meta.warnings) if meta.path else []
    known = {e.name for e in exps}
    stray = [k for k in meta.experiments if k not in known]
    if stray and fmt == "directory":
        warnings.append(f"meta.json describes experiment(s) with no CSV: {', '.join(sorted(stray))}")
    for e in exps:
        warnings.extend(e.warnings)
    if meta.path:
        notes.append(f"metadata from {meta.path}")
    else:
        notes.append("no meta.json: material unknown, default physics and forward options")
    return Dataset(
        name=name,
        path=str(path),
        format=fmt,
        experiments=exps,
        material=meta.material,
        meta=meta.raw,
        physics=meta.physics,
        forward=meta.forward,
        meta_path=meta.path,
        warnings=warnings,
        notes=notes,
    )


def load_directory(path) -> Dataset:
    """A dataset directory: one ``*.csv`` per experiment (sorted by name) and an optional ``meta.json``."""
    path = Path(path)
    try:
        entries = sorted(path.iterdir())
    except OSError as exc:
        raise InputError(path, f"cannot list the directory: {exc.strerror or exc}")
    csvs = [p for p in entries if p.suffix.lower() == ".csv" and p.is_file()]
    meta_path = path / "meta.json"
    if not csvs:
        others = [p.name for p in entries if p.suffix.lower() == ".mat"]
        hint = f" (found .mat file(s) {', '.join(others[:4])}: pass a .mat file itself)" if others else ""
        raise InputError(path, f"no experiment .csv files in this directory{hint}")
    exps = [load_experiment_csv(p) for p in csvs]
    if not meta_path.is_file():
        # a folder of camera exports: usable as it is, but the user should know what was assumed
        ds = _dataset(path.name, path, "directory", exps, Meta(), [f"{len(exps)} experiment CSV file(s)"])
        ds.warnings.insert(
            0,
            f"{path}: no meta.json, so the material is 'unknown' and the default physical "
            "constants (water-like gel at 20 °C, 1 atm) and forward options are used; add a "
            'meta.json ({"material": "...", "physics": {...}}) to record them',
        )
        return ds
    meta = read_meta(meta_path)
    return _dataset(path.name, path, "directory", exps, meta, [f"{len(exps)} experiment CSV file(s)"])


def load_dataset(path, camera: str | None = None) -> Dataset:
    """Load whatever ``path`` is (see module docstring); ``camera`` keeps one view of dual-camera data.

    Raises
    ------
    InputError
        On any problem, naming the file at fault.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(path, "no such file or directory")
    if path.is_file() and path.name == "meta.json":
        path = path.parent
    if path.is_dir():
        ds = load_directory(path)
    else:
        suffix = path.suffix.lower()
        if suffix == ".csv":
            table = read_table(path)
            meta = _sibling_meta(path)
            if table.labels is not None:
                ds = _dataset(path.stem, path, "long-csv", _long(path, table), meta, ["long CSV"])
            else:
                ds = _dataset(path.stem, path, "csv", [_single(path, table)], meta, ["single CSV"])
        elif suffix == ".mat":
            layout, exps = load_mat(path)
            note = f".mat layout {layout!r} found: {LAYOUTS[layout]}; converted to SI"
            ds = _dataset(path.stem, path, f"mat:{layout}", exps, Meta(), [note])
        else:
            raise InputError(
                path,
                f"unrecognised file type {suffix or '(no extension)'!r}; expected a dataset "
                "directory, a .csv or a .mat file",
            )
    if camera == MEAN_OF_VIEWS:
        ds = mean_of_views(ds, path)
    elif camera is not None:
        cams = sorted({e.camera for e in ds.experiments if e.camera})
        ds = ds.select(camera=camera)
        if not ds.experiments:
            raise InputError(path, f"no experiment from camera {camera!r}; cameras found: {', '.join(cams) or 'none'}")
        ds.notes.append(f"kept camera view {camera!r} only ({len(ds.experiments)} experiments)")
    _note_camera_pairs(ds)
    return ds


def _note_camera_pairs(ds: Dataset) -> None:
    cams = {e.camera for e in ds.experiments if e.camera}
    if len(cams) > 1:
        ds.warnings.append(
            f"experiments are views of the same bubbles from {len(cams)} cameras "
            f"({', '.join(sorted(cams))}); they are not independent experiments "
            f"(use --camera {MEAN_OF_VIEWS} to average the views of each bubble, or --camera NAME "
            f"to keep one view)"
        )


#: ``--camera`` value that averages the views of each bubble frame by frame
MEAN_OF_VIEWS = "mean"

#: a late view difference beyond this fraction of the tail radius is worth a warning
VIEW_SPREAD_WARN = 0.05


def mean_of_views(ds: Dataset, path) -> Dataset:
    """One experiment per bubble: the frame-by-frame mean radius of its camera views.

    Views of one bubble share a name up to their ``_cam...`` suffix and a time axis (frames present in
    every view are kept). Two orthogonal views of a bubble that is not quite round, or of cameras whose
    scales differ, disagree by more than their noise: the mean is the better spherical-equivalent
    radius, and half the views' difference over the record's last ``n`` frames (``info
    ["view_req_spread_m"]``) is the systematic uncertainty preprocessing adds to an estimated Req.
    Raises InputError when there is nothing to average.
    """
    groups: dict = {}
    for e in ds.experiments:
        if not e.camera:
            raise InputError(path, f"--camera {MEAN_OF_VIEWS}: experiment {e.name!r} has no camera view label")
        head = e.name[: -len(e.camera) - 1] if e.name.endswith("_" + e.camera) else e.name
        groups.setdefault(head, []).append(e)
    exps, spreads = [], []
    for head, views in groups.items():
        if len(views) < 2:
            raise InputError(
                path,
                f"--camera {MEAN_OF_VIEWS}: bubble {head!r} has one view only ({views[0].camera}); nothing to average",
            )
        dt = min(float(np.median(np.diff(v.t_s))) for v in views)
        keys = [np.round(v.t_s / (1e-3 * dt)).astype(np.int64) for v in views]
        common = keys[0]
        for k in keys[1:]:
            common = np.intersect1d(common, k)
        if common.size < 10:
            raise InputError(
                path,
                f"--camera {MEAN_OF_VIEWS}: the views of bubble {head!r} share "
                f"{common.size} frame times; they are not on one time axis",
            )
        R = np.stack([v.R_m[np.searchsorted(k, common)] for v, k in zip(views, keys)])
        t = views[0].t_s[np.searchsorted(keys[0], common)]
        n_tail = min(20, common.size // 4)
        tail_diff = float(np.ptp(R[:, -n_tail:].mean(axis=1)))
        tail_mean = float(R[:, -n_tail:].mean())
        info = {
            "camera": MEAN_OF_VIEWS,
            "views": [v.name for v in views],
            "view_difference_rms_m": float(np.sqrt(np.mean(np.ptp(R, axis=0) ** 2))),
            "view_req_spread_m": 0.5 * tail_diff,
            "view_tail_frames": n_tail,
        }
        warns = [w for v in views for w in v.warnings]
        dropped = sum(v.t_s.size - common.size for v in views)
        if dropped:
            warns.append(f"bubble {head!r}: {dropped} frame(s) missing from some view dropped before averaging")
        given = all(v.req_m is not None for v in views)
        req_sd = [v.req_sd_m for v in views if v.req_sd_m is not None]
        exps.append(
            Experiment(
                head,
                t,
                R.mean(axis=0),
                ", ".join(v.source for v in views),
                req_m=float(np.mean([v.req_m for v in views])) if given else None,
                req_sd_m=float(np.mean(req_sd)) if given and len(req_sd) == len(views) else None,
                req_source=views[0].req_source if given else None,
                info=info,
                warnings=warns,
            )
        )
        spreads.append((head, tail_diff, tail_mean))
    out = Dataset(
        ds.name,
        ds.path,
        ds.format,
        exps,
        ds.material,
        ds.meta,
        ds.physics,
        ds.forward,
        ds.meta_path,
        [w for w in ds.warnings if "not independent" not in w],
        list(ds.notes),
    )
    out.notes.append(
        f"averaged the camera views of each bubble frame by frame ({len(exps)} bubbles from "
        f"{len(ds.experiments)} views)"
    )
    far = [(h, d, m) for h, d, m in spreads if d > VIEW_SPREAD_WARN * m]
    if far:
        out.warnings.append(
            f"the camera views disagree late in the record by more than {VIEW_SPREAD_WARN:.0%} of the tail radius: "
            + "; ".join(f"{h} {d * 1e6:.1f} µm ({d / m:.0%} of the tail radius)" for h, d, m in far)
            + " -- the bubble is not round or the cameras' scales differ; half the difference is added to "
            "Req's uncertainty"
        )
    return out
