"""COCO annotations of a scene (``scene_gt_coco.json``), as the BOP toolkit's ``calc_gt_coco.py`` writes them,
with COCO keypoints when the ``keypoints`` channel is generated."""

from __future__ import annotations

import numpy as np

__all__ = ["coco_annotation", "coco_scene", "BBOX_EDGES"]

#: The 12 edges of a bbox's 8 corners (simtest's corner order, 1-based as COCO's ``skeleton``).
BBOX_EDGES = ((1, 2), (1, 3), (1, 5), (2, 4), (2, 6), (3, 4), (3, 7), (4, 8), (5, 6), (5, 7), (6, 8), (7, 8))


def coco_annotation(ann_id: int, im_id: int, inst, mask: np.ndarray, mask_visib: np.ndarray, bbox_type: str,
                    keypoints: np.ndarray | None = None) -> dict:
    """One COCO annotation.

    Ids count from 1 within the scene file (pycocotools' COCOeval reads id 0 as "no match"); the segmentation
    is the visible mask (compressed RLE); ``ignore`` marks instances less than 10 % visible; the box is COCO's
    (pixel extent, ``w = xmax - xmin + 1``) of the amodal mask cut to the image, or of the visible mask with
    ``bbox_type="modal"``. ``keypoints`` (J, 3) ``[u, v, visibility]`` become COCO's flat ``keypoints`` list
    (COCO's pixel convention: +0.5 on OpenCV's centres; ``0, 0, 0`` for keypoints outside the image) and
    ``num_keypoints``.
    """
    from pycocotools import mask as mask_utils

    rle = mask_utils.encode(np.asfortranarray(mask_visib.astype(np.uint8)))
    box_rle = rle if bbox_type == "modal" else mask_utils.encode(np.asfortranarray(mask.astype(np.uint8)))
    bbox = [int(round(float(v))) for v in mask_utils.toBbox(box_rle)]
    rle["counts"] = rle["counts"].decode("ascii")
    h, w = mask_visib.shape
    out = {"id": int(ann_id), "image_id": int(im_id), "category_id": int(inst.obj_id), "iscrowd": 0,
           "area": int(np.count_nonzero(mask_visib)), "bbox": bbox, "segmentation": rle,
           "ignore": bool(inst.visib_fract < 0.1), "width": int(w), "height": int(h)}
    if keypoints is not None:
        flat = []
        for u, v, vis in np.asarray(keypoints, np.float64):
            flat += [round(float(u) + 0.5, 3), round(float(v) + 0.5, 3), int(vis)] if vis > 0 else [0, 0, 0]
        out["keypoints"] = flat
        out["num_keypoints"] = int(np.count_nonzero(np.asarray(keypoints)[:, 2] > 0))
    return out


def coco_scene(scene_id: int, images: list, annotations: list, categories: list[int],
               keypoint_counts: dict[int, tuple[int, int]] | None = None) -> dict:
    """The ``scene_gt_coco.json`` content; ``keypoint_counts`` ``{obj_id: (bbox corners, surface keypoints)}``
    names each category's keypoints (``bbox_0..7``, ``fps_0..``) and gives the bbox edges as its skeleton."""
    cats = []
    for c in categories:
        cat = {"id": int(c), "name": str(c), "supercategory": "object"}
        if keypoint_counts and c in keypoint_counts:
            nb, nf = keypoint_counts[c]
            cat["keypoints"] = [f"bbox_{i}" for i in range(nb)] + [f"fps_{i}" for i in range(nf)]
            cat["skeleton"] = [list(e) for e in BBOX_EDGES] if nb == 8 else []
        cats.append(cat)
    return {"info": {"description": f"scene {scene_id}"}, "licenses": [], "images": images,
            "annotations": annotations, "categories": cats}
