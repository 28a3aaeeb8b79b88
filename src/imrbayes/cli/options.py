"""Shared command-line helpers: option parsing, run folders (:func:`new_run_dir`, :func:`prepare_out`,
from :mod:`imrbayes.io`), and the plumbing of the execution layer (docs/guide.md): ``--workers``,
``--scheduler``, ``--resume``, ``--retry-failed`` for ``fit``, ``diagnose`` and ``validate``.

The run directory is ``--out``: ``run.json`` (the exact configuration, its fingerprint, the
imrbayes version), ``status.json`` and ``units/`` (one checkpoint per finished unit) next to the
command's own outputs.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import math
import sys

import click
import numpy as np

from imrbayes.errors import InputError
from imrbayes.io import new_run_dir, prepare_out  # the run folders' home; the commands take them from here

__all__ = [
    "execution_options",
    "estimate_text",
    "force_option",
    "open_execution",
    "data_fingerprint",
    "echo_execution",
    "check_options",
    "new_run_dir",
    "prepare_out",
    "key_values",
    "coerce_setting",
    "method_settings",
    "prior_overrides",
    "compare_line",
]


def estimate_text(estimate: dict, summary: dict | None = None) -> str:
    """One line of a fit's estimate with units on every number: ``G = 13.5 kPa ± 0.6 kPa (95 %
    12.3-14.7 kPa), mu = ...``; a range the data do not bound reads ``G not bounded by the data (best
    fit 7.3 kPa)`` (:func:`imrbayes.report.estimate_phrase` decides, for the report too)."""
    from imrbayes.report import _units, estimate_phrase

    units = _units(summary or {})
    return ", ".join(estimate_phrase(name, e or {}, units, summary) for name, e in estimate.items())


def force_option(f):
    """Decorator adding ``--force``: write into an existing, non-empty ``--out`` folder."""
    return click.option(
        "--force",
        is_flag=True,
        default=None,
        help="Write into --out even if it already holds files (files of the same name are "
        "replaced; a folder holding a run is still refused). Without it a non-empty --out is "
        "refused.",
    )(f)


def execution_options(with_workers: bool = True):
    """Decorator adding ``--scheduler``, ``--resume``, ``--retry-failed`` (and ``--workers``)."""

    def deco(f):
        f = click.option(
            "--retry-failed",
            "retry_failed",
            is_flag=True,
            default=None,
            help="With --resume: rerun the units that failed last time (default: report them again).",
        )(f)
        f = click.option(
            "--resume",
            is_flag=True,
            default=None,
            help="Continue the run in --out: finished units are read back, not rerun. Refused if "
            "the configuration (data, model, settings, seed) or the imrbayes version differs.",
        )(f)
        f = click.option(
            "--scheduler",
            default=None,
            metavar="local|tcp://HOST:PORT",
            help="Run the units on a Dask cluster: 'local' starts a LocalCluster with --workers "
            "processes; an address uses an existing cluster's workers.",
        )(f)
        if with_workers:
            f = click.option(
                "--workers",
                type=int,
                default=None,
                help="Worker processes for the units (experiments, windows, cases) [default: 1: in this process].",
            )(f)
        return f

    return deco


def data_fingerprint(*arrays, names=()) -> str:
    """SHA-256 of the arrays' bytes (dtype, shape, contents) and the names: what the units see."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(np.asarray(a))
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    for n in names:
        h.update(str(n).encode("utf-8") + b"\0")
    return h.hexdigest()


def check_options(workers, scheduler, resume, retry_failed) -> tuple:
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise InputError("--workers", f"must be a positive integer, got {workers!r}")
    if retry_failed and not resume:
        raise InputError("--retry-failed", "only makes sense with --resume")
    if scheduler is not None:
        s = str(scheduler).strip()
        if s != "local" and "://" not in s:
            raise InputError(
                "--scheduler", f"must be 'local' or a scheduler address such as tcp://host:8786, got {scheduler!r}"
            )
    return workers, scheduler, bool(resume), bool(retry_failed)


