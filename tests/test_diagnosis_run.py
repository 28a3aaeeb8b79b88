"""diagnose's bookkeeping: a statistic left out of the check is reported, and the En4D-Var
baseline is checkpointed with the other units (small polytropic runs, no candidates)."""

import json

import numpy as np
import pytest

import imrbayes.diagnosis.check as check_mod
import imrbayes.diagnosis.run as run_mod
from imrbayes.diagnosis import DiagnoseSettings, diagnose
from imrbayes.diagnosis.synthetic import synthetic_obs
from imrbayes.execution import Execution, RunStore
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
    s = DiagnoseSettings.quick(
        baseline_method="en4dvar", en4dvar_n_ens=6, en4dvar_n_runs=1, mienks_drift=False, **SMALL
    )
    config = {"test": "en4dvar-resume"}

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    with monkeypatch.context() as m, RunStore.open(tmp_path, config) as store:
        m.setattr(run_mod, "bootstrap_check", interrupted)  # stop right after the baseline stage
        with pytest.raises(KeyboardInterrupt):
            diagnose(obs, OPTS, settings=s, seed=0, execution=Execution(store=store, progress=False))
    with RunStore.open(tmp_path, config, resume=True) as store:
        ex = Execution(store=store, progress=False)
        r = diagnose(obs, OPTS, settings=s, seed=0, execution=ex).result
    en4dvar = [rep for desc, rep in ex.reports if desc.startswith("en4dvar")]
    assert en4dvar, [desc for desc, _ in ex.reports]
    assert all(rep.n_computed == 0 and rep.n_resumed == obs.n_exp for rep in en4dvar)
    assert r["baseline"]["method"] == "en4dvar" and set(r["baseline"]["estimate"]) >= {"G", "mu"}
    rc = r["baseline"]["req_consistency"]  # one row per experiment whose Req was estimated
    assert rc["n_estimated"] == int(np.sum(obs.nuisance_sd[:, 2] > 0)) == len(rc["experiments"])
    ac = r["baseline"]["alignment_consistency"]  # one row per experiment, Rmax and time of the maximum
    assert [q["experiment"] for q in ac["experiments"]] == list(obs.names)
    assert ac["n_estimated"] == int(
        np.sum(np.any(obs.nuisance_sd[:, :2] > 0, axis=1))
    )  # those with Rmax or t0 inferred
    fits = [rep for desc, rep in ex.reports if desc == "diagnose baseline fits"]
    assert len(fits) == 1 and fits[0].n_computed == 0 and fits[0].n_resumed == 1
    whole = diagnose(obs, OPTS, settings=s, seed=0).result  # no store, nothing interrupted
    same = lambda a, b: json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)  # NaN == NaN
    for k in ("estimate_map", "chi2_norm", "misfit_by_phase", "nuisance"):
        assert same(r["baseline"][k], whole["baseline"][k]), k
    assert same(
        r["constant_parameter_check"]["evidence"]["statistics"],
        whole["constant_parameter_check"]["evidence"]["statistics"],
    )


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
    held = {
        "nhkv": {"forecast": {"rmse": 0.05}},
        "better": {"forecast": {"rmse": 0.04}},
        "worse": {"forecast": {"rmse": 0.06}},
        "inconsistent": {"forecast": {"rmse": 0.03}},
        "failed": {"forecast": {"rmse": float("nan")}},
    }
    cands = {
        "nhkv": _Cand(True),
        "better": _Cand(True),
        "worse": _Cand(True),
        "inconsistent": _Cand(False),
        "failed": _Cand(True),
        "no-forecast-unit": _Cand(True),
    }
    fits = {k: _Fit() for k in cands}
    assert run_mod.loeo_keys(held, fits, cands, "nhkv") == ["nhkv", "better"]
    assert run_mod.loeo_keys(held, fits, cands, "nhkv", loeo_all=True) == [
        "nhkv",
        "better",
        "worse",
        "inconsistent",
        "failed",
    ]
    # behind on the mean but within the paired noise (per-bubble RMSE differences 0.34 SE behind, as
    # qkv on stiffening 1004): left to LOEO; clearly behind (4.5 SE, as Carreau there): not
    base_rows = [0.020, 0.030, 0.025, 0.022, 0.028]
    held["nhkv"]["forecast"]["per_experiment"] = base_rows
    held["level"] = {"forecast": {"rmse": 0.052, "per_experiment": [0.012, 0.041, 0.020, 0.031, 0.022]}}
    held["behind"] = {
        "forecast": {"rmse": 0.06, "per_experiment": [r + 0.0012 + 1e-4 * i for i, r in enumerate(base_rows)]}
    }
    cands.update(level=_Cand(True), behind=_Cand(True))
    fits.update(level=_Fit(), behind=_Fit())
    d_level = np.subtract(base_rows, held["level"]["forecast"]["per_experiment"])
    assert -1.0 < d_level.mean() / (d_level.std(ddof=1) / np.sqrt(5)) < 0  # the premise: behind, within 1 SE
    assert run_mod.loeo_keys(held, fits, cands, "nhkv") == ["nhkv", "better", "level"]
    held["nhkv"]["forecast"]["rmse"] = float("nan")  # a record too short to forecast: LOEO for all
    assert run_mod.loeo_keys(held, fits, cands, "nhkv") == [
        "nhkv",
        "better",
        "worse",
        "inconsistent",
        "failed",
        "level",
        "behind",
    ]


