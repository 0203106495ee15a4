"""``SceneSpec``: a pure, frozen, serializable description of one scene, sampled from a config and one rng.

Everything random about a scene is drawn here, once, in a fixed order, so rebuilding from the spec (or from
the same ``(seed, scene index, attempt)``) reproduces it exactly. Camera views are stored relative to the
point of interest (the centre of the settled objects), which is only known after physics has run.
"""

from __future__ import annotations

import colorsys
from dataclasses import asdict, dataclass

import numpy as np

from simtest.errors import ConfigError
from simtest.generators.aiming import object_probabilities, weighted_uniform
from simtest.generators.config import GenerateConfig
from simtest.generators.distractor_objects import DistractorObjectSpec, sample_distractor_objects
from simtest.generators.looks import EnvironmentSpec, appearance_rng, sample_environment, sample_material, surface_maps
from simtest.objects import ObjectModel, ObjectSet
from simtest.objects.appearance import tint_rgba

__all__ = [
    "ObjectPlacement", "DistractorSpec", "random_quat_wxyz", "LightSpec", "SurfaceSpec", "ViewSpec", "SceneSpec", "PlacementError",
    "sample_scene_spec", "object_colour",
]


class PlacementError(ConfigError):
    """The sampled objects do not fit on the table without overlapping (the scene is re-sampled)."""


@dataclass(frozen=True)
class ObjectPlacement:
    """One object instance: which model, where it is dropped from, how it looks."""

    obj_id: int
    position: tuple[float, float, float]  # metres, world
    quat_wxyz: tuple[float, float, float, float]  # initial orientation, MuJoCo order (w, x, y, z)
    rgba: tuple[float, float, float, float]
    specular: float
    shininess: float
    reflectance: float
    skin_seed: int | None = None  # variant of a built-in object's print (generators.looks.skin_of); None: its own
    plain: bool = False  # drawn without its print, in its base colour (``materials.object_textures = false``)


@dataclass(frozen=True)
class DistractorSpec:
    """An unannotated primitive (box / cylinder / sphere / capsule) that occludes and clutters."""

    shape: str
    size: tuple[float, float, float]  # MuJoCo geom size parameters, metres
    position: tuple[float, float, float]
    quat_wxyz: tuple[float, float, float, float]
    rgba: tuple[float, float, float, float]
    image: str | None = None  # an image texture instead of the flat colour (earlier releases' ``materials.textures``)
    material: str | None = None  # a material key (generators.looks.surface_maps) instead of the flat colour


@dataclass(frozen=True)
class LightSpec:
    position: tuple[float, float, float]
    direction: tuple[float, float, float]
    diffuse: tuple[float, float, float]
    specular: float


@dataclass(frozen=True)
class SurfaceSpec:
    """A procedural texture: MuJoCo builtin pattern with two colours."""

    pattern: str  # "checker" | "gradient" | "flat"
    rgb1: tuple[float, float, float]
    rgb2: tuple[float, float, float]
    repeat: float  # texture repeats per metre
    noise: float  # fraction of randomly coloured texels ("random" marks), 0..1
    image: str | None = None  # an image file used instead of the pattern (earlier releases' ``materials.textures``)
    material: str | None = None  # a material key (generators.looks.surface_maps) instead of the pattern


@dataclass(frozen=True)
class ViewSpec:
    """One camera view relative to the point of interest: spherical shell coordinates plus roll (radians)."""

    distance: float
    elevation: float
    azimuth: float
    roll: float
    poi_offset: tuple[float, float, float]


@dataclass(frozen=True)
class SceneSpec:
    scene_index: int
    attempt: int
    objects: tuple[ObjectPlacement, ...]
    distractors: tuple[DistractorSpec, ...]
    lights: tuple[LightSpec, ...]
    ambient: float
    table: SurfaceSpec
    floor: SurfaceSpec
    walls: SurfaceSpec
    views: tuple[ViewSpec, ...]
    environment: EnvironmentSpec | None = None  # pbr environment lighting (None: the constant ambient term)
    ceiling: tuple[float, float, float] | None = None  # the ceiling panel's display-referred brightness (RGB)
    distractor_objects: tuple[DistractorObjectSpec, ...] = ()  # unannotated objects of another set

    def to_dict(self) -> dict:
        return asdict(self)


