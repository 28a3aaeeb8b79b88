"""diagnose's bookkeeping: a statistic left out of the check is reported, and the En4D-Var
baseline is checkpointed with the other units (small polytropic runs, no candidates)."""

import json

import numpy as np
import pytest

import imrbayes.diagnosis.check as check_mod
import imrbayes.diagnosis.run as run_mod
from imrbayes.diagnosis import DiagnoseSettings, diagnose
from imrbayes.diagnosis.synthetic import synthetic_obs
from imrbayes.execution import Execution
from imrbayes.execution import RunStore
from imrbayes.forward import ForwardOptions

OPTS = ForwardOptions(bubble="polytropic")
SMALL = {"n_bootstrap": 2, "candidates": (), "loeo": False, "n_draws": 20}


def _obs():
    return synthetic_obs("none", 11, OPTS, n_exp=3, noise_scale=0.5)[0]


def _lost_every_member(*args, **kwargs):
    raise RuntimeError("experiment 0: fewer than two ensemble members survived the hand-off")


@pytest.mark.parametrize("case", ["settings", "smoother"])
def test_failed_mienks_drift_is_reported(case, monkeypatch):
    """The MIEnKS drift statistic that cannot be computed (settings the record cannot hold; the
    smoother failing on the data) is left out of the check with a warning naming the error."""
    if case == "settings":
        s, expect = DiagnoseSettings.quick(mienks_n_ens=2, mienks_drift=True, **SMALL), "at least 3 members"
    else:
        monkeypatch.setattr(check_mod, "mienks_drift", _lost_every_member)
        s, expect = DiagnoseSettings.quick(mienks_drift=True, **SMALL), "ensemble members survived"
    r = diagnose(_obs(), OPTS, settings=s, seed=0).result
    assert "mienks_drift" not in r["constant_parameter_check"]["evidence"]["statistics"]
    hits = [w for w in r["warnings"] if "mienks_drift" in w]
    assert len(hits) == 1 and expect in hits[0], r["warnings"]


def test_en4dvar_baseline_resumes_from_its_checkpoint(tmp_path, monkeypatch):
    """An interrupted diagnose reads the finished baseline fits (unit ``observed``) and En4D-Var
    units back from its run store, and ends where an uninterrupted run ends."""
    obs = _obs()
    s = DiagnoseSettings.quick(baseline_method="en4dvar", en4dvar_n_ens=6, en4dvar_n_runs=1, mienks_drift=False,
                               **SMALL)
    config = {"test": "en4dvar-resume"}

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    with monkeypatch.context() as m, RunStore.open(tmp_path, config) as store:
        m.setattr(run_mod, "bootstrap_check", interrupted)   # stop right after the baseline stage
        with pytest.raises(KeyboardInterrupt):
            diagnose(obs, OPTS, settings=s, seed=0, execution=Execution(store=store, progress=False))
    with RunStore.open(tmp_path, config, resume=True) as store:
        ex = Execution(store=store, progress=False)
        r = diagnose(obs, OPTS, settings=s, seed=0, execution=ex).result
    en4dvar = [rep for desc, rep in ex.reports if desc.startswith("en4dvar")]
    assert en4dvar, [desc for desc, _ in ex.reports]
    assert all(rep.n_computed == 0 and rep.n_resumed == obs.n_exp for rep in en4dvar)
    assert r["baseline"]["method"] == "en4dvar" and set(r["baseline"]["estimate"]) >= {"G", "mu"}
    rc = r["baseline"]["req_consistency"]          # one row per experiment whose Req was estimated
    assert rc["n_estimated"] == int(np.sum(obs.nuisance_sd[:, 2] > 0)) == len(rc["experiments"])
    ac = r["baseline"]["alignment_consistency"]    # one row per experiment, Rmax and time of the maximum
    assert [q["experiment"] for q in ac["experiments"]] == list(obs.names)
    assert ac["n_estimated"] == int(np.sum(np.any(obs.nuisance_sd[:, :2] > 0, axis=1)))   # those with Rmax or t0 inferred
    fits = [rep for desc, rep in ex.reports if desc == "diagnose baseline fits"]
    assert len(fits) == 1 and fits[0].n_computed == 0 and fits[0].n_resumed == 1
    whole = diagnose(obs, OPTS, settings=s, seed=0).result       # no store, nothing interrupted
    same = lambda a, b: json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)   # NaN == NaN
    for k in ("estimate_map", "chi2_norm", "misfit_by_phase", "nuisance"):
        assert same(r["baseline"][k], whole["baseline"][k]), k
    assert same(r["constant_parameter_check"]["evidence"]["statistics"],
                whole["constant_parameter_check"]["evidence"]["statistics"])


