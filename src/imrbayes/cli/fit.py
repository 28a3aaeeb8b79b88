"""``imrbayes fit`` (interfaces.md §2): one inference method on one dataset.

Writes ``summary.json``, ``posterior.nc`` and ``figures/*.png`` under ``--out``. Every option can
come from ``--config FILE.toml`` (the command line wins). As for every command, a ``[fit]`` table
is read in preference to the top level; its keys are the option names (``method``, ``model``,
``out``, ``seed``, ``workers``, ``scheduler``, ``quiet``, ``camera``, ``dt_star``, ``n_steps``, ``noise``, ``set``
as a list of ``"KEY=VALUE"``), plus tables ``forward`` (forward-model options; a list of
``"KEY=VALUE"`` also works), ``prior`` (``G = [6e3, 2.8e3]``: mean and sd, SI) and ``imr``,
``pimr``, ``en4dvar``, ``mienks`` (method settings, as ``--set``), e.g. ``[fit.en4dvar]``, and
``mcmc`` (``true``, or a table of MCMC settings as ``--mcmc-set`` plus ``windows``).

``--mcmc`` (methods with a Gaussian posterior: ``mienks`` and ``en4dvar``) then samples every
window's posterior with emcee (:mod:`imrbayes.mcmc.fit`: one execution unit per window) and writes
``mcmc.nc``, ``compare.json`` and ``figures/mcmc_*.png``. The methods, their settings, figures and
labels come from the registry :data:`imrbayes.ensemble.METHODS`.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

import click

from imrbayes import __version__
from imrbayes.cli import main, read_config
from imrbayes.cli.options import (
    EXPERIMENTS_HELP,
    check_options,
    command_line,
    compare_line,
    data_fingerprint,
    echo_execution,
    estimate_text,
    execution_options,
    force_option,
    key_values,
    method_settings,
    open_execution,
    prepare_out,
    prior_base_name,
    prior_overrides,
    select_experiments,
)
from imrbayes.ensemble import METHODS
from imrbayes.ensemble.search import global_search
from imrbayes.errors import InputError
from imrbayes.execution.progress import finish, plan

METHOD_NAMES = tuple(METHODS)


def set_help() -> str:
    """``--set``'s help: one line per method naming its first keys; every key with its default and
    meaning is in docs/cli.md (generated from the settings classes)."""
    lines = ["Method setting; repeatable. Every key, its default and meaning: docs/cli.md.", "", "\b"]
    for m in METHODS.values():
        names = [f.name for f in dataclasses.fields(m.settings_class)]
        more = f", ... ({len(names)} keys)" if len(names) > 6 else ""
        lines.append(f"{m.name}: {', '.join(names[:6])}{more}")
    return "\n".join(lines)


def planned_units(meth, settings, n_exp: int, n_steps: int, fm=None) -> tuple:
    """(units the fit will run, what they are in words) for the progress bar's total, so that it counts
    the whole run from the start (``mienks: 18 windows x 5 experiments``); ``(None, "")`` when not
    known (the bar then grows batch by batch). Each method declares it
    (:meth:`~imrbayes.ensemble.InferenceMethod.n_units`; docs/guide.md)."""
    n, what = meth.n_units(settings, n_exp, n_steps, fm)
    return (None, "") if n is None else (int(n), what)


#: keys of the [fit] table (the options) and its sub-tables ([fit.forward], [fit.imr], ...)
CONFIG_OPTIONS = (
    "method",
    "model",
    "out",
    "seed",
    "prior_name",
    "workers",
    "scheduler",
    "quiet",
    "camera",
    "experiments",
    "dt_star",
    "n_steps",
    "noise",
    "likelihood",
    "forward",
    "prior",
    "set",
    "mcmc",
    "mcmc_set",
    "mcmc_windows",
    *METHOD_NAMES,
)
CONFIG_TABLES = ("forward", "prior", "mcmc", *METHOD_NAMES)


def _load_config(path) -> dict:
    """``--config``: the ``[fit]`` table (or the top level) as :func:`imrbayes.cli.read_config`
    reads it, with fit's own readings: ``[fit.mcmc]`` turns MCMC on with its settings, and
    ``forward`` may be a list of ``"KEY=VALUE"``."""
    cfg = read_config(
        path, "fit", options=CONFIG_OPTIONS, tables=CONFIG_TABLES, shared=("forward", "prior", *METHOD_NAMES)
    )  # a top-level [mcmc] does not turn MCMC on
    if isinstance(cfg.get("mcmc"), dict):  # [fit.mcmc] table: MCMC on, with these settings
        cfg["mcmc_table"], cfg["mcmc"] = cfg.pop("mcmc"), True
    if "mcmc" in cfg and not isinstance(cfg["mcmc"], bool):
        raise InputError(path, "mcmc must be true/false or a table of MCMC settings")
    for name in ("forward", "prior", *METHOD_NAMES):
        v = cfg.get(name)
        if name == "forward" and isinstance(v, (list, tuple)):
            cfg[name] = key_values(v, "--config forward")
        elif v is not None and not isinstance(v, dict):
            raise InputError(path, f"{name} must be a table")
    return cfg


@main.command("fit", help_lists=("models", "methods"))
@click.argument("data", type=click.Path(path_type=Path))
@click.option(
    "--method",
    type=click.Choice(METHOD_NAMES),
    default=None,
    help="Inference method (list below; or 'method' in --config).  [required]",
)
@click.option("--model", default=None, help="Constitutive model (list below).  [default: nhkv]")
@click.option(
    "--out",
    type=click.Path(path_type=Path),
    default=None,
    help="Output folder (default: a new folder under ./imrbayes-runs/).",
)
@click.option("--seed", type=int, default=None, help="Seed of every random draw [default: 0].")
@click.option(
    "--config",
    "config",
    type=click.Path(path_type=Path),
    default=None,
    help="TOML file: a [fit] table (or the top level) with any of these options, and "
    "[fit.forward], [fit.prior], [fit.<method>] tables; the command line wins.",
)
@click.option(
    "--forward",
    "forward",
    multiple=True,
    metavar="KEY=VALUE",
    help="Forward-model option overriding meta.json's forward block (bubble=polytropic, "
    "scheme=imrv2-fd, nt=25, radial=km, ...); repeatable.",
)
@click.option("--set", "settings", multiple=True, metavar="KEY=VALUE", help=None)
@click.option(
    "--prior",
    "priors",
    multiple=True,
    metavar="NAME=MEAN:SD",
    help="A named prior (wide: weakly informative over G 10 Pa-0.9 MPa and mu 1e-4-9 Pa s; paper: "
    "G 6 kPa sd 2.8, mu 0.209 Pa s sd 0.088), or NAME=MEAN:SD in SI units (G [Pa], mu [Pa s]) over "
    "it; repeatable  [default: wide; paper with --likelihood paper].",
)
@click.option(
    "--workers",
    type=int,
    default=None,
    help="Worker processes for the units (imr, en4dvar: experiments; mienks: the experiments of each "
    "window) [default: 1: in this process].",
)
@execution_options(with_workers=False)
@click.option(
    "--camera",
    default=None,
    help='Keep one camera view of multi-camera data (e.g. cam0deg), or "mean" to average the views of each bubble frame by frame.',
)
@click.option("--experiments", default=None, help=EXPERIMENTS_HELP)
@click.option("--dt-star", type=float, default=None, help="Grid step in t* [-] [default: 0.025].")
@click.option("--n-steps", type=int, default=None, help="Grid steps [-] [default: 120].")
@click.option(
    "--noise",
    type=click.Choice(["auto", "sample", "pooled", "paper"]),
    default=None,
    help="Observation noise P_k of --likelihood paper: sample: the across-experiment sample variance; "
    "pooled: the same pooled over 11 neighbouring steps (better weights with few experiments); "
    "paper: the paper's verification noise model; auto: sample with >= 2 experiments, else paper. "
    "The default likelihood uses each record's own noise.  [default: auto]",
)
@click.option(
    "--likelihood",
    type=click.Choice(["default", "paper"]),
    default=None,
    help="default: each sample once, each record's own noise, Rmax/Req/time of the maximum as "
    "nuisances, residual correlation tempered, a between-bubble layer; paper: the paper's averaged "
    "cost, across-experiment P_k and prior-corrected fusion (en4dvar, mienks).  [default: default]",
)
@click.option(
    "--mcmc",
    is_flag=True,
    default=None,
    help="Also sample every window's posterior with emcee and compare it with the ensemble's Gaussian "
    "(mienks: each window; en4dvar: the fitting window): mcmc.nc, compare.json, figures. Slow: "
    "sampling stops on convergence, typically after 2,000-5,000 likelihood evaluations per window "
    "(many more with nuisances): seconds per window with --forward bubble=polytropic, 0.5-3 min "
    "with the thermal bubble -- about 25 min on 2 cores for the 18 windows of a 5-experiment "
    "MIEnKS-MDA run, its fit included (fewer windows with --mcmc-windows).",
)
@click.option(
    "--mcmc-set",
    "mcmc_settings",
    multiple=True,
    metavar="KEY=VALUE",
    help="emcee setting: n_walkers, n_chains (independent ensembles), n_steps (hard cap), moves, "
    "indep_scale, indep_dof, indep_adapt, place (auto, start, laplace), min_steps, "
    "rhat_max, ess_min, tau_rule, burn, thin, "
    "max_draws, init_scale, lockstep, loglik, quadrature (true: also the exact grid posterior of "
    "2-parameter windows, ~40 % more time) [default: 2 ensembles x 8 walkers (2 per coordinate "
    "with nuisances), moves auto (indep:0.7,de:0.3; with nuisances the start placed on the target "
    "first, then 8 independent walkers (one nuisance per experiment) or ridge:0.5,blocks:0.5), "
    "stopped when R-hat <= 1.01, bulk and tail ESS >= 400 and >= 50 tau, cap 5000 steps]; "
    "repeatable.",
)
@click.option(
    "--mcmc-windows",
    default=None,
    metavar="all|J,K,...",
    help="Windows to sample with --mcmc (indices from 0) [default: all].",
)
@click.option("--quiet", is_flag=True, default=None, help="Print nothing but errors.")
@force_option
def fit_cmd(
    data,
    method,
    model,
    out,
    seed,
    config,
    forward,
    settings,
    priors,
    workers,
    camera,
    experiments,
    dt_star,
    n_steps,
    noise,
    likelihood,
    mcmc,
    mcmc_settings,
    mcmc_windows,
    quiet,
    scheduler,
    resume,
    retry_failed,
    force,
):
    """Fit a constitutive model to DATA (dataset folder, .csv or .mat) with one inference method.

    Writes summary.json (estimate: SI units, G [Pa], mu [Pa s]; times as t*), posterior.nc (ArviZ)
    and figures/*.png; 'imrbayes report OUT' turns them into one HTML page.

    Runtime: seconds (pimr) to minutes (imr, en4dvar, mienks; the thermal bubble is the slow part,
    --forward bubble=polytropic the fast one); --mcmc adds minutes to hours (see --mcmc).
    """
    t_start = time.perf_counter()
    cfg = _load_config(config)
    given = {
        "method": method,
        "model": model,
        "seed": seed,
        "workers": workers,
        "scheduler": scheduler,
        "quiet": quiet,
        "camera": camera,
        "experiments": experiments,
        "dt_star": dt_star,
        "n_steps": n_steps,
        "noise": noise,
        "out": out,
        "mcmc": mcmc,
        "mcmc_windows": mcmc_windows,
        "likelihood": likelihood,
    }
    invocation = {
        "data": data,
        "config": config,
        "resume": resume,
        "retry_failed": retry_failed,
        "force": force,
        "argv": command_line(click.get_current_context()),
    }
    opts = _resolve_options(cfg, given, invocation, mcmc_settings)
    meth = METHODS[opts.method]
    s = _fit_settings(opts, cfg, settings)
    # the paper's likelihood, however it was chosen (--likelihood or --set likelihood=paper), brings
    # the paper's prior unless another is named
    prior_base, priors = prior_base_name(priors, cfg.get("prior_name"), getattr(s, "likelihood", opts.likelihood))
    prior = prior_overrides(cfg.get("prior", {}), key_values(priors, "--prior"))
    mcmc_s = _mcmc_settings(opts, cfg, mcmc_settings)
    ds, pre, fm, obs, space = _load_inputs(opts, cfg, forward, prior, prior_base)
    meth.check_settings(s, obs)  # before any output: a refused --set leaves no folder behind
    if mcmc_s is not None:
        mcmc_s.check(space.n)  # before the fit: a bad walker count must not cost a fit
    out = prepare_out(
        Path(opts.out) if opts.out is not None else None,
        f"fit-{opts.method}",
        ds.name,
        protect=Path(data),
        force=bool(force),
        resume=bool(resume),
    )
    run_config = _run_config(opts, s, space, fm, obs, pre, mcmc_s)
    res, space, adequacy, compare, exec_summary = _execute(
        opts, out, run_config, s, fm, obs, space, pre, mcmc_s, t_start
    )
    written = _write_fit(out, res, obs, pre, fm, space, opts, exec_summary, t_start, compare=compare, adequacy=adequacy)
    if not opts.quiet:
        _echo_result(opts, out, res, obs, pre, fm, ds, compare, written)
    if compare is not None:
        _echo_mcmc_failures(compare)
    echo_execution(exec_summary, opts.quiet)
    if pre.skipped:
        click.echo(
            f"imrbayes: warning: {len(pre.skipped)} experiment(s) left out (preprocessing failed): "
            + "; ".join(f"{x['name']}: {x['error']}" for x in pre.skipped),
            err=True,
        )


next(p for p in fit_cmd.params if p.name == "settings").help = set_help()


@dataclasses.dataclass(frozen=True)
class FitOptions:
    """``fit``'s options once resolved: the command line wins over ``--config``, which wins over the
    default; plus how the command was invoked (what summary.json records of it).

    Attributes
    ----------
    method, model : str
        Inference method and constitutive model names.
    seed, workers : int
        Seed of every random draw; worker processes.
    scheduler : str or None
        Execution scheduler.
    quiet : bool
        Print nothing but errors.
    camera, experiments : str or None
        Camera view selection; 1-based experiment positions.
    dt_star : float
        Grid step in t* [-].
    n_steps : int
        Grid steps [-].
    noise : str
        Observation-noise choice of the paper likelihood.
    out : str, Path or None
        Output folder as given (None: a new one).
    mcmc : bool
        Also sample the window posteriors with emcee.
    mcmc_table : dict
        ``[fit.mcmc]``'s MCMC settings, its ``windows`` key removed.
    mcmc_windows : list of int or None
        Windows to sample (None: all).
    likelihood : str or None
        ``default`` or ``paper`` (None: the method's own).
    data : Path
        The dataset (folder, .csv or .mat).
    config : Path or None
        The ``--config`` file.
    resume, retry_failed, force : bool
        Execution and output-folder flags.
    argv : list of str
        The command line as typed.
    """

    method: str
    model: str
    seed: int
    workers: int
    scheduler: str | None
    quiet: bool
    camera: str | None
    experiments: str | None
    dt_star: float
    n_steps: int
    noise: str
    out: object
    mcmc: bool
    mcmc_table: dict
    mcmc_windows: list | None
    likelihood: str | None
    data: Path
    config: Path | None
    resume: bool
    retry_failed: bool
    force: bool
    argv: list


def _resolve_options(cfg: dict, given: dict, invocation: dict, mcmc_settings) -> FitOptions:
    """Resolve ``fit``'s options: the command line's value, else ``--config``'s, else the default; check them.

    Parameters
    ----------
    cfg : dict
        ``--config``'s ``[fit]`` table as :func:`_load_config` reads it.
    given : dict
        The command line's option values by name (None: not given).
    invocation : dict
        ``data``, ``config``, ``resume``, ``retry_failed``, ``force`` and ``argv`` as given.
    mcmc_settings : tuple of str
        ``--mcmc-set``'s ``KEY=VALUE`` items (they need ``--mcmc``).

    Returns
    -------
    FitOptions
        The resolved options; raises :class:`~imrbayes.errors.InputError` on a bad one.
    """

    def pick(name, default):
        value = given.get(name)
        return value if value is not None else cfg.get(name, default)

    method = pick("method", None)
    if method is None:
        raise InputError("--method", f"choose one of {', '.join(METHOD_NAMES)}")
    if method not in METHOD_NAMES:
        raise InputError("--method", f"unknown method {method!r}; choose one of {', '.join(METHOD_NAMES)}")
    model = pick("model", "nhkv")
    seed = pick("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise InputError("--seed", f"must be a non-negative integer, got {seed!r}")
    workers = pick("workers", 1)
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise InputError("--workers", f"must be a positive integer, got {workers!r}")
    scheduler = pick("scheduler", None)
    check_options(workers, scheduler, invocation["resume"], invocation["retry_failed"])
    quiet = bool(pick("quiet", False))
    camera = pick("camera", None)
    experiments = pick("experiments", None)
    dt_star = float(pick("dt_star", 0.025))
    n_steps = int(pick("n_steps", 120))
    noise = pick("noise", "auto")
    out = pick("out", None)
    mcmc = bool(pick("mcmc", False))
    mcmc_table = dict(cfg.get("mcmc_table") or {})
    mcmc_windows = _window_list(pick("mcmc_windows", mcmc_table.pop("windows", None)))
    if (mcmc_settings or mcmc_windows is not None) and not mcmc:
        raise InputError("--mcmc-set" if mcmc_settings else "--mcmc-windows", "needs --mcmc")
    if mcmc and not METHODS[method].gaussian_posterior:
        checkable = " or ".join(m.name for m in METHODS.values() if m.gaussian_posterior)
        raise InputError("--mcmc", f"needs --method {checkable} (a Gaussian posterior to check), got {method}")
    return FitOptions(
        method=method,
        model=model,
        seed=seed,
        workers=workers,
        scheduler=scheduler,
        quiet=quiet,
        camera=camera,
        experiments=experiments,
        dt_star=dt_star,
        n_steps=n_steps,
        noise=noise,
        out=out,
        mcmc=mcmc,
        mcmc_table=mcmc_table,
        mcmc_windows=mcmc_windows,
        likelihood=pick("likelihood", None),
        **invocation,
    )


def _fit_settings(opts: FitOptions, cfg: dict, settings):
    """The method's settings from ``[fit.<method>]``, ``[fit] set`` and ``--set`` (in rising precedence),
    with ``--likelihood`` applied.

    Parameters
    ----------
    opts : FitOptions
        The resolved options (method, likelihood).
    cfg : dict
        ``--config``'s ``[fit]`` table.
    settings : tuple of str
        ``--set``'s ``KEY=VALUE`` items.

    Returns
    -------
    dataclass
        An instance of the method's settings class.
    """
    meth = METHODS[opts.method]
    s = method_settings(
        meth.settings_class,
        cfg.get(opts.method, {}),
        {**key_values(cfg.get("set", []), "--config set"), **key_values(settings, "--set")},
    )
    if opts.likelihood is not None:
        if not any(f.name == "likelihood" for f in dataclasses.fields(s)):
            if opts.likelihood != "default":
                raise InputError(
                    "--likelihood",
                    f"applies to methods with a likelihood choice; {opts.method} has one observation model",
                )
        else:
            s = dataclasses.replace(s, likelihood=opts.likelihood)
    return s


def _mcmc_settings(opts: FitOptions, cfg: dict, mcmc_settings):
    """The emcee settings of ``--mcmc`` from ``[fit.mcmc]``, ``[fit] mcmc_set`` and ``--mcmc-set``.

    Parameters
    ----------
    opts : FitOptions
        The resolved options (mcmc, mcmc_table).
    cfg : dict
        ``--config``'s ``[fit]`` table.
    mcmc_settings : tuple of str
        ``--mcmc-set``'s ``KEY=VALUE`` items.

    Returns
    -------
    imrbayes.mcmc.MCMCSettings or None
        None without ``--mcmc``.
    """
    if not opts.mcmc:
        return None
    from imrbayes.mcmc import MCMCSettings

    return method_settings(
        MCMCSettings,
        opts.mcmc_table,
        {**key_values(cfg.get("mcmc_set", []), "--config mcmc_set"), **key_values(mcmc_settings, "--mcmc-set")},
        "--mcmc-set",
    )


def _load_inputs(opts: FitOptions, cfg: dict, forward, prior: dict, prior_base: str) -> tuple:
    """Load and preprocess the dataset and build the forward model, observations and parameter space.

    Parameters
    ----------
    opts : FitOptions
        The resolved options (data, camera, experiments, dt_star, n_steps, noise, model).
    cfg : dict
        ``--config``'s ``[fit]`` table (its ``forward`` table).
    forward : tuple of str
        ``--forward``'s ``KEY=VALUE`` items (over meta.json's and the config's forward options).
    prior : dict
        Prior overrides ``{name: (mean, sd)}`` in SI units.
    prior_base : str
        The named base prior (``wide``, ``paper``).

    Returns
    -------
    tuple
        ``(ds, pre, fm, obs, space)``: the dataset, its preprocessing, the
        :class:`~imrbayes.forward.ForwardModel`, the :class:`~imrbayes.ensemble.Observations` and the
        :class:`~imrbayes.ensemble.ParamSpace`.
    """
    from imrbayes.data import load_dataset, preprocess_dataset
    from imrbayes.ensemble import Observations, ParamSpace
    from imrbayes.forward import ForwardModel, ForwardOptions

    ds = select_experiments(load_dataset(opts.data, camera=opts.camera), opts.experiments)
    pre = preprocess_dataset(ds, dt_star=opts.dt_star, n_steps=opts.n_steps, noise=opts.noise, skip_failed=True)
    fopts = {**(ds.forward or {}), **(cfg.get("forward") or {}), **key_values(forward, "--forward")}
    fm = ForwardModel(
        opts.model,
        options=ForwardOptions.from_dict(fopts, source="forward options"),
        physics_overrides=ds.physics or None,
    )
    obs = Observations.from_preprocessed(pre)
    space = ParamSpace.for_model(fm.constitutive, prior, base=prior_base)
    return ds, pre, fm, obs, space


def _run_config(opts: FitOptions, s, space, fm, obs, pre, mcmc_s) -> dict:
    """The run's configuration: everything that determines the numbers (and nothing that does not:
    workers, scheduler, --out, --quiet), which a resumed run must match.

    Parameters
    ----------
    opts : FitOptions
        The resolved options.
    s : dataclass
        The method's settings.
    space, fm, obs, pre
        Parameter space, forward model, observations and preprocessing of the run.
    mcmc_s : imrbayes.mcmc.MCMCSettings or None
        The emcee settings (None without ``--mcmc``).

    Returns
    -------
    dict
        JSON-ready configuration.
    """
    run_config = {
        "command": "fit",
        "method": opts.method,
        "model": opts.model,
        "seed": opts.seed,
        "settings": dataclasses.asdict(s),
        "prior": space.describe(),
        "forward": fm.describe(),
        "preprocessing": {
            "dt_star": opts.dt_star,
            "n_steps": opts.n_steps,
            "noise": opts.noise,
            "camera": opts.camera,
            **({"experiments": opts.experiments} if opts.experiments else {}),
        },
        "data": data_fingerprint(
            obs.t_star, obs.R_star, obs.P, obs.rmax_m, obs.req_m, obs.t_collapse_star, names=obs.names
        ),
        "skipped_experiments": [x["name"] for x in pre.skipped],
    }
    if opts.mcmc:
        run_config["mcmc"] = {"settings": dataclasses.asdict(mcmc_s), "windows": opts.mcmc_windows}
    return run_config


def _execute(opts: FitOptions, out: Path, run_config: dict, s, fm, obs, space, pre, mcmc_s, t_start: float) -> tuple:
    """Run the fit (after the global search where the method asks for one) and, with ``--mcmc``, the
    emcee sampling of its windows, under one execution (resumable units, progress bar).

    Parameters
    ----------
    opts : FitOptions
        The resolved options.
    out : Path
        The output folder (prepared).
    run_config : dict
        The run's configuration (:func:`_run_config`).
    s : dataclass
        The method's settings.
    fm, obs, space, pre
        Forward model, observations, parameter space and preprocessing.
    mcmc_s : imrbayes.mcmc.MCMCSettings or None
        The emcee settings (None without ``--mcmc``).
    t_start : float
        ``time.perf_counter()`` at the command's start [s].

    Returns
    -------
    tuple
        ``(res, space, adequacy, compare, exec_summary)``: the method's result, the parameter space
        (with the global search's start where one ran), :func:`_adequacy`'s dict, the MCMC comparison
        (None without ``--mcmc``) and the execution summary.
    """
    from imrbayes.forward import Runner

    meth = METHODS[opts.method]
    runner = Runner(fm)
    compare = None
    with open_execution(
        out,
        run_config,
        workers=opts.workers,
        scheduler=opts.scheduler,
        resume=opts.resume,
        retry_failed=opts.retry_failed,
        quiet=opts.quiet,
        desc=opts.method,
    ) as execution:
        n_units, what = planned_units(meth, s, obs.n_exp, obs.n_samples - 1, fm)
        if what and execution.bar is not None:
            execution.bar.write(f"imrbayes: {opts.method}: {n_units} units ({what})", file=sys.stderr)
        search = None
        if meth.global_start(s, space):
            search = global_search(fm, obs, runner, progress=None if opts.quiet else _stage_line)
            space = space.with_start(*search.start(space))
        plan(execution.bar, n_units, opts.method)
        res = meth.fit(fm, obs, space, s, seed=opts.seed, runner=runner, execution=execution)
        finish(execution.bar)
        adequacy = _adequacy(res, obs, space, opts.model, search)
        if opts.mcmc:
            # the fit's own files first: an interrupted or failed MCMC phase leaves a complete fit behind
            _write_fit(out, res, obs, pre, fm, space, opts, execution.summary(), t_start, adequacy=adequacy)
            if not opts.quiet:
                click.echo(f"{opts.method} done in {res.runtime_s:.1f} s; sampling the window posteriors with emcee")
            compare = _sample_windows(opts, out, res, fm, obs, space, mcmc_s, execution, runner)
        exec_summary = execution.summary()
    return res, space, adequacy, compare, exec_summary


def _sample_windows(opts: FitOptions, out: Path, res, fm, obs, space, mcmc_s, execution, runner) -> dict:
    """``--mcmc``: sample every chosen window's posterior with emcee and compare it with the fit's Gaussian.

    Parameters
    ----------
    opts : FitOptions
        The resolved options (mcmc_windows, seed, quiet).
    out : Path
        The output folder (mcmc.nc, compare.json, figures).
    res
        The method's result (its window posteriors).
    fm, obs, space
        Forward model, observations and parameter space of the fit.
    mcmc_s : imrbayes.mcmc.MCMCSettings
        The emcee settings.
    execution, runner
        The open execution and the forward runner of the fit.

    Returns
    -------
    dict
        The comparison (``compare.json``'s content, plus its figures' paths).
    """
    from imrbayes.mcmc.fit import run_fit_mcmc

    n_win = len(getattr(res, "window_posteriors", None) or []) or 1
    n_win = n_win if opts.mcmc_windows is None else len([w for w in opts.mcmc_windows if w < n_win]) or 1
    plan(execution.bar, n_win, "emcee windows")
    return run_fit_mcmc(
        fm,
        obs,
        space,
        res,
        out,
        mcmc_s,
        opts.seed,
        execution=execution,
        runner=runner,
        windows=opts.mcmc_windows,
        warn=None if opts.quiet else (lambda w: click.echo(f"imrbayes: warning: {w}", err=True)),
    )


def _echo_result(opts: FitOptions, out: Path, res, obs, pre, fm, ds, compare, written: list) -> None:
    """Print the fit's warnings, its estimate and check, the constants it rests on and the files written.

    Parameters
    ----------
    opts : FitOptions
        The resolved options (method, model).
    out : Path
        The output folder (its summary.json is read back: the checks added to it).
    res, obs, pre, fm, ds
        The method's result, observations, preprocessing, forward model and dataset.
    compare : dict or None
        The MCMC comparison (None without ``--mcmc``).
    written : list of Path
        The figures written.
    """
    from imrbayes.io import read_json
    from imrbayes.report import fit_check_sentence, grouped_warnings

    summary = read_json(out / "summary.json", required=True)  # what the lead's checks added to it
    for w in grouped_warnings(list(pre.warnings) + list(res.warnings), res.param_names):
        click.echo(f"imrbayes: warning: {w}", err=True)  # warnings first: they qualify the result
    check = fit_check_sentence(summary)
    if check and (summary.get("fit_check") or {}).get("described") is False:
        click.echo(check)
    click.echo(
        f"{opts.method} ({opts.model}, {obs.n_exp} experiment(s)): {estimate_text(summary['estimate'], summary)}; "
        f"rmse {res.rmse:.3g} R* [-] ({res.rmse * _mean_rmax_um(obs):.3g} µm); {res.runtime_s:.1f} s"
    )
    if check and (summary.get("fit_check") or {}).get("described") is not False:
        click.echo(check)
    click.echo(constants_line(fm.physics, ds.physics or {}))
    extra = ", mcmc.nc, compare.json" if compare is not None else ""
    tables = ", time_resolved.csv" if (out / "time_resolved.csv").exists() else ""
    click.echo(
        f"wrote {out / 'summary.json'}, {out / 'posterior.nc'}, estimate.csv{tables}{extra} and "
        f"{len(written)} figure(s)"
    )
    if compare is not None:
        click.echo(compare_line(compare))


def _echo_mcmc_failures(compare: dict) -> None:
    """Warn of every MCMC window that failed and every emcee ensemble left out.

    Parameters
    ----------
    compare : dict
        The MCMC comparison (``compare.json``'s content).
    """
    for f in compare["overall"].get("failed_windows", []):
        click.echo(f"imrbayes: warning: MCMC of window {f['window']} failed: {f['error']}", err=True)
    for e in compare["windows"]:
        for c, err in ((e.get("mcmc") or {}).get("sampler") or {}).get("failed_chains", {}).items():
            click.echo(
                f"imrbayes: warning: MCMC window {e['index']}: emcee ensemble {c} failed and was left out: {err}",
                err=True,
            )


def _mean_rmax_um(obs) -> float:
    """The records' mean Rmax [µm]: R* = R/Rmax, so an rmse in R* times it is one in µm."""
    import numpy as np

    return float(np.mean(obs.rmax_m)) * 1e6


def _window_list(value):
    """``--mcmc-windows``: None/"all" -> None (every window), "0,3,5" or [0, 3] -> [0, 3, 5]."""
    if value is None or (isinstance(value, str) and value.strip().lower() == "all"):
        return None
    items = value if isinstance(value, (list, tuple)) else str(value).split(",")
    try:
        out = [int(str(v).strip()) for v in items if str(v).strip()]
    except ValueError:
        raise InputError("--mcmc-windows", f"expected 'all' or window indices such as 0,3,5, got {value!r}")
    if not out or min(out) < 0:
        raise InputError("--mcmc-windows", f"expected 'all' or non-negative window indices, got {value!r}")
    return sorted(set(out))


def _stage_line(text: str) -> None:
    click.echo(f"imrbayes: {text}", err=True)


def _adequacy(res, obs, space, model, search) -> dict:
    """What summary.json says beside the estimate: the fit check, the annotated estimate (bounded,
    G consistent with 0), the data's share of the posterior, the global search."""
    from imrbayes.ensemble.adequacy import annotate_estimate, fit_check

    out = {
        "fit_check": fit_check(res, obs, model),
        "estimate": annotate_estimate(res.estimate, space, res.cov_internal, search),
        "search": search.describe() if search is not None else None,
        "search_s": round(search.seconds, 2) if search is not None else None,
        "data_share": space.data_share(res.cov_internal) if res.cov_internal is not None else None,
    }
    return out


def _write_fit(
    out, res, obs, pre, fm, space, opts: FitOptions, exec_summary, t_start, compare=None, adequacy=None
) -> list:
    """summary.json, posterior.nc, estimate.csv (and time_resolved.csv where the method resolves
    time) and the method's figures; returns the figure paths."""
    import os
    import shlex

    from imrbayes.ensemble import figures as figs
    from imrbayes.ensemble.output import posterior_tree, summary_dict, write_summary
    from imrbayes.results import write_tables

    exec_summary["skipped_experiments"] = list(pre.skipped)
    if adequacy is not None and adequacy.get("search_s") is not None:
        exec_summary["global_search_s"] = adequacy["search_s"]
    mcmc_part = {}
    if compare is not None:
        mcmc_part = {"mcmc": {"files": ["mcmc.nc", "compare.json"], "overall": compare["overall"]}}
    prior = space.describe()
    checks = {}
    if adequacy is not None:
        prior["data_share"] = adequacy["data_share"]
        checks = {"fit_check": adequacy["fit_check"], **({"search": adequacy["search"]} if adequacy["search"] else {})}
    summary = summary_dict(
        res,
        obs,
        seed=opts.seed,
        extra={
            **checks,
            "forward": fm.describe(),
            "prior": prior,
            "preprocessing": pre.to_dict(arrays=False),
            "data": str(opts.data),
            "warnings_preprocessing": list(pre.warnings),
            "command": {
                "name": "fit",
                "method": opts.method,
                "model": opts.model,
                "seed": opts.seed,
                "workers": opts.workers,
                "scheduler": opts.scheduler,
                "resume": bool(opts.resume),
                "config": str(opts.config) if opts.config else None,
                "imrbayes_version": __version__,
                **({"argv": list(opts.argv), "line": shlex.join(opts.argv), "cwd": os.getcwd()} if opts.argv else {}),
            },
            "execution": exec_summary,
            "failures": {
                "skipped_experiments": list(pre.skipped),
                "failed_units": res.details.get("failed_units", []),
                "failed_member_runs": res.details.get("failed_member_runs", res.details.get("failed_grid_runs")),
                "redrawn_members": res.details.get("redrawn_members"),
            },
            "total_runtime_s": time.perf_counter() - t_start,
            **mcmc_part,
        },
    )
    if adequacy is not None:
        summary["estimate"] = adequacy["estimate"]
    write_summary(out / "summary.json", summary)
    posterior_tree(res, obs).to_netcdf(out / "posterior.nc")
    write_tables(out, summary)
    fdir = out / "figures"
    # the figures' µs and strain-rate axes: each experiment's time scale t_c [s] (t = t* t_c)
    tcs = {
        e.get("name"): e.get("tc_s") for e in pre.to_dict(arrays=False).get("experiments", []) if isinstance(e, dict)
    }
    if all(tcs.get(n) for n in obs.names):
        res.time_scale_s = [float(tcs[n]) for n in obs.names]
    written = [figs.fit_figure(obs, res, fdir / "fit.png")] + list(METHODS[opts.method].figures(obs, res, fdir))
    if compare is not None:
        written += list(compare.get("figures", []))
    return written


def constants_line(physics, given: dict) -> str:
    """One line naming the constants an estimate of G rests on and where each came from: on the
    stiff-PA data, rho 998.2 instead of 1064 kg/m^3 alone lowers G by 30 % (docs/validation.md 2a'')."""
    parts = []
    for key, label, unit in (
        ("rho", "rho", "kg/m^3"),
        ("p8", "p8", "Pa"),
        ("surface_tension", "S", "N/m"),
        ("kappa", "kappa", ""),
    ):
        src = "meta.json" if key in given else "default"
        parts.append(f"{label} {getattr(physics, key):g}{' ' + unit if unit else ''} ({src})")
    return (
        "constants: " + ", ".join(parts) + '; defaults are IMRv2\'s, meta.json "physics" sets them '
        "(G depends on rho: docs/guide.md)"
    )
