"""Pose arithmetic of the robot's motions: pose errors as rotation vectors, capped and linear interpolation."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from simtest.geometry import Pose

__all__ = ["interpolate_pose", "lerp_pose", "pose_error", "rotvec_to_matrix"]


def rotvec_to_matrix(rv: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (axis * angle, rad), Rodrigues' formula."""
    rv = np.asarray(rv, dtype=np.float64)
    angle = float(np.sqrt(rv @ rv))
    if angle < 1e-12:
        return np.eye(3)
    k = rv / angle
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


def pose_error(target: Pose, pos: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position error (3,) m and rotation error as a world-frame rotation vector (3,) rad."""
    e_p = target.t - pos
    e_r = Rotation.from_matrix(target.R @ R.T).as_rotvec()
    return e_p, e_r


def interpolate_pose(a: Pose, b: Pose, max_dist: float, max_angle: float) -> Pose:
    """The pose from ``a`` toward ``b`` at most ``max_dist`` m and ``max_angle`` rad away."""
    dp = b.t - a.t
    rv = Rotation.from_matrix(b.R @ a.R.T).as_rotvec()
    dist, ang = float(np.linalg.norm(dp)), float(np.linalg.norm(rv))
    s = 1.0
    if dist > max_dist:
        s = min(s, max_dist / dist)
    if ang > max_angle:
        s = min(s, max_angle / ang)
    if s >= 1.0:
        return b
    return Pose(Rotation.from_rotvec(rv * s).as_matrix() @ a.R, a.t + dp * s)


def lerp_pose(a: Pose, b: Pose, s: float) -> Pose:
    """The pose a fraction ``s`` of the way from ``a`` to ``b`` (straight line, slerp)."""
    rv = Rotation.from_matrix(b.R @ a.R.T).as_rotvec()
    return Pose(Rotation.from_rotvec(rv * s).as_matrix() @ a.R, a.t + (b.t - a.t) * s)
