"""Does the fitted model describe the records?  Checked before any number is printed.

A fit's estimate is the material's property only if the model reproduces the records to within
their noise. :func:`fit_check` compares, per bubble, the RMS of the fitted curve's residual with
the record's own noise sd (:func:`imrbayes.ensemble.likelihood.record_noise_sd`: fourth
differences), and takes the median over bubbles. On camera-style synthetic data made with the
fitted model the ratio stays below :data:`FIT_CHECK_THRESHOLD` (calibrated by
``python -m validation calibration`` and ``range``: docs/validation.md); above it the model does not describe the
records and the estimate is the best fit of a wrong model.

:func:`annotate_estimate` adds what the headline needs: whether the data bound each parameter
(the posterior narrower than half the prior in the internal coordinate), how much of the
posterior is the data's, and, from the global search (:mod:`imrbayes.ensemble.search`), whether
G is consistent with 0 and its 95 % upper bound (the profile likelihood's).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["FIT_CHECK_THRESHOLD", "BOUND_RATIO", "fit_check", "annotate_estimate"]

#: The largest median (residual RMS / record noise) of a model that describes its records: the
#: 95th percentile of the ratio on camera-style synthetic nulls is below it (docs/validation.md).
FIT_CHECK_THRESHOLD = 3.0
#: A modulus below this [Pa] moves no bubble (1/Ca = G/p_inf < 1e-5): an interval reaching it reaches 0.
NEGLIGIBLE_G_PA = 1.0
#: A parameter is bounded by the data when its posterior sd is below this fraction of the prior's
#: (internal coordinate, i.e. log scale for G and mu).
BOUND_RATIO = 0.5


def fit_check(res, obs, model: str = "nhkv", threshold: float = FIT_CHECK_THRESHOLD) -> dict:
    """The fitted curves against the records' noise.

    Parameters
    ----------
    res : FitResult
        With ``fitted`` (n_exp, n) and ``fit_mask`` (n_exp, n).
    obs : Observations
    model : str
        The constitutive model's name (for the message).

    Returns
    -------
    dict
        ``described`` (bool), ``residual_to_noise`` (median over bubbles), ``per_experiment`` (list
        of ``{"name", "residual_rms", "noise_sd", "ratio"}``, R* units), ``threshold`` and a one-sentence
        ``message``.
    """
    from imrbayes.ensemble.likelihood import record_noise_sd

    rows = []
    for n in range(obs.n_exp):
        mask = np.asarray(res.fit_mask[n], dtype=bool) & np.isfinite(res.fitted[n])
        if mask.sum() < 2:
            continue
        rms = float(np.sqrt(np.mean((res.fitted[n][mask] - obs.R_star[n][mask]) ** 2)))
        noise = float(record_noise_sd(obs, n))
        rows.append({"name": obs.names[n], "residual_rms": rms, "noise_sd": noise, "ratio": rms / noise})
    if not rows:
        return {
            "described": None,
            "residual_to_noise": None,
            "per_experiment": [],
            "threshold": threshold,
            "p_value": None,
            "message": "no fitted curve to check",
        }
    ratio = float(np.median([r["ratio"] for r in rows]))
    described = ratio <= threshold
    label = model.upper()
    if described:
        msg = (
            f"{label} describes these records: the fitted curves miss them by {ratio:.1f}x their noise "
            f"(a model that describes them stays below {threshold:g}x)."
        )
    else:
        msg = (
            f"{label} does not describe these records: the residual is {ratio:.0f}x their noise; these "
            f"numbers are the best {label} fit, not the material's properties -- `imrbayes diagnose` "
            f"looks for the cause."
        )
    return {
        "described": bool(described),
        "residual_to_noise": ratio,
        "per_experiment": rows,
        "threshold": threshold,
        "p_value": None,
        "message": msg,
    }


def annotate_estimate(estimate: dict, space, cov_internal=None, search=None) -> dict:
    """``estimate`` (name -> {"mean", "sd", "hdi95", ...}, SI) with ``bounded`` per parameter and,
    for G, ``consistent_with_zero`` / ``upper95`` from the global search. Returns a new dict; the
    data's share of the posterior is :meth:`ParamSpace.data_share`."""
    out = {k: dict(v) for k, v in estimate.items()}
    if cov_internal is not None:
        post_sd = np.sqrt(np.diag(np.asarray(cov_internal, dtype=np.float64)))
        prior_sd = np.sqrt(np.diag(space.prior_cov))
        for i, nm in enumerate(space.names):
            if nm in out:
                ok = bool(post_sd[i] < BOUND_RATIO * prior_sd[i])
                out[nm]["bounded"] = {"lower": ok, "upper": ok}
    zero = (
        (search or {}).get("zero_modulus")
        if isinstance(search, dict)
        else (search.zero_modulus if search is not None else None)
    )
    lo = (out.get("G", {}).get("hdi95") or [None])[0]
    if zero is None and lo is not None and lo < NEGLIGIBLE_G_PA:
        # a grid method's interval that reaches G = 0 (IMR, pIMR: G = 0 is a grid point)
        zero = {"consistent_with_zero": True}
    if zero and "G" in out:
        out["G"]["consistent_with_zero"] = bool(zero["consistent_with_zero"])
        if zero["consistent_with_zero"]:
            # the data bound a liquid's G from above only: the search's profile-likelihood bound (a
            # Gaussian in log G describes a one-sided likelihood badly), else the interval's upper end
            up = zero.get("upper95_pa") or (out["G"].get("hdi95") or [None, None])[1]
            ok = up is not None and math.isfinite(up)
            out["G"]["upper95"] = float(up) if ok else None
            out["G"]["bounded"] = {"lower": False, "upper": ok}
    return out
