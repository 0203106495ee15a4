"""Load object sets: built-in names, a single mesh file, a folder of meshes, or a BOP ``models/`` folder.

``load_object_set(spec)`` is the one entry point the rest of simtest uses:

- ``"builtin"`` / ``"builtin-small"``: the procedural set (:mod:`simtest.objects.builtin`).
- a folder with ``models_info.json`` (or a dataset root with ``models/models_info.json``): a BOP models
  folder, read by :func:`read_bop_models` (millimetres by default, symmetries read).
- any other folder: every mesh file in it (``.obj .ply .stl .glb .gltf .off``). Ids come from
  ``obj_000005``-style names when every file is named so, else from the sorted file names (1..N).
- a single mesh file: one object with id 1 (or the id in an ``obj_000005``-style name).

Units (``units=``): ``"m"``, ``"mm"``, or ``"auto"`` (metres unless the mesh is more than
:data:`MAX_SIZE_M` across, then millimetres). Whatever the units, the size in metres must lie between
:data:`MIN_SIZE_M` and :data:`MAX_SIZE_M`, else an :class:`AssetError` says which units would fit.
Meshes from files are re-centred at their bbox centre; the subtracted centre (metres, file frame) is
recorded in ``extra["origin_offset"]``. Mesh files carry no symmetries; ``load_object_set`` detects them
(``symmetry="auto"``, see :mod:`simtest.objects.symmetry_detect`) unless told ``symmetry="none"``.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import trimesh

from simtest.errors import AssetError, DatasetError
from simtest.io.bop import read_json
from simtest.io.bop_models import (INFO_FILE, MM_PER_M, find_models_dir, read_models_info,
                                    read_symmetries)
from simtest.objects.collision import open_mesh_note
from simtest.objects.model import ContinuousSymmetry, ObjectModel, ObjectSet, validate_mesh
from simtest.objects.symmetry_detect import SYMMETRY_POLICIES, apply_symmetry_policy

__all__ = ["load_object_set", "load_mesh_file", "load_mesh_folder", "load_mesh", "unit_scale",
           "read_bop_models", "load_dataset_objects", "MESH_EXTENSIONS", "UNITS", "MIN_SIZE_M", "MAX_SIZE_M"]

MESH_EXTENSIONS = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off")
UNITS = ("m", "mm", "auto")
#: Plausible object sizes (bbox diagonal, metres): anything outside means the units are wrong.
MIN_SIZE_M = 0.002
MAX_SIZE_M = 3.0
#: Default density (kg/m^3) of loaded meshes.
DEFAULT_DENSITY = 500.0

_BOP_NAME = re.compile(r"obj_(\d+)")


def _m_per_unit() -> dict[str, float]:
    return {"m": 1.0, "mm": 1.0 / MM_PER_M}


def unit_scale(mesh: trimesh.Trimesh, units: str, path: str | Path) -> tuple[float, str]:
    """Factor from file units to metres, and the units used, checked against plausible object sizes.

    Args:
        mesh: The mesh as read (file units).
        units: ``"m"``, ``"mm"`` or ``"auto"``.
        path: File name for error messages.

    Raises:
        AssetError: Unknown units, or a size in metres outside [MIN_SIZE_M, MAX_SIZE_M] (the message says
            the size and which ``units=`` would fit).
    """
    if units not in UNITS:
        raise AssetError(f"{path}: units must be one of {', '.join(UNITS)}, got {units!r}")
    table = _m_per_unit()
    size = float(np.linalg.norm(np.ptp(np.asarray(mesh.vertices), axis=0)))
    chosen = units if units != "auto" else ("m" if size <= MAX_SIZE_M else "mm")
    size_m = size * table[chosen]
    if MIN_SIZE_M <= size_m <= MAX_SIZE_M:
        return table[chosen], chosen
    fits = [u for u in ("m", "mm") if MIN_SIZE_M <= size * table[u] <= MAX_SIZE_M]
    hint = f"; it looks like {fits[0]!r}: pass units={fits[0]!r}" if fits else ""
    raise AssetError(
        f"{path}: mesh is {size_m:.4g} m across (bbox diagonal) when read with units={chosen!r}, outside the "
        f"plausible {MIN_SIZE_M} m .. {MAX_SIZE_M} m{hint}")


def _rgba_of(mesh: trimesh.Trimesh) -> tuple[float, float, float, float] | None:
    """Mean colour of a mesh's visual, if it has one."""
    try:
        visual = mesh.visual
        if visual.kind == "vertex":
            c = np.asarray(visual.vertex_colors, dtype=np.float64).mean(axis=0) / 255.0
        elif visual.kind == "face":
            c = np.asarray(visual.face_colors, dtype=np.float64).mean(axis=0) / 255.0
        elif visual.kind == "texture" and getattr(visual, "material", None) is not None:
            c = np.asarray(visual.material.main_color, dtype=np.float64) / 255.0
        else:
            return None
        c = np.clip(c, 0.0, 1.0)
        return (float(c[0]), float(c[1]), float(c[2]), 1.0)
    except Exception:  # colour is a nicety; a strange visual never blocks loading
        return None


