"""Referring expressions per annotated instance ("the small red mug left of the bowl").

Language-guided trackers need a short text description of each object, and the description must pick out
that object and no other in the scene. Everything here is a pure function of what the scene knows: the
objects' categories, the colour of their dominant appearance, their sizes and their settled poses, seen from
one camera. :func:`scene_captions` adapts a settled :class:`~simtest.generators.builder.SimScene`.

Words and how they are decided (lengths in metres, world frame Z up, camera frame OpenCV):

* **category**: the object's category name, ``_`` and ``-`` read as spaces (``soup_can`` -> "soup can").
* **colour**: the name of :data:`COLOUR_NAMES` nearest (CIELAB, Delta-E 1976) to the instance's colour. A
  plain object's colour is its material rgba; a textured or vertex/face-coloured one gets the name most of
  its surface area carries (each face coloured by its texel at the UV centroid, or the mean of its vertex
  colours, times the material tint).
* **size**: "small" when its diameter is at most 1/1.2 of every other instance of its category, "large" when
  at least 1.2 x every other one; no size word otherwise (one of its category, or no clear difference).
* **relations** (to the three nearest other instances, by centre distance, and to the table), all in the
  camera frame of the scene's **first image** (``im_id`` 0), so left and right are as seen in that image:

  - "on top of B": A's lowest point is within 2 cm of B's highest point, A's centre lies over B's footprint
    (horizontal distance below B's largest horizontal extent from its centre) and A is not on the table;
  - "on the table": A's lowest point is within 1 cm of the table top;
  - otherwise, for A and B side by side (neither on top of the other), with ``lateral`` the horizontal
    offset of the centres in the first image (normalised image x times mean depth) and ``depth`` their
    difference in camera z: "left of B" / "right of B" when ``|lateral| >= 2 cm`` and ``|lateral| >=
    |depth|``; "behind B" / "in front of B" when ``|depth| >= 2 cm`` and ``|depth| > |lateral|``.
    "left of" therefore means A's centre projects to a smaller image column ``u``, "behind" that A's centre is
    farther from the camera.

Expressions are tried shortest first (by words): the category alone, with the colour, with the size word,
with both; then each of those plus one relation to a landmark (an instance with its own shortest unique
description without relations, or the table). An expression is *unique* when exactly one instance of the
scene satisfies every word of it (the same predicates as above, evaluated for every instance). Each instance
gets up to three unique expressions, shortest first, and ``"unique": true``; when none is unique it gets its
most specific description and ``"unique": false``.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from simtest.camera import CameraModel
from simtest.render.colour import srgb_to_linear
from simtest.errors import ConfigError
from simtest.geometry import Pose
from simtest.io.files import atomic_write_json
from simtest.generators.looks import skin_of
from simtest.objects.appearance import render_texture

__all__ = ["COLOUR_NAMES", "CAPTIONS_FILE", "CaptionObject", "srgb_to_lab", "colour_name", "dominant_colour",
           "caption_category", "check_caption_objects", "relation_matrix", "caption_scene", "scene_captions",
           "write_scene_captions"]

CAPTIONS_FILE = "scene_captions.json"

#: Colour names and their prototypes in CIELAB (D65; L*, a*, b*). Hand-written on purpose: referring
#: expressions need a small, fixed vocabulary (the eleven basic colour terms of English) that never changes
#: between versions or machines, so the same seed keeps giving the same words; no colour-naming library or
#: learned model is needed, and a nearest-prototype rule in a perceptual space such as CIELAB names colours
#: much as people do. Prototypes are typical sRGB swatches converted once: red (200, 30, 30), orange
#: (240, 140, 20), yellow (240, 220, 40), green (40, 160, 50), blue (30, 70, 200), purple (120, 50, 160), pink
#: (240, 140, 180), brown (120, 75, 35), white (240, 240, 240), grey (128, 128, 128), black (20, 20, 20).
COLOUR_NAMES: dict[str, tuple[float, float, float]] = {
    "red": (43.0, 63.0, 45.0),
    "orange": (68.0, 31.0, 70.0),
    "yellow": (87.0, -10.0, 81.0),
    "green": (58.0, -54.0, 46.0),
    "blue": (36.0, 36.0, -71.0),
    "purple": (36.0, 49.0, -47.0),
    "pink": (70.0, 43.0, -4.0),
    "brown": (36.0, 15.0, 31.0),
    "white": (95.0, 0.0, 0.0),
    "grey": (54.0, 0.0, 0.0),
    "black": (6.0, 0.0, 0.0),
}
_NAMES = tuple(COLOUR_NAMES)
_PROTOTYPES = np.array([COLOUR_NAMES[n] for n in _NAMES])

#: Category names that say nothing about the object (loader placeholders).
_PLACEHOLDERS = frozenset({"obj", "object", "objects", "mesh", "model", "item", "part"})

SIZE_RATIO = 1.2  # size words need this ratio of diameters to every other instance of the category
CONTACT_TOL = 0.02  # m: "on top of" gap between A's bottom and B's top
TABLE_TOL = 0.01  # m: "on the table" gap between the lowest point and the table top
SIDE_MIN = 0.02  # m: smallest lateral / depth separation for left/right/behind/in front
NEIGHBOURS = 3  # landmarks per instance: the nearest other instances

_REL_ORDER = ("left of", "right of", "behind", "in front of", "on top of")


@dataclass(frozen=True)
class CaptionObject:
    """What the captions know of one annotated instance (world frame, metres).

    Attributes:
        gt_id: Index of the instance in every image's ``scene_gt.json`` list.
        obj_id: Object id.
        category: Category words ("mug").
        colour: Colour name (a key of :data:`COLOUR_NAMES`).
        rgb: The sRGB colour (each in [0, 1]) the name was taken from.
        diameter: Object diameter, metres.
        centre: (3,) model-frame origin (the 3D bbox centre) in the world.
        z_min, z_max: Lowest and highest point of the posed mesh (world z).
        radius_xy: Largest horizontal distance of a mesh point from ``centre``.
    """

    gt_id: int
    obj_id: int
    category: str
    colour: str
    rgb: tuple[float, float, float]
    diameter: float
    centre: tuple[float, float, float]
    z_min: float
    z_max: float
    radius_xy: float


# ---------------------------------------------------------------------------------------------------------
# Colour
def srgb_to_lab(rgb: np.ndarray) -> np.ndarray:
    """CIELAB (D65) of sRGB colours ``(..., 3)`` in [0, 1]."""
    lin = srgb_to_linear(rgb)
    m = np.array([[0.4124564, 0.3575761, 0.1804375], [0.2126729, 0.7151522, 0.0721750],
                  [0.0193339, 0.1191920, 0.9503041]])
    xyz = lin @ m.T / np.array([0.95047, 1.0, 1.08883])
    f = np.where(xyz > (6 / 29) ** 3, np.cbrt(xyz), xyz / (3 * (6 / 29) ** 2) + 4 / 29)
    return np.stack([116 * f[..., 1] - 16, 500 * (f[..., 0] - f[..., 1]), 200 * (f[..., 1] - f[..., 2])], -1)


def _name_index(rgb: np.ndarray) -> np.ndarray:
    """Index into :data:`COLOUR_NAMES` of the nearest prototype of each colour ``(..., 3)``."""
    lab = srgb_to_lab(rgb)
    return np.argmin(np.linalg.norm(lab[..., None, :] - _PROTOTYPES, axis=-1), axis=-1)


def colour_name(rgb: Sequence[float]) -> str:
    """The name of :data:`COLOUR_NAMES` nearest to one sRGB colour (each in [0, 1])."""
    return _NAMES[int(_name_index(np.asarray(rgb, dtype=np.float64)[:3]))]


def _face_colours(obj, texture: np.ndarray | None = None) -> np.ndarray | None:
    """(M, 3) colour in [0, 1] of each face of a textured / vertex- or face-coloured object, else None: the
    texel the renderer draws at the face's UV centroid (:func:`~simtest.objects.appearance.render_texture`, which
    bakes vertex and face colours into one texel per face); ``texture`` replaces the object's own texture (an
    instance's print variant on the same UVs)."""
    drawn = None if obj.appearance is None else render_texture(obj.appearance, obj.faces)
    if drawn is None:
        return None
    tex, face_uv = drawn
    if texture is not None:
        tex = texture
    h, w = tex.shape[:2]
    uv = np.mod(face_uv.mean(axis=1), 1.0)  # UV centroid per face, wrapped
    col = np.clip(np.floor(uv[:, 0] * w).astype(np.int64), 0, w - 1)
    row = np.clip(np.floor((1.0 - uv[:, 1]) * h).astype(np.int64), 0, h - 1)  # v up, row 0 at the top
    return tex[row, col].astype(np.float64) / 255.0


