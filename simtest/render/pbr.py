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
* camera: a ``perspective`` sensor with the exact OpenCV intrinsics (fov from fx, principal point offset from
  cx, cy; OpenCV pixel centres at integer coordinates), box pixel filter.

Mitsuba and ``pyoidn`` are the optional extra ``simtest[pbr]``, imported on first use. The Mitsuba variant is
``render.pbr_variant`` (:func:`simtest.render.llvm.choose_variant`; ``auto``: ``cuda_ad_rgb`` with a CUDA
device, else ``llvm_ad_rgb`` with a libLLVM >= 16, else ``scalar_rgb``). A fixed scene, sample count, seed and
variant give the same image on one machine (on ``llvm_ad_rgb`` also with any thread count).
"""

from __future__ import annotations

import hashlib
import importlib
import os
from typing import Any

import numpy as np

import simtest  # noqa: F401  (GL backend before mujoco)
import mujoco

from simtest.camera import CameraModel
from simtest.render.colour import linear_to_srgb8, srgb_to_linear
from simtest.errors import RenderError
from simtest.render.llvm import PBR_VARIANTS, Variant, choose_variant, find_libllvm, point_drjit_at
from simtest.render.rasterizer import Frame, camera_id
from simtest.rng import child_sequence

__all__ = ["PbrRenderer", "require_pbr", "resolved_variant", "frame_seed", "renderer_versions", "auto_spp",
           "INSTALL_HINT", "PBR_VARIANTS"]

INSTALL_HINT = "pip install 'simtest[pbr]'"
#: Radius of the light source that stands in for each MuJoCo spot / point light (metres).
LIGHT_RADIUS = 0.08
#: Point spots that stand in for each MuJoCo spot light, spread over a disk of radius LIGHT_RADIUS.
SPOT_SAMPLES = 8
#: Half size of a MuJoCo plane whose size is 0 ("infinite"), metres.
INFINITE_PLANE = 50.0
#: Longest light path of the path tracer (3: direct light plus one indirect bounce, which carries most of the
#: interreflection in these rooms at a fraction of the cost of more bounces).
MAX_DEPTH = 3
#: Samples per pixel of the albedo / normal guide pass: its samples are jittered within the pixel, so one gives
#: noisy rather than aliased edges, which the denoiser prefilters.
AUX_SPP = 1
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
    :func:`choose_variant`): the extra is installed, the variant is available and ``fx == fy``. A fallback of
    ``auto`` is logged here (once per run).

    Raises:
        RenderError: Naming ``pip install 'simtest[pbr]'`` when Mitsuba or pyoidn is missing, naming the library
            to install when an explicit ``cuda`` / ``llvm`` is unavailable, or naming the focal lengths when the
            pixels are not square.
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
    ``round(16 * sqrt(320 * 240 / pixels))`` clamped to [8, 16], i.e. 16 at 320x240 and below, 8 at 640x480 and
    above (the knees of PSNR against cost measured at those sizes: more pixels give the denoiser more to work
    with, so fewer samples reach the same quality)."""
    return int(np.clip(round(16.0 * np.sqrt(320 * 240 / max(1, int(width) * int(height)))), 8, 16))


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


def _transform(mi, R: np.ndarray, t: np.ndarray, scale: np.ndarray | None = None):
    """Mitsuba 4x4 transform ``[R diag(scale) | t]``."""
    M = np.eye(4)
    M[:3, :3] = R if scale is None else R @ np.diag(scale)
    M[:3, 3] = t
    return mi.ScalarTransform4f(M.tolist())


