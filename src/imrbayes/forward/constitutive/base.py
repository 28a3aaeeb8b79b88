"""The constitutive-model protocol and registry.

A constitutive model is one small module that defines

* ``N_AUX`` - the number of auxiliary stress states it integrates;
* ``stress(R, Rdot, z, p, req, zdot) -> (S, Sdot, J)`` - a numba ``@njit(cache=True, error_model="numpy")`` function
  giving the dimensionless stress integral S (forward-model.md §5), its time derivative *without*
  the term proportional to Rddot, and the coefficient J of that term; it writes the rates of its
  auxiliary states into ``zdot``. ``p`` is the dimensionless parameter vector from
  :meth:`ConstitutiveModel.nondimensionalise`: ``p[0] = G/p8`` (1/Ca, 0 without elasticity),
  ``p[1] = mu/(rho Uc Rmax)`` (1/Re), then model-specific entries, and last (``p[-1]``, appended
  by the forward model, not by the model's map) the ``zener_j`` option: 1 ``consistent``, 0 ``imrv2``;
* ``dissipation_q(x, y, p)`` - the elastic dissipation factor used by the medium energy equation;
* ``MODEL`` - a :class:`ConstitutiveModel` describing its parameters.

and one line in ``REGISTRY`` below. Nothing else changes to add a model.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from imrbayes.errors import InputError

# name -> module holding the model (imported lazily).
REGISTRY = {
    "none": "imrbayes.forward.constitutive.inviscid",
    "newtonian": "imrbayes.forward.constitutive.newtonian",
    "nhkv": "imrbayes.forward.constitutive.nhkv",
    "kv": "imrbayes.forward.constitutive.kv",
    "qkv": "imrbayes.forward.constitutive.qkv",
    "zener": "imrbayes.forward.constitutive.zener",
    "maxwell": "imrbayes.forward.constitutive.maxwell",
    "qzener": "imrbayes.forward.constitutive.qzener",
    "oldroyd-b": "imrbayes.forward.constitutive.oldroydb",
    "fung": "imrbayes.forward.constitutive.fung",
    "carreau": "imrbayes.forward.constitutive.carreau",
}
ALIASES = {"sls": "zener", "ucm": "oldroyd-b", "oldroydb": "oldroyd-b", "inviscid": "none"}


@dataclass(frozen=True)
class Parameter:
    """One material parameter: ``name``, SI ``unit``, a typical ``default``, whether it must be
    ``positive`` (inference then works on its logarithm), a one-line ``description``, and
    ``prior_sd`` [SI]: the default prior's sd where half the default cannot be (a default of 0;
    None: 1 SI unit -- 1 s for a time of microseconds would make every member fail)."""

    name: str
    unit: str
    default: float
    positive: bool = True
    description: str = ""
    prior_sd: float | None = None


@dataclass(frozen=True)
class ConstitutiveModel:
    """Metadata and the SI -> dimensionless map of one registered model."""

    name: str
    description: str
    parameters: tuple
    n_aux: int
    module: str
    imrv2_stress: int | None = None
    _nondim: Callable = field(default=None, repr=False)

    @property
    def param_names(self) -> tuple:
        return tuple(p.name for p in self.parameters)

    @property
    def defaults(self) -> dict:
        return {p.name: p.default for p in self.parameters}

    def param_array(self, params, n: int | None = None, source: str = "parameters") -> np.ndarray:
        """SI parameters as an ``(n, n_params)`` array from a dict of scalars/arrays or an array.

        Missing names take the model default. Raises InputError on unknown names or bad values.
        """
        if isinstance(params, dict):
            unknown = set(params) - set(self.param_names)
            if unknown:
                raise InputError(source, f"model {self.name!r} has no parameter(s) {sorted(unknown)}; "
                                 f"it takes {list(self.param_names)}")
            cols = [np.atleast_1d(np.asarray(params.get(p.name, p.default), dtype=float))
                    for p in self.parameters]
            size = max([c.size for c in cols] + [n or 1])
            arr = np.column_stack([np.broadcast_to(c, (size,)) for c in cols]) if cols else np.zeros((size, 0))
        else:
            arr = np.asarray(params, dtype=float)
            if arr.ndim == 1:
                arr = arr[None, :]
            if arr.shape[-1] != len(self.parameters):
                raise InputError(source, f"model {self.name!r} takes {len(self.parameters)} parameters "
                                 f"{list(self.param_names)}, got {arr.shape[-1]}")
        if n is not None and arr.shape[0] == 1 and n > 1:
            arr = np.repeat(arr, n, axis=0)
        return np.ascontiguousarray(arr, dtype=float)

    def nondimensionalise(self, params_si: np.ndarray, *, rho: float, p8: float, uc: float,
                          rmax_m: np.ndarray) -> np.ndarray:
        """``(..., n_params)`` SI parameters -> ``(..., n_p)`` kernel vector (p[0]=1/Ca, p[1]=1/Re)."""
        return np.ascontiguousarray(self._nondim(np.asarray(params_si, dtype=float), rho=rho, p8=p8,
                                                 uc=uc, rmax_m=np.asarray(rmax_m, dtype=float)))


def canonical_name(name: str) -> str:
    key = str(name).strip().lower()
    return ALIASES.get(key, key)


def available_models() -> list:
    """Names of the registered constitutive models."""
    return sorted(REGISTRY)


def get_model(name: str) -> ConstitutiveModel:
    """The registered model called ``name`` (aliases such as ``sls``, ``ucm`` accepted)."""
    key = canonical_name(name)
    if key not in REGISTRY:
        raise InputError("--model", f"unknown constitutive model {name!r}; available: {available_models()}")
    module = importlib.import_module(REGISTRY[key])
    return module.MODEL


def inv_re(mu, *, rho, uc, rmax_m):
    """1/Re = mu / (rho Uc Rmax) for mu [Pa s]."""
    return mu / (rho * uc * rmax_m)
