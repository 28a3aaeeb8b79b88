"""Calibrated constant-parameter check (parametric bootstrap).

Statistics of one dataset under the baseline (constant-parameter NHKV):

* ``drift``: the largest squared Mahalanobis distance between the (log G, log mu) estimates of
  fits to the 1st collapse, to the 2nd collapse and to the whole record (covariances of the two
  Laplace posteriors added);
* ``misfit``: the normalised chi-square (mean of r^2/P_k) of the whole-record fit;
* ``phase_misfit``: the largest normalised chi-square of one phase of that fit;
* ``mienks_drift`` (when MIEnKS settings are given): the drift of the MIEnKS-MDA window estimates
  G(t), mu(t): weighted least-squares slopes of the fused window means of log G and log mu against
  the window centre t*, each divided by its standard error (window variances as weights), squared
  and summed. The windows overlap and are chained, so these standard errors are not the slopes'
  true ones (and the chain's walk from the prior is a drift of its own): the bootstrap, which runs
  the same smoother on constant-parameter replicates, is what makes the number comparable.

The fits are those of ``fit``'s default likelihood (:mod:`imrbayes.diagnosis.lsq`: the record's
own noise, tempering by the residuals' n_eff / K, each experiment's Rmax, Req and time of the
maximum fitted as nuisances); ``misfit`` and ``phase_misfit`` divide by each record's own noise
variance. None of the statistics has a known null distribution (residuals are correlated in time,
the noise is estimated), so each is calibrated by a parametric bootstrap: B synthetic datasets of
the same design generated from the baseline fit (each experiment at its fitted geometry and
alignment; white noise of the record's sd *at the camera frames*, interpolated onto the grid as
the data were -- or at the samples when the data are point values), processed exactly as the data
(the nuisances start from the preprocessing values again, noise and tempering re-estimated, the
same fits). Each statistic's p-value is (1 + #{T_b >= T}) / (B + 1). They are combined by the
nonparametric combination of dependent tests (Pesarin & Salmaso 2010, Fisher's combining function):
the data and the B replicates form one exchangeable pool; in it every member gets its own p-value
per statistic (its rank among the B + 1), the combined statistic C = -sum log p, and the combined
p-value is #{members with C >= the data's C} / (B + 1). Under the null this is exactly a rank test
at any B. (A first version calibrated the smallest p-value against leave-one-out p-values of the
replicates, whose denominator B made the data's p = 1/(B+1) beat every replicate's 1/B: the data
extreme on *any one* statistic was then rejected, ~3 alpha with three statistics -- 4 false
alarms in 20 camera-style nulls, measured. With the pool the same 20 nulls give none, and the
mechanisms' detections are kept: docs/methods.md.)

The replicates run in batches (:func:`bootstrap_check`; default after 5, after 10, then all 19):
after each, the check stops ``adequate`` when replicates at or above the data on every statistic
already keep the p-value above alpha (:func:`adequate_already`, exact), and ``inadequate`` when the
data lie above every replicate and at least :func:`decisive_z` of their sd (40 after 5, 20 after 10)
above their mean on a chi-square-like statistic (:func:`inadequate_already`; the reported p-value is
then Cantelli's distribution-free bound, S / (1 + z^2), not a rank). That stop adds at most the
bound (0.25 % per statistic at the replicates' true moments) to the test's size.
"""

from __future__ import annotations

import numpy as np

from imrbayes.data.noise import noise_variance
from imrbayes.diagnosis.lsq import ObsModel, fit_map, fit_tempered, frame_values
from imrbayes.ensemble import Observations

__all__ = [
    "statistics",
    "bootstrap_check",
    "window_drift",
    "mienks_drift",
    "combined_p_value",
    "adequate_already",
    "inadequate_already",
    "p_value_text",
    "min_replicates",
]

