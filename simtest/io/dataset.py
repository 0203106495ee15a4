"""Selecting the images of a BOP dataset split, with their validated ground truth (:mod:`simtest.io.bop`).

Used by evaluation and scoring; metres and the OpenCV camera frame, as everywhere past :mod:`simtest.io.bop`.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from simtest.errors import ConfigError, DatasetError
from simtest.io import bop
from simtest.io.bop_checks import RotationRepairs
from simtest.io.bop_targets import TARGETS_BOP19, TARGETS_BOP24

__all__ = ["ImageRef", "DataNotes", "select_scene_dirs", "select_images", "image_size", "image_targets",
           "describe_dataset", "labels_root", "WITHHELD"]

log = logging.getLogger(__name__)

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
    #: The object ids a BOP test-target file lists for this image (only their instances are targets, as the BOP
    #: toolkit counts them), or None: every object (no such file, or a detection-task file).
    listed: frozenset[int] | None = None

    @property
    def gt_dir(self) -> Path:
        """The folder holding this image's ground truth and masks."""
        return self.scene_dir if self.label_dir is None else self.label_dir

    def scores(self, obj_id: int) -> bool:
        """Whether instances of ``obj_id`` can be targets here: always, unless a test-target file chose this
        image and does not list the object (the BOP toolkit's rule)."""
        return self.listed is None or obj_id in self.listed

    @property
    def has_depth(self) -> bool:
        """Whether the scene has a ``depth/`` folder (real BOP test excerpts may ship RGB only)."""
        return (self.scene_dir / "depth").is_dir()

    @property
    def has_masks(self) -> bool:
        """Whether the scene's labels have a ``mask_visib/`` folder (real BOP test sets ship none)."""
        return (self.gt_dir / "mask_visib").is_dir()


@dataclass
class DataNotes:
    """What a reader repaired, skipped or found missing in a dataset, for its log and its report.

    Attributes:
        repairs: Ground-truth rotations projected to the nearest rotation (rounded real annotations).
        no_depth_scenes: Scene ids without ``depth/``.
        no_mask_scenes: Scene ids without ``mask_visib/``.
        targets_file: The BOP test-target file that chose the images (``""``: none was used).
        skipped_images: Images of the split not listed in ``targets_file`` (not evaluated).
        lines: Further notes, one line each.
    """

    repairs: RotationRepairs = field(default_factory=RotationRepairs)
    no_depth_scenes: list[int] = field(default_factory=list)
    no_mask_scenes: list[int] = field(default_factory=list)
    targets_file: str = ""
    skipped_images: int = 0
    lines: list[str] = field(default_factory=list)

    @property
    def has_depth(self) -> bool:
        """Every selected scene has depth."""
        return not self.no_depth_scenes

    @property
    def has_masks(self) -> bool:
        """Every selected scene has visible masks."""
        return not self.no_mask_scenes

    def summary(self) -> list[str]:
        """The notes as lines for a report (empty when the data was read as it is)."""
        return ([self.repairs.summary()] if self.repairs.count else []) + self.other_lines()

    def other_lines(self) -> list[str]:
        """The notes but the rotation repairs (those are a warning of their own)."""
        out = []
        if self.targets_file:
            out.append(f"images chosen by {self.targets_file}"
                       + (f" ({self.skipped_images} images of the split not listed there were skipped)"
                          if self.skipped_images else ""))
        if self.no_depth_scenes:
            out.append(f"no depth/ in scenes {_ids(self.no_depth_scenes)}: VSD and estimators that read depth "
                       "are unavailable")
        if self.no_mask_scenes:
            out.append(f"no mask_visib/ in scenes {_ids(self.no_mask_scenes)}: visib_fract taken from "
                       "scene_gt_info.json as given; estimators given ground-truth masks are unavailable")
        return out + self.lines


def _ids(ids: Sequence[int]) -> str:
    return ", ".join(str(i) for i in ids[:8]) + (f" and {len(ids) - 8} more" if len(ids) > 8 else "")


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


