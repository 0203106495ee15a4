"""BOP ``models/`` folders: ``obj_{id:06d}.ply`` in millimetres and ``models_info.json``.

Together with :mod:`simtest.io.bop` this is the only place that converts between metres (used everywhere
in simtest) and the millimetres of the BOP format, through :data:`MM_PER_M`.

Written layout (what the BOP toolkit's ``inout.load_ply`` and ``load_json`` read)::

    models/obj_000001.ply      binary little-endian PLY: x y z nx ny nz (float32, mm), red green blue
                               (uchar) or, for a textured object, texture_u texture_v (float32, v up) with
                               "comment TextureFile obj_000001.png"; faces as "list uchar int vertex_indices"
    models/obj_000001.png      the texture of a textured object (as BOP's textured models)
    models/models_info.json    {"1": {diameter, min_x, min_y, min_z, size_x, size_y, size_z,
                                      symmetries_discrete?: [[16 floats, translation in mm]],
                                      symmetries_continuous?: [{axis: [3], offset: [3] (mm)}]}}
    models/simtest_objects.json  simtest's extra metadata (name, category, instance, density, rgba,
                                 source); the BOP toolkit ignores it

Every file is written atomically (a temporary file in the same folder, then ``os.replace``). Reading a folder
into object models is :func:`simtest.objects.loaders.read_bop_models`, built on the readers here.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import trimesh

from simtest.errors import AssetError
from simtest.io.bop import MM_PER_M
from simtest.io.files import atomic_write_bytes as _atomic_write

__all__ = ["MM_PER_M", "write_bop_models", "find_models_dir", "read_models_info", "read_symmetries",
           "models_info_entry", "INFO_FILE", "META_FILE"]

INFO_FILE = "models_info.json"
META_FILE = "simtest_objects.json"


def ply_bytes(vertices_mm: np.ndarray, faces: np.ndarray, normals: np.ndarray, rgb: np.ndarray | None,
              comment: str = "", uv: np.ndarray | None = None) -> bytes:
    """A binary little-endian PLY (float32 positions in mm and normals, optional uchar colours, optional
    float32 ``texture_u texture_v`` per vertex)."""
    n = len(vertices_mm)
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    if rgb is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    if uv is not None:
        fields += [("texture_u", "<f4"), ("texture_v", "<f4")]
    vert = np.zeros(n, dtype=fields)
    for i, key in enumerate("xyz"):
        vert[key] = vertices_mm[:, i]
        vert["n" + key] = normals[:, i]
    if rgb is not None:
        for i, key in enumerate(("red", "green", "blue")):
            vert[key] = rgb[:, i]
    if uv is not None:
        vert["texture_u"], vert["texture_v"] = uv[:, 0], uv[:, 1]
    face = np.zeros(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    face["n"] = 3
    face["v"] = faces
    header = ["ply", "format binary_little_endian 1.0"]
    header += [f"comment {line}" for line in comment.splitlines() if line]
    header += [f"element vertex {n}"] + [f"property {'float' if t == '<f4' else 'uchar'} {k}" for k, t in fields]
    header += [f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header"]
    return ("\n".join(header) + "\n").encode("ascii") + vert.tobytes() + face.tobytes()


def models_info_entry(obj) -> dict:
    """The ``models_info.json`` record of one object (millimetres)."""
    lo = obj.bbox[0] * MM_PER_M
    size = obj.size * MM_PER_M
    info = {"diameter": float(obj.diameter * MM_PER_M),
            "min_x": float(lo[0]), "min_y": float(lo[1]), "min_z": float(lo[2]),
            "size_x": float(size[0]), "size_y": float(size[1]), "size_z": float(size[2])}
    if obj.symmetries_discrete:
        flat = []
        for T in obj.symmetries_discrete:
            T = np.array(T, dtype=np.float64)
            T[:3, 3] *= MM_PER_M
            flat.append([float(v) + 0.0 for v in T.reshape(-1)])  # + 0.0 turns -0.0 into 0.0
        info["symmetries_discrete"] = flat
    if obj.symmetries_continuous:
        info["symmetries_continuous"] = [
            {"axis": [float(a) for a in s.axis], "offset": [float(o) * MM_PER_M for o in s.offset]}
            for s in obj.symmetries_continuous]
    return info


def _png_bytes(image: np.ndarray) -> bytes:
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image, dtype=np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def _model_ply(obj, out: Path) -> bytes:
    """The PLY of one object with its appearance: vertex colours (the material colour when it has none,
    colours per face on vertices split per face) or texture coordinates, the texture written next to it."""
    mesh, app = obj.mesh, obj.appearance
    verts, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    normals = np.asarray(mesh.vertex_normals)
    comment = f"simtest obj_id {obj.obj_id} {obj.name}\nunits mm, origin at bbox centre, Z up"
    rgb = uv = None
    kind = "none" if app is None else app.kind
    if kind == "none":
        rgb = np.tile(np.round(np.asarray(obj.rgba[:3]) * 255).astype(np.uint8), (len(verts), 1))
    elif kind == "vertex":
        rgb = app.vertex_colors
    elif kind == "face":  # BOP has colours per vertex only: every face gets its own three vertices
        idx = faces.reshape(-1)
        verts, normals = verts[idx], np.repeat(np.asarray(mesh.face_normals), 3, axis=0)
        rgb, faces = np.repeat(app.face_colors, 3, axis=0), np.arange(len(idx)).reshape(-1, 3)
    else:  # texture: one vertex per (position, uv) pair, as the file format needs
        corners = np.column_stack([faces.reshape(-1), app.face_uv.reshape(-1, 2)])
        unique, inverse = np.unique(corners, axis=0, return_inverse=True)
        idx = unique[:, 0].astype(np.int64)
        verts, normals, uv, faces = verts[idx], normals[idx], unique[:, 1:], inverse.reshape(-1, 3)
        texture = f"obj_{obj.obj_id:06d}.png"
        _atomic_write(out / texture, _png_bytes(app.texture))
        comment = f"TextureFile {texture}\n{comment}"
    return ply_bytes(verts * MM_PER_M, faces, normals, rgb, comment=comment, uv=uv)


def write_bop_models(objects, out_dir: str | Path) -> Path:
    """Write an object set as a BOP ``models/`` folder (millimetres).

    Args:
        objects: An :class:`~simtest.objects.ObjectSet` (or any iterable of ``ObjectModel``).
        out_dir: The ``models`` folder to write (created if needed; existing files are replaced).

    Returns:
        ``out_dir`` as a Path.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    info: dict[str, dict] = {}
    meta: dict[str, dict] = {}
    for obj in objects:
        _atomic_write(out / f"obj_{obj.obj_id:06d}.ply", _model_ply(obj, out))
        info[str(obj.obj_id)] = models_info_entry(obj)
        meta[str(obj.obj_id)] = {"name": obj.name, "category": obj.category, "instance": int(obj.instance),
                                 "density": float(obj.density), "rgba": [float(c) for c in obj.rgba],
                                 "source": obj.source}
    _atomic_write(out / INFO_FILE, (json.dumps(info, indent=2) + "\n").encode("utf-8"))
    _atomic_write(out / META_FILE, (json.dumps(meta, indent=2) + "\n").encode("utf-8"))
    return out


