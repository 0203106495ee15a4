"""Rigid transforms. ``T_a_b`` maps points from frame ``b`` into frame ``a``; translations in metres."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["Pose", "as_matrix", "transform_points", "random_rotation", "rotation_about"]


@dataclass(frozen=True)
class Pose:
    """A rigid transform ``x_a = R @ x_b + t``.

    Attributes:
        R: 3x3 rotation matrix.
        t: Translation (3,), metres.
    """

    R: np.ndarray
    t: np.ndarray

    def __post_init__(self) -> None:
        # Own copies: a pose made from live arrays (MuJoCo's data.xpos, cam_xpos) must not move with them.
        R = np.array(self.R, dtype=np.float64).reshape(3, 3)
        t = np.array(self.t, dtype=np.float64).reshape(3)
        if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
            raise ValueError(f"Pose has non-finite values: R={R.tolist()}, t={t.tolist()}")
        R.setflags(write=False)
        t.setflags(write=False)
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)

    @staticmethod
    def identity() -> "Pose":
        return Pose(np.eye(3), np.zeros(3))

    @staticmethod
    def from_matrix(T: np.ndarray) -> "Pose":
        T = np.asarray(T, dtype=np.float64)
        if T.shape != (4, 4):
            raise ValueError(f"expected a 4x4 matrix, got shape {T.shape}")
        return Pose(T[:3, :3], T[:3, 3])

    @staticmethod
    def from_quat_wxyz(quat_wxyz: np.ndarray, t: np.ndarray) -> "Pose":
        """From a (w, x, y, z) quaternion, MuJoCo's order."""
        w, x, y, z = np.asarray(quat_wxyz, dtype=np.float64)
        return Pose(Rotation.from_quat([x, y, z, w]).as_matrix(), t)

    def quat_wxyz(self) -> np.ndarray:
        """The rotation as a (w, x, y, z) quaternion with w >= 0 (MuJoCo's order)."""
        x, y, z, w = Rotation.from_matrix(self.R).as_quat()
        q = np.array([w, x, y, z])
        return q if q[0] >= 0 else -q

    def matrix(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = self.R
        T[:3, 3] = self.t
        return T

    def inverse(self) -> "Pose":
        return Pose(self.R.T, -self.R.T @ self.t)

    def __matmul__(self, other: "Pose") -> "Pose":
        """Composition: ``(T_a_b @ T_b_c) = T_a_c``."""
        return Pose(self.R @ other.R, self.R @ other.t + self.t)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Transform points (N, 3) -> (N, 3)."""
        return np.asarray(points, dtype=np.float64) @ self.R.T + self.t


def as_matrix(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """A 4x4 homogeneous matrix from R (3x3) and t (3,)."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t).reshape(3)
    return T


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4x4 transform to points (N, 3)."""
    return np.asarray(points) @ T[:3, :3].T + T[:3, 3]


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random rotation matrix drawn with ``rng``."""
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    return Rotation.from_quat(q).as_matrix()


def rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix of ``angle`` radians about ``axis`` (normalised here)."""
    axis = np.asarray(axis, dtype=np.float64)
    n = np.linalg.norm(axis)
    if n == 0:
        raise ValueError("rotation axis must be non-zero")
    return Rotation.from_rotvec(axis / n * angle).as_matrix()
