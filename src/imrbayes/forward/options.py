"""Forward-model options (interfaces.md §1 ``forward``) and the bubble/medium grids."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from imrbayes.errors import InputError

RADIAL = {"rp": 1, "km": 2, "km-enthalpy": 3, "gilmore": 4}
SCHEMES = ("converged", "imrv2-fd")

# Default resolution per scheme: (nt, mt). The converged scheme clusters points at the wall
# (see bubble_grid). Its grid is the cheapest wall-clustered grid within 1.5e-3 (relative L2 in R*,
# t* <= 3) of the grid limit on the refinement study's cases (LIC, a stiff and a soft gel, the LIC
# batch; with and without mass transfer) and on held-out bubbles over the range of the real gels
# (benchmarks/grid_refinement.py, docs/methods.md "Default resolution"). mt (medium points)
# matters only with the warm medium, which the study did not cover: it stays at 64.
DEFAULT_RESOLUTION = {"imrv2-fd": (25, 25), "converged": (96, 64)}
DEFAULT_STRETCH = 2.75
# (rtol, atol) per integrator, chosen so that R has <= 1e-4 pointwise relative error against a
# tight solve on the LIC benchmark batch (benchmarks/forward.py, row d) on the previous default grid
# (stretch 1.5, nt 64). On the converged default grid (stretch 2.75, nt 96) Radau's 2e-5 gives
# 1.1e-4 at the worst instant of that batch and 2.5e-6 relative L2 (the grid's error is ~5e-4).
DEFAULT_TOLERANCES = {"ark548": (3e-6, 3e-8), "ark324": (1e-7, 1e-9), "dopri5": (1e-7, 1e-9),
                      "dop853": (3e-6, 3e-8), "radau5": (2e-5, 2e-7)}
# IMRv2's coarse uniform grid amplifies integration error through the collapses, so it gets
# tighter tolerances (benchmark batch: ARK 3e-6 gave 9e-4 in R; Radau 3e-5 gave 6.6e-4, 3e-6 3.6e-5).
IMRV2_FD_TOLERANCES = {"ark548": (2e-7, 2e-9), "radau5": (3e-6, 3e-8)}
INTEGRATORS = ("ark548", "ark324", "radau5", "dopri5", "dop853")


@dataclass(frozen=True)
class ForwardOptions:
    """Which physics the forward model solves and how finely.

    radial : ``km`` (Keller-Miksis, pressure form; default), ``rp`` (Rayleigh-Plesset),
        ``km-enthalpy`` (Keller-Miksis with a Tait liquid), ``gilmore``.
    bubble : ``thermal`` (temperature PDE inside the bubble; default) or ``polytropic``.
    vapor, mass_transfer : vapour in the bubble; vapour diffusion and condensation (thermal only).
    medium : ``cold`` (wall at T8; default) or ``warm`` (temperature field in the medium).
    scheme : ``converged`` (default; wall-clustered grid, grid-converged) or ``imrv2-fd``
        (IMRv2's uniform finite differences, for conformance).
    nt, mt : points inside the bubble and in the medium (None: the scheme's default).
    stretch : wall clustering of the converged grid (``y = tanh(b s)/tanh(b)``).
    polytropic_pdot : ``consistent`` (exact rate of the polytropic pressure) or ``imrv2`` (IMRv2's
        rate computed from the total pressure, vapour included); None picks ``imrv2`` for the
        ``imrv2-fd`` scheme and ``consistent`` otherwise.
    zener_j : ``consistent`` (the Keller-Miksis coefficient of Rddot is the Zener-type stress's own
        instantaneous viscosity, 4 Lambda/Re) or ``imrv2`` (IMRv2's stress model 3/4 uses 4/Re for
        every Lambda); None picks ``imrv2`` for the ``imrv2-fd`` scheme and ``consistent``
        otherwise. Only the Zener family (zener, maxwell, qzener) reads it.
    rtol, atol : integrator tolerances (per component: atol + rtol |y|); None: the integrator's
        default (DEFAULT_TOLERANCES).
    integrator : ``radau5`` (Radau IIA, implicit 5th order with the structured Jacobian; default
        for the thermal bubble in a cold medium), ``ark548`` (5th-order implicit-explicit; default
        with the warm medium), ``ark324`` (3rd order), ``dop853`` (explicit 8th order; default for
        the polytropic bubble, which is not stiff) or ``dopri5`` (explicit 5th order).
    """

    radial: str = "km"
    bubble: str = "thermal"
    vapor: bool = True
    mass_transfer: bool = True
    medium: str = "cold"
    scheme: str = "converged"
    nt: int | None = None
    mt: int | None = None
    stretch: float | None = None
    polytropic_pdot: str | None = None
    zener_j: str | None = None
    rtol: float | None = None
    atol: float | None = None
    integrator: str | None = None

    def __post_init__(self):
        src = "forward options"
        if self.radial not in RADIAL:
            raise InputError(src, f"radial must be one of {list(RADIAL)}, got {self.radial!r}")
        if self.bubble not in ("thermal", "polytropic"):
            raise InputError(src, f"bubble must be 'thermal' or 'polytropic', got {self.bubble!r}")
        if self.medium not in ("cold", "warm"):
            raise InputError(src, f"medium must be 'cold' or 'warm', got {self.medium!r}")
        if self.scheme not in SCHEMES:
            raise InputError(src, f"scheme must be one of {list(SCHEMES)}, got {self.scheme!r}")
        if self.polytropic_pdot not in (None, "consistent", "imrv2"):
            raise InputError(src, f"polytropic_pdot must be 'consistent' or 'imrv2', got {self.polytropic_pdot!r}")
        if self.zener_j not in (None, "consistent", "imrv2"):
            raise InputError(src, f"zener_j must be 'consistent' or 'imrv2', got {self.zener_j!r}")
        if self.mass_transfer and not (self.vapor and self.bubble == "thermal"):
            # IMRv2 has no polytropic mass transfer; vapour off leaves nothing to transfer.
            object.__setattr__(self, "mass_transfer", False)
        if self.medium == "warm" and self.bubble != "thermal":
            raise InputError(src, "medium='warm' needs bubble='thermal'")
        for name in ("nt", "mt"):
            v = getattr(self, name)
            if v is not None and (int(v) != v or v < 5):
                raise InputError(src, f"{name} must be an integer >= 5, got {v!r}")
        if self.integrator not in (None, *INTEGRATORS):
            raise InputError(src, f"integrator must be one of {', '.join(INTEGRATORS)}, got {self.integrator!r}")
        if self.integrator == "radau5" and not (self.thermal and self.medium == "cold"):
            raise InputError(src, "integrator radau5 needs bubble=thermal with medium=cold "
                                  "(use ark548 for the warm medium, dop853 for the polytropic bubble)")
        if self.integrator in ("dopri5", "dop853") and self.thermal:
            raise InputError(src, f"integrator {self.integrator} is explicit: it needs bubble=polytropic "
                                  "(the thermal bubble's diffusion is stiff; use radau5, or ark548 with the warm medium)")
        tol = DEFAULT_TOLERANCES[self.method]
        if self.scheme == "imrv2-fd":
            tol = IMRV2_FD_TOLERANCES.get(self.method, tol)
        if self.rtol is None:
            object.__setattr__(self, "rtol", tol[0])
        if self.atol is None:
            object.__setattr__(self, "atol", tol[1])
        if not (0 < self.rtol < 1 and 0 < self.atol < 1):
            raise InputError(src, "rtol and atol must lie in (0, 1)")

    @classmethod
    def from_dict(cls, d: dict | None, source: str = "forward options") -> ForwardOptions:
        """Build from a dict whose values may be strings (``--forward KEY=VALUE``, meta.json)."""
        fields = {f.name: f for f in dataclasses.fields(cls)}
        kwargs = {}
        for key, value in (d or {}).items():
            name = key.replace("-", "_")
            if name == "masstrans":
                name = "mass_transfer"
            if name not in fields:
                raise InputError(source, f"unknown forward option {key!r}; known: {sorted(fields)}")
            kwargs[name] = _parse(name, value, source)
        return cls(**kwargs)

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["nt"], d["mt"] = self.resolution
        d["stretch"] = self.grid_stretch
        d["polytropic_pdot"] = self.pdot_mode
        d["zener_j"] = self.j_mode
        d["integrator"] = self.method
        return d

    @property
    def method(self) -> str:
        """The time integrator actually used."""
        if self.integrator:
            return self.integrator
        if not self.thermal:
            return "dop853"
        return "radau5" if self.medium == "cold" else "ark548"

    @property
    def resolution(self) -> tuple:
        nt0, mt0 = DEFAULT_RESOLUTION[self.scheme]
        return (int(self.nt) if self.nt else nt0, int(self.mt) if self.mt else mt0)

    @property
    def grid_stretch(self) -> float:
        if self.scheme == "imrv2-fd":
            return 0.0
        return DEFAULT_STRETCH if self.stretch is None else float(self.stretch)

    def _imrv2_choice(self, value) -> str:
        """An IMRv2-conformance choice: ``value``, or by default IMRv2's on its own scheme."""
        return value or ("imrv2" if self.scheme == "imrv2-fd" else "consistent")

    @property
    def pdot_mode(self) -> str:
        return self._imrv2_choice(self.polytropic_pdot)

    @property
    def j_mode(self) -> str:
        return self._imrv2_choice(self.zener_j)

    @property
    def thermal(self) -> bool:
        return self.bubble == "thermal"


_BOOL = {"true": True, "1": True, "yes": True, "on": True, "false": False, "0": False, "no": False, "off": False}


def _parse(name, value, source):
    if name in ("vapor", "mass_transfer"):
        if isinstance(value, bool):
            return value
        if isinstance(value, (int, np.integer)) and value in (0, 1):
            return bool(value)
        if isinstance(value, str) and value.strip().lower() in _BOOL:
            return _BOOL[value.strip().lower()]
        raise InputError(source, f"forward option {name!r} must be true or false, got {value!r}")
    if name in ("nt", "mt"):
        if value is None or (isinstance(value, str) and value.lower() in ("", "none", "default")):
            return None
        try:
            f = float(value)
        except (TypeError, ValueError):
            raise InputError(source, f"forward option {name!r} must be an integer, got {value!r}")
        if f != int(f):
            raise InputError(source, f"forward option {name!r} must be an integer, got {value!r}")
        return int(f)
    if name in ("rtol", "atol", "stretch"):
        try:
            return float(value)
        except (TypeError, ValueError):
            raise InputError(source, f"forward option {name!r} must be a number, got {value!r}")
    return str(value).strip().lower() if isinstance(value, str) else value


def bubble_grid(nt: int, stretch: float) -> tuple:
    """Bubble grid ``y = r/R`` (nt,) and its difference coefficients, shape (8, nt).

    ``stretch = 0`` is IMRv2's uniform grid; ``stretch = b > 0`` maps a uniform ``s`` through
    ``y = tanh(b s)/tanh(b)``, which clusters points at the wall where the thermal and vapour
    boundary layers form. Rows (see layout.GR_*): y; first derivative (lower, centre, upper);
    spherical Laplacian d2/dy2 + (2/y) d/dy (lower, centre, upper); the wall row's one-sided
    derivative coefficients on (wall, wall-1, wall-2) in entries 0..2 of the last row.
    On the uniform grid these are exactly IMRv2's second-order formulas.
    """
    s = np.linspace(0.0, 1.0, nt)
    y = s.copy() if stretch == 0 else np.tanh(stretch * s) / np.tanh(stretch)
    y[0], y[-1] = 0.0, 1.0
    out = np.zeros((8, nt))
    out[0] = y
    for i in range(1, nt - 1):
        hm, hp = y[i] - y[i - 1], y[i + 1] - y[i]
        d1 = np.array([-hp / (hm * (hm + hp)), (hp - hm) / (hm * hp), hm / (hp * (hm + hp))])
        d2 = np.array([2.0 / (hm * (hm + hp)), -2.0 / (hm * hp), 2.0 / (hp * (hm + hp))]) + 2.0 / y[i] * d1
        out[1:4, i] = d1
        out[4:7, i] = d2
    h1 = y[1] - y[0]
    out[5, 0] = -6.0 / h1**2  # centre row: 3 d2/dy2 with the even-symmetry ghost point
    out[6, 0] = 6.0 / h1**2
    x = y[-1] - np.array([y[-1], y[-2], y[-3]])  # distances from the wall: 0, h1, h1 + h2
    vander = np.vstack([np.ones(3), -x, x**2])
    out[7, :3] = np.linalg.solve(vander, np.array([0.0, 1.0, 0.0]))
    return y, out


def medium_grid(mt: int, lt: float) -> np.ndarray:
    """IMRv2's medium grid, shape (2, mt): xi from 1 (wall) to -1 (infinity) and y = r/R."""
    xi = 1.0 + np.arange(mt) * (-2.0 / (mt - 1))
    with np.errstate(divide="ignore"):
        ym = 1.0 + lt * (1.0 - xi) / (1.0 + xi)
    ym[-1] = np.inf
    return np.vstack([xi, ym])
