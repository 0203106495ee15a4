"""Pose from rendered templates and frozen ImageNet features (``templates``): no training, RGB only."""

from simtest.estimators.templates.estimator import TemplateEstimator

__all__ = ["TemplateEstimator"]
