"""Joint weighted least squares (MAP) of one candidate over several experiments, with a Laplace
posterior, on the default likelihood of ``fit`` (methods.md §7):

    1/2 sum_n w_n^2 sum_{k=1..K} (y_nk - f_nk(z, nu_n))^2 + 1/2 ||(z - m0)/s0||^2 + 1/2 sum_n ||nu_n / s_n||^2

* ``w_n = sqrt(alpha_n) / sigma_n``: sigma_n the record's own noise (raised to the residual's RMS of
  the baseline fit where the model misses it), alpha_n = n_eff / K its residual autocorrelation's
  tempering (:class:`ObsModel`, :mod:`imrbayes.ensemble.likelihood`);
* ``nu_n = (a, delta, rho, b_G, b_mu)`` experiment n's geometry and alignment nuisances (relative
  Rmax error, time of the true maximum [t*], log Req error) with the preprocessing prior sd s_n, and
  its own material offsets (log G, log mu of this bubble minus the shared values: bubble-to-bubble
  scatter of the gel, a random effect with prior sd ``re_sd``), fitted with the shared material
  parameters (``f`` is :func:`imrbayes.ensemble.likelihood.predict`'s time map: samples
  before the maximum from the mirror image; camera data predicted at the frame times and
  interpolated onto the grid as the data were);
* Levenberg–Marquardt with a forward-difference Jacobian: one column per material coordinate, and
  five batched columns for the nuisances (experiment n's residuals depend on its own nu_n only, so
  one perturbation of coordinate j in every experiment fills the block diagonal).

The Laplace covariance is (J^T J)^-1 at the optimum; its material block is marginal over the
nuisances. Sample 0 (R* = 1 by construction) is never fitted.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

__all__ = [
    "ObsModel",
    "predict",
    "frame_values",
    "fit_map",
    "MapOptions",
    "fit_tempered",
    "fit_nuisances",
    "MapFit",
    "nuisance_restarts",
]

FAIL_RESIDUAL = 1.0  # R* error assigned to a failed solve (per sample)
MAX_STEPS = 20_000  # a member needing more integrator steps counts as failed (stiff corners of the prior)
NU_STEP = 0.05  # nuisance finite-difference step [prior sd]
#: longest trial step of the material coordinates [prior sd]: a coordinate the data barely see (a
#: relaxation time near the NHKV limit) has Marquardt damping ~ its prior precision only, and steps of
#: 2-7 prior sd there sent the trial solves to far-off, slow parameter sets (docs/methods.md, Runtime)
TRUST_SD = 2.0
#: the MAP of a candidate's extension (its parameters beyond G and mu) is searched within this many
#: prior sd of the prior mean (the prior density there is < 4e-6 of its peak). Why: a first fit on
#: the records' noise swamps the prior, and where the data prefer the NHKV limit of a nested model
#: (zener's lambda1 -> 0) the fit crawled to lambda1 ~ 1e-14 s: R* within 3e-5 of lambda1 = 1 ns,
#: but up to 7x the Radau steps per solve (at 1e-14 s) and 40 iterations unconverged -- UMich
#: PA10's zener fit took 892 s (docs/methods.md, Runtime). No stored final fit of a candidate
#: lies beyond 4 prior sd.
EXTENSION_BOX_SD = 5.0
#: stop when the Gauss-Newton model predicts less than this decrease of the cost (log-density
#: units; 1e-3 is a move of ~0.05 posterior sd): the crawl along a flat direction buys nothing
NEWTON_DECREMENT = 1e-3
#: relative stop of a candidate's first fit (on the records' noise; 1e-6 in every other fit). That
#: fit picks the basin and sets the tempering: on a misfitting model its cost is the tempered one
#: times chi-square/n (~150 on stiff PA), so 1e-4 of it is ~0.01-0.03 nats of the tempered fit
#: that follows, and its last iterations (a fifth of them) polished a point that fit moves away
#: from anyway. Not the baseline's: its tempering is every later fit's, and with 1e-4 its
#: tempered fit on stiff PA 1-5 ended at chi-square/n 115.4 against 107.0 (docs/methods.md, Runtime)
CANDIDATE_FIRST_TOL = 1e-4
#: the race's runner-up also goes on to convergence when it is at most this fraction behind the
#: leader and in another basin of the candidate's extension (its parameters beyond G and mu more
#: than RUNNER_UP_APART apart, internal units): relaxation 2001's zener on three bubbles led at
#: cost 105 after the race and ended at 94.9 (lambda1 1.5 us) while the runner-up (119, lambda1
#: 2.8 us) ends at 87.7 (3.4 us; truth 3.9 us); a trace found a runner-up 18 % behind that
#: ended 3.6 % lower. Any basin (G and mu too) cost stiff PA 1-5 50 s for no change of any fit
#: (docs/methods.md, Runtime)
RUNNER_UP_BEHIND = 0.25
RUNNER_UP_APART = 0.3
#: prior sd of each bubble's log G and log mu offset from the gel's: a fixed prior for the
#: bubble-to-bubble scatter (not estimated here; ``fit``'s random-effects layer estimates it)
RE_SD = (0.15, 0.15)


@dataclass
class ObsModel:
    """How one dataset's samples are compared with a prediction (per experiment n):
    ``noise_sd`` (E,) the record's noise sd in R* (the check's statistics divide by it);
    ``sd_used`` (E,) the sd of the likelihood (noise raised to the baseline's residual RMS);
    ``alpha`` (E,) the tempering n_eff / K; ``nu_sd`` (E, 5) the nuisances' prior sd (0: held
    fixed): Rmax, t0, Req, then the bubble's log G and log mu offsets; ``frames`` per experiment the camera frame times t* (None: point values)."""

    noise_sd: np.ndarray
    sd_used: np.ndarray
    alpha: np.ndarray
    nu_sd: np.ndarray
    frames: list | None = None
    n_eff: np.ndarray | None = None
    tau: np.ndarray | None = field(default=None)

    @property
    def weight(self) -> np.ndarray:
        return np.sqrt(self.alpha) / self.sd_used

    @classmethod
    def of(cls, obs, nuisances: bool = True, random_effects=RE_SD) -> ObsModel:
        """Record noise, no tempering yet; nuisances with their preprocessing prior (or fixed);
        ``random_effects`` the prior sd of each bubble's (log G, log mu) offset (None: none; with one
        experiment there is no scatter to speak of, so none)."""
        from imrbayes.ensemble.likelihood import nuisance_prior_sd, record_noise_sd

        E = obs.n_exp
        sd = np.array([record_noise_sd(obs, n) for n in range(E)])
        nu_sd = np.array([nuisance_prior_sd(obs, n) for n in range(E)]) if nuisances else np.zeros((E, 3))
        re = np.zeros((E, 2)) if random_effects is None or E < 2 else np.tile(np.asarray(random_effects, float), (E, 1))
        nu_sd = np.hstack([np.where(np.isfinite(nu_sd) & (nu_sd > 0), nu_sd, 0.0), re])
        return cls(sd, sd.copy(), np.ones(E), nu_sd, None if obs.frame_t is None else list(obs.frame_t))

    def tempered(self, obs, fitted) -> ObsModel:
        """The likelihood at the baseline fit ``fitted`` (E, n): each experiment's variance raised
        to its residual's mean square, tempered by its residuals' n_eff / K."""
        from imrbayes.ensemble.likelihood import observation_model

        out = [
            observation_model(obs.R_star[n, 1:], fitted[n, 1:], float(self.noise_sd[n]) ** 2) for n in range(obs.n_exp)
        ]
        return replace(
            self,
            sd_used=np.array([np.sqrt(o["var"]) for o in out]),
            alpha=np.array([o["alpha"] for o in out]),
            n_eff=np.array([o["effective_samples"] for o in out]),
            tau=np.array([o["autocorrelation_time"] for o in out]),
        )

    def without_random_effects(self) -> ObsModel:
        """The same with every bubble's material offset held at 0 (a new bubble's material is the
        gel's prediction)."""
        nu_sd = self.nu_sd.copy()
        nu_sd[:, 3:] = 0.0
        return replace(self, nu_sd=nu_sd)

    def take(self, idx) -> ObsModel:
        idx = np.atleast_1d(np.asarray(idx, dtype=int))
        pick = lambda a: None if a is None else np.asarray(a)[idx]
        return ObsModel(
            self.noise_sd[idx],
            self.sd_used[idx],
            self.alpha[idx],
            self.nu_sd[idx],
            None if self.frames is None else [self.frames[i] for i in idx],
            pick(self.n_eff),
            pick(self.tau),
        )

    def describe(self) -> dict:
        return {
            "noise_sd": self.noise_sd.tolist(),
            "sd_used": self.sd_used.tolist(),
            "alpha": self.alpha.tolist(),
            "effective_samples": None if self.n_eff is None else self.n_eff.tolist(),
            "nuisance_prior_sd": self.nu_sd.tolist(),
            "frames": self.frames is not None,
            "random_effects_sd": self.nu_sd[0, 3:].tolist() if self.nu_sd.shape[0] else [],
            "note": "per experiment: the record's noise sd in R* (fourth differences / preprocessing), the sd "
            "used (raised to the baseline fit's residual RMS), the tempering alpha = n_eff/K (residual "
            "autocorrelation), the prior sd of (Rmax rel. error, t0 offset [t*], log Req error, the "
            "bubble's log G and log mu offsets from the gel's); the observation model of `fit "
            "--likelihood default`, with a fixed-sd random effect per bubble",
        }


