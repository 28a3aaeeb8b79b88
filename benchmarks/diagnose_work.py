"""Where a diagnosis spends its forward work: member runs and integrator steps per stage and caller.

Runs ``imrbayes diagnose`` in this process with every ``ForwardModel.propagate`` call counted
(members, integrator steps, wall time), attributed to the stage the diagnosis was in and to the
last three imrbayes functions outside ``forward/`` on the call stack. Steps are the load-independent
measure of cost (wall time depends on what else runs on the machine); #21's runtime target is
judged on a quiet machine's wall time, this says where to cut. docs/diagnosis.md, Runtime.

Usage (the arguments after ``--`` are diagnose's own):

    python benchmarks/diagnose_work.py --json work.json -- ../shared/data/lic/estrada2018_stiffPA_270kfps \\
        --experiments 1,2,3,4,5 --seed 0 --out /tmp/prof
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
import time
import traceback

import numpy as np

from _machine import machine_info


def _caller() -> str:
    names = [f"{fr.filename.rsplit('/', 1)[-1][:-3]}.{fr.name}" for fr in traceback.extract_stack()[:-2]
             if "/imrbayes/" in fr.filename and "/forward/" not in fr.filename]
    return " > ".join(names[-3:])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", default=None, help="write the rows here")
    ap.add_argument("diagnose_args", nargs=argparse.REMAINDER, help="-- then diagnose's arguments")
    a = ap.parse_args(argv)
    args = a.diagnose_args[1:] if a.diagnose_args[:1] == ["--"] else a.diagnose_args
    if not args:
        ap.error("give diagnose's arguments after --")

    import imrbayes.diagnosis as diagnosis
    import imrbayes.forward.model as model
    from imrbayes.cli import main as cli

    stage = ["(before the first stage)"]
    rec = collections.defaultdict(lambda: [0, 0, 0.0, 0])      # members, steps, wall [s], calls
    propagate = model.ForwardModel.propagate

    def counted(self, state, params, t_end, t_eval=None, **kw):
        t = time.perf_counter()
        out = propagate(self, state, params, t_end, t_eval, **kw)
        r = rec[(stage[0], _caller())]
        r[0] += int(state.n)
        r[1] += int(np.sum(out.n_steps))
        r[2] += time.perf_counter() - t
        r[3] += 1
        return out

    run = diagnosis.diagnose

    def staged(*args_, log=None, **kw):
        def log_stage(msg):
            stage[0] = msg
            if log is not None:
                log(msg)
        return run(*args_, log=log_stage, **kw)

    model.ForwardModel.propagate = counted
    diagnosis.diagnose = staged          # the CLI imports it from the package at call time
    t0 = time.perf_counter()
    try:
        cli(["diagnose", *args], standalone_mode=False)
    finally:
        model.ForwardModel.propagate, diagnosis.diagnose = propagate, run
    wall = time.perf_counter() - t0
    rows = [{"stage": s, "caller": c, "members": v[0], "steps": v[1], "wall_s": v[2], "calls": v[3]}
            for (s, c), v in rec.items()]
    total = sum(r["steps"] for r in rows) or 1
    by_stage = collections.defaultdict(lambda: [0, 0, 0.0])
    for r in rows:
        b = by_stage[r["stage"]]
        b[0], b[1], b[2] = b[0] + r["members"], b[1] + r["steps"], b[2] + r["wall_s"]
    print(f"{'stage':60s} {'members':>8s} {'steps':>10s} {'share':>6s} {'solve s':>8s}")
    for s, (m, st, w) in by_stage.items():
        print(f"{s[:60]:60s} {m:8d} {st:10d} {100 * st / total:5.1f}% {w:8.1f}")
    print(f"\n{'steps':>10s} {'members':>8s} {'calls':>6s}  stage / caller (largest 20)")
    for r in sorted(rows, key=lambda r: -r["steps"])[:20]:
        print(f"{r['steps']:10d} {r['members']:8d} {r['calls']:6d}  {r['stage'][:28]} / {r['caller']}")
    print(f"\ntotal: {sum(r['members'] for r in rows)} member runs, {total} steps, {wall:.0f} s wall")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump({"diagnose_args": args, "wall_s": wall, "machine": machine_info(), "rows": rows}, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
