"""What a study is: datasets with condition labels, what to run on each, the shared fit options.

A study comes from a TOML file (:func:`read_study_file`) or from the command line's short form
(:func:`study_from_args`); both end in :class:`StudySpec`, checked once by :func:`check_study`.

TOML layout (SI units; labels are free keys)::

    methods = ["en4dvar", "mienks"]      # default; also "imr", "pimr"
    collapses = [1, 2]                   # optional: IMR fitted up to the k-th collapse, one run per k
    diagnose = false                     # true: also `imrbayes diagnose` per dataset; "quick": --quick
    seed = 0
    experiments = "1-3"                  # optional, as fit --experiments
    model = "nhkv"
    [forward]                            # fit --forward, for every dataset
    bubble = "polytropic"
    [set.en4dvar]                        # fit --set per method
    n_ens = 12

    [[dataset]]
    name = "agarose-0.5"                 # optional: the folder name by default
    data = "data/agarose0p5"             # relative to the TOML file
    labels = {material = "agarose", concentration = "0.5 %", temperature = 25}
"""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from imrbayes.errors import InputError

__all__ = [
    "Condition",
    "StudySpec",
    "read_study_file",
    "study_from_args",
    "check_study",
    "parse_label_value",
    "numeric_labels",
    "diagnose_mode",
    "DEFAULT_METHODS",
]

#: the constant estimate (En4D-Var) and the time-resolved G(t), mu(t) (MIEnKS-MDA)
DEFAULT_METHODS = ("en4dvar", "mienks")
_TOP_KEYS = {
    "methods",
    "collapses",
    "diagnose",
    "seed",
    "experiments",
    "model",
    "forward",
    "set",
    "dataset",
    "dt_star",
    "n_steps",
    "camera",
    "likelihood",
}
_DATASET_KEYS = {"name", "data", "labels"}
_NUMBER_UNIT = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(.*?)\s*$")


@dataclass(frozen=True)
class Condition:
    """One dataset of the study: its name (unique), path and condition labels ({key: text or number})."""

    name: str
    data: Path
    labels: dict = field(default_factory=dict)


@dataclass
class StudySpec:
    """A study: conditions and what to run on each.

    ``methods``: fit methods run on the whole record; ``collapses``: IMR fits to the k-th collapse
    (k = 1, 2, ...); ``diagnose``: False, ``"full"`` or ``"quick"`` (``diagnose --quick``); ``fit_options``: options every fit
    shares (``--forward`` items, ``--set`` items per method, seed, experiments, model, grid).
    ``source``: the study file (or ``--label``) that bad input is blamed on.
    """

    conditions: list
    methods: tuple = DEFAULT_METHODS
    collapses: tuple = ()
    diagnose: str | bool = False
    seed: int = 0
    model: str = "nhkv"
    experiments: str | None = None
    forward: dict = field(default_factory=dict)
    settings: dict = field(default_factory=dict)
    grid: dict = field(default_factory=dict)
    source: str = "study"

    def label_keys(self) -> list:
        """The label keys, in the order they first appear."""
        keys = []
        for c in self.conditions:
            keys += [k for k in c.labels if k not in keys]
        return keys


def parse_label_value(text):
    """A label value as ``(number, unit)`` when it reads as a number with an optional unit
    (``"0.5 %"`` -> ``(0.5, "%")``, ``25`` -> ``(25.0, "")``), else ``(None, text)``."""
    if isinstance(text, bool):
        return None, str(text).lower()
    if isinstance(text, (int, float)):
        return (float(text), "") if math.isfinite(text) else (None, str(text))
    m = _NUMBER_UNIT.match(str(text))
    if m:
        return float(m.group(1)), m.group(2)
    return None, str(text)


