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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from simtest.errors import ConfigError, DatasetError
from simtest.io.dataset import select_scene_dirs
from simtest.pointcloud_stream import ObjectPoints, PointCloudSequence  # per-frame object point clouds (tracking)

__all__ = [
    "PoseDataset", "Corrupt", "RandomCorrupt", "Compose", "collate", "sample_rng", "project_points",
    "canonical_symmetry", "KEYPOINT_TYPES", "TRAIN_WEATHER", "augmentation", "AUGMENTATIONS",
    "PointCloudSequence", "ObjectPoints",
]

#: Keypoint sets a dataset can return: the 8 bbox corners or the model's farthest-point-sampled surface points.
KEYPOINT_TYPES: tuple[str, ...] = ("bbox", "fps")
#: Image corruptions used by the ``weather`` augmentation. The four evaluation conditions of the robustness
#: tables (brightness, frost, snow, fog) are deliberately left out so they stay unseen in training.
TRAIN_WEATHER: tuple[str, ...] = ("gaussian_noise", "shot_noise", "defocus_blur", "motion_blur", "contrast",
                                  "saturate", "jpeg_compression", "pixelate", "gaussian_blur", "spatter")
#: Names understood by :func:`augmentation`.
AUGMENTATIONS: tuple[str, ...] = ("occlusion", "weather", "depth")

#: The reference camera-frame orientation symmetric objects are canonicalised towards: model x -> camera x
#: (right), model y -> camera z (away from the camera), model z -> camera -y (up in the image).
_R_REF = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def sample_rng(seed: int, epoch: int, index: int) -> np.random.Generator:
    """The generator of sample ``index`` in ``epoch`` (independent of workers and iteration order)."""
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(int(epoch), int(index))))


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
def check_feed_options(seed: Any, rgb_dtype: Any, crop: Any) -> tuple[int, tuple[int, int] | None]:
    """``(seed, crop)`` of a training feed, checked: a non-negative integer seed, ``rgb_dtype`` ``"float32"`` or
    ``"uint8"``, ``crop`` None or ``(height, width)`` of at least 8 pixels each.

    Raises:
        ConfigError: Naming the bad value.
    """
    seed = check_seed(seed)
    if rgb_dtype not in ("float32", "uint8"):
        raise ConfigError(f"rgb_dtype must be 'float32' or 'uint8', got {rgb_dtype!r}")
    if crop is not None:
        crop = (int(crop[0]), int(crop[1]))
        if min(crop) < 8:
            raise ConfigError(f"crop must be (height, width) of at least 8 pixels each, got {crop!r}")
    return seed, crop


def check_seed(seed: Any) -> int:
    """``seed`` as an int if it is a non-negative integer.

    Raises:
        ConfigError: Naming the bad value.
    """
    if seed is None or isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"seed must be a non-negative integer, got {seed!r}")
    return int(seed)


def crop_window(a: np.ndarray, y0: int, x0: int, height: int, width: int) -> np.ndarray:
    """The ``height`` x ``width`` window of image ``a`` whose top-left pixel is ``(y0, x0)`` (may lie outside
    the image: pixels past the border are zero)."""
    h, w = a.shape[:2]
    out = np.zeros((height, width) + a.shape[2:], dtype=a.dtype)
    sy0, sx0, sy1, sx1 = max(0, y0), max(0, x0), min(h, y0 + height), min(w, x0 + width)
    if sy1 > sy0 and sx1 > sx0:
        out[sy0 - y0:sy1 - y0, sx0 - x0:sx1 - x0] = a[sy0:sy1, sx0:sx1]
    return out


def crop_intrinsics(K: np.ndarray, y0: int, x0: int) -> np.ndarray:
    """``K`` of the window whose top-left pixel is ``(y0, x0)``: the principal point moves by ``(-x0, -y0)``."""
    K = np.array(K, np.float64, copy=True)
    K[0, 2] -= x0
    K[1, 2] -= y0
    return K