STATS = ("drift", "misfit", "phase_misfit")
#: replicate counts after which the sequential check looks at its verdict before running the rest
LOOKS = (5, 10)
#: statistics that may decide "inadequate" after the first batch: means of squared residuals over
#: hundreds of samples, whose replicates are tight and light-tailed (the drift statistics are not:
#: a Mahalanobis distance between window fits has a heavy right tail)
DECIDE_STATS = ("misfit", "phase_misfit")
#: distance of the data beyond the first batch's mean, in the batch's sd, that decides "inadequate".
#: Cantelli's one-sided inequality bounds a replicate's chance to lie that far out by 1/(1 + Z^2) =
#: 0.25 % whatever the distribution (at the true moments); 20 leaves room for ten replicates'
#: sample sd (below half the true sd with probability ~1 % for chi-square-like statistics).
#: Thermal fits of real records lie 400-32 000 sd out (docs/methods.md, Runtime).
Z_DECIDED = 20.0
#: the same after only 5 replicates: their sd (4 degrees of freedom) is below a quarter of the true
#: sd with probability ~0.75 % (chi-square-like statistics), as 10 replicates' is below half with
#: ~1.3 %, so both thresholds leave the data >= 10 true sd out (Cantelli: <= 1 %) at like odds.
#: Every stored thermal row decided this early was decided inadequate after 10 as well, and the 20
#: nulls lie <= 3.2 sd out after 5 (docs/methods.md, Runtime).
Z_DECIDED_FIRST = 40.0


def decisive_z(n: int) -> float:
    """The distance (in replicate sd) that decides ``inadequate`` after ``n`` replicates: 40 below
    10 replicates, :data:`Z_DECIDED` from 10 on (:func:`inadequate_already` needs at least 5)."""
    return Z_DECIDED if n >= 10 else Z_DECIDED_FIRST


def mienks_drift(base, obs, settings, seed: int = 0) -> tuple:
    """MIEnKS-MDA of the baseline over the whole record; returns (statistic, details) with the
    slopes of log G and log mu per unit t* and their standard errors (see module doc)."""
    from imrbayes.ensemble import ParamSpace
    from imrbayes.ensemble.mienks import fit_mienks

    sp = ParamSpace.for_model(base.fm.constitutive)
    with np.errstate(all="ignore"):
        r = fit_mienks(base.fm, obs, sp, settings, seed=seed)
    m = np.array([w["mean_internal"] for w in r.windows])[:, :2]
    v = np.array([np.diag(w["cov_internal"]) for w in r.windows])[:, :2]
    tc = np.array([0.5 * (w["t_star"][0] + w["t_star"][1]) for w in r.windows])
    slope, se = np.zeros(2), np.zeros(2)
    for i in range(2):
        w = 1.0 / np.maximum(v[:, i], 1e-12)
        tb = np.sum(w * tc) / w.sum()
        sxx = np.sum(w * (tc - tb) ** 2)
        slope[i] = np.sum(w * (tc - tb) * (m[:, i] - np.sum(w * m[:, i]) / w.sum())) / sxx
        se[i] = 1.0 / np.sqrt(sxx)
    T = float(np.sum((slope / se) ** 2))
    return T, {
        "slope_log_G": float(slope[0]),
        "slope_log_mu": float(slope[1]),
        "se_log_G": float(se[0]),
        "se_log_mu": float(se[1]),
        "t_star_windows": tc.tolist(),
        "G_windows": np.exp(m[:, 0]).tolist(),
        "mu_windows": np.exp(m[:, 1]).tolist(),
    }


def window_drift(cand, obs, phases, full, om=None) -> tuple:
    """Largest squared Mahalanobis distance between the (log G, log mu) of the whole-record fit
    ``full`` and fits of ``cand`` to the 1st and 2nd collapse (observation model ``om``); returns
    (drift, fits)."""
    K1, K2 = phases.collapse_index(1), phases.collapse_index(2)
    fits = {"all": full}
    for name, K in (("collapse-1", K1), ("collapse-2", K2)):
        fits[name] = fit_map(cand, obs, K=K, minima=phases.minima, om=om, starts=[full.z], nu0=full.nu)
    keys = list(fits)
    drift = 0.0
    for i in range(len(keys)):
        for j in range(i + 1, len(keys)):
            a, b = fits[keys[i]], fits[keys[j]]
            dz = a.z[:2] - b.z[:2]
            C = a.cov[:2, :2] + b.cov[:2, :2]
            try:
                drift = max(drift, float(dz @ np.linalg.solve(C, dz)))
            except np.linalg.LinAlgError:
                pass
    return drift, fits