def dominant_colour(obj, rgba: Sequence[float], texture: np.ndarray | None = None
                    ) -> tuple[str, tuple[float, float, float]]:
    """``(name, rgb)`` of the colour most of an instance's surface shows.

    Args:
        obj: The :class:`~simtest.objects.ObjectModel` (its ``appearance``, faces and face areas); None for an
            instance drawn in its material colour alone.
        rgba: The instance's material colour (it tints a texture or vertex colours), each in [0, 1].
        texture: The instance's own texture when it differs from the object's (a print variant, same UVs).

    Returns:
        The winning name (area-weighted vote over faces) and the area-weighted mean sRGB of the faces that
        carry it; for a plain object, the name of ``rgba`` and ``rgba[:3]``.
    """
    tint = np.asarray(rgba, dtype=np.float64)[:3]
    faces = None if obj is None else _face_colours(obj, texture)
    if faces is None:
        return colour_name(tint), tuple(float(v) for v in tint)
    faces = faces * tint
    areas = np.asarray(obj.mesh.area_faces, dtype=np.float64)
    names = _name_index(faces)
    votes = np.bincount(names, weights=areas, minlength=len(_NAMES))
    best = int(np.argmax(votes))
    sel = names == best
    mean = (faces[sel] * areas[sel, None]).sum(axis=0) / max(float(areas[sel].sum()), 1e-12)
    return _NAMES[best], tuple(float(v) for v in mean)


