"""Dressed grasp scenes on a kept model: an episode's looks written into fixed texture, material and light slots.

A dressed scene (:func:`simtest.envs.looks.dress_grasp_spec`) has its own materials, prints, lights and
environment. Compiling each one costs a reset tens of milliseconds, and a new GL context's uploads more. So a
pool model (:class:`simtest.envs.model_cache.ModelPool`) is compiled once from :func:`slot_spec`: every room
surface and the occluder box with a library material, every printed object copy with a print, and
:data:`LIGHT_SLOTS` lights. Each reset then writes the episode's looks into that model (:func:`write_looks`):

* a library material's maps into its surface's textures (``tex_data``, same size: ``texture_size`` pixels a
  side), its values (tiling, specular, shininess, metallic, roughness) into the material;
* an instance's print into its copy's print textures, or the copy's material pointed at the object's own
  texture, or at none (plain);
* the occluder's material, or none (its flat colour);
* the lights :meth:`simtest.generators.builder.SceneBuilder.light_values` gives for the spec into the first
  slots (type, position, direction, colours), the other slots switched off (``light_active``), and the ambient
  term.

The values come from the same functions the builder compiles a dressed spec with
(:func:`~simtest.generators.builder.library_values`, :func:`~simtest.generators.builder.skin_values`,
:func:`~simtest.generators.builder.texture_pixels`, ``light_values``), so a scene on the slots looks like the scene compiled from its spec. The GL textures written
must then be uploaded again (``mjr_uploadTexture``): :func:`write_looks` returns their ids.

Specs whose looks do not fit the slots (builtin patterns or image files on a surface, a ceiling panel,
distractor objects, more lights than slots) are :func:`poolable` False and get a model of their own.
"""

from __future__ import annotations

import dataclasses

import numpy as np

import simtest  # noqa: F401  (GL backend before mujoco)
import mujoco

from simtest.generators.builder import SceneBuilder, SimScene, library_values, skin_values, texture_pixels
from simtest.generators.looks import material_maps, skin_of
from simtest.generators.scene_spec import LightSpec, SceneSpec, SurfaceSpec

__all__ = ["LIGHT_SLOTS", "poolable", "slot_spec", "write_looks", "SlotMismatch"]

#: Lights of a dressed pool: the most a dressed spec has (1-4 lights, or up to 3 from an environment).
LIGHT_SLOTS = 4
#: The material every slot is compiled with (its maps have the size of every library material's).
_SLOT_MATERIAL = "wood:0"
#: The print variant printed objects are compiled with.
_SLOT_SKIN = 0
#: (texture-role suffix, map attribute) of a library material's textures, as the builder names them.
_SURFACE_MAPS = (("tex", "albedo"), ("rough", "roughness"), ("normal", "normal"))
_SKIN_MAPS = (("skin", "albedo"), ("skin_rough", "roughness"), ("skin_metal", "metallic"))


class SlotMismatch(ValueError):
    """A look's texture does not have its slot's size (the episode then gets a model of its own)."""


def _library(s: SurfaceSpec) -> bool:
    return s.material is not None and s.image is None


def poolable(spec: SceneSpec) -> bool:
    """Whether ``spec``'s looks fit a dressed pool's slots (see the module docstring)."""
    if not all(_library(s) for s in (spec.table, spec.floor, spec.walls)):
        return False
    if spec.ceiling is not None or spec.distractor_objects or any(d.image is not None for d in spec.distractors):
        return False
    return spec.environment is not None or len(spec.lights) <= LIGHT_SLOTS


def slot_spec(spec: SceneSpec, objects) -> SceneSpec:
    """The spec a dressed pool is compiled from: ``spec`` (parked objects and distractors) with the slot
    material on every surface and distractor (floor and walls kept apart), a print on every object that has
    one, :data:`LIGHT_SLOTS` lights and no environment. ``objects``: the object set of its placements."""
    surface = SurfaceSpec("flat", (1.0, 1.0, 1.0), (1.0, 1.0, 1.0), 1.0, 0.0, material=_SLOT_MATERIAL)
    placements = tuple(dataclasses.replace(p, skin_seed=_SLOT_SKIN if "skin" in objects.get(p.obj_id).extra else None,
                                           plain=False) for p in spec.objects)
    distractors = tuple(dataclasses.replace(d, image=None, material=_SLOT_MATERIAL) for d in spec.distractors)
    lights = tuple(LightSpec((0.0, 0.0, 2.0), (0.0, 0.0, -1.0), (0.5, 0.5, 0.5), 0.1) for _ in range(LIGHT_SLOTS))
    return dataclasses.replace(spec, objects=placements, distractors=distractors, lights=lights, ambient=0.3,
                               table=surface, floor=surface, walls=dataclasses.replace(surface, repeat=2.0),
                               environment=None, ceiling=None, distractor_objects=())


def _id(m: mujoco.MjModel, kind: mujoco.mjtObj, name: str) -> int:
    return int(mujoco.mj_name2id(m, kind, name))


class _Writes:
    """Texture writes of one episode, checked before any is made (a mismatch leaves the model untouched)."""

    def __init__(self, m: mujoco.MjModel) -> None:
        self.m = m
        self.todo: list[tuple[int, np.ndarray]] = []

    def texture(self, name: str, image: np.ndarray | None) -> None:
        """Queue ``image`` for texture ``name`` (skipped where the model has no such texture: the profile
        compiled without that map)."""
        tid = _id(self.m, mujoco.mjtObj.mjOBJ_TEXTURE, name)
        if tid < 0 or image is None:
            return
        pixels = texture_pixels(image)
        slot = (int(self.m.tex_height[tid]), int(self.m.tex_width[tid]), int(self.m.tex_nchannel[tid]))
        if pixels.shape != slot:
            raise SlotMismatch(f"texture {name!r}: a look of shape {pixels.shape} for a slot of shape {slot}")
        self.todo.append((tid, pixels))

    def apply(self) -> list[int]:
        for tid, pixels in self.todo:
            adr = int(self.m.tex_adr[tid])
            self.m.tex_data[adr:adr + pixels.size] = pixels.reshape(-1)
        return [tid for tid, _ in self.todo]


