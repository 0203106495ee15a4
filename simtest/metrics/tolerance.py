"""Pose-error tolerance of a grasp: the largest error along an axis that keeps the success rate at a level,
read from a curve of success against error magnitude. Pure functions.

A magnitude is *tolerated* when its success rate and that of every smaller magnitude of the grid are at least
the level (90 % by default): the tolerance is a step function of the grid, never interpolated, and a single
bad cell below a good one ends it (a dip is not averaged away).

A :class:`ToleranceMap` holds those limits per object and axis (read from ``tolerance.csv``); an estimate is
grasp-ready (the ``grasp_tolerance`` metric of ``simtest eval``) when each component of its error
(:func:`error_components`) lies within the limit of its axis. The limits were measured one axis at a time, so
this box rule does not see errors that only fail together.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from simtest.errors import ConfigError

__all__ = ["TOLERANCE_LEVEL", "TOLERANCE_AXES", "Tolerance", "ToleranceMap", "largest_tolerated",
           "error_components", "read_tolerance_map"]

#: Success rate a tolerated error must keep.
TOLERANCE_LEVEL = 0.9


@dataclass(frozen=True)
class Tolerance:
    """Where a success curve falls below the level.

    Attributes:
        tolerated: The largest magnitude of the grid tolerated (None when even the smallest is not).
        first_below: The smallest magnitude below the level (None when every magnitude is tolerated: the
            grid ends before success falls).
        reaches_zero: Whether some magnitude of the grid has no success at all.
    """

    tolerated: float | None
    first_below: float | None
    reaches_zero: bool


def largest_tolerated(magnitudes: Sequence[float], successes: Sequence[int], episodes: Sequence[int],
                      level: float = TOLERANCE_LEVEL) -> Tolerance:
    """The tolerance of one success curve (see the module doc); magnitudes in any order, in the axis' unit.

    Raises:
        ValueError: Lengths differ, a cell has no episodes or more successes than episodes, or ``level`` is
            outside (0, 1].
    """
    if not len(magnitudes) == len(successes) == len(episodes):
        raise ValueError(f"magnitudes, successes and episodes must have the same length, got "
                         f"{len(magnitudes)}, {len(successes)}, {len(episodes)}")
    if not 0.0 < level <= 1.0:
        raise ValueError(f"level must be in (0, 1], got {level!r}")
    cells = sorted(zip(magnitudes, successes, episodes))
    tolerated = first_below = None
    for m, k, n in cells:
        if n <= 0 or not 0 <= k <= n:
            raise ValueError(f"a cell needs 0 <= successes <= episodes and episodes > 0, got {k}/{n} at {m!r}")
        if first_below is None and k / n >= level:
            tolerated = float(m)
        elif first_below is None:
            first_below = float(m)
    return Tolerance(tolerated, first_below, any(k == 0 for _, k, _ in cells))


#: Axes of a tolerance map: translation along the object's x, y, z and the viewing ray (mm), rotation about
#: the object's x, y, z (degrees); as :data:`simtest.estimators.oracle.ERROR_AXES`.
TOLERANCE_AXES = ("t_x", "t_y", "t_z", "t_ray", "r_x", "r_y", "r_z")


@dataclass(frozen=True)
class ToleranceMap:
    """Per object the largest error it tolerates along each axis, read from a ``tolerance.csv``.

    Attributes:
        limits: ``{obj_id: {axis: limit}}``, millimetres (``t_*``) or degrees (``r_*``); ``inf`` on an axis of
            continuous symmetry (no error at all), ``-1`` when not even the smallest magnitude kept the level.
        level: The success rate the limits keep.
        source: Where the map was read from.
    """

    limits: dict
    level: float = TOLERANCE_LEVEL
    source: str = ""

    @classmethod
    def from_rows(cls, rows: Sequence[dict], level: float = TOLERANCE_LEVEL, source: str = "") -> "ToleranceMap":
        """The map of ``tolerance.csv`` rows (``obj_id``, ``axis``, ``magnitude``, ``successes``, ``episodes``,
        ``symmetry``; strings or numbers).

        Raises:
            ValueError: A row without those columns, or an unknown axis.
        """
        curves: dict = {}
        for r in rows:
            try:
                key = (int(r["obj_id"]), str(r["axis"]))
                point = (float(r["magnitude"]), int(r["successes"]), int(r["episodes"]), str(r.get("symmetry") or ""))
            except (KeyError, TypeError, ValueError) as exc:
                raise ValueError(f"a tolerance row needs obj_id, axis, magnitude, successes, episodes; got {r!r} "
                                 f"({exc})") from None
            if key[1] not in TOLERANCE_AXES:
                raise ValueError(f"unknown axis {key[1]!r} in a tolerance row; allowed: {', '.join(TOLERANCE_AXES)}")
            curves.setdefault(key, []).append(point)
        limits: dict = {}
        for (obj_id, axis), pts in curves.items():
            if pts[0][3] == "continuous":
                limit = math.inf
            else:
                tol = largest_tolerated([p[0] for p in pts], [p[1] for p in pts], [p[2] for p in pts], level)
                limit = -1.0 if tol.tolerated is None else tol.tolerated
            limits.setdefault(obj_id, {})[axis] = limit
        return cls(limits, level, source)

    def allows(self, obj_id: int, components: dict) -> bool | None:
        """Whether every error component (``{axis: |error|}``, mm / degrees) lies within the object's limit on
        that axis (axes the map lacks are not checked); None when the map has no entry for ``obj_id``."""
        lim = self.limits.get(int(obj_id))
        if lim is None:
            return None
        return all(components[a] <= lim[a] + 1e-9 for a in lim if a in components)


def error_components(R_e: np.ndarray, t_e: np.ndarray, R_g: np.ndarray, t_g: np.ndarray,
                     syms: np.ndarray | None = None) -> dict[str, float]:
    """The error of an estimate split along the axes of :data:`TOLERANCE_AXES`, as magnitudes.

    Against the symmetric ground-truth pose nearest in rotation (``syms``: (S, 4, 4) object-frame symmetry
    transforms, identity first; None for none): ``t_x, t_y, t_z`` the translation error in the object's frame
    and ``t_ray`` along the viewing ray through the object's origin (millimetres), ``r_x, r_y, r_z`` the
    components of the rotation vector of ``R_g^T R_e`` in the object's frame (degrees).
    """
    R_e, t_e = np.asarray(R_e, dtype=np.float64), np.asarray(t_e, dtype=np.float64).reshape(3)
    R_g, t_g = np.asarray(R_g, dtype=np.float64), np.asarray(t_g, dtype=np.float64).reshape(3)
    S = np.eye(4)[None] if syms is None else np.asarray(syms, dtype=np.float64).reshape(-1, 4, 4)
    Rs = R_g[None] @ S[:, :3, :3]  # (S, 3, 3) symmetric ground-truth rotations
    cos = np.clip((np.einsum("sij,ij->s", Rs, R_e) - 1.0) / 2.0, -1.0, 1.0)
    k = int(np.argmax(cos))
    R_k, t_k = Rs[k], R_g @ S[k, :3, 3] + t_g
    d = t_e - t_k
    n = float(np.linalg.norm(t_k))
    ray = t_k / n if n > 0 else np.array([0.0, 0.0, 1.0])
    local = R_k.T @ d
    rel = R_k.T @ R_e
    angle = math.acos(float(np.clip((np.trace(rel) - 1.0) / 2.0, -1.0, 1.0)))
    if angle < 1e-12:
        rotvec = np.zeros(3)
    elif angle > math.pi - 1e-6:  # 180 degrees: the axis is the eigenvector of eigenvalue 1
        w, v = np.linalg.eigh((rel + rel.T) / 2.0)
        rotvec = v[:, int(np.argmax(w))] * angle
    else:
        rotvec = np.array([rel[2, 1] - rel[1, 2], rel[0, 2] - rel[2, 0], rel[1, 0] - rel[0, 1]]) * (
            angle / (2.0 * math.sin(angle)))
    deg = np.degrees(np.abs(rotvec))
    return {"t_x": abs(1000.0 * local[0]), "t_y": abs(1000.0 * local[1]), "t_z": abs(1000.0 * local[2]),
            "t_ray": abs(1000.0 * float(d @ ray)), "r_x": float(deg[0]), "r_y": float(deg[1]), "r_z": float(deg[2])}


def read_tolerance_map(path: str | Path, level: float = TOLERANCE_LEVEL) -> ToleranceMap:
    """The :class:`ToleranceMap` of a ``tolerance.csv`` (written by ``simtest tolerance``).

    Raises:
        ConfigError: The file cannot be read or is not a tolerance table (the message names the file).
    """
    from simtest.io.files import read_csv

    try:
        rows = read_csv(path)
        if not rows:
            raise ValueError("no rows")
        return ToleranceMap.from_rows(rows, level, str(path))
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path}: not a readable tolerance.csv of simtest tolerance ({exc})") from None
