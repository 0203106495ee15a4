"""Recipes: named presets of generation values. A recipe fills the values a config leaves out; every value the
user gives (config file or command line) wins over it.

``tabletop`` (the default) is the empty preset. ``bop-pbr`` follows the BOP challenge's BlenderProc recipe
(``examples/datasets/bop_challenge/main_*_random.py`` of BlenderProc4BOP), side by side:

=========================  ==========================================  ==============================================
part                       BlenderProc4BOP                             ``--recipe bop-pbr``
=========================  ==========================================  ==============================================
room                       five 2 x 2 m planes (floor, 4 walls 2 m     floor and 4 walls at +-2 m, 2 m high
                           high), no table                             (``scene.room_half_size``, ``wall_height``),
                                                                       no table (``scene.table_height = 0``)
room material              one random CC0 PBR material per scene on    one procedural (or ``--textures``) material per
                           all planes                                  scene on floor and walls (``room_material``)
ceiling                    3 x 3 m emissive plane 10 m up, strength    3 x 3 m emissive panel 10 m up
                           U(3, 6), grey-ish colour U(0.5, 1)          (``scene.ceiling_light``), floor irradiance
                                                                       U(0.3, 0.6) of white, grey-ish colour
point light                energy 200, colour U(0.5, 1), shell 1-1.5   one light on a shell of 1-1.5 m, colour
                           m, elevation 5-89 deg                       jitter; elevation 30-85 deg (simtest's lights)
objects                    21 targets + 6 distractors from other       8-15 targets (repeats allowed) + 6 primitive
                           datasets; random roughness / specular       distractors with library materials; specular
                           U(0, 1)                                     and shininess U(0, 1)
drop                       +-0.2-0.3 m x 0-0.6 m above the floor,      over a 0.6 x 0.6 m area, 0.05-0.6 m above the
                           uniform SO(3), physics 3-10 s               floor, uniform SO(3), settled to rest (<= 6 s)
cameras                    25 per scene, shell 0.61-1.24 m,            25 per scene (``frames_per_scene``), shell
                           elevation 5-89 deg, uniform in-plane        0.61-1.24 m, elevation 5-89 deg, in-plane
                           rotation                                    rotation +-180 deg
environment                none (the room's lights)                    none (``lights.environment = "constant"``)
renderer                   Cycles, <= 50 samples, OIDN denoiser        choose ``--profile pbr`` (Mitsuba 3 + OIDN)
=========================  ==========================================  ==============================================

Not reproduced: BlenderProc's camera check that no obstacle lies within 0.3 m of the camera (the shell here
starts at 0.61 m and the room is empty above the objects). Distractor *objects* of another set are an option
of every recipe (``scene.distractor_objects``, :mod:`simtest.generators.distractor_objects`).
"""

from __future__ import annotations

import copy
from typing import Any

from simtest.errors import ConfigError

__all__ = ["RECIPES", "with_recipe"]

#: Each recipe's values, as nested config tables (dotted paths of ``simtest generate --print-config``).
RECIPES: dict[str, dict[str, Any]] = {
    "tabletop": {},
    "bop-pbr": {
        "frames_per_scene": 25,
        "scene": {"table_height": 0.0, "table_size": [0.75, 0.75], "drop_area": 0.8, "drop_height": [0.05, 0.6],
                  "objects_per_scene": [8, 15], "distractors": [6, 6], "room_half_size": 2.0,
                  "wall_height": 2.0, "ceiling_light": True, "settle_max_time": 6.0},
        "shell": {"distance": [0.61, 1.24], "elevation_deg": [5.0, 89.0], "azimuth_deg": [0.0, 360.0],
                  "roll_deg": 180.0, "poi_jitter": 0.1},
        "lights": {"count": [1, 1], "distance": [1.0, 1.5], "environment": "constant", "ambient": [0.05, 0.15]},
        "materials": {"room_material": "shared", "specular": [0.0, 1.0], "shininess": [0.0, 1.0]},
    },
}


def _merge(base: dict, over: dict) -> dict:
    """``base`` with ``over``'s values on top, tables merged key by key."""
    out = copy.deepcopy(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def with_recipe(data: dict[str, Any], source: str = "config") -> dict[str, Any]:
    """``data`` (a config as nested dicts) on top of its ``recipe``'s preset (``tabletop`` when absent).

    Raises:
        ConfigError: Naming ``source``, the value and the recipes, if ``recipe`` is unknown.
    """
    name = data.get("recipe", "tabletop")
    if name not in RECIPES:
        raise ConfigError(f"{source}: recipe = {name!r} is invalid; allowed: {' | '.join(map(repr, RECIPES))}")
    return _merge(RECIPES[name], data)
