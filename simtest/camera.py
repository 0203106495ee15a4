"""Pinhole camera model, and the one place where MuJoCo and OpenCV camera conventions meet.

OpenCV (used for every annotation): x right, y down, z forward; pixel centres at integer coordinates, so
pixel ``(row v, col u)`` covers ``[u - 0.5, u + 0.5) x [v - 0.5, v + 0.5)``.
MuJoCo: the camera looks along its -z axis with +y up; its principal point is measured from the image centre
on a grid whose pixel corners sit at integers. Both conversions live here and nowhere else.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from simtest.errors import ConfigError
from simtest.geometry import Pose

__all__ = ["CameraModel", "backproject", "R_MJ_CV", "intrinsics_matrix", "default_intrinsics", "D435_FOCAL_PX",
           "mujoco_camera_intrinsics", "mujoco_model_intrinsics", "pinhole_pixels", "pinhole_points",
           "window_intrinsics"]

#: Rotation from the OpenCV camera frame to the MuJoCo camera frame (and back: it is its own inverse).
R_MJ_CV = np.diag([1.0, -1.0, -1.0])


def intrinsics_matrix(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """The 3x3 OpenCV intrinsics matrix (pixels)."""
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


#: Focal length (pixels) of the default RealSense-D435-like colour camera at 640 px width.
D435_FOCAL_PX = 615.0


def pinhole_pixels(K: np.ndarray, points: np.ndarray, z: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates ``(u, v)`` of camera-frame points (..., 3), metres, under intrinsics ``K``:
    ``u = fx x / z + cx``, ``v = fy y / z + cy`` (OpenCV: pixel centres at integers). ``z`` replaces the points'
    own depth as the divisor (e.g. kept away from 0)."""
    p = np.asarray(points, dtype=np.float64)
    z = p[..., 2] if z is None else z
    return K[0, 0] * p[..., 0] / z + K[0, 2], K[1, 1] * p[..., 1] / z + K[1, 2]


