"""Load object sets: built-in names, a single mesh file, a folder of meshes, or a BOP ``models/`` folder.

``load_object_set(spec)`` is the one entry point the rest of simtest uses:

- ``"builtin"`` / ``"builtin-small"``: the procedural set (:mod:`simtest.objects.builtin`).
- a folder with ``models_info.json`` (or a dataset root with ``models/models_info.json``): a BOP models
  folder, read by :func:`read_bop_models` (millimetres by default, symmetries read).
- a folder with an ``objects.toml`` manifest (:mod:`simtest.objects.manifest`): exactly the files it lists,
  with their names, categories, units, symmetries, mass and friction.
- any other folder: the mesh files in it (``.glb .gltf .obj .ply .stl .off``) and one level of subfolders,
  read as ``category/instance.ext``. One object per base name: of ``mug.obj``, ``mug.stl`` and ``mug.glb`` the
  textured visual file wins (glb > gltf > obj > ply > stl > off); skipped files are reported in one logged warning.
  Ids come from ``obj_000005``-style names when every file is named so, else from the sorted paths (1..N).
- a single mesh file: one object with id 1 (or the id in an ``obj_000005``-style name).

Units (``units=``) and ``scale``: file units times ``scale`` give metres; ``"m"``, ``"cm"``, ``"mm"``, or
``"auto"`` (metres, but a diameter outside :data:`AUTO_MIN_DIAMETER_M` .. :data:`AUTO_MAX_DIAMETER_M` is
refused with the measured size and the ``--units`` / ``--scale`` that would fit). Any mesh below
:data:`MIN_DIAMETER_M` after scaling is rejected as degenerate.
Meshes from files are re-centred at their bbox centre; the subtracted centre (metres, file frame) is
recorded in ``extra["origin_offset"]``. Appearance (UV texture, colours per vertex or face, material colour)
is read with the mesh (:mod:`simtest.objects.appearance`).
Mesh files carry no symmetries unless a manifest declares them; ``load_object_set`` detects them
(``symmetry="auto"``, see :mod:`simtest.objects.symmetry_detect`) unless told ``symmetry="none"``.
"""

from __future__ import annotations

import dataclasses
import logging
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import trimesh

from simtest.errors import AssetError, DatasetError
from simtest.io.bop import read_json
from simtest.io.bop_models import (INFO_FILE, MM_PER_M, find_models_dir, read_models_info,
                                    read_symmetries)
from simtest.objects.appearance import Appearance, appearance_from_visual
from simtest.objects.collision import open_mesh_note
from simtest.objects.manifest import Manifest, ManifestEntry, read_manifest
from simtest.objects.model import (ContinuousSymmetry, ObjectEntry, ObjectModel, ObjectSet, mesh_diameter,
                                   validate_mesh)
from simtest.objects.symmetry_detect import SYMMETRY_POLICIES, apply_symmetry_policy

log = logging.getLogger(__name__)

__all__ = ["load_object_set", "load_mesh_file", "load_mesh_folder", "load_mesh", "unit_scale",
           "read_bop_models", "load_dataset_objects", "MESH_EXTENSIONS", "UNITS", "MIN_DIAMETER_M",
           "AUTO_MIN_DIAMETER_M", "AUTO_MAX_DIAMETER_M", "MAX_DIAMETER_M", "LoadedMesh", "LAZY_MIN_OBJECTS"]

