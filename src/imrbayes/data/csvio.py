"""Reading and writing the radius CSVs of interfaces.md §1.

Two shapes are read: one experiment per file (header ``t_s,R_m``) and one long file with a column
``experiment`` (header ``experiment,t_s,R_m``). Column order is free; the set of columns is not.
Empty cells and ``nan``/``NA`` are missing values: such rows are dropped with a warning giving their
line numbers. Anything else that is not a finite decimal number is refused.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imrbayes.errors import InputError

__all__ = ["read_table", "Table", "format_lines", "write_experiment_csv", "EXPERIMENT_COLUMNS", "LONG_COLUMNS"]

EXPERIMENT_COLUMNS = ("t_s", "R_m")
LONG_COLUMNS = ("experiment", "t_s", "R_m")
_NUMBER = re.compile(r"^[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?$")
_MISSING = {"", "nan", "na", "n/a", "null", "none"}
_UNIT_HINTS = {
    "us": "µs",
    "µs": "µs",
    "ms": "ms",
    "um": "µm",
    "µm": "µm",
    "mm": "mm",
    "px": "pixels",
    "pixels": "pixels",
    "frame": "frames",
    "frames": "frames",
}


@dataclass
class Table:
    """A parsed CSV: the header, numeric columns and the file line of every kept row.

    ``columns`` maps a numeric column name to a float64 array (n,); ``labels`` holds the
    ``experiment`` column (list of str) for the long format, else None; ``lines`` (n,) int are
    1-based line numbers in the file; ``dropped_lines`` lists rows dropped for missing values.
    """

    header: tuple
    columns: dict
    labels: list | None
    lines: np.ndarray
    dropped_lines: list


def read_text(path: Path) -> str:
    """The file's text (UTF-8, BOM allowed); refuses binary files with a clear message."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputError(path, "no such file")
    except IsADirectoryError:
        raise InputError(path, "is a directory, expected a file")
    except OSError as exc:
        raise InputError(path, f"cannot be read: {exc.strerror or exc}")
    if b"\x00" in data:
        raise InputError(path, "looks like a binary file (it contains NUL bytes), not a CSV")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise InputError(path, "is not UTF-8 text, so not a CSV this loader reads")


def _split(line: str, lineno: int, path: Path) -> list:
    try:
        return [f.strip() for f in next(csv.reader([line]))]
    except (csv.Error, StopIteration) as exc:
        raise InputError(path, f"line {lineno}: cannot be parsed as CSV ({exc})")


#: columns of a per-bubble collapse-time summary (the published pIMR sets): no R(t) curve
_SUMMARY_COLUMNS = {"rmax_m", "t_collapse_s"}


def _header_problem(found: tuple, expected_sets: tuple) -> str:
    found_l = [f.lower() for f in found]
    if _SUMMARY_COLUMNS <= set(found_l):
        return (
            f"holds per-bubble collapse-time summaries ({','.join(found)}), not R(t) curves: fit, "
            f"diagnose and inspect need t_s,R_m records; pIMR on such a file: python "
            f"validation/pimr_summaries.py (docs/guide.md)"
        )
    for name in found:
        parts = name.lower().replace("[", "_").replace("]", "").replace("(", "_").replace(")", "").split("_")
        if len(parts) > 1 and parts[0] in ("t", "time", "r", "radius") and parts[-1] in _UNIT_HINTS:
            return (
                f"column {name!r} suggests values in {_UNIT_HINTS[parts[-1]]}; columns must be "
                f"t_s,R_m in SI units (seconds, metres)"
            )
    want = expected_sets[0]
    missing = [c for c in want if c not in found]
    extra = [c for c in found if c not in want]
    if len(found) == 1 and any(d in found[0] for d in (";", "\t", "|")):
        return f"header {found[0]!r} is not comma-separated; expected columns {','.join(want)}"
    if "experiment" not in found_l:
        msg = []
        if missing:
            msg.append(f"missing column(s) {', '.join(missing)}")
        if extra:
            msg.append(f"unexpected column(s) {', '.join(repr(e) for e in extra)}")
        return (
            "; ".join(msg) + f" (found {','.join(found) or 'nothing'}; expected {','.join(want)} "
            f"or {','.join(expected_sets[1])})"
        )
    want = expected_sets[1]
    missing = [c for c in want if c not in found]
    extra = [c for c in found if c not in want]
    msg = []
    if missing:
        msg.append(f"missing column(s) {', '.join(missing)}")
    if extra:
        msg.append(f"unexpected column(s) {', '.join(repr(e) for e in extra)}")
    return "; ".join(msg) + f" (found {','.join(found)}; expected {','.join(want)})"


