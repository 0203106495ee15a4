"""``objects.toml``: an optional manifest in a mesh folder saying what each file is.

Example (see docs/objects.md)::

    units = "cm"                 # defaults of every entry: units, scale, density
    [[object]]
    file = "cans/soup.obj"       # path relative to the folder
    name = "soup_can"
    category = "can"
    symmetry = ["continuous z", "discrete 2 x"]     # or BOP form, or "none"
    mass = 0.35                  # kg (or density, kg/m^3)
    friction = 0.8
    graspable = true

Symmetry short forms (axes of the model frame, through its origin, the bbox centre): ``"continuous z"``
(any rotation about z), ``"discrete N x"`` (rotations by multiples of 360/N degrees about x), ``"none"``
(declared asymmetric). The BOP form is a table ``{symmetries_continuous = [{axis = [0, 0, 1],
offset = [0, 0, 0]}], symmetries_discrete = [[16 numbers, row-major 4x4]]}`` with offsets and translations in
the file's units (scaled like the mesh).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from simtest.errors import AssetError
from simtest.io.bop_models import read_symmetries
from simtest.objects.model import ContinuousSymmetry

__all__ = ["MANIFEST_FILE", "ManifestEntry", "Manifest", "read_manifest", "parse_symmetry"]

MANIFEST_FILE = "objects.toml"
UNITS = ("m", "cm", "mm", "auto")
_ENTRY_KEYS = ("file", "name", "category", "units", "scale", "symmetry", "density", "mass", "friction",
               "graspable", "obj_id")
_TOP_KEYS = ("units", "scale", "density", "object")
_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


@dataclass(frozen=True)
class ManifestEntry:
    """One ``[[object]]`` of a manifest (``None``: not given, the loader's default applies).

    ``symmetry`` is ``None`` when not declared, else ``(discrete 4x4 transforms in file units, continuous
    symmetries)``; ``mass`` in kg, ``density`` in kg/m^3.
    """

    file: str
    name: str | None = None
    category: str | None = None
    units: str | None = None
    scale: float | None = None
    symmetry: tuple[tuple[np.ndarray, ...], tuple[ContinuousSymmetry, ...]] | None = None
    density: float | None = None
    mass: float | None = None
    friction: float | None = None
    graspable: bool | None = None
    obj_id: int | None = None


@dataclass(frozen=True)
class Manifest:
    path: Path
    entries: tuple[ManifestEntry, ...]
    units: str | None = None
    scale: float | None = None
    density: float | None = None


def _bad(where: str, key: str, value, allowed: str) -> AssetError:
    return AssetError(f"{where}: {key} = {value!r} is invalid; allowed: {allowed}")


def _rotation(axis: str, angle: float) -> np.ndarray:
    a = np.asarray(_AXES[axis])
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    T = np.eye(4)
    T[:3, :3] = np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K
    return np.round(T, 15)


def parse_symmetry(value, where: str) -> tuple[tuple[np.ndarray, ...], tuple[ContinuousSymmetry, ...]]:
    """Symmetries from a short form (a string or a list of them) or the BOP form (a table), in file units.

    Raises:
        AssetError: Naming ``where`` and the bad value, listing the allowed forms.
    """
    allowed = ("'none', 'continuous x|y|z', 'discrete N x|y|z' (N >= 2), a list of these, or a table "
               "{symmetries_continuous = [...], symmetries_discrete = [...]} (BOP form)")
    if isinstance(value, dict):
        unknown = set(value) - {"symmetries_continuous", "symmetries_discrete"}
        if unknown:
            raise _bad(where, "symmetry", value, allowed)
        sym_d, sym_c = read_symmetries(value, where, to_m=1.0)
        return tuple(sym_d), tuple(ContinuousSymmetry(a, o) for a, o in sym_c)
    items = [value] if isinstance(value, str) else value
    if not isinstance(items, list) or not all(isinstance(v, str) for v in items):
        raise _bad(where, "symmetry", value, allowed)
    discrete: list[np.ndarray] = []
    continuous: list[ContinuousSymmetry] = []
    for text in items:
        words = text.lower().split()
        if words == ["none"]:
            continue
        if len(words) == 2 and words[0] == "continuous" and words[1] in _AXES:
            continuous.append(ContinuousSymmetry(_AXES[words[1]]))
        elif len(words) == 3 and words[0] == "discrete" and re.fullmatch(r"\d+", words[1]) \
                and int(words[1]) >= 2 and words[2] in _AXES:
            n = int(words[1])
            discrete += [_rotation(words[2], 2 * math.pi * k / n) for k in range(1, n)]
        else:
            raise _bad(where, "symmetry", text, allowed)
    return tuple(discrete), tuple(continuous)


def _number(entry: dict, key: str, where: str, lo: float, hi: float) -> float | None:
    if key not in entry:
        return None
    v = entry[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (lo < v <= hi):
        raise _bad(where, key, v, f"a number in ({lo:g}, {hi:g}]")
    return float(v)


def _units(entry: dict, where: str) -> str | None:
    if "units" in entry and entry["units"] not in UNITS:
        raise _bad(where, "units", entry["units"], " | ".join(UNITS))
    return entry.get("units")


def _entry(raw, where: str, folder: Path) -> ManifestEntry:
    if not isinstance(raw, dict):
        raise AssetError(f"{where}: expected a table [[object]] with file = ..., got {raw!r}")
    unknown = sorted(set(raw) - set(_ENTRY_KEYS))
    if unknown:
        raise AssetError(f"{where}: unknown key(s) {unknown}; allowed: {', '.join(_ENTRY_KEYS)}")
    file = raw.get("file")
    if not isinstance(file, str) or not file:
        raise _bad(where, "file", file, "a mesh path relative to the folder")
    if not (folder / file).is_file():
        raise AssetError(f"{where}: file {file!r} not found in {folder}")
    for key in ("name", "category"):
        if key in raw and (not isinstance(raw[key], str) or not raw[key]):
            raise _bad(where, key, raw[key], "a non-empty string")
    if "graspable" in raw and not isinstance(raw["graspable"], bool):
        raise _bad(where, "graspable", raw["graspable"], "true | false")
    if "density" in raw and "mass" in raw:
        raise AssetError(f"{where}: give density or mass, not both")
    obj_id = raw.get("obj_id")
    if obj_id is not None and (isinstance(obj_id, bool) or not isinstance(obj_id, int) or obj_id < 1):
        raise _bad(where, "obj_id", obj_id, "a positive integer")
    return ManifestEntry(
        file=file, name=raw.get("name"), category=raw.get("category"), units=_units(raw, where),
        scale=_number(raw, "scale", where, 0.0, 1e6),
        symmetry=None if "symmetry" not in raw else parse_symmetry(raw["symmetry"], f"{where}: symmetry"),
        density=_number(raw, "density", where, 0.0, 1e5), mass=_number(raw, "mass", where, 0.0, 1e4),
        friction=_number(raw, "friction", where, 0.0, 10.0), graspable=raw.get("graspable"), obj_id=obj_id)


def read_manifest(folder: str | Path) -> Manifest | None:
    """The folder's ``objects.toml``, validated (None when there is none).

    Raises:
        AssetError: Unreadable TOML, unknown keys, bad values or missing files (naming the entry and key).
    """
    import tomllib

    path = Path(folder) / MANIFEST_FILE
    if not path.is_file():
        return None
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise AssetError(f"{path}: cannot read TOML ({exc})") from None
    unknown = sorted(set(data) - set(_TOP_KEYS))
    if unknown:
        raise AssetError(f"{path}: unknown key(s) {unknown}; allowed: {', '.join(_TOP_KEYS)} "
                         "(per-file settings go in [[object]] tables)")
    raw = data.get("object", [])
    if not isinstance(raw, list) or not raw:
        raise AssetError(f"{path}: no [[object]] tables; add one per mesh file (file = \"name.obj\")")
    entries = tuple(_entry(e, f"{path} [[object]] #{i + 1}", path.parent) for i, e in enumerate(raw))
    files = [e.file for e in entries]
    dup = sorted({f for f in files if files.count(f) > 1})
    if dup:
        raise AssetError(f"{path}: file(s) listed more than once: {', '.join(dup)}")
    return Manifest(path, entries, units=_units(data, str(path)), scale=_number(data, "scale", str(path), 0.0, 1e6),
                    density=_number(data, "density", str(path), 0.0, 1e5))
