"""Scaling bank patches (object cutouts) to an occluder's size and blending their outline into the image.

A cutout is shrunk by area averaging (no aliasing) and enlarged bilinearly; an enlarged mask is blurred by half
its scale before its 0.5 threshold, so its outline follows the shape smoothly instead of the staircase of its
source pixels, and the pixels just outside the pasted mask are blended with the patch (an antialiased edge).
Used by :mod:`simtest.corrupt.occlusion`.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["bank_size", "resample", "bank_coverage", "blend_edge"]


def bank_size(shape: tuple[int, int], r: float) -> tuple[int, int]:
    """``(height, width)`` in pixels of a bank patch of ``shape`` scaled so its longer side spans ``2 r``."""
    ah, aw = shape
    k = 2.0 * r / max(ah, aw)
    return max(1, int(round(ah * k))), max(1, int(round(aw * k)))


def resample(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``image`` resized to ``(height, width)``: area averaging when it shrinks (no aliasing), bilinear when it
    grows."""
    ph, pw = size
    h, w = image.shape[:2]
    interp = cv2.INTER_AREA if ph <= h and pw <= w else cv2.INTER_LINEAR
    return cv2.resize(image, (pw, ph), interpolation=interp)


def bank_coverage(alpha: np.ndarray, r: float) -> np.ndarray:
    """The coverage in ``[0, 1]`` (float32) of a bank shape's bool ``alpha`` scaled to radius ``r`` pixels.

    The mask is resampled (:func:`resample`), and when it is enlarged by ``k > 1`` also blurred by a Gaussian of
    sigma ``k / 2`` output pixels: the 0.5 level of the result follows the shape's outline smoothly instead of
    the staircase of its source pixels (an enlarged cutout would otherwise show them as steps ``k`` pixels
    long). Its ``>= 0.5`` region is the occluder's mask."""
    ph, pw = bank_size(alpha.shape, r)
    a = resample(alpha.astype(np.float32), (ph, pw))
    k = max(ph / alpha.shape[0], pw / alpha.shape[1])
    if k > 1.0:
        a = cv2.GaussianBlur(a, (0, 0), sigmaX=0.5 * k, borderType=cv2.BORDER_CONSTANT)
    return np.clip(a, 0.0, 1.0)


def blend_edge(out: np.ndarray, m: np.ndarray, tex_full: np.ndarray, origin: tuple[int, int]) -> None:
    """Antialias a bank occluder's outline in ``out`` (in place): the pixels just outside its mask ``m`` get
    the texture ``tex_full`` (placed at ``origin`` = (y, x), its border repeated outwards) blended by the
    mask's blurred coverage, so the edge is not a hard pixel step. Pixels of ``m`` itself are pasted opaque by
    the caller (they are the ones counted as occluded)."""
    pad = 3
    h, w = m.shape
    ph, pw = tex_full.shape[:2]
    py0, px0 = origin[0] - pad, origin[1] - pad
    ys0, xs0 = max(py0, 0), max(px0, 0)
    ys1, xs1 = min(py0 + ph + 2 * pad, h), min(px0 + pw + 2 * pad, w)
    if ys1 <= ys0 or xs1 <= xs0:
        return
    region = np.s_[ys0:ys1, xs0:xs1]
    inside = m[region].astype(np.float32)
    cov = cv2.GaussianBlur(inside, (0, 0), sigmaX=0.6, borderType=cv2.BORDER_CONSTANT)
    ring = (cov > 0.02) & (inside == 0)
    if not ring.any():
        return
    tex = np.pad(tex_full, ((pad, pad), (pad, pad), (0, 0)), mode="edge")
    tex = tex[ys0 - py0:ys1 - py0, xs0 - px0:xs1 - px0].astype(np.float32)
    a = cov[ring][:, None]
    dst = out[region]
    dst[ring] = np.clip(a * tex[ring] + (1.0 - a) * dst[ring].astype(np.float32) + 0.5, 0, 255).astype(np.uint8)