def _colour(rng: np.random.Generator, sat: tuple[float, float] = (0.1, 0.6), val: tuple[float, float] = (0.3, 0.9)
            ) -> tuple[float, float, float]:
    h = rng.uniform(0, 1)
    s = rng.uniform(*sat)
    v = rng.uniform(*val)
    return tuple(float(c) for c in colorsys.hsv_to_rgb(h, s, v))


def _surface(cfg: GenerateConfig, rng: np.random.Generator, base: tuple[float, float, float], material: str | None,
             extent: float) -> SurfaceSpec:
    """A room surface: a library material repeated at its physical tile size across ``extent`` metres, else a
    MuJoCo builtin pattern (or ``base`` when not randomized)."""
    if material is not None:
        tile = float(surface_maps(cfg, material).tile_m)
        return SurfaceSpec("flat", (1.0, 1.0, 1.0), (1.0, 1.0, 1.0), max(1.0, extent / tile), 0.0, material=material)
    if not cfg.materials.background_textures:
        return SurfaceSpec("flat", base, base, 1.0, 0.0)
    pattern = ["checker", "gradient", "flat"][int(rng.integers(3))]
    c1 = _colour(rng)
    c2 = tuple(float(np.clip(c + rng.normal(0, 0.15), 0, 1)) for c in c1)
    return SurfaceSpec(pattern, c1, c2, float(rng.uniform(1.0, 8.0)), float(rng.uniform(0.0, 0.3)))




def _jitter_colour(rgba, amount: float, rng: np.random.Generator) -> tuple[float, float, float, float]:
    rgb = np.clip(np.asarray(rgba[:3]) + rng.normal(0, amount, 3), 0.02, 0.98)
    return (float(rgb[0]), float(rgb[1]), float(rgb[2]), 1.0)


def object_colour(obj: ObjectModel, colour_jitter: float, texture_jitter: float,
                  rng: np.random.Generator, plain: bool = False) -> tuple[float, float, float, float]:
    """The material colour of one instance: a textured (or vertex-coloured) object keeps its texture, tinted
    around its own material colour by up to ``texture_jitter`` (never replaced); a plain one gets its colour
    jittered by ``colour_jitter`` (standard deviation per channel). ``plain``: a built-in object drawn without
    its print gets its base colour (``obj.extra["skin"]["base_rgb"]``) jittered."""
    if plain:
        return _jitter_colour((*obj.extra["skin"]["base_rgb"], 1.0), colour_jitter, rng)
    if obj.appearance is None:
        return _jitter_colour(obj.rgba, colour_jitter, rng)
    tint = tint_rgba(texture_jitter, rng)
    return (*(float(a * b) for a, b in zip(obj.rgba[:3], tint[:3])), 1.0)


def random_quat_wxyz(rng: np.random.Generator) -> tuple[float, float, float, float]:
    """A uniformly random unit quaternion (w, x, y, z) with w >= 0, drawn with ``rng``."""
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    if q[0] < 0:
        q = -q
    return tuple(float(v) for v in q)