def load_mesh(path: str | Path) -> tuple[trimesh.Trimesh, tuple | None]:
    """Read a triangle mesh (file units) and its mean colour, with clear errors.

    Raises:
        AssetError: Missing or unreadable file, unsupported extension, empty or degenerate mesh, NaN or
            infinite vertices.
    """
    path = Path(path)
    if not path.exists():
        raise AssetError(f"{path}: mesh file not found")
    if not path.is_file():
        raise AssetError(f"{path}: not a file")
    if path.suffix.lower() not in MESH_EXTENSIONS:
        raise AssetError(f"{path}: unsupported mesh format {path.suffix!r}; allowed: {', '.join(MESH_EXTENSIONS)}")
    try:
        loaded = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:
        raise AssetError(f"{path}: cannot read mesh ({type(exc).__name__}: {exc})") from None
    if isinstance(loaded, trimesh.Scene):  # an empty scene
        raise AssetError(f"{path}: mesh is empty (no triangles)")
    if not isinstance(loaded, trimesh.Trimesh):
        raise AssetError(f"{path}: expected a triangle mesh, got {type(loaded).__name__}")
    rgba = _rgba_of(loaded)
    validate_mesh(loaded, str(path))
    mesh = trimesh.Trimesh(np.asarray(loaded.vertices, dtype=np.float64), np.asarray(loaded.faces), process=True)
    validate_mesh(mesh, str(path))
    return mesh, rgba


def load_mesh_file(path: str | Path, obj_id: int | None = None, units: str = "auto", name: str | None = None,
                   category: str | None = None, density: float = DEFAULT_DENSITY) -> ObjectModel:
    """One object from a mesh file, re-centred at its bbox centre, in metres.

    Args:
        path: ``.obj``, ``.ply``, ``.stl``, ``.glb``, ``.gltf`` or ``.off`` file.
        obj_id: Object id (default: from an ``obj_000005``-style name, else 1).
        units: ``"m"``, ``"mm"`` or ``"auto"`` (see the module docstring).
        name: Object name (default: the file stem).
        category: Category (default: the stem without a trailing ``_<number>``).
        density: kg/m^3.

    Raises:
        AssetError: See :func:`load_mesh` and :func:`unit_scale`.
    """
    path = Path(path)
    mesh, rgba = load_mesh(path)
    scale, unit = unit_scale(mesh, units, path)
    verts = np.asarray(mesh.vertices) * scale
    center = 0.5 * (verts.min(axis=0) + verts.max(axis=0))
    mesh = trimesh.Trimesh(verts - center, np.asarray(mesh.faces), process=False)
    if obj_id is None:
        match = _BOP_NAME.fullmatch(path.stem)
        obj_id = int(match.group(1)) if match else 1
    stem = path.stem
    obj = ObjectModel(
        obj_id=obj_id, name=name or stem, category=category or (re.sub(r"_\d+$", "", stem) or stem),
        instance=0, mesh=mesh, density=density, rgba=rgba or (0.7, 0.7, 0.7, 1.0), source=str(path),
        extra={"units": unit, "scale": scale, "origin_offset": center.tolist()})
    if not mesh.is_watertight:
        warnings.warn(f"{path}: {open_mesh_note(obj)}", stacklevel=2)
    return obj


