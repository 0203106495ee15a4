"""Texel geometry of an equirectangular map of H rows and 2H columns (convention in
:mod:`simtest.materials.environments`): texel-centre directions, solid angles, cosine weights."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

__all__ = ["LUMA", "row_edges", "directions", "solid_angles", "up_weights", "polar_angles"]

#: Rec. 709 / sRGB luminance weights of linear RGB.
LUMA = np.array([0.2126, 0.7152, 0.0722])


def row_edges(height: int) -> np.ndarray:
    """The H + 1 polar angles (radians from +z) bounding the rows."""
    return np.linspace(0.0, np.pi, height + 1)


def polar_angles(height: int) -> tuple[np.ndarray, np.ndarray]:
    """(theta (H,), phi (2H,)) at texel centres, radians."""
    theta = (np.arange(height) + 0.5) * np.pi / height
    phi = (np.arange(2 * height) + 0.5) * 2.0 * np.pi / (2 * height)
    return theta, phi


@lru_cache(maxsize=8)
def directions(height: int) -> np.ndarray:
    """(H, 2H, 3) float64 unit directions of the texel centres, world frame z up (read-only)."""
    theta, phi = polar_angles(height)
    st = np.sin(theta)[:, None]
    d = np.stack([st * np.cos(phi)[None, :], st * np.sin(phi)[None, :],
                  np.repeat(np.cos(theta)[:, None], 2 * height, axis=1)], axis=-1)
    d.setflags(write=False)
    return d


def solid_angles(height: int) -> np.ndarray:
    """(H,) solid angle of one texel of each row, steradians (exact: the row's band over 2H columns)."""
    e = row_edges(height)
    return (np.cos(e[:-1]) - np.cos(e[1:])) * (2.0 * np.pi / (2 * height))


def up_weights(height: int) -> np.ndarray:
    """(H,) integral of cos(theta) dOmega over one texel of each row for an upward-facing surface (0 below the
    horizon), exact: 0.5 (sin^2 theta1 - sin^2 theta0) dphi clipped at theta = pi / 2."""
    e = np.minimum(row_edges(height), np.pi / 2.0)
    return 0.5 * (np.sin(e[1:]) ** 2 - np.sin(e[:-1]) ** 2) * (2.0 * np.pi / (2 * height))