def _times(obs, idx, K, frames):
    """Per experiment the times to simulate (grid or frames) and the interpolation back to the grid."""
    from imrbayes.ensemble.likelihood import frame_operator

    t = np.asarray(obs.t_star[: K + 1], dtype=float)
    rows, ops = [], []
    for e in idx:
        if frames is None:
            rows.append(t)
            ops.append(None)
            continue
        tf, ia, w = frame_operator(frames[e], t)
        rows.append(tf)
        ops.append((ia, w))
    return rows, ops


def predict(cand, z, obs, idx, minima, K: int, nu=None, frames=None) -> np.ndarray:
    """R* (M, len(idx), K+1) on the data's samples 0..K for parameter sets z (M, d); ``nu`` the
    nuisances (M, E, q), (E, q) or None (zero: the preprocessing geometry and no material offset;
    q = 3 or 5, :class:`ObsModel`), ``frames`` per
    experiment of ``obs`` the camera frame times (None: point values). NaN where a solve failed."""
    return _predict(cand, z, obs, idx, minima, K, nu, frames)[0]


def frame_values(cand, z, obs, minima, nu=None) -> list:
    """Per experiment of ``obs``, R* at the camera frames its grid is interpolated from (or at the
    grid's samples for point-value data), for one parameter set z (d,) and nuisances nu (E, q)."""
    E = obs.n_exp
    _, R, rows = _predict(
        cand,
        np.asarray(z, dtype=float)[None],
        obs,
        np.arange(E),
        minima,
        obs.n_samples - 1,
        None if nu is None else np.asarray(nu, dtype=float)[None],
        obs.frame_t,
    )
    return [R[e, : rows[e].size].copy() for e in range(E)]