@contextlib.contextmanager
def open_execution(
    out,
    config: dict,
    *,
    workers=None,
    scheduler=None,
    resume=False,
    retry_failed=False,
    quiet: bool = False,
    desc: str = "run",
):
    """RunStore under ``out`` for ``config`` + the executor ``--workers/--scheduler`` ask for, as an
    :class:`imrbayes.execution.Execution` with, unless ``quiet``, one progress bar (``desc``) over
    every batch on a terminal, one line per batch otherwise; the command plans its total
    (:func:`imrbayes.execution.progress.plan`). Bad options and refused resumes raise InputError."""
    from imrbayes.execution import Execution, RunStore, make_executor
    from imrbayes.io import jsonable

    workers, scheduler, resume, retry_failed = check_options(workers, scheduler, resume, retry_failed)
    # the executor first: an unreachable --scheduler must not leave a new run directory behind
    with make_executor(workers, scheduler) as ex, RunStore.open(out, jsonable(config), resume=resume) as store:
        bar = None
        if store.previous_interrupted is not None and not quiet:
            st = store.previous_interrupted
            click.echo(
                f"imrbayes: the earlier run in {out} was interrupted (its last batch: {st.get('n_done', '?')} "
                f"of {st.get('n_units', '?')} units done); continuing from its checkpoints",
                err=True,
            )
        if not quiet and _isatty(sys.stderr):
            from imrbayes.execution.progress import progress_bar

            bar = progress_bar(total=None, desc=desc, unit="units", file=sys.stderr)
        elif not quiet:  # a log file or pipe: one line per stage, never silence until the end
            from imrbayes.execution.progress import StageLog

            bar = StageLog(desc=desc, file=sys.stderr)
        try:
            yield Execution(store=store, executor=ex, retry_failed=retry_failed, progress=False, bar=bar)
        finally:
            if bar is not None:
                bar.close()


