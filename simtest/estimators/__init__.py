"""Pose estimators: the plug-in API and CPU baselines (``oracle``, ``icp``, ``umeyama``)."""

from simtest.estimators.base import (ESTIMATORS, Estimator, Observation, PoseEstimate, load_estimator,
                                     register_estimator)

__all__ = ["ESTIMATORS", "Estimator", "Observation", "PoseEstimate", "load_estimator", "register_estimator"]
