"""``segicp``: objects found by a small learned segmentation network on RGB (optionally RGB-D), poses fitted
to depth by coarse rotation search + ICP (needs PyTorch: ``simtest[train]``).

Train the network with ``simtest train segmentation`` (:mod:`simtest.training.segmentation`); a checkpoint for
``builtin-small`` at 320x240 ships in ``simtest/estimators/weights/``. Evaluate with ``simtest eval --estimator
segicp``.

Importing this package does not import torch; building the estimator or training does.
"""

from simtest.estimators.segicp.infer import SegICPEstimator, Segmenter, default_checkpoint, estimate_segmented

__all__ = ["SegICPEstimator", "Segmenter", "default_checkpoint", "estimate_segmented"]
