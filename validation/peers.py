"""The forward model against its peers: IMRv2's reference runs and, when installed, PyIMR.

* IMRv2: every reference run of ``--reference`` (default ``../shared/reference/imrv2``) made with
  IMRv2's finite-difference solver and without a caveat, solved by imrbayes with the run's own
  options and grid (tight tolerances); relative L2 and largest |dR*| over t* in [0, 3], and both
  codes' solve times (IMRv2's as its index records it, on its machine).
* PyIMR (the optional ``peers`` extra): the LIC case of ``benchmarks/forward.py --peers`` (timings
  at PyIMR's defaults and R* at both codes' grid limits); skipped with one line when not installed.

``--quick``: the first 3 IMRv2 runs, no PyIMR.
"""

from __future__ import annotations

import csv
import importlib.util
import time
from pathlib import Path

import numpy as np

from validation._common import ROOT, SHARED, failures, parser, run_cases, write_table

NAME = "peers"


def imrv2_case(root: Path, case_id: str) -> callable:
    def run(work: Path) -> dict:
        from imrbayes.forward import reference

        case = reference.load_case(root, case_id, rtol=1e-8, atol=1e-10)
        case.model.simulate(case.params, case.rmax_m, case.req_m, case.t_star[:3])  # compile outside the timing
        t0 = time.perf_counter()
        out = case.model.simulate(case.params, case.rmax_m, case.req_m, case.t_star)
        seconds = time.perf_counter() - t0
        if out.failed[0]:
            raise RuntimeError(out.failure_summary())
        return {
            "peer": "IMRv2",
            "case_id": case_id,
            "rel_l2": reference.relative_l2(out.R_star[0], case.R_star),
            "max_abs_dR": float(np.max(np.abs(out.R_star[0] - case.R_star))),
            "ours_s": seconds,
        }

    return run


def pyimr_rows() -> dict | None:
    """``benchmarks/forward.py``'s PyIMR comparison, or None when PyIMR is not installed."""
    if importlib.util.find_spec("pyimr") is None:
        return None
    spec = importlib.util.spec_from_file_location("forward_benchmark", ROOT / "benchmarks" / "forward.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    return bench.peer_rows()


def main(argv=None) -> None:
    ap = parser(NAME, __doc__)
    ap.add_argument(
        "--reference", type=Path, default=SHARED / "reference" / "imrv2", help="IMRv2 reference folder (index.csv)"
    )
    ap.add_argument("--no-pyimr", action="store_true", help="IMRv2 rows only")
    a = ap.parse_args(argv)
    index = a.reference / "index.csv"
    if not index.exists():
        ap.error(f"--reference {a.reference}: no index.csv")
    with open(index) as fh:
        runs = [r for r in csv.DictReader(fh) if r["solver"] == "imrv2 fd" and not r["caveat"]]
    runs = runs[:3] if a.quick else runs
    wall = {r["case_id"]: float(r["solve_wall_s"]) for r in runs}
    rows = run_cases(
        a.out,
        [(r["case_id"], imrv2_case(a.reference, r["case_id"])) for r in runs],
        a.resume,
        lambda r: f"rel. L2 {r['rel_l2']:.2e}, max |dR*| {r['max_abs_dR']:.2e}",
    )
    table = [{**r, "imrv2_s": wall.get(r["case_id"])} for r in rows if r["status"] == "ok"]
    meta = {"reference": str(a.reference), "quick": a.quick, "failed_cases": failures(rows)}
    if a.quick or a.no_pyimr:
        meta["pyimr"] = "not run (--quick or --no-pyimr)"
    else:
        peer = pyimr_rows()
        if peer is None:
            print("PyIMR: not installed (pip install 'imrbayes[peers]'); its rows are skipped", flush=True)
            meta["pyimr"] = "not installed; skipped"
        else:
            meta["pyimr_detail"] = peer
            for label, c in peer["limits"].items():
                table.append(
                    {
                        "peer": f"PyIMR {peer['version']}",
                        "case_id": f"LIC thermal, grid limits ({label})",
                        "rel_l2": c["to_our_limit"],
                        "max_abs_dR": c["max_abs_Rstar"],
                        "ours_s": peer["ours_single_ms"] / 1e3,
                        "peer_s": peer["single_ms"] / 1e3,
                    }
                )
    write_table(
        a.out,
        "peers",
        "The forward model against IMRv2 and PyIMR",
        {
            "peer": "peer",
            "case_id": "case",
            "rel_l2": "relative L2 in R*",
            "max_abs_dR": "max abs dR*",
            "ours_s": "imrbayes solve [s]",
            "imrv2_s": "IMRv2 solve [s] (its machine)",
            "peer_s": "PyIMR solve [s]",
        },
        table,
        meta,
    )


if __name__ == "__main__":
    main()