@pytest.mark.slow
def test_diagnose_reports_loeo_where_it_ran():
    """A run with LOEO: the baseline has both schemes; every candidate has LOEO exactly when the
    rule gives it, a note when not, and its score averages only the schemes it has."""
    s = DiagnoseSettings.quick(**{**SMALL, "candidates": ("qkv", "zener"), "loeo": True})
    r = diagnose(
        synthetic_obs("strain-stiffening", 3, OPTS, n_exp=3, noise_scale=0.5)[0], OPTS, settings=s, seed=0
    ).result
    base = r["baseline"]["heldout"]
    assert set(base) == {"forecast", "loeo"} and len(base["loeo"]["per_experiment"]) == 3
    for c in r["candidates"]:
        pd = c["heldout"]["forecast"]["paired_vs_baseline"]
        in_contention = c["consistent"] and (
            c["heldout"]["forecast"]["rmse"] < base["forecast"]["rmse"]
            or pd["mean_diff"] > -run_mod.LOEO_BEHIND_SE * pd["se"]
        )
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
        return {
            "drift": float(rng.exponential(1e-3)),
            "misfit": 1e-6 * (1 + 0.01 * rng.standard_normal()),
            "phase_misfit": 1e-6 * (1 + 0.01 * rng.standard_normal()),
        }

    monkeypatch.setattr(check_mod, "bootstrap_unit", fake_unit)
    s = DiagnoseSettings.quick(**{**SMALL, "n_bootstrap": 19})
    r = diagnose(_obs(), OPTS, settings=s, seed=0).result
    chk = r["constant_parameter_check"]
    ev = chk["evidence"]
    stages = [d["stage"] for d in r["stage_seconds"]]
    assert stages[0].startswith("baseline fits") and any(m.startswith("constant-parameter check") for m in stages)
    assert all(d["seconds"] >= 0 and d["cpu_seconds"] >= 0 for d in r["stage_seconds"])
    assert not any("cannot find" in w for w in r["warnings"])  # 19 replicates can reject at 5 %
    if case == "far":
        assert len(calls) == 5 and ev["n_bootstrap"] == 5 and ev["sequential"]["decided"] == "inadequate"
        assert ev["sequential"]["looks"] == [5, 10] and ev["sequential"]["first_batch"] == 5
        z = max(ev["sequential"]["z_first_batch"].values())
        assert z >= check_mod.Z_DECIDED_FIRST
        assert chk["verdict"] == "inadequate" and ev["p_value_kind"] == "bound"
        assert ev["p_value"] == pytest.approx(3 / (1 + z**2)) and ev["p_value_rank"] == pytest.approx(1 / 6)
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


#: a zero-mean, unit-sd pattern over 8 experiments: a scheme's per-experiment relative gains are m + s P
P = np.array([-1.5, -1.0, -0.5, 0.0, 0.0, 0.5, 1.0, 1.5])
P = P / P.std(ddof=1)
BASE_RMSE = 0.01


def gains(mean, z, sign=1.0):
    """Per-experiment relative gains over 8 experiments with this mean and this paired z."""
    return mean + sign * mean * np.sqrt(P.size) / z * P


