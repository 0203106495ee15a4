"""How often a detector's region holds the object, on a BOP dataset with visible masks (docs/sim2real.md).

Per target (``visib_fract >= 0.1``): the detector's class map of the image, the connected regions of the
target's class (``min_region_pixels`` and up), and whether the region a rule picks overlaps the target's
``mask_visib`` with IoU >= 0.3. Rules: ``area`` (largest region), ``prob`` (highest mean class probability),
``top3`` (any of the three largest), ``prob3`` (any of the three most probable: what ``--opt candidates=3``, the
shipped pipeline, could reach with a perfect verifier), ``cands`` (any of the candidate regions the template
stage poses, eroded and pooled as it pools them: with ``--extra P`` also those of ``--opt region_extra=P``). Also the
class IoU of the whole class map, per object. Run from the repository root::

    simtest masks --data LMO --out LMO-masked          # real sets ship without masks
    python docs/sim2real_detector.py simtest/estimators/weights/keypoints_detector_lmo_640x480.onnx LMO-masked
    python docs/sim2real_detector.py "FIRST.onnx+SECOND.onnx" LMO-masked [--threshold 0.1]   # pooled regions
    python docs/sim2real_detector.py "FIRST.onnx+SECOND.onnx" LMO-masked --extra 0.2 --per-object
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from simtest.estimators.keypoints.template_stage import TEMPLATE_CANDIDATES  # noqa: E402
from simtest.estimators.segicp.infer import Segmenter  # noqa: E402
from simtest.estimators.templates.estimator import pooled_regions  # noqa: E402
from simtest.io import bop  # noqa: E402
from simtest.io.bop_splits import dataset_split_dir, scene_dirs  # noqa: E402

HIT_IOU = 0.3
RULES = ("area", "prob", "top3", "prob3", "cands")


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


def score(detector: str, data: Path, max_images: int | None, threads: int, threshold: float = 0.0,
          extra: float = 0.0) -> dict:
    """``{"targets": n, "hits": {rule: count}, "class_iou": {obj_id: iou}, "by_object": {obj_id: {rule:
    count, "targets": n}}, "candidates": mean candidate regions per object and image}`` over the dataset's
    images. ``detector``: one checkpoint, or several joined by ``+`` (as the estimators pool them): ``prob3``
    and ``cands`` are then any region of each, the other rules and the class IoU are the first's."""
    segs = [Segmenter(d, "cpu", 40, threads, runtime="auto") for d in detector.split("+")]
    hits, n = dict.fromkeys(RULES, 0), 0
    by_object: dict[int, dict[str, int]] = {}
    counts: list[int] = []
    inter: dict[int, int] = {}
    union: dict[int, int] = {}
    images = [(s, im, d) for s in scene_dirs(dataset_split_dir(data)) for im, d in sorted(bop.read_scene(s).items())]
    for scene, im, d in images[:max_images]:
        rgb = bop.read_image(scene, im)
        probs = [seg.probabilities(rgb, np.zeros(rgb.shape[:2], np.float32), d["K"]) for seg in segs]
        ids = tuple(int(g.obj_id) for g in d["gt"] if g.obj_id in segs[0].class_ids)
        cands = pooled_regions(segs, probs, SimpleNamespace(target_obj_ids=ids), TEMPLATE_CANDIDATES, "prob",
                               threshold, extra)
        counts += [sum(o == oid for o, _, _ in cands) for oid in set(ids)]
        for k, g in enumerate(d["gt"]):
            if g.visib_fract < 0.1 or g.obj_id not in segs[0].class_ids:
                continue
            m = bop.read_mask(scene, im, k)
            n += 1
            mine = by_object.setdefault(int(g.obj_id), {**dict.fromkeys(RULES, 0), "targets": 0})
            mine["targets"] += 1
            held = any(o == g.obj_id and _iou(r, m) >= HIT_IOU for o, r, _ in cands)
            hits["cands"] += held
            mine["cands"] += held
            found = [_regions(seg, prob, seg.class_ids.index(g.obj_id) + 1, threshold)
                     for seg, prob in zip(segs, probs)]
            p = found[0][0]
            inter[g.obj_id] = inter.get(g.obj_id, 0) + int((p & m).sum())
            union[g.obj_id] = union.get(g.obj_id, 0) + int((p | m).sum())
            held = any(_iou(r, m) >= HIT_IOU for _, regions, probs_ in found
                       for r in [regions[i] for i in np.argsort(-np.asarray(probs_), kind="stable")[:3]])
            hits["prob3"] += held
            mine["prob3"] += held
            _, regions, region_probs = found[0]
            if not regions:
                continue
            ious = [_iou(r, m) for r in regions]
            by_area = np.argsort([-r.sum() for r in regions], kind="stable")
            hits["area"] += ious[by_area[0]] >= HIT_IOU
            hits["prob"] += ious[int(np.argmax(region_probs))] >= HIT_IOU
            hits["top3"] += max(ious[i] for i in by_area[:3]) >= HIT_IOU
    return {"targets": n, "hits": hits, "class_iou": {o: inter[o] / max(union[o], 1) for o in sorted(inter)},
            "by_object": by_object, "candidates": float(np.mean(counts)) if counts else 0.0}


def _regions(seg: Segmenter, prob: np.ndarray, c: int, threshold: float) -> tuple[np.ndarray, list, list]:
    """Class ``c``'s pixels (the class map, or probability > ``threshold``), its connected regions of at least
    ``min_region_pixels`` and their mean class probabilities."""
    p = prob.argmax(0) == c if threshold <= 0 else prob[c] > threshold  # as the estimator's region_threshold
    count, comp, stats, _ = cv2.connectedComponentsWithStats(p.astype(np.uint8), connectivity=8)
    regions = [comp == i for i in range(1, count) if stats[i, cv2.CC_STAT_AREA] >= seg.min_region_pixels]
    return p, regions, [float(prob[c][r].mean()) for r in regions]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("detector", help="segmentation checkpoint (.pt or .onnx), or several joined by +")
    ap.add_argument("data", type=Path, help="BOP dataset with mask_visib/")
    ap.add_argument("--max-images", type=int, default=None)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--threshold", type=float, default=0.0,
                    help="regions from class probability > THRESHOLD instead of the class map (region_threshold)")
    ap.add_argument("--extra", type=float, default=0.0,
                    help="cands: also the regions of class probability > EXTRA (--opt region_extra)")
    ap.add_argument("--per-object", action="store_true", help="prob3 and cands per object too")
    args = ap.parse_args()
    r = score(args.detector, args.data, args.max_images, args.threads, args.threshold, args.extra)
    n = r["targets"]
    for rule in RULES:
        print(f"{rule:5s} {r['hits'][rule]}/{n} = {100 * r['hits'][rule] / max(n, 1):.1f} %")
    print(f"candidate regions per object and image: {r['candidates']:.2f}")
    if args.per_object:
        for o, c in sorted(r["by_object"].items()):
            print(f"object {o}: {c['targets']} targets, prob3 {c['prob3']}, cands {c['cands']}")
    ious = r["class_iou"]
    print("class IoU: " + ", ".join(f"{o}: {v:.3f}" for o, v in ious.items())
          + f"; mean {np.mean(list(ious.values())):.3f}")


if __name__ == "__main__":
    main()
