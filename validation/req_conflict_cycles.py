"""How the Req conflict develops over En4D-Var's restart cycles: each cycle's z per bubble.

MIEnKS-MDA's default Req prior is a whole-record En4D-Var fit whose only use is each bubble's Req
against its record's tail (``req_tail.req_shift_z``; beyond 3 sd the record's Req is kept). This
probe runs that fit exactly as ``mienks.req_prior_from_en4dvar`` does, without a stop, and records
the Req z after every cycle (``cycles[].req_z``), to choose the bound past which cycles 2 and 3
cannot bring a bubble back within 3 (``En4DVarSettings.req_conflict_stop``).

    python validation/req_conflict_cycles.py camera BUBBLE FAMILY FIRST_SEED N_SEEDS out.json
    python validation/req_conflict_cycles.py data FOLDER [EXPERIMENTS] out.json

(``camera``: ``camera_calibration.py``'s records, BUBBLE polytropic|thermal, FAMILY camera|scatter;
``data``: a dataset folder, thermal bubble, EXPERIMENTS like ``1-5``.) Prints each record's z per
cycle and writes them as JSON, a row per bubble.
"""
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from camera_calibration import simulate  # noqa: E402
from imrbayes.cli.options import select_experiments  # noqa: E402
from imrbayes.data import load_dataset, preprocess_dataset  # noqa: E402
from imrbayes.ensemble import Observations, ParamSpace  # noqa: E402
from imrbayes.ensemble.en4dvar import En4DVarSettings, _fit_en4dvar  # noqa: E402
from imrbayes.ensemble.req_tail import req_shift_z  # noqa: E402
from imrbayes.execution import Execution  # noqa: E402
from imrbayes.forward import ForwardModel, Runner  # noqa: E402


def cycles_z(obs, bubble: str, seed: int, label: str) -> list:
    fm = ForwardModel("nhkv", options={"bubble": bubble})
    space = ParamSpace.for_model(fm.constitutive)
    s = En4DVarSettings(n_draws=1, loglik=False)        # req_prior_from_en4dvar's settings
    s.check()
    e4 = _fit_en4dvar(fm, obs, space, s.resolved(), seed, Runner(fm), None, Execution(progress=False),
                      tag={"req_prior": "en4dvar"})
    final = {q["experiment"]: q["z"] for q in req_shift_z(obs, e4.per_experiment)}
    rows = []
    for name in e4.details["cycles"][0]["experiments"]:
        z = [c["req_z"][c["experiments"].index(name)] for c in e4.details["cycles"] if name in c["experiments"]]
        rows.append({"source": label, "seed": seed, "experiment": name, "z_cycles": z, "z_final": final.get(name)})
        print(label, seed, name, np.round(z, 2), round(final.get(name, np.nan), 2), flush=True)
    return rows


def main(argv) -> int:
    out, rows = argv[-1], []
    if argv[0] == "camera":
        bubble, family, first, n = argv[1], argv[2], int(argv[3]), int(argv[4])
        for seed in range(first, first + n):
            with tempfile.TemporaryDirectory() as tmp:
                folder = Path(tmp) / "data"
                simulate(folder, seed, family, bubble)
                obs = Observations.from_preprocessed(preprocess_dataset(load_dataset(folder), skip_failed=True))
            rows += cycles_z(obs, bubble, seed, f"{family}-{bubble}")
            Path(out).write_text(json.dumps(rows, indent=1))
    else:
        folder = Path(argv[1])
        ds = select_experiments(load_dataset(folder), argv[2] if len(argv) > 3 else None)
        obs = Observations.from_preprocessed(preprocess_dataset(ds, skip_failed=True))
        rows += cycles_z(obs, "thermal", 0, folder.name)
        Path(out).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