def _top(per_scheme, consistent=True, key="qkv", mechanism="strain-stiffening"):
    """A top-ranked candidate as ``diagnose`` ranks it, from its per-experiment relative gains per
    scheme (baseline RMSE BASE_RMSE in every experiment): the real paired, score and combined rows."""
    from imrbayes.diagnosis.heldout import paired

    base = {k: {"per_experiment": [BASE_RMSE] * len(g), "rmse": BASE_RMSE} for k, g in per_scheme.items()}
    cand = {}
    for k, g in per_scheme.items():
        per = BASE_RMSE * (1 - np.asarray(g, dtype=float))
        cand[k] = {"per_experiment": per.tolist(), "rmse": float(np.sqrt(np.mean(per**2)))}
    score = float(np.mean([1 - cand[k]["rmse"] / base[k]["rmse"] for k in cand]))
    held = {
        k: {**cand[k], "paired_vs_baseline": paired(base[k]["per_experiment"], cand[k]["per_experiment"])} for k in cand
    }
    return {
        "key": key,
        "model": key,
        "mechanism": mechanism,
        "score": score,
        "consistent": consistent,
        "heldout": held,
        "combined_vs_baseline": run_mod.combined_paired(base, cand, list(per_scheme)),
    }


MECH = {"qkv": "strain-stiffening", "damage": "damage-softening", "carreau": "rate-dependent-viscosity"}


def test_combined_gain_is_the_mean_over_schemes_per_experiment():
    """The combined z is the paired z of the per-experiment mean of the schemes' relative gains,
    so two schemes that err together (same records) do not add up as independent evidence."""
    gf, gl = gains(0.15, 0.8), gains(0.15, 2.4)
    top = _top({"forecast": gf, "loeo": gl})
    d = (gf + gl) / 2
    assert top["combined_vs_baseline"]["z"] == pytest.approx(d.mean() / (d.std(ddof=1) / np.sqrt(d.size)))
    assert top["combined_vs_baseline"]["mean_diff"] == pytest.approx(0.15)
    assert run_mod.separation_se(top) == pytest.approx({"forecast": 0.8, "loeo": 2.4})
    # the same gains, the leave-one-out errors opposite to the forecast's: they cancel, the evidence adds
    anti = _top({"forecast": gf, "loeo": gains(0.15, 2.4, sign=-1)})
    assert anti["combined_vs_baseline"]["z"] > 2.4 > top["combined_vs_baseline"]["z"]
    assert _top({"forecast": gf})["combined_vs_baseline"]["z"] == pytest.approx(0.8)


@pytest.mark.parametrize(
    "top, tied, cause, words",
    [
        # the PyIMR null: 0.5 % at 0.3 SE on the forecast and 2.4 SE on leave-one-out
        (
            _top({"forecast": gains(0.005, 0.3), "loeo": gains(0.005, 2.4)}),
            [],
            "unexplained",
            "of the held-out error -- too little to name a cause",
        ),
        # the IMRv2 null: 5 %, clear on both schemes -- real, but too small to be a mechanism's
        (
            _top(
                {"forecast": gains(0.05, 3.0), "loeo": gains(0.05, 3.0)},
                key="carreau",
                mechanism="rate-dependent-viscosity",
            ),
            ["carreau", "damage"],
            "unexplained",
            "(carreau, rate-dependent-viscosity) recovers",
        ),
        (_top({"forecast": gains(0.57, 6.0), "loeo": gains(0.57, 8.0)}), [], "strain-stiffening", "held-out gain"),
        (
            _top({"forecast": gains(0.11, 3.0), "loeo": gains(0.11, 4.0)}, key="damage", mechanism="damage-softening"),
            [],
            "damage-softening",
            "held-out gain",
        ),
        (_top({"forecast": gains(0.15, 2.1)}), [], "strain-stiffening", "2.1 paired SE"),  # the forecast alone
        # 13 %, named by the old any-scheme rule on leave-one-out alone: together 2 / (1/1.2 + 1/2.4) = 1.6 SE
        (
            _top({"forecast": gains(0.2, 1.2), "loeo": gains(0.2, 2.4)}),
            [],
            "unexplained",
            "within 2 paired SE of the baseline over the schemes taken together",
        ),
        # thermal relaxation: a weak forecast (few samples) does not hide a clear leave-one-out
        (_top({"forecast": gains(0.15, 1.6), "loeo": gains(0.15, 4.2)}), [], "strain-stiffening", "forecast 1.6"),
        (_top({"forecast": gains(0.3, 5.0)}), ["qkv", "damage"], "ambiguous", ""),
        (_top({"forecast": gains(0.3, 5.0)}, consistent=False), [], "unexplained", "no consistent candidate"),
        (_top({"forecast": gains(-0.01, 5.0)}), [], "unexplained", "no consistent candidate"),
    ],
)
def test_a_cause_is_named_only_when_its_gain_is_large_and_clear_over_the_schemes(top, tied, cause, words):
    got, ext, got_tied, note = run_mod.name_cause("inadequate", top, tied, MECH, name_se=2.0, min_gain=0.10)
    assert got == cause, note
    assert (ext is None) == (cause == "unexplained")
    assert got_tied == (tied if cause == "ambiguous" else [] if cause == "unexplained" else tied)
    assert words in note
    if top["consistent"] and top["score"] > 0 and cause != "ambiguous":
        assert f"{100 * top['score']:.2g} %" in note  # the gain the floor was compared with
    assert run_mod.name_cause("adequate", top, tied, MECH)[0] == "none"


