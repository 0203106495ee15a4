"""Scoring pose estimates against a BOP dataset's ground truth: matching, per-target errors and aggregates.

Per-target errors are in metres / degrees / pixels (see :mod:`simtest.evaluation.run` for the protocol); the aggregates
are the metrics of :mod:`simtest.metrics.registry`, pooled over targets, plus BOP19's Average Recall.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from simtest.errors import DatasetError
from simtest.io import bop
from simtest.io.dataset import ImageRef, image_size, image_targets, select_images
from simtest.metrics.auc import ADDS_2CM, ycb_auc
from simtest.metrics.bop19 import VISIB_GT_MIN, VSD_DELTA, VSD_TAUS, EvalImage, GroundTruthPose, ResultRow
from simtest.metrics.bop19 import evaluate_bop19
from simtest.metrics.intervals import cluster_bootstrap_interval, wilson_interval
from simtest.metrics.pose import MSPD_REFERENCE_WIDTH, add, adi, mspd, mssd, re, re_sym, te, vsd
from simtest.metrics.registry import NDEG_MCM
from simtest.metrics.tolerance import ToleranceMap, error_components
from simtest.metrics.viewpoint import PI_6, PI_18, accuracy_at
from simtest.objects.loaders import load_dataset_objects

__all__ = ["score_estimates", "aggregate", "aggregate_by_category", "has_categories", "match_estimates",
           "image_matches"]


def match_estimates(ests: list[ResultRow], targets: list[tuple[int, bop.ImageGT]]) -> dict[int, int]:
    """{target index -> estimate index}: by decreasing score, nearest translation, one estimate per target."""
    order = sorted(range(len(ests)), key=lambda i: -float(ests[i].score))
    free = set(range(len(targets)))
    out: dict[int, int] = {}
    for i in order:
        cands = [j for j in free if targets[j][1].obj_id == ests[i].obj_id]
        if not cands:
            continue
        j = min(cands, key=lambda j: float(np.linalg.norm(ests[i].t - targets[j][1].T_cam_obj.t)))
        free.discard(j)
        out[j] = i
    return out


def image_matches(refs: Iterable[ImageRef], estimates: Iterable[ResultRow], models: dict[int, Any]
                  ) -> Iterator[tuple[ImageRef, list[tuple[int, bop.ImageGT]], list[ResultRow], dict[int, int]]]:
    """Per image of ``refs`` (in order): ``(ref, targets, estimates, match)``: its targets (``(gt_id, gt)`` with
    ``visib_fract >= VISIB_GT_MIN``), its estimates of objects in ``models``, and :func:`match_estimates` of the
    two. The one matching of every scorer (:func:`score_estimates`, tracking)."""
    by_image: dict[tuple[int, int], list[ResultRow]] = defaultdict(list)
    for e in estimates:
        by_image[(int(e.scene_id), int(e.im_id))].append(e)
    for ref in refs:
        targets = image_targets(ref, VISIB_GT_MIN)
        ests = [e for e in by_image.get((ref.scene_id, ref.im_id), []) if e.obj_id in models]
        yield ref, targets, ests, match_estimates(ests, targets)


def aggregate(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Aggregate metrics (:mod:`simtest.metrics.registry` keys) pooled over per-target error rows."""
    n = len(rows)
    inf = float("inf")

    def col(key: str, miss: float) -> np.ndarray:
        return np.array([r[key] if r["matched"] else miss for r in rows], dtype=np.float64)

    adds = col("adi", inf)
    addsa = col("add_s_or_add", inf)
    diam = np.array([r["diameter_m"] for r in rows])
    re_s = col("re_sym", 180.0)
    te_m = col("te", inf)
    out: dict[str, Any] = {
        "num_targets": n,
        "num_matched": int(sum(r["matched"] for r in rows)),
        "add_s_or_add_01d": float(np.mean(addsa < 0.1 * diam)),
        "auc_adds": ycb_auc(adds),
        "auc_add_s_or_add": ycb_auc(addsa),
        "adds_lt_2cm": float(np.mean(adds < ADDS_2CM)),
        "acc_pi_6": accuracy_at(np.radians(re_s), PI_6),
        "acc_pi_18": accuracy_at(np.radians(re_s), PI_18),
        "median_re_deg": float(np.median(re_s)),
        "median_te_m": float(np.median(te_m)),
        "mean_add_s_or_add_m": float(np.mean(addsa[np.isfinite(addsa)])) if np.isfinite(addsa).any() else inf,
    }
    hits = {"add_s_or_add_01d": addsa < 0.1 * diam, "adds_lt_2cm": adds < ADDS_2CM,
            "acc_pi_6": np.radians(re_s) < PI_6, "acc_pi_18": np.radians(re_s) < PI_18}
    for nd, mc in NDEG_MCM:
        hits[f"{nd:g}deg{mc:g}cm"] = (re_s <= nd) & (te_m <= mc / 100.0)
        out[f"{nd:g}deg{mc:g}cm"] = float(np.mean(hits[f"{nd:g}deg{mc:g}cm"]))
    #: 95 % Wilson intervals of the proportions of targets, [low, high] fractions
    out["ci95"] = {k: list(wilson_interval(int(np.sum(h)), n)) for k, h in hits.items()}
    ready = [bool(r["grasp_ready"]) for r in rows if r.get("grasp_ready") is not None]
    if ready:  # scored with a tolerance map: over the targets of the objects it covers
        out["grasp_tolerance"] = float(np.mean(ready))
        out["num_grasp_targets"] = len(ready)
        out["ci95"]["grasp_tolerance"] = list(wilson_interval(int(sum(ready)), len(ready)))
    scenes = [r.get("scene_id") for r in rows]
    if len(set(scenes)) > 1:
        #: 95 % percentile-bootstrap intervals over scenes (targets of one scene are not independent)
        out["ci95_scenes"] = {k: list(cluster_bootstrap_interval(h.astype(np.float64), scenes))
                              for k, h in hits.items()}
        out["num_scenes"] = len(set(scenes))
    return out


