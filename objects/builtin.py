"""The built-in procedural object set: YCB-like household objects generated from a seed.

Nine categories with three instances each (different nominal shape parameters, jittered by the seed):

=====  ============  =========  ===========================================================
ids    category      concave    symmetry (exact by construction, model frame)
=====  ============  =========  ===========================================================
1-3    can           no         continuous about z through the origin
4-6    bottle        no         continuous about z through the origin
7-9    mug           yes        none (the handle breaks it)
10-12  bowl          yes        continuous about z through the origin
13-15  box           no         discrete: rotations by pi about x, y, z (box_2 has a square
                                cross-section: the 8-element dihedral group about z)
16-18  cup           yes        continuous about z through the origin
19-21  marker        no         continuous about z through the origin
22-24  banana        yes        none
25-27  drill         yes        none
=====  ============  =========  ===========================================================

Object ids are fixed by this order (category order, then instance) and do not depend on the seed; names
are ``<category>_<instance>`` (``can_0`` ...). ``builtin-small`` holds ``box_0``, ``can_0``, ``mug_0`` and
``banana_0`` with the same ids as in ``builtin``.

Every mesh is watertight, in metres, Z up, with its origin at the centre of its axis-aligned bounding box.
Bodies of revolution use a multiple of 4 segments, so the bbox stays centred on the axis and the
continuous symmetry has zero offset. The discretisation (48 segments) deviates from the ideal surface of
revolution by less than 0.15 mm, well below the 1 mm tolerance the symmetry tests use.

The seed changes shape parameters (about +-6 %) and colours; the same seed gives byte-identical vertices.
Densities are chosen per category so that masses are plausible (about 50 g to 1 kg).

Every object wears the default skin of its category (:mod:`simtest.objects.skins`: printed labels, cartons,
glazed ceramics, a banana peel, a two-tone drill, capped markers) as a texture with face-corner UVs on the mesh
above, unchanged. The texture carries the colour, so ``rgba`` is white (MuJoCo multiplies the two; a scene's
per-instance tint multiplies it too); ``extra["skin"]`` holds ``family``, ``base_rgb`` (the colour the seed
drew, the dominant colour of the print, sRGB in [0, 1]) and the skin ``seed`` (drawn from its own stream
``default_rng([seed, category index, instance, 7])``), so ``skins.skin(category, base_rgb, other_seed)`` gives
other variants of the same object.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import trimesh

from simtest.errors import AssetError
import simtest.objects.shapes as shapes
import simtest.objects.skins as skins
from simtest.objects.appearance import Appearance
from simtest.objects.model import ContinuousSymmetry, ObjectModel, ObjectSet

__all__ = ["load_builtin", "BUILTIN_SETS", "CATEGORIES", "SMALL_NAMES", "build_object"]

#: Segments of every body of revolution (multiple of 4: keeps the bbox centred on the axis).
SEGMENTS = 48
#: Relative jitter of shape parameters drawn from the seed.
JITTER = 0.06

Z_SYMMETRY = (ContinuousSymmetry(axis=(0.0, 0.0, 1.0), offset=(0.0, 0.0, 0.0)),)


@dataclass(frozen=True)
class Shape:
    """What a category builder returns: the raw mesh (any origin) and its symmetries about the bbox centre."""

    mesh: trimesh.Trimesh
    symmetries_discrete: tuple[np.ndarray, ...] = ()
    symmetries_continuous: tuple[ContinuousSymmetry, ...] = ()
    params: dict | None = None


@dataclass(frozen=True)
class Category:
    """A procedural category.

    Attributes:
        name: Category name, also the name prefix.
        build: ``build(params, rng) -> Shape``; ``params`` are the jittered nominal parameters (metres).
        instances: Nominal parameters (metres) of each instance.
        density: kg/m^3.
        palette: Plausible base colours (RGB in [0, 1]); the seed picks one and jitters it.
        concave: Whether collision needs a convex decomposition (False: the convex hull is close enough,
            e.g. the shallow end recesses of a can or the neck of a bottle).
    """

    name: str
    build: Callable[[dict, np.random.Generator], Shape]
    instances: tuple[dict, ...]
    density: float
    palette: tuple[tuple[float, float, float], ...]
    concave: bool


def _jitter(params: dict, rng: np.random.Generator) -> dict:
    """Each float parameter scaled by ``1 + U(-JITTER, JITTER)`` (keys in sorted order, for determinism)."""
    out = {}
    for key in sorted(params):
        val = params[key]
        out[key] = float(val * (1.0 + rng.uniform(-JITTER, JITTER))) if isinstance(val, float) else val
    return out


# --- categories ------------------------------------------------------------------------------------------------

def _can(p: dict, rng: np.random.Generator) -> Shape:
    """A food can: a cylinder with a rolled rim at both ends, top and bottom alike (as real cans' seams are),
    so the shape is symmetric under any turn about z and under the half turn about x that swaps the ends."""
    r, h = p["radius"], p["height"]
    bottom = [(0, 0.003), (r - 0.006, 0.003), (r - 0.004, 0.0), (r - 0.0015, 0.0), (r, 0.003)]
    prof = bottom + [(x, h - z) for x, z in reversed(bottom)]
    flip = np.diag([1.0, -1.0, -1.0, 1.0])  # half turn about x through the bbox centre
    return Shape(shapes.lathe(np.array(prof), SEGMENTS), (flip,), Z_SYMMETRY)


def _bottle(p: dict, rng: np.random.Generator) -> Shape:
    r, h, rn = p["radius"], p["height"], p["neck_radius"]
    z_sh, z_neck, cap_h = p["shoulder"] * h, p["neck"] * h, p["cap_height"]
    rc = rn + 0.0015
    prof = [(0, 0.0), (r - 0.005, 0.0), (r - 0.0015, 0.0015), (r, 0.005), (r, z_sh)]
    for t in np.linspace(0, 1, 7)[1:]:
        prof.append((rn + (r - rn) * 0.5 * (1 + np.cos(np.pi * t)), z_sh + (z_neck - z_sh) * t))
    zc = h - cap_h
    prof += [(rn, zc), (rc, zc), (rc, h - 0.0015), (rc - 0.0015, h), (0, h)]
    return Shape(shapes.lathe(np.array(prof), SEGMENTS), (), Z_SYMMETRY)


def _vessel_profile(r_bot: float, r_top: float, h: float, wall: float, bottom: float) -> list:
    """Profile (r, z) of an open straight-walled vessel: outer wall up, rounded rim, inner wall down."""
    return [(0, 0.0), (r_bot - 0.004, 0.0), (r_bot, 0.004), (r_top, h - 0.002), (r_top - 0.0012, h),
            (r_top - wall + 0.0012, h), (r_top - wall, h - 0.002),
            (r_bot - wall + (r_top - r_bot) * (bottom + 0.004) / h, bottom + 0.004),
            (r_bot - wall - 0.004 + (r_top - r_bot) * bottom / h, bottom), (0, bottom)]


def _mug(p: dict, rng: np.random.Generator) -> Shape:
    r, h, wall = p["radius"], p["height"], p["wall"]
    body = shapes.lathe(np.array(_vessel_profile(r, r, h, wall, p["bottom"])), SEGMENTS)
    # Handle: an elliptical C-shaped tube in the xz plane on the +x side, its ends buried in the wall.
    a, b = p["handle_reach"], p["handle_span"] / 2
    zc = p["handle_center"] * h
    th = np.linspace(np.pi / 2, -np.pi / 2, 21)
    x0 = r - 0.4 * wall
    centers = np.stack([x0 + a * np.cos(th), np.zeros_like(th), zc + b * np.sin(th)], axis=1)
    tangents = np.stack([-a * np.sin(th), np.zeros_like(th), b * np.cos(th)], axis=1)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    binormals = np.tile([0.0, 1.0, 0.0], (len(th), 1))
    normals = np.cross(binormals, tangents)
    handle = shapes.sweep_tube(centers, normals, binormals, np.full(len(th), p["handle_thick"] / 2),
                               np.full(len(th), p["handle_width"] / 2), sides=12)
    return Shape(shapes.union(body, handle), (), ())


def _bowl(p: dict, rng: np.random.Generator) -> Shape:
    r, h, rf, wall, bottom = p["radius"], p["height"], p["foot_radius"], p["wall"], p["bottom"]
    foot = 0.006
    t = np.linspace(0, 1, 9)[1:]
    outer = [(rf + (r - rf) * np.sin(np.pi / 2 * s), foot + (h - foot) * (1 - np.cos(np.pi / 2 * s))) for s in t]
    inner = [(rf - wall + (r - rf) * np.sin(np.pi / 2 * s), bottom + (h - bottom) * (1 - np.cos(np.pi / 2 * s)))
             for s in t[::-1]]
    inner[0] = (r - wall, h - 0.0015)
    outer[-1] = (r, h - 0.0015)
    prof = [(0, 0.0), (rf, 0.0), (rf, foot)] + outer + [(r - 0.0012, h), (r - wall + 0.0012, h)] + inner
    prof += [(rf - wall, bottom), (0, bottom)]
    return Shape(shapes.lathe(np.array(prof), SEGMENTS), (), Z_SYMMETRY)


def _cup(p: dict, rng: np.random.Generator) -> Shape:
    prof = _vessel_profile(p["bottom_radius"], p["top_radius"], p["height"], p["wall"], p["bottom"])
    return Shape(shapes.lathe(np.array(prof), SEGMENTS), (), Z_SYMMETRY)


def _box(p: dict, rng: np.random.Generator) -> Shape:
    if p.get("square"):
        size = np.array([p["width"], p["width"], p["height"]])
    else:
        size = np.array([p["depth"], p["width"], p["height"]])
    sym = box_symmetries(size)
    return Shape(shapes.box(size, subdivisions=2), sym, ())


def box_symmetries(size: np.ndarray, rtol: float = 1e-9) -> tuple[np.ndarray, ...]:
    """Proper rotations (4x4, identity excluded) mapping a centred box of ``size`` (metres) onto itself.

    Always the rotations by pi about x, y and z; for each pair of equal edges also the quarter turns about
    the third axis and the half turns about the diagonals (a cube gives all 23 non-trivial rotations).
    """
    from scipy.spatial.transform import Rotation

    size = np.asarray(size, dtype=np.float64)
    out = []
    for R in Rotation.create_group("O").as_matrix():  # the 24 rotations of the cube
        R = np.round(R)
        if np.allclose(R, np.eye(3)):
            continue
        if np.allclose(np.abs(R) @ size, size, rtol=rtol, atol=0):
            T = np.eye(4)
            T[:3, :3] = R
            out.append(T)
    return tuple(out)


def _marker(p: dict, rng: np.random.Generator) -> Shape:
    r, length, rc, cap = p["radius"], p["length"], p["radius"] + 0.0015, p["cap_length"]
    prof = [(0, 0.0), (0.002, 0.0), (0.0028, 0.005), (0.6 * r, 0.012), (r, 0.018), (r, length - cap),
            (rc, length - cap), (rc, length - 0.002), (rc - 0.002, length), (0, length)]
    return Shape(shapes.lathe(np.array(prof), SEGMENTS), (), Z_SYMMETRY)


def _banana(p: dict, rng: np.random.Generator) -> Shape:
    radius, length, r_max = p["bend_radius"], p["length"], p["thickness"] / 2
    span = length / radius
    m = 25
    th = np.linspace(-span / 2, span / 2, m)
    # The arc lies in the horizontal xy plane (a banana resting on its side).
    centers = np.stack([radius * np.sin(th), radius * np.cos(th) - radius, np.zeros(m)], axis=1)
    normals = np.stack([np.sin(th), np.cos(th), np.zeros(m)], axis=1)
    tangents = np.stack([np.cos(th), -np.sin(th), np.zeros(m)], axis=1)
    binormals = np.cross(tangents, normals)
    s = np.linspace(0, 1, m)
    taper = np.sin(np.pi * np.clip(s, 0.02, 0.98)) ** 0.5
    taper = taper * (1.0 - 0.15 * s)  # the stem end is thinner
    r = np.maximum(r_max * taper, 0.004)
    caps = np.stack([centers[0] - tangents[0] * 0.006, centers[-1] + tangents[-1] * 0.010])
    mesh = shapes.sweep_tube(centers, normals, binormals, r, 0.92 * r, sides=16, caps=caps,
                             shape_fn=lambda phi: 1.0 + 0.05 * np.cos(5 * phi))
    return Shape(mesh, (), ())


def _drill(p: dict, rng: np.random.Generator) -> Shape:
    import manifold3d as mf

    seg = 24
    rb, lb = p["body_radius"], p["body_length"]
    hl, hw, hd = p["handle_length"], p["handle_width"], p["handle_depth"]
    zb = hl + 0.02  # height of the motor axis above the battery's top
    body = mf.Manifold.cylinder(lb, rb, rb * 0.92, circular_segments=seg).rotate([0.0, 90.0, 0.0]) \
        .translate([0.0, 0.0, zb])
    back = mf.Manifold.sphere(rb, circular_segments=seg).scale([0.5, 1.0, 1.0]).translate([0.0, 0.0, zb])
    chuck = mf.Manifold.cylinder(p["chuck_length"], p["chuck_radius"], 0.8 * p["chuck_radius"],
                                 circular_segments=seg).rotate([0.0, 90.0, 0.0]).translate([lb - 0.003, 0.0, zb])
    handle = mf.Manifold.cube([hd, hw, hl + 0.03], center=True).rotate([0.0, -12.0, 0.0]) \
        .translate([0.045, 0.0, zb - (hl + 0.03) / 2])
    battery = mf.Manifold.cube([p["battery_length"], p["battery_width"], 0.035], center=True) \
        .translate([0.05, 0.0, 0.0175 - 0.02])
    mesh = shapes.from_manifold(mf.Manifold.batch_boolean([body, back, chuck, handle, battery], mf.OpType.Add))
    return Shape(mesh, (), ())


CATEGORIES: tuple[Category, ...] = (
    Category("can", _can, (
        dict(radius=0.0335, height=0.102),   # soup can
        dict(radius=0.026, height=0.135),    # slim drink can
        dict(radius=0.034, height=0.070),    # short food can
    ), 850.0, ((0.75, 0.12, 0.12), (0.78, 0.78, 0.80), (0.15, 0.45, 0.25), (0.9, 0.75, 0.2)), False),
    Category("bottle", _bottle, (
        dict(radius=0.032, height=0.200, neck_radius=0.013, shoulder=0.62, neck=0.86, cap_height=0.018),
        dict(radius=0.025, height=0.150, neck_radius=0.011, shoulder=0.55, neck=0.83, cap_height=0.016),
        dict(radius=0.033, height=0.170, neck_radius=0.012, shoulder=0.70, neck=0.88, cap_height=0.020),
    ), 600.0, ((0.2, 0.45, 0.8), (0.2, 0.6, 0.3), (0.95, 0.8, 0.15), (0.85, 0.85, 0.9)), False),
    Category("mug", _mug, (
        dict(radius=0.041, height=0.095, wall=0.006, bottom=0.008, handle_reach=0.030, handle_span=0.060,
             handle_center=0.52, handle_thick=0.010, handle_width=0.012),
        dict(radius=0.037, height=0.085, wall=0.005, bottom=0.007, handle_reach=0.026, handle_span=0.050,
             handle_center=0.55, handle_thick=0.009, handle_width=0.011),
        dict(radius=0.044, height=0.105, wall=0.006, bottom=0.009, handle_reach=0.033, handle_span=0.066,
             handle_center=0.50, handle_thick=0.011, handle_width=0.013),
    ), 1800.0, ((0.93, 0.92, 0.88), (0.2, 0.35, 0.7), (0.75, 0.15, 0.15), (0.25, 0.25, 0.27)), True),
    Category("bowl", _bowl, (
        dict(radius=0.080, height=0.055, foot_radius=0.035, wall=0.006, bottom=0.012),
        dict(radius=0.070, height=0.045, foot_radius=0.030, wall=0.005, bottom=0.011),
        dict(radius=0.085, height=0.062, foot_radius=0.040, wall=0.006, bottom=0.013),
    ), 1500.0, ((0.92, 0.9, 0.86), (0.75, 0.2, 0.15), (0.3, 0.55, 0.35), (0.2, 0.3, 0.6)), True),
    Category("box", _box, (
        dict(depth=0.060, width=0.158, height=0.210, square=False),   # cracker box
        dict(depth=0.038, width=0.089, height=0.175, square=False),   # sugar box
        dict(width=0.066, height=0.120, square=True),                 # tea box, square cross-section
    ), 250.0, ((0.85, 0.2, 0.12), (0.95, 0.85, 0.3), (0.3, 0.5, 0.75), (0.85, 0.55, 0.2)), False),
    Category("cup", _cup, (
        dict(bottom_radius=0.027, top_radius=0.038, height=0.095, wall=0.004, bottom=0.006),
        dict(bottom_radius=0.024, top_radius=0.033, height=0.080, wall=0.0035, bottom=0.005),
        dict(bottom_radius=0.030, top_radius=0.036, height=0.110, wall=0.004, bottom=0.006),
    ), 1100.0, ((0.8, 0.15, 0.15), (0.95, 0.95, 0.95), (0.25, 0.55, 0.8), (0.95, 0.65, 0.15)), True),
    Category("marker", _marker, (
        dict(radius=0.0085, length=0.125, cap_length=0.045),
        dict(radius=0.0095, length=0.135, cap_length=0.050),
        dict(radius=0.0070, length=0.140, cap_length=0.040),
    ), 700.0, ((0.1, 0.1, 0.1), (0.15, 0.25, 0.75), (0.8, 0.1, 0.1), (0.1, 0.55, 0.2)), False),
    Category("banana", _banana, (
        dict(bend_radius=0.13, length=0.19, thickness=0.036),
        dict(bend_radius=0.11, length=0.17, thickness=0.033),
        dict(bend_radius=0.16, length=0.21, thickness=0.038),
    ), 900.0, ((0.95, 0.82, 0.2), (0.9, 0.85, 0.25), (0.75, 0.8, 0.2)), True),
    Category("drill", _drill, (
        dict(body_radius=0.028, body_length=0.150, chuck_radius=0.014, chuck_length=0.045,
             handle_length=0.110, handle_width=0.035, handle_depth=0.042, battery_length=0.090,
             battery_width=0.075),
        dict(body_radius=0.025, body_length=0.135, chuck_radius=0.012, chuck_length=0.040,
             handle_length=0.100, handle_width=0.033, handle_depth=0.040, battery_length=0.080,
             battery_width=0.070),
        dict(body_radius=0.030, body_length=0.160, chuck_radius=0.015, chuck_length=0.050,
             handle_length=0.115, handle_width=0.037, handle_depth=0.044, battery_length=0.095,
             battery_width=0.078),
    ), 1000.0, ((0.75, 0.12, 0.1), (0.1, 0.5, 0.55), (0.95, 0.75, 0.1), (0.2, 0.2, 0.22)), True),
)

#: Names in ``builtin-small`` (ids equal to those in ``builtin``).
SMALL_NAMES = ("box_0", "can_0", "mug_0", "banana_0")

#: The built-in set names understood by :func:`load_builtin`.
BUILTIN_SETS = ("builtin", "builtin-small")


def _category_index(name: str) -> int:
    for i, cat in enumerate(CATEGORIES):
        if cat.name == name:
            return i
    raise AssetError(f"unknown built-in category {name!r}; known: {', '.join(c.name for c in CATEGORIES)}")


def _first_id(cat_index: int) -> int:
    return 1 + sum(len(c.instances) for c in CATEGORIES[:cat_index])


def build_object(category: str, instance: int, seed: int = 0) -> ObjectModel:
    """Build one built-in object.

    Args:
        category: Category name (see :data:`CATEGORIES`).
        instance: Instance index within the category (0-based).
        seed: Non-negative integer; jitters shape parameters and picks the colour.

    Raises:
        AssetError: Unknown category or instance.
    """
    ci = _category_index(category)
    cat = CATEGORIES[ci]
    if not 0 <= instance < len(cat.instances):
        raise AssetError(f"built-in category {category!r} has instances 0..{len(cat.instances) - 1}, "
                         f"got {instance!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise AssetError(f"built-in seed must be a non-negative integer, got {seed!r}")
    rng = np.random.default_rng([int(seed), ci, instance])
    params = _jitter(cat.instances[instance], rng)
    shape = cat.build(params, rng)
    mesh, offset = shapes.center_bbox(shape.mesh)
    base = np.asarray(cat.palette[int(rng.integers(len(cat.palette)))])
    rgb = np.clip(base + rng.uniform(-0.04, 0.04, size=3), 0.0, 1.0)
    base_rgb = tuple(np.round(rgb, 4).tolist())
    # The skin's variant comes from its own stream: shapes and colours above stay as they were.
    skin_seed = int(np.random.default_rng([int(seed), ci, instance, 7]).integers(2**31))
    look = skins.skin(cat.name, base_rgb, skin_seed)
    appearance = Appearance(texture=look.albedo, face_uv=skins.skin_uv(cat.name, mesh, params))
    return ObjectModel(
        obj_id=_first_id(ci) + instance,
        name=f"{cat.name}_{instance}",
        category=cat.name,
        instance=instance,
        mesh=mesh,
        density=cat.density,
        concave=cat.concave,
        rgba=(1.0, 1.0, 1.0, 1.0),
        appearance=appearance,
        symmetries_discrete=shape.symmetries_discrete,
        symmetries_continuous=shape.symmetries_continuous,
        source=f"builtin:{cat.name}:{seed}",
        extra={"params": params, "origin_offset": offset.tolist(), "seed": int(seed),
               "skin": {"family": skins.SKIN_FAMILIES[cat.name], "base_rgb": list(base_rgb), "seed": skin_seed}},
    )


@functools.lru_cache(maxsize=8)
def load_builtin(name: str = "builtin", seed: int = 0) -> ObjectSet:
    """The built-in procedural set (cached in-process per ``(name, seed)``).

    Args:
        name: ``"builtin"`` (all 27 objects) or ``"builtin-small"`` (``box_0``, ``can_0``, ``mug_0``,
            ``banana_0``, same ids).
        seed: Non-negative integer seed of shapes and colours.

    Raises:
        AssetError: Unknown set name or a bad seed.
    """
    if name not in BUILTIN_SETS:
        raise AssetError(f"unknown built-in object set {name!r}; known: {', '.join(BUILTIN_SETS)}")
    if name == "builtin-small":
        full = load_builtin("builtin", seed)
        return ObjectSet([full.by_name(n) for n in SMALL_NAMES], name="builtin-small")
    objs = [build_object(cat.name, i, seed) for cat in CATEGORIES for i in range(len(cat.instances))]
    return ObjectSet(objs, name="builtin")

