"""How far MIEnKS-MDA's default Req prior (the whole-record En4D-Var posterior) moves from each camera
record's preprocessing Req, in preprocessing prior sd: the z that ``REQ_PRIOR_CONFLICT_Z`` bounds.

    python validation/req_conflict_probe.py BUBBLE FAMILY FIRST_SEED N_SEEDS out.json

(BUBBLE polytropic|thermal, FAMILY camera|scatter: ``camera_calibration.py``'s records.) Prints each
seed's z per bubble and writes every seed's z, preprocessing Req and En4D-Var Req (mean, sd) as JSON.
"""
import json, sys, tempfile
from pathlib import Path
import numpy as np
sys.path.insert(0, 'validation')
from camera_calibration import simulate
from imrbayes.data import load_dataset, preprocess_dataset
from imrbayes.ensemble import Observations, ParamSpace
from imrbayes.ensemble.mienks import req_prior_from_en4dvar
from imrbayes.execution import Execution
from imrbayes.forward import ForwardModel, Runner
bubble, family, first, n, out = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
fm = ForwardModel("nhkv", options={"bubble": bubble}); space = ParamSpace.for_model(fm.constitutive)
rows = []
for seed in range(first, first + n):
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "data"
        simulate(folder, seed, family, bubble)
        obs = Observations.from_preprocessed(preprocess_dataset(load_dataset(folder), skip_failed=True))
    # no bound: a conflicting bubble would otherwise keep its preprocessing Req and read z = 0
    _, info = req_prior_from_en4dvar(fm, obs, space, seed, Runner(fm), Execution(progress=False), conflict_z=np.inf)
    pre, psd, post, qsd = (np.array(info[k]) for k in ("preprocessing_req_m", "preprocessing_req_sd_m", "req_m", "req_sd_m"))
    z = (post - pre) / psd
    rows.append({"seed": seed, "z": z.tolist(), "pre": pre.tolist(), "pre_sd": psd.tolist(), "post": post.tolist(), "post_sd": qsd.tolist()})
    print(seed, np.round(z, 2), flush=True)
    Path(out).write_text(json.dumps(rows))
