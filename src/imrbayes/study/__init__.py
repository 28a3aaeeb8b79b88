"""``imrbayes study``: datasets under conditions (material, concentration, temperature, ...), each
fitted as an ordinary run, compared from their posteriors.

Modules: :mod:`spec` (the study file and its checks), :mod:`jobs` (run folders, fingerprints,
scheduling), :mod:`results` (what each run folder says), :mod:`contrasts` (ratios and trends from
draws), :mod:`analysis` (table, differences, conclusion), :mod:`outputs` (files and page),
:mod:`run` (all of it), :mod:`load` (:func:`load_study`).
"""

from imrbayes.study.load import load_study
from imrbayes.study.run import run_study
from imrbayes.study.spec import Condition, StudySpec, read_study_file, study_from_args

__all__ = ["load_study", "run_study", "read_study_file", "study_from_args", "StudySpec", "Condition"]
