"""The checkpoint store and driver, and never losing work when a run is interrupted."""

from __future__ import annotations

import io
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from _exec_helpers import same

import imrbayes
from imrbayes.errors import InputError
from imrbayes.execution import (
    RunInterrupted,
    RunStore,
    Unit,
    config_fingerprint,
    driver as driver_mod,
    run_units,
    safe_name,
    store as store_mod,
    unit_id,
)
from imrbayes.execution.store import decode_value, encode_value
from imrbayes.execution.toy import toy_bubble, toy_units

# Checkpoint store and driver: run.json and its fingerprint, atomic unit files (a partial temporary
# file is never read), exact round trips of unit values, resume skipping finished units with results
# identical to an uninterrupted run, refusal of a changed configuration, failure records and retries,
# progress output only on a terminal.


CONFIG = {"method": "toy", "model": "nhkv", "seed": 3, "settings": {"n_iter": 5, "windows": [0.0, 0.85]}}
UNITS = toy_units(4, windows=2, steps=300)


def _run(out, units=UNITS, config=CONFIG, resume=False, fn=toy_bubble, **kw):
    with RunStore.open(out, config, resume=resume) as store:
        return run_units(units, fn, seed=config.get("seed", 0), store=store, progress=False, **kw)


# ------------------------------------------------------------------------------------------ run.json


def test_run_json_records_config_version_fingerprint(tmp_path):
    report = _run(tmp_path / "run")
    info = json.loads((tmp_path / "run" / "run.json").read_text())
    assert info["config"] == CONFIG
    assert info["imrbayes_version"] == imrbayes.__version__
    assert info["fingerprint"] == config_fingerprint(CONFIG) and info["fingerprint"].startswith("sha256:")
    assert info["started"].endswith("+00:00")
    assert info["sessions"][0]["execution"] == [{"backend": "in-process", "workers": 1}]
    status = json.loads((tmp_path / "run" / "status.json").read_text())
    assert status["complete"] and status["n_done"] == len(UNITS) == report.n_computed
    names = sorted(p.name for p in (tmp_path / "run" / "units").iterdir())
    assert names == sorted(f"{safe_name(u.unit_id)}.npz" for u in UNITS)


def test_fingerprint_is_canonical():
    a = {"b": (1, 2.5), "a": {"y": np.float64(0.1), "x": np.int64(3)}}
    b = {"a": {"x": 3, "y": 0.1}, "b": [1, 2.5]}
    assert config_fingerprint(a) == config_fingerprint(b)
    assert config_fingerprint(b) != config_fingerprint({**b, "b": [1, 2.50000001]})
    with pytest.raises(TypeError, match="config.f"):
        config_fingerprint({"f": object()})


# --------------------------------------------------------------------------------------------- resume


def test_resume_skips_finished_units_and_matches_uninterrupted(tmp_path):
    full = _run(tmp_path / "full")
    part = _run(tmp_path / "part", units=UNITS[:3])  # "interrupted" after three units
    mtimes = {p.name: p.stat().st_mtime_ns for p in (tmp_path / "part" / "units").iterdir()}
    resumed = _run(tmp_path / "part", resume=True)
    assert part.n_computed == 3 and resumed.n_resumed == 3 and resumed.n_computed == len(UNITS) - 3
    assert {p.name: p.stat().st_mtime_ns for p in (tmp_path / "part" / "units").iterdir() if p.name in mtimes} == mtimes
    same(resumed.results, full.results)
    again = _run(tmp_path / "part", resume=True)
    assert again.n_computed == 0 and again.n_resumed == len(UNITS)
    same(again.results, full.results)
    info = json.loads((tmp_path / "part" / "run.json").read_text())
    assert [s["resume"] for s in info["sessions"]] == [False, True, True]


def test_existing_run_needs_resume(tmp_path):
    _run(tmp_path / "run", units=UNITS[:1])
    with pytest.raises(InputError, match="already holds a run.*--resume"):
        RunStore.open(tmp_path / "run", CONFIG)


def test_resume_on_a_new_directory_starts_a_run(tmp_path):
    report = _run(tmp_path / "new", resume=True)
    assert report.n_computed == len(UNITS)