@dataclass(frozen=True)
class Corrupt:
    """Apply one :class:`simtest.corrupt.CorruptionSpec` with probability ``p``.

    A paste occlusion is controlled on the union of the visible masks, and the visible masks are updated.
    """

    spec: Any
    p: float = 1.0

    def __call__(self, sample: dict[str, Any], rng: np.random.Generator) -> dict[str, Any]:
        from simtest.corrupt import update_visible_masks

        if rng.random() >= self.p or self.spec.is_identity:
            return sample
        masks = sample["masks"]
        use_masks = masks if len(masks) else np.zeros((1,) + sample["rgb"].shape[:2], bool)
        rgb, depth, occ = self.spec.apply(sample["rgb"], sample["depth"], use_masks, rng, sample["K"])
        out = dict(sample, rgb=rgb, depth=depth)
        if occ.any() and len(masks):
            out["masks"] = np.stack(update_visible_masks(masks, occ))
        return out


@dataclass(frozen=True)
class RandomCorrupt:
    """Pick one of several corruption kinds per sample (with probability ``p``) at a random severity / level.

    Attributes:
        weather: Image corruption names to choose from (empty: none).
        severities: Severities to choose from.
        occlusion_levels: Paste-occlusion levels to choose from (empty: none).
        depth_noise: Depth presets to choose from (empty: none).
        p: Probability of corrupting a sample at all; each kind is then applied independently with
            probability ``p_each``.
        p_each: See ``p``.
    """

    weather: tuple[str, ...] = ()
    severities: tuple[int, ...] = (1, 2, 3, 4, 5)
    occlusion_levels: tuple[int, ...] = ()
    depth_noise: tuple[str, ...] = ()
    p: float = 1.0
    p_each: float = 0.5

    def __call__(self, sample: dict[str, Any], rng: np.random.Generator) -> dict[str, Any]:
        from simtest.corrupt import CorruptionSpec

        r_gate, r_kind, r_apply = rng.spawn(3)
        if r_gate.random() >= self.p:
            return sample
        draws = r_kind.random(3)
        picks = r_kind.integers(0, 1 << 30, size=4)
        kw: dict[str, Any] = {}
        if self.weather and draws[0] < self.p_each:
            kw["weather"] = self.weather[picks[0] % len(self.weather)]
            kw["severity"] = int(self.severities[picks[1] % len(self.severities)])
        if self.occlusion_levels and draws[1] < self.p_each:
            kw["occlusion"] = int(self.occlusion_levels[picks[2] % len(self.occlusion_levels)])
        if self.depth_noise and draws[2] < self.p_each:
            kw["depth_noise"] = self.depth_noise[picks[3] % len(self.depth_noise)]
        if not kw:
            return sample
        return Corrupt(CorruptionSpec(**kw))(sample, r_apply)


@dataclass(frozen=True)
class Compose:
    """Apply transforms in order; each gets its own child generator (adding one does not shift the others)."""

    transforms: tuple[Callable[[dict[str, Any], np.random.Generator], dict[str, Any]], ...] = field(default=())

    def __call__(self, sample: dict[str, Any], rng: np.random.Generator) -> dict[str, Any]:
        for tf, child in zip(self.transforms, rng.spawn(len(self.transforms))):
            sample = tf(sample, child)
        return sample


def augmentation(names: Sequence[str] | str | None, p: float = 0.8) -> Compose | None:
    """The training augmentation for ``names`` (subset of :data:`AUGMENTATIONS`), or None for none.

    ``occlusion``: paste occluders at level L1..L3; ``weather``: one of :data:`TRAIN_WEATHER` at severity
    1..5; ``depth``: a depth-noise preset. Each named kind is applied to a sample with probability 0.5, and a
    sample is corrupted at all with probability ``p``.

    Raises:
        ConfigError: An unknown name (lists the valid ones).
    """
    if names is None:
        return None
    if isinstance(names, str):
        names = [n.strip() for n in names.split(",") if n.strip()]
    names = [n for n in names if n != "none"]
    bad = [n for n in names if n not in AUGMENTATIONS]
    if bad:
        raise ConfigError(f"unknown augmentation {bad[0]!r}; valid: {', '.join(AUGMENTATIONS)} (comma-separated) "
                          "or none")
    if not names:
        return None
    from simtest.corrupt import DEPTH_PRESETS

    return Compose((RandomCorrupt(
        weather=TRAIN_WEATHER if "weather" in names else (),
        occlusion_levels=(1, 2, 3) if "occlusion" in names else (),
        depth_noise=tuple(DEPTH_PRESETS) if "depth" in names else (), p=p),))


