"""User material folders (ambientCG, Poly Haven and plain images): finding the sets and reading them as
:class:`~simtest.materials.maps.MaterialMaps`.

A set is recognised by its file names (case-insensitive): ``NAME[_RES]_KIND.ext`` (ambientCG,
``Wood049_2K_Color.jpg``, ``Wood049_2K-JPG_Color.jpg``) or ``NAME_KIND[_RES].ext`` (Poly Haven,
``planks_diff_1k.jpg``), KIND one of Color/BaseColor/Albedo/Diffuse/diff (colour), Roughness/rough,
NormalGL/nor_gl, NormalDX/nor_dx. Other maps of a set (displacement, AO, metalness, ...) are not used. Files
directly in the folder and one subfolder level deep are read. Any other .png/.jpg/.jpeg image is an
albedo-only material of its own, except a set's preview image named exactly like the set.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from simtest.errors import AssetError, ConfigError
from simtest.materials.maps import MaterialMaps, encode_normal

__all__ = ["MaterialSource", "folder_materials", "load_folder_material", "IMAGE_SUFFIXES"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
_KINDS = {"color": "color", "basecolor": "color", "albedo": "color", "diffuse": "color", "diff": "color",
          "roughness": "roughness", "rough": "roughness", "normalgl": "gl", "nor_gl": "gl",
          "normaldx": "dx", "nor_dx": "dx"}
#: Maps of a set that are recognised and not used (so they do not become albedo-only materials).
_OTHER = ("displacement", "disp", "height", "ambientocclusion", "ao", "metalness", "metallic", "metal",
          "opacity", "bump", "arm", "specular", "spec", "gloss", "glossiness", "emission", "normal", "nor",
          "mask", "idmap")
_RES = r"\d+k(?:-(?:jpg|png))?"
_PATTERN = re.compile(
    rf"^(?P<name>.+?)(?:_(?P<res1>{_RES}))?_(?P<kind>{'|'.join(sorted([*_KINDS, *_OTHER], key=len, reverse=True))})"
    rf"(?:_(?P<res2>{_RES}))?$", re.IGNORECASE)


@dataclass(frozen=True)
class MaterialSource:
    """The image files of one folder material.

    Attributes:
        name: The set name (``"Wood049"`` for ``Wood049_2K_Color.jpg``) or the image stem.
        color: Absolute path of the colour / albedo image.
        roughness: Absolute path of the roughness map, or None.
        normal: Absolute path of the normal map, or None.
        normal_convention: ``"gl"`` (+y = +v) or ``"dx"`` (+y = -v) for ``normal``.
    """

    name: str
    color: str
    roughness: str | None = None
    normal: str | None = None
    normal_convention: str = "gl"


def _resolution(match: re.Match) -> int:
    tag = (match["res1"] or match["res2"] or "0k").lower()
    return int(tag.split("k")[0])


def _best(maps: dict[str, list[tuple[int, Path]]], kind: str) -> str | None:
    """The absolute path of the highest-resolution file of ``kind`` (ties: first path), or None."""
    found = sorted(maps.get(kind, []), key=lambda rp: (-rp[0], str(rp[1])))
    return str(found[0][1].resolve()) if found else None


def _images(root: Path) -> list[Path]:
    out = []
    for p in sorted(root.iterdir()):
        if p.is_dir():
            out.extend(q for q in sorted(p.iterdir()) if q.is_file() and q.suffix.lower() in IMAGE_SUFFIXES)
        elif p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES:
            out.append(p)
    return out


def folder_materials(folder: str) -> tuple[MaterialSource, ...]:
    """The materials of ``folder`` (and its subfolders one level deep), sorted by name (then colour path).

    Raises:
        ConfigError: ``folder`` is not a folder or holds no image.
    """
    root = Path(folder)
    if not root.is_dir():
        raise ConfigError(f"material folder {folder!r} is not a folder")
    images = _images(root)
    if not images:
        raise ConfigError(f"material folder {folder!r} holds no .png/.jpg/.jpeg image (also none one subfolder "
                          f"level deep)")
    sets: dict[tuple[str, str], dict[str, list[tuple[int, Path]]]] = {}
    names: dict[tuple[str, str], str] = {}
    plain: list[Path] = []
    for p in images:
        m = _PATTERN.match(p.stem)
        if m is None:
            plain.append(p)
            continue
        key = (str(p.parent), m["name"].lower())
        names.setdefault(key, m["name"])
        kind = _KINDS.get(m["kind"].lower(), "other")
        sets.setdefault(key, {}).setdefault(kind, []).append((_resolution(m), p))
    out = []
    for key, maps in sets.items():
        if "color" not in maps:
            continue                                               # maps without a colour image are ignored
        gl, dx = _best(maps, "gl"), _best(maps, "dx")
        out.append(MaterialSource(names[key], _best(maps, "color"), _best(maps, "roughness"), gl or dx,
                                  "gl" if gl or not dx else "dx"))
    taken = {(str(Path(s.color).parent), s.name.lower()) for s in out}
    out += [MaterialSource(p.stem, str(p.resolve())) for p in plain
            if (str(p.resolve().parent), p.stem.lower()) not in taken]
    return tuple(sorted(out, key=lambda s: (s.name.lower(), s.name, s.color)))


def _read(path: str) -> np.ndarray:
    """An image as float32 in [0, 1], (H, W) or (H, W, C) RGB(A) order; 8- and 16-bit files."""
    import cv2

    img = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise AssetError(f"material image {path!r} could not be read (missing, or not a PNG/JPEG image)")
    if img.dtype == np.uint8:
        f = img.astype(np.float32) / 255.0
    elif img.dtype == np.uint16:
        f = img.astype(np.float32) / 65535.0
    elif img.dtype.kind == "f":
        f = np.clip(img.astype(np.float32), 0.0, 1.0)
    else:
        raise AssetError(f"material image {path!r} has unsupported pixel type {img.dtype}; use 8- or 16-bit")
    if f.ndim == 3:
        f = f[..., :3][..., ::-1] if f.shape[2] >= 3 else f[..., 0]
    return np.ascontiguousarray(f)


def _resize(img: np.ndarray, side: int) -> np.ndarray:
    import cv2

    if img.shape[:2] == (side, side):
        return img
    shrink = max(img.shape[:2]) > side
    return cv2.resize(img, (side, side), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)


def _grey(img: np.ndarray) -> np.ndarray:
    return img[..., 0] if img.ndim == 3 else img


def load_folder_material(source: MaterialSource, size: int = 512) -> MaterialMaps:
    """The maps of ``source``: square, side ``min(size, longest side of the colour image)``.

    Missing roughness -> constant 0.6 (153); missing normal -> flat; DX normals converted to GL (green flipped);
    16-bit files scaled; grey maps stored as RGB use their first channel; maps whose size differs from the
    colour image are resized with it. ``metallic`` 0, ``specular`` 0.5, ``tile_m`` 1.0.

    Raises:
        AssetError: A file is unreadable. ConfigError: ``size`` is not an integer in [1, 16384].
    """
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or not 1 <= size <= 16384:
        raise ConfigError(f"material size {size!r} must be an integer in [1, 16384]")
    return _load(source, int(size))


@lru_cache(maxsize=32)
def _load(source: MaterialSource, size: int) -> MaterialMaps:
    colour = _read(source.color)
    side = min(size, max(colour.shape[:2]))
    if colour.ndim == 2:
        colour = np.repeat(colour[..., None], 3, axis=2)
    albedo = np.rint(_resize(colour, side) * 255.0).astype(np.uint8)
    if source.roughness is not None:
        roughness = np.rint(_resize(_grey(_read(source.roughness)), side) * 255.0).astype(np.uint8)
    else:
        roughness = np.full((side, side), 153, np.uint8)
    if source.normal is not None:
        raw = _read(source.normal)
        if raw.ndim != 3:
            raise AssetError(f"normal map {source.normal!r} has one channel; a normal map needs RGB")
        n = _resize(raw, side) * 2.0 - 1.0
        if source.normal_convention == "dx":
            n[..., 1] = -n[..., 1]
        n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-6)
        normal = encode_normal(n)
    else:
        normal = np.empty((side, side, 3), np.uint8)
        normal[...] = (128, 128, 255)
    return MaterialMaps(source.name, albedo, roughness, normal, 0.0, 0.5, 1.0)
