"""Weighted draws over a range: how a generation config aims its views, targets and occluders at the parts of
a range it weights (``shell.*_weights``, ``occlusion.visib_weights``, ``scene.object_weights``; written by
``simtest adapt``, docs/adapt.md). With no weights every function draws exactly what the uniform sampler did, so
configs without them give the same datasets as before. Pure functions of their arguments and ``rng``."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from simtest.errors import ConfigError

__all__ = ["weighted_part", "weighted_uniform", "object_probabilities"]


def weighted_part(rng: np.random.Generator, span: tuple[float, float], weights: Sequence[float]
                  ) -> tuple[float, float]:
    """One of ``len(weights)`` equal parts of ``span`` (in ``span``'s unit), drawn in proportion to its weight;
    ``span`` itself when ``weights`` is empty (nothing drawn)."""
    lo, hi = float(span[0]), float(span[1])
    if not weights:
        return lo, hi
    w = np.asarray(weights, dtype=np.float64)
    k = int(rng.choice(len(w), p=w / w.sum()))
    step = (hi - lo) / len(w)
    return lo + k * step, lo + (k + 1) * step


def weighted_uniform(rng: np.random.Generator, span: tuple[float, float], weights: Sequence[float]) -> float:
    """A value of ``span`` (its unit): a part drawn by :func:`weighted_part`, then uniform inside it; with no
    weights one ``rng.uniform(*span)`` draw, as the uniform sampler."""
    if not weights:
        return float(rng.uniform(*span))
    return float(rng.uniform(*weighted_part(rng, span, weights)))


def object_probabilities(ids: Sequence[int], weights: Mapping[str, float]) -> np.ndarray | None:
    """The probability of each of ``ids`` as a scene's target under ``scene.object_weights`` (ids left out weigh
    1); None for no weights (the uniform draw).

    Raises:
        ConfigError: A weighted id not in ``ids`` (the known ids listed), or every weight of ``ids`` zero.
    """
    if not weights:
        return None
    known = {int(i) for i in ids}
    unknown = sorted(int(k) for k in weights if int(k) not in known)
    if unknown:
        raise ConfigError(f"scene.object_weights names object ids {unknown} not in the object set; known ids: "
                          f"{sorted(known)}")
    by_id = {int(k): float(v) for k, v in weights.items()}
    w = np.array([by_id.get(int(i), 1.0) for i in ids], dtype=np.float64)
    if w.sum() <= 0:
        raise ConfigError(f"scene.object_weights = {dict(weights)} gives every object of the set weight 0")
    return w / w.sum()
