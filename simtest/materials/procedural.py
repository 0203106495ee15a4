"""Seeded procedural PBR materials: nine families, each a believable look with per-seed variants.

``procedural_material(family, seed, size)`` is pure and cached: the same (family, seed, size) gives identical
bytes. Every map tiles seamlessly (all noise is periodic on the texel grid, every pattern has an integer number
of periods per tile). Feature scales are fixed in cycles per tile, so a material looks the same at every size;
``tile_m`` gives the physical size of one tile. Map conventions: :mod:`simtest.materials.maps`.
"""

from __future__ import annotations

from functools import lru_cache
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from simtest.errors import ConfigError
from simtest.materials.maps import MaterialMaps, height_to_normal
from simtest.materials.noise import band_noise, fractal_noise, grid_uv, hsv_to_rgb, smoothstep
from simtest.render.colour import linear_to_srgb8, srgb_to_linear
from simtest.rng import child_sequence

__all__ = ["FAMILIES", "procedural_material"]

FAMILIES: tuple[str, ...] = ("wood", "tiles", "fabric", "concrete", "marble", "brushed_metal",
                             "painted_plastic", "cardboard", "paper")


class _Raw(NamedTuple):
    """A family's output before encoding: linear albedo (S, S, 3), roughness (S, S) in [0, 1], a height field
    and its bump strength (surface slope per unit height at S = 256), and the constant parameters."""

    albedo: np.ndarray
    roughness: np.ndarray
    height: np.ndarray
    bump: float
    metallic: float
    specular: float
    tile_m: float


def _srgb(h: float, s: float, v: float) -> np.ndarray:
    """An HSV colour picked in sRGB space, returned linear (3,)."""
    return srgb_to_linear(hsv_to_rgb(h, s, v)).astype(np.float32)


def _lerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    t = t[..., None]
    return a * (1.0 - t) + b * t


def _wrap_dist(x: np.ndarray) -> np.ndarray:
    """Distance of x to the nearest integer (periodic)."""
    return np.abs(x - np.rint(x))


def _wood(rng: np.random.Generator, size: int) -> _Raw:
    n = int(rng.integers(3, 7))                                   # planks per tile (along v)
    hue, sat = rng.uniform(0.045, 0.1), rng.uniform(0.45, 0.75)
    light = _srgb(hue, sat * 0.8, rng.uniform(0.6, 0.88))
    dark = _srgb(hue - 0.01, min(sat * 1.2, 0.95), rng.uniform(0.3, 0.5))
    joints, rings = rng.uniform(0, 1, n), rng.uniform(2.0, 6.0, n)
    phases, tones = rng.uniform(0, 1, n), rng.uniform(0.8, 1.15, n)
    shifts = rng.integers(0, 1 << 30, n)
    r0 = rng.uniform(0.3, 0.5)
    grain, warp = band_noise(rng, size, 1.5, 28), band_noise(rng, size, 1.2, 3.0)
    u, v = grid_uv(size)
    p = np.minimum((v * n).astype(np.int64), n - 1)
    vl = v * n - p
    cols = (np.arange(size)[None, :] + (shifts[p] % size)) % size
    rows = np.arange(size)[:, None]
    w, g = warp[rows, cols], grain[rows, cols]                    # each plank sees its own stretch of noise
    t = rings[p] * (vl + 0.18 * w) + phases[p] + 0.04 * g
    r = t - np.floor(t)
    ring = np.exp(-((r - 0.75) / 0.12) ** 2) + 0.3 * smoothstep(0.2, 0.7, r)
    mix = np.clip(0.55 * ring + 0.18 * g + 0.2, 0.0, 1.0)
    gw = max(0.004, 1.2 / size)                                   # gap half-width, tile units
    d = np.minimum(np.minimum(vl, 1.0 - vl) / n, _wrap_dist(u - joints[p]))
    gap = 1.0 - smoothstep(0.5 * gw, gw, d)
    albedo = _lerp(light, dark, mix) * tones[p][..., None] * (1.0 - 0.65 * gap)[..., None]
    varnish = np.clip(r0 + 0.04 * g + 0.05 * ring, 0.3, 0.6)
    rough = varnish + (0.9 - varnish) * gap
    height = -1.5 * gap + 0.03 * g - 0.02 * ring
    return _Raw(albedo, rough, height, 60.0, 0.0, 0.5, 0.6)


