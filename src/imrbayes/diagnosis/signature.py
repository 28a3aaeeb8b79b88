"""The MIEnKS-MDA signature of a dataset, and how well a fitted candidate reproduces it.

The paper's instrument as a statistic: the sliding-window smoother (MIEnKS-MDA,
:func:`imrbayes.ensemble.mienks.fit_mienks`) run with the constant-parameter NHKV baseline on the
data gives window estimates G(t), mu(t) -- the *observed signature*. On data that a constant NHKV
explains, the curves settle to flat lines after the walk from the prior; a mechanism the baseline
lacks (strain stiffening, a rate-dependent viscosity, damage, ...) makes them bend in its own way.

A fitted candidate predicts a *distribution* of signatures: ``simulate(rng)`` (the caller's: the
candidate's fitted curves on the data's design, with noise, processed as the data were) gives one
synthetic dataset, the same smoother with the same baseline model runs on it, and ``n_rep``
replicates give a per-window predictive distribution. The candidate is scored by how far the
observed signature lies from it (:func:`signature_score`), next to its held-out prediction.

Choices
-------
* **Likelihood ``paper``** (one pass; ``default`` would add a pilot pass, twice the cost). The
  signature is never read as a posterior: it is a statistic, and only its comparison with the same
  statistic on replicates is interpreted, so the calibration comes from the replicates, not from
  the likelihood's noise model. ``paper`` depends on the data only through R* and the
  preprocessing's P_k, which a replicate re-estimates exactly as the data's were; the default
  likelihood also reads per-record noise levels and the time-of-maximum uncertainty (which a
  synthetic replicate does not have unless the caller copies them) and its pilot pass turns model
  misfit into noise (the very thing the signature should show). It is also the paper's instrument
  as the issue asks, and what ``check.mienks_drift`` uses.
* **Cheap smoother** (16 members, 2 Gauss-Newton iterations, the paper's windows L = 35, h = 5):
  as ``mienks_drift``. Measured on a 5-experiment, 121-sample record (18 windows, 4320 member
  runs, numba compiled): ~0.9 s per smoother run with the polytropic bubble (2-6 s when other work
  shares the two cores), ~25 s with the thermal bubble; the default likelihood adds its pilot pass (2.8 s
  polytropic measured). A diagnosis costs (1 + n_rep x candidates) smoother runs: with 4 replicates and 5
  candidates ~20 s polytropic, ~9 min thermal.
* **Replicates** ``n_rep = 4``: the smallest number with a usable spread (3 degrees of freedom)
  and a leave-one-out tail probability; cost per candidate = n_rep smoother runs plus n_rep
  ``simulate`` calls. Replicate r uses ``numpy.random.default_rng([seed, r])`` for ``simulate``
  and smoother seed ``seed + 1 + r``: with the same ``seed`` for every candidate the candidates
  share their random numbers, so their score *differences* are less noisy.
* **Bands**: the central 80 % (10 / 90 %) *prediction interval* of one more replicate in log
  space, mean +- t_{0.9, n-1} s sqrt(1 + 1/n) (Student t, n replicates, s their sd), not empirical
  quantiles: with 3-5 replicates empirical 10/90 % quantiles are just the extremes. ``G_mean``,
  ``mu_mean`` are the geometric means over the replicates (exp of the mean log).
* **Score** (lower is better), per window j and parameter p in (log G, log mu)::

      D = mean_{j,p} (o_jp - m_jp)^2 / ((1 + 1/n) s_jp^2 + v_jp)

  o: observed window mean, m and s^2: mean and variance of the n replicates' window means, v: the
  observed window's posterior variance. (1 + 1/n) s^2 is the variance of o - m when o is one more
  draw from the replicates' distribution (m is itself a mean of n draws). v is added, and with the
  ``paper`` likelihood it dominates (measured, 5 polytropic experiments, 121 samples: window
  posterior sd ~0.27 in log G and log mu, replicate spread 0.02-0.15), so D is essentially the
  squared distance of the candidate's predicted mean signature from the data's in units of the
  data's own window posterior sd -- a posterior predictive check of the signature. Why not the
  replicate spread alone (the textbook bootstrap standardisation): (i) with 3-5 replicates s^2 has
  2-4 degrees of freedom, so each window's ratio has a heavy-tailed F(1, n-1) null and a window
  whose replicates happen to agree dominates; in the early windows the shared prior makes every
  replicate alike, so s is small there by construction; (ii) it is not monotone in the size of a
  mismatch: a grossly wrong candidate whose replicates scatter more scores *better* (measured:
  truth 2.3, G x 1.5 73, G x 3 only 36; with v: 0.12, 1.7, 7.5; mu x 2: 54 vs 2.9); (iii) real data
  carry variation no ``simulate`` reproduces (Rmax, Req and time-of-maximum errors, camera
  interpolation), which a replicate-only scale would read as a mismatch of every candidate. Under a
  correct candidate D is then well below 1 (0.06-0.12 measured); about 1 means the observed curves
  sit one posterior sd from the prediction. The two parameters are standardised separately (a 2x2
  replicate covariance from 3-5 draws is not estimable); windows overlap and are chained, so D is
  not a chi-square: it ranks candidates, and :func:`signature_tail` gives a rough calibration.
* **Tail probability** (:func:`signature_tail`, no extra runs): each replicate is scored as if
  observed against the other n - 1, and p = (1 + #{D_b >= D}) / (n + 1). Coarse (resolution
  1/(n+1): with 4 replicates it cannot go below 0.2) and the leave-one-out reference uses one
  replicate fewer; read it as a flag, not a test. It is not part of the diagnosis.json layout.

Result layout (``result["signature"]`` of diagnosis.json, :func:`signature_result`; SI units)::

    {"observed": {"t_star", "G", "G_sd", "mu", "mu_sd"},
     "predicted": {key: {"t_star", "G_mean", "G_lo", "G_hi", "mu_mean", "mu_lo", "mu_hi"}},
     "score": {key: float}, "note": str}

Only stable APIs are used: ``fit_mienks``/``MIEnKSSettings``, ``ParamSpace``, ``Observations``,
``ForwardModel`` and the caller's ``simulate``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from imrbayes.ensemble import Observations, ParamSpace
from imrbayes.ensemble.mienks import MIEnKSSettings, fit_mienks
from imrbayes.errors import InputError

__all__ = [
    "SignatureSettings",
    "observed_signature",
    "predicted_signature",
    "signature_score",
    "signature_tail",
    "signature_result",
]

PARAMS = ("G", "mu")


@dataclass
class SignatureSettings:
    """The smoother that makes a signature (the same for the data and every replicate) and how many
    replicates a candidate gets (module doc)."""

    n_ens: int = 16
    """MIEnKS-MDA ensemble size (default 16)."""
    n_iter: int = 2
    """MIEnKS-MDA iterations per window (default 2)."""
    L: int = 35
    """MIEnKS window length [samples] (default 35)."""
    h: int = 5
    """MIEnKS window shift [samples] (default 5)."""
    rtps: float = 0.7
    """MIEnKS relaxation to the prior spread (default 0.7)."""
    likelihood: str = "paper"
    """MIEnKS likelihood (default ``paper``: one pass)."""
    n_rep: int = 4
    """Replicates per candidate for its predicted signature (default 4)."""
    band: float = 0.8
    """Central probability of the predicted band (default 0.8: 10 / 90 %)."""

    def mienks(self) -> MIEnKSSettings:
        """The :class:`MIEnKSSettings` (one posterior draw per window: the draws are not used)."""
        return MIEnKSSettings(
            n_ens=self.n_ens,
            n_iter=self.n_iter,
            L=self.L,
            h=self.h,
            rtps=self.rtps,
            n_draws=1,
            likelihood=self.likelihood,
        )

    def skip_reason(self, obs: Observations) -> str | None:
        """Why the signature cannot be computed on ``obs`` with these settings (e.g. the record is
        shorter than one window), else None."""
        try:
            self.mienks().check(obs.n_samples - 1)
        except InputError as exc:
            return f"MIEnKS signature skipped: {exc}"
        if not 0.0 < self.band < 1.0:
            return f"MIEnKS signature skipped: band must lie in (0, 1), got {self.band}"
        return None


def _settings(settings) -> SignatureSettings:
    if settings is None:
        return SignatureSettings()
    if isinstance(settings, MIEnKSSettings):
        return SignatureSettings(
            n_ens=settings.n_ens,
            n_iter=settings.n_iter,
            L=settings.L,
            h=settings.h,
            rtps=settings.rtps,
            likelihood=settings.likelihood,
        )
    return settings


def _space(fm, space):
    sp = space or ParamSpace.for_model(fm.constitutive)
    missing = [p for p in PARAMS if p not in sp.names]
    if missing:
        raise InputError("signature", f"the baseline model needs parameters {PARAMS}, has {tuple(sp.names)}")
    return sp


def _windows(fm, obs, s: SignatureSettings, space, seed):
    """(t* window centres (nw,), means (nw, 2), variances (nw, 2)) of (log G, log mu)."""
    idx = [list(space.names).index(p) for p in PARAMS]
    with np.errstate(all="ignore"):
        r = fit_mienks(fm, obs, space, s.mienks(), seed=int(seed))
    tc = np.array([0.5 * (w["t_star"][0] + w["t_star"][1]) for w in r.windows])
    m = np.array([w["mean_internal"] for w in r.windows])[:, idx]
    v = np.array([np.diag(w["cov_internal"]) for w in r.windows])[:, idx]
    return tc, m, v


def _slopes(tc, m, v) -> dict:
    """Weighted least-squares slopes of m[:, i] against tc (weights 1/v) and their nominal
    standard errors (windows overlap and are chained: not the slopes' true ones)."""
    out = {}
    for i, p in enumerate(PARAMS):
        w = 1.0 / np.maximum(v[:, i], 1e-12)
        if tc.size < 2:
            out[f"log_{p}"], out[f"se_log_{p}"] = float("nan"), float("nan")
            continue
        tb = np.sum(w * tc) / w.sum()
        sxx = np.sum(w * (tc - tb) ** 2)
        out[f"log_{p}"] = float(np.sum(w * (tc - tb) * (m[:, i] - np.sum(w * m[:, i]) / w.sum())) / sxx)
        out[f"se_log_{p}"] = float(1.0 / np.sqrt(sxx))
    return out


def observed_signature(fm, obs: Observations, settings=None, seed: int = 0, space: ParamSpace | None = None) -> dict:
    """The signature of ``obs``: MIEnKS-MDA with the baseline forward model ``fm`` (constant NHKV).

    ``settings``: :class:`SignatureSettings` (or an :class:`MIEnKSSettings`; None: defaults);
    ``space``: the parameter space (default: the paper prior of ``fm``'s model). Returns
    ``t_star`` (window centres), ``log_G``, ``log_mu`` (fused window means, internal log
    coordinates), ``sd_log_G``, ``sd_log_mu``, ``G``, ``mu`` (SI medians exp(mean)), ``G_sd``,
    ``mu_sd`` (SI sd of the window's log-normal), ``slopes`` (weighted least-squares slopes of log G
    and log mu per unit t*, with nominal standard errors) -- all arrays / floats."""
    s = _settings(settings)
    why = s.skip_reason(obs)
    if why:
        raise InputError("signature", why)
    sp = _space(fm, space)
    tc, m, v = _windows(fm, obs, s, sp, seed)
    sd = np.sqrt(np.maximum(v, 0.0))
    out = {"t_star": tc, "slopes": _slopes(tc, m, v), "settings": dict(s.__dict__)}
    for i, p in enumerate(PARAMS):
        out[f"log_{p}"], out[f"sd_log_{p}"] = m[:, i], sd[:, i]
        out[p] = np.exp(m[:, i])
        out[f"{p}_sd"] = np.exp(m[:, i] + 0.5 * v[:, i]) * np.sqrt(np.expm1(v[:, i]))
    return out


def _t_quantile(q: float, dof: int) -> float:
    from scipy import stats

    return float(stats.t.ppf(q, dof))


def predicted_signature(
    simulate, fm, settings=None, n_rep: int | None = None, seed: int = 0, space: ParamSpace | None = None
) -> dict:
    """The signature distribution a fitted candidate predicts.

    ``simulate(rng) -> Observations``: one synthetic dataset of the data's design from the fitted
    candidate (its curves on the data's grid with the data's Rmax, Req, noise added, P_k
    re-estimated as for the data). Each of ``n_rep`` (default ``settings.n_rep``) replicates goes
    through the same smoother as :func:`observed_signature` (same ``fm``, settings, ``space``).
    Replicates whose simulation or smoother fails are left out (``failures`` says why).

    Returns ``t_star``, the replicate curves ``log_G_reps``, ``log_mu_reps`` (n_ok, nw) and their
    window sds ``sd_log_G_reps``, ``sd_log_mu_reps``; per window ``log_G_mean``, ``log_G_spread``
    (replicate sd, ddof 1; NaN below two replicates), the same for mu; SI ``G_mean`` (geometric
    mean), ``G_lo``, ``G_hi`` (the ``band`` prediction interval, module doc), the same for mu;
    ``n_rep``, ``n_ok``, ``band``, ``failures``."""
    s = _settings(settings)
    n = int(s.n_rep if n_rep is None else n_rep)
    if n < 1:
        raise InputError("n_rep", f"needs at least one replicate, got {n}")
    sp = _space(fm, space)
    tcs, ms, vs, failures = [], [], [], []
    for r in range(n):
        try:
            ob = simulate(np.random.default_rng([int(seed), r]))
        except Exception as exc:  # noqa: BLE001 -- the caller's code: any failure is one replicate's
            failures.append(f"replicate {r}: simulate failed ({type(exc).__name__}: {_first_line(exc)})")
            continue
        why = s.skip_reason(ob)
        if why:
            raise InputError("signature", f"replicate {r}: {why}")
        try:
            tc, m, v = _windows(fm, ob, s, sp, seed + 1 + r)
        except InputError:
            raise
        except (RuntimeError, ValueError, FloatingPointError, np.linalg.LinAlgError) as exc:
            failures.append(f"replicate {r}: smoother failed ({type(exc).__name__}: {_first_line(exc)})")
            continue
        if tcs and (tc.shape != tcs[0].shape or not np.allclose(tc, tcs[0])):
            raise InputError(
                "signature", f"replicate {r} has other windows than replicate 0: simulate must keep the data's design"
            )
        tcs.append(tc)
        ms.append(m)
        vs.append(v)
    k = len(ms)
    out = {"n_rep": n, "n_ok": k, "band": float(s.band), "failures": failures}
    if k == 0:
        out["t_star"] = np.array([])
        return out
    M, V = np.stack(ms), np.stack(vs)  # (k, nw, 2)
    mean = M.mean(axis=0)
    spread = M.std(axis=0, ddof=1) if k >= 2 else np.full(mean.shape, np.nan)
    half = (
        _t_quantile(0.5 + 0.5 * s.band, k - 1) * spread * math.sqrt(1.0 + 1.0 / k)
        if k >= 2
        else np.full(mean.shape, np.nan)
    )
    out["t_star"] = tcs[0]
    for i, p in enumerate(PARAMS):
        out[f"log_{p}_reps"] = M[:, :, i]
        out[f"sd_log_{p}_reps"] = np.sqrt(np.maximum(V[:, :, i], 0.0))
        out[f"log_{p}_mean"] = mean[:, i]
        out[f"log_{p}_spread"] = spread[:, i]
        out[f"{p}_mean"] = np.exp(mean[:, i])
        out[f"{p}_lo"] = np.exp(mean[:, i] - half[:, i])
        out[f"{p}_hi"] = np.exp(mean[:, i] + half[:, i])
    return out


def _first_line(exc) -> str:
    lines = str(exc).splitlines()
    return lines[0] if lines else ""


def _distance(o, v, M) -> float:
    """Mean over windows and (log G, log mu) of (o - mean M)^2 / ((1 + 1/n) var M + v); o, v
    (nw, 2) observed means and posterior variances, M (n, nw, 2) replicate means (n >= 2)."""
    n = M.shape[0]
    d2 = (o - M.mean(axis=0)) ** 2 / ((1.0 + 1.0 / n) * M.var(axis=0, ddof=1) + np.maximum(v, 0.0))
    d2 = d2[np.isfinite(d2)]
    return float(np.mean(d2)) if d2.size else float("nan")


def _arrays(observed, predicted):
    o = np.column_stack([np.asarray(observed[f"log_{p}"], dtype=float) for p in PARAMS])
    v = np.column_stack([np.asarray(observed[f"sd_log_{p}"], dtype=float) ** 2 for p in PARAMS])
    if int(predicted.get("n_ok", 0)) < 2:
        return o, v, None
    M = np.stack([np.asarray(predicted[f"log_{p}_reps"], dtype=float) for p in PARAMS], axis=-1)
    to, tp = np.asarray(observed["t_star"], dtype=float), np.asarray(predicted["t_star"], dtype=float)
    if to.shape != tp.shape or not np.allclose(to, tp):
        raise InputError(
            "signature",
            f"observed ({to.size}) and predicted ({tp.size}) signatures have other "
            "windows: the replicates must keep the data's design and settings",
        )
    return o, v, M


def signature_score(observed: dict, predicted: dict) -> float:
    """How far the observed signature lies from a candidate's predicted distribution (lower is
    better): the mean over windows and (log G, log mu) of the squared standardised distance
    (o - m)^2 / ((1 + 1/n) s^2 + v) (module doc). NaN when fewer than two replicates succeeded."""
    o, v, M = _arrays(observed, predicted)
    return float("nan") if M is None else _distance(o, v, M)


def signature_tail(observed: dict, predicted: dict) -> float:
    """Monte-Carlo tail probability of :func:`signature_score` (module doc): each replicate scored
    against the other replicates, p = (1 + #{D_b >= D}) / (n + 1). NaN below three replicates."""
    o, v, M = _arrays(observed, predicted)
    if M is None or M.shape[0] < 3:
        return float("nan")
    Vr = np.stack([np.asarray(predicted[f"sd_log_{p}_reps"], dtype=float) ** 2 for p in PARAMS], axis=-1)
    D = _distance(o, v, M)
    n = M.shape[0]
    Db = np.array([_distance(M[b], Vr[b], np.delete(M, b, axis=0)) for b in range(n)])
    Db = np.where(np.isfinite(Db), Db, np.inf)
    return float((1.0 + np.sum(Db >= D)) / (n + 1.0))


def _list(a) -> list:
    return [float(x) if math.isfinite(float(x)) else None for x in np.asarray(a, dtype=float).ravel()]


def _num(x):
    x = float(x)
    return x if math.isfinite(x) else None


NOTE = (
    "MIEnKS-MDA signature: window estimates G(t*), mu(t*) of the constant-parameter NHKV smoother "
    "(likelihood {lik}, {n_ens} members, {n_iter} iterations, windows L = {L}, h = {h}) on the data "
    "(observed: median and sd of each window's log-normal) and on {n_rep} synthetic replicates of "
    "the data's design from each fitted candidate (predicted: geometric mean and the {band:.0f} % "
    "prediction interval of one more replicate). score: mean over windows and (log G, log mu) of "
    "(observed - replicate mean)^2 / ((1 + 1/n) replicate variance + observed window variance); "
    "lower is better: well below 1 when the candidate reproduces the signature, about 1 when the "
    "observed curves lie one window posterior sd from the prediction. The windows overlap and are "
    "chained, so it ranks candidates rather than testing them."
)


def signature_result(observed: dict, predicted_by_key: dict, note: str | None = None) -> dict:
    """``result["signature"]`` for diagnosis.json (module doc): SI lists (non-finite -> None),
    one ``predicted`` entry and one ``score`` per candidate key."""
    s = SignatureSettings(**observed["settings"]) if "settings" in observed else SignatureSettings()
    n_rep = sorted({int(p.get("n_rep", 0)) for p in predicted_by_key.values()}) or [s.n_rep]
    obs_out = {"t_star": _list(observed["t_star"])}
    for p in PARAMS:
        obs_out[p], obs_out[f"{p}_sd"] = _list(observed[p]), _list(observed[f"{p}_sd"])
    pred_out, score = {}, {}
    for key, pr in predicted_by_key.items():
        e = {"t_star": _list(pr.get("t_star", []))}
        for p in PARAMS:
            for q in ("mean", "lo", "hi"):
                e[f"{p}_{q}"] = _list(pr.get(f"{p}_{q}", []))
        pred_out[key] = e
        score[key] = _num(signature_score(observed, pr))
    if note is None:
        note = NOTE.format(
            lik=s.likelihood,
            n_ens=s.n_ens,
            n_iter=s.n_iter,
            L=s.L,
            h=s.h,
            n_rep="/".join(map(str, n_rep)),
            band=100 * s.band,
        )
    return {"observed": obs_out, "predicted": pred_out, "score": score, "note": note}
