"""``imrbayes inspect`` and ``imrbayes simulate`` (interfaces.md §2), registered on the main group."""

from __future__ import annotations

import json
import math
import re
from datetime import datetime
from pathlib import Path

import click
import numpy as np

from imrbayes import __version__
from imrbayes.cli import config_option, main
from imrbayes.errors import InputError


# ----------------------------------------------------------------------------- helpers
def new_run_dir(kind: str, name: str, base: Path = Path("imrbayes-runs")) -> Path:
    """A fresh folder ``base/<kind>-<name>-<YYYYmmdd-HHMMSS>[-k]`` (created)."""
    slug = re.sub(r"[^A-Za-z0-9._-]+", "_", name)[:60] or "run"
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    path = base / f"{kind}-{slug}-{stamp}"
    k = 2
    while path.exists():
        path = base / f"{kind}-{slug}-{stamp}-{k}"
        k += 1
    return path


def _prepare_out(out: Path | None, kind: str, name: str, protect: Path | None = None) -> Path:
    if out is None:
        out = new_run_dir(kind, name)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError("--out", f"{out} exists and is not a directory")
    if protect is not None:
        p = protect if protect.is_dir() else protect.parent
        if out.resolve() == p.resolve():
            raise InputError("--out", f"{out} is the data folder; choose another folder (input files are "
                                      f"never written to)")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError("--out", f"cannot create {out}: {exc.strerror or exc}")
    return out


def _fmt(x, digits=4) -> str:
    return "n/a" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{digits}g}"


def _table_rows(pre) -> list:
    rows = []
    for e in pre.experiments:
        rows.append({"name": e.name, "rmax_um": e.rmax_m * 1e6, "req_um": e.req_m * 1e6,
                     "req_sd_um": e.req_sd_m * 1e6, "rmax_over_req": e.ratio, "rmax_over_req_sd": e.ratio_sd,
                     "t_collapse_star": e.t_collapse_star, "t_collapse_us": e.t_collapse_s * 1e6,
                     "req_source": e.req_source})
    return rows


def _jsonable(obj):
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    return obj


def _pm(mean, sd, digits) -> str:
    return f"{mean:.{digits}f}" if sd is None or not math.isfinite(sd) else f"{mean:.{digits}f} ± {sd:.{digits}f}"


def _print_table(pre, out: Path) -> None:
    ds = pre.dataset
    click.echo(f"dataset: {ds.name} ({ds.format}, {len(pre.experiments)} experiment(s)); material: {ds.material}")
    width = max(10, *(len(e.name) for e in pre.experiments))
    click.echo(f"{'experiment':<{width}}  {'Rmax [µm]':>15}  {'Req [µm]':>15}  {'Rmax/Req':>13}  {'t_c*':>15}")
    for r in _table_rows(pre):
        click.echo(f"{r['name']:<{width}}  {r['rmax_um']:15.2f}  {_pm(r['req_um'], r['req_sd_um'], 2):>15}  "
                   f"{_pm(r['rmax_over_req'], r['rmax_over_req_sd'], 3):>13}  {r['t_collapse_star']:15.4f}")
    if len(pre.experiments) > 1:
        s = pre.to_dict(arrays=False)["summary"]
        cells = [_pm(s[k]["mean"], s[k]["sd"], d) for k, d in
                 (("rmax_um", 2), ("req_um", 2), ("rmax_over_req", 3), ("t_collapse_star", 4))]
        click.echo(f"{'mean ± sd':<{width}}  {cells[0]:>15}  {cells[1]:>15}  {cells[2]:>13}  {cells[3]:>15}")
    c = pre.choices
    click.echo(f"grid: {pre.t_star.size} samples, dt* = {c['dt_star']:g} (t* <= {pre.t_star[-1]:.4g}); "
               f"maximum: {c['rmax_method']}; collapse: {c['collapse_method']}; "
               f"P_k: {c['noise']['method']} (floor {c['noise']['floor']:.3g})")
    click.echo(f"wrote {out / 'dataset.json'} and {out / 'figures' / 'radius.png'}")


