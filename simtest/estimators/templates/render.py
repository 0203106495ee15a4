"""Colour and mask renders of one object alone at given poses (MuJoCo offscreen), the raw templates of a bank.

The object is drawn with its own appearance (vertex colours, face colours or texture, baked as the dataset
renders do: :func:`simtest.objects.appearance.add_object_visual`) under a camera-attached light, on black. The
camera has exactly the OpenCV intrinsics ``K`` (:func:`simtest.camera.mujoco_camera_intrinsics`); poses are
model to camera, OpenCV frame, metres. The mask is the object's pixels in MuJoCo's segmentation render.
"""

from __future__ import annotations

import numpy as np

import simtest  # noqa: F401  (GL backend before mujoco)
import mujoco

from simtest.camera import mujoco_camera_intrinsics
from simtest.errors import ConfigError, RenderError
from simtest.objects.appearance import add_object_visual, texture_roles

__all__ = ["ObjectRenderer", "AMBIENT", "DIFFUSE"]

#: Headlight (camera-attached) ambient and diffuse intensities, per channel in [0, 1].
AMBIENT = 0.45
DIFFUSE = 0.55
#: OpenCV camera frame to MuJoCo camera frame (y and z flipped).
_FLIP = np.diag([1.0, -1.0, -1.0])


class ObjectRenderer:
    """Renders ``obj`` alone through a ``width`` x ``height`` camera with intrinsics ``K`` (context manager).

    ``render(R, t)`` gives ``(rgb (H, W, 3) uint8, mask (H, W) bool)`` for the pose ``x_cam = R x_model + t``
    (metres, OpenCV camera frame).

    Raises:
        ConfigError: A malformed ``K`` or image size. RenderError: No working GL backend.
    """

    def __init__(self, obj, K: np.ndarray, width: int, height: int, ambient: float = AMBIENT,
                 diffuse: float = DIFFUSE) -> None:
        K = np.asarray(K, np.float64)
        if K.shape != (3, 3) or not (K[0, 0] > 0 and K[1, 1] > 0):
            raise ConfigError(f"ObjectRenderer: K must be 3x3 with positive focal lengths, got {K.tolist()!r}")
        if int(width) < 8 or int(height) < 8:
            raise ConfigError(f"ObjectRenderer: image must be at least 8x8 pixels, got {width!r}x{height!r}")
        self.width, self.height, self.K = int(width), int(height), K
        try:
            self.model = _compile(obj, K, self.width, self.height, float(ambient), float(diffuse))
            self.data = mujoco.MjData(self.model)
            self.renderer = mujoco.Renderer(self.model, self.height, self.width)
        except Exception as exc:  # no GL backend, etc.
            raise RenderError(f"cannot render templates of {obj.name}: {exc} (try MUJOCO_GL=egl or osmesa)") from exc
        self._quat = np.zeros(4)

    def render(self, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The object at pose ``(R, t)``: RGB (H, W, 3) uint8 (black background) and its mask (H, W) bool."""
        Rm = _FLIP @ np.asarray(R, np.float64)
        mujoco.mju_mat2Quat(self._quat, Rm.reshape(-1))
        self.data.mocap_pos[0] = _FLIP @ np.asarray(t, np.float64).reshape(3)
        self.data.mocap_quat[0] = self._quat
        mujoco.mj_forward(self.model, self.data)
        self.renderer.update_scene(self.data, camera=0)
        rgb = self.renderer.render().copy()
        self.renderer.enable_segmentation_rendering()
        try:
            seg = self.renderer.render()
        finally:
            self.renderer.disable_segmentation_rendering()
        mask = seg[..., 0] >= 0
        rgb[~mask] = 0
        return rgb, mask

    def close(self) -> None:
        self.renderer.close()

    def __enter__(self) -> "ObjectRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _compile(obj, K: np.ndarray, width: int, height: int, ambient: float, diffuse: float) -> mujoco.MjModel:
    """A model of ``obj`` on a mocap body in front of a camera at the origin with intrinsics ``K``."""
    spec = mujoco.MjSpec()
    spec.visual.global_.offwidth = width
    spec.visual.global_.offheight = height
    spec.visual.map.znear = 0.001
    spec.stat.extent = 1.0
    _mesh, texture = add_object_visual(spec, obj, "obj")
    material = spec.add_material(name="obj_mat", rgba=list(obj.rgba))
    if texture is not None:
        material.textures = texture_roles(texture)
    body = spec.worldbody.add_body(name="obj", mocap=True)
    geom = body.add_geom()
    geom.type = mujoco.mjtGeom.mjGEOM_MESH
    geom.meshname = "obj"
    geom.material = "obj_mat"
    geom.contype = geom.conaffinity = 0
    spec.visual.headlight.ambient = [ambient] * 3
    spec.visual.headlight.diffuse = [diffuse] * 3
    spec.visual.headlight.specular = [0.0] * 3
    cam = spec.worldbody.add_camera(name="cam")
    for key, val in mujoco_camera_intrinsics(K, width, height).items():
        setattr(cam, key, val)
    return spec.compile()