def _mesh(mi, name: str, verts: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None,
          uv: np.ndarray | None = None):
    """A Mitsuba triangle mesh from arrays (world coordinates)."""
    mesh = mi.Mesh(name, len(verts), len(faces), has_vertex_normals=normals is not None,
                   has_vertex_texcoords=uv is not None)
    params = mi.traverse(mesh)
    params["vertex_positions"] = np.ascontiguousarray(verts, dtype=np.float32).ravel()
    params["faces"] = np.ascontiguousarray(faces, dtype=np.uint32).ravel()
    if normals is not None:
        params["vertex_normals"] = np.ascontiguousarray(normals, dtype=np.float32).ravel()
    if uv is not None:
        params["vertex_texcoords"] = np.ascontiguousarray(uv, dtype=np.float32).ravel()
    params.update()
    return mesh


def _box_arrays(half: np.ndarray, repeat: np.ndarray, top_only: bool = False):
    """Vertices, faces, normals and uv of a box with half sizes ``half`` (metres); ``top_only``: its +z face
    alone (a plane). Each face carries the texture ``repeat`` times across it (MuJoCo's 2D mapping with
    ``texuniform`` off)."""
    sides = [(2, 1.0)] if top_only else [(a, s) for a in range(3) for s in (1.0, -1.0)]
    verts, faces, normals, uvs = [], [], [], []
    for n_ax, sign in sides:
        # (u, v, n) right-handed, so the corners below run counter-clockwise seen from outside.
        u_ax, v_ax = ((n_ax + 1) % 3, (n_ax + 2) % 3) if sign > 0 else ((n_ax + 2) % 3, (n_ax + 1) % 3)
        base = len(verts)
        for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
            p = np.zeros(3)
            p[n_ax], p[u_ax], p[v_ax] = sign * half[n_ax], su * half[u_ax], sv * half[v_ax]
            verts.append(p)
            normals.append(np.eye(3)[n_ax] * sign)
            uvs.append([(su + 1) / 2 * repeat[0], (sv + 1) / 2 * repeat[1]])
        faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
    return np.array(verts), np.array(faces), np.array(normals), np.array(uvs)


def _sphere_arrays(n_lat: int = 24, n_lon: int = 48) -> tuple[np.ndarray, np.ndarray]:
    """Unit sphere: vertices (= normals) and faces of a latitude-longitude tessellation."""
    th = np.linspace(0.0, np.pi, n_lat + 1)
    ph = np.linspace(0.0, 2 * np.pi, n_lon + 1)
    T, P = np.meshgrid(th, ph, indexing="ij")
    verts = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], axis=-1).reshape(-1, 3)
    idx = np.arange((n_lat + 1) * (n_lon + 1)).reshape(n_lat + 1, n_lon + 1)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return verts, faces


