"""The looks of grasp scenes: the generator's appearance (materials, prints, environments, lights) on a grasp spec.

Datasets draw their appearance from :mod:`simtest.generators.looks` with the dataset defaults
(:class:`~simtest.generators.config.GenerateConfig`): procedural materials on the table, floor, walls and
distractors, a printed skin per instance of a built-in object, colour and gloss jitter, one to four lights and a
sky or studio environment (approximated by directional lights and the ambient term outside the pbr profile).
:func:`dress_grasp_spec` puts the same looks on a sampled grasp scene (:func:`simtest.envs.scene.sample_grasp_spec`),
so a network trained on the datasets sees the same kind of images in the wrist camera.

The looks are drawn from the episode's *appearance stream*: :func:`simtest.generators.looks.appearance_rng` of the
episode's scene stream, a child of that stream's ``SeedSequence`` derived without drawing from it (as datasets
derive theirs from a scene's geometry stream). Nothing is drawn from any other stream of the episode, and only
appearance fields of the spec change (colours, gloss, prints, materials, lights, the environment): object and
occluder poses, sizes and the ground truth are the same with and without looks.
"""

from __future__ import annotations

import colorsys
import dataclasses
from typing import Callable

import numpy as np

from simtest.generators.config import GenerateConfig
from simtest.generators.looks import appearance_rng, sample_environment, sample_material, surface_maps
from simtest.generators.scene_spec import LightSpec, SceneSpec, SurfaceSpec, object_colour
from simtest.objects import ObjectSet

__all__ = ["LOOKS_CONFIG", "dress_grasp_spec", "dresser", "looks_stream", "TABLE_EXTENT"]

#: The appearance settings grasp scenes draw their looks with: the dataset defaults.
LOOKS_CONFIG = GenerateConfig()
#: Extent (m) a table material is tiled across, as datasets tile theirs.
TABLE_EXTENT = 0.7


def looks_stream(scene_rng: np.random.Generator) -> np.random.Generator:
    """The appearance stream of an episode whose scene stream is ``scene_rng`` (nothing is drawn from it)."""
    return appearance_rng(scene_rng)


def _colour(rng: np.random.Generator) -> tuple[float, float, float]:
    """A random colour (hue uniform, saturation 0.1-0.6, value 0.3-0.9), as datasets colour distractors."""
    h, s, v = rng.uniform(0, 1), rng.uniform(0.1, 0.6), rng.uniform(0.3, 0.9)
    return tuple(float(c) for c in colorsys.hsv_to_rgb(h, s, v))


def _surface(cfg: GenerateConfig, look: np.random.Generator, base: tuple[float, float, float],
             extent: float) -> SurfaceSpec:
    """A room surface: a library material tiled at its physical size across ``extent`` metres, else a builtin
    pattern in random colours (else ``base``), as :func:`simtest.generators.scene_spec.sample_scene_spec` draws."""
    material = sample_material(cfg, look)
    if material is not None:
        tile = float(surface_maps(cfg, material).tile_m)
        return SurfaceSpec("flat", (1.0, 1.0, 1.0), (1.0, 1.0, 1.0), max(1.0, extent / tile), 0.0, material=material)
    if not cfg.materials.background_textures:
        return SurfaceSpec("flat", base, base, 1.0, 0.0)
    pattern = ["checker", "gradient", "flat"][int(look.integers(3))]
    c1 = _colour(look)
    c2 = tuple(float(np.clip(c + look.normal(0, 0.15), 0, 1)) for c in c1)
    return SurfaceSpec(pattern, c1, c2, float(look.uniform(1.0, 8.0)), float(look.uniform(0.0, 0.3)))


def _lights(cfg: GenerateConfig, look: np.random.Generator, table_z: float) -> tuple[LightSpec, ...]:
    """One to four lights around the table (distances, intensities and tints of ``cfg.lights``), world metres."""
    lc = cfg.lights
    lights = []
    for _ in range(int(look.integers(lc.count[0], lc.count[1] + 1))):
        d = look.uniform(*lc.distance)
        el = look.uniform(np.deg2rad(30), np.deg2rad(85))
        az = look.uniform(0, 2 * np.pi)
        pos = np.array([d * np.cos(el) * np.cos(az), d * np.cos(el) * np.sin(az), table_z + d * np.sin(el)])
        direction = np.array([0.0, 0.0, table_z]) - pos
        direction /= np.linalg.norm(direction)
        tint = np.clip(1.0 + look.normal(0, lc.colour_jitter, 3), 0.5, 1.5)
        diffuse = np.clip(look.uniform(*lc.intensity) * tint, 0, 1)
        lights.append(LightSpec(tuple(float(v) for v in pos), tuple(float(v) for v in direction),
                                tuple(float(v) for v in diffuse), float(look.uniform(0.0, 0.4))))
    return tuple(lights)


def dress_grasp_spec(spec: SceneSpec, objects: ObjectSet, look: np.random.Generator, table_z: float,
                     cfg: GenerateConfig = LOOKS_CONFIG) -> SceneSpec:
    """``spec`` with the generator's looks drawn from ``look`` (see the module docstring); poses, sizes, object
    ids and views unchanged.

    Args:
        spec: A sampled grasp scene (:func:`simtest.envs.scene.sample_grasp_spec`).
        objects: The object set of ``spec``'s placements.
        look: The episode's appearance stream (:func:`looks_stream`).
        table_z: Height of the table top, m (lights aim at the table's centre).
        cfg: The appearance settings (its ``materials`` and ``lights``; default :data:`LOOKS_CONFIG`).
    """
    mat = cfg.materials
    placements = []
    for p in spec.objects:
        obj = objects.get(int(p.obj_id))
        plain = not mat.object_textures and "skin" in obj.extra
        rgba = object_colour(obj, mat.colour_jitter, mat.texture_jitter, look, plain)
        skin_seed = (mat.first_variant + int(look.integers(mat.variants))
                     if mat.object_textures and "skin" in obj.extra else None)
        placements.append(dataclasses.replace(
            p, rgba=rgba, specular=float(look.uniform(*mat.specular)), shininess=float(look.uniform(*mat.shininess)),
            reflectance=float(look.uniform(*mat.reflectance)), skin_seed=skin_seed, plain=plain))
    distractors = tuple(dataclasses.replace(d, rgba=(*_colour(look), 1.0), material=sample_material(cfg, look))
                        for d in spec.distractors)
    lights = _lights(cfg, look, table_z)
    ambient = float(look.uniform(*cfg.lights.ambient))
    half = cfg.scene.room_half_size
    table = _surface(cfg, look, (0.55, 0.45, 0.35), TABLE_EXTENT)
    floor = _surface(cfg, look, (0.35, 0.35, 0.35), 2.0 * half)
    walls = (floor if mat.room_material == "shared" and floor.material is not None
             else _surface(cfg, look, (0.6, 0.6, 0.62), 2.0 * half))
    environment = sample_environment(cfg, look)
    return dataclasses.replace(spec, objects=tuple(placements), distractors=distractors, lights=lights,
                               ambient=ambient, table=table, floor=floor, walls=walls, environment=environment)


def dresser(objects: ObjectSet, scene_rng: np.random.Generator, builder) -> "Callable[[SceneSpec], SceneSpec]":
    """What dresses an episode's sampled spec: :func:`dress_grasp_spec` with the appearance stream of the
    episode's scene stream ``scene_rng`` (:func:`looks_stream`), lights aimed at ``builder``'s table."""
    look, table_z = looks_stream(scene_rng), float(builder.options.room.table_height)
    return lambda spec: dress_grasp_spec(spec, objects, look, table_z)
