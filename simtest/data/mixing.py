"""Unlabelled target-domain images and one loader that mixes them with a labelled dataset.

Weakly- and self-supervised pose estimators train on labelled synthetic images plus *unlabelled* images of
the target domain (another renderer, sensor or appearance). ``simtest generate --unlabelled`` writes such a
split (only ``rgb/``, ``depth/`` and ``scene_camera.json``; the labels are withheld in ``<dataset>/withheld/``
for evaluation); :class:`UnlabelledDataset` reads it (or any split, ignoring its labels) and
:class:`MixedDataset` draws from several datasets in a fixed ratio. :func:`collate_mixed` batches both kinds:
images of every sample, targets only of the labelled ones.

Unlabelled sample (a ``dict``; image ``H x W`` after an optional crop): ``rgb``, ``depth`` and ``K`` as in a
:class:`simtest.data.PoseDataset` sample (the same code makes them, :class:`simtest.data.ImageFeed`), and:

==================  ===================  ===================================================================
key                 type / shape         meaning
==================  ===================  ===================================================================
``labelled``        bool                 ``False``
``scene_id``,
``im_id``,``index`` int                  where the sample came from
==================  ===================  ===================================================================

Randomness: as :mod:`simtest.data`, sample ``i`` of epoch ``e`` draws its transforms and crop from
:func:`simtest.data.sample_rng` ``(seed, e, i)``; :class:`MixedDataset` draws its epoch's order from
``SeedSequence(seed, spawn_key=(e,))``. Everything is a function of the seeds and the epoch, never of the
worker count or the iteration order.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from simtest.data.feed import ImageFeed, check_feed_options, check_seed, collate, crop_intrinsics, crop_window
from simtest.io.dataset import select_scene_dirs
from simtest.errors import ConfigError, DatasetError

__all__ = ["UnlabelledDataset", "MixedDataset", "collate_mixed", "labelled_mixture", "parse_weights"]


@dataclass(frozen=True)
class _Image:
    scene_dir: str
    scene_id: int
    im_id: int
    K: tuple[float, ...]
    depth_scale: float


class UnlabelledDataset(ImageFeed):
    """Map-style dataset of the images of a split without their labels (see the module doc for the keys).

    Args:
        root: BOP dataset folder.
        split: Split folder, e.g. ``"target"`` (a split written with ``--unlabelled``, or any split: its labels
            are not read).
        scenes: Scene ids to use (default all).
        transform: ``f(sample, rng) -> sample`` on numpy arrays (as in :class:`simtest.data.PoseDataset`; the
            sample has ``masks`` of shape (0, H, W)).
        seed: Non-negative seed of the transforms and crops.
        crop: ``(height, width)`` of a crop at a uniformly random position (zero padding where it exceeds the
            image), or None; ``K`` is shifted accordingly.
        rgb_dtype: ``"float32"`` (in [0, 1]) or ``"uint8"``.
        max_images: Use only the first N images.

    Raises:
        DatasetError: Missing dataset folder or split, no image, or a malformed ``scene_camera.json``.
        ConfigError: Bad seed, crop, dtype or scene ids.
    """

    def __init__(self, root: str | Path, split: str | None = None, scenes: Sequence[int] | None = None, *,
                 transform: Callable | None = None, seed: int = 0, crop: tuple[int, int] | None = None,
                 rgb_dtype: str = "float32", max_images: int | None = None) -> None:
        from simtest.io import bop

        self.seed, crop = check_feed_options(seed, rgb_dtype, crop)
        self.root, self.transform, self.crop, self.rgb_dtype = str(root), transform, crop, rgb_dtype
        self.split = bop.resolve_split(root, split)
        self.epoch = 0
        split_dir = bop.dataset_split_dir(root, self.split)
        dirs = select_scene_dirs(split_dir, scenes)
        images: list[_Image] = []
        for d in dirs:
            cams = bop.read_scene_camera(d)  # the labels, if any, are never read
            for key in sorted(cams, key=int):
                cam = cams[key]
                images.append(_Image(str(d), int(d.name), int(key), tuple(float(v) for v in cam["cam_K"]),
                                     float(cam.get("depth_scale", 1.0))))
        if max_images is not None:
            images = images[:int(max_images)]
        if not images:
            raise DatasetError(f"{split_dir}: no images found")
        self._entries = images

    def load_numpy(self, index: int) -> dict[str, Any]:
        """Sample ``index`` before the transforms: ``rgb`` (H, W, 3) uint8, ``depth`` (H, W) metres, ``K``,
        empty ``masks`` (0, H, W), ids."""
        s = self._read_rgbd(index)
        s["masks"] = np.zeros((0,) + s["rgb"].shape[:2], bool)
        return s

    def _crop(self, s: dict[str, Any], rng: np.random.Generator) -> dict[str, Any]:
        return _random_crop(s, self.crop, rng)

    def _finish(self, s: dict[str, Any], torch: Any) -> dict[str, Any]:
        return {**self._image_tensors(s, torch), "labelled": False, "scene_id": int(s["scene_id"]),
                "im_id": int(s["im_id"]), "index": int(s["index"])}


def _random_crop(s: dict[str, Any], size: tuple[int, int], rng: np.random.Generator) -> dict[str, Any]:
    """``s`` cut to ``size`` (height, width) at a uniformly random offset (zero padding past the image)."""
    ch, cw = size
    h, w = s["rgb"].shape[:2]
    y0 = int(rng.integers(min(0, h - ch), max(0, h - ch) + 1))
    x0 = int(rng.integers(min(0, w - cw), max(0, w - cw) + 1))

    return dict(s, rgb=crop_window(s["rgb"], y0, x0, ch, cw), depth=crop_window(s["depth"], y0, x0, ch, cw),
                K=crop_intrinsics(s["K"], y0, x0), masks=np.zeros((0, ch, cw), bool))


class MixedDataset:
    """Samples from several datasets in a fixed ratio, in an order fixed by the seed and the epoch.

    Each epoch has ``length`` samples; dataset ``k`` supplies ``round(ratio[k] * length)`` of them (largest
    remainder, so the counts add up), each of its images at most once per pass through it (its indices are
    a fresh permutation per pass), and the sources are interleaved in a random order. Every sample gets
    ``labelled`` (``True`` for samples with targets, unless the sample says otherwise) and ``source`` (``k``).

    Args:
        datasets: Map-style datasets (e.g. a :class:`simtest.data.PoseDataset` and an
            :class:`UnlabelledDataset`); each must have the same image size for batching.
        ratio: Non-negative weight per dataset (normalised; at least one positive); default: proportional to
            the datasets' lengths.
        length: Samples per epoch; default: the sum of the datasets' lengths.
        seed: Non-negative seed of the order.

    Raises:
        ConfigError: No dataset, an empty one, or a bad ratio, length or seed.
    """

    def __init__(self, datasets: Sequence[Any], ratio: Sequence[float] | None = None, length: int | None = None,
                 seed: int = 0) -> None:
        self.datasets = list(datasets)
        if not self.datasets or any(len(d) == 0 for d in self.datasets):
            raise ConfigError(f"MixedDataset needs one or more non-empty datasets, got lengths "
                              f"{[len(d) for d in self.datasets]}")
        sizes = np.array([len(d) for d in self.datasets], dtype=np.float64)
        w = sizes if ratio is None else np.asarray(ratio, dtype=np.float64)
        if w.shape != sizes.shape or not np.all(np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
            raise ConfigError(f"ratio must be {len(sizes)} non-negative weights (one per dataset, not all 0), "
                              f"got {ratio!r}")
        self.ratio = tuple(float(v) for v in w / w.sum())
        self.length = int(sizes.sum()) if length is None else int(length)
        if self.length < 1:
            raise ConfigError(f"length must be >= 1, got {length!r}")
        self.seed = check_seed(seed)
        self.epoch = 0
        self._order: tuple[int, np.ndarray, np.ndarray] | None = None

    def __len__(self) -> int:
        return self.length

    def counts(self) -> list[int]:
        """Samples per dataset in one epoch (largest-remainder rounding of ``ratio * length``)."""
        exact = np.asarray(self.ratio) * self.length
        n = np.floor(exact).astype(np.int64)
        for k in np.argsort(-(exact - n), kind="stable")[:self.length - int(n.sum())]:
            n[k] += 1
        return [int(v) for v in n]

    def set_epoch(self, epoch: int) -> None:
        """Select the epoch (its order) and pass it on to every dataset that has ``set_epoch``."""
        self.epoch = int(epoch)
        for d in self.datasets:
            if hasattr(d, "set_epoch"):
                d.set_epoch(epoch)

    def order(self) -> tuple[np.ndarray, np.ndarray]:
        """``(source, index)`` arrays of this epoch: sample ``i`` is ``datasets[source[i]][index[i]]``."""
        if self._order is not None and self._order[0] == self.epoch:
            return self._order[1], self._order[2]
        rng = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(self.epoch,)))
        counts = self.counts()
        source = rng.permutation(np.repeat(np.arange(len(counts)), counts))
        index = np.zeros(self.length, dtype=np.int64)
        for k, (n, d) in enumerate(zip(counts, self.datasets)):
            passes = -(-n // len(d))
            index[source == k] = np.concatenate([rng.permutation(len(d)) for _ in range(passes)] or
                                                [np.zeros(0, np.int64)])[:n]
        self._order = (self.epoch, source, index)
        return source, index

    def __getitem__(self, i: int) -> dict[str, Any]:
        if not 0 <= int(i) < self.length:
            raise IndexError(f"index {i} out of range for {self.length} samples")
        source, index = self.order()
        k = int(source[int(i)])
        sample = dict(self.datasets[k][int(index[int(i)])])
        sample.setdefault("labelled", "obj_ids" in sample)
        sample["source"] = k
        return sample


def collate_mixed(samples: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Batch labelled and unlabelled samples (``collate_fn`` of a ``DataLoader`` over :class:`MixedDataset`).

    ``rgb``, ``depth`` and ``K`` are stacked for every sample (B, ...); ``labelled`` is a bool tensor (B,);
    ``source`` (when present), ``scene_id``, ``im_id`` and ``index`` are int64 tensors (B,). The per-instance
    targets of :func:`simtest.data.collate` (``masks``, ``obj_ids``, ``R``, ``t``, ...) are concatenated over the
    labelled samples only, with ``batch_index`` giving each instance's position in the whole batch; they are
    absent when no sample of the batch is labelled (``batch_index`` is then empty).

    Raises:
        ConfigError: An empty list, or images of different sizes.
    """
    import torch

    if not samples:
        raise ConfigError("collate_mixed got an empty list of samples")
    shapes = {tuple(s["rgb"].shape) for s in samples}
    if len(shapes) > 1:
        raise ConfigError(f"cannot batch images of different sizes {sorted(shapes)}; crop both datasets to one "
                          "size (crop=(H, W))")
    flags = [bool(s.get("labelled", "obj_ids" in s)) for s in samples]
    out: dict[str, Any] = {k: torch.stack([s[k] for s in samples]) for k in ("rgb", "depth", "K")}
    out["labelled"] = torch.tensor(flags, dtype=torch.bool)
    rows = [b for b, f in enumerate(flags) if f]
    if rows:
        sub = collate([samples[b] for b in rows])
        for k, v in sub.items():
            if k not in out and k not in ("scene_id", "im_id", "index"):
                out[k] = v
        out["batch_index"] = torch.tensor(rows, dtype=torch.int64)[sub["batch_index"]]
    else:
        out["batch_index"] = torch.zeros(0, dtype=torch.int64)
    keys = ("source", "scene_id", "im_id", "index") if all("source" in s for s in samples) else \
        ("scene_id", "im_id", "index")
    for k in keys:
        out[k] = torch.tensor([int(s[k]) for s in samples], dtype=torch.int64)
    return out