def read_table(path) -> Table:
    """Parse a radius CSV (either shape) into a :class:`Table`; raises InputError on bad content."""
    path = Path(path)
    text = read_text(path)
    rows = []
    header = None
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        fields = _split(line, lineno, path)
        if header is None:
            header = tuple(fields)
            continue
        rows.append((lineno, fields))
    if header is None:
        raise InputError(path, "is empty (expected a header line t_s,R_m and data rows)")
    if len(set(header)) != len(header):
        raise InputError(path, f"repeated column names in header {','.join(header)}")
    if set(header) == set(EXPERIMENT_COLUMNS):
        numeric, label = EXPERIMENT_COLUMNS, None
    elif set(header) == set(LONG_COLUMNS):
        numeric, label = ("t_s", "R_m"), "experiment"
    else:
        raise InputError(path, _header_problem(header, (EXPERIMENT_COLUMNS, LONG_COLUMNS)))
    if not rows:
        raise InputError(path, "has a header but no data rows")
    idx = {name: header.index(name) for name in header}
    ncol = len(header)
    values = {name: np.empty(len(rows)) for name in numeric}
    labels = [] if label else None
    lines = np.empty(len(rows), dtype=np.int64)
    for r, (lineno, fields) in enumerate(rows):
        if len(fields) != ncol:
            raise InputError(path, f"line {lineno}: {len(fields)} values, expected {ncol} ({','.join(header)})")
        lines[r] = lineno
        for name in numeric:
            text_value = fields[idx[name]]
            low = text_value.lower()
            if low in _MISSING:
                values[name][r] = np.nan
            elif _NUMBER.match(text_value):
                v = float(text_value)
                if not np.isfinite(v):
                    raise InputError(path, f"line {lineno}: {name} value {text_value!r} is out of range")
                values[name][r] = v
            else:
                shown = text_value if len(text_value) <= 30 else text_value[:27] + "..."
                raise InputError(path, f"line {lineno}: {name} value {shown!r} is not a number")
        if label:
            name = fields[idx[label]]
            if not name:
                raise InputError(path, f"line {lineno}: empty experiment name")
            labels.append(name)
    bad = np.zeros(len(rows), dtype=bool)
    for name in numeric:
        bad |= np.isnan(values[name])
    dropped = [int(x) for x in lines[bad]]
    keep = ~bad
    columns = {name: values[name][keep] for name in numeric}
    if labels is not None:
        labels = [lab for lab, k in zip(labels, keep) if k]
    return Table(header, columns, labels, lines[keep], dropped)


def format_lines(lines) -> str:
    """``[2, 3, 4, 9]`` -> ``"2-4, 9"`` (compact list of line numbers, at most 8 ranges shown)."""
    lines = sorted(int(x) for x in lines)
    ranges = []
    for x in lines:
        if ranges and x == ranges[-1][1] + 1:
            ranges[-1][1] = x
        else:
            ranges.append([x, x])
    parts = [f"{a}" if a == b else f"{a}-{b}" for a, b in ranges]
    if len(parts) > 8:
        parts = parts[:8] + [f"... ({len(parts) - 8} more ranges)"]
    return ", ".join(parts)


def write_experiment_csv(path, t_s, R_m) -> None:
    """Write one experiment as ``t_s,R_m`` with 17 significant digits (round-trips float64)."""
    t_s = np.asarray(t_s, dtype=np.float64)
    R_m = np.asarray(R_m, dtype=np.float64)
    with open(path, "w", encoding="utf-8", newline="\n") as fh:
        fh.write("t_s,R_m\n")
        for t, r in zip(t_s, R_m):
            fh.write(f"{t:.17g},{r:.17g}\n")
