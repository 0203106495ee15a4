"""simtest's ``pbr`` profile against Blender Cycles: the same scene, the same views, equal samples per pixel.

Two halves, so that Blender never enters simtest's environment:

``export`` (simtest's venv) builds settled scenes exactly as ``simtest generate --profile pbr`` does (built-in
objects, 10 per scene, the default looks), renders their views with :class:`simtest.render.pbr.PbrRenderer`
(timing each), and writes to a folder what Cycles needs to draw the same pictures: the geometry the path tracer
builds (``PbrRenderer._scene_dict``: every shape as a triangle mesh in world coordinates, per-corner normals and
texture coordinates), each BSDF's parameters and texture arrays as loaded into Mitsuba, the emitters, the
environment map and the cameras::

    python docs/cycles_comparison.py export /work/data/cycles/run --scenes 2 --views 4

``render`` (a venv with the ``bpy`` wheel, Blender 5.0.1 on Python 3.11) imports that folder into a fresh
Blender scene per simulated scene, renders every view with Cycles on the CPU under each setting of
:data:`SETTINGS`, times each frame and writes the summary (``summary.json``) and a side-by-side figure::

    python3.11 -m venv /work/bpyenv && /work/bpyenv/bin/pip install bpy==5.0.1 numpy
    /work/bpyenv/bin/python docs/cycles_comparison.py render /work/data/cycles/run \\
        --figure docs/images/cycles_comparison.jpg

Units: lengths in metres, angles in degrees where named ``*_deg``, times in wall seconds, radiometry as in
:mod:`simtest.render.pbr` (linear sRGB-primaries RGB; radiance W m^-2 sr^-1, irradiance W m^-2, intensity
W sr^-1). The first view of each scene is a warm-up on both sides (scene load, kernel compile / BVH build) and
is not counted; every other view is one timed frame.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

#: Cycles settings rendered for each view. ``simtest``: equal to simtest's pbr at 640x480 (8 spp, no adaptive
#: sampling, Mitsuba ``max_depth = 3`` = direct light plus one indirect bounce = Cycles ``max_bounces = 1``);
#: ``blenderproc``: BlenderProc's renderer defaults with its BOP recipes' 50 samples (adaptive threshold 0.01,
#: bounces: diffuse 3, glossy 0, transmission 0, transparent 8, volume 0, total 3).
SETTINGS: dict[str, dict[str, Any]] = {
    "simtest": {"samples": 8, "adaptive": None, "max": 1, "diffuse": 1, "glossy": 1, "transmission": 1,
                "transparent": 8, "volume": 0},
    "blenderproc": {"samples": 50, "adaptive": 0.01, "max": 3, "diffuse": 3, "glossy": 0, "transmission": 0,
                    "transparent": 8, "volume": 0},
}
#: Tessellation of the path tracer's analytic shapes (spheres, cylinders, disks) for Cycles: segments around.
RING = 64


@functools.lru_cache(maxsize=1)
def _colour():
    """simtest's sRGB transfer function (``simtest/render/colour.py``, numpy only), loaded by its path: the bpy
    venv has no simtest installed, and the conversion must be the one the renderer uses."""
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "simtest" / "render" / "colour.py"
    spec = importlib.util.spec_from_file_location("simtest_colour", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _commit(root: Path) -> str:
    """The checkout's git commit (with ``+dirty`` when it has changes), or ``unknown``."""
    import subprocess

    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, check=True).stdout.strip()
        return head + ("+dirty" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _loadavg() -> list[float]:
    """The 1, 5 and 15 minute load averages (runnable processes)."""
    return [round(v, 2) for v in os.getloadavg()]


# ----------------------------------------------------------------------------------------------------------------
# export: simtest's venv
# ----------------------------------------------------------------------------------------------------------------

def _sphere(center: np.ndarray, radius: float) -> dict[str, np.ndarray]:
    """Mitsuba's ``sphere`` (metres) as a triangle mesh with exact normals and its texture coordinates
    ``(phi / 2 pi, theta / pi)`` (azimuth from local +x, polar angle from local +z)."""
    n_lat, n_lon = RING // 2, RING
    th, ph = np.meshgrid(np.linspace(0.0, np.pi, n_lat + 1), np.linspace(0.0, 2.0 * np.pi, n_lon + 1), indexing="ij")
    n = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1).reshape(-1, 3)
    uv = np.stack([ph / (2.0 * np.pi), th / np.pi], -1).reshape(-1, 2)
    return {"v": n * radius + center, "n": n, "uv": uv, "f": _grid_faces(n_lat, n_lon)}


def _grid_faces(rows: int, cols: int) -> np.ndarray:
    """Triangles of a (rows + 1) x (cols + 1) vertex grid (row-major)."""
    idx = np.arange((rows + 1) * (cols + 1)).reshape(rows + 1, cols + 1)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    return np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])


def _cylinder(M: np.ndarray, p0: np.ndarray, p1: np.ndarray, radius: float) -> dict[str, np.ndarray]:
    """Mitsuba's ``cylinder`` (an open tube from local ``p0`` to ``p1`` on the z axis, no caps) under 4x4 ``M``,
    with its texture coordinates ``(phi / 2 pi, distance from p0 / length)``."""
    # rows: along the axis (fraction of the length), columns: around it
    z, ph = np.meshgrid(np.linspace(0.0, 1.0, 2), np.linspace(0.0, 2.0 * np.pi, RING + 1), indexing="ij")
    ring = np.stack([np.cos(ph), np.sin(ph), np.zeros_like(ph)], -1)
    local = ring * radius + np.stack([np.zeros_like(z), np.zeros_like(z), p0[2] + z * (p1[2] - p0[2])], -1)
    uv = np.stack([ph / (2.0 * np.pi), z], -1)
    return {"v": local.reshape(-1, 3) @ M[:3, :3].T + M[:3, 3], "n": ring.reshape(-1, 3) @ M[:3, :3].T,
            "uv": uv.reshape(-1, 2), "f": _grid_faces(1, RING)}


