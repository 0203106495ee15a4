"""A quick look at one object: MuJoCo renders of it alone from a few azimuths (``simtest objects preview``)."""

from __future__ import annotations

import numpy as np

import simtest  # noqa: F401  (GL backend before mujoco)
import mujoco

from simtest.errors import RenderError
from simtest.objects.appearance import add_object_visual, texture_roles

__all__ = ["render_preview"]


def render_preview(obj, size: int = 256, views: int = 4) -> np.ndarray:
    """Render ``obj`` alone from ``views`` azimuths (MuJoCo offscreen), side by side.

    Args:
        obj: The :class:`~simtest.objects.ObjectModel` (metres).
        size: Side of each view, pixels.
        views: Number of views, at evenly spaced azimuths 30 degrees above the object.

    Returns:
        (size, views * size, 3) uint8 RGB.

    Raises:
        RenderError: No working GL backend (the message says which to try).
    """
    try:
        return _render(obj, size, views)
    except RenderError:
        raise
    except Exception as exc:  # no GL backend, etc.
        raise RenderError(f"cannot render a preview of {obj.name}: {exc} (try MUJOCO_GL=egl or osmesa)") from exc


def _render(obj, size: int, views: int) -> np.ndarray:
    spec = mujoco.MjSpec()
    spec.visual.global_.offwidth = max(size, 64)
    spec.visual.global_.offheight = max(size, 64)
    _mesh, texture = add_object_visual(spec, obj, "obj")
    material = spec.add_material(name="obj_mat", rgba=list(obj.rgba))
    if texture is not None:
        material.textures = texture_roles(texture)
    body = spec.worldbody.add_body()
    geom = body.add_geom()
    geom.type = mujoco.mjtGeom.mjGEOM_MESH
    geom.meshname = "obj"
    geom.material = "obj_mat"
    geom.contype = 0
    geom.conaffinity = 0
    spec.visual.headlight.ambient = [0.35, 0.35, 0.35]  # textures read at every view, not only the lit side
    spec.visual.headlight.diffuse = [0.45, 0.45, 0.45]
    light = spec.worldbody.add_light()
    light.pos = [0.0, -0.3, 1.0]
    light.dir = [0.0, 0.3, -1.0]
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = 0.0
    cam.distance = 2.2 * max(obj.diameter, 0.02)
    cam.elevation = -30.0
    images = []
    with mujoco.Renderer(model, size, size) as renderer:
        for k in range(views):
            cam.azimuth = 45.0 + 360.0 * k / views
            renderer.update_scene(data, camera=cam)
            images.append(renderer.render().copy())
    return np.concatenate(images, axis=1)