def pinhole_points(K: np.ndarray, u: np.ndarray, v: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Camera-frame points (..., 3), metres, of pixels ``(u, v)`` at planar depth ``z`` (metres) under intrinsics
    ``K``: the inverse of :func:`pinhole_pixels`."""
    return np.stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z], axis=-1)


def backproject(depth: np.ndarray, K: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Camera-frame points (N, 3), metres, of the pixels with depth > 0 (inside ``mask`` if given).

    Args:
        depth: (H, W) planar depth, metres, 0 = missing.
        K: 3x3 intrinsics (pixels); pixel centres at integer coordinates.
        mask: Optional (H, W) bool.
    """
    valid = np.asarray(depth) > 0
    if mask is not None:
        valid &= np.asarray(mask, dtype=bool)
    v, u = np.nonzero(valid)
    return pinhole_points(K, u, v, np.asarray(depth, dtype=np.float64)[v, u])


def default_intrinsics(width: int, height: int, fx: float | None = None, fy: float | None = None,
                       cx: float | None = None, cy: float | None = None) -> np.ndarray:
    """The default D435-like intrinsics for a ``width`` x ``height`` image (pixels), with any given value kept.

    Focal lengths default to :data:`D435_FOCAL_PX` scaled by ``width / 640``; the principal point to the image
    centre in OpenCV's convention (pixel centres at integers: ``((width - 1) / 2, (height - 1) / 2)``).
    """
    s = width / 640.0
    return intrinsics_matrix(D435_FOCAL_PX * s if fx is None else fx, D435_FOCAL_PX * s if fy is None else fy,
                             (width - 1) / 2.0 if cx is None else cx, (height - 1) / 2.0 if cy is None else cy)


def mujoco_camera_intrinsics(K: np.ndarray, width: int, height: int) -> dict[str, list[float]]:
    """MjSpec camera fields that make MuJoCo render exactly the OpenCV intrinsics ``K``.

    Returns a dict with ``resolution``, ``focal_pixel``, ``principal_pixel`` and ``sensor_size`` for a
    ``mujoco.MjsCamera``. The principal-point offset is measured from the image centre, and MuJoCo's pixel
    corners sit at integers, hence the half-pixel shift (checked against rendered pixels in the tests).
    """
    fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    return {
        "resolution": [float(width), float(height)],
        "focal_pixel": [fx, fy],
        "principal_pixel": [width / 2.0 - (cx + 0.5), height / 2.0 - (cy + 0.5)],
        # Any positive sensor size works: MuJoCo converts pixels to lengths with sensor_size / resolution.
        "sensor_size": [width * 1e-5, height * 1e-5],
    }


def mujoco_model_intrinsics(K: np.ndarray, width: int, height: int) -> tuple[list[float], list[float], list[int]]:
    """The compiled model's camera fields for the OpenCV intrinsics ``K``: ``(cam_intrinsic, cam_sensorsize,
    cam_resolution)``, what MuJoCo compiles :func:`mujoco_camera_intrinsics` into (focal length and principal
    offset as lengths on the sensor); written into ``model.cam_*`` they make the next render use ``K``."""
    spec = mujoco_camera_intrinsics(K, width, height)
    px, py = (s / r for s, r in zip(spec["sensor_size"], spec["resolution"]))
    (fx, fy), (ox, oy) = spec["focal_pixel"], spec["principal_pixel"]
    return [fx * px, fy * py, ox * px, oy * py], list(spec["sensor_size"]), [int(width), int(height)]


def window_intrinsics(K: np.ndarray, window: tuple[int, int, int, int]) -> np.ndarray:
    """The intrinsics of the window ``(r0, r1, c0, c1)`` (rows ``r0:r1``, columns ``c0:c1``) of an image with
    intrinsics ``K``: the principal point moved by the window's corner."""
    out = np.array(K, dtype=np.float64)
    out[0, 2] -= window[2]
    out[1, 2] -= window[0]
    return out


@dataclass(frozen=True)
class CameraModel:
    """A pinhole camera with OpenCV intrinsics and its pose in the world.

    Pixel centres: ``K`` follows OpenCV, so the centre of pixel ``(row v, col u)`` is the image point
    ``(u, v)`` (integer coordinates) and ``cx = (width - 1) / 2`` puts the principal point at the image centre.
    simtest's masks hold exactly the pixels whose centre the silhouette covers. Renderers that sample pixel
    centres at ``(u + 0.5, v + 0.5)`` (OpenGL-style, e.g. the BOP toolkit's vispy renderer) reproduce simtest's
    masks when given ``cx + 0.5`` and ``cy + 0.5`` (same ``fx``, ``fy``).

    Attributes:
        K: 3x3 intrinsics (pixels), OpenCV convention (pixel centres at integer coordinates).
        width: Image width (pixels).
        height: Image height (pixels).
        T_world_cam: Pose of the OpenCV camera frame in the world (metres).
    """

    K: np.ndarray
    width: int
    height: int
    T_world_cam: Pose = field(default_factory=Pose.identity)

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=np.float64).reshape(3, 3)
        if not (K[0, 0] > 0 and K[1, 1] > 0):
            raise ConfigError(f"camera focal lengths must be > 0 pixels, got fx={K[0, 0]!r}, fy={K[1, 1]!r}")
        if int(self.width) < 1 or int(self.height) < 1:
            raise ConfigError(f"camera size must be >= 1 pixel, got {self.width!r}x{self.height!r}")
        K.setflags(write=False)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    @staticmethod
    def default(width: int = 640, height: int = 480) -> "CameraModel":
        """A RealSense-D435-like colour camera (fx = fy = 615 px at 640x480), scaled to ``width``."""
        return CameraModel(default_intrinsics(width, height), width, height)

    def with_pose(self, T_world_cam: Pose) -> "CameraModel":
        return CameraModel(self.K, self.width, self.height, T_world_cam)

    @property
    def T_cam_world(self) -> Pose:
        return self.T_world_cam.inverse()

    def project(self, points_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project camera-frame points (N, 3), metres, to pixels.

        Returns:
            ``(uv, z)``: pixel coordinates (N, 2) with integer pixel centres, and depth z (N,) in metres.
        """
        p = np.asarray(points_cam, dtype=np.float64)
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = (p @ self.K.T)[:, :2] / z[:, None]
        return uv, z

    def project_world(self, points_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points (N, 3) to pixels; see :meth:`project`."""
        return self.project(self.T_cam_world.apply(points_world))

    def backproject(self, depth: np.ndarray) -> np.ndarray:
        """Camera-frame points (H, W, 3) from a planar depth image (metres; 0 stays at the origin)."""
        h, w = depth.shape
        u, v = np.meshgrid(np.arange(w), np.arange(h))
        z = depth.astype(np.float64)
        x = (u - self.K[0, 2]) / self.K[0, 0] * z
        y = (v - self.K[1, 2]) / self.K[1, 1] * z
        return np.stack([x, y, z], axis=-1)

    # --- the MuJoCo side -------------------------------------------------------------------------------
    def mujoco_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Position (3,) and rotation matrix (3x3) of the equivalent MuJoCo camera in the world."""
        return self.T_world_cam.t.copy(), self.T_world_cam.R @ R_MJ_CV

    @staticmethod
    def from_mujoco(pos: np.ndarray, xmat: np.ndarray, K: np.ndarray, width: int, height: int) -> "CameraModel":
        """From a MuJoCo camera's world position and 3x3 orientation (``data.cam_xpos``, ``data.cam_xmat``)."""
        R_world_mj = np.asarray(xmat, dtype=np.float64).reshape(3, 3)
        return CameraModel(K, width, height, Pose(R_world_mj @ R_MJ_CV, pos))

    def mujoco_intrinsics(self) -> dict[str, list[float]]:
        return mujoco_camera_intrinsics(self.K, self.width, self.height)

    def look_at(self, eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0),
                roll: float = 0.0) -> "CameraModel":
        """This camera placed at ``eye`` looking at ``target`` (world, metres), rolled by ``roll`` radians."""
        return self.with_pose(look_at_pose(eye, target, up, roll))


def look_at_pose(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0),
                 roll: float = 0.0) -> Pose:
    """``T_world_cam`` (OpenCV) of a camera at ``eye`` looking at ``target``, with in-plane ``roll`` (rad)."""
    eye = np.asarray(eye, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - eye
    n = np.linalg.norm(z)
    if n < 1e-9:
        raise ConfigError(f"camera eye and target coincide at {eye.tolist()}")
    z /= n
    up = np.asarray(up, dtype=np.float64)
    x = np.cross(z, up)  # image right; image down (y) then points along -up
    if np.linalg.norm(x) < 1e-6:  # looking straight along up: pick any perpendicular
        x = np.cross(z, np.array([0.0, 1.0, 0.0]))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=1)
    if roll:
        c, s = np.cos(roll), np.sin(roll)
        R = R @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return Pose(R, eye)