def _isatty(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


def echo_execution(summary: dict, quiet: bool, what: str = "units") -> None:
    """One line with the unit counts; every failed unit on stderr (never silently dropped)."""
    if summary.get("n_units") and not quiet:
        click.echo(
            f"{summary['n_units']} {what}: {summary['n_computed']} computed, {summary['n_resumed']} from "
            f"checkpoints, {summary['n_failed']} failed"
        )
    for f in summary.get("failed", []):
        click.echo(f"imrbayes: warning: unit {f['unit']} failed: {f['error']}", err=True)


# ----------------------------------------------------------------------------- helpers
def key_values(items, option: str, numeric: bool = False) -> dict:
    """``["KEY=VALUE", ...]`` from a repeatable option as a dict. Numeric values become finite floats
    (keys kept as given: parameter names); other values stay strings with dashes in their keys read
    as underscores (option names such as ``n-ens``)."""
    out = {}
    for item in items:
        key, sep, value = str(item).partition("=")
        key = key.strip()
        if not sep or not key or not value.strip():
            raise InputError(option, f"expected KEY=VALUE, got {item!r}")
        if numeric:
            try:
                v = float(value)
            except ValueError:
                raise InputError(option, f"{key} must be a number, got {value!r}")
            if not math.isfinite(v):
                raise InputError(option, f"{key} must be finite, got {value!r}")
            out[key] = v
        else:
            out[key.replace("-", "_")] = value.strip()
    return out


EXPERIMENTS_HELP = (
    "Use only these experiments: 1-based positions in the dataset's order (after --camera), "
    "comma-separated, ranges allowed (e.g. 1,2,5-8). Selected before preprocessing: the noise "
    "estimate and everything else see only these records."
)


def select_experiments(ds, spec):
    """``--experiments``: a copy of dataset ``ds`` keeping the experiments at the 1-based positions
    in ``spec`` ("1,2,5-8"; None or "" keeps all), in the dataset's order."""
    if spec is None or not str(spec).strip():
        return ds
    n = len(ds.experiments)
    pos = set()
    for tok in str(spec).split(","):
        tok = tok.strip()
        if not tok:
            continue
        lo, dash, hi = tok.partition("-")
        try:
            a = int(lo)
            b = int(hi) if dash else a
        except ValueError:
            raise InputError("--experiments", f"expected 1-based positions or ranges such as 1,2,5-8, got {spec!r}")
        if a > b:
            raise InputError("--experiments", f"range {tok!r} runs backwards")
        pos.update(range(a, b + 1))
    if not pos:
        raise InputError("--experiments", f"no experiment selected by {spec!r}")
    if min(pos) < 1 or max(pos) > n:
        raise InputError(
            "--experiments", f"positions must lie in 1..{n} ({ds.path} has {n} experiment(s)), got {spec!r}"
        )
    keep = [e.name for i, e in enumerate(ds.experiments, 1) if i in pos]
    out = ds.select(names=keep)
    out.notes.append(f"kept experiments {spec} of {n}: {', '.join(keep)}")
    return out


def coerce_setting(cls, name, value, source):
    """A setting value (string from the command line or a TOML value) as the field's type."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    if name not in fields:
        raise InputError(source, f"unknown setting {name!r}; known: {', '.join(sorted(fields))}")
    typ = str(fields[name].type)
    if not isinstance(value, str):
        if "bool" in typ and not isinstance(value, bool):
            raise InputError(source, f"{name} must be true or false, got {value!r}")
        if "int" in typ and "float" not in typ and not (isinstance(value, int) and not isinstance(value, bool)):
            raise InputError(source, f"{name} must be an integer, got {value!r}")
        if "float" in typ and isinstance(value, (int, float)) and not isinstance(value, bool):
            value = float(value)
            if not math.isfinite(value):
                raise InputError(source, f"{name} must be finite, got {value!r}")
        return value
    v = value.strip()
    if "None" in typ and v.lower() in ("none", "null", ""):
        return None
    try:
        if "bool" in typ:
            low = v.lower()
            if low not in ("true", "false", "1", "0", "yes", "no", "on", "off"):
                raise ValueError
            return low in ("true", "1", "yes", "on")
        if "int" in typ and "float" not in typ:
            f = float(v)
            if f != int(f):
                raise ValueError
            return int(f)
        if "float" in typ:
            try:
                f = float(v)
            except ValueError:
                if "str" in typ:  # a field that also takes text (e.g. prior_widen=mu:3)
                    return v
                raise
            if not math.isfinite(f):
                raise ValueError
            return f
    except (ValueError, OverflowError):
        raise InputError(source, f"{name} must be a {typ.replace(' | None', '')}, got {value!r}")
    return v


def method_settings(cls, table: dict, cli: dict, option: str = "--set"):
    kwargs = {}
    for k, v in (table or {}).items():
        kwargs[k.replace("-", "_")] = coerce_setting(cls, k.replace("-", "_"), v, "--config")
    for k, v in cli.items():
        kwargs[k] = coerce_setting(cls, k, v, option)
    return cls(**kwargs)


def prior_base_name(priors, config_name, likelihood) -> tuple:
    """(the named base prior, the remaining ``NAME=MEAN:SD`` items) from ``--prior`` values: a value
    without ``=`` names the base (``wide``, ``paper``); the default is ``wide``, and ``paper`` with the
    paper's likelihood (the paper's settings together)."""
    from imrbayes.ensemble.problem import PRIORS

    named = [p for p in priors if "=" not in str(p)]
    rest = [p for p in priors if "=" in str(p)]
    if len(named) > 1:
        raise InputError("--prior", f"name one prior, got {', '.join(named)}")
    name = named[0] if named else (config_name or ("paper" if likelihood == "paper" else "wide"))
    if name not in PRIORS:
        raise InputError("--prior", f"unknown prior {name!r}; choose one of {', '.join(PRIORS)} or give NAME=MEAN:SD")
    return name, rest


def prior_overrides(table: dict, cli: dict) -> dict:
    out = {}
    for k, v in (table or {}).items():
        if not (isinstance(v, (list, tuple)) and len(v) == 2):
            raise InputError("--config", f"prior.{k} must be [mean, sd], got {v!r}")
        out[k] = (float(v[0]), float(v[1]))
    for k, v in cli.items():
        parts = v.split(":")
        try:
            if len(parts) != 2:
                raise ValueError
            out[k] = (float(parts[0]), float(parts[1]))
        except ValueError:
            raise InputError("--prior", f"expected NAME=MEAN:SD (SI units), got {k}={v}")
    return out


def compare_line(compare: dict) -> str:
    o = compare["overall"]
    worst = (
        f"; worst window {o['worst_window']} (sample KL {o['max_kl_sample']:.3g} nats)"
        if o.get("worst_window") is not None and o.get("max_kl_sample") is not None
        else ""
    )
    return (
        f"ensemble vs MCMC: {o['n_agree']} window(s) agree, {o['n_disagree']} disagree, {o['n_undecided']} "
        f"undecided (chains not converged){worst}; see compare.json"
    )


def command_line(ctx: click.Context) -> list:
    """The command as typed, rebuilt from what click parsed (``sys.argv`` is not the command under a
    test runner or a Python caller): ``["imrbayes", "fit", DATA, "--method", "mienks", ...]`` with
    every option given on the command line, in the command's option order, so that running it again
    repeats the run (defaults from ``--config`` are kept by keeping ``--config``)."""
    from click.core import ParameterSource

    words = ["imrbayes", ctx.info_name]
    options = []
    for prm in ctx.command.params:
        src = ctx.get_parameter_source(prm.name) if prm.name else None
        value = ctx.params.get(prm.name)
        if isinstance(prm, click.Argument):
            words += [str(v) for v in (value if isinstance(value, (list, tuple)) else [value]) if v is not None]
            continue
        if src is not ParameterSource.COMMANDLINE or value is None:
            continue
        opt = max(prm.opts, key=len)
        if prm.is_flag:
            if value:
                options.append(opt)
        elif prm.multiple:
            for v in value:
                options += [opt, str(v)]
        else:
            options += [opt, str(value)]
    return words + options
