"""Zoom-in crops of the keypoint estimator: the square window around a detection, the crop's intrinsics and
image, and the training feed of crops (numpy; torch only when a batch is built).

Pixel convention (OpenCV): pixel ``(u, v)`` has its centre at integer coordinates and covers
``[u - 0.5, u + 0.5] x [v - 0.5, v + 0.5]``. A crop window ``(x0, y0, side_w, side_h)`` is a rectangle in those
continuous coordinates (``x0``, ``y0`` its left and top edges: the whole image is ``(-0.5, -0.5, W, H)``),
resampled to ``size = (height, width)`` pixels. The map from full-image pixels to crop pixels is the affine
``M`` (3x3, last row ``0 0 1``) that takes the window's edges to the crop's edges::

    u' = a_x (u - x0) - 0.5,   a_x = width / side_w   (and the same for v with a_y, y0, height)

so a crop pixel ``p'`` is the full-image point ``M^-1 p'`` and the crop's intrinsics are ``K' = M K``
(:func:`crop_intrinsics`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np

from simtest.camera import backproject
from simtest.errors import ConfigError

__all__ = ["crop_intrinsics", "crop_window_for_box", "warp_crop", "map_pixels", "jitter_box", "KeypointCrops",
           "collate_crops", "object_coords_image", "cell_object_coords", "DEFAULT_MARGIN", "DEFAULT_CROP_SIZE"]

#: Side of the square crop window as a multiple of the detection box's longer side.
DEFAULT_MARGIN = 1.3
#: Crop size (pixels) the network sees.
DEFAULT_CROP_SIZE = 128


def _size(size: int | Sequence[int]) -> tuple[int, int]:
    if isinstance(size, (int, np.integer)):
        h = w = int(size)
    else:
        h, w = (int(v) for v in size)
    if h < 1 or w < 1:
        raise ConfigError(f"crop size must be positive pixels (height, width), got {size!r}")
    return h, w


def crop_intrinsics(K: np.ndarray, box: Sequence[float], size: int | Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    """Intrinsics of a crop and the pixel map from the full image to it.

    Args:
        K: 3x3 intrinsics of the full image (pixels, OpenCV).
        box: Crop window ``(x0, y0, side_w, side_h)`` in continuous full-image pixel coordinates (left and top
            edges; see the module doc).
        size: Crop size in pixels, ``S`` or ``(height, width)``.

    Returns:
        ``(K_crop, M)``: ``K_crop = M @ K`` and ``M`` (3x3) mapping full-image pixels to crop pixels; crop
        pixel ``p'`` is full-image pixel ``M^-1 p'``.

    Raises:
        ConfigError: A window of non-positive size.
    """
    h, w = _size(size)
    x0, y0, bw, bh = (float(v) for v in box)
    if not (bw > 0 and bh > 0 and np.isfinite([x0, y0, bw, bh]).all()):
        raise ConfigError(f"crop window must have positive finite width and height, got {tuple(box)!r}")
    ax, ay = w / bw, h / bh
    M = np.array([[ax, 0.0, -ax * x0 - 0.5], [0.0, ay, -ay * y0 - 0.5], [0.0, 0.0, 1.0]])
    return M @ np.asarray(K, np.float64), M


def map_pixels(M: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Pixels (..., 2) through the affine pixel map ``M`` (3x3, last row ``0 0 1``): full image -> crop with the
    ``M`` of :func:`crop_intrinsics`, crop -> full image with its inverse."""
    M = np.asarray(M, np.float64)
    return np.asarray(points, np.float64) @ M[:2, :2].T + M[:2, 2]


def crop_window_for_box(box: Sequence[float], margin: float = DEFAULT_MARGIN, min_side: float = 16.0
                        ) -> tuple[float, float, float, float]:
    """The square crop window ``(x0, y0, side, side)`` centred on a detection box.

    Args:
        box: ``[x, y, w, h]`` as BOP's ``bbox_visib`` (``x``, ``y`` the first pixel, ``w = xmax - xmin``), so
            the box covers ``[x - 0.5, x + w + 0.5]`` in continuous coordinates.
        margin: Window side as a multiple of the box's longer side (pixels covered).
        min_side: Smallest window side, pixels.
    """
    x, y, bw, bh = (float(v) for v in box)
    cx, cy = x + 0.5 * bw, y + 0.5 * bh
    side = max(float(min_side), float(margin) * (max(bw, bh) + 1.0))
    return cx - 0.5 * side, cy - 0.5 * side, side, side