def test_resume_with_other_configuration_is_refused(tmp_path):
    _run(tmp_path / "run", units=UNITS[:2])
    changed = {**CONFIG, "model": "qkv", "settings": {"n_iter": 7, "windows": [0.0, 0.85]}, "extra": 1}
    with pytest.raises(InputError) as err:
        RunStore.open(tmp_path / "run", changed, resume=True)
    msg = str(err.value)
    assert "cannot resume: the configuration differs" in msg
    assert 'model: "nhkv" (stored) vs "qkv" (now)' in msg
    assert "settings.n_iter: 5 (stored) vs 7 (now)" in msg
    assert "extra: absent (stored) vs 1 (now)" in msg
    assert "windows" not in msg
    # nothing was modified by the refused attempt
    assert RunStore.open(tmp_path / "run", CONFIG, resume=True).close() is None


def test_resume_with_other_version_or_seed_is_refused(tmp_path):
    out = tmp_path / "run"
    _run(out, units=UNITS[:2])
    info = json.loads((out / "run.json").read_text())
    (out / "run.json").write_text(json.dumps({**info, "imrbayes_version": "0.0.1"}))
    with pytest.raises(InputError, match="started with imrbayes 0.0.1"):
        RunStore.open(out, CONFIG, resume=True)
    RunStore.open(out, CONFIG, resume=True, check_version=False).close()
    # a seed outside the configuration is still checked unit by unit
    noseed = {"method": "toy"}
    _run(tmp_path / "b", config=noseed, units=UNITS[:2])
    with RunStore.open(tmp_path / "b", noseed, resume=True) as store:
        with pytest.raises(InputError, match="computed with seed 0, this run uses seed 1"):
            run_units(UNITS, toy_bubble, seed=1, store=store, progress=False)


def test_a_run_is_locked_while_open(tmp_path):
    with RunStore.open(tmp_path / "run", CONFIG):
        with pytest.raises(InputError, match="open in another process"):
            RunStore.open(tmp_path / "run", CONFIG, resume=True)
    RunStore.open(tmp_path / "run", CONFIG, resume=True).close()


# -------------------------------------------------------------------------------------- atomic files


def test_partial_temporary_file_is_ignored_and_removed(tmp_path):
    out = tmp_path / "run"
    full = _run(tmp_path / "full")
    _run(out, units=UNITS[:2])
    victim = UNITS[2].unit_id
    tmp = out / "units" / f".{safe_name(victim)}.npz.0123456789ab.tmp"
    tmp.write_bytes(b"PK\x03\x04 half a zip file")  # a writer killed before os.replace
    (out / ".run.json.deadbeef0000.tmp").write_text("{")
    with RunStore.open(out, CONFIG, resume=True) as store:
        assert store.status(victim) is None
        assert not tmp.exists() and not list(out.glob(".*.tmp"))
        report = run_units(UNITS, toy_bubble, seed=3, store=store, progress=False)
    assert report.n_resumed == 2 and report.n_computed == len(UNITS) - 2
    same(report.results, full.results)


def test_crash_during_write_leaves_no_unit_file(tmp_path, monkeypatch):
    out = tmp_path / "run"

    def boom(fh, **arrays):
        fh.write(b"PK\x03\x04 partial")
        raise OSError("disk full")

    with RunStore.open(out, CONFIG) as store:
        monkeypatch.setattr(store_mod.np, "savez", boom)
        with pytest.raises(OSError, match="disk full"):
            store.save("exp=000", {"x": np.arange(3)}, seed=3)
        monkeypatch.undo()
        assert store.status("exp=000") is None
        assert list((out / "units").iterdir()) == []
        # and a failure of os.replace itself
        monkeypatch.setattr(store_mod.os, "replace", lambda *a: (_ for _ in ()).throw(OSError("EIO")))
        with pytest.raises(OSError, match="EIO"):
            store.save("exp=000", {"x": np.arange(3)}, seed=3)
        monkeypatch.undo()
        assert list((out / "units").iterdir()) == []


def test_damaged_unit_file_is_recomputed(tmp_path):
    out = tmp_path / "run"
    full = _run(out)
    path = out / "units" / f"{safe_name(UNITS[1].unit_id)}.npz"
    path.write_bytes(path.read_bytes()[:100])
    with pytest.warns(RuntimeWarning, match=r"cannot be read \(BadZipFile.*\); recomputing unit 'exp=000/window=001'"):
        report = _run(out, resume=True)
    assert report.n_computed == 1
    same(report.results, full.results)


# -------------------------------------------------------------------------------------- unit values