def _predict(cand, z, obs, idx, minima, K, nu, frames):
    z = np.atleast_2d(np.asarray(z, dtype=float))
    idx = np.atleast_1d(np.asarray(idx, dtype=int))
    M, E = z.shape[0], idx.size
    if nu is None:
        nu = np.zeros((M, E, 3))
    nu = np.asarray(nu, dtype=float)
    nu = np.broadcast_to(nu, (M, E, nu.shape[-1]))
    zz = np.repeat(z, E, axis=0)  # member i*E + e
    if nu.shape[-1] > 3:  # the bubble's own (log G, log mu)
        zz[:, :2] += nu[..., 3:5].reshape(M * E, 2)
    rows, ops = _times(obs, idx, K, frames)
    m = max(r.size for r in rows)
    a, delta, rho = nu[..., 0].ravel(), nu[..., 1].ravel(), nu[..., 2].ravel()
    scale = 1.0 + a
    bad = ~(scale > 0.5) | ~np.isfinite(a + delta + rho)
    scale, delta, rho = np.where(bad, 1.0, scale), np.where(bad, 0.0, delta), np.where(bad, 0.0, rho)
    T = np.empty((M * E, m))
    for i in range(M):
        for j, r in enumerate(rows):
            T[i * E + j, : r.size] = r
            T[i * E + j, r.size :] = r[-1]
    S = np.abs(T - delta[:, None]) / scale[:, None]
    order = np.argsort(S, axis=1, kind="stable")
    S = np.take_along_axis(S, order, axis=1)
    rmax = np.tile(obs.rmax_m[idx], M) * scale
    req = np.tile(obs.req_m[idx], M) * np.exp(rho)
    bad |= ~(req < rmax)  # a step that puts Req above Rmax: a failed member, not an error
    req = np.where(bad, 0.5 * rmax, req)
    kw = {}
    if not cand.piecewise:
        P = cand.forward_params(zz)  # (M*E, 1, np)
    else:
        # each experiment breaks at its own measured collapses (on the data's clock, mapped to the
        # member's); experiments with fewer collapses in the window get breaks after its end
        brs = [[float(obs.t_star[q]) for q in minima[e] if 0 < q < K] for e in idx]
        nb = max(len(b) for b in brs)
        t_end = float(np.max(S)) + 1.0
        B = np.array([b + [np.nan] * (nb - len(b)) for b in brs], dtype=float).reshape(E, nb)
        B = (np.tile(B, (M, 1)) - delta[:, None]) / scale[:, None]
        pad = t_end + np.arange(nb)[None, :]
        B = np.where(np.isfinite(B), B, pad)
        B = np.maximum.accumulate(np.maximum(B, 1e-6), axis=1) + 1e-9 * np.arange(nb)[None, :]
        P = cand.forward_params(zz, n_pieces=nb + 1)
        kw["breaks_star"] = B
    with np.errstate(all="ignore"):
        o = cand.fm.simulate(P, rmax, req, S, max_steps=MAX_STEPS, **kw)
    R = np.empty_like(o.R_star)
    np.put_along_axis(R, order, o.R_star, axis=1)
    R = np.where((o.failed | bad)[:, None], np.nan, R * scale[:, None])
    out = np.empty((M, E, K + 1))
    for i in range(M):
        for j, op in enumerate(ops):
            r = R[i * E + j]
            out[i, j] = r[: K + 1] if op is None else (1.0 - op[1]) * r[op[0]] + op[1] * r[op[0] + 1]
    return out, R, rows


@dataclass
class MapFit:
    key: str
    z: np.ndarray  # (d,) material MAP, internal coordinates
    cov: np.ndarray  # (d, d) Laplace covariance, marginal over the nuisances
    cost: float
    chi2: float  # data part of 2 * cost (weighted)
    n_data: int
    fitted: np.ndarray  # (E, K+1) prediction at the MAP (with the nuisances)
    K: int
    idx: np.ndarray
    n_iter: int
    converged: bool
    nu: np.ndarray | None = None  # (E, q) nuisance MAP (ObsModel: Rmax, t0, Req, log G and log mu offsets)
    nu_sd: np.ndarray | None = None  # (E, q) their Laplace sd


def _residuals(R, y, w):
    r = (y[None] - R[..., 1:]) * w[None, :, None]
    bad = ~np.isfinite(r)
    r[bad] = FAIL_RESIDUAL * np.broadcast_to(w[None, :, None], r.shape)[bad]
    return r.reshape(r.shape[0], -1)


#: Extension starts (:func:`extension_starts`): levels of one extension parameter [its prior sd from
#: the prior mean], the log G offsets screened at each level, and how many such starts are kept.
EXT_LEVELS = (-1.0, -0.5, 0.5, 1.0)
EXT_LOG_G = tuple(np.linspace(-1.5, 1.0, 11))
EXT_KEEP = 2


