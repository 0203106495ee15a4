"""ImageNet-C noise corruptions (gaussian, shot, impulse, speckle), severities 1..5; see :mod:`simtest.corrupt.weather`."""

from __future__ import annotations

import numpy as np

from simtest.corrupt.image_ops import to_float, to_uint8

__all__ = ["gaussian_noise", "shot_noise", "impulse_noise", "speckle_noise"]


def gaussian_noise(image: np.ndarray, severity: int, rng: np.random.Generator) -> np.ndarray:
    """Additive Gaussian noise ``x + N(0, sigma)``, sigma = .08 .12 .18 .26 .38 (image in [0, 1])."""
    c = [0.08, 0.12, 0.18, 0.26, 0.38][severity - 1]
    x = to_float(image)
    return to_uint8(x + rng.standard_normal(x.shape, dtype=np.float32) * np.float32(c))


def shot_noise(image: np.ndarray, severity: int, rng: np.random.Generator) -> np.ndarray:
    """Poisson (shot) noise ``Poisson(x c) / c``, c = 60 25 12 5 3 photons at full scale."""
    c = [60, 25, 12, 5, 3][severity - 1]
    x = to_float(image)
    return to_uint8(rng.poisson(x * c).astype(np.float32) / np.float32(c))


def impulse_noise(image: np.ndarray, severity: int, rng: np.random.Generator) -> np.ndarray:
    """Salt-and-pepper noise on a fraction ``amount`` = .03 .06 .09 .17 .27 of the values (per channel).

    As ``skimage.util.random_noise(mode='s&p')``: each channel value is replaced with probability ``amount``,
    half of the replacements by 1 (salt) and half by 0 (pepper).
    """
    c = [0.03, 0.06, 0.09, 0.17, 0.27][severity - 1]
    out = image.copy()
    flipped = rng.random(image.shape, dtype=np.float32) < c
    salted = rng.random(image.shape, dtype=np.float32) < 0.5
    out[flipped & salted] = 255
    out[flipped & ~salted] = 0
    return out


def speckle_noise(image: np.ndarray, severity: int, rng: np.random.Generator) -> np.ndarray:
    """Multiplicative noise ``x + x N(0, c)``, c = .15 .2 .35 .45 .6."""
    c = [0.15, 0.2, 0.35, 0.45, 0.6][severity - 1]
    x = to_float(image)
    return to_uint8(x + x * rng.standard_normal(x.shape, dtype=np.float32) * np.float32(c))
