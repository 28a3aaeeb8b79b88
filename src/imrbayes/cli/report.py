"""``imrbayes report RUN_DIR`` (interfaces.md §2): one self-contained ``report.html`` of a run
directory written by ``imrbayes fit`` (any method, with or without ``--mcmc``); see
:mod:`imrbayes.report` and ``docs/guide.md``."""

from __future__ import annotations

from pathlib import Path

import click

from imrbayes.cli import main


@main.command("report")
@click.argument("run_dir", type=click.Path(path_type=Path))
@click.option(
    "--out",
    type=click.Path(path_type=Path, dir_okay=False),
    default=None,
    help="HTML file to write [default: RUN_DIR/report.html].",
)
@click.option("--quiet", is_flag=True, help="Print nothing but errors.")
def report_cmd(run_dir, out, quiet):
    """Write one self-contained HTML report of RUN_DIR (a folder written by 'imrbayes fit').

    It holds the dataset summary (Rmax [µm], Req [µm], Rmax/Req, first-collapse t* per experiment),
    the preprocessing, forward model, prior and method settings, warnings and failures, the estimate
    in SI units (G [Pa], mu [Pa s]), the per-window table (mienks), ArviZ summary tables of
    posterior.nc and, after 'fit --mcmc', of mcmc.nc per window, the ensemble-vs-MCMC comparison
    (KL [nats], W2 [posterior sd], R-hat, ESS) with a plain-language list of flagged windows, and
    every figures/*.png embedded.
    """
    from imrbayes.report import write_run_report

    path = write_run_report(run_dir, out)
    if not quiet:
        click.echo(f"wrote {path}")
