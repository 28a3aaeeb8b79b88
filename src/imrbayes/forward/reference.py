"""Read IMRv2 reference trajectories (shared/reference/imrv2) as forward-model set-ups."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imrbayes.forward.model import ForwardModel
from imrbayes.forward.options import ForwardOptions

_RADIAL = {1: "rp", 2: "km", 3: "km-enthalpy", 4: "gilmore"}
# IMRv2 defaults for the inputs a case may leave out (forward-model.md §10).
_DEFAULTS = {"g": 1e3, "mu": 8.3283e-4, "lambda1": 1e-7, "lambda2": 1e-8, "alphax": 0.25,
             "radial": 1, "bubtherm": 0, "medtherm": 0, "vapor": 0, "masstrans": 0, "stress": 0,
             "nt": 25, "mt": 25}


@dataclass
class ReferenceCase:
    """One IMRv2 run: ``case_id``, the equivalent ``model``, SI ``params``, ``rmax_m``, ``req_m``,
    output times ``t_star`` (121,), IMRv2's ``R_star`` (121,), and the raw ``json`` record."""

    case_id: str
    model: ForwardModel
    params: dict
    rmax_m: float
    req_m: float
    t_star: np.ndarray
    R_star: np.ndarray
    json: dict


def constitutive_for(inputs: dict) -> tuple:
    """(model name, SI params) equivalent to IMRv2's ``stress`` option and material inputs."""
    v = {**_DEFAULTS, **{k.lower(): val for k, val in inputs.items()}}
    G, mu, l1, l2, a = v["g"], v["mu"], v["lambda1"], v["lambda2"], v["alphax"]
    return {
        0: ("none", {}),
        1: ("nhkv", {"G": G, "mu": mu}),
        2: ("qkv", {"G": G, "mu": mu, "alpha": a}),
        3: ("zener", {"G": G, "mu": mu, "lambda1": l1, "lambda2": l2}),
        4: ("qzener", {"G": G, "mu": mu, "alpha": a, "lambda1": l1, "lambda2": l2}),
        5: ("oldroyd-b", {"mu": mu, "lambda1": l1, "lambda2": l2}),
    }[int(v["stress"])]


def options_for(inputs: dict, **overrides) -> ForwardOptions:
    """ForwardOptions reproducing IMRv2's finite-difference solver with these inputs."""
    v = {**_DEFAULTS, **{k.lower(): val for k, val in inputs.items()}}
    kw = dict(scheme="imrv2-fd", radial=_RADIAL[int(v["radial"])],
              bubble="thermal" if v["bubtherm"] else "polytropic", vapor=bool(v["vapor"]),
              mass_transfer=bool(v["masstrans"]), medium="warm" if v["medtherm"] else "cold",
              nt=int(v["nt"]), mt=int(v["mt"]))
    kw.update(overrides)
    return ForwardOptions(**kw)


def load_case(root, case_id: str, **option_overrides) -> ReferenceCase:
    """Load ``<root>/<case_id>.{json,csv}`` (root: shared/reference/imrv2)."""
    root = Path(root)
    record = json.loads((root / f"{case_id}.json").read_text())
    data = np.genfromtxt(root / f"{case_id}.csv", delimiter=",", names=True)
    inputs = record["inputs_passed_to_imrv2"]
    name, params = constitutive_for(inputs)
    model = ForwardModel(name, options=options_for(inputs, **option_overrides))
    low = {k.lower(): v for k, v in inputs.items()}
    return ReferenceCase(case_id, model, params, float(low["r0"]), float(low["req"]),
                         np.asarray(data["t_star"]), np.asarray(data["R_star"]), record)


def relative_l2(a, b) -> float:
    """||a - b|| / ||b||."""
    return float(np.linalg.norm(np.asarray(a) - np.asarray(b)) / np.linalg.norm(np.asarray(b)))