def select_images(dataset_dir: Path, split: str | None, scenes: Sequence[int] | None,
                  max_images: int | None, obj_ids: Iterable[int],
                  labels: str | Path | None = None, notes: DataNotes | None = None) -> list[ImageRef]:
    """The selected images with their validated ground truth (:func:`simtest.io.bop.read_scene`; a ground-truth
    ``obj_id`` outside ``obj_ids`` is a :class:`DatasetError`): scenes in order, images in order.

    A dataset as the BOP benchmark distributes it is read as it is: nearly orthonormal rotations are repaired
    (one warning for the whole selection), and when the dataset root has a test-target file
    (``test_targets_bop19.json``, else ``test_targets_bop24.json``) whose images all lie in the selected scenes,
    only the images it lists are selected (:func:`_listed_images`).

    Args:
        dataset_dir: BOP dataset root.
        split: Split folder name; None: the dataset's only split (:func:`simtest.io.bop.resolve_split`).
        scenes: Scene ids to keep (default all).
        max_images: Keep only the first N images.
        obj_ids: The object ids of the dataset's models.
        labels: Folder of withheld labels (``<labels>/<split>/<scene>/``); default: see :func:`labels_root`.
            Images and depth are always read from the split.
        notes: Filled with what was repaired, skipped or missing (:class:`DataNotes`).

    Raises:
        ConfigError: Unknown scene ids or a bad ``max_images``.
        DatasetError: Missing split or no images, no ground truth (a split without labels and none given), or
            invalid ground truth (naming the file and entry).
    """
    notes = notes if notes is not None else DataNotes()
    split_dir = bop.dataset_split_dir(dataset_dir, split)
    label_root = labels_root(Path(dataset_dir), labels)
    obj_ids = sorted(obj_ids)
    if max_images is not None and int(max_images) < 1:
        raise ConfigError(f"max_images must be >= 1 or None, got {max_images!r}")
    dirs = select_scene_dirs(split_dir, scenes)
    frames_of: list[tuple[Path, Path, dict[int, dict]]] = []
    for d in dirs:
        gt_dir = _scene_gt_dir(d, label_root)
        frames_of.append((d, gt_dir, bop.read_scene(gt_dir, obj_ids, notes.repairs)))
    listed = _listed_images(Path(dataset_dir), {int(d.name): set(f) for d, _, f in frames_of}, notes)
    refs: list[ImageRef] = []
    for d, gt_dir, frames in frames_of:
        for im_id in sorted(frames):
            if listed is not None and (int(d.name), im_id) not in listed:
                continue
            refs.append(ImageRef(int(d.name), im_id, d, frames[im_id], None if gt_dir == d else gt_dir,
                                 None if listed is None else listed[(int(d.name), im_id)]))
            if max_images is not None and len(refs) >= int(max_images):
                break
        if max_images is not None and len(refs) >= int(max_images):
            break
    if not refs:
        raise DatasetError(f"{split_dir}: no images found")
    if listed is not None:
        _note_listed_targets(refs, notes)
    chosen = sorted({r.scene_id: r for r in refs}.values(), key=lambda r: r.scene_id)
    notes.no_depth_scenes = [r.scene_id for r in chosen if not r.has_depth]
    notes.no_mask_scenes = [r.scene_id for r in chosen if not r.has_masks]
    if notes.repairs.count:
        log.warning("%s", notes.repairs.summary())
    for line in notes.other_lines():
        log.info("%s", line)
    return refs


def _note_listed_targets(refs: Sequence[ImageRef], notes: DataNotes) -> None:
    """Note how the test-target file's entries compare with the annotations: listed objects with no instance
    visible from 10 % (not targets: the BOP toolkit counts a listed instance only when visible) and instances
    visible from 10 % of objects not listed (not targets either)."""
    unseen = unlisted = 0
    for r in refs:
        if r.listed is None:
            continue
        seen = {g.obj_id for g in r.info["gt"] if g.visib_fract >= 0.1}
        unseen += len(r.listed - seen)
        unlisted += sum(g.visib_fract >= 0.1 and g.obj_id not in r.listed for g in r.info["gt"])
    if unseen or unlisted:
        notes.lines.append(f"{notes.targets_file}: {unseen} listed objects have no instance with visib_fract >= 0.1 "
                           f"and {unlisted} instances with visib_fract >= 0.1 are of objects not listed for their "
                           "image; neither is a target (the BOP toolkit's rule: a target is listed and visible)")


def _listed_images(root: Path, images: dict[int, set[int]], notes: DataNotes
                   ) -> dict[tuple[int, int], frozenset[int] | None] | None:
    """``{(scene_id, im_id): listed obj_ids}`` of the selected scenes' images that a BOP test-target file at
    ``root`` lists (obj_ids None for ``test_targets_bop24.json``, which names none), when it describes them
    (every image it lists in those scenes is one of ``images``, ``{scene_id: {im_id}}``); None when there is no
    such file. A file that names images the split lacks (e.g. another split's) is not used, with a note."""
    for name in (TARGETS_BOP19, TARGETS_BOP24):
        path = root / name
        if not path.is_file():
            continue
        items = bop.read_json(path)
        if not isinstance(items, list) or not all(isinstance(t, dict) and "scene_id" in t and "im_id" in t
                                                  for t in items):
            raise DatasetError(f"{path}: expected a list of objects with scene_id and im_id (the BOP toolkit's "
                               "test-target format)")
        listed: dict[tuple[int, int], set[int] | None] = {}
        for t in items:
            if int(t["scene_id"]) in images:
                objs = listed.setdefault((int(t["scene_id"]), int(t["im_id"])), set() if "obj_id" in t else None)
                if objs is not None:
                    objs.add(int(t["obj_id"]))
        missing = sorted((sc, im) for sc, im in listed if im not in images[sc])
        if not listed or missing:
            why = (f"names images the split lacks (scene {missing[0][0]} image {missing[0][1]}"
                   f"{f' and {len(missing) - 1} more' if len(missing) > 1 else ''})" if missing
                   else "lists no image of the selected scenes")
            notes.lines.append(f"{name} {why}: not used to choose images")
            return None
        notes.targets_file = name
        notes.skipped_images = sum(len(v) for v in images.values()) - len(listed)
        return {k: None if v is None else frozenset(v) for k, v in listed.items()}
    return None


def image_size(dataset_dir: Path) -> tuple[int, int]:
    """``(width, height)`` of the dataset's images, pixels (from ``camera.json``)."""
    cam = bop.read_camera_json(dataset_dir / "camera.json")
    return int(cam["width"]), int(cam["height"])


def image_targets(ref: ImageRef, visib_min: float) -> list[tuple[int, bop.ImageGT]]:
    """``(gt_id, gt)`` of the instances that are scored: ``visib_fract >= visib_min`` (BOP19: 0.1) and, when a
    test-target file chose the image, of an object it lists there (the BOP toolkit's valid ground truth)."""
    return [(j, g) for j, g in enumerate(ref.info["gt"])
            if g.visib_fract >= visib_min and ref.scores(g.obj_id)]


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