def test_values_round_trip_exactly(tmp_path):
    value = {
        "f64": np.array([[0.1, -0.0], [np.nan, np.inf]]),
        "f32": np.float32([1.5, 2.25]),
        "i8": np.int8([-3, 4]),
        "bool": np.array([True, False]),
        "c": np.array([1 + 2j]),
        "s": np.array(["ab", "c"]),
        "zero_d": np.array(2.5),
        "empty": np.empty((0, 3)),
        "f_order": np.asfortranarray(np.arange(6.0).reshape(2, 3)),
        "np_scalars": [np.float64(0.1), np.int64(7), np.bool_(True), np.float32(3.5)],
        "py": [None, True, 3, 2**70, 0.1, -0.0, math.nan, math.inf, "ü/x"],
        "tuple": (1, (2.0, "x"), np.arange(2)),
        "nested": {"__nd__": "not an array", "k": {"x": []}},
        "nested_list": [[np.zeros(2)], {}],
    }
    tree, arrays = encode_value(value)
    same(decode_value(json.loads(json.dumps(tree)), arrays), value)
    with RunStore.open(tmp_path / "run", CONFIG) as store:
        back = store.save("u", value, seed=3)
        same(back, value)
        same(store.load("u", seed=3), value)
        meta = store.load_meta("u")
        assert meta["unit_id"] == "u" and meta["seed"] == 3
    for bad in ({1: 2}, np.array([object()], dtype=object), {1, 2}, Unit("x")):
        with pytest.raises(TypeError, match="cannot be stored|keys must be strings"):
            encode_value(bad)


# ------------------------------------------------------------------------------------------ failures

_FLAKY = {"fail": True}


def flaky(unit, rng):
    if unit.data and _FLAKY["fail"]:
        raise RuntimeError("solver diverged\nsecond line")
    return {"draw": rng.standard_normal(3)}


def test_failures_are_recorded_and_retried_only_if_asked(tmp_path):
    out = tmp_path / "run"
    units = [Unit(unit_id(exp=i), i in (1, 3)) for i in range(5)]
    first = _run(out, units=units, fn=flaky)
    assert list(first.failures) == ["exp=001", "exp=003"]
    assert first.failures["exp=001"].error == "RuntimeError: solver diverged"
    rec = json.loads((out / "units" / "exp=001.failed.json").read_text())
    assert rec["error"] == "RuntimeError: solver diverged" and "second line" in rec["traceback"]
    status = json.loads((out / "status.json").read_text())
    assert status["n_failed"] == 2 and status["failed"] == ["exp=001", "exp=003"] and status["n_done"] == 3

    _FLAKY["fail"] = False
    try:
        kept = _run(out, units=units, fn=flaky, resume=True)
        assert kept.n_computed == 0 and list(kept.failures) == ["exp=001", "exp=003"]
        assert kept.failures["exp=001"].from_checkpoint
        retried = _run(out, units=units, fn=flaky, resume=True, retry_failed=True)
    finally:
        _FLAKY["fail"] = True
    assert retried.ok and retried.n_computed == 2 and list(retried.results) == [u.unit_id for u in units]
    assert not list((out / "units").glob("*.failed.json"))
    _FLAKY["fail"] = False
    try:
        clean = _run(tmp_path / "clean", units=units, fn=flaky)
    finally:
        _FLAKY["fail"] = True
    same(retried.results, clean.results)


def test_unstorable_value_is_a_clear_error(tmp_path):
    with pytest.raises(TypeError, match="result.x: a unit result of type set cannot be stored"):
        _run(tmp_path / "run", units=[Unit("a")], fn=lambda unit, rng: {"x": {1}})


# ------------------------------------------------------------------------------------------ progress


class _Stream(io.StringIO):
    def __init__(self, tty):
        super().__init__()
        self._tty = tty

    def isatty(self):
        return self._tty


@pytest.mark.parametrize("tty", [True, False])
def test_progress_bar_only_on_a_terminal(monkeypatch, tty):
    stream = _Stream(tty)
    monkeypatch.setattr(driver_mod.sys, "stderr", stream)
    report = run_units(toy_units(3, steps=50), toy_bubble, seed=0)
    assert report.n_computed == 3
    out = stream.getvalue()
    assert ("3/3" in out) if tty else (out == "")
    forced = _Stream(False)
    monkeypatch.setattr(driver_mod.sys, "stderr", forced)
    run_units(toy_units(2, steps=50), toy_bubble, seed=0, progress=True, desc="windows")
    assert "windows" in forced.getvalue() and "2/2" in forced.getvalue()