def _disk(M: np.ndarray) -> dict[str, np.ndarray]:
    """Mitsuba's ``disk`` (unit disk in local z = 0, normal +z) under 4x4 ``M``, with its polar texture
    coordinates ``(r, phi / 2 pi)``."""
    rings = 8
    r, ph = np.meshgrid(np.linspace(0.0, 1.0, rings + 1), np.linspace(0.0, 2.0 * np.pi, RING + 1), indexing="ij")
    local = np.stack([r * np.cos(ph), r * np.sin(ph), np.zeros_like(r)], -1).reshape(-1, 3)
    normal = M[:3, 2] / np.linalg.norm(M[:3, 2])
    uv = np.stack([r, ph / (2.0 * np.pi)], -1).reshape(-1, 2)
    return {"v": local @ M[:3, :3].T + M[:3, 3], "n": np.tile(normal, (len(local), 1)), "uv": uv,
            "f": _grid_faces(rings, RING)}


def _rectangle(M: np.ndarray) -> dict[str, np.ndarray]:
    """Mitsuba's ``rectangle`` ([-1, 1]^2 in local z = 0, normal +z, faces wound counter-clockwise about it)."""
    v = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    normal = M[:3, 2] / np.linalg.norm(M[:3, 2])
    return {"v": v @ M[:3, :3].T + M[:3, 3], "n": np.tile(normal, (4, 1)), "f": np.array([[0, 1, 2], [0, 2, 3]])}


def _matrix(transform) -> np.ndarray:
    """A Mitsuba ScalarTransform4f as a 4x4 numpy array."""
    return np.array(transform.matrix, dtype=np.float64).reshape(4, 4)


def _mesh_arrays(mi, mesh) -> dict[str, np.ndarray]:
    """Vertices, normals, uv (when present) and faces of a loaded Mitsuba mesh (world coordinates)."""
    p = mi.traverse(mesh)
    out = {"v": np.array(p["vertex_positions"]).reshape(-1, 3), "f": np.array(p["faces"]).reshape(-1, 3)}
    n = np.array(p["vertex_normals"]) if "vertex_normals" in p else np.zeros(0)
    if n.size:
        out["n"] = n.reshape(-1, 3)
    uv = np.array(p["vertex_texcoords"]) if "vertex_texcoords" in p else np.zeros(0)
    if uv.size:
        out["uv"] = uv.reshape(-1, 2)
    return out


def _wound_with_normals(a: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``a`` with each triangle wound counter-clockwise about its corners' mean normal (Blender takes the
    winding as the front side and flips the shading normal on a back-face hit)."""
    if "n" not in a:
        return a
    v, f = a["v"], np.array(a["f"])
    face_n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    flip = np.einsum("ij,ij->i", face_n, a["n"][f].sum(axis=1)) < 0.0
    f[flip] = f[flip][:, ::-1]
    return {**a, "f": f}


def _shape_arrays(mi, shape) -> dict[str, np.ndarray]:
    """A shape of the path tracer's scene dict (loaded mesh or ``sphere`` / ``cylinder`` / ``disk`` /
    ``rectangle`` dict) as triangle-mesh arrays, wound about its normals."""
    return _wound_with_normals(_raw_shape_arrays(mi, shape))


def _raw_shape_arrays(mi, shape) -> dict[str, np.ndarray]:
    """:func:`_shape_arrays` before the winding."""
    if not isinstance(shape, dict):
        return _mesh_arrays(mi, shape)
    kind = shape["type"]
    if kind == "sphere":
        return _sphere(np.asarray(shape["center"], dtype=np.float64), float(shape["radius"]))
    M = _matrix(shape["to_world"]) if "to_world" in shape else np.eye(4)
    if kind == "cylinder":
        return _cylinder(M, np.asarray(shape["p0"]), np.asarray(shape["p1"]), float(shape["radius"]))
    if kind == "disk":
        return _disk(M)
    if kind == "rectangle":
        return _rectangle(M)
    raise ValueError(f"shape type {kind!r} is not exported")


def _bsdf_record(mi, bsdf, name: str, arrays: dict[str, np.ndarray]) -> dict[str, Any]:
    """The parameters of a loaded ``twosided`` (``normalmap``) ``principled`` BSDF, read back from Mitsuba:
    each of base colour, roughness and metallic as ``{"value": ...}`` or ``{"texture": key}`` (the key of its
    array in ``arrays``: (H, W, C) float32, row 0 at v = 0), specular, and the normal map's key or None."""
    p = mi.traverse(bsdf)
    keys = list(p.keys())

    def find(suffix: str) -> str | None:
        return next((k for k in keys if k.endswith(suffix)), None)

    rec: dict[str, Any] = {}
    for param in ("base_color", "roughness", "metallic"):
        data, value = find(f".{param}.data"), find(f".{param}.value")
        if data is not None:
            key = f"tex_{name}_{param}"
            arrays[key] = np.asarray(np.array(p[data]), dtype=np.float32)
            rec[param] = {"texture": key}
        elif value is not None:
            val = np.array(p[value], dtype=np.float64).ravel()
            rec[param] = {"value": val.tolist() if param == "base_color" else float(val[0])}
        else:
            raise ValueError(f"BSDF {name}: no {param} among {keys}")
        if param == "base_color" and "value" in rec[param] and len(rec[param]["value"]) == 1:
            rec[param]["value"] = rec[param]["value"] * 3
    spec = find(".specular")
    rec["specular"] = float(np.array(p[spec]).ravel()[0]) if spec is not None else 0.5
    nm = next((k for k in keys if k.endswith("normalmap.data")), None)
    rec["normal_map"] = None
    if nm is not None:
        key = f"tex_{name}_normal"
        arrays[key] = np.asarray(np.array(p[nm]), dtype=np.float32)
        rec["normal_map"] = key
    return rec


