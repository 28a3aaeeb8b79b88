"""The in-memory form of measured data: :class:`Experiment` and :class:`Dataset`.

Loaders (``loaders.py``) build these from files; preprocessing (``pipeline.py``) reads them and
never changes them. All arrays are float64 in SI units.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Experiment", "Dataset", "DEFAULT_RHO", "DEFAULT_P8"]

#: Far-field density [kg/m^3] and pressure [Pa] used to nondimensionalise unless meta.json
#: ``physics`` overrides them (``rho``/``rho8``, ``p8``/``P8``). Same defaults as the forward model.
DEFAULT_RHO = 1064.0
DEFAULT_P8 = 101325.0


@dataclass
class Experiment:
    """One recorded bubble, as measured.

    Attributes
    ----------
    name : str
        Experiment name (CSV file stem, long-CSV ``experiment`` value, or a name the .mat layout gives).
    t_s : ndarray, shape (n,)
        Time [s], strictly increasing; any origin (growth frames before the maximum allowed).
    R_m : ndarray, shape (n,)
        Bubble radius [m], positive. NaN rows already dropped (see ``warnings``).
    source : str
        The file it came from (used to start error messages).
    req_m : float or None
        Equilibrium radius [m] given by meta.json or by the file itself; None = estimate it.
    req_sd_m : float or None
        Its uncertainty [m] if given.
    req_source : str or None
        Where ``req_m`` came from (``"meta.json"``, ``"file"``), None when not given.
    info : dict
        Per-experiment metadata (meta.json ``experiments`` entry, layout details); kept, not interpreted.
    warnings : list of str
        Things a user should know (dropped rows, ...).
    """

    name: str
    t_s: np.ndarray
    R_m: np.ndarray
    source: str
    req_m: float | None = None
    req_sd_m: float | None = None
    req_source: str | None = None
    info: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)

    def __post_init__(self):
        self.t_s = np.asarray(self.t_s, dtype=np.float64)
        self.R_m = np.asarray(self.R_m, dtype=np.float64)

    @property
    def n_samples(self) -> int:
        return int(self.t_s.size)

    @property
    def camera(self) -> str | None:
        """Camera view label (``info["camera"]`` or a ``_cam...`` name suffix), else None."""
        cam = self.info.get("camera")
        if isinstance(cam, str) and cam:
            return cam
        head, sep, tail = self.name.rpartition("_cam")
        return f"cam{tail}" if sep and head and tail else None


@dataclass
class Dataset:
    """Experiments of one material/condition, with the dataset's metadata.

    Attributes
    ----------
    name : str
        Directory name or file stem.
    path : str
        What the user gave.
    format : str
        ``"directory"``, ``"csv"``, ``"long-csv"`` or ``"mat:<layout>"``.
    experiments : list of Experiment
    material : str
        meta.json ``material`` (``"unknown"`` when absent).
    meta : dict
        The whole meta.json object (unknown keys kept), ``{}`` if there was none.
    physics : dict
        meta.json ``physics`` overrides (SI), passed through to the forward model.
    forward : dict
        meta.json ``forward`` options, passed through to ``ForwardOptions.from_dict``.
    meta_path : str or None
        The meta.json read, if any.
    warnings, notes : list of str
        Warnings for the user; notes record what the loader decided (layout found, units converted).
    """

    name: str
    path: str
    format: str
    experiments: list
    material: str = "unknown"
    meta: dict = field(default_factory=dict)
    physics: dict = field(default_factory=dict)
    forward: dict = field(default_factory=dict)
    meta_path: str | None = None
    warnings: list = field(default_factory=list)
    notes: list = field(default_factory=list)

    @property
    def names(self) -> list:
        return [e.name for e in self.experiments]

    def physical_constant(self, *keys, default: float) -> float:
        """First of ``keys`` present in ``physics`` (as float), else ``default``."""
        for key in keys:
            if key in self.physics:
                return float(self.physics[key])
        return float(default)

    @property
    def rho(self) -> float:
        """Density used to nondimensionalise [kg/m^3]."""
        return self.physical_constant("rho", "rho8", default=DEFAULT_RHO)

    @property
    def p8(self) -> float:
        """Far-field pressure used to nondimensionalise [Pa]."""
        return self.physical_constant("p8", "P8", default=DEFAULT_P8)

    def select(self, camera: str | None = None, names=None) -> Dataset:
        """A copy keeping experiments of one camera view and/or the given names."""
        keep = list(self.experiments)
        if camera is not None:
            keep = [e for e in keep if e.camera == camera or (e.camera is None and camera in e.name)]
        if names is not None:
            wanted = set(names)
            keep = [e for e in keep if e.name in wanted]
        return Dataset(
            self.name,
            self.path,
            self.format,
            keep,
            self.material,
            self.meta,
            self.physics,
            self.forward,
            self.meta_path,
            list(self.warnings),
            list(self.notes),
        )
