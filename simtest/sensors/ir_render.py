"""Rendering the scene from a stereo sensor's IR cameras and projector through the scene's own renderer: the
render camera placed at another pose with the IR intrinsics, over the whole image or a window of it
(:class:`RenderAt`), and the materials darkened by their reflectance for the IR renders
(:class:`DiffuseMaterials`); both restore the model exactly."""

from __future__ import annotations

import numpy as np

from simtest.camera import CameraModel, mujoco_model_intrinsics, window_intrinsics
from simtest.errors import ConfigError
from simtest.geometry import Pose

__all__ = ["RenderAt", "DiffuseMaterials"]


class RenderAt:
    """Renders the scene's render camera at other poses with the IR intrinsics, over the whole image or a window
    of it; restores the camera (pose, ``cam_intrinsic``, ``cam_sensorsize``, ``cam_resolution``) on exit.

    A window ``(r0, r1, c0, c1)`` is rendered as an image of its own (:func:`simtest.camera.window_intrinsics`
    written into the model by :func:`simtest.camera.mujoco_model_intrinsics`), drawn into a corner of the
    renderer's buffer. It equals the crop of the whole render (depth to float32 rounding; tested).
    """

    def __init__(self, renderer, data, camera_id: int, camera: CameraModel, K_ir: np.ndarray) -> None:
        self.renderer, self.data, self.cid, self.camera = renderer, data, int(camera_id), camera
        self.model = renderer.model
        self.K_ir = np.asarray(K_ir, dtype=np.float64)

    def __enter__(self) -> "RenderAt":
        m, c = self.model, self.cid
        self.pos = self.data.cam_xpos[c].copy()
        self.mat = self.data.cam_xmat[c].copy()
        self.saved = [(a, a[c].copy()) for a in (m.cam_intrinsic, m.cam_sensorsize, m.cam_resolution)]
        if not np.all(m.cam_sensorsize[c] > 0):
            raise ConfigError("the stereo sensor needs a camera given by focal_pixel/sensor_size "
                              "(simtest.camera.mujoco_camera_intrinsics)")
        return self

    def render(self, T_world: Pose, rgb: bool, seg: bool = False, window: tuple[int, int, int, int] | None = None):
        """The frame at ``T_world`` (OpenCV camera pose): the whole image, or ``window``'s pixels only."""
        full = (0, self.camera.height, 0, self.camera.width)
        window = full if window is None else tuple(int(x) for x in window)
        w, h = window[3] - window[2], window[1] - window[0]
        m, c = self.model, self.cid
        m.cam_intrinsic[c], m.cam_sensorsize[c], m.cam_resolution[c] = mujoco_model_intrinsics(
            window_intrinsics(self.K_ir, window), w, h)
        pos, R_mj = self.camera.with_pose(T_world).mujoco_pose()
        self.data.cam_xpos[self.cid] = pos
        self.data.cam_xmat[self.cid] = R_mj.reshape(-1)
        size = None if window == full else (w, h)
        return self.renderer.render(self.data, self.cid, rgb=rgb, depth=True, seg=seg, size=size)

    def __exit__(self, *exc) -> None:
        for a, copy in self.saved:
            a[self.cid] = copy
        self.data.cam_xpos[self.cid] = self.pos
        self.data.cam_xmat[self.cid] = self.mat


class DiffuseMaterials:
    """The mirror term in the materials, for the IR renders: each material's colour (``mat_rgba``, and
    ``geom_rgba`` where a geom's own colour overrides its material's) and specular scaled by
    ``1 - reflectance``, reflectance 0 (light a mirror-like surface reflects specularly does not come back to the
    cameras, and MuJoCo draws no reflection for it); every array restored exactly on exit. MuJoCo reads the
    materials from the model at each ``mjv_updateScene``: nothing is uploaded."""

    _DEFAULT_RGBA = np.array([0.5, 0.5, 0.5, 1.0], dtype=np.float32)

    def __init__(self, model, enabled: bool) -> None:
        self.model, self.saved = model, []
        self.enabled = bool(enabled) and bool(np.any(model.mat_reflectance > 0))

    def __enter__(self) -> "DiffuseMaterials":
        if not self.enabled:
            return self
        m = self.model
        self.saved = [(a, a.copy()) for a in (m.mat_rgba, m.mat_specular, m.mat_reflectance, m.geom_rgba)]
        try:
            keep = np.clip(1.0 - m.mat_reflectance, 0.0, 1.0).astype(np.float32)
            m.mat_rgba[:, :3] *= keep[:, None]
            m.mat_specular *= keep
            m.mat_reflectance[:] = 0.0
            # mjv_updateScene draws a geom's own rgba instead of its material's when it is not the default
            matid = np.asarray(m.geom_matid)
            own = (matid >= 0) & np.any(m.geom_rgba != self._DEFAULT_RGBA, axis=1)
            for g in np.nonzero(own)[0]:
                rgba = m.geom_rgba[g]
                rgba[:3] *= keep[matid[g]]
                if np.array_equal(rgba, self._DEFAULT_RGBA):  # would read as "no colour of its own"
                    rgba[0] = np.nextafter(np.float32(0.5), np.float32(0.0))
        except BaseException:
            self.__exit__()
            raise
        return self

    def __exit__(self, *exc) -> None:
        for a, copy in self.saved:
            np.copyto(a, copy)