# ---------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _ImageEntry:
    scene_dir: str
    scene_id: int
    im_id: int
    K: tuple[float, ...]
    depth_scale: float
    # per instance: (gt_id, obj_id, R (9), t (3))
    instances: tuple[tuple[int, int, tuple[float, ...], tuple[float, ...]], ...]
    px_count_all: tuple[int, ...]  # amodal pixel counts (BOP scene_gt_info), -1 if unknown


class ImageFeed:
    """What the map-style datasets over a split's images share (:class:`PoseDataset`,
    :class:`simtest.mixing.UnlabelledDataset`): one entry per image (with ``scene_dir``, ``scene_id``, ``im_id``,
    ``K`` and ``depth_scale``), the epoch, and :meth:`__getitem__`: the sample's numpy arrays
    (:meth:`load_numpy`), its seeded transform and crop (:func:`sample_rng`), then tensors (:meth:`_finish`)."""

    _entries: list
    seed: int
    epoch: int
    transform: Callable | None
    crop: tuple[int, int] | None
    rgb_dtype: str

    def __len__(self) -> int:
        return len(self._entries)

    def set_epoch(self, epoch: int) -> None:
        """Select the epoch whose random transforms :meth:`__getitem__` draws (see :func:`sample_rng`)."""
        self.epoch = int(epoch)

    def image_key(self, index: int) -> tuple[int, int]:
        """``(scene_id, im_id)`` of sample ``index``."""
        e = self._entries[index]
        return e.scene_id, e.im_id

    def load_numpy(self, index: int) -> dict[str, Any]:  # pragma: no cover - every feed has its own
        raise NotImplementedError

    def _crop(self, s: dict[str, Any], rng: np.random.Generator) -> dict[str, Any]:  # pragma: no cover
        raise NotImplementedError

    def _finish(self, s: dict[str, Any], torch: Any) -> dict[str, Any]:  # pragma: no cover
        raise NotImplementedError

    def _read_rgbd(self, index: int) -> dict[str, Any]:
        """Image ``index``'s ``rgb`` (H, W, 3) uint8, ``depth`` (H, W) metres, ``K`` and ids, as numpy."""
        from simtest.io import bop

        e = self._entries[index]
        return {"rgb": bop.read_image(e.scene_dir, e.im_id),
                "depth": bop.read_depth(e.scene_dir, e.im_id, e.depth_scale),
                "K": np.asarray(e.K, np.float64).reshape(3, 3), "scene_id": e.scene_id, "im_id": e.im_id,
                "index": int(index)}

    def _image_tensors(self, s: dict[str, Any], torch: Any) -> dict[str, Any]:
        """``rgb`` (3, H, W) (float32 in [0, 1] or uint8, see ``rgb_dtype``), ``depth`` (1, H, W) and ``K``
        tensors of sample ``s``."""
        rgb = torch.from_numpy(np.ascontiguousarray(s["rgb"].transpose(2, 0, 1)))
        if self.rgb_dtype == "float32":
            rgb = rgb.to(torch.float32).div_(255.0)
        return {"rgb": rgb, "depth": torch.from_numpy(np.ascontiguousarray(s["depth"], dtype=np.float32))[None],
                "K": torch.from_numpy(s["K"].astype(np.float64))}

    def __getitem__(self, index: int) -> dict[str, Any]:
        import torch

        if not 0 <= int(index) < len(self._entries):
            raise IndexError(f"index {index} out of range for {len(self._entries)} images")
        tf_rng, crop_rng = sample_rng(self.seed, self.epoch, int(index)).spawn(2)
        s = self.load_numpy(int(index))
        if self.transform is not None:
            s = self.transform(s, tf_rng)
        if self.crop is not None:
            s = self._crop(s, crop_rng)
        return self._finish(s, torch)


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

    def __init__(self, root: str | Path, split: str = "train_pbr", scenes: Sequence[int] | None = None, *,
                 objects: Any = None, keypoints: str = "bbox", transform: Callable | None = None, seed: int = 0,
                 min_visib_fract: float = 0.0, crop: tuple[int, int] | None = None, crop_jitter: float = 0.25,
                 symmetry_canonical: bool = True, amodal_masks: bool = False, rgb_dtype: str = "float32",
                 max_images: int | None = None) -> None:
        from simtest.io import bop

        if keypoints not in KEYPOINT_TYPES:
            raise ConfigError(f"unknown keypoint type {keypoints!r}; valid: {', '.join(KEYPOINT_TYPES)}")
        seed, crop = check_feed_options(seed, rgb_dtype, crop)
        self.root = str(Path(root))
        self.split = split
        self.keypoints = keypoints
        self.transform = transform
        self.seed = int(seed)
        self.epoch = 0
        self.crop = crop
        self.crop_jitter = float(crop_jitter)
        self.symmetry_canonical = bool(symmetry_canonical)
        self.amodal_masks = bool(amodal_masks)
        self.rgb_dtype = rgb_dtype
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
        self.symmetries: dict[int, np.ndarray] = {
            i: (np.asarray(by_id[i].symmetry_transforms(), np.float64) if by_id[i].is_symmetric else np.eye(4)[None])
            for i in self.class_ids}

        split_dir = bop.dataset_split_dir(self.root, split)
        dirs = select_scene_dirs(split_dir, scenes)
        if dirs and not (dirs[0] / "scene_gt.json").is_file():
            raise DatasetError(f"{dirs[0]} has no scene_gt.json: split {split!r} is unlabelled; read its images "
                               "with simtest.mixing.UnlabelledDataset (labels withheld by generate --unlabelled "
                               "are in DATASET/withheld/, for evaluation)")
        entries: list[_ImageEntry] = []
        for d in dirs:
            for im_id, info in sorted(bop.read_scene(d, gt_obj_ids).items()):
                keep = [(j, g) for j, g in enumerate(info["gt"])
                        if g.obj_id in by_id and (g.visib_fract >= min_visib_fract or g.visib_fract < 0)]
                inst = tuple((j, g.obj_id, tuple(g.T_cam_obj.R.reshape(-1).tolist()), tuple(g.T_cam_obj.t.tolist()))
                             for j, g in keep)
                entries.append(_ImageEntry(str(d), int(d.name), int(im_id), tuple(info["K"].reshape(-1).tolist()),
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
        return out


# ---------------------------------------------------------------------------------------------------------
_STACKED = ("rgb", "depth", "K")
_PER_INSTANCE = ("masks", "masks_amodal", "obj_ids", "labels", "R", "t", "R_sym", "t_sym", "boxes", "keypoints_2d",
                 "keypoints_3d", "visib_fract")


def collate(samples: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Batch samples with different instance counts.

    Images of equal size (``rgb``, ``depth``, ``K``) are stacked into (B, ...) tensors; per-instance fields are
    concatenated over the batch (``(sum N_b, ...)``) with ``batch_index`` (int64, one entry per instance)
    telling which image each instance belongs to; ids become int64 tensors of length B.

    Raises:
        ConfigError: Images of different sizes (use ``crop=`` to train on a fixed size).
    """
    import torch

    if not samples:
        raise ConfigError("collate got an empty list of samples")
    shapes = {tuple(s["rgb"].shape) for s in samples}
    if len(shapes) > 1:
        raise ConfigError(f"cannot batch images of different sizes {sorted(shapes)}; use crop=(H, W)")
    out: dict[str, Any] = {k: torch.stack([s[k] for s in samples]) for k in _STACKED}
    for k in _PER_INSTANCE:
        if k in samples[0]:
            out[k] = torch.cat([s[k] for s in samples])
    out["batch_index"] = torch.cat([torch.full((len(s["obj_ids"]),), b, dtype=torch.int64)
                                    for b, s in enumerate(samples)])
    for k in ("scene_id", "im_id", "index"):
        out[k] = torch.tensor([int(s[k]) for s in samples], dtype=torch.int64)
    return out
