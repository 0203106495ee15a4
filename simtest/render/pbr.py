"""Path-traced RGB (the ``pbr`` profile): Mitsuba 3 renders a settled MuJoCo state, Open Image Denoise cleans it.

:class:`PbrRenderer` has the :class:`simtest.render.rasterizer.Renderer` interface but renders only RGB: depth, masks and
every annotation keep coming from MuJoCo's exact rasterizer, so all profiles share them. The Mitsuba scene is
read from the compiled model and data every frame, so it is what MuJoCo would draw:

* geometry: every drawn geom (groups 0-2, alpha > 0) at its world pose ``data.geom_xpos`` / ``geom_xmat``;
  meshes from ``model.mesh_vert`` / ``mesh_face`` with MuJoCo's own corner normals, spheres / cylinders /
  capsules as Mitsuba shapes, boxes / planes / ellipsoids as triangle meshes (boxes and planes with the
  texture coordinates of their 2D texture);
* materials: a two-sided principled BSDF per geom; base colour = material (or geom) rgba, read as sRGB, or
  its 2D texture times rgba; roughness = 1 - shininess, specular = specular, metallic = reflectance;
* lights: a MuJoCo spot light becomes a cluster of spots over a small disk (its cutoff and falloff, soft
  shadows), a point light a spherical area light, a directional light stays directional; each is calibrated so
  its irradiance at the scene centre (``model.stat.center``) matches MuJoCo's unattenuated ``diffuse``; the
  ambient (headlight + lights) becomes a constant environment;
* camera: a ``perspective`` sensor with the exact OpenCV intrinsics (fov from the focal length, principal point
  offset from cx, cy; OpenCV pixel centres at integer coordinates), box pixel filter. Mitsuba's sensor has
  square pixels (and refuses a scale in its ``to_world``), so a K with ``fx != fy`` is rendered on a film with
  the larger focal length on both axes, denser along the other axis over the same field of view, and
  area-resampled onto the image's pixel grid along that axis only (:class:`FilmGrid`): every pixel sees the
  rays K gives it; square pixels render the image's own grid.

Mitsuba and ``pyoidn`` are the optional extra ``simtest[pbr]``, imported on first use. The Mitsuba variant is
``render.pbr_variant`` (:func:`simtest.render.llvm.choose_variant`; ``auto``: ``cuda_ad_rgb`` with a CUDA
device, else ``llvm_ad_rgb`` with a libLLVM >= 16, else ``scalar_rgb``). A fixed scene, sample count, seed and
variant give the same image on one machine (on ``llvm_ad_rgb`` also with any thread count).
"""

from __future__ import annotations

import hashlib
import importlib
import logging
import os
from typing import Any

import numpy as np

import simtest  # noqa: F401  (GL backend before mujoco)
import mujoco

from simtest.camera import CameraModel
from simtest.render.colour import linear_to_srgb8, srgb_to_linear
from simtest.errors import RenderError
from simtest.render.llvm import (PBR_VARIANTS, Variant, choose_variant, find_libllvm, note_once, point_drjit_at,
                                 without_gc)
from simtest.render.pbr_film import FilmGrid, film_grid, resample_to_image
from simtest.render.pbr_lights import emitters, panel
from simtest.render.pbr_stages import StageTimes, process_stages
from simtest.render.pbr_shapes import INFINITE_PLANE, geom_shapes, transform
from simtest.render.rasterizer import Frame, camera_id
from simtest.rng import child_sequence

__all__ = ["PbrRenderer", "require_pbr", "resolved_variant", "frame_seed", "renderer_versions", "auto_spp",
           "FilmGrid", "film_grid", "resample_to_image", "INSTALL_HINT", "PBR_VARIANTS", "SAMPLERS",
           "DENOISE_QUALITIES", "GUIDE_SPP"]

