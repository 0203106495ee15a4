"""Object cutouts: rendered objects of a BOP dataset, cut out with their visible masks, as 2D paste occluders.

The ``objects`` occlusion kind pastes these instead of procedural shapes, as Occluded LINEMOD and
OccludedPASCAL3D+ occlude with real object silhouettes. A cutout is an ``(h, w, 4)`` RGBA uint8 patch: the
RGB image cropped to the instance's visible mask, alpha 255 on the mask. Only (nearly) unoccluded
instances are used, so every cutout shows a whole object.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from simtest.errors import DatasetError
from simtest.io.bop import read_image, read_json, read_mask

__all__ = ["object_cutouts", "MIN_VISIB_FRACT", "MIN_PIXELS"]

#: Smallest visible fraction of an instance used as a cutout.
MIN_VISIB_FRACT = 0.95
#: Smallest visible pixel count of an instance used as a cutout.
MIN_PIXELS = 64


def _candidates(scenes: list[Path]) -> list[tuple[Path, int, int]]:
    """``(scene, im_id, gt_id)`` of every instance visible enough whose visible mask file exists, in file order."""
    out = []
    for scene in scenes:
        info_path = scene / "scene_gt_info.json"
        if not info_path.is_file():
            continue
        for im_key, infos in sorted(read_json(info_path).items(), key=lambda kv: int(kv[0])):
            for gt_id, inf in enumerate(infos):
                if float(inf.get("visib_fract", 0.0)) >= MIN_VISIB_FRACT and \
                        int(inf.get("px_count_visib", 0)) >= MIN_PIXELS and \
                        (scene / "mask_visib" / f"{int(im_key):06d}_{gt_id:06d}.png").is_file():
                    out.append((scene, int(im_key), gt_id))
    return out


def object_cutouts(scenes: list[Path], max_count: int = 64) -> list[np.ndarray]:
    """Up to ``max_count`` RGBA cutouts of unoccluded instances, evenly spread over ``scenes`` (BOP scene
    folders with ``rgb/``, ``mask_visib/`` and ``scene_gt_info.json``). Deterministic: depends on the files only.

    Raises:
        DatasetError: If no instance is visible enough (``visib_fract >= 0.95``, >= 64 pixels) with its
            ``mask_visib/`` file.
    """
    cands = _candidates(scenes)
    if not cands:
        raise DatasetError(f"no object cutouts: no instance in {len(scenes)} scene(s) is at least "
                           f"{MIN_VISIB_FRACT:.0%} visible with {MIN_PIXELS} pixels (scene_gt_info.json) and a "
                           f"mask_visib/ file; use the 'paste' occlusion kind")
    pick = np.unique(np.linspace(0, len(cands) - 1, min(max_count, len(cands))).round().astype(int))
    out = []
    for i in pick:
        scene, im_id, gt_id = cands[i]
        mask = read_mask(scene, im_id, gt_id, visible=True)
        ys, xs = np.nonzero(mask)
        crop = np.s_[ys.min():ys.max() + 1, xs.min():xs.max() + 1]
        alpha = np.where(mask[crop], 255, 0).astype(np.uint8)
        out.append(np.dstack([read_image(scene, im_id)[crop], alpha]))
    return out
