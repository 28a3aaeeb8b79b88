"""Physical constants (SI) and the dimensionless groups of the bubble problem.

One place holds every constant: :class:`Physics` (defaults = IMRv2's ``default_case``) and
:func:`nondimensional_groups`, which forms the groups exactly as IMRv2 does (lengths scaled by
Rmax, velocities by ``Uc = sqrt(p8/rho)``, pressures by ``p8``, temperature by ``T8``).
See ``shared/docs/methods.md`` §1, §2 and §10.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from imrbayes.errors import InputError

__all__ = ["Physics", "nondimensional_groups", "saturation_pressure_pa", "GROUP_NAMES"]


@dataclass(frozen=True)
class Physics:
    """Material-independent physical constants, SI units. Defaults are IMRv2's.

    Attributes (unit in brackets): ``rho`` far-field density [kg/m^3]; ``p8`` far-field pressure [Pa];
    ``c8`` sound speed [m/s]; ``tait_b`` Tait B [Pa]; ``tait_n`` Tait exponent [-];
    ``surface_tension`` [N/m]; ``kappa`` ratio of specific heats [-]; ``T8`` far-field temperature [K];
    ``k_gas_a``, ``k_gas_b`` gas conductivity ``K = a T + b`` [W/(m K^2)], [W/(m K)];
    ``k_vap_a``, ``k_vap_b`` vapour conductivity, same form; ``k_medium`` [W/(m K)];
    ``cp_medium`` [J/(kg K)]; ``d_vapour`` vapour-gas diffusivity [m^2/s]; ``latent_heat`` [J/kg];
    ``r_universal`` [J/(mol K)]; ``m_vapour``, ``m_gas`` molar masses [kg/mol];
    ``medium_stretch`` the medium grid stretch ``Lt`` [-].
    """

    rho: float = 1064.0
    p8: float = 101325.0
    c8: float = 1484.0
    tait_b: float = 3049.13e5
    tait_n: float = 7.15
    surface_tension: float = 0.07
    kappa: float = 1.47
    T8: float = 298.15
    k_gas_a: float = 5.28e-5
    k_gas_b: float = 1.165e-2
    k_vap_a: float = 3.30e-5
    k_vap_b: float = 1.742e-2
    k_medium: float = 0.55
    cp_medium: float = 4181.0
    d_vapour: float = 24.2e-6
    latent_heat: float = 2264.76e3
    r_universal: float = 8.3144598
    m_vapour: float = 18.01528e-3
    m_gas: float = 28.966e-3
    medium_stretch: float = 2.0

    # Accepted spellings in meta.json "physics" (interfaces.md §1) -> field name.
    _ALIASES = {"rho8": "rho", "P8": "p8", "C8": "c8", "S": "surface_tension", "t8": "T8",
                "GAM": "tait_b", "nstate": "tait_n", "Km": "k_medium", "Cp": "cp_medium",
                "D0": "d_vapour", "L_heat": "latent_heat"}

    # Constants that may be switched off (an ideal, tension-free interface).
    _MAY_BE_ZERO = ("surface_tension",)

    @classmethod
    def from_overrides(cls, overrides: dict | None = None, source: str = "physics") -> Physics:
        """Defaults with ``overrides`` (a dict of field names or IMRv2 aliases -> SI values)."""
        fields = {f.name for f in dataclasses.fields(cls)}
        kwargs = {}
        for key, value in (overrides or {}).items():
            name = cls._ALIASES.get(key, key)
            if name not in fields:
                raise InputError(source, f"unknown physical constant {key!r}; known: {sorted(fields)}")
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise InputError(source, f"physical constant {key!r} must be a number, got {value!r}")
            if not math.isfinite(value) or value < 0.0 or (value == 0.0 and name not in cls._MAY_BE_ZERO):
                raise InputError(source, f"physical constant {key!r} must be finite and positive, got {value}")
            kwargs[name] = value
        return cls(**kwargs)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @property
    def velocity_scale(self) -> float:
        """``Uc = sqrt(p8/rho)`` [m/s]."""
        return math.sqrt(self.p8 / self.rho)

    def time_scale(self, rmax_m):
        """``tc = Rmax/Uc`` [s]; works on arrays."""
        return np.asarray(rmax_m, dtype=float) / self.velocity_scale


def saturation_pressure_pa(T_k):
    """IMRv2's vapour saturation pressure ``1.17e11 exp(-5200/T)`` [Pa] at ``T_k`` [K]."""
    return 1.17e11 * np.exp(-5200.0 / np.asarray(T_k, dtype=float))


