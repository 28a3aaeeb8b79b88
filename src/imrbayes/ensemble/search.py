"""A global search of the material range before any local method: where the data are.

Every local method (En4D-Var, MIEnKS-MDA, the MCMC check) searches near where it starts. Started at
one prior it returns that prior on a material far from it (a liquid, a gel whose bubbles collapse at
t* ~ 0.4), so this module runs the actual forward model on a log grid (half decades) over the whole range a
user can bring -- G in {0} and 10 Pa .. 1 MPa, mu in 1e-4 .. 10 Pa s -- for up to six bubbles at the
preprocessing's geometry, and fuses the bubbles' costs (docs/methods.md, "Global start").

The cost of bubble n at grid point theta is its chi-square with the record's own noise,
``chi2_n = sum_k (y_k - R*_k(theta))^2 / sigma_n^2``, tempered the way the default likelihood tempers
it (:mod:`imrbayes.ensemble.likelihood`): divided by ``s_n = max(1, min chi2_n / K)`` (the noise is
raised to the residual where the model cannot reach it) and by the residual's integrated
autocorrelation time at the bubble's best point (correlated residuals are fewer independent
observations). The fused cost is the sum over bubbles; its best point with G = 0 and its best point
with G > 0 are then refined continuously (Brent in log mu; Nelder-Mead in log G, log mu) at fixed
tempering, and the better of the two is the methods' start.

The grid includes G = 0 (a liquid; the forward model takes it exactly), so the search also answers
whether the records need elasticity at all: the likelihood-ratio statistic of the best G = 0 point
against the best overall, ``lr = fused(G=0 profile) - fused(min)``, is compared with 2.71 (a 5 %
one-sided test on the boundary, chi-square with 1 degree of freedom at 10 %).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

__all__ = ["SearchResult", "global_search", "G_GRID_PA", "MU_GRID_PAS", "LR_ZERO_THRESHOLD"]

#: G grid [Pa]: 0 (a liquid) and 11 log-spaced points from 10 Pa to 1 MPa (half a decade apart; a
#: decade grid lands between a liquid's basin and its neighbours and picks a wrong one).
G_GRID_PA = np.concatenate([[0.0], np.logspace(1.0, 6.0, 11)])
#: mu grid [Pa s]: 11 log-spaced points from 1e-4 to 10 Pa s.
MU_GRID_PAS = np.logspace(-4.0, 1.0, 11)
#: Bubbles the search runs at most (evenly spread over the dataset): enough to find the basin, and
#: the search's cost stays a fraction of the fit's.
MAX_SEARCH_BUBBLES = 6
#: One-sided 5 % test of G = 0 on the boundary of G >= 0: half chi-square(0) + half chi-square(1).
LR_ZERO_THRESHOLD = 2.71
#: A second local minimum of the fused cost counts as a separate basin within this much of the best.
BASIN_DELTA = 2.0 * LR_ZERO_THRESHOLD


@dataclass
class SearchResult:
    """The global search's grid of costs and what it implies.

    Attributes
    ----------
    G_pa, mu_pas : ndarray (n_G,), (n_mu,)
        The grid [Pa], [Pa s]; ``G_pa[0] = 0``.
    cost : ndarray (n_exp, n_G, n_mu)
        Each bubble's tempered chi-square (inf where the forward run failed).
    fused : ndarray (n_G, n_mu)
        Sum of ``cost`` over bubbles.
    best : dict
        ``{"G": Pa, "mu": Pa s}`` at the refined fused minimum.
    best_per_experiment : list of dict
        The same per bubble.
    basins : list of dict
        Local minima of ``fused`` within :data:`BASIN_DELTA` of the best, best first:
        ``{"G", "mu", "delta_cost"}``.
    zero_modulus : dict
        ``{"lr", "threshold", "consistent_with_zero", "upper95_pa", "best_liquid", "best_solid"}``:
        the likelihood-ratio statistic of G = 0 (refined cost at G = 0 minus the refined best), the
        test's answer, where consistent the G at which the profile cost (over mu) rises by the
        threshold (the 95 % one-sided upper bound; None beyond the range), and the two refined points.
    n_runs : int
        Forward runs made.
    seconds : float
        Wall time.
    """

    G_pa: np.ndarray
    mu_pas: np.ndarray
    cost: np.ndarray
    fused: np.ndarray
    best: dict
    best_per_experiment: list
    basins: list
    zero_modulus: dict
    n_runs: int
    seconds: float
    notes: list = field(default_factory=list)

    def start(self, space, sd_log: float = 1.0):
        """(mean, cov) of the internal coordinates where the methods start: the fused best point
        (G = 0 maps to the grid's smallest positive G) with ``sd_log`` per positive parameter."""
        theta = np.array([self.best.get(nm, np.nan) for nm in space.names], dtype=np.float64)
        if "G" in space.names:
            i = space.names.index("G")
            theta[i] = max(theta[i], float(self.G_pa[1]))
        mean = np.where(
            np.isfinite(theta), space.to_internal(np.where(np.isfinite(theta), theta, 1.0)), space.prior_mean
        )
        sd = np.sqrt(np.diag(space.prior_cov)).copy()
        known = np.isfinite(theta) & np.asarray(space.positive)
        sd[known] = np.minimum(sd[known], sd_log)
        return mean, np.diag(sd**2)

    def describe(self) -> dict:
        """JSON-ready summary (``summary.json["search"]``; its wall time goes to the run's execution
        block, so that the same data give the same summary)."""
        return {
            "grid": {"G_pa": self.G_pa.tolist(), "mu_pas": self.mu_pas.tolist()},
            "best": self.best,
            "best_per_experiment": self.best_per_experiment,
            "basins": self.basins,
            "zero_modulus": self.zero_modulus,
            "n_runs": int(self.n_runs),
            "notes": list(self.notes),
            "rule": "tempered chi-square of each record on a log grid of full forward runs at the "
            "preprocessing's geometry, summed over bubbles",
        }


def _autocorrelation_time(resid: np.ndarray) -> float:
    """Integrated autocorrelation time of a residual series (>= 1), with emcee's automatic window
    (c = 5); a short series is not an MCMC chain, so emcee's length warning does not apply."""
    from emcee.autocorr import auto_window, function_1d

    r = np.asarray(resid, dtype=np.float64)
    if r.size < 8 or not np.all(np.isfinite(r)) or np.std(r) == 0:
        return 1.0
    taus = 2.0 * np.cumsum(function_1d(r)) - 1.0
    tau = float(taus[auto_window(taus, 5.0)])
    return max(1.0, tau) if math.isfinite(tau) else 1.0


def _tempering(chi2_best: float, resid_best: np.ndarray, n: int) -> float:
    """The divisor of one record's chi-square: the noise raised to its best point's residual where
    the model cannot reach it, times the residual's integrated autocorrelation time there."""
    return max(1.0, chi2_best / n) * _autocorrelation_time(resid_best)


def _local_minima(f: np.ndarray) -> list:
    """Indices (i, j) of the finite local minima of a 2-D array (8-neighbourhood), best first."""
    out = []
    n_i, n_j = f.shape
    for i in range(n_i):
        for j in range(n_j):
            v = f[i, j]
            if not math.isfinite(v):
                continue
            nb = f[max(0, i - 1) : i + 2, max(0, j - 1) : j + 2]
            if v <= np.min(nb):
                out.append((i, j))
    return sorted(out, key=lambda ij: f[ij])


def _fused_at(runner, obs, theta_row, K, temper) -> float:
    """The fused tempered cost at one parameter row (SI), all bubbles in one batched call."""
    from imrbayes.ensemble.likelihood import record_noise_sd, simulate_shifted

    n = obs.n_exp
    R, failed = simulate_shifted(runner, np.tile(theta_row, (n, 1)), obs.rmax_m, obs.req_m, obs.t_star[:K], np.zeros(n))
    if failed.any() or not np.all(np.isfinite(R)):
        return float("inf")
    sd = np.array([record_noise_sd(obs, i) for i in range(n)])
    chi2 = np.sum((R[:, 1:] - obs.R_star[:, 1:K]) ** 2, axis=1) / sd**2
    return float(np.sum(chi2 / temper))


def _refine(runner, obs, K, temper, row, iG, imu, G0, mu0, liquid: bool) -> tuple:
    """The fused cost's minimum near a grid point, continuously: over log mu alone at G = 0 (bounded
    Brent), over (log G, log mu) otherwise (Nelder-Mead); returns (cost, G, mu, evaluations)."""
    from scipy import optimize

    def at(G, mu):
        th = row.copy()
        th[iG], th[imu] = G, mu
        return _fused_at(runner, obs, th, K, temper)

    if liquid:
        x0 = math.log(mu0)
        r = optimize.minimize_scalar(
            lambda x: at(0.0, math.exp(x)),
            bounds=(x0 - 1.2, x0 + 1.2),
            method="bounded",
            options={"xatol": 5e-3, "maxiter": 30},
        )
        return float(r.fun), 0.0, float(math.exp(r.x)), int(r.nfev)
    x0 = np.array([math.log(G0), math.log(mu0)])
    r = optimize.minimize(
        lambda x: at(math.exp(x[0]), math.exp(x[1])),
        x0,
        method="Nelder-Mead",
        options={"initial_simplex": [x0, x0 + [0.6, 0.0], x0 + [0.0, 0.6]], "xatol": 5e-3, "fatol": 0.05, "maxfev": 80},
    )
    return float(r.fun), float(math.exp(r.x[0])), float(math.exp(r.x[1])), int(r.nfev)


def _profile_upper_bound(runner, obs, K, temper, row, iG, imu, f_best, mu_start, G_pa, fused) -> float | None:
    """The G [Pa] where the profile cost (minimised over mu at fixed G) rises :data:`LR_ZERO_THRESHOLD`
    above the best: the 95 % one-sided upper bound of a liquid's G. None when it lies beyond 1 MPa."""
    from scipy import optimize

    def profile(log_g):
        th = row.copy()
        th[iG] = math.exp(log_g)
        x0 = math.log(mu_start)

        def at(x):
            th[imu] = math.exp(x)
            return _fused_at(runner, obs, th, K, temper)

        r = optimize.minimize_scalar(
            at, bounds=(x0 - 1.2, x0 + 1.2), method="bounded", options={"xatol": 1e-2, "maxiter": 20}
        )
        return float(r.fun) - f_best - LR_ZERO_THRESHOLD

    lo = math.log(float(G_pa[1]) / 10.0)
    # the first coarse G whose row is clearly above the threshold brackets the bound from above
    rows = np.min(fused, axis=1) - np.min(fused)
    above = [i for i in range(1, len(G_pa)) if rows[i] > 4.0 * LR_ZERO_THRESHOLD]
    for i in above:
        hi = math.log(float(G_pa[i]))
        if profile(hi) > 0:
            return float(math.exp(optimize.brentq(profile, lo, hi, xtol=0.05, maxiter=12)))
    return None


def _grid_chi2(runner, obs, theta, K) -> tuple:
    """Every bubble's chi-square with its record's noise at every row of ``theta``: (chi2 (n_exp,
    n_points), inf where a run failed; the residual (n_exp, K - 1) at each bubble's best row)."""
    from imrbayes.ensemble.likelihood import record_noise_sd, simulate_shifted

    m = len(theta)
    chi2 = np.full((obs.n_exp, m), np.inf)
    best_resid = np.zeros((obs.n_exp, K - 1))
    for n in range(obs.n_exp):
        R, failed = simulate_shifted(
            runner, theta, np.full(m, obs.rmax_m[n]), np.full(m, obs.req_m[n]), obs.t_star[:K], np.zeros(m)
        )
        resid = R[:, 1:] - obs.R_star[n, 1:K]
        c = np.sum(resid**2, axis=1) / record_noise_sd(obs, n) ** 2
        chi2[n] = np.where(failed | ~np.isfinite(c), np.inf, c)
        if np.isfinite(chi2[n]).any():
            best_resid[n] = resid[int(np.argmin(chi2[n]))]
    return chi2, best_resid


def global_search(fm, obs, runner, n_samples: int | None = None, G_pa=None, mu_pas=None, progress=None) -> SearchResult:
    """Run the grid for (up to six of) the bubbles and fuse.

    Parameters
    ----------
    fm : imrbayes.forward.ForwardModel
        The model the method will fit; its constitutive model must have parameters G and mu.
    obs : imrbayes.ensemble.Observations
    runner : imrbayes.forward.Runner
        Batched solves (one call per bubble, all grid points at once).
    n_samples : int, optional
        Samples of the record to use (default: all).
    G_pa, mu_pas : array_like, optional
        The grid (default :data:`G_GRID_PA`, :data:`MU_GRID_PAS`).
    progress : callable(str), optional
        Called at the end with a line of text.
    """
    t_start = time.perf_counter()
    runs_before = int(getattr(runner, "n_member_runs", 0))
    G_pa = np.asarray(G_GRID_PA if G_pa is None else G_pa, dtype=np.float64)
    mu_pas = np.asarray(MU_GRID_PAS if mu_pas is None else mu_pas, dtype=np.float64)
    names = [p.name for p in fm.constitutive.parameters]
    if "G" not in names or "mu" not in names:
        raise ValueError(f"the global search needs a model with G and mu, {fm.constitutive.name} has {names}")
    iG, imu = names.index("G"), names.index("mu")
    defaults = np.array([p.default for p in fm.constitutive.parameters], dtype=np.float64)

    def rows(pairs):
        th = np.tile(defaults, (len(pairs), 1))
        th[:, iG], th[:, imu] = [p[0] for p in pairs], [p[1] for p in pairs]
        return th

    K = obs.n_samples if n_samples is None else int(n_samples)
    if obs.n_exp > MAX_SEARCH_BUBBLES:
        obs = obs.take(np.unique(np.linspace(0, obs.n_exp - 1, MAX_SEARCH_BUBBLES).round().astype(int)))
    pairs = [(g, m) for g in G_pa for m in mu_pas]
    chi2, resid = _grid_chi2(runner, obs, rows(pairs), K)
    temper = np.array([_tempering(float(np.min(chi2[n])), resid[n], K - 1) for n in range(obs.n_exp)])
    cost = (chi2 / temper[:, None]).reshape(obs.n_exp, G_pa.size, mu_pas.size)
    fused = np.sum(cost, axis=0)
    if not np.isfinite(fused).any():
        raise RuntimeError("the global search found no grid point where every bubble's forward run succeeded")
    minima = _local_minima(fused)
    i0, j0 = minima[0]
    # refine the best G = 0 point and the best G > 0 point continuously: on a grid the modulus stands
    # in for the viscosity between two grid values (a liquid at mu 0.05 Pa s reads G 300 Pa), and
    # precise records resolve mu far below any affordable grid step
    i_pos = int(np.argmin(fused[1:].min(axis=1))) + 1
    c_zero, _, mu_zero, n_zero = _refine(
        runner, obs, K, temper, defaults, iG, imu, 0.0, float(mu_pas[int(np.argmin(fused[0]))]), liquid=True
    )
    c_pos, G_pos, mu_pos, n_pos = _refine(
        runner,
        obs,
        K,
        temper,
        defaults,
        iG,
        imu,
        float(G_pa[i_pos]),
        float(mu_pas[int(np.argmin(fused[i_pos]))]),
        liquid=False,
    )
    f_best = min(c_zero, c_pos)
    best = {"G": 0.0, "mu": mu_zero} if c_zero <= c_pos else {"G": G_pos, "mu": mu_pos}
    notes = []
    basins = [
        {"G": float(G_pa[i]), "mu": float(mu_pas[j]), "delta_cost": float(fused[i, j] - fused[i0, j0])}
        for i, j in minima
        if fused[i, j] - fused[i0, j0] <= BASIN_DELTA
    ]
    if len(basins) > 1:
        notes.append(
            f"the cost has {len(basins)} separate basins within {BASIN_DELTA:g} of the best: "
            + "; ".join(f"G {b['G']:.3g} Pa, mu {b['mu']:.3g} Pa s" for b in basins)
        )
    theta_best = np.argmin(cost.reshape(obs.n_exp, -1), axis=1)
    best_each = [
        {"name": obs.names[n], "G": float(pairs[k][0]), "mu": float(pairs[k][1])} for n, k in enumerate(theta_best)
    ]
    lr = float(c_zero - f_best)
    consistent = lr <= LR_ZERO_THRESHOLD
    upper = (
        _profile_upper_bound(runner, obs, K, temper, defaults, iG, imu, f_best, mu_zero, G_pa, fused)
        if consistent
        else None
    )
    zero = {
        "lr": lr,
        "threshold": LR_ZERO_THRESHOLD,
        "consistent_with_zero": bool(consistent),
        "upper95_pa": upper,
        "best_liquid": {"mu": mu_zero, "cost": c_zero},
        "best_solid": {"G": G_pos, "mu": mu_pos, "cost": c_pos},
    }
    for edge, where in (
        (best["G"] >= G_pa[-1], "G's largest grid value"),
        (best["mu"] <= mu_pas[0], "mu's smallest grid value"),
        (best["mu"] >= mu_pas[-1], "mu's largest grid value"),
    ):
        if edge:
            notes.append(f"the best point sits on {where}: the material may lie outside the searched range")
    if progress is not None:
        progress(
            f"global search: {len(pairs)} grid points x {obs.n_exp} bubbles; best G {best['G']:.3g} Pa, "
            f"mu {best['mu']:.3g} Pa s"
        )
    return SearchResult(
        G_pa,
        mu_pas,
        cost,
        fused,
        best,
        best_each,
        basins,
        zero,
        int(getattr(runner, "n_member_runs", 0)) - runs_before,
        time.perf_counter() - t_start,
        notes,
    )
