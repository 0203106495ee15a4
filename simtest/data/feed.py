"""What the map-style datasets over a split's images share: one entry per image, seeded per-sample generators,
the option checks, crops (pixels and intrinsics) and batching (``collate``; torch imported lazily).

Randomness: sample ``i`` of epoch ``e`` draws from ``np.random.default_rng(SeedSequence(seed, spawn_key=(e,
i)))`` (:func:`sample_rng`), so a sample is the same whatever the worker count, batch order or process.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from simtest.errors import ConfigError

__all__ = ["ImageFeed", "ImageEntry", "sample_rng", "check_feed_options", "check_seed", "crop_window",
           "crop_intrinsics", "collate"]


def sample_rng(seed: int, epoch: int, index: int) -> np.random.Generator:
    """The generator of sample ``index`` in ``epoch`` (independent of workers and iteration order)."""
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(int(epoch), int(index))))




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




# ---------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ImageEntry:
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
    :class:`simtest.data.mixing.UnlabelledDataset`): one entry per image (with ``scene_dir``, ``scene_id``, ``im_id``,
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


# ---------------------------------------------------------------------------------------------------------
_STACKED = ("rgb", "depth", "K")
#: Dense channels (same size as the image) stacked like it when a feed reads them.
_DENSE = ("instances", "coords", "coords_mask", "normals", "flow", "flow_valid")
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
    out: dict[str, Any] = {k: torch.stack([s[k] for s in samples]) for k in _STACKED + _DENSE if k in samples[0]}
    for k in _PER_INSTANCE:
        if k in samples[0]:
            out[k] = torch.cat([s[k] for s in samples])
    out["batch_index"] = torch.cat([torch.full((len(s["obj_ids"]),), b, dtype=torch.int64)
                                    for b, s in enumerate(samples)])
    for k in ("scene_id", "im_id", "index"):
        out[k] = torch.tensor([int(s[k]) for s in samples], dtype=torch.int64)
    return out
