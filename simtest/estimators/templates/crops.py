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

__all__ = ["Crop", "ray_rotation", "region_crop", "MAX_BOX_POINTS"]

#: Mask pixels used to find a region's box in the virtual camera (a deterministic subsample beyond this).
MAX_BOX_POINTS = 4000


@dataclass(frozen=True)
class Crop:
    """One crop: ``rgb`` (S, S, 3) uint8, ``mask`` (S, S) bool (the region in the crop), ``valid`` (S, S) bool
    (crop pixels that come from inside the image), ``K`` (3, 3) its intrinsics (pixels) and ``R_virt`` (3, 3)
    the rotation from the real camera frame into the crop's camera frame."""

    rgb: np.ndarray
    mask: np.ndarray
    valid: np.ndarray
    K: np.ndarray
    R_virt: np.ndarray


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
    K_crop = crop_intrinsics(K, window, int(size))[0]
    H = K_crop @ R_virt @ np.linalg.inv(K)
    S = int(size)
    out = cv2.warpPerspective(rgb, H, (S, S), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    m = cv2.warpPerspective(mask.astype(np.uint8), H, (S, S), flags=cv2.INTER_NEAREST) > 0
    valid = cv2.warpPerspective(np.ones(mask.shape, np.uint8), H, (S, S), flags=cv2.INTER_NEAREST) > 0
    return Crop(rgb=out, mask=m, valid=valid, K=K_crop, R_virt=R_virt)
