"""``load_study(DIR)``: a study's table as a pandas DataFrame."""

from __future__ import annotations

from pathlib import Path

from imrbayes.errors import InputError

__all__ = ["load_study"]


def load_study(path):
    """The table of the study in folder ``path`` (written by ``imrbayes study``): one row per
    condition, its labels, G and mu [SI] with 95 % intervals, between-bubble sd, bubbles, fit check,
    diagnose verdict.

    Returns
    -------
    pandas.DataFrame
        Indexed by condition name.
    """
    import pandas as pd

    csv = Path(path) / "study.csv"
    if not csv.is_file():
        raise InputError(path, "no study.csv (is this a folder written by 'imrbayes study'?)")
    return pd.read_csv(csv).set_index("condition")
