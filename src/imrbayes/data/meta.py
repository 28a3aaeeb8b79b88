"""``meta.json`` of a dataset (interfaces.md §1).

Only the keys the data layer needs are checked: ``material`` (string; a warning when absent),
``physics`` (object of positive numbers), ``forward`` (object; interpreted by the forward model),
``experiments`` (per-experiment objects, optionally with ``Req_m`` and ``Req_sd_m`` in metres).
``experiments`` may be an object keyed by file name (``"exp_001.csv"``) or experiment name
(``"exp_001"``), or a list of objects each with a ``file`` key (the shape the shared datasets use).

Every top-level key must be one of :data:`KNOWN_KEYS` (the ones above and the descriptive ones
the shared datasets and ``imrbayes simulate`` write), or start with ``x_`` (the user's own), and
every ``physics`` key a constant the forward model knows: a misspelt key (``phisics``) would
otherwise be ignored without a word. Every command that reads data checks this here, so each
refuses the same file with the same one-line error. The keys' values are kept untouched in
``Meta.raw``.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

from imrbayes.data.checks import MAX_RADIUS_M, MIN_RADIUS_M
from imrbayes.errors import InputError

__all__ = ["Meta", "read_meta", "parse_meta", "KNOWN_KEYS"]

#: top-level keys of meta.json: read by imrbayes, or descriptive ones kept in ``Meta.raw``
KNOWN_KEYS = frozenset(
    {
        "material",
        "physics",
        "forward",
        "experiments",  # read by the data layer
        "description",
        "synthetic",
        "truth",
        "temperature",
        "temperature_C",
        "concentration",
        "dataset",
        "source",
        "real_or_synthetic",
        "n_experiments",
        "n_files",
        "caveats",
        "conversion",
        "checks",
        "notes",
        "physics_note",
        "camera",
        "cameras",
        "frame_interval_s",
        "frame_rate_fps",
        "frame_rate_note",
        "frames",
        "frames_per_record",
        "pixel_size_m",
        "pixel_size_note",
        "time_origin",
        "source_variables",
        "source_scalars",
        "reference_estimates",
        "Req_in_file",
        "Req_note",
        "Req_stored_m",
        "Rmax_stats_um",
        "Rmax_stored_sample_m",
        "UNIT_BUG_WARNING",
        "authors_selection",
        "collapse_times_from_tloc_s",
        "columns",
        "derived_files_not_converted",
        "missing_full_curves",
        "not_converted",
        "use",
    }
)


@dataclass
class Meta:
    """Parsed meta.json. ``experiments`` maps experiment name (file stem) -> its entry (dict)."""

    raw: dict = field(default_factory=dict)
    material: str = "unknown"
    physics: dict = field(default_factory=dict)
    forward: dict = field(default_factory=dict)
    experiments: dict = field(default_factory=dict)
    path: str | None = None
    warnings: list = field(default_factory=list)

    def entry(self, name: str) -> dict:
        """The entry for experiment ``name`` (file stem), ``{}`` if none."""
        return self.experiments.get(name, {})


def read_meta(path) -> Meta:
    """Read and parse a meta.json file; raises InputError if it is not a valid JSON object."""
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8-sig")
    except FileNotFoundError:
        raise InputError(path, "no such file")
    except UnicodeDecodeError:
        raise InputError(path, "is not UTF-8 text")
    except OSError as exc:
        raise InputError(path, f"cannot be read: {exc.strerror or exc}")
    try:
        raw = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(path, f"is not valid JSON: line {exc.lineno} column {exc.colno}: {exc.msg}")
    except RecursionError:
        raise InputError(path, "is not valid JSON: nested too deeply")
    return parse_meta(raw, path)


def _stem(name: str) -> str:
    return name[:-4] if name.lower().endswith(".csv") else name


def _positive(value, where: str, path) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(path, f"{where} must be a number, got {value!r}")
    try:
        value = float(value)
    except OverflowError:
        raise InputError(path, f"{where} is too large")
    if not math.isfinite(value) or value <= 0.0:
        raise InputError(path, f"{where} must be finite and positive, got {value!r}")
    return value


def parse_meta(raw, path=None) -> Meta:
    """Check the parts of a meta.json object the data layer relies on; keep the rest."""
    src = path if path is not None else "meta.json"
    if not isinstance(raw, dict):
        raise InputError(src, f"must hold a JSON object, found {type(raw).__name__}")
    meta = Meta(raw=raw, path=None if path is None else str(path))
    _check_keys(raw, src)
    material = raw.get("material")
    if material is None:
        meta.warnings.append("meta.json has no 'material' (say what the gel is, e.g. \"10 % PAAm\")")
    elif not isinstance(material, str):
        raise InputError(src, f"'material' must be a string, got {material!r}")
    else:
        meta.material = material
    physics = raw.get("physics", {})
    if not isinstance(physics, dict):
        raise InputError(src, f"'physics' must be an object, got {physics!r}")
    meta.physics = {k: _positive(v, f"physics.{k}", src) for k, v in physics.items()}
    forward = raw.get("forward", {})
    if not isinstance(forward, dict):
        raise InputError(src, f"'forward' must be an object, got {forward!r}")
    meta.forward = dict(forward)
    exps = raw.get("experiments", {})
    if isinstance(exps, dict):
        items = list(exps.items())
    elif isinstance(exps, list):
        items = []
        for i, entry in enumerate(exps):
            if not isinstance(entry, dict) or not isinstance(entry.get("file"), str):
                raise InputError(src, f"experiments[{i}] must be an object with a 'file' name")
            items.append((entry["file"], entry))
    else:
        raise InputError(src, f"'experiments' must be an object or a list, got {type(exps).__name__}")
    for key, entry in items:
        if not isinstance(entry, dict):
            raise InputError(src, f"experiments.{key} must be an object, got {entry!r}")
        for name in ("Req_m", "Req_sd_m"):
            if name in entry and entry[name] is not None:
                value = (
                    _positive(entry[name], f"experiments.{key}.{name}", src)
                    if name == "Req_m"
                    else _nonneg(entry[name], f"experiments.{key}.{name}", src)
                )
                if name == "Req_m" and not (MIN_RADIUS_M <= value <= MAX_RADIUS_M):
                    raise InputError(
                        src, f"experiments.{key}.Req_m = {value:g} is not a radius in metres (looks like µm?)"
                    )
        meta.experiments[_stem(str(key))] = entry
    return meta


def _suggest(key: str, known) -> str:
    import difflib

    close = difflib.get_close_matches(key, sorted(known), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _check_keys(raw: dict, src) -> None:
    """Refuse an unknown top-level key or ``physics`` key with one line naming the file."""
    for key in raw:
        if key not in KNOWN_KEYS and not str(key).startswith("x_"):
            raise InputError(
                src,
                f"unknown key {key!r}{_suggest(str(key), KNOWN_KEYS)}; imrbayes reads material, "
                "physics, forward and experiments (every known key: docs/cli.md, meta.json); "
                "prefix your own keys with x_",
            )
    physics = raw.get("physics")
    if isinstance(physics, dict):
        from imrbayes.forward.constants import Physics

        known = {f.name for f in dataclasses.fields(Physics)} | set(Physics._ALIASES)
        for key in physics:
            if key not in known:
                raise InputError(
                    src,
                    f"unknown physics key {key!r}{_suggest(str(key), known)}; known: "
                    f"{', '.join(sorted(known, key=str.lower))}",
                )


def _nonneg(value, where, path) -> float:
    try:
        ok = (
            not isinstance(value, bool)
            and isinstance(value, (int, float))
            and math.isfinite(float(value))
            and value >= 0
        )
    except OverflowError:
        ok = False
    if not ok:
        raise InputError(path, f"{where} must be a finite number >= 0, got {str(value)[:30]}")
    return float(value)
