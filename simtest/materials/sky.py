"""The radiance of the procedural environments (a sunny sky, a photo studio), as (H, 2H, 3) float64 linear
arrays in the convention of :mod:`simtest.materials.environments`, scaled so the irradiance on an
upward-facing horizontal surface (luminance) is pi."""

from __future__ import annotations

import numpy as np

from simtest.materials.sphere import LUMA, directions, up_weights

__all__ = ["sky_radiance", "studio_radiance", "sunny_sky", "unit_direction"]


def unit_direction(elevation: float, azimuth: float) -> np.ndarray:
    """World direction (3,) of an elevation above the horizon and an azimuth from +x toward +y, radians."""
    ce = np.cos(elevation)
    return np.array([ce * np.cos(azimuth), ce * np.sin(azimuth), np.sin(elevation)])


def _luma_one(rgb: np.ndarray) -> np.ndarray:
    return np.asarray(rgb, dtype=np.float64) / float(np.asarray(rgb) @ LUMA)


def _irradiance_up(radiance: np.ndarray) -> float:
    return float(((radiance @ LUMA) * up_weights(radiance.shape[0])[:, None]).sum())


def sky_radiance(rng: np.random.Generator, height: int) -> np.ndarray:
    """A clear-to-hazy sky with a sun disk and a ground, its parameters drawn from ``rng`` (see
    ``procedural_environment``)."""
    elevation, azimuth = np.radians(rng.uniform(15.0, 75.0)), rng.uniform(0.0, 2.0 * np.pi)
    turbidity = rng.uniform(2.0, 6.0)
    share = float(np.clip(0.85 - 0.03 * (turbidity - 2.0) + rng.uniform(-0.02, 0.02), 0.7, 0.85))
    rho = rng.uniform(0.2, 0.3)
    ground = np.array([rng.uniform(0.9, 1.1), 1.0, rng.uniform(0.65, 0.85)])
    return sunny_sky(height, unit_direction(elevation, azimuth), turbidity, share, rho, ground)


def sunny_sky(height: int, sun: np.ndarray, turbidity: float = 3.0, share: float = 0.8, rho: float = 0.25,
              ground_rgb: np.ndarray = (1.0, 1.0, 0.8)) -> np.ndarray:
    """A sky lit by a sun disk (angular radius 1.2 texel rows) toward the unit direction ``sun`` (above the
    horizon), scaled so the horizontal irradiance is pi with the fraction ``share`` from the sun; turbidity
    2 (clear) .. 6 (hazy); a ground of albedo ``rho`` (colour ``ground_rgb``, normalised to luminance 1)."""
    haze = (turbidity - 2.0) / 4.0
    d = directions(height)
    cos_z = np.clip(d[..., 2], 0.0, 1.0)
    cos_g = np.clip(d @ sun, -1.0, 1.0)
    gamma = np.arccos(cos_g)
    zenith = (1.0 - 0.6 * haze) * np.array([0.16, 0.32, 0.85]) + 0.6 * haze * np.array([0.55, 0.6, 0.7])
    horizon = np.array([0.8, 0.85, 0.95])
    g = np.exp(-cos_z / (0.18 + 0.15 * haze))[..., None]
    sky = zenith * (1.0 - g) + horizon * g
    glow = (1.0 + 0.6 * cos_g ** 2 + (1.5 + 3.0 * haze) * np.exp(-gamma / 0.2))[..., None]
    sky = sky * glow * np.array([1.0, 0.97, 0.9 + 0.1 * (1.0 - haze)])
    upper = (d[..., 2] > 0.0)[..., None]
    sky = np.where(upper, sky, 0.0)
    disk = (gamma < 1.2 * np.pi / height) & upper[..., 0]
    disk.flat[int(np.argmin(gamma))] = True
    sin_e = float(sun[2])
    sun_col = _luma_one(np.array([1.0, 0.86 + 0.1 * sin_e, 0.62 + 0.3 * sin_e]))
    sun_e_unit = float((disk * up_weights(height)[:, None]).sum())
    sky *= np.pi * (1.0 - share) / _irradiance_up(sky)
    sky[disk] = np.pi * share / sun_e_unit * sun_col
    return np.where(upper, sky, rho * _luma_one(np.asarray(ground_rgb, dtype=np.float64)))


def _box(d: np.ndarray, centre: np.ndarray, half_u: float, half_v: float) -> np.ndarray:
    """Soft-edged mask of a rectangle of half-angles (half_u, half_v) seen face-on around ``centre``."""
    e1 = np.cross([0.0, 0.0, 1.0], centre)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(centre, e1)
    depth = d @ centre
    safe = np.where(depth > 1e-6, depth, 1.0)
    s = np.maximum(np.abs(d @ e1) / safe / np.tan(half_u), np.abs(d @ e2) / safe / np.tan(half_v))
    t = np.clip((s - 0.85) / 0.15, 0.0, 1.0)
    return np.where(depth > 1e-6, 1.0 - t * t * (3.0 - 2.0 * t), 0.0)


def studio_radiance(rng: np.random.Generator, height: int) -> np.ndarray:
    """A dark-grey studio with 2-4 soft boxes and a floor bounce (see ``procedural_environment``)."""
    d = directions(height)
    n = int(rng.integers(2, 5))
    grey = rng.uniform(0.006, 0.018)
    rad = np.repeat((grey * (1.0 + 0.3 * np.clip(d[..., 2], 0.0, 1.0)))[..., None], 3, axis=2)
    az0 = rng.uniform(0.0, 2.0 * np.pi)
    for i in range(n):
        az = az0 + 2.0 * np.pi * i / n + rng.uniform(-0.4, 0.4)
        centre = unit_direction(np.radians(rng.uniform(20.0, 65.0)), az)
        mask = _box(d, centre, np.radians(rng.uniform(12.0, 24.0)), np.radians(rng.uniform(9.0, 18.0)))
        colour = _luma_one(np.array([1.0, rng.uniform(0.9, 1.0), rng.uniform(0.75, 1.0)]))
        rad += (rng.uniform(0.6, 1.0) * mask)[..., None] * colour
    upper = (d[..., 2] > 0.0)[..., None]
    rad *= np.pi / _irradiance_up(np.where(upper, rad, 0.0))
    rho = rng.uniform(0.2, 0.35)
    below = np.clip(-d[..., 2], 0.0, 1.0)[..., None]
    floor = rho * (0.7 + 0.3 * below) * _luma_one(np.array([1.0, 0.97, 0.92]))
    return np.where(upper, rad, floor)