INSTALL_HINT = "pip install 'simtest[pbr]'"
#: Longest light path of the path tracer (3: direct light plus one indirect bounce, which carries most of the
#: interreflection in these rooms at a fraction of the cost of more bounces).
MAX_DEPTH = 3
#: Samples per pixel of the albedo / normal guide pass (at most the image's): four stratified samples give guides
#: clean enough to hand to the denoiser as noise-free (OIDN's ``clean_aux``), which keeps more texture detail
#: than one jittered sample with the denoiser's noisy-guide weights (+0.3-0.5 dB PSNR against a 512-spp
#: reference, for 0.02-0.03 s per frame; docs/generate.md).
GUIDE_SPP = 4
#: Guides of at least this many samples are passed to the denoiser as noise-free (``clean_aux``).
CLEAN_GUIDE_SPP = 4
#: Mitsuba samplers the profile can use (``render.pbr_sampler``): ``multijitter`` (correlated multi-jittered,
#: any sample count; the default: +0.7-1.5 dB over ``independent`` at the same samples and cost),
#: ``independent`` (uniform random; earlier releases), ``stratified`` (rounds the count to a square).
SAMPLERS = ("multijitter", "independent", "stratified")
#: Open Image Denoise quality levels (``render.pbr_denoise_quality``); ``fast`` halves the denoiser's time at
#: 640x480 for 0.2-0.65 dB, which the default sampler and guides more than pay back.
DENOISE_QUALITIES = ("fast", "balanced", "high")
#: World from Mitsuba's envmap frame (y up, u = atan2(x, -z) / 2 pi): maps the simtest convention (z up, azimuth
#: from +x toward +y, row 0 the zenith) onto Mitsuba's latitude-longitude lookup.
_R_ENV_MI = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
#: Mitsuba camera frame (x left, y up, z forward) from the OpenCV camera frame (x right, y down, z forward).
_R_CV_MI = np.diag([-1.0, -1.0, 1.0])
#: First spawn key of the sampler seeds (scene spawn keys start with the scene index, < 10^7).
_SEED_STREAM = 0x50425200
_G = mujoco.mjtGeom
_MITSUBA: dict[str, Any] = {}
_CHOSEN: dict[str, Variant] = {}


def _modules(requested: str = "auto") -> tuple[Any, Any, Variant]:
    """``(mitsuba, pyoidn, the variant for `requested`)``, imported once (libLLVM chosen before the import);
    RenderError naming the extra if missing."""
    if "mi" not in _MITSUBA:
        point_drjit_at(find_libllvm())  # before drjit is imported: Dr.Jit reads DRJIT_LIBLLVM_PATH at import
        try:
            mi = importlib.import_module("mitsuba")
            oidn = importlib.import_module("pyoidn")
        except ImportError as exc:
            raise RenderError(f"the 'pbr' render profile needs Mitsuba 3 and Open Image Denoise ({exc}); "
                              f"install them with: {INSTALL_HINT}") from None
        _MITSUBA["mi"], _MITSUBA["oidn"] = mi, oidn
    mi = _MITSUBA["mi"]
    if requested not in _CHOSEN:
        _CHOSEN[requested] = choose_variant(mi, requested)
    chosen = _CHOSEN[requested]
    if mi.variant() != chosen.name:
        mi.set_variant(chosen.name)
    return mi, _MITSUBA["oidn"], chosen


def require_pbr(camera: CameraModel, variant: str = "auto") -> None:
    """Check that the ``pbr`` profile can render ``camera`` with path-tracer ``variant`` (see
    :func:`choose_variant`): the extra is installed and the variant is available (any pinhole K renders:
    :class:`FilmGrid`). A fallback of ``auto`` is logged here (once per run).

    Raises:
        RenderError: Naming ``pip install 'simtest[pbr]'`` when Mitsuba or pyoidn is missing, or naming the library
            to install when an explicit ``cuda`` / ``llvm`` is unavailable.
    """
    mi, _, _ = _modules(variant)
    camera_sensor(mi, camera, 1)


def resolved_variant(variant: str = "auto") -> str:
    """The ``render.pbr_variant`` value (``cuda``, ``llvm`` or ``scalar``) that ``variant`` resolves to in this
    process. A run pins it for its workers, so every image of a dataset comes from one variant even where a
    worker would resolve ``auto`` otherwise (another node's libLLVM, a process that imported Dr.Jit first)."""
    name = _modules(variant)[2].name
    return next(k for k, v in PBR_VARIANTS.items() if v == name)