class _Spec:
    def __init__(self, ok):
        self.ok = ok

    def consistent(self, medians, estimate=None):
        return self.ok, "" if self.ok else "fitted alpha <= 0"


class _Cand:
    def __init__(self, ok):
        self.spec = _Spec(ok)

    def estimate(self, z, cov):
        return {"G": {"median": 1.0}}


class _Fit:
    z, cov = None, None


def test_loeo_runs_for_the_baseline_and_the_candidates_in_contention():
    """Leave-one-experiment-out for the baseline and each consistent candidate whose forecast beats
    the baseline's or is behind it by less than a paired SE; not for an inconsistent one, one the
    forecast puts clearly behind (or behind without per-bubble rows to say by how much), or one whose forecast
    failed -- unless every model is asked for, or the baseline's own forecast is undefined."""
    held = {"nhkv": {"forecast": {"rmse": 0.05}}, "better": {"forecast": {"rmse": 0.04}},
            "worse": {"forecast": {"rmse": 0.06}}, "inconsistent": {"forecast": {"rmse": 0.03}},
            "failed": {"forecast": {"rmse": float("nan")}}}
    cands = {"nhkv": _Cand(True), "better": _Cand(True), "worse": _Cand(True), "inconsistent": _Cand(False),
             "failed": _Cand(True), "no-forecast-unit": _Cand(True)}
    fits = {k: _Fit() for k in cands}
    assert run_mod.loeo_keys(held, fits, cands, "nhkv") == ["nhkv", "better"]
    assert run_mod.loeo_keys(held, fits, cands, "nhkv", loeo_all=True) == ["nhkv", "better", "worse",
                                                                           "inconsistent", "failed"]
    # behind on the mean but within the paired noise (per-bubble RMSE differences 0.34 SE behind, as
    # qkv on stiffening 1004): left to LOEO; clearly behind (4.5 SE, as Carreau there): not
    base_rows = [0.020, 0.030, 0.025, 0.022, 0.028]
    held["nhkv"]["forecast"]["per_experiment"] = base_rows
    held["level"] = {"forecast": {"rmse": 0.052, "per_experiment": [0.012, 0.041, 0.020, 0.031, 0.022]}}
    held["behind"] = {"forecast": {"rmse": 0.06, "per_experiment": [r + 0.0012 + 1e-4 * i for i, r in enumerate(base_rows)]}}
    cands.update(level=_Cand(True), behind=_Cand(True))
    fits.update(level=_Fit(), behind=_Fit())
    d_level = np.subtract(base_rows, held["level"]["forecast"]["per_experiment"])
    assert -1.0 < d_level.mean() / (d_level.std(ddof=1) / np.sqrt(5)) < 0     # the premise: behind, within 1 SE
    assert run_mod.loeo_keys(held, fits, cands, "nhkv") == ["nhkv", "better", "level"]
    held["nhkv"]["forecast"]["rmse"] = float("nan")    # a record too short to forecast: LOEO for all
    assert run_mod.loeo_keys(held, fits, cands, "nhkv") == ["nhkv", "better", "worse", "inconsistent", "failed",
                                                            "level", "behind"]


@pytest.mark.slow
def test_diagnose_reports_loeo_where_it_ran():
    """A run with LOEO: the baseline has both schemes; every candidate has LOEO exactly when the
    rule gives it, a note when not, and its score averages only the schemes it has."""
    s = DiagnoseSettings.quick(**{**SMALL, "candidates": ("qkv", "zener"), "loeo": True})
    r = diagnose(synthetic_obs("strain-stiffening", 3, OPTS, n_exp=3, noise_scale=0.5)[0], OPTS,
                 settings=s, seed=0).result
    base = r["baseline"]["heldout"]
    assert set(base) == {"forecast", "loeo"} and len(base["loeo"]["per_experiment"]) == 3
    for c in r["candidates"]:
        pd = c["heldout"]["forecast"]["paired_vs_baseline"]
        in_contention = c["consistent"] and (c["heldout"]["forecast"]["rmse"] < base["forecast"]["rmse"]
                                             or pd["mean_diff"] > -run_mod.LOEO_BEHIND_SE * pd["se"])
        assert ("loeo" in c["heldout"]) == in_contention, c["key"]
        assert set(c["relative_reduction"]) == set(c["heldout"])
        assert bool(c["loeo_note"]) == (not in_contention)


