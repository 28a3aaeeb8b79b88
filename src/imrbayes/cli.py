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
        except (click.exceptions.Exit, click.exceptions.Abort, click.ClickException):
            raise
        except InputError as exc:
            if os.environ.get("IMRBAYES_DEBUG"):
                raise
            click.echo(f"imrbayes: error: {exc}", err=True)
            ctx.exit(2)
        except KeyboardInterrupt:
            click.echo("imrbayes: interrupted", err=True)
            ctx.exit(130)
        except Exception as exc:  # one line, never a traceback
            if os.environ.get("IMRBAYES_DEBUG"):
                raise
            click.echo(f"imrbayes: error: {type(exc).__name__}: {exc}", err=True)
            ctx.exit(1)


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="imrbayes")
def main():
    """Bayesian, time-resolved inertial microcavitation rheometry."""


def _register_commands():
    # Command modules register themselves on `main`; importing them here keeps cli.py small.
    import importlib

    for name in ("cli_data", "cli_fit"):
        try:
            importlib.import_module(f"imrbayes.{name}")
        except ModuleNotFoundError as exc:  # a command module not written yet
            if exc.name != f"imrbayes.{name}":
                raise


_register_commands()

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