def extension_starts(cand, base) -> np.ndarray:
    """Points of a candidate's extension to screen (E, d): from ``base`` (internal, the baseline
    optimum with the extension at its prior mean), one extension parameter moved to each of
    :data:`EXT_LEVELS` prior sd, G moved along :data:`EXT_LOG_G` (an extension trades off against
    G: stiffening, relaxation and damage each change the G that fits), mu kept. Levels whose SI
    values point the wrong way for the mechanism (``spec.consistent``) are left out: such a fit is
    ranked last anyway.

    Why: the cost along the extension's trade-off with G has a local minimum at every alignment of
    the collapses -- on camera-style stiffening data (qkv seed 1002) the fit started at the baseline
    optimum stopped at alpha 0.07 (cost 510) while starts at alpha 0.125, 0.25 ended at 0.13 (345)
    and 0.31 (224; truth 0.42), and no (G, mu) grid point with the extension at its prior mean
    leads there."""
    base = np.asarray(base, dtype=float)
    out = []
    for j in range(2, cand.d):
        for lv in EXT_LEVELS:
            z = base.copy()
            z[j] = cand.prior_mean[j] + lv * cand.prior_sd[j]
            ok, _ = cand.spec.consistent(dict(zip(cand.names, cand.to_si(z))))
            if ok:
                line = np.repeat(z[None], len(EXT_LOG_G), axis=0)
                line[:, 0] += EXT_LOG_G
                out.extend(line)
    return np.array(out).reshape(-1, cand.d)


def grid_starts(
    cand,
    obs,
    idx,
    K,
    minima,
    om,
    nu0,
    extra_starts=(),
    n_best: int = 2,
    n_grid: int = 8,
    n_random: int = 48,
    seed: int = 0,
    ext_keep: int = EXT_KEEP,
) -> list:
    """Starting points: the best ``n_best`` of a log grid over (G, mu) (other parameters at their
    prior mean), random prior draws (sd 1.5x) and ``extra_starts``, by the MAP cost at ``nu0``;
    with a candidate's extension, also the best ``ext_keep`` of :func:`extension_starts` around the
    first of ``extra_starts`` (one per level and parameter: the best G on its line), which the
    screen cannot rank against the others (at the baseline's alignment every point off its
    optimum costs more, the better basins included) and so are always tried."""
    rng = np.random.default_rng(seed)
    Gs = np.log(np.geomspace(300.0, 6e4, n_grid))
    mus = np.log(np.geomspace(0.005, 1.0, n_grid))
    gg, mm = np.meshgrid(Gs, mus, indexing="ij")
    Z = np.repeat(cand.prior_mean[None], gg.size, axis=0)
    Z[:, 0], Z[:, 1] = gg.ravel(), mm.ravel()
    parts = [Z, cand.prior_mean + 1.5 * cand.prior_sd * rng.standard_normal((n_random, cand.d))]
    if len(extra_starts):
        parts.append(np.atleast_2d(np.asarray(extra_starts, dtype=float)))
    Z = np.vstack(parts)
    n_z = Z.shape[0]
    if len(extra_starts) and ext_keep and cand.d > 2:
        Z = np.vstack([Z, extension_starts(cand, extra_starts[0])])
    y = obs.R_star[idx, 1 : K + 1]
    r = _residuals(predict(cand, Z, obs, idx, minima, K, nu0, om.frames), y, om.weight)
    cost = 0.5 * np.sum(r * r, axis=1) + 0.5 * np.sum(((Z - cand.prior_mean) / cand.prior_sd) ** 2, axis=1)
    # extension lines (one per parameter and level): each line's best G, then the ext_keep best lines
    X, line_cost = Z[n_z:].reshape(-1, len(EXT_LOG_G), cand.d), cost[n_z:].reshape(-1, len(EXT_LOG_G))
    best_g = line_cost.argmin(axis=1)
    ext = [X[i, best_g[i]] for i in np.argsort(line_cost.min(axis=1), kind="stable")[:ext_keep]]
    Z, cost = Z[:n_z], cost[:n_z]
    order = np.argsort(cost)
    out = [Z[order[0]]]
    for i in order[1:]:
        if len(out) >= n_best:
            break
        if np.max(np.abs(Z[i, :2] - out[0][:2])) > 0.3:  # a different basin in (G, mu)
            out.append(Z[i])
    for s in [*extra_starts, *ext]:  # always try the given starts (e.g. the baseline optimum) -- once:
        s = np.asarray(s, dtype=float)  # when one is also the screen's best, a second copy repeats its fit
        if not any(np.array_equal(s, o) for o in out):
            out.append(s)
    return out