# Order of the per-member group vector handed to the compiled kernel.
GROUP_NAMES = (
    "inv_we", "cstar", "tait_b", "tait_n", "kappa", "chi", "fom", "foh", "br", "iota",
    "alpha_g", "beta_g", "alpha_v", "beta_v", "rv", "rg", "lstar", "req", "pv", "kv0",
    "T8", "p8", "lt", "pb0",
)


def nondimensional_groups(physics: Physics, rmax_m, req_m, *, thermal: bool, vapor: bool) -> dict:
    """Dimensionless groups and initial contents for bubbles of maximum radius ``rmax_m`` [m].

    ``rmax_m`` and ``req_m`` [m] may be scalars or arrays of one shape; every value returned has
    that shape (or is a scalar constant). Keys: the names in :data:`GROUP_NAMES` plus ``uc``
    [m/s], ``tc`` [s]. ``pb0`` is the initial bubble pressure over p8, ``pv`` the vapour pressure
    over p8, ``kv0`` the initial vapour mass fraction (forward-model.md §2).
    """
    ph = physics
    rmax = np.asarray(rmax_m, dtype=float)
    req = np.asarray(req_m, dtype=float)
    uc = ph.velocity_scale
    k8 = 0.5 * ((ph.k_gas_a * ph.T8 + ph.k_gas_b) + (ph.k_vap_a * ph.T8 + ph.k_vap_b))
    r_nd = ph.p8 / (ph.rho * ph.T8)
    rv = ph.r_universal / ph.m_vapour / r_nd
    rg = ph.r_universal / ph.m_gas / r_nd
    pv_pa = saturation_pressure_pa(ph.T8) if vapor else 0.0
    pv = pv_pa / ph.p8
    exponent = 3.0 if thermal else 3.0 * ph.kappa
    pg0 = (ph.p8 + 2.0 * ph.surface_tension / req - pv_pa) * (req / rmax) ** exponent
    pb0 = pg0 / ph.p8 + pv
    if vapor:
        theta0 = (rv / rg) * (pb0 / pv - 1.0)
        kv0 = 1.0 / (1.0 + theta0)
    else:
        kv0 = np.zeros_like(pb0)
    d_medium = ph.k_medium / (ph.rho * ph.cp_medium)
    return {
        "uc": uc,
        "tc": rmax / uc,
        "inv_we": 2.0 * ph.surface_tension / (ph.p8 * rmax),
        "cstar": ph.c8 / uc,
        "tait_b": ph.tait_b / ph.p8,
        "tait_n": ph.tait_n,
        "kappa": ph.kappa,
        "chi": ph.T8 * k8 / (ph.p8 * rmax * uc),
        "fom": ph.d_vapour / (uc * rmax),
        "foh": d_medium / (uc * rmax),
        "br": uc**2 / (ph.cp_medium * ph.T8),
        "iota": ph.k_medium / (k8 * ph.medium_stretch),
        "alpha_g": ph.k_gas_a * ph.T8 / k8,
        "beta_g": ph.k_gas_b / k8,
        "alpha_v": ph.k_vap_a * ph.T8 / k8,
        "beta_v": ph.k_vap_b / k8,
        "rv": rv,
        "rg": rg,
        "lstar": ph.latent_heat / uc**2,
        "req": req / rmax,
        "pv": pv,
        "kv0": kv0,
        "T8": ph.T8,
        "p8": ph.p8,
        "lt": ph.medium_stretch,
        "pb0": pb0,
    }


def group_matrix(groups: dict, n: int) -> np.ndarray:
    """Stack ``groups`` into the kernel's ``(n, len(GROUP_NAMES))`` float64 array."""
    out = np.empty((n, len(GROUP_NAMES)))
    for j, name in enumerate(GROUP_NAMES):
        out[:, j] = groups[name]      # scalar or (n,): plain assignment broadcasts
    return out
