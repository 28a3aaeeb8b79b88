"""scripts/diagnosis_confusion.py: a row's diagnosis is checkpointed in its run folder, so an
interrupted row resumes from its finished units (the diagnosis itself is replaced by a stand-in
that runs two units; no physics)."""

import json
import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest



@pytest.fixture(scope="module")
def conf(confusion_script):
    return confusion_script


class Interrupted(BaseException):
    """Stands for a killed process: not an Exception, so nothing records it as the row's error."""


def _fake_obs(seed):
    rng = np.random.default_rng(seed)
    return SimpleNamespace(t_star=np.linspace(0, 3, 20)[None, :], R_star=rng.random((1, 20)), P=np.ones(1),
                           rmax_m=np.array([3e-4]), req_m=np.array([4e-5]), names=["exp01"])


@pytest.fixture
def stand_in(monkeypatch):
    """diagnose() replaced by two units through the given execution; ``state['interrupt']`` makes
    unit b raise Interrupted once. Returns the log of units actually computed."""
    import imrbayes.diagnosis as diag
    import imrbayes.diagnosis.synthetic as synth
    from imrbayes.execution import Unit

    state = {"computed": [], "interrupt": False}

    def unit_fn(unit, rng):
        if unit.unit_id == "b" and state["interrupt"]:
            state["interrupt"] = False
            raise Interrupted
        state["computed"].append(unit.unit_id)
        return {"value": float(rng.random())}

    def fake_diagnose(obs, options, settings=None, seed=0, execution=None):
        rep = execution.run([Unit("a"), Unit("b")], unit_fn, seed, desc="stand-in")
        values = {k: v["value"] for k, v in rep.results.items()}
        result = {"cause": "none", "candidates_tied": [], "gain": {}, "values": values,
                  "constant_parameter_check": {"verdict": "adequate", "evidence": {"p_value": 0.5}}}
        return SimpleNamespace(result=result)

    monkeypatch.setattr(diag, "diagnose", fake_diagnose)
    monkeypatch.setattr(synth, "camera_obs", lambda cls, seed, opts, design: (_fake_obs(seed), {"theta": {}}))
    return state


def _job(tmp_path, seed=7):
    return {"kind": "class", "class": "none", "seed": seed, "design": "1Mfps-2um-5", "forward": {},
            "quick": True, "loeo": False, "n_bootstrap": None, "mienks_drift": None, "stop_when_adequate": False,
            "path": str(tmp_path / "runs" / f"none__s{seed}.json")}


def test_an_interrupted_row_resumes_from_its_finished_units(conf, stand_in, tmp_path):
    job = _job(tmp_path)
    Path(job["path"]).parent.mkdir(parents=True)
    stand_in["interrupt"] = True
    with pytest.raises(Interrupted):
        conf.run_one(job)
    assert stand_in["computed"] == ["a"]
    assert not Path(job["path"]).exists()             # no row yet: the run was not finished
    row = conf.run_one(job)
    assert stand_in["computed"] == ["a", "b"]         # a came from the checkpoint, not computed again
    assert row["status"] == "ok" and row["checkpoint"]["sessions"] == 2
    assert re.fullmatch(r"[0-9a-f]{7,40}(\+dirty)?|unknown", row["code"])
    # the checkpointed value is the one a fresh, uninterrupted run computes (same seeds)
    fresh = conf.run_one(_job(tmp_path / "fresh"))
    assert fresh["result"]["values"] == row["result"]["values"]
    compact = conf.compact_row(json.loads(Path(job["path"]).read_text()))
    assert compact["code"] == row["code"] and compact["sessions"] == 2


def test_a_run_folder_of_other_data_is_set_aside(conf, stand_in, tmp_path, monkeypatch):
    job = _job(tmp_path)
    Path(job["path"]).parent.mkdir(parents=True)
    conf.run_one(job)
    folder = Path(job["path"]).with_suffix("")
    # the same folder name, but the data differ (as after a change of the generator): not reused
    stand_in["computed"].clear()
    import imrbayes.diagnosis.synthetic as synth

    monkeypatch.setattr(synth, "camera_obs", lambda cls, seed, opts, design: (_fake_obs(seed + 1), {"theta": {}}))
    row = conf.run_one(job)
    assert stand_in["computed"] == ["a", "b"]
    assert row["checkpoint"]["sessions"] == 1
    assert (folder.parent / f"{folder.name}.stale-0" / "run.json").exists()


def test_compact_rows_keep_every_candidates_heldout_gain(conf):
    """The committed row keeps each compared candidate's gain and paired z by scheme, computed
    against the baseline's held-out RMSE (hand-made result: 0.02 -> 0.015 is a 25 % reduction)."""
    result = {"gain": {"by_scheme": {"forecast": {"baseline": 0.02}, "loeo": {"baseline": 0.01}}},
              "candidates": [
                  {"key": "zener", "rank": 1, "ruled_out": "",
                   "heldout": {"forecast": {"rmse": 0.015, "paired_vs_baseline": {"mean_diff": 0.003, "se": 0.002}},
                               "loeo": {"rmse": 0.008, "paired_vs_baseline": {"mean_diff": 0.001, "se": 0.00025}}}},
                  {"key": "qkv", "rank": 2, "ruled_out": "fitted alpha <= 0",
                   "heldout": {"forecast": {"rmse": 0.03, "paired_vs_baseline": {"mean_diff": -0.004, "se": 0.0}}}}]}
    out = conf.candidate_gains(result)
    assert [c["key"] for c in out] == ["zener", "qkv"]
    assert out[0]["forecast"]["relative_reduction"] == pytest.approx(0.25)
    assert out[0]["forecast"]["z"] == pytest.approx(1.5)
    assert out[0]["loeo"] == {"relative_reduction": pytest.approx(0.2), "z": pytest.approx(4.0)}
    assert out[1]["forecast"]["relative_reduction"] == pytest.approx(-0.5) and out[1]["forecast"]["z"] is None
    assert out[1]["ruled_out"] == "fitted alpha <= 0" and "loeo" not in out[1]
    assert conf.candidate_gains({"candidates": [], "gain": {}}) == []
