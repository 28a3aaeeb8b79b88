#!/usr/bin/env python3
"""Regenerate docs/gallery.md and docs/figures/gallery/*.png: what imrbayes produces, shown before
installing it.

    python scripts/gallery.py                  # the bundled example and the stiff-PA data
    python scripts/gallery.py --quick          # shorter emcee run (for a check of the script)
    python scripts/gallery.py --work /tmp/g    # keep the run directories there

Two cases, each run through the command line exactly as a user would:

1. the bundled example (scripts/example.sh): the paper's verification case simulated with the
   polytropic bubble, fitted with En4D-Var and checked against emcee (``--mcmc``), and the same data
   fitted with MIEnKS-MDA (time-resolved G(t), mu(t));
2. the stiff polyacrylamide of Estrada et al. 2018 (shared/data/lic/estrada2018_stiffPA_270kfps,
   20 bubbles at 270 000 fps), fitted with En4D-Var and MIEnKS-MDA -- with the polytropic bubble
   too, so that the page regenerates in minutes; the page says so.

The committed PNGs are small: figures downscaled to at most 900 px wide and quantised to a palette.
When Chromium is installed, the top of each report (its conclusion) is rendered in a headless
browser (scripts/check_report_browser.py, which also checks the page) and shown as a screenshot.
"""

from __future__ import annotations

import argparse
import html as _html
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "gallery.md"
FIG = ROOT / "docs" / "figures" / "gallery"
MAX_WIDTH = 900
STIFF_PA = "estrada2018_stiffPA_270kfps"
sys.path.insert(0, str(ROOT / "scripts"))


def _find_data(name: str) -> Path | None:
    """The shared dataset ``name`` (shared/data/lic/NAME or shared/data/NAME beside the repository)."""
    for base in (ROOT / "shared" / "data", ROOT.parent / "shared" / "data", Path("/work/shared/data")):
        for p in (base / "lic" / name, base / name):
            if (p / "meta.json").is_file():
                return p
    return None


_REUSE = {"work": None, "times": {}}


def _shown(args) -> str:
    """The command as the page shows it: run folders relative to the work folder, data under shared/."""
    text = " ".join(["imrbayes", *map(str, args)])
    if _REUSE["work"] is not None:
        text = text.replace(str(_REUSE["work"]) + os.sep, "")
    return re.sub(r"\S*/(shared/data/)", r"\1", text)


def _cli(args, log) -> float:
    """Run ``imrbayes ARGS`` (this checkout's sources); returns the wall time [s]. With ``--reuse``, a
    simulate/inspect/fit whose ``--out`` already holds its result is not rerun (its recorded time is
    shown); reports are always rewritten."""
    shown = _shown(args)
    out = Path(str(args[args.index("--out") + 1])) if "--out" in args else None
    done = {"simulate": "meta.json", "inspect": "dataset.json", "fit": "summary.json"}.get(str(args[0]))
    if _REUSE["work"] is not None and out is not None and done and (out / done).is_file() \
            and shown in _REUSE["times"]:
        dt = _REUSE["times"][shown]
        log.append((shown, dt, "", ""))
        print(f"[reused ] {shown}", flush=True)
        return dt
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT / "src") + os.pathsep + env.get("PYTHONPATH", "")
    cmd = [sys.executable, "-m", "imrbayes.cli", *map(str, args)]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    dt = time.perf_counter() - t0
    log.append((shown, dt, proc.stdout.strip(), proc.stderr.strip()))
    print(f"[{dt:6.0f} s] {shown}", flush=True)
    if proc.returncode != 0:
        raise SystemExit(f"gallery: command failed ({proc.returncode}): {' '.join(cmd)}\n{proc.stderr}")
    _REUSE["times"][shown] = dt
    if _REUSE["work"] is not None:
        (_REUSE["work"] / "gallery_times.json").write_text(json.dumps(_REUSE["times"], indent=1))
    return dt


