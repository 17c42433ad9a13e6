"""Learned probabilistic kinematics: Gaussian mixtures and the mixture density network
(MDN paper, sections III-IV)."""

from riskplan.kinematics.mixture import GaussianMixture

__all__ = ["GaussianMixture"]