def parse_weights(text: str | None, n: int, flag: str = "--data-weights") -> tuple[float, ...] | None:
    """``"0.7,0.3"`` -> ``(0.7, 0.3)``: ``n`` non-negative finite weights, not all zero (None stays None).

    Raises:
        ConfigError: Naming ``flag``, the text and how many weights were expected.
    """
    if text is None:
        return None
    try:
        vals = tuple(float(v) for v in str(text).split(","))
    except ValueError:
        vals = ()
    if len(vals) != n or not all(np.isfinite(vals)) or min(vals) < 0 or sum(vals) <= 0:
        raise ConfigError(f"{flag} must be {n} comma-separated non-negative weights (one per --data, not all 0), "
                          f"got {text!r}")
    return vals


def labelled_mixture(roots: Sequence[str], split: str | None = None, weights: Sequence[float] | None = None,
                     seed: int = 0, **dataset_options: Any) -> Any:
    """The labelled training feed of one or several BOP datasets.

    One root gives its :class:`simtest.data.PoseDataset`; several give a :class:`MixedDataset` of theirs
    drawing ``weights`` (normalised; default proportional to the datasets' sizes) of each epoch's samples
    (as many as all datasets hold together), in an order fixed by ``seed`` and the epoch. Dataset ``k`` seeds
    its own transforms with ``seed + k``, so two datasets do not corrupt their ``i``-th images alike.

    Args:
        roots: BOP dataset folders (same object set). split: Their split folder.
        weights: One non-negative weight per root, or None.
        seed: Seed of the order and of the transforms.
        **dataset_options: Passed to every :class:`~simtest.data.PoseDataset` (``objects``, ``transform``, ...).

    Raises:
        ConfigError: No root, or weights that do not match the roots.
    """
    from simtest.data.labelled import PoseDataset

    roots = [str(r) for r in ([roots] if isinstance(roots, (str, Path)) else roots)]
    if not roots:
        raise ConfigError("labelled_mixture needs at least one dataset folder")
    if weights is not None and len(weights) != len(roots):
        raise ConfigError(f"{len(weights)} mixture weights given for {len(roots)} datasets ({', '.join(roots)})")
    sets = [PoseDataset(r, split, seed=int(seed) + k, **dataset_options) for k, r in enumerate(roots)]
    if len(sets) == 1:
        return sets[0]
    return MixedDataset(sets, ratio=weights, seed=int(seed))
