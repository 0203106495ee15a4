"""Appearance as data: materials (albedo, roughness, normal maps, parameters) made by seeded procedural
generators or read from a folder, cached by (family, seed); each renderer maps the same material to what it
can draw. Object appearance read from assets stays in :mod:`simtest.objects.appearance`.

Modules: ``maps`` (:class:`MaterialMaps`, the map encodings), ``noise`` (periodic noise fields),
``procedural`` (the nine families), ``folders`` (ambientCG / Poly Haven / plain image folders),
``environments`` (procedural skies and studios, HDR files, light summaries), ``sky`` and ``sphere`` (their
radiance and texel geometry).
"""

from simtest.materials.environments import (ENVIRONMENTS, Environment, environment_files, irradiance_up,
                                            light_summary, procedural_environment, read_environment, rotated)
from simtest.materials.folders import MaterialSource, folder_materials, load_folder_material
from simtest.materials.maps import MaterialMaps, decode_normal, encode_normal, height_to_normal
from simtest.materials.procedural import FAMILIES, procedural_material

__all__ = ["MaterialMaps", "FAMILIES", "procedural_material", "MaterialSource", "folder_materials",
           "load_folder_material", "Environment", "ENVIRONMENTS", "procedural_environment", "irradiance_up",
           "environment_files", "read_environment", "light_summary", "rotated", "height_to_normal",
           "encode_normal", "decode_normal"]