def renderer_versions(variant: str = "auto") -> dict[str, str]:
    """Versions of the path tracer and denoiser, the Mitsuba variant ``variant`` resolves to and, on the LLVM
    variant, the libLLVM file and version loaded (recorded in the manifest)."""
    from importlib.metadata import version

    mi, _, chosen = _modules(variant)
    out = {"mitsuba": mi.__version__, "mitsuba_variant": chosen.name, "pyoidn": version("pyoidn")}
    if chosen.libllvm is not None:
        out.update(libllvm=chosen.libllvm, libllvm_version=chosen.libllvm_version)
    return out


def auto_spp(width: int, height: int) -> int:
    """Samples per pixel of ``render.pbr_spp = "auto"`` for a ``width`` x ``height`` image:
    ``round(12 * sqrt(320 * 240 / pixels))`` clamped to [6, 12], i.e. 12 at 320x240 and below, 6 at 640x480 and
    above: with the default sampler, guides and denoiser these match or beat the PSNR of the earlier default
    (independent samples, 16 / 8 spp, one-sample guides, OIDN ``high``) against a 512-1024 spp reference with
    the looks on (docs/generate.md; more pixels give the denoiser more to work with, so fewer samples reach
    the same quality)."""
    return int(np.clip(round(12.0 * np.sqrt(320 * 240 / max(1, int(width) * int(height)))), 6, 12))


def frame_seed(seed: int, scene_id: int, im_id: int) -> int:
    """The sampler seed (uint32) of image ``im_id`` of scene ``scene_id``: a stream of its own below the run's
    seed, so path tracing draws nothing from the scene's generator (which keeps every other file unchanged)."""
    return int(child_sequence(seed, _SEED_STREAM, scene_id, im_id).generate_state(1)[0])


