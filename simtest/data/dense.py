"""Dense ground-truth channels of a sample (files written by ``simtest generate --channels``), read for a feed.

Sample keys (numpy here; :class:`~simtest.data.PoseDataset` turns them into tensors, channels first):

==================  ==================  =================================================================
key                 numpy               meaning
==================  ==================  =================================================================
``instances``       int64 (H, W)        0 background, ``k + 1`` the sample's ``k``-th instance (its masks)
``coords``          float32 (H, W, 3)   model-frame coordinates of the visible surface point, metres
``coords_mask``     bool (H, W)         where ``coords`` holds a point
``normals``         float32 (H, W, 3)   unit surface normals, OpenCV camera frame; 0 where nothing is hit
``flow``            float32 (H, W, 2)   forward flow to the next image (pixels); 0 where invalid
``flow_valid``      bool (H, W)         where the flow is valid (all False for a scene's last image)
==================  ==================  =================================================================

After the feed's transforms, ``instances`` and ``coords_mask`` follow the (possibly occluded) visible masks; the
normals and flow describe the rendered surfaces (a pasted occluder does not appear in them).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from simtest.errors import ConfigError, DatasetError

__all__ = ["DENSE_CHANNELS", "DENSE_KEYS", "check_channels", "load_channels", "masks_to_instances"]

#: Channels a feed can read (the keypoints channel lives in JSON and is not an image).
DENSE_CHANNELS = ("instances", "coords", "normals", "flow")
#: Sample keys per channel.
DENSE_KEYS = {"instances": ("instances",), "coords": ("coords", "coords_mask"), "normals": ("normals",),
              "flow": ("flow", "flow_valid")}


def check_channels(channels) -> tuple[str, ...]:
    """The channel names as a tuple; ConfigError naming a bad one and the valid ones."""
    out = tuple(channels or ())
    bad = [c for c in out if c not in DENSE_CHANNELS]
    if bad:
        raise ConfigError(f"unknown dense channel {bad[0]!r}; valid: {', '.join(DENSE_CHANNELS)}")
    return out


def masks_to_instances(masks: np.ndarray) -> np.ndarray:
    """(H, W) int64 instance map (0 background, ``k + 1``) of (N, H, W) disjoint visible masks."""
    out = np.zeros(masks.shape[1:], np.int64)
    for k, m in enumerate(masks):
        out[m] = k + 1
    return out


def load_channels(scene_dir: str | Path, im_id: int, channels: tuple[str, ...], masks: np.ndarray,
                  bboxes: list[tuple[np.ndarray, np.ndarray]]) -> dict[str, np.ndarray]:
    """The asked channels of one image as numpy arrays (keys: :data:`DENSE_KEYS`).

    Args:
        masks: (N, H, W) the sample's visible masks (which pixels belong to which instance).
        bboxes: Per instance ``(bbox_min (3,), bbox_size (3,))`` metres of its model (how coords are encoded).

    Raises:
        DatasetError: A channel's file is missing (the dataset was generated without it), except a scene's last
            flow image, which does not exist by design.
    """
    from simtest.io import dense

    h, w = masks.shape[1:]
    out: dict[str, np.ndarray] = {}
    for name in channels:
        try:
            img = dense.read_channel(scene_dir, name, im_id)
        except FileNotFoundError as exc:
            if name == "flow" and (Path(scene_dir) / "flow").is_dir():
                out["flow"], out["flow_valid"] = np.zeros((h, w, 2), np.float32), np.zeros((h, w), bool)
                continue
            raise DatasetError(f"{exc}; generate the dataset with --channels {name} to read it") from None
        if name == "instances":
            out["instances"] = img.astype(np.int64)
        elif name == "coords":
            coords = np.zeros((h, w, 3), np.float32)
            have = np.zeros((h, w), bool)
            for m, (lo, size) in zip(masks, bboxes):
                m = m & img.any(-1)
                coords[m] = dense.decode_coords(img[m], lo, size)
                have |= m
            out["coords"], out["coords_mask"] = coords, have
        elif name == "normals":
            out["normals"] = np.nan_to_num(dense.decode_normals(img)).astype(np.float32)
        else:
            flow, valid = dense.decode_flow(img)
            out["flow"], out["flow_valid"] = np.where(valid[..., None], flow, 0.0).astype(np.float32), valid
    return out
