"""BOP24 6D object detection: greedy matching per threshold, COCO-style Average Precision, and the mAP over
thresholds and objects, as the BOP toolkit's ``scripts/eval_bop24_pose.py`` computes them.

The protocol (the estimator is told nothing about the image: no object ids, no instance counts):

* At most :data:`MAX_ESTIMATES_PER_IMAGE` estimates per image are kept, those of highest score (ties keep the
  order they were given in): :func:`keep_top_per_image`.
* Every ground-truth instance of the image takes part in the matching, whatever its visibility. Per image,
  object and threshold, the estimates in order of decreasing score each take the not yet matched
  ground-truth instance of the same object with the smallest error below the threshold (strictly below; the
  first instance on ties), at most one estimate per instance (:func:`greedy_match`).
* An estimate matched to an instance with ``visib_fract < 0.1`` is ignored (neither true nor false
  positive); one matched to another instance is a true positive, an unmatched one a false positive. Only
  estimates of objects present in the image's ground truth are scored at all (the toolkit computes errors only
  for them), so an estimate of an absent object costs nothing.
* Per object and threshold: the estimates of every image sorted by decreasing score (a stable sort over the
  images in dataset order, the objects of an image in order of their first ground-truth instance, the
  estimates in score order), precision and recall over the object's instances with ``visib_fract >= 0.1``,
  and the AP of COCO: the mean over 101 recall points 0, 0.01, ..., 1 of the largest precision at a recall
  at least that large (:func:`average_precision`).
* AP of an object = the mean over thresholds; an object without an instance with ``visib_fract >= 0.1`` is
  left out; AP_MSSD, AP_MSPD (and AP_MSSD in millimetres) = the mean over objects; the BOP24 AP = the mean of
  AP_MSSD and AP_MSPD.

Thresholds: MSSD 0.05, 0.10, ..., 0.50 of the object's diameter (errors at or beyond one diameter between the
centres are infinite, as the toolkit's sphere test); MSSD 2, 4, ..., 20 mm; MSPD 5, 10, ..., 50 px of an image
640 px wide (errors scaled by 640 / width).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["MAX_ESTIMATES_PER_IMAGE", "VISIB_GT_MIN", "THRESHOLDS", "ERROR_KINDS", "ObjectErrors",
           "Bop24Result", "keep_top_per_image", "greedy_match", "average_precision", "evaluate_bop24"]

#: Estimates kept per image (highest score first), as the toolkit's ``max_num_estimates_per_image``.
MAX_ESTIMATES_PER_IMAGE = 100
#: Ground-truth instances less visible than this are ignored (their matched estimates too).
VISIB_GT_MIN = 0.1
#: Thresholds of correctness per error kind: MSSD as a fraction of the diameter, MSSD in metres (the toolkit's
#: 2, 4, ..., 20 mm; the kind keeps the toolkit's name), MSPD in px (640 px wide image). ``np.arange`` as the
#: toolkit writes them, so the floats are the same.
THRESHOLDS: dict[str, tuple[float, ...]] = {
    "mssd": tuple(float(t) for t in np.arange(0.05, 0.51, 0.05)),
    "mssd_mm": tuple(0.002 * k for k in range(1, 11)),
    "mspd": tuple(float(t) for t in np.arange(5, 51, 5)),
}
#: The error kinds, in the order of ``THRESHOLDS``.
ERROR_KINDS: tuple[str, ...] = tuple(THRESHOLDS)
#: Recall points of the COCO-style AP.
_RECALL_POINTS = np.linspace(0.0, 1.0, 101, endpoint=True)


@dataclass(frozen=True)
class ObjectErrors:
    """The estimates of one object in one image and their errors against that object's ground-truth instances.

    Attributes:
        scene_id, im_id, obj_id: Where.
        scores: ``(n_est,)`` confidences, in decreasing order (the order of the image's kept estimates).
        visib: ``(n_gt,)`` ``visib_fract`` of the object's ground-truth instances, in ground-truth order.
        errors: ``{kind: (n_est, n_gt) errors}`` in the units of :data:`THRESHOLDS` (``mssd``: fraction of the
            diameter, ``inf`` when the centres are a diameter or more apart; ``mssd_mm``: metres, same rule;
            ``mspd``: px at 640 px width).
    """

    scene_id: int
    im_id: int
    obj_id: int
    scores: np.ndarray
    visib: np.ndarray
    errors: dict[str, np.ndarray] = field(default_factory=dict)


@dataclass
class Bop24Result:
    """``per_object[obj_id]``: ``ap_mssd``, ``ap_mssd_mm``, ``ap_mspd``, ``ap`` (mean of AP_MSSD and AP_MSPD) and
    ``num_gt_visible``; ``overall``: the same APs averaged over the objects with visible instances (NaN when
    there is none), plus ``num_gt_visible``."""

    per_object: dict[int, dict[str, float]]
    overall: dict[str, float]


def keep_top_per_image(rows: Iterable[Any], limit: int = MAX_ESTIMATES_PER_IMAGE) -> list[Any]:
    """The ``limit`` estimates of highest score of each image (rows with ``scene_id``, ``im_id``, ``score``),
    images in order of first appearance, each image's rows by decreasing score (a stable sort: equal scores
    keep their order)."""
    by_image: dict[tuple[int, int], list[Any]] = {}
    for r in rows:
        by_image.setdefault((int(r.scene_id), int(r.im_id)), []).append(r)
    out: list[Any] = []
    for group in by_image.values():
        out += sorted(group, key=lambda r: float(r.score), reverse=True)[:limit]
    return out


def greedy_match(errors: np.ndarray, threshold: float) -> list[int]:
    """Per estimate (rows of ``errors``, already in decreasing score order): the index of the ground-truth
    instance (column) it is matched to, or -1. Each estimate in turn takes the unmatched instance with the
    smallest error strictly below ``threshold`` (the first such column on ties)."""
    taken: set[int] = set()
    out = []
    for row in np.asarray(errors, dtype=np.float64):
        best, best_err = -1, threshold
        for j, e in enumerate(row):
            if j not in taken and e < best_err:
                best, best_err = j, e
        if best >= 0:
            taken.add(best)
        out.append(best)
    return out


def average_precision(true_positive: Sequence[bool], num_gt: int) -> float:
    """COCO-style AP of detections in decreasing score order (``True``: a true positive, ``False``: a false
    positive) over ``num_gt`` ground-truth instances: the mean over the 101 recall points of the largest
    precision reached at a recall at least as large (0 where none is)."""
    tp = np.asarray(true_positive, dtype=bool)
    tp_c = np.cumsum(tp)
    fp_c = np.cumsum(~tp)
    recall = tp_c / float(num_gt)
    with np.errstate(invalid="ignore", divide="ignore"):
        precision = tp_c / (tp_c + fp_c)
    precision[~np.isfinite(precision)] = 0.0
    rec = np.concatenate(([0.0], recall, [1.0]))
    pre = np.concatenate(([0.0], precision, [0.0]))
    return float(np.mean([pre[rec >= r].max() if np.any(rec >= r) else 0.0 for r in _RECALL_POINTS]))


def _object_ap(groups: list[ObjectErrors], kind: str, threshold: float) -> float:
    """AP of one object's groups at one threshold (see the module doc)."""
    num_gt = sum(int(np.count_nonzero(g.visib >= VISIB_GT_MIN)) for g in groups)
    scored: list[tuple[float, bool]] = []
    for g in groups:
        for i, j in enumerate(greedy_match(g.errors[kind], threshold)):
            if j >= 0 and g.visib[j] < VISIB_GT_MIN:
                continue  # matched to an instance too hidden to count: ignored
            scored.append((float(g.scores[i]), j >= 0))
    ordered = sorted(scored, key=lambda s: s[0], reverse=True)
    return average_precision([tp for _, tp in ordered], num_gt)