def test_progress_callback():
    calls = []
    run_units(toy_units(3, steps=50), toy_bubble, seed=0, progress=lambda done, total: calls.append((done, total)))
    assert calls == [(1, 3), (2, 3), (3, 3)]


# ------------------------------------------------------------------------------------------- signals


def _terminates_at_third(unit, rng):
    if unit.data in (2, 9):
        os.kill(os.getpid(), signal.SIGTERM)
    if unit.data == 2:
        time.sleep(5)  # the handler raises before this ends
    return {"x": rng.random()}


def test_sigterm_stops_the_run_cleanly_and_restores_handlers(tmp_path):
    units = [Unit(unit_id(exp=i), i) for i in range(5)]
    before = (signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT))
    with pytest.raises(RunInterrupted, match="SIGTERM") as err:
        _run(tmp_path / "run", units=units, fn=_terminates_at_third)
    assert err.value.signum == signal.SIGTERM and isinstance(err.value, KeyboardInterrupt)
    assert (signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)) == before
    status = json.loads((tmp_path / "run" / "status.json").read_text())
    assert status["interrupted"] and status["n_done"] == 2 and not status["complete"]
    # someone else's handler is respected
    seen = []
    old = signal.signal(signal.SIGTERM, lambda s, f: seen.append(s))
    try:
        report = run_units([Unit("x", 9)], _terminates_at_third, seed=0, progress=False)
    finally:
        signal.signal(signal.SIGTERM, old)
    assert seen == [signal.SIGTERM] and report.ok


# ------------------------------------------------------------------------------ killed outright
_KILLED_CHILD = """
import os, signal, sys
from imrbayes.execution import RunStore, Unit, run_units
from imrbayes.execution.toy import toy_bubble
store = RunStore.open(sys.argv[1], {"seed": 0, "workload": "killed"})
run_units([Unit("exp=000", 0)], lambda u, rng: {"x": 1.0}, seed=0, store=store, progress=False)
os.kill(os.getpid(), signal.SIGKILL)
"""


def test_a_run_killed_with_sigkill_reads_as_interrupted_and_resume_says_so(tmp_path):
    import subprocess
    import sys

    from imrbayes.execution.store import read_status

    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-c", _KILLED_CHILD, str(out)], capture_output=True, text=True)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    raw = json.loads((out / "status.json").read_text())
    assert raw["running"] and not raw["complete"]  # what the killed process left: never "complete"
    status = read_status(out)
    assert status["interrupted"] and not status["complete"] and not status["running"]
    with RunStore.open(out, {"seed": 0, "workload": "killed"}, resume=True) as store:
        assert store.previous_interrupted["interrupted"] and store.previous_interrupted["n_done"] == 1
    with RunStore.open(out, {"seed": 0, "workload": "killed"}, resume=True) as store:
        assert store.previous_interrupted is None  # the resumed run closed normally


def test_status_is_complete_only_after_the_run_closes(tmp_path):
    with RunStore.open(tmp_path / "run", CONFIG) as store:
        run_units(UNITS, toy_bubble, seed=0, store=store, progress=False)
        mid = json.loads((tmp_path / "run" / "status.json").read_text())
        assert not mid["complete"] and mid["running"] and mid["owner"]["pid"] == os.getpid()
    end = json.loads((tmp_path / "run" / "status.json").read_text())
    assert end["complete"] and not end["running"] and not end["interrupted"]


# Never lose work: a run in a subprocess (``python -m imrbayes.execution.toy`` with slow units) is
# killed part-way with SIGTERM or SIGKILL, then resumed. Every unit finished before the kill is kept
# untouched (same bytes, same mtime: not recomputed), no worker process outlives the run, and the final
# results equal an uninterrupted run's.


N_UNITS, STEPS, SLEEP, SEED = 12, 300, 0.25, 5
RESUME_CONFIG = {"workload": "toy_bubble", "units": N_UNITS, "windows": 1, "steps": STEPS, "fail": [], "seed": SEED}

posix_only = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")


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
    with RunStore.open(out, RESUME_CONFIG) as store:
        return run_units(units, toy_bubble, seed=SEED, store=store, progress=False).results


# One kill in the default tier; the other signals and backends in the slow tier.
@posix_only
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
    with RunStore.open(out, RESUME_CONFIG, resume=True) as store:
        final = run_units(toy_units(N_UNITS, steps=STEPS), toy_bubble, seed=SEED, store=store, progress=False)
    assert final.n_resumed == N_UNITS
    same(final.results, uninterrupted)


@posix_only
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


@posix_only
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


@posix_only
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
