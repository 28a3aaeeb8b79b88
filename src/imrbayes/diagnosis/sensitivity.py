"""How much the baseline's material estimate depends on the bubble model.

A bubble-model candidate (``kind == "bubble"``: the baseline material with another bubble model,
:mod:`imrbayes.diagnosis.candidates`) that the data cannot tell from the baseline but that puts the
material elsewhere is a systematic uncertainty of the estimate, whatever the check says. Measured on
camera-style data (docs/methods.md, thermal matrix, bubble-thermal seed 5000): records made with
vapour mass transfer switched off differ from the fitted model's by 36-41 noise sd before a refit,
yet the NHKV refit absorbs them to the noise level (check p = 0.91) by moving G +70 % and mu -19 %
off the truth, while the right bubble model fits no better on held-out data. The check cannot see
such an error; this comparison can at least say that the estimate moves with the bubble model.

:func:`bubble_model_sensitivity` compares each bubble candidate's whole-record MAP estimate with
the baseline's (both Laplace summaries of the same likelihood) and calls the two indistinguishable
when no held-out scheme separates them by ``tie_se`` paired standard errors (the rule ``diagnose``
uses for ties).
"""

from __future__ import annotations

import math

__all__ = ["bubble_model_sensitivity", "flagged", "options_text"]

#: a shift that matters: at least this many baseline posterior sd and this relative change
SHIFT_SD = 2.0
SHIFT_REL = 0.10


def _separation(candidate: dict) -> float | None:
    """Largest |paired held-out difference| / SE over the schemes run (None: no scheme)."""
    z = []
    for v in (candidate.get("heldout") or {}).values():
        pd = v.get("paired_vs_baseline") or {}
        d, se = pd.get("mean_diff"), pd.get("se")
        if d is not None and se and math.isfinite(d) and math.isfinite(se) and se > 0:
            z.append(abs(d) / se)
    return max(z) if z else None


def bubble_model_sensitivity(
    candidates: list, baseline_estimate: dict, tie_se: float = 2.0, overrides: dict | None = None
) -> dict:
    """Each bubble candidate's material estimate against the baseline's.

    candidates: diagnose's candidate entries (``kind``, ``key``, ``mechanism``,
    ``estimate`` {name: {median, sd}}, ``heldout`` {scheme: {paired_vs_baseline}}); baseline_estimate:
    the baseline's MAP estimate {name: {median, sd}} (SI units); overrides: key -> the forward
    options the alternative changes (reported as ``bubble_options``). Returns {"alternatives": [...],
    "material_depends_on_bubble_model": bool, "rule": str}; each alternative has ``shift`` (relative)
    and ``shift_sd`` (in baseline sd) per shared parameter, ``separation_se`` and
    ``indistinguishable``.
    """
    out = []
    for c in candidates:
        if c.get("kind") != "bubble":
            continue
        est = c.get("estimate") or {}
        shared = [n for n in baseline_estimate if n in est]
        shift = {
            n: est[n]["median"] / baseline_estimate[n]["median"] - 1.0 for n in shared if baseline_estimate[n]["median"]
        }
        shift_sd = {
            n: (est[n]["median"] - baseline_estimate[n]["median"]) / baseline_estimate[n]["sd"]
            for n in shared
            if baseline_estimate[n].get("sd")
        }
        sep = _separation(c)
        same = sep is not None and sep < tie_se
        moves = [n for n in shift if abs(shift[n]) >= SHIFT_REL and abs(shift_sd.get(n, 0.0)) >= SHIFT_SD]
        out.append(
            {
                "key": c.get("key"),
                "mechanism": c.get("mechanism"),
                "bubble_options": dict((overrides or {}).get(c.get("key")) or {}),
                "estimate": {n: est[n]["median"] for n in shared},
                "baseline": {n: baseline_estimate[n]["median"] for n in shared},
                "shift": shift,
                "shift_sd": shift_sd,
                "separation_se": sep,
                "indistinguishable": same,
                "material_moves": moves,
            }
        )
    return {
        "alternatives": out,
        "material_depends_on_bubble_model": any(a["indistinguishable"] and a["material_moves"] for a in out),
        "rule": f"a bubble-model alternative the held-out schemes do not separate from the baseline (< {tie_se:g} "
        f"paired SE) whose MAP moves a parameter by >= {SHIFT_REL:.0%} and >= {SHIFT_SD:g} baseline sd",
    }


def flagged(sensitivity: dict | None) -> list:
    """The alternatives of a ``bubble_model_sensitivity`` result that the data cannot separate from
    the baseline and that move the material, largest move first."""
    alts = [
        a
        for a in (sensitivity or {}).get("alternatives") or []
        if a.get("indistinguishable") and a.get("material_moves")
    ]
    return sorted(alts, key=lambda a: -max(abs(a["shift"][n]) for n in a["material_moves"]))


def options_text(alternative: dict) -> str:
    """'mass_transfer=False': the forward options an alternative changes (else its key)."""
    o = alternative.get("bubble_options") or {}
    return ", ".join(f"{k}={v}" for k, v in o.items()) or str(alternative.get("key"))
