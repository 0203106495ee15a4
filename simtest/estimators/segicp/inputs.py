"""What the segmentation network's input looks like, shared by training (torch) and inference (numpy, ONNX):
the relative depth channel and the padding of input sizes. Torch-free."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["DEPTH_RANGE_M", "depth_channel_np", "size_multiple"]

#: Half-range (metres) of the relative depth input channel of the network (torch and numpy alike).
DEPTH_RANGE_M = 0.25


def depth_channel_np(depth: np.ndarray) -> np.ndarray:
    """numpy twin of :func:`simtest.estimators.segicp.model.depth_channel` for one (H, W) image in metres: the
    depth relative to the median of the valid depth (torch's median: the lower middle value of an even count),
    clipped to +-``DEPTH_RANGE_M`` and divided by it, 0 where depth is missing."""
    out = np.zeros(depth.shape, np.float32)
    valid = depth > 0
    v = depth[valid].astype(np.float32)
    if v.size:
        k = (v.size - 1) // 2
        med = np.partition(v, k)[k]
        rel = np.clip(depth.astype(np.float32) - med, -DEPTH_RANGE_M, DEPTH_RANGE_M) / np.float32(DEPTH_RANGE_M)
        out[valid] = rel[valid]
    return out


def size_multiple(net: dict[str, Any]) -> int:
    """The multiple (pixels) that a network's input height and width are padded to, from its config dict
    (a checkpoint's ``net``): 32 for the EfficientNet encoder (its fixed TensorFlow padding), 16 for the plain
    one."""
    return 32 if net.get("backbone", "plain") != "plain" else 16