def write_looks(scene: SimScene, spec: SceneSpec, materials: list[str], builder: SceneBuilder) -> list[int]:
    """Write ``spec``'s looks into the slots of ``scene``'s model (compiled from :func:`slot_spec`; instance
    ``i`` shown by material ``materials[i]``); returns the ids of the textures written (to upload to GL).

    Call after the model's arrays are restored and the episode's colours written, before ``mj_resetData``
    (lights of static bodies take their poses there).

    Raises:
        SlotMismatch: If a map or print does not have its slot's size (nothing is written then).
    """
    m, opt = scene.model, builder.options
    writes = _Writes(m)
    values: list[tuple[int, dict[str, float], float]] = []
    for name, s, size in (("table", spec.table, 1.0), ("floor", spec.floor, 1.0), ("wall", spec.walls, 1.0)):
        maps = material_maps(s.material, opt.material_folder, opt.texture_size)
        for suffix, attr in _SURFACE_MAPS:
            writes.texture(f"{name}_{suffix}", getattr(maps, attr))
        values.append((_id(m, mujoco.mjtObj.mjOBJ_MATERIAL, f"{name}_mat"), library_values(maps), s.repeat * size))
    for j, d in enumerate(spec.distractors):
        if d.material is not None:
            maps = material_maps(d.material, opt.material_folder, opt.texture_size)
            for suffix, attr in _SURFACE_MAPS:
                writes.texture(f"distractor_{j}_{suffix}", getattr(maps, attr))
            values.append((_id(m, mujoco.mjtObj.mjOBJ_MATERIAL, f"distractor_{j}_mat"), library_values(maps), 1.0))
    skins = []
    for i, p in enumerate(spec.objects):
        skinned = skin_of(builder.objects.get(p.obj_id), p.skin_seed) if _textured(m, p.obj_id) else None
        prefix = materials[i][:-len("_mat")]
        if skinned is not None:
            for suffix, attr in _SKIN_MAPS:
                writes.texture(f"{prefix}_{suffix}", getattr(skinned, attr))
        skins.append(skinned)
    ambient, lights = builder.light_values(spec)
    if len(lights) > LIGHT_SLOTS:
        raise SlotMismatch(f"{len(lights)} lights for {LIGHT_SLOTS} light slots")
    uploaded = writes.apply()

    for mat, vals, repeat in values:
        m.mat_texrepeat[mat] = (repeat, repeat)
        m.mat_specular[mat], m.mat_shininess[mat] = vals["specular"], vals["shininess"]
        m.mat_metallic[mat], m.mat_roughness[mat] = vals["metallic"], vals["roughness"]
    for j, d in enumerate(spec.distractors):  # its colour (or white under a material) is written already
        if d.material is None:
            m.geom_matid[_id(m, mujoco.mjtObj.mjOBJ_GEOM, f"distractor_{j}_geom")] = -1
    for i, (p, skinned) in enumerate(zip(spec.objects, skins)):
        _object_material(m, p, skinned, materials[i])
    _write_lights(m, ambient, lights)
    return uploaded


def _textured(m: mujoco.MjModel, obj_id: int) -> bool:
    """Whether the object's mesh has its own texture in the model (the builder's ``mesh_{obj_id}_tex``)."""
    return _id(m, mujoco.mjtObj.mjOBJ_TEXTURE, f"mesh_{obj_id}_tex") >= 0


def _object_material(m: mujoco.MjModel, p, skinned, material: str) -> None:
    """Point an instance's material at its print (the slot's textures, as compiled), its object's own texture
    (a tint of it) or no texture (plain or untextured), with the builder's values."""
    mat = _id(m, mujoco.mjtObj.mjOBJ_MATERIAL, material)
    if skinned is not None:
        vals = skin_values(skinned)
        m.mat_specular[mat], m.mat_roughness[mat], m.mat_metallic[mat] = (vals["specular"], vals["roughness"],
                                                                          vals["metallic"])
        return
    m.mat_texid[mat] = -1
    m.mat_roughness[mat] = m.mat_metallic[mat] = -1.0  # unset, as an MjSpec material without them
    if _textured(m, p.obj_id) and not p.plain:
        m.mat_texid[mat, int(mujoco.mjtTextureRole.mjTEXROLE_RGB)] = _id(
            m, mujoco.mjtObj.mjOBJ_TEXTURE, f"mesh_{p.obj_id}_tex")


def _write_lights(m: mujoco.MjModel, ambient: list[float], lights: list) -> None:
    """``lights`` (:class:`~simtest.generators.builder.LightValue`) in the first slots (``light_0`` ...), the
    other slots off; the ambient term (RGB)."""
    for k in range(LIGHT_SLOTS):
        lid = _id(m, mujoco.mjtObj.mjOBJ_LIGHT, f"light_{k}")
        m.light_active[lid] = k < len(lights)
        if k < len(lights):
            light = lights[k]
            d = np.asarray(light.direction, dtype=np.float64)
            m.light_type[lid] = int(light.type)
            m.light_pos[lid], m.light_dir[lid] = light.position, d / np.linalg.norm(d)
            m.light_diffuse[lid], m.light_specular[lid] = light.diffuse, light.specular
    m.vis.headlight.ambient[:] = ambient
