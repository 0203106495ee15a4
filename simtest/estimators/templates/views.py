"""Viewpoints of a template bank: camera directions on the object's viewing sphere and the rotations they give.

Conventions: ``R`` maps model-frame points into the OpenCV camera frame (x right, y down, z forward); the camera
looks at the model origin with the model's +Z projected upwards in the image (the look-at of
:func:`simtest.camera.look_at_pose`), so a view's in-plane angle 0 shows the object upright.
"""

from __future__ import annotations

import numpy as np

from simtest.camera import look_at_pose
from simtest.errors import ConfigError

__all__ = ["sphere_directions", "view_rotation", "inplane_rotation", "angular_spacing_deg"]

_GOLDEN = np.pi * (3.0 - np.sqrt(5.0))


def sphere_directions(count: int, min_elevation_deg: float = -90.0) -> np.ndarray:
    """Unit vectors (n, 3) from the model origin toward the camera, spread evenly (a Fibonacci lattice) over
    the part of the sphere at or above ``min_elevation_deg`` (degrees above the model's XY plane).

    ``count`` is the number of lattice points of the whole sphere; those below the elevation are dropped, so a
    hemisphere keeps about half of them.

    Raises:
        ConfigError: ``count`` below 2 or an elevation outside [-90, 90] degrees.
    """
    if int(count) < 2:
        raise ConfigError(f"sphere_directions: count must be >= 2, got {count!r}")
    if not -90.0 <= float(min_elevation_deg) <= 90.0:
        raise ConfigError(f"sphere_directions: min_elevation_deg must be in [-90, 90], got {min_elevation_deg!r}")
    n = int(count)
    i = np.arange(n, dtype=np.float64)
    z = 1.0 - 2.0 * (i + 0.5) / n
    r = np.sqrt(1.0 - z * z)
    d = np.stack([r * np.cos(_GOLDEN * i), r * np.sin(_GOLDEN * i), z], axis=1)
    return d[z >= np.sin(np.radians(float(min_elevation_deg))) - 1e-12]


def angular_spacing_deg(count: int) -> float:
    """The typical angle (degrees) between neighbouring directions of a ``count``-point lattice of the sphere."""
    return float(np.degrees(np.sqrt(4.0 * np.pi / int(count))))


def view_rotation(direction: np.ndarray) -> np.ndarray:
    """``R`` (3, 3), model to camera, of a camera on ``direction`` (from the model origin) looking at the origin,
    model +Z up in the image (in-plane angle 0)."""
    d = np.asarray(direction, np.float64)
    pose = look_at_pose(d / np.linalg.norm(d), np.zeros(3), up=(0.0, 0.0, 1.0))
    return np.asarray(pose.R, np.float64).T


def inplane_rotation(angle_rad: float) -> np.ndarray:
    """Rotation (3, 3) of the camera frame about its optical axis (z) by ``angle_rad``: image content turns
    clockwise on screen for positive angles (x right, y down)."""
    c, s = np.cos(float(angle_rad)), np.sin(float(angle_rad))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
