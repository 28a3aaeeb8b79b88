"""``imrbayes inspect``: load and preprocess a dataset; report Rmax, Req, Rmax/Req and t_c*."""

from __future__ import annotations

import json
import math
from pathlib import Path

import click

from imrbayes import __version__
from imrbayes.cli import config_option, main
from imrbayes.cli.options import force_option, prepare_out
from imrbayes.errors import InputError
from imrbayes.io import jsonable, write_json


def _fmt(x, digits=4) -> str:
    return "n/a" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{digits}g}"


def _table_rows(pre) -> list:
    rows = []
    for e in pre.experiments:
        rows.append(
            {
                "name": e.name,
                "rmax_um": e.rmax_m * 1e6,
                "req_um": e.req_m * 1e6,
                "req_sd_um": e.req_sd_m * 1e6,
                "rmax_over_req": e.ratio,
                "rmax_over_req_sd": e.ratio_sd,
                "t_collapse_star": e.t_collapse_star,
                "t_collapse_us": e.t_collapse_s * 1e6,
                "req_source": e.req_source,
            }
        )
    return rows


def _pm(mean, sd, digits) -> str:
    return f"{mean:.{digits}f}" if sd is None or not math.isfinite(sd) else f"{mean:.{digits}f} ± {sd:.{digits}f}"


def _print_table(pre, out: Path) -> None:
    ds = pre.dataset
    click.echo(f"dataset: {ds.name} ({ds.format}, {len(pre.experiments)} experiment(s)); material: {ds.material}")
    width = max(10, *(len(e.name) for e in pre.experiments))
    click.echo(f"{'experiment':<{width}}  {'Rmax [µm]':>15}  {'Req [µm]':>15}  {'Rmax/Req':>13}  {'t_c*':>15}")
    for r in _table_rows(pre):
        click.echo(
            f"{r['name']:<{width}}  {r['rmax_um']:15.2f}  {_pm(r['req_um'], r['req_sd_um'], 2):>15}  "
            f"{_pm(r['rmax_over_req'], r['rmax_over_req_sd'], 3):>13}  {r['t_collapse_star']:15.4f}"
        )
    if len(pre.experiments) > 1:
        s = pre.to_dict(arrays=False)["summary"]
        cells = [
            _pm(s[k]["mean"], s[k]["sd"], d)
            for k, d in (("rmax_um", 2), ("req_um", 2), ("rmax_over_req", 3), ("t_collapse_star", 4))
        ]
        click.echo(f"{'mean ± sd':<{width}}  {cells[0]:>15}  {cells[1]:>15}  {cells[2]:>13}  {cells[3]:>15}")
    c = pre.choices
    click.echo(
        f"grid: {pre.t_star.size} samples, dt* = {c['dt_star']:g} (t* <= {pre.t_star[-1]:.4g}); "
        f"maximum: {c['rmax_method']}; collapse: {c['collapse_method']}; "
        f"P_k: {c['noise']['method']} (floor {c['noise']['floor']:.3g})"
    )
    click.echo(f"wrote {out / 'dataset.json'} and {out / 'figures' / 'radius.png'}")


# ----------------------------------------------------------------------------- inspect
@main.command("inspect", short_help="Load and preprocess a dataset; report Rmax, Req, Rmax/Req, t_c*.")
@click.argument("data", type=click.Path(path_type=Path))
@click.option(
    "--out",
    type=click.Path(path_type=Path),
    default=None,
    help="Output folder (default: a new folder under ./imrbayes-runs/).",
)
@click.option("--json", "as_json", is_flag=True, help="Print the per-experiment table as JSON on stdout.")
@click.option(
    "--dt-star",
    type=float,
    default=0.025,
    show_default=True,
    help="Grid step in dimensionless time t* = t sqrt(p8/rho)/Rmax [-].",
)
@click.option(
    "--n-steps",
    type=int,
    default=120,
    show_default=True,
    help="Grid steps [-] (fewer if the shortest record ends earlier).",
)
@click.option(
    "--camera",
    default=None,
    help='Keep one camera view of multi-camera data (e.g. cam0deg), or "mean" to average the views of each '
    "bubble frame by frame; default: every view.",
)
@click.option(
    "--rmax-method",
    type=click.Choice(["local-fit", "parabola", "sample"]),
    default="local-fit",
    show_default=True,
    help="Time and value of the maximum: a polynomial fitted over the frames "
    "within 0.35 t_c (robust to noise), the parabola through three frames, or "
    "the largest sample.",
)
@click.option(
    "--collapse-method",
    type=click.Choice(["parabola", "sample"]),
    default="parabola",
    show_default=True,
    help="First-collapse time: sub-frame parabola or smallest sample.",
)
@click.option(
    "--interp",
    type=click.Choice(["linear", "pchip"]),
    default="linear",
    show_default=True,
    help="Interpolation onto the t* grid.",
)
@click.option(
    "--n-tail",
    type=int,
    default=20,
    show_default=True,
    help="Samples [-] averaged for Req when meta.json does not give it.",
)
@click.option(
    "--noise",
    type=click.Choice(["auto", "sample", "pooled", "paper"]),
    default="auto",
    show_default=True,
    help="P_k: sample variance across experiments, the same pooled over 11 neighbouring steps, or the "
    "paper's verification noise model sd |R*-1|/20 + (1-exp(-t*/10))/30.",
)
@click.option("--quiet", is_flag=True, help="Print nothing but errors (and --json output).")
@config_option
@force_option
def inspect_cmd(
    data, out, as_json, dt_star, n_steps, camera, rmax_method, collapse_method, interp, n_tail, noise, quiet, force
):
    """Load DATA (dataset folder, .csv or .mat), preprocess it and report Rmax, Req, Rmax/Req and the
    first-collapse time t_c* of every experiment. Writes dataset.json and figures/radius.png."""
    from imrbayes.data import load_dataset, preprocess_dataset
    from imrbayes.data.figures import radius_figure

    if n_tail < 2:
        raise InputError("--n-tail", f"must be at least 2, got {n_tail}")
    ds = load_dataset(data, camera=camera)
    pre = preprocess_dataset(
        ds,
        dt_star=dt_star,
        n_steps=n_steps,
        rmax_method=rmax_method,
        collapse_method=collapse_method,
        interp=interp,
        n_tail=n_tail,
        noise=noise,
    )
    out = prepare_out(out, "inspect", ds.name, protect=Path(data), force=bool(force))
    record = pre.to_dict()
    record["command"] = {
        "name": "inspect",
        "data": str(data),
        "dt_star": dt_star,
        "n_steps": n_steps,
        "camera": camera,
        "imrbayes_version": __version__,
    }
    write_json(out / "dataset.json", record)
    radius_figure(pre, out / "figures" / "radius.png")
    if as_json:
        table = {
            "dataset": ds.name,
            "path": ds.path,
            "format": ds.format,
            "material": ds.material,
            "n_experiments": len(pre.experiments),
            "experiments": _table_rows(pre),
            "summary": pre.to_dict(arrays=False)["summary"],
            "choices": pre.choices,
            "warnings": pre.warnings,
            "out": str(out),
        }
        click.echo(json.dumps(jsonable(table), indent=1))
    elif not quiet:
        _print_table(pre, out)
    if not quiet:
        for w in pre.warnings:
            click.echo(f"imrbayes: warning: {w}", err=True)
