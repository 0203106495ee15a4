"""The material record every renderer reads (:class:`MaterialMaps`) and the map encodings it uses.

Conventions: images are row-major with row 0 at the TOP of the texture; texture coordinate ``u`` grows to the
right (columns) and ``v`` grows UP (towards row 0). Normal maps are tangent-space, OpenGL convention
("NormalGL": +x = +u, +y = +v, +z out of the surface), stored as uint8 ``128 + 127 * n`` so a flat normal
(0, 0, 1) is exactly (128, 128, 255).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simtest.errors import ConfigError

__all__ = ["MaterialMaps", "FLAT_NORMAL", "height_to_normal", "encode_normal", "decode_normal", "read_only"]

#: The encoded flat normal (0, 0, 1).
FLAT_NORMAL = (128, 128, 255)


def read_only(a: np.ndarray) -> np.ndarray:
    """``a`` as a C-contiguous array with ``flags.writeable = False`` (a copy only if not contiguous)."""
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class MaterialMaps:
    """One material: square maps of side S plus constant parameters.

    Attributes:
        name: Family name (``"wood"``, ``"tiles"``, ...) or a folder material's set name.
        albedo: (S, S, 3) uint8 sRGB-encoded base colour, row 0 = top of the image.
        roughness: (S, S) uint8, linear roughness * 255 (0 = mirror, 255 = fully rough).
        normal: (S, S, 3) uint8 tangent-space normal map, OpenGL convention, flat = (128, 128, 255).
        metallic: 0..1, constant over the material.
        specular: 0..1, principled-BSDF "specular" (0.5 = IOR 1.5).
        tile_m: Physical size of one texture tile in metres.

    The arrays are made read-only on construction, so cached instances can be shared.
    """

    name: str
    albedo: np.ndarray
    roughness: np.ndarray
    normal: np.ndarray
    metallic: float
    specular: float
    tile_m: float

    def __post_init__(self) -> None:
        s = self.albedo.shape[0] if self.albedo.ndim == 3 else -1
        expect = {"albedo": (s, s, 3), "roughness": (s, s), "normal": (s, s, 3)}
        for field, shape in expect.items():
            a = getattr(self, field)
            if not isinstance(a, np.ndarray) or a.dtype != np.uint8 or a.shape != shape or s <= 0:
                got = (getattr(a, "shape", None), getattr(a, "dtype", type(a).__name__))
                raise ConfigError(f"material {self.name!r}: {field} must be a uint8 array of shape (S, S"
                                  f"{', 3' if len(shape) == 3 else ''}) with S > 0, got shape/dtype {got}")
            object.__setattr__(self, field, read_only(a))
        for field in ("metallic", "specular"):
            value = float(getattr(self, field))
            if not 0.0 <= value <= 1.0:
                raise ConfigError(f"material {self.name!r}: {field} must be in [0, 1], got {value}")
            object.__setattr__(self, field, value)
        if not float(self.tile_m) > 0.0:
            raise ConfigError(f"material {self.name!r}: tile_m must be > 0 metres, got {self.tile_m}")
        object.__setattr__(self, "tile_m", float(self.tile_m))

    @property
    def size(self) -> int:
        """S, the side of the maps in texels."""
        return int(self.albedo.shape[0])


def encode_normal(n: np.ndarray) -> np.ndarray:
    """Unit tangent-space normals (..., 3) floats -> uint8 ``round(128 + 127 * n)`` (flat -> 128, 128, 255)."""
    return np.clip(np.rint(128.0 + 127.0 * np.asarray(n, dtype=np.float32)), 0, 255).astype(np.uint8)


def decode_normal(encoded: np.ndarray) -> np.ndarray:
    """uint8 normal map (..., 3) in this module's encoding -> float32 unit vectors."""
    n = (np.asarray(encoded, dtype=np.float32) - 128.0) / 127.0
    return n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-6)


def height_to_normal(height: np.ndarray, strength: float) -> np.ndarray:
    """Encoded OpenGL normal map of a periodic height field.

    Central finite differences on the periodic grid (``np.roll``), so a tiling height gives a tiling normal map.

    Args:
        height: (S, S) float height in texels' units of "texel widths" times ``strength``: the surface is
            ``z = strength * height`` with one texel = 1 unit across, row 0 = top (+v up).
        strength: Bump strength; 0 gives a flat map.
    Returns:
        (S, S, 3) uint8, flat = (128, 128, 255) exactly where the height's gradient is zero.
    """
    h = np.asarray(height, dtype=np.float32) * np.float32(strength)
    dh_du = 0.5 * (np.roll(h, -1, axis=1) - np.roll(h, 1, axis=1))
    dh_dv = 0.5 * (np.roll(h, 1, axis=0) - np.roll(h, -1, axis=0))  # +v is up: row r - 1 lies at larger v
    n = np.stack([-dh_du, -dh_dv, np.ones_like(h)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return encode_normal(n)