def statistics(base, obs, phases, starts=None, mienks=None, seed: int = 0, nuisances: bool = True, nu0=None) -> dict:
    """Window fits and the statistics of ``obs`` under the baseline candidate ``base`` (with
    ``mienks``, an :class:`~imrbayes.ensemble.mienks.MIEnKSSettings`, also ``mienks_drift``, or,
    when it cannot be computed, ``mienks_error``: the one-line error). The whole-record fit is made
    twice: on the record's noise, then on the likelihood tempered at that fit (``om`` in the output,
    the observation model every later fit of this dataset uses).
    ``nu0`` (E, q): the nuisances' start (a replicate: its truth); without it the whole-record fit
    also searches the nuisances' other basins (:func:`lsq.nuisance_restarts`)."""
    om0 = ObsModel.of(obs, nuisances=nuisances)
    full, om = fit_tempered(base, obs, phases.minima, om0, starts=starts, nu0=nu0)
    drift, fits = window_drift(base, obs, phases, full, om)
    r2 = (obs.R_star[:, 1:] - full.fitted[:, 1:]) ** 2 / om.noise_sd[:, None] ** 2
    per_phase = []
    for m in phases.masks():
        mm = m[1:]
        per_phase.append(float(np.nanmean(r2[:, mm])) if mm.any() else float("nan"))
    out = {
        "fits": fits,
        "om": om,
        "drift": drift,
        "misfit": float(np.nanmean(r2)),
        "phase_misfit": float(np.nanmax(per_phase)),
        "phase_chi2": per_phase,
    }
    if mienks is not None:
        try:
            T, det = mienks_drift(base, obs, mienks, seed=seed)
        except (RuntimeError, ValueError, np.linalg.LinAlgError) as exc:  # e.g. the smoother lost its members
            msg = str(exc).splitlines()
            out["mienks_error"] = f"{type(exc).__name__}: {msg[0]}" if msg else type(exc).__name__
        else:
            if np.isfinite(T):
                out["mienks_drift"], out["mienks"] = T, det
            else:
                out["mienks_error"] = f"the statistic is not finite ({T})"
    return out


def replicate(obs, Rf, sd, rng):
    """A synthetic dataset of ``obs``'s design from the curves ``Rf`` (per experiment, R* at its
    camera frames -- or at the grid's samples for point-value data -- :func:`lsq.frame_values`):
    white noise of sd ``sd[e]`` added to every frame after the maximum, the frames interpolated onto
    the grid as the data were (the first, the maximum itself, is the normalisation's anchor: R* = 1
    without noise, as in the preprocessing); the replicate's record noise is the sd it was made
    with. (Re-estimating it from the frames the grid needs, as a first version did, inflates it at
    coarse frame rates -- the collapse's own fourth differences count as noise over a short stretch,
    while the data's estimate runs over the whole record with its quiet tail -- and made the data's
    chi-square look too large: false alarms on a 270 kfps design.)"""
    from imrbayes.ensemble.likelihood import frame_operator

    E, n = obs.n_exp, obs.n_samples
    t = np.asarray(obs.t_star, dtype=float)
    Y = np.empty((E, n))
    noise_sd = np.empty(E)
    for e in range(E):
        yf = np.asarray(Rf[e], dtype=float) + sd[e] * rng.standard_normal(len(Rf[e]))
        noise_sd[e] = sd[e]
        if obs.frame_t is None:
            Y[e] = yf
            continue
        if obs.frame_t[e][0] == 0.0:
            yf[0] = 1.0
        _, ia, w = frame_operator(obs.frame_t[e], t)
        Y[e] = (1.0 - w) * yf[ia] + w * yf[ia + 1]
    Y = np.maximum(Y, 1e-3)
    Y[:, 0] = obs.R_star[:, 0]
    P, _ = noise_variance(t, Y) if E >= 2 else (obs.P, None)
    return Observations(
        t,
        Y,
        P,
        obs.rmax_m,
        obs.req_m,
        obs.t_collapse_star,
        list(obs.names),
        noise_sd=noise_sd,
        nuisance_sd=obs.nuisance_sd,
        t0_s=obs.t0_s,
        tc_s=obs.tc_s,
        frame_t=obs.frame_t,
    )


