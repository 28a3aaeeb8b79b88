"""``imrbayes study``: several datasets under conditions, each fitted as an ordinary run, compared.

``imrbayes study STUDY.toml --out DIR`` or ``imrbayes study DATA... --label KEY=V1,V2,... --out DIR``.
Writes ``DIR/runs/<condition>/<method>/`` (ordinary run folders, reused when their configuration
is unchanged), ``study.csv``, ``study.json``, ``study.nc``, ``figures/`` and ``study.html``.
"""

from __future__ import annotations

import time
from pathlib import Path

import click

from imrbayes.cli import main
from imrbayes.cli.options import check_options, key_values
from imrbayes.errors import InputError


@main.command("study", short_help="Fit several datasets under conditions and compare them.")
@click.argument("inputs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option(
    "--out",
    type=click.Path(path_type=Path),
    required=True,
    help="Study folder (rerun into the same folder: unchanged runs are reused).",
)
@click.option(
    "--label",
    "labels",
    multiple=True,
    metavar="KEY=V1,V2,...",
    help="Condition label, one value per DATA in order (e.g. concentration=0.5%,5%); repeatable. Short form only.",
)
@click.option(
    "--name",
    "names",
    default=None,
    metavar="N1,N2,...",
    help="Condition names, one per DATA (default: each dataset's folder name). Short form only.",
)
@click.option(
    "--method",
    "methods",
    default=None,
    metavar="M1,M2",
    help="Fit methods run on each dataset [default: en4dvar,mienks: the constant estimate and G(t), mu(t)].",
)
@click.option(
    "--collapses",
    default=None,
    metavar="K1,K2",
    help="Also fit IMR to the k-th collapse of each dataset, one run per k (e.g. 1,2).",
)
@click.option(
    "--diagnose",
    type=click.Choice(["full", "quick"]),
    default=None,
    help="Also run 'imrbayes diagnose' (quick: --quick) on each dataset.",
)
@click.option("--model", default=None, help="Constitutive model [default: nhkv].")
@click.option("--seed", type=int, default=None, help="Seed of every run [default: 0].")
@click.option("--experiments", default=None, help="As fit --experiments, for every dataset.")
@click.option("--dt-star", type=float, default=None, help="As fit --dt-star, for every dataset [default: 0.025].")
@click.option("--n-steps", type=int, default=None, help="As fit --n-steps, for every dataset [default: 120].")
@click.option(
    "--forward",
    "forward",
    multiple=True,
    metavar="KEY=VALUE",
    help="Forward-model option for every run (bubble=polytropic, ...); repeatable.",
)
@click.option(
    "--set",
    "settings",
    multiple=True,
    metavar="METHOD.KEY=VALUE",
    help="A method's setting for every dataset (e.g. en4dvar.n_ens=12); repeatable.",
)
@click.option(
    "--workers",
    type=int,
    default=None,
    help="Worker processes: runs of different datasets in parallel [default: 1: in this process].",
)
@click.option(
    "--scheduler", default=None, metavar="local|tcp://HOST:PORT", help="Run the datasets' runs on a Dask cluster."
)
@click.option(
    "--force",
    is_flag=True,
    default=False,
    help="Replace run folders whose configuration changed (default: such a dataset is reported as failed).",
)
@click.option("--quiet", is_flag=True, default=False, help="Print nothing but errors.")
def study_cmd(
    inputs,
    out,
    labels,
    names,
    methods,
    collapses,
    diagnose,
    model,
    seed,
    experiments,
    dt_star,
    n_steps,
    forward,
    settings,
    workers,
    scheduler,
    force,
    quiet,
):
    """Compare materials and conditions: fit each dataset (an ordinary run folder under
    OUT/runs), then put the conditions side by side -- G and mu with 95 % intervals, ratios between
    conditions and trends along numeric labels computed from the posteriors -- in study.csv,
    study.json, study.nc, figures/ and study.html.

    INPUTS is one STUDY.toml (datasets, labels, methods, shared fit options) or dataset folders/files
    with --label.

    Runtime: each dataset costs what its fits cost (en4dvar with --forward bubble=polytropic: seconds
    to a minute; mienks and the thermal bubble: minutes each).
    """
    from imrbayes.study import read_study_file, run_study, study_from_args
    from imrbayes.study.spec import check_study, diagnose_mode

    t0 = time.perf_counter()
    check_options(workers, scheduler, False, False)
    options = {
        "methods": _names(methods, "--method"),
        "collapses": _ints(collapses, "--collapses"),
        "diagnose": diagnose,
        "model": model,
        "seed": seed,
        "experiments": experiments,
    }
    fwd = key_values(forward, "--forward")
    grid = {k: v for k, v in (("dt_star", dt_star), ("n_steps", n_steps)) if v is not None}
    sets = _method_settings(settings)
    if len(inputs) == 1 and inputs[0].suffix.lower() == ".toml":
        if labels or names:
            raise InputError(
                "--label" if labels else "--name",
                "belongs to the short form; a study file gives each dataset's labels and name",
            )
        spec = read_study_file(inputs[0])
        for k, v in options.items():
            if v is not None:
                setattr(spec, k, diagnose_mode(v, "--diagnose") if k == "diagnose" else v)
        spec.forward = {**spec.forward, **fwd}
        spec.grid = {**spec.grid, **grid}
        for m, kv in sets.items():
            spec.settings[m] = {**spec.settings.get(m, {}), **kv}
        spec.source = str(inputs[0])
        check_study(spec)
    else:
        name_list = [n.strip() for n in names.split(",")] if names else None
        if name_list is not None and len(name_list) != len(inputs):
            raise InputError("--name", f"{len(name_list)} name(s) for {len(inputs)} dataset(s)")
        if options["diagnose"] is not None:
            options["diagnose"] = diagnose_mode(options["diagnose"], "--diagnose")
        spec = study_from_args(inputs, labels, name_list, forward=fwd, settings=sets, grid=grid, **options)
    _check_out(out, [c.data for c in spec.conditions])
    out.mkdir(parents=True, exist_ok=True)
    say = (lambda s: None) if quiet else (lambda s: click.echo(f"imrbayes: study: {s}", err=True))
    study = run_study(spec, out, workers=workers, scheduler=scheduler, replace=force, report=say)
    failed = [k for k, v in study["runs"].items() if v["status"] == "failed"]
    if not quiet:
        for line in study["conclusion"]:
            click.echo(line)
        click.echo(
            f"wrote {out / 'study.csv'}, study.json, study.nc, study.html ({len(spec.conditions)} "
            f"condition(s), {len(study['runs'])} run(s), {len(failed)} failed; "
            f"{time.perf_counter() - t0:.0f} s)"
        )
    for k in failed:
        click.echo(f"imrbayes: warning: {k} failed: {study['runs'][k]['error']}", err=True)