def camera_sensor(mi, camera: CameraModel, spp: int) -> dict:
    """A Mitsuba ``perspective`` sensor with ``camera``'s exact intrinsics and pose.

    OpenCV pixel ``u`` is centred at integer ``u``; Mitsuba's film pixel ``i`` covers ``[i, i + 1)``, so the
    principal point sits at ``cx + 0.5`` film units and its offset from the film centre, as a fraction of the
    film, is ``(cx + 0.5 - W / 2) / W`` (Mitsuba's x axis points left, hence the sign).

    Raises:
        RenderError: If ``fx != fy`` (Mitsuba's perspective sensor has square pixels).
    """
    K, w, h = camera.K, camera.width, camera.height
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if abs(fx - fy) > 1e-9 * fx:
        raise RenderError(f"the 'pbr' render profile needs square pixels: camera fx={fx!r} and fy={fy!r} differ; "
                          f"set camera.fy equal to camera.fx")
    T = camera.T_world_cam
    return {
        "type": "perspective", "fov_axis": "x", "fov": float(np.degrees(2.0 * np.arctan(w / (2.0 * fx)))),
        "principal_point_offset_x": float(-(cx + 0.5 - w / 2.0) / w),
        "principal_point_offset_y": float(-(cy + 0.5 - h / 2.0) / h),
        "near_clip": 0.001, "far_clip": 100.0,
        "to_world": _transform(mi, T.R @ _R_CV_MI, T.t),
        "film": {"type": "hdrfilm", "width": w, "height": h, "pixel_format": "rgb", "rfilter": {"type": "box"}},
        "sampler": {"type": "independent", "sample_count": int(spp)},
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

    Views of one scene whose geometry, materials and lights are unchanged reuse the loaded Mitsuba scene with
    only the sensor changed (the same bytes as loading it again).

    Raises:
        RenderError: If the ``pbr`` extra is not installed (the message names it), ``spp`` is invalid, an
            explicit ``variant`` is unavailable, or ``fx != fy``.
    """

    def __init__(self, model: mujoco.MjModel, camera: CameraModel, spp: int | str = 16, denoise: bool = True,
                 geomgroups: tuple[int, ...] = (0, 1, 2), threads: int | None = None,
                 variant: str = "auto") -> None:
        spp = auto_spp(camera.width, camera.height) if spp == "auto" else spp
        if isinstance(spp, bool) or not isinstance(spp, (int, np.integer)) or int(spp) < 1:
            raise RenderError(f"samples per pixel must be an integer >= 1 or 'auto', got {spp!r}")
        self._mi, self._oidn, self._variant = _modules(variant)
        if threads is not None:
            import drjit

            drjit.set_thread_count(max(1, int(threads)))
            # the denoiser's pool, read when its device is made (first denoise of the process); same bytes
            os.environ["OIDN_NUM_THREADS"] = str(max(1, int(threads)))
        self.model, self.camera = model, camera
        self.spp, self.denoise = int(spp), bool(denoise)
        camera_sensor(self._mi, camera, self.spp)  # fail early on unsupported intrinsics
        self._groups = frozenset(int(g) for g in geomgroups)
        self._textures: dict[tuple, Any] = {}
        self._aux = None
        self._loaded: tuple[bytes, Any] | None = None  # (scene key, loaded Mitsuba scene)

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
        ``cam_xmat`` as they are). ``seed`` seeds the sampler (uint32). Returns a Frame with rgb only."""
        mi = self._mi
        if mi.variant() != self._variant.name:  # another renderer of this process chose another variant
            mi.set_variant(self._variant.name)
        cid = self._camera_id(camera)
        cam = CameraModel.from_mujoco(data.cam_xpos[cid], data.cam_xmat[cid], self.camera.K, self.width,
                                      self.height)
        key = self._scene_key(data)
        if self._loaded is None or self._loaded[0] != key:
            self._loaded = None  # free the previous scene first
            self._loaded = (key, mi.load_dict(self._scene_dict(data, cam)))
        scene = self._loaded[1]
        sensor = mi.load_dict(camera_sensor(mi, cam, self.spp))
        seed = int(seed) & 0xFFFFFFFF
        color = np.maximum(_finite(mi.render(scene, sensor=sensor, seed=seed, spp=self.spp)), 0.0)
        if self.denoise:
            # The guides come from a second, cheaper pass: Mitsuba's aov integrator costs ~2.5x a path sample.
            if self._aux is None:
                self._aux = mi.load_dict({"type": "aov", "aovs": "albedo:albedo,nn:sh_normal"})
            aux = _finite(mi.render(scene, sensor=sensor, integrator=self._aux, seed=seed,
                                    spp=min(self.spp, AUX_SPP)))
            color = self._oidn.denoise(color, np.ascontiguousarray(np.clip(aux[..., 0:3], 0.0, 1.0)),
                                       np.ascontiguousarray(np.clip(aux[..., 3:6], -1.0, 1.0)), hdr=True)
        return Frame(linear_to_srgb8(color), None, None)

    def _scene_key(self, data: mujoco.MjData) -> bytes:
        """A digest of everything :meth:`_scene_dict` reads apart from the camera: equal keys, equal scenes."""
        m = self.model
        h = hashlib.blake2b(digest_size=16)
        for a in (data.geom_xpos, data.geom_xmat, data.light_xpos, data.light_xdir, m.geom_rgba, m.geom_group,
                  m.geom_matid, m.geom_type, m.geom_size, m.geom_dataid, m.mat_rgba, m.mat_specular,
                  m.mat_shininess, m.mat_reflectance, m.mat_texrepeat, m.mat_texid, m.light_active, m.light_type,
                  m.light_ambient, m.light_diffuse, m.light_cutoff, m.light_exponent, m.vis.headlight.ambient,
                  m.stat.center, m.tex_data):
            h.update(np.ascontiguousarray(a).tobytes())
        return h.digest()

    def _camera_id(self, camera: int | str) -> int:
        return camera_id(self.model, camera)

    def _scene_dict(self, data: mujoco.MjData, cam: CameraModel) -> dict:
        mi = self._mi
        scene: dict[str, Any] = {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": MAX_DEPTH, "hide_emitters": True},
            "sensor": camera_sensor(mi, cam, self.spp),
        }
        m = self.model
        for g in range(m.ngeom):
            rgba = _geom_rgba(m, g)
            if int(m.geom_group[g]) not in self._groups or rgba[3] <= 0.0:
                continue
            bsdf = self._bsdf(g, rgba)
            for k, shape in enumerate(self._geom_shapes(data, g, bsdf)):
                scene[f"geom_{g}_{k}"] = shape
        scene.update(self._emitters(data))
        return scene

    # --- materials ----------------------------------------------------------------------------------------
    def _bsdf(self, g: int, rgba: np.ndarray):
        """Two-sided principled BSDF of geom ``g``: base colour (texture x rgba, sRGB read as linear radiance
        reflectance), roughness = 1 - shininess, specular, metallic = reflectance (MuJoCo defaults without a
        material: specular 0.5, shininess 0.5, reflectance 0)."""
        m, mi = self.model, self._mi
        mat = int(m.geom_matid[g])
        spec, shin, refl = (m.mat_specular[mat], m.mat_shininess[mat], m.mat_reflectance[mat]) if mat >= 0 \
            else (0.5, 0.5, 0.0)
        tex = int(m.mat_texid[mat, int(mujoco.mjtTextureRole.mjTEXROLE_RGB)]) if mat >= 0 else -1
        colour = srgb_to_linear(rgba[:3])
        if tex >= 0 and int(m.tex_type[tex]) == int(mujoco.mjtTexture.mjTEXTURE_2D):
            base = {"type": "bitmap", "bitmap": self._bitmap(tex, colour), "wrap_mode": "repeat",
                    "filter_type": "bilinear", "raw": True}
        else:
            if tex >= 0:  # cube / skybox textures: their mean colour
                colour = colour * self._texels(tex).reshape(-1, 3).mean(axis=0)
            base = {"type": "rgb", "value": colour.tolist()}
        return mi.load_dict({"type": "twosided", "bsdf": {
            "type": "principled", "base_color": base, "roughness": float(np.clip(1.0 - shin, 0.05, 1.0)),
            "specular": float(np.clip(spec, 0.0, 1.0)), "metallic": float(np.clip(refl, 0.0, 1.0))}})

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

    # --- geometry -----------------------------------------------------------------------------------------
    def _geom_shapes(self, data: mujoco.MjData, g: int, bsdf) -> list:
        """Mitsuba shapes (dicts or meshes) of geom ``g`` at its world pose in ``data``."""
        m, mi = self.model, self._mi
        R, t = data.geom_xmat[g].reshape(3, 3).astype(np.float64), data.geom_xpos[g].astype(np.float64)
        size, gtype = m.geom_size[g].astype(np.float64), int(m.geom_type[g])
        name = f"geom_{g}"
        if gtype == _G.mjGEOM_MESH:
            return [self._mesh_geom(int(m.geom_dataid[g]), R, t, name, bsdf)]
        if gtype in (_G.mjGEOM_BOX, _G.mjGEOM_PLANE):
            mat = int(m.geom_matid[g])
            repeat = m.mat_texrepeat[mat].astype(np.float64) if mat >= 0 else np.ones(2)
            half = size.copy()
            if gtype == _G.mjGEOM_PLANE:
                half[:2] = np.where(half[:2] > 0, half[:2], INFINITE_PLANE)
            v, f, n, uv = _box_arrays(half, repeat, top_only=gtype == _G.mjGEOM_PLANE)
            return [self._with_bsdf(_mesh(mi, name, v @ R.T + t, f, n @ R.T, uv), bsdf)]
        if gtype == _G.mjGEOM_SPHERE:
            return [{"type": "sphere", "center": t.tolist(), "radius": float(size[0]), "bsdf": bsdf}]
        if gtype == _G.mjGEOM_ELLIPSOID:
            v, f = _sphere_arrays()
            n = v / size
            n /= np.linalg.norm(n, axis=1, keepdims=True)
            return [self._with_bsdf(_mesh(mi, name, (v * size) @ R.T + t, f, n @ R.T), bsdf)]
        if gtype in (_G.mjGEOM_CYLINDER, _G.mjGEOM_CAPSULE):
            r, hh = float(size[0]), float(size[1])
            shapes = [{"type": "cylinder", "p0": [0.0, 0.0, -hh], "p1": [0.0, 0.0, hh], "radius": r,
                       "to_world": _transform(mi, R, t), "bsdf": bsdf}]
            for s in (1.0, -1.0):
                end = t + s * hh * R[:, 2]
                if gtype == _G.mjGEOM_CAPSULE:
                    shapes.append({"type": "sphere", "center": end.tolist(), "radius": r, "bsdf": bsdf})
                else:  # a cap disk facing outward
                    Rc = R if s > 0 else R @ np.diag([1.0, -1.0, -1.0])
                    shapes.append({"type": "disk", "to_world": _transform(mi, Rc, end, np.array([r, r, 1.0])),
                                   "bsdf": bsdf})
            return shapes
        return []  # heightfields, SDFs, lines: not drawn by the path tracer

    def _with_bsdf(self, mesh, bsdf):
        mesh.set_bsdf(bsdf)
        return mesh

    def _mesh_geom(self, mesh_id: int, R: np.ndarray, t: np.ndarray, name: str, bsdf):
        """Mesh ``mesh_id`` in the world, with MuJoCo's per-corner normals and texture coordinates (unshared
        corners)."""
        m = self.model
        va, fa, na = int(m.mesh_vertadr[mesh_id]), int(m.mesh_faceadr[mesh_id]), int(m.mesh_normaladr[mesh_id])
        fn = int(m.mesh_facenum[mesh_id])
        verts = m.mesh_vert[va:va + int(m.mesh_vertnum[mesh_id])].astype(np.float64)
        normals = m.mesh_normal[na:na + int(m.mesh_normalnum[mesh_id])].astype(np.float64)
        faces = m.mesh_face[fa:fa + fn]
        corner_v = verts[faces].reshape(-1, 3) @ R.T + t
        corner_n = normals[m.mesh_facenormal[fa:fa + fn]].reshape(-1, 3) @ R.T
        tris = np.arange(3 * fn, dtype=np.uint32).reshape(-1, 3)
        uv = None
        if int(m.mesh_texcoordnum[mesh_id]) > 0:
            ta = int(m.mesh_texcoordadr[mesh_id])
            texcoords = m.mesh_texcoord[ta:ta + int(m.mesh_texcoordnum[mesh_id])].astype(np.float64)
            uv = texcoords[m.mesh_facetexcoord[fa:fa + fn]].reshape(-1, 2)  # same (u, v) convention as Mitsuba
        return self._with_bsdf(_mesh(self._mi, name, corner_v, tris, corner_n, uv), bsdf)

    # --- lights -------------------------------------------------------------------------------------------
    def _emitters(self, data: mujoco.MjData) -> dict:
        """The constant environment (MuJoCo's ambient) and the emitters of every active light.

        MuJoCo's light colours, like its material colours, are display (sRGB) values: they are linearized, so
        a surface lit by them keeps about the brightness the rasterizer gives it. Each light is calibrated at
        its distance ``d`` to ``model.stat.center``: there its irradiance is ``pi D`` (D the linearized
        ``diffuse``), so a white Lambertian surface facing it reflects radiance ``D``, as MuJoCo's unattenuated
        light does. A spot light becomes ``SPOT_SAMPLES`` spots spread over a disk of radius ``LIGHT_RADIUS``
        across its axis (soft shadows) with MuJoCo's cutoff and a beam width where ``cos^exponent`` halves; a
        point light becomes a sphere of that radius; a directional light stays directional.
        """
        m = self.model
        ambient = np.asarray(m.vis.headlight.ambient, dtype=np.float64).copy()
        out: dict[str, Any] = {}
        centre = np.asarray(m.stat.center, dtype=np.float64)
        for i in range(m.nlight):
            if not m.light_active[i]:
                continue
            ambient += m.light_ambient[i]
            diffuse = srgb_to_linear(m.light_diffuse[i])
            pos = np.asarray(data.light_xpos[i], dtype=np.float64)
            axis = np.asarray(data.light_xdir[i], dtype=np.float64)
            d2 = max(float(np.sum((pos - centre) ** 2)), LIGHT_RADIUS ** 2)
            kind = int(m.light_type[i])
            if kind == int(mujoco.mjtLightType.mjLIGHT_DIRECTIONAL):
                out[f"light_{i}"] = {"type": "directional", "direction": axis.tolist(),
                                     "irradiance": {"type": "rgb", "value": (np.pi * diffuse).tolist()}}
            elif kind == int(mujoco.mjtLightType.mjLIGHT_SPOT):
                out.update(self._spot(i, pos, axis, np.pi * diffuse * d2))
            else:
                out[f"light_{i}"] = {"type": "sphere", "center": pos.tolist(), "radius": LIGHT_RADIUS,
                                     "emitter": {"type": "area", "radiance": {
                                         "type": "rgb", "value": (diffuse * d2 / LIGHT_RADIUS ** 2).tolist()}}}
        out["environment"] = {"type": "constant",
                              "radiance": {"type": "rgb", "value": srgb_to_linear(ambient).tolist()}}
        return out

    def _spot(self, i: int, pos: np.ndarray, axis: np.ndarray, intensity: np.ndarray) -> dict:
        """Light ``i`` as ``SPOT_SAMPLES`` Mitsuba spots (total on-axis ``intensity``, W/sr) on a Vogel disk."""
        m = self.model
        cutoff = float(np.clip(m.light_cutoff[i], 1.0, 89.0))
        exponent = float(m.light_exponent[i])
        half = float(np.degrees(np.arccos(0.5 ** (1.0 / exponent)))) if exponent > 0 else cutoff
        beam = min(half, 0.95 * cutoff)
        axis = axis / max(np.linalg.norm(axis), 1e-12)
        u = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[2]) < 0.9 else [1.0, 0.0, 0.0])
        u /= np.linalg.norm(u)
        v = np.cross(axis, u)
        out = {}
        for k in range(SPOT_SAMPLES):
            r = LIGHT_RADIUS * np.sqrt((k + 0.5) / SPOT_SAMPLES)
            a = k * np.pi * (3.0 - np.sqrt(5.0))  # golden angle
            p = pos + r * (np.cos(a) * u + np.sin(a) * v)
            out[f"light_{i}_{k}"] = {
                "type": "spot", "cutoff_angle": cutoff, "beam_width": beam,
                "to_world": self._mi.ScalarTransform4f().look_at(origin=p.tolist(), target=(p + axis).tolist(),
                                                                 up=u.tolist()),
                "intensity": {"type": "rgb", "value": (intensity / SPOT_SAMPLES).tolist()}}
        return out

    def close(self) -> None:
        self._textures.clear()

    def __enter__(self) -> "PbrRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
