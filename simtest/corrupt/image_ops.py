"""Pieces the ImageNet-C corruptions share: float/uint8 conversion, blurs, zoom, motion kernels, the plasma
fractal, disk kernels and HSV value/saturation. Images are ``float32`` in ``[0, 1]`` between :func:`to_float` and
:func:`to_uint8`."""

from __future__ import annotations

import cv2
import numpy as np

from simtest.errors import ConfigError

__all__ = ["to_float", "to_uint8", "gaussian", "centre_zoom", "motion_kernel", "motion_blur_float", "plasma_fractal",
           "next_pow2", "disk", "rgb_value_saturation"]


def to_float(image: np.ndarray) -> np.ndarray:
    """uint8 image -> ``float32`` in ``[0, 1]``."""
    return image.astype(np.float32) * np.float32(1.0 / 255.0)


def to_uint8(x: np.ndarray) -> np.ndarray:
    """``[0, 1]`` float -> uint8, clipped and rounded to nearest."""
    return np.clip(np.rint(x * 255.0), 0, 255).astype(np.uint8)


def gaussian(x: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian filter matching ``skimage.filters.gaussian`` (truncate 4 sigma, edge-replicated border)."""
    k = 2 * int(4.0 * sigma + 0.5) + 1
    return cv2.GaussianBlur(x, (k, k), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REPLICATE)


def centre_zoom(x: np.ndarray, factor: float) -> np.ndarray:
    """Zoom in by ``factor`` (>= 1) about the image centre, bilinear, same output size (``clipped_zoom``)."""
    h, w = x.shape[:2]
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    M = np.array([[factor, 0.0, (1.0 - factor) * cx], [0.0, factor, (1.0 - factor) * cy]], dtype=np.float64)
    out = cv2.warpAffine(x, M, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(x.shape)


def motion_kernel(radius: int, sigma: float, angle_deg: float) -> tuple[np.ndarray, tuple[int, int]]:
    """One-sided Gaussian line kernel of ImageMagick's ``-motion-blur radius x sigma + angle``.

    Width ``2 radius + 1`` taps with weights ``exp(-i^2 / (2 sigma^2))``, ``i = 0 .. 2 radius``, laid along
    ``angle_deg`` (image x axis, y down) and rounded to the pixel grid, as ``imagecorruptions`` does.

    Returns:
        ``(kernel, anchor)`` for ``cv2.filter2D``; the kernel is cropped to its non-zero box.
    """
    width = 2 * int(radius) + 1
    i = np.arange(width, dtype=np.float64)
    weights = np.exp(-(i ** 2) / (2.0 * sigma ** 2))
    weights /= weights.sum()
    a = np.deg2rad(angle_deg)
    dx = np.rint(i * np.cos(a)).astype(int)
    dy = np.rint(i * np.sin(a)).astype(int)
    x0, y0 = dx.min(), dy.min()
    kernel = np.zeros((dy.max() - y0 + 1, dx.max() - x0 + 1), dtype=np.float32)
    np.add.at(kernel, (dy - y0, dx - x0), weights.astype(np.float32))
    # filter2D correlates: output(p) = sum k(q) x(p + q - anchor); the anchor is the i = 0 tap, so the
    # output at p averages the pixels trailing along the motion direction.
    return kernel, (int(-x0), int(-y0))


def motion_blur_float(x: np.ndarray, radius: int, sigma: float, angle_deg: float) -> np.ndarray:
    kernel, anchor = motion_kernel(radius, sigma, angle_deg)
    out = cv2.filter2D(x, -1, kernel, anchor=anchor, borderType=cv2.BORDER_REPLICATE)
    return out.reshape(x.shape)


def plasma_fractal(mapsize: int, wibbledecay: float, rng: np.random.Generator) -> np.ndarray:
    """Square diamond-square plasma fractal of side ``mapsize`` (a power of 2), normalised to ``[0, 1]``.

    Same recursion as the reference ``plasma_fractal`` (initial wibble 100, divided by ``wibbledecay`` per
    level, toroidal neighbours), with the uniform draws taken from ``rng``.
    """
    if mapsize & (mapsize - 1):
        raise ConfigError(f"plasma fractal size must be a power of 2, got {mapsize!r}")
    maparray = np.zeros((mapsize, mapsize), dtype=np.float64)
    stepsize = mapsize
    wibble = 100.0

    def wibbledmean(array: np.ndarray) -> np.ndarray:
        return array / 4 + wibble * rng.uniform(-wibble, wibble, array.shape)

    while stepsize >= 2:
        half = stepsize // 2
        # squares
        cornerref = maparray[0:mapsize:stepsize, 0:mapsize:stepsize]
        squareaccum = cornerref + np.roll(cornerref, shift=-1, axis=0)
        squareaccum += np.roll(squareaccum, shift=-1, axis=1)
        maparray[half:mapsize:stepsize, half:mapsize:stepsize] = wibbledmean(squareaccum)
        # diamonds
        drgrid = maparray[half:mapsize:stepsize, half:mapsize:stepsize]
        ulgrid = maparray[0:mapsize:stepsize, 0:mapsize:stepsize]
        ltsum = drgrid + np.roll(drgrid, 1, axis=0) + ulgrid + np.roll(ulgrid, -1, axis=1)
        maparray[0:mapsize:stepsize, half:mapsize:stepsize] = wibbledmean(ltsum)
        ttsum = drgrid + np.roll(drgrid, 1, axis=1) + ulgrid + np.roll(ulgrid, -1, axis=0)
        maparray[half:mapsize:stepsize, 0:mapsize:stepsize] = wibbledmean(ttsum)
        stepsize //= 2
        wibble /= wibbledecay
    maparray -= maparray.min()
    peak = maparray.max()
    return maparray / peak if peak > 0 else maparray


def next_pow2(n: int) -> int:
    return 1 << max(int(n) - 1, 1).bit_length()


def disk(radius: int, alias_blur: float) -> np.ndarray:
    """The reference's anti-aliased disk kernel (normalised)."""
    if radius <= 8:
        L = np.arange(-8, 8 + 1)
        ksize = (3, 3)
    else:
        L = np.arange(-radius, radius + 1)
        ksize = (5, 5)
    X, Y = np.meshgrid(L, L)
    d = ((X ** 2 + Y ** 2) <= radius ** 2).astype(np.float32)
    d /= d.sum()
    return cv2.GaussianBlur(d, ksize=ksize, sigmaX=alias_blur)


def rgb_value_saturation(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """HSV value ``V = max``, ``min`` and saturation ``S = (V - min) / V`` (0 where V = 0) of float RGB."""
    v = x.max(axis=2)
    mn = x.min(axis=2)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(v > 0, (v - mn) / v, 0.0).astype(np.float32)
    return v, mn, s