def has_categories(categories: dict[int, str]) -> bool:
    """Whether ``{obj_id: category}`` groups objects: more than one category, and fewer than objects."""
    return 1 < len(set(categories.values())) < len(categories)


def aggregate_by_category(rows: list[dict[str, Any]], per_object: dict[int, dict[str, Any]],
                          categories: dict[int, str]) -> dict[str, dict[str, Any]]:
    """Aggregates per object category (sorted by name), pooled over the targets of the category's objects.

    The metrics of :func:`aggregate` (Acc@pi/6 and Acc@pi/18 of the viewpoint protocol among them) come from
    the category's error rows; BOP19's AR_VSD / AR_MSSD / AR_MSPD are the per-object recalls weighted by
    their target counts (exact: each recall is a count of matched targets), AR their mean; ``num_objects``
    counts the category's objects with targets.

    Args:
        rows: Per-target error rows (``obj_id``, ``matched``, errors; see :func:`score_estimates`).
        per_object: ``{obj_id: metrics}`` of the same rows (for the BOP19 recalls).
        categories: ``{obj_id: category}``; an object missing here counts as category ``"?"``.
    """
    by_cat: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        by_cat[categories.get(r["obj_id"], "?")].append(r)
    out: dict[str, dict[str, Any]] = {}
    for cat in sorted(by_cat):
        objs = sorted({r["obj_id"] for r in by_cat[cat]})
        m = aggregate(by_cat[cat])
        m["num_objects"] = len(objs)
        n = [per_object[o]["num_targets"] for o in objs]
        for k in ("ar_vsd", "ar_mssd", "ar_mspd"):
            vals = [per_object[o].get(k, float("nan")) for o in objs]
            m[k] = float(np.dot(vals, n) / sum(n)) if sum(n) else float("nan")
        ars = [m[k] for k in ("ar_vsd", "ar_mssd", "ar_mspd") if math.isfinite(m[k])]
        m["ar"] = float(np.mean(ars)) if ars else float("nan")
        out[cat] = m
    return out


def _errors(e: ResultRow, g: bop.ImageGT, obj, syms: np.ndarray, K: np.ndarray, width: int,
            depth: np.ndarray | None) -> dict[str, float]:
    """Errors of one matched estimate against its target: metres, degrees, pixels at 640 px width (MSPD), and
    the mean VSD over BOP19's taus when the test ``depth`` (metres) is given."""
    R_g, t_g = g.T_cam_obj.R, g.T_cam_obj.t
    pts = obj.vertices
    out = {"score": float(e.score), "add": add(e.R, e.t, R_g, t_g, pts), "adi": adi(e.R, e.t, R_g, t_g, pts)}
    out["add_s_or_add"] = out["adi"] if obj.is_symmetric else out["add"]
    out.update(re=re(e.R, R_g), re_sym=re_sym(e.R, R_g, syms), te=te(e.t, t_g),
               mssd=mssd(e.R, e.t, R_g, t_g, pts, syms),
               mspd=mspd(e.R, e.t, R_g, t_g, K, pts, syms) * MSPD_REFERENCE_WIDTH / width)
    if depth is not None:
        out["vsd"] = float(np.mean(vsd(e.R, e.t, R_g, t_g, depth, K, obj, VSD_DELTA, VSD_TAUS, obj.diameter)))
    return out


