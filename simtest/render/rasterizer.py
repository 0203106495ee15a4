"""Offscreen rendering with MuJoCo: RGB, planar depth (metres) and exact per-geom segmentation.

:class:`Renderer` draws with MuJoCo's own low-level API (``mjv_updateScene``, ``mjr_render``,
``mjr_readPixels``), the same calls ``mujoco.Renderer`` makes, and gives the same arrays (tested), with three
savings that matter when every scene is a new model:

* one GL context per process, shared by the renderers of successive scenes (``mujoco.Renderer`` makes one
  per instance);
* the smallest font atlas and a scene buffer sized to the model (font and buffer allocation dominated
  ``mujoco.Renderer``'s start-up);
* depth and segmentation read from one pass (the segmentation pass fills the depth buffer too), so a full
  frame is two GL passes instead of three; a depth-only request reads back the depth buffer alone, and RGB +
  depth without segmentation is one pass (``fast`` profile).

Shadows, reflections and MSAA are off in the ``fast`` profile and on in ``quality``.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Literal

import numpy as np

import simtest  # noqa: F401  (selects the GL backend before mujoco is imported)
import mujoco

from simtest.errors import RenderError
from simtest.render.gl import SYSTEM_PACKAGES_HINT, backend, before_first_context, check_fork, context_made, \
    forked_after_context

__all__ = ["Frame", "Renderer", "Profile", "camera_id"]

Profile = Literal["fast", "quality"]

#: Object type code of geoms in MuJoCo's segmentation output.
_GEOM = int(mujoco.mjtObj.mjOBJ_GEOM)

_CONTEXT_LOCK = threading.Lock()
_CONTEXT: dict[str, object] = {}


def _gl_context(width: int, height: int):
    """The process's shared GL context, made (or remade larger) on demand.

    A context that is replaced by a larger one is not freed here: the renderers made in it keep it alive (it is
    freed with the last of them), since freeing it would blank their images.

    Raises:
        RenderError: In a process forked after its parent made a context (see :func:`simtest.render.gl.check_fork`),
            or when no context can be made.
    """
    before_first_context()
    with _CONTEXT_LOCK:
        ctx = _CONTEXT.get("ctx")
        size = _CONTEXT.get("size", (0, 0))
        if ctx is None or width > size[0] or height > size[1]:
            w, h = max(width, size[0]), max(height, size[1])
            try:
                ctx = mujoco.GLContext(w, h)
            except Exception as exc:  # backend import errors, EGL/OSMesa init failures
                raise RenderError(f"could not create an offscreen OpenGL context with MUJOCO_GL={backend()!r}: "
                                  f"{exc}. {SYSTEM_PACKAGES_HINT}") from exc
            _CONTEXT["ctx"], _CONTEXT["size"] = ctx, (w, h)
            context_made()
        return ctx


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



def camera_id(model: mujoco.MjModel, camera: int | str) -> int:
    """The id of fixed camera ``camera`` (an id or a name) of ``model``.

    Raises:
        RenderError: No such camera (the message lists the model's cameras).
    """
    cid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera) if isinstance(camera, str) else int(camera)
    if not 0 <= cid < model.ncam:
        names = [model.camera(i).name for i in range(model.ncam)]
        raise RenderError(f"unknown camera {camera!r}; the model has {names}")
    return cid

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
        RenderError: If no OpenGL context can be created (the message says which packages to install), or
            the image is larger than the model's offscreen buffer.
    """

    def __init__(self, model: mujoco.MjModel, width: int, height: int, profile: Profile = "fast",
                 geomgroups: tuple[int, ...] = (0, 1, 2)) -> None:
        if profile not in ("fast", "quality"):
            raise RenderError(f"render profile must be 'fast' or 'quality', got {profile!r}")
        self.model = model
        self.width, self.height = int(width), int(height)
        bw, bh = int(model.vis.global_.offwidth), int(model.vis.global_.offheight)
        if self.width > bw or self.height > bh:
            raise RenderError(f"image {self.width}x{self.height} exceeds the model's offscreen buffer {bw}x{bh} "
                              f"(visual.global offwidth/offheight)")
        self._con = None
        self._ctx = _gl_context(self.width, self.height)
        self._ctx.make_current()
        self._con = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_50)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._con)
        # Read depth as reversed Z (0 at the far plane), the mapping _linear_depth inverts.
        self._con.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self._scene = mujoco.MjvScene(model, maxgeom=int(model.ngeom) + 500)
        self._rect = mujoco.MjrRect(0, 0, self.width, self.height)
        self._cam = mujoco.MjvCamera()
        self._cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._pert = mujoco.MjvPerturb()
        self.option = mujoco.MjvOption()
        self.option.geomgroup[:] = 0
        for g in geomgroups:
            self.option.geomgroup[g] = 1
        quality = profile == "quality"
        flags = self._scene.flags
        flags[mujoco.mjtRndFlag.mjRND_SHADOW] = quality
        flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = quality
        flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = False
        flags[mujoco.mjtRndFlag.mjRND_FOG] = False
        self.profile: Profile = profile
        extent = float(model.stat.extent)
        self.znear = float(model.vis.map.znear) * extent
        self.zfar = float(model.vis.map.zfar) * extent

    def upload_textures(self, textures) -> None:
        """Upload the model's textures ``textures`` (ids) to this renderer's GL context again, after their
        ``tex_data`` was written in place."""
        if self._con is None:
            raise RenderError("upload_textures() called after close()")
        self._ctx.make_current()
        for t in textures:
            mujoco.mjr_uploadTexture(self.model, self._con, int(t))

    def _camera_id(self, camera: int | str) -> int:
        return camera_id(self.model, camera)

    def render(self, data: mujoco.MjData, camera: int | str, rgb: bool = True, depth: bool = True,
               seg: bool = True, size: tuple[int, int] | None = None) -> Frame:
        """Render the requested channels from fixed camera ``camera`` (id or name) at ``data``'s state.

        ``data.cam_xpos`` / ``cam_xmat`` are used as they are (a caller may place the camera there).
        ``size``: ``(width, height)`` of a smaller image (at most the renderer's), drawn into a corner of the
        buffer; the camera's intrinsics (``model.cam_sensorsize``, ``cam_intrinsic``) must then describe that
        image (e.g. a window of the full one: :mod:`simtest.sensors.stereo`).
        """
        if self._con is None:
            raise RenderError("render() called after close()")
        check_fork()
        rect = self._rect
        if size is not None:
            w, h = int(size[0]), int(size[1])
            if not (0 < w <= self.width and 0 < h <= self.height):
                raise RenderError(f"render size {size} must be within the renderer's {self.width}x{self.height}")
            rect = mujoco.MjrRect(0, 0, w, h)
        self._cam.fixedcamid = self._camera_id(camera)
        self._ctx.make_current()
        # Renderers share the GL context: bind this one's offscreen buffer (another may have been made since).
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._con)
        mujoco.mjv_updateScene(self.model, data, self.option, self._pert, self._cam,
                               mujoco.mjtCatBit.mjCAT_ALL, self._scene)
        out_rgb = out_depth = out_seg = None
        if rgb:
            mujoco.mjr_render(rect, self._scene, self._con)
            buf = np.empty((rect.height, rect.width, 3), dtype=np.uint8)
            # RGB and depth without segmentation: the colour pass's depth buffer is the same geometry (one pass
            # instead of two; not with MSAA, whose resolved depth blends samples at edges)
            zbuf = np.empty((rect.height, rect.width), dtype=np.float32) if depth and not seg and \
                self.profile != "quality" else None
            mujoco.mjr_readPixels(buf, zbuf, rect, self._con)
            out_rgb = np.ascontiguousarray(buf[::-1])
            if zbuf is not None:
                return Frame(out_rgb, self._linear_depth(zbuf[::-1]), None)
        if depth or seg:
            s, z = self._seg_and_depth(seg, rect)
            out_seg = s if seg else None
            out_depth = self._linear_depth(z) if depth else None
        return Frame(out_rgb, out_depth, out_seg)

    def _seg_and_depth(self, seg: bool, rect) -> tuple[np.ndarray | None, np.ndarray]:
        """The segmentation pass (flat id colours: no lighting or textures) and its depth buffer in ``rect``;
        without ``seg`` only the depth buffer is read back (a depth-only pass)."""
        scene = self._scene
        saved = scene.flags.copy()
        try:
            scene.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = True
            scene.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = True
            mujoco.mjr_render(rect, scene, self._con)
            colour = np.empty((rect.height, rect.width, 3), dtype=np.uint8) if seg else None
            zbuf = np.empty((rect.height, rect.width), dtype=np.float32)
            mujoco.mjr_readPixels(colour, zbuf, rect, self._con)
        finally:
            np.copyto(scene.flags, saved)
        if colour is None:
            return None, zbuf[::-1]
        # The colour codes segid + 1 in 24 bits, R lowest (0 = background); codes above ngeom read as ngeom.
        lut = np.full(scene.ngeom + 1, -1, dtype=np.int32)
        for g in scene.geoms[:scene.ngeom]:
            if g.segid != -1 and g.objtype == _GEOM:
                lut[g.segid + 1] = g.objid
        flipped = colour[::-1]  # GL rows run bottom-up
        if scene.ngeom < 255:  # every code fits in R: one 256-entry lookup of one channel
            seg = lut[np.minimum(np.arange(256), scene.ngeom)][flipped[..., 0]]
        else:
            rgbx = np.zeros(flipped.shape[:2] + (4,), dtype=np.uint8)
            rgbx[..., :3] = flipped
            code = rgbx.view("<u4")[..., 0]
            seg = lut[np.minimum(code, scene.ngeom, out=code)]
        return seg, zbuf[::-1]

    def _linear_depth(self, zbuf: np.ndarray) -> np.ndarray:
        """Reversed-Z depth buffer values -> planar depth in metres (0 beyond the far plane).

        Inverts the perspective projection in float32 constants, as ``mujoco.Renderer`` does.
        """
        far, near = np.float32(self.zfar), np.float32(self.znear)
        c = -(far + near) / (far - near)
        d = -(np.float32(2) * far * near) / (far - near)
        c = np.float32(-0.5) * c - np.float32(0.5)
        d = np.float32(-0.5) * d
        z64 = zbuf.astype(np.float64)  # also a contiguous copy of a flipped view
        z64 += c
        np.divide(d, z64, out=z64)
        z = z64.astype(np.float32)
        z[~(z < self.zfar * 0.999)] = 0.0
        return z

    def close(self) -> None:
        """Free the GL resources of this model (textures, meshes, buffers); the shared context stays."""
        if self._con is not None:
            if not forked_after_context():  # the parent's GL objects cannot be freed (or used) after fork
                self._ctx.make_current()
                self._con.free()
            self._con = None

    def __enter__(self) -> "Renderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:  # pragma: no cover - best effort
        try:
            self.close()
        except Exception:
            pass
