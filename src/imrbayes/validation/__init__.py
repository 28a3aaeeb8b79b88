"""Synthetic validation suite (``imrbayes validate``): the methods.md §5 verification case and
recovery checks of every method, each with a pass/fail criterion.

>>> report = run_suite("quick", out_dir, seed=0)
>>> report["passed"], [c["name"] for c in report["cases"]]
"""

from imrbayes.validation.suite import CASES, SUITES, run_suite, verification_data

__all__ = ["CASES", "SUITES", "run_suite", "verification_data"]