def sample_scene_spec(cfg: GenerateConfig, objects: ObjectSet, rng: np.random.Generator, scene_index: int,
                      attempt: int = 0) -> SceneSpec:
    """Draw one scene description.

    Args:
        cfg: Validated generation config.
        objects: The object set to draw targets from.
        rng: The scene's generator (from ``simtest.rng.child_rng(seed, scene_index, attempt)``).
        scene_index: Index of the scene in the dataset.
        attempt: Re-sampling attempt (0 first).

    Raises:
        PlacementError: If the drawn objects cannot be placed without overlapping.
    """
    sc = cfg.scene
    n_obj = int(rng.integers(sc.objects_per_scene[0], sc.objects_per_scene[1] + 1))
    ids = np.asarray(objects.ids)
    if not sc.allow_repeats and n_obj > len(ids):
        raise ConfigError(f"scene.objects_per_scene max {n_obj} exceeds the {len(ids)} objects of set "
                          f"{objects.name!r} while scene.allow_repeats is false")
    p = object_probabilities(objects.ids, sc.object_weights)
    if p is not None and not sc.allow_repeats and n_obj > int((p > 0).sum()):
        raise ConfigError(f"scene.objects_per_scene max {n_obj} exceeds the {int((p > 0).sum())} objects of set "
                          f"{objects.name!r} with a positive scene.object_weights while scene.allow_repeats is false")
    chosen = (rng.choice(ids, size=n_obj, replace=sc.allow_repeats) if p is None
              else rng.choice(ids, size=n_obj, replace=sc.allow_repeats, p=p))
    n_dis = int(rng.integers(sc.distractors[0], sc.distractors[1] + 1))

    # Non-overlapping drop positions: bounding spheres over the drop area, stacked in height if needed.
    half = np.asarray(sc.table_size) / 2.0 * sc.drop_area
    placed: list[tuple[np.ndarray, float]] = []

    def place(radius: float) -> np.ndarray:
        for _ in range(60):
            xy = rng.uniform(-half, half)
            z = sc.table_height + radius + rng.uniform(*sc.drop_height)
            p = np.array([xy[0], xy[1], z])
            if all(np.linalg.norm(p - q) > radius + r + 0.005 for q, r in placed):
                placed.append((p, radius))
                return p
        # Stack above everything placed so far rather than give up at once.
        top = max((q[2] + r for q, r in placed), default=sc.table_height)
        p = np.array([*rng.uniform(-half, half), top + radius + 0.01])
        if p[2] - sc.table_height > 1.5:
            raise PlacementError(f"scene {scene_index}: {n_obj} objects and {n_dis} distractors do not fit on a "
                                 f"{sc.table_size[0]} x {sc.table_size[1]} m table (drop_area={sc.drop_area})")
        placed.append((p, radius))
        return p

    # Appearance (colours, materials, lights) from the scene's appearance stream: the geometry stream `rng`
    # draws the same values whatever the appearance options.
    look = appearance_rng(rng)
    mat = cfg.materials
    placements = []
    for oid in chosen:
        obj = objects.get(int(oid))
        pos = place(obj.diameter / 2.0)
        quat = random_quat_wxyz(rng)
        plain = not mat.object_textures and "skin" in obj.extra
        rgba = (object_colour(obj, mat.colour_jitter, mat.texture_jitter, look, plain)
                if mat.randomize_object_colour else (*obj.extra["skin"]["base_rgb"], 1.0) if plain else obj.rgba)
        skin_seed = mat.first_variant + int(look.integers(mat.variants)) if mat.object_textures and "skin" in obj.extra else None
        placements.append(ObjectPlacement(
            obj_id=int(oid), position=tuple(float(v) for v in pos), quat_wxyz=quat, rgba=rgba,
            specular=float(look.uniform(*mat.specular)), shininess=float(look.uniform(*mat.shininess)),
            reflectance=float(look.uniform(*mat.reflectance)), skin_seed=skin_seed, plain=plain))

    distractors = []
    for _ in range(n_dis):
        shape = ["box", "cylinder", "sphere", "capsule"][int(rng.integers(4))]
        dims = rng.uniform(0.015, 0.06, 3)
        size = (float(dims[0]), float(dims[1]), float(dims[2]))
        radius = float(np.linalg.norm(dims)) if shape == "box" else float(dims[0] + dims[1])
        pos = place(radius)
        distractors.append(DistractorSpec(shape, size, tuple(float(v) for v in pos), random_quat_wxyz(rng),
                                          (*_colour(look), 1.0), material=sample_material(cfg, look)))
    distractor_objects = sample_distractor_objects(cfg, rng, look, place, random_quat_wxyz, _colour)

    lc = cfg.lights
    lights = []
    for _ in range(int(look.integers(lc.count[0], lc.count[1] + 1))):
        d = look.uniform(*lc.distance)
        el = look.uniform(np.deg2rad(30), np.deg2rad(85))
        az = look.uniform(0, 2 * np.pi)
        pos = np.array([d * np.cos(el) * np.cos(az), d * np.cos(el) * np.sin(az), sc.table_height + d * np.sin(el)])
        direction = np.array([0.0, 0.0, sc.table_height]) - pos
        direction /= np.linalg.norm(direction)
        inten = look.uniform(*lc.intensity)
        tint = np.clip(1.0 + look.normal(0, lc.colour_jitter, 3), 0.5, 1.5)
        diffuse = np.clip(inten * tint, 0, 1)
        lights.append(LightSpec(tuple(float(v) for v in pos), tuple(float(v) for v in direction),
                                tuple(float(v) for v in diffuse), float(look.uniform(0.0, 0.4))))
    ambient = float(look.uniform(*lc.ambient))

    table = _surface(cfg, look, (0.55, 0.45, 0.35), sample_material(cfg, look), 0.7)
    floor = _surface(cfg, look, (0.35, 0.35, 0.35), sample_material(cfg, look), 2.0 * sc.room_half_size)
    walls = (floor if mat.room_material == "shared" and floor.material is not None
             else _surface(cfg, look, (0.6, 0.6, 0.62), sample_material(cfg, look), 2.0 * sc.room_half_size))
    environment = sample_environment(cfg, look)
    ceiling = None
    if sc.ceiling_light:
        grey = look.uniform(0.5, 1.0)
        colour = np.clip(grey + look.normal(0.0, 0.03, 3), 0.4, 1.0) * look.uniform(*lc.ceiling_strength)
        ceiling = tuple(float(c) for c in colour)

    views = tuple(_sample_views(cfg, rng))
    return SceneSpec(scene_index, attempt, tuple(placements), tuple(distractors), tuple(lights), ambient,
                     table, floor, walls, views, environment, ceiling, distractor_objects)


