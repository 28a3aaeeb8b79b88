"""Never lose work: a run in a subprocess (``python -m imrbayes.execution.toy`` with slow units) is
killed part-way with SIGTERM or SIGKILL, then resumed. Every unit finished before the kill is kept
untouched (same bytes, same mtime: not recomputed), no worker process outlives the run, and the final
results equal an uninterrupted run's."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from _exec_helpers import same

from imrbayes.execution import RunStore, run_units
from imrbayes.execution.toy import toy_bubble, toy_units

N_UNITS, STEPS, SLEEP, SEED = 12, 300, 0.25, 5
CONFIG = {"workload": "toy_bubble", "units": N_UNITS, "windows": 1, "steps": STEPS, "fail": [], "seed": SEED}

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")


def _cmd(out, *extra):
    return [
        sys.executable,
        "-m",
        "imrbayes.execution.toy",
        "--out",
        str(out),
        "--units",
        str(N_UNITS),
        "--steps",
        str(STEPS),
        "--sleep",
        str(SLEEP),
        "--seed",
        str(SEED),
        *extra,
    ]


def _snapshot(units_dir: Path) -> dict:
    return {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in units_dir.glob("*.npz")}


def _alive_in_group(pgid: int) -> list[int]:
    """Non-zombie processes of a process group (Linux /proc)."""
    alive = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            alive.append(int(stat.parent.name))
    return alive


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    out = tmp_path_factory.mktemp("uninterrupted") / "run"
    units = toy_units(N_UNITS, steps=STEPS)  # no sleep: it does not change results
    with RunStore.open(out, CONFIG) as store:
        return run_units(units, toy_bubble, seed=SEED, store=store, progress=False).results


# One kill in the default tier; the other signals and backends in the slow tier.
@pytest.mark.parametrize(
    "sig,extra",
    [
        pytest.param(signal.SIGTERM, ["--workers", "2"], id="sigterm-2proc", marks=pytest.mark.slow),
        pytest.param(signal.SIGKILL, ["--workers", "2"], id="sigkill-2proc", marks=pytest.mark.slow),
        pytest.param(signal.SIGTERM, [], id="sigterm-inproc", marks=pytest.mark.slow),
        pytest.param(signal.SIGKILL, [], id="sigkill-inproc"),
        pytest.param(
            signal.SIGTERM, ["--scheduler", "local", "--workers", "2"], id="sigterm-dask", marks=pytest.mark.slow
        ),
    ],
)
def test_kill_and_resume_loses_nothing(tmp_path, uninterrupted, sig, extra):
    out = tmp_path / "run"
    proc = subprocess.Popen(
        _cmd(out, *extra), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
    )
    try:
        deadline = time.monotonic() + 60
        while len(list((out / "units").glob("*.npz"))) < 3:
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "the run did not get going"
            time.sleep(0.02)
        os.kill(proc.pid, sig)
        before = _snapshot(out / "units")  # taken after the signal: anything here was finished
        _, err = proc.communicate(timeout=30)
        assert proc.returncode in (128 + sig, -sig), err
        if sig == signal.SIGTERM:
            assert "interrupted by SIGTERM" in err and "Traceback" not in err
        # no worker process outlives its parent (SIGKILL: they notice and exit on their own)
        if sys.platform.startswith("linux"):
            deadline = time.monotonic() + 10
            while _alive_in_group(proc.pid) and time.monotonic() < deadline:
                time.sleep(0.1)
            assert _alive_in_group(proc.pid) == []
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    n_killed = len(list((out / "units").glob("*.npz")))
    assert 3 <= n_killed < N_UNITS, "killed too late to test anything"
    if sig == signal.SIGTERM:
        status = json.loads((out / "status.json").read_text())
        assert status["interrupted"] and not status["complete"]

    # resume (in-process, fast): nothing finished is redone, nothing lost
    res = subprocess.run(_cmd(out, "--resume", "--sleep", "0"), capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    rep = json.loads(res.stdout.strip().splitlines()[-1])
    assert rep["n_resumed"] == n_killed and rep["n_computed"] == N_UNITS - n_killed and rep["n_failed"] == 0
    after = _snapshot(out / "units")
    assert set(before) <= set(after)
    assert {k: after[k] for k in before} == before  # same bytes, same mtime: kept, not recomputed
    with RunStore.open(out, CONFIG, resume=True) as store:
        final = run_units(toy_units(N_UNITS, steps=STEPS), toy_bubble, seed=SEED, store=store, progress=False)
    assert final.n_resumed == N_UNITS
    same(final.results, uninterrupted)


def test_changed_options_on_resume_exit_2(tmp_path):
    out = tmp_path / "run"
    subprocess.run(_cmd(out, "--sleep", "0"), check=True, capture_output=True)
    res = subprocess.run([*_cmd(out, "--resume", "--sleep", "0"), "--steps", "301"], capture_output=True, text=True)
    assert res.returncode == 2
    assert (
        "cannot resume: the configuration differs from the stored run (steps: 300 (stored) vs 301 (now))" in res.stderr
    )


def _stopped_in_compiled_code(unit, rng):
    """A unit that an interrupt stops inside a numba kernel: numba hands back a SystemError whose
    cause is the interrupt the signal handler raised."""
    from imrbayes.execution import RunInterrupted

    if unit["value"] == 2:
        try:
            raise RunInterrupted(signal.SIGTERM)
        except RunInterrupted as stop:
            raise SystemError(
                "CPUDispatcher(<function integrate_batch_parallel>) returned a result with an exception set"
            ) from stop
    return {"x": float(unit["value"])}


def _plain(unit, rng):
    return {"x": float(unit["value"])}


def test_an_interrupt_inside_compiled_code_is_not_recorded_as_the_units_failure(tmp_path):
    from imrbayes.execution import RunInterrupted

    units = [{"unit_id": f"u{i}", "value": i} for i in range(4)]
    out = tmp_path / "run"
    with RunStore.open(out, {"what": "interrupt"}) as store:
        with pytest.raises(RunInterrupted):
            run_units(units, _stopped_in_compiled_code, store=store, progress=False)
    assert not list((out / "units").glob("*.failed.json"))
    assert sorted(p.name for p in (out / "units").glob("*.npz")) == ["u0.npz", "u1.npz"]
    with RunStore.open(out, {"what": "interrupt"}, resume=True) as store:
        rep = run_units(units, _plain, store=store, progress=False)
    assert rep.ok and rep.n_resumed == 2 and rep.n_computed == 2
    assert [rep.results[f"u{i}"]["x"] for i in range(4)] == [0.0, 1.0, 2.0, 3.0]


def test_a_failure_record_written_by_an_interrupt_is_rerun_on_resume(tmp_path):
    units = [{"unit_id": f"u{i}", "value": i} for i in range(3)]
    out = tmp_path / "run"
    with RunStore.open(out, {"what": "old record"}) as store:
        run_units(units[:2], _plain, store=store, progress=False)
        # as older code wrote it: the interrupt wrapped by numba, recorded as the unit's failure
        store.save_failure(
            "u2",
            seed=0,
            error="SystemError: CPUDispatcher(...) returned a result with an exception set",
            traceback="Traceback ...\nimrbayes.execution.driver.RunInterrupted: interrupted by SIGTERM\n",
        )
        store.save_failure("u3", seed=0, error="ValueError: a real failure", traceback="Traceback ...\nValueError: x\n")
    units.append({"unit_id": "u3", "value": 3})
    with RunStore.open(out, {"what": "old record"}, resume=True) as store:
        with pytest.warns(RuntimeWarning, match="recorded as failed when an interrupt stopped it"):
            rep = run_units(units, _plain, store=store, progress=False)
    assert rep.results["u2"]["x"] == 2.0 and rep.n_computed == 1
    assert list(rep.failures) == ["u3"] and rep.failures["u3"].from_checkpoint
