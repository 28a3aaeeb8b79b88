"""Stiff-PA dataset variants for the one-factor study (IMR v1's choices, /tmp/s19/imrv1_constants.md)."""
import json, shutil
from pathlib import Path
import numpy as np, pandas as pd
SRC = Path("../shared/data/lic/estrada2018_stiffPA_270kfps")
meta = json.loads((SRC / "meta.json").read_text())
def variant(name, physics=None, req=False):
    out = Path("/tmp/s19") / name
    shutil.rmtree(out, ignore_errors=True)
    shutil.copytree(SRC, out)
    m = dict(meta)
    if physics:
        m["physics"] = {**m.get("physics", {}), **physics}
    if req:
        ex = {}
        for f in sorted(out.glob("exp*.csv")):
            d = pd.read_csv(f)
            t = d.iloc[:, 0].to_numpy(); R = d.iloc[:, 1].to_numpy()
            k = np.rint(t * 270000).astype(int)          # frame index from the max frame (column 12)
            sel = (k >= 50) & (k <= 89)                  # IMR v1: columns 62..101 (1-based)
            ex[f.name] = {"Req_m": float(np.median(R[sel]))}
        m["experiments"] = [{**e, **ex.get(e["file"], {})} for e in m["experiments"]]
    (out / "meta.json").write_text(json.dumps(m, indent=1))
    return out
variant("pa_v1const", physics={"rho": 998.2, "surface_tension": 0.056, "kappa": 1.4})
variant("pa_v1req", req=True)
variant("pa_v1all", physics={"rho": 998.2, "surface_tension": 0.056, "kappa": 1.4}, req=True)
print([e["Req_m"] / e["Rmax_sample_m"] for e in json.loads(Path("/tmp/s19/pa_v1req/meta.json").read_text())["experiments"]])
variant("pa_rho", physics={"rho": 998.2})
variant("pa_S", physics={"surface_tension": 0.056})
variant("pa_kappa", physics={"kappa": 1.4})