@pytest.mark.parametrize("case", ["far", "holed", "dominated"])
def test_bootstrap_stops_after_the_first_batch_only_when_decided(case, monkeypatch):
    """Replicates whose misfit sits far below the data's decide 'inadequate' at the first look
    (5 of 19 run, p-value Cantelli's bound); with one of them failed every look stays open, all 19
    run and the rank test decides (the failure counting against rejection); replicates above the
    data everywhere decide 'adequate' at the first look."""
    import numpy as np

    calls = []

    def fake_unit(unit, rng):
        calls.append(unit.unit_id)
        if case == "dominated":
            return {"drift": 1e9, "misfit": 1e9, "phase_misfit": 1e9}
        if case == "holed" and unit.unit_id == "bootstrap=003":
            raise RuntimeError("replicate fit failed")
        return {"drift": float(rng.exponential(1e-3)), "misfit": 1e-6 * (1 + 0.01 * rng.standard_normal()),
                "phase_misfit": 1e-6 * (1 + 0.01 * rng.standard_normal())}

    monkeypatch.setattr(check_mod, "bootstrap_unit", fake_unit)
    s = DiagnoseSettings.quick(**{**SMALL, "n_bootstrap": 19})
    r = diagnose(_obs(), OPTS, settings=s, seed=0).result
    chk = r["constant_parameter_check"]
    ev = chk["evidence"]
    stages = [d["stage"] for d in r["stage_seconds"]]
    assert stages[0].startswith("baseline fits") and any(m.startswith("constant-parameter check") for m in stages)
    assert all(d["seconds"] >= 0 and d["cpu_seconds"] >= 0 for d in r["stage_seconds"])
    assert not any("cannot find" in w for w in r["warnings"])     # 19 replicates can reject at 5 %
    if case == "far":
        assert len(calls) == 5 and ev["n_bootstrap"] == 5 and ev["sequential"]["decided"] == "inadequate"
        assert ev["sequential"]["looks"] == [5, 10] and ev["sequential"]["first_batch"] == 5
        z = max(ev["sequential"]["z_first_batch"].values())
        assert z >= check_mod.Z_DECIDED_FIRST
        assert chk["verdict"] == "inadequate" and ev["p_value_kind"] == "bound"
        assert ev["p_value"] == pytest.approx(3 / (1 + z ** 2)) and ev["p_value_rank"] == pytest.approx(1 / 6)
        assert check_mod.p_value_text(ev).startswith("p ≤ ")
    elif case == "holed":
        assert len(calls) == 19 and ev["n_bootstrap"] == 19 and ev["sequential"]["decided"] is None
        # the failed replicate counts against rejection (+inf): p = 2/20, as before the early stop
        assert ev["p_value_kind"] == "rank" and ev["p_value"] == pytest.approx(0.10) and chk["verdict"] == "adequate"
        assert np.isnan(ev["statistics"]["misfit"]["bootstrap"][3])
    else:
        assert len(calls) == 5 and ev["sequential"]["decided"] == "adequate" and chk["verdict"] == "adequate"
        assert check_mod.p_value_text(ev) == f"p = {ev['p_value']:.3f}"


def test_too_few_replicates_to_reject_are_named():
    """With B replicates a rank test's smallest p-value is 1/(B+1): below 19 at 5 % the check can
    never say inadequate, and the diagnosis says so (a user lowering --n-bootstrap to save time)."""
    r = diagnose(_obs(), OPTS, settings=DiagnoseSettings.quick(**SMALL), seed=0).result
    hits = [w for w in r["warnings"] if "cannot find the constant-parameter model inadequate" in w]
    assert len(hits) == 1 and "1/3 > alpha = 0.05" in hits[0] and "at least 19 replicates" in hits[0]
    assert r["constant_parameter_check"]["verdict"] == "adequate"


def _top(z_forecast, z_loeo=None, score=0.05, consistent=True):
    """A top-ranked candidate as ``diagnose`` ranks it: per-scheme paired differences against the
    baseline (mean_diff > 0: the candidate predicts better), se fixed, z set by mean_diff."""
    held = {"forecast": {"paired_vs_baseline": {"mean_diff": z_forecast * 1e-4, "se": 1e-4}}}
    if z_loeo is not None:
        held["loeo"] = {"paired_vs_baseline": {"mean_diff": z_loeo * 1e-4, "se": 1e-4}}
    return {"key": "bubble-gilmore", "model": "bubble-gilmore", "mechanism": "bubble-compressibility",
            "score": score, "consistent": consistent, "heldout": held}


