"""scripts/diagnosis_confusion.py: the summary's arithmetic on hand-made run files (no diagnosis run)."""

import json
import re
from pathlib import Path

import pytest
from scipy.stats import binomtest



@pytest.fixture(scope="module")
def conf(confusion_script):
    return confusion_script


def _write(folder: Path, name: str, **row):
    folder.mkdir(parents=True, exist_ok=True)
    base = {"kind": "class", "seed": 0, "design": "1Mfps-2um-5", "forward": {}, "status": "ok", "runtime_s": 1.0}
    (folder / f"{name}.json").write_text(json.dumps({**base, **row}))


@pytest.fixture
def out(tmp_path):
    runs, nulls = tmp_path / "runs", tmp_path / "nulls"
    ss = "strain-stiffening"
    _write(runs, "a", **{"class": ss, "cause": ss})
    _write(runs, "b", **{"class": ss, "cause": "ambiguous", "candidates_tied": ["qkv", "zener"]})      # keys
    _write(runs, "c", **{"class": ss, "cause": "ambiguous",
                         "candidates_tied": ["viscoelastic-relaxation", "rate-dependent-viscosity"]})
    _write(runs, "d", **{"class": ss, "cause": "none"})
    _write(runs, "e", **{"class": "bubble-thermal", "cause": "bubble-thermal"})
    _write(runs, "f", **{"class": "bubble-thermal", "cause": "none"})
    for i, c in enumerate(["none", "none", "damage-softening"]):
        _write(runs, f"n{i}", **{"class": "none", "cause": c})
    _write(runs, "err", **{"class": "none", "cause": "error", "status": "error", "error": "RuntimeError: boom"})
    for i, v in enumerate(["adequate", "inadequate", "adequate", "adequate", "inadequate"]):
        _write(nulls, f"null{i}", **{"kind": "null", "class": "none", "seed": 900000 + i, "verdict": v,
                                     "design": ["A", "B"][i % 2], "cause": "none" if v == "adequate" else "unexplained"})
    return tmp_path


def test_wilson_matches_scipy(conf):
    for k, n in [(0, 5), (2, 5), (5, 5), (7, 20), (1, 1)]:
        ci = binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
        assert conf.wilson(k, n) == pytest.approx((ci.low, ci.high), abs=1e-12)
    lo, hi = conf.wilson(1.5, 4)                    # half credits: between the neighbours' intervals
    assert conf.wilson(1, 4)[0] < lo < conf.wilson(2, 4)[0] and conf.wilson(1, 4)[1] < hi < conf.wilson(2, 4)[1]


def test_half_credit_only_when_the_truth_is_tied(conf):
    assert conf.expected_cause("bubble-thermal") == "bubble-thermal"        # a cause diagnose can name
    assert conf.expected_cause("bubble-thermal", mechanisms=("none", "strain-stiffening")) == "unexplained"
    assert conf.expected_cause("strain-stiffening") == "strain-stiffening"
    row = {"class": "strain-stiffening", "cause": "ambiguous"}
    assert conf.score({**row, "candidates_tied": ["qkv", "carreau"]}) == 0.5
    assert conf.score({**row, "candidates_tied": ["strain-stiffening", "damage-softening"]}) == 0.5
    assert conf.score({**row, "candidates_tied": ["zener", "carreau"]}) == 0.0
    assert conf.score({**row, "candidates_tied": None}) == 0.0
    assert conf.score({"class": "none", "cause": "none"}) == 1.0


def test_summary(conf, out):
    s = conf.write_summary(out, "diagnosis_confusion.py --out X")
    pc = s["per_class"]
    assert pc["strain-stiffening"]["n"] == 4 and pc["strain-stiffening"]["score"] == 1.5
    assert pc["strain-stiffening"]["n_half_credit"] == 1
    assert pc["strain-stiffening"]["wilson95"] == pytest.approx(list(conf.wilson(1.5, 4)))
    assert pc["bubble-thermal"]["hit_rate"] == 0.5 and pc["bubble-thermal"]["expected"] == "bubble-thermal"
    assert pc["none"]["n"] == 3 and pc["none"]["score"] == 2            # the error run is not counted
    m = s["matrix"]
    assert m["strain-stiffening"]["ambiguous"] == 2 and m["strain-stiffening"]["none"] == 1
    assert m["none"]["damage-softening"] == 1
    assert {"ambiguous", "unexplained"} <= set(s["found_columns"])
    n = s["nulls"]
    assert (n["n"], n["alarms"], n["false_alarm_rate"]) == (5, 2, 0.4)
    ci = binomtest(2, 5).proportion_ci(method="wilson")
    assert n["wilson95"] == pytest.approx([ci.low, ci.high])
    assert n["by_design"] == {"A": {"n": 3, "alarms": 1}, "B": {"n": 2, "alarms": 1}}
    assert s["errors"] == [{"class": "none", "seed": 0, "error": "RuntimeError: boom"}]
    md = (out / "summary.md").read_text()
    assert "diagnosis_confusion.py --out X" in md and "2/5 = 0.40" in md and "1.5/4 = 0.38" in md
    assert json.loads((out / "summary.json").read_text())["nulls"]["alarms"] == 2


