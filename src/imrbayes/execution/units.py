"""Units of work and their random streams.

A *unit* is one independent piece of a run (one experiment, one window of one experiment, one chunk
of a parameter grid, one MCMC chain) with a stable string id such as ``"exp=003/window=07"``. The id
names the unit's checkpoint file and seeds its random numbers, so it must be the same every time the
run is set up from the same configuration (build it from indices, never from ``id()`` or a clock).

Each unit draws from its own :class:`numpy.random.Generator` seeded from (run seed, unit id -- or the
unit's ``stream`` key where it sets one) through
:class:`numpy.random.SeedSequence`, with a SHA-256 of the id as the spawn key. Python's ``hash`` is
salted per process and is never used. So a unit's random numbers, and therefore its result, do not
depend on which backend ran it, how many workers there were, in which order units finished, or
whether the run was resumed.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = [
    "Unit",
    "unit_id",
    "unit_seed_sequence",
    "unit_rng",
    "unit_stream",
    "normalize_units",
    "safe_name",
    "SEEDING_SCHEME",
]

#: Recorded in ``run.json``; bump it if the derivation below ever changes (stored runs would no
#: longer resume to the same numbers).
SEEDING_SCHEME = "SeedSequence(entropy=seed, spawn_key=sha256(unit_id) as 8 little-endian uint32)/PCG64"


@dataclass(frozen=True)
class Unit:
    """One independent piece of work.

    Parameters
    ----------
    unit_id : str
        Stable, unique within a run, e.g. ``"exp=003/window=07"``.
    data : any
        What the unit function needs (picklable; kept small: it travels to the worker).
    stream : str, optional
        The key of the unit's random stream when it must not be the id (default: the id). An id that
        also carries a digest of inputs computed upstream (so that a resume after they changed
        recomputes the unit) would otherwise reseed the unit whenever those inputs move in their last
        bits: MIEnKS-MDA's reported pass did that, and a 1e-12 change of the forward output moved one
        bubble's G by 2-11 %, a change of seed dressed up as chaos.
    """

    unit_id: str
    data: Any = field(default=None, compare=False)
    stream: str | None = field(default=None, compare=False)


def unit_id(**parts) -> str:
    """``unit_id(exp=3, window=7) -> "exp=003/window=007"`` (ints zero-padded to 3 digits, so ids
    sort in index order; the keyword order is kept)."""
    if not parts:
        raise ValueError("unit_id needs at least one key=value part")
    out = []
    for key, val in parts.items():
        if isinstance(val, (int, np.integer)) and not isinstance(val, bool):
            val = f"{int(val):03d}"
        out.append(f"{key}={val}")
    return "/".join(out)


def _check_id(uid) -> str:
    if not isinstance(uid, str) or not uid:
        raise ValueError(f"a unit id must be a non-empty string, got {uid!r}")
    return uid


def _id_of(unit) -> str:
    if isinstance(unit, dict):
        if "unit_id" not in unit:
            raise ValueError(f"a unit given as a dict needs a 'unit_id' key: {unit!r}"[:200])
        return _check_id(unit["unit_id"])
    uid = getattr(unit, "unit_id", None)
    if uid is None:
        raise ValueError(f"a unit needs a 'unit_id' (attribute or dict key): {unit!r}"[:200])
    return _check_id(uid)


def normalize_units(units: Iterable) -> list[tuple[str, Any]]:
    """``[(unit_id, unit), ...]`` in the given order; units are :class:`Unit`, any object with a
    ``unit_id`` attribute, or dicts with a ``"unit_id"`` key. Duplicate ids raise ``ValueError``."""
    out, seen = [], set()
    for unit in units:
        uid = _id_of(unit)
        if uid in seen:
            raise ValueError(f"duplicate unit id {uid!r}")
        seen.add(uid)
        out.append((uid, unit))
    return out


def _hash_words(uid: str, n: int = 8) -> tuple[int, ...]:
    digest = hashlib.sha256(uid.encode("utf-8")).digest()
    return tuple(int.from_bytes(digest[4 * i : 4 * i + 4], "little") for i in range(n))


def _check_seed(seed) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or int(seed) < 0:
        raise ValueError(f"the run seed must be a non-negative integer, got {seed!r}")
    return int(seed)


def unit_seed_sequence(seed: int, uid: str) -> np.random.SeedSequence:
    """The unit's :class:`~numpy.random.SeedSequence`: ``entropy=seed``, ``spawn_key`` from
    SHA-256 of the id (stable across processes, machines and Python versions)."""
    return np.random.SeedSequence(entropy=_check_seed(seed), spawn_key=_hash_words(_check_id(uid)))


def unit_stream(unit, uid: str) -> str:
    """The key of ``unit``'s random stream: its ``stream`` (attribute or dict key) when set, else ``uid``."""
    stream = unit.get("stream") if isinstance(unit, dict) else getattr(unit, "stream", None)
    return uid if stream is None else _check_id(stream)


def unit_rng(seed: int, uid: str) -> np.random.Generator:
    """The unit's generator (PCG64 on :func:`unit_seed_sequence`)."""
    return np.random.Generator(np.random.PCG64(unit_seed_sequence(seed, uid)))


_MAX_NAME = 120


_SAFE = frozenset("abcdefghijklmnopqrstuvwxyz0123456789_.-=")


def safe_name(uid: str) -> str:
    """A file-name stem for a unit id: lower-case letters, digits and ``_.-=`` are kept, every other
    byte of its UTF-8 is percent-encoded (``/`` -> ``%2F``, ``A`` -> ``%41``). One-to-one, even on
    case-insensitive file systems (upper case occurs only as hex digits after ``%``). Ids whose
    encoding is longer than 120 characters keep an 80-character prefix plus ``~`` and 16 hex digits of
    SHA-256 (``~`` never occurs in an encoding). The id is also stored inside the file and checked
    when it is read."""
    name = "".join(ch if ch in _SAFE else "".join(f"%{b:02X}" for b in ch.encode("utf-8")) for ch in _check_id(uid))
    if len(name) > _MAX_NAME:
        name = name[:80] + "~" + hashlib.sha256(uid.encode("utf-8")).hexdigest()[:16]
    return name