def jitter_box(box: Sequence[float], rng: np.random.Generator, scale: float = 0.15, shift: float = 0.1
               ) -> tuple[float, float, float, float]:
    """A detection box ``[x, y, w, h]`` perturbed as a detector would: the side lengths scaled by
    ``exp(U(-scale, scale))`` each and the centre moved by up to ``shift`` times the longer side."""
    x, y, bw, bh = (float(v) for v in box)
    cx, cy = x + 0.5 * bw, y + 0.5 * bh
    sx, sy = np.exp(rng.uniform(-scale, scale, size=2))
    long = max(bw, bh) + 1.0
    dx, dy = rng.uniform(-shift, shift, size=2) * long
    nw, nh = bw * sx, bh * sy
    return cx + dx - 0.5 * nw, cy + dy - 0.5 * nh, nw, nh


def warp_crop(image: np.ndarray, M: np.ndarray, size: int | Sequence[int], nearest: bool = False) -> np.ndarray:
    """The crop of ``image`` (H, W[, C]) under the pixel map ``M`` of :func:`crop_intrinsics`: crop pixel
    ``p'`` takes the (bilinear, or nearest) value at full-image pixel ``M^-1 p'``; zero past the image."""
    h, w = _size(size)
    src = image.astype(np.uint8) if image.dtype == bool else image
    out = cv2.warpAffine(src, np.asarray(M, np.float64)[:2], (w, h),
                         flags=cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out.astype(bool) if image.dtype == bool else out


class KeypointCrops:
    """Training feed of zoom-in crops: item ``i`` is every usable instance of image ``i`` of ``dataset`` (a
    :class:`simtest.data.PoseDataset` or a :class:`simtest.data.MixedDataset` of them; its transforms run on
    the full image first), each cut around its jittered visible box (:func:`jitter_box`,
    :func:`crop_window_for_box`) and resized to ``size``.

    Item (numpy; ``n`` crops): ``rgb`` (n, 3, S, S) float32 in [0, 1], ``fg`` (n, S, S) bool (the target
    instance's visible mask in the crop), ``keypoints_2d`` (n, J, 2) crop pixels, ``labels`` (n,) 1..C,
    ``K`` (n, 3, 3) crop intrinsics. The jitter draws from the sample's own generator (seed, epoch, index).
    With ``xyz_stride`` also the object-coordinate targets (:func:`cell_object_coords`): ``xyz`` (n, 3, S/s,
    S/s) float32 metres in the symmetry-canonical model frame (``R_sym``, ``t_sym``) and ``xyz_valid``
    (n, S/s, S/s) bool.

    Args:
        dataset: The image feed. size: Crop side (pixels). margin: Window side / box side.
        min_visib: Instances less visible than this (or with under ``min_pixels`` visible pixels) are skipped.
        max_crops: At most this many crops per image (the most visible first).
        seed: Seed of the box jitter. jitter_scale, jitter_shift: See :func:`jitter_box` (0: no jitter).
        xyz_stride: Cell size (crop pixels) of the object-coordinate targets; None: none.
    """

    def __init__(self, dataset: Any, size: int = DEFAULT_CROP_SIZE, margin: float = DEFAULT_MARGIN,
                 min_visib: float = 0.1, min_pixels: int = 30, max_crops: int = 8, seed: int = 0,
                 jitter_scale: float = 0.15, jitter_shift: float = 0.1, xyz_stride: int | None = None) -> None:
        self.xyz_stride = None if xyz_stride is None else int(xyz_stride)
        self.jitter_scale, self.jitter_shift = float(jitter_scale), float(jitter_shift)
        self.dataset = dataset
        self.size = int(size)
        self.margin = float(margin)
        self.min_visib = float(min_visib)
        self.min_pixels = int(min_pixels)
        self.max_crops = int(max_crops)
        self.seed = int(seed)
        self.epoch = 0

    def __len__(self) -> int:
        return len(self.dataset)

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)
        self.dataset.set_epoch(epoch)

    def __getitem__(self, index: int) -> dict[str, Any]:
        s = self.dataset[int(index)]
        rng = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(self.epoch, int(index), 0xC0)))
        rgb = np.ascontiguousarray(s["rgb"].numpy().transpose(1, 2, 0), np.float32)
        masks = s["masks"].numpy()
        K = s["K"].numpy()
        pix = masks.reshape(len(masks), -1).sum(1) if len(masks) else np.zeros(0)
        vis = s["visib_fract"].numpy()
        order = [k for k in np.argsort(-vis, kind="stable") if vis[k] >= self.min_visib and pix[k] >= self.min_pixels]
        order = order[:self.max_crops]
        S = self.size
        n = len(order)
        J = s["keypoints_2d"].shape[1] if len(masks) else 8
        out = {"rgb": np.zeros((n, 3, S, S), np.float32), "fg": np.zeros((n, S, S), bool),
               "keypoints_2d": np.zeros((n, J, 2)), "labels": np.zeros(n, np.int64), "K": np.zeros((n, 3, 3))}
        kp = s["keypoints_2d"].numpy()
        st = self.xyz_stride
        if st is not None:
            out["xyz"] = np.zeros((n, 3, S // st, S // st), np.float32)
            out["xyz_valid"] = np.zeros((n, S // st, S // st), bool)
            depth = s["depth"].numpy()[0]
        for c, k in enumerate(order):
            box = crop_window_for_box(jitter_box(s["boxes"][k].numpy(), rng, self.jitter_scale, self.jitter_shift),
                                      self.margin)
            Kc, M = crop_intrinsics(K, box, S)
            out["rgb"][c] = warp_crop(rgb, M, S).transpose(2, 0, 1)
            out["fg"][c] = warp_crop(masks[k], M, S, nearest=True)
            out["keypoints_2d"][c] = map_pixels(M, kp[k])
            out["labels"][c] = int(s["labels"][k])
            out["K"][c] = Kc
            if st is not None:
                xyz = object_coords_image(depth, K, masks[k], s["R_sym"][k].numpy(), s["t_sym"][k].numpy())
                out["xyz"][c], out["xyz_valid"][c] = cell_object_coords(warp_crop(xyz, M, S, nearest=True),
                                                                        out["fg"][c], st)
        return out


def object_coords_image(depth: np.ndarray, K: np.ndarray, mask: np.ndarray, R: np.ndarray, t: np.ndarray
                        ) -> np.ndarray:
    """(H, W, 3) float32: at each pixel of ``mask`` with depth, the model-frame point ``R^T (X - t)`` of its
    back-projected camera-frame surface point ``X`` (metres; ``depth`` planar, ``K`` the image's intrinsics);
    zero elsewhere."""
    sel = np.asarray(mask, bool) & (np.asarray(depth) > 0)
    out = np.zeros(depth.shape + (3,), np.float32)
    pts = backproject(depth, K, sel)
    out[sel] = (pts - np.asarray(t, np.float64)) @ np.asarray(R, np.float64)
    return out


def cell_object_coords(xyz: np.ndarray, fg: np.ndarray, stride: int, min_coverage: float = 0.3
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Per ``stride`` x ``stride`` cell of a crop: the mean object coordinates of its ``fg`` pixels that have
    them (``xyz`` (S, S, 3), zero where none) as (3, S/s, S/s) float32, and whether the cell has a target
    (at least ``min_coverage`` of it covered by such pixels, the mask cells' rule)."""
    S = fg.shape[0]
    h = S // stride
    have = (np.asarray(fg, bool) & np.any(xyz != 0, axis=-1))[:h * stride, :h * stride]
    cnt = have.reshape(h, stride, h, stride).sum((1, 3))
    tot = (xyz[:h * stride, :h * stride] * have[..., None]).reshape(h, stride, h, stride, 3).sum((1, 3))
    valid = cnt >= min_coverage * stride * stride
    mean = np.where(valid[..., None], tot / np.maximum(cnt, 1)[..., None], 0.0).astype(np.float32)
    return mean.transpose(2, 0, 1), valid


def collate_crops(items: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Concatenate the crops of several images into tensors (``rgb`` (N, 3, S, S), ``fg`` (N, S, S), ...)."""
    import torch

    return {k: torch.from_numpy(np.concatenate([it[k] for it in items])) for k in items[0]}