#: Mesh formats, the preferred one first when a folder holds several files with one base name.
MESH_EXTENSIONS = (".glb", ".gltf", ".obj", ".ply", ".stl", ".off")
UNITS = ("m", "cm", "mm", "auto")
#: ``units="auto"`` accepts diameters (metres) in this range only.
AUTO_MIN_DIAMETER_M = 0.01
AUTO_MAX_DIAMETER_M = 1.5
#: Whatever the units, a diameter (metres) below this is degenerate, above it absurd.
MIN_DIAMETER_M = 0.005
MAX_DIAMETER_M = 3.0
#: A mesh folder with more objects than this is read lazily by default (:func:`load_mesh_folder`): reading and
#: examining a mesh eagerly costs 0.1-0.3 s for simple shapes (symmetry detection), seconds for scans.
LAZY_MIN_OBJECTS = 16
#: Default density (kg/m^3) of loaded meshes.
DEFAULT_DENSITY = 500.0
#: Mesh formats simtest does not read; a folder holding them says so.
_OTHER_MESH_FORMATS = (".msh", ".dae", ".fbx", ".3ds", ".blend", ".usd", ".usda", ".usdc", ".usdz", ".wrl", ".3mf")

_BOP_NAME = re.compile(r"obj_(\d+)")
_M_PER_UNIT = {"m": 1.0, "cm": 0.01, "mm": 1.0 / MM_PER_M}


def _fitting_hints(diameter: float, scale: float, auto: bool) -> str:
    """``"--units cm or --scale 0.01"``-style advice for a diameter (file units) outside the plausible range
    (of ``--units auto`` when ``auto``, else of any units)."""
    lo, hi = (AUTO_MIN_DIAMETER_M, AUTO_MAX_DIAMETER_M) if auto else (MIN_DIAMETER_M, MAX_DIAMETER_M)
    candidates = ("cm", "mm") if auto else ("m", "cm", "mm")
    units = [u for u in candidates if lo <= diameter * scale * _M_PER_UNIT[u] <= hi]
    powers = sorted(range(-4, 5), key=abs)
    fit = next((10.0 ** k for k in powers if lo <= diameter * scale * 10.0 ** k <= hi), None)
    if units:  # the scale that reads the file as those units
        fit = _M_PER_UNIT[units[0]]
    hints = [f"--units {u}" for u in units]
    if fit is not None and fit * scale != 1.0:
        hints.append(f"--scale {fit * scale:g}")
    if auto and MIN_DIAMETER_M <= diameter * scale <= MAX_DIAMETER_M:
        hints.append(f"--units m to keep {diameter * scale:.3g} m")
    return " or ".join(hints) or "--scale S with S = metres per file unit"


def unit_scale(diameter: float, units: str, path: str | Path, scale: float = 1.0) -> tuple[float, str]:
    """Factor from file units to metres, and the units used, checked against plausible object sizes.

    Args:
        diameter: The mesh's diameter in file units.
        units: ``"m"``, ``"cm"``, ``"mm"`` or ``"auto"`` (metres, refused outside 1 cm .. 1.5 m).
        path: File name for error messages.
        scale: Extra factor (metres per file unit, times the units' factor).

    Raises:
        AssetError: Unknown units, a bad scale, a diameter that auto refuses (with the measured size and the
            ``--units`` / ``--scale`` that would fit) or one below :data:`MIN_DIAMETER_M` / above
            :data:`MAX_DIAMETER_M`.
    """
    if units not in UNITS:
        raise AssetError(f"{path}: units must be one of {', '.join(UNITS)}, got {units!r}")
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not (0 < scale < 1e6):
        raise AssetError(f"{path}: scale must be a number > 0 (metres per file unit factor), got {scale!r}")
    used = "m" if units == "auto" else units
    factor = _M_PER_UNIT[used] * float(scale)
    d_m = diameter * factor
    if units == "auto" and not AUTO_MIN_DIAMETER_M <= d_m <= AUTO_MAX_DIAMETER_M:
        raise AssetError(
            f"{path}: mesh is {diameter:.4g} units across (diameter), {d_m:.4g} m read as metres, outside the "
            f"{AUTO_MIN_DIAMETER_M:g} .. {AUTO_MAX_DIAMETER_M:g} m that --units auto accepts; pass "
            f"{_fitting_hints(diameter, scale, True)} (units / scale in a config or objects.toml)")
    if d_m < MIN_DIAMETER_M:
        raise AssetError(f"{path}: mesh is degenerate: {d_m * 1000:.3g} mm across (diameter) with units={used!r} "
                         f"scale={scale:g}, below {MIN_DIAMETER_M * 1000:g} mm; if its units are wrong pass "
                         f"{_fitting_hints(diameter, 1.0, False)}")
    if d_m > MAX_DIAMETER_M:
        raise AssetError(f"{path}: mesh is {d_m:.4g} m across (diameter) with units={used!r} scale={scale:g}, "
                         f"above {MAX_DIAMETER_M:g} m; pass {_fitting_hints(diameter, 1.0, False)}")
    return factor, used


