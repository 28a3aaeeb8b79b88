"""The maintained validation suite: one claim per module, each regenerating its tables (markdown +
JSON) and figures under ``validation/results/<NAME>/``.

    python -m validation NAME [--quick] [--resume] [--out DIR] [claim options]
    python -m validation NAME --help
"""

from __future__ import annotations

import importlib
import sys

#: claim name -> module (in this folder) whose ``main(argv)`` regenerates it
CLAIMS = {
    "calibration": "validation.calibration",
    "confusion": "validation.confusion",
    "realdata": "validation.realdata",
    "mcmc": "validation.mcmc",
    "peers": "validation.peers",
    "range": "validation.range",
    "study_trend": "validation.study_trend",
    "diagnosis_nulls": "validation.diagnosis_nulls",
}


def usage() -> str:
    lines = [__doc__.strip(), "", "Claims:"]
    for name, module in CLAIMS.items():
        doc = importlib.import_module(module).__doc__ or ""
        lines.append(f"  {name:<12} {doc.strip().splitlines()[0] if doc.strip() else ''}")
    return "\n".join(lines)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(usage())
        return 0
    name, rest = argv[0], argv[1:]
    if name not in CLAIMS:
        print(f"python -m validation: unknown claim {name!r}; known: {', '.join(CLAIMS)}", file=sys.stderr)
        return 2
    importlib.import_module(CLAIMS[name]).main(rest)
    return 0


if __name__ == "__main__":
    sys.exit(main())