def score_estimates(dataset_dir: str | Path, estimates: Iterable[ResultRow], *, split: str | None = None,
                    scenes: Sequence[int] | None = None, max_images: int | None = None, vsd_enabled: bool = True,
                    scales: Sequence[float] | None = None, objects=None, progress: bool = False,
                    tolerance: ToleranceMap | None = None,
                    _refs: list[ImageRef] | None = None) -> tuple[dict, dict, list[dict], dict[int, str]]:
    """Score estimates (metres) against the dataset's ground truth.

    Args:
        dataset_dir: BOP dataset root.
        estimates: Result rows (:class:`simtest.metrics.bop19.ResultRow`, metres).
        split: Split folder name.
        scenes: Scene ids to evaluate (default all).
        max_images: Evaluate only the first N images (scenes in order, images in order).
        vsd_enabled: Compute VSD (per-target mean over taus and BOP19 AR_VSD).
        scales: Optional scale of each estimate (parallel to ``estimates``), copied into the error rows of the
            matched ones when it is not 1.
        objects: The object set (default :func:`simtest.objects.loaders.load_dataset_objects`).
        progress: Show a progress bar.
        tolerance: A grasp tolerance map (``simtest tolerance``): each target of an object it covers gets
            ``grasp_ready`` (its estimate's error within the object's limit on every axis; a miss is not) and
            the aggregates ``grasp_tolerance``.

    Returns:
        ``(overall, per_object, error_rows, object_names)``; every target of the selected images counts,
        images without estimates are all misses.
    """
    from tqdm import tqdm

    root = Path(dataset_dir)
    objects = load_dataset_objects(root) if objects is None else objects
    refs = _refs if _refs is not None else select_images(root, split, scenes, max_images, objects.ids)
    width, height = image_size(root)
    estimates = list(estimates)
    scale_of = {} if scales is None else {id(e): float(s) for e, s in zip(estimates, scales, strict=True) if s != 1.0}
    models = {o.obj_id: o for o in objects}
    sym_cache: dict[int, np.ndarray] = {}
    rows: list[dict[str, Any]] = []
    # BOP19 hit counts: sum over images of ar_x * num_targets, per object.
    bop_hits: dict[int, dict[str, float]] = defaultdict(lambda: defaultdict(float))
    error_types = ("vsd", "mssd", "mspd") if vsd_enabled else ("mssd", "mspd")
    bar = tqdm(refs, desc="score", unit="img", disable=not progress, dynamic_ncols=True)
    for ref, targets, ests, match in image_matches(bar, estimates, models):
        if not targets:
            continue
        K = ref.info["K"]
        depth = bop.read_depth(ref.scene_dir, ref.im_id, ref.info["depth_scale"]) if vsd_enabled else None
        for j, (gt_id, g) in enumerate(targets):
            obj = models[g.obj_id]
            if g.obj_id not in sym_cache:
                sym_cache[g.obj_id] = obj.symmetry_transforms()
            syms = sym_cache[g.obj_id]
            row: dict[str, Any] = {"scene_id": ref.scene_id, "im_id": ref.im_id, "gt_id": gt_id, "obj_id": g.obj_id,
                                   "visib_fract": float(g.visib_fract), "diameter_m": float(obj.diameter),
                                   "symmetric": bool(obj.is_symmetric), "matched": j in match}
            if j in match:
                e = ests[match[j]]
                row.update(_errors(e, g, obj, syms, K, width, depth if vsd_enabled else None))
                if id(e) in scale_of:
                    row["scale"] = scale_of[id(e)]
            if tolerance is not None and g.obj_id in tolerance.limits:
                row["grasp_ready"] = bool(j in match and tolerance.allows(g.obj_id, error_components(
                    ests[match[j]].R, ests[match[j]].t, g.T_cam_obj.R, g.T_cam_obj.t, syms)))
            rows.append(row)
        # BOP19 on this image.
        gts = [GroundTruthPose(ref.scene_id, ref.im_id, j, g.obj_id, g.T_cam_obj.R, g.T_cam_obj.t, g.visib_fract)
               for j, g in enumerate(ref.info["gt"]) if g.obj_id in models and ref.scores(g.obj_id)]
        res = evaluate_bop19(ests, gts, models, {(ref.scene_id, ref.im_id): EvalImage(K, width, height, depth)},
                             error_types=error_types)
        for o, po in res.per_object.items():
            n = po["num_targets"]
            for k in ("ar_vsd", "ar_mssd", "ar_mspd"):
                if math.isfinite(po[k]):
                    bop_hits[o][k] += po[k] * n
            bop_hits[o]["n"] += n
    if not rows:
        raise DatasetError(f"{root}/{split}: no ground-truth instance with visib_fract >= {VISIB_GT_MIN} and a "
                           "known model in the selected images; nothing to score")

    def bop_of(objs: Iterable[int]) -> dict[str, float]:
        objs = list(objs)
        n = sum(bop_hits[o]["n"] for o in objs)
        out = {}
        for k in ("ar_vsd", "ar_mssd", "ar_mspd"):
            out[k] = sum(bop_hits[o][k] for o in objs) / n if (n and (k != "ar_vsd" or vsd_enabled)) else float("nan")
        vals = [out[k] for k in ("ar_vsd", "ar_mssd", "ar_mspd") if math.isfinite(out[k])]
        out["ar"] = float(np.mean(vals)) if vals else float("nan")
        return out

    overall = aggregate(rows)
    overall.update(bop_of(bop_hits))
    per_object: dict[int, dict[str, Any]] = {}
    by_obj: dict[int, list] = defaultdict(list)
    for r in rows:
        by_obj[r["obj_id"]].append(r)
    for o in sorted(by_obj):
        per_object[o] = aggregate(by_obj[o])
        per_object[o].update(bop_of([o]))
    names = {o.obj_id: o.name for o in objects}
    return overall, per_object, rows, names