def _names(value, option):
    if value is None:
        return None
    out = tuple(v.strip() for v in str(value).split(",") if v.strip())
    if not out:
        raise InputError(option, f"expected comma-separated names, got {value!r}")
    return out


def _ints(value, option):
    if value is None:
        return None
    try:
        return tuple(int(v) for v in str(value).split(",") if v.strip())
    except ValueError:
        raise InputError(option, f"expected comma-separated integers such as 1,2, got {value!r}")


def _method_settings(items) -> dict:
    """``--set METHOD.KEY=VALUE`` items as ``{method: {key: value}}``."""
    out = {}
    for key, value in key_values(items, "--set").items():
        method, dot, name = key.partition(".")
        if not dot or not method or not name:
            raise InputError("--set", f"expected METHOD.KEY=VALUE (e.g. en4dvar.n_ens=12), got {key}={value}")
        out.setdefault(method, {})[name] = value
    return out


def _check_out(out: Path, data_paths) -> None:
    """``--out`` must be a folder that is new, empty or an earlier study (it holds ``runs/`` or
    ``study.json``), and no dataset's folder."""
    if out.exists() and not out.is_dir():
        raise InputError("--out", f"{out} exists and is not a directory")
    for d in data_paths:
        p = d if d.is_dir() else d.parent
        if out.resolve() == p.resolve():
            raise InputError(
                "--out", f"{out} is a dataset's folder; choose another folder (input files are never written to)"
            )
    if out.is_dir() and any(out.iterdir()) and not ((out / "runs").is_dir() or (out / "study.json").is_file()):
        raise InputError("--out", f"{out} holds files but no study; choose a new or empty folder")
