"""Measured data in: loaders, checks, preprocessing (interfaces.md §1).

>>> ds = load_dataset("shared/data/lic/estrada2018_stiffPA_270kfps")
>>> pre = preprocess_dataset(ds)            # dt* = 0.025, 120 steps
>>> pre.t_star.shape, pre.R_star.shape, pre.P.shape
((121,), (20, 121), (121,))
"""

from imrbayes.data.loaders import load_dataset
from imrbayes.data.noise import noise_variance, paper_sigma
from imrbayes.data.pipeline import ExperimentSummary, Preprocessed, preprocess_dataset
from imrbayes.data.records import Dataset, Experiment

__all__ = [
    "load_dataset",
    "preprocess_dataset",
    "Dataset",
    "Experiment",
    "Preprocessed",
    "ExperimentSummary",
    "noise_variance",
    "paper_sigma",
]