def nuisance_restarts(cand, obs, idx, K, minima, om: ObsModel, z, nu, levels=(-2.0, 2.0), max_iter: int = 10):
    """Per experiment of ``idx`` the best nuisances, material held at ``z``, over fits started from
    ``nu`` (E, q), from 0 and from each of ``levels`` prior sd along each free coordinate. The
    experiments' nuisances are independent given the material, so every start of every experiment
    is one stacked nuisance-only fit (one batch of forward solves). Returns (nu (E, q), the
    experiments whose objective fell).

    Why: each bubble's (Rmax, t0, Req, log G and log mu offsets) objective is multimodal -- an offset
    of the bubble's material can stand in for a misalignment -- and a joint fit started at 0 ends
    in such a basin for one bubble in five on the stiff-PA design (its chi-square 10-20x that of
    the fit started at the truth: docs/methods.md)."""
    idx = np.atleast_1d(np.asarray(idx, dtype=int))
    E, q = idx.size, om.nu_sd.shape[1]
    s_nu = om.nu_sd[idx]
    nu = np.asarray(nu, dtype=float)[:, :q]
    starts = [nu, np.zeros((E, q))]
    for j in range(q):
        if np.any(s_nu[:, j] > 0):
            for lv in levels:
                st = np.zeros((E, q))
                st[:, j] = lv * s_nu[:, j]
                starts.append(st)
    S = len(starts)
    rows = np.tile(idx, S)
    sub = obs.take(rows)
    mins = None if minima is None else [minima[e] for e in rows]
    f = fit_map(
        cand,
        sub,
        K=K,
        minima=mins,
        om=om.take(rows),
        starts=[np.asarray(z, dtype=float)],
        nu0=np.vstack(starts),
        options=MapOptions(fix_material=True, max_iter=max_iter),
    )
    w = om.weight[rows]
    y = obs.R_star[rows, 1 : K + 1]
    u = np.where(om.nu_sd[rows] > 0, f.nu / np.where(om.nu_sd[rows] > 0, om.nu_sd[rows], 1.0), 0.0)
    obj = 0.5 * (np.nansum((w[:, None] * (y - f.fitted[:, 1:])) ** 2, axis=1) + np.sum(u**2, axis=1))
    obj = np.where(np.all(np.isfinite(f.fitted[:, 1:]), axis=1), obj, np.inf).reshape(S, E)
    best = np.argmin(obj, axis=0)
    # start 0 is the given nuisances refitted: "improved" is measured against it, not against a
    # point the nuisance-only fit could still polish
    improved = obj[best, np.arange(E)] < obj[0] - 1e-6 * np.maximum(1.0, np.abs(obj[0]))
    out = f.nu.reshape(S, E, q)[best, np.arange(E)]
    return np.where(improved[:, None], out, nu), improved


#: forward-difference step of the material coordinates in the Jacobian [internal units]
Z_STEP = 0.01


@dataclass
class MapOptions:
    """How :func:`fit_map` searches, besides the starts it is given."""

    extra_starts: tuple = ()
    """Further material starts screened with the grid's (internal coordinates; default none)."""
    alt_nu0: np.ndarray | None = None
    """A second set of starting nuisances (E_all, q): the screen is repeated from them (default None)."""
    fix_material: bool = False
    """Fit the nuisances only, the material held at ``starts[0]`` (default off)."""
    restarts: bool = False
    """After convergence, look for better nuisance basins per experiment and refit (default off)."""
    max_iter: int = 40
    """Most Levenberg-Marquardt iterations (default 40)."""
    tol: float = 1e-6
    """Stop when an accepted step lowers the cost by less than this fraction (default 1e-6)."""
    trace: list | None = None
    """A list that receives one dict per iteration, to study the fit's path (default None)."""


def _nuisance_units(nu0, idx, active, s_nu) -> tuple:
    """(nuisances (E, q), the same in prior-sd units, 0 where inactive) from ``nu0`` (E_all, q' ) rows
    ``idx`` (default 0)."""
    E, q = s_nu.shape
    nu = np.zeros((E, q))
    if nu0 is not None:
        n0 = np.asarray(nu0, dtype=float)[idx]
        nu[:, : min(q, n0.shape[1])] = n0[:, :q]
    return nu, np.where(active, nu / np.where(active, s_nu, 1.0), 0.0)