# ---------------------------------------------------------------------------------------------------------
# Categories
def caption_category(name: str) -> str | None:
    """The words a category name gives in a caption (``soup_can`` -> ``soup can``), or None when it names no
    kind of thing (empty, a placeholder such as ``obj``, digits or other characters than letters)."""
    words = re.sub(r"[_\-]+", " ", str(name)).strip().lower()
    if not re.fullmatch(r"[a-z]+( [a-z]+)*", words) or len(words.replace(" ", "")) < 2 or words in _PLACEHOLDERS:
        return None
    return words


def check_caption_objects(objects, field: str = "captions") -> None:
    """Raise :class:`ConfigError` unless every object of the set has a usable category name.

    The error names the config field, the objects and their categories, and how to give categories.
    """
    bad = [o for o in objects if caption_category(o.category) is None]
    if bad:
        listed = ", ".join(f"{o.name} (obj_id {o.obj_id}, category {o.category!r})" for o in bad[:6])
        more = f" and {len(bad) - 6} more" if len(bad) > 6 else ""
        raise ConfigError(f"{field} = true needs a category name (letters, e.g. 'mug' or 'soup_can') for every "
                          f"object; object set {getattr(objects, 'name', '?')!r} has none usable for {listed}{more}; "
                          "give categories with category folders (category/instance.ext) or 'category' in "
                          "objects.toml")


# ---------------------------------------------------------------------------------------------------------
# Attributes and relations
def _size_words(objs: Sequence[CaptionObject]) -> list[str | None]:
    """"small" / "large" / None per instance (see the module doc)."""
    out: list[str | None] = []
    for a in objs:
        others = [b.diameter for b in objs if b is not a and b.category == a.category]
        word = None
        if others and a.diameter * SIZE_RATIO <= min(others):
            word = "small"
        elif others and a.diameter >= SIZE_RATIO * max(others):
            word = "large"
        out.append(word)
    return out


def _on_top(a: CaptionObject, b: CaptionObject, table_height: float) -> bool:
    """Whether ``a`` rests on ``b`` (see the module doc)."""
    dxy = float(np.hypot(a.centre[0] - b.centre[0], a.centre[1] - b.centre[1]))
    return (abs(a.z_min - b.z_max) <= CONTACT_TOL and dxy <= b.radius_xy and a.centre[2] > b.centre[2]
            and a.z_min - table_height > TABLE_TOL)