def numeric_labels(spec: StudySpec) -> dict:
    """The labels that are numbers (one unit) on every condition: {key: unit}; a label of two or more
    distinct values only (a trend needs them)."""
    out = {}
    for key in spec.label_keys():
        parsed = [parse_label_value(c.labels[key]) for c in spec.conditions]
        units = {u for _, u in parsed}
        if all(v is not None for v, _ in parsed) and len(units) == 1 and len({v for v, _ in parsed}) >= 2:
            out[key] = units.pop()
    return out


def diagnose_mode(value, source) -> str | bool:
    """``diagnose`` of a study: False (not run), ``"full"`` (true) or ``"quick"`` (``diagnose --quick``)."""
    if value is True or value == "full":
        return "full"
    if value is False or value == "quick":
        return value
    raise InputError(source, f'diagnose must be true, false or "quick", got {value!r}')


def _tuple_of(value, source, what, kind=str):
    if isinstance(value, (str, int)) and not isinstance(value, bool):
        value = [value] if kind is int else [v for v in str(value).split(",") if v.strip()]
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, kind) and not isinstance(v, bool) for v in value):
        raise InputError(source, f"{what} must be a list of {'integers' if kind is int else 'names'}, got {value!r}")
    return tuple(v.strip() if kind is str else v for v in value)


def read_study_file(path) -> StudySpec:
    """The study in TOML file ``path`` (layout: module doc), checked (:func:`check_study`).

    Raises :class:`~imrbayes.errors.InputError` naming the file: missing, not TOML, an unknown key,
    and every problem :func:`check_study` finds.
    """
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(path, "study file not found")
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(path, f"not valid TOML: {' '.join(str(exc).split())}")
    data = data.get("study", data) if isinstance(data.get("study"), dict) and "dataset" not in data else data
    unknown = sorted(set(data) - _TOP_KEYS)
    if unknown:
        raise InputError(path, f"unknown key(s) {unknown}; known: {sorted(_TOP_KEYS)}")
    rows = data.get("dataset")
    if not isinstance(rows, list) or not rows:
        raise InputError(path, "no [[dataset]] entries: a study needs at least one dataset")
    conditions = []
    for i, row in enumerate(rows, 1):
        if not isinstance(row, dict):
            raise InputError(path, f"dataset {i} must be a table")
        bad = sorted(set(row) - _DATASET_KEYS)
        if bad:
            raise InputError(path, f"dataset {i}: unknown key(s) {bad}; known: {sorted(_DATASET_KEYS)}")
        if not isinstance(row.get("data"), str):
            raise InputError(path, f'dataset {i} has no data = "PATH"')
        labels = row.get("labels", {})
        if not isinstance(labels, dict) or any(isinstance(v, (dict, list)) for v in labels.values()):
            raise InputError(path, f"dataset {i}: labels must be a table of numbers or strings")
        data_path = Path(row["data"])
        data_path = data_path if data_path.is_absolute() else path.parent / data_path
        name = str(row.get("name") or data_path.stem)
        conditions.append(Condition(name, data_path, dict(labels)))
    spec = StudySpec(conditions=conditions, source=str(path))
    _apply_options(spec, data, str(path))
    return check_study(spec)


def _apply_options(spec: StudySpec, data: dict, source: str) -> None:
    """The shared options of a study file's top level onto ``spec``."""
    if "methods" in data:
        spec.methods = _tuple_of(data["methods"], source, "methods")
    if "collapses" in data:
        spec.collapses = _tuple_of(data["collapses"], source, "collapses", int)
    if "diagnose" in data:
        spec.diagnose = diagnose_mode(data["diagnose"], source)
    if "seed" in data:
        spec.seed = data["seed"]
    for key in ("model", "experiments", "camera", "likelihood"):
        if key in data and not isinstance(data[key], str):
            raise InputError(source, f"{key} must be a string, got {data[key]!r}")
    spec.model = data.get("model", spec.model)
    spec.experiments = data.get("experiments", spec.experiments)
    for key in ("camera", "likelihood"):
        if key in data:
            spec.grid[key] = data[key]
    for key in ("dt_star", "n_steps"):
        if key in data:
            spec.grid[key] = data[key]
    if "forward" in data:
        if not isinstance(data["forward"], dict):
            raise InputError(source, "forward must be a table of forward-model options")
        spec.forward = {k: v for k, v in data["forward"].items()}
    if "set" in data:
        if not isinstance(data["set"], dict) or not all(isinstance(v, dict) for v in data["set"].values()):
            raise InputError(source, "set must hold one table per method, e.g. [set.en4dvar]")
        spec.settings = {m: dict(v) for m, v in data["set"].items()}


