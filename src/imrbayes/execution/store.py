"""Checkpoints: a run directory that never loses finished work.

Layout under the run directory (``--out DIR``)::

    run.json                      configuration, its fingerprint, package version, start time, sessions
    status.json                   counts after the latest run_units call; ``complete`` only once the run
                                  closed normally, ``running`` with the owner's pid while it is open
    units/<safe id>.npz           one finished unit: its value and a JSON header (id, seed, timing)
    units/<safe id>.failed.json   one failed unit: its error message and traceback
    .lock                         held (flock) while a process has the run open

Every file is written atomically (:mod:`imrbayes.io`): to a temporary file in the same directory, flushed and
fsynced, then ``os.replace``-d onto its name (and the directory fsynced), so a file under its final name is
always complete. A temporary file left by a killed process is never read and is removed the next
time the run is opened. A unit file that cannot be read anyway (e.g. a damaged copy) is reported
and recomputed.

Unit values may be numpy arrays and scalars, ``None``, bools, ints, floats, strings, and lists,
tuples and ``str``-keyed dicts of these, nested freely. They round-trip exactly: arrays keep dtype
and shape, numpy scalars their type, floats every bit. Anything else is refused with a
``TypeError`` when the unit is saved.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import hashlib
import json
import os
import socket
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from imrbayes.errors import InputError
from imrbayes.execution.units import SEEDING_SCHEME, safe_name
from imrbayes.io import atomic_write, write_json

__all__ = [
    "RunStore",
    "canonical_config",
    "config_fingerprint",
    "CorruptUnitError",
    "encode_value",
    "decode_value",
    "read_status",
    "pid_alive",
]

RUN_FORMAT = "imrbayes-run/1"
UNIT_FORMAT = 1


class CorruptUnitError(RuntimeError):
    """A unit file exists but cannot be read back (it will be recomputed)."""


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")


# -------------------------------------------------------------------------------- configurations


def _plain(obj, where: str = "config"):
    if obj is None or type(obj) in (bool, int, float, str):
        return obj
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        obj = {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)}
    if isinstance(obj, dict):
        out = {}
        for key, val in obj.items():
            if not isinstance(key, str):
                raise TypeError(f"{where}: keys must be strings, got {key!r}")
            out[key] = _plain(val, f"{where}.{key}")
        return out
    if isinstance(obj, (list, tuple)):
        return [_plain(v, f"{where}[{i}]") for i, v in enumerate(obj)]
    if isinstance(obj, (bool, int, float, str)):  # subclasses (enums, ...)
        return _base_scalar(obj)
    raise TypeError(
        f"{where}: {type(obj).__name__} cannot be recorded in run.json (use numbers, strings, lists and dicts)"
    )


def _base_scalar(obj):
    for typ in (bool, int, float, str):
        if isinstance(obj, typ):
            return typ(obj)
    raise AssertionError


def canonical_config(config: dict) -> dict:
    """``config`` as plain JSON data (tuples to lists, numpy scalars and arrays to numbers and lists,
    paths to strings, dataclasses to dicts); ``TypeError`` names anything else."""
    if not isinstance(config, dict):
        raise TypeError(f"the run configuration must be a dict, got {type(config).__name__}")
    return _plain(config)


def _canonical_json(config: dict) -> str:
    return json.dumps(canonical_config(config), sort_keys=True, separators=(",", ":"), ensure_ascii=False)


def config_fingerprint(config: dict) -> str:
    """``"sha256:<hex>"`` over the canonical JSON of ``config`` (sorted keys, no spaces, UTF-8)."""
    return "sha256:" + hashlib.sha256(_canonical_json(config).encode("utf-8")).hexdigest()


_MISSING = object()


def _flatten(obj, prefix="") -> dict:
    if isinstance(obj, dict) and obj:
        out = {}
        for key, val in obj.items():
            out.update(_flatten(val, f"{prefix}.{key}" if prefix else key))
        return out
    return {prefix or "(root)": obj}


def _short(val) -> str:
    if val is _MISSING:
        return "absent"
    text = json.dumps(val, sort_keys=True)
    return text if len(text) <= 60 else text[:57] + "..."


def config_differences(stored: dict, now: dict) -> list[str]:
    """Human-readable ``"key: stored -> now"`` lines for dotted keys that differ."""
    a, b = _flatten(canonical_config(stored)), _flatten(canonical_config(now))
    lines = []
    for key in sorted(set(a) | set(b)):
        va, vb = a.get(key, _MISSING), b.get(key, _MISSING)
        if va is _MISSING or vb is _MISSING or json.dumps(va, sort_keys=True) != json.dumps(vb, sort_keys=True):
            lines.append(f"{key}: {_short(va)} (stored) vs {_short(vb)} (now)")
    return lines


# ----------------------------------------------------------------------------------- unit values

_RESERVED = ("__nd__", "__np__", "__tuple__", "__dict__")


def encode_value(value) -> tuple[Any, dict[str, np.ndarray]]:
    """Split a unit value into a JSON tree and the arrays it refers to (see the module docstring)."""
    arrays: dict[str, np.ndarray] = {}

    def enc(obj, where):
        if obj is None or type(obj) in (bool, int, str):
            return obj
        if type(obj) is float:
            return obj  # json writes repr(): exact round trip, NaN/Infinity included
        if isinstance(obj, np.ndarray):
            if obj.dtype.hasobject:
                raise TypeError(f"{where}: object arrays cannot be stored")
            key = f"a{len(arrays)}"
            arrays[key] = obj
            return {"__nd__": key}
        if isinstance(obj, np.generic):
            if obj.dtype.hasobject:
                raise TypeError(f"{where}: object scalars cannot be stored")
            key = f"a{len(arrays)}"
            arrays[key] = np.asarray(obj)
            return {"__np__": key}
        if isinstance(obj, tuple):
            return {"__tuple__": [enc(v, f"{where}[{i}]") for i, v in enumerate(obj)]}
        if type(obj) is list:
            return [enc(v, f"{where}[{i}]") for i, v in enumerate(obj)]
        if type(obj) is dict:
            for key in obj:
                if not isinstance(key, str):
                    raise TypeError(f"{where}: dict keys must be strings, got {key!r}")
            body = {k: enc(v, f"{where}.{k}") for k, v in obj.items()}
            return {"__dict__": body} if any(k in _RESERVED for k in obj) else body
        raise TypeError(
            f"{where}: a unit result of type {type(obj).__name__} cannot be stored; return numpy "
            f"arrays/scalars, numbers, strings, None, or lists/tuples/dicts of these"
        )

    return enc(value, "result"), arrays


def decode_value(tree, arrays) -> Any:
    """Inverse of :func:`encode_value` (``arrays``: a mapping such as an open ``NpzFile``)."""

    def dec(obj):
        if isinstance(obj, list):
            return [dec(v) for v in obj]
        if isinstance(obj, dict):
            if len(obj) == 1:
                ((key, val),) = obj.items()
                if key == "__nd__":
                    return np.array(arrays[val])
                if key == "__np__":
                    return np.asarray(arrays[val])[()]
                if key == "__tuple__":
                    return tuple(dec(v) for v in val)
                if key == "__dict__":
                    return {k: dec(v) for k, v in val.items()}
            return {k: dec(v) for k, v in obj.items()}
        return obj

    return dec(tree)


# ------------------------------------------------------------------------------------------ store


class RunStore:
    """A run directory (see the module docstring). Open it with :meth:`RunStore.open`.

    Attributes
    ----------
    path : Path
        The run directory.
    config : dict
        The canonical configuration (as stored in ``run.json``).
    fingerprint : str
        ``"sha256:..."`` of the configuration.
    resumed : bool
        True when an existing run was opened.
    """

    def __init__(self, path: Path, info: dict, resumed: bool, lock_fd: int | None):
        self.path = Path(path)
        self.info = info
        self.resumed = resumed
        self._lock_fd = lock_fd
        self._last_status: dict = {}
        #: the status.json an earlier session left behind when it ended without closing the run
        #: (killed, SIGKILL included): None when it ended normally or there was none
        self.previous_interrupted: dict | None = None

    # -- opening -----------------------------------------------------------------------------------
    @classmethod
    def open(cls, out, config: dict, *, resume: bool = False, check_version: bool = True) -> RunStore:
        """Create the run directory ``out`` for ``config``, or (``resume=True``) reopen it.

        ``config`` must hold everything that determines the results (data, model, method
        settings, seed) and nothing that does not (workers, scheduler, progress, output paths):
        its fingerprint decides whether a resume is allowed.

        Raises :class:`~imrbayes.errors.InputError` (exit status 2) when ``out`` already holds a run
        and ``resume`` is false; when resuming a run whose configuration differs (the message lists
        the differing keys) or that another imrbayes version wrote (unless ``check_version=False``);
        when another process has the run open. ``resume=True`` on a directory without a run
        starts one.
        """
        out = Path(out)
        conf = canonical_config(config)
        fingerprint = config_fingerprint(conf)
        if out.exists() and not out.is_dir():
            raise InputError(out, "--out must be a directory, this is a file")
        out.mkdir(parents=True, exist_ok=True)
        (out / "units").mkdir(exist_ok=True)
        lock_fd = _lock(out)
        try:
            run_json = out / "run.json"
            session = {"started": _now(), "host": socket.gethostname(), "pid": os.getpid()}
            if run_json.exists():
                if not resume:
                    raise InputError(
                        out, "already holds a run (run.json); pass --resume to continue it, or choose a new --out"
                    )
                info = cls._read_info(run_json)
                if info.get("fingerprint") != fingerprint:
                    diff = config_differences(info.get("config", {}), conf)
                    listed = "; ".join(diff[:6]) + (f"; and {len(diff) - 6} more" if len(diff) > 6 else "")
                    raise InputError(
                        out,
                        f"cannot resume: the configuration differs from the stored run "
                        f"({listed or 'fingerprint differs'}); use the same options or a new --out",
                    )
                import imrbayes

                if check_version and info.get("imrbayes_version") != imrbayes.__version__:
                    raise InputError(
                        out,
                        f"cannot resume: the run was started with imrbayes "
                        f"{info.get('imrbayes_version')}, this is {imrbayes.__version__}; "
                        f"results could differ; use a new --out",
                    )
                if info.get("seeding") != SEEDING_SCHEME:
                    raise InputError(out, "cannot resume: the run used another random-seeding scheme")
                info.setdefault("sessions", []).append({**session, "resume": True})
                store = cls(out, info, True, lock_fd)
                store.previous_interrupted = _interrupted_status(out / "status.json")
                if store.previous_interrupted is not None:  # this session takes the run over
                    store._last_status = {
                        k: v for k, v in store.previous_interrupted.items() if k not in ("owner", "updated")
                    } | {"interrupted": False, "complete": False}
            else:
                import imrbayes

                info = {
                    "format": RUN_FORMAT,
                    "imrbayes_version": imrbayes.__version__,
                    "fingerprint": fingerprint,
                    "seeding": SEEDING_SCHEME,
                    "started": session["started"],
                    "config": conf,
                    "sessions": [{**session, "resume": False}],
                }
                store = cls(out, info, False, lock_fd)
            store._write_info()
            store._clean_temporaries()
            return store
        except BaseException:
            _unlock(lock_fd)
            raise

    @staticmethod
    def _read_info(run_json: Path) -> dict:
        try:
            info = json.loads(run_json.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise InputError(run_json, f"cannot be read as a run record: {exc}")
        if not isinstance(info, dict) or info.get("format") != RUN_FORMAT:
            raise InputError(run_json, f"is not an imrbayes run record (format {RUN_FORMAT})")
        return info

    def _write_info(self) -> None:
        write_json(self.path / "run.json", self.info, indent=2)

    def _clean_temporaries(self) -> None:
        for folder in (self.path, self.path / "units"):
            for tmp in folder.glob(".*.tmp"):
                try:
                    tmp.unlink()
                except OSError:
                    pass

    def close(self, interrupted: bool = False) -> None:
        """Mark ``status.json`` finished (``complete`` when the last batch finished every unit and
        nothing interrupted it) and release the run's lock (the files stay)."""
        fd, self._lock_fd = self._lock_fd, None
        if fd is not None and self._last_status:
            last = self._last_status
            done = bool(last.get("complete")) and not interrupted and not last.get("interrupted")
            try:
                write_json(
                    self.path / "status.json",
                    {
                        **last,
                        "complete": done,
                        "interrupted": bool(interrupted or last.get("interrupted")),
                        "running": False,
                        "updated": _now(),
                    },
                    indent=2,
                )
            except OSError:  # never mask the original problem
                pass
        _unlock(fd)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        self.close(interrupted=exc_type is not None and issubclass(exc_type, KeyboardInterrupt))

    def __del__(self):  # pragma: no cover - best effort
        try:
            self.close()
        except Exception:
            pass

    # -- properties --------------------------------------------------------------------------------
    @property
    def config(self) -> dict:
        return self.info["config"]

    @property
    def fingerprint(self) -> str:
        return self.info["fingerprint"]

    def note_execution(self, description: dict) -> None:
        """Record where this session runs units (backend, workers) in ``run.json``."""
        session = self.info["sessions"][-1]
        runs = session.setdefault("execution", [])
        if description not in runs:
            runs.append(description)
            self._write_info()

    # -- units ---------------------------------------------------------------------------------------
    def _unit_path(self, uid: str) -> Path:
        return self.path / "units" / f"{safe_name(uid)}.npz"

    def _failure_path(self, uid: str) -> Path:
        return self.path / "units" / f"{safe_name(uid)}.failed.json"

    def status(self, uid: str) -> str | None:
        """``"done"``, ``"failed"`` or ``None`` (not run, or lost in flight)."""
        if self._unit_path(uid).exists():
            return "done"
        if self._failure_path(uid).exists():
            return "failed"
        return None

    def save(self, uid: str, value, *, seed: int, seconds: float | None = None, worker: str | None = None):
        """Write a finished unit atomically and return its value as it will read back (identical to
        what :meth:`load` gives after a resume). A failure record of the unit is removed."""
        tree, arrays = encode_value(value)
        meta = {
            "unit_id": uid,
            "seed": int(seed),
            "fingerprint": self.fingerprint,
            "finished": _now(),
            "seconds": seconds,
            "worker": worker,
        }
        header = json.dumps({"format": UNIT_FORMAT, "meta": meta, "value": tree}, allow_nan=True)
        payload = {**arrays, "__json__": np.array(header)}
        atomic_write(self._unit_path(uid), lambda fh: np.savez(fh, **payload))
        fail = self._failure_path(uid)
        if fail.exists():
            fail.unlink()
        return decode_value(tree, arrays)

    def _read_unit(self, uid: str) -> tuple[dict, Any]:
        path = self._unit_path(uid)
        try:
            with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as npz:
                doc = json.loads(str(npz["__json__"][()]))
                value = decode_value(doc["value"], npz)
                meta = doc["meta"]
        except FileNotFoundError:
            raise
        except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile, json.JSONDecodeError) as exc:
            raise CorruptUnitError(f"{path}: cannot be read ({type(exc).__name__}: {exc})") from exc
        if meta.get("unit_id") != uid:
            raise CorruptUnitError(f"{path}: holds unit {meta.get('unit_id')!r}, not {uid!r}")
        return meta, value

    def load(self, uid: str, *, seed: int | None = None):
        """The stored value of a finished unit. With ``seed``, a unit computed under another run seed
        or another configuration raises :class:`~imrbayes.errors.InputError`; an unreadable file
        raises :class:`CorruptUnitError`."""
        meta, value = self._read_unit(uid)
        if meta.get("fingerprint") != self.fingerprint:
            raise InputError(
                self._unit_path(uid), "was computed for another configuration (its fingerprint differs from run.json)"
            )
        if seed is not None and meta.get("seed") != int(seed):
            raise InputError(
                self._unit_path(uid),
                f"was computed with seed {meta.get('seed')}, this run uses "
                f"seed {int(seed)}; use the same --seed or a new --out",
            )
        return value

    def load_meta(self, uid: str) -> dict:
        """The stored header of a finished unit (id, seed, fingerprint, finished, seconds, worker)."""
        return self._read_unit(uid)[0]

    def save_failure(
        self,
        uid: str,
        *,
        seed: int,
        error: str,
        traceback: str | None = None,
        seconds: float | None = None,
        worker: str | None = None,
    ) -> None:
        """Record a unit that raised (atomically)."""
        write_json(
            self._failure_path(uid),
            {
                "unit_id": uid,
                "seed": int(seed),
                "fingerprint": self.fingerprint,
                "finished": _now(),
                "error": error,
                "traceback": traceback,
                "seconds": seconds,
                "worker": worker,
            },
            indent=2,
        )

    def load_failure(self, uid: str) -> dict:
        """The stored failure record of a unit (``error``, ``traceback``, ...)."""
        path = self._failure_path(uid)
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise CorruptUnitError(f"{path}: cannot be read ({type(exc).__name__}: {exc})") from exc
        return doc

    def write_status(self, status: dict) -> None:
        """Write the latest batch's counts to ``status.json``. While the run is open the file says
        ``running`` with this process's pid and never ``complete``: a process killed outright
        (SIGKILL) cannot mark its run, so only :meth:`close` writes ``complete``."""
        self._last_status = dict(status)
        write_json(
            self.path / "status.json",
            {**status, "complete": False, "running": True, "owner": _owner(), "updated": _now()},
            indent=2,
        )


