"""The `imrbayes` command line.

Every command turns an :class:`~imrbayes.errors.InputError` into one line on stderr and exit
status 2; any other failure into one line and exit status 1. No tracebacks unless
``IMRBAYES_DEBUG=1``.
"""

from __future__ import annotations

import os
import sys

import click

from imrbayes import __version__
from imrbayes.errors import InputError

#: ``ctx.meta`` key: KEY=VALUE items that --config tables give each option, merged by :class:`_Command`
_CONFIG_ITEMS = "imrbayes.config_items"


def _format_lists(formatter, which) -> None:
    """``--help``'s lists of what a name may be: the constitutive models (with their parameters and
    units) and the inference methods, read from the registries when the help is shown."""
    if "models" in which:
        rows = []
        try:
            from imrbayes.forward.constitutive.base import available_models, get_model

            for name in available_models():
                try:
                    m = get_model(name)
                    rows.append((name, ", ".join(f"{p.name} [{p.unit}]" for p in m.parameters) or "no parameters"))
                except Exception:  # a model that cannot be loaded is still listed
                    rows.append((name, ""))
        except Exception:  # pragma: no cover - the forward layer is always there
            rows = []
        if rows:
            with formatter.section("Constitutive models (--model)"):
                formatter.write_dl(rows)
    if "methods" in which:
        from imrbayes.ensemble import METHODS

        with formatter.section("Inference methods (--method)"):
            formatter.write_dl(
                [
                    (m.name, m.label + ("; --mcmc checks its Gaussian posterior" if m.gaussian_posterior else ""))
                    for m in METHODS.values()
                ]
            )


class _Command(click.Command):
    """A command whose ``KEY=VALUE`` options start from the --config sub-table's items: the command
    line's items come after them, so they win key by key (as ``fit`` merges ``[fit.forward]``).
    ``help_lists`` (``("models", "methods")``) appends those lists to ``--help``."""

    def __init__(self, *args, help_lists=(), **kwargs):
        super().__init__(*args, **kwargs)
        self.help_lists = tuple(help_lists)

    def parse_args(self, ctx, args):
        rest = super().parse_args(ctx, args)
        for name, items in ctx.meta.pop(_CONFIG_ITEMS, {}).items():
            ctx.params[name] = (*items, *(ctx.params.get(name) or ()))
        return rest

    def format_epilog(self, ctx, formatter):
        super().format_epilog(ctx, formatter)
        if self.help_lists:
            _format_lists(formatter, self.help_lists)


class _Group(click.Group):
    command_class = _Command

    def format_epilog(self, ctx, formatter):
        super().format_epilog(ctx, formatter)
        _format_lists(formatter, ("models", "methods"))
        with formatter.section("Runtimes"):
            formatter.write_text(
                "inspect, simulate, report, compare: seconds. fit: seconds (pimr) to minutes "
                "(imr, en4dvar, mienks); fit --mcmc: seconds per window with "
                "--forward bubble=polytropic, 0.5-3 min per window with the thermal bubble "
                "(~25 min for a 5-experiment mienks run on 2 cores); en4dvar's one window also samples "
                "every bubble's nuisances: up to hours with the thermal bubble. diagnose: ~20 min for 5 experiments with the "
                "thermal bubble (a few with --forward bubble=polytropic --quick). validate --suite "
                "quick: minutes."
            )

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except click.UsageError as exc:  # a bad option value: one line naming it, exit status 2
            if os.environ.get("IMRBAYES_DEBUG"):
                raise
            click.echo(f"imrbayes: error: {' '.join(exc.format_message().split())}", err=True)
            ctx.exit(2)
        except (click.exceptions.Exit, click.exceptions.Abort, click.ClickException):
            raise
        except InputError as exc:
            if os.environ.get("IMRBAYES_DEBUG"):
                raise
            click.echo(f"imrbayes: error: {exc}", err=True)
            ctx.exit(2)
        except KeyboardInterrupt as exc:
            signum = getattr(exc, "signum", None)  # execution.RunInterrupted: SIGTERM/SIGINT during units
            if signum is not None:
                click.echo(f"imrbayes: {exc}; finished units are saved, continue with --resume", err=True)
                ctx.exit(128 + int(signum))
            click.echo("imrbayes: interrupted", err=True)
            ctx.exit(130)
        except Exception as exc:  # one line, never a traceback
            if os.environ.get("IMRBAYES_DEBUG"):
                raise
            click.echo(f"imrbayes: error: {type(exc).__name__}: {exc}", err=True)
            ctx.exit(1)