def _tiles(rng: np.random.Generator, size: int) -> _Raw:
    n = int(rng.choice([2, 3, 4]))
    if rng.uniform() < 0.5:
        base = (rng.uniform(0, 1), rng.uniform(0.0, 0.12), rng.uniform(0.8, 0.95))
    else:
        base = (rng.uniform(0, 1), rng.uniform(0.3, 0.8), rng.uniform(0.35, 0.85))
    jitter = rng.uniform(0.9, 1.06, (n, n))
    grout_col = _srgb(rng.uniform(0.05, 0.12), rng.uniform(0.0, 0.15), min(0.45, 0.6 * base[2]))
    gw, r_tile = rng.uniform(0.01, 0.018), rng.uniform(0.05, 0.2)
    mottle = band_noise(rng, size, 10.0)
    u, v = grid_uv(size)
    iu, iv = np.minimum((u * n).astype(np.int64), n - 1), np.minimum((v * n).astype(np.int64), n - 1)
    d = np.minimum(_wrap_dist(u * n), _wrap_dist(v * n)) / n      # distance to the nearest grout centre line
    bevel = max(0.004, 1.0 / size)
    face = smoothstep(gw, gw + bevel, d)
    tile_col = _srgb(*base) * (jitter[iv, iu] * (1.0 + 0.025 * mottle))[..., None]
    albedo = _lerp(grout_col, tile_col, face)
    rough = r_tile + (rng.uniform(0.85, 0.95) - r_tile) * (1.0 - face)
    return _Raw(albedo, rough, face, 30.0, 0.0, 0.5, 0.6)


def _fabric(rng: np.random.Generator, size: int) -> _Raw:
    k = 2 * int(rng.integers(6, 13))                              # threads per tile, even so the weave tiles
    c1 = _srgb(rng.uniform(0, 1), rng.uniform(0.25, 0.8), rng.uniform(0.3, 0.8))
    c2 = c1 * np.float32(rng.uniform(0.7, 0.95))
    r0 = rng.uniform(0.85, 0.95)
    fibre = band_noise(rng, size, 48.0)
    slub = band_noise(rng, size, 0.8, 12.0)
    u, v = grid_uv(size)
    a, b = u * k, v * k
    fa, fb = a - np.floor(a), b - np.floor(b)
    over = (np.floor(a) + np.floor(b)).astype(np.int64) % 2 == 0
    pw, pf = np.sin(np.pi * fa), np.sin(np.pi * fb)
    height = np.where(over, pw * (0.6 + 0.4 * pf), pf * (0.6 + 0.4 * pw)) + 0.08 * fibre
    albedo = np.where(over[..., None], c1, c2) * (0.7 + 0.3 * height + 0.04 * slub)[..., None]
    rough = np.clip(r0 + 0.04 * fibre, 0.8, 1.0)
    return _Raw(albedo, rough, height, 12.0, 0.0, 0.5, 0.08)


def _concrete(rng: np.random.Generator, size: int) -> _Raw:
    grey = _srgb(rng.uniform(0.05, 0.6), rng.uniform(0.0, 0.07), rng.uniform(0.45, 0.68))
    mottle = fractal_noise(rng, size, beta=1.4, low=1.0, high=48.0)
    fine = band_noise(rng, size, 80.0)
    pores_field = band_noise(rng, size, 70.0)
    threshold = rng.uniform(2.0, 2.5)
    pores = smoothstep(threshold, threshold + 0.6, pores_field)
    albedo = grey * ((1.0 + 0.1 * mottle + 0.04 * fine) * (1.0 - 0.5 * pores))[..., None]
    rough = np.clip(rng.uniform(0.85, 0.95) + 0.03 * fine, 0.8, 1.0)
    height = 0.15 * mottle + 0.2 * fine - 1.5 * pores
    return _Raw(albedo, rough, height, 8.0, 0.0, 0.5, 1.0)


