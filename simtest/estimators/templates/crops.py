"""Object-centred crops through a virtual camera: the same framing for a rendered template and a real region.

A region (a mask in the full image) is looked at by a virtual camera at the real camera's centre, turned so
that its optical axis passes through the region's box centre and then rolled by an in-plane angle; the crop is
the square window around the region's box in that camera (side ``margin`` times the box's longer side),
resampled to ``size`` pixels. The crop is then an exact pinhole image: intrinsics ``K_crop`` (pixels), camera
rotation ``R_virt`` (real camera to virtual camera), and a pose ``(R, t)`` in the real camera is
``(R_virt R, R_virt t)`` in the crop's camera. A template (the object rendered on the optical axis) is the same
construction with ``R_virt`` the identity.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from simtest.estimators.keypoints.crops import crop_intrinsics, crop_window_for_box
from simtest.estimators.templates.views import inplane_rotation
from simtest.errors import ConfigError

__all__ = ["Crop", "ray_rotation", "region_crop", "window_crop", "aimed_crop", "window_centre", "mask_in_crop",
           "MAX_BOX_POINTS"]

#: Mask pixels used to find a region's box in the virtual camera (a deterministic subsample beyond this).
MAX_BOX_POINTS = 4000


@dataclass(frozen=True)
class Crop:
    """One crop: ``rgb`` (S, S, 3) uint8, ``mask`` (S, S) bool (the region in the crop), ``valid`` (S, S) bool
    (crop pixels that come from inside the image), ``K`` (3, 3) its intrinsics (pixels) and ``R_virt`` (3, 3)
    the rotation from the real camera frame into the crop's camera frame; ``window`` ``(x0, y0, side, side)`` is
    the crop's square in the virtual camera's image (pixels at the real focal lengths)."""

    rgb: np.ndarray
    mask: np.ndarray
    valid: np.ndarray
    K: np.ndarray
    R_virt: np.ndarray
    window: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)


def ray_rotation(K: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """The smallest rotation (3, 3) of the camera frame that brings the ray through pixel ``uv`` onto the
    optical axis (``R @ ray`` is along +z)."""
    r = np.linalg.solve(np.asarray(K, np.float64), np.array([uv[0], uv[1], 1.0]))
    r /= np.linalg.norm(r)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(r, z)
    s, c = np.linalg.norm(axis), float(r @ z)
    if s < 1e-12:
        return np.eye(3)
    return cv2.Rodrigues((axis / s * np.arctan2(s, c)).reshape(3, 1))[0]


def _mask_points(mask: np.ndarray) -> np.ndarray:
    v, u = np.nonzero(mask)
    if len(u) > MAX_BOX_POINTS:
        keep = np.linspace(0, len(u) - 1, MAX_BOX_POINTS).astype(np.int64)
        u, v = u[keep], v[keep]
    return np.stack([u, v], axis=1).astype(np.float64)


def region_crop(rgb: np.ndarray, mask: np.ndarray, K: np.ndarray, size: int, margin: float = 1.2,
                inplane_rad: float = 0.0) -> Crop:
    """The crop of the region ``mask`` (H, W) bool of the image ``rgb`` (H, W, 3) with intrinsics ``K``, the
    virtual camera rolled by ``inplane_rad`` about its axis (see the module doc).

    Raises:
        ConfigError: An empty mask, shapes that disagree or a non-positive size or margin.
    """
    mask = np.asarray(mask, bool)
    if mask.shape != rgb.shape[:2] or not mask.any():
        raise ConfigError(f"region_crop: need a non-empty mask of the image's shape {rgb.shape[:2]}, got "
                          f"{mask.shape} with {int(mask.sum())} pixels")
    if int(size) < 8 or not float(margin) > 0:
        raise ConfigError(f"region_crop: need size >= 8 and margin > 0, got {size!r}, {margin!r}")
    K = np.asarray(K, np.float64)
    pts = _mask_points(mask)
    lo, hi = pts.min(0), pts.max(0)
    R_virt = inplane_rotation(inplane_rad) @ ray_rotation(K, 0.5 * (lo + hi))
    H0 = K @ R_virt @ np.linalg.inv(K)  # real pixels -> virtual pixels (the real focal lengths)
    q = cv2.perspectiveTransform(pts.reshape(-1, 1, 2), H0).reshape(-1, 2)
    qlo, qhi = q.min(0), q.max(0)
    window = crop_window_for_box([qlo[0], qlo[1], qhi[0] - qlo[0], qhi[1] - qlo[1]], margin)
    return window_crop(rgb, K, R_virt, window, size, mask)


def window_crop(rgb: np.ndarray, K: np.ndarray, R_virt: np.ndarray, window, size: int,
                mask: np.ndarray | None = None) -> Crop:
    """The crop of ``rgb`` (H, W, 3) seen by the virtual camera ``R_virt`` (real to virtual camera) through the
    square ``window`` ``(x0, y0, side, side)`` of its image (pixels at the real intrinsics ``K``), resampled to
    ``size`` pixels; ``mask`` (H, W) bool is carried along (None: an empty crop mask)."""
    K = np.asarray(K, np.float64)
    S = int(size)
    K_crop = crop_intrinsics(K, window, S)[0]
    H = K_crop @ R_virt @ np.linalg.inv(K)
    out = cv2.warpPerspective(rgb, H, (S, S), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    m = np.zeros((S, S), bool) if mask is None else _warp_mask(mask, H, S)
    valid = _warp_mask(np.ones(rgb.shape[:2], np.uint8), H, S)
    return Crop(rgb=out, mask=m, valid=valid, K=K_crop, R_virt=R_virt, window=tuple(float(v) for v in window))


def _warp_mask(mask: np.ndarray, H: np.ndarray, size: int) -> np.ndarray:
    return cv2.warpPerspective(np.asarray(mask, np.uint8), H, (size, size), flags=cv2.INTER_NEAREST) > 0


def mask_in_crop(mask: np.ndarray, K: np.ndarray, crop: Crop) -> np.ndarray:
    """A mask (H, W) of the real image (intrinsics ``K``) as ``crop`` sees it: (S, S) bool, nearest pixel (the
    warp :func:`window_crop` gives its own ``mask``)."""
    S = int(crop.rgb.shape[0])
    return _warp_mask(mask, crop.K @ crop.R_virt @ np.linalg.inv(np.asarray(K, np.float64)), S)


def aimed_crop(rgb: np.ndarray, K: np.ndarray, uv, side: float, roll_rad: float, size: int) -> Crop:
    """The crop of a virtual camera aimed at the real pixel ``uv`` and rolled by ``roll_rad``, whose window is
    the square of ``side`` pixels (at the real focal lengths) around its principal point: the framing of
    :func:`region_crop` given by a centre and a size instead of a region."""
    K = np.asarray(K, np.float64)
    R_virt = inplane_rotation(roll_rad) @ ray_rotation(K, np.asarray(uv, np.float64))
    cx, cy, s = float(K[0, 2]), float(K[1, 2]), float(side)
    return window_crop(rgb, K, R_virt, (cx - 0.5 * s, cy - 0.5 * s, s, s), size)


def window_centre(crop: Crop, K: np.ndarray) -> np.ndarray:
    """The real image pixel (2,) seen at the centre of ``crop``'s window."""
    x0, y0, side, _ = crop.window
    K = np.asarray(K, np.float64)
    p = K @ crop.R_virt.T @ np.linalg.solve(K, np.array([x0 + 0.5 * side, y0 + 0.5 * side, 1.0]))
    return p[:2] / p[2]