@dataclasses.dataclass(frozen=True)
class LoadedMesh:
    """A mesh as read from a file (file units; vertices merged into one closed surface where they coincide),
    its appearance (aligned with ``mesh.faces`` and ``mesh.vertices``) and its material colour."""

    mesh: trimesh.Trimesh
    appearance: Appearance | None
    rgba: tuple | None


def _merged(loaded: trimesh.Trimesh, appearance: Appearance | None) -> tuple[trimesh.Trimesh, Appearance | None]:
    """Merge coincident vertices (split at UV seams by the file) into one surface; faces keep their order, so
    UVs per face corner stay valid and colours per vertex move to the merged vertices."""
    faces = np.asarray(loaded.faces)
    mesh = trimesh.Trimesh(np.asarray(loaded.vertices, dtype=np.float64), faces, process=True)
    if len(mesh.faces) != len(faces):  # merging never drops faces; keep the file's vertices if it did
        mesh = trimesh.Trimesh(np.asarray(loaded.vertices, dtype=np.float64), faces, process=False)
        return mesh, appearance
    if appearance is not None and appearance.vertex_colors is not None:
        corner = appearance.vertex_colors[faces].reshape(-1, 3)
        merged = np.asarray(mesh.faces).reshape(-1)
        colors = np.zeros((len(mesh.vertices), 3), dtype=np.uint8)
        colors[merged] = corner
        if np.array_equal(colors[merged], corner):
            return mesh, Appearance(vertex_colors=colors)
        # coinciding vertices of different colours (a colour per face, drawn on split vertices): keep the
        # colour of each face, exact for drawing
        mean = np.rint(corner.reshape(-1, 3, 3).astype(np.float64).mean(axis=1)).astype(np.uint8)
        return mesh, Appearance(face_colors=mean)
    return mesh, appearance


def _visual(loaded: trimesh.Trimesh, path: Path) -> tuple[Appearance | None, tuple | None]:
    try:
        return appearance_from_visual(loaded.visual, np.asarray(loaded.faces))
    except Exception as exc:  # appearance is secondary: a strange visual never blocks loading geometry
        log.warning("%s: cannot read its colours or texture (%s: %s); it is drawn in the default grey", path,
                    type(exc).__name__, exc)
        return None, None


