"""``imrbayes fit`` on the execution layer: the same numbers in-process, on a process pool and on a
Dask LocalCluster; a run killed part-way (SIGTERM, SIGKILL) and resumed gives the numbers of an
uninterrupted run without recomputing what was finished; a changed configuration is refused;
failed units and experiments are contained and reported. Polytropic bubble, tiny settings."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from _ens_synth import observations, space
from click.testing import CliRunner

from imrbayes.cli import main

# Whole fits on every backend, killed and resumed: the default tier's execution tests are
# test_execution_resume.py and test_execution_backends.py (toy units).
pytestmark = pytest.mark.slow

TINY = {
    "imr": ["n_G=9", "n_mu=7", "G_max=15e3", "mu_max=0.2", "n_draws=20"],
    "en4dvar": ["n_ens=8", "n_runs=2", "n_iter=2", "n_draws=4"],
    "mienks": ["n_ens=8", "n_iter=2", "L=40", "h=20", "n_draws=5"],
}
VOLATILE = ("runtime_s", "total_runtime_s", "command", "execution")


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    d = tmp_path_factory.mktemp("scaling") / "data"
    res = CliRunner().invoke(
        main,
        [
            "simulate",
            "--model",
            "nhkv",
            "--param",
            "G=7.29e3",
            "--param",
            "mu=0.088",
            "--n-exp",
            "3",
            "--forward",
            "bubble=polytropic",
            "--out",
            str(d),
            "--quiet",
        ],
    )
    assert res.exit_code == 0, res.output
    return d


@pytest.fixture(scope="module")
def mienks_ref(dataset, tmp_path_factory):
    """One uninterrupted in-process MIEnKS-MDA run of ``dataset``: every comparison below is against
    its numbers (the run is deterministic given the seed, so one is enough)."""
    out = tmp_path_factory.mktemp("scaling") / "mienks-ref"
    _fit(_args(dataset, "mienks", out))
    return numbers(out)


def _args(dataset, method, out, *extra):
    args = [
        str(dataset),
        "--method",
        method,
        "--out",
        str(out),
        "--seed",
        "4",
        "--forward",
        "bubble=polytropic",
        "--quiet",
    ]
    for s in TINY[method]:
        args += ["--set", s]
    return args + [str(x) for x in extra]


def _fit(args, expect=0):
    res = CliRunner().invoke(main, ["fit", *args])
    assert res.exit_code == expect, res.output
    return res


def numbers(out: Path) -> dict:
    """Everything in summary.json that results from the computation, and posterior.nc's arrays."""
    import xarray as xr

    s = json.loads((out / "summary.json").read_text())
    for k in VOLATILE:
        s.pop(k, None)
    arrays = {}
    with xr.open_datatree(out / "posterior.nc") as dt:
        for node in dt.subtree:
            for name, var in node.ds.data_vars.items():
                arrays[f"{node.path}/{name}"] = np.asarray(var.values).tobytes()
    return {"summary": s, "arrays": arrays}


def _same(a, b):
    assert a["summary"] == b["summary"]
    assert a["arrays"].keys() == b["arrays"].keys()
    for k in a["arrays"]:
        assert a["arrays"][k] == b["arrays"][k], k


@pytest.mark.parametrize(
    "method,extra",
    [
        ("imr", ["--workers", "2"]),
        ("en4dvar", ["--workers", "2"]),
        ("mienks", ["--workers", "2"]),
        ("mienks", ["--scheduler", "local", "--workers", "2"]),
    ],
    ids=["imr-2proc", "en4dvar-2proc", "mienks-2proc", "mienks-dask"],
)
def test_same_numbers_on_every_backend(dataset, tmp_path, method, extra, request):
    if method == "mienks":
        one = request.getfixturevalue("mienks_ref")
    else:
        _fit(_args(dataset, method, tmp_path / "one"))
        one = numbers(tmp_path / "one")
    _fit(_args(dataset, method, tmp_path / "many", *extra))
    _same(one, numbers(tmp_path / "many"))
    ex = json.loads((tmp_path / "many" / "summary.json").read_text())["execution"]
    assert ex["n_failed"] == 0 and ex["n_computed"] == ex["n_units"] > 0