def bootstrap_unit(unit, rng) -> dict:
    """Unit ``bootstrap=007``: one replicate -- a synthetic dataset of the data's design from the
    baseline fit's curves ``R0`` with the records' noise ``sd`` (:func:`replicate`, from the unit's own
    ``rng``), processed as the data; returns its statistics. The baseline candidate is rebuilt from (options, physics, prior)."""
    from imrbayes.diagnosis.candidates import BASELINE
    from imrbayes.diagnosis.models import make_candidate

    d = unit.data
    obs = d["obs"]
    base = make_candidate(BASELINE.key, d["options"], d["physics"], d["prior"])
    ob = replicate(obs, d["R0"], d["sd"], rng)
    # a replicate's fits start from its truth (z0, nu0): in the basin it was made in
    st = statistics(
        base,
        ob,
        d["phases"],
        starts=[d["z0"]],
        mienks=d["mienks"],
        seed=int(d["seed"]),
        nuisances=d.get("nuisances", True),
        nu0=d.get("nu0"),
    )
    return {k: float(st.get(k, float("nan"))) for k in d["stats"]}


def combined_p_value(observed, boot) -> tuple:
    """Nonparametric (Fisher) combination of the statistics ``observed`` (S,) against the replicates
    ``boot`` (S, B) (module doc); returns (combined p, the data's p per statistic (S,)). A replicate
    without a statistic (NaN) counts against rejection: its value is taken as +inf."""
    X = np.column_stack([np.asarray(observed, dtype=float), np.asarray(boot, dtype=float).reshape(len(observed), -1)])
    X = np.where(np.isfinite(X), X, np.inf)
    n = X.shape[1]
    # p of every pool member on every statistic: the share of the pool at or above it (itself included)
    P = (X[:, None, :] >= X[:, :, None]).sum(axis=2) / n  # (S, n)
    C = -np.log(P).sum(axis=0)
    # members with the same ranks in another order tie mathematically; a tolerance keeps the sums'
    # rounding from breaking such ties in the data's favour (measured: 6 % rejections instead of 5)
    return float(np.sum(C >= C[0] - 1e-9 * max(1.0, abs(C[0]))) / n), P[:, 0]


def min_replicates(alpha: float) -> int:
    """The fewest replicates with which the rank test can reject at ``alpha``: its smallest p-value
    is 1 / (B + 1) (19 at 5 %)."""
    return int(np.ceil(1.0 / alpha - 1.0 - 1e-9))


def adequate_already(n_dominating: int, B: int, alpha: float) -> bool:
    """Whether the check is decided ``adequate`` before all B replicates are in: ``n_dominating``
    replicates at or above the data on *every* statistic have, in any final pool, a combined
    statistic at or above the data's, so the combined p-value is at least (1 + n_dominating) / (B + 1);
    decided when that bound exceeds ``alpha``."""
    return (1.0 + int(n_dominating)) / (B + 1.0) > alpha


