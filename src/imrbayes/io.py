"""Writing files: plain-JSON conversion, atomic writes and run folders -- the one home of each.

* :func:`jsonable` -- numpy scalars and arrays, tuples and non-finite floats as plain JSON values;
* :func:`atomic_write` / :func:`atomic_write_bytes` / :func:`atomic_write_text` -- a file that is
  either the old one or the complete new one, never a part (temporary file in the same folder,
  flushed, fsynced, ``os.replace``-d onto its name, the folder fsynced);
* :func:`write_json` -- :func:`jsonable` + strict JSON (no NaN) + newline, written atomically: every
  JSON file imrbayes writes (``summary.json``, ``compare.json``, ``dataset.json``, ``run.json``, ...);
* :func:`new_run_dir` / :func:`prepare_out` -- the ``--out`` folder of a command;
* :func:`code_version` -- the source a result was computed with (git hash), for result files that
  grow over several sessions.
"""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import uuid
from collections.abc import Callable
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from imrbayes.errors import InputError

__all__ = [
    "jsonable",
    "read_json",
    "atomic_write",
    "atomic_write_bytes",
    "atomic_write_text",
    "write_json",
    "new_run_dir",
    "prepare_out",
    "code_version",
]


# ------------------------------------------------------------------------------------------ JSON
def jsonable(obj):
    """``obj`` as plain JSON types, recursively.

    dict keys -> ``str(key)``; tuples and lists -> lists; ndarrays -> nested lists; numpy bools,
    integers and floats -> ``bool``, ``int``, ``float``; NaN and +-inf -> ``None``. Anything else
    (str, None, Python ints) is returned as it is.
    """
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if math.isfinite(v) else None
    return obj


# -------------------------------------------------------------------------------- atomic files
def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:  # e.g. Windows: directories cannot be opened
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def atomic_write(path, write: Callable[[Any], None]) -> Path:
    """Call ``write(fh)`` on a binary file handle and put the result at ``path`` atomically.

    The temporary file is ``.<name>.<12 hex>.tmp`` in the same folder (a run store removes such
    leftovers of a killed process); it is deleted if ``write`` raises. Returns ``path``.
    """
    path = Path(path)
    tmp = path.parent / f".{path.name}.{uuid.uuid4().hex[:12]}.tmp"
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    _fsync_dir(path.parent)
    return path


def atomic_write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically: readers see the old file or the new one, never a part."""
    return atomic_write(path, lambda fh: fh.write(data))


def atomic_write_text(path, text: str) -> Path:
    """``text`` as UTF-8 written with :func:`atomic_write_bytes`."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def write_json(path, obj, indent: int | None = 1) -> Path:
    """``json.dumps(jsonable(obj), indent=indent, allow_nan=False)`` and a newline, written atomically.

    ``indent``: 1 for the result files (summary.json, compare.json, dataset.json, ...), 2 for the
    dataset's meta.json/truth.json and the run store's records (what each has always used).
    """
    return atomic_write_text(path, json.dumps(jsonable(obj), indent=indent, allow_nan=False) + "\n")


# --------------------------------------------------------------------------------- run folders
def new_run_dir(kind: str, name: str, base: Path = Path("imrbayes-runs")) -> Path:
    """A fresh folder path ``base/<kind>-<name>-<YYYYmmdd-HHMMSS>[-k]`` (not created yet)."""
    slug = re.sub(r"[^A-Za-z0-9._-]+", "_", name)[:60] or "run"
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    path = base / f"{kind}-{slug}-{stamp}"
    k = 2
    while path.exists():
        path = base / f"{kind}-{slug}-{stamp}-{k}"
        k += 1
    return path


def prepare_out(
    out: Path | None, kind: str, name: str, protect: Path | None = None, *, force: bool = False, resume: bool = False
) -> Path:
    """The command's ``--out`` folder, created: ``out``, or :func:`new_run_dir` when it is None.

    InputError (option ``--out``) when ``out`` is a file, is the data folder ``protect`` (or the
    folder of the data file ``protect``: input files are never written to), cannot be created, or
    already holds files -- unless ``force`` (the user accepts that files of the same name are
    replaced) or ``resume`` (a run continues in its own folder; the run store checks it is one).
    """
    if out is None:
        out = new_run_dir(kind, name)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError("--out", f"{out} exists and is not a directory")
    if protect is not None:
        p = protect if protect.is_dir() else protect.parent
        if out.resolve() == p.resolve():
            raise InputError(
                "--out", f"{out} is the data folder; choose another folder (input files are never written to)"
            )
    if out.is_dir() and not resume and (out / "run.json").exists():
        # --force does not reach here: the folder's checkpoints belong to that run and would be read as this one's
        raise InputError(
            out,
            "already holds a run (run.json); pass --resume to continue it, or choose a new --out"
            + (" (--force does not replace a run: delete the folder first)" if force else ""),
        )
    if out.is_dir() and not (force or resume):
        entries = sorted(p.name for p in out.iterdir())
        if entries:
            shown = ", ".join(entries[:3]) + (", ..." if len(entries) > 3 else "")
            raise InputError(
                "--out",
                f"{out} already holds {len(entries)} file(s) ({shown}); choose a new folder, "
                f"or pass --force to write into it (files of the same name are replaced)",
            )
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError("--out", f"cannot create {out}: {exc.strerror or exc}")
    return out


def read_json(path: Path, required: bool = True):
    """The JSON object in ``path``; None if it is absent and not ``required``. InputError naming the
    file when it is absent (and required), not a file, unreadable, not JSON or not an object."""
    if not path.exists():
        if required:
            raise InputError(path, "not found (is this a run directory written by 'imrbayes fit'?)")
        return None
    if not path.is_file():
        raise InputError(path, "not a file")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(path, f"not valid JSON ({' '.join(str(exc).split())})")
    except OSError as exc:
        raise InputError(path, f"cannot be read ({exc.strerror or exc})")
    if not isinstance(data, dict):
        raise InputError(path, f"expected a JSON object, got {type(data).__name__}")
    return data


def code_version() -> str:
    """The imrbayes source this process runs: git's short hash of the checkout holding the imported
    package, "+dirty" when its src/ has uncommitted changes ("unknown" outside git or without git).
    Result files that are resumed across sessions (calibration rows, confusion-matrix rows) record
    it per row, so that a file mixing versions can say so."""
    import imrbayes

    src = Path(imrbayes.__file__).resolve().parents[1]
    try:
        head = subprocess.run(
            ["git", "-C", str(src), "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(src), "status", "--porcelain", "--", "."], capture_output=True, text=True, check=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("+dirty" if dirty else "")
