"""``imrbayes diagnose`` (units: candidate fits, held-out fits) and ``imrbayes validate`` (units:
cases) on the execution layer: same numbers after a resume on a process pool, refusals, run.json."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from imrbayes.cli import main


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