def load_mesh(path: str | Path) -> LoadedMesh:
    """Read a triangle mesh (file units) with its appearance, with clear errors.

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
    validate_mesh(loaded, str(path))
    appearance, rgba = _visual(loaded, path)
    mesh, appearance = _merged(loaded, appearance)
    validate_mesh(mesh, str(path))
    return LoadedMesh(mesh, appearance, rgba)


def _symmetries_m(symmetry, factor: float) -> tuple[tuple[np.ndarray, ...], tuple[ContinuousSymmetry, ...]]:
    """Manifest symmetries (file units) in metres."""
    sym_d, sym_c = symmetry
    out_d = []
    for T in sym_d:
        T = np.array(T, dtype=np.float64)
        T[:3, 3] *= factor
        out_d.append(T)
    return tuple(out_d), tuple(ContinuousSymmetry(s.axis, tuple(o * factor for o in s.offset)) for s in sym_c)


def load_mesh_file(path: str | Path, obj_id: int | None = None, units: str = "auto", name: str | None = None,
                   category: str | None = None, density: float = DEFAULT_DENSITY, scale: float = 1.0,
                   entry: ManifestEntry | None = None) -> ObjectModel:
    """One object from a mesh file, re-centred at its bbox centre, in metres, with its appearance.

    Args:
        path: ``.glb``, ``.gltf``, ``.obj``, ``.ply``, ``.stl`` or ``.off`` file.
        obj_id: Object id (default: from an ``obj_000005``-style name, else 1).
        units: ``"m"``, ``"cm"``, ``"mm"`` or ``"auto"`` (see the module docstring).
        name: Object name (default: the file stem).
        category: Category (default: the stem without a trailing ``_<number>``).
        density: kg/m^3.
        scale: Factor applied on top of the units (metres = file units x units factor x scale).
        entry: The file's manifest entry; its values override the arguments (symmetry, mass, friction and
            graspable only come from here).

    Raises:
        AssetError: See :func:`load_mesh` and :func:`unit_scale`.
    """
    path = Path(path)
    e = entry or ManifestEntry(file=path.name)
    units = e.units or units
    scale = e.scale if e.scale is not None else scale
    loaded = load_mesh(path)
    factor, unit = unit_scale(mesh_diameter(loaded.mesh), units, path, scale)
    verts = np.asarray(loaded.mesh.vertices) * factor
    center = 0.5 * (verts.min(axis=0) + verts.max(axis=0))
    mesh = trimesh.Trimesh(verts - center, np.asarray(loaded.mesh.faces), process=False)
    if obj_id is None:
        match = _BOP_NAME.fullmatch(path.stem)
        obj_id = e.obj_id or (int(match.group(1)) if match else 1)
    stem = path.stem
    sym_d, sym_c = _symmetries_m(e.symmetry, factor) if e.symmetry is not None else ((), ())
    extra = {"units": unit, "scale": factor, "origin_offset": center.tolist()}
    if e.symmetry is not None:
        extra["symmetry"] = "declared"  # detection leaves it alone, even a declared "none"
    obj = ObjectModel(
        obj_id=obj_id, name=e.name or name or stem,
        category=e.category or category or (re.sub(r"_\d+$", "", stem) or stem),
        instance=0, mesh=mesh, density=e.density or density, rgba=loaded.rgba or (0.7, 0.7, 0.7, 1.0),
        symmetries_discrete=sym_d, symmetries_continuous=sym_c, source=str(path), graspable_override=e.graspable,
        friction=e.friction, extra=extra, appearance=loaded.appearance)
    if e.mass is not None:
        obj = dataclasses.replace(obj, density=e.mass / (obj.mass / obj.density))
    if not mesh.is_watertight:
        log.warning("%s: %s", path, open_mesh_note(obj))
    return obj


def _base_name_files(folder: Path) -> tuple[list[tuple[Path, str | None]], list[str]]:
    """Mesh files of ``folder`` and its direct subfolders (``category/instance.ext``), one per base name, with
    the category of each (``None`` at the top level), and the notes on files left out."""
    notes: list[str] = []
    groups: dict[tuple[Path, str], list[Path]] = {}
    other: list[str] = []
    deeper: list[str] = []
    for p in sorted(folder.rglob("*")):
        if not p.is_file():
            continue
        rel = p.relative_to(folder)
        ext = p.suffix.lower()
        if ext in _OTHER_MESH_FORMATS:
            other.append(str(rel))
        elif ext in MESH_EXTENSIONS:
            if len(rel.parts) > 2:
                deeper.append(str(rel))
            else:
                groups.setdefault((p.parent, p.stem), []).append(p)
    chosen = []
    for (parent, _stem), paths in sorted(groups.items()):
        paths.sort(key=lambda q: MESH_EXTENSIONS.index(q.suffix.lower()))
        if len(paths) > 1:
            skipped = ", ".join(str(q.relative_to(folder)) for q in paths[1:])
            notes.append(f"{paths[0].relative_to(folder)} used, {skipped} skipped (same base name)")
        chosen.append((paths[0], None if parent == folder else parent.name))
    if other:
        notes.append(f"formats simtest does not read skipped: {', '.join(other)}")
    if deeper:
        notes.append(f"files deeper than category/instance skipped: {', '.join(deeper)} (list them in objects.toml)")
    return chosen, notes


def _folder_ids(paths: list[Path], folder: Path) -> list[int]:
    """Ids from ``obj_000005``-style names when every file is named so, else 1..N in path order."""
    matches = [_BOP_NAME.fullmatch(p.stem) for p in paths]
    ids = [int(m.group(1)) for m in matches] if all(matches) else list(range(1, len(paths) + 1))
    seen: dict[int, Path] = {}
    for obj_id, path in zip(ids, paths):
        if obj_id in seen:
            raise AssetError(f"{folder}: duplicate obj_id {obj_id} from {seen[obj_id].name} and {path.name}")
        if obj_id < 1:
            raise AssetError(f"{path}: obj_id must be a positive integer, got {obj_id}")
        seen[obj_id] = path
    return ids


def _default_category(stem: str) -> str:
    """Category of a file outside category folders: the stem without a trailing ``_<number>``."""
    return re.sub(r"_\d+$", "", stem) or stem


def _manifest_objects(folder: Path, manifest: Manifest, units: str, scale: float
                      ) -> tuple[list[ObjectEntry], Callable[[ObjectEntry], ObjectModel]]:
    """Entries of the files a manifest lists (no mesh read) and the loader that reads one of them."""
    entries = manifest.entries
    listed = {(folder / e.file).resolve() for e in entries}
    unlisted = sorted(str(p.relative_to(folder)) for p in folder.rglob("*")
                      if p.is_file() and p.suffix.lower() in MESH_EXTENSIONS and p.resolve() not in listed)
    if unlisted:
        log.warning("%s: mesh files not listed in %s skipped: %s", folder, manifest.path.name, ", ".join(unlisted))
    paths = [folder / e.file for e in entries]
    by_id: dict[int, ManifestEntry] = {}
    out = []
    for p, obj_id, e in zip(paths, _manifest_ids(entries, paths), entries):
        by_id[obj_id] = e
        category = e.category or Path(e.file).parent.name or _default_category(p.stem)
        out.append(ObjectEntry(obj_id, e.name or p.stem, category, str(p)))

    def load(entry: ObjectEntry) -> ObjectModel:
        return load_mesh_file(entry.source, entry.obj_id, manifest.units or units,
                              density=manifest.density or DEFAULT_DENSITY,
                              scale=manifest.scale if manifest.scale is not None else scale,
                              category=entry.category, entry=by_id[entry.obj_id])

    return out, load


def _tree_objects(folder: Path, chosen: list[tuple[Path, str | None]], units: str, scale: float
                  ) -> tuple[list[ObjectEntry], Callable[[ObjectEntry], ObjectModel]]:
    """Entries of the files of a folder without manifest (ids, names and categories from the paths, no mesh
    read; a name found in several category folders gets its category as prefix) and their loader."""
    paths = [p for p, _ in chosen]
    cats = [c or _default_category(p.stem) for p, c in chosen]
    stems = [p.stem for p in paths]
    names = [f"{c}_{s}" if stems.count(s) > 1 else s for s, c in zip(stems, cats)]
    entries = [ObjectEntry(i, n, c, str(p)) for i, n, c, p in zip(_folder_ids(paths, folder), names, cats, paths)]

    def load(entry: ObjectEntry) -> ObjectModel:
        return load_mesh_file(entry.source, entry.obj_id, units, name=entry.name, category=entry.category,
                              scale=scale)

    return entries, load


def _read_all(folder: Path, entries: list[ObjectEntry], load: Callable[[ObjectEntry], ObjectModel],
              notes: list[str], skip_degenerate: bool) -> ObjectSet:
    """Read every object now; degenerate or empty meshes are left out and noted when ``skip_degenerate``."""
    objects = []
    for entry in entries:
        try:
            objects.append(load(entry))
        except AssetError as exc:
            if not skip_degenerate or ("degenerate" not in str(exc) and "empty" not in str(exc)):
                raise
            notes.append(f"rejected {exc}")
    if notes:
        log.warning("%s: %s", folder, "; ".join(notes))
    if not objects:
        raise AssetError(f"{folder}: no usable mesh: " + "; ".join(notes))
    objects.sort(key=lambda o: o.obj_id)
    return ObjectSet(objects, name=str(folder))


def _manifest_ids(entries: tuple[ManifestEntry, ...], paths: list[Path]) -> list[int]:
    """Declared ``obj_id`` values; the others from ``obj_000005``-style names when every file is named so,
    else the smallest free ids in listing order."""
    matches = [_BOP_NAME.fullmatch(p.stem) for p in paths]
    if all(matches):
        return [e.obj_id or int(m.group(1)) for e, m in zip(entries, matches)]
    taken = {e.obj_id for e in entries if e.obj_id is not None}
    free = (i for i in range(1, len(entries) + len(taken) + 1) if i not in taken)
    return [e.obj_id if e.obj_id is not None else next(free) for e in entries]


def load_mesh_folder(folder: str | Path, units: str = "auto", scale: float = 1.0,
                     lazy: bool | None = None) -> ObjectSet:
    """The objects of a mesh folder: as its ``objects.toml`` says, else one per base name (see the module
    docstring). Skipped files and degenerate meshes are reported in one logged warning naming them.

    Args:
        folder: The folder.
        units, scale: As in :func:`load_object_set`.
        lazy: ``True``: a :class:`~simtest.objects.lazy.LazyObjectSet` (ids, names and categories from the
            paths and manifest now, each mesh read on first use; a broken mesh raises then, naming its file);
            ``False``: read every mesh now; ``None``: lazy when the folder holds more than
            :data:`LAZY_MIN_OBJECTS` objects.

    Raises:
        AssetError: Missing folder, no usable mesh files, duplicate ids, a bad manifest, or a file error
            other than a degenerate mesh (units, unreadable files).
    """
    from simtest.objects.lazy import LazyObjectSet

    folder = Path(folder)
    if not folder.is_dir():
        raise AssetError(f"{folder}: folder not found")
    manifest = read_manifest(folder)
    notes: list[str] = []
    if manifest is not None:
        entries, load = _manifest_objects(folder, manifest, units, scale)
    else:
        chosen, notes = _base_name_files(folder)
        if not chosen:
            raise AssetError(f"{folder}: no mesh files ({', '.join(MESH_EXTENSIONS)}) in the folder or its "
                             "subfolders")
        entries, load = _tree_objects(folder, chosen, units, scale)
    if lazy is None:
        lazy = len(entries) > LAZY_MIN_OBJECTS
    if not lazy:
        return _read_all(folder, entries, load, notes, skip_degenerate=manifest is None)
    if notes:
        log.warning("%s: %s", folder, "; ".join(notes))
    return LazyObjectSet(entries, load, name=str(folder))


def load_object_set(spec: str | Path = "builtin", units: str = "auto", seed: int = 0,
                    scale: float = 1.0, symmetry: str = "auto", lazy: bool | None = None) -> ObjectSet:
    """An object set by name or path.

    Args:
        spec: ``"builtin"``, ``"builtin-small"``, a BOP models folder (or dataset root), a folder of meshes,
            or one mesh file.
        units: ``"m"``, ``"cm"``, ``"mm"`` or ``"auto"`` for files (an ``objects.toml`` may set its own);
            BOP folders read ``"auto"`` as millimetres. Ignored for built-in sets.
        seed: Seed of the built-in sets (ignored for files).
        scale: Factor on top of the units (metres = file units x units factor x scale); ignored for
            built-in sets.
        symmetry: ``"auto"``: mesh files that declare no symmetry get the detected ones
            (:func:`~simtest.objects.symmetry_detect.apply_symmetry_policy`); ``"none"``: they get none.
            Built-in sets and BOP models folders keep their own symmetries. A lazy set detects them for an
            object when it is read.
        lazy: For a mesh folder, whether meshes are read on first use (see :func:`load_mesh_folder`; ``None``:
            when it holds more than :data:`LAZY_MIN_OBJECTS` objects). Other sets are read at once.

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
            return read_bop_models(path, units="mm" if units == "auto" else units, scale=scale)
        return apply_symmetry_policy(load_mesh_folder(path, units, scale, lazy=lazy), symmetry)
    if path.is_file():
        return apply_symmetry_policy(ObjectSet([load_mesh_file(path, units=units, scale=scale)], name=str(path)),
                                     symmetry)
    raise AssetError(f"object set {text!r} not found: not a built-in set ({', '.join(BUILTIN_SETS)}) and no such "
                     "file or folder")