class _LMProblem:
    """The least-squares system :func:`fit_map` solves for experiments ``idx``, samples 1..K: the
    residual vector of x = (material z (d,), active nuisances in prior sd), its forward-difference
    Jacobian and the projected, damped Levenberg-Marquardt iteration. A state of the iteration is the
    list [x, r, cost, R, damping, converged, iterations, J at x if converged, (x, J, rejected
    dampings)]."""

    def __init__(self, cand, obs, idx, K, minima, om, z_fixed, o: MapOptions):
        self.cand, self.obs, self.idx, self.K, self.minima = cand, obs, idx, K, minima
        self.tol, self.trace = o.tol, o.trace
        self.E = E = idx.size
        self.w = om.weight[idx]
        self.s_nu = om.nu_sd[idx]  # (E, q)
        self.q = q = self.s_nu.shape[1]
        self.active = active = self.s_nu > 0
        self.jn = [j for j in range(q) if active[:, j].any()]  # nuisance coordinates with a column
        self.y = obs.R_star[idx, 1 : K + 1]
        self.m0, self.s0 = m0, s0 = cand.prior_mean, cand.prior_sd
        self.d = d = 0 if o.fix_material else cand.d
        self.z_fixed = z_fixed
        self.frames = om.frames
        self.n_x = n_x = d + int(active.sum())
        self.lo, self.hi = np.full(n_x, -np.inf), np.full(n_x, np.inf)
        if d > 2:
            self.lo[2:d], self.hi[2:d] = m0[2:d] - EXTENSION_BOX_SD * s0[2:d], m0[2:d] + EXTENSION_BOX_SD * s0[2:d]
        # column of the Jacobian for nuisance (e, j)
        self.col = -np.ones((E, q), dtype=int)
        self.col[active] = d + np.arange(int(active.sum()))
        self.n_y = E * K
        self.step_scale = np.concatenate([s0[:d], np.full(n_x - d, np.inf)])  # material steps in prior sd

    def res(self, Z, U):
        """Z (M, d_all) material, U (M, E, q) nuisances in prior-sd units -> (M, n_res) residuals, R."""
        R = predict(self.cand, Z, self.obs, self.idx, self.minima, self.K, U * self.s_nu[None], self.frames)
        parts = [_residuals(R, self.y, self.w)]
        if self.d:
            parts.append((Z - self.m0) / self.s0)
        parts.append(U[:, self.active])
        return np.hstack(parts), R

    def pack(self, z, u):
        """x of material z and nuisances u (prior sd)."""
        return np.concatenate([z[: self.d], u[self.active]])

    def unpack(self, x):
        """(material z, nuisances u (E, q) in prior sd) of x."""
        z = x[: self.d] if self.d else self.z_fixed
        u = np.zeros((self.E, self.q))
        u[self.active] = x[self.d :]
        return z, u

    def jacobian(self, z, u, r):
        """(n_res, n_x) forward-difference Jacobian at (z, u) with residuals r: one batch."""
        d, E, q, K = self.d, self.E, self.q, self.K
        Zs = [z + Z_STEP * np.eye(self.cand.d)[i] for i in range(d)]
        Us = [u] * d
        for j in self.jn:
            du = np.zeros((E, q))
            du[:, j] = NU_STEP
            Zs.append(z)
            Us.append(u + du)
        if not Zs:
            return np.zeros((r.size, 0))
        rp, _ = self.res(np.array(Zs), np.array(Us))
        J = np.zeros((r.size, self.n_x))
        for i in range(d):
            J[:, i] = (rp[i] - r) / Z_STEP
        for i_j, j in enumerate(self.jn):
            diff = (rp[d + i_j] - r) / NU_STEP
            for e in range(E):
                if self.active[e, j]:
                    c = self.col[e, j]
                    J[e * K : (e + 1) * K, c] = diff[e * K : (e + 1) * K]
                    J[self.n_y + c, c] = 1.0
        return J

    def capped(self, step):
        """``step`` shortened so that no material coordinate moves more than TRUST_SD prior sd."""
        m = np.max(np.abs(step) / self.step_scale) if self.d else 0.0
        return step * (TRUST_SD / m) if m > TRUST_SD else step

    def jacobian_at(self, x, r, J_at):
        """(the Jacobian at x, the dampings already rejected there): ``J_at``'s (x', J, rejected)
        when x' is x (after a rejected step the point is unchanged, and its Jacobian is d + 5
        batched solves, ~3/4 of an iteration), else computed, with none rejected."""
        if J_at is not None and np.array_equal(J_at[0], x):
            return J_at[1], J_at[2]
        return self.jacobian(*self.unpack(x), r), np.zeros(0)

    def lm(self, x, r, cost, Rz, lam, n_iter, J_at=None):
        """Up to n_iter iterations from x; ``J_at`` (x, J, dampings rejected at x) a Jacobian already
        computed. Returns the state (class doc)."""
        conv, it, J_x = False, 0, None
        lo, hi, trace = self.lo, self.hi, self.trace
        for it in range(1, n_iter + 1):
            z, u = self.unpack(x)
            J, rejected = self.jacobian_at(x, r, J_at)
            J_at = (x, J, rejected)
            A, g = J.T @ J, J.T @ r
            # a coordinate at its bound that the gradient pushes outwards is held (projected LM)
            free = ~(((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0)))
            A, g = A[np.ix_(free, free)], g[free]
            try:
                decrement = 0.5 * float(g @ np.linalg.solve(A + 1e-12 * np.diag(np.diag(A) + 1e-9), g))
            except np.linalg.LinAlgError:
                decrement = np.inf
            if trace is not None:
                trace.append(
                    {
                        "it": it,
                        "cost": float(cost),
                        "decrement": float(decrement),
                        "lam": float(lam),
                        "z": np.asarray(z, dtype=float).tolist(),
                        "t": time.perf_counter(),
                    }
                )
            if decrement < NEWTON_DECREMENT:
                conv, J_x = True, J
                break
            lams = lam * np.array([0.1, 1.0, 10.0])
            # after a rejection the damping rises 100-fold, so its smallest trial is the last
            # iteration's largest, whose step (same point, same Jacobian) was already rejected
            lams = lams[~np.isclose(lams[:, None], rejected[None, :], rtol=1e-9, atol=0.0).any(axis=1)]
            steps = []
            for lm_ in lams:
                step = np.zeros(self.n_x)
                try:
                    step[free] = -np.linalg.solve(A + lm_ * np.diag(np.diag(A) + 1e-9), g)
                except np.linalg.LinAlgError:
                    pass
                steps.append(np.clip(x + self.capped(step), lo, hi) - x)
            trials = [self.unpack(x + s) for s in steps]
            rt, Rt = self.res(np.array([t[0] for t in trials]), np.array([t[1] for t in trials]))
            costs = 0.5 * np.einsum("ij,ij->i", rt, rt)
            k = int(np.argmin(costs))
            if costs[k] < cost:
                rel = (cost - costs[k]) / max(cost, 1e-300)
                x, r, cost, Rz = x + steps[k], rt[k], float(costs[k]), Rt[k]
                lam = max(lams[k] * 0.3, 1e-7)
                if rel < self.tol or np.max(np.abs(steps[k])) < 1e-5:
                    conv = True
                    break
            else:
                J_at = (x, J, np.concatenate([rejected, lams]))
                lam *= 100.0
                if lam > 1e8:
                    conv = True
                    break
        return [x, r, cost, Rz, lam, conv, it, J_x, J_at]

    def lm_from(self, z, u, n_iter):
        """The state after up to n_iter iterations from material z and nuisances u (prior sd)."""
        r0, R0 = self.res(z[None], u[None])
        return self.lm(self.pack(z, u), r0[0], 0.5 * float(r0[0] @ r0[0]), R0[0], 1e-2, n_iter)

    def map_fit(self, state) -> MapFit:
        """The :class:`MapFit` of a final state, with the Laplace covariance (J^T J)^-1 at it."""
        x, r, cost, Rz, _, conv, it, J, J_at = state
        d, s0 = self.d, self.s0
        z, u = self.unpack(x)
        if J is None:
            J = self.jacobian_at(x, r, J_at)[0]
        try:
            C = np.linalg.inv(J.T @ J)
        except np.linalg.LinAlgError:
            C = np.diag(np.concatenate([s0[:d] ** 2, np.ones(self.n_x - d)]))
        cov = C[:d, :d] if d else np.zeros((self.cand.d, self.cand.d))
        nu_sd = np.zeros((self.E, self.q))
        nu_sd[self.active] = np.sqrt(np.clip(np.diag(C)[d:], 0, None)) * self.s_nu[self.active]
        chi2 = float(np.sum(r[: self.n_y] ** 2))
        return MapFit(
            self.cand.key,
            np.asarray(z, dtype=float).copy(),
            cov,
            cost,
            chi2,
            int(self.y.size),
            Rz,
            self.K,
            self.idx,
            it,
            conv,
            u * self.s_nu,
            nu_sd,
        )


