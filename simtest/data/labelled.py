"""A PyTorch map-style dataset over a BOP dataset, with on-the-fly corruptions seeded per sample and epoch.

``torch`` is imported only when a sample is built or batches are collated, so ``import simtest.data`` works
without it. :class:`PoseDataset` does not subclass ``torch.utils.data.Dataset`` (``DataLoader`` needs only
``__len__`` and ``__getitem__``); it holds plain Python data (no open files, no meshes), so it pickles cheaply
into ``DataLoader`` worker processes.

Sample (a ``dict``; ``N`` instances, ``J`` keypoints, image ``H x W`` after an optional crop):

==================  ===================  ===================================================================
key                 type / shape         meaning
==================  ===================  ===================================================================
``rgb``             float32 (3, H, W)    colour in [0, 1] (``uint8`` when ``rgb_dtype="uint8"``)
``depth``           float32 (1, H, W)    planar depth in metres, 0 = missing
``K``               float64 (3, 3)       intrinsics of this (possibly cropped) image, pixels
``masks``           bool (N, H, W)       visible masks (after pasted occluders)
``masks_amodal``    bool (N, H, W)       amodal masks (only with ``amodal_masks=True``)
``obj_ids``         int64 (N,)           BOP object ids
``labels``          int64 (N,)           class index 1..C in :attr:`PoseDataset.class_ids` order (0 = background)
``R``, ``t``        float64 (N,3,3),(N,3) ground-truth pose model -> camera; ``t`` in metres
``R_sym``,``t_sym`` float64 (N,3,3),(N,3) the symmetry-equivalent pose the keypoints are computed from
                                         (equal to ``R``, ``t`` for objects without symmetries)
``boxes``           float32 (N, 4)       visible box ``[x, y, w, h]`` in pixels, from the (updated) mask, as
                                         BOP's ``bbox_visib`` (``w = xmax - xmin``); zeros when not visible
``keypoints_2d``    float64 (N, J, 2)    model keypoints projected with ``(R_sym, t_sym)`` and ``K``, pixels
``keypoints_3d``    float64 (N, J, 3)    the model-frame keypoints, metres
``visib_fract``     float32 (N,)         visible fraction after the transforms
``scene_id``,
``im_id``,``index`` int                  where the sample came from
==================  ===================  ===================================================================

Randomness: sample ``i`` of epoch ``e`` draws from ``np.random.default_rng(SeedSequence(seed, spawn_key=(e,
i)))`` (:func:`sample_rng`), so a sample is the same whatever the worker count, batch order or process, and
epochs differ. Call :meth:`PoseDataset.set_epoch` before iterating each epoch (``DataLoader`` copies the dataset
into its workers when an iterator starts, so do not use ``persistent_workers=True`` with epoch-dependent
transforms).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from simtest.errors import ConfigError, DatasetError
from simtest.data.dense import DENSE_KEYS, check_channels, load_channels, masks_to_instances
from simtest.data.feed import ImageEntry, ImageFeed, check_feed_options, crop_intrinsics, crop_window
from simtest.io.dataset import select_scene_dirs

__all__ = ["PoseDataset", "project_points", "canonical_symmetry", "KEYPOINT_TYPES"]

#: Keypoint sets a dataset can return: the 8 bbox corners or the model's farthest-point-sampled surface points.
KEYPOINT_TYPES: tuple[str, ...] = ("bbox", "fps")


#: The reference camera-frame orientation symmetric objects are canonicalised towards: model x -> camera x
#: (right), model y -> camera z (away from the camera), model z -> camera -y (up in the image).
_R_REF = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])



def project_points(points: np.ndarray, R: np.ndarray, t: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Pinhole projection of model points.

    Args:
        points: (J, 3) model-frame points, metres.
        R, t: Pose model -> camera (t in metres).
        K: 3x3 intrinsics, pixels.

    Returns:
        (J, 2) pixel coordinates (OpenCV convention: pixel centres at integer coordinates).
    """
    pc = np.asarray(points, dtype=np.float64) @ np.asarray(R, dtype=np.float64).T + np.asarray(t, dtype=np.float64)
    uv = pc @ np.asarray(K, dtype=np.float64).T
    return uv[:, :2] / uv[:, 2:3]