def inadequate_already(observed: dict, boot: dict, stats, alpha: float, z_decided: float | None = None) -> tuple:
    """Whether the check is decided ``inadequate`` from the first replicates alone: the data lie
    beyond every one of them and at least ``z_decided`` (default :func:`decisive_z` of their number)
    of their sd above their mean on one of
    :data:`DECIDE_STATS` (``observed``: statistic -> value; ``boot``: statistic -> replicate values).
    Returns (decided, p_bound, z per statistic). ``p_bound`` = S / (1 + z^2) (Cantelli's bound at
    the replicates' moments, Bonferroni over the S statistics of the check) is what such a datum's
    p-value can at most be; a missing replicate (NaN) decides nothing, as in the rank test."""
    zs, bound = {}, 1.0
    for k in (k for k in DECIDE_STATS if k in stats):
        b = np.asarray(boot[k], dtype=float)
        z_min = decisive_z(b.size) if z_decided is None else z_decided
        obs_k = float(observed[k])
        if b.size < 5 or not np.all(np.isfinite(b)) or not np.isfinite(obs_k):
            continue
        sd = float(np.std(b, ddof=1))
        if not sd > 0.0:
            continue
        z = (obs_k - float(np.mean(b))) / sd
        zs[k] = z
        if obs_k > b.max() and z >= z_min:
            bound = min(bound, len(stats) / (1.0 + z * z))
    return bool(bound <= alpha), float(bound), zs


def p_value_text(ev: dict) -> str:
    """The check's p-value as a reader should see it (``ev``: the check's ``evidence``): ``p = 0.050``
    from the rank test, ``p <= 6.1e-09 (Cantelli bound, 10 replicates)`` when decided early."""
    p = ev.get("p_value")
    try:
        p = float(p)
    except (TypeError, ValueError):
        return "p = –"
    if ev.get("p_value_kind") == "bound":
        return f"p ≤ {p:.2g} (Cantelli bound, {ev.get('n_bootstrap', '?')} replicates)"
    return f"p = {p:.3f}"