def _start_pairs(p: _LMProblem, om, starts, nu0, o: MapOptions) -> tuple:
    """(material starts, [(z0, u0)] the (material, nuisances in prior sd) pairs raced): ``starts``
    (default: the grid screen) at ``nu0``'s nuisances, and with ``o.alt_nu0`` the screen again
    at those."""
    nu_start, u_start = _nuisance_units(nu0, p.idx, p.active, p.s_nu)
    if starts is None:
        starts = grid_starts(p.cand, p.obs, p.idx, p.K, p.minima, om, nu_start, o.extra_starts)
    starts = [np.asarray(s, dtype=float) for s in starts]
    pairs = [(z0, u_start) for z0 in starts]
    if o.alt_nu0 is not None and not o.fix_material:
        nu_alt, u_alt = _nuisance_units(o.alt_nu0, p.idx, p.active, p.s_nu)
        if not np.array_equal(u_alt, u_start):  # the same nuisances would repeat every start's fit
            # screened again at these nuisances: the first set's material starts raced from them
            # miss better basins (docs/methods.md, Runtime)
            alt = grid_starts(p.cand, p.obs, p.idx, p.K, p.minima, om, nu_alt, o.extra_starts)
            pairs += [(np.asarray(z0, dtype=float), u_alt) for z0 in alt]
    return starts, pairs


def _race(p: _LMProblem, pairs: list, n_main: int, max_iter: int) -> list:
    """Every start a few iterations, then the best of each set of starting nuisances (the first
    ``n_main`` pairs, the rest) and a distinct close runner-up to convergence; returns the best state."""
    trace, d = p.trace, p.d
    states = []
    for i_s, (z0, u0) in enumerate(pairs if d else pairs[:1]):
        if trace is not None and len(pairs) > 1:  # a marker per raced start
            trace.append({"start": i_s, "set": int(i_s >= n_main), "t": time.perf_counter()})
        x0 = np.clip(p.pack(z0, u0), p.lo, p.hi)
        z0 = p.unpack(x0)[0] if d else z0
        r0, R0 = p.res(z0[None], u0[None])
        states.append(
            p.lm(
                x0,
                r0[0],
                0.5 * float(r0[0] @ r0[0]),
                R0[0],
                1e-2,
                max_iter if len(pairs) == 1 or not d else min(6, max_iter),
            )
        )

    def converge(st):
        if trace is not None and len(states) > 1:
            trace.append({"converge": True, "t": time.perf_counter()})
        if len(states) > 1 and not st[5]:
            it0 = st[6]
            st = p.lm(st[0], st[1], st[2], st[3], st[4], max(1, max_iter - it0), st[8])
            st[6] += it0
        return st

    # each set of starting nuisances sends its best start on to convergence: a start far from its
    # set's nuisance optimum (the preprocessing's, when the baseline's have adapted to the wrong
    # model) is costly after a few iterations and only shows its basin at the end
    n_main = n_main if d else 1
    sets = [states[:n_main], states[n_main:]] if d else [states]
    finalists = []
    for st in sets:
        if not st:
            continue
        leader, *rest = sorted(st, key=lambda q: q[2])
        finalists.append(leader)
        lead_ext = leader[0][2:d]  # the extension's coordinates (x starts with z)
        close = [q_ for q_ in rest if lead_ext.size and q_[2] <= leader[2] * (1.0 + RUNNER_UP_BEHIND)]
        finalists += [q_ for q_ in close if np.max(np.abs(q_[0][2:d] - lead_ext)) > RUNNER_UP_APART][:1]
    return min((converge(st) for st in finalists), key=lambda q: q[2])