def _sample_views(cfg: GenerateConfig, rng: np.random.Generator) -> list[ViewSpec]:
    n = cfg.frames_per_scene
    if cfg.rig == "sequence":
        sq = cfg.sequence
        d0 = rng.uniform(*sq.start_distance)
        d1 = rng.uniform(*sq.end_distance)
        el0, el1 = np.deg2rad(rng.uniform(*sq.elevation_deg, size=2))
        az0 = rng.uniform(0, 2 * np.pi)
        sweep = np.deg2rad(sq.sweep_deg) * rng.choice([-1.0, 1.0])
        offset = tuple(float(v) for v in rng.uniform(-0.03, 0.03, 3) * [1, 1, 0])
        out = []
        for k in range(n):
            s = k / max(n - 1, 1)
            s = 0.5 - 0.5 * np.cos(np.pi * s)  # ease in/out: smooth start and stop
            out.append(ViewSpec(float(d0 + (d1 - d0) * s), float(el0 + (el1 - el0) * s), float(az0 + sweep * s),
                                0.0, offset))
        return out
    sh = cfg.shell
    out = []
    for _ in range(n):
        out.append(ViewSpec(
            distance=weighted_uniform(rng, sh.distance, sh.distance_weights),
            elevation=float(np.deg2rad(weighted_uniform(rng, sh.elevation_deg, sh.elevation_weights))),
            azimuth=float(np.deg2rad(rng.uniform(*sh.azimuth_deg))),
            roll=float(np.deg2rad(weighted_uniform(rng, sh.roll_range(), sh.roll_weights))),
            poi_offset=tuple(float(v) for v in rng.uniform(-sh.poi_jitter, sh.poi_jitter, 3) * [1, 1, 0.3])))
    return out


def view_to_camera_pose(view: ViewSpec, poi: np.ndarray):
    """``T_world_cam`` (OpenCV) of a view around ``poi`` (world, metres)."""
    from simtest.camera import look_at_pose

    target = np.asarray(poi, dtype=np.float64) + np.asarray(view.poi_offset)
    ce = np.cos(view.elevation)
    eye = target + view.distance * np.array([ce * np.cos(view.azimuth), ce * np.sin(view.azimuth),
                                             np.sin(view.elevation)])
    return look_at_pose(eye, target, roll=view.roll)
