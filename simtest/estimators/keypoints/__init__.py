"""Confidence-based keypoint 6D pose estimation from single RGB images (training needs PyTorch: ``simtest[train]``).

``keypoints`` (:class:`KeypointEstimator`, :mod:`.crop_infer`): a detector finds each object (the shipped RGB-only
segmentation network, segicp's RGB-D one, or ground-truth boxes), a square crop around its box is resampled to
128 x 128 pixels (:mod:`.crops`: ``K' = M K``), and a small network (:mod:`.crop_model`) predicts per stride-4 cell
an object-mask logit and the offsets of the object's projected keypoints (the 8 bbox corners) with a learned
confidence, trained with the KL-derived loss ``c |g - e|_1 - log c`` (:mod:`.loss`). The most confident
predictions are fused per keypoint, mapped back to the full image and PnP gives the pose.

``keypoints-full`` (:class:`FullImageKeypointEstimator`, :mod:`.infer`): the first network, on whole images at
stride 4 (:mod:`.model`). Both train with ``simtest train keypoints`` (:mod:`simtest.training.keypoints`,
``--arch crop|full``).

Importing this package does not import torch; building a torch network or training does.
"""

from simtest.estimators.checkpoint import check_objects, object_record, save_checkpoint
from simtest.estimators.keypoints.checkpoint import load_checkpoint
from simtest.estimators.keypoints.crop_infer import CropKeypointEstimator
from simtest.estimators.keypoints.crops import crop_intrinsics, crop_window_for_box
from simtest.estimators.keypoints.infer import KeypointEstimator as FullImageKeypointEstimator
from simtest.estimators.keypoints.infer import fuse_keypoints, mask_cells, solve_pnp

#: The registered ``keypoints`` estimator.
KeypointEstimator = CropKeypointEstimator

__all__ = ["KeypointEstimator", "CropKeypointEstimator", "FullImageKeypointEstimator", "fuse_keypoints",
           "solve_pnp", "mask_cells", "check_objects", "load_checkpoint", "object_record", "save_checkpoint",
           "crop_intrinsics", "crop_window_for_box"]