def _restart_nuisances(p: _LMProblem, best: list, om, max_iter: int) -> list:
    """Up to two rounds of per-experiment nuisance restarts (:func:`nuisance_restarts`) from the
    converged state ``best``, each refitted jointly; returns the better state."""
    for _ in range(2):
        z, u = p.unpack(best[0])
        nu_new, better = nuisance_restarts(p.cand, p.obs, p.idx, p.K, p.minima, om, z, u * p.s_nu)
        if not better.any():
            break
        u_new = np.where(p.active, nu_new / np.where(p.active, p.s_nu, 1.0), 0.0)
        it0 = best[6]
        refit = p.lm_from(z, u_new, max_iter)
        refit[6] += it0
        # the restarts compare nuisance-only fits of each bubble; the joint refit from their basins
        # may still end higher -- keep the better, and without a gain another round would start
        # from the same point
        gained = refit[2] < best[2] * (1.0 - p.tol)
        if refit[2] < best[2]:
            best = refit
        if not gained:
            break
    return best


def fit_map(
    cand,
    obs,
    idx=None,
    K=None,
    minima=None,
    om: ObsModel | None = None,
    starts=None,
    nu0=None,
    options: MapOptions | None = None,
) -> MapFit:
    """MAP + Laplace fit of ``cand`` to experiments ``idx`` over samples 1..K (module doc).

    Parameters
    ----------
    cand : the candidate (:func:`imrbayes.diagnosis.models.make_candidate`).
    obs : Observations, E_all experiments.
    idx : (E,) int, experiments fitted (default all).
    K : last sample fitted (default the record's last).
    minima : (E_all, m) collapse indices (:class:`imrbayes.diagnosis.phases.Phases`).
    om : the observation model (default :meth:`ObsModel.of` ``obs``: record noise, nuisances free);
        indexed by experiment of ``obs`` (``idx`` picks from it).
    starts : internal starting points of the material (default: grid + prior draws); the best wins.
    nu0 : (E_all, q) starting nuisances (default 0).
    options : :class:`MapOptions` (extra starts, a second nuisance start, nuisances only, restarts,
        iterations, tolerance, trace).
    """
    o = options or MapOptions()
    idx = np.arange(obs.n_exp) if idx is None else np.atleast_1d(np.asarray(idx, dtype=int))
    K = obs.n_samples - 1 if K is None else int(K)
    om = ObsModel.of(obs) if om is None else om
    p = _LMProblem(cand, obs, idx, K, minima, om, None, o)
    starts, pairs = _start_pairs(p, om, starts, nu0, o)
    p.z_fixed = starts[0]
    best = _race(p, pairs, len(starts), o.max_iter)
    if o.restarts and p.d and p.active.any():
        best = _restart_nuisances(p, best, om, o.max_iter)
    return p.map_fit(best)


def fit_tempered(
    cand, obs, minima, om0: ObsModel, first_tol: float = 1e-6, starts=None, nu0=None, extra_starts=(), alt_nu0=None
) -> tuple:
    """``fit``'s two-step fit of one model: on the records' noise (``om0``), then on the likelihood
    tempered at that fit, from its optimum. Returns (MapFit, the tempered ObsModel); ``starts``,
    ``nu0``, ``extra_starts`` and ``alt_nu0`` go to the first :func:`fit_map`, which, without ``nu0``, also searches the
    nuisances' other basins (``restarts``); ``first_tol`` is its relative stop (the candidates use
    :data:`CANDIDATE_FIRST_TOL`)."""
    # nuisance restarts when the fit has no informed nuisance start (the baseline); the candidates
    # start from the baseline's nuisances, found with them
    first = fit_map(
        cand,
        obs,
        minima=minima,
        om=om0,
        starts=starts,
        nu0=nu0,
        options=MapOptions(extra_starts=extra_starts, alt_nu0=alt_nu0, restarts=nu0 is None, tol=first_tol),
    )
    om = om0.tempered(obs, first.fitted)
    return fit_map(cand, obs, minima=minima, om=om, starts=[first.z], nu0=first.nu), om


def fit_nuisances(cand, obs, idx, z, minima=None, om: ObsModel | None = None, K=None, nu0=None) -> MapFit:
    """The geometry and alignment of experiments ``idx`` with the material held at ``z`` and no
    material offset (a new bubble's geometry is measured, its material predicted: the held-out
    schemes use this). Started from ``nu0`` ((E_all, q), default 0), 0 and +-1, +-2 prior sd along
    each coordinate, the best basin per experiment (:func:`nuisance_restarts`: the objective is
    multimodal, and a left-out bubble aligned in the wrong basin would count against the model)."""
    om = (ObsModel.of(obs) if om is None else om).without_random_effects()
    idx = np.atleast_1d(np.asarray(idx, dtype=int))
    K = obs.n_samples - 1 if K is None else int(K)
    q = om.nu_sd.shape[1]
    start = np.zeros((obs.n_exp, q))
    if nu0 is not None:
        n0 = np.asarray(nu0, dtype=float)
        start[:, : min(q, n0.shape[1])] = n0[:, :q]
    start[:, 3:] = 0.0
    start = np.where(om.nu_sd > 0, start, 0.0)
    z = np.asarray(z, dtype=float)
    if np.any(om.nu_sd[idx] > 0):
        # the restarts only pick each bubble's basin (the fit below converges from it): three iterations
        # per start pick the same basins as ten on stiff PA's leave-one-out folds (5 of 5; left-out
        # RMSE identical in 4, 4e-4 relative in 1) for 35 % fewer solves (2472 -> 1614)
        best, _ = nuisance_restarts(
            cand, obs, idx, K, minima, om, z, start[idx], levels=(-2.0, -1.0, 1.0, 2.0), max_iter=3
        )
        start[idx] = best
    return fit_map(
        cand, obs, idx=idx, K=K, minima=minima, om=om, starts=[z], nu0=start, options=MapOptions(fix_material=True)
    )