def _emitter_records(mi, scene_dict: dict) -> tuple[list[dict], dict[str, Any]]:
    """The light emitters (spots, spheres, directional lights; panels are shapes) and the environment of a scene
    dict, in plain numbers."""
    lights: list[dict] = []
    env: dict[str, Any] = {"type": "none"}
    for key, item in scene_dict.items():
        if not isinstance(item, dict):
            continue
        kind = item.get("type")
        if key == "environment":
            if kind == "constant":
                env = {"type": "constant", "radiance": list(map(float, item["radiance"]["value"]))}
            elif kind == "envmap":
                env = {"type": "envmap", "to_world": _matrix(item["to_world"]).tolist()}
        elif kind == "spot":
            M = _matrix(item["to_world"])
            lights.append({"type": "spot", "position": M[:3, 3].tolist(), "direction": M[:3, 2].tolist(),
                           "intensity": list(map(float, item["intensity"]["value"])),
                           "cutoff_deg": float(item["cutoff_angle"]), "beam_deg": float(item["beam_width"])})
        elif kind == "directional":
            lights.append({"type": "directional", "direction": list(map(float, item["direction"])),
                           "irradiance": list(map(float, item["irradiance"]["value"]))})
        elif kind == "sphere" and "emitter" in item:
            lights.append({"type": "sphere", "center": list(map(float, item["center"])),
                           "radius": float(item["radius"]),
                           "radiance": list(map(float, item["emitter"]["radiance"]["value"]))})
    return lights, env


def export(out: Path, scenes: int, views: int, width: int, height: int, spp: int, seed: int,
           overrides: dict[str, Any] | None = None) -> dict:
    """Build ``scenes`` settled scenes as ``simtest generate --profile pbr`` does, render ``views`` views of each
    with the pbr renderer (``spp`` samples per pixel, denoised; view 0 of each scene is the untimed warm-up) and
    write everything :func:`render` needs to ``out``. ``overrides``: further config values (dotted keys, e.g.
    ``{"lights.environment": "constant"}``). Returns the run's record (also ``out/export.json``)."""
    root = Path(__file__).resolve().parents[1]
    sys.path.insert(0, str(root))
    import simtest

    # pyproject.toml maps simtest.generators / objects / envs to top-level folders; serve this checkout's (an
    # editable install of another checkout would otherwise answer for them)
    if (root / "generators").is_dir() and str(root) not in simtest.__path__:
        simtest.__path__.insert(1, str(root))
    from PIL import Image

    from simtest.backend.threads import worker_threads
    from simtest.camera import CameraModel
    from simtest.generators.config import GenerateConfig
    from simtest.generators.pipeline import load_objects, prepare_scene
    from simtest.generators.recorder import pbr_renderer, scene_cameras
    from simtest.render.pbr import MAX_DEPTH, frame_seed, renderer_versions

    cfg = GenerateConfig().replace(**{
        "objects": "builtin", "scenes": scenes, "frames_per_scene": views, "camera.width": width,
        "camera.height": height, "scene.objects_per_scene": [10, 10], "render.profile": "pbr",
        "render.pbr_spp": spp, "seed": seed, **(overrides or {})})
    out.mkdir(parents=True, exist_ok=True)
    record: dict[str, Any] = {
        "width": width, "height": height, "spp": spp, "views_per_scene": views, "seed": seed,
        "config_overrides": overrides or {}, "max_depth": MAX_DEPTH, "sampler": cfg.render.pbr_sampler,
        "guide_spp": min(spp, cfg.render.pbr_guide_spp), "denoise_quality": cfg.render.pbr_denoise_quality,
        "threads": worker_threads(cfg.workers, cfg.ray_address).cores,
        "versions": {**renderer_versions(cfg.render.pbr_variant), "python": platform.python_version(),
                     "simtest_commit": _commit(root)},
        "loadavg_start": _loadavg(), "scenes": []}
    objects = load_objects(cfg)
    for sid in range(scenes):
        t0 = time.perf_counter()
        scene, *_ = prepare_scene(cfg, objects, sid)
        cams = scene_cameras(cfg, scene)[:views]
        settle_s = time.perf_counter() - t0
        renderer = pbr_renderer(cfg, scene)
        folder = out / f"scene_{sid:03d}"
        folder.mkdir(exist_ok=True)
        view_records = []
        for k, (cam, _) in enumerate(cams):
            scene.set_camera(cam)
            before = renderer.stages.copy()
            t = time.perf_counter()
            frame = renderer.render(scene.data, scene.camera_id, seed=frame_seed(cfg.seed, sid, k))
            seconds = time.perf_counter() - t
            stages = renderer.stages.since(before).seconds
            Image.fromarray(frame.rgb).save(folder / f"simtest_{k}.png")
            cid = scene.camera_id
            drawn = CameraModel.from_mujoco(scene.data.cam_xpos[cid], scene.data.cam_xmat[cid], renderer.camera.K,
                                            width, height)
            view_records.append({
                "view": k, "warmup": k == 0, "K": drawn.K.tolist(), "R_world_cam": drawn.T_world_cam.R.tolist(),
                "t_world_cam": drawn.T_world_cam.t.tolist(), "simtest_png": f"simtest_{k}.png",
                "simtest_seconds": seconds, "simtest_stages": {s: round(v, 4) for s, v in stages.items()}})
            print(f"scene {sid} view {k}: simtest {seconds:.2f} s" + (" (warm-up)" if k == 0 else ""), flush=True)
        # the scene as the path tracer builds it (the one its views were rendered from)
        t = time.perf_counter()
        mi = renderer._mi
        sd = renderer._scene_dict(scene.data, CameraModel.from_mujoco(
            scene.data.cam_xpos[scene.camera_id], scene.data.cam_xmat[scene.camera_id], renderer.camera.K,
            width, height))
        arrays: dict[str, np.ndarray] = {}
        materials: dict[str, dict] = {}
        material_of: dict[tuple, str] = {}  # the renderer's BSDF cache key (material id, rgba bytes) -> name
        for key, bsdf in renderer._bsdfs.items():
            name = f"m{len(materials)}"
            material_of[key] = name
            materials[name] = _bsdf_record(mi, bsdf, name, arrays)
        m = scene.model
        from simtest.render.pbr import _geom_rgba  # the colour key the renderer's BSDF cache uses

        shapes = []
        for key, item in sd.items():
            if not key.startswith("geom_"):
                continue
            g = int(key.split("_")[1])
            a = _shape_arrays(mi, item)
            i = len(shapes)
            for part, arr in a.items():
                arrays[f"shape{i}_{part}"] = np.asarray(arr, dtype=np.uint32 if part == "f" else np.float32)
            rec: dict[str, Any] = {"name": key, "geom": g, "uv": "uv" in a, "normals": "n" in a}
            if key.endswith("_panel"):
                rec["emission"] = list(map(float, item["emitter"]["radiance"]["value"]))
            else:
                rgba = np.asarray(_geom_rgba(m, g), dtype=np.float64)
                rec["material"] = material_of[(int(m.geom_matid[g]), rgba.tobytes())]
            shapes.append(rec)
        lights, env = _emitter_records(mi, sd)
        if env["type"] == "envmap":
            arrays["environment"] = np.asarray(np.array(sd["environment"]["bitmap"]), dtype=np.float32)
        np.savez(folder / "arrays.npz", **arrays)
        spec = scene.spec.environment
        (folder / "scene.json").write_text(json.dumps({
            "scene": sid, "width": width, "height": height, "shapes": shapes, "materials": materials,
            "lights": lights, "environment": env,
            "environment_spec": None if spec is None else {"kind": spec.kind, "source": spec.source,
                                                           "rotation": spec.rotation, "strength": spec.strength},
            "views": view_records}, indent=1))
        record["scenes"].append({"scene": sid, "folder": folder.name, "settle_seconds": round(settle_s, 2),
                                 "export_seconds": round(time.perf_counter() - t, 2),
                                 "triangles": int(sum(len(arrays[f"shape{i}_f"]) for i in range(len(shapes))))})
        renderer.close()
    timed = [v for s in record["scenes"] for v in
             json.loads((out / s["folder"] / "scene.json").read_text())["views"] if not v["warmup"]]
    record["loadavg_end"] = _loadavg()
    record["simtest_seconds_per_frame"] = float(np.mean([v["simtest_seconds"] for v in timed]))
    (out / "export.json").write_text(json.dumps(record, indent=1))
    print(f"simtest pbr: {record['simtest_seconds_per_frame']:.2f} s/frame over {len(timed)} frames "
          f"({width}x{height}, {spp} spp, denoised); load average {record['loadavg_end']}", flush=True)
    return record