# ----------------------------------------------------------------------------- inspect
@main.command("inspect", short_help="Load and preprocess a dataset; report Rmax, Req, Rmax/Req, t_c*.")
@click.argument("data", type=click.Path(path_type=Path))
@click.option("--out", type=click.Path(path_type=Path), default=None,
              help="Output folder (default: a new folder under ./imrbayes-runs/).")
@click.option("--json", "as_json", is_flag=True, help="Print the per-experiment table as JSON on stdout.")
@click.option("--dt-star", type=float, default=0.025, show_default=True,
              help="Grid step in dimensionless time t* = t sqrt(p8/rho)/Rmax [-].")
@click.option("--n-steps", type=int, default=120, show_default=True,
              help="Grid steps [-] (fewer if the shortest record ends earlier).")
@click.option("--camera", default=None,
              help="Keep one camera view of multi-camera data (e.g. cam0deg); default: every view.")
@click.option("--rmax-method", type=click.Choice(["parabola", "sample"]), default="parabola", show_default=True,
              help="Time and value of the maximum: sub-frame parabola or largest sample.")
@click.option("--collapse-method", type=click.Choice(["parabola", "sample"]), default="parabola",
              show_default=True, help="First-collapse time: sub-frame parabola or smallest sample.")
@click.option("--interp", type=click.Choice(["linear", "pchip"]), default="linear", show_default=True,
              help="Interpolation onto the t* grid.")
@click.option("--n-tail", type=int, default=20, show_default=True,
              help="Samples [-] averaged for Req when meta.json does not give it.")
@click.option("--noise", type=click.Choice(["auto", "sample", "pooled", "paper"]), default="auto", show_default=True,
              help="P_k: sample variance across experiments, the same pooled over 11 neighbouring steps, or the "
                   "methods.md §5 noise model.")
@click.option("--quiet", is_flag=True, help="Print nothing but errors (and --json output).")
@config_option
def inspect_cmd(data, out, as_json, dt_star, n_steps, camera, rmax_method, collapse_method, interp, n_tail,
                noise, quiet):
    """Load DATA (dataset folder, .csv or .mat), preprocess it and report Rmax, Req, Rmax/Req and the
    first-collapse time t_c* of every experiment. Writes dataset.json and figures/radius.png."""
    from imrbayes.data import load_dataset, preprocess_dataset
    from imrbayes.data.figures import radius_figure

    if n_tail < 2:
        raise InputError("--n-tail", f"must be at least 2, got {n_tail}")
    ds = load_dataset(data, camera=camera)
    pre = preprocess_dataset(ds, dt_star=dt_star, n_steps=n_steps, rmax_method=rmax_method,
                             collapse_method=collapse_method, interp=interp, n_tail=n_tail, noise=noise)
    out = _prepare_out(out, "inspect", ds.name, protect=Path(data))
    record = pre.to_dict()
    record["command"] = {"name": "inspect", "data": str(data), "dt_star": dt_star, "n_steps": n_steps,
                         "camera": camera, "imrbayes_version": __version__}
    (out / "dataset.json").write_text(json.dumps(_jsonable(record), indent=1) + "\n")
    radius_figure(pre, out / "figures" / "radius.png")
    if as_json:
        table = {"dataset": ds.name, "path": ds.path, "format": ds.format, "material": ds.material,
                 "n_experiments": len(pre.experiments), "experiments": _table_rows(pre),
                 "summary": pre.to_dict(arrays=False)["summary"], "choices": pre.choices,
                 "warnings": pre.warnings, "out": str(out)}
        click.echo(json.dumps(_jsonable(table), indent=1))
    elif not quiet:
        _print_table(pre, out)
    if not quiet:
        for w in pre.warnings:
            click.echo(f"imrbayes: warning: {w}", err=True)


# ----------------------------------------------------------------------------- simulate
def _key_values(items, option: str, numeric: bool) -> dict:
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
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
            out[key] = value.strip()
    return out


@main.command("simulate", short_help="Write a synthetic dataset from the forward model (with truth.json).")
@click.option("--model", required=True, help="Constitutive model (e.g. nhkv); see the error for the list.")
@click.option("--param", "params", multiple=True, metavar="NAME=VALUE",
              help="Material parameter in SI units (G [Pa], mu [Pa s], ...); repeat for each parameter.")
