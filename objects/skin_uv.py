"""UV layouts of the built-in objects' skins: a category's mesh, unchanged, mapped into its atlas.

Images: row 0 at the top; UVs: ``v`` up, origin bottom-left. Atlases are cut into regions (``LAYOUTS``); a face
maps into one region, inset by ``INSET``. Bodies of revolution: the side goes into ``side`` cylindrically (``u``
= azimuth over ``1 + WRAP`` turns, a face across the seam gets ``+1`` turn on its small azimuths; ``v`` = height
through the fixed ``SIDE_BANDS``: the can's rims, the bottle's shoulder and cap, the marker's cap from
``params["cap_length"]``), caps, insides and the mug's handle planar into theirs. Box: one cell per face
(``front`` / ``back`` = +x / -x). Banana: ``u`` along (0 tip, 1 stem), ``v`` around (``1 + WRAP`` turns). Drill:
triplanar per part. The textures drawn into these regions: :mod:`simtest.objects.skins`.
"""

from __future__ import annotations

import numpy as np
import trimesh

from simtest.errors import AssetError

__all__ = ["CATEGORIES", "LAYOUTS", "SIDE_BANDS", "INSET", "WRAP", "skin_uv"]

#: The categories of built-in objects that have a UV layout.
CATEGORIES = ("can", "bottle", "mug", "bowl", "cup", "box", "marker", "banana", "drill")

#: Atlas regions ``(u0, v0, u1, v1)`` per layout (UV units, v up).
LAYOUTS: dict[str, dict[str, tuple[float, float, float, float]]] = {
    "revolution": {"side": (0.0, 0.25, 1.0, 1.0), "top": (0.0, 0.0, 0.25, 0.25), "bottom": (0.25, 0.0, 0.5, 0.25),
                   "inside": (0.5, 0.0, 0.75, 0.25), "extra": (0.75, 0.0, 1.0, 0.25)},
    "carton": {"front": (0.0, 0.5, 0.375, 1.0), "back": (0.375, 0.5, 0.75, 1.0), "right": (0.75, 0.5, 1.0, 1.0),
               "left": (0.75, 0.0, 1.0, 0.5), "top": (0.0, 0.0, 0.375, 0.5), "bottom": (0.375, 0.0, 0.75, 0.5)},
    "banana": {"peel": (0.0, 0.0, 1.0, 1.0)},
    "drill": {"body": (0.0, 0.5, 0.5, 1.0), "handle": (0.5, 0.5, 1.0, 1.0), "battery": (0.0, 0.0, 0.5, 0.5),
              "chuck": (0.5, 0.0, 1.0, 0.5)},
}
#: Inset of every face's UVs from its region's border, as a fraction of the region.
INSET = 0.02
#: Extra turns the ``side`` region spans beyond one (room for faces across the azimuth seam).
WRAP = 0.125
#: Side heights (v in the side region, 0 bottom .. 1 top) of the fixed height knots of each category.
SIDE_BANDS = {"can": (0.05, 0.95), "bottle": (0.6, 0.8, 0.85), "marker": (0.12, 0.6), "vessel": (0.05,)}


def _to_region(local: np.ndarray, rect: tuple[float, float, float, float]) -> np.ndarray:
    """Face-local coordinates (..., 2) in [0, 1] -> atlas UVs inside ``rect``, inset by ``INSET``."""
    u0, v0, u1, v1 = rect
    k = INSET + (1 - 2 * INSET) * np.clip(local, 0.0, 1.0)
    return np.stack([u0 + (u1 - u0) * k[..., 0], v0 + (v1 - v0) * k[..., 1]], axis=-1)


def _param(params: dict, key: str, category: str) -> float:
    try:
        return float(params[key])
    except (KeyError, TypeError, ValueError):
        raise AssetError(f"skin_uv: category {category!r} needs params[{key!r}] (a number, metres or a fraction "
                         f"as the builder stores it), got params={params!r}") from None


def _unwrap(turns: np.ndarray) -> np.ndarray:
    """Per face (rows of 3 corners), add one turn to the small values of a face that straddles the seam."""
    turns = turns.copy()
    straddle = (turns.max(axis=1) - turns.min(axis=1)) > 0.5
    turns[straddle] += (turns[straddle] < 0.5)
    return turns


