"""Training the learned estimators' networks (torch imported when a run starts): one loop, :func:`fit`, that each
network's trainer configures.

| module | owns |
|---|---|
| :mod:`~simtest.training.fit` | the loop: epochs, optimiser and schedule, checkpoints and resume, validation and the best epoch, progress with the time left, ONNX files beside the checkpoints |
| :mod:`~simtest.training.optim` | AdamW with the encoder's learning-rate scale, the warm-up + cosine schedule, one clipped step, frozen encoder batch norms |
| :mod:`~simtest.training.batches` | an epoch's seeded shuffling and data loader, stride-16 padding |
| :mod:`~simtest.training.settings` | the checks every training config shares, its record in the checkpoints |
| :mod:`~simtest.training.keypoints` | ``simtest train keypoints``: the keypoint estimator's networks (crop, full) |
| :mod:`~simtest.training.segmentation` | ``simtest train segmentation``: ``segicp``'s segmentation network |

The old module ``simtest.estimators.training`` imports as this package (a DeprecationWarning), so its names are
all here; ``check_device`` lives in :mod:`simtest.estimators.onnx_net` and ``init_conv_weights`` in
:mod:`simtest.estimators.blocks` (torch), where the networks reach them.
"""

from __future__ import annotations

from typing import Any

from simtest.estimators.onnx_net import check_device
from simtest.training.batches import epoch_generator, epoch_loader, pad16
from simtest.training.fit import Plan, TrainResult, export_beside, fit
from simtest.training.optim import lr_at, make_optimizer, optimizer_step, set_lr, train_mode
from simtest.training.settings import check_encoder_settings, check_settings, settings_dict

__all__ = ["fit", "Plan", "TrainResult", "export_beside", "epoch_generator", "lr_at", "epoch_loader", "pad16",
           "optimizer_step", "check_device", "check_settings", "settings_dict", "init_conv_weights",
           "make_optimizer", "set_lr", "train_mode", "check_encoder_settings"]


def __getattr__(name: str) -> Any:
    """``init_conv_weights`` from :mod:`simtest.estimators.blocks` (torch, imported on first use)."""
    if name == "init_conv_weights":
        from simtest.estimators.blocks import init_conv_weights

        return init_conv_weights
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