@click.option("--rmax", default="263e-6", show_default=True,
              help="Maximum radius [m], or MEAN:SD [m] to draw each experiment's value.")
@click.option("--ratio", default="7.58", show_default=True,
              help="Rmax/Req [-], or MEAN:SD [-] to draw each experiment's value.")
@click.option("--n-exp", type=int, default=5, show_default=True, help="Number of experiments [-].")
@click.option("--noise", default="paper", show_default=True,
              help="paper (sd |R*-1|/20 + (1-exp(-t*/10))/30 in R*), none, or a number (sd in R* [-]).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of every random draw.")
@click.option("--forward", "forward", multiple=True, metavar="KEY=VALUE",
              help="Forward-model option (radial=km, bubble=polytropic, vapor=false, ...); repeatable.")
@click.option("--physics", "physics", multiple=True, metavar="KEY=VALUE",
              help="Physical-constant override in SI units (rho [kg/m^3], p8 [Pa], ...); repeatable.")
@click.option("--t-end", type=float, default=3.0, show_default=True, help="End of each record in t* [-].")
@click.option("--dt-star", type=float, default=0.025, show_default=True,
              help="Sample interval in t* [-] (ignored with --frame-s).")
@click.option("--frame-s", type=float, default=None,
              help="Sample at a camera frame interval [s] instead of the dt* grid.")
@click.option("--material", default=None, help="Text for meta.json 'material' (default: synthetic <model>).")
@click.option("--out", type=click.Path(path_type=Path), default=None,
              help="Dataset folder to create (default: a new folder under ./imrbayes-runs/).")
