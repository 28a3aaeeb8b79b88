"""The maintained validation suite (``python -m validation NAME``): its registry, its help, and one
tiny real run of the calibration claim end to end (simulate, fit, checkpoint, table, resume)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CLAIMS = ("calibration", "confusion", "realdata", "mcmc", "peers", "range")


def _run(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run(
        [sys.executable, "-m", "validation", *args], cwd=ROOT, env=env, capture_output=True, text=True, timeout=600
    )


def test_registry_lists_every_claim_with_a_module():
    res = _run("--help")
    assert res.returncode == 0, res.stderr
    for name in CLAIMS:
        assert f"  {name} " in res.stdout
        assert (ROOT / "validation" / f"{name}.py").is_file()


def test_unknown_claim_is_one_line_and_status_2():
    res = _run("nosuch")
    assert res.returncode == 2
    assert res.stderr.strip().count("\n") == 0 and "nosuch" in res.stderr


@pytest.mark.parametrize("name", CLAIMS)
def test_claim_help_names_the_common_options(name):
    res = _run(name, "--help")
    assert res.returncode == 0, res.stderr
    for option in ("--quick", "--resume", "--out"):
        assert option in res.stdout


def test_calibration_one_seed_end_to_end(tmp_path):
    out = tmp_path / "cal"
    res = _run("calibration", "--quick", "--seeds", "1", "--families", "verification", "--out", str(out))
    assert res.returncode == 0, res.stderr
    case = json.loads((out / "cases" / "verification_en4dvar_polytropic_seed100.json").read_text())
    assert case["status"] == "ok"
    truth = json.loads((out / "work" / case["case"] / "data" / "truth.json").read_text())
    table = json.loads((out / "coverage.json").read_text())
    assert (out / "coverage.md").read_text().startswith("# Coverage") and (out / "coverage.png").stat().st_size > 0
    z2 = 1.959964**2
    for row in table["rows"]:
        name = row["parameter"]
        true = truth["parameters"][name]  # what simulate drew the data with
        assert row["truth"] == pytest.approx(true)
        lo, hi = case["estimate"][name]["hdi95"]
        hit = int(lo <= true <= hi)
        assert row["coverage"] == hit
        # Wilson's interval of 1 or 0 successes in 1 trial: [1/(1+z^2), 1] or [0, z^2/(1+z^2)]
        assert row["wilson95"] == pytest.approx([1 / (1 + z2), 1.0] if hit else [0.0, z2 / (1 + z2)], abs=1e-6)
        assert row["mean_rel_error"] == pytest.approx(case["estimate"][name]["mean"] / true - 1)
    again = _run("calibration", "--quick", "--seeds", "1", "--families", "verification", "--out", str(out), "--resume")
    assert again.returncode == 0, again.stderr
    assert "done before" in again.stdout
    assert json.loads((out / "coverage.json").read_text())["rows"] == table["rows"]
