"""validation/camera_calibration.py's summary on hand-made rows: coverage with its Wilson interval,
and MIEnKS-MDA's per-window coverage over seeds whose records hold different numbers of windows."""

import importlib.util
import math
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "validation" / "camera_calibration.py"


@pytest.fixture(scope="module")
def cal():
    spec = importlib.util.spec_from_file_location("camera_calibration", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _row(seed, covers_g, windows_g, mean_g=5200.0):
    est = lambda m, c: {"mean": m, "sd": 0.1 * m, "hdi95": [0.8 * m, 1.2 * m], "covers": c,  # noqa: E731
                        "rel_error": m / 5200.0 - 1}
    return {"seed": seed, "default": {"runtime_s": 1.0, "G": est(mean_g, covers_g), "mu": est(0.065, True),
                                      "windows": {"G": windows_g, "mu": [True] * len(windows_g)}}}


def test_wilson_interval_matches_the_closed_form(cal):
    lo, hi = cal.wilson(18, 20)
    # Wilson score interval of 18/20 at z = 1.96 (Agresti & Coull 1998): [0.699, 0.972]
    assert lo == pytest.approx(0.6990, abs=1e-3) and hi == pytest.approx(0.9721, abs=1e-3)
    assert cal.wilson(20, 20)[1] == pytest.approx(1.0)


def test_window_coverage_per_index_and_over_all(cal):
    rows = [_row(0, True, [True, True, False]), _row(1, False, [True, False, True, True]),
            _row(2, True, [False, True, True])]
    s = cal.summarise(rows, ["default"])["default"]
    assert s["G"]["coverage"] == pytest.approx(2 / 3)
    # per window index over the seeds, truncated to the fewest windows (3)
    assert s["G"]["window_coverage"] == pytest.approx([2 / 3, 2 / 3, 2 / 3])
    assert s["G"]["window_coverage_min"] == pytest.approx(2 / 3)
    # over every (seed, window) pair: 7 of 10
    assert s["G"]["window_coverage_all"] == pytest.approx(0.7)
    assert s["G"]["window_coverage_all_wilson95"] == pytest.approx(cal.wilson(7, 10))
    assert s["mu"]["window_coverage_all"] == pytest.approx(1.0)


def test_en4dvar_rows_have_no_window_entry(cal):
    rows = [_row(0, True, [])]
    del rows[0]["default"]["windows"]
    s = cal.summarise(rows, ["default"])["default"]
    assert "window_coverage" not in s["G"] and s["G"]["coverage"] == 1.0


def _file(tmp_path, name, rows, cal, settings=None):
    for r in rows:                       # En4D-Var rows: no windows
        r["default"].pop("windows", None)
    p = tmp_path / name
    cal._write(p, {"family": "camera", "bubble": "thermal", "method": "en4dvar", "settings": settings or {}},
               rows, [], ["default"])
    return p


def test_merge_unites_seed_ranges_run_apart(cal, tmp_path):
    a = _file(tmp_path, "a.json", [_row(0, True, []), _row(1, False, [])], cal)
    b = _file(tmp_path, "b.json", [_row(2, True, []), _row(1, False, [])], cal)   # seed 1 in both, the same
    out = tmp_path / "all.json"
    m = cal.merge([b, a], out)
    assert [r["seed"] for r in m["rows"]] == [0, 1, 2]
    import json
    d = json.loads(out.read_text())
    assert d["summary"]["default"]["G"]["coverage"] == pytest.approx(2 / 3)
    assert d["settings"] == {} and d["bubble"] == "thermal"


def test_merge_refuses_another_design_or_a_conflicting_seed(cal, tmp_path):
    a = _file(tmp_path, "a.json", [_row(0, True, [])], cal)
    other = _file(tmp_path, "o.json", [_row(1, True, [])], cal, settings={"bubble_posterior": "sampled"})
    with pytest.raises(SystemExit, match="another design"):
        cal.merge([a, other], None)
    clash = _file(tmp_path, "c.json", [_row(0, False, [])], cal)
    with pytest.raises(SystemExit, match="seed 0 differs"):
        cal.merge([a, clash], None)


def test_merge_names_a_file_that_is_not_a_result(cal, tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(SystemExit, match="bad.json: not a calibration result file"):
        cal.merge([bad], None)


def test_window_medians_separate_a_narrowing_log_normal_from_a_trend(cal):
    # windows whose medians sit at the truth while the log-normal mean exp(s^2/2) - 1 shrinks with
    # the window's log sd (0.45 -> 0.05): the means show a decline, the medians none
    sds = [0.45, 0.3, 0.15, 0.05, 0.05, 0.05]
    rows = []
    for seed in range(3):
        r = _row(seed, True, [True] * len(sds))
        r["default"]["window_rel_error"] = {n: [math.exp(s * s / 2) - 1 for s in sds] for n in ("G", "mu")}
        r["default"]["window_rel_error_median"] = {n: [0.0] * len(sds) for n in ("G", "mu")}
        rows.append(r)
    s = cal.summarise(rows, ["default"])["default"]["G"]
    first, last = sum(math.exp(x * x / 2) - 1 for x in sds[:2]) / 2, math.exp(0.05 ** 2 / 2) - 1
    assert s["early_minus_late"]["mean"] == pytest.approx(first - last)
    assert s["median_early_minus_late"]["mean"] == pytest.approx(0.0, abs=1e-15)
    assert s["window_median_rel_error_mean"] == pytest.approx([0.0] * len(sds))


def test_rows_record_the_code_version(cal):
    import re

    v = cal.code_version()
    assert v == "unknown" or re.fullmatch(r"[0-9a-f]{7,40}(\+dirty)?", v), v
