"""Selecting the images of a BOP dataset split, with their validated ground truth (:mod:`simtest.io.bop`).

Used by evaluation and scoring; metres and the OpenCV camera frame, as everywhere past :mod:`simtest.io.bop`.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from simtest.errors import ConfigError, DatasetError
from simtest.io import bop

__all__ = ["ImageRef", "select_images", "image_size", "image_targets", "describe_dataset"]


@dataclass(frozen=True)
class ImageRef:
    """One selected image of a split: its ids, scene folder and validated ground truth."""

    scene_id: int
    im_id: int
    scene_dir: Path
    info: dict  # read_scene entry: K, depth_scale, gt


def select_images(dataset_dir: Path, split: str, scenes: Sequence[int] | None,
                  max_images: int | None, obj_ids: Iterable[int]) -> list[ImageRef]:
    """The selected images with their validated ground truth (:func:`simtest.io.bop.read_scene`; a ground-truth
    ``obj_id`` outside ``obj_ids`` is a :class:`DatasetError`): scenes in order, images in order.

    Args:
        dataset_dir: BOP dataset root.
        split: Split folder name.
        scenes: Scene ids to keep (default all).
        max_images: Keep only the first N images.
        obj_ids: The object ids of the dataset's models.

    Raises:
        ConfigError: Unknown scene ids or a bad ``max_images``.
        DatasetError: Missing split or no images, or invalid ground truth (naming the file and entry).
    """
    split_dir = bop.dataset_split_dir(dataset_dir, split)
    obj_ids = sorted(obj_ids)
    if max_images is not None and int(max_images) < 1:
        raise ConfigError(f"max_images must be >= 1 or None, got {max_images!r}")
    dirs = bop.scene_dirs(split_dir)
    if scenes is not None:
        want = {int(s) for s in scenes}
        known = {int(d.name) for d in dirs}
        missing = sorted(want - known)
        if missing:
            raise ConfigError(f"scenes {missing} not in {split_dir}; available: {sorted(known)}")
        dirs = [d for d in dirs if int(d.name) in want]
    refs: list[ImageRef] = []
    for d in dirs:
        frames = bop.read_scene(d, obj_ids)
        for im_id in sorted(frames):
            refs.append(ImageRef(int(d.name), im_id, d, frames[im_id]))
            if max_images is not None and len(refs) >= int(max_images):
                return refs
    if not refs:
        raise DatasetError(f"{split_dir}: no images found")
    return refs


def image_size(dataset_dir: Path) -> tuple[int, int]:
    """``(width, height)`` of the dataset's images, pixels (from ``camera.json``)."""
    cam = bop.read_camera_json(dataset_dir / "camera.json")
    return int(cam["width"]), int(cam["height"])


def image_targets(ref: ImageRef, visib_min: float) -> list[tuple[int, bop.ImageGT]]:
    """``(gt_id, gt)`` of the instances that are scored: ``visib_fract >= visib_min`` (BOP19: 0.1)."""
    return [(j, g) for j, g in enumerate(ref.info["gt"]) if g.visib_fract >= visib_min]


def describe_dataset(path: Path) -> str:
    """A short human summary of a BOP dataset folder: layout, objects, instances, visibility."""
    manifest = bop.read_json(path / "manifest.json")
    split = path / manifest["config"]["split"]
    n_img = n_inst = 0
    visib = []
    per_obj: dict[int, int] = {}
    for sd in bop.scene_dirs(split):
        for im in bop.read_scene(sd).values():
            n_img += 1
            for g in im["gt"]:
                n_inst += 1
                visib.append(g.visib_fract)
                per_obj[g.obj_id] = per_obj.get(g.obj_id, 0) + 1
    names = {o["obj_id"]: o["name"] for o in manifest["objects"]}
    lines = [f"dataset {path}: {n_img} RGB-D images, {n_inst} annotated instances of {len(per_obj)} objects",
             f"  layout: camera.json, models/ (PLY in mm + models_info.json), "
             f"{manifest['config']['split']}/<scene>/rgb, depth, mask, mask_visib, scene_camera.json, "
             f"scene_gt.json, scene_gt_info.json",
             "  instances per object: " + ", ".join(f"{names.get(k, k)}={v}" for k, v in sorted(per_obj.items()))]
    if visib:
        v = np.asarray(visib)
        lines.append(f"  visibility: median visib_fract {np.median(v):.2f}; {np.mean(v < 0.5) * 100:.0f}% of "
                     f"instances less than half visible")
    return "\n".join(lines)
