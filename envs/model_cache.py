"""Reuse of compiled grasp-scene models across episodes of the same structure.

Compiling a scene (``MjSpec.compile``) and making its GL resources dominate a reset, and every new model
leaves allocator-held memory behind. Episodes whose scenes have the same *structure* (the same objects per
instance, the same distractor shapes and sizes, the same number of lights and the same room) differ only in
values: object poses, colours, lights, the table colour and the occluder's size and pose. So
:class:`GraspModelCache` compiles one **template** per structure, from a canonical spec (objects parked at
fixed spots, fixed colours and lights, a white table texture), keeps a snapshot of its arrays, and builds
each episode by restoring the model's arrays from that snapshot, resetting the data and writing the episode's
values:

* object poses into the free joints' ``qpos``; object colours into their materials;
* distractor (occluder) poses into ``qpos``, their colours into ``geom_rgba``;
* light positions, directions and colours into ``light_*``; the ambient light into ``vis.headlight``;
* the table colour into the table material's ``rgba`` (the texture stays white: GL multiplies the two).

The compiled model is therefore a function of the structure only, and an episode's scene is the same whether
its model was just compiled or reused: the same seed gives identical observations either way.

When the structure changes, the old template is released first (the ``on_release`` callback closes the
renderers that use it), then freed heap is returned to the operating system (:func:`trim_heap`, once the
resident size has grown by :data:`TRIM_SLACK_MB`) before the new model is compiled.
Only the last structure is kept.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import dataclasses
import os
import sys
from typing import Callable

import numpy as np

import simtest  # noqa: F401  (GL backend before mujoco)
import mujoco

from simtest.generators.builder import SceneBuilder, SimScene
from simtest.generators.scene_spec import LightSpec, SceneSpec, SurfaceSpec

__all__ = ["GraspModelCache", "structure_key", "apply_spec", "snapshot_model", "restore_model", "trim_heap",
           "resident_mb", "TRIM_SLACK_MB"]

_WHITE = (1.0, 1.0, 1.0)
_GREY = (0.5, 0.5, 0.5, 1.0)


def structure_key(spec: SceneSpec) -> tuple:
    """What decides the compiled model of a grasp scene: obj_id per instance, distractor shapes and sizes
    (sizes set the masses), the number of lights and the room surfaces (a flat table only by its pattern)."""
    table = spec.table
    table_key = (table.pattern, table.repeat) if _flat(table) else table
    return (tuple(int(p.obj_id) for p in spec.objects),
            tuple((d.shape, tuple(float(v) for v in d.size)) for d in spec.distractors),
            len(spec.lights), table_key, spec.floor, spec.walls)


def _flat(s: SurfaceSpec) -> bool:
    """A surface of one colour: drawn as a white texture times its material colour."""
    return s.pattern == "flat" and s.noise == 0.0


def _canonical_spec(spec: SceneSpec) -> SceneSpec:
    """``spec`` with every per-episode value replaced by a fixed one (same structure, see :func:`structure_key`)."""
    objects = tuple(dataclasses.replace(p, position=(10.0 * (i + 1), 0.0, -10.0), quat_wxyz=(1.0, 0.0, 0.0, 0.0),
                                        rgba=_GREY, specular=0.5, shininess=0.5, reflectance=0.0)
                    for i, p in enumerate(spec.objects))
    distractors = tuple(dataclasses.replace(d, position=(-10.0 * (j + 1), 0.0, -10.0),
                                            quat_wxyz=(1.0, 0.0, 0.0, 0.0), rgba=_GREY)
                        for j, d in enumerate(spec.distractors))
    lights = tuple(LightSpec((0.0, 0.0, 2.0), (0.0, 0.0, -1.0), (0.5, 0.5, 0.5), 0.1) for _ in spec.lights)
    table = dataclasses.replace(spec.table, rgb1=_WHITE, rgb2=_WHITE) if _flat(spec.table) else spec.table
    return dataclasses.replace(spec, scene_index=0, attempt=0, objects=objects, distractors=distractors,
                               lights=lights, ambient=0.3, table=table, views=())


#: Model arrays that hold asset payloads (meshes and their BVHs, textures, height fields, skins, flexes) or
#: names: megabytes that no scene code changes, so they are not snapshotted (the rest is ~0.3 MB).
_ASSET_PREFIXES = ("mesh_", "bvh_", "oct_", "tex_", "hfield_", "skin_", "flex", "name", "text_", "paths")


def snapshot_model(model: mujoco.MjModel) -> dict[str, np.ndarray]:
    """Copies of the model's arrays except asset payloads (see :func:`restore_model`)."""
    return {n: getattr(model, n).copy() for n in dir(model)
            if not n.startswith(("_",) + _ASSET_PREFIXES) and isinstance(getattr(model, n), np.ndarray)}


def restore_model(model: mujoco.MjModel, snapshot: dict[str, np.ndarray]) -> None:
    """Copy the arrays of ``snapshot`` (:func:`snapshot_model` of ``model`` as compiled) back into ``model``, in
    place: undoes whatever an episode changed (settling's gravity compensation of parked bodies, damping,
    occluder sizes, colours, lights)."""
    for name, values in snapshot.items():
        np.copyto(getattr(model, name), values)


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def _set_free_pose(model: mujoco.MjModel, data: mujoco.MjData, body: int, position, quat_wxyz) -> None:
    adr = int(model.jnt_qposadr[model.body_jntadr[body]])
    data.qpos[adr:adr + 3] = position
    data.qpos[adr + 3:adr + 7] = _unit(quat_wxyz)