def _floats(value, n: int, where: str, field: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise AssetError(f"{where}: {field} must be {n} numbers, got {value!r}") from None
    if arr.size != n or not np.all(np.isfinite(arr)):
        raise AssetError(f"{where}: {field} must be {n} finite numbers, got {value!r}")
    return arr


def _load_json(path: Path) -> dict:
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
    except FileNotFoundError:
        raise AssetError(f"{path}: file not found") from None
    except (OSError, json.JSONDecodeError) as exc:
        raise AssetError(f"{path}: cannot read JSON ({exc})") from None
    if not isinstance(data, dict):
        raise AssetError(f"{path}: expected a JSON object keyed by obj_id, got {type(data).__name__}")
    return data


def find_models_dir(models_dir: str | Path) -> Path:
    """The folder holding ``models_info.json``: ``models_dir`` itself or its ``models/`` sub-folder.

    Raises:
        AssetError: The folder does not exist.
    """
    root = Path(models_dir)
    if not root.is_dir():
        raise AssetError(f"{root}: BOP models folder not found")
    if not (root / INFO_FILE).exists() and (root / "models" / INFO_FILE).exists():
        root = root / "models"
    return root


def read_models_info(root: Path) -> tuple[dict[int, dict], dict[str, dict]]:
    """``({obj_id: models_info entry}, simtest_objects.json records)`` of a models folder, keys checked.

    Raises:
        AssetError: Missing or malformed ``models_info.json`` (naming the file and the bad key or entry).
    """
    info_path = root / INFO_FILE
    info = _load_json(info_path)
    meta = _load_json(root / META_FILE) if (root / META_FILE).exists() else {}
    out: dict[int, dict] = {}
    for key, entry in info.items():
        if not re.fullmatch(r"\d+", str(key)) or int(key) < 1:
            raise AssetError(f"{info_path}: keys must be positive integer object ids, got {key!r}")
        if not isinstance(entry, dict):
            raise AssetError(f"{info_path} (obj_id {int(key)}): expected an object with diameter, min_x, ..., "
                             f"got {entry!r}")
        out[int(key)] = entry
    return out, meta if isinstance(meta, dict) else {}


def read_symmetries(entry: dict, where: str, to_m: float) -> tuple[list[np.ndarray], list[tuple]]:
    """The symmetries of one ``models_info`` entry in metres.

    Args:
        entry: The ``models_info.json`` record.
        where: Text naming the file and object, for errors.
        to_m: File units -> metres (applied to translations and offsets).

    Returns:
        ``(discrete 4x4 transforms, continuous (axis, offset) tuples)``.

    Raises:
        AssetError: A discrete symmetry that is not rigid, or a malformed continuous one.
    """
    sym_d = []
    for i, flat in enumerate(entry.get("symmetries_discrete", []) or []):
        T = _floats(flat, 16, where, f"symmetries_discrete[{i}]").reshape(4, 4).copy()
        R = T[:3, :3]
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or not np.allclose(T[3], [0, 0, 0, 1], atol=1e-6):
            raise AssetError(f"{where}: symmetries_discrete[{i}] is not a rigid transform: {flat!r}")
        T[:3, 3] *= to_m
        sym_d.append(T)
    sym_c = []
    for i, sym in enumerate(entry.get("symmetries_continuous", []) or []):
        if not isinstance(sym, dict) or "axis" not in sym:
            raise AssetError(f"{where}: symmetries_continuous[{i}] must be {{axis, offset}}, got {sym!r}")
        axis = _floats(sym["axis"], 3, where, f"symmetries_continuous[{i}].axis")
        if np.linalg.norm(axis) == 0:
            raise AssetError(f"{where}: symmetries_continuous[{i}].axis must be non-zero, got {sym['axis']!r}")
        offset = _floats(sym.get("offset", [0, 0, 0]), 3, where, f"symmetries_continuous[{i}].offset")
        sym_c.append((tuple(float(a) for a in axis), tuple(float(o) * to_m for o in offset)))
    return sym_d, sym_c


#: Model-frame keypoints of every object, beside ``models_info.json`` (the ``keypoints`` channel).
KEYPOINTS_FILE = "models_keypoints.json"


def write_models_keypoints(objects, models_dir: str | Path) -> Path:
    """``models/models_keypoints.json``: per object id, the keypoint names and model-frame points (mm) that
    ``scene_keypoints.json`` and the COCO keypoints project: the 8 bbox corners, then the farthest-point surface
    keypoints."""
    from simtest.io.files import atomic_write_json

    data = {}
    for obj in sorted(objects, key=lambda o: int(o.obj_id)):
        bb, fps = np.asarray(obj.keypoints_bbox, np.float64), np.asarray(obj.keypoints_fps, np.float64)
        data[str(int(obj.obj_id))] = {"names": [f"bbox_{i}" for i in range(len(bb))] + [f"fps_{i}" for i in range(len(fps))],
                                      "points_mm": np.round(np.concatenate([bb, fps]) * MM_PER_M, 6).tolist()}
    path = Path(models_dir) / KEYPOINTS_FILE
    atomic_write_json(path, data)
    return path
