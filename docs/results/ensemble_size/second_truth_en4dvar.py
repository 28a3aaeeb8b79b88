"""En4D-Var part of the second-truth case (suite quick: polytropic), seeds 0-4, one setting at two
values: 24 vs 48 members (default: ``python second_truth_en4dvar.py out.json``; session 55) or e.g.
``python second_truth_en4dvar.py out.json n_iter_later 3 5`` (session 56), or text values, e.g.
``python second_truth_en4dvar.py out.json nuisance_integral cycle req`` (session 58)."""
import json, sys
from imrbayes.ensemble import En4DVarSettings, ParamSpace, fit_en4dvar
from imrbayes.forward import ForwardModel
from imrbayes.validation.suite import TRUTH_2, RATIO_2, verification_data, TRUTH
key, values = (sys.argv[2], [int(v) if v.lstrip("-").isdigit() else v for v in sys.argv[3:]]) if len(sys.argv) > 2 else ("n_ens", [24, 48])
fm = ForwardModel("nhkv", options={"bubble": "polytropic"})
space = ParamSpace.for_model(fm.constitutive)
rows = []
for case, (tr, ratio) in {"second": (TRUTH_2, RATIO_2), "verification": (TRUTH, None)}.items():
    for seed in range(5):
        obs = verification_data(fm, seed, truth=tr, ratio=ratio) if ratio else verification_data(fm, seed)
        for n in values:
            en = fit_en4dvar(fm, obs, space, En4DVarSettings(**{key: n}, n_draws=1, loglik=False), seed=seed)
            r = {"case": case, "seed": seed, key: n, "runtime_s": en.runtime_s}
            for p in tr:
                e = en.estimate[p]
                r[p] = {"mean": e["mean"], "sd": e["sd"], "rel": e["mean"] / tr[p] - 1,
                        "covers": bool(e["hdi95"][0] <= tr[p] <= e["hdi95"][1])}
            rows.append(r)
            print(case, seed, n, f"G {r['G']['rel']:+.3f} {r['G']['covers']} mu {r['mu']['rel']:+.3f} {r['mu']['covers']} {en.runtime_s:.1f}s", flush=True)
json.dump(rows, open(sys.argv[1], "w"), indent=1)