def _marble(rng: np.random.Generator, size: int) -> _Raw:
    dark = rng.uniform() < 0.3
    if dark:
        base = _srgb(rng.choice([0.33, 0.6, 0.0]), rng.uniform(0.1, 0.4), rng.uniform(0.12, 0.3))
        vein_col = _srgb(rng.uniform(0.08, 0.15), rng.uniform(0.0, 0.2), rng.uniform(0.75, 0.92))
    else:
        base = _srgb(rng.uniform(0.05, 0.15), rng.uniform(0.0, 0.08), rng.uniform(0.86, 0.95))
        vein_col = _srgb(rng.uniform(0.05, 0.65), rng.uniform(0.0, 0.25), rng.uniform(0.25, 0.55))
    freq = [(int(rng.integers(1, 3)), int(rng.integers(-2, 3))) for _ in range(2)]
    phases, widths = rng.uniform(0, 2 * np.pi, 2), rng.uniform(0.06, 0.16, 2)
    r0 = rng.uniform(0.04, 0.14)
    turb = [fractal_noise(rng, size, beta=2.0, low=1.0, high=40.0) for _ in range(2)]
    cloud = band_noise(rng, size, 5.0)
    u, v = grid_uv(size)
    vein = np.zeros_like(u)
    for (a, b), ph, w, t, weight in zip(freq, phases, widths, turb, (1.0, 0.5)):
        s = np.sin(2.0 * np.pi * (a * u + b * v) + 2.2 * t + ph)
        core = 1.0 - smoothstep(0.0, w, np.abs(s))
        halo = 1.0 - smoothstep(0.0, 6.0 * w, np.abs(s))        # the soft cloud around a vein
        vein = np.maximum(vein, weight * np.maximum(core, 0.3 * halo))
    albedo = _lerp(base * (1.0 + 0.05 * cloud)[..., None], vein_col, 0.85 * vein)
    rough = np.clip(r0 + 0.06 * vein, 0.0, 0.3)
    return _Raw(albedo, rough, -vein, 0.5, 0.0, 0.5, 0.8)


def _brushed_metal(rng: np.random.Generator, size: int) -> _Raw:
    presets = np.array([[0.56, 0.57, 0.58], [0.91, 0.92, 0.92], [0.66, 0.65, 0.63],
                        [0.91, 0.78, 0.42], [0.95, 0.64, 0.54]], dtype=np.float32)
    base = presets[int(rng.integers(0, len(presets)))] * np.float32(rng.uniform(0.9, 1.0))
    r0 = rng.uniform(0.25, 0.38)
    streak = 0.7 * band_noise(rng, size, 0.6, 90.0) + 0.5 * band_noise(rng, size, 2.0, 200.0)
    blotch = band_noise(rng, size, 3.0)
    albedo = base * (1.0 + 0.05 * streak + 0.02 * blotch)[..., None]
    rough = np.clip(r0 + 0.04 * streak + 0.02 * blotch, 0.2, 0.45)
    return _Raw(albedo, rough, streak, 2.0, 1.0, 0.5, 0.3)


def _painted_plastic(rng: np.random.Generator, size: int) -> _Raw:
    colour = _srgb(rng.uniform(0, 1), rng.uniform(0.6, 0.92), rng.uniform(0.5, 0.9))
    r0 = rng.uniform(0.32, 0.55)
    peel = band_noise(rng, size, 36.0) - 0.6 * band_noise(rng, size, 12.0)
    shade = band_noise(rng, size, 2.0)
    albedo = colour * (1.0 + 0.03 * shade + 0.01 * peel)[..., None]
    rough = np.clip(r0 + 0.02 * peel, 0.3, 0.6)
    return _Raw(albedo, rough, peel, 3.0, 0.0, 0.5, 0.25)