def relation_matrix(objs: Sequence[CaptionObject], T_cam_world, table_height: float) -> list[list[str | None]]:
    """``rel[i][j]``: the relation of instance ``i`` to instance ``j`` (None: none, and on the diagonal).

    Args:
        objs: The instances.
        T_cam_world: :class:`~simtest.geometry.Pose` of the reference (first) camera.
        table_height: World z of the table top, metres.
    """
    n = len(objs)
    pc = T_cam_world.apply(np.array([o.centre for o in objs], dtype=np.float64).reshape(n, 3))
    rel: list[list[str | None]] = [[None] * n for _ in range(n)]
    for i in range(n):
        for j in range(n):
            if i == j:
                continue
            a, b = objs[i], objs[j]
            if _on_top(a, b, table_height):
                rel[i][j] = "on top of"
                continue
            if _on_top(b, a, table_height):
                continue
            lateral = (pc[j, 0] / pc[j, 2] - pc[i, 0] / pc[i, 2]) * 0.5 * (pc[i, 2] + pc[j, 2])  # > 0: i left
            depth = pc[i, 2] - pc[j, 2]  # > 0: i farther
            if abs(lateral) >= SIDE_MIN and abs(lateral) >= abs(depth):
                rel[i][j] = "left of" if lateral > 0 else "right of"
            elif abs(depth) >= SIDE_MIN and abs(depth) > abs(lateral):
                rel[i][j] = "behind" if depth > 0 else "in front of"
    return rel


def _on_table(o: CaptionObject, table_height: float) -> bool:
    return o.z_min - table_height <= TABLE_TOL


# ---------------------------------------------------------------------------------------------------------
# Expressions
@dataclass(frozen=True)
class _Desc:
    """A description: attribute words plus at most one relation (to instance ``landmark``, or the table)."""

    colour: str | None
    size: str | None
    relation: str | None = None
    landmark: int | None = None  # instance index; None with relation "on": the table
    landmark_text: str = ""

    def text(self, category: str) -> str:
        words = ["the"] + [w for w in (self.size, self.colour) if w] + [category]
        if self.relation == "on":
            words += ["on the table"]
        elif self.relation is not None:
            words += [self.relation, self.landmark_text]
        return " ".join(words)


def _matches(d: _Desc, k: int, cat: str, objs, sizes, rel, on_table) -> bool:
    o = objs[k]
    if o.category != cat or (d.colour and o.colour != d.colour) or (d.size and sizes[k] != d.size):
        return False
    if d.relation == "on":
        return on_table[k]
    if d.relation is not None:
        return k != d.landmark and rel[k][d.landmark] == d.relation
    return True


def _attribute_descs(i: int, objs, sizes) -> list[_Desc]:
    o = objs[i]
    out = [_Desc(None, None), _Desc(o.colour, None)]
    if sizes[i]:
        out += [_Desc(None, sizes[i]), _Desc(o.colour, sizes[i])]
    return out


def _count(d: _Desc, cat: str, objs, sizes, rel, on_table) -> int:
    return sum(_matches(d, k, cat, objs, sizes, rel, on_table) for k in range(len(objs)))


def _landmark_text(j: int, objs, sizes, rel, on_table) -> str | None:
    """Shortest unique description of ``j`` without relations, or None."""
    cat = objs[j].category
    for d in _attribute_descs(j, objs, sizes):
        if _count(d, cat, objs, sizes, rel, on_table) == 1:
            return d.text(cat)
    return None


def _neighbours(i: int, objs: Sequence[CaptionObject]) -> list[int]:
    """The :data:`NEIGHBOURS` nearest other instances (centre distance; ties by index)."""
    c = np.array([o.centre for o in objs])
    d = np.linalg.norm(c - c[i], axis=1)
    order = sorted((float(d[j]), j) for j in range(len(objs)) if j != i)
    return [j for _, j in order[:NEIGHBOURS]]


