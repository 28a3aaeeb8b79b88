"""``report.html`` of a run directory (``imrbayes report RUN_DIR``, interfaces.md §2).

One self-contained HTML file (inline style, figures as base64 PNG, no external links) holding

* the dataset (path, experiments with Rmax [µm], Req [µm], Rmax/Req, first-collapse t*), the
  preprocessing choices, forward model, prior, method settings, seed, version, runtime, warnings
  and failed or skipped units;
* the estimate (SI units) and, for MIEnKS-MDA, the per-window table;
* ArviZ summary tables (``az.summary(..., round_to="none")``, 95 % HDI) of ``posterior.nc`` and,
  when the fit ran with ``--mcmc``, of every window of ``mcmc.nc``; displayed rounded, the raw
  value of every number in the cell's tooltip (``title``);
* the ensemble-vs-MCMC comparison of ``compare.json`` per window and a plain-language list of the
  flagged windows (disagreeing and undecided ones, with the reason);
* every ``figures/*.png``, with a caption.

Parts that are absent (no ``mcmc.nc``/``compare.json`` for a fit without ``--mcmc``, no figures)
are said to be absent. Unreadable files raise :class:`~imrbayes.errors.InputError` naming the file.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import warnings
from pathlib import Path

from imrbayes import __version__
from imrbayes.ensemble import METHODS
from imrbayes.ensemble.windows import PRIOR_WEIGHT_LIMIT
from imrbayes.errors import InputError
from imrbayes.html import embed_png, esc, is_png, num, table, write_page
from imrbayes.io import read_json

__all__ = ["read_run_dir", "write_run_report", "flagged_windows", "window_phase"]

# Thresholds used when compare.json does not carry its own (imrbayes.mcmc.compare.THRESHOLDS).
_DEFAULT_THRESHOLDS = {"kl_sym": 0.1, "w2": 0.5, "kl_sample": 0.1, "rhat": 1.01, "ess_bulk": 400.0, "tau_rule": 50.0}
_CI_PROB = 0.95


def _method(summary):
    """The registered method (:data:`imrbayes.ensemble.METHODS`) that wrote ``summary``, or None."""
    name = summary.get("method")
    return METHODS.get(name) if isinstance(name, str) else None


# ----------------------------------------------------------------------------------------- loading
def _open_tree(path: Path):
    import xarray as xr

    if not path.exists():
        return None
    if not path.is_file():
        raise InputError(path, "not a file")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with xr.open_datatree(path) as dt:
                return dt.load()
    except Exception as exc:  # netCDF/HDF5 errors come in many types
        msg = " ".join(str(exc).split())
        if "did not find a match" in msg:  # xarray: no backend recognises the bytes
            raise InputError(path, "cannot be read as netCDF (not a netCDF4/HDF5 file)")
        msg = msg if len(msg) <= 160 else msg[:159] + "…"
        raise InputError(path, f"cannot be read as netCDF ({type(exc).__name__}: {msg})")


def read_run_dir(run_dir) -> dict:
    """Read and check a run directory; returns its parts (``None`` for absent optional files).

    Raises InputError (naming the file) for a missing directory, a missing or invalid
    ``summary.json``, or an unreadable ``posterior.nc``, ``mcmc.nc`` or ``compare.json``.
    """
    run_dir = Path(run_dir)
    if not run_dir.exists():
        raise InputError(run_dir, "run directory not found")
    if not run_dir.is_dir():
        raise InputError(run_dir, "not a directory (expected a run directory written by 'imrbayes fit')")
    sp = run_dir / "summary.json"
    summary = read_json(sp, required=True)
    missing = [k for k in ("method", "parameters", "estimate") if k not in summary]
    if missing:
        raise InputError(sp, f"has no {', '.join(repr(k) for k in missing)} (not written by 'imrbayes fit')")
    if not isinstance(summary["parameters"], list) or not isinstance(summary["estimate"], dict):
        raise InputError(sp, "'parameters' must be a list and 'estimate' an object")
    for key in ("windows", "time_resolved"):
        if summary.get(key) is not None and not isinstance(summary[key], list):
            raise InputError(sp, f"'{key}' must be a list")

    post = _open_tree(run_dir / "posterior.nc")
    if post is not None and "posterior" not in post.children:
        raise InputError(run_dir / "posterior.nc", "has no 'posterior' group (not written by 'imrbayes fit')")
    mcmc = _open_tree(run_dir / "mcmc.nc")
    if (
        mcmc is not None
        and not any(k.startswith("window_") for k in mcmc.children)
        and "posterior" not in mcmc.children
    ):
        raise InputError(
            run_dir / "mcmc.nc",
            "holds neither window_XX groups nor a 'posterior' group (not written by 'imrbayes fit --mcmc')",
        )
    cp = run_dir / "compare.json"
    compare = read_json(cp, required=False)
    if compare is not None:
        wins = compare.get("windows")
        if not isinstance(wins, list) or not all(isinstance(w, dict) and "index" in w for w in wins):
            raise InputError(
                cp,
                "has no 'windows' list of entries with an 'index' (not written by 'imrbayes compare' or 'fit --mcmc')",
            )
        if not isinstance(compare.get("overall", {}), dict):
            raise InputError(cp, "'overall' must be an object")
    fdir = run_dir / "figures"
    figures = sorted(fdir.glob("*.png")) if fdir.is_dir() else []
    return {
        "run_dir": run_dir,
        "summary": summary,
        "posterior": post,
        "mcmc": mcmc,
        "compare": compare,
        "figures": figures,
    }


# --------------------------------------------------------------------------------------- helpers
def _units(summary) -> dict:
    out = {"G": "Pa", "mu": "Pa s"}
    try:
        from imrbayes.forward.constitutive.base import get_model

        out.update({p.name: p.unit for p in get_model(summary.get("model", "")).parameters})
    except Exception:  # unknown model name in an old run: the default units
        pass
    return out


def _raw(x) -> str:
    """The exact value for a tooltip."""
    try:
        return repr(float(x))
    except (TypeError, ValueError):
        return esc(x)


def _ncell(x, spec=".5g", cls=None):
    c = f" {cls}" if cls else ""
    return (num(x, spec), f"class='n{c}' title='{_raw(x)}'")


def _fnum(x, default=math.nan) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return default
    return v


def _span(ts, spec=".3g") -> str:
    if not ts or len(ts) != 2:
        return "–"
    return f"{num(ts[0], spec)}–{num(ts[1], spec)}"


def _plain(v) -> str:
    """A value of summary.json as a reader wants it (HTML): numbers rounded, strings as they are,
    objects as nested ``key = value`` lists, lists of objects one per line -- never raw JSON."""
    if v is None:
        return "none"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return num(v, ".6g")
    if isinstance(v, int):
        return esc(v)
    if isinstance(v, dict):
        if not v:
            return "<i>none</i>"
        return (
            "<ul class='plain'>"
            + "".join(f"<li><code>{esc(k)}</code> = {_plain(x)}</li>" for k, x in v.items())
            + "</ul>"
        )
    if isinstance(v, (list, tuple)):
        if not v:
            return "<i>none</i>"
        if all(isinstance(x, dict) for x in v):
            return "<ul class='plain'>" + "".join(f"<li>{_plain_inline(x)}</li>" for x in v) + "</ul>"
        return ", ".join(_plain(x) for x in v)
    return esc(v)


def _plain_inline(d: dict) -> str:
    """One object on one line: ``exp_003: Req could not be estimated`` for a {name, error} pair,
    else ``key = value, ...``."""
    if set(d) >= {"name", "error"} and len(d) <= 3:
        return f"{esc(d['name'])}: {esc(d['error'])}"
    return ", ".join(f"<code>{esc(k)}</code> = {_plain(x)}" for k, x in d.items())


def _kv_list(d: dict, skip=()) -> str:
    if not d:
        return "<i>none</i>"
    items = [f"<code>{esc(k)}</code>&nbsp;=&nbsp;{_plain(v)}" for k, v in d.items() if k not in skip]
    return ", ".join(items) if items else "<i>none</i>"


def _kv_table(d: dict, skip=()) -> str:
    """A key-value table (no header row) of an object of summary.json."""
    rows = [(f"<code>{esc(k)}</code>", _plain(v)) for k, v in d.items() if k not in skip]
    return table(None, rows, cls="kv") if rows else "<p><i>none</i></p>"


# display units of the parameters people read most (SI otherwise): G in kPa, mu in Pa s
_DISPLAY = {"G": (1e-3, "kPa"), "mu": (1.0, "Pa s")}
_NUISANCE = {"rmax_m": ("Rmax", 1e6, "µm"), "req_m": ("Req", 1e6, "µm"), "t0_s": ("t0", 1e6, "µs")}


def _disp(name, units) -> tuple:
    """(factor from SI, unit) in which ``name`` is shown in the conclusion."""
    return _DISPLAY.get(name, (1.0, units.get(name, "")))


def _q(x, name, units, spec=".3g", unit=True) -> str:
    """``x`` (SI) in the display unit of ``name``: ``11 kPa``."""
    f, u = _disp(name, units)
    v = _fnum(x)
    if not math.isfinite(v):
        return "–"
    return num(v * f, spec) + (f" {u}" if unit and u else "")


def _qrange(lo, hi, name, units, spec=".3g") -> str:
    if not (math.isfinite(_fnum(lo)) and math.isfinite(_fnum(hi))):
        return "–"
    return f"{_q(lo, name, units, spec, unit=False)}–{_q(hi, name, units, spec)}"


#: an interval wider than this factor (high / low) is not a measurement: the data do not bound it
UNBOUNDED_FACTOR = 100.0


def _box(summary, name) -> tuple:
    """(low, high) edges of ``name``'s prior box (a grid method's ``{name}_min``/``{name}_max``
    settings, SI), NaN where the run has none."""
    st = ((summary or {}).get("details") or {}).get("settings") or {}
    return _fnum(st.get(f"{name}_min")), _fnum(st.get(f"{name}_max"))


def bounds(e: dict, name: str = "", summary=None) -> tuple:
    """(lower bounded, upper bounded) by the data for estimate object ``e``.

    The fit's own answer (``e["bounded"]``, ``{"lower": bool, "upper": bool}``) wins where present.
    Otherwise the 95 % interval [lo, hi] is read: an end that reaches the prior box's edge (a grid
    method's ``{name}_min``/``{name}_max``, within 1 %) is not bounded by the data, and an interval
    spanning more than :data:`UNBOUNDED_FACTOR` (hi / lo > 100, or lo <= 0 < hi) bounds neither
    end: it says where the data are not, not where the parameter is. No interval but an sd: both
    (the sd is the method's answer); neither an interval nor an sd: neither.
    """
    b = e.get("bounded")
    if isinstance(b, dict):
        return bool(b.get("lower", True)), bool(b.get("upper", True))
    hdi = e.get("hdi95") or [None, None]
    lo, hi = (_fnum(hdi[0]), _fnum(hdi[1])) if len(hdi) == 2 else (math.nan, math.nan)
    if not (math.isfinite(lo) and math.isfinite(hi)):
        sd = _fnum(e.get("sd"))
        return (True, True) if math.isfinite(sd) else (False, False)
    bmin, bmax = _box(summary, name)
    lower = not (math.isfinite(bmin) and lo <= bmin + 0.01 * abs(bmax - bmin if math.isfinite(bmax) else bmin))
    upper = not (math.isfinite(bmax) and hi >= bmax - 0.01 * abs(bmax - (bmin if math.isfinite(bmin) else 0.0)))
    if hi > 0 and (lo <= 0 or hi / lo > UNBOUNDED_FACTOR):
        return False, False
    return lower, upper


def _liquid(summary, name: str) -> bool:
    """Whether the fit found ``name`` consistent with 0 (a liquid's G): no spread to report."""
    return bool((((summary or {}).get("estimate") or {}).get(name) or {}).get("consistent_with_zero"))


def estimate_phrase(name: str, e: dict, units: dict, summary=None) -> str:
    """One parameter's estimate in words with units on every number (plain text):
    ``G = 13.5 kPa ± 0.6 kPa (95 % 12.3-14.7 kPa)``, ``G not bounded by the data (best fit 7.3 kPa)``,
    ``G consistent with 0 (95 % upper bound 1.2 kPa)``, ``G on a ridge 2.1-30 kPa (best fit 7.3 kPa)``."""
    mean, sd = _fnum(e.get("mean")), _fnum(e.get("sd"))
    if e.get("consistent_with_zero"):
        up = _fnum(e.get("upper95"))
        return f"{name} consistent with 0" + (
            f" (95 % upper bound {_txt(up, name, units)})" if math.isfinite(up) else ""
        )
    if not math.isfinite(mean):
        return f"{name}: no estimate"
    hdi = e.get("hdi95") or [None, None]
    lo, hi = (_fnum(hdi[0]), _fnum(hdi[1])) if len(hdi) == 2 else (math.nan, math.nan)
    if e.get("ridge") and not math.isfinite(sd):
        r = e["ridge"]
        return (
            f"{name} on a ridge {_txt(r[0], name, units, unit=False)}-{_txt(r[1], name, units)} "
            f"(best fit {_txt(mean, name, units)})"
        )
    if not (math.isfinite(sd) or math.isfinite(lo)):
        return f"{name} = {_txt(mean, name, units, '.4g')} (no interval)"
    lower, upper = bounds(e, name, summary)
    if not lower and not upper:
        return f"{name} not bounded by the data (best fit {_txt(mean, name, units)})"
    if lower and not upper:
        return f"{name} above {_txt(lo, name, units)} (upper end not bounded by the data; best fit {_txt(mean, name, units)})"
    if upper and not lower:
        return f"{name} below {_txt(hi, name, units)} (lower end not bounded by the data; best fit {_txt(mean, name, units)})"
    out = f"{name} = {_txt(mean, name, units, '.4g')}"
    if math.isfinite(sd):
        out += f" ± {_txt(sd, name, units, '.2g')}"
    if math.isfinite(lo) and math.isfinite(hi):
        out += f" (95 % {_txt(lo, name, units, unit=False)}-{_txt(hi, name, units)})"
    return out


def _txt(x, name, units, spec=".3g", unit=True) -> str:
    """``x`` (SI) as plain text in ``name``'s display unit: ``13.5 kPa``."""
    f, u = _disp(name, units)
    v = _fnum(x)
    if not math.isfinite(v):
        return "–"
    return format(v * f, spec) + (f" {u}" if unit and u else "")


def model_label(summary) -> str:
    """The constitutive model's name as people write it (``NHKV``)."""
    return str((summary or {}).get("model", "the model")).upper()


def fit_check_sentence(summary) -> str | None:
    """The fit-adequacy check in one plain sentence (``summary["fit_check"]``), or None without one.
    A model that does not describe the records says so first and points at ``imrbayes diagnose``."""
    fc = (summary or {}).get("fit_check")
    if not isinstance(fc, dict) or "described" not in fc:
        return None
    model = model_label(summary)
    ratio = _fnum(fc.get("residual_to_noise"))
    times = f"{ratio:.2g}x" if math.isfinite(ratio) else "several times"
    if fc.get("described") is False:
        return (
            f"{model} does not describe these records: the residual is {times} their noise; these numbers are "
            f"the best {model} fit, not the material's properties -- `imrbayes diagnose` looks for the cause."
        )
    msg = str(fc.get("message") or "").strip()
    return msg or f"{model} describes these records: the residual is {times} their noise."


def prior_sentence(summary, units) -> str | None:
    """Which prior the run used and how much of each posterior is the data's (``summary["prior"]``
    ``name`` and ``data_share``: 1 - posterior var / prior var), or None when the run records neither."""
    prior = (summary or {}).get("prior") or {}
    name, share = prior.get("name"), prior.get("data_share")
    if name is None and not isinstance(share, dict):
        return None
    words = {"wide": "the wide default prior", "paper": "the paper's prior", "custom": "a prior set for this run"}
    out = f"Prior: {words.get(name, str(name))}" if name is not None else "Prior"
    if isinstance(share, dict) and share:
        bits = [f"{p} {100 * _fnum(v):.0f} %" for p, v in share.items() if math.isfinite(_fnum(v))]
        out += "; share of the posterior that comes from the data: " + ", ".join(bits)
        weak = [p for p, v in share.items() if _fnum(v) < 0.5]
        if weak:
            out += f" ({' and '.join(weak)} mostly the prior)"
    return out + "."


def name_parameters(text: str, names) -> str:
    """``parameter 1`` (a 0-based index into ``names``) written as the parameter's name (``mu``)."""
    import re

    names = list(names or [])

    def sub(m):
        i = int(m.group(1))
        return names[i] if 0 <= i < len(names) else m.group(0)

    return re.sub(r"\bparameter (\d+)\b", sub, str(text))


def grouped_warnings(warnings, names=()) -> list:
    """Warnings with parameter indices named, near-identical ones (the same words, other numbers:
    one per window) said once with their count: ``... (14 times, e.g. windows 3-16)`` style."""
    import re

    groups: dict = {}
    for w in warnings:
        w = name_parameters(w, names)
        key = re.sub(r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?", "#", w)
        groups.setdefault(key, []).append(w)
    out = []
    for items in groups.values():
        out.append(
            items[0] if len(items) == 1 else f"{items[0]} (and {len(items) - 1} more like it: {len(items)} in all)"
        )
    return out


def truth(summary) -> dict:
    """Synthetic data's true parameters (``truth.json`` beside the data: ``parameters``, SI), or {}."""
    data = (summary or {}).get("data")
    if not data:
        return {}
    from imrbayes.io import read_json

    path = Path(data)
    path = path if path.is_dir() else path.parent
    try:
        t = read_json(path / "truth.json", required=False)
    except Exception:  # an unreadable truth file marks nothing
        return {}
    params = (t or {}).get("parameters") if isinstance(t, dict) else None
    return {k: float(v) for k, v in (params or {}).items() if math.isfinite(_fnum(v))}


def _prior_log_sd(s) -> dict:
    """Prior sd per parameter in the internal coordinates (log for log-normal parameters)."""
    prior = s.get("prior") or (s.get("details") or {}).get("parameter_space") or {}
    names = prior.get("names") or list(prior.get("prior_si") or {})
    cov = prior.get("prior_internal_cov")
    out = {}
    try:
        for i, n in enumerate(names):
            out[n] = math.sqrt(float(cov[i][i]))
    except (TypeError, IndexError, ValueError):
        ls = prior.get("log_space") or {}
        for n, v in (prior.get("prior_si") or {}).items():
            m, sd = _fnum((v or {}).get("mean")), _fnum((v or {}).get("sd"))
            if ls.get(n, True) and m > 0 and sd > 0:
                out[n] = math.sqrt(math.log1p((sd / m) ** 2))
            elif sd > 0:
                out[n] = sd
    return out


def _post_internal_sd(e, log: bool) -> float:
    """Posterior sd in the internal coordinates from an estimate object (its 95 % interval, else
    its sd): the same yardstick as the prior's."""
    hdi = e.get("hdi95") or [None, None]
    lo, hi = _fnum(hdi[0]) if len(hdi) == 2 else math.nan, _fnum(hdi[1]) if len(hdi) == 2 else math.nan
    if math.isfinite(lo) and math.isfinite(hi) and hi > lo and (not log or lo > 0):
        return (math.log(hi) - math.log(lo) if log else hi - lo) / (2 * 1.959964)
    m, sd = _fnum(e.get("mean")), _fnum(e.get("sd"))
    if math.isfinite(sd) and sd > 0:
        return sd / m if log and m > 0 else (sd if not log else math.nan)
    return math.nan


def constraint_ratios(s, estimate=None) -> dict:
    """Per parameter: posterior width / prior width (internal coordinates; 1 = the data said nothing)."""
    est = s.get("estimate") if estimate is None else estimate
    prior_sd = _prior_log_sd(s)
    ls = ((s.get("prior") or {}).get("log_space")) or {}
    out = {}
    for p, e in (est or {}).items():
        if p in prior_sd and isinstance(e, dict):
            r = _post_internal_sd(e, bool(ls.get(p, True))) / prior_sd[p]
            if math.isfinite(r):
                out[p] = r
    return out


def window_ratios(s) -> list:
    """Per MIEnKS window: {parameter: posterior sd / prior sd} in the internal coordinates."""
    prior_sd = _prior_log_sd(s)
    names = s.get("parameters", [])
    out = []
    for w in s.get("windows") or []:
        r = {}
        cov = (w or {}).get("cov_internal")
        for i, p in enumerate(names):
            try:
                r[p] = math.sqrt(float(cov[i][i])) / prior_sd[p]
            except (TypeError, IndexError, KeyError, ValueError, ZeroDivisionError):
                pass
        out.append(r)
    return out


#: posterior / prior width at or above which the data "say little" (the window "barely moved")
SAYS_LITTLE = 0.8


def _collapse_time(summary) -> float:
    pre = summary.get("preprocessing") or {}
    s = (pre.get("summary") or {}).get("t_collapse_star") or {}
    tc = _fnum(s.get("mean"))
    if math.isfinite(tc):
        return tc
    vals = [_fnum(e.get("t_collapse_star")) for e in pre.get("experiments") or [] if isinstance(e, dict)]
    vals = [v for v in vals if math.isfinite(v)]
    return sum(vals) / len(vals) if vals else math.nan


def window_phase(t_star, tc: float, tol: float = 0.05) -> str:
    """Where a window lies relative to the mean first-collapse time ``tc`` (t*), in words."""
    if not t_star or len(t_star) != 2 or not math.isfinite(tc):
        return ""
    a, b = float(t_star[0]), float(t_star[1])
    if b < tc - tol:
        return "before the first collapse"
    if a > tc + tol:
        return "after the first collapse"
    if b > 2.0 * tc:
        return "from before the first collapse through the rebounds after it"
    return "around the first collapse"


# ---------------------------------------------------------------------------- flagged windows
def _thresholds(compare) -> dict:
    return {**_DEFAULT_THRESHOLDS, **((compare.get("overall") or {}).get("thresholds") or {})}


def _entry_diag(e) -> dict:
    m = e.get("mcmc") or {}
    rh = [_fnum(v) for v in (m.get("rhat") or {}).values()]
    es = [_fnum(v) for v in (m.get("ess_bulk") or {}).values()]
    sampler = m.get("sampler") or {}
    return {
        "rhat": max(rh) if rh else math.nan,
        "ess": min(es) if es else math.nan,
        "n_over_tau": _fnum(sampler.get("n_steps_over_tau")),
        "tau_ok": sampler.get("all_tau_ok"),
        "n_chains": m.get("n_chains"),
        "n_steps": sampler.get("n_steps"),
        "n_draws": m.get("n_draws"),
    }


def _shape_words(e) -> str | None:
    neg = e.get("negentropy") or {}
    mar = e.get("mardia") or {}
    parts = []
    if _fnum(mar.get("skew_p"), 1.0) < 1e-3:
        parts.append("skewed")
    kz = _fnum(mar.get("kurt_z"), 0.0)
    if _fnum(mar.get("kurt_p"), 1.0) < 1e-3:
        parts.append("heavy-tailed" if kz > 0 else "light-tailed")
    non_gauss = _fnum(neg.get("estimate"), 0.0)
    curved = _fnum(neg.get("raw"), -1.0) > _fnum(neg.get("null_q99"), math.inf)
    if not parts and (curved or non_gauss > 0.05):
        parts.append("non-Gaussian (curved)")
    if not parts:
        return None
    return (
        f"the MCMC posterior is {' and '.join(parts)} (negentropy {num(non_gauss, '.2g')} nats, "
        f"Mardia skewness p = {num(mar.get('skew_p'), '.2g')}, kurtosis z = {num(mar.get('kurt_z'), '.2f')})"
    )


def _moment_words(e) -> list:
    out = []
    shift = {k: _fnum(v) for k, v in (e.get("mean_shift_sd") or {}).items()}
    shift = {k: v for k, v in shift.items() if math.isfinite(v)}
    if shift:
        k = max(shift, key=lambda n: abs(shift[n]))
        if abs(shift[k]) >= 0.25:
            out.append(
                f"the ensemble mean of {k} lies {num(abs(shift[k]), '.2g')} MCMC posterior sd "
                f"{'above' if shift[k] > 0 else 'below'} the MCMC mean"
            )
    ratio = {k: _fnum(v) for k, v in (e.get("sd_ratio") or {}).items()}
    ratio = {k: v for k, v in ratio.items() if math.isfinite(v) and v > 0}
    if ratio:
        k = max(ratio, key=lambda n: abs(math.log(ratio[n])))
        if abs(math.log(ratio[k])) >= math.log(1.25):
            out.append(
                f"the ensemble sd of {k} is {num(ratio[k], '.2g')}× the MCMC sd "
                f"({'too narrow' if ratio[k] < 1 else 'too wide'})"
            )
    return out


def _criteria_words(e, th) -> list:
    crit = e.get("criteria") or {}
    neg = _fnum((e.get("negentropy") or {}).get("estimate"), 0.0)
    out = []
    kl_sym, w2, kls = _fnum(e.get("kl_sym")), _fnum(e.get("w2")), _fnum(e.get("kl_sample"))
    if crit.get("kl_sym") is False or (not crit and kl_sym > th["kl_sym"]):
        out.append(f"symmetric KL {num(kl_sym, '.2g')} nats > {num(th['kl_sym'], 'g')}")
    if crit.get("w2") is False or (not crit and w2 > th["w2"]):
        out.append(f"W2 {num(w2, '.2g')} posterior sd > {num(th['w2'], 'g')}")
    if crit.get("kl_sample") is False or (not crit and kls > th["kl_sample"]):
        out.append(
            f"sample KL {num(kls, '.2g')} nats > {num(th['kl_sample'], 'g')} "
            f"(Gaussian part {num(e.get('kl_gauss'), '.2g')}, non-Gaussian part {num(neg, '.2g')})"
        )
    return out


def _longer(d, th) -> str:
    """A suggested ``n_steps`` that would meet the tau rule and the bulk-ESS threshold (ESS and
    chain length in tau both grow about linearly with the steps)."""
    n = _fnum(d["n_steps"])
    if not math.isfinite(n) or n <= 0:
        return "n_steps=…"
    f = 1.0
    if math.isfinite(d["n_over_tau"]) and d["n_over_tau"] > 0:
        f = max(f, th["tau_rule"] / d["n_over_tau"])
    if math.isfinite(d["ess"]) and d["ess"] > 0:
        f = max(f, th["ess_bulk"] / d["ess"])
    return f"n_steps={int(math.ceil(1.2 * f * n / 100.0) * 100)}"


def flagged_windows(compare: dict, summary: dict | None = None) -> list:
    """Plain-language lines (plain text, not HTML) for every window whose ``agree`` is not true
    (disagreeing: which criterion failed and how; undecided: why the MCMC is not trusted), for
    windows whose MCMC failed and for windows that were not sampled; ``[]`` when all agree."""
    if not compare:
        return []
    summary = summary or {}
    th = _thresholds(compare)
    tc = _collapse_time(summary)
    tc_txt = f" (mean first collapse t* ≈ {num(tc, '.3g')})" if math.isfinite(tc) else ""
    lines = []
    for e in sorted(compare.get("windows") or [], key=lambda w: w.get("index", 0)):
        agree = e.get("agree")
        if agree is True:
            continue
        ts = e.get("t_star")
        phase = window_phase(ts, tc)
        where = f"t* {_span(ts)}" + (f", {phase}{tc_txt}" if phase else "")
        head = f"Window {e.get('index')} ({where})"
        if agree is False:
            why = _criteria_words(e, th)
            shape, moments = [w for w in (_shape_words(e),) if w], _moment_words(e)
            # lead with what dominates KL(MCMC || ensemble): location/scale (Gaussian part) or shape
            neg = _fnum((e.get("negentropy") or {}).get("estimate"), 0.0)
            what = shape + moments if neg > _fnum(e.get("kl_gauss"), 0.0) else moments + shape
            text = (
                f"{head}: disagrees — {'; '.join(what + why) if (what or why) else e.get('notes', '')}; "
                "the Gaussian ensemble approximation is not adequate here."
            )
        else:
            d = _entry_diag(e)
            why = []
            if not (e.get("mcmc") or {}).get("rhat") and (d["n_chains"] or 0) < 2:
                why.append("only one chain, so R-hat cannot be computed")
            if math.isfinite(d["rhat"]) and d["rhat"] > th["rhat"]:
                why.append(f"max R-hat {num(d['rhat'], '.4f')} > {num(th['rhat'], 'g')}")
            if math.isfinite(d["ess"]) and d["ess"] < th["ess_bulk"]:
                why.append(f"min bulk ESS {num(d['ess'], '.0f')} < {num(th['ess_bulk'], 'g')}")
            if d["tau_ok"] is False:
                why.append(
                    f"chains only {num(d['n_over_tau'], '.3g')} autocorrelation times long "
                    f"(< {num(th['tau_rule'], 'g')} τ)"
                )
            if not why:
                why.append(e.get("notes") or "the MCMC run does not meet the convergence criteria")
            prov = _criteria_words(e, th)
            prov_txt = (
                f" Provisional metrics (not to be trusted yet): {'; '.join(prov)}."
                if prov
                else " The provisional metrics are within the agreement thresholds."
            )
            steps = f" than {d['n_steps']} steps" if d["n_steps"] else ""
            text = (
                f"{head}: undecided — the MCMC reference is not trustworthy: {'; '.join(why)}. "
                f"Sample longer{steps} (e.g. --mcmc-set {_longer(d, th)}) and rerun.{prov_txt}"
            )
        lines.append(text)
    overall = compare.get("overall") or {}
    for f in overall.get("failed_windows") or []:
        if isinstance(f, dict):
            lines.append(
                f"Window {f.get('window')} (t* {_span(f.get('t_star'))}): the MCMC failed "
                f"({f.get('error', 'unknown error')}); no comparison."
            )
    sampled = {w.get("index") for w in compare.get("windows") or []}
    failed = {f.get("window") for f in overall.get("failed_windows") or [] if isinstance(f, dict)}
    rest = [
        w.get("index")
        for w in summary.get("windows") or []
        if isinstance(w, dict) and w.get("index") not in sampled | failed
    ]
    if rest and sampled:
        lines.append(
            f"Not sampled by MCMC (no comparison): window{'s' if len(rest) > 1 else ''} "
            f"{', '.join(str(i) for i in rest)}."
        )
    return lines


# ----------------------------------------------------------------------------------- sections
def _warnings_list(s) -> list:
    """Every warning of the run (run, preprocessing, per experiment), de-duplicated, in order."""
    warn = []
    for w in (
        list(s.get("warnings") or [])
        + list(s.get("warnings_preprocessing") or [])
        + list((s.get("preprocessing") or {}).get("warnings") or [])
    ):
        if w not in warn:
            warn.append(w)
    for e in (s.get("preprocessing") or {}).get("experiments") or []:
        for w in (e.get("warnings") or []) if isinstance(e, dict) else []:
            item = f"{e.get('name')}: {w}"
            if item not in warn:
                warn.append(item)
    return warn


def _duration(seconds: float) -> str:
    if not math.isfinite(seconds) or seconds <= 0:
        return ""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    if seconds < 2 * 86400:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:.1f} days"


def _mcmc_eta(s) -> str:
    """What ``--mcmc`` costs with the default emcee settings, in words: the evaluations per window and
    minutes or hours per window depending on the bubble model this fit used."""
    try:
        from imrbayes.mcmc import MCMCSettings

        d = MCMCSettings()
        evals = d.n_walkers * d.n_steps * d.n_chains
        head = f"{d.n_walkers} walkers × {d.n_steps} steps × {d.n_chains} ensembles = {evals:,} evaluations"
    except Exception:  # an unusual installation: no numbers
        head = "the default emcee settings"
    n_win = len(s.get("windows") or [])
    per = f" in each of {n_win} windows" if n_win > 1 else ""
    bubble = str((((s.get("forward") or {}).get("options")) or {}).get("bubble", "thermal"))
    speed = (
        "minutes per window with this fit's polytropic bubble"
        if bubble == "polytropic"
        else "hours per window with this fit's thermal bubble"
    )
    return f" ({head}{per}: {speed}; --mcmc-windows and --mcmc-set n_steps=... make it shorter)"


def _mcmc_words(run) -> str:
    """The MCMC agreement in one sentence (HTML)."""
    s, compare = run["summary"], run["compare"]
    meth = _method(s)
    name = s.get("method", "?")
    if compare is not None:
        ov = compare.get("overall") or {}
        wins = sorted(compare.get("windows") or [], key=lambda w: w.get("index", 0))
        n = len(wins)
        dis = [w for w in wins if w.get("agree") is False]
        und = [w for w in wins if w.get("agree") is None]
        ok = [w for w in wins if w.get("agree") is True]
        where = (
            (lambda ws: "window" + ("s " if len(ws) > 1 else " ") + ", ".join(str(w.get("index")) for w in ws))
            if n > 1
            else (lambda ws: "the fitting window")
        )
        parts = []
        if ok:
            parts.append(f"emcee agrees with the ensemble Gaussian in {len(ok)} of {n} sampled window(s)")
        if dis:
            units = _units(s)
            nums = []
            for w in dis[:3]:
                m, sd = (w.get("mcmc") or {}).get("mean") or {}, (w.get("mcmc") or {}).get("sd") or {}
                txt = ", ".join(
                    f"{esc(p)} = {_q(m.get(p), p, units)} ± {_q(sd.get(p), p, units, '.2g', unit=False)}"
                    for p in s.get("parameters", [])
                    if p in m
                )
                if txt:
                    nums.append((f"window {esc(w.get('index'))}: " if n > 1 else "") + txt)
            parts.append(
                f"<span class='caveat'>disagrees in {where(dis)}: believe the MCMC posterior there, not the "
                f"Gaussian" + (f" (emcee: {'; '.join(nums)})" if nums else "") + "; see Flagged windows</span>"
            )
        if und:
            parts.append(
                f"<span class='caveat'>undecided in {where(und)}: the emcee chains did not converge, so the "
                "check says nothing yet (sample longer: see Flagged windows)</span>"
            )
        if ov.get("failed_windows"):
            parts.append(f"<span class='caveat'>the MCMC failed in {len(ov['failed_windows'])} window(s)</span>")
        return "MCMC check: " + ("; ".join(parts) if parts else "no window compared") + "."
    if meth is not None and not meth.gaussian_posterior:
        return f"MCMC check: not applicable ({esc(meth.label)} gives no Gaussian posterior for emcee to check)."
    if run["mcmc"] is not None:
        return "MCMC check: mcmc.nc is here but compare.json is not: run <code>imrbayes compare RUN_DIR</code>."
    return (
        f"MCMC check: not run. To check the Gaussian posterior against emcee: <code>imrbayes fit DATA --method "
        f"{esc(name)} --mcmc</code>{esc(_mcmc_eta(s))}."
    )


def _section_conclusion(run) -> str:
    """The block a rheologist reads first: gel-level estimate with units and its interval, the
    bubble-to-bubble spread, a new bubble's range, the MCMC agreement, what the data did not
    constrain, and the caveats. Every number comes from summary.json (and compare.json)."""
    s = run["summary"]
    units = _units(s)
    head = _conclusion_head(s, units)
    items = _conclusion_scatter(s, units)
    items.append(_mcmc_words(run))
    prior_words = prior_sentence(s, units)
    if prior_words:
        items.append(esc(prior_words))
    items += _conclusion_constraints(s)
    items += _conclusion_nuisances(s)
    items += _conclusion_caveats(s, units)
    return (
        "<h2 id='conclusion'>Conclusion</h2><div class='conclusion'>"
        + head
        + "<ul>"
        + "".join(f"<li>{i}</li>" for i in items)
        + "</ul></div>"
    )


def _conclusion_head(s: dict, units) -> str:
    """The conclusion's opening: the gel-level estimate of each parameter (with the truth where known)
    and the fit check, the check first where the model does not describe the records.

    Parameters
    ----------
    s : dict
        summary.json's content.
    units
        The display units of the parameters (:func:`_units`).

    Returns
    -------
    str
        HTML paragraphs.
    """
    params = s.get("parameters", [])
    est = s["estimate"]
    meth = _method(s)
    n_exp = s.get("n_experiments")
    label = meth.label if meth is not None else s.get("method", "?")
    true = truth(s)
    phrases = []
    for p in params:
        txt = esc(estimate_phrase(p, est.get(p) or {}, units, s))
        if p in true:
            txt += f" (truth {esc(_txt(true[p], p, units, '.4g'))})"
        phrases.append(txt)
    what = f"({esc(s.get('model', '?'))}, {esc(n_exp)} experiment(s), {esc(label)})"
    check = fit_check_sentence(s)
    if check and (s.get("fit_check") or {}).get("described") is False:
        # the model does not describe the records: that is the conclusion, the numbers only its detail
        head = (
            f"<p class='caveat'><b>{esc(check)}</b></p><p>Best {esc(model_label(s))} fit {what}: "
            f"{'; '.join(phrases)}.</p>"
        )
    else:
        head = f"<p><b>Gel-level estimate</b> {what}: <b>{'</b>; <b>'.join(phrases)}</b>.</p>"
        if check:
            head += f"<p>{esc(check)}</p>"
    return head


def _conclusion_scatter(s: dict, units) -> list:
    """The conclusion's items on the bubble-to-bubble spread and a new bubble's predictive range.

    Parameters
    ----------
    s : dict
        summary.json's content.
    units
        The display units of the parameters (:func:`_units`).

    Returns
    -------
    list of str
        HTML list items.
    """
    params = s.get("parameters", [])
    n_exp = s.get("n_experiments")
    items = []
    # bubble-to-bubble spread and a new bubble
    be, pred = s.get("between_experiments"), s.get("predictive")
    if n_exp == 1:
        items.append(
            "One experiment: bubble-to-bubble scatter unknown (one bubble cannot show how much the next one differs)."
        )
    elif isinstance(be, dict) and be:
        bits = []
        for p in params:
            b = be.get(p) or {}
            hd = b.get("hdi95") or [None, None]
            if _liquid(s, p):
                bits.append(f"{esc(p)}: none to report (consistent with 0)")
            elif len(hd) == 2 and hd[0] is not None and _fnum(hd[0]) <= 0 < _fnum(hd[1]):
                bits.append(f"{esc(p)} sd below {_q(hd[1], p, units)} (consistent with no scatter)")
            elif len(hd) == 2 and hd[0] is not None and not all(bounds({"hdi95": hd}, p, s)):
                bits.append(f"{esc(p)} sd not bounded by the data")
            else:
                bits.append(
                    f"{esc(p)} sd {_q(b.get('sd'), p, units)}"
                    + (f" (95 % {_qrange(hd[0], hd[1], p, units)})" if len(hd) == 2 and hd[0] is not None else "")
                )
        items.append("Between bubbles (scatter of the gel from bubble to bubble): " + "; ".join(bits) + ".")
    else:
        rng = []
        for p, (lo, hi) in _per_experiment_range(s).items():
            rng.append(f"{esc(p)} {_qrange(lo, hi, p, units)}")
        items.append(
            "Between bubbles: not estimated by this run"
            + (f"; the per-experiment estimates span {', '.join(rng)}" if rng else "")
            + "."
        )
    if isinstance(pred, dict) and pred:
        bits = []
        for p in params:
            b = pred.get(p) or {}
            hd = b.get("hdi95") or [None, None]
            if _liquid(s, p):
                bits.append(f"{esc(p)} consistent with 0")
            elif len(hd) == 2 and hd[0] is not None and not all(bounds({"hdi95": hd}, p, s)):
                bits.append(f"{esc(p)} not bounded by the data")
            else:
                bits.append(f"{esc(p)} {_qrange(hd[0], hd[1], p, units)}" if len(hd) == 2 else f"{esc(p)} –")
        items.append("A new bubble of this gel (95 % predictive range): " + "; ".join(bits) + ".")
    return items


def _conclusion_constraints(s: dict) -> list:
    """The conclusion's items on what the data did not constrain: ridges, each parameter's posterior
    width against the prior's, windows the data barely moved and prior-dominated windows.

    Parameters
    ----------
    s : dict
        summary.json's content.

    Returns
    -------
    list of str
        HTML list items.
    """
    params = s.get("parameters", [])
    est = s["estimate"]
    items = []
    # what the data did not constrain
    ratios = constraint_ratios(s)
    ridge = [p for p in params if p not in ratios and (est.get(p) or {}).get("ridge")]
    if ridge:
        items.append(
            f"<span class='caveat'>{esc(' and '.join(ridge))}: the data fix only a combination of the "
            "parameters (a ridge), not each one on its own.</span>"
        )
    for p in params:
        r = ratios.get(p)
        if r is None:
            continue
        pct = f"{100 * r:.0f} % of the prior's width"
        if r >= SAYS_LITTLE:
            items.append(
                f"<span class='caveat'>{esc(p)}: posterior as wide as the prior — the data say little "
                f"({pct}); the estimate is mostly the prior.</span>"
            )
        elif r >= 0.5:
            items.append(f"{esc(p)}: only partly constrained by the data (posterior {pct}).")
        else:
            items.append(f"{esc(p)}: constrained by the data (posterior {pct}).")
    wr = window_ratios(s)
    wins = s.get("windows") or []
    barely = [w for w, r in zip(wins, wr) if r and max(r.values()) >= SAYS_LITTLE]
    if barely:
        spans = ", ".join(f"{esc(w.get('index'))} (t* {_span(w.get('t_star'))})" for w in barely)
        items.append(
            f"<span class='caveat'>Window{'s' if len(barely) > 1 else ''} {spans}: the data barely moved "
            f"the prior (posterior ≥ {100 * SAYS_LITTLE:.0f} % of its width).</span>"
        )
    dominated = [w for w in wins if isinstance(w, dict) and w.get("prior_dominated")]
    if dominated:
        spans = ", ".join(f"{esc(w.get('index'))} (t* {_span(w.get('t_star'))})" for w in dominated)
        items.append(
            f"<span class='caveat'>Prior-dominated window{'s' if len(dominated) > 1 else ''} {spans}: the "
            f"parameter prior's mean keeps more than {PRIOR_WEIGHT_LIMIT:.0%} of the weight in these window means (directly or "
            "through the chain of window priors; a linearised lower bound), so a trend that starts in them "
            "is not evidence of time-dependent material (hatched in the parameters figure).</span>"
        )
    return items


def _conclusion_nuisances(s: dict) -> list:
    """The conclusion's items on Rmax, Req and the time origin estimated per experiment: how Req's
    prior was centred and where that biases the windows.

    Parameters
    ----------
    s : dict
        summary.json's content.

    Returns
    -------
    list of str
        HTML list items (none without nuisance parameters).
    """
    wins = s.get("windows") or []
    items = []
    per = s.get("per_experiment") or []
    if any(isinstance(x, dict) and x.get("nuisance") for x in per):
        items.append(
            "Rmax, Req and the time origin were estimated per experiment with the material (nuisance "
            "parameters): see Experiments."
        )
        req_inferred = any(
            _fnum(((x.get("nuisance") or {}).get("req_m") or {}).get("prior_sd")) > 0
            for x in per
            if isinstance(x, dict)
        )
        req_from_fit = ((s.get("details") or {}).get("req_prior") or {}).get("method") == "en4dvar"
        rt = (s.get("details") or {}).get("req_tail") or {}
        moved = [f for f in (_fnum(x) for x in rt.get("factor") or []) if math.isfinite(f) and f != 1.0]
        if rt.get("method") in ("model", "inline") and moved:
            inline = rt.get("method") == "inline"
            items.append(
                f"Req's prior was centred by the model's own tail (req_tail={rt.get('method')}"
                f"{', the default for the thermal bubble' if rt.get('setting') == 'auto' else ''}): "
                + (
                    f"the record's tail mean lies {100 * (min(moved) - 1):.1f}–{100 * (max(moved) - 1):.1f} % above Req"
                    if min(moved) > 1
                    else f"the record's tail mean differs from Req by {100 * (min(moved) - 1):+.1f} "
                    f"to {100 * (max(moved) - 1):+.1f} %"
                )
                + f" in {len(moved)} of {len(rt.get('factor'))} experiments, "
                + (
                    "each experiment's first-cycle posterior placed the material and its later cycles fitted "
                    "with Req moved"
                    if inline
                    else (
                        f"the {(rt.get('start') or {}).get('source')} placed the material"
                        if rt.get("start")
                        else "a quick first fit placed the material"
                    )
                    + ", and the estimate is the fit after it"
                )
                + "."
            )
        rp = (s.get("details") or {}).get("req_prior") or {}
        conflicts = rp.get("conflicts") or []
        bound = _fnum(rp.get("conflict_z", 3.0))
        if len(wins) > 1 and req_from_fit:
            items.append(
                "Each estimated Req's prior came from a whole-record En4D-Var fit of the same data "
                "(req_prior=en4dvar, the default), so the early windows start from the Req the record's tail decides."
            )
            if conflicts:
                items.append(
                    f"<span class='caveat'>In {len(conflicts)} experiment{'s' if len(conflicts) > 1 else ''} "
                    f"({esc(', '.join(str(c.get('experiment')) for c in conflicts))}) that fit put Req more "
                    f"than {bound:g} prior sd from the record's own tail (a model that needs another bubble "
                    "size to fit the collapses); those experiments kept the record's Req prior.</span>"
                )
        elif len(wins) > 1 and req_inferred:
            # measured on camera-style synthetic records of a constant gel (docs/validation.md, "Where the
            # decline of the decided windows comes from", 20 seeds): with Req inferred the mu windows fell
            # and the aggregate was G +17 %, mu +12 %; with the true Req given, flat and G +4 %, mu +1 %
            items.append(
                "<span class='caveat'>Req was estimated from each record's tail and inferred window by "
                "window (its prior sd > 0): on camera-style synthetic records of a constant gel that alone made the windows' mu "
                "fall through the record and the aggregate G and mu 10-20 % high (with the true Req given: "
                "flat, both within 5 %). A decline of mu(t) of that size is not evidence of time-dependent "
                "material; where Req was measured, give it in meta.json (Req_m, Req_sd_m).</span>"
            )
    return items


def _conclusion_caveats(s: dict, units) -> list:
    """The conclusion's closing items: the caveats (warnings, failures, a gel-level estimate no
    experiment supports, pIMR's limits) and the fit's RMSE.

    Parameters
    ----------
    s : dict
        summary.json's content.
    units
        The display units of the parameters (:func:`_units`).

    Returns
    -------
    list of str
        HTML list items.
    """
    params = s.get("parameters", [])
    est = s["estimate"]
    meth = _method(s)
    items = []
    # caveats
    warn = grouped_warnings(_warnings_list(s), params)
    fail = s.get("failures") or {}
    n_failed = len(fail.get("failed_units") or []) + len(fail.get("skipped_experiments") or [])
    cav = [esc(_no_paths(w)) for w in warn[:6]]
    if len(warn) > 6:
        cav.append(f"{len(warn) - 6} more warnings (see Warnings and failures)")
    if n_failed:
        cav.append(f"{n_failed} experiment(s) or unit(s) failed or were left out (see Warnings and failures)")
    for p, (lo, hi) in _per_experiment_range(s, width=1.96).items():
        m = _fnum((est.get(p) or {}).get("mean"))
        if math.isfinite(m) and not (lo <= m <= hi):
            cav.append(
                f"the gel-level {esc(p)} ({_q(m, p, units)}) lies outside every experiment's own 95 % interval "
                f"(together {_qrange(lo, hi, p, units)}): no single bubble supports it, so the combination "
                "of the experiments is not to be trusted (they disagree with each other or with the model)"
            )
    fit = s.get("fit") or {}
    if meth is not None and meth.name == "pimr":
        cav.append("pIMR fits the collapse time only, not the shape of R(t)")
    if cav:
        items.append(
            "<span class='caveat'>Caveats:</span><ul class='caveats'>"
            + "".join(f"<li>{c[:1].upper() + c[1:]}</li>" for c in cav)
            + "</ul>"
        )
    else:
        items.append("Caveats: none recorded.")
    if fit.get("rmse") is not None:
        items.append(
            f"Fit: RMSE {num(fit.get('rmse'), '.3g')} R* [-] (R* = R/Rmax){_rmse_um(s, fit.get('rmse'))} over "
            f"{esc(fit.get('n_samples', '–'))} samples."
        )
    return items


def _no_paths(text: str) -> str:
    """A warning without summary.json paths (``per_experiment[].likelihood.nuisance_integral``): the
    path's last name in words (``nuisance integral``)."""
    import re

    roots = ("per_experiment", "details", "likelihood", "windows", "estimate", "settings", "preprocessing", "fit")
    return re.sub(
        r"`?\b[\w]+(?:\[\])?(?:\.[\w]+(?:\[\])?)+`?",
        lambda m: (
            m.group(0).strip("`").rsplit(".", 1)[-1].replace("_", " ")
            if "[]" in m.group(0) or m.group(0).strip("`").startswith(roots)
            else m.group(0)
        ),
        str(text),
    )


def _rmse_um(s, rmse) -> str:
    """`` (2.1 µm)``: an rmse in R* times the records' mean Rmax; empty without Rmax."""
    rm = _fnum((((s.get("preprocessing") or {}).get("summary") or {}).get("rmax_um") or {}).get("mean"))
    r = _fnum(rmse)
    return f", {r * rm:.3g} µm" if math.isfinite(rm) and math.isfinite(r) else ""


def _per_experiment_range(s, width: float = 0.0) -> dict:
    """{parameter: (min, max)} of the per-experiment posterior means (two experiments or more), or
    with ``width`` > 0 of their intervals mean ± width sd (the union of the experiments' own
    intervals; sd missing: the mean alone)."""
    per = [x for x in s.get("per_experiment") or [] if isinstance(x, dict) and isinstance(x.get("estimate"), dict)]
    out = {}
    for p in s.get("parameters", []):
        lo, hi = [], []
        for x in per:
            e = x["estimate"].get(p) or {}
            m, sd = _fnum(e.get("mean")), _fnum(e.get("sd"), 0.0)
            if math.isfinite(m):
                sd = sd if math.isfinite(sd) else 0.0
                lo.append(m - width * sd)
                hi.append(m + width * sd)
        if len(lo) >= 2:
            out[p] = (min(lo), max(hi))
    return out


def _section_experiments(s) -> str:
    """Per experiment: its own estimate and, when the fit estimated them, its nuisance parameters
    (Rmax, Req, time origin) and effective samples."""
    per = [x for x in s.get("per_experiment") or [] if isinstance(x, dict)]
    has_est = any(isinstance(x.get("estimate"), dict) for x in per)
    nkeys = []
    for x in per:
        for k, v in (x.get("nuisance") or {}).items():
            if isinstance(v, dict) and k not in nkeys:  # quantities; "treatment" is a note
                nkeys.append(k)
    if not per or not (has_est or nkeys):
        return ""
    units = _units(s)
    params = s.get("parameters", [])
    eff = (s.get("likelihood") or {}).get("effective_samples") or []
    heads = ["experiment"]
    if has_est:
        for p in params:
            f, u = _disp(p, units)
            heads += [f"{esc(p)} mean [{esc(u)}]", f"{esc(p)} sd [{esc(u)}]"]
    for k in nkeys:
        lab, _, u = _NUISANCE.get(k, (k, 1.0, ""))
        heads += [f"{esc(lab)} mean" + (f" [{esc(u)}]" if u else ""), f"{esc(lab)} sd" + (f" [{esc(u)}]" if u else "")]
    if eff:
        heads.append("effective samples")
    rows = []
    for i, x in enumerate(per):
        r = [esc(x.get("name", i))]
        if has_est:
            for p in params:
                e = (x.get("estimate") or {}).get(p) or {}
                f, _ = _disp(p, units)
                r += [_ncell(_fnum(e.get("mean")) * f, ".4g"), _ncell(_fnum(e.get("sd")) * f, ".3g")]
        for k in nkeys:
            e = (x.get("nuisance") or {}).get(k)
            e = e if isinstance(e, dict) else {}
            _, f, _ = _NUISANCE.get(k, (k, 1.0, ""))
            r += [_ncell(_fnum(e.get("mean")) * f, ".4g"), _ncell(_fnum(e.get("sd")) * f, ".3g")]
        if eff:
            r.append(_ncell(eff[i] if i < len(eff) else None, ".3g"))
        rows.append(r)
    note = (
        "Each experiment's own posterior (display units: G in kPa, mu in Pa s)"
        + ("; Rmax, Req [µm] and the time origin t0 [µs] estimated with the material" if nkeys else "")
        + "."
    )
    return f"<h2 id='experiments'>Experiments</h2><p class='note'>{note}</p>" + table(heads, rows)


def _section_contents(run) -> str:
    rd = run["run_dir"]
    s = run["summary"]
    ran_mcmc = "mcmc" in s
    meth = _method(s)
    applies = meth is None or meth.gaussian_posterior
    rows = [("summary.json", "<span class='ok'>present</span>", "run summary (dataset, settings, estimate)")]
    rows.append(
        (
            "posterior.nc",
            "<span class='ok'>present</span>" if run["posterior"] is not None else "<span class='absent'>absent</span>",
            "ArviZ posterior of the fit",
        )
    )
    if applies or run["mcmc"] is not None or run["compare"] is not None:
        if run["mcmc"] is not None:
            st = "<span class='ok'>present</span>"
        elif ran_mcmc:
            st = "<span class='absent'>absent, although summary.json records an MCMC run</span>"
        else:
            st = "not written (the fit ran without <code>--mcmc</code>)"
        rows.append(("mcmc.nc", st, "MCMC reference posteriors per window"))
        if run["compare"] is not None:
            st = "<span class='ok'>present</span>"
        elif run["mcmc"] is not None:
            st = "<span class='absent'>absent</span> (run <code>imrbayes compare RUN_DIR</code>)"
        else:
            st = "not written"
        rows.append(("compare.json", st, "ensemble Gaussian vs MCMC, per window"))
    rows.append(
        (
            "figures/*.png",
            f"{len(run['figures'])} file(s)" if run["figures"] else "<span class='absent'>absent</span>",
            "figures (embedded above)",
        )
    )
    out = table(["file", "status", "content"], [(f"<code>{esc(a)}</code>", b, esc(c)) for a, b, c in rows])
    return f"<h2 id='contents'>Run directory</h2><p><code>{esc(rd)}</code></p>{out}"


def _section_dataset(s) -> str:
    pre = s.get("preprocessing") or {}
    ds = pre.get("dataset") or {}
    meta = ds.get("meta") or {}
    head = [f"<b>Data:</b> <code>{esc(s.get('data', ds.get('path', '–')))}</code>"]
    if ds.get("format"):
        head.append(f"format {esc(ds['format'])}")
    if ds.get("material") or meta.get("material"):
        head.append(f"material: {esc(ds.get('material') or meta.get('material'))}")
    if meta.get("temperature_C") is not None:
        head.append(f"temperature {num(meta['temperature_C'], '.3g')} °C")
    if meta.get("description"):
        head.append(f"description: {esc(meta['description'])}")
    n_exp = s.get("n_experiments", pre.get("n_experiments"))
    head.append(f"{esc(n_exp)} experiment(s) used")
    rows = []
    for e in pre.get("experiments") or []:
        if not isinstance(e, dict):
            continue
        rmax, req = _fnum(e.get("rmax_m")), _fnum(e.get("req_m"))
        rows.append(
            (
                esc(e.get("name", "?")),
                f"<code>{esc(e.get('source', ''))}</code>",
                _ncell(rmax * 1e6, ".4g"),
                _ncell(req * 1e6, ".4g"),
                esc(e.get("req_source", "")),
                _ncell(e.get("rmax_over_req"), ".4g"),
                _ncell(e.get("t_collapse_star"), ".4g"),
                _ncell(e.get("n_samples"), ".0f"),
                _ncell(e.get("n_steps_available"), ".0f"),
                esc("; ".join(e.get("warnings") or [])) or "–",
            )
        )
    out = "<h2 id='dataset'>Dataset</h2><p>" + "; ".join(head) + "</p>"
    if rows:
        out += table(
            [
                "experiment",
                "file",
                "Rmax [µm]",
                "Req [µm]",
                "Req from",
                "Rmax/Req [-]",
                "first collapse t* [-]",
                "samples",
                "grid steps available",
                "warnings",
            ],
            rows,
        )
        summ = pre.get("summary") or {}
        srows = []
        for key, lab in (
            ("rmax_um", "Rmax [µm]"),
            ("req_um", "Req [µm]"),
            ("rmax_over_req", "Rmax/Req [-]"),
            ("t_collapse_star", "first collapse t* [-]"),
        ):
            v = summ.get(key)
            if isinstance(v, dict):
                srows.append(
                    (
                        lab,
                        _ncell(v.get("mean"), ".4g"),
                        _ncell(v.get("sd"), ".3g"),
                        _ncell(v.get("min"), ".4g"),
                        _ncell(v.get("max"), ".4g"),
                    )
                )
        if srows:
            out += table(["across experiments", "mean", "sd", "min", "max"], srows)
    else:
        out += "<p class='absent'>summary.json lists no per-experiment preprocessing results.</p>"
    skipped = pre.get("skipped") or (s.get("failures") or {}).get("skipped_experiments") or []
    if skipped:
        out += f"<p><b>Experiments left out by preprocessing:</b></p>{_plain(skipped)}"
    choices = pre.get("choices") or {}
    if choices:
        out += "<h3 id='preprocessing'>Preprocessing</h3>" + _kv_table(choices)
    return out


def _section_config(s) -> str:
    cmd = s.get("command") or {}
    fwd = s.get("forward") or {}
    prior = s.get("prior") or (s.get("details") or {}).get("parameter_space") or {}
    units = _units(s)
    method = s.get("method", "?")
    label = _method(s).label if _method(s) is not None else ""
    rows = [
        ("method", f"{esc(method)} — {esc(label)}"),
        ("constitutive model", esc(s.get("model", fwd.get("constitutive", "?")))),
        ("parameters", esc(", ".join(f"{p} [{units.get(p, '?')}]" for p in s.get("parameters", [])))),
        ("seed", esc(s.get("seed", cmd.get("seed", "–")))),
        ("imrbayes version", esc(cmd.get("imrbayes_version", "–"))),
        ("command", _command_cell(s, cmd)),
        (
            "runtime",
            f"method {num(s.get('runtime_s'), '.3g')} s; whole command {num(s.get('total_runtime_s'), '.3g')} s",
        ),
    ]
    ex = s.get("execution") or {}
    if ex:
        exe = ex.get("executor") or {}
        g = lambda d, k: esc(d.get(k, "–"))  # noqa: E731
        rows.append(
            (
                "execution",
                f"{g(ex, 'n_units')} unit(s): {g(ex, 'n_computed')} computed, "
                f"{g(ex, 'n_resumed')} from checkpoints, {g(ex, 'n_failed')} failed; "
                f"backend {g(exe, 'backend')}, workers {g(exe, 'workers')}",
            )
        )
    if fwd:
        rows.append(("forward model", f"{esc(fwd.get('constitutive', ''))}; {_kv_list(fwd.get('options') or {})}"))
        rows.append(("physical constants", _kv_list(fwd.get("physics") or {})))
    settings = (s.get("details") or {}).get("settings")
    if settings:
        rows.append(("method settings", _kv_list(settings)))
    out = "<h2 id='config'>Run configuration</h2>" + table(None, rows, cls="kv")
    psi = prior.get("prior_si") or {}
    if psi:
        ls = prior.get("log_space") or {}
        prow = [
            (
                esc(k),
                esc(units.get(k, "?")),
                _ncell(v.get("mean")),
                _ncell(v.get("sd")),
                "log-normal" if ls.get(k, True) else "Gaussian",
            )
            for k, v in psi.items()
            if isinstance(v, dict)
        ]
        out += "<h3>Prior</h3>" + table(["parameter", "unit", "mean", "sd", "distribution"], prow)
        if prior.get("prior_rule"):
            out += f"<p class='note'>{esc(prior['prior_rule'])}</p>"
    return out


def _command_cell(s, cmd) -> str:
    """The command that ran, as typed (recorded by ``fit``), with the folder it ran in; runs written
    before the command was recorded: rebuilt from the recorded options (``--forward``, ``--set``
    and ``--experiments`` then missing), and said to be incomplete."""
    if cmd.get("line"):
        where = f" <span class='note'>(run in <code>{esc(cmd['cwd'])}</code>)</span>" if cmd.get("cwd") else ""
        return f"<code>{esc(cmd['line'])}</code>{where}"
    rebuilt = (
        "imrbayes fit "
        + str(s.get("data", "DATA"))
        + " "
        + " ".join(
            f"--{k.replace('_', '-')} {v}"
            for k, v in cmd.items()
            if k not in ("name", "imrbayes_version", "resume") and v is not None
        )
        + (" --resume" if cmd.get("resume") else "")
    )
    return (
        f"<code>{esc(rebuilt)}</code> <span class='note'>(rebuilt: this run did not record its command line, "
        "so options such as --forward and --set may be missing)</span>"
    )


def _section_warnings(s, compare) -> str:
    warn = grouped_warnings(_warnings_list(s), s.get("parameters", []))
    fail = s.get("failures") or {}
    items = []
    if fail.get("skipped_experiments"):
        items.append(f"experiments left out (preprocessing failed): {_plain(fail['skipped_experiments'])}")
    for u in fail.get("failed_units") or []:
        items.append(f"failed unit: {_plain_inline(u) if isinstance(u, dict) else esc(u)}")
    ex_failed = (s.get("execution") or {}).get("failed") or []
    for u in ex_failed:
        t = _plain_inline(u) if isinstance(u, dict) else esc(u)
        if not any(t in i for i in items):
            items.append(f"failed execution unit: {t}")
    for key, lab in (
        ("failed_member_runs", "failed forward runs of ensemble members / grid points"),
        ("redrawn_members", "ensemble members redrawn"),
    ):
        v = fail.get(key)
        if v:
            items.append(f"{lab}: {_plain(v)}")
    for f in ((compare or {}).get("overall") or {}).get("failed_windows") or []:
        items.append(
            f"MCMC failed in window {esc(f.get('window') if isinstance(f, dict) else f)}: "
            f"{esc(f.get('error', '') if isinstance(f, dict) else '')}"
        )
    out = "<h2 id='warnings'>Warnings and failures</h2>"
    out += (
        ("<ul>" + "".join(f"<li>{esc(_no_paths(w))}</li>" for w in warn) + "</ul>") if warn else "<p>No warnings.</p>"
    )
    out += (
        "<p><b>Failed or skipped units:</b></p><ul>" + "".join(f"<li>{i}</li>" for i in items) + "</ul>"
        if items
        else "<p>No failed or skipped units.</p>"
    )
    return out


def _section_estimate(s) -> str:
    units = _units(s)
    rows = []
    true = truth(s)
    for p in s.get("parameters", []):
        e = s["estimate"].get(p) or {}
        hdi = e.get("hdi95") or [None, None]
        lower, upper = bounds(e, p, s) if len(hdi) == 2 and None not in hdi else (True, True)
        rows.append(
            (
                esc(p),
                esc(units.get(p, "?")),
                _ncell(e.get("mean")),
                _ncell(e.get("sd"), ".3g"),
                _ncell(e.get("median")),
                _ncell(hdi[0]) if lower else ("not bounded by the data", ""),
                _ncell(hdi[1]) if upper else ("not bounded by the data", ""),
            )
            + ((_ncell(true.get(p)),) if true else ())
        )
    out = (
        "<h2 id='estimate'>Estimate (SI units)</h2><p class='note'>The numbers of summary.json, the one "
        "source of every estimate in this report (the conclusion shows them in kPa and Pa s).</p>"
    )
    note = _method(s).estimate_note if _method(s) is not None else ""
    if note:
        out += f"<p>{esc(note)}</p>"
    out += table(
        ["parameter", "unit", "mean", "sd", "median", "95 % HDI lower", "95 % HDI upper"]
        + (["truth (truth.json)"] if true else []),
        rows,
    )
    if any((s["estimate"].get(p) or {}).get("sd") is None for p in s.get("parameters", [])):
        det = s.get("details") or {}
        why = det.get("uncertainty") or det.get("note")
        out += "<p class='note'>– : not available from this method" + (f" ({_plain(why)})" if why else "") + ".</p>"
    fit = s.get("fit") or {}
    if fit:
        out += (
            f"<p>Fit: RMSE {num(fit.get('rmse'), '.4g')} in R* over {esc(fit.get('n_samples', '–'))} "
            f"samples <span class='note'>({esc(fit.get('rmse_definition', ''))})</span></p>"
        )
    return out


def _section_windows(s) -> str:
    wins = [w for w in s.get("windows") or [] if isinstance(w, dict)]
    if not wins:
        return ""
    units = _units(s)
    params = s.get("parameters", [])
    tc = _collapse_time(s)
    heads = ["window", "t* span [-]", "phase"]
    for p in params:
        heads += [f"{esc(p)} mean [{esc(units.get(p, '?'))}]", f"{esc(p)} sd [{esc(units.get(p, '?'))}]"]
    has_be = any(isinstance(w.get("between_experiments"), dict) for w in wins)
    if has_be:
        heads += [f"{esc(p)} between-bubble sd [{esc(units.get(p, '?'))}]" for p in params]
    heads += ["posterior / prior width", "failed experiments"]
    ratios = window_ratios(s)
    rows = []
    for w, ratio in zip(wins, ratios + [{}] * (len(wins) - len(ratios))):
        r = [esc(w.get("index")), _span(w.get("t_star"), ".4g"), esc(window_phase(w.get("t_star"), tc) or "–")]
        for p in params:
            r += [_ncell((w.get(p) or {}).get("mean")), _ncell((w.get(p) or {}).get("sd"), ".3g")]
        if has_be:
            r += [_ncell(((w.get("between_experiments") or {}).get(p) or {}).get("sd"), ".3g") for p in params]
        if ratio:
            little = max(ratio.values()) >= SAYS_LITTLE
            txt = ", ".join(f"{esc(p)} {100 * v:.0f} %" for p, v in ratio.items())
            r.append((txt + (" (barely moved)" if little else ""), "class='undecided'" if little else ""))
        else:
            r.append("–")
        fe = w.get("failed_experiments") or []
        r.append(esc(", ".join(map(str, fe))) if fe else "–")
        rows.append(r)
    n_tr = len(s.get("time_resolved") or [])
    return (
        f"<h2 id='windows'>Windows ({len(wins)})</h2><p>Per-window posterior (mean, sd; SI units). "
        f"The time-resolved estimate has {n_tr} points (see the parameters figure). Posterior / prior width: "
        f"the window posterior's sd over the prior's (log coordinates); ≥ {100 * SAYS_LITTLE:.0f} %: the data "
        "barely moved the prior in that window.</p>" + table(heads, rows)
    )


_AZ_COLS = [
    ("mean", ".5g"),
    ("sd", ".3g"),
    ("hdi95_lb", ".5g"),
    ("hdi95_ub", ".5g"),
    ("ess_bulk", ".0f"),
    ("ess_tail", ".0f"),
    ("r_hat", ".4f"),
    ("mcse_mean", ".3g"),
    ("mcse_sd", ".3g"),
]


def _az_summary(tree, var_names=None):
    """``az.summary`` with a 95 % HDI and raw numbers; (DataFrame, None) or (None, error text)."""
    import arviz as az

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            kw = {"var_names": var_names} if var_names else {}
            return az.summary(tree, round_to="none", ci_kind="hdi", ci_prob=_CI_PROB, **kw), None
    except Exception as exc:  # a tree ArviZ cannot summarise: reported, not fatal
        return None, f"{type(exc).__name__}: {' '.join(str(exc).split())[:200]}"


def _az_table(df, th=None, only=None) -> str:
    cols = [(c, f) for c, f in _AZ_COLS if c in df.columns and (only is None or c in only)]
    if only is None:
        cols += [(c, ".4g") for c in df.columns if c not in {k for k, _ in cols}]
    rows = []
    for name, rec in df.iterrows():
        r = [f"<code>{esc(name)}</code>"]
        for c, f in cols:
            v = rec[c]
            cls = None
            if th is not None:
                fv = _fnum(v)
                if c == "r_hat" and math.isfinite(fv):
                    cls = "bad" if fv > th["rhat"] else "ok"
                if c == "ess_bulk" and math.isfinite(fv):
                    cls = "bad" if fv < th["ess_bulk"] else "ok"
            r.append(_ncell(v, f, cls))
        rows.append(r)
    return table(["variable"] + [c for c, _ in cols], rows)


def _section_posterior(run) -> str:
    out = "<h2 id='posterior'>Sampling diagnostics of posterior.nc (ArviZ)</h2>"
    tree = run["posterior"]
    if tree is None:
        return out + "<p class='absent'>posterior.nc is absent from this run directory.</p>"
    df, err = _az_summary(tree)
    if df is None:
        return out + f"<p class='absent'>ArviZ could not summarise posterior.nc ({esc(err)}).</p>"
    post = tree["posterior"]
    n_chain = post.sizes.get("chain", 1)
    n_draw = post.sizes.get("draw", 0)
    out += (
        f'<p><code>az.summary(tree, round_to="none", ci_kind="hdi", ci_prob={_CI_PROB})</code>; '
        f"{n_chain} chain(s) × {n_draw} draws: the effective sample sizes, R-hat and Monte Carlo errors of the "
        "draws. Their mean, sd and interval are not repeated here: the estimate is the one of the Estimate and "
        "Windows tables (summary.json), so that the report gives one number for one quantity. Numbers are "
        "shown rounded; hover a cell for its raw value."
    )
    if "window" in post.dims:
        out += " Rows <code>G[j]</code> etc. are window j."
    if n_chain < 2:
        out += (
            " These are independent draws from the method's posterior approximation (one chain), not a "
            "Markov chain: r_hat is undefined (–) and ESS and MCSE treat the draws as one sequence."
        )
    return out + "</p>" + _az_table(df, only=("ess_bulk", "ess_tail", "r_hat", "mcse_mean", "mcse_sd"))


def _section_mcmc(run) -> str:
    out = "<h2 id='mcmc'>MCMC reference posteriors (mcmc.nc)</h2>"
    tree = run["mcmc"]
    if tree is None:
        return ""  # the conclusion and the MCMC check say why (not run, or not applicable)
    th = _thresholds(run["compare"] or {})
    try:
        settings = json.loads(tree.attrs.get("mcmc_settings_json", "null")) or {}
    except (TypeError, ValueError):
        settings = {}
    if settings:
        out += f"<p>emcee settings: {_kv_list(settings)}.</p>"
    out += (
        f'<p>Per window, <code>az.summary(round_to="none", ci_kind="hdi", ci_prob={_CI_PROB})</code>; '
        f"one chain = one independent emcee ensemble. Shaded: r_hat &gt; {num(th['rhat'], 'g')} or "
        f"ess_bulk &lt; {num(th['ess_bulk'], 'g')} (red), within the thresholds (green).</p>"
    )
    keys = sorted(k for k in tree.children if k.startswith("window_"))
    span = {}
    for e in (run["compare"] or {}).get("windows") or []:
        span[e.get("index")] = e.get("t_star")
    if not keys:  # a single-window tree (posterior at the top)
        keys = [None]
    for k in keys:
        node = tree if k is None else tree[k]
        idx = None
        if k is not None:
            try:
                idx = int(k.split("_", 1)[1])
            except ValueError:
                idx = k
        ts = span.get(idx)
        if ts is None:
            try:
                ts = (json.loads(node.attrs.get("ensemble_json", "null")) or {}).get("t_star")
            except (TypeError, ValueError, AttributeError):
                ts = None
        title = f"Window {esc(idx)}" if k is not None else "Posterior"
        out += f"<h3>{title}" + (f" (t* {_span(ts)})" if ts else "") + "</h3>"
        if "posterior" not in node.children:
            out += "<p class='absent'>no posterior group in this node.</p>"
            continue
        try:
            diag = json.loads(node.attrs.get("diagnostics_json", "null")) or {}
        except (TypeError, ValueError):
            diag = {}
        if diag:
            acc = diag.get("acceptance") or []
            acc = [a for a in (acc if isinstance(acc, list) else [acc]) if isinstance(a, (int, float))]
            g = lambda k: esc(diag.get(k, "–"))  # noqa: E731
            rule = num(diag.get("tau_rule", th["tau_rule"]), "g")
            out += (
                f"<p class='note'>{g('n_chains')} ensembles × {g('n_walkers')} walkers × {g('n_steps')} steps; "
                f"burn {g('burn')}, thin {g('thin')}; max τ {num(diag.get('tau_max'), '.3g')} steps, n_steps/τ "
                f"{num(diag.get('n_steps_over_tau'), '.3g')} (rule ≥ {rule})"
                + (f"; mean acceptance {num(sum(acc) / len(acc), '.2f')}" if acc else "")
                + "</p>"
            )
        df, err = _az_summary(node)
        if df is None:
            out += f"<p class='absent'>ArviZ summary failed: {esc(err)}</p>"
            continue
        internal = [i for i in df.index if str(i).startswith("log_")]
        out += _az_table(df.drop(index=internal), th)
        if internal:
            out += (
                "<details><summary>the same in the sampler's internal coordinates (log G, log mu)</summary>"
                + _az_table(df.loc[internal], th)
                + "</details>"
            )
    return out


def _section_compare(run) -> str:
    out = "<h2 id='compare'>MCMC check: ensemble Gaussian vs emcee (compare.json)</h2>"
    compare = run["compare"]
    if compare is None:
        meth = _method(run["summary"])
        if meth is not None and not meth.gaussian_posterior and run["mcmc"] is None:
            return ""  # does not apply (pIMR, IMR): the conclusion says so in one line
        return out + f"<p>{_mcmc_words(run)}</p>"
    th = _thresholds(compare)
    ov = compare.get("overall") or {}
    n_win = ov.get("n_windows", len(compare.get("windows") or []))
    out += (
        f"<p>{esc(n_win)} window(s): {esc(ov.get('n_agree', '–'))} agree, {esc(ov.get('n_disagree', '–'))} "
        f"disagree, {esc(ov.get('n_undecided', '–'))} undecided.</p>"
    )
    if ov.get("agree_rule"):
        out += f"<p class='note'>Rule: {esc(ov['agree_rule'])}. {esc(ov.get('coordinates', ''))}</p>"
    rows = []
    tc = _collapse_time(run["summary"])
    for e in sorted(compare.get("windows") or [], key=lambda w: w.get("index", 0)):
        d = _entry_diag(e)
        a = e.get("agree")
        lab, cls = ("yes", "ok") if a is True else (("no", "bad") if a is False else ("undecided", "undecided"))
        bad = lambda v, t: "bad" if _fnum(v) > t else None  # noqa: E731
        phase = esc(window_phase(e.get("t_star"), tc) or "–")
        rows.append(
            (
                esc(e.get("index")),
                _span(e.get("t_star"), ".4g"),
                phase,
                _ncell(e.get("kl_gauss"), ".3g"),
                _ncell(e.get("kl_gauss_reverse"), ".3g"),
                _ncell(e.get("kl_sym"), ".3g", bad(e.get("kl_sym"), th["kl_sym"])),
                _ncell(e.get("w2"), ".3g", bad(e.get("w2"), th["w2"])),
                _ncell(e.get("kl_sample"), ".3g", bad(e.get("kl_sample"), th["kl_sample"])),
                _ncell(d["rhat"], ".4f", bad(d["rhat"], th["rhat"])),
                _ncell(d["ess"], ".0f", "bad" if _fnum(d["ess"], math.inf) < th["ess_bulk"] else None),
                _ncell(d["n_over_tau"], ".3g", "bad" if d["tau_ok"] is False else None),
                (lab, f"class='{cls}'"),
                esc(e.get("state_source", "–")),
            )
        )
    out += table(
        [
            "window",
            "t* span [-]",
            "phase",
            "KL(MCMC‖ens) [nats]",
            "KL(ens‖MCMC) [nats]",
            f"KL sym [nats] (≤ {num(th['kl_sym'], 'g')})",
            f"W2 [sd] (≤ {num(th['w2'], 'g')})",
            f"sample KL [nats] (≤ {num(th['kl_sample'], 'g')})",
            f"max R-hat (≤ {num(th['rhat'], 'g')})",
            f"min ESS bulk (≥ {num(th['ess_bulk'], 'g')})",
            f"n_steps/τ (≥ {num(th['tau_rule'], 'g')})",
            "agree",
            "start state",
        ],
        rows,
    )
    notes = [(e.get("index"), e.get("notes")) for e in compare.get("windows") or [] if e.get("notes")]
    if notes:
        out += (
            "<details><summary>notes per window (compare.json)</summary><ul>"
            + "".join(f"<li>window {esc(i)}: {esc(n)}</li>" for i, n in notes)
            + "</ul></details>"
        )
    return out


def _section_flagged(run) -> str:
    out = "<h2 id='flagged'>Flagged windows</h2>"
    if run["compare"] is None:
        return ""
    lines = flagged_windows(run["compare"], run["summary"])
    if not lines:
        return out + "<p>None: in every sampled window the ensemble Gaussian agrees with its MCMC posterior.</p>"
    return out + "<ul class='flagged'>" + "".join(f"<li>{esc(ln)}</li>" for ln in lines) + "</ul>"


#: figure file -> (title, caption); the figures are shown in this order, the rest after them
_CAPTIONS = {
    "fit.png": (
        "Fit to the data",
        "Measured R/Rmax (dots) and the fitted curve per experiment, against t* and "
        "time [µs]; samples the method did not fit are shaded.",
    ),
    "parameters.png": (
        "Time-resolved parameters",
        "G and mu per window (posterior mean, 95 % band) with the "
        "prior's 95 % band, against t*, time [µs] and the wall strain rate -2Ṙ/R [1/s]; windows "
        "the data barely moved are hatched.",
    ),
    "experiments.png": (
        "Per-experiment estimates",
        "Per-experiment posterior mean ± 2 sd and the gel-level (fused) estimate.",
    ),
    "landscape.png": (
        "Cost landscape",
        "Cost over (G, mu) (grid of the IMR/pIMR method) with the optimum and the 95 % region.",
    ),
    "radius.png": ("Radius records", "Preprocessed radius records R*(t*)."),
    "mcmc_forest.png": (
        "MCMC check per window",
        "Per window: ensemble Gaussian (blue) and MCMC (red) median and "
        "95 % interval against the window's t* span; ▼ marks a disagreeing window.",
    ),
    "mcmc_divergence.png": (
        "MCMC agreement against time",
        "KL (Gaussian, symmetrised, and sample-based) and W2 "
        "per window against t*, with the agreement thresholds, under the measured R*(t*).",
    ),
}


def _caption(p: Path, summary=None) -> tuple:
    """(title, caption) of a figure file."""
    if p.name in _CAPTIONS:
        title, cap = _CAPTIONS[p.name]
        if p.name == "fit.png" and (summary or {}).get("method") == "pimr":
            cap = (
                "Measured R/Rmax (dots) and the curve at the pIMR estimate: pIMR fits the first-collapse time "
                "only, so only the collapse time of the curve is fitted, not its shape."
            )
        return title, cap
    if p.name.startswith("mcmc_pair_window_"):
        w = esc(p.stem.rsplit("_", 1)[-1].lstrip("0") or "0")
        return (
            f"MCMC posterior, window {w}",
            f"Window {w}: MCMC draws of G [kPa] and mu [Pa s] (log axes) with the 1- and 2-sd ellipses of the "
            "ensemble Gaussian and of the MCMC draws' Gaussian, and both marginals.",
        )
    return p.stem.replace("_", " "), esc(p.stem.replace("_", " "))


def _figure_order(p: Path):
    keys = list(_CAPTIONS)
    return (keys.index(p.name) if p.name in keys else len(keys), p.name)


def _section_figures(run) -> str:
    out = "<h2 id='figures'>Figures</h2>"
    if not run["figures"]:
        return out + "<p class='absent'>No figures: figures/*.png is absent.</p>"
    parts, bad = [], []
    for p in sorted(run["figures"], key=_figure_order):
        if not is_png(p):
            bad.append(p.name)
            continue
        title, cap = _caption(p, run["summary"])
        parts.append(
            embed_png(p, caption=f"{cap} <span class='note'>(<code>figures/{esc(p.name)}</code>)</span>", title=title)
        )
    if bad:
        out += f"<p class='absent'>Not embedded (not a readable PNG file): {esc(', '.join(bad))}</p>"
    return out + "".join(parts)


def write_run_report(run_dir, path=None) -> Path:
    """Write the HTML report of ``run_dir`` to ``path`` (default ``run_dir/report.html``); returns it.

    Order: the conclusion first (what a rheologist reads), then the estimate, experiments, windows
    and figures, the MCMC check where it applies, and the dataset, warnings, configuration, raw
    sampling diagnostics and files at the bottom."""
    run = read_run_dir(run_dir)
    s = run["summary"]
    path = Path(path) if path is not None else run["run_dir"] / "report.html"
    title = f"imrbayes report: {s.get('method', '?')} fit ({s.get('model', '?')}) of {s.get('data', '?')}"
    sections = [
        ("conclusion", "Conclusion", _section_conclusion(run)),
        ("estimate", "Estimate", _section_estimate(s)),
        ("experiments", "Experiments", _section_experiments(s)),
        ("windows", "Windows", _section_windows(s)),
        ("figures", "Figures", _section_figures(run)),
        ("compare", "MCMC check", _section_compare(run)),
        ("flagged", "Flagged windows", _section_flagged(run)),
        ("mcmc", "MCMC tables", _section_mcmc(run)),
        ("dataset", "Dataset", _section_dataset(s)),
        ("warnings", "Warnings and failures", _section_warnings(s, run["compare"])),
        ("config", "Run configuration", _section_config(s)),
        ("posterior", "Sampling diagnostics", _section_posterior(run)),
        ("contents", "Run directory", _section_contents(run)),
    ]
    nav = " · ".join(f"<a href='#{a}'>{esc(b)}</a>" for a, b, html_ in sections if html_)
    now = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    body = "\n".join(
        [f"<h1>{esc(title)}</h1><p class='note'>{nav}</p>"]
        + [h for _, _, h in sections if h]
        + [f"<p class='note'>Written {now} by imrbayes {esc(__version__)} (<code>imrbayes report</code>).</p>"]
    )
    try:
        write_page(path, title, body)
    except OSError as exc:
        raise InputError(path, f"cannot be written ({exc.strerror or exc})")
    return path
