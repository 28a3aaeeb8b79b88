"""The study's runs: one ordinary ``fit`` (or ``diagnose``) run folder per dataset and method, under
``DIR/runs/<condition>/<job>``, scheduled as execution units (``--workers``, ``--scheduler``).

A folder is reused when its ``study-job.json`` fingerprint (the command's arguments, the dataset's
bytes, the imrbayes version) matches; a folder that an interrupted run left (``run.json`` without
its result) is resumed; a folder of another configuration is replaced only with ``replace``.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from dataclasses import dataclass
from pathlib import Path

from imrbayes import __version__
from imrbayes.errors import InputError
from imrbayes.io import read_json, write_json

__all__ = ["Job", "plan_jobs", "run_jobs", "run_job", "data_digest", "JOB_FILE"]

#: the fingerprint file each study run folder carries
JOB_FILE = "study-job.json"


@dataclass(frozen=True)
class Job:
    """One command on one dataset: ``condition`` (name), ``name`` (``en4dvar``, ``imr-collapse2``,
    ``diagnose``), ``command`` (``fit``/``diagnose``), ``args`` (its arguments without ``--out``),
    ``folder`` (the run folder), ``product`` (the file that marks it finished)."""

    condition: str
    name: str
    command: str
    args: tuple
    folder: Path
    product: str

    @property
    def unit_id(self) -> str:
        return f"{self.condition}/{self.name}"


def data_digest(path) -> str:
    """SHA-256 of a dataset's bytes: the file, or every file under the folder (relative names and contents)."""
    path = Path(path)
    h = hashlib.sha256()
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    for f in files:
        h.update(str(f.relative_to(path) if f != path else f.name).encode() + b"\0")
        h.update(f.read_bytes())
    return h.hexdigest()


def _fit_args(spec, cond, method: str, extra_settings=()) -> list:
    args = ["fit", str(cond.data), "--method", method, "--model", spec.model, "--seed", str(spec.seed)]
    args += [a for k, v in spec.forward.items() for a in ("--forward", f"{k}={_text(v)}")]
    settings = [f"{k}={_text(v)}" for k, v in spec.settings.get(method, {}).items()] + list(extra_settings)
    args += [a for s in settings for a in ("--set", s)]
    if spec.experiments:
        args += ["--experiments", spec.experiments]
    for key, opt in (("dt_star", "--dt-star"), ("n_steps", "--n-steps"), ("camera", "--camera")):
        if key in spec.grid:
            args += [opt, str(spec.grid[key])]
    if "likelihood" in spec.grid and method in ("en4dvar", "mienks"):
        args += ["--likelihood", spec.grid["likelihood"]]
    return args


def _diagnose_args(spec, cond) -> list:
    args = ["diagnose", str(cond.data), "--seed", str(spec.seed)]
    args += [a for k, v in spec.forward.items() for a in ("--forward", f"{k}={_text(v)}")]
    if spec.experiments:
        args += ["--experiments", spec.experiments]
    for key, opt in (("dt_star", "--dt-star"), ("n_steps", "--n-steps"), ("camera", "--camera")):
        if key in spec.grid:
            args += [opt, str(spec.grid[key])]
    return args + (["--quick"] if spec.diagnose == "quick" else [])


def _text(v) -> str:
    return str(v).lower() if isinstance(v, bool) else str(v)


def plan_jobs(spec, out: Path) -> list:
    """Every :class:`Job` of the study ``spec`` whose run folders live under ``out/runs``."""
    jobs = []
    for c in spec.conditions:
        base = Path(out) / "runs" / c.name
        for m in spec.methods:
            jobs.append(Job(c.name, m, "fit", tuple(_fit_args(spec, c, m)[1:]), base / m, "summary.json"))
        for k in spec.collapses:
            args = _fit_args(spec, c, "imr", [f"window=collapse:{k}"])
            jobs.append(
                Job(c.name, f"imr-collapse{k}", "fit", tuple(args[1:]), base / f"imr-collapse{k}", "summary.json")
            )
        if spec.diagnose:
            jobs.append(
                Job(
                    c.name,
                    "diagnose",
                    "diagnose",
                    tuple(_diagnose_args(spec, c)[1:]),
                    base / "diagnose",
                    "diagnosis.json",
                )
            )
    return jobs


def fingerprint(job: Job, digest: str) -> str:
    """What decides a run's numbers: the command, its arguments, the data's bytes, the imrbayes version."""
    text = json.dumps(
        {"command": job.command, "args": list(job.args), "data": digest, "version": __version__}, sort_keys=True
    )
    return hashlib.sha256(text.encode()).hexdigest()


def run_job(unit, rng=None) -> dict:
    """Run one job (an execution unit whose ``data`` is ``{"job": Job, "fingerprint": str, "replace":
    bool}``) through the command's own Python function; returns ``{"status": "reused" | "resumed" |
    "computed"}``. Top-level, so that every backend can ship it to a worker."""
    job, fp, replace = unit.data["job"], unit.data["fingerprint"], unit.data["replace"]
    folder = Path(job.folder)
    marker = read_json(folder / JOB_FILE, required=False) if (folder / JOB_FILE).is_file() else None
    resume = False
    if marker is not None and marker.get("fingerprint") == fp:
        if (folder / job.product).is_file():
            return {"status": "reused"}
        resume = (folder / "run.json").is_file()
    elif folder.is_dir() and any(folder.iterdir()):
        if not replace:
            raise InputError(
                folder,
                "holds a run of another configuration (data, options or imrbayes version); pass --force to replace it",
            )
        shutil.rmtree(folder)
    folder.mkdir(parents=True, exist_ok=True)
    write_json(
        folder / JOB_FILE,
        {"fingerprint": fp, "command": job.command, "args": list(job.args), "imrbayes_version": __version__},
    )
    command = _command(job.command)
    command.main(
        [*job.args, "--out", str(folder), "--quiet", "--resume" if resume else "--force"],
        prog_name=f"imrbayes {job.command}",
        standalone_mode=False,
    )
    if not (folder / job.product).is_file():
        raise RuntimeError(f"{job.command} ended without writing {job.product}")
    return {"status": "resumed" if resume else "computed"}


def _command(name: str):
    if name == "fit":
        from imrbayes.cli.fit import fit_cmd

        return fit_cmd
    from imrbayes.cli.diagnose import diagnose_cmd

    return diagnose_cmd


def run_jobs(jobs, *, seed: int, workers=None, scheduler=None, replace: bool = False, report=None) -> dict:
    """Run ``jobs`` on the executor ``workers``/``scheduler`` ask for; a failed job is reported
    (``report(line)``) and the others go on. Returns ``{unit_id: {"status": ..., "error": ...}}``."""
    from imrbayes.execution import Unit, make_executor

    digests = {}
    units = []
    for job in jobs:
        key = str(Path(job.args[0]).resolve())
        if key not in digests:
            digests[key] = data_digest(job.args[0])
        units.append(
            Unit(
                job.unit_id, data={"job": job, "fingerprint": fingerprint(job, digests[key]), "replace": bool(replace)}
            )
        )
    results = {}
    with make_executor(workers, scheduler) as ex:
        for outcome in ex.map(run_job, units, seed=seed):
            if outcome.ok:
                results[outcome.unit_id] = dict(outcome.value)
            else:
                results[outcome.unit_id] = {"status": "failed", "error": outcome.error}
            if report is not None:
                r = results[outcome.unit_id]
                report(f"{outcome.unit_id}: {r['status']}" + (f" ({r['error']})" if r.get("error") else ""))
    return results