#: A BOP model whose bbox centre is farther than this from its origin (metres) triggers a warning.
CENTER_TOLERANCE = 1e-3


def read_bop_models(models_dir: str | Path, units: str = "mm", scale: float = 1.0) -> ObjectSet:
    """Read a BOP ``models/`` folder into an :class:`~simtest.objects.ObjectSet` (metres).

    The model frame of the files is kept as it is (ground-truth poses of a BOP dataset refer to it); BOP
    models have their origin at the bbox centre, and a model whose bbox centre is more than 1 mm off
    its origin triggers a warning (its offset is recorded in ``extra["bbox_center"]``).

    Args:
        models_dir: Folder with ``models_info.json`` and ``obj_{id:06d}.ply``; a dataset root holding a
            ``models/`` folder is accepted too.
        units: Units of the files: ``"mm"`` (the BOP standard), ``"cm"``, ``"m"`` or ``"auto"``.
        scale: Factor on top of the units.

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
        loaded = load_mesh(ply)
        factor, unit = unit_scale(mesh_diameter(loaded.mesh), units, ply, scale)
        mesh = trimesh.Trimesh(np.asarray(loaded.mesh.vertices) * factor, np.asarray(loaded.mesh.faces),
                               process=False)
        sym_d, sym_c = read_symmetries(entry, where, to_m=factor)
        sym_c = [ContinuousSymmetry(axis, offset) for axis, offset in sym_c]
        m = meta.get(str(obj_id), {})
        center = 0.5 * (mesh.bounds[0] + mesh.bounds[1])
        extra = {"units": unit, "scale": factor, "path": str(ply)}
        if np.linalg.norm(center) > CENTER_TOLERANCE:
            log.warning("%s: bbox centre is %s mm off the model origin (BOP models are centred); the file frame is "
                        "kept so dataset poses stay valid", ply, np.round(center * 1000, 2).tolist())
            extra["bbox_center"] = center.tolist()
        rgba = tuple(m.get("rgba", loaded.rgba or (0.7, 0.7, 0.7, 1.0)))
        objects.append(ObjectModel(
            obj_id=obj_id, name=str(m.get("name", f"obj_{obj_id:06d}")), category=str(m.get("category", "obj")),
            instance=int(m.get("instance", 0)), mesh=mesh, density=float(m.get("density", 500.0)), rgba=rgba,
            symmetries_discrete=tuple(sym_d), symmetries_continuous=tuple(sym_c),
            source=str(m.get("source", str(ply))), extra=extra, appearance=loaded.appearance))
    listed = {f"obj_{o.obj_id:06d}.ply" for o in objects}
    extra_files = sorted(p.name for p in root.glob("obj_*.ply") if p.name not in listed)
    if extra_files:
        log.warning("%s: model files not listed in %s are ignored: %s", root, INFO_FILE, ", ".join(extra_files))
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
