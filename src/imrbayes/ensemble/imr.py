"""Standard IMR: least squares on a (G, mu) grid (methods.md §1).

Cost, with every experiment simulated with its own Rmax and Req,

    J(theta) = (1/N_exp) sum_n J_n(theta),   J_n = sum_{k in window_n} c_k (Y_nk(theta) - y_nk)^2,

c_k = 1 (``weighting="none"``, methods.md) or 1/P_k (``"P"``); the window is samples 1..K_n
(sample 0 is R* = 1 for every curve) with K_n from ``window``: ``"all"``, ``"t:T"`` (t* <= T) or
``"collapse:k"`` (through the k-th collapse, the k-th local minimum of experiment n's measured
curve with prominence >= ``collapse_prominence``).

Grid: G in [G_min, G_max], mu in [mu_min, mu_max], n_G x n_mu points, log-spaced by default over
the whole range a user can bring (G = 0 and 10 Pa to 1 MPa, mu 1e-4 to 10 Pa s; a liquid's G = 0 is a
grid point); ``spacing=linear`` with the paper's [0, 25] kPa x [0, 0.5] Pa s reproduces the paper's
grid. Other parameters of the model are held at their defaults.

Reported: the overall optimum (grid argmin; ``refine`` adds a sub-grid optimum from a quadratic
fit to the 3 x 3 neighbourhood), the optimum of every J_n, the landscape, and a 95 % confidence
region built as follows (Beale 1960, "F on the cost"). With n = sum_n K_n residuals and p = 2
parameters, the noise scale is estimated from the residuals at the optimum, s^2 = N_exp J_min/(n-p),
and the region is

    J(theta) <= J_min (1 + p/(n - p) F_{p, n-p}(0.95)).

The matching pseudo-posterior on the grid, p(theta) ∝ exp(-(n - p) J(theta) / (2 J_min)), gives the
reported sd and 95 % HDI (its 95 % HPD region is the contour above for large n); when it is
narrower than one grid cell, the Laplace approximation of the same pseudo-posterior at the refined
optimum (the quadratic fit's Hessian) is used instead (``details["uncertainty_from"]``). Caveat: it treats
the residuals as independent; residuals of one R(t) curve are correlated in time, so the region is
optimistic. ``estimate[*]["mean"]`` is the optimum (standard IMR's point estimate); the
pseudo-posterior mean is ``posterior_mean``.

Nuisances (methods.md §7.3). Standard IMR is kept as the literature's method: Rmax, Req and the
time of the maximum stay fixed at preprocessing's estimates (the local fit of the maximum, Req from
the tail), and its region does not include their uncertainty. Adding three nuisances per bubble
would turn the 2-D grid into a (2 + 3 N_exp)-D search, and its purpose here is the paper's
reference answer. For intervals that include alignment and geometry (and each sample counted
once) use ``en4dvar`` (the default likelihood); ``details["nuisances"]`` says this in each run.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from imrbayes.ensemble.method import InferenceMethod
from imrbayes.ensemble.result import FitResult, rmse
from imrbayes.errors import InputError
from imrbayes.execution import Execution, Unit, unit_id
from imrbayes.forward import Runner, fm_spec, register_runner, runner_for

__all__ = ["IMR", "IMRSettings", "fit_imr", "imr_unit", "fit_indices", "collapse_indices", "confidence_level"]


@dataclass
class IMRSettings:
    """Grid, window and cost weighting of standard IMR (see module doc). SI units."""

    G_min: float = 0.0  #: lowest G [Pa] (0: a liquid)
    G_max: float = 1e6  #: highest G [Pa]
    mu_min: float = 1e-4  #: lowest mu [Pa s]
    mu_max: float = 10.0  #: highest mu [Pa s]
    n_G: int = 120  #: grid points in G
    n_mu: int = 74  #: grid points in mu
    spacing: str = "log"  #: log (from 1e-5 of the top where the bottom is 0, which is kept) | linear
    window: str = "all"
    weighting: str = "none"
    level: float = 0.95
    refine: bool = True
    collapse_prominence: float = 0.05
    n_draws: int = 1000

    def check(self):
        if self.n_G < 3 or self.n_mu < 3:
            raise InputError("grid", "needs at least 3 points per axis")
        if not (self.G_max > self.G_min >= 0 and self.mu_max > self.mu_min >= 0):
            raise InputError("grid", "needs 0 <= G_min < G_max and 0 <= mu_min < mu_max")
        if self.spacing not in ("log", "linear"):
            raise InputError("spacing", f"must be 'log' or 'linear', got {self.spacing!r}")
        if self.weighting not in ("none", "P"):
            raise InputError("weighting", f"must be 'none' or 'P', got {self.weighting!r}")
        if not 0 < self.level < 1:
            raise InputError("level", f"must lie in (0, 1), got {self.level}")


def grid_axis(lo: float, hi: float, n: int, spacing: str = "log") -> np.ndarray:
    """(n,) grid from ``lo`` to ``hi``: linear, or log-spaced (where ``lo`` is 0 it stays the first
    point and the log spacing starts at 1e-5 ``hi``: 10 Pa for a 1 MPa top)."""
    if spacing == "linear":
        return np.linspace(lo, hi, n)
    if lo > 0:
        return np.logspace(np.log10(lo), np.log10(hi), n)
    return np.concatenate([[0.0], np.logspace(np.log10(hi) - 5.0, np.log10(hi), n - 1)])


def collapse_indices(y, prominence: float = 0.05) -> np.ndarray:
    """Sample indices of the collapses (local minima with the given prominence in R*) of one curve."""
    # scipy is imported where it is used: the method registry (imported when the CLI starts) stays cheap
    from scipy import signal

    idx, _ = signal.find_peaks(-np.asarray(y, dtype=float), prominence=prominence)
    return idx


def fit_indices(obs, window: str, prominence: float = 0.05) -> np.ndarray:
    """Last fitted sample K_n (n_exp,) for ``window`` = all | t:T | collapse:k."""
    w = str(window).strip().lower()
    n = obs.n_samples
    if w == "all":
        return np.full(obs.n_exp, n - 1)
    kind, _, val = w.partition(":")
    if kind == "t":
        try:
            T = float(val)
        except ValueError:
            raise InputError("window", f"expected t:T with T a number of t* units, got {window!r}")
        K = int(np.searchsorted(obs.t_star, T + 1e-9, side="right") - 1)
        if K < 2:
            raise InputError("window", f"t* <= {T} holds fewer than two samples")
        return np.full(obs.n_exp, K)
    if kind == "collapse":
        try:
            k = int(val)
        except ValueError:
            raise InputError("window", f"expected collapse:k with k = 1, 2, ..., got {window!r}")
        if k < 1:
            raise InputError("window", f"collapse number must be >= 1, got {k}")
        out = np.empty(obs.n_exp, dtype=int)
        for e in range(obs.n_exp):
            idx = collapse_indices(obs.R_star[e], prominence)
            if idx.size < k:
                raise InputError(
                    "window", f"experiment {obs.names[e]!r} shows {idx.size} collapse(s) on the grid, fewer than {k}"
                )
            out[e] = idx[k - 1]
        return out
    raise InputError("window", f"expected all, t:T or collapse:k, got {window!r}")


def confidence_level(J_min: float, n: int, p: int, level: float = 0.95) -> float:
    """Cost level of the region J <= J_min (1 + p/(n-p) F_{p,n-p}(level)) (NaN if n <= p)."""
    if n <= p:
        return float("nan")
    from scipy import stats

    return float(J_min * (1.0 + p / (n - p) * stats.f.ppf(level, p, n - p)))


def grid_edge_warnings(side_G, side_mu, Gg, mg, label: str) -> list:
    """One line per parameter whose optimum lies on the grid's edge; ``side_*``: "low", "high" or
    None. An upper edge makes the estimate a bound (widen the grid); a lower edge (0) means the data
    push the parameter there -- the model may not describe them, or they do not constrain it."""
    out = []
    for side, val, name, unit, key in ((side_G, Gg, "G", "Pa", "G_max"), (side_mu, mg, "mu", "Pa s", "mu_max")):
        if side == "high":
            out.append(
                f"{label} optimum: {name} at the grid's upper end ({val[-1]:.4g} {unit}): the estimate is a "
                f"lower bound; widen the grid (--set {key}=...)"
            )
        elif side == "low":
            out.append(
                f"{label} optimum: {name} at the grid's lower end ({val[0]:.4g} {unit}): the data push it "
                f"there -- the model (or its bubble physics) may not describe them, or they do not "
                f"constrain {name}"
            )
    return out


def _edge_side(k: int, n: int):
    return "low" if k == 0 else "high" if k == n - 1 else None


def _edge_warnings(i, j, s, Gg, mg, per_index, names) -> list:
    """Standard IMR's grid-edge warnings: the pooled optimum's (:func:`grid_edge_warnings`) and the
    count of experiments whose own optimum lies on the edge."""
    out = grid_edge_warnings(_edge_side(i, s.n_G), _edge_side(j, s.n_mu), Gg, mg, "standard IMR")
    on_edge = [nm for (ie, je), nm in zip(per_index, names) if _edge_side(ie, s.n_G) or _edge_side(je, s.n_mu)]
    if on_edge:
        shown = ", ".join(on_edge[:5]) + (", ..." if len(on_edge) > 5 else "")
        out.append(f"{len(on_edge)} of {len(names)} experiments have their own optimum on the grid's edge ({shown})")
    return out


def _quadratic_refine(J, Gg, mg, i, j):
    """Sub-grid minimum of a quadratic fitted to the 3 x 3 neighbourhood (None if not convex/interior)."""
    if not (0 < i < J.shape[0] - 1 and 0 < j < J.shape[1] - 1):
        return None
    sub = J[i - 1 : i + 2, j - 1 : j + 2]
    if not np.all(np.isfinite(sub)):
        return None
    dG, dm = Gg[1] - Gg[0], mg[1] - mg[0]
    u, v = np.meshgrid([-1.0, 0.0, 1.0], [-1.0, 0.0, 1.0], indexing="ij")
    X = np.column_stack([np.ones(9), u.ravel(), v.ravel(), u.ravel() ** 2, u.ravel() * v.ravel(), v.ravel() ** 2])
    c, *_ = np.linalg.lstsq(X, sub.ravel(), rcond=None)
    Hq = np.array([[2 * c[3], c[4]], [c[4], 2 * c[5]]])
    if np.any(np.linalg.eigvalsh(Hq) <= 0):
        return None
    d = -np.linalg.solve(Hq, c[1:3])
    if np.any(np.abs(d) > 1.0):
        return None
    scale = np.array([dG, dm])
    Hsi = Hq / np.outer(scale, scale)
    return np.array([Gg[i] + d[0] * dG, mg[j] + d[1] * dm]), float(c[0] + 0.5 * c[1:3] @ d), Hsi


def _grid_summary(J, Jmin, n, p, Gg, mg, opt):
    lp = -0.5 * (n - p) * J / Jmin if (n > p and Jmin > 0) else np.where(J <= np.nanmin(J), 0.0, -np.inf)
    lp = np.where(np.isfinite(lp), lp, -np.inf)
    w = np.exp(lp - lp.max())
    w /= w.sum()
    out = {}
    for ax, (name, grid) in enumerate((("G", Gg), ("mu", mg))):
        marg = w.sum(axis=1 - ax)
        mean = float(np.sum(marg * grid))
        sd = float(np.sqrt(np.sum(marg * (grid - mean) ** 2)))
        order = np.argsort(marg)[::-1]
        k = int(np.searchsorted(np.cumsum(marg[order]), 0.95)) + 1
        sel = grid[order[:k]]
        h = 0.5 * (grid[1] - grid[0])
        out[name] = {
            "mean": float(opt[ax]),
            "sd": sd,
            "hdi95": [float(max(grid[0], sel.min() - h)), float(min(grid[-1], sel.max() + h))],
            "posterior_mean": mean,
        }
    return out, w


def imr_unit(unit: Unit, rng) -> dict:
    """One experiment on the whole (G, mu) grid: cost J_n per grid point (inf where it failed)."""
    d = unit.data
    runner = runner_for(d)
    before = (runner.n_member_runs, runner.n_failed)
    theta = d["theta"]
    n_pts = theta.shape[0]
    K = int(d["K"])
    out = runner.simulate(theta, np.full(n_pts, d["rmax"]), np.full(n_pts, d["req"]), d["t_eval"])
    r = out.R_star[:, 1 : K + 1] - d["y"][1 : K + 1]
    j = np.sum(d["cw"][1 : K + 1] * r * r, axis=1)
    bad = out.failed | ~np.isfinite(j)
    return {"J": np.where(bad, np.inf, j), "n_failed": int(bad.sum()), **runner.counts_since(before)}


def _grid_theta(Gg, mg, names, defaults) -> np.ndarray:
    """Parameter vectors of every grid point, (n_G * n_mu, n_params), G-major; parameters other than G
    and mu at their model defaults."""
    GG, MM = np.meshgrid(Gg, mg, indexing="ij")
    theta = np.empty((GG.size, len(names)))
    for i, nm in enumerate(names):
        theta[:, i] = GG.ravel() if nm == "G" else (MM.ravel() if nm == "mu" else defaults[nm])
    return theta


def _collect_costs(rep, obs, n_pts, progress):
    """Per-experiment grid costs from the units' report.

    Returns ``(Jn (n_exp, n_pts) NaN for failed experiments, failed grid runs, member runs,
    warnings, failed_units)``; ``progress(n)`` is called after each experiment that ran.
    """
    Jn = np.full((obs.n_exp, n_pts), np.nan)
    n_failed, member_runs, warnings, failed_units = 0, 0, [], []
    for e in range(obs.n_exp):
        uid = unit_id(exp=e)
        if uid not in rep.results:
            err = rep.failures[uid].error
            failed_units.append({"unit": uid, "experiment": obs.names[e], "error": err})
            warnings.append(f"experiment {obs.names[e]!r} failed ({err}); left out of the cost")
            continue
        r = rep.results[uid]
        Jn[e] = r["J"]
        n_failed += int(r["n_failed"])
        member_runs += int(r["member_runs"])
        if progress is not None:
            progress(e + 1)
    return Jn, n_failed, member_runs, warnings, failed_units


def _per_experiment(obs, Jn, ok, failed_units, mask, Gg, mg, Kn, refine: bool) -> list:
    """Each experiment's own optimum on the grid (Jn (n_exp, n_G, n_mu)) as a list of dicts; a failed
    experiment gets its error and its row of ``mask`` (n_exp, n_samples) is cleared in place."""
    per = []
    for e in range(obs.n_exp):
        if e not in ok:
            per.append(
                {
                    "name": obs.names[e],
                    "failed": True,
                    "error": next(f["error"] for f in failed_units if f["experiment"] == obs.names[e]),
                }
            )
            mask[e] = False
            continue
        ie, je = np.unravel_index(np.argmin(Jn[e]), Jn[e].shape)
        r_e = _quadratic_refine(Jn[e], Gg, mg, ie, je) if refine else None
        o = r_e[0] if r_e is not None else np.array([Gg[ie], mg[je]])
        per.append(
            {
                "name": obs.names[e],
                "optimum": {"G": float(o[0]), "mu": float(o[1])},
                "grid_optimum": {"G": float(Gg[ie]), "mu": float(mg[je])},
                "J_min": float(Jn[e, ie, je]),
                "last_sample": int(Kn[e]),
                "t_end_star": float(obs.t_star[Kn[e]]),
            }
        )
    return per


def _uncertainty_and_draws(est, laplace, pmf, refined, Gg, mg, n_draws: int, rng, warnings):
    """Posterior sd, interval and draws of (G, mu): the Laplace quadratic where the pseudo-posterior is
    narrower than a grid cell, else the grid's pmf (n_G, n_mu) with uniform jitter inside a cell.

    ``est`` and ``warnings`` are updated in place. Returns ``(G draws (n_draws,), mu draws (n_draws,),
    whether the Laplace approximation was used)``.
    """
    spacing = np.array([Gg[1] - Gg[0], mg[1] - mg[0]])
    resolved = all(est[nm]["sd"] >= spacing[a] for a, nm in enumerate(("G", "mu")))
    use_laplace = laplace is not None and not resolved
    if use_laplace:
        # the pseudo-posterior is narrower than a grid cell: use the local quadratic (Laplace)
        sd = laplace["sd"]
        for a, nm in enumerate(("G", "mu")):
            est[nm]["sd_grid"], est[nm]["hdi95_grid"] = est[nm]["sd"], est[nm]["hdi95"]
            est[nm]["sd"] = float(sd[a])
            est[nm]["hdi95"] = [float(refined[a] - 1.959964 * sd[a]), float(refined[a] + 1.959964 * sd[a])]
        dr = rng.multivariate_normal(refined, np.array(laplace["cov"]), size=n_draws)
        dG_draw, dm_draw = dr[:, 0], dr[:, 1]
    else:
        if not resolved:
            # narrower than a cell and no quadratic to refine it (the optimum next to the grid's edge):
            # the grid cannot say more than "inside this cell", so no sd below a uniform cell's
            thin = []
            for a, nm in enumerate(("G", "mu")):
                if est[nm]["sd"] < spacing[a] / np.sqrt(12.0):
                    est[nm]["sd_grid"], est[nm]["sd"] = est[nm]["sd"], float(spacing[a] / np.sqrt(12.0))
                    thin.append(nm)

            if thin:
                warnings.append(
                    f"standard IMR: the pseudo-posterior of {' and '.join(thin)} lies inside one grid cell "
                    f"and the optimum could not be refined (no local quadratic): its sd is the cell's "
                    f"(spacing/sqrt 12); a finer grid (--set n_G=/n_mu= or the bounds) resolves it"
                )
        idx = rng.choice(pmf.size, size=n_draws, p=pmf.ravel())
        ii, jj = np.unravel_index(idx, pmf.shape)
        dG_draw = np.clip(Gg[ii] + (rng.random(n_draws) - 0.5) * spacing[0], Gg[0], Gg[-1])
        dm_draw = np.clip(mg[jj] + (rng.random(n_draws) - 0.5) * spacing[1], mg[0], mg[-1])
    return dG_draw, dm_draw, use_laplace


def _experiment_units(obs, spec, token, theta, t_eval, Kn, cw) -> list:
    """One :class:`Unit` per experiment: the whole grid ``theta`` (n_pts, n_params) scored on samples
    1..Kn[e] with weights ``cw`` (n_samples,)."""
    return [
        Unit(
            unit_id(exp=e),
            {
                "spec": spec,
                "runner": token,
                "theta": theta,
                "rmax": float(obs.rmax_m[e]),
                "req": float(obs.req_m[e]),
                "t_eval": t_eval,
                "K": int(Kn[e]),
                "y": obs.R_star[e],
                "cw": cw,
            },
        )
        for e in range(obs.n_exp)
    ]


def _fitted_curves(runner, obs, theta_opt, names, refined, mask) -> np.ndarray:
    """Fitted R* (n_exp, n_samples) at the refined optimum (G, mu) with the other parameters of
    ``theta_opt`` (n_params,); NaN outside ``mask`` except the first sample."""
    th = np.tile(theta_opt, (obs.n_exp, 1))
    th[:, names.index("G")] = refined[0]
    th[:, names.index("mu")] = refined[1]
    fo = runner.simulate(th, obs.rmax_m, obs.req_m, obs.t_star)
    fitted = np.where(mask, fo.R_star, np.nan)
    fitted[:, 0] = fo.R_star[:, 0]
    return fitted


def fit_imr(
    fm,
    obs,
    space,
    settings: IMRSettings | None = None,
    seed: int = 0,
    runner: Runner | None = None,
    progress=None,
    execution=None,
) -> FitResult:
    """Grid search of (G, mu); see module doc. ``progress(n)`` is called after experiment n.

    Units (:func:`imr_unit`): one per experiment (``exp=003``: its cost on the whole grid);
    ``execution`` (:class:`~imrbayes.execution.Execution`) says where they run and are checkpointed
    (default: this process, with ``runner``). An experiment whose unit fails is left out of the cost
    (counted, reported in ``details["failed_units"]`` and the warnings)."""
    s = settings or IMRSettings()
    s.check()
    t0 = time.perf_counter()
    names = tuple(space.names)
    if "G" not in names or "mu" not in names:
        raise InputError("--method imr", f"the IMR grid is over G and mu; model parameters are {list(names)}")
    ex = execution or Execution(progress=False)
    runner = runner or Runner(fm)
    spec, token = fm_spec(fm), register_runner(runner)
    Kn = fit_indices(obs, s.window, s.collapse_prominence)
    Kmax = int(Kn.max())
    t_eval = obs.t_star[: Kmax + 1]
    Gg = grid_axis(s.G_min, s.G_max, s.n_G, s.spacing)
    mg = grid_axis(s.mu_min, s.mu_max, s.n_mu, s.spacing)
    defaults = fm.constitutive.defaults
    theta = _grid_theta(Gg, mg, names, defaults)
    n_pts = theta.shape[0]
    mask = np.zeros((obs.n_exp, obs.n_samples), dtype=bool)
    for e, K in enumerate(Kn):
        mask[e, 1 : K + 1] = True
    cw = np.ones(obs.n_samples) if s.weighting == "none" else 1.0 / obs.P
    units = _experiment_units(obs, spec, token, theta, t_eval, Kn, cw)
    rep = ex.run(units, imr_unit, seed, desc="imr experiments")
    Jn, n_failed, member_runs, warnings, failed_units = _collect_costs(rep, obs, n_pts, progress)
    ok = [e for e in range(obs.n_exp) if unit_id(exp=e) in rep.results]
    if not ok:
        raise RuntimeError(f"every experiment failed (e.g. {failed_units[0]['error']})")
    Jn = Jn.reshape(obs.n_exp, s.n_G, s.n_mu)
    J = Jn[ok].mean(axis=0)
    if not np.any(np.isfinite(J)):
        raise RuntimeError("every grid point failed in the forward model")
    i, j = np.unravel_index(np.argmin(J), J.shape)
    opt = np.array([Gg[i], mg[j]])
    Jmin = float(J[i, j])
    ref = _quadratic_refine(J, Gg, mg, i, j) if s.refine else None
    refined = ref[0] if ref is not None else opt
    n_res, p = int(Kn[ok].sum()), 2
    level_J = confidence_level(Jmin, n_res, p, s.level)
    est, pmf = _grid_summary(J, Jmin, n_res, p, Gg, mg, refined)
    laplace = None
    if ref is not None and n_res > p and Jmin > 0:
        # -log p = (n - p) J / (2 Jmin)  ->  precision = (n - p) Hess(J) / (2 Jmin)
        cov = np.linalg.inv((n_res - p) * ref[2] / (2.0 * Jmin))
        laplace = {"cov": cov.tolist(), "sd": np.sqrt(np.diag(cov)).tolist()}
    per = _per_experiment(obs, Jn, ok, failed_units, mask, Gg, mg, Kn, s.refine)
    warnings += _edge_warnings(
        i, j, s, Gg, mg, [np.unravel_index(np.argmin(Jn[e]), Jn[e].shape) for e in ok], [obs.names[e] for e in ok]
    )
    fitted = _fitted_curves(runner, obs, theta[i * s.n_mu + j], names, refined, mask)
    spacing = np.array([Gg[1] - Gg[0], mg[1] - mg[0]])
    dG_draw, dm_draw, use_laplace = _uncertainty_and_draws(
        est, laplace, pmf, refined, Gg, mg, s.n_draws, np.random.default_rng(seed), warnings
    )
    dG, dm = spacing
    details = {
        "nuisances": "Rmax, Req and the time of the maximum fixed at preprocessing's estimates (not "
        "propagated); en4dvar's default likelihood includes them",
        "settings": asdict(s),
        "grid": {
            "G": [float(Gg[0]), float(Gg[-1]), s.n_G, float(dG)],
            "mu": [float(mg[0]), float(mg[-1]), s.n_mu, float(dm)],
        },
        "grid_optimum": {"G": float(opt[0]), "mu": float(opt[1])},
        "optimum": {"G": float(refined[0]), "mu": float(refined[1])},
        "refined": ref is not None,
        "J_min": Jmin,
        "confidence": {
            "level": s.level,
            "J_level": level_J,
            "n_residuals": n_res,
            "p": p,
            "rule": "J <= J_min (1 + p/(n-p) F_{p,n-p}(level)) (Beale; residuals "
            "treated as independent, so optimistic)",
        },
        "laplace": laplace,
        "uncertainty_from": "laplace" if use_laplace else "grid",
        "n_grid_points": n_pts,
        "member_runs": member_runs + obs.n_exp,
        "failed_units": failed_units,
        "experiments_used": [obs.names[e] for e in ok],
        "failed_grid_runs": n_failed,
        "window": s.window,
        "fixed_parameters": {nm: defaults[nm] for nm in names if nm not in ("G", "mu")},
        "last_sample": Kn.tolist(),
        "rmse": rmse(fitted, obs.R_star, mask),
    }
    return FitResult(
        method="imr",
        model=fm.constitutive.name,
        param_names=("G", "mu"),
        estimate=est,
        fitted=fitted,
        fit_mask=mask,
        per_experiment=per,
        details=details,
        posterior={"G": dG_draw[None], "mu": dm_draw[None]},
        extra_groups={"landscape": {"J": J, "J_experiment": Jn}},
        extra_dims={"J": ["G_grid", "mu_grid"], "J_experiment": ["experiment", "G_grid", "mu_grid"]},
        coords={"G_grid": Gg, "mu_grid": mg, "experiment": list(obs.names)},
        runtime_s=time.perf_counter() - t0,
        warnings=warnings,
    )


class IMR(InferenceMethod):
    """Standard IMR as a plug-in (:class:`~imrbayes.ensemble.method.InferenceMethod`)."""

    name = "imr"
    label = "standard IMR (grid least squares)"
    settings_class = IMRSettings
    fit = staticmethod(fit_imr)

    @staticmethod
    def check_settings(settings, obs):
        settings.check()
        fit_indices(obs, settings.window, settings.collapse_prominence)

    @staticmethod
    def n_units(settings, n_exp, n_steps, fm=None):
        return n_exp, f"grid over {n_exp} experiments"

    @staticmethod
    def n_forward_runs(settings, n_exp, n_steps):
        return settings.n_G * settings.n_mu * n_exp + n_exp  # the grid, then the fitted curves

    @staticmethod
    def figures(obs, res, fdir):
        from imrbayes.ensemble.figures import landscape_figure

        return [landscape_figure(res, fdir / "landscape.png")]
