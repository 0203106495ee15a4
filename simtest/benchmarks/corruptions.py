"""Timings of the image corruptions: ``simtest bench corruptions``.

Each ImageNet-C corruption at one severity on a fixed synthetic 640 x 480 RGB image (a colour gradient with
a checkerboard), best of ``repeat`` runs, in milliseconds per call.
"""

from __future__ import annotations

import time

import numpy as np

from simtest.corrupt import CORRUPTIONS, corrupt_rgb

__all__ = ["run", "table"]


def _image(height: int, width: int) -> np.ndarray:
    y, x = np.mgrid[0:height, 0:width]
    checker = ((x // 32 + y // 32) % 2) * 60
    rgb = np.stack([x * 255 // max(width - 1, 1), y * 255 // max(height - 1, 1), checker + 100], axis=-1)
    return np.clip(rgb, 0, 255).astype(np.uint8)


def run(width: int = 640, height: int = 480, severity: int = 4, repeat: int = 2) -> dict[str, float]:
    """Milliseconds per call of each corruption (best of ``repeat``), in :data:`CORRUPTIONS` order."""
    img = _image(height, width)
    out = {}
    for name in CORRUPTIONS:
        best = np.inf
        for k in range(repeat):
            t0 = time.perf_counter()
            corrupt_rgb(img, name, severity, np.random.default_rng(k))
            best = min(best, time.perf_counter() - t0)
        out[name] = 1000.0 * best
    return out


def table(timings: dict[str, float]) -> str:
    """One line per corruption: name and milliseconds per call."""
    return "\n".join(f"{name:20s} {ms:9.1f} ms" for name, ms in timings.items())