def test_the_floor_is_a_module_constant_the_rule_uses_by_default():
    top = _top({"forecast": gains(0.08, 5.0), "loeo": gains(0.08, 5.0)})
    assert run_mod.MIN_GAIN == 0.10
    assert run_mod.name_cause("inadequate", top, [], MECH)[0] == "unexplained"
    assert run_mod.name_cause("inadequate", top, [], MECH, min_gain=0.05)[0] == "strain-stiffening"


def test_one_experiment_names_on_the_score_and_says_so():
    """No paired SE exists for one experiment: the separation cannot be measured, the rule names on
    the score (above the floor) and the note says that it did."""
    top = _top({"forecast": [0.3]})
    assert np.isnan(top["combined_vs_baseline"]["z"]) and run_mod.separation_se(top) == {}
    cause, ext, _, note = run_mod.name_cause("inadequate", top, [], MECH)
    assert cause == "strain-stiffening" and ext == "qkv" and "not measured" in note
    assert run_mod.name_cause("inadequate", _top({"forecast": [0.02]}), [], MECH)[0] == "unexplained"


def test_misfit_summary_is_the_median_residual_over_noise():
    """Residual RMS / noise sd per record (samples 1..n), the median over records, and the sentence."""
    from types import SimpleNamespace

    rng = np.random.default_rng(1)
    fitted = np.zeros((3, 2001))
    sd = np.array([0.01, 0.02, 0.005])
    scale = np.array([1.0, 3.0, 10.0])  # how far each record is missed, in its noise
    R = fitted + (scale * sd)[:, None] * rng.standard_normal(fitted.shape)
    m = run_mod.misfit_summary(SimpleNamespace(R_star=R), fitted, sd)
    assert m["residual_to_noise"] == pytest.approx(3.0, rel=0.05)
    assert m["sentence"] == "the constant model misses these records by 3 x their noise"


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
    s = DiagnoseSettings.quick(
        baseline_method="en4dvar", en4dvar_n_ens=6, en4dvar_n_runs=1, mienks_drift=False, **SMALL
    )
    ex = Execution(progress=False)
    b = diagnose(obs, OPTS, settings=s, seed=0, execution=ex).result["baseline"]
    info = b["req_tail"]
    assert info["method"] == "model" and "least-squares" in info["start"]["source"]
    assert "first_pass_estimate" not in info
    assert "tail at the least-squares baseline" in b["estimate_note"] and "estimate_map" in b["estimate_note"]
    # one En4D-Var pass: its experiments' units once (the given start), no 'req=first' pass
    assert [desc for desc, _ in ex.reports].count("en4dvar experiments") == 1
    theta = np.array(
        [[b["estimate_map"][k]["median"] * np.exp(n[f"log_{k}_offset"]) for k in ("G", "mu")] for n in b["nuisance"]]
    )
    rmax = np.array([n["rmax_m"]["fitted"] for n in b["nuisance"]])
    assert np.allclose(info["start"]["theta_si"], theta, rtol=1e-12)
    assert np.allclose(info["start"]["rmax_m"], rmax, rtol=1e-12)
    _, factor = model_tail_req(Runner(make_candidate(BASELINE.key, OPTS).fm), obs, theta, rmax)
    assert np.allclose(info["factor"], factor, rtol=0, atol=1e-12) and not np.allclose(factor, 1.0)