# ----------------------------------------------------------------------------------------------------------------
# render: the bpy venv
# ----------------------------------------------------------------------------------------------------------------

def _image(bpy, name: str, arr: np.ndarray, data: bool):
    """A packed float Blender image of an (H, W, C) array whose row 0 is texture v = 0 (Blender's first pixel
    row is v = 0 too, so rows go in as they are); ``data``: no colour transform (roughness, normals)."""
    arr = np.asarray(arr, dtype=np.float32)
    h, w = arr.shape[:2]
    rgba = np.ones((h, w, 4), dtype=np.float32)
    rgba[..., :3] = arr if arr.shape[2] == 3 else np.repeat(arr[..., :1], 3, axis=2)
    img = bpy.data.images.new(name, w, h, alpha=False, float_buffer=True)
    img.colorspace_settings.name = "Non-Color" if data else "Linear Rec.709"
    img.pixels.foreach_set(rgba.ravel())
    img.pack()  # Cycles reads an image's pixels from its packed copy
    return img


def _texture(bpy, nt, arr: np.ndarray, name: str, data: bool):
    """An image-texture node (bilinear, repeating, the mesh's UV map) of ``arr``."""
    node = nt.nodes.new("ShaderNodeTexImage")
    node.image = _image(bpy, name, arr, data)
    node.interpolation = "Linear"
    node.extension = "REPEAT"
    return node


def _material(bpy, name: str, rec: dict, arrays) -> Any:
    """A Principled BSDF material with the path tracer's parameters: base colour, roughness, metallic (values or
    textures), IOR from Mitsuba's ``specular`` (``eta = 2 / (1 - sqrt(0.08 specular)) - 1``, Specular IOR
    Level left neutral), single-scattering GGX, a tangent-space normal map."""
    mat = bpy.data.materials.new(name)
    nt = mat.node_tree
    bsdf = nt.nodes.get("Principled BSDF")
    if bsdf is None:
        bsdf = nt.nodes.new("ShaderNodeBsdfPrincipled")
        nt.links.new(bsdf.outputs[0], nt.nodes["Material Output"].inputs["Surface"])
    bsdf.distribution = "GGX"
    for param, socket, data in (("base_color", "Base Color", False), ("roughness", "Roughness", True),
                                ("metallic", "Metallic", True)):
        p = rec[param]
        if "texture" in p:
            tex = _texture(bpy, nt, arrays[p["texture"]], f"{name}_{param}", data)
            nt.links.new(tex.outputs["Color"], bsdf.inputs[socket])
        elif param == "base_color":
            bsdf.inputs[socket].default_value = (*p["value"][:3], 1.0)
        else:
            bsdf.inputs[socket].default_value = float(p["value"])
    s = float(np.clip(rec["specular"], 0.0, 1.0))
    bsdf.inputs["IOR"].default_value = 2.0 / (1.0 - np.sqrt(0.08 * s)) - 1.0
    bsdf.inputs["Specular IOR Level"].default_value = 0.5
    if rec["normal_map"] is not None:
        # The path tracer's map already has Mitsuba's tangent frame (x along dp/du, y along n x dp/du, which is
        # dp/dv on these meshes); Blender's tangent space is x along dp/du, y along dp/dv: the same map fits.
        tex = _texture(bpy, nt, arrays[rec["normal_map"]], f"{name}_normal", True)
        nm = nt.nodes.new("ShaderNodeNormalMap")
        nm.space = "TANGENT"
        nm.uv_map = "UVMap"
        nt.links.new(tex.outputs["Color"], nm.inputs["Color"])
        nt.links.new(nm.outputs["Normal"], bsdf.inputs["Normal"])
    return mat


