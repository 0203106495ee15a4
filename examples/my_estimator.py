"""A complete, minimal simtest pose estimator (see docs/plugins.md).

Translation: the centroid of the target's visible depth pixels, pushed back along the viewing ray by a fraction
of the object's radius (the camera sees the front surface, the model origin is the bbox centre). Rotation: the
identity. Run it with

    simtest eval --data DATASET --estimator examples/my_estimator.py:DepthCentroid --opt push_back=0.5 --out RUN
    simtest grasp --estimator examples/my_estimator.py:DepthCentroid --episodes 5 --out RUN
"""

from __future__ import annotations

import numpy as np

from simtest.estimators import Observation, PoseEstimate


class DepthCentroid:
    """Depth-centroid translation and identity rotation for every target.

    Args:
        push_back: Offset along the viewing ray, as a fraction of the object's radius (diameter / 2).
        min_points: Fewest valid depth pixels needed for an estimate.
    """

    needs_gt_masks = True  # ask for the ground-truth visible mask of each target

    def __init__(self, push_back: float = 0.5, min_points: int = 10) -> None:
        self.push_back = float(push_back)
        self.min_points = int(min_points)

    def estimate(self, obs: Observation) -> list[PoseEstimate]:
        fx, fy, cx, cy = obs.K[0, 0], obs.K[1, 1], obs.K[0, 2], obs.K[1, 2]
        out = []
        for k, (obj_id, mask) in enumerate(zip(obs.target_obj_ids or (), obs.masks or ())):
            v, u = np.nonzero(mask & (obs.depth > 0))  # pixel rows, columns
            if len(u) < self.min_points:
                continue  # no estimate: this target counts as a miss
            z = obs.depth[v, u].astype(np.float64)  # planar depth, metres
            centroid = np.stack([(u - cx) * z / fx, (v - cy) * z / fy, z], axis=1).mean(axis=0)
            radius = 0.5 * obs.objects.get(obj_id).diameter
            T = np.eye(4)  # T_cam_obj: model -> camera (OpenCV frame), metres
            T[:3, 3] = centroid + self.push_back * radius * centroid / np.linalg.norm(centroid)
            out.append(PoseEstimate.from_matrix(T, obj_id, score=len(u) / mask.size, target_index=k))
        return out
