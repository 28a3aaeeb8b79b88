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


class _Group(click.Group):
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
            signum = getattr(exc, "signum", None)   # execution.RunInterrupted: SIGTERM/SIGINT during units
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


def _load_config(ctx, param, value):
    """``--config FILE.toml``: its keys (option names, dashes or underscores) become the command's
    defaults, so every option can come from the file and the command line still wins. A table
    named after the command (``[fit]``, ``[simulate]``) is read in preference to the top level."""
    if value is None:
        return None
    import tomllib
    from pathlib import Path

    path = Path(value)
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(path, "config file not found")
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(path, f"not valid TOML: {exc}")
    section = data.get(ctx.info_name, data)
    if not isinstance(section, dict):
        raise InputError(path, f"[{ctx.info_name}] must be a table")
    known = {}
    for prm in ctx.command.params:  # option spellings (--n-exp, n_exp) -> parameter name
        known[prm.name] = prm.name
        for opt in getattr(prm, "opts", []):
            known[opt.lstrip("-").replace("-", "_")] = prm.name
    defaults = {}
    for key, val in section.items():
        if isinstance(val, dict):
            continue  # another command's table
        name = known.get(key.replace("-", "_"))
        if name is None:
            raise InputError(path, f"unknown option {key!r} for 'imrbayes {ctx.info_name}'")
        defaults[name] = list(val) if isinstance(val, (list, tuple)) else val
    ctx.default_map = {**(ctx.default_map or {}), **defaults}
    return value


def config_option(f):
    """Decorator adding ``--config FILE.toml`` (processed before every other option)."""
    return click.option("--config", type=click.Path(dir_okay=False), callback=_load_config, is_eager=True,
                        expose_value=False, help="TOML file of option values; the command line wins.")(f)


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="imrbayes")
def main():
    """Bayesian, time-resolved inertial microcavitation rheometry."""


# Each command is one module that registers itself on `main` (add a module, then its name here).
COMMANDS = ("inspect", "simulate", "fit", "validate", "diagnose", "compare", "report")


def _register_commands():
    import importlib

    for name in COMMANDS:
        importlib.import_module(f"imrbayes.cli.{name}")


_register_commands()

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