def _emission_material(bpy, name: str, radiance: list[float]) -> Any:
    """A one-sided emitter of ``radiance`` (front face; the back is black), as Mitsuba's ``area`` emitter."""
    mat = bpy.data.materials.new(name)
    nt = mat.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    peak = max(max(radiance), 1e-12)
    em = nt.nodes.new("ShaderNodeEmission")
    em.inputs["Color"].default_value = (*[c / peak for c in radiance], 1.0)
    em.inputs["Strength"].default_value = peak  # Cycles: emitted radiance = colour x strength
    black = nt.nodes.new("ShaderNodeBsdfDiffuse")
    black.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    geo = nt.nodes.new("ShaderNodeNewGeometry")
    mix = nt.nodes.new("ShaderNodeMixShader")
    nt.links.new(geo.outputs["Backfacing"], mix.inputs["Fac"])
    nt.links.new(em.outputs[0], mix.inputs[1])
    nt.links.new(black.outputs[0], mix.inputs[2])
    nt.links.new(mix.outputs[0], out.inputs["Surface"])
    return mat


def _mesh(bpy, name: str, v: np.ndarray, f: np.ndarray, n: np.ndarray | None, uv: np.ndarray | None):
    """A Blender mesh object from world-space arrays: per-vertex normals become custom corner normals."""
    me = bpy.data.meshes.new(name)
    me.vertices.add(len(v))
    me.vertices.foreach_set("co", np.asarray(v, dtype=np.float32).ravel())
    me.loops.add(3 * len(f))
    me.loops.foreach_set("vertex_index", np.asarray(f, dtype=np.int32).ravel())
    me.polygons.add(len(f))
    me.polygons.foreach_set("loop_start", np.arange(0, 3 * len(f), 3, dtype=np.int32))
    me.update()
    if uv is not None:
        layer = me.uv_layers.new(name="UVMap")
        layer.data.foreach_set("uv", np.asarray(uv, dtype=np.float32)[np.asarray(f).ravel()].ravel())
    me.shade_smooth()
    if n is not None:
        nn = np.asarray(n, dtype=np.float64)
        nn /= np.maximum(np.linalg.norm(nn, axis=1, keepdims=True), 1e-12)
        me.normals_split_custom_set_from_vertices(nn.tolist())
    me.validate(clean_customdata=False)
    obj = bpy.data.objects.new(name, me)
    # shadow rays leave from the surface as in Mitsuba (Cycles' default moves them off smooth-shaded low-poly
    # meshes, which lights faces whose geometry faces away from the light)
    obj.cycles.shadow_terminator_geometry_offset = 0.0
    obj.cycles.shadow_terminator_offset = 0.0
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _envmap_pixels(env: np.ndarray, to_world: np.ndarray) -> np.ndarray:
    """The path tracer's environment map resampled (nearest texel) into Blender's equirectangular layout.

    Mitsuba looks up world direction ``d`` at ``l = R^T d`` (``R`` the envmap's ``to_world``), ``u = atan2(l_x,
    -l_z) / 2 pi``, ``v = acos(l_y) / pi`` (row 0 at v = 0). Blender's Environment Texture looks ``d`` up at
    ``u = 1/2 - atan2(d_y, d_x) / 2 pi``, ``v = 1/2 + asin(d_z) / pi`` (its first pixel row at v = 0). With
    simtest's ``R`` each Blender texel centre lands on a Mitsuba texel centre, so this is a permutation."""
    h, w = env.shape[:2]
    u = (np.arange(w) + 0.5) / w
    v = (np.arange(h) + 0.5) / h
    phi = (0.5 - u)[None, :] * 2.0 * np.pi
    elev = (v - 0.5)[:, None] * np.pi
    d = np.stack([np.cos(elev) * np.cos(phi), np.cos(elev) * np.sin(phi), np.sin(elev) * np.ones_like(phi)], -1)
    R = np.asarray(to_world, dtype=np.float64)[:3, :3]
    local = d @ R  # R^T d for each row vector d
    um = (np.arctan2(local[..., 0], -local[..., 2]) / (2.0 * np.pi)) % 1.0
    vm = np.arccos(np.clip(local[..., 1], -1.0, 1.0)) / np.pi
    col = np.minimum((um * w).astype(np.int64), w - 1)
    row = np.minimum((vm * h).astype(np.int64), h - 1)
    return env[row, col]


def _light(bpy, name: str, rec: dict) -> None:
    """A Blender light with the path tracer's emitter's power (Cycles: a point or spot light of power ``P`` W
    has radiant intensity ``P / 4 pi`` W/sr, a spot's cone cutting it off without changing it; a sun's strength
    is its irradiance W/m^2; a point light of radius ``r`` is a sphere of radiance ``P / (4 pi^2 r^2)``).
    Checked on a white Lambertian plane: each gives the radiance ``E / pi`` of its irradiance ``E``."""
    from mathutils import Matrix, Vector

    colour = np.asarray(rec.get("intensity", rec.get("irradiance", rec.get("radiance"))), dtype=np.float64)
    peak = max(float(colour.max()), 1e-12)
    kind = rec["type"]
    if kind == "spot":
        light = bpy.data.lights.new(name, "SPOT")
        light.energy = 4.0 * np.pi * peak
        light.shadow_soft_size = 0.0
        cutoff, beam = np.radians(rec["cutoff_deg"]), np.radians(rec["beam_deg"])
        light.spot_size = 2.0 * cutoff
        # Mitsuba falls off linearly in angle from the beam width to the cutoff, Cycles by a smoothstep in cos
        # over the outer `blend` fraction of (1 - cos cutoff): the transition starts at the same angle.
        light.spot_blend = float(np.clip((np.cos(beam) - np.cos(cutoff)) / (1.0 - np.cos(cutoff)), 0.0, 1.0))
        light.show_cone = False
    elif kind == "sphere":
        light = bpy.data.lights.new(name, "POINT")
        r = float(rec["radius"])
        light.shadow_soft_size = r
        light.energy = 4.0 * np.pi ** 2 * r * r * peak
    elif kind == "directional":
        light = bpy.data.lights.new(name, "SUN")
        light.energy = peak
        light.angle = 0.0
    else:
        raise ValueError(f"light type {kind!r}")
    light.color = tuple(colour / peak)
    obj = bpy.data.objects.new(name, light)
    if kind == "sphere":
        obj.location = rec["center"]
    else:
        direction = Vector(rec["direction"]).normalized()
        obj.matrix_world = direction.to_track_quat("-Z", "Y").to_matrix().to_4x4()
        if kind == "spot":
            obj.matrix_world = Matrix.Translation(Vector(rec["position"])) @ obj.matrix_world
    bpy.context.scene.collection.objects.link(obj)