def _cardboard(rng: np.random.Generator, size: int) -> _Raw:
    colour = _srgb(rng.uniform(0.07, 0.1), rng.uniform(0.4, 0.62), rng.uniform(0.5, 0.72))
    k = int(rng.integers(18, 36))                                 # corrugation ridges per tile
    fibres = band_noise(rng, size, 5.0, 90.0, angle=rng.uniform(-0.3, 0.3))
    blotch = fractal_noise(rng, size, beta=1.6, low=1.0, high=24.0)
    specks = smoothstep(2.3, 2.9, band_noise(rng, size, 90.0))
    _, v = grid_uv(size)
    ridge = 0.5 + 0.5 * np.cos(2.0 * np.pi * k * v)
    albedo = colour * ((1.0 - 0.06 * ridge + 0.05 * fibres + 0.06 * blotch) * (1.0 - 0.4 * specks))[..., None]
    rough = np.clip(rng.uniform(0.85, 0.93) + 0.03 * fibres, 0.8, 1.0)
    return _Raw(albedo, rough, ridge + 0.1 * fibres, 6.0, 0.0, 0.5, 0.3)


def _paper(rng: np.random.Generator, size: int) -> _Raw:
    colour = _srgb(rng.uniform(0, 1), rng.uniform(0.0, 0.16), rng.uniform(0.88, 0.97))
    angles = rng.uniform(0, np.pi, 3)
    fibres = sum(band_noise(rng, size, 6.0, 110.0, angle=a) for a in angles) / np.sqrt(3.0)
    cloud = band_noise(rng, size, 6.0)
    albedo = colour * (1.0 + 0.03 * fibres + 0.02 * cloud)[..., None]
    rough = np.clip(rng.uniform(0.86, 0.95) + 0.03 * fibres, 0.8, 1.0)
    return _Raw(albedo, rough, fibres, 1.5, 0.0, 0.5, 0.3)


_GENERATORS: dict[str, Callable[[np.random.Generator, int], _Raw]] = {
    "wood": _wood, "tiles": _tiles, "fabric": _fabric, "concrete": _concrete, "marble": _marble,
    "brushed_metal": _brushed_metal, "painted_plastic": _painted_plastic, "cardboard": _cardboard,
    "paper": _paper,
}


def procedural_material(family: str, seed: int, size: int = 256) -> MaterialMaps:
    """The material of ``family`` drawn from ``seed``, with square maps of side ``size``.

    Args:
        family: One of :data:`FAMILIES`.
        seed: Non-negative integer; each seed is a visibly different variant (colour, scale, pattern phase).
        size: Map side in texels, a power of two in [32, 2048].
    Raises:
        ConfigError: Unknown family, bad seed or size.
    """
    if family not in _GENERATORS:
        raise ConfigError(f"material family {family!r} is unknown; allowed: {', '.join(FAMILIES)}")
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or not 32 <= size <= 2048 \
            or size & (size - 1):
        raise ConfigError(f"material size {size!r} (family {family!r}) must be a power of two in [32, 2048]")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"material seed {seed!r} (family {family!r}) must be a non-negative integer")
    return _cached(family, int(seed), int(size))


@lru_cache(maxsize=128)
def _cached(family: str, seed: int, size: int) -> MaterialMaps:
    rng = np.random.default_rng(child_sequence(seed, FAMILIES.index(family)))
    raw = _GENERATORS[family](rng, size)
    height = np.asarray(raw.height, dtype=np.float32)
    return MaterialMaps(
        name=family,
        albedo=linear_to_srgb8(raw.albedo),
        roughness=np.clip(np.rint(np.asarray(raw.roughness) * 255.0), 0, 255).astype(np.uint8),
        normal=height_to_normal(height, raw.bump * size / 256.0),
        metallic=raw.metallic, specular=raw.specular, tile_m=raw.tile_m)
