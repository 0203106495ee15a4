"""The 95 % intervals of a sweep's pose scores, from one cell's ``metrics.json`` overall and ``errors.csv``.

Every score is over the cell's targets (``n``: the ground-truth instances with ``visib_fract >= 0.1``):

* **Proportions of targets** (ADD(-S)-0.1d, ADD-S<2cm, Acc@pi/6, Acc@pi/18, n deg m cm): the binomial Wilson
  interval ``simtest eval`` records in ``overall["ci95"]`` (method ``wilson``).
* **Means over targets and medians** (AR and its AR_VSD / AR_MSSD / AR_MSPD, the AUCs, median errors, mean
  ADD(-S)): a percentile bootstrap over targets (:func:`simtest.metrics.intervals.bootstrap_interval`,
  :data:`RESAMPLES` resamples, seeded, so the same cell always gives the same interval; method ``bootstrap``).
  A target's share of AR is the mean over the BOP19 thresholds of whether its error is under each (a miss
  counts 0), from the per-target errors (VSD: its mean over the taus); where the pooled BOP19 matching makes
  the reported score differ from the mean of those shares (several instances of one object in an image), the
  interval is moved by that difference, so it is always around the reported score.
* Scores with no per-target form (the detection task's AP and classification accuracy) have ``n`` and no
  interval.

:func:`differs` is the rule the report's summary uses: two scores differ only when each lies outside the
other's interval.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from simtest.metrics.auc import YCB_AUC_MAX_THRESHOLD
from simtest.metrics.bop19 import MSPD_THETAS, MSSD_THETAS, VSD_THETAS
from simtest.metrics.intervals import bootstrap_interval

__all__ = ["Interval", "RESAMPLES", "pose_intervals", "differs"]

#: Bootstrap resamples per score.
RESAMPLES = 2000


@dataclass(frozen=True)
class Interval:
    """A score's count and 95 % interval: ``n`` targets (or episodes), ``[low, high]`` in the score's stored
    unit (NaN when there is none), and how it was made (``wilson`` | ``bootstrap`` | ``""``)."""

    n: int
    low: float = math.nan
    high: float = math.nan
    method: str = ""

    @property
    def known(self) -> bool:
        """Whether both ends are numbers (``inf`` included: a median of misses)."""
        return not (math.isnan(self.low) or math.isnan(self.high))


def _float(text: str | None, missing: float) -> float:
    try:
        x = float(text) if text not in (None, "") else missing
    except ValueError:
        return missing
    return missing if math.isnan(x) else x


def _matched(row: Mapping[str, str]) -> bool:
    return str(row.get("matched", "")).strip().lower() in ("1", "true")


def _column(errors: Sequence[Mapping[str, str]], key: str, miss: float) -> np.ndarray:
    """``errors[key]`` as floats; ``miss`` for unmatched targets and empty cells."""
    return np.array([_float(r.get(key), miss) if _matched(r) else miss for r in errors], dtype=np.float64)


def _recall_share(err: np.ndarray, thresholds: np.ndarray) -> np.ndarray:
    """Per target: the fraction of ``thresholds`` its error is under (strictly, as BOP19)."""
    return (err[:, None] < thresholds[None, :]).mean(axis=1)


def _target_shares(overall: Mapping, errors: Sequence[Mapping[str, str]]) -> dict[str, np.ndarray]:
    """Per-target values whose mean (or median) over targets is the score, keyed by metric."""
    inf = math.inf
    diam = np.array([_float(r.get("diameter_m"), math.nan) for r in errors])
    out = {"ar_mssd": _recall_share(_column(errors, "mssd", inf) / diam, np.asarray(MSSD_THETAS)),
           "ar_mspd": _recall_share(_column(errors, "mspd", inf), np.asarray(MSPD_THETAS))}
    parts = ["ar_mssd", "ar_mspd"]
    vsd = _column(errors, "vsd", inf)
    if math.isfinite(_float(str(overall.get("ar_vsd", "")), math.nan)) and np.isfinite(vsd).any():
        out["ar_vsd"] = _recall_share(vsd, np.asarray(VSD_THETAS))
        parts.insert(0, "ar_vsd")
    out["ar"] = np.mean([out[k] for k in parts], axis=0)
    for key, col in (("auc_adds", "adi"), ("auc_add_s_or_add", "add_s_or_add")):
        out[key] = np.maximum(0.0, 1.0 - _column(errors, col, inf) / YCB_AUC_MAX_THRESHOLD)
    return out


def _mean(batch: np.ndarray) -> np.ndarray:
    return batch.mean(axis=1)


def _median(batch: np.ndarray) -> np.ndarray:
    return np.median(batch, axis=1)


def _shifted(value: float, proxy: float, lo: float, hi: float, bounds: tuple[float, float]) -> tuple[float, float]:
    """``[lo, hi]`` (an interval around ``proxy``) moved to lie around ``value``, clipped to ``bounds``."""
    d = value - proxy if math.isfinite(value) and math.isfinite(proxy) else 0.0
    return max(bounds[0], min(lo + d, value)), min(bounds[1], max(hi + d, value))


def pose_intervals(overall: Mapping, errors: Sequence[Mapping[str, str]], *, seed: int = 0
                   ) -> dict[str, Interval]:
    """The :class:`Interval` of every pose score of one evaluation.

    Args:
        overall: The ``overall`` of ``metrics.json`` (with ``num_targets`` and ``ci95``).
        errors: The rows of its ``errors.csv`` (one per target, strings as read).
        seed: Seed of the bootstrap.

    Returns:
        ``{metric key: Interval}`` for the scores in ``overall``; counts and timings are left out.
    """
    n = int(_float(str(overall.get("num_targets", "")), 0.0))
    found: dict[str, Interval] = {}
    for key, (lo, hi) in (overall.get("ci95") or {}).items():
        found[key] = Interval(n, float(lo), float(hi), "wilson")
    for key in ("ap", "ap_mssd", "ap_mspd", "ap_mssd_mm", "cls_acc", "cls_acc_pi_6", "cls_acc_pi_18",
                "cls_median_re_deg"):
        if key in overall:
            found[key] = Interval(int(_float(str(overall.get("num_gt_visible", n)), n)))
    if not errors or len(errors) != n:
        return found
    for key, shares in _target_shares(overall, errors).items():
        value = _float(str(overall.get(key, "")), math.nan)
        if key in overall and math.isfinite(value):
            lo, hi = bootstrap_interval(shares, _mean, seed=seed, resamples=RESAMPLES)
            lo, hi = _shifted(value, float(shares.mean()), lo, hi, (0.0, 1.0))
            found[key] = Interval(n, lo, hi, "bootstrap")
    medians = {"median_re_deg": _column(errors, "re_sym", 180.0), "median_te_m": _column(errors, "te", math.inf)}
    for key, values in medians.items():
        if key in overall:
            lo, hi = bootstrap_interval(values, _median, seed=seed, resamples=RESAMPLES)
            found[key] = Interval(n, lo, hi, "bootstrap")
    adds = _column(errors, "add_s_or_add", math.inf)
    adds = adds[np.isfinite(adds)]
    if "mean_add_s_or_add_m" in overall and adds.size:
        lo, hi = bootstrap_interval(adds, _mean, seed=seed, resamples=RESAMPLES)
        found["mean_add_s_or_add_m"] = Interval(int(adds.size), lo, hi, "bootstrap")
    return found


def differs(a: tuple[float, Interval], b: tuple[float, Interval]) -> bool:
    """Whether two scores ``(value, interval)`` differ beyond their 95 % intervals: each value lies outside
    the other's interval. Without an interval on either side, plain inequality."""
    (va, ia), (vb, ib) = a, b
    if math.isnan(va) or math.isnan(vb):
        return False
    if not (ia.known and ib.known):
        return va != vb
    return not ib.low <= va <= ib.high and not ia.low <= vb <= ia.high