def _finite(img) -> np.ndarray:
    """A Mitsuba image tensor as a contiguous float32 array with NaN / inf set to 0."""
    a = np.nan_to_num(np.array(img, dtype=np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    return np.ascontiguousarray(a)


def _geom_rgba(m: mujoco.MjModel, g: int) -> np.ndarray:
    """The colour MuJoCo draws geom ``g`` with: its material's rgba when it has a material and its own rgba is
    MuJoCo's default (0.5, 0.5, 0.5, 1), else its own rgba."""
    own = m.geom_rgba[g]
    if m.geom_matid[g] >= 0 and np.allclose(own, (0.5, 0.5, 0.5, 1.0)):
        return m.mat_rgba[m.geom_matid[g]]
    return own


def sensor_to_world(mi, camera: CameraModel):
    """The Mitsuba sensor's ``to_world`` for ``camera``'s pose (OpenCV camera frame flipped to Mitsuba's)."""
    T = camera.T_world_cam
    return transform(mi, T.R @ _R_CV_MI, T.t)


def camera_sensor(mi, camera: CameraModel, spp: int, sampler: str = "multijitter") -> dict:
    """A Mitsuba ``perspective`` sensor with ``camera``'s exact intrinsics and pose, on the film of
    :func:`film_grid` (the image's own grid when ``fx == fy``).

    OpenCV pixel ``u`` is centred at integer ``u``; Mitsuba's film pixel ``i`` covers ``[i, i + 1)``, so the
    principal point sits at ``cx + 0.5`` film units and its offset from the film centre, as a fraction of the
    film, is ``(cx + 0.5 - W / 2) / W`` (Mitsuba's x axis points left, hence the sign).
    """
    g = film_grid(camera)
    w, h = g.width, g.height
    return {
        "type": "perspective", "fov_axis": "x", "fov": float(np.degrees(2.0 * np.arctan(w / (2.0 * g.focal)))),
        "principal_point_offset_x": float(-(g.cx + 0.5 - w / 2.0) / w),
        "principal_point_offset_y": float(-(g.cy + 0.5 - h / 2.0) / h),
        "near_clip": 0.001, "far_clip": 100.0,
        "to_world": sensor_to_world(mi, camera),
        "film": {"type": "hdrfilm", "width": w, "height": h, "pixel_format": "rgb", "rfilter": {"type": "box"}},
        "sampler": {"type": sampler, "sample_count": int(spp)},
    }


class PbrRenderer:
    """Path-traced RGB of a MuJoCo model (see the module docstring for how the scene is mapped).

    Args:
        model: Compiled model (geoms, materials, textures and lights are read from it).
        camera: Intrinsics and image size (``K``, ``width``, ``height``); its pose is ignored, each
            :meth:`render` reads the camera pose from ``data``.
        spp: Samples per pixel (>= 1), or ``"auto"``: :func:`auto_spp` of the image size.
        denoise: Denoise with Open Image Denoise (albedo and normal AOVs as guides).
        geomgroups: Which geom groups (0-5) are drawn, as for :class:`simtest.render.rasterizer.Renderer`.
        threads: Size of the path tracer's thread pool (process-wide, ``drjit.set_thread_count``) and of the
            denoiser's (``OIDN_NUM_THREADS``, taken at the process's first denoise); ``None`` keeps their
            defaults (all cores). Several generation workers each take their share of the cores.
        variant: ``render.pbr_variant``: ``"auto"``, ``"cuda"``, ``"llvm"`` or ``"scalar"``
            (:func:`simtest.render.llvm.choose_variant`); :attr:`variant` is the Mitsuba variant used.
        environment: ``(radiance, strength)`` of an environment map (:meth:`set_environment`), or ``None``.
        sampler: The Mitsuba sampler (:data:`SAMPLERS`; ``render.pbr_sampler``).
        guide_spp: Samples per pixel of the albedo / normal guide pass (at most ``spp``; :data:`GUIDE_SPP`).
        denoise_quality: Open Image Denoise's quality level (:data:`DENOISE_QUALITIES`).

    Views of one scene whose geometry, materials and lights are unchanged reuse the loaded Mitsuba scene with
    only the sensor changed (the same bytes as loading it again); its compiled kernel is the same for every
    view and scene (Dr.Jit's kernel cache answers it). Geoms with one material and colour share one BSDF. The views
    of a loaded scene move one sensor and, with :attr:`freeze` (JIT variants), replay the kernels recorded at the
    scene's first view (same bytes); a caller whose scene changes at every frame (the grasp env: the arm moves)
    sets ``freeze = False``, since recordings that never replay only cost.
    :attr:`stages` keeps the wall seconds of each stage of its frames (:mod:`simtest.render.pbr_stages`).

    Any pinhole K renders, ``fx != fy`` included (:class:`FilmGrid`: the path tracer's square-pixel film is
    area-resampled onto the image's grid along one axis).

    Raises:
        RenderError: If the ``pbr`` extra is not installed (the message names it), ``spp`` is invalid or an
            explicit ``variant`` is unavailable.
    """

    def __init__(self, model: mujoco.MjModel, camera: CameraModel, spp: int | str = 16, denoise: bool = True,
                 geomgroups: tuple[int, ...] = (0, 1, 2), threads: int | None = None,
                 variant: str = "auto", environment: tuple[np.ndarray, float] | None = None,
                 sampler: str = "multijitter", guide_spp: int = GUIDE_SPP, denoise_quality: str = "fast") -> None:
        spp = auto_spp(camera.width, camera.height) if spp == "auto" else spp
        if isinstance(spp, bool) or not isinstance(spp, (int, np.integer)) or int(spp) < 1:
            raise RenderError(f"samples per pixel must be an integer >= 1 or 'auto', got {spp!r}")
        if sampler not in SAMPLERS:
            raise RenderError(f"pbr sampler {sampler!r} is unknown; allowed: {', '.join(SAMPLERS)}")
        if denoise_quality not in DENOISE_QUALITIES:
            raise RenderError(f"denoise quality {denoise_quality!r} is unknown; allowed: "
                              f"{', '.join(DENOISE_QUALITIES)}")
        if isinstance(guide_spp, bool) or not isinstance(guide_spp, (int, np.integer)) or int(guide_spp) < 1:
            raise RenderError(f"guide samples per pixel must be an integer >= 1, got {guide_spp!r}")
        self._mi, self._oidn, self._variant = _modules(variant)
        if threads is not None:
            import drjit

            drjit.set_thread_count(max(1, int(threads)))
            # the denoiser's pool, read when its device is made (first denoise of the process); same bytes
            os.environ["OIDN_NUM_THREADS"] = str(max(1, int(threads)))
        self.model, self.camera = model, camera
        self.spp, self.denoise = int(spp), bool(denoise)
        self.sampler, self.denoise_quality = sampler, denoise_quality
        #: Samples per pixel of the guide pass (at most :attr:`spp`).
        self.guide_spp = min(self.spp, int(guide_spp))
        self._grid = film_grid(camera)
        self._groups = frozenset(int(g) for g in geomgroups)
        self._textures: dict[tuple, Any] = {}
        self._bsdfs: dict[tuple, Any] = {}  # (material, rgba) -> loaded BSDF, shared by the geoms drawn with it
        self._aux = None
        #: Wall seconds per stage of this renderer's frames (:mod:`simtest.render.pbr_stages`).
        self.stages = StageTimes()
        self._loaded: tuple[bytes, Any] | None = None  # (scene key, loaded Mitsuba scene)
        self._sensor = self._sensor_params = None  # the loaded scene's sensor, moved view by view
        self._calls = None  # (trace, guides) of the loaded scene (:meth:`_render_calls`)
        self._frozen_ok = True  # False once Dr.Jit refused to record the loaded scene
        #: Replay recorded kernels for the views of a loaded scene (Dr.Jit's frozen functions; JIT variants): a
        #: replay saves about 0.06 s per view at 320x240, a recording costs about 0.1 s more than a traced view,
        #: so a caller whose scene changes at every frame turns it off (docs/generate.md).
        self.freeze = True
        self._environment: tuple[np.ndarray, float] | None = None
        self._env_bitmap = None
        self.set_environment(environment)

    def set_environment(self, environment: tuple[np.ndarray, float] | None) -> None:
        """Light the scene by an environment map instead of MuJoCo's constant ambient term: ``(radiance, strength)``
        with ``radiance`` an (H, 2H, 3) linear equirectangular map in the convention of
        :class:`simtest.materials.Environment` (world z up, row 0 the zenith, azimuth from +x toward +y), times
        ``strength``; ``None`` goes back to the ambient term. MuJoCo's lights stay as they are."""
        if environment is None:
            self._environment, self._env_bitmap = None, None
            return
        radiance, strength = environment
        radiance = np.ascontiguousarray(np.maximum(np.asarray(radiance, dtype=np.float32), 0.0) * float(strength))
        if radiance.ndim != 3 or radiance.shape[2] != 3 or radiance.shape[1] != 2 * radiance.shape[0]:
            raise RenderError(f"an environment map must be (H, 2H, 3) radiance, got shape {radiance.shape}")
        self._environment = (radiance, float(strength))
        self._env_bitmap = self._mi.Bitmap(radiance)

    @property
    def width(self) -> int:
        return self.camera.width

    @property
    def height(self) -> int:
        return self.camera.height

    @property
    def variant(self) -> str:
        """The Mitsuba variant this renderer path-traces with (``llvm_ad_rgb``, ...)."""
        return self._variant.name

    def render(self, data: mujoco.MjData, camera: int | str, seed: int = 0) -> Frame:
        """Path-trace RGB from fixed camera ``camera`` (id or name) at ``data``'s state (``data.cam_xpos`` /
        ``cam_xmat`` as they are). ``seed`` seeds the sampler (uint32). Returns a Frame with rgb only (the
        image's size; a ``fx != fy`` film is denoised, then resampled onto the image's grid)."""
        mi = self._mi
        if mi.variant() != self._variant.name:  # another renderer of this process chose another variant
            mi.set_variant(self._variant.name)
        cid = self._camera_id(camera)
        cam = CameraModel.from_mujoco(data.cam_xpos[cid], data.cam_xmat[cid], self.camera.K, self.width,
                                      self.height)
        also = process_stages()
        with self.stages.stage("scene", also):
            key = self._scene_key(data)
            if self._loaded is None or self._loaded[0] != key:
                self._loaded = self._sensor = self._calls = None  # free the previous scene first
                self._frozen_ok = True
                self._bsdfs.clear()
                self._loaded = (key, mi.load_dict(self._scene_dict(data, cam)))
                self.stages.loads += 1
                also.loads += 1
        scene = self._loaded[1]
        with self.stages.stage("sensor", also):
            sensor = self._view_sensor(cam)
        if self._aux is None and self.denoise:
            self._aux = mi.load_dict({"type": "aov", "aovs": "albedo:albedo,nn:sh_normal"})
        trace, guides = self._render_calls()
        seed = int(seed) & 0xFFFFFFFF
        with self.stages.stage("trace", also):
            color = np.maximum(_finite(trace(scene, sensor, seed)), 0.0)
        if self.denoise:
            # The guides come from a second pass of fewer samples: Mitsuba's aov integrator costs ~2.5x a path
            # sample, and the guides need no more samples than make their edges clean.
            with self.stages.stage("guides", also):
                aux = _finite(guides(scene, sensor, seed))
            with self.stages.stage("denoise", also):
                color = self._oidn.denoise(color, np.ascontiguousarray(np.clip(aux[..., 0:3], 0.0, 1.0)),
                                           np.ascontiguousarray(np.clip(aux[..., 3:6], -1.0, 1.0)), hdr=True,
                                           clean_aux=self.guide_spp >= CLEAN_GUIDE_SPP,
                                           quality=self.denoise_quality)
        with self.stages.stage("image", also):
            color = resample_to_image(np.asarray(color, dtype=np.float32), self._grid, self.width, self.height)
            rgb = linear_to_srgb8(color)
        self.stages.frames += 1
        also.frames += 1
        return Frame(rgb, None, None)

    def _view_sensor(self, cam: CameraModel):
        """The loaded scene's sensor at ``cam``'s pose: made once per scene, then only its ``to_world`` is
        updated (the same image as a sensor loaded anew, and the same object for the frozen calls)."""
        mi = self._mi
        if self._sensor is None:
            self._sensor = mi.load_dict(camera_sensor(mi, cam, self.spp, self.sampler))
            self._sensor_params = mi.traverse(self._sensor)
        else:
            self._sensor_params["to_world"] = sensor_to_world(mi, cam)
            self._sensor_params.update()
        return self._sensor

    def _render_calls(self):
        """``(trace, guides)``: functions ``(scene, sensor, seed) -> image`` of the path tracer and of the guide
        pass. With :attr:`freeze` on a JIT variant they are Dr.Jit frozen functions made once per loaded scene:
        the first view records the kernels, later views replay them without tracing Mitsuba's integrator again
        (0.06-0.1 s per call); the images are the same bytes either way."""
        if self._calls is not None:
            return self._calls
        mi, spp, gspp, aux = self._mi, self.spp, self.guide_spp, self._aux

        def trace(scene, sensor, seed):
            return mi.render(scene, sensor=sensor, seed=seed, spp=spp)

        def guides(scene, sensor, seed):
            return mi.render(scene, sensor=sensor, integrator=aux, seed=seed, spp=gspp)

        if self._variant.name.startswith(("llvm", "cuda")) and self.freeze:
            import drjit

            # every input opaque from the first call: one recording per scene, not one per literal seen to change
            frozen = (drjit.freeze(trace, auto_opaque=False), drjit.freeze(guides, auto_opaque=False))
            self._calls = tuple(self._or_traced(f, plain) for f, plain in zip(frozen, (trace, guides)))
        else:
            self._calls = (trace, guides)
        return self._calls

    def _or_traced(self, frozen, plain):
        """``frozen`` called with the seed as a Dr.Jit array, the garbage collector paused (``without_gc``); if
        Dr.Jit cannot record this scene (it refuses some nested virtual calls), its views are traced (same bytes)."""
        mi = self._mi

        def call(scene, sensor, seed):
            if not self._frozen_ok:
                return plain(scene, sensor, seed)
            try:
                return without_gc(frozen, scene, sensor, mi.UInt32(seed))
            except RuntimeError as exc:
                self._frozen_ok = False
                note_once(logging.INFO, f"pbr: Dr.Jit could not record a scene's kernels "
                                        f"({str(exc).splitlines()[0][:200]}); such scenes are traced view by view")
                return plain(scene, sensor, seed)
        return call

    def _scene_key(self, data: mujoco.MjData) -> bytes:
        """A digest of everything :meth:`_scene_dict` reads apart from the camera: equal keys, equal scenes."""
        m = self.model
        h = hashlib.blake2b(digest_size=16)
        for a in (data.geom_xpos, data.geom_xmat, data.light_xpos, data.light_xdir, m.geom_rgba, m.geom_group,
                  m.geom_matid, m.geom_type, m.geom_size, m.geom_dataid, m.mat_rgba, m.mat_specular,
                  m.mat_shininess, m.mat_reflectance, m.mat_texrepeat, m.mat_texid, m.light_active, m.light_type,
                  m.light_ambient, m.light_diffuse, m.light_cutoff, m.light_exponent, m.vis.headlight.ambient,
                  m.stat.center, m.tex_data, m.mat_roughness, m.mat_metallic, m.mat_emission):
            h.update(np.ascontiguousarray(a).tobytes())
        if self._environment is not None:
            h.update(self._environment[0].tobytes())
        return h.digest()

    def _camera_id(self, camera: int | str) -> int:
        return camera_id(self.model, camera)

    def _scene_dict(self, data: mujoco.MjData, cam: CameraModel) -> dict:
        mi = self._mi
        scene: dict[str, Any] = {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": MAX_DEPTH, "hide_emitters": True},
            "sensor": camera_sensor(mi, cam, self.spp, self.sampler),
        }
        m = self.model
        for g in range(m.ngeom):
            rgba = _geom_rgba(m, g)
            if int(m.geom_group[g]) not in self._groups or rgba[3] <= 0.0:
                continue
            mat = int(m.geom_matid[g])
            if mat >= 0 and m.mat_emission[mat] > 0 and int(m.geom_type[g]) == _G.mjGEOM_BOX:
                scene[f"geom_{g}_panel"] = panel(mi, m, data, g, rgba[:3] * float(m.mat_emission[mat]))
                continue
            bsdf = self._shared_bsdf(g, rgba)
            for k, shape in enumerate(geom_shapes(mi, m, data, g, bsdf)):
                scene[f"geom_{g}_{k}"] = shape
        scene.update(emitters(mi, self.model, data))
        if self._env_bitmap is not None:
            scene["environment"] = {"type": "envmap", "bitmap": self._env_bitmap,
                                    "to_world": transform(mi, _R_ENV_MI, np.zeros(3))}
        return scene

    # --- materials ----------------------------------------------------------------------------------------
    def _shared_bsdf(self, g: int, rgba: np.ndarray):
        """The BSDF of geom ``g`` (:meth:`_bsdf`), loaded once per (material, colour) for the scene being built:
        geoms drawn with the same material (walls, table legs) share one BSDF and its textures (same image as
        one BSDF per geom; fewer texture copies and a faster scene load)."""
        key = (int(self.model.geom_matid[g]), np.asarray(rgba, dtype=np.float64).tobytes())
        if key not in self._bsdfs:
            self._bsdfs[key] = self._bsdf(g, rgba)
        return self._bsdfs[key]

    def _bsdf(self, g: int, rgba: np.ndarray):
        """Two-sided principled BSDF of geom ``g``: base colour (texture x rgba, sRGB read as linear radiance
        reflectance); roughness = the material's ``roughness`` when set (>= 0), else 1 - shininess, times its
        roughness map if it has one (role ``ROUGHNESS``); metallic = the material's ``metallic`` when set, else
        reflectance, or its metallic map (role ``METALLIC``); specular; a ``NORMAL`` map becomes Mitsuba's
        ``normalmap`` (MuJoCo defaults without a material: specular 0.5, shininess 0.5, reflectance 0)."""
        m, mi = self.model, self._mi
        mat = int(m.geom_matid[g])
        spec, shin, refl = (m.mat_specular[mat], m.mat_shininess[mat], m.mat_reflectance[mat]) if mat >= 0 \
            else (0.5, 0.5, 0.0)
        rough = float(m.mat_roughness[mat]) if mat >= 0 and m.mat_roughness[mat] >= 0 else 1.0 - float(shin)
        metal = float(m.mat_metallic[mat]) if mat >= 0 and m.mat_metallic[mat] >= 0 else float(refl)
        tex = self._role(mat, mujoco.mjtTextureRole.mjTEXROLE_RGB)
        colour = srgb_to_linear(rgba[:3])
        if tex >= 0 and int(m.tex_type[tex]) == int(mujoco.mjtTexture.mjTEXTURE_2D):
            base = self._bitmap_texture(self._bitmap(tex, colour))
        else:
            if tex >= 0:  # cube / skybox textures: their mean colour
                colour = colour * self._texels(tex).reshape(-1, 3).mean(axis=0)
            base = {"type": "rgb", "value": colour.tolist()}
        principled = {"type": "principled", "base_color": base, "roughness": float(np.clip(rough, 0.05, 1.0)),
                      "specular": float(np.clip(spec, 0.0, 1.0)), "metallic": float(np.clip(metal, 0.0, 1.0))}
        for key, role in (("roughness", mujoco.mjtTextureRole.mjTEXROLE_ROUGHNESS),
                          ("metallic", mujoco.mjtTextureRole.mjTEXROLE_METALLIC)):
            t = self._role(mat, role)
            if t >= 0:
                lo = 0.05 if key == "roughness" else 0.0
                principled[key] = self._bitmap_texture(self._raw_bitmap(t, ("grey", lo)))
        bsdf = principled
        t = self._role(mat, mujoco.mjtTextureRole.mjTEXROLE_NORMAL)
        if t >= 0:
            bsdf = {"type": "normalmap", "normalmap": self._bitmap_texture(self._raw_bitmap(t, ("normal", 0.0))),
                    "bsdf": principled}
        return mi.load_dict({"type": "twosided", "bsdf": bsdf})

    def _role(self, mat: int, role) -> int:
        """The texture id of material ``mat`` in ``role`` (-1: none)."""
        return int(self.model.mat_texid[mat, int(role)]) if mat >= 0 else -1

    @staticmethod
    def _bitmap_texture(bitmap) -> dict:
        return {"type": "bitmap", "bitmap": bitmap, "wrap_mode": "repeat", "filter_type": "bilinear", "raw": True}

    def _raw_bitmap(self, tex: int, kind: tuple[str, float]):
        """A data map (not colour) of texture ``tex`` as a Mitsuba bitmap: ``("grey", lo)`` its first channel
        / 255 clipped to >= lo; ``("normal", _)`` a tangent-space normal map in Mitsuba's frame (the texture is
        OpenGL-style, +y toward the image's top; Mitsuba's tangent ``t`` runs toward increasing v, i.e. down
        the image, so green is flipped)."""
        key = (tex, *kind)
        if key not in self._textures:
            m = self.model
            w, h, c = int(m.tex_width[tex]), int(m.tex_height[tex]), int(m.tex_nchannel[tex])
            adr = int(m.tex_adr[tex])
            raw = np.asarray(m.tex_data[adr:adr + w * h * c], dtype=np.float32).reshape(h, w, c) / 255.0
            if kind[0] == "grey":
                arr = np.maximum(raw[..., :1], kind[1])
            else:
                arr = raw[..., :3].copy()
                arr[..., 1] = 1.0 - arr[..., 1]
            self._textures[key] = self._mi.Bitmap(np.ascontiguousarray(arr, dtype=np.float32))
        return self._textures[key]

    def _texels(self, tex: int) -> np.ndarray:
        """Texture ``tex`` as linear RGB floats (H, W, 3)."""
        m = self.model
        w, h, c = int(m.tex_width[tex]), int(m.tex_height[tex]), int(m.tex_nchannel[tex])
        adr = int(m.tex_adr[tex])
        raw = np.asarray(m.tex_data[adr:adr + w * h * c], dtype=np.float64).reshape(-1, w, c)[..., :3]
        if c == 1:
            raw = np.repeat(raw, 3, axis=-1)
        return srgb_to_linear(raw / 255.0)

    def _bitmap(self, tex: int, colour: np.ndarray):
        """A Mitsuba bitmap of 2D texture ``tex`` tinted by linear ``colour`` (cached per texture and tint)."""
        key = (tex, *np.round(colour, 6).tolist())
        if key not in self._textures:
            self._textures[key] = self._mi.Bitmap((self._texels(tex) * colour).astype(np.float32))
        return self._textures[key]

    def close(self) -> None:
        self._textures.clear()
        self._bsdfs.clear()
        self._loaded = self._sensor = self._sensor_params = self._calls = None

    def __enter__(self) -> "PbrRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
