"""How much colour varies across the objects of a dataset's images: the rg-chromaticity spread inside masks.

A flat-coloured object varies in brightness (shading) but hardly in chromaticity; a printed or textured one
varies in both. :func:`chromaticity_spread` measures the second, per annotated instance, from the written
files only (``rgb/``, ``mask_visib/``, ``scene_gt.json`` and the object set's ``models/simtest_objects.json``
for category names). Built-in objects with flat colours give about 0.024; printed or textured ones 0.04-0.2.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["chromaticity_spread", "instance_spread", "MIN_VISIBLE", "MIN_SUM", "EDGE"]

#: Instances with fewer visible pixels (``mask_visib``) are left out.
MIN_VISIBLE = 400
#: Pixels with ``r + g + b`` (8-bit values) at or below this are left out (chromaticity is noise there).
MIN_SUM = 30
#: Pixels closer than this to the mask's border (pixels) are left out: they blend with the background
#: (anti-aliasing, JPEG blocks) and would count the background's colour as the object's.
EDGE = 2


def instance_spread(rgb: np.ndarray, mask: np.ndarray) -> float | None:
    """``sqrt(var(r / (r + g + b)) + var(g / (r + g + b)))`` over the pixels of ``mask`` at least :data:`EDGE`
    pixels inside its border with ``r + g + b > MIN_SUM`` (8-bit RGB), or None when fewer than two remain."""
    import cv2

    inner = np.asarray(mask, dtype=np.uint8)
    if EDGE > 0:
        inner = cv2.erode(inner, np.ones((2 * EDGE + 1, 2 * EDGE + 1), np.uint8))
    pix = np.asarray(rgb)[inner.astype(bool)].astype(np.float64)
    total = pix.sum(axis=1)
    keep = total > MIN_SUM
    if keep.sum() < 2:
        return None
    chroma = pix[keep, :2] / total[keep, None]
    return float(np.sqrt(chroma.var(axis=0).sum()))


def _categories(dataset_dir: Path) -> dict[int, str]:
    """Object id -> category from ``models/simtest_objects.json`` (``obj_<id>`` where it says none)."""
    from simtest.io.bop import read_json

    path = dataset_dir / "models" / "simtest_objects.json"
    if not path.is_file():
        return {}
    return {int(k): str(v.get("category") or f"obj_{k}") for k, v in read_json(path).items()}


def chromaticity_spread(dataset_dir: str | Path, split: str | None = None) -> dict:
    """The rg-chromaticity spread inside the objects of a dataset split.

    Definition: for every annotated instance of every image with at least :data:`MIN_VISIBLE` pixels in its
    visible mask (``mask_visib``), the pixels of the RGB image inside that mask, at least :data:`EDGE` pixels
    from its border (the mask eroded by a square of side ``2 * EDGE + 1``) and with ``r + g + b >``
    :data:`MIN_SUM`, give chromaticities ``r / (r + g + b)`` and ``g / (r + g + b)``; the instance's spread is
    ``sqrt(var_r + var_g)`` (population variances, :func:`instance_spread`). Unitless, 0 for a constant
    colour. Reported: the mean over instances, their median and the mean per category.

    Args:
        dataset_dir: A BOP dataset folder as ``simtest generate`` writes it.
        split: The split folder (``train_pbr``, ``test``, ...).

    Returns:
        ``{"mean", "median", "instances", "per_category": {category: {"mean", "instances"}}}`` (``mean`` and
        ``median`` None when no instance qualifies).

    Raises:
        DatasetError: The dataset or split is missing, or a listed mask or image is unreadable.
    """
    from simtest.io.bop import dataset_split_dir, read_image, read_json, read_mask, scene_dirs

    root = Path(dataset_dir)
    cats = _categories(root)
    values: list[float] = []
    by_cat: dict[str, list[float]] = {}
    for scene in scene_dirs(dataset_split_dir(root, split)):
        for im_key, gts in sorted(read_json(scene / "scene_gt.json").items(), key=lambda kv: int(kv[0])):
            im_id = int(im_key)
            rgb = None
            for gt_id, gt in enumerate(gts):
                mask = read_mask(scene, im_id, gt_id, visible=True)
                if int(mask.sum()) < MIN_VISIBLE:
                    continue
                rgb = read_image(scene, im_id) if rgb is None else rgb
                value = instance_spread(rgb, mask)
                if value is None:
                    continue
                values.append(value)
                obj_id = int(gt["obj_id"])
                by_cat.setdefault(cats.get(obj_id, f"obj_{obj_id}"), []).append(value)
    arr = np.asarray(values)
    return {
        "mean": float(arr.mean()) if len(arr) else None,
        "median": float(np.median(arr)) if len(arr) else None,
        "instances": int(len(arr)),
        "per_category": {c: {"mean": float(np.mean(v)), "instances": len(v)} for c, v in sorted(by_cat.items())},
    }
