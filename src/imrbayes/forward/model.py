"""The forward model: propagate ensembles of bubble states with ensembles of parameters.

Methods (smoothers, samplers) see only this API: make initial states at Rmax, propagate N states
with N parameter sets from t0* to t1*, read R* on a grid, hand the end states on. Times are
dimensionless (t* = t / tc, tc = Rmax/sqrt(p8/rho)); radii are R* = R/Rmax; parameters are SI.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numba
import numpy as np

from imrbayes.errors import ForwardModelError, InputError
from imrbayes.forward import layout as L
from imrbayes.forward.codegen import kernel_module
from imrbayes.forward.constants import Physics, group_matrix, nondimensional_groups
from imrbayes.forward.constitutive import ConstitutiveModel, get_model
from imrbayes.forward.options import RADIAL, ForwardOptions, bubble_grid, medium_grid
from imrbayes.forward.tableaux import TABLEAUX

__all__ = ["ForwardModel", "BatchState", "Propagation"]


@dataclass
class BatchState:
    """The full evolved states of N bubbles at one time.

    y : (N, n_state) dimensionless state [R, Rdot, p_b, theta (nt), T_m (mt), k_v (nt), stress states]
        (each field present only when its physics is on; :meth:`ForwardModel.layout` names them).
    t_star : the common dimensionless time of the states.
    rmax_m, req_m : (N,) maximum and equilibrium radius of each bubble [m] (they set its groups).
    """

    y: np.ndarray
    t_star: float
    rmax_m: np.ndarray
    req_m: np.ndarray

    @property
    def n(self) -> int:
        return self.y.shape[0]

    @property
    def R(self) -> np.ndarray:
        """(N,) R* = R/Rmax."""
        return self.y[:, 0]

    @property
    def Rdot(self) -> np.ndarray:
        """(N,) dR*/dt*."""
        return self.y[:, 1]

    def take(self, index) -> BatchState:
        """A new state holding members ``index`` (an int array or boolean mask), copied."""
        index = np.asarray(index)
        return BatchState(self.y[index].copy(), self.t_star, self.rmax_m[index].copy(), self.req_m[index].copy())

    def copy(self) -> BatchState:
        return BatchState(self.y.copy(), self.t_star, self.rmax_m.copy(), self.req_m.copy())


@dataclass
class Propagation:
    """Result of one ensemble propagation.

    t_star : (m,) output times; R_star : (N, m) R/Rmax there (NaN after a failure);
    end : the states at t1; status : (N,) 0 = ok, else a code in :data:`STATUS_TEXT`;
    n_steps, n_rejected : (N,) accepted and rejected integrator steps.
    """

    t_star: np.ndarray
    R_star: np.ndarray
    end: BatchState
    status: np.ndarray
    n_steps: np.ndarray
    n_rejected: np.ndarray
    status_text: dict = field(default_factory=lambda: dict(L.STATUS_TEXT))

    @property
    def failed(self) -> np.ndarray:
        """(N,) True where the member's solve failed (R <= 0, step collapse, NaN, too many steps)."""
        return self.status != L.OK

    def failure_summary(self) -> dict:
        codes, counts = np.unique(self.status[self.failed], return_counts=True)
        return {self.status_text[int(c)]: int(k) for c, k in zip(codes, counts)}


