"""Reuse of compiled grasp-scene models across episodes.

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

**One model for the whole object set.** With random targets and distractors drawn from a set, nearly every
episode has another structure. So the cache first tries a **pool** (:class:`ModelPool`): one model holding every
object of the set :data:`POOL_COPIES` times, plus the scene's distractor primitives (the grasp scene's occluder
box). An episode takes, for each of its instances, the next copy of that object; the rest are **parked**: far
above the room, out of collision (``contype``/``conaffinity`` 0, per geom and per body), out of the drawn groups
(group :data:`PARKED_GROUP`) and asleep (MuJoCo's sleeping islands, ``mjENBL_SLEEP``: their trees get the
``mjSLEEP_INIT`` policy, so :func:`mujoco.mj_resetData` puts them to sleep where they are, and a sleeping tree
costs no kinematics, dynamics or collision work in ``mj_step``). The episode's instances and the occluder get
``mjSLEEP_NEVER`` and the actuated arm never sleeps, so nothing in play is ever frozen. The pool depends only on
the object set, the image size and the room, so the same seed gives the same scene on a reused pool and on a
newly compiled one. Episodes the pool cannot hold (an object more than :data:`POOL_COPIES` times, other
distractors) and object sets too large for a pool (more than :data:`POOL_MAX_INSTANCES` pool instances) use the
per-structure model above.

**Looks.** Dressed episodes (the generator's materials, prints, lights and environment on the wrist camera's
scene, :mod:`simtest.envs.looks`) run on a pool with looks slots when their looks fit them
(:func:`simtest.envs.looks_slots.poolable`: library materials on the room, at most
:data:`~simtest.envs.looks_slots.LIGHT_SLOTS` lights): every surface, the occluder and every printed copy
compiled with a texture of its look's size, and a fixed set of lights. A reset writes the episode's textures,
material values and lights into it (:func:`~simtest.envs.looks_slots.write_looks`), and :attr:`GraspModelCache.uploads`
names the textures the renderers must upload again. Other dressed specs get a model of their own structure,
which then includes what is compiled into textures (prints, images, materials, the environment).
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
from simtest.robot import reset_arm
from simtest.generators.scene_spec import DistractorSpec, LightSpec, ObjectPlacement, SceneSpec, SurfaceSpec
from simtest.envs.looks_slots import SlotMismatch, poolable, slot_spec, write_looks

__all__ = ["GraspModelCache", "ModelPool", "structure_key", "apply_spec", "snapshot_model", "restore_model",
           "trim_heap", "resident_mb", "TRIM_SLACK_MB", "POOL_COPIES", "POOL_MAX_INSTANCES", "PARKED_GROUP"]

_WHITE = (1.0, 1.0, 1.0)
_GREY = (0.5, 0.5, 0.5, 1.0)


def structure_key(spec: SceneSpec) -> tuple:
    """What decides the compiled model of a grasp scene: obj_id per instance, distractor shapes and sizes
    (sizes set the masses), the room and lights (:func:`_room_key`), and what is compiled into textures: each
    instance's print (or plain look) and each distractor's image or material."""
    return (tuple(int(p.obj_id) for p in spec.objects),
            tuple((d.shape, tuple(float(v) for v in d.size)) for d in spec.distractors),
            *_room_key(spec),
            tuple((p.skin_seed, p.plain) for p in spec.objects),
            tuple((d.image, d.material) for d in spec.distractors))


def _room_key(spec: SceneSpec) -> tuple:
    """The lights and the room: the number of lights, the room surfaces (a flat table only by its pattern),
    the environment and the ceiling panel."""
    table = spec.table
    table_key = (table.pattern, table.repeat) if _flat(table) else table
    return (len(spec.lights), table_key, spec.floor, spec.walls, spec.environment, spec.ceiling)


def _undressed(spec: SceneSpec) -> bool:
    """No print, plain look, image or material on an instance or distractor (a pool without looks slots shows
    each copy as compiled)."""
    return (all(p.skin_seed is None and not p.plain for p in spec.objects)
            and all(d.image is None and d.material is None for d in spec.distractors))


#: The key of a pool with looks slots (:mod:`simtest.envs.looks_slots`): every dressed spec it can hold.
LOOKS_KEY = ("looks slots",)


def _pool_key(spec: SceneSpec) -> tuple:
    """The pool that holds ``spec``: one with looks slots if its looks fit them, else one per room."""
    return LOOKS_KEY if poolable(spec) else _room_key(spec)


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
    restore_model(template.model, pristine)
    scene = dataclasses.replace(template, spec=spec, active=[True] * len(spec.objects))
    _write_episode(scene, spec, [f"obj_{i}_mat" for i in range(len(spec.objects))])
    return scene


def _write_episode(scene: SimScene, spec: SceneSpec, materials: list[str],
                   looks: Callable[[], None] | None = None) -> None:
    """Write the episode's values into the scene's model (instance colours: instance i has material
    ``materials[i]``; distractor colours, lights, ambient light, table colour) and then ``looks`` (a pool's
    looks slots, :func:`simtest.envs.looks_slots.write_looks`), reset its data, then put the instances and
    distractors at their poses and the arm at home (``mj_forward`` run).

    The model is written before the reset: with sleeping enabled (pool models), the poses of static bodies'
    lights are computed by :func:`mujoco.mj_resetData`, not by ``mj_forward``.
    """
    m, d = scene.model, scene.data
    for i, p in enumerate(spec.objects):
        mat = _id(m, mujoco.mjtObj.mjOBJ_MATERIAL, materials[i])
        m.mat_rgba[mat] = p.rgba
        m.mat_specular[mat], m.mat_shininess[mat], m.mat_reflectance[mat] = p.specular, p.shininess, p.reflectance
    for j, dis in enumerate(spec.distractors):  # an image or material is not tinted (as the builder draws it)
        textured = dis.image is not None or dis.material is not None
        geom = _id(m, mujoco.mjtObj.mjOBJ_GEOM, f"distractor_{j}_geom")
        m.geom_rgba[geom] = (*_WHITE, 1.0) if textured else dis.rgba
    # With an environment its lights and ambient term are compiled (its structure); looks slots write their own.
    if spec.environment is None and looks is None:
        for k, light in enumerate(spec.lights):
            lid = _id(m, mujoco.mjtObj.mjOBJ_LIGHT, f"light_{k}")
            m.light_pos[lid], m.light_dir[lid] = light.position, _unit(light.direction)
            m.light_diffuse[lid], m.light_specular[lid] = light.diffuse, [light.specular] * 3
        m.vis.headlight.ambient[:] = [spec.ambient] * 3
    if _flat(spec.table):
        m.mat_rgba[_id(m, mujoco.mjtObj.mjOBJ_MATERIAL, "table_mat")] = (*spec.table.rgb1, 1.0)
    if looks is not None:
        looks()
    mujoco.mj_resetData(m, d)
    for i, p in enumerate(spec.objects):
        _set_free_pose(m, d, scene.instance_bodies[i], p.position, p.quat_wxyz)
    for j, dis in enumerate(spec.distractors):
        _set_free_pose(m, d, _id(m, mujoco.mjtObj.mjOBJ_BODY, f"distractor_{j}"), dis.position, dis.quat_wxyz)
    if scene.panda is not None:
        reset_arm(m, d, scene.panda)  # also runs mj_forward
    else:
        mujoco.mj_forward(m, d)


#: Copies of every object in a pool model: episodes with an object more often fall back to a model of their own.
#: Two copies hold every episode with up to two distractors (and nearly all with more).
POOL_COPIES = 2
#: Largest pool (object instances: set size times :data:`POOL_COPIES`); larger sets use per-structure models.
POOL_MAX_INSTANCES = 128
#: Geom group of parked pool geoms: not among the drawn groups (:data:`simtest.generators.builder.DRAWN_GROUPS`).
PARKED_GROUP = 5
#: Where pool instances are parked: a grid of spots (m) at this height, far beyond every camera's far plane.
_PARK_HEIGHT, _PARK_SPACING = 40.0, 3.0


def _park_spot(k: int) -> tuple[float, float, float]:
    """The k-th parking spot of a pool model (metres, world): a 10-wide grid in the sky, 3 m apart."""
    return (_PARK_SPACING * (k % 10 - 5), _PARK_SPACING * (k // 10 - 5), _PARK_HEIGHT)


def _body_geoms(model: mujoco.MjModel, body: int) -> slice:
    adr = int(model.body_geomadr[body])
    return slice(adr, adr + int(model.body_geomnum[body]))


@dataclasses.dataclass
class ModelPool:
    """A compiled model with every object of a set :data:`POOL_COPIES` times (see the module docstring).

    Attributes:
        template: The pool scene (all instances parked; its ``spec`` lists them in pool order).
        pristine: :func:`snapshot_model` of the model with everything parked.
        slots: obj_id -> the pool instance indices of its copies.
        distractors: (shape, size) of the pool's distractor primitives, in body order.
        distractor_bodies: Their body ids.
        key: :func:`structure_key` parts that are not objects or distractors (lights, room).
        live: Model values of the geoms and bodies of an instance in play (contact types, draw groups).
    """

    template: SimScene
    pristine: dict[str, np.ndarray]
    slots: dict[int, list[int]]
    distractors: tuple
    distractor_bodies: list[int]
    key: tuple
    live: dict[str, np.ndarray]
    builder: SceneBuilder | None = None
    uploaded: list[int] = dataclasses.field(default_factory=list)

    @property
    def dressed(self) -> bool:
        """Whether the pool has looks slots (:mod:`simtest.envs.looks_slots`)."""
        return self.key == LOOKS_KEY

    @classmethod
    def compile(cls, builder: SceneBuilder, spec: SceneSpec, distractors: tuple) -> "ModelPool":
        """The pool of ``builder``'s object set for scenes like ``spec`` (its lights and room, or looks slots
        when its looks fit them), with the distractor primitives ``distractors`` ((shape, size) pairs)."""
        ids = [int(i) for i in builder.objects.ids]
        objects = tuple(ObjectPlacement(obj_id=oid, position=_park_spot(c * len(ids) + k), quat_wxyz=(1.0, 0, 0, 0),
                                        rgba=_GREY, specular=0.5, shininess=0.5, reflectance=0.0)
                        for c in range(POOL_COPIES) for k, oid in enumerate(ids))
        n = len(objects)
        dis = tuple(DistractorSpec(shape, tuple(size), _park_spot(n + j), (1.0, 0, 0, 0), _GREY)
                    for j, (shape, size) in enumerate(distractors))
        key = _pool_key(spec)
        pool_spec = dataclasses.replace(_canonical_spec(spec), objects=objects, distractors=dis)
        template = builder.build(slot_spec(pool_spec, builder.objects) if key == LOOKS_KEY else pool_spec)
        m = template.model
        m.opt.enableflags |= int(mujoco.mjtEnableBit.mjENBL_SLEEP)  # before MjData: it initialises sleep
        template = dataclasses.replace(template, data=mujoco.MjData(m))
        live = {n_: getattr(m, n_).copy() for n_ in ("geom_contype", "geom_conaffinity", "geom_group",
                                                   "body_contype", "body_conaffinity", "body_gravcomp")}
        dbodies = [_id(m, mujoco.mjtObj.mjOBJ_BODY, f"distractor_{j}") for j in range(len(dis))]
        for b in list(template.instance_bodies) + dbodies:
            _park(m, b)
        slots: dict[int, list[int]] = {}
        for i, oid in enumerate(template.instance_obj_ids):
            slots.setdefault(int(oid), []).append(i)
        return cls(template, snapshot_model(m), slots, tuple(distractors), dbodies, key, live, builder)

    def fits(self, spec: SceneSpec) -> bool:
        """Whether the pool holds ``spec``: its room and lights (or looks that fit the slots), no object more
        often than the pool has it, and either no distractors or exactly the pool's."""
        if _pool_key(spec) != self.key or (not self.dressed and not _undressed(spec)):
            return False
        if spec.distractors and _distractor_key(spec) != self.distractors:
            return False
        counts: dict[int, int] = {}
        for p in spec.objects:
            counts[int(p.obj_id)] = counts.get(int(p.obj_id), 0) + 1
        return all(c <= len(self.slots.get(oid, ())) for oid, c in counts.items())

    def scene(self, spec: SceneSpec) -> SimScene:
        """The scene of ``spec`` (which :meth:`fits`) on the pool's model and data.

        Raises:
            SlotMismatch: A dressed spec's texture does not fit its slot (the model is left to the next
                :meth:`scene`, which restores it).
        """
        m, t = self.template.model, self.template
        taken: dict[int, int] = {}
        pool_index = []
        for p in spec.objects:
            oid = int(p.obj_id)
            pool_index.append(self.slots[oid][taken.get(oid, 0)])
            taken[oid] = taken.get(oid, 0) + 1
        bodies = [t.instance_bodies[k] for k in pool_index]
        restore_model(m, self.pristine)
        for b in bodies + (self.distractor_bodies if spec.distractors else []):
            _unpark(m, b, self.live)
        geom_instance = np.full(m.ngeom, -1, dtype=np.int32)
        for i, b in enumerate(bodies):
            geom_instance[_body_geoms(m, b)] = i
        scene = dataclasses.replace(
            t, spec=spec, instance_obj_ids=[int(p.obj_id) for p in spec.objects], instance_bodies=bodies,
            instance_qpos=[t.instance_qpos[k] for k in pool_index],
            instance_dofs=[t.instance_dofs[k] for k in pool_index],
            geom_instance=geom_instance, active=[True] * len(spec.objects))
        materials = [f"obj_{k}_mat" for k in pool_index]
        self.uploaded = []
        looks = None
        if self.dressed:
            def looks() -> None:
                self.uploaded = write_looks(scene, spec, materials, self.builder)
        _write_episode(scene, spec, materials, looks)
        return scene


