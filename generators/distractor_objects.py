"""Unannotated distractor *objects*: the meshes of another object set dropped among the targets
(``scene.distractor_objects``), as BlenderProc's BOP recipe drops objects of other datasets.

Real test scenes hold objects other than the targets; primitive distractors (boxes, cylinders, spheres) do not
look like them. Distractor objects occlude, collide and cast shadows like the targets, wear their prints
(built-in sets) or their own colour (mesh files), and are never annotated: their geoms are drawn in group 0
with the room and the primitive distractors, so the visibility masks count them as occluders and no
annotation names them. (What they did for a detector on real LM-O frames is measured in docs/sim2real.md.)
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from simtest.errors import AssetError, ConfigError
from simtest.objects import ObjectSet

__all__ = ["DistractorObjectSpec", "distractor_object_set", "sample_distractor_objects"]


@dataclass(frozen=True)
class DistractorObjectSpec:
    """One distractor object: which model of the distractor set, where it is dropped from, how it looks."""

    obj_id: int  # id in the distractor set (``scene.distractor_objects``), not in the target set
    position: tuple[float, float, float]  # metres, world
    quat_wxyz: tuple[float, float, float, float]  # initial orientation, MuJoCo order (w, x, y, z)
    rgba: tuple[float, float, float, float]  # multiplies the print (white for printed objects)
    specular: float
    shininess: float
    skin_seed: int | None = None  # variant of a built-in object's print; None: the object's own look


@functools.lru_cache(maxsize=4)
def distractor_object_set(name: str) -> ObjectSet:
    """The object set ``scene.distractor_objects`` names, loaded once per process (its own units: a BOP models
    folder in millimetres, a mesh folder by its ``objects.toml`` or guessed).

    Raises:
        ConfigError: If the set cannot be loaded (the loader's reason, with the config key).
    """
    from simtest.objects import load_object_set

    try:
        objects = load_object_set(name)
    except AssetError as exc:
        raise ConfigError(f"scene.distractor_objects = {name!r} cannot be loaded: {exc}") from exc
    if not objects.ids:
        raise ConfigError(f"scene.distractor_objects = {name!r} holds no objects")
    return objects


def sample_distractor_objects(cfg, rng: np.random.Generator, look: np.random.Generator, place, random_quat,
                              sample_look) -> tuple[DistractorObjectSpec, ...]:
    """Draw the scene's distractor objects: their count, models and drop poses from the geometry stream
    ``rng``, their looks from the appearance stream ``look``; ``place(radius)`` returns a free drop position
    (metres), ``random_quat(rng)`` a uniform orientation (w, x, y, z) and ``sample_look(look)`` a random
    ``(r, g, b)`` for objects without a print (the scene sampler's own draws). Draws nothing when
    ``scene.distractor_objects`` is unset, so scenes without them keep their bytes."""
    sc, mat = cfg.scene, cfg.materials
    if not sc.distractor_objects:
        return ()
    objects = distractor_object_set(sc.distractor_objects)
    n = int(rng.integers(sc.distractor_object_count[0], sc.distractor_object_count[1] + 1))
    out = []
    for oid in rng.choice(np.asarray(objects.ids), size=n, replace=True):
        obj = objects.get(int(oid))
        pos = place(obj.diameter / 2.0)
        quat = random_quat(rng)
        printed = "skin" in obj.extra
        rgba = (1.0, 1.0, 1.0, 1.0) if printed or obj.appearance is not None else (*sample_look(look), 1.0)
        out.append(DistractorObjectSpec(
            int(oid), tuple(float(v) for v in pos), quat, rgba, float(look.uniform(*mat.specular)),
            float(look.uniform(*mat.shininess)), int(look.integers(1 << 30)) if printed else None))
    return tuple(out)