def _revolution_uv(category: str, mesh: trimesh.Trimesh, params: dict) -> np.ndarray:
    P = np.asarray(mesh.vertices, dtype=np.float64)[np.asarray(mesh.faces)]
    lo, hi = np.asarray(mesh.bounds, dtype=np.float64)
    axis = np.array([lo[0] + _param(params, "radius", category) if category == "mug" else 0.0, 0.0])
    n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-18)
    rel = P[..., :2] - axis  # (M, 3, 2) corners about the axis
    rel_c = rel.mean(axis=1)
    rc = np.linalg.norm(rel_c, axis=1)
    nr = (n[:, :2] * rel_c).sum(axis=1) / np.maximum(rc, 1e-12)
    radius = _param(params, "radius", category) if category == "mug" else float(np.linalg.norm(rel, axis=2).max())
    region = np.zeros(len(P), dtype=np.int64)  # 0 side, 1 top, 2 bottom, 3 inside, 4 extra
    if category in ("mug", "bowl", "cup"):
        region[:] = 3
        handle = rc > radius + 5e-4
        top = ~handle & (n[:, 2] > 0.45) & (P[:, :, 2].mean(axis=1) > hi[2] - 0.0025)
        side = ~handle & ~top & (nr > 0.2)
        region[side], region[top], region[handle] = 0, 1, 4
        region[~handle & ~top & ~side & (n[:, 2] < -0.5)] = 2
        foot = (radius - 0.004 if category == "mug" else _param(params, "foot_radius", category)
                if category == "bowl" else _param(params, "bottom_radius", category) - 0.004)
        r_knots, rr_knots = [0.0, foot, max(radius, foot + 1e-4)], [0.0, 0.8, 1.0]
    else:
        region[(nr <= 0.5) & (n[:, 2] > 0)] = 1
        region[(nr <= 0.5) & (n[:, 2] <= 0)] = 2
        r_knots, rr_knots = [0.0, radius], [0.0, 1.0]
    uv = np.zeros((len(P), 3, 2))
    turns = _unwrap((np.arctan2(rel[..., 1], rel[..., 0]) / (2 * np.pi)) % 1.0)
    height, v_knots = float(hi[2] - lo[2]), [0.0, *SIDE_BANDS.get(category, SIDE_BANDS["vessel"]), 1.0]
    if category == "can":
        z_knots = [0.0, 0.003, height - 0.003, height]
    elif category in ("bottle", "marker"):  # shoulder, neck and cap; the marker's tip cone and cap
        z_knots = ([_param(params, k, category) * height for k in ("shoulder", "neck")] if category == "bottle"
                   else [0.018]) + [height - _param(params, "cap_height" if category == "bottle" else "cap_length",
                                                    category)]
        z_knots = [0.0, *z_knots, height]
    else:
        z_knots = [0.0, 0.006 if category == "bowl" else 0.004, height]
    side_local = np.stack([turns / (1 + WRAP), np.interp(P[..., 2] - lo[2], z_knots, v_knots)], axis=-1)
    r = np.linalg.norm(rel, axis=2, keepdims=True)
    disc = 0.5 + 0.5 * np.interp(r, r_knots, rr_knots) * rel / np.maximum(r, 1e-12)
    hp = P[..., [0, 2]]
    if (region == 4).any():
        hlo, hhi = hp[region == 4].min(axis=(0, 1)), hp[region == 4].max(axis=(0, 1))
        hp = (hp - hlo) / np.maximum(hhi - hlo, 1e-9)
    for code, name, local in ((0, "side", side_local), (1, "top", disc), (2, "bottom", disc), (3, "inside", disc),
                              (4, "extra", hp)):
        sel = region == code
        uv[sel] = _to_region(local[sel], LAYOUTS["revolution"][name])
    return uv


def _box_uv(mesh: trimesh.Trimesh) -> np.ndarray:
    P = np.asarray(mesh.vertices, dtype=np.float64)[np.asarray(mesh.faces)]
    lo, hi = np.asarray(mesh.bounds, dtype=np.float64)
    q = (P - lo) / np.maximum(hi - lo, 1e-12)
    n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    axis = np.abs(n).argmax(axis=1)
    positive = n[np.arange(len(n)), axis] > 0
    x, y, z = q[..., 0], q[..., 1], q[..., 2]
    faces = {(0, True): ("front", y, z), (0, False): ("back", 1 - y, z), (1, True): ("right", 1 - x, z),
             (1, False): ("left", x, z), (2, True): ("top", y, 1 - x), (2, False): ("bottom", y, x)}
    uv = np.zeros((len(P), 3, 2))
    for (ax, pos), (name, s, t) in faces.items():
        sel = (axis == ax) & (positive == pos)
        uv[sel] = _to_region(np.stack([s[sel], t[sel]], axis=-1), LAYOUTS["carton"][name])
    return uv


