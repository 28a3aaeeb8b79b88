"""``imrbayes simulate``: a synthetic dataset from the forward model, with truth.json."""

from __future__ import annotations

import math
from pathlib import Path

import click
import numpy as np

from imrbayes import __version__
from imrbayes.cli import config_option, main
from imrbayes.cli.options import force_option, key_values, prepare_out
from imrbayes.errors import InputError

#: truth.json's account of the order of the random draws (a seed reproduces the dataset)
RANDOM_DRAWS = (
    "numpy.random.default_rng(seed): Rmax (n_exp, if MEAN:SD), ratio (n_exp, if "
    "MEAN:SD), then the noise of each experiment in turn; phases and scatter from "
    "SeedSequence(seed, spawn_key=(1,)) and (2,)"
)


@main.command(
    "simulate", short_help="Write a synthetic dataset from the forward model (with truth.json).", help_lists=("models",)
)
@click.option("--model", required=True, help="Constitutive model (list below), e.g. nhkv.")
@click.option(
    "--param",
    "params",
    multiple=True,
    metavar="NAME=VALUE",
    help="Material parameter in SI units (G [Pa], mu [Pa s], ...); repeat for each parameter.",
)
@click.option(
    "--rmax",
    default="263e-6",
    show_default=True,
    help="Maximum radius [m], or MEAN:SD [m] to draw each experiment's value.",
)
@click.option(
    "--ratio", default="7.58", show_default=True, help="Rmax/Req [-], or MEAN:SD [-] to draw each experiment's value."
)
@click.option("--n-exp", type=int, default=5, show_default=True, help="Number of experiments [-].")
@click.option(
    "--noise",
    default="paper",
    show_default=True,
    help="paper (sd |R*-1|/20 + (1-exp(-t*/10))/30 in R*), none, a number (sd in R* [-]), a number "
    "with um (sd in µm, e.g. 3um), a number with R (sd that fraction of R*, e.g. 0.02R: grows with "
    "the radius), a number with C (e.g. 0.01C: sd 0.01 (1 + 4 exp(-((R* - R*_c)/0.05)^2)), R*_c the "
    "nearest collapse's radius: 5x larger at collapses), or a sum of these joined by + (e.g. "
    "2um+0.01: variances add).",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of every random draw.")
@click.option(
    "--forward",
    "forward",
    multiple=True,
    metavar="KEY=VALUE",
    help="Forward-model option (radial=km, bubble=polytropic, vapor=false, ...); repeatable.",
)
@click.option(
    "--physics",
    "physics",
    multiple=True,
    metavar="KEY=VALUE",
    help="Physical-constant override in SI units (rho [kg/m^3], p8 [Pa], ...); repeatable.",
)
@click.option("--t-end", type=float, default=3.0, show_default=True, help="End of each record in t* [-].")
@click.option(
    "--dt-star",
    type=float,
    default=0.025,
    show_default=True,
    help="Sample interval in t* [-] (ignored with --frame-s).",
)
@click.option(
    "--frame-s", type=float, default=None, help="Sample at a camera frame interval [s] instead of the dt* grid."
)
@click.option(
    "--phase",
    type=click.Choice(["0", "random"]),
    default="0",
    show_default=True,
    help="With --frame-s: the first frame's sub-frame offset from the maximum (random: uniform in one "
    "frame, per experiment, from the seed).",
)
@click.option(
    "--pre-max-s",
    type=float,
    default=0.0,
    show_default=True,
    help="With --frame-s: the record starts this many seconds [s] before the maximum (the growth is "
    "taken as the mirror of the collapse).",
)
@click.option(
    "--scatter",
    "scatter",
    multiple=True,
    metavar="NAME=SD",
    help="Per-bubble material scatter: each experiment's NAME is drawn log-normally around --param's "
    "value with relative sd SD [-] (e.g. G=0.15); repeatable. truth.json records every draw.",
)
@click.option(
    "--req-in-meta/--no-req-in-meta",
    default=True,
    show_default=True,
    help="Write each experiment's true Rmax and Req into meta.json (off: Req must be estimated from "
    "the record's tail, as for most real data).",
)
@click.option(
    "--generator",
    type=click.Choice(["imrbayes", "pyimr"]),
    default="imrbayes",
    show_default=True,
    help="The code that makes the curves: imrbayes's forward model, or PyIMR (another code, the optional "
    "'peers' extra) with the same physics, constants and options -- data no part of imrbayes made.",
)
@click.option("--material", default=None, help="Text for meta.json 'material' (default: synthetic <model>).")
@click.option(
    "--out",
    type=click.Path(path_type=Path),
    default=None,
    help="Dataset folder to create (default: a new folder under ./imrbayes-runs/).",
)
@click.option("--quiet", is_flag=True, help="Print nothing but errors.")
@config_option
@force_option
def simulate_cmd(
    model,
    params,
    rmax,
    ratio,
    n_exp,
    noise,
    seed,
    forward,
    physics,
    t_end,
    dt_star,
    frame_s,
    phase,
    pre_max_s,
    scatter,
    req_in_meta,
    generator,
    material,
    out,
    quiet,
    force,
):
    """Write a synthetic dataset (one CSV per experiment, t_s,R_m in SI; meta.json) from the forward model, with
    truth.json."""
    from imrbayes.data import synthetic as syn

    _check_sampling(n_exp, t_end, dt_star, frame_s, phase, pre_max_s)
    rmax_spec = syn.parse_spec(rmax, "--rmax")
    ratio_spec = syn.parse_spec(ratio, "--ratio")
    if rmax_spec.mean > 0.01:
        raise InputError("--rmax", f"{rmax_spec.mean:g} m is over 1 cm; give Rmax in metres (e.g. 263e-6)")
    if ratio_spec.mean <= 1:
        raise InputError("--ratio", f"Rmax/Req must exceed 1, got {ratio_spec.mean:g}")
    noise_d = syn.parse_noise(noise)
    pvals = key_values(params, "--param", numeric=True)
    fopts = key_values(forward, "--forward", numeric=False)
    fm = _forward_model(model, fopts, key_values(physics, "--physics", numeric=True))
    names = tuple(fm.constitutive.param_names)
    scatter_sd = _check_parameters(model, names, pvals, scatter)
    ph = fm.physics.to_dict()
    rng = np.random.default_rng(seed)
    rmax_m = syn.draw_values(rmax_spec, n_exp, rng, lambda x: (x > 0) & (x <= 0.01), "--rmax")
    ratios = syn.draw_values(ratio_spec, n_exp, rng, lambda x: x > 1.0, "--ratio")
    req_m = rmax_m / ratios
    tc_s = rmax_m / math.sqrt(float(ph["p8"]) / float(ph["rho"]))
    phases = syn.draw_phases(seed, n_exp, frame_s or 0.0, phase == "random")
    grids = _sample_grids(tc_s, t_end, dt_star, frame_s, pre_max_s, phases)
    exp_params = syn.draw_scatter(seed, pvals, scatter_sd, n_exp) if scatter_sd else pvals
    maker = _curve_maker(fm, generator, quiet)
    clean = syn.simulate_dataset(maker, exp_params, rmax_m, req_m, grids)
    records, redrawn, t_max_s, sd_at_max = _noisy_records(grids, clean, rmax_m, tc_s, noise_d, rng)
    out = prepare_out(out, "simulate", model, force=bool(force))
    if any(out.glob("*.csv")) or (out / "meta.json").exists():
        raise InputError("--out", f"{out} already holds a dataset; choose a new or empty folder")
    noise_d = {
        **noise_d,
        "applied_to": "R* = R/Rmax, independent Gaussian per sample",
        "n_redrawn_nonpositive": redrawn,
    }
    files = [f"exp_{i:03d}.csv" for i in range(1, n_exp + 1)]
    options = fm.options.to_dict()
    description = f"imrbayes simulate: {model} {pvals}, noise {noise_d['kind']}, seed {seed}" + (
        "" if generator == "imrbayes" else f", curves by {generator}"
    )
    meta = _meta(material or f"synthetic ({model})", description, ph, options, files, req_m, rmax_m, req_in_meta)
    sampling = (
        {"dt_star": dt_star}
        if frame_s is None
        else {"frame_s": frame_s, "phase": phase, "pre_max_s": pre_max_s, "before_maximum": "mirror of the collapse"}
    ) | {"t_end_star": t_end}
    truth = {
        "model": model,
        "parameters": pvals,
        "param_names": list(names),
        "seed": seed,
        "n_experiments": n_exp,
        "noise": noise_d,
        "forward": options,
        "physics": ph,
        "rmax_spec_m": rmax_spec.to_dict(),
        "ratio_spec": ratio_spec.to_dict(),
        "sampling": sampling,
        "req_in_meta": req_in_meta,
        "scatter": scatter_sd,
        "generator": ({"code": "imrbayes", "forward": options} if generator == "imrbayes" else maker.describe()),
        "experiments": _truth_experiments(
            files,
            (rmax_m, req_m, ratios, tc_s),
            grids,
            (t_max_s, phases, sd_at_max),
            exp_params if scatter_sd else [pvals] * n_exp,
        ),
        "random_draws": RANDOM_DRAWS,
        "imrbayes_version": __version__,
    }
    syn.write_dataset(out, records, meta, truth)
    if not quiet:
        click.echo(f"wrote {n_exp} experiment(s), meta.json and truth.json to {out}")


def _meta(material: str, description: str, physics: dict, options: dict, files, req_m, rmax_m, req_in_meta: bool):
    """The dataset's meta.json.

    Parameters
    ----------
    material, description : str
        meta.json's ``material`` and ``description`` texts.
    physics, options : dict
        The physical constants (SI) and forward-model options the curves were made with.
    files : list of str
        The CSV file names, length n_exp.
    req_m, rmax_m : ndarray, shape (n_exp,)
        Each experiment's true Req and Rmax [m].
    req_in_meta : bool
        Write them per experiment (else Req must be estimated from each record's tail).

    Returns
    -------
    dict
    """
    return {
        "material": material,
        "description": description,
        "synthetic": True,
        "truth": "truth.json",
        "physics": physics,
        "forward": options,
        "experiments": (
            {f: {"Req_m": float(q), "Rmax_m": float(r)} for f, q, r in zip(files, req_m, rmax_m)} if req_in_meta else {}
        ),
    }


def _curve_maker(fm, generator: str, quiet: bool):
    """The code that makes the curves: the forward model itself, or PyIMR with its physics and options.

    Parameters
    ----------
    fm : imrbayes.forward.ForwardModel
        The forward model.
    generator : str
        ``imrbayes`` or ``pyimr``.
    quiet : bool
        Print nothing but errors (else PyIMR's version is announced).

    Returns
    -------
    object
        ``fm``, or an :class:`imrbayes.forward.peers.PyIMRModel` around it.
    """
    if generator != "pyimr":
        return fm
    from imrbayes.forward.peers import PyIMRModel

    maker = PyIMRModel(fm)
    if not quiet:
        click.echo(
            f"generating with PyIMR {maker.describe()['version']} (spectral, Nt {maker.nt}); "
            f"the first solve compiles (~15 s)",
            err=True,
        )
    return maker


def _check_sampling(n_exp: int, t_end: float, dt_star: float, frame_s, phase: str, pre_max_s: float) -> None:
    """Check the experiment count and the sampling options; raise InputError naming the bad option.

    Parameters
    ----------
    n_exp : int
        Number of experiments [-].
    t_end : float
        End of each record in t* [-].
    dt_star : float
        Sample interval in t* [-] (used without ``frame_s``).
    frame_s : float or None
        Camera frame interval [s] (None: the dt* grid).
    phase : str
        ``"0"`` or ``"random"``: the first frame's sub-frame offset.
    pre_max_s : float
        Record start before the maximum [s].
    """
    if n_exp < 1:
        raise InputError("--n-exp", f"must be at least 1, got {n_exp}")
    if not (math.isfinite(t_end) and t_end > 0):
        raise InputError("--t-end", f"must be a positive number of t* units, got {t_end}")
    if frame_s is None and not (math.isfinite(dt_star) and 0 < dt_star <= t_end):
        raise InputError("--dt-star", f"must be positive and at most --t-end, got {dt_star}")
    if frame_s is not None and not (math.isfinite(frame_s) and 0 < frame_s <= 1e-3):
        raise InputError("--frame-s", f"must be a frame interval in seconds, 0 < S <= 1e-3, got {frame_s}")
    if frame_s is None and (phase != "0" or pre_max_s):
        raise InputError("--phase" if phase != "0" else "--pre-max-s", "needs --frame-s (a camera frame interval)")
    if not (math.isfinite(pre_max_s) and 0 <= pre_max_s <= (1e-3 if frame_s is None else 1000 * frame_s)):
        raise InputError("--pre-max-s", f"must be a time in seconds, 0 <= S <= 1000 frames, got {pre_max_s}")


def _forward_model(model: str, fopts: dict, phys: dict):
    """The forward model of ``--model``, ``--forward`` and ``--physics``; a bad one raises InputError.

    Parameters
    ----------
    model : str
        Constitutive model name.
    fopts : dict
        Forward-model options ``{key: value}``.
    phys : dict
        Physical-constant overrides in SI units.

    Returns
    -------
    imrbayes.forward.ForwardModel
    """
    from imrbayes import forward as fwd

    models = list(fwd.available_models())
    try:
        return fwd.ForwardModel(
            model, options=fwd.ForwardOptions.from_dict(fopts, source="--forward"), physics_overrides=phys or None
        )
    except InputError as exc:
        if model not in models and exc.source in (None, "--model", "model"):
            raise InputError("--model", f"unknown model {model!r}; available: {', '.join(models)}")
        raise
    except (KeyError, ValueError) as exc:
        if model not in models:
            raise InputError("--model", f"unknown model {model!r}; available: {', '.join(models)}")
        raise InputError("--forward", str(exc))


def _check_parameters(model: str, names: tuple, pvals: dict, scatter) -> dict:
    """Check that ``--param`` gives exactly the model's parameters and ``--scatter`` only known ones,
    each relative sd in [0, 2].

    Parameters
    ----------
    model : str
        Constitutive model name (for the messages).
    names : tuple of str
        The model's parameter names.
    pvals : dict
        ``--param``'s values ``{name: value}`` in SI units.
    scatter : tuple of str
        ``--scatter``'s ``NAME=SD`` items (relative sds [-]).

    Returns
    -------
    dict
        The relative sds ``{name: sd}`` [-], checked.
    """
    unknown = [k for k in pvals if k not in names]
    missing = [k for k in names if k not in pvals]
    if unknown or missing:
        parts = ([f"unknown parameter(s) {', '.join(unknown)}"] if unknown else []) + (
            [f"missing {', '.join(missing)}"] if missing else []
        )
        raise InputError(
            "--param",
            f"{'; '.join(parts)}; model {model!r} takes {', '.join(names)} "
            f"(SI units, e.g. --param {names[0] if names else 'G'}=...)",
        )
    scatter_sd = key_values(scatter, "--scatter", numeric=True)
    bad = [k for k in scatter_sd if k not in names]
    if bad:
        raise InputError(
            "--scatter", f"unknown parameter(s) {', '.join(bad)}; model {model!r} takes {', '.join(names)}"
        )
    if any(not 0 <= v <= 2 for v in scatter_sd.values()):
        raise InputError("--scatter", f"a relative sd must be in [0, 2], got {scatter_sd}")
    return scatter_sd


def _sample_grids(tc_s, t_end: float, dt_star: float, frame_s, pre_max_s: float, phases) -> list:
    """Each experiment's sample times in t*: the dt* grid, or camera frames.

    Parameters
    ----------
    tc_s : ndarray, shape (n_exp,)
        Each experiment's time scale t_c [s].
    t_end : float
        End of each record in t* [-].
    dt_star : float
        Sample interval in t* [-] (used without ``frame_s``).
    frame_s : float or None
        Camera frame interval [s] (None: the dt* grid).
    pre_max_s : float
        Record start before the maximum [s].
    phases : ndarray, shape (n_exp,)
        The first frame's offset from the maximum [s].

    Returns
    -------
    list of ndarray
        One grid of t* values [-] per experiment.
    """
    from imrbayes.data import synthetic as syn

    if frame_s is None:
        n = int(math.floor(t_end / dt_star + 1e-9))
        return [np.arange(n + 1) * dt_star for _ in range(len(tc_s))]
    grids = [syn.camera_times(tc, frame_s, t_end, pre_max_s, ph) for tc, ph in zip(tc_s, phases)]
    if min(g.size for g in grids) < 10:
        raise InputError("--frame-s", f"{frame_s:g} s gives fewer than 10 frames per record")
    return grids


def _noisy_records(grids, clean, rmax_m, tc_s, noise_d: dict, rng) -> tuple:
    """Add the observation noise to each clean radius history and put it in camera time and metres.

    Parameters
    ----------
    grids : list of ndarray
        Each experiment's sample times in t* [-].
    clean : list of ndarray
        Each experiment's noise-free R* = R/Rmax [-], the shape of its grid.
    rmax_m, tc_s : ndarray, shape (n_exp,)
        Each experiment's Rmax [m] and time scale t_c [s].
    noise_d : dict
        The noise model (:func:`imrbayes.data.synthetic.parse_noise`).
    rng : numpy.random.Generator
        The generator of the noise draws (after the Rmax and ratio draws).

    Returns
    -------
    tuple
        ``(records, redrawn, t_max_s, sd_at_max)``: ``(t [s], R [m])`` per experiment, the time 0 at
        the first frame; the count of non-positive radii redrawn; each maximum's time [s]; the noise sd
        at the maximum in R* [-].
    """
    from imrbayes.data import synthetic as syn

    records, redrawn, t_max_s, sd_at_max = [], 0, [], []
    for g, Rs, rm, tc in zip(grids, clean, rmax_m, tc_s):
        if Rs.shape != g.shape or not np.all(np.isfinite(Rs)):
            raise RuntimeError("forward model returned a radius history of the wrong shape or with NaN")
        Rn, k = syn.noisy(g, Rs, noise_d, rng, rmax_m=rm)
        redrawn += k
        records.append(((g - g[0]) * tc, Rn * rm))  # camera time: 0 at the first frame
        t_max_s.append(-g[0] * tc)
        sd_at_max.append(float(syn.noise_sd(np.zeros(1), np.ones(1), noise_d, rm)[0]))
    return records, redrawn, t_max_s, sd_at_max


def _truth_experiments(files, sizes, grids, timing, exp_params) -> list:
    """truth.json's per-experiment entries.

    Parameters
    ----------
    files : list of str
        The CSV file names, length n_exp.
    sizes : tuple of ndarray, each shape (n_exp,)
        ``(rmax_m, req_m, ratios, tc_s)``: Rmax [m], Req [m], Rmax/Req [-] and time scale t_c [s].
    grids : list of ndarray
        Sample times in t* [-].
    timing : tuple of sequences, each length n_exp
        ``(t_max_s, phases, sd_at_max)``: time of the maximum [s], first frame's offset [s], noise sd
        at the maximum in R* [-].
    exp_params : list of dict
        Each experiment's material parameters in SI units.

    Returns
    -------
    list of dict
    """
    return [
        {
            "file": f,
            "rmax_m": float(r),
            "req_m": float(q),
            "rmax_over_req": float(a),
            "tc_s": float(tc),
            "n_samples": int(g.size),
            "t_max_s": float(tm),
            "phase_s": float(ph),
            "noise_sd_at_max_r_star": float(sm),
            "parameters": p,
        }
        for f, r, q, a, tc, g, tm, ph, sm, p in zip(files, *sizes, grids, *timing, exp_params)
    ]
