"""``imrbayes compare RUN_DIR`` (interfaces.md §2): the ensemble Gaussians of a fit against the MCMC
posteriors in its ``mcmc.nc``, window by window -- ``compare.json`` and the comparison figures.

``fit --mcmc`` already writes both; ``compare`` recomputes them from the files alone (e.g. after
changing thresholds, or for a run directory copied from a cluster) without any forward solve.
"""

from __future__ import annotations

import json
from pathlib import Path

import click
import numpy as np

from imrbayes.cli import main
from imrbayes.errors import InputError
from imrbayes.io import read_json


def _open_tree(path: Path, what: str):
    import xarray as xr

    if not path.is_file():
        raise InputError(path, f"not found; {what}")
    try:
        with xr.open_datatree(path) as dt:
            return dt.load()
    except Exception as exc:  # netCDF/HDF5 errors have many types
        raise InputError(path, f"cannot be read as netCDF ({type(exc).__name__}: {' '.join(str(exc).split())[:160]})")


@main.command("compare")
@click.argument("run_dir", type=click.Path(path_type=Path))
@click.option(
    "--out",
    type=click.Path(path_type=Path),
    default=None,
    help="Folder for compare.json and figures/ [default: RUN_DIR].",
)
@click.option(
    "--pairs",
    default="worst",
    show_default=True,
    metavar="worst|all|J,K,...",
    help="Windows to draw pair plots for (both posteriors overlaid).",
)
@click.option("--quiet", is_flag=True, help="Print nothing but errors.")
def compare_cmd(run_dir, out, pairs, quiet):
    """Compare the ensemble-Gaussian posteriors of RUN_DIR (a 'fit --mcmc' run) with its MCMC ones.

    Writes compare.json (per window: moments of both, Gaussian KL both ways, W2, sample KL, R-hat,
    ESS, MCSE, Mardia, the agree flag and why) and figures/mcmc_*.png.
    """
    from imrbayes.io import write_json
    from imrbayes.mcmc.figures import comparison_figures
    from imrbayes.mcmc.windows import compare_from_tree

    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise InputError(run_dir, "not a directory")
    summary = read_json(run_dir / "summary.json")
    if "parameters" not in summary:
        raise InputError(run_dir / "summary.json", "has no 'parameters' (not written by 'imrbayes fit')")
    tree = _open_tree(run_dir / "mcmc.nc", "run 'imrbayes fit ... --mcmc' first")
    if not any(k.startswith("window_") for k in tree.children):
        raise InputError(run_dir / "mcmc.nc", "holds no window_XX groups (not written by 'imrbayes fit --mcmc')")
    if pairs not in ("worst", "all"):
        try:
            pairs = [int(p) for p in str(pairs).split(",") if p.strip()]
        except ValueError:
            raise InputError("--pairs", f"expected worst, all or window indices such as 0,3, got {pairs!r}")
    try:
        compare = compare_from_tree(summary, tree)
    except (KeyError, ValueError, TypeError) as exc:
        raise InputError(run_dir / "mcmc.nc", f"does not match summary.json ({type(exc).__name__}: {exc})")
    if not compare["windows"]:
        raise InputError(run_dir / "mcmc.nc", "no window has both an MCMC posterior and an ensemble Gaussian")
    out = Path(out) if out is not None else run_dir
    out.mkdir(parents=True, exist_ok=True)
    t_star = R_star = None
    post = run_dir / "posterior.nc"
    if post.is_file():
        ptree = _open_tree(post, "")
        if "observed_data" in ptree.children and "R_obs" in ptree["observed_data"].data_vars:
            R = ptree["observed_data"]["R_obs"]
            t_star = np.asarray(R["t_obs"].values, float)
            R_star = np.nanmean(np.asarray(R.values, float), axis=0)
    failed = (
        json.loads((run_dir / "compare.json").read_text()).get("overall", {}).get("failed_windows")
        if (run_dir / "compare.json").is_file()
        else None
    )
    if failed:
        compare["overall"]["failed_windows"] = failed
    figures = comparison_figures(compare, out / "figures", tree, t_star, R_star, pairs=pairs)
    write_json(out / "compare.json", compare)
    if not quiet:
        from imrbayes.cli.options import compare_line

        click.echo(compare_line(compare))
        for e in compare["windows"]:
            if e["agree"] is not True:
                t0, t1 = e["t_star"] if e.get("t_star") else (float("nan"), float("nan"))
                click.echo(f"  window {e['index']} (t* {t0:.3g}-{t1:.3g}): {e['notes']}")
        click.echo(f"wrote {out / 'compare.json'} and {len(figures)} figure(s)")
