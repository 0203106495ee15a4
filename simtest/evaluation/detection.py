"""Scoring of the 6D detection task (``evaluate(..., task="detection")``): BOP24 AP and classification.

The estimator is told nothing about the image (``Observation.target_obj_ids`` is ``None``) and may return any
number of scored estimates; the :data:`~simtest.metrics.bop24.MAX_ESTIMATES_PER_IMAGE` of highest score per
image are kept. Two scores:

* **BOP24 AP** (:mod:`simtest.metrics.bop24`, as the BOP toolkit's ``eval_bop24_pose.py``): AP_MSSD, AP_MSPD,
  their mean AP, and AP_MSSD in millimetres; per object and overall (the mean over objects), per category as
  the mean of its objects' APs.
* **Classification** (the compositional protocol): each target (``visib_fract >= 0.1``) is matched to at most
  one estimate regardless of object: per image, estimates in order of decreasing score each take the unmatched
  target with the nearest translation among those whose centre lies less than half the target object's
  diameter away. A target is **classified** when its estimate's object has the target object's category
  (misses and unmatched targets count as wrong). Acc@pi/6 and Acc@pi/18 count classified targets whose
  rotation error (``re_sym`` against the target, over its object's symmetries) is below the threshold; the
  median rotation error counts every target not classified as 180 degrees.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from simtest.io.dataset import ImageRef
from simtest.metrics.bop24 import VISIB_GT_MIN, ObjectErrors, evaluate_bop24, keep_top_per_image
from simtest.metrics.bop19 import ResultRow
from simtest.metrics.pose import MSPD_REFERENCE_WIDTH, mspd, mssd, re_sym
from simtest.metrics.viewpoint import PI_6, PI_18, accuracy_at

__all__ = ["DetectionScores", "score_detection", "detection_groups", "classification_rows",
           "classification_aggregate", "keep_top_per_image", "CLASSIFICATION_GATE"]

#: A class-agnostic match needs the estimate's centre within this fraction of the target's diameter.
CLASSIFICATION_GATE = 0.5
_AP_KEYS = ("ap", "ap_mssd", "ap_mspd", "ap_mssd_mm")


@dataclass
class DetectionScores:
    """Detection scores: ``overall`` and ``per_object`` (AP keys, ``num_gt_visible``, classification keys),
    ``per_category`` (the same, APs averaged over the category's objects) and the per-target classification
    rows."""

    overall: dict[str, Any]
    per_object: dict[int, dict[str, Any]]
    per_category: dict[str, dict[str, Any]] = field(default_factory=dict)
    rows: list[dict[str, Any]] = field(default_factory=list)


def _by_image(estimates: Iterable[ResultRow]) -> dict[tuple[int, int], list[ResultRow]]:
    out: dict[tuple[int, int], list[ResultRow]] = defaultdict(list)
    for e in estimates:
        out[(int(e.scene_id), int(e.im_id))].append(e)
    return out


def detection_groups(refs: Sequence[ImageRef], estimates: Iterable[ResultRow], models: dict[int, Any],
                     width: int) -> list[ObjectErrors]:
    """One :class:`~simtest.metrics.bop24.ObjectErrors` per (image, object with a ground-truth instance in it),
    in the toolkit's order; ``estimates`` are the kept ones, each image's in decreasing score order."""
    syms: dict[int, np.ndarray] = {}
    by_image = _by_image(estimates)
    out = []
    for ref in refs:
        gts = [g for g in ref.info["gt"] if g.obj_id in models]
        ests = by_image.get((ref.scene_id, ref.im_id), [])
        K = ref.info["K"]
        for obj_id in dict.fromkeys(g.obj_id for g in gts):
            obj = models[obj_id]
            if obj_id not in syms:
                syms[obj_id] = obj.symmetry_transforms()
            og = [g for g in gts if g.obj_id == obj_id]
            oe = [e for e in ests if e.obj_id == obj_id]
            err = {k: np.full((len(oe), len(og)), np.inf) for k in ("mssd", "mssd_mm", "mspd")}
            for i, e in enumerate(oe):
                for j, g in enumerate(og):
                    R_g, t_g = g.T_cam_obj.R, g.T_cam_obj.t
                    if np.linalg.norm(e.t - t_g) < obj.diameter:  # the toolkit's sphere test
                        d = mssd(e.R, e.t, R_g, t_g, obj.vertices, syms[obj_id])
                        err["mssd"][i, j], err["mssd_mm"][i, j] = d / obj.diameter, d  # metres
                    err["mspd"][i, j] = mspd(e.R, e.t, R_g, t_g, K, obj.vertices, syms[obj_id]) \
                        * MSPD_REFERENCE_WIDTH / width
            out.append(ObjectErrors(ref.scene_id, ref.im_id, obj_id, np.array([e.score for e in oe], float),
                                    np.array([g.visib_fract for g in og], float), err))
    return out


def classification_rows(refs: Sequence[ImageRef], estimates: Iterable[ResultRow], models: dict[int, Any],
                        categories: dict[int, str]) -> list[dict[str, Any]]:
    """One row per target (``visib_fract >= 0.1``): ``scene_id, im_id, gt_id, obj_id, category, matched,
    est_obj_id, est_category, classified, re_sym`` (degrees; 180 unless classified), by the class-agnostic
    matching of the module doc."""
    by_image = _by_image(estimates)
    syms: dict[int, np.ndarray] = {}
    rows = []
    for ref in refs:
        targets = [(j, g) for j, g in enumerate(ref.info["gt"]) if g.obj_id in models and g.visib_fract >= VISIB_GT_MIN]
        ests = sorted(by_image.get((ref.scene_id, ref.im_id), []), key=lambda e: float(e.score), reverse=True)
        free = set(range(len(targets)))
        match: dict[int, ResultRow] = {}
        for e in ests:
            cands = [(float(np.linalg.norm(e.t - targets[k][1].T_cam_obj.t)), k) for k in sorted(free)]
            cands = [(d, k) for d, k in cands if d < CLASSIFICATION_GATE * models[targets[k][1].obj_id].diameter]
            if cands:
                k = min(cands)[1]
                free.discard(k)
                match[k] = e
        for k, (gt_id, g) in enumerate(targets):
            e = match.get(k)
            cat = categories.get(g.obj_id, "?")
            est_cat = categories.get(e.obj_id, "?") if e is not None else ""
            ok = e is not None and est_cat == cat
            r = 180.0
            if ok:
                if g.obj_id not in syms:
                    syms[g.obj_id] = models[g.obj_id].symmetry_transforms()
                r = re_sym(e.R, g.T_cam_obj.R, syms[g.obj_id])
            rows.append({"scene_id": ref.scene_id, "im_id": ref.im_id, "gt_id": gt_id, "obj_id": g.obj_id,
                         "category": cat, "matched": e is not None, "est_obj_id": "" if e is None else e.obj_id,
                         "est_category": est_cat, "classified": ok, "re_sym": float(r)})
    return rows


def classification_aggregate(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Top-1 classification accuracy, Acc@pi/6, Acc@pi/18 and the median rotation error over ``rows``."""
    ok = np.array([r["classified"] for r in rows], bool)
    re_rad = np.radians(np.array([r["re_sym"] for r in rows], float))
    if not len(rows):
        nan = float("nan")
        return {"cls_acc": nan, "cls_acc_pi_6": nan, "cls_acc_pi_18": nan, "cls_median_re_deg": nan}
    return {"cls_acc": float(ok.mean()), "cls_acc_pi_6": accuracy_at(re_rad, PI_6),
            "cls_acc_pi_18": accuracy_at(re_rad, PI_18), "cls_median_re_deg": float(np.degrees(np.median(re_rad)))}


def score_detection(refs: Sequence[ImageRef], estimates: Sequence[ResultRow], models: dict[int, Any],
                    categories: dict[int, str], width: int, with_categories: bool) -> DetectionScores:
    """BOP24 AP and classification of the kept ``estimates`` (see the module doc); ``per_category`` only with
    ``with_categories``."""
    kept = keep_top_per_image(e for e in estimates if e.obj_id in models)
    res = evaluate_bop24(detection_groups(refs, kept, models, width))
    rows = classification_rows(refs, kept, models, categories)
    by_obj: dict[int, list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        by_obj[r["obj_id"]].append(r)
    per_object = {o: {**res.per_object.get(o, {}), **classification_aggregate(by_obj[o])} for o in sorted(by_obj)}
    overall = {**res.overall, **classification_aggregate(rows)}
    per_category: dict[str, dict[str, Any]] = {}
    if with_categories:
        by_cat: dict[str, list[dict[str, Any]]] = defaultdict(list)
        for r in rows:
            by_cat[r["category"]].append(r)
        for cat in sorted(by_cat):
            objs = sorted({r["obj_id"] for r in by_cat[cat]} & set(res.per_object))
            m: dict[str, Any] = {"num_objects": len({r["obj_id"] for r in by_cat[cat]}),
                                 "num_targets": len(by_cat[cat]), **classification_aggregate(by_cat[cat])}
            for k in _AP_KEYS:
                vals = [res.per_object[o][k] for o in objs]
                m[k] = float(np.mean(vals)) if vals else float("nan")
            per_category[cat] = m
    return DetectionScores(overall, per_object, per_category, rows)
