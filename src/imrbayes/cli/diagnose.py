"""``imrbayes diagnose DATA`` (interfaces.md §2-3): is a constant-parameter NHKV adequate for DATA,
and if not, which mechanism explains it and what does the extended model gain on unseen data.

Writes ``diagnosis.json``, a self-contained ``report.html`` and ``figures/*.png`` under ``--out``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import click

from imrbayes import __version__
from imrbayes.cli import config_option, main
from imrbayes.cli.options import (
    EXPERIMENTS_HELP,
    check_options,
    data_fingerprint,
    echo_execution,
    execution_options,
    force_option,
    key_values,
    open_execution,
    prepare_out,
    select_experiments,
)
from imrbayes.diagnosis.candidates import CANDIDATES, DEFAULT_CANDIDATES
from imrbayes.errors import InputError


@main.command("diagnose")
@config_option
@click.argument("data", type=click.Path(path_type=Path))
@click.option(
    "--out",
    type=click.Path(path_type=Path),
    default=None,
    help="Output folder (default: a new folder under ./imrbayes-runs/).",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the bootstrap and every draw.")
@click.option(
    "--quick", is_flag=True, default=False, help="Exploration: MAP baseline (no En4D-Var), fewer Laplace draws."
)
@click.option(
    "--forward",
    "forward",
    multiple=True,
    metavar="KEY=VALUE",
    help="Forward-model option overriding meta.json's forward block (bubble=polytropic, "
    "scheme=imrv2-fd, ...); repeatable. Default: the forward model's own, grid-converged "
    "(scheme=converged).",
)
@click.option(
    "--n-bootstrap",
    type=int,
    default=None,
    help="Bootstrap replicates of the constant-parameter check [-] [default: 19, the smallest "
    "that can reject at 5 %; more sharpen the p-value at ~20 s each (thermal, 5 bubbles)].",
)
@click.option(
    "--candidates",
    default=None,
    metavar="KEY[,KEY...]",
    help="Comma-separated candidate models: "
    + "; ".join(f"{k} ({c.mechanism})" for k, c in CANDIDATES.items())
    + f" [default: {','.join(DEFAULT_CANDIDATES)}].",
)
@click.option(
    "--no-loeo",
    is_flag=True,
    default=False,
    help="Skip leave-one-experiment-out (N_exp extra fits per model; by default run for the baseline and "
    "the candidates the forecast leaves in contention). A cause is named only for a held-out gain "
    ">= 10 % at >= 2 paired SE over the baseline on the schemes taken together, so without it the "
    "forecast alone must show that.",
)
@click.option(
    "--loeo-all",
    is_flag=True,
    default=False,
    help="Leave-one-experiment-out for every candidate, not only those the forecast leaves in contention.",
)
@click.option(
    "--mienks-drift",
    is_flag=True,
    default=False,
    help="Add the MIEnKS-MDA G(t), mu(t) drift to the check's statistics (doubles the bootstrap's cost; "
    "not part of the measured power and false-alarm rate).",
)
@click.option(
    "--stop-when-adequate",
    is_flag=True,
    default=False,
    help="End after the constant-parameter check when it finds the model adequate (the cause is 'none' "
    "either way), without comparing the candidates: ~60 % of such a run's time.",
)
@click.option("--experiments", default=None, help=EXPERIMENTS_HELP)
@click.option(
    "--camera",
    default=None,
    help='Keep one camera view of multi-camera data (e.g. cam0deg), or "mean" to average the views of each bubble frame by frame.',
)
@click.option("--dt-star", type=float, default=0.025, show_default=True, help="Grid step in t* [-].")
@click.option("--n-steps", type=int, default=120, show_default=True, help="Grid steps [-].")
@click.option("--quiet", is_flag=True, default=False, help="Print nothing but errors.")
@execution_options(with_workers=True)
@force_option
def diagnose_cmd(
    data,
    out,
    seed,
    quick,
    forward,
    n_bootstrap,
    candidates,
    no_loeo,
    loeo_all,
    mienks_drift,
    stop_when_adequate,
    experiments,
    camera,
    dt_star,
    n_steps,
    quiet,
    workers,
    scheduler,
    resume,
    retry_failed,
    force,
):
    """Diagnose DATA: baseline NHKV fit and misfit by phase (t* = dimensionless time), a bootstrap-
    calibrated constant-parameter check, candidate mechanisms (see --candidates) ranked by held-out
    prediction, and the gain of the extended model (RMSE in R* = R/Rmax, ELPD in nats). SI units for
    all parameters.

    Runtime (measured on 2 cores): 5 bubbles with the default thermal bubble 11-14 min at default
    settings on AMD znver4/znver5 hosts, 17.5-19 min on AVX2-only znver3 ones and 23 min on an Intel
    icelake one; 20 bubbles with --forward
    bubble=polytropic and --quick ~25 min on one core; --experiments and --no-loeo cut it (--workers
    helps only where cores are idle: the forward model already spreads its batches over the cores).
    Writes diagnosis.json, report.html and figures."""
    t_start = time.perf_counter()
    check_options(workers, scheduler, resume, retry_failed)
    if seed < 0:
        raise InputError("--seed", f"must be a non-negative integer, got {seed}")
    s = _diagnose_settings(
        quick=quick,
        n_bootstrap=n_bootstrap,
        candidates=candidates,
        no_loeo=no_loeo,
        loeo_all=loeo_all,
        mienks_drift=mienks_drift,
        stop_when_adequate=stop_when_adequate,
    )
    ds, pre, obs, options, physics = _load_inputs(data, camera, experiments, dt_star, n_steps, forward)
    out = prepare_out(
        Path(out) if out is not None else None,
        "diagnose",
        ds.name,
        protect=Path(data),
        force=bool(force),
        resume=bool(resume),
    )
    if options.bubble == "thermal" and not quiet:
        click.echo(
            f"imrbayes: note: thermal bubble, scheme={options.scheme}; a diagnosis needs "
            "O(1e5) solves (tens of minutes for 5 experiments on 2 cores). For exploration use --quick, --forward "
            "bubble=polytropic, --experiments and --no-loeo.",
            err=True,
        )
    from dataclasses import asdict

    run_config = {
        "command": "diagnose",
        "seed": seed,
        "settings": {**asdict(s), "candidates": list(s.candidates)},
        "forward": options.to_dict(),
        "physics": physics.to_dict(),
        "preprocessing": {"dt_star": dt_star, "n_steps": n_steps, "camera": camera, "experiments": experiments},
        "data": data_fingerprint(obs.t_star, obs.R_star, obs.P, obs.rmax_m, obs.req_m, names=obs.names),
    }
    execution_kw = {"workers": workers, "scheduler": scheduler, "resume": resume, "retry_failed": retry_failed}
    d, exec_summary = _run_diagnosis(out, run_config, execution_kw, s, obs, options, physics, seed, quiet)
    exec_summary["skipped_experiments"] = list(pre.skipped)
    res = d.result
    res["data"] = str(data)
    res["experiments"] = list(obs.names)
    res["forward"] = options.to_dict()
    res["preprocessing"] = pre.to_dict(arrays=False)
    res["command"] = {"name": "diagnose", "seed": seed, "quick": bool(quick), "imrbayes_version": __version__}
    res["execution"] = exec_summary
    res["failures"] = {"skipped_experiments": list(pre.skipped), "failed_units": res.get("failed_units", [])}
    res["total_runtime_s"] = time.perf_counter() - t_start
    _write_outputs(d, res, out, ds.name)
    if not quiet:
        _echo_result(res, out)
    echo_execution(exec_summary, quiet)
    for w in res.get("warnings", []):  # what the diagnosis left out (also in diagnosis.json)
        click.echo(f"imrbayes: warning: {w}", err=True)
    if pre.skipped:
        click.echo(
            f"imrbayes: warning: {len(pre.skipped)} experiment(s) left out (preprocessing failed): "
            + "; ".join(f"{x['name']}: {x['error']}" for x in pre.skipped),
            err=True,
        )


def _diagnose_settings(*, quick, n_bootstrap, candidates, no_loeo, loeo_all, mienks_drift, stop_when_adequate):
    """The diagnosis settings from the command's options (checked).

    Parameters
    ----------
    quick : bool
        ``--quick``: the exploration settings.
    n_bootstrap : int or None
        Bootstrap replicates [-] (None: the default).
    candidates : str or None
        Comma-separated candidate keys (None: the default candidates).
    no_loeo, loeo_all, mienks_drift, stop_when_adequate : bool
        The flags of the same names.

    Returns
    -------
    imrbayes.diagnosis.DiagnoseSettings
        The settings; raises :class:`~imrbayes.errors.InputError` on a bad option.
    """
    from imrbayes.diagnosis import DiagnoseSettings

    kw = {}
    if n_bootstrap is not None:
        if n_bootstrap < 1:
            raise InputError("--n-bootstrap", f"must be at least 1, got {n_bootstrap}")
        kw["n_bootstrap"] = int(n_bootstrap)
    if candidates:
        keys = tuple(c.strip() for c in candidates.split(",") if c.strip())
        bad = [k for k in keys if k not in CANDIDATES]
        if bad or not keys:
            raise InputError("--candidates", f"unknown candidate(s) {bad}; known: {', '.join(CANDIDATES)}")
        kw["candidates"] = keys
    else:
        kw["candidates"] = DEFAULT_CANDIDATES
    if no_loeo:
        kw["loeo"] = False
    if loeo_all:
        if no_loeo:
            raise InputError("--loeo-all", "cannot be combined with --no-loeo")
        kw["loeo_all"] = True
    if mienks_drift:
        kw["mienks_drift"] = True
    if stop_when_adequate:
        kw["compare_when_adequate"] = False
    return DiagnoseSettings.quick(**kw) if quick else DiagnoseSettings(**kw)


def _load_inputs(data, camera, experiments, dt_star: float, n_steps: int, forward) -> tuple:
    """Load and preprocess the dataset; the forward options and physical constants of the diagnosis.

    Parameters
    ----------
    data : Path
        The dataset (folder, .csv or .mat).
    camera, experiments : str or None
        Camera view selection; 1-based experiment positions.
    dt_star : float
        Grid step in t* [-].
    n_steps : int
        Grid steps [-].
    forward : tuple of str
        ``--forward``'s ``KEY=VALUE`` items (over meta.json's forward block).

    Returns
    -------
    tuple
        ``(ds, pre, obs, options, physics)``: the dataset, its preprocessing, the
        :class:`~imrbayes.ensemble.Observations`, the :class:`~imrbayes.forward.ForwardOptions` and
        the :class:`~imrbayes.forward.constants.Physics`.
    """
    from imrbayes.data import load_dataset, preprocess_dataset
    from imrbayes.ensemble import Observations
    from imrbayes.forward import ForwardOptions
    from imrbayes.forward.constants import Physics

    ds = select_experiments(load_dataset(data, camera=camera), experiments)
    pre = preprocess_dataset(ds, dt_star=dt_star, n_steps=n_steps, skip_failed=True)
    obs = Observations.from_preprocessed(pre)
    # The forward model's own default discretisation (grid-converged; methods.md §7.5): IMRv2's coarse
    # Nt = 25 grid moves the inferred viscosity by ~2x on real data and raises alarms on constant-parameter
    # data, so it is never a silent default here. meta.json or --forward scheme=imrv2-fd select it.
    fopts = {**(ds.forward or {}), **key_values(forward, "--forward")}
    options = ForwardOptions.from_dict(fopts, source="forward options")
    physics = Physics.from_overrides(ds.physics or None)
    return ds, pre, obs, options, physics


def _run_diagnosis(out: Path, run_config: dict, execution_kw: dict, s, obs, options, physics, seed: int, quiet: bool):
    """Run the diagnosis under one execution, with a progress bar on a terminal and one line per stage
    elsewhere.

    Parameters
    ----------
    out : Path
        The output folder (prepared).
    run_config : dict
        Everything that determines the numbers (a resumed run must match it).
    execution_kw : dict
        ``workers``, ``scheduler``, ``resume``, ``retry_failed`` for :func:`open_execution`.
    s : imrbayes.diagnosis.DiagnoseSettings
        The settings.
    obs, options, physics
        Observations, forward options and physical constants.
    seed : int
        Seed of the bootstrap and every draw.
    quiet : bool
        Print nothing but errors.

    Returns
    -------
    tuple
        ``(d, exec_summary)``: the diagnosis (:func:`imrbayes.diagnosis.diagnose`) and the execution
        summary.
    """
    from imrbayes.diagnosis import diagnose
    from imrbayes.diagnosis.check import min_replicates

    show = (not quiet) and sys.stderr.isatty()
    bar = None
    if show:
        from imrbayes.execution.progress import progress_bar

        bar = progress_bar(
            total=1 + s.n_bootstrap + 2 * len(s.candidates) + 1, unit="steps", desc="diagnose", file=sys.stderr
        )
    try:
        with open_execution(out, run_config, **execution_kw, quiet=True) as execution:
            t_stage = time.perf_counter()
            if s.n_bootstrap < min_replicates(s.alpha) and not quiet:  # again among the run's warnings
                click.echo(
                    f"imrbayes: note: --n-bootstrap {s.n_bootstrap}: fewer than {min_replicates(s.alpha)} "
                    f"replicates cannot reject at alpha = {s.alpha:g} (smallest p-value 1/(B+1)); the check "
                    "will say adequate whatever the data",
                    err=True,
                )

            def stage(msg):  # off a terminal (logs, batch jobs): one line per stage, with the time
                click.echo(f"imrbayes: diagnose [{time.perf_counter() - t_stage:6.0f} s] {msg}", err=True)

            log = bar.set_postfix_str if bar is not None else (None if quiet else stage)
            d = diagnose(
                obs,
                options,
                physics,
                s,
                seed=seed,
                progress=(bar.update if bar is not None else None),
                log=log,
                execution=execution,
            )
            exec_summary = execution.summary()
    finally:
        if bar is not None:
            bar.close()
    return d, exec_summary


def _write_outputs(d, res: dict, out: Path, name: str) -> None:
    """Write the figures, diagnosis.json and report.html.

    Parameters
    ----------
    d
        The diagnosis (:func:`imrbayes.diagnosis.diagnose`; its figures' data).
    res : dict
        diagnosis.json's content.
    out : Path
        The output folder.
    name : str
        The dataset's name (the report's title).
    """
    from imrbayes.diagnosis.figures import write_figures
    from imrbayes.diagnosis.report import write_report
    from imrbayes.io import write_json

    figs = write_figures(d, out / "figures")
    write_json(out / "diagnosis.json", res)
    write_report(res, figs, out / "report.html", title=f"imrbayes diagnose: {name}")


def _echo_result(res: dict, out: Path) -> None:
    """Print the check's verdict, the cause, the held-out gain, the sensitivity and consistency flags
    and the files written.

    Parameters
    ----------
    res : dict
        diagnosis.json's content.
    out : Path
        The output folder.
    """
    from imrbayes.diagnosis.check import p_value_text
    from imrbayes.diagnosis.sensitivity import flagged, options_text

    chk = res["constant_parameter_check"]
    g = res.get("gain") or {}
    click.echo(
        f"constant-parameter check: {chk['verdict']} ({p_value_text(chk['evidence'])}); "
        f"cause: {res['cause']}; extended model: {res['extended_model']}"
    )
    if res.get("cause_note"):
        click.echo(f"cause: {res['cause_note']}")
    if g:
        click.echo(
            f"held-out RMSE ({g.get('candidate')}, {g.get('heldout_scheme')}): baseline "
            f"{g['heldout_rmse_baseline']:.4g} -> {g['heldout_rmse_extended']:.4g}; ELPD diff "
            f"{g['elpd_diff']:.1f} ± {g['elpd_se']:.1f}"
        )
    for a in flagged(res.get("bubble_model_sensitivity")):
        moved = ", ".join(f"{n} {a['shift'][n]:+.0%}" for n in a["material_moves"])
        click.echo(
            f"bubble-model sensitivity: with {options_text(a)} (not separated by the held-out data, "
            f"{a['separation_se']:.1f} SE) the material estimate moves: {moved}"
        )
    rc = (res.get("baseline") or {}).get("req_consistency") or {}
    if rc.get("flagged"):
        click.echo(
            f"Req conflict: in {rc['n_conflict']} of {rc['n_estimated']} experiments the baseline's Req lies "
            f"more than {rc['bound']:g} tail sd from the record's own (median |z| {rc['median_abs_z']:.3g}): "
            "the model fits the collapses with another bubble than the one filmed"
        )
    ac = (res.get("baseline") or {}).get("alignment_consistency") or {}
    if ac.get("flagged"):
        click.echo(
            f"alignment conflict: in {ac['n_conflict']} of {ac['n_estimated']} experiments the baseline's Rmax or "
            f"time of the maximum lies more than {ac['bound']:g} sd from the local fit of the maximum (median |z| "
            f"{ac['median_abs_z_rmax']:.3g} / {ac['median_abs_z_t0']:.3g}): model error absorbed by the alignment"
        )
    click.echo(f"wrote {out / 'diagnosis.json'}, {out / 'report.html'} ({res['total_runtime_s']:.0f} s)")
