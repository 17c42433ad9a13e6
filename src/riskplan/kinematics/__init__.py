"""Learned probabilistic kinematics: Gaussian mixtures and the mixture density network
(MDN paper, sections III-IV).

``load_model(path or shipped name, e.g. "paper") -> MDNModel``; ``model.predict(displacements (..., m)) -> GaussianMixture``.
"""

from riskplan.kinematics.mdn import MDN, MDNModel, Normalisation
from riskplan.kinematics.model_io import load_model, resolve_model, save_model, shipped_models
from riskplan.kinematics.torch_mixture import GaussianMixture
from riskplan.kinematics.training import TrainConfig, train

__all__ = [
    "MDN",
    "GaussianMixture",
    "MDNModel",
    "Normalisation",
    "TrainConfig",
    "load_model",
    "resolve_model",
    "save_model",
    "shipped_models",
    "train",
]