def load_mesh_folder(folder: str | Path, units: str = "auto") -> ObjectSet:
    """Every mesh file in ``folder`` (not recursive) as one object each.

    Ids: parsed from the names when every file is named ``obj_<number>.<ext>``, else 1..N in sorted file
    name order.

    Raises:
        AssetError: Missing folder, no mesh files, duplicate ids, or any per-file error.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise AssetError(f"{folder}: folder not found")
    files = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in MESH_EXTENSIONS)
    if not files:
        raise AssetError(f"{folder}: no mesh files ({', '.join(MESH_EXTENSIONS)}) in the folder")
    matches = [_BOP_NAME.fullmatch(p.stem) for p in files]
    ids = [int(m.group(1)) for m in matches] if all(matches) else list(range(1, len(files) + 1))
    seen: dict[int, Path] = {}
    for obj_id, path in zip(ids, files):
        if obj_id in seen:
            raise AssetError(f"{folder}: duplicate obj_id {obj_id} from {seen[obj_id].name} and {path.name}")
        if obj_id < 1:
            raise AssetError(f"{path}: obj_id must be a positive integer, got {obj_id}")
        seen[obj_id] = path
    objects = [load_mesh_file(path, obj_id, units) for obj_id, path in zip(ids, files)]
    objects.sort(key=lambda o: o.obj_id)
    return ObjectSet(objects, name=str(folder))


def load_object_set(spec: str | Path = "builtin", units: str = "auto", seed: int = 0,
                    symmetry: str = "auto") -> ObjectSet:
    """An object set by name or path.

    Args:
        spec: ``"builtin"``, ``"builtin-small"``, a BOP models folder (or dataset root), a folder of meshes,
            or one mesh file.
        units: ``"m"``, ``"mm"`` or ``"auto"`` for files; BOP folders read ``"auto"`` as millimetres.
            Ignored for built-in sets.
        seed: Seed of the built-in sets (ignored for files).
        symmetry: ``"auto"``: mesh files that declare no symmetry get the detected ones
            (:func:`~simtest.objects.symmetry_detect.apply_symmetry_policy`); ``"none"``: they get none.
            Built-in sets and BOP models folders keep their own symmetries.

    Raises:
        AssetError: Unknown name or missing path (listing the built-in names), or any loading error.
    """
    from simtest.objects.builtin import BUILTIN_SETS, load_builtin

    if units not in UNITS:
        raise AssetError(f"units must be one of {', '.join(UNITS)}, got {units!r}")
    if symmetry not in SYMMETRY_POLICIES:
        raise AssetError(f"symmetry must be one of {', '.join(SYMMETRY_POLICIES)}, got {symmetry!r}")
    text = str(spec)
    if text in BUILTIN_SETS:
        return load_builtin(text, seed)
    path = Path(text).expanduser()
    if path.is_dir():
        if (path / INFO_FILE).exists() or (path / "models" / INFO_FILE).exists():
            return read_bop_models(path, units="mm" if units == "auto" else units)
        return apply_symmetry_policy(load_mesh_folder(path, units), symmetry)
    if path.is_file():
        return apply_symmetry_policy(ObjectSet([load_mesh_file(path, units=units)], name=str(path)), symmetry)
    raise AssetError(f"object set {text!r} not found: not a built-in set ({', '.join(BUILTIN_SETS)}) and no such "
                     "file or folder")


#: A BOP model whose bbox centre is farther than this from its origin (metres) triggers a warning.
CENTER_TOLERANCE = 1e-3


def read_bop_models(models_dir: str | Path, units: str = "mm") -> ObjectSet:
    """Read a BOP ``models/`` folder into an :class:`~simtest.objects.ObjectSet` (metres).

    The model frame of the files is kept as it is (ground-truth poses of a BOP dataset refer to it); BOP
    models have their origin at the bbox centre, and a model whose bbox centre is more than 1 mm off
    its origin triggers a warning (its offset is recorded in ``extra["bbox_center"]``).

    Args:
        models_dir: Folder with ``models_info.json`` and ``obj_{id:06d}.ply``; a dataset root holding a
            ``models/`` folder is accepted too.
        units: Units of the files: ``"mm"`` (the BOP standard), ``"m"`` or ``"auto"`` (by size).

    Raises:
        AssetError: Missing folder, ``models_info.json`` or model file, malformed entries (naming the file,
            object and field), absurd sizes for the units, or broken meshes.
    """
    root = find_models_dir(models_dir)
    info_path = root / INFO_FILE
    info, meta = read_models_info(root)
    objects = []
    for obj_id, entry in info.items():
        where = f"{info_path} (obj_id {obj_id})"
        ply = root / f"obj_{obj_id:06d}.ply"
        if not ply.exists():
            raise AssetError(f"{ply}: model file of obj_id {obj_id} listed in {info_path} not found")
        mesh, raw_rgba = load_mesh(ply)
        scale, unit = unit_scale(mesh, units, ply)
        mesh = trimesh.Trimesh(np.asarray(mesh.vertices) * scale, np.asarray(mesh.faces), process=False)
        sym_d, sym_c = read_symmetries(entry, where, to_m=scale)
        sym_c = [ContinuousSymmetry(axis, offset) for axis, offset in sym_c]
        m = meta.get(str(obj_id), {})
        center = 0.5 * (mesh.bounds[0] + mesh.bounds[1])
        extra = {"units": unit, "scale": scale, "path": str(ply)}
        if np.linalg.norm(center) > CENTER_TOLERANCE:
            warnings.warn(f"{ply}: bbox centre is {np.round(center * 1000, 2).tolist()} mm off the model origin "
                          "(BOP models are centred); the file frame is kept so dataset poses stay valid",
                          stacklevel=2)
            extra["bbox_center"] = center.tolist()
        rgba = tuple(m.get("rgba", raw_rgba or (0.7, 0.7, 0.7, 1.0)))
        objects.append(ObjectModel(
            obj_id=obj_id, name=str(m.get("name", f"obj_{obj_id:06d}")), category=str(m.get("category", "obj")),
            instance=int(m.get("instance", 0)), mesh=mesh, density=float(m.get("density", 500.0)), rgba=rgba,
            symmetries_discrete=tuple(sym_d), symmetries_continuous=tuple(sym_c),
            source=str(m.get("source", str(ply))), extra=extra))
    listed = {f"obj_{o.obj_id:06d}.ply" for o in objects}
    extra_files = sorted(p.name for p in root.glob("obj_*.ply") if p.name not in listed)
    if extra_files:
        warnings.warn(f"{root}: model files not listed in {INFO_FILE} are ignored: {', '.join(extra_files)}",
                      stacklevel=2)
    objects.sort(key=lambda o: o.obj_id)
    return ObjectSet(objects, name=str(root))


def load_dataset_objects(dataset_dir: str | Path) -> ObjectSet:
    """The object set the dataset's poses refer to: ``DATASET/models/`` if present, else the manifest's
    ``object_set`` (a built-in name or a path).

    Raises:
        DatasetError: The folder does not exist, or neither models nor an object set is there.
    """
    root = Path(dataset_dir)
    if not root.is_dir():
        raise DatasetError(f"dataset folder {root} does not exist")
    models_dir = root / "models"
    if (models_dir / INFO_FILE).is_file():
        return read_bop_models(models_dir)
    manifest = root / "manifest.json"
    if manifest.is_file():
        data = read_json(manifest)
        name = data.get("object_set") if isinstance(data, dict) else None
        if name:
            return load_object_set(name)
    raise DatasetError(f"{root}: no models/models_info.json and no 'object_set' in manifest.json; cannot tell "
                       "which object models the poses refer to")