class ForwardModel:
    """Keller-Miksis bubble dynamics with IMR's bubble contents and a constitutive model.

    Parameters
    ----------
    constitutive : str or ConstitutiveModel
        A registered model name (``nhkv``, ``qkv``, ``zener``, ...; see ``available_models()``).
    options : ForwardOptions or dict, optional
        Physics and discretisation (default: KM, thermal bubble, vapour, mass transfer, cold
        medium, grid-converged scheme).
    physics : Physics, optional
        Physical constants (SI); ``physics_overrides`` (a dict) modifies the defaults instead.
    parallel : bool
        Spread the members of a batch over numba threads (default True). False runs the same
        compiled loop on one thread, so the results are bitwise the same either way.
        ``NUMBA_NUM_THREADS`` caps the threads.
    """

    def __init__(self, constitutive="nhkv", options=None, physics: Physics | None = None,
                 physics_overrides: dict | None = None, parallel: bool = True):
        self.constitutive: ConstitutiveModel = (constitutive if isinstance(constitutive, ConstitutiveModel)
                                                else get_model(constitutive))
        if options is None:
            options = ForwardOptions()
        elif isinstance(options, dict):
            options = ForwardOptions.from_dict(options)
        self.options: ForwardOptions = options
        if physics is None:
            physics = Physics.from_overrides(physics_overrides)
        self.physics: Physics = physics
        o = options
        self.nt, self.mt = o.resolution
        thermal = o.thermal
        medium = o.medium == "warm"
        mass = o.mass_transfer
        self._flags = np.array([RADIAL[o.radial], int(thermal), int(medium), int(o.vapor), int(mass),
                                0 if o.pdot_mode == "imrv2" else 1, self.nt, self.mt,
                                self.constitutive.n_aux], dtype=np.int64)
        self._grid_y, self._grid = bubble_grid(self.nt, o.grid_stretch)
        self._mgrid = medium_grid(self.mt, physics.medium_stretch)
        sizes = [("R", 1), ("Rdot", 1), ("pb", 1), ("theta", self.nt if thermal else 0),
                 ("Tm", self.mt if medium else 0), ("kv", self.nt if mass else 0),
                 ("stress", self.constitutive.n_aux)]
        self._slices, start = {}, 0
        for name, size in sizes:
            self._slices[name] = slice(start, start + size)
            start += size
        self.n_state = start
        # Coupling variables whose Jacobian columns join the implicit operator (see kernel).
        cols = [1]
        if thermal:
            th = self._slices["theta"].start
            cols += [2, th + self.nt - 2, th + self.nt - 3]
        if mass:
            kv = self._slices["kv"].start
            cols += [kv + self.nt - 2, kv + self.nt - 3]
        if medium:
            # With the warm medium the wall temperature is a root of the flux balance; its
            # linearisation misled the step control near collapse (tested on the IMRv2 cases),
            # so the warm medium runs on the plain tridiagonal splitting.
            cols = []
        self._cols = np.array(cols, dtype=np.int64)
        self._radau = o.method == "radau5"
        if self._radau:
            # Radau: every Jacobian entry outside the fields' block-tridiagonal pattern lies in
            # these columns (see kernel): R, Rdot, p_b, the field values next to the wall
            # (through the wall gradient in p_b's rate) and the stress states.
            dense = [0, 1, 2, th + self.nt - 2, th + self.nt - 3]
            if mass:
                dense += [kv + self.nt - 2, kv + self.nt - 3]
            st = self._slices["stress"]
            dense += list(range(st.start, st.stop))
            self._cols = np.array(dense, dtype=np.int64)
        self._kernel = None
        self.parallel = bool(parallel)
        tab = TABLEAUX["ark548" if o.method == "radau5" else o.method]()  # radau5 ignores the tableau
        self._tableau = (tab["AE"], tab["AI"], tab["b"], tab["bhat"], tab["c"], float(tab["gamma"]),
                         float(tab["order"]))

    # ------------------------------------------------------------------ description
    def __repr__(self):
        return f"ForwardModel({self.constitutive.name!r}, {self.options})"

    def layout(self) -> dict:
        """Name -> slice of the state vector (empty slices for absent physics)."""
        return dict(self._slices)

    @property
    def grid_y(self) -> np.ndarray:
        """(nt,) bubble grid r/R."""
        return self._grid_y.copy()

    def state_is_valid(self, state) -> np.ndarray:
        """(N,) True where a state (BatchState or (N, n_state) array) can be propagated: every
        entry finite, R* > 0, bubble pressure > 0 (thermal bubble), vapour mass fraction in
        [0, 1], bubble temperature variable inside the domain of its inverse
        (1 + 2 alpha theta > 0) and medium temperature > 0. An ensemble analysis that updates the
        state can leave it; the smoother checks before handing such a state on."""
        return ~np.any(np.stack(list(self.state_problems(state).values())), axis=0)

    def state_problems(self, state) -> dict:
        """{check: (N,) True where the state fails it} for the checks of :meth:`state_is_valid`:
        ``non_finite``, ``radius`` (R* <= 0), ``pressure`` (p_b <= 0), ``vapour_fraction`` (outside
        [0, 1]), ``temperature`` (1 + 2 alpha theta <= 0), ``medium_temperature`` (warm medium)."""
        y = np.atleast_2d(np.asarray(state.y if isinstance(state, BatchState) else state, dtype=float))
        if y.shape[1] != self.n_state:
            raise ForwardModelError(f"state has {y.shape[1]} entries, this model needs {self.n_state}")
        with np.errstate(invalid="ignore"):
            out = {"non_finite": ~np.all(np.isfinite(y), axis=1), "radius": ~(y[:, 0] > 0)}
            if self.options.thermal:
                out["pressure"] = ~(y[:, 2] > 0)
                g = self.groups(1.0, 0.5)          # alpha_g, alpha_v do not depend on the bubble size
                kv = y[:, self._slices["kv"]] if self.options.mass_transfer else np.full((y.shape[0], 1), float(g["kv0"]))
                out["vapour_fraction"] = ~np.all((kv >= 0) & (kv <= 1), axis=1)
                am = kv * g["alpha_v"] + (1 - kv) * g["alpha_g"]
                out["temperature"] = ~np.all(1 + 2 * am * y[:, self._slices["theta"]] > 0, axis=1)
                if self.options.medium == "warm":
                    out["medium_temperature"] = ~np.all(y[:, self._slices["Tm"]] > 0, axis=1)
        return out

    def describe(self) -> dict:
        """JSON-able record of everything that defines this forward model."""
        return {"constitutive": self.constitutive.name, "parameters": list(self.constitutive.param_names),
                "options": self.options.to_dict(), "physics": self.physics.to_dict(), "n_state": self.n_state}

    @property
    def kernel(self):
        if self._kernel is None:
            self._kernel = kernel_module(self.constitutive.module)
        return self._kernel

    # ------------------------------------------------------------------ set-up
    def groups(self, rmax_m, req_m) -> dict:
        """Dimensionless groups (constants.nondimensional_groups) for these bubbles."""
        return nondimensional_groups(self.physics, rmax_m, req_m, thermal=self.options.thermal,
                                     vapor=self.options.vapor)

    def initial_state(self, rmax_m, req_m, n: int | None = None) -> BatchState:
        """States at the maximum radius: R* = 1, at rest, equilibrium contents, zero extra stress.

        ``rmax_m``, ``req_m`` [m]: scalars or (N,) arrays; ``n`` repeats scalars N times.
        """
        rmax = np.atleast_1d(np.asarray(rmax_m, dtype=float))
        req = np.atleast_1d(np.asarray(req_m, dtype=float))
        size = max(rmax.size, req.size, n or 1)
        rmax = np.broadcast_to(rmax, (size,)).copy()
        req = np.broadcast_to(req, (size,)).copy()
        if not (np.all(np.isfinite(rmax)) and np.all(rmax > 0) and np.all(np.isfinite(req)) and np.all(req > 0)):
            raise InputError("initial state", "Rmax and Req must be finite and positive")
        if np.any(req > rmax):
            raise InputError("initial state", "Req must not exceed Rmax (the bubble starts at its maximum)")
        g = self.groups(rmax, req)
        y = np.zeros((size, self.n_state))
        y[:, 0] = 1.0
        y[:, 2] = g["pb0"]
        y[:, self._slices["theta"]] = 0.0
        y[:, self._slices["Tm"]] = 1.0
        y[:, self._slices["kv"]] = np.asarray(g["kv0"])[:, None] if np.ndim(g["kv0"]) else g["kv0"]
        return BatchState(y, 0.0, rmax, req)

    def _parameter_table(self, params, n, rmax_m, source="parameters"):
        """SI params -> (N, n_pieces, n_p) dimensionless table."""
        arr = np.asarray(params, dtype=float) if not isinstance(params, dict) else None
        if arr is not None and arr.ndim == 3:
            table = arr
        else:
            table = self.constitutive.param_array(params, n=n, source=source)[:, None, :]
        if table.shape[0] == 1 and n > 1:
            table = np.repeat(table, n, axis=0)
        if table.shape[0] != n:
            raise InputError(source, f"got {table.shape[0]} parameter sets for {n} states")
        if not np.all(np.isfinite(table)):
            raise InputError(source, "parameters must be finite")
        ph = self.physics
        nd = self.constitutive.nondimensionalise(table, rho=ph.rho, p8=ph.p8, uc=ph.velocity_scale,
                                                 rmax_m=np.asarray(rmax_m)[:, None])
        # The last entry of every kernel vector is the option flag the Zener family reads (base.py).
        # concatenate makes a new C-ordered float array: writable (see the note on ``te`` in propagate)
        flag = np.full(nd.shape[:-1] + (1,), 1.0 if self.options.j_mode == "consistent" else 0.0)
        return np.concatenate([np.asarray(nd, dtype=float), flag], axis=-1)

    # ------------------------------------------------------------------ propagation
    def propagate(self, state: BatchState, params, t_end: float, t_eval=None, *, breaks_star=None,
                  h_init: float = 0.0, max_steps: int = 200_000) -> Propagation:
        """Propagate N states with N parameter sets from ``state.t_star`` to ``t_end``.

        params : dict name -> scalar or (N,) array [SI], or an (N, n_params) array, or an
            (N, n_pieces, n_params) array of piecewise-constant-in-time parameters whose pieces
            change at ``breaks_star``: (n_pieces-1,) increasing t*, the same for every member, or
            (N, n_pieces-1), one row per member (e.g. each bubble's own collapse times).
        t_eval : (m,) output times in [t0, t_end] (default: t_end only), or (N, m): each member's own
            increasing times (e.g. a per-member time offset of the observations).
        Members whose solve fails are flagged in ``status`` (NaN output after the failure);
        they never stop the batch.
        """
        n = state.n
        t0 = float(state.t_star)
        t_end = float(t_end)
        if not t_end >= t0:
            raise InputError("t_end", f"end time {t_end} is before the start time {t0}")
        t_eval = np.atleast_1d(np.asarray([t_end] if t_eval is None else t_eval, dtype=float))
        if t_eval.ndim > 2 or (t_eval.ndim == 2 and t_eval.shape[0] != n):
            raise InputError("t_eval", f"expected (m,) or ({n}, m) output times, got shape {t_eval.shape}")
        if t_eval.size and (np.any(np.diff(t_eval, axis=-1) < 0) or np.min(t_eval) < t0 - 1e-12
                            or np.max(t_eval) > t_end + 1e-12 or not np.all(np.isfinite(t_eval))):
            raise InputError("t_eval", "output times must be increasing and inside [t0, t_end]")
        # Always a writable C copy: a read-only broadcast view is another numba type, which would be
        # compiled in this process rather than loaded from the cache the child wrote (codegen.py).
        te = np.array(np.broadcast_to(t_eval, (n, t_eval.shape[-1])), dtype=float, order="C")
        breaks = np.atleast_1d(np.asarray([] if breaks_star is None else breaks_star, dtype=float))
        if breaks.ndim > 2 or (breaks.ndim == 2 and breaks.shape[0] != n):
            raise InputError("breaks_star", f"expected (n_breaks,) or ({n}, n_breaks) break times, got shape "
                             f"{breaks.shape}")
        breaks = np.array(np.broadcast_to(breaks, (n, breaks.shape[-1])), dtype=float, order="C")
        if not np.all(np.isfinite(breaks)) or np.any(np.diff(breaks, axis=1) <= 0):
            raise InputError("breaks_star", "break times must be finite and strictly increasing")
        P = self._parameter_table(params, n, state.rmax_m)
        if P.shape[1] != breaks.shape[1] + 1:
            raise InputError("parameters", f"{P.shape[1]} parameter pieces need {P.shape[1] - 1} break times, "
                             f"got {breaks.shape[1]}")
        if state.y.shape[1] != self.n_state:
            raise ForwardModelError(f"state has {state.y.shape[1]} entries, this model needs {self.n_state}")
        G = group_matrix(self.groups(state.rmax_m, state.req_m), n)
        o = self.options
        # One compiled entry point for every batch, serial or threaded: the serial and the threaded
        # compilations of the member loop differ in their last bits (1e-10 relative through a
        # collapse), and a process used whichever it loaded first -- so a run's numbers depended on
        # --workers (through MIEnKS-MDA's seeding, since fixed, that became 11 % of one bubble's G).
        # Serial means one thread for this call.
        threads = numba.get_num_threads()
        serial = not self.parallel or n < 2
        if serial and threads > 1:
            numba.set_num_threads(1)
        try:
            Y, R, status, nsteps, nrej = self.kernel.integrate_batch_parallel(
                np.array(state.y, dtype=float, order="C"), t0, t_end, te, G, P, breaks, self._flags,
                self._grid, self._mgrid, o.rtol, o.atol, float(h_init), int(max_steps), *self._tableau, self._cols,
                self._radau)
        finally:
            if serial and threads > 1:
                numba.set_num_threads(threads)
        end = BatchState(Y, t_end, state.rmax_m.copy(), state.req_m.copy())
        return Propagation(t_eval, R, end, status, nsteps, nrej)

    def simulate(self, params, rmax_m, req_m, t_star, **kwargs) -> Propagation:
        """Propagate from the maximum radius (t* = 0) and return R* on ``t_star`` ((m,) or (N, m))."""
        t_star = np.asarray(t_star, dtype=float)
        n = None
        if not isinstance(params, dict):
            arr = np.asarray(params, dtype=float)
            n = arr.shape[0] if arr.ndim >= 2 else 1
        else:
            n = max([np.size(v) for v in params.values()] + [1])
        state = self.initial_state(rmax_m, req_m, n=n)
        return self.propagate(state, params, float(np.max(t_star[..., -1])), t_star, **kwargs)

    def simulate_radius(self, params: dict, rmax_m: float, req_m: float, t_star) -> np.ndarray:
        """R* on ``t_star`` for one bubble; raises ForwardModelError if the solve fails."""
        out = self.simulate(params, rmax_m, req_m, t_star)
        if out.failed[0]:
            raise ForwardModelError(f"forward solve failed: {out.status_text[int(out.status[0])]} "
                                    f"(params {params}, Rmax {rmax_m} m, Req {req_m} m)")
        return out.R_star[0]

    def with_options(self, **changes) -> ForwardModel:
        """A copy with some options changed."""
        return ForwardModel(self.constitutive, replace(self.options, **changes), self.physics, parallel=self.parallel)