def test_resume_after_lost_units_and_refusals(dataset, tmp_path, mienks_ref):
    out = tmp_path / "run"
    _fit(_args(dataset, "mienks", out))
    ref = numbers(out)
    _same(ref, mienks_ref)
    run = json.loads((out / "run.json").read_text())
    assert run["config"]["method"] == "mienks" and run["imrbayes_version"] and run["config"]["settings"]["n_ens"] == 8
    # lose the last windows of the reported pass (as an interruption would), then resume on 2 processes
    # (the default likelihood's pilot pass, pass=pilot/..., is kept)
    units = sorted(p for p in (out / "units").glob("*window=00[234]*.npz") if not p.name.startswith("pass=pilot"))
    assert len(units) == 9
    for p in units:
        p.unlink()
    (out / "summary.json").unlink()
    res = _fit(_args(dataset, "mienks", out, "--resume", "--workers", "2"))
    _same(numbers(out), ref)
    ex = json.loads((out / "summary.json").read_text())["execution"]
    assert (ex["n_resumed"], ex["n_computed"]) == (21, 9)
    # same --out without --resume: refused; with another configuration: refused (one line, exit 2)
    res = _fit(_args(dataset, "mienks", out), expect=2)
    assert "already holds a run" in res.output and len(res.output.strip().splitlines()) == 1
    res = _fit(_args(dataset, "mienks", out, "--resume", "--set", "n_iter=3"), expect=2)
    assert "cannot resume: the configuration differs" in res.output and "n_iter: 2 (stored) vs 3 (now)" in res.output
    assert len(res.output.strip().splitlines()) == 1
    res = _fit(_args(dataset, "mienks", out, "--resume", "--seed", "5"), expect=2)
    assert "seed" in res.output
    res = _fit(_args(dataset, "mienks", tmp_path / "x", "--retry-failed"), expect=2)
    assert "--retry-failed" in res.output


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
@pytest.mark.parametrize(
    "sig,extra",
    [(signal.SIGTERM, []), (signal.SIGKILL, []), (signal.SIGKILL, ["--workers", "2"])],
    ids=["sigterm", "sigkill", "sigkill-2proc"],
)
def test_fit_killed_and_resumed(dataset, tmp_path, sig, extra, mienks_ref):
    """A real ``imrbayes fit`` process killed part-way; the resume keeps every finished unit (same
    bytes, not recomputed) and ends with an uninterrupted run's numbers."""
    out = tmp_path / "run"
    env = {**os.environ, "IMRBAYES_UNIT_DELAY_S": "0.3"}
    cmd = [
        sys.executable,
        "-c",
        "import sys; from imrbayes.cli import main; sys.exit(main())",
        "fit",
        *_args(dataset, "mienks", out, *extra),
    ]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, start_new_session=True
    )
    try:
        deadline = time.monotonic() + 120
        while len(list((out / "units").glob("*.npz"))) < 4:
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "the fit did not get going"
            time.sleep(0.02)
        os.kill(proc.pid, sig)
        before = {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in (out / "units").glob("*.npz")}
        _, err = proc.communicate(timeout=60)
        assert proc.returncode in (128 + sig, -sig), err
        if sig == signal.SIGTERM:
            assert "interrupted by SIGTERM" in err and "--resume" in err and "Traceback" not in err
            assert json.loads((out / "status.json").read_text())["interrupted"]
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    n_done = len(before)
    assert 4 <= n_done < 30, "killed too late to test anything"  # 15 units per pass, pilot and reported
    assert not (out / "summary.json").exists()
    _fit(_args(dataset, "mienks", out, "--resume"))
    after = {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in (out / "units").glob("*.npz")}
    assert {k: after[k] for k in before} == before  # kept, not recomputed
    ex = json.loads((out / "summary.json").read_text())["execution"]
    assert ex["n_resumed"] >= n_done and ex["n_resumed"] + ex["n_computed"] == 30
    _same(numbers(out), mienks_ref)