def bootstrap_check(
    base,
    obs,
    phases,
    observed: dict,
    B: int = 19,
    seed: int = 0,
    alpha: float = 0.05,
    progress=None,
    mienks=None,
    execution=None,
    build: dict | None = None,
) -> dict:
    """Verdict ``adequate``/``inadequate`` with the evidence (see module doc); ``mienks``: the
    MIEnKS settings the observed ``mienks_drift`` was computed with (None: not used).

    The B replicates are units of the execution layer (``bootstrap=007``, each with its own random
    stream from (seed, id)): parallel with ``--workers``, checkpointed, resumed. ``build`` =
    {options, physics, prior} rebuilds ``base`` in a unit (default: ``base``'s own). A replicate
    whose unit fails counts against rejection (its statistics are treated as +inf). Every replicate
    is fitted by the data's Levenberg-Marquardt fits, started at its truth; the verdict is looked
    at after each of :data:`LOOKS` replicates (module doc)."""
    import dataclasses

    from imrbayes.execution import Execution, Unit

    stats = STATS + (("mienks_drift",) if mienks is not None and "mienks_drift" in observed else ())
    full = observed["fits"]["all"]
    z0 = full.z
    R0 = frame_values(base, z0, obs, phases.minima, full.nu)  # at every experiment's fitted geometry, alignment
    sd = observed["om"].noise_sd
    build = build or {"options": base.fm.options, "physics": base.fm.physics, "prior": dict(base.space.prior_si)}
    common = {
        **build,
        "obs": obs,
        "phases": phases,
        "R0": R0,
        "sd": sd,
        "z0": z0,
        "nu0": full.nu,
        "stats": list(stats),
        "nuisances": bool(np.any(observed["om"].nu_sd > 0)),
        "mienks": mienks if "mienks_drift" in stats else None,
    }
    units = [Unit(f"bootstrap={b:03d}", {**common, "seed": seed + 1000 + b}) for b in range(B)]
    ex = execution or Execution(progress=False)
    if progress is not None and ex.bar is None:
        ex = dataclasses.replace(ex, progress=lambda done, total: progress(1))
    # sequential: batches (5, 10, then the rest) while the verdict is still open. A replicate at or
    # above the data on every statistic keeps the combined p-value at (1 + their number) / (B + 1) or
    # more whatever the rest give (adequate_already): with that bound above alpha the data are
    # adequate and the rest is not run.
    # Symmetrically, data far beyond every first replicate on a chi-square-like statistic cannot be
    # made adequate by the rest except at odds below Cantelli's bound (inadequate_already): the
    # real records lie hundreds of replicate sd out, and the other half of the check is not run.
    looks = [n for n in LOOKS if n < B]
    results, decided, done, p_bound, z_first = {}, None, 0, 1.0, {}
    for n in looks + [B]:
        rep = ex.run(units[done:n], bootstrap_unit, seed, desc="diagnose bootstrap")
        results.update(rep.results)
        done = n
        n_dom = sum(1 for r in results.values() if all(not (r.get(k, np.inf) < observed[k]) for k in stats))
        if n == B and looks:
            break
        first = units[:n]  # z_first_batch: at the last look (all B when there is none)
        first_boot = {k: [results.get(u.unit_id, {}).get(k, float("nan")) for u in first] for k in stats}
        bad, p_bound, z_first = inadequate_already(observed, first_boot, stats, alpha)
        if n < B:
            decided = "adequate" if adequate_already(n_dom, B, alpha) else "inadequate" if bad else None
            if decided is not None:
                B = n
                break
    boot = {k: [results.get(f"bootstrap={b:03d}", {}).get(k, float("nan")) for b in range(B)] for k in stats}
    p_comb, p_each = combined_p_value([observed[k] for k in stats], [boot[k] for k in stats])
    p = dict(zip(stats, map(float, p_each)))
    ev = {
        "n_bootstrap": B,
        "alpha": alpha,
        "p_value": p_bound if decided == "inadequate" else p_comb,
        "p_value_kind": "bound" if decided == "inadequate" else "rank",
        "p_value_rank": p_comb,
        "replicate_fits": "full",
        "sequential": {
            "first_batch": len(first),
            "looks": looks,
            "n_planned": len(units),
            "stopped_early": decided is not None,
            "decided": decided,
            "n_dominating": int(n_dom),
            "z_first_batch": {k: float(v) for k, v in z_first.items()} if decided != "adequate" else {},
            "rule": f"stop after the first {' or '.join(map(str, looks)) or len(units)} replicates when "
            "(1 + the number of them at or "
            "above the data on every statistic) / (B + 1) > alpha (the verdict cannot become "
            "inadequate), or when the data lie above all of them and >= "
            f"{' / '.join(f'{decisive_z(n):g}' for n in looks) or Z_DECIDED} of their sd above "
            f"their mean on {' or '.join(DECIDE_STATS)} "
            "(inadequate: p_value is then the bound S / (1 + z^2), Cantelli's inequality with "
            "Bonferroni over the S statistics; p_value_rank the rank test of the replicates run)",
        },
        "rule": f"inadequate when the combined p-value of ({', '.join(stats)}) is <= alpha: Fisher's "
        "nonparametric combination, the data ranked in the pool of data and replicates",
        "statistics": {},
    }
    for k in stats:
        q = np.quantile(boot[k], [0.05, 0.5, 0.95]).tolist()
        ev["statistics"][k] = {
            "observed": float(observed[k]),
            "bootstrap_q05_q50_q95": q,
            "p_value": p[k],
            "bootstrap": [float(v) for v in boot[k]],
        }
    ev["window_estimates"] = {}
    for name, f in observed["fits"].items():
        th = base.to_si(f.z)
        sd_ = np.sqrt(np.diag(f.cov))
        ev["window_estimates"][name] = {
            "t_star_end": float(obs.t_star[f.K]),
            **{n: {"median": float(th[i]), "sd_log": float(sd_[i])} for i, n in enumerate(base.names)},
        }
    ev["phase_chi2"] = observed["phase_chi2"]
    if "mienks" in observed:
        ev["mienks_windows"] = {
            **observed["mienks"],
            "settings": {"n_ens": mienks.n_ens, "n_iter": mienks.n_iter, "L": mienks.L, "h": mienks.h},
        }
    return {"verdict": "inadequate" if ev["p_value"] <= alpha else "adequate", "evidence": ev}
