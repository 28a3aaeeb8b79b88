"""Constitutive models of the material around the bubble, one module each (see base.py)."""

from imrbayes.forward.constitutive.base import ConstitutiveModel, Parameter, available_models, canonical_name, get_model

__all__ = ["ConstitutiveModel", "Parameter", "available_models", "canonical_name", "get_model"]