def _build_scene(bpy, folder: Path) -> tuple[dict, Any]:
    """A fresh Blender scene holding ``folder``'s exported scene (shapes, materials, lights, environment) and a
    camera. Returns ``(scene.json contents, camera object)``."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    meta = json.loads((folder / "scene.json").read_text())
    arrays = np.load(folder / "arrays.npz")
    mats = {name: _material(bpy, name, rec, arrays) for name, rec in meta["materials"].items()}
    for i, s in enumerate(meta["shapes"]):
        obj = _mesh(bpy, s["name"], arrays[f"shape{i}_v"], arrays[f"shape{i}_f"],
                    arrays[f"shape{i}_n"] if s["normals"] else None, arrays[f"shape{i}_uv"] if s["uv"] else None)
        mat = _emission_material(bpy, s["name"] + "_emit", s["emission"]) if "emission" in s else mats[s["material"]]
        obj.data.materials.append(mat)
    for i, rec in enumerate(meta["lights"]):
        _light(bpy, f"light_{i}", rec)
    world = bpy.data.worlds.new("world")
    bpy.context.scene.world = world
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Strength"].default_value = 1.0
    env = meta["environment"]
    if env["type"] == "envmap":
        pix = _envmap_pixels(arrays["environment"], np.asarray(env["to_world"]))
        node = world.node_tree.nodes.new("ShaderNodeTexEnvironment")
        node.image = _image(bpy, "environment", pix, data=False)
        node.interpolation = "Linear"
        world.node_tree.links.new(node.outputs["Color"], bg.inputs["Color"])
    elif env["type"] == "constant":
        bg.inputs["Color"].default_value = (*env["radiance"], 1.0)
    else:
        bg.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    bpy.context.scene.collection.objects.link(cam)
    bpy.context.scene.camera = cam
    return meta, cam


def _place_camera(cam, view: dict, width: int, height: int) -> None:
    """Blender camera with OpenCV ``K`` and pose: horizontal sensor fit, focal length ``fx`` pixels, principal
    point ``(cx + 0.5, cy + 0.5)`` in Blender's pixel coordinates (OpenCV centres pixels on integers) as a shift
    in units of the image width; the camera looks down its -z with +y up (OpenCV: +z, +y down)."""
    from mathutils import Matrix

    K = np.asarray(view["K"], dtype=np.float64)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if abs(fx - fy) > 1e-9 * fx:
        raise ValueError(f"only square pixels are exported to Blender (fx = {fx}, fy = {fy})")
    data = cam.data
    data.type = "PERSP"
    data.sensor_fit = "HORIZONTAL"
    data.sensor_width = 36.0
    data.lens = fx * 36.0 / width
    data.shift_x = (width / 2.0 - (cx + 0.5)) / width
    data.shift_y = ((cy + 0.5) - height / 2.0) / width
    data.clip_start, data.clip_end = 0.001, 100.0
    M = np.eye(4)
    M[:3, :3] = np.asarray(view["R_world_cam"]) @ np.diag([1.0, -1.0, -1.0])
    M[:3, 3] = view["t_world_cam"]
    cam.matrix_world = Matrix(M.tolist())


def _configure(bpy, setting: dict, width: int, height: int, threads: int) -> None:
    """Cycles on the CPU with ``threads`` threads, ``setting``'s samples, adaptive threshold and bounces; box
    pixel filter 1 px wide (Mitsuba's ``box``); no clamping or glossy filter (the path tracer has neither); OIDN
    with albedo and normal guides (prefiltered); camera rays that miss show black (Mitsuba's ``hide_emitters``:
    transparent film, premultiplied colour); BVH and textures kept between the views of a scene."""
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    sc.render.resolution_x, sc.render.resolution_y, sc.render.resolution_percentage = width, height, 100
    sc.render.pixel_aspect_x = sc.render.pixel_aspect_y = 1.0
    sc.render.threads_mode, sc.render.threads = "FIXED", threads
    sc.render.use_persistent_data = True
    sc.render.film_transparent = True
    sc.view_settings.view_transform, sc.view_settings.look = "Standard", "None"
    sc.view_settings.exposure, sc.view_settings.gamma = 0.0, 1.0
    sc.render.image_settings.file_format = "OPEN_EXR"
    sc.render.image_settings.color_depth = "32"
    c = sc.cycles
    c.device = "CPU"
    c.samples = int(setting["samples"])
    c.use_adaptive_sampling = setting["adaptive"] is not None
    if setting["adaptive"] is not None:
        c.adaptive_threshold = float(setting["adaptive"])
        c.adaptive_min_samples = 0  # automatic
    c.max_bounces = setting["max"]
    c.diffuse_bounces, c.glossy_bounces = setting["diffuse"], setting["glossy"]
    c.transmission_bounces, c.transparent_max_bounces = setting["transmission"], setting["transparent"]
    c.volume_bounces = setting["volume"]
    c.sample_clamp_direct = c.sample_clamp_indirect = 0.0
    c.blur_glossy = 0.0
    c.pixel_filter_type, c.filter_width = "BOX", 1.0
    c.seed, c.use_animated_seed = 0, False
    c.use_denoising = True
    c.denoiser = "OPENIMAGEDENOISE"
    c.denoising_input_passes = "RGB_ALBEDO_NORMAL"
    c.denoising_prefilter = "ACCURATE"
    c.denoising_quality = "HIGH"
    c.denoising_use_gpu = False


def _render_view(bpy, folder: Path, name: str) -> tuple[np.ndarray, float]:
    """Render the scene's camera; returns the linear RGB image (H, W, 3) and the frame's wall seconds
    (``bpy.ops.render.render``: scene update, path tracing, denoising; not the file written afterwards)."""
    t0 = time.perf_counter()
    bpy.ops.render.render()
    seconds = time.perf_counter() - t0
    path = folder / f"{name}.exr"
    bpy.data.images["Render Result"].save_render(str(path))
    img = bpy.data.images.load(str(path), check_existing=False)
    px = np.empty(img.size[0] * img.size[1] * 4, dtype=np.float32)
    img.pixels.foreach_get(px)
    w, h = img.size
    bpy.data.images.remove(img)
    path.unlink()
    rgba = px.reshape(h, w, 4)[::-1]
    return np.ascontiguousarray(rgba[..., :3]), seconds


def _figure(left: np.ndarray, right: np.ndarray, out: Path, width: int = 480) -> None:
    """Two (H, W, 3) uint8 sRGB images side by side (simtest | Cycles), each area-averaged down to ``width``
    pixels, as a small JPEG."""
    import bpy

    width = min(width, left.shape[1])
    h = int(round(left.shape[0] * width / left.shape[1]))

    def scaled(a: np.ndarray) -> np.ndarray:
        ys = np.linspace(0, a.shape[0], h + 1).astype(int)
        xs = np.linspace(0, a.shape[1], width + 1).astype(int)
        rows = np.add.reduceat(a.astype(np.float64), ys[:-1], axis=0) / np.diff(ys)[:, None, None]
        return np.add.reduceat(rows, xs[:-1], axis=1) / np.diff(xs)[None, :, None]

    gap = np.full((h, 4, 3), 255.0)
    row = np.concatenate([scaled(left), gap, scaled(right)], axis=1) / 255.0
    _save_bytes_image(bpy, row, out, "JPEG", quality=85)
    print(f"figure: {out} ({out.stat().st_size // 1024} KB; simtest pbr | Cycles)", flush=True)


def _mean(values: list[float]) -> float:
    return round(float(np.mean(values)), 3) if values else float("nan")


def render(folder: Path, threads: int, figure: Path | None, settings: list[str], denoise_split: bool = True) -> dict:
    """Render every exported view with Cycles under each of ``settings`` and write ``folder/summary.json``:
    per setting, Cycles' and simtest's wall seconds per frame over the timed views, their ratio (Cycles over
    simtest), the split of each frame into rendering and denoising, and each view's times and brightness (mean
    linear value of the 8-bit image, Cycles over simtest).

    Cycles reports no denoising time of its own (its progress goes from the last sample to "Finished"), so with
    ``denoise_split`` the last view of each scene is rendered once more without denoising (not counted) and
    the difference of the two is its denoising estimate; simtest's split comes from its stage timers (trace
    and guides: rendering; denoise)."""
    import bpy

    exp = json.loads((folder / "export.json").read_text())
    width, height = exp["width"], exp["height"]
    summary: dict[str, Any] = {
        "image": f"{width}x{height}", "threads": {"cycles": threads, "simtest": exp["threads"]},
        "versions": {"blender": bpy.app.version_string, "blender_build": bpy.app.build_hash.decode(),
                     "python_bpy": platform.python_version(), "simtest": exp["versions"]},
        "machine": {"cores": os.cpu_count(), "processor": platform.processor() or platform.machine()},
        "loadavg": {"export_start": exp["loadavg_start"], "export_end": exp["loadavg_end"],
                    "render_start": _loadavg()},
        "settings": {}}
    shown = None
    for name in settings:
        setting = SETTINGS[name]
        frames: list[dict] = []
        splits: list[float] = []
        for sc_rec in exp["scenes"]:
            sdir = folder / sc_rec["folder"]
            t = time.perf_counter()
            meta, cam = _build_scene(bpy, sdir)
            build_s = time.perf_counter() - t
            _configure(bpy, setting, width, height, threads)
            for view in meta["views"]:
                _place_camera(cam, view, width, height)
                rgb, seconds = _render_view(bpy, sdir, f"cycles_{name}_{view['view']}")
                srgb = _colour().linear_to_srgb8(rgb)
                _write_png(bpy, srgb, sdir / f"cycles_{name}_{view['view']}.png")
                sim = _read_png(bpy, sdir / view["simtest_png"])
                to_linear = _colour().srgb_to_linear
                bright = float(to_linear(srgb / 255.0).mean() / max(to_linear(sim / 255.0).mean(), 1e-9))
                frames.append({"scene": meta["scene"], "view": view["view"], "warmup": view["warmup"],
                               "cycles_seconds": round(seconds, 3),
                               "simtest_seconds": round(view["simtest_seconds"], 3),
                               "simtest_stages": view["simtest_stages"],
                               "brightness_cycles_over_simtest": round(bright, 3)})
                if view["warmup"]:
                    frames[-1]["blender_scene_build_seconds"] = round(build_s, 2)
                print(f"{name}: scene {meta['scene']} view {view['view']}: Cycles {seconds:.2f} s, simtest "
                      f"{view['simtest_seconds']:.2f} s, brightness Cycles / simtest {bright:.2f}"
                      + (" (warm-up)" if view["warmup"] else ""), flush=True)
                if name == "simtest" and shown is None and not view["warmup"]:
                    shown = (sim, srgb)
            if denoise_split and len(meta["views"]) > 1:
                bpy.context.scene.cycles.use_denoising = False
                _, plain = _render_view(bpy, sdir, "no_denoise")
                bpy.context.scene.cycles.use_denoising = True
                splits.append(frames[-1]["cycles_seconds"] - plain)
                frames[-1]["cycles_seconds_without_denoising"] = round(plain, 3)
                print(f"{name}: scene {meta['scene']} view {meta['views'][-1]['view']} without denoising: "
                      f"{plain:.2f} s", flush=True)
        timed = [f for f in frames if not f["warmup"]]
        cyc = _mean([f["cycles_seconds"] for f in timed])
        sim = _mean([f["simtest_seconds"] for f in timed])
        stage = {k: _mean([f["simtest_stages"][k] for f in timed]) for k in ("trace", "guides", "denoise")}
        summary["settings"][name] = {
            "cycles": {"samples": setting["samples"], "adaptive_threshold": setting["adaptive"],
                       "bounces": {k: setting[k] for k in ("max", "diffuse", "glossy", "transmission",
                                                           "transparent", "volume")},
                       "denoiser": "OIDN (albedo + normal, prefilter accurate)"},
            "simtest": {"spp": exp["spp"], "max_depth": exp["max_depth"],
                        "sampler": exp.get("sampler", "independent"),
                        "denoiser": f"OIDN {exp.get('denoise_quality', 'high')} (albedo + normal from a "
                                    f"{exp.get('guide_spp', 1)}-spp guide pass)"},
            "timed_frames": len(timed), "cycles_s_per_frame": cyc, "simtest_s_per_frame": sim,
            "ratio_cycles_over_simtest": round(cyc / sim, 2),
            "cycles_denoise_s_estimate": _mean(splits), "simtest_stages_s_per_frame": stage,
            "cycles_s_per_frame_min_max": [min(f["cycles_seconds"] for f in timed),
                                           max(f["cycles_seconds"] for f in timed)],
            "simtest_s_per_frame_min_max": [min(f["simtest_seconds"] for f in timed),
                                            max(f["simtest_seconds"] for f in timed)],
            "brightness_cycles_over_simtest": _mean([f["brightness_cycles_over_simtest"] for f in frames]),
            "frames": frames}
        print(f"== {name}: Cycles {cyc:.2f} s/frame, simtest {sim:.2f} s/frame, Cycles / simtest = "
              f"{cyc / sim:.2f}", flush=True)
    summary["loadavg"]["render_end"] = _loadavg()
    (folder / "summary.json").write_text(json.dumps(summary, indent=1))
    keys = ("cycles_s_per_frame", "simtest_s_per_frame", "ratio_cycles_over_simtest", "cycles_denoise_s_estimate",
            "simtest_stages_s_per_frame", "brightness_cycles_over_simtest")
    print(json.dumps({"loadavg": summary["loadavg"],
                      **{k: {kk: v[kk] for kk in keys} for k, v in summary["settings"].items()}}, indent=1))
    if figure is not None and shown is not None:
        _figure(shown[0], shown[1], figure)
    return summary


def _write_png(bpy, srgb: np.ndarray, path: Path) -> None:
    """Save an (H, W, 3) uint8 sRGB image (row 0 at the top) as PNG, bytes unchanged."""
    _save_bytes_image(bpy, srgb.astype(np.float64) / 255.0, path, "PNG")


def _save_bytes_image(bpy, srgb: np.ndarray, path: Path, fmt: str, quality: int = 90) -> None:
    """Save sRGB-encoded floats in [0, 1] (H, W, 3), row 0 at the top, through a byte image (its bytes as
    given: ``Image.save`` applies no view transform)."""
    h, w = srgb.shape[:2]
    img = bpy.data.images.new(path.stem, w, h, alpha=False)
    rgba = np.ones((h, w, 4), dtype=np.float32)
    rgba[..., :3] = srgb
    img.pixels.foreach_set(rgba[::-1].ravel())
    img.filepath_raw = str(path)
    img.file_format = fmt
    path.parent.mkdir(parents=True, exist_ok=True)
    img.save(quality=quality)
    bpy.data.images.remove(img)


def _read_png(bpy, path: Path) -> np.ndarray:
    """An 8-bit sRGB PNG as (H, W, 3) uint8, row 0 at the top."""
    img = bpy.data.images.load(str(path), check_existing=False)
    img.colorspace_settings.name = "Non-Color"  # the stored bytes, undecoded
    px = np.empty(img.size[0] * img.size[1] * 4, dtype=np.float32)
    img.pixels.foreach_get(px)
    w, h = img.size
    bpy.data.images.remove(img)
    return np.round(px.reshape(h, w, 4)[::-1, :, :3] * 255.0).astype(np.uint8)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    e = sub.add_parser("export", help="simtest's venv: build, render and time the scenes, write the folder")
    e.add_argument("out", type=Path)
    e.add_argument("--scenes", type=int, default=2)
    e.add_argument("--views", type=int, default=4, help="views per scene, the first a warm-up")
    e.add_argument("--width", type=int, default=640)
    e.add_argument("--height", type=int, default=480)
    e.add_argument("--spp", type=int, default=8)
    e.add_argument("--seed", type=int, default=0)
    e.add_argument("--set", action="append", default=[], metavar="KEY=JSON",
                   help="another config value, e.g. --set lights.environment='\"constant\"' (repeatable)")
    r = sub.add_parser("render", help="the bpy venv: render the exported folder with Cycles, write the summary")
    r.add_argument("folder", type=Path)
    r.add_argument("--threads", type=int, default=2)
    r.add_argument("--figure", type=Path, default=None, help="side-by-side JPEG of the first timed view")
    r.add_argument("--settings", default=",".join(SETTINGS), help=f"comma-separated, of {', '.join(SETTINGS)}")
    r.add_argument("--no-denoise-split", action="store_true",
                   help="skip the extra frame per scene without denoising that estimates Cycles' denoising time")
    args = ap.parse_args(argv)
    if args.cmd == "export":
        overrides = {k: json.loads(v) for k, v in (item.split("=", 1) for item in args.set)}
        export(args.out, args.scenes, args.views, args.width, args.height, args.spp, args.seed, overrides)
    else:
        render(args.folder, args.threads, args.figure, [s for s in args.settings.split(",") if s],
               not args.no_denoise_split)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
