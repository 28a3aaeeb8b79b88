"""``imrbayes validate``: the synthetic validation suite (known truth)."""

from __future__ import annotations

from pathlib import Path

import click

from imrbayes.cli import config_option, main
from imrbayes.cli.options import (
    check_options,
    echo_execution,
    execution_options,
    force_option,
    key_values,
    open_execution,
    prepare_out,
)
from imrbayes.errors import InputError


@main.command("validate")
@config_option
@click.option(
    "--suite",
    type=click.Choice(["quick", "full"]),
    default="quick",
    show_default=True,
    help="quick: polytropic bubble, about a minute; full: thermal bubble on the grid-converged "
    "default and the paper's IMR grid (tens of minutes).",
)
@click.option("--case", "cases", multiple=True, help="Run only these cases (repeatable); default: all.")
@click.option(
    "--out",
    type=click.Path(path_type=Path),
    default=None,
    help="Output folder (default: a new folder under ./imrbayes-runs/).",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the synthetic noise and every draw.")
@click.option(
    "--forward",
    "forward",
    multiple=True,
    metavar="KEY=VALUE",
    help="Forward-model option overriding the suite's (bubble=polytropic, scheme=imrv2-fd, nt=96, ...).",
)
@click.option("--quiet", is_flag=True, help="Print nothing but errors.")
@execution_options(with_workers=True)
@force_option
def validate_cmd(suite, cases, out, seed, forward, quiet, workers, scheduler, resume, retry_failed, force):
    """Synthetic validation: the paper's verification case (G0 = 7.29 kPa, mu0 = 0.088 Pa s,
    Rmax = 263 µm, Rmax/Req = 7.58, five noisy experiments) for En4D-Var and MIEnKS-MDA, IMR and
    pIMR recovery checks, and the fusion rule. Writes validation.json and figures; exit status 1 if
    any case fails."""
    from imrbayes.io import write_json
    from imrbayes.validation import CASES, run_suite

    unknown = [c for c in cases if c not in CASES]
    if unknown:
        raise InputError("--case", f"unknown case(s) {unknown}; known: {', '.join(CASES)}")
    check_options(workers, scheduler, resume, retry_failed)
    if seed < 0:
        raise InputError("--seed", f"must be a non-negative integer, got {seed}")
    fwd = key_values(forward, "--forward")
    from imrbayes.forward import ForwardOptions
    from imrbayes.validation.suite import FORWARD

    ForwardOptions.from_dict({**FORWARD[suite], **fwd}, source="--forward")  # bad options: exit 2 here
    out = prepare_out(Path(out) if out is not None else None, "validate", suite, force=bool(force), resume=bool(resume))

    def show(row):
        if not quiet:
            status = "PASS" if row["passed"] else "FAIL"
            click.echo(f"{status}  {row['name']:<24} {row['runtime_s']:7.1f} s  {row.get('error') or row['criteria']}")

    run_config = {
        "command": "validate",
        "suite": suite,
        "cases": list(dict.fromkeys(cases)) or None,
        "seed": seed,
        "forward": fwd,
    }
    with open_execution(
        out, run_config, workers=workers, scheduler=scheduler, resume=resume, retry_failed=retry_failed, quiet=quiet
    ) as execution:
        report = run_suite(
            suite,
            out,
            seed=seed,
            cases=list(dict.fromkeys(cases)) or None,
            forward=fwd,
            progress=show,
            execution=execution,
        )
        report["execution"] = execution.summary()
    write_json(out / "validation.json", report)
    if not quiet:
        n_ok = sum(r["passed"] for r in report["cases"])
        click.echo(
            f"{n_ok}/{len(report['cases'])} passed in {report['runtime_s']:.0f} s; wrote {out / 'validation.json'}"
        )
    echo_execution(report["execution"], quiet, what="cases")
    if not report["passed"]:
        raise click.exceptions.Exit(1)