def canonical_symmetry(R: np.ndarray, syms: np.ndarray) -> int:
    """Index of the symmetry transform ``S`` whose pose ``R R_S`` is closest to a fixed camera-frame reference.

    Symmetric objects have several correct poses; regressing keypoints of an arbitrary one gives ambiguous
    targets. Choosing, for every image, the equivalent pose nearest to one reference orientation makes the
    target a function of the image (with unavoidable jumps where two equivalents are equally near).

    Args:
        R: 3x3 rotation, model -> camera.
        syms: (S, 4, 4) symmetry transforms, identity first (see ``ObjectModel.symmetry_transforms``).
    """
    score = np.einsum("ij,sjk,ik->s", R, syms[:, :3, :3], _R_REF)  # trace(R_ref^T R R_s)
    return int(np.argmax(score))


# ---------------------------------------------------------------------------------------------------------
# Transforms: (sample dict of numpy arrays, rng) -> sample dict


class PoseDataset(ImageFeed):
    """Map-style dataset over the images of a BOP dataset (see the module doc for the sample keys).

    Args:
        root: BOP dataset folder (with ``models/`` or a manifest naming the object set).
        split: Split folder, e.g. ``"train_pbr"``.
        scenes: Scene ids to use (default all).
        objects: Object set the classes and keypoints come from (default: the dataset's own, via
            :func:`simtest.objects.loaders.load_dataset_objects`, and then a ground-truth ``obj_id`` outside it is an
            error); with a given set, instances of other objects are dropped.
        keypoints: ``"bbox"`` (8 corners) or ``"fps"`` (the model's farthest-point-sampled points).
        transform: ``f(sample, rng) -> sample`` on numpy arrays (e.g. :class:`Corrupt`, :class:`Compose`,
            :func:`augmentation`), seeded by :func:`sample_rng`.
        seed: Non-negative seed of the transforms (and of crop placement).
        min_visib_fract: Drop instances less visible than this (before the transforms).
        crop: ``(height, width)`` of a crop around one randomly chosen instance (with jitter), or None. The
            crop may extend past the image (zero padding); ``K`` is shifted accordingly.
        crop_jitter: Maximum shift of the crop centre from the instance's box centre, as a fraction of the
            crop size.
        symmetry_canonical: Compute keypoints from the canonical symmetry-equivalent pose
            (:func:`canonical_symmetry`) for symmetric objects.
        amodal_masks: Also read the amodal masks.
        rgb_dtype: ``"float32"`` (in [0, 1]) or ``"uint8"``.
        max_images: Use only the first N images.

    Raises:
        DatasetError: Missing dataset folder or split, no image, or malformed ground truth (see
            :func:`simtest.io.bop.read_scene_files`).
        ConfigError: Bad keypoint type, crop or seed.
    """

    def __init__(self, root: str | Path, split: str | None = None, scenes: Sequence[int] | None = None, *,
                 objects: Any = None, keypoints: str = "bbox", transform: Callable | None = None, seed: int = 0,
                 min_visib_fract: float = 0.0, crop: tuple[int, int] | None = None, crop_jitter: float = 0.25,
                 symmetry_canonical: bool = True, amodal_masks: bool = False, rgb_dtype: str = "float32",
                 max_images: int | None = None, channels: Sequence[str] = ()) -> None:
        from simtest.io import bop

        if keypoints not in KEYPOINT_TYPES:
            raise ConfigError(f"unknown keypoint type {keypoints!r}; valid: {', '.join(KEYPOINT_TYPES)}")
        seed, crop = check_feed_options(seed, rgb_dtype, crop)
        self.root = str(Path(root))
        self.split = bop.resolve_split(self.root, split)
        self.keypoints = keypoints
        self.transform = transform
        self.seed = int(seed)
        self.epoch = 0
        self.crop = crop
        self.crop_jitter = float(crop_jitter)
        self.symmetry_canonical = bool(symmetry_canonical)
        self.amodal_masks = bool(amodal_masks)
        self.rgb_dtype = rgb_dtype
        self.channels = check_channels(channels)
        # With the dataset's own objects an unknown ground-truth obj_id is an error; with a given object set,
        # instances of other objects are dropped.
        gt_obj_ids = None
        if objects is None:
            from simtest.objects.loaders import load_dataset_objects

            objects = load_dataset_objects(self.root)
            gt_obj_ids = [int(o.obj_id) for o in objects]
        #: Object ids in class order: class ``c`` (1-based) is ``class_ids[c - 1]``.
        self.class_ids: tuple[int, ...] = tuple(sorted(int(o.obj_id) for o in objects))
        by_id = {int(o.obj_id): o for o in objects}
        self.keypoints_3d: dict[int, np.ndarray] = {
            i: np.asarray(by_id[i].keypoints_bbox if keypoints == "bbox" else by_id[i].keypoints_fps, np.float64)
            for i in self.class_ids}
        self.bboxes: dict[int, tuple[np.ndarray, np.ndarray]] = {
            i: (np.asarray(by_id[i].bbox[0], np.float64), np.asarray(by_id[i].size, np.float64)) for i in self.class_ids}
        self.symmetries: dict[int, np.ndarray] = {
            i: (np.asarray(by_id[i].symmetry_transforms(), np.float64) if by_id[i].is_symmetric else np.eye(4)[None])
            for i in self.class_ids}

        split_dir = bop.dataset_split_dir(self.root, self.split)
        dirs = select_scene_dirs(split_dir, scenes)
        if dirs and not (dirs[0] / "scene_gt.json").is_file():
            raise DatasetError(f"{dirs[0]} has no scene_gt.json: split {self.split!r} is unlabelled; read its images "
                               "with simtest.data.mixing.UnlabelledDataset (labels withheld by generate --unlabelled "
                               "are in DATASET/withheld/, for evaluation)")
        lacking = [d for d in dirs if not (d / "depth").is_dir() or not (d / "mask_visib").is_dir()]
        if lacking:
            raise DatasetError(f"{lacking[0]} has no {'depth' if not (lacking[0] / 'depth').is_dir() else 'mask_visib'}"
                               f"/ folder ({len(lacking)} of {len(dirs)} scenes lack depth/ or mask_visib/): training "
                               "samples need depth and visible masks, as simtest generate writes them (a real BOP "
                               "test set without them can be evaluated, not trained on)")
        entries: list[ImageEntry] = []
        for d in dirs:
            for im_id, info in sorted(bop.read_scene(d, gt_obj_ids).items()):
                keep = [(j, g) for j, g in enumerate(info["gt"])
                        if g.obj_id in by_id and (g.visib_fract >= min_visib_fract or g.visib_fract < 0)]
                inst = tuple((j, g.obj_id, tuple(g.T_cam_obj.R.reshape(-1).tolist()), tuple(g.T_cam_obj.t.tolist()))
                             for j, g in keep)
                entries.append(ImageEntry(str(d), int(d.name), int(im_id), tuple(info["K"].reshape(-1).tolist()),
                                           float(info["depth_scale"]), inst,
                                           tuple(int(g.px_count_all) for _, g in keep)))
                if max_images is not None and len(entries) >= int(max_images):
                    break
            if max_images is not None and len(entries) >= int(max_images):
                break
        if not entries:
            raise DatasetError(f"{split_dir}: no images found")
        self._entries = entries

    # -----------------------------------------------------------------------------------------------------
    @property
    def num_classes(self) -> int:
        """Object classes (background excluded)."""
        return len(self.class_ids)

    def load_numpy(self, index: int) -> dict[str, Any]:
        """Sample ``index`` before the transforms, as numpy arrays (``rgb`` (H, W, 3) uint8, ``depth`` (H, W)
        metres, ``masks`` (N, H, W) bool, ``K``, ``obj_ids``, ``R``, ``t``; ids)."""
        from simtest.io import bop

        e = self._entries[index]
        out = self._read_rgbd(index)
        h, w = out["rgb"].shape[:2]
        n = len(e.instances)
        masks = np.stack([bop.read_mask(e.scene_dir, e.im_id, j, True) for j, *_ in e.instances]) if n else \
            np.zeros((0, h, w), bool)
        out.update(masks=masks, obj_ids=np.array([o for _, o, _, _ in e.instances], np.int64),
                   R=np.array([r for *_, r, _ in e.instances], np.float64).reshape(n, 3, 3),
                   t=np.array([t for *_, t in e.instances], np.float64).reshape(n, 3))
        if self.amodal_masks:
            out["masks_amodal"] = np.stack([bop.read_mask(e.scene_dir, e.im_id, j, False) for j, *_ in e.instances]) \
                if n else np.zeros((0, h, w), bool)
        # Amodal pixel counts: from scene_gt_info, else the amodal masks, else the unoccluded visible masks.
        px = [c if c > 0 else int((out["masks_amodal"] if self.amodal_masks else masks)[k].sum())
              for k, c in enumerate(e.px_count_all)]
        out["px_all"] = np.array([max(1, c) for c in px], np.int64)
        if self.channels:
            out.update(load_channels(e.scene_dir, e.im_id, self.channels, masks,
                                     [self.bboxes[int(o)] for o in out["obj_ids"]]))
        return out

    # -----------------------------------------------------------------------------------------------------
    def _crop(self, s: dict[str, Any], rng: np.random.Generator) -> dict[str, Any]:
        ch, cw = self.crop
        h, w = s["rgb"].shape[:2]
        masks = s["masks"]
        vis = [i for i in range(len(masks)) if masks[i].any()]
        if vis:
            i = vis[int(rng.integers(len(vis)))]
            ys, xs = np.nonzero(masks[i])
            cy, cx = 0.5 * (ys.min() + ys.max()), 0.5 * (xs.min() + xs.max())
        else:
            cy, cx = 0.5 * (h - 1), 0.5 * (w - 1)
        jy, jx = rng.uniform(-1.0, 1.0, size=2) * self.crop_jitter
        y0 = int(round(cy + jy * ch - 0.5 * ch))
        x0 = int(round(cx + jx * cw - 0.5 * cw))

        def cut(a: np.ndarray) -> np.ndarray:
            return crop_window(a, y0, x0, ch, cw)

        out = dict(s, rgb=cut(s["rgb"]), depth=cut(s["depth"]), K=crop_intrinsics(s["K"], y0, x0),
                   masks=np.stack([cut(m) for m in masks]) if len(masks) else np.zeros((0, ch, cw), bool))
        if "masks_amodal" in s:
            ma = s["masks_amodal"]
            out["masks_amodal"] = np.stack([cut(m) for m in ma]) if len(ma) else np.zeros((0, ch, cw), bool)
        for name in self.channels:
            for key in DENSE_KEYS[name]:
                out[key] = cut(s[key])
        return out

    def _finish(self, s: dict[str, Any], torch: Any) -> dict[str, Any]:
        n = len(s["obj_ids"])
        labels = np.array([self.class_ids.index(int(o)) + 1 for o in s["obj_ids"]], np.int64)
        J = len(next(iter(self.keypoints_3d.values())))
        kp2 = np.zeros((n, J, 2))
        kp3 = np.zeros((n, J, 3))
        R_sym = s["R"].copy()
        t_sym = s["t"].copy()
        for k in range(n):
            o = int(s["obj_ids"][k])
            kp3[k] = self.keypoints_3d[o]
            syms = self.symmetries[o]
            if self.symmetry_canonical and len(syms) > 1:
                S = syms[canonical_symmetry(s["R"][k], syms)]
                R_sym[k] = s["R"][k] @ S[:3, :3]
                t_sym[k] = s["R"][k] @ S[:3, 3] + s["t"][k]
            kp2[k] = project_points(kp3[k], R_sym[k], t_sym[k], s["K"])
        from simtest.io.bop import mask_bbox

        masks = s["masks"]
        boxes = np.zeros((n, 4), np.float32)
        for k in range(n):
            if masks[k].any():
                boxes[k] = mask_bbox(masks[k])
        visib = np.array([masks[k].sum() / s["px_all"][k] for k in range(n)], np.float32) if n else \
            np.zeros(0, np.float32)
        out = {
            **self._image_tensors(s, torch),
            "masks": torch.from_numpy(np.ascontiguousarray(masks, dtype=bool)),
            "obj_ids": torch.from_numpy(s["obj_ids"]),
            "labels": torch.from_numpy(labels),
            "R": torch.from_numpy(s["R"]), "t": torch.from_numpy(s["t"]),
            "R_sym": torch.from_numpy(R_sym), "t_sym": torch.from_numpy(t_sym),
            "boxes": torch.from_numpy(boxes),
            "keypoints_2d": torch.from_numpy(kp2), "keypoints_3d": torch.from_numpy(kp3),
            "visib_fract": torch.from_numpy(visib),
            "scene_id": int(s["scene_id"]), "im_id": int(s["im_id"]), "index": int(s["index"]),
        }
        if "masks_amodal" in s:
            out["masks_amodal"] = torch.from_numpy(np.ascontiguousarray(s["masks_amodal"], dtype=bool))
        if "instances" in self.channels:  # after the transforms: the (possibly occluded) visible masks
            out["instances"] = torch.from_numpy(masks_to_instances(masks))
        if "coords" in self.channels:
            have = s["coords_mask"] & masks.any(0) if len(masks) else np.zeros_like(s["coords_mask"])
            out["coords"] = torch.from_numpy(np.ascontiguousarray((s["coords"] * have[..., None]).transpose(2, 0, 1)))
            out["coords_mask"] = torch.from_numpy(have)
        if "normals" in self.channels:
            out["normals"] = torch.from_numpy(np.ascontiguousarray(s["normals"].transpose(2, 0, 1)))
        if "flow" in self.channels:
            out["flow"] = torch.from_numpy(np.ascontiguousarray(s["flow"].transpose(2, 0, 1)))
            out["flow_valid"] = torch.from_numpy(s["flow_valid"])
        return out


