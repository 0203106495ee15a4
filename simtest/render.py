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
        """Render the requested channels from fixed camera ``camera`` (id or name) at ``data``'s state.

        Depth and segmentation come from one pass (the segmentation pass also fills the depth buffer), so a
        full frame costs two GL passes instead of the three of ``mujoco.Renderer``'s separate calls.
        """
        r = self._r
        r.update_scene(data, camera=camera, scene_option=self.option)
        out_rgb = out_depth = out_seg = None
        if rgb:
            out_rgb = r.render().copy()
        if depth and seg and self._fused:
            out_seg, raw_depth = self._seg_and_depth()
            out_depth = self._linear_depth(raw_depth)
        else:
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

    # --- one pass for segmentation + depth (uses mujoco.Renderer's context, checked at construction) --------
    @property
    def _fused(self) -> bool:
        r = self._r
        return all(hasattr(r, a) for a in ("_rect", "_mjr_context", "_gl_context")) and r._gl_context is not None

    def _seg_and_depth(self) -> tuple[np.ndarray, np.ndarray]:
        r = self._r
        scene = r.scene
        saved = scene.flags.copy()
        try:
            scene.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = True
            scene.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = True
            r._gl_context.make_current()
            mujoco.mjr_render(r._rect, scene, r._mjr_context)
            colour = np.empty((self.height, self.width, 3), dtype=np.uint8)
            zbuf = np.empty((self.height, self.width), dtype=np.float32)
            mujoco.mjr_readPixels(colour, zbuf, r._rect, r._mjr_context)
        finally:
            np.copyto(scene.flags, saved)
        code = colour.astype(np.int32)
        segid = code[..., 0] + (code[..., 1] << 8) + (code[..., 2] << 16)  # 0 = background, else segid + 1
        lut = np.full(scene.ngeom + 1, -1, dtype=np.int32)
        for g in scene.geoms[:scene.ngeom]:
            if g.segid != -1 and g.objtype == _GEOM:
                lut[g.segid + 1] = g.objid
        seg = lut[np.clip(segid, 0, scene.ngeom)]
        return np.ascontiguousarray(seg[::-1]), np.ascontiguousarray(zbuf[::-1])

    def _linear_depth(self, zbuf: np.ndarray) -> np.ndarray:
        """Reversed-Z depth buffer values -> planar depth in metres (0 beyond the far plane)."""
        far, near = np.float32(self.zfar), np.float32(self.znear)
        c = -(far + near) / (far - near)
        d = -(np.float32(2) * far * near) / (far - near)
        c = np.float32(-0.5) * c - np.float32(0.5)
        d = np.float32(-0.5) * d
        z = (d / (zbuf.astype(np.float64) + c)).astype(np.float32)
        return np.where(z < self.zfar * 0.999, z, 0.0).astype(np.float32)

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
