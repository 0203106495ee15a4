"""95 % intervals of the reported accuracies: Wilson's score interval for a proportion of targets (episodes,
images), a normal interval for a mean of per-target values in [0, 1], and a percentile bootstrap over clusters
(scenes) for a proportion whose targets are not independent. Pure functions."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

__all__ = ["Z95", "wilson_interval", "mean_interval", "bootstrap_interval", "cluster_bootstrap_interval"]

_CHUNK = 250  # bootstrap resamples drawn at once (bounds the memory of a large set)
_HUGE = 1e300

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


def cluster_bootstrap_interval(values: Sequence[float], clusters: Sequence[object], n_boot: int = 2000,
                               seed: int = 0, level: float = 0.95) -> tuple[float, float] | None:
    """Percentile bootstrap interval of the pooled mean of ``values`` (per-target hits or scores) resampling
    whole ``clusters`` (e.g. scene ids) with replacement: targets of one scene share its camera path, clutter
    and lighting, so they are not independent and a binomial interval over targets is too narrow when scenes
    differ. Each replicate is the ratio ``sum(values) / count`` over the drawn clusters. Deterministic in
    ``seed``. None for fewer than two clusters (nothing to resample).

    Raises:
        ValueError: ``values`` and ``clusters`` of different lengths, ``n_boot < 100`` or ``level`` outside (0, 1).
    """
    if len(values) != len(clusters):
        raise ValueError(f"values and clusters must have the same length, got {len(values)} and {len(clusters)}")
    if n_boot < 100 or not 0.0 < level < 1.0:
        raise ValueError(f"need n_boot >= 100 and 0 < level < 1, got {n_boot!r}, {level!r}")
    keys = sorted(set(clusters), key=repr)
    if len(keys) < 2:
        return None
    index = {k: i for i, k in enumerate(keys)}
    c = np.array([index[k] for k in clusters])
    sums = np.bincount(c, weights=np.asarray(values, np.float64), minlength=len(keys))
    counts = np.bincount(c, minlength=len(keys)).astype(np.float64)
    rng = np.random.default_rng(np.random.SeedSequence(int(seed)))
    draws = rng.integers(0, len(keys), size=(int(n_boot), len(keys)))
    means = sums[draws].sum(1) / np.maximum(counts[draws].sum(1), 1.0)
    a = (1.0 - level) / 2.0
    lo, hi = np.quantile(means, [a, 1.0 - a])
    return float(lo), float(hi)


def bootstrap_interval(values: np.ndarray, stat: Callable[[np.ndarray], np.ndarray], *, seed: int = 0,
                       resamples: int = 2000) -> tuple[float, float]:
    """Percentile bootstrap 95 % interval of ``stat`` over the rows of ``values``.

    Args:
        values: Per-target values, ``(n,)``.
        stat: The statistic of a batch of resamples: ``(b, n) -> (b,)`` (e.g. a mean or median over axis 1).
        seed: Seed of the resampling.
        resamples: Number of resamples.

    Raises:
        ValueError: ``values`` empty or not one-dimensional.
    """
    v = np.asarray(values, dtype=np.float64)
    if v.ndim != 1 or v.size == 0:
        raise ValueError(f"values must be a non-empty 1-D array, got shape {v.shape}")
    rng = np.random.default_rng(seed)
    stats = []
    for start in range(0, resamples, _CHUNK):
        idx = rng.integers(0, v.size, size=(min(_CHUNK, resamples - start), v.size))
        stats.append(stat(v[idx]))
    # a median of misses is inf: percentiles between two infs would be NaN, so they go through a finite stand-in
    found = np.clip(np.concatenate(stats), -_HUGE, _HUGE)
    lo, hi = (float(q) if abs(q) < _HUGE else math.copysign(math.inf, q) for q in np.percentile(found, [2.5, 97.5]))
    return lo, hi
