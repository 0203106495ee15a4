"""Colour pictures of a scene's per-pixel channels: depth and, when a scene folder holds them, the dense
ground-truth channels.

Dense channels (each ``SCENE/<channel>/{im:06d}.png``, 16-bit PNG):

* ``instances/``: uint16 (H, W); 0 = background, ``k + 1`` = the ``k``-th instance of ``scene_gt.json``.
* ``coords/``: uint16 (H, W, 3) model coordinates normalized by the model's bounding box, 0 = no object.
* ``normals/``: uint16 (H, W, 3) camera-frame unit normals as ``(n + 1) / 2 * 65535``.
* ``flow/``: KITTI 16-bit optical flow to the next image, pixels: ``u = (R - 2^15) / 64``,
  ``v = (G - 2^15) / 64``, ``B`` = valid.

All pictures returned are RGB uint8 (H, W, 3), pixel for pixel aligned with the camera image.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from simtest.errors import DatasetError
from simtest.io import dense
from simtest.viz.draw import palette

__all__ = ["DENSE_CHANNELS", "Colourized", "colourize_depth", "colourize_instances", "colourize_coords",
           "colourize_normals", "colourize_flow", "read_dense_channel", "dense_panels"]

#: Dense channel folders looked for in a scene folder, in the order they are shown (the files' formats:
#: :mod:`simtest.io.dense`).
DENSE_CHANNELS: tuple[str, ...] = dense.CHANNEL_FOLDERS


@dataclass(frozen=True)
class Colourized:
    """A colour picture of a channel and the one-line caption that says how to read it."""

    image: np.ndarray
    caption: str


def colourize_depth(depth_m: np.ndarray, range_m: tuple[float, float] | None = None) -> Colourized:
    """Depth (H, W), metres, 0 = missing, as the turbo colour map from the 1st to the 99th percentile of the
    valid depths, or over ``range_m`` (e.g. another image's, for one scale across images; near = blue, far =
    red); missing pixels black."""
    d = np.asarray(depth_m, dtype=np.float32)
    valid = d > 0
    out = np.zeros((*d.shape, 3), dtype=np.uint8)
    if not valid.any():
        return Colourized(out, "depth: no valid pixel")
    lo, hi = np.percentile(d[valid], [1, 99]) if range_m is None else range_m
    hi = max(float(hi), float(lo) + 1e-6)
    g = np.clip((d - lo) / (hi - lo) * 255.0, 0, 255).astype(np.uint8)
    col = cv2.applyColorMap(g, cv2.COLORMAP_TURBO)[..., ::-1]
    out[valid] = col[valid]
    holes = int((~valid).sum())
    return Colourized(out, f"depth {lo:.2f}-{hi:.2f} m (blue near, red far), "
                           f"{holes / d.size * 100:.1f}% holes (black)")


def colourize_instances(inst: np.ndarray) -> Colourized:
    """Instance ids (H, W), 0 = background, ``k + 1`` = instance ``k``, in the instance colours of the RGB
    panel (:func:`simtest.viz.draw.palette`); background black."""
    ids = np.asarray(inst).astype(np.int64)
    n = int(ids.max()) if ids.size else 0
    lut = np.zeros((n + 1, 3), dtype=np.uint8)
    for k in range(n):
        lut[k + 1] = palette(k)
    return Colourized(lut[ids], f"instances: {len(np.unique(ids[ids > 0]))} (colours as the contours)")


def colourize_coords(coords: np.ndarray) -> Colourized:
    """Normalized model coordinates (H, W, 3) uint16 as RGB = (x, y, z) scaled to 0..255; 0 = none (black)."""
    c = np.asarray(coords)
    return Colourized((c // 257).astype(np.uint8), "model coords (RGB = x, y, z in the model box)")


def colourize_normals(normals: np.ndarray) -> Colourized:
    """Camera-frame normals stored as ``(n + 1) / 2 * 65535`` (H, W, 3) as RGB = (x, y, z) 0..255; pixels
    stored as 0 (no surface) black."""
    c = np.asarray(normals)
    out = (c // 257).astype(np.uint8)
    out[(c == 0).all(axis=-1)] = 0
    return Colourized(out, "normals, camera frame (RGB = x right, y down, z forward)")


def colourize_flow(flow: np.ndarray, valid: np.ndarray | None = None) -> Colourized:
    """Optical flow (H, W, 2), pixels, on the usual HSV colour wheel: hue = direction, brightness = length
    relative to the largest valid length (its 99th percentile); invalid pixels black."""
    f = np.asarray(flow, dtype=np.float32)
    valid = np.ones(f.shape[:2], dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    mag, ang = cv2.cartToPolar(f[..., 0], f[..., 1])
    top = float(np.percentile(mag[valid], 99)) if valid.any() else 0.0
    hsv = np.zeros((*f.shape[:2], 3), dtype=np.uint8)
    hsv[..., 0] = (ang * (90.0 / np.pi)).astype(np.uint8)  # OpenCV hue: 0..180
    hsv[..., 1] = 255
    hsv[..., 2] = np.clip(mag / max(top, 1e-6) * 255.0, 0, 255).astype(np.uint8)
    rgb = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)
    rgb[~valid] = 0
    return Colourized(rgb, f"flow to next image (hue = direction, max {top:.1f} px)")


def read_dense_channel(scene_dir: Path, channel: str, im_id: int) -> np.ndarray | None:
    """The stored array of ``channel`` for image ``im_id`` (:func:`simtest.io.dense.read_channel`: 3-channel
    images in RGB order), or None when the scene has no such file.

    Raises:
        DatasetError: The file exists but is not a 16-bit PNG.
    """
    try:
        raw = dense.read_channel(scene_dir, channel, im_id)
    except FileNotFoundError:
        return None
    if raw.dtype != np.uint16:
        raise DatasetError(f"{Path(scene_dir) / channel / f'{int(im_id):06d}.png'}: expected a 16-bit PNG")
    return raw


def dense_panels(scene_dir: Path, im_id: int) -> list[tuple[str, Colourized]]:
    """``(channel, picture)`` of every dense channel the scene folder holds for ``im_id``, in
    :data:`DENSE_CHANNELS` order; none when the folders are absent."""
    out = []
    for name in DENSE_CHANNELS:
        raw = read_dense_channel(scene_dir, name, im_id)
        if raw is None:
            continue
        if name == "instances":
            out.append((name, colourize_instances(raw if raw.ndim == 2 else raw[..., 0])))
        elif name == "coords":
            out.append((name, colourize_coords(raw)))
        elif name == "normals":
            out.append((name, colourize_normals(raw)))
        else:
            out.append((name, colourize_flow(*dense.decode_flow(raw))))
    return out
