"""As req_start.py, but the given start's units carry the first-pass path's tag (req=model), so the
unit seeds match `fit`'s req_tail=auto run: the difference is the Req factors alone."""
import json, sys, time
import imrbayes.ensemble as ens
import imrbayes.ensemble.en4dvar as en
from imrbayes.cli import main

orig, orig_inner = ens.fit_en4dvar, en._fit_en4dvar
out = sys.argv[1]

def inner(*a, tag=None, **k):
    if tag == {"req": "given"}:
        tag = {"req": "model"}
    return orig_inner(*a, tag=tag, **k)

def wrapped(*a, **k):
    t = time.perf_counter()
    r = orig(*a, **k)
    json.dump({"req_tail": r.details["req_tail"], "estimate": r.estimate, "seconds": time.perf_counter() - t,
               "member_runs": r.details["member_runs"],
               "per_experiment": [{k2: p.get(k2) for k2 in ("name", "estimate", "nuisance")} for p in r.per_experiment]},
              open(out, "w"), indent=1, default=float)
    raise SystemExit(0)

en._fit_en4dvar = inner
ens.fit_en4dvar = wrapped
main(sys.argv[2:], standalone_mode=False)