def caption_scene(objs: Sequence[CaptionObject], camera: CameraModel, table_height: float) -> dict:
    """Attributes, relations and referring expressions of every instance (see the module doc).

    Args:
        objs: The annotated instances, in ``gt_id`` order.
        camera: The reference camera (the first image's; its ``T_world_cam`` decides left/right and depth).
        table_height: World z of the table top, metres.

    Returns:
        ``{"reference_im_id": 0, "frame": ..., "instances": {"<gt_id>": {...}}}`` ready for JSON.
    """
    sizes = _size_words(objs)
    rel = relation_matrix(objs, camera.T_cam_world, table_height)
    on_table = [_on_table(o, table_height) for o in objs]
    landmarks = [_landmark_text(j, objs, sizes, rel, on_table) for j in range(len(objs))]
    out: dict[str, dict] = {}
    for i, o in enumerate(objs):
        relations = []
        for j in _neighbours(i, objs):
            if rel[i][j] is not None:
                relations.append((rel[i][j], j))
        relations.sort(key=lambda r: _REL_ORDER.index(r[0]))
        records = [{"relation": r, "gt_id": objs[j].gt_id, "obj_id": objs[j].obj_id, "landmark": landmarks[j]}
                   for r, j in relations]
        if on_table[i]:
            records.append({"relation": "on", "gt_id": None, "obj_id": None, "landmark": "the table"})
        attrs = _attribute_descs(i, objs, sizes)
        cands = list(attrs)
        for a in attrs:
            cands += [_Desc(a.colour, a.size, r, j, landmarks[j]) for r, j in relations if landmarks[j]]
            if on_table[i]:
                cands.append(_Desc(a.colour, a.size, "on"))
        texts = [(len(d.text(o.category).split()), n, d) for n, d in enumerate(cands)]
        unique = [d for _, _, d in sorted(texts, key=lambda t: t[:2])
                  if _count(d, o.category, objs, sizes, rel, on_table) == 1]
        if unique:
            expressions = [d.text(o.category) for d in unique[:3]]
        else:
            full = attrs[-1]
            rich = [d for d in cands if d.colour == full.colour and d.size == full.size and d.relation]
            expressions = [(rich[0] if rich else full).text(o.category)]
        out[str(o.gt_id)] = {
            "obj_id": o.obj_id, "category": o.category, "colour": o.colour, "rgb": [round(v, 4) for v in o.rgb],
            "size": sizes[i], "diameter_m": round(o.diameter, 5), "relations": records,
            "expressions": expressions, "unique": bool(unique)}
    return {"reference_im_id": 0,
            "frame": "camera of image 0 (OpenCV): left/right = image columns, behind/in front = camera depth",
            "instances": out}


# ---------------------------------------------------------------------------------------------------------
# Scene adapter
def scene_captions(scene, objects, camera: CameraModel, table_height: float) -> dict:
    """:func:`caption_scene` of a settled scene's annotated (active) instances, seen from ``camera``.

    ``gt_id`` is the rank of the instance among the active ones, as in every image's ``scene_gt.json``; the
    colour is the instance's material rgba from the scene spec (with the object's texture or vertex colours, or
    the instance's print variant).
    """
    objs = []
    active = [i for i, a in enumerate(scene.active) if a]
    for gt_id, i in enumerate(active):
        oid = scene.instance_obj_ids[i]
        obj = objects.get(oid)
        R, t = scene.object_pose_world(i)
        pts = Pose(R, t).apply(obj.vertices)
        placement = scene.spec.objects[i]
        skin = skin_of(obj, placement.skin_seed)
        name, rgb = (dominant_colour(None, placement.rgba) if placement.plain
                     else dominant_colour(obj, placement.rgba, None if skin is None else skin.albedo))
        objs.append(CaptionObject(
            gt_id=gt_id, obj_id=int(oid), category=caption_category(obj.category) or obj.category, colour=name,
            rgb=rgb, diameter=float(obj.diameter), centre=tuple(float(v) for v in t),
            z_min=float(pts[:, 2].min()), z_max=float(pts[:, 2].max()),
            radius_xy=float(np.linalg.norm(pts[:, :2] - t[:2], axis=1).max())))
    return caption_scene(objs, camera, table_height)


def write_scene_captions(scene_dir: str | Path, scene, objects, camera: CameraModel, table_height: float) -> Path:
    """Write :data:`CAPTIONS_FILE` (atomically) into ``scene_dir``; returns its path."""
    path = Path(scene_dir) / CAPTIONS_FILE
    atomic_write_json(path, scene_captions(scene, objects, camera, table_height))
    return path