def _distractor_key(spec: SceneSpec) -> tuple:
    return structure_key(spec)[1]


def _park(model: mujoco.MjModel, body: int) -> None:
    """Take a free body out of play: no contacts, not drawn, floating, asleep from :func:`mujoco.mj_resetData`
    on (its tree's policy ``mjSLEEP_INIT``)."""
    g = _body_geoms(model, body)
    model.geom_contype[g] = model.geom_conaffinity[g] = 0
    model.geom_group[g] = PARKED_GROUP
    model.body_contype[body] = model.body_conaffinity[body] = 0
    model.body_gravcomp[body] = 1.0
    model.tree_sleep_policy[model.body_treeid[body]] = int(mujoco.mjtSleepPolicy.mjSLEEP_INIT)


def _unpark(model: mujoco.MjModel, body: int, live: dict[str, np.ndarray]) -> None:
    """Put a parked body back in play with its compiled contact types, groups and gravity; never asleep."""
    g = _body_geoms(model, body)
    for name in ("geom_contype", "geom_conaffinity", "geom_group"):
        getattr(model, name)[g] = live[name][g]
    for name in ("body_contype", "body_conaffinity", "body_gravcomp"):
        getattr(model, name)[body] = live[name][body]
    model.tree_sleep_policy[model.body_treeid[body]] = int(mujoco.mjtSleepPolicy.mjSLEEP_NEVER)


