"""Offscreen rendering with MuJoCo: RGB, planar depth (metres) and exact per-geom segmentation.

:class:`Renderer` owns one GL context (``mujoco.Renderer``). Rendering a :class:`Frame` costs one pass per
requested channel; shadows, reflections and MSAA are off in the ``fast`` profile and on in ``quality``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

import simtest  # noqa: F401  (selects the GL backend before mujoco is imported)
import mujoco

from simtest.errors import RenderError
from simtest.gl import SYSTEM_PACKAGES_HINT, backend

__all__ = ["Frame", "Renderer", "Profile"]

Profile = Literal["fast", "quality"]

#: Object type code of geoms in MuJoCo's segmentation output.
_GEOM = int(mujoco.mjtObj.mjOBJ_GEOM)


@dataclass(frozen=True)
class Frame:
    """One rendered view.

    Attributes:
        rgb: (H, W, 3) uint8, or ``None`` if not rendered.
        depth: (H, W) float32 planar depth in metres; 0 where nothing was hit (beyond the far plane).
        seg: (H, W) int32 geom id per pixel, -1 for background; ``None`` if not rendered.
    """

    rgb: np.ndarray | None
    depth: np.ndarray | None
    seg: np.ndarray | None


class Renderer:
    """Renders RGB / depth / segmentation of a MuJoCo model from its fixed cameras.

    Args:
        model: Compiled model; its cameras carry the intrinsics (see :mod:`simtest.camera`).
        width: Image width (pixels); must not exceed ``model.vis.global_.offwidth``.
        height: Image height (pixels); must not exceed ``model.vis.global_.offheight``.
        profile: ``"fast"`` (no shadows/reflections) or ``"quality"`` (shadows and reflections on; MSAA comes
            from ``model.vis.quality.offsamples``, set when the scene is built).
        geomgroups: Which geom groups (0-5) are drawn; collision-only geoms should live in a hidden group.

    Raises:
        RenderError: If no OpenGL context can be created; the message says which packages to install.
    """

    def __init__(self, model: mujoco.MjModel, width: int, height: int, profile: Profile = "fast",
                 geomgroups: tuple[int, ...] = (0, 1, 2)) -> None:
        if profile not in ("fast", "quality"):
            raise RenderError(f"render profile must be 'fast' or 'quality', got {profile!r}")
        self.model = model
        self.width, self.height = int(width), int(height)
        try:
            self._r = mujoco.Renderer(model, self.height, self.width)
        except Exception as exc:  # backend import errors, EGL/OSMesa init failures, framebuffer size
            raise RenderError(
                f"could not create a {self.width}x{self.height} offscreen renderer with MUJOCO_GL="
                f"{backend()!r}: {exc}. {SYSTEM_PACKAGES_HINT}") from exc
        self.option = mujoco.MjvOption()
        self.option.geomgroup[:] = 0
        for g in geomgroups:
            self.option.geomgroup[g] = 1
        quality = profile == "quality"
        flags = self._r.scene.flags
        flags[mujoco.mjtRndFlag.mjRND_SHADOW] = quality
        flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = quality
        flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = False
        flags[mujoco.mjtRndFlag.mjRND_FOG] = False
        self.profile: Profile = profile
        extent = float(model.stat.extent)
        self.znear = float(model.vis.map.znear) * extent
        self.zfar = float(model.vis.map.zfar) * extent

    def render(self, data: mujoco.MjData, camera: int | str, rgb: bool = True, depth: bool = True,
               seg: bool = True) -> Frame:
        """Render the requested channels from fixed camera ``camera`` (id or name) at ``data``'s state."""
        r = self._r
        r.update_scene(data, camera=camera, scene_option=self.option)
        out_rgb = out_depth = out_seg = None
        if rgb:
            out_rgb = r.render().copy()
        if depth:
            r.enable_depth_rendering()
            d = r.render()
            r.disable_depth_rendering()
            out_depth = np.where(d < self.zfar * 0.999, d, 0.0).astype(np.float32)
        if seg:
            r.enable_segmentation_rendering()
            s = r.render()
            r.disable_segmentation_rendering()
            out_seg = np.where(s[..., 1] == _GEOM, s[..., 0], -1).astype(np.int32)
        return Frame(out_rgb, out_depth, out_seg)

    def render_raw(self, data: mujoco.MjData, camera: int | str) -> None:
        """The same three passes with no post-processing (the benchmark's raw MuJoCo reference)."""
        r = self._r
        r.update_scene(data, camera=camera, scene_option=self.option)
        r.render()
        r.enable_depth_rendering()
        r.render()
        r.disable_depth_rendering()
        r.enable_segmentation_rendering()
        r.render()
        r.disable_segmentation_rendering()

    def close(self) -> None:
        if getattr(self, "_r", None) is not None:
            self._r.close()
            self._r = None

    def __enter__(self) -> "Renderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:  # pragma: no cover - best effort
        try:
            self.close()
        except Exception:
            pass
