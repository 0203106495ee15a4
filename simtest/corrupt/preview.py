"""A labelled grid of every image corruption at severities 1..5, for eyeballing parameters."""

from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np

from simtest.corrupt.weather import CORRUPTIONS, check_corruption_name, corrupt_rgb
from simtest.errors import ConfigError
from simtest.rng import child_rng

__all__ = ["preview_grid", "MAX_GRID_WIDTH"]

#: Upper bound of the grid width (pixels); tiles are downscaled to fit six columns.
MAX_GRID_WIDTH = 3960


def _label(tile: np.ndarray, text: str, bar: int) -> np.ndarray:
    """The tile with a black label bar of ``bar`` px on top (white text)."""
    h, w = tile.shape[:2]
    cell = np.zeros((h + bar, w, 3), np.uint8)
    cell[bar:] = tile
    scale = bar / 30.0
    cv2.putText(cell, text, (max(2, bar // 6), int(bar * 0.72)), cv2.FONT_HERSHEY_SIMPLEX, scale,
                (255, 255, 255), max(1, int(round(scale * 1.5))), cv2.LINE_AA)
    return cell


def preview_grid(image: np.ndarray, names: Sequence[str] | None = None, seed: int = 0,
                 max_width: int = MAX_GRID_WIDTH) -> np.ndarray:
    """Grid of corruptions: one row per name, columns original and severities 1..5.

    Each corruption runs on the full-resolution image with ``child_rng(seed, index of the name in
    CORRUPTIONS, severity)`` (the same cell whatever subset is shown); tiles are then downscaled (area
    interpolation) so that six columns fit in ``max_width`` pixels. Labels are drawn with ``cv2.putText``.

    Args:
        image: ``(H, W, 3)`` uint8 RGB.
        names: Corruption names (default: all 19).
        seed: Non-negative integer seed.
        max_width: Maximum grid width in pixels.

    Returns:
        ``(rows * (tile_h + bar), 6 * tile_w, 3)`` uint8 RGB grid.
    """
    names = list(CORRUPTIONS) if names is None else [check_corruption_name(n) for n in names]
    if not names:
        raise ConfigError(f"no corruption names given; valid names: {', '.join(CORRUPTIONS)}")
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ConfigError(f"preview image must be (H, W, 3) uint8 RGB, got {image.dtype} {image.shape}")
    h, w = image.shape[:2]
    tile_w = min(w, max_width // 6)
    tile_h = max(1, int(round(h * tile_w / w)))
    bar = max(14, min(40, tile_w // 10))
    order = list(CORRUPTIONS)

    def tile(img: np.ndarray) -> np.ndarray:
        if (tile_w, tile_h) == (w, h):
            return img
        return cv2.resize(img, (tile_w, tile_h), interpolation=cv2.INTER_AREA)

    rows = []
    original = tile(image)
    for name in names:
        cells = [_label(original, f"{name}: original", bar)]
        for severity in range(1, 6):
            out = corrupt_rgb(image, name, severity, child_rng(seed, order.index(name), severity))
            cells.append(_label(tile(out), f"severity {severity}", bar))
        rows.append(np.concatenate(cells, axis=1))
    return np.concatenate(rows, axis=0)
