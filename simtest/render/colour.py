"""The sRGB transfer function (IEC 61966-2-1), both ways; colours as floats in [0, 1] unless stated."""

from __future__ import annotations

import numpy as np

__all__ = ["srgb_to_linear", "linear_to_srgb", "linear_to_srgb8"]


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] (clipped) -> linear values."""
    c = np.clip(np.asarray(c, dtype=np.float64), 0.0, 1.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c: np.ndarray) -> np.ndarray:
    """Linear values (clipped to [0, 1]) -> sRGB-encoded floats in [0, 1]."""
    c = np.clip(np.asarray(c, dtype=np.float64), 0.0, 1.0)
    return np.where(c <= 0.0031308, c * 12.92, 1.055 * c ** (1.0 / 2.4) - 0.055)


def linear_to_srgb8(c: np.ndarray) -> np.ndarray:
    """Linear values (clipped to [0, 1]) -> sRGB-encoded uint8."""
    return np.round(linear_to_srgb(c) * 255.0).astype(np.uint8)