def _banana_uv(mesh: trimesh.Trimesh, sides: int = 16) -> np.ndarray:
    """From the swept tube's vertex order: apex, ``m`` rings of ``sides`` vertices, apex."""
    nv, f = len(mesh.vertices), np.asarray(mesh.faces)
    m = (nv - 2) // sides
    if (nv - 2) % sides or m < 2:
        raise AssetError(f"skin_uv: a banana mesh is a swept tube of 2 + m * {sides} vertices, got {nv}")
    pole = (f == 0) | (f == nv - 1)
    s = np.where(f == 0, 0.0, np.where(f == nv - 1, 1.0, ((f - 1) // sides + 1) / (m + 1)))
    t = np.where(pole, np.nan, ((f - 1) % sides) / sides)
    t = _unwrap(np.where(pole, np.nanmean(np.where(pole, np.nan, t), axis=1, keepdims=True), t))
    t = np.where(pole, np.nanmean(np.where(pole, np.nan, t), axis=1, keepdims=True), t)
    return _to_region(np.stack([s, t / (1 + WRAP)], axis=-1), LAYOUTS["banana"]["peel"])


def _drill_uv(mesh: trimesh.Trimesh, params: dict) -> np.ndarray:
    """Parts from the builder's layout (motor axis along x at the top, chuck at +x, battery at the bottom),
    each triplanar-projected (the two axes across the face's dominant normal) into its own region."""
    P = np.asarray(mesh.vertices, dtype=np.float64)[np.asarray(mesh.faces)]
    lo, hi = np.asarray(mesh.bounds, dtype=np.float64)
    rb, c = _param(params, "body_radius", "drill"), P.mean(axis=1)
    chuck = c[:, 0] > hi[0] - (_param(params, "chuck_length", "drill") - 0.003) + 1e-4
    battery = ~chuck & (c[:, 2] < lo[2] + 0.035 + 1e-4)
    body = ~chuck & ~battery & (np.hypot(c[:, 1], c[:, 2] - (hi[2] - rb)) < 1.02 * rb)
    n = np.abs(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])).argmax(axis=1)
    pairs = np.array([[1, 2], [0, 2], [0, 1]])[n]  # (M, 2) the axes across the dominant normal
    proj = np.take_along_axis(P, np.repeat(pairs[:, None, :], 3, axis=1), axis=2)
    uv = np.zeros((len(P), 3, 2))
    for name, sel in (("chuck", chuck), ("battery", battery), ("body", body), ("handle", ~(chuck | battery | body))):
        if sel.any():
            plo = P[sel].min(axis=(0, 1))
            span = np.maximum(P[sel].max(axis=(0, 1)) - plo, 1e-9)
            a0, a1 = pairs[sel, 0][:, None], pairs[sel, 1][:, None]
            local = np.stack([(proj[sel, :, 0] - plo[a0]) / span[a0], (proj[sel, :, 1] - plo[a1]) / span[a1]], -1)
            uv[sel] = _to_region(local, LAYOUTS["drill"][name])
    return uv


def skin_uv(category: str, mesh: trimesh.Trimesh, params: dict) -> np.ndarray:
    """Face-corner UVs (M, 3, 2) in [0, 1] (v up) of a built-in category's mesh into its skin atlas.

    Args:
        category: One of :data:`CATEGORIES`.
        mesh: The category's mesh in its model frame (origin at the bbox centre, z up, metres), as built.
        params: The instance's jittered shape parameters (``ObjectModel.extra["params"]``).

    Raises:
        AssetError: Unknown category, or a mesh / params the category's layout cannot map.
    """
    if category not in CATEGORIES:
        raise AssetError(f"skin_uv: unknown category {category!r}; known: {', '.join(CATEGORIES)}")
    if category in ("box", "banana"):
        return np.clip(_box_uv(mesh) if category == "box" else _banana_uv(mesh), 0.0, 1.0)
    return np.clip(_drill_uv(mesh, params) if category == "drill" else _revolution_uv(category, mesh, params), 0, 1)
