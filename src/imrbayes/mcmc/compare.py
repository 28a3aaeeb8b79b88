"""Ensemble-Gaussian vs MCMC posterior of a window (``compare.json``, interfaces.md §3).

The ensemble methods report a Gaussian N(m_E, S_E) of the internal parameters z (log G, log mu);
MCMC gives draws from the window's target density (:mod:`imrbayes.mcmc.target`). Everything is
compared in z, where both methods work (so no log-normal moment conversion enters a metric).
N(m_M, S_M) is the Gaussian with the MCMC draws' mean and covariance.

Metrics
-------
* ``kl_gauss`` = KL(N_M || N_E), ``kl_gauss_reverse`` = KL(N_E || N_M), closed form
  ``1/2 [tr(S1^-1 S0) + (m1 - m0)^T S1^-1 (m1 - m0) - d + log det S1 - log det S0]`` [nats];
  ``kl_sym`` their mean. KL is invariant under affine maps, so whitening does not change it.
* ``w2``: 2-Wasserstein distance between the two Gaussians after whitening with the MCMC
  covariance (z -> L^-1 z, S_M = L L^T): in units of posterior standard deviations (a pure mean
  shift of a 1-D posterior by delta sd gives w2 = delta). ``w2_log``: the same in raw z.
  ``W2^2 = |m0 - m1|^2 + tr(S0 + S1 - 2 (S1^1/2 S0 S1^1/2)^1/2)``.
* ``kl_sample``: KL(p_MCMC || N_E) from the draws themselves. For a Gaussian q and the
  moment-matched Gaussian N_M of p, KL(p || q) = J(p) + KL(N_M || q) exactly, where the
  negentropy J(p) = H(N_M) - H(p) >= 0 measures non-Gaussianity alone. J is estimated from n
  near-independent MCMC draws (thinned to at most min(ESS_bulk, ``n_max``)) with the
  Kozachenko-Leonenko k-nearest-neighbour entropy estimator (k = 5) in whitened coordinates,
  bias-corrected by the median of the same estimator on Gaussian samples of size n (parametric
  bootstrap; with n = 1000 its noise sd is about 0.02 nats). ``kl_sample`` sees shape
  differences (skew, curvature) that the moment metrics cannot, in the same unit (nats) as the
  Gaussian KL, so one threshold serves both.
* ``sample_check``: the energy distance (Szekely & Rizzo; within-sample terms over distinct pairs)
  between thinned MCMC draws and draws of N(m_E, S_E), whitened with S_M, with a parametric
  bootstrap p-value (a two-sample test, reported; with many draws it rejects differences too small
  to matter, so it is not part of ``agree``), and the sample 1-Wasserstein distance of the same
  draws (optimal assignment; equals ``scipy.stats.wasserstein_distance_nd`` for equal-size samples)
  with its null median. The energy distance is weakly sensitive to shape: a banana with
  negentropy 1.1 nats scores below a 0.5-sd mean shift, which is why ``kl_sample`` decides.
* ``mardia``: multivariate skewness b1 and kurtosis b2 of the thinned MCMC draws with their
  asymptotic tests (n b1/6 ~ chi2 with d(d+1)(d+2)/6 dof; (b2 - d(d+2)) / sqrt(8 d (d+2)/n) ~ N(0, 1)).
* ArviZ diagnostics with ``round_to="none"``: R-hat, bulk/tail ESS, MCSE of mean and sd, one chain
  per independent emcee ensemble.
* ``quadrature`` (2-parameter windows, when the grid posterior is given or stored with the tree):
  the exact posterior's moments, marginal 95 % intervals and 95 % HDR
  (:mod:`imrbayes.mcmc.quadrature`), ``vs_mcmc`` (MCMC minus grid, in MCSE units; ``within_mc_error``)
  and ``vs_ensemble`` (the ensemble Gaussian against the grid's moments: KL, W2). Reported, not part
  of ``agree``; a converged MCMC that misses the grid beyond its Monte-Carlo error is noted.

Agreement rule (``agree``)
--------------------------
``agree`` is true when all of

1. ``kl_sym <= 0.1`` nats (for equal covariances: a mean shift of 0.45 posterior sd; for a 1-D
   scale mismatch: a standard-deviation ratio of about 1.3);
2. ``w2 <= 0.5`` posterior standard deviations;
3. ``kl_sample <= 0.1`` nats: the same tolerance for the whole MCMC distribution, shape
   included (a banana x2 = b (x1^2 - 1) + 0.5 e has negentropy 0.5 log(1 + 8 b^2): it fails for
   b >= 0.2).

``agree`` is ``None`` (JSON null: undecided) when the MCMC itself is not trustworthy: max R-hat >
1.01, min bulk or tail ESS < 400, or (when the sampler reports it) a chain shorter than 50 tau or
a run that hit its hard step cap before its convergence check passed (``cap_hit``). ``notes``
says which criterion failed. Mardia's statistics are reported (and noted when the MCMC posterior
is clearly non-Gaussian) but do not enter ``agree``: the sample check already measures whether a
non-Gaussian shape matters at the scale of the criteria above.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from scipy import optimize, stats
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist, pdist
from scipy.special import digamma, gammaln

__all__ = [
    "THRESHOLDS",
    "AGREE_RULE",
    "gaussian_kl",
    "gaussian_w2",
    "whitener",
    "energy_distance",
    "energy_shift_reference",
    "sample_w1",
    "knn_entropy",
    "negentropy",
    "mardia",
    "sample_check",
    "mcmc_summary",
    "compare_window",
    "compare_windows",
    "lognormal_moments",
    "quadrature_block",
]

#: Thresholds of the agreement rule (module docstring).
THRESHOLDS = {
    "kl_sym": 0.1,
    "w2": 0.5,
    "kl_sample": 0.1,
    "rhat": 1.01,
    "ess_bulk": 400.0,
    "ess_tail": 400.0,
    "tau_rule": 50.0,
}

AGREE_RULE = (
    "agree = kl_sym <= {kl_sym} nats and w2 <= {w2} (MCMC-whitened sd units) and kl_sample <= {kl_sample} "
    "nats (KL(MCMC || ensemble Gaussian) = Gaussian KL + bias-corrected kNN negentropy of the draws); "
    "null (undecided) when max R-hat > {rhat}, min bulk ESS < {ess_bulk:g}, min tail ESS < {ess_tail:g}, "
    "a chain is shorter than {tau_rule:g} tau, or the sampler stopped at its step cap unconverged"
)


def _sym(a):
    a = np.asarray(a, dtype=np.float64)
    return 0.5 * (a + a.T)


def _sqrtm_psd(S):
    lam, V = np.linalg.eigh(_sym(S))
    return (V * np.sqrt(np.clip(lam, 0.0, None))) @ V.T


def gaussian_kl(m0, S0, m1, S1) -> float:
    """KL(N(m0, S0) || N(m1, S1)) [nats]; S0, S1 symmetric positive definite (d, d)."""
    m0, m1 = np.atleast_1d(np.asarray(m0, float)), np.atleast_1d(np.asarray(m1, float))
    d = m0.size
    S0, S1 = _sym(np.reshape(S0, (d, d))), _sym(np.reshape(S1, (d, d)))
    L1 = np.linalg.cholesky(S1)
    L0 = np.linalg.cholesky(S0)
    A = np.linalg.solve(L1, L0)  # L1^-1 L0: tr(S1^-1 S0) = ||A||_F^2
    r = np.linalg.solve(L1, m1 - m0)
    logdet = 2.0 * (np.sum(np.log(np.diag(L1))) - np.sum(np.log(np.diag(L0))))
    return float(0.5 * (np.sum(A * A) + r @ r - d + logdet))


def gaussian_w2(m0, S0, m1, S1) -> float:
    """2-Wasserstein distance between N(m0, S0) and N(m1, S1) (closed form, PSD covariances)."""
    m0, m1 = np.atleast_1d(np.asarray(m0, float)), np.atleast_1d(np.asarray(m1, float))
    d = m0.size
    S0, S1 = _sym(np.reshape(S0, (d, d))), _sym(np.reshape(S1, (d, d)))
    r1 = _sqrtm_psd(S1)
    cross = _sqrtm_psd(r1 @ S0 @ r1)
    w2sq = float(np.sum((m0 - m1) ** 2) + np.trace(S0) + np.trace(S1) - 2.0 * np.trace(cross))
    return math.sqrt(max(w2sq, 0.0))


def whitener(S) -> np.ndarray:
    """W = L^-1 with S = L L^T: ``z -> W z`` maps N(., S) to unit covariance."""
    return np.linalg.inv(np.linalg.cholesky(_sym(S)))


def energy_distance(X, Y) -> float:
    """Energy distance ``2 E|X - Y| - E|X - X'| - E|Y - Y'|`` of two samples (n, d), (m, d), with the
    within-sample terms over distinct pairs (unbiased: mean ~0 when both come from one law)."""
    X, Y = np.atleast_2d(np.asarray(X, float)), np.atleast_2d(np.asarray(Y, float))
    return float(2.0 * cdist(X, Y).mean() - pdist(X).mean() - pdist(Y).mean())


@lru_cache(maxsize=64)
def energy_shift_reference(d: int, delta: float) -> float:
    """Population energy distance between N(0, I_d) and N(delta e_1, I_d) (a scale for
    :func:`energy_distance` in whitened coordinates).

    X - Y ~ N(-delta e_1, 2 I) and X - X' ~ N(0, 2 I), so with chi-type norms
    ``D = 2 sqrt(2) (E sqrt(ncx2(d, delta^2/2)) - E chi_d)``, E chi_d = sqrt(2) Gamma((d+1)/2)/Gamma(d/2).
    """
    d, delta = int(d), float(delta)
    if delta == 0.0:
        return 0.0
    e_nc = stats.ncx2(d, delta * delta / 2.0).expect(np.sqrt)
    e_c = math.sqrt(2.0) * math.exp(math.lgamma((d + 1) / 2.0) - math.lgamma(d / 2.0))
    return float(2.0 * math.sqrt(2.0) * (e_nc - e_c))


def sample_w1(X, Y) -> float:
    """1-Wasserstein distance of two equal-size empirical distributions (optimal assignment)."""
    X, Y = np.atleast_2d(np.asarray(X, float)), np.atleast_2d(np.asarray(Y, float))
    if X.shape != Y.shape:
        raise ValueError("sample_w1 needs samples of equal size")
    C = cdist(X, Y)
    r, c = optimize.linear_sum_assignment(C)
    return float(C[r, c].mean())


def knn_entropy(X, k: int = 5) -> float:
    """Kozachenko-Leonenko entropy estimate [nats] of a sample (n, d) (distinct rows):
    ``psi(n) - psi(k) + log V_d + d mean(log eps_k)``, eps_k the distance to the k-th neighbour."""
    X = np.atleast_2d(np.asarray(X, float))
    n, d = X.shape
    eps = cKDTree(X).query(X, k=k + 1)[0][:, k]
    log_vd = 0.5 * d * math.log(math.pi) - gammaln(0.5 * d + 1.0)
    return float(digamma(n) - digamma(k) + log_vd + d * np.mean(np.log(eps)))


def _negentropy_raw(X, k):
    Xc = X - X.mean(axis=0)
    d = X.shape[1]
    Z = Xc @ whitener(np.cov(Xc, rowvar=False).reshape(d, d)).T
    return 0.5 * d * math.log(2.0 * math.pi * math.e) - knn_entropy(Z, k)


@lru_cache(maxsize=32)
def _negentropy_null(n: int, d: int, k: int, n_null: int) -> np.ndarray:
    """The kNN negentropy estimator on ``n_null`` Gaussian samples of size n (fixed seed, cached)."""
    rng = np.random.default_rng(12345 + 7 * n + d)
    return np.array([_negentropy_raw(rng.standard_normal((n, d)), k) for _ in range(n_null)])


def negentropy(X, k: int = 5, n_null: int = 100) -> dict:
    """Non-Gaussianity J = H(N_moment-matched) - H(p) >= 0 of a sample (n, d) [nats].

    ``raw``: kNN estimate; ``bias``: median of the same estimator on ``n_null`` Gaussian samples of
    size n (it is positive: about 0.02 nats at n = 1000, k = 5, d = 2); ``estimate`` = max(raw - bias, 0);
    ``null_q99``: 99 % quantile of the null (raw values a Gaussian sample reaches by chance).
    Duplicate rows (a walker that did not move) are dropped first.
    """
    X = np.unique(np.atleast_2d(np.asarray(X, float)), axis=0)
    n, d = X.shape
    raw = _negentropy_raw(X, k)
    null = _negentropy_null(int(n), int(d), int(k), int(n_null))
    bias = float(np.median(null))
    return {
        "raw": float(raw),
        "bias": bias,
        "estimate": float(max(raw - bias, 0.0)),
        "null_sd": float(null.std()),
        "null_q99": float(np.quantile(null, 0.99)),
        "n": int(n),
        "k": int(k),
    }


def mardia(X) -> dict:
    """Mardia's multivariate skewness b1 and kurtosis b2 of a sample (n, d) and their tests.

    For a Gaussian: b1 -> 0, b2 -> d (d + 2). ``skew_p`` from n b1/6 ~ chi2(d (d+1) (d+2)/6),
    ``kurt_z`` = (b2 - d (d+2)) / sqrt(8 d (d+2)/n) ~ N(0, 1) (both assume independent draws).
    """
    X = np.atleast_2d(np.asarray(X, float))
    n, d = X.shape
    Xc = X - X.mean(axis=0)
    Y = Xc @ whitener(Xc.T @ Xc / n).T  # y_i . y_j = x_i^T S^-1 x_j (S with 1/n)
    T = np.einsum("ia,ib,ic->abc", Y, Y, Y)  # b1 = sum_ij (y_i . y_j)^3 / n^2 = |T|^2 / n^2
    b1 = float(np.sum(T * T) / n**2)
    b2 = float(np.mean(np.sum(Y * Y, axis=1) ** 2))
    df = d * (d + 1) * (d + 2) / 6.0
    skew_stat = n * b1 / 6.0
    kz = (b2 - d * (d + 2)) / math.sqrt(8.0 * d * (d + 2) / n)
    return {
        "n": int(n),
        "b1": b1,
        "b2": b2,
        "b2_gaussian": float(d * (d + 2)),
        "skew_stat": float(skew_stat),
        "skew_df": float(df),
        "skew_p": float(stats.chi2.sf(skew_stat, df)),
        "kurt_z": float(kz),
        "kurt_p": float(2.0 * stats.norm.sf(abs(kz))),
    }


def sample_check(X, ens_mean, ens_cov, ref_cov=None, rng=None, n_null: int = 100, n_w1: int = 300) -> dict:
    """Two-sample energy test of MCMC draws ``X`` (n, d) (near-independent) against N(ens_mean, ens_cov).

    All draws are whitened with ``ref_cov`` (default: the covariance of X). The null distribution is
    that of two independent samples of the sizes used from one Gaussian (parametric bootstrap,
    ``n_null`` replicates) -> ``p_value``, ``null_q99``; ``shift_reference`` is the population energy
    distance of a 0.5-sd mean shift (for scale). ``w1``: sample 1-Wasserstein distance of the first
    ``n_w1`` draws of each (whitened), with its null median.
    """
    rng = np.random.default_rng(0) if rng is None else rng
    X = np.atleast_2d(np.asarray(X, float))
    n, d = X.shape
    ref_cov = np.cov(X, rowvar=False).reshape(d, d) if ref_cov is None else ref_cov
    W = whitener(ref_cov)
    Y = rng.multivariate_normal(np.asarray(ens_mean, float), _sym(ens_cov), size=n)
    Xw, Yw = X @ W.T, Y @ W.T
    stat = energy_distance(Xw, Yw)
    null = np.array([energy_distance(rng.standard_normal((n, d)), rng.standard_normal((n, d))) for _ in range(n_null)])
    k = min(n, int(n_w1))
    w1 = sample_w1(Xw[:k], Yw[:k])
    w1_null = float(
        np.median([sample_w1(rng.standard_normal((k, d)), rng.standard_normal((k, d))) for _ in range(min(20, n_null))])
    )
    return {
        "method": "energy distance, whitened by the MCMC covariance, vs draws of the ensemble Gaussian",
        "n": int(n),
        "statistic": float(stat),
        "p_value": float((1 + np.sum(null >= stat)) / (1 + null.size)),
        "null_median": float(np.median(null)),
        "null_q99": float(np.quantile(null, 0.99)),
        "shift_reference": energy_shift_reference(d, 0.5),
        "w1": w1,
        "w1_n": int(k),
        "w1_null_median": w1_null,
    }


def lognormal_moments(mean, cov, positive):
    """SI mean (d,) and covariance (d, d) of theta when z ~ N(mean, cov), z = log theta on ``positive`` axes."""
    mean, cov = np.asarray(mean, float), _sym(cov)
    pos = np.asarray(positive, bool)
    E = np.where(pos, np.exp(mean + 0.5 * np.diag(cov)), mean)
    out = np.empty_like(cov)
    for i in range(mean.size):
        for j in range(mean.size):
            if pos[i] and pos[j]:
                out[i, j] = E[i] * E[j] * math.expm1(cov[i, j])
            elif pos[i] or pos[j]:
                out[i, j] = E[i if pos[i] else j] * cov[i, j]
            else:
                out[i, j] = cov[i, j]
    return E, out


def _corr(S):
    s = np.sqrt(np.diag(S))
    return S / np.outer(s, s)


def _moments_block(names, internal_names, m_int, S_int, m_si, S_si) -> dict:
    sd_si = np.sqrt(np.diag(S_si))
    return {
        "mean": {n: float(v) for n, v in zip(names, m_si)},
        "sd": {n: float(v) for n, v in zip(names, sd_si)},
        "cov": S_si.tolist(),
        "corr": _corr(S_int).tolist(),
        "mean_internal": {n: float(v) for n, v in zip(internal_names, m_int)},
        "sd_internal": {n: float(v) for n, v in zip(internal_names, np.sqrt(np.diag(S_int)))},
        "cov_internal": S_int.tolist(),
    }


def mcmc_summary(dt, var_names) -> dict:
    """ArviZ summary (``round_to="none"``) of ``var_names``: dicts of r_hat, ess_bulk, ess_tail,
    mcse_mean, mcse_sd keyed by variable."""
    import arviz as az

    s = az.summary(dt, var_names=list(var_names), round_to="none")
    out = {}
    for col in ("r_hat", "ess_bulk", "ess_tail", "mcse_mean", "mcse_sd"):
        out[col] = {v: float(s.loc[v, col]) for v in var_names}
    return out


def _draws(mcmc, internal_names):
    """(chain, draw, d) internal draws from a DataTree (posterior vars) or an array."""
    if isinstance(mcmc, np.ndarray):
        x = np.asarray(mcmc, float)
        return x if x.ndim == 3 else x[None]
    post = mcmc["posterior"]
    return np.stack([np.asarray(post[v].values, float) for v in internal_names], axis=-1)


def quadrature_block(quad: dict, x, mE, SE, mcse_mean=None, mcse_sd=None) -> dict:
    """The ``quadrature`` entry of a window: the grid posterior (:meth:`imrbayes.mcmc.quadrature.
    GridPosterior.to_dict`), whether the MCMC draws ``x`` (chain, draw, 2) agree with it within their
    Monte-Carlo error (``vs_mcmc``), and the ensemble Gaussian against the grid's moments
    (``vs_ensemble``: Gaussian KL both ways, symmetrised, and whitened W2, as for the MCMC)."""
    from imrbayes.mcmc.quadrature import compare_to_mcmc

    names = list(quad["mean_internal"])
    mQ = np.array([quad["mean_internal"][n] for n in names])
    SQ = _sym(np.asarray(quad["cov_internal"], float))
    W = whitener(SQ)
    kl_qe, kl_eq = gaussian_kl(mQ, SQ, mE, SE), gaussian_kl(mE, SE, mQ, SQ)
    return {
        **quad,
        "vs_mcmc": compare_to_mcmc(quad, x, mcse_mean, mcse_sd),
        "vs_ensemble": {
            "kl_gauss": kl_qe,
            "kl_gauss_reverse": kl_eq,
            "kl_sym": 0.5 * (kl_qe + kl_eq),
            "w2": gaussian_w2(W @ mE, W @ SE @ W.T, W @ mQ, np.eye(len(names))),
        },
    }


def _mcmc_block(mcmc, x, names, internal, positive, diagnostics, notes):
    """The ``entry["mcmc"]`` block: moments, R-hat/ESS/MCSE (two or more chains) and the sampler's
    diagnostics, with the convergence verdict.

    x (C, D, d) internal draws of ``mcmc`` (a DataTree or that array), positive (d,) bool; ``notes`` gets the reasons a
    run is not converged. Returns ``(block, ArviZ summary or None, converged, least bulk ESS)``.
    """
    C, D, d = x.shape
    # diagnostics (ArviZ: one chain per ensemble)
    if isinstance(mcmc, np.ndarray):
        import arviz as az

        dt = az.from_dict({"posterior": {v: x[:, :, i] for i, v in enumerate(internal)}})
    else:
        dt = mcmc
    diag = mcmc_summary(dt, internal) if C >= 2 else None
    flat = x.reshape(C * D, d)
    thetaM = np.where(positive, np.exp(np.where(positive, flat, 0.0)), flat)
    mcmc_block = _moments_block(
        names,
        internal,
        flat.mean(axis=0),
        np.cov(flat, rowvar=False).reshape(d, d),
        thetaM.mean(axis=0),
        np.cov(thetaM, rowvar=False).reshape(d, d),
    )
    converged = True
    if diag is not None:
        by_name = lambda col: {n: diag[col][v] for n, v in zip(names, internal)}  # noqa: E731
        mcmc_block.update(
            {
                "rhat": by_name("r_hat"),
                "ess_bulk": by_name("ess_bulk"),
                "ess_tail": by_name("ess_tail"),
                "mcse_mean": diag["mcse_mean"],
                "mcse_sd": diag["mcse_sd"],
            }
        )
        rmax = max(diag["r_hat"].values())
        emin = min(diag["ess_bulk"].values())
        if not rmax <= THRESHOLDS["rhat"]:
            converged = False
            notes.append(f"MCMC not converged: max R-hat {rmax:.4f} > {THRESHOLDS['rhat']}")
        if not emin >= THRESHOLDS["ess_bulk"]:
            converged = False
            notes.append(f"MCMC bulk ESS {emin:.0f} < {THRESHOLDS['ess_bulk']:g}")
        tmin = min(diag["ess_tail"].values())
        if not tmin >= THRESHOLDS["ess_tail"]:
            converged = False
            notes.append(f"MCMC tail ESS {tmin:.0f} < {THRESHOLDS['ess_tail']:g}")
        ess_min = emin
    else:
        converged = False
        notes.append("one chain only: R-hat not available")
        ess_min = float(C * D)
    if diagnostics is not None:
        mcmc_block["sampler"] = diagnostics
        if diagnostics.get("all_tau_ok") is False:
            converged = False
            notes.append(
                f"chains shorter than {diagnostics.get('tau_rule', 50):g} tau "
                f"(n_steps/tau = {diagnostics.get('n_steps_over_tau', float('nan')):.1f})"
            )
        if diagnostics.get("cap_hit"):
            converged = False
            notes.append(f"hard cap of {diagnostics.get('cap')} steps reached before the convergence check passed")
        failed = diagnostics.get("failed_chains") or {}
        if failed:
            first = next(iter(failed.items()))
            notes.append(
                f"{len(failed)} emcee ensemble(s) failed and were left out (ensemble {first[0]}: "
                f"{first[1]}); the diagnostics use the other {C}"
            )
    mcmc_block.update({"n_chains": int(C), "n_draws": int(C * D), "converged": bool(converged)})
    return mcmc_block, diag, converged, ess_min


def _sample_metrics(flat, ess_min, mE, SE, SM, seed, n_max, n_energy, n_null, notes):
    """Sample-based checks of the draws flat (n, d) against the ensemble Gaussian (mE (d,), SE (d, d)).

    The draws are thinned to about the ESS; ``notes`` gets non-Gaussianity and energy-test rejections.
    Returns ``(negentropy dict, sample_check dict, mardia dict)``.
    """
    n_draws = flat.shape[0]
    # sample-based: thin to about the ESS (near-independent draws)
    rng = np.random.default_rng(seed)
    n_use = int(max(50, min(n_max, ess_min, n_draws)))
    pick = np.unique(np.linspace(0, n_draws - 1, n_use).round().astype(int))
    sub = flat[pick]
    neg = negentropy(sub, n_null=n_null)
    e_pick = pick[np.unique(np.linspace(0, pick.size - 1, min(pick.size, n_energy)).round().astype(int))]
    chk = sample_check(flat[e_pick], mE, SE, ref_cov=SM, rng=rng, n_null=n_null)
    mar = mardia(sub)
    if mar["skew_p"] < 1e-3 or mar["kurt_p"] < 1e-3 or neg["raw"] > neg["null_q99"]:
        notes.append(
            f"MCMC posterior is non-Gaussian (negentropy {neg['estimate']:.3g} nats, Mardia skewness "
            f"p = {mar['skew_p']:.2g}, kurtosis z = {mar['kurt_z']:.2f})"
        )
    if chk["p_value"] < 0.01:
        notes.append(f"energy test rejects equality with the ensemble Gaussian (p = {chk['p_value']:.2g})")
    return neg, chk, mar


def _quadrature_entry(quadrature, mcmc, x, mE, SE, diag, internal, converged, notes):
    """``entry["quadrature"]`` (or None): the grid posterior (default: ``mcmc``'s ``quadrature_json``
    attribute) compared with the ensemble and the draws x (C, D, 2); ``notes`` gets disagreements."""
    d = len(internal)
    if quadrature is None and not isinstance(mcmc, np.ndarray):
        import json

        quadrature = json.loads((getattr(mcmc, "attrs", None) or {}).get("quadrature_json", "null"))
    quad = None
    if quadrature is not None and "mean_internal" in quadrature and d == 2:
        mc = (
            (np.array([diag["mcse_mean"][v] for v in internal]), np.array([diag["mcse_sd"][v] for v in internal]))
            if diag is not None
            else (None, None)
        )
        quad = quadrature_block(quadrature, x, mE, SE, *mc)
        if not quad["vs_mcmc"]["within_mc_error"] and converged:
            notes.append(
                "MCMC and the grid quadrature differ by more than their Monte-Carlo error (mean/sd z "
                f"{max(map(abs, quad['vs_mcmc']['mean_z'].values())):.1f}/"
                f"{max(map(abs, quad['vs_mcmc']['sd_z'].values())):.1f})"
            )
    elif quadrature is not None and "error" in quadrature:
        quad = quadrature
        notes.append(f"grid quadrature failed: {quadrature['error']}")
    return quad


def _agreement(kl_sym, w2w, kl_sample, kl_me, neg, converged, notes):
    """The criteria (``{name: passed}``) and the verdict: True/False, None when the MCMC run is not
    converged. ``notes`` gets each failed criterion and the verdict first (KL in nats, W2 in sd)."""
    crit = {
        "kl_sym": bool(kl_sym <= THRESHOLDS["kl_sym"]),
        "w2": bool(w2w <= THRESHOLDS["w2"]),
        "kl_sample": bool(kl_sample <= THRESHOLDS["kl_sample"]),
    }
    why = {
        "kl_sym": f"Gaussian KL (symmetrised) {kl_sym:.3g} > {THRESHOLDS['kl_sym']} nats",
        "w2": f"W2 {w2w:.3g} sd > {THRESHOLDS['w2']}",
        "kl_sample": f"sample KL {kl_sample:.3g} > {THRESHOLDS['kl_sample']} nats "
        f"(Gaussian part {kl_me:.3g} + non-Gaussian part {neg['estimate']:.3g})",
    }
    notes.extend(why[k] for k, ok in crit.items() if not ok)
    agree = bool(all(crit.values())) if converged else None
    if agree:
        notes.insert(0, "ensemble Gaussian agrees with MCMC")
    elif agree is None:
        notes.insert(0, "undecided: the MCMC run does not meet the convergence criteria")
    return crit, agree


def compare_window(
    ens_mean,
    ens_cov,
    mcmc,
    names,
    positive,
    *,
    index: int = 0,
    t_star=None,
    diagnostics=None,
    seed: int = 0,
    n_max: int = 2000,
    n_energy: int = 500,
    n_null: int = 100,
    quadrature: dict | None = None,
) -> dict:
    """One window's entry of ``compare.json`` (module docstring).

    Parameters
    ----------
    ens_mean, ens_cov : (d,), (d, d)
        The ensemble method's Gaussian in internal coordinates (``mean_internal``/``cov_internal``
        of a ``summary.json`` window).
    mcmc : xarray.DataTree with a ``posterior`` holding the internal variables (``log_G``; as
        :meth:`MCMCRun.to_datatree` writes), or an array (chain, draw, d) of internal draws.
    names : parameter names (SI); positive : (d,) bool, log-transformed parameters.
    index, t_star : window index and [start, end] t*.
    diagnostics : optional :meth:`MCMCRun.diagnostics` dict (tau rule, acceptance) to include.
    seed : for the sample check's Gaussian draws and null replicates.
    n_max : most MCMC draws used for the negentropy and Mardia's statistics (fewer when the bulk ESS
        is lower: the draws are thinned to about the ESS); n_energy : most draws in the energy test.
    n_null : bootstrap replicates of the null distributions.
    quadrature : the window's grid posterior (``GridPosterior.to_dict()``; default: the tree's
        ``quadrature_json`` attribute, which ``fit --mcmc`` writes for 2-parameter windows): added
        as ``entry["quadrature"]`` (:func:`quadrature_block`); it does not enter ``agree``.
    """
    names = list(names)
    positive = np.asarray(positive, bool)
    internal = [f"log_{n}" if p else n for n, p in zip(names, positive)]
    d = len(names)
    mE, SE = np.asarray(ens_mean, float).reshape(d), _sym(np.asarray(ens_cov, float).reshape(d, d))
    x = _draws(mcmc, internal)  # (C, D, d)
    C, D, _ = x.shape
    flat = x.reshape(C * D, d)
    mM, SM = flat.mean(axis=0), np.cov(flat, rowvar=False).reshape(d, d)
    mE_si, SE_si = lognormal_moments(mE, SE, positive)
    notes = []

    mcmc_block, diag, converged, ess_min = _mcmc_block(mcmc, x, names, internal, positive, diagnostics, notes)

    # Gaussian metrics
    kl_me = gaussian_kl(mM, SM, mE, SE)
    kl_em = gaussian_kl(mE, SE, mM, SM)
    W = whitener(SM)
    w2w = gaussian_w2(W @ mE, W @ SE @ W.T, W @ mM, np.eye(d))
    w2l = gaussian_w2(mE, SE, mM, SM)
    sdM, sdE = np.sqrt(np.diag(SM)), np.sqrt(np.diag(SE))

    neg, chk, mar = _sample_metrics(flat, ess_min, mE, SE, SM, seed, n_max, n_energy, n_null, notes)
    kl_sample = kl_me + neg["estimate"]

    kl_sym = 0.5 * (kl_me + kl_em)
    crit, agree = _agreement(kl_sym, w2w, kl_sample, kl_me, neg, converged, notes)
    quad = _quadrature_entry(quadrature, mcmc, x, mE, SE, diag, internal, converged, notes)
    entry = {
        "index": int(index),
        "t_star": None if t_star is None else [float(t) for t in t_star],
        "parameters": names,
        "internal": internal,
        "ensemble": _moments_block(names, internal, mE, SE, mE_si, SE_si),
        "mcmc": mcmc_block,
        "kl_gauss": kl_me,
        "kl_gauss_reverse": kl_em,
        "kl_sym": kl_sym,
        "w2": w2w,
        "w2_log": w2l,
        "mean_shift_sd": {n: float(v) for n, v in zip(names, (mE - mM) / sdM)},
        "sd_ratio": {n: float(v) for n, v in zip(names, sdE / sdM)},
        "kl_sample": kl_sample,
        "negentropy": neg,
        "sample_check": chk,
        "mardia": mar,
        "criteria": crit,
        "agree": agree,
        "notes": "; ".join(notes),
    }
    if quad is not None:
        entry["quadrature"] = quad
    return entry


def compare_windows(entries) -> dict:
    """``{"windows": entries, "overall": {...}}`` -- the compare.json object (interfaces.md §3)."""
    entries = list(entries)
    kl = [e["kl_sym"] for e in entries]
    w2 = [e["w2"] for e in entries]
    kls = [e["kl_sample"] for e in entries]
    agree = [e["agree"] for e in entries]
    worst = int(entries[int(np.argmax(kls))]["index"]) if entries else None
    overall = {
        "n_windows": len(entries),
        "n_agree": sum(a is True for a in agree),
        "n_disagree": sum(a is False for a in agree),
        "n_undecided": sum(a is None for a in agree),
        "all_agree": bool(entries) and all(a is True for a in agree),
        "all_converged": all(e["mcmc"]["converged"] for e in entries),
        "max_kl_sym": max(kl) if kl else None,
        "max_w2": max(w2) if w2 else None,
        "max_kl_sample": max(kls) if kls else None,
        "worst_window": worst,
        "thresholds": dict(THRESHOLDS),
        "agree_rule": AGREE_RULE.format(**THRESHOLDS),
        "coordinates": "internal parameters: log for positive parameters (log G [Pa], log mu [Pa s])",
    }
    return {"windows": entries, "overall": overall}