MECH = {"bubble-gilmore": "bubble-compressibility", "qkv": "strain-stiffening"}


@pytest.mark.parametrize("top, tied, cause", [
    # bubble-thermal 5001 of the thermal matrix: inadequate, Gilmore ahead by 1.8 and 0.7 SE -- a guess
    (_top(1.79, 0.68), [], "unexplained"),
    (_top(1.79, 2.4), [], "bubble-compressibility"),         # leave-one-out separates it
    (_top(2.1), [], "bubble-compressibility"),               # the forecast alone (no LOEO run)
    (_top(2.1, -0.5), ["bubble-gilmore", "qkv"], "ambiguous"),
    (_top(1.0, 1.5), ["bubble-gilmore", "qkv"], "unexplained"),  # a tie of guesses is no cause either
    (_top(5.0, 5.0, consistent=False), [], "unexplained"),
    (_top(5.0, 5.0, score=-0.01), [], "unexplained"),
])
def test_a_cause_is_named_only_when_its_gain_is_separated_from_the_baseline(top, tied, cause):
    got, ext, got_tied, note = run_mod.name_cause("inadequate", top, tied, MECH, name_se=2.0)
    assert got == cause
    assert (ext is None) == (cause == "unexplained")
    if cause == "ambiguous":
        assert got_tied == tied
    if cause == "unexplained":
        assert got_tied == []
    if cause == "unexplained" and top["consistent"] and top["score"] > 0:
        assert "within 2 paired SE on every scheme" in note and "forecast 1." in note
    assert run_mod.name_cause("adequate", top, tied, MECH)[0] == "none"


def test_one_experiment_names_on_the_score_and_says_so():
    """No paired SE exists for one experiment: the separation cannot be measured, the rule names on
    the score (as before) and the note says that it did."""
    top = _top(0.0)
    top["heldout"]["forecast"]["paired_vs_baseline"] = {"mean_diff": float("nan"), "se": float("nan")}
    cause, ext, _, note = run_mod.name_cause("inadequate", top, [], MECH)
    assert cause == "bubble-compressibility" and ext == "bubble-gilmore" and "not measured" in note
    assert run_mod.separation_se(top) == {}


def test_the_en4dvar_baseline_places_req_at_the_least_squares_fit(monkeypatch):
    """With ``req_tail=model`` (the thermal default; forced here on a small polytropic camera set),
    diagnose's En4D-Var evaluates the model's tail at its least-squares baseline -- each bubble's
    material with its fitted offsets, its fitted Rmax -- instead of running a first pass of its own."""
    import imrbayes.ensemble.en4dvar as en4dvar_mod
    from imrbayes.diagnosis.models import BASELINE, make_candidate
    from imrbayes.diagnosis.synthetic import camera_obs
    from imrbayes.ensemble.req_tail import model_tail_req
    from imrbayes.forward import Runner

    monkeypatch.setattr(en4dvar_mod, "req_tail_mode", lambda settings, fm: "model")
    obs = camera_obs("none", 3, OPTS, n_exp=2)[0]
    s = DiagnoseSettings.quick(baseline_method="en4dvar", en4dvar_n_ens=6, en4dvar_n_runs=1, mienks_drift=False,
                               **SMALL)
    ex = Execution(progress=False)
    b = diagnose(obs, OPTS, settings=s, seed=0, execution=ex).result["baseline"]
    info = b["req_tail"]
    assert info["method"] == "model" and "least-squares" in info["start"]["source"]
    assert "first_pass_estimate" not in info
    assert "tail at the least-squares baseline" in b["estimate_note"] and "estimate_map" in b["estimate_note"]
    # one En4D-Var pass: its experiments' units once (the given start), no 'req=first' pass
    assert [desc for desc, _ in ex.reports].count("en4dvar experiments") == 1
    theta = np.array([[b["estimate_map"][k]["median"] * np.exp(n[f"log_{k}_offset"]) for k in ("G", "mu")]
                      for n in b["nuisance"]])
    rmax = np.array([n["rmax_m"]["fitted"] for n in b["nuisance"]])
    assert np.allclose(info["start"]["theta_si"], theta, rtol=1e-12)
    assert np.allclose(info["start"]["rmax_m"], rmax, rtol=1e-12)
    _, factor = model_tail_req(Runner(make_candidate(BASELINE.key, OPTS).fm), obs, theta, rmax)
    assert np.allclose(info["factor"], factor, rtol=0, atol=1e-12) and not np.allclose(factor, 1.0)
