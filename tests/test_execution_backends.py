"""Execution backends, and the execution units of ``imrbayes diagnose`` and ``imrbayes validate``."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from _exec_helpers import same
from click.testing import CliRunner

from imrbayes.cli import main
from imrbayes.errors import InputError
from imrbayes.execution import (
    DaskExecutor,
    InProcessExecutor,
    ProcessPoolExecutor,
    Unit,
    make_executor,
    normalize_units,
    run_units,
    safe_name,
    unit_id,
    unit_rng,
)
from imrbayes.execution.toy import toy_bubble, toy_units

# Execution backends: one interface, bit-identical results whatever the backend or worker count,
# contained failures, clean shutdown; seeding from (run seed, unit id) that no process salt changes.


SEED = 11
UNITS = toy_units(6, windows=2, steps=600)


@pytest.fixture(scope="module")
def dask_local():
    """One LocalCluster (2 workers x 1 thread) for the whole module: start-up takes seconds."""
    ex = DaskExecutor("local", n_workers=2, threads_per_worker=1)
    yield ex
    ex.close()


@pytest.fixture(scope="module")
def reference():
    return run_units(UNITS, toy_bubble, seed=SEED, progress=False)


# ----------------------------------------------------------------------------------------- seeding


def test_unit_rng_is_fixed_by_seed_and_id():
    # Golden values: changing them breaks the resumability of stored runs (bump SEEDING_SCHEME).
    assert unit_rng(0, "exp=000/window=000").integers(0, 2**32, size=3).tolist() == [1982966354, 1607394214, 2444372978]
    assert unit_rng(7, "exp=003/window=07").integers(0, 2**32, size=3).tolist() == [3994474509, 1936201145, 1469914999]
    a = unit_rng(1, "exp=001").random(4)
    assert np.array_equal(a, unit_rng(1, "exp=001").random(4))
    assert not np.array_equal(a, unit_rng(2, "exp=001").random(4))
    assert not np.array_equal(a, unit_rng(1, "exp=002").random(4))


def _first_draw(unit, rng):
    return float(rng.random())


@pytest.mark.parametrize("workers", [1, 2])
def test_a_units_stream_key_seeds_it_instead_of_its_id(workers):
    """Units whose ids differ but whose ``stream`` keys agree draw the same numbers (in any backend);
    without a stream key the id seeds the unit; dict units may set ``"stream"`` too."""
    units = [
        Unit("noise=aaaa/exp=000", stream="exp=000"),
        Unit("noise=bbbb/exp=000", stream="exp=000"),
        {"unit_id": "noise=cccc/exp=000", "stream": "exp=000"},
        Unit("exp=000"),
        Unit("noise=aaaa/exp=001"),
    ]
    ex = InProcessExecutor() if workers == 1 else ProcessPoolExecutor(workers)
    try:
        rep = run_units(units, _first_draw, seed=SEED, executor=ex, progress=False)
    finally:
        ex.close()
    r = rep.results
    ref = unit_rng(SEED, "exp=000").random()
    assert r["noise=aaaa/exp=000"] == r["noise=bbbb/exp=000"] == r["noise=cccc/exp=000"] == r["exp=000"] == ref
    assert r["noise=aaaa/exp=001"] == unit_rng(SEED, "noise=aaaa/exp=001").random() != ref
    bad = run_units([Unit("exp=002", stream="")], _first_draw, seed=SEED, progress=False)
    assert "non-empty string" in bad.failures["exp=002"].error


def test_unit_rng_ignores_python_hash_salt():
    code = "from imrbayes.execution import unit_rng; print(unit_rng(5, 'exp=004/window=02').random().hex())"
    outs = set()
    for salt in ("1", "2", "random"):
        env = {**os.environ, "PYTHONHASHSEED": salt}
        outs.add(
            subprocess.run(
                [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
            ).stdout.strip()
        )
    assert outs == {unit_rng(5, "exp=004/window=02").random().hex()}


def test_unit_ids_and_safe_names():
    assert unit_id(exp=3, window=7) == "exp=003/window=007"
    assert unit_id(exp=3, model="nhkv") == "exp=003/model=nhkv"
    ids = [
        "exp=003/window=07",
        "exp=003%2Fwindow=07",
        "a b",
        "a~b",
        "ü",
        ".",
        "..",
        "x" * 300,
        "x" * 301,
        "model=NHKV",
        "model=nhkv",
        "%41",
        "A",
    ]
    names = [safe_name(i) for i in ids]
    assert len({n.lower() for n in names}) == len(ids)  # distinct even on case-insensitive file systems
    assert safe_name("model=NHKV") == "model=%4E%48%4B%56"
    assert safe_name("exp=003/window=07") == "exp=003%2Fwindow=07"
    assert all("/" not in n and len(n) <= 120 for n in names)
    with pytest.raises(ValueError, match="duplicate"):
        normalize_units([Unit("a"), {"unit_id": "a"}])
    with pytest.raises(ValueError, match="unit_id"):
        normalize_units([{"data": 1}])
    with pytest.raises(ValueError, match="non-negative"):
        unit_rng(-1, "a")


# ------------------------------------------------------------------------------- bit-identical runs


def test_in_process_results_are_in_input_order(reference):
    assert list(reference.results) == [u.unit_id for u in UNITS]
    assert reference.n_computed == len(UNITS) and reference.ok


@pytest.mark.parametrize("workers", [2, 3])
def test_process_pool_is_bit_identical(reference, workers):
    with make_executor(workers=workers) as ex:
        assert isinstance(ex, ProcessPoolExecutor) and ex.n_workers == workers
        report = run_units(UNITS, toy_bubble, seed=SEED, executor=ex, progress=False)
        pids = {o.worker.rsplit(":", 1)[1] for o in ex.map(toy_bubble, UNITS, seed=SEED)}
    same(report.results, reference.results)
    assert str(os.getpid()) not in pids and 1 <= len(pids) <= workers
    assert set(report.unit_seconds) == {u.unit_id for u in UNITS}


def test_local_dask_cluster_is_bit_identical(reference, dask_local):
    assert dask_local.n_workers == 2 and dask_local.describe()["backend"] == "dask"
    report = run_units(UNITS, toy_bubble, seed=SEED, executor=dask_local, progress=False)
    same(report.results, reference.results)
    # the same executor serves a second map (e.g. the next window), in a shuffled order
    again = run_units(UNITS[::-1], toy_bubble, seed=SEED, executor=dask_local, progress=False)
    same(dict(reversed(list(again.results.items()))), reference.results)


def test_seed_changes_results(reference):
    other = run_units(UNITS[:2], toy_bubble, seed=SEED + 1, progress=False)
    assert not np.array_equal(other.results[UNITS[0].unit_id]["draws"], reference.results[UNITS[0].unit_id]["draws"])


# ------------------------------------------------------------------------------------------ failures


def _with_failures():
    units = toy_units(5, steps=200, fail={"exp=001/window=000", "exp=003/window=000"})
    return units, {"exp=001/window=000", "exp=003/window=000"}


@pytest.mark.parametrize("backend", ["in-process", "pool", "dask"])
def test_failures_are_contained(backend, dask_local):
    units, bad = _with_failures()
    if backend == "in-process":
        ex = InProcessExecutor()
    elif backend == "pool":
        ex = ProcessPoolExecutor(2)
    else:
        ex = dask_local
    try:
        report = run_units(units, toy_bubble, seed=0, executor=ex, progress=False)
    finally:
        if ex is not dask_local:
            ex.close()
    assert set(report.failures) == bad and report.n_failed == 2 and not report.ok
    assert set(report.results) == {u.unit_id for u in units} - bad
    fail = report.failures["exp=001/window=000"]
    assert fail.error == "ValueError: toy failure in exp=001/window=000"
    assert "Traceback" in fail.traceback and fail.worker
    assert "5 units: 5 computed, 0 from checkpoints, 2 failed (exp=001/window=000: ValueError" in report.summary()
    with pytest.raises(RuntimeError, match="2 failed"):
        report.raise_if_failed()


def test_pool_survives_an_early_stop_and_is_reused():
    with ProcessPoolExecutor(2) as ex:
        units = toy_units(8, steps=200, sleep=0.05)
        it = ex.map(toy_bubble, units, seed=0)
        first = next(it)
        it.close()  # abandons the rest: the pool is stopped and restarted on the next map
        assert first.ok
        outs = list(ex.map(toy_bubble, units, seed=0))
    assert sorted(o.unit_id for o in outs) == sorted(u.unit_id for u in units)


# --------------------------------------------------------------------------------------- the factory


def test_make_executor_choices():
    assert isinstance(make_executor(), InProcessExecutor)
    assert isinstance(make_executor(workers=1), InProcessExecutor)
    with make_executor(workers=2) as ex:
        assert isinstance(ex, ProcessPoolExecutor)
    for bad in (0, -1, "2", 1.5, True):
        with pytest.raises(InputError, match="--workers"):
            make_executor(workers=bad)
    with pytest.raises(InputError, match="--scheduler"):
        make_executor(scheduler="  ")


def test_unreachable_scheduler_is_an_input_error():
    with pytest.raises(InputError, match="cannot connect to a Dask scheduler at 'tcp://127.0.0.1:9'"):
        DaskExecutor("tcp://127.0.0.1:9", connect_timeout=0.5)


def test_dask_executor_on_an_existing_client(dask_local, reference):
    ex = DaskExecutor(client=dask_local.client)
    report = run_units(UNITS[:3], toy_bubble, seed=SEED, executor=ex, progress=False)
    ex.close()  # does not close a client it was given
    assert dask_local.client.status == "running"
    same(report.results, {k: reference.results[k] for k in report.results})


def test_scheduler_address_connects_to_a_running_cluster(dask_local, reference):
    address = dask_local.client.scheduler.address  # what `dask scheduler` would print
    with make_executor(scheduler=address, workers=7) as ex:  # workers is ignored for a remote cluster
        assert isinstance(ex, DaskExecutor) and ex.describe()["address"] == address and ex.n_workers == 2
        report = run_units(UNITS, toy_bubble, seed=SEED, executor=ex, progress=False)
    same(report.results, reference.results)
    assert dask_local.client.status == "running"  # closing our client leaves the cluster up


def test_dask_gather_exits_after_an_interruption_print_nothing_other_loop_errors_do(caplog):
    """SIGTERM during ``future.result()`` leaves distributed's gather waiters ending in ``AllExit``
    that nobody awaits; asyncio printed their traceback (the 'never a traceback' rule). The loop's
    handler drops exactly those and passes every other exception on."""
    import asyncio
    import logging
    from types import SimpleNamespace

    from distributed.client import AllExit

    from imrbayes.execution.backends import _quiet_gather_exits

    loop = asyncio.new_event_loop()
    try:
        _quiet_gather_exits(SimpleNamespace(loop=SimpleNamespace(asyncio_loop=loop)))

        def printed():  # other tests' clients may still log through distributed's loggers
            return [r for r in caplog.records if r.name == "asyncio" and r.levelno >= logging.ERROR]

        with caplog.at_level(logging.ERROR, logger="asyncio"):
            loop.call_exception_handler({"message": "Task exception was never retrieved", "exception": AllExit()})
            assert printed() == []
            loop.call_exception_handler(
                {"message": "Task exception was never retrieved", "exception": ValueError("a real error")}
            )
        assert len(printed()) == 1 and "a real error" in printed()[0].getMessage() + str(printed()[0].exc_info)
    finally:
        loop.close()


# ``imrbayes diagnose`` (units: candidate fits, held-out fits) and ``imrbayes validate`` (units:
# cases) on the execution layer: same numbers after a resume on a process pool, refusals, run.json.


def _strip(obj, drop=("runtime_s", "total_runtime_s", "stage_seconds", "command", "execution", "figures")):
    """The computed numbers only (timings, paths and execution counts removed), recursively."""
    if isinstance(obj, dict):
        return {k: _strip(v, drop) for k, v in obj.items() if k not in drop}
    if isinstance(obj, list):
        return [_strip(v, drop) for v in obj]
    return obj


def _assert_same(a, b, path="", rtol=1e-4, atol=1e-9):
    """Same keys, strings and decisions exactly; floats to ``rtol`` (round-off grown through fits:
    the same diagnose compiled for another CPU moves its numbers by up to ~1.4e-6 relative, and CI
    has seen a run and its resume on worker processes differ at that level)."""
    if isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for k in a:
            _assert_same(a[k], b[k], f"{path}/{k}", rtol, atol)
    elif isinstance(a, list):
        assert len(a) == len(b), path
        for i, (u, v) in enumerate(zip(a, b)):
            _assert_same(u, v, f"{path}[{i}]", rtol, atol)
    elif isinstance(a, float) and isinstance(b, float):
        assert a == pytest.approx(b, rel=rtol, abs=atol, nan_ok=True), (path, a, b)
    else:
        assert a == b, (path, a, b)


def _run(*args, expect=0):
    res = CliRunner().invoke(main, [str(a) for a in args])
    assert res.exit_code == expect, res.output
    return res


@pytest.fixture(scope="module")
def gel(tmp_path_factory):
    d = tmp_path_factory.mktemp("gel") / "data"
    _run(
        "simulate",
        "--model",
        "nhkv",
        "--param",
        "G=6e3",
        "--param",
        "mu=0.08",
        "--rmax",
        "300e-6:20e-6",
        "--ratio",
        "7.5:0.3",
        "--n-exp",
        "3",
        "--noise",
        "paper",
        "--seed",
        "1",
        "--forward",
        "bubble=polytropic",
        "--out",
        d,
        "--quiet",
    )
    return d


@pytest.mark.slow
def test_diagnose_resume_on_two_processes_gives_the_same_diagnosis(gel, tmp_path):
    out = tmp_path / "run"
    args = [
        "diagnose",
        gel,
        "--out",
        out,
        "--quick",
        "--n-bootstrap",
        "2",
        "--candidates",
        "qkv",
        "--no-loeo",
        "--forward",
        "bubble=polytropic",
        "--quiet",
    ]
    _run(*args)
    ref = json.loads((out / "diagnosis.json").read_text())
    # the baseline fits, 2 bootstrap, 1 candidate, 2 held-out
    assert ref["execution"]["n_units"] == 6 and ref["failed_units"] == []
    assert json.loads((out / "run.json").read_text())["config"]["command"] == "diagnose"
    (out / "units" / "candidate=qkv.npz").unlink()  # as if killed before they finished
    (out / "units" / "bootstrap=001.npz").unlink()
    _run(*args, "--resume", "--workers", "2")
    again = json.loads((out / "diagnosis.json").read_text())
    assert (again["execution"]["n_computed"], again["execution"]["n_resumed"]) == (2, 4)
    _assert_same(_strip(again), _strip(ref))
    res = _run(*args[:-1], "--resume", "--seed", "3", expect=2)  # another configuration: refused
    assert "cannot resume" in res.output and len(res.output.strip().splitlines()) == 1


@pytest.mark.slow
def test_validate_cases_are_units(tmp_path):
    cases = ["--case", "fusion-linear-gaussian", "--case", "pimr-collapse-time"]
    _run("validate", *cases, "--out", tmp_path / "a", "--quiet")
    res = _run("validate", *cases, "--out", tmp_path / "b", "--workers", "2")
    assert "2 cases: 2 computed, 0 from checkpoints, 0 failed" in res.output
    a = json.loads((tmp_path / "a" / "validation.json").read_text())
    b = json.loads((tmp_path / "b" / "validation.json").read_text())
    assert _strip(a) == _strip(b) and a["passed"]
    res = _run("validate", *cases, "--out", tmp_path / "a", "--resume")
    assert "0 computed, 2 from checkpoints" in res.output
    res = _run("validate", "--case", "imr-recovery", "--out", tmp_path / "a", "--resume", expect=2)
    assert "cannot resume" in res.output


def test_validate_crashing_case_is_a_failed_unit_that_retry_failed_reruns(tmp_path, monkeypatch):
    """A case that raises is a failed unit (recorded as failed, not checkpointed as done): a plain
    --resume reports it again without rerunning it, --resume --retry-failed reruns it. The user
    still sees a FAIL row with the error, and validation.json holds it."""
    from imrbayes.validation import suite

    calls = []

    def flaky(name, fm, out, seed):
        calls.append(name)
        if len(calls) == 1:
            raise RuntimeError("boom")
        return {"passed": True, "criteria": "ran again", "metrics": {}, "figures": []}

    monkeypatch.setitem(suite.CASES, "flaky", flaky)
    out = tmp_path / "v"
    res = _run("validate", "--case", "flaky", "--out", out, expect=1)
    assert "FAIL  flaky" in res.output and "RuntimeError: boom" in res.output
    assert "1 cases: 1 computed, 0 from checkpoints, 1 failed" in res.output
    row = json.loads((out / "validation.json").read_text())["cases"][0]
    assert (row["name"], row["passed"], row["error"]) == ("flaky", False, "RuntimeError: boom")
    assert not (out / "units" / "case=flaky.npz").exists()
    res = _run("validate", "--case", "flaky", "--out", out, "--resume", expect=1)  # reported again, not rerun
    assert len(calls) == 1 and "RuntimeError: boom" in res.output
    res = _run("validate", "--case", "flaky", "--out", out, "--resume", "--retry-failed")
    assert len(calls) == 2 and "PASS  flaky" in res.output
    assert "1 cases: 1 computed, 0 from checkpoints, 0 failed" in res.output
    assert json.loads((out / "validation.json").read_text())["passed"]