class GraspModelCache:
    """Compiled grasp-scene models kept across episodes: the object set's pool (:class:`ModelPool`), and the
    model of the last structure for episodes the pool cannot hold (see the module docstring).

    Args:
        builder: The scene builder (object set and config) the models are compiled with.
        on_release: Called before a cached model is dropped (to close renderers and drop references to it).
        pool_distractors: (shape, size) of the distractor primitives the pool holds (each episode has all of
            them or none); episodes with other distractors use per-structure models.
        pool: Use a pool model when the object set is small enough (at most :data:`POOL_MAX_INSTANCES` pool
            instances); False keeps only per-structure models.

    Attributes:
        compiles: Models compiled so far; ``reuses``: scenes built on a kept model; ``pool_misses``: scenes the
            pool could not hold.
        uploads: Texture ids the last :meth:`build` wrote into a kept model (its looks slots): GL contexts made
            for that model must upload them again (``mujoco.mjr_uploadTexture``) before drawing.
    """

    def __init__(self, builder: SceneBuilder, on_release: Callable[[], None] | None = None,
                 pool_distractors: tuple = (), pool: bool = True) -> None:
        self.builder = builder
        self.on_release = on_release
        self.pool_distractors = tuple((str(shape), tuple(float(v) for v in size)) for shape, size in pool_distractors)
        self.use_pool = bool(pool) and len(builder.objects) * POOL_COPIES <= POOL_MAX_INSTANCES
        self.compiles = 0
        self.reuses = 0
        self.pool_misses = 0
        self.uploads: list[int] = []
        self._pool: ModelPool | None = None
        self._key: tuple | None = None
        self._template: SimScene | None = None
        self._pristine: dict[str, np.ndarray] | None = None

    def matches(self, spec: SceneSpec) -> bool:
        """Whether the scene of ``spec`` reuses a compiled model (the pool's or the last structure's)."""
        if self._pool is not None and self._pool.fits(spec):
            return True
        return self._template is not None and structure_key(spec) == self._key

    def build(self, spec: SceneSpec) -> SimScene:
        """The scene of ``spec``: on the pool when it holds ``spec``, else on the model of its structure (the
        cached one when the structure matches, else a new one)."""
        self.uploads = []
        if self.use_pool:
            reuse = self._pool is not None and self._pool.fits(spec)
            some_pool = poolable(spec) or _undressed(spec)  # else no pool holds it: keep the one there is
            if not reuse and some_pool and (self._pool is None or self._pool.key != _pool_key(spec)):
                self.clear()
                self._pool = ModelPool.compile(self.builder, spec, self.pool_distractors)
                self.compiles += 1
            if self._pool is not None and self._pool.fits(spec):
                try:
                    scene = self._pool.scene(spec)
                except SlotMismatch:
                    pass
                else:
                    self.reuses += reuse
                    self.uploads = list(self._pool.uploaded) if reuse else []
                    return scene
            self.pool_misses += 1
        if self._template is not None and structure_key(spec) == self._key:
            self.reuses += 1
        else:
            self._drop_structure()
            template = self.builder.build(_canonical_spec(spec))
            self._pristine = snapshot_model(template.model)
            self._template, self._key = template, structure_key(spec)
            self.compiles += 1
        return apply_spec(self._template, self._pristine, spec)

    def _drop_structure(self) -> None:
        """Drop the per-structure model (after ``on_release``), trimming the heap (see :meth:`clear`)."""
        if self._template is None:
            return
        if self.on_release is not None:
            self.on_release()
        self._template = self._pristine = self._key = None
        trim_heap(TRIM_SLACK_MB)

    def clear(self) -> None:
        """Drop the cached models (after ``on_release``) and return freed heap to the operating system (once the
        resident size has grown by :data:`TRIM_SLACK_MB`, see :func:`trim_heap`)."""
        if self._pool is not None:
            if self.on_release is not None:
                self.on_release()
            self._pool = None
            trim_heap(TRIM_SLACK_MB)
        self._drop_structure()


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