def test_summarize_only_and_resume(conf, out, capsys):
    conf.main(["--out", str(out), "--summarize-only"])
    assert "False alarms" in capsys.readouterr().out
    assert (out / "summary.md").exists()
    assert conf._finished(str(out / "runs" / "a.json")) and not conf._finished(str(out / "runs" / "err.json"))
    assert not conf._finished(str(out / "runs" / "missing.json"))


def test_jobs(conf, tmp_path):
    import argparse

    a = argparse.Namespace(out=tmp_path, forward=["bubble=polytropic"], quick=True, loeo=False, n_bootstrap=None,
                           seeds=2, seed_offset=0, design="1Mfps-2um-5", nulls=7)
    designs = ["A", "B", "C"]
    jobs = conf.jobs_for(a, ["none", "bubble-thermal"], designs)
    cls = [j for j in jobs if j["kind"] == "class"]
    nul = [j for j in jobs if j["kind"] == "null"]
    k = conf._classes().index("bubble-thermal")
    assert [j["seed"] for j in cls] == [0, 1, 1000 * k, 1000 * k + 1]
    assert [j["design"] for j in nul] == ["A", "B", "C", "A", "B", "C", "A"]
    assert len({j["path"] for j in jobs}) == len(jobs) and cls[0]["forward"] == {"bubble": "polytropic"}


def _check_row(observed, boot, verdict, cause):
    stats = {k: {"observed": o, "bootstrap": b} for k, o, b in zip(("drift", "misfit", "phase_misfit"), observed, boot)}
    return {"kind": "null", "class": "none", "seed": 1, "design": "1Mfps-2um-5", "status": "ok", "verdict": verdict,
            "cause": cause, "candidates_tied": ["zener", "damage"], "p_value": 0.05,
            "result": {"constant_parameter_check": {"evidence": {"alpha": 0.05, "statistics": stats}}}}


def test_rescore_recomputes_the_verdict_from_the_stored_replicates(conf, tmp_path):
    """A null that topped one statistic of three (the first combination's false alarm) is adequate
    under the pooled combination, cause none; one above every replicate on all three stays inadequate;
    one that would turn inadequate is left for a rerun."""
    boot = [[float(i) for i in range(19)]] * 3
    one_high = conf.rescore_row(_check_row([100.0, 9.5, 9.5], boot, "inadequate", "ambiguous"))
    assert one_high["verdict"] == "adequate" and one_high["cause"] == "none" and one_high["candidates_tied"] == []
    assert one_high["rescored"]["cause_before"] == "ambiguous" and one_high["p_value"] > 0.05
    all_high = conf.rescore_row(_check_row([100.0, 100.0, 100.0], boot, "inadequate", "damage-softening"))
    assert all_high["verdict"] == "inadequate" and all_high["cause"] == "damage-softening"
    assert all_high["p_value"] == pytest.approx(1 / 20)
    flipped = conf.rescore_row(_check_row([100.0, 100.0, 100.0], boot, "adequate", "none"))
    assert flipped["status"] == "error" and "rerun" in flipped["error"]
    early = _check_row([0.5, 1e4, 1e4], [b[:10] for b in boot], "inadequate", "damage-softening")
    early["p_value"] = 3e-8
    early["result"]["constant_parameter_check"]["evidence"]["p_value_kind"] = "bound"
    kept = conf.rescore_row(early)                      # decided early by a bound: ten ranks would say 1/11
    assert kept["verdict"] == "inadequate" and kept["p_value"] == 3e-8 and "kept" in kept["rescored"]["rule"]
    src = tmp_path / "old"
    (src / "nulls").mkdir(parents=True)
    (src / "nulls" / "null__000.json").write_text(json.dumps(_check_row([100.0, 9.5, 9.5], boot, "inadequate", "x")))
    assert conf.rescore(src, tmp_path / "new") == 1
    assert json.loads((tmp_path / "new" / "nulls" / "null__000.json").read_text())["verdict"] == "adequate"