def evaluate_bop24(groups: Iterable[ObjectErrors], kinds: Sequence[str] = ERROR_KINDS) -> Bop24Result:
    """AP per object and error kind, and their means (see the module doc).

    Args:
        groups: One :class:`ObjectErrors` per (image, object present in its ground truth), in the order the
            toolkit visits them: images in dataset order, the objects of an image in order of their first
            ground-truth instance (it decides the order of estimates of equal score).
        kinds: Error kinds to evaluate (keys of :data:`THRESHOLDS`).
    """
    by_obj: dict[int, list[ObjectErrors]] = {}
    for g in groups:
        by_obj.setdefault(int(g.obj_id), []).append(g)
    per_object: dict[int, dict[str, float]] = {}
    for obj_id in sorted(by_obj):
        gs = by_obj[obj_id]
        n = sum(int(np.count_nonzero(g.visib >= VISIB_GT_MIN)) for g in gs)
        if n == 0:
            continue
        m: dict[str, float] = {"num_gt_visible": n}
        for kind in kinds:
            m[f"ap_{kind}"] = float(np.mean([_object_ap(gs, kind, th) for th in THRESHOLDS[kind]]))
        per_object[obj_id] = _with_mean(m)
    overall: dict[str, float] = {"num_gt_visible": sum(int(m["num_gt_visible"]) for m in per_object.values())}
    for kind in kinds:
        vals = [m[f"ap_{kind}"] for m in per_object.values()]
        overall[f"ap_{kind}"] = float(np.mean(vals)) if vals else float("nan")
    return Bop24Result(per_object, _with_mean(overall))


def _with_mean(m: dict[str, float]) -> dict[str, float]:
    """``m`` with ``ap``: the mean of ``ap_mssd`` and ``ap_mspd`` when both are there."""
    if "ap_mssd" in m and "ap_mspd" in m:
        a, b = m["ap_mssd"], m["ap_mspd"]
        m["ap"] = float(np.mean([a, b])) if math.isfinite(a) and math.isfinite(b) else float("nan")
    return m