def _small_png(src: Path, dst: Path, max_width: int = MAX_WIDTH, crop_height: int | None = None) -> Path:
    """``src`` downscaled to ``max_width`` px (optionally its top ``crop_height`` px first), quantised."""
    from PIL import Image

    im = Image.open(src).convert("RGB")
    if crop_height is not None and im.height > crop_height:
        im = im.crop((0, 0, im.width, crop_height))
    if im.width > max_width:
        im = im.resize((max_width, round(im.height * max_width / im.width)), Image.LANCZOS)
    im = im.quantize(colors=96, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
    dst.parent.mkdir(parents=True, exist_ok=True)
    im.save(dst, optimize=True)
    return dst


def _conclusion_text(report: Path) -> list:
    """The report's conclusion block as plain-text lines (headline, then one line per item)."""
    page = report.read_text(encoding="utf-8")
    m = re.search(r"<div class='conclusion'>(.*?)</div>", page, re.S)
    if not m:
        return []
    block = m.group(1)
    head = re.search(r"<p>(.*?)</p>", block, re.S)
    items = re.findall(r"<li>(.*?)</li>", block, re.S)

    def plain(x):
        return " ".join(_html.unescape(re.sub(r"<[^>]+>", "", x)).split())

    return ([plain(head.group(1))] if head else []) + [plain(i) for i in items]


def _screenshot(report: Path, name: str, problems: list) -> Path | None:
    import check_report_browser as chk

    if chk.find_browser() is None:
        return None
    with tempfile.TemporaryDirectory() as tmp:
        full = Path(tmp) / "page.png"
        res = chk.check(report, png=full, width=1100)
        problems += [f"{report}: {p}" for p in res["problems"]]
        return _small_png(full, FIG / name, crop_height=1250)


def _section(title, intro, runs, figures, shots, log_from, log) -> str:
    out = [f"## {title}", "", intro, ""]
    out += ["Commands (run by `scripts/gallery.py`; the wall time on the machine that made this page, a shared "
            "2-core machine, so treat it as an upper bound):", "", "```"]
    for cmd, dt, _, _ in log[log_from:]:
        out.append(f"{cmd}    # {dt:.0f} s")
    out += ["```", ""]
    for label, run in runs:
        summary = json.loads((run / "summary.json").read_text())
        lines = _conclusion_text(run / "report.html")
        out += [f"**{label}** — `report.html` opens with this conclusion "
                f"({summary['n_experiments']} experiments, {summary['method']}):", ""]
        out += [f"> {lines[0]}" if lines else "> (no conclusion)", ">"]
        out += [f"> - {ln}" for ln in lines[1:]]
        out.append("")
        if label in shots and shots[label] is not None:
            out += [f"![{label}: the top of report.html in a browser](figures/gallery/{shots[label].name})", ""]
    for caption, path in figures:
        out += [f"![{caption}](figures/gallery/{path.name})", "", f"*{caption}*", ""]
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", type=Path, default=None, help="folder for the run directories (default: a temporary one)")
    ap.add_argument("--quick", action="store_true", help="a short emcee run (500 steps) and smaller ensembles")
    ap.add_argument("--reuse", action="store_true",
                    help="with --work: keep the runs already there (only the reports and the page are redone)")
    a = ap.parse_args(argv)
    if a.reuse and a.work is None:
        ap.error("--reuse needs --work")
    work = (a.work or Path(tempfile.mkdtemp(prefix="imrbayes-gallery-"))).resolve()
    if work.exists() and any(work.iterdir()) and not a.reuse:
        shutil.rmtree(work)
    work.mkdir(parents=True, exist_ok=True)
    _REUSE["work"] = work
    tfile = work / "gallery_times.json"
    if a.reuse and tfile.is_file():
        _REUSE["times"] = json.loads(tfile.read_text())
    if FIG.exists():
        shutil.rmtree(FIG)
    FIG.mkdir(parents=True)
    log, problems, parts = [], [], []
    steps = 500 if a.quick else 2000
    poly = ["--forward", "bubble=polytropic"]

    # 1. the bundled example (scripts/example.sh), with the time-resolved MIEnKS-MDA fit added
    ex = work / "example"
    start = len(log)
    _cli(["simulate", "--model", "nhkv", "--param", "G=7.29e3", "--param", "mu=0.088", "--rmax", "263e-6",
          "--ratio", "7.58", "--n-exp", "5", "--noise", "paper", "--seed", "0", *poly, "--out", ex / "data",
          "--quiet"], log)
    _cli(["fit", ex / "data", "--method", "en4dvar", "--seed", "0", "--out", ex / "en4dvar", "--mcmc",
          "--mcmc-set", "n_walkers=16", "--mcmc-set", f"n_steps={steps}", "--quiet"], log)
    _cli(["fit", ex / "data", "--method", "mienks", "--seed", "0", "--out", ex / "mienks", "--quiet"], log)
    for r in ("en4dvar", "mienks"):
        _cli(["report", ex / r, "--quiet"], log)
    shots = {"En4D-Var + MCMC": _screenshot(ex / "en4dvar" / "report.html", "example_report.png", problems)}
    figs = [("Example, En4D-Var: measured vs fitted R/Rmax per bubble (µs on top)",
             _small_png(ex / "en4dvar" / "figures" / "fit.png", FIG / "example_fit.png")),
            ("Example, En4D-Var: each bubble's posterior and the gel-level estimate",
             _small_png(ex / "en4dvar" / "figures" / "experiments.png", FIG / "example_experiments.png")),
            ("Example, MCMC check: emcee draws (red) against the ensemble Gaussian (blue), in kPa and Pa s",
             _small_png(ex / "en4dvar" / "figures" / "mcmc_pair_window_00.png", FIG / "example_mcmc_pair.png")),
            ("Example, MIEnKS-MDA: G(t), mu(t) with the prior band, µs axis and wall strain rate; hatched: "
             "windows the data barely moved",
             _small_png(ex / "mienks" / "figures" / "parameters.png", FIG / "example_parameters.png"))]
    truth = "G = 7.29 kPa, mu = 0.088 Pa s"
    parts.append(_section(
        "1. The bundled example (synthetic, known truth)",
        f"The paper's verification case ({truth}; Rmax 263 µm, Rmax/Req 7.58, five bubbles with the paper's "
        "noise), simulated and fitted with the **polytropic** bubble (`--forward bubble=polytropic` in the data's "
        f"meta.json), as `scripts/example.sh` does; emcee with 16 walkers × {steps} steps × 4 ensembles.",
        [("En4D-Var + MCMC", ex / "en4dvar"), ("MIEnKS-MDA", ex / "mienks")], figs, shots, start, log))

    # 2. stiff polyacrylamide (Estrada et al. 2018)
    data = _find_data(STIFF_PA)
    if data is None:
        print(f"gallery: {STIFF_PA} not found under shared/data: skipping the real-data case", file=sys.stderr)
    else:
        sp = work / "stiffPA"
        start = len(log)
        _cli(["inspect", data, "--out", sp / "inspect", "--quiet"], log)
        _cli(["fit", data, "--method", "en4dvar", *poly, "--seed", "0", "--out", sp / "en4dvar", "--quiet"], log)
        mk = ["--set", "n_ens=16"] if a.quick else []
        _cli(["fit", data, "--method", "mienks", *poly, *mk, "--seed", "0", "--out", sp / "mienks", "--quiet"], log)
        for r in ("en4dvar", "mienks"):
            _cli(["report", sp / r, "--quiet"], log)
        shots = {"En4D-Var": _screenshot(sp / "en4dvar" / "report.html", "stiffPA_report.png", problems)}
        figs = [("Stiff PA: the 20 radius records after preprocessing",
                 _small_png(sp / "inspect" / "figures" / "radius.png", FIG / "stiffPA_radius.png")),
                ("Stiff PA, En4D-Var: measured vs fitted R/Rmax (polytropic bubble)",
                 _small_png(sp / "en4dvar" / "figures" / "fit.png", FIG / "stiffPA_fit.png")),
                ("Stiff PA, En4D-Var: each bubble's posterior and the gel-level estimate",
                 _small_png(sp / "en4dvar" / "figures" / "experiments.png", FIG / "stiffPA_experiments.png")),
                ("Stiff PA, MIEnKS-MDA: G(t), mu(t) against t*, µs and the wall strain rate",
                 _small_png(sp / "mienks" / "figures" / "parameters.png", FIG / "stiffPA_parameters.png"))]
        parts.append(_section(
            "2. Real data: stiff polyacrylamide (Estrada et al. 2018)",
            "Twenty bubbles in the \"stiff PA\" gel of Estrada et al. 2018 (JMPS 112:291), filmed at 270 000 fps "
            f"(`shared/data/lic/{STIFF_PA}`). To keep this page cheap to regenerate, the fits use the "
            "**polytropic** bubble (`--forward bubble=polytropic`) and default method settings, not the "
            "thermal bubble a real analysis should use; the report's caveats and the fit panels show what that "
            "costs.", [("En4D-Var", sp / "en4dvar"), ("MIEnKS-MDA", sp / "mienks")], figs, shots, start, log))

    head = ["# Gallery: what imrbayes produces", "",
            "Generated by `python scripts/gallery.py` (do not edit by hand): every command below ran through the "
            "`imrbayes` command line, and every image is a downscaled copy of a figure or of a report that it "
            "wrote. Each `report.html` is one self-contained page (figures embedded) that opens with the "
            "conclusion quoted here; `docs/report.md` lists its sections.", ""]
    if problems:
        head += ["Browser check problems:", ""] + [f"- {p}" for p in problems] + [""]
    DOC.write_text("\n".join(head + parts).rstrip() + "\n", encoding="utf-8")
    total = sum(p.stat().st_size for p in FIG.glob("*.png"))
    print(f"gallery: wrote {DOC.relative_to(ROOT)} and {len(list(FIG.glob('*.png')))} PNG(s) "
          f"({total / 1024:.0f} KiB) under {FIG.relative_to(ROOT)}; runs in {work}")
    if problems:
        print("gallery: browser check problems:\n  " + "\n  ".join(problems), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
