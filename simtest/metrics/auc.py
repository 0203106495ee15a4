"""YCB-Video accuracy-threshold AUC (PoseCNN protocol) and fixed-threshold accuracy. Distances in metres.

The YCB-Video toolbox (``evaluate_poses_keyframe.m`` / ``VOCap.m``, and its Python ports) scores a list of
ADD-S or ADD(-S) distances, one per ground-truth object instance (a missed instance counts with distance
``inf``), by the area under the accuracy-vs-threshold curve for thresholds in ``[0, 0.10 m]``:

1. distances ``> max_threshold`` are set to ``inf``; the list is sorted ascending; ``n`` counts all entries;
2. ``accuracy_k = k / n`` for the k-th smallest distance (1-based);
3. keeping only the finite distances ``d_1 <= ... <= d_m``: ``mrec = [0, d_1, ..., d_m, max_threshold]``,
   ``mpre = [0, acc_1, ..., acc_m, acc_m]``, ``mpre`` made non-decreasing by a running maximum;
4. ``AUC = sum_i (mrec[i] - mrec[i-1]) * mpre[i] / max_threshold``.

This is a right-endpoint rule: on ``(d_{k-1}, d_k]`` the curve is taken at its value *after* the step at
``d_k``. The exact area under the step curve ``acc(x) = #{d < x} / n`` is ``mean(max(0, 1 - d / thr))``
(:func:`auc_mean_rule`); the VOC-style value exceeds it by ``d_m / (n * max_threshold)``, the largest
finite distance over ``n * thr``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from simtest.errors import ConfigError

__all__ = ["ycb_auc", "auc_mean_rule", "accuracy_below", "YCB_AUC_MAX_THRESHOLD", "ADDS_2CM"]

#: Upper end of the YCB-Video threshold range, metres.
YCB_AUC_MAX_THRESHOLD = 0.10
#: The "ADD-S < 2 cm" threshold, metres.
ADDS_2CM = 0.02


def _distances(d: Sequence[float] | np.ndarray) -> np.ndarray:
    d = np.asarray(d, dtype=np.float64).reshape(-1)
    if len(d) == 0:
        raise ConfigError("distances must not be empty (count a missed instance as inf)")
    if np.any(np.isnan(d)):
        raise ConfigError(f"distances contain NaN at indices {np.flatnonzero(np.isnan(d))[:10].tolist()}; "
                          "use inf for a missed instance")
    if np.any(d < 0):
        raise ConfigError(f"distances must be >= 0 metres, got {d[d < 0][:10].tolist()}")
    return d


def _threshold(thr: float) -> float:
    thr = float(thr)
    if not thr > 0:
        raise ConfigError(f"threshold must be > 0 metres, got {thr!r}")
    return thr


def ycb_auc(distances: Sequence[float] | np.ndarray, max_threshold: float = YCB_AUC_MAX_THRESHOLD) -> float:
    """Area under the accuracy-threshold curve, YCB-Video / PoseCNN VOC-style rule (see module doc).

    Args:
        distances: One ADD-S (or ADD(-S)) distance per ground-truth instance, metres; ``inf`` for a miss.
        max_threshold: Upper end of the threshold range, metres (0.10 in YCB-Video).

    Returns:
        AUC in [0, 1] (multiply by 100 for the usual percentage).
    """
    d = _distances(distances)
    thr = _threshold(max_threshold)
    n = len(d)
    d = np.sort(np.where(d > thr, np.inf, d))
    acc = np.arange(1, n + 1, dtype=np.float64) / n
    finite = np.isfinite(d)
    if not np.any(finite):
        return 0.0
    rec, prec = d[finite], acc[finite]
    mrec = np.concatenate([[0.0], rec, [thr]])
    mpre = np.maximum.accumulate(np.concatenate([[0.0], prec, [prec[-1]]]))
    return float(np.sum(np.diff(mrec) * mpre[1:]) / thr)


def auc_mean_rule(distances: Sequence[float] | np.ndarray, max_threshold: float = YCB_AUC_MAX_THRESHOLD) -> float:
    """Exact area under the step curve ``acc(x) = #{d < x} / n`` on ``[0, thr]``, divided by ``thr``.

    Closed form: ``mean(max(0, 1 - d / thr))`` (``inf`` contributes 0). Compare :func:`ycb_auc`, which is
    larger by ``d_max_finite / (n thr)``.

    Args:
        distances: Distances, metres; ``inf`` for a miss.
        max_threshold: Upper end of the threshold range, metres.

    Returns:
        AUC in [0, 1].
    """
    d = _distances(distances)
    thr = _threshold(max_threshold)
    return float(np.mean(np.maximum(0.0, 1.0 - d / thr)))


def accuracy_below(distances: Sequence[float] | np.ndarray, threshold: float = ADDS_2CM) -> float:
    """Fraction of distances strictly below ``threshold`` (e.g. "ADD-S < 2 cm" with 0.02 m).

    Args:
        distances: Distances, metres; ``inf`` for a miss.
        threshold: Threshold, metres.

    Returns:
        Fraction in [0, 1].
    """
    d = _distances(distances)
    return float(np.mean(d < _threshold(threshold)))