# ------------------------------------------------------------------------------------------- lock
def _owner() -> dict:
    return {"pid": os.getpid(), "host": socket.gethostname()}


def pid_alive(pid) -> bool:
    """Whether process ``pid`` exists on this host (a zombie counts as gone only once reaped)."""
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: alive
        return True
    except (OSError, TypeError, ValueError, OverflowError):
        return False
    return True


def read_status(out) -> dict | None:
    """``status.json`` of run directory ``out`` with ``interrupted`` decided: a status that still
    says ``running`` whose owner is gone (killed, SIGKILL included) reads as interrupted; None when
    there is no readable status."""
    path = Path(out) / "status.json"
    try:
        status = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    if not isinstance(status, dict):
        return None
    owner = status.get("owner") or {}
    if status.get("running") and not (owner.get("host") == socket.gethostname() and pid_alive(owner.get("pid"))):
        status = {**status, "running": False, "interrupted": True, "complete": False}
    return status


def _interrupted_status(path: Path) -> dict | None:
    """The earlier session's status when it ended without closing the run (the caller holds the
    lock, so an owner that still says ``running`` is gone)."""
    try:
        status = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    if not isinstance(status, dict):
        return None
    if status.get("running") or status.get("interrupted"):
        return {**status, "running": False, "interrupted": True, "complete": False}
    return None


def _lock(out: Path) -> int | None:
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows: no lock
        return None
    fd = os.open(out / ".lock", os.O_RDWR | os.O_CREAT, 0o666)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        try:
            other = os.pread(fd, 64, 0).decode(errors="replace").strip()
        finally:
            os.close(fd)
        raise InputError(
            out, f"the run is open in another process ({other or 'unknown'}); wait for it to finish or stop it first"
        )
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"pid {os.getpid()} on {socket.gethostname()}".encode(), 0)
    return fd


def _unlock(fd: int | None) -> None:
    if fd is None:
        return
    try:
        import fcntl

        fcntl.flock(fd, fcntl.LOCK_UN)
    except (ImportError, OSError):
        pass
    try:
        os.close(fd)
    except OSError:
        pass
