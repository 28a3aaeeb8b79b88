"""Another code behind our ``simulate_radius`` interface: PyIMR as a data generator.

Synthetic data made by the model that is then fitted test the inference, not the model: its
discretisation, integrator and bookkeeping are shared by both sides. :class:`PyIMRModel` makes
the same physics with the other Python IMR code (``pyimr`` on the package index, the optional
``peers`` extra: JAX/diffrax, Chebyshev collocation of the bubble's fields), so that
``imrbayes simulate --generator pyimr`` writes records that no part of imrbayes produced.

Every constant is passed from our :class:`~imrbayes.forward.constants.Physics` (PyIMR's own
polytropic exponent is 1.4 against IMRv2's 1.47); the forward options map one to one (radial
model, thermal or polytropic bubble, vapour, mass transfer, cold or warm medium). Materials:
``nhkv``, ``qkv``, ``zener`` (IMRv2's stress models 1, 2 and the Zener family in both codes; the
Zener with ``zener_j=consistent``, our default, which is PyIMR's).
Measured agreement at both codes' grid limits: ``docs/methods.md`` (peer row) and
``docs/validation.md`` ("Data from another code").
"""

from __future__ import annotations

import numpy as np

from imrbayes.errors import ForwardModelError, InputError

__all__ = ["PyIMRModel", "PEER_MODELS"]

#: our model name -> (PyIMR class name, our parameter names in PyIMR's order)
PEER_MODELS = {"nhkv": ("NeoHookeanKelvinVoigt", ("G", "mu")),
               "qkv": ("QuadraticKelvinVoigt", ("G", "mu", "alpha")),
               "zener": ("Zener", ("G", "mu", "lambda1", "lambda2"))}
_RADIAL = {"rp": 1, "km": 2, "km-enthalpy": 3, "gilmore": 4}


class PyIMRModel:
    """PyIMR with our physics and options; ``simulate_radius`` as :class:`ForwardModel`'s.

    fm : the :class:`~imrbayes.forward.ForwardModel` whose model, options and constants to copy.
    nt : PyIMR's collocation points in the bubble (65: its own 33 -> 65 refinement is ~2e-3 in
        relative L2 of R*, and it lies 5e-4 from our grid limit on the LIC case).
    rtol, atol : PyIMR's integrator tolerances.
    """

    def __init__(self, fm, nt: int = 65, rtol: float = 1e-8, atol: float = 1e-10):
        try:
            import pyimr
        except ImportError:
            raise InputError("--generator", "pyimr is not installed; install the optional extra: "
                                            "pip install -e '.[peers]' (or pip install pyimr)") from None
        name = fm.constitutive.name
        if name not in PEER_MODELS:
            raise InputError("--generator", f"PyIMR data for model {name!r} is not mapped; "
                                            f"mapped: {', '.join(PEER_MODELS)}")
        o = fm.options
        if name == "zener" and o.j_mode != "consistent":
            raise InputError("--generator", "PyIMR's Zener has the consistent Keller-Miksis coefficient "
                                            "(4 Lambda/Re); zener_j=imrv2 has no PyIMR counterpart")
        if o.radial not in _RADIAL:
            raise InputError("--generator", f"radial model {o.radial!r} has no PyIMR counterpart")
        self.fm, self.physics, self.options = fm, fm.physics, o
        self.nt, self.rtol, self.atol = int(nt), float(rtol), float(atol)
        self._pyimr = pyimr
        ph = fm.physics
        self._phys = pyimr.PhysicalParameters(
            far_field_pressure_pa=ph.p8, medium_density_kg_m3=ph.rho, surface_tension_n_m=ph.surface_tension,
            sound_speed_m_s=ph.c8, polytropic_exponent=ph.kappa, tait_pressure_pa=ph.tait_b,
            tait_exponent=ph.tait_n, gas_conductivity_slope=ph.k_gas_a, gas_conductivity_offset=ph.k_gas_b,
            vapor_conductivity_slope=ph.k_vap_a, vapor_conductivity_offset=ph.k_vap_b,
            medium_conductivity_w_m_k=ph.k_medium, medium_specific_heat_j_kg_k=ph.cp_medium,
            medium_grid_length=ph.medium_stretch, mass_diffusivity_m2_s=ph.d_vapour,
            latent_heat_j_kg=ph.latent_heat, universal_gas_constant_j_mol_k=ph.r_universal,
            vapor_molar_mass_kg_mol=ph.m_vapour, gas_molar_mass_kg_mol=ph.m_gas)
        self._case = dict(radial=_RADIAL[o.radial], vapor=int(o.vapor), bubtherm=int(o.bubble == "thermal"),
                          masstrans=int(o.mass_transfer), medtherm=int(o.medium == "warm"), T8=ph.T8)

    def describe(self) -> dict:
        """What made the data (for truth.json)."""
        return {"code": "pyimr", "version": getattr(self._pyimr, "__version__", "?"), "thermal": "spectral",
                "Nt": self.nt, "rtol": self.rtol, "atol": self.atol, "case": dict(self._case),
                "constants": "imrbayes Physics, every field passed (PyIMR's own polytropic exponent is 1.4)"}

    def material(self, params: dict):
        cls, names = PEER_MODELS[self.fm.constitutive.name]
        vals = [float(params.get(n, 0.0)) for n in names]
        return getattr(self._pyimr, cls)(*vals)

    def simulate_radius(self, params: dict, rmax_m: float, req_m: float, t_star) -> np.ndarray:
        """R* = R/Rmax on ``t_star`` (t* from the maximum, >= 0) for one bubble; raises
        ForwardModelError if PyIMR's solve fails."""
        t_star = np.asarray(t_star, dtype=float)
        tc = float(self.physics.time_scale(rmax_m))
        lead = t_star.size == 0 or t_star[0] > 0.0          # PyIMR's output grid starts at the maximum
        tv = np.concatenate([[0.0], t_star]) * tc if lead else t_star * tc
        cfg = self._pyimr.SimulationConfig(R0=float(rmax_m), Req=float(req_m), material=self.material(params),
                                           Nt=self.nt, rtol=self.rtol, atol=self.atol, physics=self._phys,
                                           **self._case)
        try:
            res = self._pyimr.prepare(cfg).solve(tv)
        except Exception as exc:                          # PyIMR raises its own SimulationError
            raise ForwardModelError(f"PyIMR solve failed: {exc} (params {params}, Rmax {rmax_m} m, "
                                    f"Req {req_m} m)") from exc
        R = np.asarray(res.radius_ratio, dtype=float)
        R = R[1:] if lead else R
        if R.shape != t_star.shape or not np.all(np.isfinite(R)):
            raise ForwardModelError(f"PyIMR returned {R.shape} values (NaN: {int(np.sum(~np.isfinite(R)))}) "
                                    f"for {t_star.shape} times (params {params})")
        return R