@click.option("--quiet", is_flag=True, help="Print nothing but errors.")
@config_option
def simulate_cmd(model, params, rmax, ratio, n_exp, noise, seed, forward, physics, t_end, dt_star, frame_s,
                 material, out, quiet):
    """Write a synthetic dataset (interfaces.md §1 format) from the forward model, with truth.json."""
    from imrbayes import forward as fwd
    from imrbayes.data import synthetic as syn

    if n_exp < 1:
        raise InputError("--n-exp", f"must be at least 1, got {n_exp}")
    if not (math.isfinite(t_end) and t_end > 0):
        raise InputError("--t-end", f"must be a positive number of t* units, got {t_end}")
    if frame_s is None and not (math.isfinite(dt_star) and 0 < dt_star <= t_end):
        raise InputError("--dt-star", f"must be positive and at most --t-end, got {dt_star}")
    if frame_s is not None and not (math.isfinite(frame_s) and 0 < frame_s <= 1e-3):
        raise InputError("--frame-s", f"must be a frame interval in seconds, 0 < S <= 1e-3, got {frame_s}")
    rmax_spec = syn.parse_spec(rmax, "--rmax")
    ratio_spec = syn.parse_spec(ratio, "--ratio")
    if rmax_spec.mean > 0.01:
        raise InputError("--rmax", f"{rmax_spec.mean:g} m is over 1 cm; give Rmax in metres (e.g. 263e-6)")
    if ratio_spec.mean <= 1:
        raise InputError("--ratio", f"Rmax/Req must exceed 1, got {ratio_spec.mean:g}")
    noise_d = syn.parse_noise(noise)
    pvals = _key_values(params, "--param", numeric=True)
    fopts = _key_values(forward, "--forward", numeric=False)
    phys = _key_values(physics, "--physics", numeric=True)
    models = list(fwd.available_models())
    try:
        fm = fwd.ForwardModel(model, options=fwd.ForwardOptions.from_dict(fopts, source="--forward"), physics_overrides=phys or None)
    except InputError as exc:
        if model not in models and exc.source in (None, "--model", "model"):
            raise InputError("--model", f"unknown model {model!r}; available: {', '.join(models)}")
        raise
    except (KeyError, ValueError) as exc:
        if model not in models:
            raise InputError("--model", f"unknown model {model!r}; available: {', '.join(models)}")
        raise InputError("--forward", str(exc))
    names = tuple(fm.constitutive.param_names)
    unknown = [k for k in pvals if k not in names]
    missing = [k for k in names if k not in pvals]
    if unknown or missing:
        parts = ([f"unknown parameter(s) {', '.join(unknown)}"] if unknown else []) + \
                ([f"missing {', '.join(missing)}"] if missing else [])
        raise InputError("--param", f"{'; '.join(parts)}; model {model!r} takes {', '.join(names)} "
                                    f"(SI units, e.g. --param {names[0] if names else 'G'}=...)")
    ph = fm.physics.to_dict()
    uc = math.sqrt(float(ph["p8"]) / float(ph["rho"]))
    rng = np.random.default_rng(seed)
    rmax_m = syn.draw_values(rmax_spec, n_exp, rng, lambda x: (x > 0) & (x <= 0.01), "--rmax")
    ratios = syn.draw_values(ratio_spec, n_exp, rng, lambda x: x > 1.0, "--ratio")
    req_m = rmax_m / ratios
    tc_s = rmax_m / uc
    if frame_s is None:
        n = int(math.floor(t_end / dt_star + 1e-9))
        grids = [np.arange(n + 1) * dt_star for _ in range(n_exp)]
    else:
        grids = [np.arange(int(math.floor(t_end * tc / frame_s + 1e-9)) + 1) * frame_s / tc for tc in tc_s]
        if min(g.size for g in grids) < 10:
            raise InputError("--frame-s", f"{frame_s:g} s gives fewer than 10 frames per record")
    clean = syn.simulate_dataset(fm, pvals, rmax_m, req_m, grids)
    records, redrawn = [], 0
    for g, Rs, rm, tc in zip(grids, clean, rmax_m, tc_s):
        if Rs.shape != g.shape or not np.all(np.isfinite(Rs)):
            raise RuntimeError("forward model returned a radius history of the wrong shape or with NaN")
        Rn, k = syn.noisy(g, Rs, noise_d, rng)
        redrawn += k
        records.append((g * tc, Rn * rm))
    out = _prepare_out(out, "simulate", model)
    if any(out.glob("*.csv")) or (out / "meta.json").exists():
        raise InputError("--out", f"{out} already holds a dataset; choose a new or empty folder")
    noise_d = {**noise_d, "applied_to": "R* = R/Rmax, independent Gaussian per sample",
               "n_redrawn_nonpositive": redrawn}
    files = [f"exp_{i:03d}.csv" for i in range(1, n_exp + 1)]
    options = fm.options.to_dict()
    meta = {"material": material or f"synthetic ({model})",
            "description": f"imrbayes simulate: {model} {pvals}, noise {noise_d['kind']}, seed {seed}",
            "synthetic": True, "truth": "truth.json", "physics": ph, "forward": options,
            "experiments": {f: {"Req_m": float(q), "Rmax_m": float(r)} for f, q, r in zip(files, req_m, rmax_m)}}
    truth = {"model": model, "parameters": pvals, "param_names": list(names), "seed": seed,
             "n_experiments": n_exp, "noise": noise_d, "forward": options, "physics": ph,
             "rmax_spec_m": rmax_spec.to_dict(), "ratio_spec": ratio_spec.to_dict(),
             "sampling": ({"dt_star": dt_star} if frame_s is None else {"frame_s": frame_s}) | {"t_end_star": t_end},
             "experiments": [{"file": f, "rmax_m": float(r), "req_m": float(q), "rmax_over_req": float(a),
                              "tc_s": float(tc), "n_samples": int(g.size)}
                             for f, r, q, a, tc, g in zip(files, rmax_m, req_m, ratios, tc_s, grids)],
             "random_draws": "numpy.random.default_rng(seed): Rmax (n_exp, if MEAN:SD), ratio (n_exp, if "
                             "MEAN:SD), then the noise of each experiment in turn",
             "imrbayes_version": __version__}
    syn.write_dataset(out, records, _jsonable(meta), _jsonable(truth))
    if not quiet:
        click.echo(f"wrote {n_exp} experiment(s), meta.json and truth.json to {out}")
