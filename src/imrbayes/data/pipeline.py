"""Dataset -> arrays every inference method consumes (interfaces.md §1 "Preprocessing").

:func:`preprocess_dataset` runs the steps of :mod:`imrbayes.data.preprocess` on every experiment,
puts all experiments on one common grid (the shortest record sets its length) and estimates P_k
(:mod:`imrbayes.data.noise`). The returned :class:`Preprocessed` carries the arrays and a record of
every choice (``choices``), ready to be written to a run's output with :meth:`Preprocessed.to_dict`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from imrbayes.data import preprocess as pp
from imrbayes.data.noise import P_FLOOR_ABS, P_FLOOR_REL, noise_variance
from imrbayes.data.records import Dataset
from imrbayes.errors import InputError
from imrbayes.io import jsonable

__all__ = ["ExperimentSummary", "Preprocessed", "preprocess_dataset"]


@dataclass
class ExperimentSummary:
    """What preprocessing found for one experiment (SI units; ``*_star`` dimensionless).

    ``t0_s``: time of the maximum in the file's clock; ``tc_s``: Rmax/sqrt(p8/rho);
    ``t_collapse_s``: first collapse measured from the maximum; ``t_last_star``: end of the record.
    ``req_sd_m`` is NaN when Req was given without an uncertainty. ``noise_sd_m``: the record's
    noise sd estimated from its fourth differences; ``t0_sd_s``, ``rmax_sd_m``: standard errors of
    the maximum's time and radius (NaN unless ``rmax_method="local-fit"``). ``req_tail_t_star``: t*
    of the frames whose mean is ``req_m`` (empty when Req was given or the tail has not settled:
    then ``req_m`` is not their mean, :func:`~imrbayes.data.preprocess.estimate_req`), so that a
    method can compare the model's own mean over the same frames (a cooling tail lies above Req).
    """

    name: str
    source: str
    n_samples: int
    rmax_m: float
    rmax_sample_m: float
    rmax_method: str
    t0_s: float
    tc_s: float
    req_m: float
    req_sd_m: float
    req_se_m: float
    req_source: str
    t_collapse_s: float
    t_collapse_star: float
    r_collapse_star: float
    collapse_method: str
    t_last_star: float
    n_steps_available: int
    warnings: list = field(default_factory=list)
    noise_sd_m: float = math.nan
    t0_sd_s: float = math.nan
    rmax_sd_m: float = math.nan
    req_tail_t_star: list = field(default_factory=list)

    @property
    def ratio(self) -> float:
        """Rmax/Req."""
        return self.rmax_m / self.req_m

    @property
    def ratio_sd(self) -> float:
        """Uncertainty of Rmax/Req propagated from ``req_sd_m`` (NaN if unknown)."""
        return self.ratio * self.req_sd_m / self.req_m

    def to_dict(self) -> dict:
        d = {k: jsonable(v) for k, v in self.__dict__.items()}
        d["rmax_over_req"] = jsonable(self.ratio)
        d["rmax_over_req_sd"] = jsonable(self.ratio_sd)
        return d


@dataclass
class Preprocessed:
    """Arrays on the common grid, plus what was done.

    Attributes
    ----------
    t_star : ndarray (n,)
        Grid k dt*, k = 0..n-1.
    R_star : ndarray (n_exp, n)
        Resampled R/Rmax per experiment.
    P : ndarray (n,)
        Measurement-noise variance per step (in R*^2).
    rmax_m, req_m, req_sd_m, t_collapse_star : ndarray (n_exp,)
        Per-experiment Rmax [m], Req [m], its sd [m] (NaN if unknown), first-collapse time t*.
    experiments : list of ExperimentSummary
    frame_t_star : list of ndarray
        Per experiment, the frame times t* (from the estimated maximum, with the point (0, 1) first)
        that the grid values interpolate linearly ([] for other interpolants).
    choices : dict
        Every setting used and the rule behind it.
    warnings : list of str
    dataset : Dataset
        The input (not modified).
    """

    t_star: np.ndarray
    R_star: np.ndarray
    P: np.ndarray
    rmax_m: np.ndarray
    req_m: np.ndarray
    req_sd_m: np.ndarray
    t_collapse_star: np.ndarray
    experiments: list
    choices: dict
    warnings: list
    dataset: Dataset
    skipped: list = field(default_factory=list)
    frame_t_star: list = field(default_factory=list)

    @property
    def names(self) -> list:
        return [e.name for e in self.experiments]

    @property
    def n_steps(self) -> int:
        return int(self.t_star.size - 1)

    def to_dict(self, arrays: bool = True) -> dict:
        """JSON-able record (what ``dataset.json`` holds)."""
        ds = self.dataset
        out = {
            "dataset": {
                "name": ds.name,
                "path": ds.path,
                "format": ds.format,
                "material": ds.material,
                "meta_path": ds.meta_path,
                "physics": ds.physics,
                "forward": ds.forward,
                "notes": ds.notes,
                "meta": ds.meta,
            },
            "n_experiments": len(self.experiments),
            "choices": self.choices,
            "experiments": [e.to_dict() for e in self.experiments],
            "summary": summarise(self.experiments),
            "warnings": self.warnings,
            "skipped": self.skipped,
        }
        if arrays:
            out["grid"] = {
                "t_star": jsonable(self.t_star),
                "P": jsonable(self.P),
                "R_star": {e.name: jsonable(self.R_star[i]) for i, e in enumerate(self.experiments)},
            }
        return out


def summarise(experiments) -> dict:
    """Mean and sd (ddof=1; NaN for one experiment) of Rmax [µm], Req [µm], Rmax/Req, t_c*."""
    cols = {
        "rmax_um": [e.rmax_m * 1e6 for e in experiments],
        "req_um": [e.req_m * 1e6 for e in experiments],
        "rmax_over_req": [e.ratio for e in experiments],
        "t_collapse_star": [e.t_collapse_star for e in experiments],
    }
    out = {}
    for k, v in cols.items():
        a = np.asarray(v, dtype=float)
        out[k] = {
            "mean": jsonable(float(a.mean())),
            "sd": jsonable(float(a.std(ddof=1)) if a.size > 1 else math.nan),
            "min": jsonable(float(a.min())),
            "max": jsonable(float(a.max())),
        }
    return out


def _check_settings(dataset, dt_star, n_steps, noise) -> None:
    """Raise :class:`InputError` for an empty dataset or a bad grid step, step count or noise choice."""
    if not dataset.experiments:
        raise InputError(dataset.path, "holds no experiments")
    if not (dt_star > 0 and math.isfinite(dt_star)):
        raise InputError("--dt-star", f"must be a positive number, got {dt_star}")
    if int(n_steps) < 1:
        raise InputError("--n-steps", f"must be at least 1, got {n_steps}")
    if noise not in ("auto", "sample", "pooled", "paper"):
        raise InputError("noise", f"must be auto, sample, pooled or paper, got {noise!r}")


def _preprocess_each(
    dataset, rho, p8, rmax_method, collapse_method, n_tail, rebound_frac, dt_star, skip_failed, warnings
):
    """Align and nondimensionalise each experiment (see :func:`preprocess_dataset` for the settings).

    Returns ``(summaries, records [(t*, R*) per experiment], skipped)``; ``warnings`` gets each
    experiment's warnings and, with ``skip_failed``, one line per experiment left out.
    """
    summaries, records = [], []
    skipped = []
    for exp in dataset.experiments:
        try:
            s, (ts, Rs) = _one(
                exp,
                rho,
                p8,
                rmax_method,
                collapse_method,
                n_tail,
                rebound_frac,
                dt_star,
                synthetic=dataset.meta.get("synthetic") is True,
            )
            if skip_failed and s.n_steps_available < 1:
                raise InputError(
                    exp.source,
                    f"experiment {exp.name!r} ends at t* = {s.t_last_star:.3g}, before one grid step dt* = {dt_star}",
                )
        except Exception as exc:
            if not skip_failed:
                raise
            msg = str(exc) if isinstance(exc, InputError) else f"{type(exc).__name__}: {exc}"
            skipped.append({"name": exp.name, "source": str(exp.source), "error": msg.splitlines()[0] if msg else ""})
            warnings.append(f"experiment {exp.name!r} left out: preprocessing failed ({skipped[-1]['error']})")
            continue
        summaries.append(s)
        records.append((ts, Rs))
        warnings.extend(f"{exp.name}: {w}" for w in s.warnings)
    if not summaries:
        raise InputError(
            dataset.path, f"preprocessing failed for every experiment ({len(skipped)}; first: {skipped[0]['error']})"
        )
    return summaries, records, skipped


def _grid_length(summaries, n_steps, dt_star, warnings) -> int:
    """Grid steps every experiment reaches, at most ``n_steps``; ``warnings`` says when it is fewer."""
    n_avail = [s.n_steps_available for s in summaries]
    n_use = min(int(n_steps), min(n_avail))
    if n_use < 1:
        worst = summaries[int(np.argmin(n_avail))]
        raise InputError(
            worst.source,
            f"experiment {worst.name!r} ends at t* = {worst.t_last_star:.3g}, before one grid step dt* = {dt_star}",
        )
    if n_use < int(n_steps):
        worst = summaries[int(np.argmin(n_avail))]
        warnings.append(
            f"grid truncated to {n_use} steps (t* <= {n_use * dt_star:.4g}) instead of {n_steps}: "
            f"experiment {worst.name!r} ends at t* = {worst.t_last_star:.4g}"
        )
    return n_use


def _resample_all(records, dt_star, n_use, interp):
    """R* on the grid t* = 0, dt*, ..., n_use dt* per record: ``(R_star (n_exp, n_use + 1), frames)``,
    frames the frame times each grid value interpolates (linear interpolation only, else empty)."""
    R_star = np.empty((len(records), n_use + 1))
    frames = []
    for i, (ts, Rs) in enumerate(records):
        grid, values, _ = pp.resample(ts, Rs, dt_star, n_use, method=interp)
        R_star[i] = values
        if interp == "linear":
            # the frame times the grid values interpolate (the anchor at the maximum first): a method can
            # interpolate its prediction the same way instead of comparing point values with chords
            tf = np.concatenate(([0.0], np.asarray(ts, float)[np.asarray(ts) > 0.0]))
            last = int(np.searchsorted(tf, n_use * dt_star, side="left"))
            frames.append(tf[: min(tf.size, last + 1)])
    return R_star, frames


def _choices(rho, p8, dt_star, n_steps, n_use, rmax_method, collapse_method, rebound_frac, n_tail, interp, pinfo):
    """The ``choices`` record of :class:`Preprocessed`: the settings used and how each quantity was estimated."""
    return {
        "rho_kg_m3": rho,
        "p8_Pa": p8,
        "time_scale": "t_c = Rmax / sqrt(p8/rho) per experiment",
        "dt_star": float(dt_star),
        "n_steps_requested": int(n_steps),
        "n_steps": n_use,
        "rmax_method": rmax_method,
        "collapse_method": collapse_method,
        "rebound_frac": rebound_frac,
        "record_noise": "sd from the median absolute fourth difference of each record (noise_sd_m)",
        "collapse_search": "rebound > max(rebound_frac Rmax, min(4 noise sd, 0.08 Rmax)) -- 2 noise sd from a "
        "minimum below 0.5 Rmax --, no earlier than t* = 0.6 after the maximum; with the noise "
        "bar, two frames in a row",
        "req": f"meta.json/file value when given, else mean of the last {n_tail} samples after the first "
        f"collapse (uncertainty: the tail's spread beyond the noise, plus noise/sqrt(n)); a tail whose spread "
        f"beyond the noise exceeds 10 % of its mean has not settled: Req at the log-midpoint of its lowest "
        f"point (raised by the expected least of n noise draws) and its mean, each one sd away",
        "n_tail": int(n_tail),
        "interpolation": interp,
        "resample_anchor": "the point (t*=0, R*=1) at the refined maximum plus the samples at t* > 0",
        "noise": pinfo,
    }


def preprocess_dataset(
    dataset: Dataset,
    dt_star: float = 0.025,
    n_steps: int = 120,
    *,
    rmax_method: str = "local-fit",
    collapse_method: str = "parabola",
    interp: str = "linear",
    n_tail: int = 20,
    rebound_frac: float = 0.05,
    noise: str = "auto",
    rho: float | None = None,
    p8: float | None = None,
    p_floor_abs: float = P_FLOOR_ABS,
    p_floor_rel: float = P_FLOOR_REL,
    skip_failed: bool = False,
) -> Preprocessed:
    """Align, nondimensionalise and resample every experiment; estimate P_k.

    Parameters
    ----------
    dataset : Dataset
    dt_star : float
        Grid step in t* (default 0.025).
    n_steps : int
        Steps wanted (default 120 -> 121 samples); fewer when the shortest record ends earlier,
        with a warning naming it.
    rmax_method : ``"local-fit"`` (default), ``"parabola"`` or ``"sample"``
        Sub-frame refinement of the maximum (see preprocess.py).
    collapse_method : ``"parabola"`` (default) or ``"sample"``
        Sub-frame refinement of the first collapse.
    interp : ``"linear"`` (default) or ``"pchip"``
    n_tail : int
        Samples averaged for Req when meta.json does not give it (default 20).
    rebound_frac : float
        Rise above the running minimum, as a fraction of Rmax, that marks the first rebound.
    noise : ``"auto"``, ``"sample"`` or ``"paper"``
        P_k from the across-experiment variance (``auto`` with >= 2 experiments), or from the
        verification noise model (``auto`` with one experiment).
    rho, p8 : float, optional
        Density [kg/m^3] and far-field pressure [Pa]; default meta.json ``physics`` or 1064, 101325.
    skip_failed : bool
        An experiment whose preprocessing fails (record ends before its first collapse or before
        one grid step, Req >= Rmax, anything else that raises) is left out, listed in
        ``skipped`` (name, source, one-line error) and in the warnings, instead of stopping the
        whole dataset; only when every experiment fails is it an error. Default False: the first
        failure raises.

    Raises
    ------
    InputError
        A record too short to reach its first collapse, an empty dataset, bad settings.
    """
    _check_settings(dataset, dt_star, n_steps, noise)
    rho = dataset.rho if rho is None else float(rho)
    p8 = dataset.p8 if p8 is None else float(p8)
    warnings = list(dataset.warnings)
    summaries, records, skipped = _preprocess_each(
        dataset, rho, p8, rmax_method, collapse_method, n_tail, rebound_frac, dt_star, skip_failed, warnings
    )
    n_use = _grid_length(summaries, n_steps, dt_star, warnings)
    R_star, frames = _resample_all(records, dt_star, n_use, interp)
    t_star = np.arange(n_use + 1) * dt_star
    if noise in ("sample", "pooled") and len(records) < 2:
        raise InputError(dataset.path, f"noise={noise!r} needs at least two experiments")
    P, pinfo = noise_variance(t_star, R_star, p_floor_abs, p_floor_rel, method=noise)
    if pinfo["method"] == "paper-noise-model" and noise == "auto":
        warnings.append(
            "one experiment: the noise variance P_k comes from the paper's verification noise model (sd |R*-1|/20 + "
            "(1-exp(-t*/10))/30), not from data; only --likelihood paper and IMR's weighting=P use it (the "
            "default likelihood takes each record's own noise sd)"
        )
    elif len(records) == 2 and noise != "paper":
        warnings.append("P_k from only two experiments is a very rough estimate")
    choices = _choices(
        rho, p8, dt_star, n_steps, n_use, rmax_method, collapse_method, rebound_frac, n_tail, interp, pinfo
    )
    return Preprocessed(
        frame_t_star=frames,
        t_star=t_star,
        R_star=R_star,
        P=P,
        rmax_m=np.array([s.rmax_m for s in summaries]),
        req_m=np.array([s.req_m for s in summaries]),
        req_sd_m=np.array([s.req_sd_m for s in summaries]),
        t_collapse_star=np.array([s.t_collapse_star for s in summaries]),
        experiments=summaries,
        choices=choices,
        warnings=warnings,
        dataset=dataset,
        skipped=skipped,
    )


def _one(exp, rho, p8, rmax_method, collapse_method, n_tail, rebound_frac, dt_star, synthetic=False):
    t, R = exp.t_s, exp.R_m
    warnings = []
    noise_sd = pp.estimate_noise_sd(R)
    u_c = math.sqrt(p8 / rho)
    mx = pp.locate_rmax(t, R, rmax_method, u_c=u_c, noise_sd_m=noise_sd)
    if mx.index == R.size - 1:
        raise InputError(
            exp.source,
            f"experiment {exp.name!r}: the largest radius is the last sample; "
            f"the record ends before the first collapse",
        )
    if mx.index == 0 and not synthetic:
        warnings.append(
            "the largest radius is the first sample: the growth phase is missing, so the "
            "maximum may lie before the record starts"
        )
    try:
        col = pp.first_collapse(
            t,
            R,
            mx.index,
            collapse_method,
            rebound_frac,
            noise_sd_m=noise_sd,
            t_min_s=0.6 * mx.rmax_m / u_c,
            t_max_s=mx.t_s,
        )
    except pp.RecordTooShort as exc:
        raise InputError(exp.source, f"experiment {exp.name!r}: {exc}")
    tc = pp.time_scale_s(mx.rmax_m, rho, p8)
    req_tail = []
    if exp.req_m is not None:
        req, req_sd, req_se, req_src = (
            exp.req_m,
            (math.nan if exp.req_sd_m is None else exp.req_sd_m),
            math.nan,
            exp.req_source or "given",
        )
    else:
        est = pp.estimate_req(R, col.index, n_tail, noise_sd_m=noise_sd)
        req, req_sd, req_se = est.req_m, est.sd_m, est.se_m
        # `req_tail=model` rescales a tail *mean* by the model's own; an unsettled tail's Req is not one
        req_tail = ((np.asarray(t[est.start_index :], dtype=float) - mx.t_s) / tc).tolist() if est.settled else []
        req_src = (
            f"mean of last {est.n} samples"
            if est.settled
            else f"last {est.n} samples not settled: between their lowest point and their mean"
        )
        if est.warning:
            warnings.append(est.warning)
        spread = float(exp.info.get("view_req_spread_m") or 0.0)
        if spread > 0.0:
            # camera views that disagree on the tail (a bubble not quite round): a systematic error
            # of the averaged radius that no tail statistic sees
            req_sd = math.hypot(req_sd, spread)
            req_src += f"; views' half-difference {spread * 1e6:.2g} µm added to its sd"
    if not req < mx.rmax_m:
        raise InputError(exp.source, f"experiment {exp.name!r}: Req = {req:g} m is not below Rmax = {mx.rmax_m:g} m")
    ratio = mx.rmax_m / req
    if not 2.0 <= ratio <= 20.0:
        warnings.append(f"Rmax/Req = {ratio:.3g} is outside the usual IMR range 2-20")
    tcol = (col.t_s - mx.t_s) / tc
    if not 0.5 <= tcol <= 1.5:
        warnings.append(
            f"first-collapse time t* = {tcol:.3g} is far from the Rayleigh collapse time 0.915; "
            f"check the time units and the record"
        )
    ts, Rs = pp.nondimensionalise(t, R, mx.t_s, mx.rmax_m, tc)
    t_last = float(ts[-1])
    n_avail = int(math.floor(t_last / dt_star + 1e-9))
    summary = ExperimentSummary(
        name=exp.name,
        source=exp.source,
        n_samples=exp.n_samples,
        rmax_m=mx.rmax_m,
        rmax_sample_m=mx.rmax_sample_m,
        rmax_method=mx.method,
        t0_s=mx.t_s,
        tc_s=tc,
        req_m=req,
        req_sd_m=req_sd,
        req_se_m=req_se,
        req_source=req_src,
        t_collapse_s=col.t_s - mx.t_s,
        t_collapse_star=(col.t_s - mx.t_s) / tc,
        r_collapse_star=col.r_m / mx.rmax_m,
        collapse_method=col.method,
        t_last_star=t_last,
        n_steps_available=n_avail,
        warnings=warnings,
        noise_sd_m=noise_sd,
        t0_sd_s=mx.t_sd_s,
        rmax_sd_m=mx.rmax_sd_m,
        req_tail_t_star=req_tail,
    )
    return summary, (ts, Rs)
