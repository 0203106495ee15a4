"""Pose-error tolerance of a grasp: the largest error along an axis that keeps the success rate at a level,
read from a curve of success against error magnitude. Pure functions.

A magnitude is *tolerated* when its success rate and that of every smaller magnitude of the grid are at least
the level (90 % by default): the tolerance is a step function of the grid, never interpolated, and a single
bad cell below a good one ends it (a dip is not averaged away).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

__all__ = ["TOLERANCE_LEVEL", "Tolerance", "largest_tolerated"]

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