def read_config(path, command: str, options, tables=(), shared=None) -> dict:
    """The ``--config`` TOML file's settings for ``imrbayes <command>``: the only TOML reader of the
    command line.

    The table named after the command (``[fit]``, ``[diagnose]``) is read in preference to the top
    level; its keys (dashes read as underscores) must be among ``options``, and its sub-tables
    (``[diagnose.forward]``) among ``tables``. A table of ``shared`` (default: every one of
    ``tables``) may also stand at the top level (``[forward]``), read when the command's own table
    lacks it. In a top-level configuration (no table named after the command) other tables belong to
    other commands and are skipped.

    Returns ``{name: value}`` (tables as dicts); ``{}`` when ``path`` is None. Raises
    :class:`~imrbayes.errors.InputError` naming the file: missing, not TOML, or a key or sub-table
    the command does not understand.
    """
    if path is None:
        return {}
    import tomllib
    from pathlib import Path

    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(path, "config file not found")
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(path, f"not valid TOML: {' '.join(str(exc).split())}")
    section = data.get(command, data)
    if not isinstance(section, dict):
        raise InputError(path, f"[{command}] must be a table")
    options, tables = set(options), set(tables)
    cfg = {}
    for key, val in section.items():
        name = key.replace("-", "_")
        if isinstance(val, dict):
            if name in tables:
                cfg[name] = val
            elif section is not data:  # inside [command]: never silently ignored
                known = ", ".join(f"[{command}.{t}]" for t in sorted(tables)) or "none"
                raise InputError(path, f"unknown table [{command}.{key}] for 'imrbayes {command}'; known: {known}")
            continue  # top level: another command's table
        if name not in options:
            raise InputError(path, f"unknown option {key!r} for 'imrbayes {command}'; known: {sorted(options)}")
        cfg[name] = val
    for name in tables if shared is None else shared:  # a top-level [forward] completes [command]
        if name not in cfg and isinstance(data.get(name), dict):
            cfg[name] = data[name]
    return cfg


def _key_value_options(command: click.Command) -> dict:
    """The command's repeatable ``KEY=VALUE`` options (``--forward``, ``--param``), which a config
    sub-table of the same name can give: {spelling (underscores): parameter name}."""
    out = {}
    for prm in command.params:
        if isinstance(prm, click.Option) and prm.multiple and "=" in (prm.metavar or ""):
            for spelling in [prm.name, *(o.lstrip("-").replace("-", "_") for o in prm.opts)]:
                out[spelling] = prm.name
    return out


def _table_items(path, table: str, values: dict) -> list:
    """A config sub-table as ``KEY=VALUE`` strings, as the option would be given on the command line."""
    items = []
    for key, val in values.items():
        if isinstance(val, (dict, list)):
            raise InputError(path, f"{table}.{key} must be a number, string or true/false, got {val!r}")
        items.append(f"{key}={str(val).lower() if isinstance(val, bool) else val}")
    return items


def _config_callback(ctx, param, value):
    """``--config FILE.toml`` (eager): the command's keys (option names, dashes or underscores) become
    its defaults, so every option can come from the file and the command line still wins; a
    sub-table named after a ``KEY=VALUE`` option (``[diagnose.forward]``) gives that option's items,
    which the command line overrides key by key."""
    if value is None:
        return None
    known = {}
    for prm in ctx.command.params:  # option spellings (--n-exp, n_exp) -> parameter name
        known[prm.name] = prm.name
        for opt in getattr(prm, "opts", []):
            known[opt.lstrip("-").replace("-", "_")] = prm.name
    tables = _key_value_options(ctx.command)
    cfg = read_config(value, ctx.info_name, options=known, tables=tables)
    defaults, items = {}, {}
    for key, val in cfg.items():
        if isinstance(val, dict):
            items[tables[key]] = _table_items(value, key, val)
        else:
            defaults[known[key]] = list(val) if isinstance(val, (list, tuple)) else val
    ctx.default_map = {**(ctx.default_map or {}), **defaults}
    ctx.meta[_CONFIG_ITEMS] = items
    return value


def config_option(f):
    """Decorator adding ``--config FILE.toml`` (processed before every other option)."""
    return click.option(
        "--config",
        type=click.Path(dir_okay=False),
        callback=_config_callback,
        is_eager=True,
        expose_value=False,
        help="TOML file of option values and [COMMAND.forward]-style tables; the command line wins.",
    )(f)


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="imrbayes")
def main():
    """Bayesian, time-resolved inertial microcavitation rheometry."""


# Each command is one module that registers itself on `main` (add a module, then its name here).
COMMANDS = ("inspect", "simulate", "fit", "validate", "diagnose", "compare", "report", "study")


def _register_commands():
    import importlib

    for name in COMMANDS:
        importlib.import_module(f"imrbayes.cli.{name}")


_register_commands()

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
