"""How well a pose-error metric predicts grasp success: ROC AUC (the Mann-Whitney statistic), its bootstrap
interval, the threshold that best separates successes from failures, and the success rate under a threshold.
Pure functions over paired arrays ``errors`` (any unit, smaller is better) and ``success`` (bool).

The AUC here is the probability that a failed episode has a larger error than a successful one, ties counting
one half: ``AUC = U / (n_s n_f)`` with the Mann-Whitney ``U = #{(i, j): e_f[i] > e_s[j]} + 0.5 #{ties}`` over
failures ``f`` and successes ``s``. 1 means the error orders every failure above every success, 0.5 chance.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["mann_whitney_u", "roc_auc", "bootstrap_auc_interval", "best_threshold", "success_below",
           "Threshold"]


def _pair(errors: Sequence[float], success: Sequence[bool]) -> tuple[np.ndarray, np.ndarray]:
    """The finite errors and their outcomes as arrays (an episode without an error value is dropped).

    Raises:
        ValueError: The two lengths differ.
    """
    e = np.asarray(errors, dtype=np.float64).ravel()
    s = np.asarray(success, dtype=bool).ravel()
    if e.shape != s.shape:
        raise ValueError(f"errors and success must have the same length, got {e.size} and {s.size}")
    keep = ~np.isnan(e)
    return e[keep], s[keep]


def mann_whitney_u(larger: Sequence[float], smaller: Sequence[float]) -> float:
    """Mann-Whitney ``U``: the pairs ``(a, b)`` of ``larger`` x ``smaller`` with ``a > b``, ties counting 1/2.

    Computed from midranks (``O(n log n)``), equal to the pair count.
    """
    a = np.asarray(larger, dtype=np.float64).ravel()
    b = np.asarray(smaller, dtype=np.float64).ravel()
    if a.size == 0 or b.size == 0:
        return 0.0
    both = np.concatenate([a, b])
    order = np.argsort(both, kind="mergesort")
    ranks = np.empty(both.size, dtype=np.float64)
    sorted_vals = both[order]
    # Midranks: equal values share the mean of their 1-based ranks.
    start = np.flatnonzero(np.r_[True, sorted_vals[1:] != sorted_vals[:-1]])
    end = np.r_[start[1:], both.size]
    for s0, e0 in zip(start, end):
        ranks[order[s0:e0]] = 0.5 * (s0 + 1 + e0)
    return float(ranks[:a.size].sum() - a.size * (a.size + 1) / 2.0)


def roc_auc(errors: Sequence[float], success: Sequence[bool]) -> float:
    """ROC AUC of ``errors`` as a predictor of success (a small error predicts success), in [0, 1].

    Returns:
        ``U(errors of failures, errors of successes) / (n_failures n_successes)``; NaN without both outcomes.
    """
    e, s = _pair(errors, success)
    n_s, n_f = int(s.sum()), int((~s).sum())
    if n_s == 0 or n_f == 0:
        return float("nan")
    return mann_whitney_u(e[~s], e[s]) / (n_s * n_f)


def bootstrap_auc_interval(errors: Sequence[float], success: Sequence[bool], *, resamples: int = 1000,
                           seed: int = 0, level: float = 0.95) -> tuple[float, float]:
    """Percentile bootstrap interval of :func:`roc_auc`, resampling episodes with replacement (a resample
    with one outcome only is drawn again within the successes and failures: stratified by outcome).

    Args:
        resamples: Bootstrap resamples (>= 10).
        seed: Seed of the resampling.
        level: Coverage in (0, 1).

    Returns:
        ``(lo, hi)``; ``(nan, nan)`` without both outcomes.

    Raises:
        ValueError: ``resamples`` < 10 or ``level`` outside (0, 1).
    """
    if resamples < 10:
        raise ValueError(f"resamples must be >= 10, got {resamples!r}")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level!r}")
    e, s = _pair(errors, success)
    es, ef = e[s], e[~s]
    if es.size == 0 or ef.size == 0:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    aucs = np.empty(resamples)
    for k in range(resamples):
        bs = es[rng.integers(es.size, size=es.size)]
        bf = ef[rng.integers(ef.size, size=ef.size)]
        aucs[k] = mann_whitney_u(bf, bs) / (bs.size * bf.size)
    tail = 100.0 * (1.0 - level) / 2.0
    lo, hi = np.percentile(aucs, [tail, 100.0 - tail])
    return float(lo), float(hi)


@dataclass(frozen=True)
class Threshold:
    """The threshold that best separates successes from failures: an episode is predicted to succeed when its
    error is ``<= threshold`` (units of the errors). ``youden`` is TPR - FPR there; ``tpr`` the fraction of
    successes below it, ``fpr`` the fraction of failures below it."""

    threshold: float
    youden: float
    tpr: float
    fpr: float


def best_threshold(errors: Sequence[float], success: Sequence[bool]) -> Threshold:
    """The threshold maximising Youden's J = TPR - FPR among the observed errors (the smallest such one).

    Returns:
        A :class:`Threshold`; NaN fields without both outcomes.
    """
    e, s = _pair(errors, success)
    n_s, n_f = int(s.sum()), int((~s).sum())
    if n_s == 0 or n_f == 0:
        nan = float("nan")
        return Threshold(nan, nan, nan, nan)
    cands = np.unique(e)
    tpr = np.array([(e[s] <= c).sum() for c in cands]) / n_s
    fpr = np.array([(e[~s] <= c).sum() for c in cands]) / n_f
    j = tpr - fpr
    k = int(np.argmax(j))
    return Threshold(float(cands[k]), float(j[k]), float(tpr[k]), float(fpr[k]))


def success_below(errors: Sequence[float], success: Sequence[bool], threshold: float) -> tuple[int, int]:
    """``(successes, episodes)`` among the episodes whose error is ``<= threshold`` (the ones a metric with
    that threshold calls correct)."""
    e, s = _pair(errors, success)
    below = e <= threshold
    return int(s[below].sum()), int(below.sum())
