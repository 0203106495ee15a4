"""95 % intervals of the reported accuracies: Wilson's score interval for a proportion of targets (episodes,
images) and a normal interval for a mean of per-target values in [0, 1]. Pure functions."""

from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = ["Z95", "wilson_interval", "mean_interval"]

#: The standard normal quantile of a two-sided 95 % interval.
Z95 = 1.959963984540054


def wilson_interval(successes: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion ``successes / n`` (95 % by default); ``(0, 1)`` for
    ``n = 0``.

    Raises:
        ValueError: ``successes`` outside ``[0, n]``.
    """
    if n <= 0:
        return 0.0, 1.0
    if not 0 <= successes <= n:
        raise ValueError(f"successes must be in [0, n={n}], got {successes!r}")
    p = successes / n
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    lo = 0.0 if successes == 0 else max(0.0, centre - half)  # exact ends: no rounding residue at 0 or n
    hi = 1.0 if successes == n else min(1.0, centre + half)
    return lo, hi


def mean_interval(values: Sequence[float], z: float = Z95, bounds: tuple[float, float] = (0.0, 1.0)
                  ) -> tuple[float, float]:
    """Normal interval of the mean of ``values`` (mean +- z * sample sd / sqrt(n)), clipped to ``bounds``;
    ``bounds`` itself for fewer than two values."""
    n = len(values)
    if n < 2:
        return bounds
    m = sum(values) / n
    sd = math.sqrt(sum((v - m) ** 2 for v in values) / (n - 1))
    h = z * sd / math.sqrt(n)
    return max(bounds[0], m - h), min(bounds[1], m + h)
