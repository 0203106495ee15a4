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

__all__ = ["ImageRef", "select_scene_dirs", "select_images", "image_size", "image_targets", "describe_dataset", "labels_root",
           "WITHHELD"]

#: Folder (in a dataset root) holding the labels of an unlabelled split: ``withheld/<split>/<scene>/``.
WITHHELD = "withheld"


@dataclass(frozen=True)
class ImageRef:
    """One selected image of a split: its ids, scene folder and validated ground truth."""

    scene_id: int
    im_id: int
    scene_dir: Path
    info: dict  # read_scene entry: K, depth_scale, gt
    label_dir: Path | None = None  # where the labels (scene_gt*, masks) are, when not in scene_dir

    @property
    def gt_dir(self) -> Path:
        """The folder holding this image's ground truth and masks."""
        return self.scene_dir if self.label_dir is None else self.label_dir


def labels_root(dataset_dir: Path, labels: str | Path | None) -> Path | None:
    """The folder holding withheld labels (``<labels>/<split>/<scene>/``), or None when they are in the split.

    ``labels`` given: that folder. Not given: ``<dataset>/withheld`` if the dataset's ``manifest.json`` says
    ``"unlabelled": true``, else None.

    Raises:
        DatasetError: ``labels`` is not a folder, or the dataset is unlabelled and its withheld folder is gone.
    """
    root = Path(dataset_dir)
    if labels is not None:
        path = Path(labels)
        if not path.is_dir():
            raise DatasetError(f"labels folder {str(path)!r} does not exist; give the folder holding "
                               f"<split>/<scene>/scene_gt.json (e.g. {root / WITHHELD})")
        return path
    manifest = root / "manifest.json"
    if not (manifest.is_file() and bop.read_json(manifest).get("unlabelled") is True):
        return None
    if not (root / WITHHELD).is_dir():
        raise DatasetError(f"dataset {root} is unlabelled (manifest.json: \"unlabelled\": true) and its withheld "
                           f"labels folder {root / WITHHELD} is missing; give the labels with --labels DIR")
    return root / WITHHELD


def _scene_gt_dir(scene_dir: Path, labels: Path | None) -> Path:
    """The folder with ``scene_gt.json`` of one scene; :class:`DatasetError` saying how to give labels when
    there is none."""
    gt_dir = scene_dir if labels is None else labels / scene_dir.parent.name / scene_dir.name
    if not (gt_dir / "scene_gt.json").is_file():
        where = ("this split has no labels" if labels is None
                 else f"the labels folder {labels} has no scene {scene_dir.parent.name}/{scene_dir.name}")
        raise DatasetError(f"{gt_dir / 'scene_gt.json'}: file is missing; no ground truth to score against "
                           f"({where}); for a split generated with --unlabelled give its withheld labels with "
                           "--labels DATASET/withheld")
    return gt_dir


def select_scene_dirs(split_dir: Path, scenes: Sequence[int] | None) -> list[Path]:
    """The complete scene folders of ``split_dir``, only ``scenes`` when given.

    Raises:
        ConfigError: A requested scene id that is not in the split (the available ones are listed).
    """
    dirs = bop.scene_dirs(split_dir)
    if scenes is not None:
        want, known = {int(s) for s in scenes}, {int(d.name) for d in dirs}
        if want - known:
            raise ConfigError(f"scenes {sorted(want - known)} not in {split_dir}; available: {sorted(known)}")
        dirs = [d for d in dirs if int(d.name) in want]
    return dirs


def select_images(dataset_dir: Path, split: str, scenes: Sequence[int] | None,
                  max_images: int | None, obj_ids: Iterable[int],
                  labels: str | Path | None = None) -> list[ImageRef]:
    """The selected images with their validated ground truth (:func:`simtest.io.bop.read_scene`; a ground-truth
    ``obj_id`` outside ``obj_ids`` is a :class:`DatasetError`): scenes in order, images in order.

    Args:
        dataset_dir: BOP dataset root.
        split: Split folder name.
        scenes: Scene ids to keep (default all).
        max_images: Keep only the first N images.
        obj_ids: The object ids of the dataset's models.
        labels: Folder of withheld labels (``<labels>/<split>/<scene>/``); default: see :func:`labels_root`.
            Images and depth are always read from the split.

    Raises:
        ConfigError: Unknown scene ids or a bad ``max_images``.
        DatasetError: Missing split or no images, no ground truth (a split without labels and none given), or
            invalid ground truth (naming the file and entry).
    """
    split_dir = bop.dataset_split_dir(dataset_dir, split)
    label_root = labels_root(Path(dataset_dir), labels)
    obj_ids = sorted(obj_ids)
    if max_images is not None and int(max_images) < 1:
        raise ConfigError(f"max_images must be >= 1 or None, got {max_images!r}")
    dirs = select_scene_dirs(split_dir, scenes)
    refs: list[ImageRef] = []
    for d in dirs:
        gt_dir = _scene_gt_dir(d, label_root)
        frames = bop.read_scene(gt_dir, obj_ids)
        for im_id in sorted(frames):
            refs.append(ImageRef(int(d.name), im_id, d, frames[im_id], None if gt_dir == d else gt_dir))
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