def test_resume_from_an_export_skips_its_runs_and_refuses_other_settings(conf, tmp_path, capsys):
    """Rows committed by --export (another session's run) seed a new OUT: the jobs they cover count as
    finished, the summary holds them, a second export keeps them intact; an export made with other
    settings is refused with a one-line error."""
    import argparse

    first = tmp_path / "first"
    ss = "strain-stiffening"
    k = conf._classes().index(ss)
    stats = {"misfit": {"observed": 3.0, "bootstrap": [1.0, 2.0], "p_value": 0.3}}
    result = {"constant_parameter_check": {"verdict": "adequate", "evidence": {"statistics": stats}}}
    _write(first / "runs", f"{ss}__s{1000 * k}", **{"class": ss, "seed": 1000 * k, "cause": ss, "verdict": "inadequate",
                                                 "result": result})
    _write(first / "runs", "none__s0", **{"class": "none", "cause": "error", "status": "error", "error": "boom"})
    _write(first / "nulls", "null__002__C", **{"kind": "null", "class": "none", "seed": conf.NULL_SEED + 2,
                                              "design": "C", "verdict": "adequate", "cause": "none", "result": result})
    cmd = "diagnosis_confusion.py --seeds 1 --nulls 3 --forward bubble=polytropic --out first"
    conf.export(first, tmp_path / "exp", cmd, "abc1234")

    new = tmp_path / "new"
    conf.main(["--out", str(new), "--summarize-only", "--forward", "bubble=polytropic",
               "--resume-from", str(tmp_path / "exp")])
    assert "2 rows taken" in capsys.readouterr().out           # the errored run is not carried over
    a = argparse.Namespace(out=new, forward=["bubble=polytropic"], quick=False, loeo=True, n_bootstrap=None,
                           seeds=1, seed_offset=0, design="1Mfps-2um-5", nulls=3)
    jobs = conf.jobs_for(a, ["none", ss], ["A", "B", "C"])
    done = {(j["class"], j["seed"]) for j in jobs if conf._finished(j["path"])}
    assert done == {(ss, 1000 * k), ("none", conf.NULL_SEED + 2)}
    s = json.loads((new / "summary.json").read_text())
    assert s["per_class"][ss]["score"] == 1 and s["nulls"]["n"] == 1 and s["nulls"]["alarms"] == 0
    conf.export(new, tmp_path / "again", cmd, "abc1234")
    again = json.loads((tmp_path / "again_classes.json").read_text())["rows"]
    assert again[0]["statistics"]["misfit"]["bootstrap"] == [1.0, 2.0] and again[0]["resumed_from"]["code"] == "abc1234"

    for prefix, msg in (("exp", r"exp_classes\.json: strain-stiffening seed \d+ was made with other settings.*forward"),
                        ("nope", "neither")):
        with pytest.raises(SystemExit) as ex:
            conf.main(["--out", str(tmp_path / "other"), "--summarize-only", "--resume-from", str(tmp_path / prefix)])
        err = capsys.readouterr().err
        assert ex.value.code == 2 and len(err.strip().splitlines()) == 1 and re.search(msg, err), err


def test_resume_checks_each_rows_own_settings(conf, tmp_path, capsys):
    """A row that records its own settings is judged by them, not by the exporting command (a
    summary exported mid-run records the summarize command)."""
    first = tmp_path / "first"
    mine = {"quick": False, "loeo": True, "n_bootstrap": None, "mienks_drift": None}
    _write(first / "runs", "none__s0", **{"class": "none", "cause": "none", "verdict": "adequate",
                                         "forward": {"bubble": "polytropic"}, "settings": mine})
    conf.export(first, tmp_path / "ok", "diagnosis_confusion.py --out first --summarize-only", "abc")
    conf.main(["--out", str(tmp_path / "a"), "--summarize-only", "--forward", "bubble=polytropic",
               "--resume-from", str(tmp_path / "ok")])
    assert conf._finished(str(tmp_path / "a" / "runs" / "none__s0.json"))
    _write(first / "runs", "none__s0", **{"class": "none", "cause": "none", "verdict": "adequate",
                                         "forward": {"bubble": "polytropic"}, "settings": {**mine, "quick": True}})
    conf.export(first, tmp_path / "bad", "diagnosis_confusion.py --out first --summarize-only", "abc")
    with pytest.raises(SystemExit) as ex:
        conf.main(["--out", str(tmp_path / "b"), "--summarize-only", "--forward", "bubble=polytropic",
                   "--resume-from", str(tmp_path / "bad")])
    assert ex.value.code == 2 and re.search(r"none seed 0 was made with other settings.*quick", capsys.readouterr().err)

