"""Log-posterior of constant parameters over one fitting window, batched for emcee.

Target density
--------------
The sampled coordinates are the *internal* parameters z (d,): ``z_i = log(theta_i / 1 SI unit)``
for positive parameters (``Parameter.positive``; G [Pa] and mu [Pa s] for NHKV), ``z_i = theta_i``
otherwise -- the same coordinates as :class:`imrbayes.ensemble.ParamSpace`. With N_exp experiments
started from given states q_n at t0 (the bubble at its maximum, or a smoother's handed-off state)
and the forward prediction R_nk(z) = R*(t_k; q_n, theta(z)),

    log p(z | y) = -1/2 sum_n sum_k c_nk (y_nk - R_nk(z))^2 / P_k  +  log p0(z)  + const,

* ``P_k`` [R*^2]: the measurement-noise variance per sample (``Preprocessed.P``);
* ``c_nk`` >= 0: the observation weight. ``c = 1`` is the plain Gaussian likelihood. The ensemble
  methods temper it, and a sampler that is compared with them must use the same weight:
  En4D-Var averages over the N_t fitted samples, ``c_k = 1/N_t`` (methods.md §3);
  MIEnKS-MDA window j uses ``c_k = beta_jk / L`` (MDA coefficient over window length, §4).
  A weight c is the same as a Gaussian likelihood with variance ``P_k / c_k``; samples with
  ``c = 0`` or at the start time t0 (where R* is the given state and does not depend on z) are not
  used;
* ``p0``: the Gaussian prior N(m0, S0) of a :class:`~imrbayes.ensemble.ParamSpace`
  (:meth:`~imrbayes.ensemble.ParamSpace.log_prob`). ``scale="internal"`` (default, the
  methods' convention: the paper's SI mean/sd are turned into a log-normal by moment
  matching) states it on z, so no Jacobian is needed. ``scale="natural"`` states it on theta
  (truncated to theta > 0 for positive parameters); sampling z = log theta then adds the Jacobian
  ``log |d theta / d z| = sum_{positive i} z_i``;
* the prior is truncated to a box of ``box_sd`` prior standard deviations around m0 (default 10):
  outside it the log-density is -inf. This keeps walkers away from absurd parameters, where the
  stiff forward solve would take very long; the box holds all the posterior mass of any sensible
  problem (the prior density there is below e^-50 of its peak) -- check ``box_sd`` if the data pull
  a parameter that far from the prior.

A forward solve that fails (``Propagation.failed``) or gives a non-finite radius makes the
log-density ``-inf``, never NaN (emcee raises on NaN).

Batching: :meth:`WindowTarget.log_prob` takes ``(n, d)`` and runs all n x N_exp members in one
``propagate`` call (emcee ``vectorize=True`` hands half the walkers per call).
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from imrbayes.ensemble.problem import ParamSpace
from imrbayes.errors import InputError
from imrbayes.forward import BatchState

__all__ = ["WindowTarget", "fitting_window_target", "window_target_from_ensemble", "loglik_pointwise"]


def loglik_pointwise(R, y, P, weight):
    """Pointwise log-likelihood, Gaussian with variance P/c: ``-1/2 [c (y - R)^2 / P + log(2 pi P / c)]``.

    All arguments broadcast (``R`` typically (n, N_exp, m)). Its sum over the used samples is the
    likelihood term of the target plus a constant; the normalisation makes it a proper density of
    y (what ``arviz.loo`` needs).
    """
    return -0.5 * (weight * (y - R) ** 2 / P + np.log(2.0 * np.pi * P / weight))


class WindowTarget:
    """Log-posterior of constant parameters over one window (see the module docstring).

    Parameters
    ----------
    model : ForwardModel or imrbayes.forward.Runner
        Anything with ``propagate(state, params (N, d) SI, t_end, t_eval) -> Propagation``.
    start : BatchState
        One state per experiment (N_exp members) at the window start t0 = ``start.t_star``.
    t_eval : (m,)
        Window samples t* (>= t0, increasing).
    y : (N_exp, m)
        Observed R* at ``t_eval``.
    P : (m,) or (N_exp, m)
        Noise variance [R*^2], > 0.
    prior : ParamSpace
        Parameter names, log transform and the prior density (its ``box_sd`` bounds the support).
    weight : scalar, (m,) or (N_exp, m)
        Observation weight c (see module docstring): 1, 1/N_t (En4D-Var) or beta_jk/L (MIEnKS-MDA).
    names : list of str, optional
        Experiment names (for the ``experiment`` coordinate).
    """

    def __init__(
        self,
        model,
        start: BatchState,
        t_eval,
        y,
        P,
        prior: ParamSpace,
        weight=1.0,
        names=None,
        description: dict | None = None,
        whiten=None,
        nuisance_sd=None,
        frames=None,
    ):
        self.model = model
        self.start = start.copy()
        self.t0 = float(start.t_star)
        self.t_eval = np.atleast_1d(np.asarray(t_eval, dtype=np.float64))
        n_exp, m = start.n, self.t_eval.size
        self.y = np.asarray(y, dtype=np.float64).reshape(n_exp, m)
        self.P = np.broadcast_to(np.asarray(P, dtype=np.float64), (n_exp, m)).copy()
        self.weight = np.broadcast_to(np.asarray(weight, dtype=np.float64), (n_exp, m)).copy()
        self.prior = prior
        self.names = list(names) if names is not None else [f"exp_{i + 1:03d}" for i in range(n_exp)]
        self.description = dict(description or {})
        if m < 1 or np.any(np.diff(self.t_eval) <= 0) or self.t_eval[0] < self.t0 - 1e-12:
            raise InputError("window", "t_eval must be increasing and start at or after the window start")
        if not (np.all(np.isfinite(self.P)) and np.all(self.P > 0)):
            raise InputError("window", "noise variances P_k must be finite and positive")
        if not (np.all(np.isfinite(self.weight)) and np.all(self.weight >= 0)):
            raise InputError("window", "observation weights must be finite and >= 0")
        if len(self.names) != n_exp:
            raise InputError("window", f"{len(self.names)} names for {n_exp} experiments")
        # samples used: positive weight, after t0 (R*(t0) is the given state, independent of z)
        self.use_time = (self.t_eval > self.t0 + 1e-12) & np.any(self.weight > 0, axis=0)
        self.use = (self.weight > 0) & self.use_time[None, :]
        if not self.use.any():
            raise InputError("window", "no observation with a positive weight after the window start")
        if not np.all(np.isfinite(self.y[self.use])):
            raise InputError("window", "observations must be finite where they are used")
        self.n_evals = 0  # parameter sets evaluated
        self.n_failed = 0  # of which the forward solve failed
        # the default likelihood (imrbayes.ensemble.likelihood): whitened residuals, and each
        # experiment's nuisances (a, delta, rho) sampled with the parameters, prior N(0, sd^2)
        self.whiten = None if whiten is None else np.asarray(whiten, dtype=np.float64).reshape(n_exp, m, m)
        if self.whiten is not None and not np.all(np.isfinite(self.whiten)):
            raise InputError("window", "whitening matrices must be finite")
        sd = (
            np.zeros((n_exp, 3))
            if nuisance_sd is None
            else np.broadcast_to(np.asarray(nuisance_sd, np.float64), (n_exp, 3))
        )
        self.nuisance_sd = np.where(np.isfinite(sd) & (sd > 0), sd, 0.0)
        self.nuisance_used = self.nuisance_sd > 0  # (n_exp, 3), row-major order of the extra coordinates
        # the grid values interpolate camera frames (imrbayes.ensemble.likelihood.frame_operator per experiment)
        self.frames = None if frames is None else list(frames)
        if self.frames is not None and len(self.frames) != n_exp:
            raise InputError("window", f"{len(self.frames)} frame operators for {n_exp} experiments")
        if (self.nuisance_used.any() or self.frames is not None) and self.t0 != 0.0:
            raise InputError("window", "nuisances need a window that starts at the maximum (t* = 0)")
        # predictions kept for :meth:`pointwise`: emcee's kept draws are points it has evaluated,
        # so the log-likelihood group costs no forward solve (oldest entries dropped beyond the budget)
        self.memo_bytes = 64 * 2**20
        self._memo = OrderedDict()

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_memo"] = OrderedDict()
        return state

    def forget(self) -> None:
        """Drop the predictions kept for :meth:`pointwise`."""
        self._memo = OrderedDict()

    def _remember(self, Z, R, failed) -> None:
        per = max(1, R[0].nbytes if R.shape[0] else 1)
        cap = int(self.memo_bytes // per)
        if cap < 1:
            return
        for z, r, f in zip(Z, R, failed):
            self._memo[z.tobytes()] = (r.copy(), bool(f))
        while len(self._memo) > cap:  # O(1) per entry (a plain dict's front scan is not)
            self._memo.popitem(last=False)

    # ------------------------------------------------------------------ description
    @property
    def ndim(self) -> int:
        return self.prior.n + int(self.nuisance_used.sum())

    @property
    def n_exp(self) -> int:
        return self.start.n

    @property
    def param_names(self) -> tuple:
        return self.prior.names

    @property
    def internal_names(self) -> list:
        """Names of the sampled coordinates: ``log_G`` for a positive ``G``, else the name."""
        return [f"log_{n}" if p else n for n, p in zip(self.prior.names, self.prior.positive)] + [
            f"{q}_{self.names[e]}"
            for e, j in zip(*np.nonzero(self.nuisance_used))
            for q in [("rmax_rel", "t0_offset", "log_req")[j]]
        ]

    @property
    def t_used(self) -> np.ndarray:
        """(m_used,) t* of the samples that enter the likelihood."""
        return self.t_eval[self.use_time]

    def describe(self) -> dict:
        return {
            "t0_star": self.t0,
            "t_star": [float(self.t_eval[0]), float(self.t_eval[-1])],
            "n_samples": int(self.t_eval.size),
            "n_used": int(self.use.sum()),
            "n_experiments": self.n_exp,
            "prior": self.prior.describe_density(),
            "internal_names": self.internal_names,
            "density": (
                "-1/2 sum_n ||W_n (y_n - R_n(z, nu_n))||^2 + log p0(z) + sum_n log N(nu_n; 0, diag(sd_n^2))"
                if self.whiten is not None
                else "-1/2 sum_n sum_k c_nk (y_nk - R_nk(z))^2 / P_k + log p0(z)"
            ),
            "nuisances_sampled": self.internal_names[self.prior.n :],
            "weight_min": float(self.weight[self.use].min()),
            "weight_max": float(self.weight[self.use].max()),
            **self.description,
        }

    @property
    def nuisance_blocks(self) -> list:
        """Each experiment's sampled nuisance columns in z, one int array per experiment (empty
        where none is sampled). Given the parameters the blocks are independent: the likelihood and
        the prior factorise over experiments (:meth:`block_terms`)."""
        cols = self.prior.n + np.cumsum(self.nuisance_used.ravel()).reshape(self.nuisance_used.shape) - 1
        return [cols[e][self.nuisance_used[e]] for e in range(self.n_exp)]

    # ------------------------------------------------------------------ evaluation
    def predict(self, Z):
        """Forward prediction for n parameter sets in one batch.

        Z : (n, d) internal coordinates.
        Returns ``R`` (n, N_exp, m) R* at ``t_eval`` (NaN where failed) and ``failed`` (n,) bool:
        any experiment's solve failed or gave a non-finite radius on a used sample.
        """
        Z = np.atleast_2d(np.asarray(Z, dtype=np.float64))
        n, ne, m = Z.shape[0], self.n_exp, self.t_eval.size
        R = np.full((n, ne, m), np.nan)
        theta = self.prior.to_si(Z[:, : self.prior.n])
        ok = np.all(np.isfinite(theta), axis=1) & np.all(np.isfinite(Z), axis=1)
        failed = ~ok
        idx = np.flatnonzero(ok)
        if idx.size:
            s = self.start
            st = BatchState(
                np.tile(s.y, (idx.size, 1)), self.t0, np.tile(s.rmax_m, idx.size), np.tile(s.req_m, idx.size)
            )
            params = np.repeat(theta[idx], ne, axis=0)  # member = i * N_exp + e
            if self.nuisance_used.any() or self.frames is not None:
                from imrbayes.ensemble.likelihood import predict as predict_nuisance

                nu = np.zeros((idx.size, ne, 3))
                nu[:, self.nuisance_used] = Z[idx, self.prior.n :]
                Rs = np.empty((idx.size, ne, m))
                bad_nu = np.zeros((idx.size, ne), dtype=bool)
                for e in range(ne):  # one batch per experiment: its own frame times
                    Rs[:, e], bad_nu[:, e] = predict_nuisance(
                        self.model,
                        theta[idx],
                        float(s.rmax_m[e]),
                        float(s.req_m[e]),
                        self.t_eval,
                        nu[:, e],
                        None if self.frames is None else self.frames[e],
                    )
                Rs = np.where(bad_nu[:, :, None], np.nan, Rs).reshape(idx.size * ne, m)
                bad_nu = bad_nu.ravel()
                out = None
            else:
                out = self.model.propagate(st, params, float(self.t_eval[-1]), self.t_eval)
                Rs = np.asarray(out.R_star, dtype=np.float64)
            Ri = Rs.reshape(idx.size, ne, m)
            failed_members = bad_nu if out is None else np.asarray(out.failed)
            bad = failed_members.reshape(idx.size, ne).any(axis=1)
            bad |= ~np.all(np.isfinite(np.where(self.use[None], Ri, 0.0)), axis=(1, 2))
            R[idx] = Ri
            failed[idx] = bad
        self.n_evals += n
        self.n_failed += int(failed.sum())
        self._remember(Z, R, failed)
        return R, failed

    def _predict_remembered(self, Z):
        """:meth:`predict`, taking the rows already evaluated from the memo (bit-identical: the same
        arrays the log-density used)."""
        hits = [self._memo.get(z.tobytes()) for z in Z]
        miss = np.array([h is None for h in hits], dtype=bool)
        R = np.empty((Z.shape[0], self.n_exp, self.t_eval.size))
        failed = np.zeros(Z.shape[0], dtype=bool)
        if miss.any():
            R[miss], failed[miss] = self.predict(Z[miss])
        for i in np.flatnonzero(~miss):
            R[i], failed[i] = hits[i]
        return R, failed

    def log_likelihood(self, Z) -> np.ndarray:
        """(n, d) -> (n,) ``-1/2 sum c (y - R)^2 / P`` over the used samples; -inf where a solve failed."""
        R, failed = self.predict(Z)
        ll = self._experiment_loglik(R, failed).sum(axis=1)
        return np.where(failed | ~np.isfinite(ll), -np.inf, ll)

    def _experiment_loglik(self, R, failed) -> np.ndarray:
        """(n, N_exp, m) predictions -> (n, N_exp) each experiment's log-likelihood term (its sum is
        :meth:`log_likelihood`); -inf where that experiment's prediction is not finite, and on every
        experiment of a set whose solve was flagged failed without a non-finite radius."""
        r = np.where(self.use[None], self.y - R, 0.0)
        with np.errstate(invalid="ignore", over="ignore"):
            if self.whiten is not None:
                ll = -0.5 * np.sum(np.einsum("eij,nej->nei", self.whiten, r) ** 2, axis=2)
            else:
                ll = -0.5 * np.sum(np.where(self.use[None], self.weight * r * r / self.P, 0.0), axis=2)
        ll = np.where(np.isfinite(ll), ll, -np.inf)
        return np.where(failed[:, None] & np.all(np.isfinite(ll), axis=1)[:, None], -np.inf, ll)

    def _nuisance_log_prior(self, Z) -> np.ndarray:
        """(n, ndim) -> (n, N_exp) each experiment's N(0, sd^2) nuisance term (-inf outside the box)."""
        out = np.zeros((Z.shape[0], self.n_exp))
        for e, cols in enumerate(self.nuisance_blocks):
            if cols.size:
                sd = self.nuisance_sd[e][self.nuisance_used[e]]
                x = Z[:, cols] / sd
                out[:, e] = -0.5 * np.sum(x * x + np.log(2 * np.pi * sd * sd), axis=1)
                out[np.any(np.abs(x) > self.prior.box_sd, axis=1), e] = -np.inf
        return out

    def block_terms(self, Z):
        """The log-posterior split by experiment: ``(lp_params (n,), T (n, N_exp), R, failed)`` with
        ``log_prob(Z) = lp_params + T.sum(1)`` (up to rounding): the parameter prior, and per
        experiment its log-likelihood plus its nuisances' prior. Predictions come from the memo where
        the set was evaluated before (no forward solve)."""
        Z = np.atleast_2d(np.asarray(Z, dtype=np.float64))
        lp0 = self.prior.log_prob(Z[:, : self.prior.n])
        T = np.full((Z.shape[0], self.n_exp), -np.inf)
        R = np.full((Z.shape[0], self.n_exp, self.t_eval.size), np.nan)
        failed = np.ones(Z.shape[0], dtype=bool)
        ok = np.isfinite(lp0)
        if ok.any():
            R[ok], failed[ok] = self._predict_remembered(Z[ok])
            T[ok] = self._experiment_loglik(R[ok], failed[ok]) + self._nuisance_log_prior(Z[ok])
        T[~np.isfinite(T)] = -np.inf
        return lp0, T, R, failed

    def accept_blocks(self, X, Q, random):
        """Metropolis acceptance of each experiment's nuisance block on its own.

        X, Q : (n, ndim) current and proposed sets that differ only in nuisance columns (the same
        parameters), Q already evaluated (its predictions in the memo). Given the parameters the
        target factorises over experiments, so each block is a Metropolis step on its own conditional
        (proposal symmetric) and all blocks of a set cost one forward batch. Returns ``(Z (n, ndim),
        lp (n,), accepted (n, N_exp))``; Z's predictions are put in the memo, so its log-density and
        pointwise log-likelihood need no new solve.
        """
        X = np.atleast_2d(np.asarray(X, dtype=np.float64))
        Q = np.atleast_2d(np.asarray(Q, dtype=np.float64))
        d = self.prior.n
        if X.shape != Q.shape or not np.array_equal(X[:, :d], Q[:, :d]):
            raise ValueError("accept_blocks: X and Q must have the same parameters")
        lp0, Tx, Rx, _ = self.block_terms(X)
        _, Tq, Rq, _ = self.block_terms(Q)
        log_u = np.log(random.rand(*Tx.shape))
        with np.errstate(invalid="ignore"):
            acc = np.isfinite(Tq) & ((Tq - Tx > log_u) | ~np.isfinite(Tx))
        Z = X.copy()
        for e, cols in enumerate(self.nuisance_blocks):
            if cols.size:
                Z[np.ix_(acc[:, e], cols)] = Q[np.ix_(acc[:, e], cols)]
        lp = lp0 + np.sum(np.where(acc, Tq, Tx), axis=1)
        lp[~np.isfinite(lp)] = -np.inf
        self._remember(Z, np.where(acc[:, :, None], Rq, Rx), ~np.isfinite(lp))
        return Z, lp, acc

    def log_prior(self, Z) -> np.ndarray:
        """(n, ndim) -> (n,) the parameter prior plus the nuisances' N(0, sd^2)."""
        Z = np.atleast_2d(np.asarray(Z, dtype=np.float64))
        d = self.prior.n
        out = self.prior.log_prob(Z[:, :d])
        if self.nuisance_used.any():
            out = out + self._nuisance_log_prior(Z).sum(axis=1)
        return out

    def log_prob(self, Z) -> np.ndarray:
        """(n, d) internal coordinates -> (n,) log-posterior (unnormalised); -inf, never NaN, where
        the prior is zero or a forward solve failed. Only parameter sets inside the prior's support
        are simulated."""
        Z = np.atleast_2d(np.asarray(Z, dtype=np.float64))
        out = self.log_prior(Z)
        ok = np.isfinite(out)
        if ok.any():
            out[ok] = out[ok] + self.log_likelihood(Z[ok])
        out[~np.isfinite(out)] = -np.inf
        return out

    __call__ = log_prob

    def pointwise(self, Z, chunk: int = 4096) -> np.ndarray:
        """(n, d) -> (n, N_exp, m_used) pointwise log-likelihood (:func:`loglik_pointwise`) on the used
        time samples (``t_used``); experiments with weight 0 at a used time, and failed solves, get
        a very low finite value (-1e300) so that ArviZ can still read the array."""
        Z = np.atleast_2d(np.asarray(Z, dtype=np.float64))
        cols = self.use_time
        out = np.empty((Z.shape[0], self.n_exp, int(cols.sum())))
        per = max(1, chunk // self.n_exp)
        for a in range(0, Z.shape[0], per):
            R, failed = self._predict_remembered(Z[a : a + per])
            w = self.weight[:, cols]
            with np.errstate(divide="ignore", invalid="ignore"):
                if self.whiten is not None:
                    # per whitened component (the nuisance correlation is in W); log|W_kk| normalises it
                    # approximately, enough for LOO diagnostics
                    r = np.where(self.use[None], self.y - R, 0.0)
                    wr = np.einsum("eij,nej->nei", self.whiten, r)[:, :, cols]
                    diag = np.abs(np.einsum("eii->ei", self.whiten))[:, cols]
                    lp = -0.5 * (wr**2 + np.log(2.0 * np.pi)) + np.log(diag)[None]
                else:
                    lp = loglik_pointwise(R[:, :, cols], self.y[:, cols], self.P[:, cols], w)
            lp = np.where((w > 0)[None] & ~failed[:, None, None] & np.isfinite(lp), lp, -1e300)
            out[a : a + per] = lp
        return out


def fitting_window_target(model, obs, prior: ParamSpace, t_end: float | None = None, weight="en4dvar") -> WindowTarget:
    """Constant parameters over [0, t_end] from the radius maximum (the En4D-Var / IMR window).

    Parameters
    ----------
    model : ForwardModel or Runner
    obs : imrbayes.ensemble.Observations or imrbayes.data.Preprocessed
        Anything with ``t_star`` (n,), ``R_star`` (N_exp, n), ``P`` (n,), ``rmax_m``, ``req_m`` (N_exp,).
    prior : ParamSpace (e.g. ``ParamSpace.for_model(fm.constitutive)``)
    t_end : last fitted t* (None: the whole record).
    weight : ``"en4dvar"`` (c = 1/K over the K fitted samples 1..K, methods.md §3; the density the
        fused En4D-Var posterior approximates), ``"plain"`` (c = 1) or an array (K,) / (N_exp, K).
    """
    fm = getattr(model, "fm", model)
    t = np.asarray(obs.t_star, dtype=np.float64)
    K = t.size - 1 if t_end is None else int(np.searchsorted(t, float(t_end) + 1e-9, side="right") - 1)
    if K < 1:
        raise InputError("t_end", f"the window t* <= {t_end} holds no sample after the maximum")
    if isinstance(weight, str):
        if weight not in ("en4dvar", "plain"):
            raise InputError("weight", f"must be 'en4dvar', 'plain' or an array, got {weight!r}")
        c = 1.0 / K if weight == "en4dvar" else 1.0
        rule = "1/N_t (En4D-Var averaging)" if weight == "en4dvar" else "1 (plain likelihood)"
    else:
        c, rule = np.asarray(weight, dtype=np.float64), "given"
    start = fm.initial_state(obs.rmax_m, obs.req_m)
    names = list(getattr(obs, "names", []) or [])
    return WindowTarget(
        model,
        start,
        t[1 : K + 1],
        np.asarray(obs.R_star)[:, 1 : K + 1],
        np.asarray(obs.P)[1 : K + 1],
        prior,
        c,
        names or None,
        description={"kind": "fitting window from the maximum", "samples": [1, K], "weight_rule": rule},
    )


def window_target_from_ensemble(
    model,
    ensemble: BatchState,
    t_eval,
    y,
    P,
    prior: ParamSpace,
    mda_weight=1.0,
    L: int | None = None,
    n_exp: int | None = None,
    groups=None,
    names=None,
    index: int | None = None,
) -> WindowTarget:
    """The density that the MIEnKS-MDA Gauss–Newton analysis of one window approximates.

    Window j starts at t0 = ``ensemble.t_star`` with the smoother's handed-off ensemble (the prior
    ensemble of the window's analysis: every member's full evolved state). Its parameter target is

        log p_j(z) = -1/2 sum_n sum_k (beta_jk / L) (y_nk - R_nk(q_n, z))^2 / P_k + log N(z; m_j, C_j)

    with (m_j, C_j) the Gaussian prior of the window's parameters (for ``fusion="chain"`` in
    ``fit_mienks``: the previous window's fused posterior after RTPS; window 0: the prior).

    **State uncertainty** is represented, to start with, by the ensemble's *mean state*: q_n is the
    average of experiment n's members' states (R, Rdot, p_b, stresses, fields). The smoother's
    analysis also updates the state and carries state-parameter correlations; this target
    conditions on the mean state instead, so it is the exact posterior of the parameters only
    when the handed-off state spread is negligible (as it is at window 0, where every member starts
    at the same state at the maximum). A wide state spread makes the MCMC posterior narrower than
    the smoother's; compare the two knowing this.

    Parameters
    ----------
    model : ForwardModel or Runner
    ensemble : BatchState
        N_exp x N_En members at the window start, grouped by experiment: member ``n * N_En + i`` is
        member i of experiment n (the order of ``fit_mienks``), unless ``groups`` says otherwise.
    t_eval : (m,) the window's samples t* (the first may equal t0; it is then not used).
    y : (N_exp, m) observed R*; P : (m,) noise variance.
    prior : ParamSpace  -- (m_j, C_j) on the internal parameters (``space.with_prior(m_j, C_j)``).
    mda_weight : scalar or (m,) beta_jk; L : window length (samples) for the 1/L average
        (default: m; 1 for fit_mienks' ``obs_weight="mda"``). The weight is ``beta_jk / L``.
    n_exp : number of experiments (default: ``len(y)``); groups : (N_exp N_En,) experiment of each member.
    """
    y = np.atleast_2d(np.asarray(y, dtype=np.float64))
    n_exp = int(n_exp or y.shape[0])
    t_eval = np.atleast_1d(np.asarray(t_eval, dtype=np.float64))
    L = int(L or t_eval.size)
    if groups is None:
        if ensemble.n % n_exp:
            raise InputError("ensemble", f"{ensemble.n} members do not split into {n_exp} experiments")
        groups = np.repeat(np.arange(n_exp), ensemble.n // n_exp)
    groups = np.asarray(groups, dtype=int)
    if groups.shape != (ensemble.n,) or set(np.unique(groups)) != set(range(n_exp)):
        raise InputError("ensemble", "groups must give an experiment 0..N_exp-1 for every member")
    ys, rmax, req, spread = [], [], [], []
    for g in range(n_exp):
        sel = groups == g
        ys.append(ensemble.y[sel].mean(axis=0))
        rmax.append(ensemble.rmax_m[sel][0])
        req.append(ensemble.req_m[sel][0])
        spread.append(float(ensemble.y[sel, 0].std()))
        if np.ptp(ensemble.rmax_m[sel]) > 0 or np.ptp(ensemble.req_m[sel]) > 0:
            raise InputError("ensemble", f"experiment {g}: members disagree on Rmax/Req")
    start = BatchState(np.array(ys), float(ensemble.t_star), np.array(rmax), np.array(req))
    beta = np.broadcast_to(np.asarray(mda_weight, dtype=np.float64), t_eval.shape)
    desc = {
        "kind": "MIEnKS-MDA window",
        "state": "mean of each experiment's handed-off ensemble",
        "weight_rule": f"beta_jk / L, L = {L}",
        "L": L,
        "R_spread_at_start": spread,
    }
    if index is not None:
        desc["index"] = int(index)
    return WindowTarget(model, start, t_eval, y, P, prior, beta / L, names, description=desc)
