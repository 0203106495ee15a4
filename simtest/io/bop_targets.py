"""The BOP test-target files of a split: ``test_targets_bop19.json`` (localization: per image and object the
number of instances with ``visib_fract >= 0.1``) and ``test_targets_bop24.json`` (detection: per image only
``scene_id`` and ``im_id``), in the BOP toolkit's formats, at the dataset root beside ``camera.json``."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from simtest.io.files import atomic_write_text

__all__ = ["TARGETS_BOP19", "TARGETS_BOP24", "targets_bop19", "targets_bop24", "write_targets"]

TARGETS_BOP19 = "test_targets_bop19.json"
TARGETS_BOP24 = "test_targets_bop24.json"
_VISIB_MIN = 0.1  # BOP19's visib_gt_min


def targets_bop19(scene_id: int, scene_gt: dict[str, list], scene_gt_info: dict[str, list]) -> list[dict[str, int]]:
    """``{"im_id", "inst_count", "obj_id", "scene_id"}`` per image (ascending) and object (in order of its first
    instance) with at least one instance visible from 10 %, as the toolkit's ``enumerate_test_targets.py``."""
    out = []
    for im in sorted(scene_gt, key=int):
        counts: dict[int, int] = {}
        for g, info in zip(scene_gt[im], scene_gt_info[im], strict=True):
            if info["visib_fract"] >= _VISIB_MIN:
                counts[int(g["obj_id"])] = counts.get(int(g["obj_id"]), 0) + 1
        out += [{"im_id": int(im), "inst_count": n, "obj_id": o, "scene_id": int(scene_id)} for o, n in counts.items()]
    return out


def targets_bop24(scene_id: int, scene_gt: dict[str, list]) -> list[dict[str, int]]:
    """``{"im_id", "scene_id"}`` per image (ascending): BOP24's detection targets name no objects or counts."""
    return [{"im_id": int(im), "scene_id": int(scene_id)} for im in sorted(scene_gt, key=int)]


def _json_lines(items: Sequence[dict[str, Any]]) -> str:
    import json

    return "[\n" + ",\n".join("  " + json.dumps(t, sort_keys=True) for t in items) + ("\n]\n" if items else "]\n")


def write_targets(dataset_dir: Path, label_dirs: Sequence[tuple[int, Path]]) -> list[Path]:
    """Write both target files into ``dataset_dir`` from the ``scene_gt.json`` / ``scene_gt_info.json`` of each
    ``(scene_id, folder)`` (scenes in the given order). Returns the paths."""
    import json

    t19: list[dict[str, int]] = []
    t24: list[dict[str, int]] = []
    for scene_id, folder in label_dirs:
        gt = json.loads((folder / "scene_gt.json").read_text())
        info = json.loads((folder / "scene_gt_info.json").read_text())
        t19 += targets_bop19(scene_id, gt, info)
        t24 += targets_bop24(scene_id, gt)
    paths = [dataset_dir / TARGETS_BOP19, dataset_dir / TARGETS_BOP24]
    for path, items in zip(paths, (t19, t24)):
        atomic_write_text(path, _json_lines(items))
    return paths
