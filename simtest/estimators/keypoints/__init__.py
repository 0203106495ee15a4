"""Confidence-based keypoint 6D pose estimation from single RGB images (needs PyTorch: ``simtest[train]``).

A fully-convolutional network predicts, per stride-4 cell, the object class and the 2D offsets of the object's
projected keypoints (the 8 bbox corners by default) with a learned confidence per keypoint, trained with the
KL-derived loss ``c |g - e|_1 - log c`` (:mod:`.loss`). Inference fuses the most confident predictions per
keypoint and solves PnP (:mod:`.infer`). Train with ``simtest train keypoints`` (:mod:`.train`); evaluate with
``simtest eval --estimator keypoints --opt checkpoint=run/model.pt``.

Importing this package does not import torch; building the estimator or training does.
"""

from simtest.estimators.keypoints.checkpoint import check_objects, load_checkpoint, object_record, save_checkpoint
from simtest.estimators.keypoints.infer import KeypointEstimator, fuse_keypoints, mask_cells, solve_pnp

__all__ = ["KeypointEstimator", "fuse_keypoints", "solve_pnp", "mask_cells", "check_objects", "load_checkpoint",
           "object_record", "save_checkpoint"]