def test_bad_experiment_left_out_and_reported(dataset, tmp_path):
    """One experiment whose record ends before its first collapse: the others are fitted, the bad one
    is listed in summary.json and on stderr."""
    import shutil

    d = tmp_path / "data"
    shutil.copytree(dataset, d)
    lines = (d / "exp_002.csv").read_text().splitlines()
    (d / "exp_002.csv").write_text("\n".join(lines[:12]) + "\n")  # cut before the first collapse
    res = CliRunner().invoke(main, ["fit", *_args(d, "en4dvar", tmp_path / "out")])
    assert res.exit_code == 0, res.output
    s = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert s["n_experiments"] == 2
    assert [x["name"] for x in s["failures"]["skipped_experiments"]] == ["exp_002"]
    assert "left out" in res.output and "exp_002" in res.output


class _Failing:
    """A runner that raises for one experiment (by its Rmax), from a given window start t* on."""

    def __init__(self, fm, rmax, t_from=0.0):
        from imrbayes.forward import Runner

        self.inner, self.rmax, self.t_from = Runner(fm), rmax, t_from
        self.fm = fm

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def propagate(self, state, params, t_end, t_eval=None):
        if np.all(state.rmax_m == self.rmax) and state.t_star >= self.t_from:
            raise FloatingPointError("injected failure")
        return self.inner.propagate(state, params, t_end, t_eval)

    def simulate(self, params, rmax_m, req_m, t_star):
        if np.all(np.asarray(rmax_m) == self.rmax) and self.t_from <= 0.0:  # a simulation starts at t* = 0
            raise FloatingPointError("injected failure")
        return self.inner.simulate(params, rmax_m, req_m, t_star)


def test_failed_units_are_contained_counted_and_retried(tmp_path):
    from imrbayes.ensemble import En4DVarSettings, IMRSettings, MIEnKSSettings, fit_en4dvar, fit_imr, fit_mienks
    from imrbayes.execution import Execution, RunStore

    fm, obs = observations(n_exp=3, n_steps=60)
    sp = space(fm)
    res = fit_imr(
        fm, obs, sp, IMRSettings(n_G=9, n_mu=7, G_max=15e3, mu_max=0.2, n_draws=10), runner=_Failing(fm, obs.rmax_m[1])
    )
    assert [f["experiment"] for f in res.details["failed_units"]] == ["exp_002"]
    assert res.per_experiment[1]["failed"] and "injected failure" in res.warnings[0]
    assert np.isfinite(res.estimate["G"]["mean"])

    s = En4DVarSettings(n_ens=8, n_runs=1, n_iter=2, n_draws=3)
    res = fit_en4dvar(fm, obs, sp, s, runner=_Failing(fm, obs.rmax_m[0]))
    assert res.details["experiments_used"] == ["exp_002", "exp_003"]
    assert res.details["failed_units"][0]["error"] == "FloatingPointError: injected failure"

    # MIEnKS: exp_003 fails from the third window on; it leaves the fusion there, the run goes on;
    # a resume with --retry-failed (and a healthy model) reruns exactly the failed units and later
    ms = MIEnKSSettings(n_ens=8, n_iter=2, L=20, h=10, n_draws=3)
    cfg = {"test": "mienks-failures"}
    with RunStore.open(tmp_path / "run", cfg) as store:
        ex = Execution(store=store, progress=False)
        res = fit_mienks(fm, obs, sp, ms, runner=_Failing(fm, obs.rmax_m[2], t_from=0.5), execution=ex)
    lost = [w["failed_experiments"] for w in res.windows]
    assert lost[:2] == [[], []] and lost[2] == ["exp_003"] and all(x == [] for x in lost[3:])
    # the default likelihood's pilot pass meets the failure first, the reported pass again
    assert [(f.get("pass"), f["window"]) for f in res.details["failed_units"]] == [("pilot", 2), (None, 2)]
    assert len(res.windows[3]["per_experiment"]) == 2
    assert ex.summary()["n_failed"] == 2
    with RunStore.open(tmp_path / "run", cfg, resume=True) as store:
        ex = Execution(store=store, progress=False, retry_failed=True)
        res2 = fit_mienks(fm, obs, sp, ms, execution=ex)
    assert res2.details["failed_units"] == [] and ex.summary()["n_failed"] == 0
    ref = fit_mienks(fm, obs, sp, ms)
    assert res2.estimate == ref.estimate