def _id(model: mujoco.MjModel, kind: mujoco.mjtObj, name: str) -> int:
    i = mujoco.mj_name2id(model, kind, name)
    if i < 0:
        raise KeyError(f"the compiled grasp scene has no {kind.name} named {name!r}")
    return int(i)


def apply_spec(template: SimScene, pristine: dict[str, np.ndarray], spec: SceneSpec) -> SimScene:
    """The scene of ``spec`` on the template's model and data (same structure): model arrays restored from
    ``pristine`` (:func:`snapshot_model`), data reset, then the episode's poses, colours and lights written; the
    arm at home."""
    from simtest.robot import reset_arm

    m, d = template.model, template.data
    restore_model(m, pristine)
    mujoco.mj_resetData(m, d)
    for i, p in enumerate(spec.objects):
        _set_free_pose(m, d, template.instance_bodies[i], p.position, p.quat_wxyz)
        mat = _id(m, mujoco.mjtObj.mjOBJ_MATERIAL, f"obj_{i}_mat")
        m.mat_rgba[mat] = p.rgba
        m.mat_specular[mat], m.mat_shininess[mat], m.mat_reflectance[mat] = p.specular, p.shininess, p.reflectance
    for j, dis in enumerate(spec.distractors):
        _set_free_pose(m, d, _id(m, mujoco.mjtObj.mjOBJ_BODY, f"distractor_{j}"), dis.position, dis.quat_wxyz)
        m.geom_rgba[_id(m, mujoco.mjtObj.mjOBJ_GEOM, f"distractor_{j}_geom")] = dis.rgba
    for k, light in enumerate(spec.lights):
        lid = _id(m, mujoco.mjtObj.mjOBJ_LIGHT, f"light_{k}")
        m.light_pos[lid], m.light_dir[lid] = light.position, _unit(light.direction)
        m.light_diffuse[lid], m.light_specular[lid] = light.diffuse, [light.specular] * 3
    m.vis.headlight.ambient[:] = [spec.ambient] * 3
    if _flat(spec.table):
        m.mat_rgba[_id(m, mujoco.mjtObj.mjOBJ_MATERIAL, "table_mat")] = (*spec.table.rgb1, 1.0)
    if template.panda is not None:
        reset_arm(m, d, template.panda)  # also runs mj_forward
    else:
        mujoco.mj_forward(m, d)
    return dataclasses.replace(template, spec=spec, active=[True] * len(spec.objects))


class GraspModelCache:
    """The compiled model of the last grasp-scene structure, reused while the structure stays the same.

    Args:
        builder: The scene builder (object set and config) the models are compiled with.
        on_release: Called before a cached model is dropped (to close renderers and drop references to it).

    Attributes:
        compiles: Models compiled so far; ``reuses``: scenes built on a cached model.
    """

    def __init__(self, builder: SceneBuilder, on_release: Callable[[], None] | None = None) -> None:
        self.builder = builder
        self.on_release = on_release
        self.compiles = 0
        self.reuses = 0
        self._key: tuple | None = None
        self._template: SimScene | None = None
        self._pristine: dict[str, np.ndarray] | None = None

    def matches(self, spec: SceneSpec) -> bool:
        """Whether ``spec`` has the cached structure (its scene reuses the compiled model)."""
        return self._template is not None and structure_key(spec) == self._key

    def build(self, spec: SceneSpec) -> SimScene:
        """The scene of ``spec``: on the cached model when the structure matches, else on a new one."""
        if self.matches(spec):
            self.reuses += 1
        else:
            self.clear()
            template = self.builder.build(_canonical_spec(spec))
            self._pristine = snapshot_model(template.model)
            self._template, self._key = template, structure_key(spec)
            self.compiles += 1
        return apply_spec(self._template, self._pristine, spec)

    def clear(self) -> None:
        """Drop the cached model (after ``on_release``) and return freed heap to the operating system (once the
        resident size has grown by :data:`TRIM_SLACK_MB`, see :func:`trim_heap`)."""
        if self._template is None:
            return
        if self.on_release is not None:
            self.on_release()
        self._template = self._pristine = self._key = None
        trim_heap(TRIM_SLACK_MB)


#: :meth:`GraspModelCache.clear` returns freed heap to the OS once the resident size exceeds its size before the
#: last trim by this much (MB): trimming costs tens of ms (and the pages fault back in), so not every time.
TRIM_SLACK_MB = 64.0

_LAST_TRIM = {"rss_mb": 0.0}


def resident_mb() -> float | None:
    """Resident set size of this process, MB (from ``/proc/self/statm``); None where that file is missing."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2 ** 20
    except (OSError, ValueError, IndexError):
        return None


def trim_heap(slack_mb: float = 0.0) -> bool:
    """Return freed heap memory to the operating system (glibc ``malloc_trim(0)``); True if it ran.

    Large MuJoCo models and GL buffers leave freed chunks in malloc's arenas; without trimming the resident
    size keeps their high-water mark. With ``slack_mb > 0`` it runs only once the resident size exceeds its
    size before the last trim by that much. False where unavailable (not Linux, not glibc).
    """
    if not sys.platform.startswith("linux"):
        return False
    rss = resident_mb()
    if slack_mb > 0 and rss is not None and rss - _LAST_TRIM["rss_mb"] < slack_mb:
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.malloc_trim(0)
    except (OSError, AttributeError):  # not glibc (musl has no malloc_trim)
        return False
    _LAST_TRIM["rss_mb"] = rss or 0.0  # the size before trimming: the working set a steady run returns to
    return True
