"""How a scene looks: materials of the room and distractors, per-instance object prints, the environment.

Everything here is drawn from the scene's *appearance stream* (:func:`appearance_rng`), a generator of its own
below the scene's seed, never from the scene's geometry stream: switching materials, environments or object
prints on or off, or changing their families, changes no pose, mask, depth or other ground-truth file.

A surface's material is a key resolved by :func:`surface_maps`: ``"FAMILY:VARIANT"`` (a procedural family of
:mod:`simtest.materials` and one of ``materials.variants`` seeds, each made once per process and cached) or
``"folder:NAME"`` (a material of the ``materials.textures`` folder).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from simtest.errors import ConfigError

if TYPE_CHECKING:  # the samplers read the dataset config; resolving a key (the builder's side) does not
    from simtest.generators.config import GenerateConfig

__all__ = ["appearance_rng", "EnvironmentSpec", "sample_material", "sample_environment", "surface_maps",
           "material_maps", "environment_of", "skin_of", "APPEARANCE_KEY"]

#: Last spawn key of a scene's appearance stream (below the scene's own ``(scene, attempt)`` key).
APPEARANCE_KEY = 0xA99E


@dataclass(frozen=True)
class EnvironmentSpec:
    """The environment lighting of a scene (pbr; the other profiles approximate it with lights).

    Attributes:
        kind: ``"sky"``, ``"studio"`` (procedural, :func:`simtest.materials.procedural_environment`) or
            ``"hdri"`` (a file of ``lights.hdri``).
        source: The procedural seed (as text) or the file's absolute path.
        rotation: Rotation about the world's +z axis, radians.
        strength: Factor on the map's radiance.
    """

    kind: str
    source: str
    rotation: float
    strength: float


def appearance_rng(rng: np.random.Generator) -> np.random.Generator:
    """The appearance stream of the scene whose geometry stream is ``rng``: a child of ``rng``'s own
    ``SeedSequence`` at key ``APPEARANCE_KEY``, derived without drawing from ``rng`` (so the geometry stream is
    the same whatever the appearance draws)."""
    ss = rng.bit_generator.seed_seq
    return np.random.default_rng(np.random.SeedSequence(ss.entropy, spawn_key=(*ss.spawn_key, APPEARANCE_KEY)))


def sample_material(cfg: GenerateConfig, look: np.random.Generator) -> str | None:
    """A material key for one surface (None: MuJoCo's builtin patterns, when no family and no folder is set)."""
    mat = cfg.materials
    if mat.textures is not None:
        sources = _folder(mat.textures)
        return f"folder:{sources[int(look.integers(len(sources)))].name}"
    if not mat.families or not mat.background_textures:
        return None
    weights = np.asarray(mat.family_weights or [1.0] * len(mat.families), dtype=np.float64)
    family = mat.families[int(look.choice(len(mat.families), p=weights / weights.sum()))]
    return f"{family}:{mat.first_variant + int(look.integers(mat.variants))}"


def _folder(folder: str):
    """The materials of ``materials.textures`` (errors name the field)."""
    from simtest.materials import folder_materials

    try:
        return folder_materials(folder)
    except ConfigError as exc:
        raise ConfigError(f"materials.textures = {folder!r}: {exc}") from None


def surface_maps(cfg: GenerateConfig, key: str):
    """The :class:`simtest.materials.MaterialMaps` of material ``key`` with the config's ``materials.textures``
    folder and ``materials.texture_size`` (see :func:`material_maps`)."""
    return material_maps(key, cfg.materials.textures, cfg.materials.texture_size)


def material_maps(key: str, folder: str | None, texture_size: int):
    """The :class:`simtest.materials.MaterialMaps` of material ``key`` (cached by the library), ``texture_size``
    pixels per side; ``folder``: where ``"folder:NAME"`` keys are found (``materials.textures``).

    Raises:
        ConfigError: If a folder material is not in ``folder`` any more.
    """
    import simtest.materials as materials

    kind, _, name = key.partition(":")
    if kind == "folder":
        sources = {s.name: s for s in _folder(folder)}
        if name not in sources:
            raise ConfigError(f"material {name!r} is not in materials.textures = {folder!r}")
        return materials.load_folder_material(sources[name], texture_size)
    return materials.procedural_material(kind, int(name), texture_size)


def sample_environment(cfg: GenerateConfig, look: np.random.Generator) -> EnvironmentSpec | None:
    """The scene's environment (None for ``lights.environment = "constant"``)."""
    lc = cfg.lights
    kind = lc.environment
    if kind == "constant":
        return None
    if kind == "auto":
        kind = "hdri" if lc.hdri is not None else ("sky", "studio")[int(look.integers(2))]
    if kind == "hdri":
        if lc.hdri is None:
            raise ConfigError("lights.environment = 'hdri' needs lights.hdri (a folder of .hdr / .exr maps)")
        from simtest.materials import environment_files

        files = environment_files(lc.hdri)
        source = files[int(look.integers(len(files)))]
    else:
        source = str(cfg.materials.first_variant + int(look.integers(cfg.materials.variants)))
    return EnvironmentSpec(kind, source, float(look.uniform(0.0, 2.0 * math.pi)),
                           float(look.uniform(*lc.environment_strength)))


def environment_of(spec: EnvironmentSpec):
    """The :class:`simtest.materials.Environment` of ``spec``, rotated (its strength is applied by the
    renderer)."""
    import simtest.materials as materials

    if spec.kind == "hdri":
        env = materials.read_environment(spec.source)
    else:
        env = materials.procedural_environment(spec.kind, int(spec.source))
    return materials.rotated(env, spec.rotation)


def skin_of(obj, seed: int | None):
    """The printed skin (:class:`simtest.objects.skins.Skin`) of one instance of a built-in object: variant
    ``seed`` of the object's skin family around its base colour; None for objects without a skin or seed."""
    info = obj.extra.get("skin") if isinstance(obj.extra, dict) else None
    if seed is None or not info:
        return None
    from simtest.objects.skins import skin

    return skin(obj.category, tuple(info["base_rgb"]), int(seed))
