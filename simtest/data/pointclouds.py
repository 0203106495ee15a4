"""Per-frame, per-object point clouds of a sequence, for tracking models that read point-cloud streams.

:class:`PointCloudSequence` walks the frames of one scene of a BOP dataset in order (a scene of
``simtest generate --rig sequence`` is one sequence) and yields, per frame, one :class:`ObjectPoints` per
object instance: the depth pixels inside the instance's visible mask, back-projected into the camera frame
(OpenCV, metres; ``x = (u - cx) z / fx, y = (v - cy) z / fy``, pixel centres at integer coordinates), their
colours, and the instance's ground truth. Subsampling to ``num_points`` is deterministic: seeded by
``(seed, scene_id, im_id, gt_id)``, with replacement only when fewer points exist (``num_points=None``
keeps them all). Used through :mod:`simtest.data`.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from simtest.errors import ConfigError
from simtest.camera import backproject
from simtest.io import bop
from simtest.io.dataset import select_images

__all__ = ["ObjectPoints", "PointCloudSequence"]


@dataclass(frozen=True)
class ObjectPoints:
    """One object instance in one frame.

    Attributes:
        points: (N, 3) float32 camera-frame points, metres.
        colors: (N, 3) uint8 RGB of the same pixels.
        R, t: Ground-truth pose model -> camera (3x3, (3,) metres).
        obj_id: BOP object id.
        category: The object's category name.
        gt_id: Instance index in the scene's ground truth (stable across the frames: the track id).
        visib_fract: Visible fraction of the instance.
        num_valid: Masked pixels with depth before subsampling.
        scene_id, im_id, frame: Scene, image id and position of the frame in the sequence (from 0).
    """

    points: np.ndarray
    colors: np.ndarray
    R: np.ndarray
    t: np.ndarray
    obj_id: int
    category: str
    gt_id: int
    visib_fract: float
    num_valid: int
    scene_id: int
    im_id: int
    frame: int


class PointCloudSequence:
    """The frames of one scene as per-object point clouds (module doc).

    Args:
        root: BOP dataset root (with a manifest or ``models/``).
        split: Split folder.
        scene: Scene id.
        num_points: Points per instance (``None``: all masked pixels with depth).
        min_points: Instances with fewer masked pixels with depth are left out of a frame.
        seed: Seed of the subsampling.

    Iterating gives one ``list[ObjectPoints]`` per frame, frames in order; ``len()`` is the number of frames.

    Raises:
        ConfigError: Bad ``num_points`` / ``min_points``, or an unknown scene (lists the known ones).
        DatasetError: Missing split, images or masks.
    """

    def __init__(self, root: str | Path, split: str | None = None, scene: int = 0, *, num_points: int | None = 1024,
                 min_points: int = 1, seed: int = 0) -> None:
        from simtest.objects.loaders import load_dataset_objects

        if num_points is not None and (isinstance(num_points, bool) or int(num_points) < 1):
            raise ConfigError(f"PointCloudSequence: num_points must be >= 1 or None, got {num_points!r}")
        if int(min_points) < 1:
            raise ConfigError(f"PointCloudSequence: min_points must be >= 1, got {min_points!r}")
        self.root = Path(root)
        self.objects = load_dataset_objects(self.root)
        self.refs = select_images(self.root, split, [int(scene)], None, self.objects.ids)
        self.num_points = None if num_points is None else int(num_points)
        self.min_points, self.seed = int(min_points), int(seed)

    def __len__(self) -> int:
        return len(self.refs)

    def __iter__(self) -> Iterator[list[ObjectPoints]]:
        for i in range(len(self.refs)):
            yield self.frame(i)

    def frame(self, index: int) -> list[ObjectPoints]:
        """The instances of frame ``index`` (0-based position in the sequence) with at least ``min_points``
        masked pixels with depth."""
        if not 0 <= index < len(self.refs):
            raise ConfigError(f"PointCloudSequence: frame {index} out of range 0..{len(self.refs) - 1}")
        ref = self.refs[index]
        rgb = bop.read_image(ref.scene_dir, ref.im_id)
        depth = bop.read_depth(ref.scene_dir, ref.im_id, ref.info["depth_scale"])
        K = ref.info["K"]
        out = []
        for j, g in enumerate(ref.info["gt"]):
            valid = bop.read_mask(ref.gt_dir, ref.im_id, j, visible=True) & (depth > 0)
            pts, colors = backproject(depth, K, valid), rgb[valid]  # both in np.nonzero order
            num_valid = len(pts)
            if num_valid < self.min_points:
                continue
            if self.num_points is not None:
                rng = np.random.default_rng([self.seed, ref.scene_id, ref.im_id, j])
                pick = rng.choice(num_valid, self.num_points, replace=num_valid < self.num_points)
                pts, colors = pts[pick], colors[pick]
            out.append(ObjectPoints(points=pts.astype(np.float32), colors=colors, R=g.T_cam_obj.R.copy(),
                                    t=g.T_cam_obj.t.copy(), obj_id=g.obj_id,
                                    category=self.objects.get(g.obj_id).category, gt_id=j,
                                    visib_fract=float(g.visib_fract), num_valid=num_valid,
                                    scene_id=ref.scene_id, im_id=ref.im_id, frame=index))
        return out
