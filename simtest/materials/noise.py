"""Periodic noise fields on a square texel grid: FFT-filtered white noise, periodic by construction, so every
texture built from them tiles seamlessly. Scales are given in cycles per tile (independent of the texel count),
so one material looks the same at every map size. Coordinates: texel centres ``u = (c + 0.5) / S`` (right) and
``v = 1 - (r + 0.5) / S`` (up), both in [0, 1).
"""

from __future__ import annotations

import numpy as np

__all__ = ["grid_uv", "band_noise", "fractal_noise", "normalize", "smoothstep", "hsv_to_rgb"]


def grid_uv(size: int) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) float32 arrays of shape (size, size) at texel centres; u to the right, v up, both in (0, 1)."""
    t = (np.arange(size, dtype=np.float32) + 0.5) / size
    u, v = np.meshgrid(t, t[::-1].copy())
    return u, v


def _frequencies(size: int) -> tuple[np.ndarray, np.ndarray]:
    fy = np.fft.fftfreq(size, 1.0 / size).astype(np.float32)[:, None]
    fx = np.fft.rfftfreq(size, 1.0 / size).astype(np.float32)[None, :]
    return fx, fy


def _filtered(rng: np.random.Generator, size: int, gain: np.ndarray) -> np.ndarray:
    white = rng.standard_normal((size, size), dtype=np.float32)
    field = np.fft.irfft2(np.fft.rfft2(white) * gain, s=(size, size)).astype(np.float32)
    return normalize(field)


def band_noise(rng: np.random.Generator, size: int, cycles_u: float, cycles_v: float | None = None,
               angle: float = 0.0) -> np.ndarray:
    """Zero-mean, unit-std periodic Gaussian noise, low-passed with a Gaussian spectrum.

    Args:
        cycles_u, cycles_v: Spectral standard deviation in cycles per tile along the (rotated) u and v axes;
            a small value gives long features along that axis (``cycles_u << cycles_v``: streaks along u).
        angle: Rotation of the feature axes, radians (counter-clockwise from +u).
    """
    cycles_v = cycles_u if cycles_v is None else cycles_v
    fx, fy = _frequencies(size)
    c, s = np.float32(np.cos(angle)), np.float32(np.sin(angle))
    fu, fv = c * fx + s * fy, -s * fx + c * fy
    gain = np.exp(-0.5 * ((fu / max(cycles_u, 1e-3)) ** 2 + (fv / max(cycles_v, 1e-3)) ** 2))
    gain[0, 0] = 0.0
    return _filtered(rng, size, gain.astype(np.float32))


def fractal_noise(rng: np.random.Generator, size: int, beta: float = 1.8, low: float = 1.0,
                  high: float = 64.0) -> np.ndarray:
    """Zero-mean, unit-std periodic fractal noise: amplitude ~ f^-beta between ``low`` and ``high`` cycles per
    tile (smooth cut-offs)."""
    fx, fy = _frequencies(size)
    f = np.sqrt(fx * fx + fy * fy)
    gain = np.power(np.maximum(f, low), -beta) * np.exp(-((f / high) ** 2))
    gain[0, 0] = 0.0
    return _filtered(rng, size, gain.astype(np.float32))


def normalize(field: np.ndarray) -> np.ndarray:
    """``field`` shifted and scaled to zero mean and unit standard deviation (float32)."""
    field = field - field.mean()
    return (field / max(float(field.std()), 1e-8)).astype(np.float32)


def smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    """Hermite step from 0 at ``e0`` to 1 at ``e1``."""
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def hsv_to_rgb(h: float, s: float, v: float) -> np.ndarray:
    """One colour: hue in turns [0, 1), saturation and value in [0, 1] -> (3,) float64 RGB in [0, 1]."""
    k = (np.array([5.0, 3.0, 1.0]) + h * 6.0) % 6.0
    return v - v * s * np.clip(np.minimum(k, 4.0 - k), 0.0, 1.0)
