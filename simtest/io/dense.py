"""Files of the dense ground-truth channels: 16-bit PNGs readable with OpenCV or numpy alone.

In each scene folder, one PNG per image (``{im:06d}.png``); channel order as stored in the file (R, G, B):

=============  =========================  ======================================================================
folder         pixel                      meaning
=============  =========================  ======================================================================
``instances``  uint16, 1 channel          0 background, ``k + 1`` = the ``k``-th instance of ``scene_gt.json``
                                          (its visible surface; equal to ``mask_visib/{im}_{k:06d}.png``)
``coords``     uint16, 3 channels         model-frame coordinates of the visible surface point, per object
                                          normalized by its bbox in ``models_info.json``: ``min_x .. min_x +
                                          size_x -> 1 .. 65535`` (same for y, z); 0 where no object
``normals``    uint16, 3 channels         unit surface normal in the OpenCV camera frame, ``(n + 1) / 2 * 65535``,
                                          every rendered surface; 0 (all three) where nothing is hit
``flow``       uint16, 3 channels         forward flow to the next image, KITTI's format: ``u = (R - 2^15) / 64``,
                                          ``v = (G - 2^15) / 64`` pixels, ``B = 1`` valid (the point is visible in
                                          both images); no file for a scene's last image
=============  =========================  ======================================================================

Reading a 3-channel file with OpenCV gives B, G, R order (``cv2.imread(path, cv2.IMREAD_UNCHANGED)[..., ::-1]``
is R, G, B). This module is the only place that knows these encodings; metres everywhere else.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

__all__ = ["CHANNEL_FOLDERS", "encode_instances", "encode_coords", "decode_coords", "encode_normals",
           "decode_normals", "encode_flow", "decode_flow", "read_channel", "nocs_from_coords", "COORD_MAX",
           "write_png16"]

#: The image channels and their folder names (``keypoints`` go to JSON, not images).
CHANNEL_FOLDERS = ("instances", "coords", "normals", "flow")
#: Largest coordinate code (``min + size`` maps to it; 1 is ``min``; 0 means no object).
COORD_MAX = 65535
_FLOW_SCALE = 64.0
_FLOW_ZERO = 2 ** 15


def encode_instances(index: np.ndarray) -> np.ndarray:
    """(H, W) instance codes (0 background, ``k + 1``) as the uint16 image."""
    return np.asarray(index, np.uint16)


def encode_coords(coords: np.ndarray, valid: np.ndarray, bbox_min: np.ndarray, bbox_size: np.ndarray) -> np.ndarray:
    """Model-frame coordinates (H, W, 3) metres -> the uint16 image; ``bbox_min`` / ``bbox_size`` (H, W, 3)
    metres per pixel (of the pixel's object), ``valid`` (H, W) bool where an object is seen."""
    t = (np.asarray(coords, np.float64) - bbox_min) / np.maximum(bbox_size, 1e-12)
    code = 1.0 + np.rint(np.clip(t, 0.0, 1.0) * (COORD_MAX - 1))
    out = np.where(valid[..., None], code, 0.0).astype(np.uint16)
    return out


def decode_coords(image: np.ndarray, bbox_min: np.ndarray, bbox_size: np.ndarray) -> np.ndarray:
    """The uint16 image (R, G, B order) -> model-frame coordinates, metres, for pixels of one object
    (``bbox_min`` / ``bbox_size`` (3,) metres, from ``models_info.json`` / 1000); NaN where the code is 0."""
    img = np.asarray(image, np.float64)
    out = (img - 1.0) / (COORD_MAX - 1) * np.asarray(bbox_size, np.float64) + np.asarray(bbox_min, np.float64)
    return np.where(img > 0, out, np.nan)


def nocs_from_coords(coords: np.ndarray, bbox_min: np.ndarray, bbox_size: np.ndarray) -> np.ndarray:
    """Model coordinates (..., 3) metres -> NOCS: centred on the bbox centre and divided by the bbox diagonal,
    then shifted by 0.5, so the object lies inside the unit cube ``[0, 1]^3`` (the NOCS dataset's convention)."""
    size = np.asarray(bbox_size, np.float64)
    centre = np.asarray(bbox_min, np.float64) + size / 2.0
    return (np.asarray(coords, np.float64) - centre) / float(np.linalg.norm(size)) + 0.5


def encode_normals(normals: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Unit normals (H, W, 3), camera frame -> the uint16 image (0 where not ``valid``)."""
    code = np.rint((np.clip(normals, -1.0, 1.0) + 1.0) / 2.0 * 65535.0)
    return np.where(valid[..., None], code, 0.0).astype(np.uint16)


def decode_normals(image: np.ndarray) -> np.ndarray:
    """The uint16 image (R, G, B order) -> unit normals (H, W, 3), NaN where nothing is hit."""
    img = np.asarray(image, np.float64)
    n = img / 65535.0 * 2.0 - 1.0
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    return np.where(img.any(-1, keepdims=True), n, np.nan)


def encode_flow(flow: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Flow (H, W, 2) pixels (u, v) -> KITTI's uint16 image (R, G, B = u, v, valid); flow beyond +-512 px is
    clipped and marked invalid."""
    code = np.rint(np.asarray(flow, np.float64) * _FLOW_SCALE + _FLOW_ZERO)
    ok = valid & np.all((code >= 0) & (code <= 65535), axis=-1)
    out = np.zeros(flow.shape[:2] + (3,), np.uint16)
    out[..., :2] = np.where(ok[..., None], np.clip(code, 0, 65535), 0).astype(np.uint16)
    out[..., 2] = ok
    return out


def decode_flow(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """KITTI's uint16 image (R, G, B order) -> ``(flow (H, W, 2) pixels, valid (H, W) bool)``."""
    img = np.asarray(image, np.float64)
    return (img[..., :2] - _FLOW_ZERO) / _FLOW_SCALE, img[..., 2] > 0


def write_png16(path: Path, image: np.ndarray) -> bytes:
    """The PNG bytes of a uint16 image (1 or 3 channels, the latter in R, G, B order)."""
    img = image if image.ndim == 2 else np.ascontiguousarray(image[..., ::-1])
    ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 3])
    if not ok:
        raise OSError(f"could not encode {path}")
    return buf.tobytes()


def read_channel(scene_dir: str | Path, channel: str, im_id: int) -> np.ndarray:
    """A channel's image as stored (uint16; 3-channel images in R, G, B order).

    Raises:
        FileNotFoundError: The scene has no such file (the channel was not generated, or the last image's flow).
    """
    path = Path(scene_dir) / channel / f"{int(im_id):06d}.png"
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) if path.is_file() else None
    if img is None:
        raise FileNotFoundError(f"{path}: no such {channel} image")
    return img if img.ndim == 2 else img[..., ::-1]