def study_from_args(data_paths, labels, names=None, **options) -> StudySpec:
    """The short form ``imrbayes study DATA... --label KEY=V1,V2,...``: one value per dataset (or one
    value for all). ``options``: the :class:`StudySpec` fields given on the command line."""
    conditions_labels = [dict() for _ in data_paths]
    for item in labels:
        key, sep, values = str(item).partition("=")
        key = key.strip()
        if not sep or not key:
            raise InputError("--label", f"expected KEY=V1,V2,..., got {item!r}")
        vals = [v.strip() for v in values.split(",")]
        if len(vals) == 1:
            vals = vals * len(data_paths)
        if len(vals) != len(data_paths) or any(not v for v in vals):
            raise InputError(
                "--label",
                f"{key} has {len(vals)} value(s) for {len(data_paths)} dataset(s); give one "
                "per dataset, in the datasets' order",
            )
        for lab, v in zip(conditions_labels, vals):
            lab[key] = v
    paths = [Path(p) for p in data_paths]
    names = list(names) if names else [p.stem for p in paths]
    conds = [Condition(n, p, lab) for n, p, lab in zip(names, paths, conditions_labels)]
    spec = StudySpec(conditions=conds, source="--label", **{k: v for k, v in options.items() if v is not None})
    return check_study(spec)


def check_study(spec: StudySpec) -> StudySpec:
    """``spec`` if it is a study that can run, else InputError naming its source: no dataset, a
    dataset that does not exist, two datasets of one name, a label given on some datasets only, an
    unknown method, a bad collapse or seed."""
    from imrbayes.ensemble import METHODS

    src = spec.source
    if not spec.conditions:
        raise InputError(src, "no datasets")
    seen = {}
    for c in spec.conditions:
        if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._+-]*", c.name):
            raise InputError(src, f"dataset name {c.name!r} must be letters, digits and . _ + - (it names a folder)")
        if c.name in seen:
            raise InputError(
                src, f"two datasets are named {c.name!r} ({seen[c.name]} and {c.data}); give each a distinct name"
            )
        seen[c.name] = c.data
        if not c.data.exists():
            raise InputError(src, f"dataset {c.name!r}: {c.data} does not exist")
    keys = spec.label_keys()
    for key in keys:
        missing = [c.name for c in spec.conditions if key not in c.labels]
        if missing:
            raise InputError(
                src, f"label {key!r} is missing on dataset(s) {', '.join(missing)}; give every dataset every label"
            )
    if len({tuple(str(c.labels[k]) for k in keys) for c in spec.conditions}) < len(spec.conditions) and keys:
        raise InputError(src, "two datasets have the same labels; conditions must differ in at least one label")
    bad = [m for m in spec.methods if m not in METHODS]
    if bad or not spec.methods:
        raise InputError(src, f"unknown method(s) {bad}; choose from {', '.join(METHODS)}")
    if any(k < 1 for k in spec.collapses):
        raise InputError(src, f"collapses count from 1 (the first collapse), got {list(spec.collapses)}")
    if isinstance(spec.seed, bool) or not isinstance(spec.seed, int) or spec.seed < 0:
        raise InputError(src, f"seed must be a non-negative integer, got {spec.seed!r}")
    unknown_sets = sorted(set(spec.settings) - set(METHODS))
    if unknown_sets:
        raise InputError(src, f"[set.{unknown_sets[0]}]: not a method; choose from {', '.join(METHODS)}")
    return spec
