"""Pose estimators: the plug-in API and CPU baselines (``oracle``, ``icp``, ``umeyama``)."""

from simtest.estimators.base import Estimator, Observation, PoseEstimate
from simtest.estimators.registry import ESTIMATORS, load_estimator, register_estimator

#: The zoom-in keypoint estimator is ``keypoints``; the first, whole-image keypoint network stays available.
register_estimator("keypoints", "simtest.estimators.keypoints:CropKeypointEstimator")
register_estimator("keypoints-full", "simtest.estimators.keypoints:FullImageKeypointEstimator")

__all__ = ["ESTIMATORS", "Estimator", "Observation", "PoseEstimate", "load_estimator", "register_estimator"]
