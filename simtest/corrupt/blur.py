"""ImageNet-C blur corruptions (defocus, glass, motion, zoom, gaussian), severities 1..5; see :mod:`simtest.corrupt.weather`."""

from __future__ import annotations

import cv2
import numpy as np

from simtest.corrupt.image_ops import centre_zoom, disk, gaussian, motion_blur_float, to_float, to_uint8

__all__ = ["defocus_blur", "glass_blur", "motion_blur", "zoom_blur", "gaussian_blur"]


def defocus_blur(image: np.ndarray, severity: int, rng: np.random.Generator) -> np.ndarray:
    """Disk-kernel defocus, (radius px, alias sigma) = (3,.1) (4,.5) (6,.5) (8,.5) (10,.5). Deterministic."""
    radius, alias = [(3, 0.1), (4, 0.5), (6, 0.5), (8, 0.5), (10, 0.5)][severity - 1]
    kernel = disk(radius, alias)
    # The reference filters with OpenCV's default border (reflect-101).
    return to_uint8(cv2.filter2D(to_float(image), -1, kernel, borderType=cv2.BORDER_REFLECT_101))


def glass_blur(image: np.ndarray, severity: int, rng: np.random.Generator) -> np.ndarray:
    """Frosted-glass blur: Gaussian blur, ``iters`` rounds of local pixel shuffles by up to ``delta`` px, blur.

    (sigma px, delta px, iters) = (.7,1,2) (.9,2,1) (1,2,3) (1.1,3,2) (1.5,4,2).

    Deviation: the reference swaps every pixel with a random neighbour in a sequential Python loop (minutes
    per megapixel). Here each round is one vectorised gather: every pixel takes the value of a neighbour at an
    offset drawn uniformly from ``[-delta, delta]`` in x and y (clamped to the image), which gives the same
    local scrambling without the loop. The first blur is quantised to uint8 as in the reference.
    """
    sigma, delta, iters = [(0.7, 1, 2), (0.9, 2, 1), (1, 2, 3), (1.1, 3, 2), (1.5, 4, 2)][severity - 1]
    h, w = image.shape[:2]
    x = to_uint8(gaussian(to_float(image), sigma))
    rows = np.arange(h, dtype=np.int32)[:, None]
    cols = np.arange(w, dtype=np.int32)[None, :]
    for _ in range(iters):
        d = rng.integers(-delta, delta + 1, size=(2, h, w), dtype=np.int32)
        x = x[np.clip(rows + d[0], 0, h - 1), np.clip(cols + d[1], 0, w - 1)]
    return to_uint8(gaussian(to_float(x), sigma))


def motion_blur(image: np.ndarray, severity: int, rng: np.random.Generator) -> np.ndarray:
    """Linear motion blur at a random angle in [-45, 45] deg, (radius px, sigma px) = (10,3) (15,5) (15,8)
    (15,12) (20,15).

    Deviation: the reference calls ImageMagick (Wand); here an OpenCV line kernel of ``2 radius + 1`` one-sided
    Gaussian taps (the kernel ImageMagick and ``imagecorruptions`` use) is applied with ``cv2.filter2D``.
    """
    radius, sigma = [(10, 3), (15, 5), (15, 8), (15, 12), (20, 15)][severity - 1]
    angle = rng.uniform(-45.0, 45.0)
    return to_uint8(motion_blur_float(to_float(image), radius, sigma, angle))


def zoom_blur(image: np.ndarray, severity: int, rng: np.random.Generator) -> np.ndarray:
    """Mean of the image and copies zoomed about the centre by ``arange(1, z_max, step)``.

    (z_max, step) = (1.11, .01) (1.16, .01) (1.21, .02) (1.26, .02) (1.31, .03). Deterministic.
    """
    stop, step = [(1.11, 0.01), (1.16, 0.01), (1.21, 0.02), (1.26, 0.02), (1.31, 0.03)][severity - 1]
    factors = np.arange(1.0, stop, step)
    x = to_float(image)
    out = x.copy()
    for z in factors:
        out += centre_zoom(x, float(z))
    return to_uint8(out / np.float32(len(factors) + 1))


def gaussian_blur(image: np.ndarray, severity: int, rng: np.random.Generator) -> np.ndarray:
    """Gaussian blur, sigma = 1 2 3 4 6 px (truncated at 4 sigma, edge-replicated). Deterministic."""
    sigma = [1, 2, 3, 4, 6][severity - 1]
    return to_uint8(gaussian(to_float(image), sigma))
