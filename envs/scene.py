"""The grasping table scene: one target, distractor objects and physical occluders.

The scene is a :class:`~simtest.generators.scene_spec.SceneSpec` built by the generator's
:class:`~simtest.generators.builder.SceneBuilder` (with the Panda and its contact physics), so grasping runs
on exactly the scenes the datasets are made of. This module only decides *what* goes where:

* the **target** (instance 0) at a random spot of the reachable part of the table, upright with a random
  yaw (``placement="upright"``; objects that cannot stand on their base lie in their most likely stable
  pose, see :func:`rest_rotation`) or dropped in a random orientation (``"random"``);
* ``n_distractors`` other objects of the set around it, never in the strip between the target and the
  observation camera (which looks at the target diagonally, 60 degrees off the direction of the robot base);
* for occlusion levels L1..L3, one **standing box** (a free, collidable body) on the line of sight between
  the observation camera and the target; its height is bisected, with segmentation renders from the
  observation viewpoint, until the target's occluded fraction is near the middle of the level's band
  (OccludedPASCAL3D+ bands: L1 20-40 %, L2 40-60 %, L3 60-80 %).

World frame: the table top is at ``z = table_height`` (0.4 m), centred at the origin; the robot base stands at
the table's -x edge (``x = -0.5`` m). Lengths in metres, angles in radians.
"""

from __future__ import annotations

import colorsys
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

import simtest  # noqa: F401  (GL backend before mujoco)
import mujoco

from simtest.camera import CameraModel, default_intrinsics, look_at_pose
from simtest.corrupt.occlusion import OCCLUSION_BANDS
from simtest.errors import ConfigError
from simtest.generators.build_options import BuildOptions, SettleOptions
from simtest.generators.builder import SceneBuilder, SimScene
from simtest.generators.config import MaterialConfig
from simtest.generators.settle import settle
from simtest.generators.occlusion import bisect_occlusion
from simtest.generators.scene_spec import (DistractorSpec, LightSpec, ObjectPlacement, SceneSpec, SurfaceSpec,
                                          object_colour, random_quat_wxyz)
from simtest.geometry import Pose
from simtest.objects import ObjectSet

__all__ = [
    "TARGET_REGION",
    "OBSERVATION_DISTANCE",
    "OBSERVATION_ELEVATION",
    "OBSERVATION_AZIMUTH",
    "OcclusionResult",
    "GraspScene",
    "build_grasp_scene",
    "rest_rotation",
    "observation_camera_pose",
    "observation_directions",
    "tune_occluder",
    "scene_config",
    "SETTLE_MAX_TIME",
    "OCCLUDER_HALF_SIZE",
    "POOL_DISTRACTORS",
]

#: Where the target is placed: (x_min, x_max), (y_min, y_max) in the world, metres (0.38-0.62 m in front of
#: the robot base, within 0.15 m of its axis: comfortably inside the Panda's reach for top-down grasps).
TARGET_REGION = ((-0.12, 0.12), (-0.15, 0.15))
#: Observation viewpoint: camera distance to the target (m) and elevation above the table plane (rad), seen
#: from the robot's side.
OBSERVATION_DISTANCE = 0.42
OBSERVATION_ELEVATION = np.deg2rad(55.0)
#: Azimuth of the observation camera away from the direction of the robot base, rad.
OBSERVATION_AZIMUTH = np.deg2rad(60.0)
#: Occluder box thickness along the line of sight (m) and its gap to the target's footprint (m).
OCCLUDER_THICKNESS = 0.03
OCCLUDER_GAP = 0.025
#: Half extents (m) of the occluder box as sampled, before :func:`tune_occluder` resizes it (this size sets
#: its mass).
OCCLUDER_HALF_SIZE = (OCCLUDER_THICKNESS / 2, 0.04, 0.025)
#: The distractor primitives of grasp scenes, as (shape, half sizes): the occluder box (the model pool of
#: :class:`simtest.envs.model_cache.GraspModelCache` holds it).
POOL_DISTRACTORS = (("box", OCCLUDER_HALF_SIZE),)
#: Placement of the occluder before it is tuned: a corner of the table, out of the way (x, y in metres).
_OCCLUDER_PARK_XY = (0.33, 0.24)


#: Simulated seconds a grasp scene settles at most.
SETTLE_MAX_TIME = 2.0


def scene_config(width: int, height: int, quality: str = "fast") -> BuildOptions:
    """The building options of grasp scenes: the default table and room, the Panda, a ``width`` x ``height``
    wrist camera with D435-like intrinsics (fx = fy = 615 px at 640 px width), models made for render
    ``quality`` (:data:`simtest.generators.build_options.QUALITIES`)."""
    return BuildOptions(camera=CameraModel(default_intrinsics(int(width), int(height)), int(width), int(height)),
                        panda=True, quality=quality)


@dataclass
class OcclusionResult:
    """The occluder of one episode.

    Attributes:
        level: Requested level, 0..3.
        occluded_fraction: Fraction of the target's pixels (as seen from the observation pose) the occluder
            hides, or ``None`` without an occluder.
        in_band: Whether that fraction lies in the level's band.
        half_size: Box half extents (m).
        position: Box centre (m, world).
    """

    level: int
    occluded_fraction: float | None = None
    in_band: bool = False
    half_size: list[float] = field(default_factory=list)
    position: list[float] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"level": f"L{self.level}", "occluded_fraction": self.occluded_fraction, "in_band": self.in_band,
                "half_size": self.half_size, "position": self.position}


@dataclass
class GraspScene:
    """A built, settled grasp scene.

    Attributes:
        sim: The generator's scene (model, data, instance maps, Panda ids).
        target_instance: Instance index of the target (always 0).
        occluder_body: Body id of the occluder box, -1 if none.
        table_height: Height of the table top, m.
    """

    sim: SimScene
    target_instance: int
    occluder_body: int
    table_height: float


def _yaw_quat(yaw: float) -> tuple[float, float, float, float]:
    return (float(np.cos(yaw / 2)), 0.0, 0.0, float(np.sin(yaw / 2)))


def _jitter(rgb, rng: np.random.Generator, amount: float = 0.08) -> tuple[float, float, float]:
    return tuple(float(np.clip(c + rng.normal(0, amount), 0.02, 0.98)) for c in rgb[:3])


def _object_rgba(obj, rng: np.random.Generator) -> tuple[float, float, float, float]:
    """A plain object's colour jittered; a textured one keeps its texture under a mild tint."""
    if obj.appearance is None:
        return (*_jitter(obj.rgba, rng), 1.0)
    return object_colour(obj, 0.0, MaterialConfig().texture_jitter, rng)


def observation_directions(target_xy: np.ndarray, base_xy: np.ndarray) -> list[np.ndarray]:
    """Horizontal unit vectors from the target toward the observation camera, preferred first.

    The camera looks at the target diagonally, :data:`OBSERVATION_AZIMUTH` away from the direction of the
    robot base (straight from the base side the camera would sit too close to the base to be reached):
    first from the side nearer the robot's axis, then the other side, then from the base side.
    """
    t = np.asarray(target_xy, dtype=np.float64)[:2]
    u = np.asarray(base_xy, dtype=np.float64)[:2] - t
    n = float(np.linalg.norm(u))
    u = u / n if n > 1e-6 else np.array([-1.0, 0.0])
    out = []
    for sign in (1.0, -1.0):
        c, s = np.cos(sign * OBSERVATION_AZIMUTH), np.sin(sign * OBSERVATION_AZIMUTH)
        out.append(np.array([c * u[0] - s * u[1], s * u[0] + c * u[1]]))
    # Nearer the robot's axis (y = base y) first: the arm reaches it more comfortably.
    out.sort(key=lambda v: abs(t[1] + 0.25 * v[1] - float(np.asarray(base_xy)[1])))
    return out + [u]


def observation_camera_pose(look_at: np.ndarray, direction_xy: np.ndarray,
                            distance: float = OBSERVATION_DISTANCE,
                            elevation: float = OBSERVATION_ELEVATION) -> Pose:
    """``T_world_cam`` (OpenCV) of an observation view looking at ``look_at``.

    The camera sits ``distance`` m from the point, ``elevation`` rad above the table plane, in the horizontal
    direction ``direction_xy`` from it (see :func:`observation_directions`); image "up" points away from
    the camera's side.
    """
    p = np.asarray(look_at, dtype=np.float64)
    u = np.asarray(direction_xy, dtype=np.float64)[:2]
    u = u / np.linalg.norm(u)
    eye = p + distance * np.array([np.cos(elevation) * u[0], np.cos(elevation) * u[1], np.sin(elevation)])
    return look_at_pose(eye, p)


_REST_CACHE: dict[str, np.ndarray] = {}


def rest_rotation(obj) -> np.ndarray:
    """Orientation (3x3, model -> world, before a random yaw) of an object resting "upright".

    Model z up when the object stands firmly on its base (the centre of mass lies at least 6 mm inside the
    convex hull of the mesh's lowest points), otherwise its most likely stable pose
    (``trimesh.poses.compute_stable_poses`` about the centre of mass): a marker with a pointed end lies on
    its side instead of balancing on the tip. Cached per mesh.
    """
    key = obj.mesh_hash
    if key not in _REST_CACHE:
        import trimesh

        R = np.eye(3)
        if _support_margin(obj) >= 0.006:
            _REST_CACHE[key] = R
            return R
        try:
            T, prob = trimesh.poses.compute_stable_poses(obj.mesh, center_mass=np.asarray(obj.center_of_mass),
                                                         n_samples=1, threshold=0.0)
        except Exception:  # degenerate hulls: keep model z up
            T, prob = np.zeros((0, 4, 4)), np.zeros(0)
        if len(prob):
            R = np.asarray(T[int(np.argmax(prob)), :3, :3])
        _REST_CACHE[key] = R
    return _REST_CACHE[key]


def _support_margin(obj, band: float = 0.001) -> float:
    """How far (m) the centre of mass lies inside the support polygon of the object standing on its model -z
    end (the 2D convex hull of the vertices within ``band`` of the lowest one); negative if outside."""
    from scipy.spatial import ConvexHull, QhullError

    v = np.asarray(obj.vertices)
    base = v[v[:, 2] <= v[:, 2].min() + band][:, :2]
    com = np.asarray(obj.center_of_mass)[:2]
    try:
        hull = ConvexHull(base)
    except (QhullError, ValueError):
        return -1.0  # a point or a line: no area to stand on
    # Facet equations n . x + c <= 0 inside, with unit normals n: the margin is the smallest -(n . com + c).
    return float(np.min(-(hull.equations[:, :2] @ com + hull.equations[:, 2])))


def _footprint_radius(obj, yaw_only: bool) -> float:
    """Horizontal radius (m) of an object's footprint about its origin (upright: xy extent of the mesh)."""
    v = np.asarray(obj.vertices) @ rest_rotation(obj).T
    if yaw_only:
        return float(np.linalg.norm(v[:, :2], axis=1).max())
    return float(obj.diameter / 2.0)


def build_grasp_scene(
    builder: SceneBuilder,
    objects: ObjectSet,
    target_id: int,
    rng: np.random.Generator,
    *,
    n_distractors: int = 0,
    occlusion: int = 0,
    placement: str = "upright",
    scene_index: int = 0,
    models: "GraspModelCache | None" = None,
    looks: "Callable[[SceneSpec], SceneSpec] | None" = None,
) -> GraspScene:
    """Sample, build and settle one grasp scene.

    Args:
        builder: A :class:`SceneBuilder` for ``objects`` with the Panda in the scene (see :func:`scene_config`);
            its room is the one settling keeps the objects on.
        objects: The object set.
        target_id: obj_id of the target.
        rng: The episode's scene generator; every random choice is drawn from it in a fixed order.
        n_distractors: Other objects of the set placed around the target (>= 0).
        occlusion: Occlusion level 0..3; > 0 adds an occluder box (tuned later by :func:`tune_occluder`).
        placement: ``"upright"`` (model z up if stable, see :func:`rest_rotation`; random yaw) or ``"random"``
            (random orientation, dropped).
        scene_index: Recorded in the spec (model name).
        models: A :class:`GraspModelCache` of ``builder`` to reuse a compiled model (the object set's pool, or
            the previous scene's model when the structure is the same); None compiles a new model. Pass it
            ``pool_distractors=POOL_DISTRACTORS`` so episodes with an occluder use the pool too.
        looks: Dresses the sampled spec before it is built (appearance only, e.g.
            :func:`simtest.envs.looks.dress_grasp_spec` with the episode's appearance stream); it draws nothing
            from ``rng``. A dressed scene runs on ``models``' pool with looks slots when its looks fit them
            (:mod:`simtest.envs.looks_slots`); ``models.uploads`` then names the textures to upload again.

    Raises:
        ConfigError: On a bad ``placement`` or ``n_distractors``, or when the target falls off the table.
    """
    spec = sample_grasp_spec(builder, objects, target_id, rng, n_distractors=n_distractors, occlusion=occlusion,
                             placement=placement, scene_index=scene_index)
    if looks is not None:
        spec = looks(spec)
    sim = builder.build(spec) if models is None else models.build(spec)
    settle(sim, SettleOptions(max_time=SETTLE_MAX_TIME, room=builder.options.room))
    if not sim.active[0]:
        raise ConfigError(f"target obj_id {target_id} fell off the table while settling; use another seed")
    occluder = -1
    if occlusion > 0:
        occluder = mujoco.mj_name2id(sim.model, mujoco.mjtObj.mjOBJ_BODY, "distractor_0")
    return GraspScene(sim, 0, occluder, float(builder.options.room.table_height))


def sample_grasp_spec(
    builder: SceneBuilder,
    objects: ObjectSet,
    target_id: int,
    rng: np.random.Generator,
    *,
    n_distractors: int = 0,
    occlusion: int = 0,
    placement: str = "upright",
    scene_index: int = 0,
) -> SceneSpec:
    """The :class:`SceneSpec` of one grasp scene (arguments as :func:`build_grasp_scene`); pure sampling.

    Raises:
        ConfigError: On a bad ``placement`` or ``n_distractors``.
    """
    if placement not in ("upright", "random"):
        raise ConfigError(f"placement must be 'upright' or 'random', got {placement!r}")
    if isinstance(n_distractors, bool) or not isinstance(n_distractors, (int, np.integer)) or n_distractors < 0:
        raise ConfigError(f"n_distractors must be an integer >= 0, got {n_distractors!r}")
    sc = builder.options.room
    table_z = float(sc.table_height)
    upright = placement == "upright"
    target = objects.get(int(target_id))

    def pose_for(obj, xy: np.ndarray) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        if upright:
            R0 = rest_rotation(obj)
            yaw = float(rng.uniform(-np.pi, np.pi))
            Rz = np.array([[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
            R = Rz @ R0
            z = table_z - float((np.asarray(obj.vertices) @ R.T)[:, 2].min()) + 0.002
            quat = tuple(float(v) for v in Pose(R, np.zeros(3)).quat_wxyz())
        else:
            z = table_z + obj.diameter / 2.0 + 0.01
            quat = random_quat_wxyz(rng)
        return (float(xy[0]), float(xy[1]), float(z)), quat

    def placement_of(obj, xy: np.ndarray) -> ObjectPlacement:
        pos, quat = pose_for(obj, xy)
        return ObjectPlacement(obj_id=int(obj.obj_id), position=pos, quat_wxyz=quat,
                               rgba=_object_rgba(obj, rng), specular=float(rng.uniform(0.0, 0.4)),
                               shininess=float(rng.uniform(0.0, 0.5)), reflectance=0.0)

    (x0, x1), (y0, y1) = TARGET_REGION
    t_xy = np.array([rng.uniform(x0, x1), rng.uniform(y0, y1)])
    placements = [placement_of(target, t_xy)]
    r_t = _footprint_radius(target, upright)

    # The strip toward the observation camera stays free of distractors.
    base_xy = np.array([-sc.table_size[0] / 2 - 0.1, 0.0])
    to_cam = observation_directions(t_xy, base_xy)[0]
    hx, hy = sc.table_size[0] / 2 - 0.06, sc.table_size[1] / 2 - 0.06
    placed: list[tuple[np.ndarray, float]] = [(t_xy, r_t)]
    others = [i for i in objects.ids if i != int(target_id)] or list(objects.ids)
    for _ in range(int(n_distractors)):
        oid = int(others[int(rng.integers(len(others)))])
        obj = objects.get(oid)
        r = _footprint_radius(obj, upright)
        xy = None
        for _attempt in range(50):
            ang = rng.uniform(-np.pi, np.pi)
            dist = r_t + r + rng.uniform(0.04, 0.16)
            cand = t_xy + dist * np.array([np.cos(ang), np.sin(ang)])
            if abs(cand[0]) > hx or abs(cand[1]) > hy:
                continue
            if np.dot(cand - t_xy, to_cam) / dist > np.cos(np.deg2rad(50.0)):
                continue  # on the camera's side of the target
            if all(np.linalg.norm(cand - q) > r + rq + 0.02 for q, rq in placed):
                xy = cand
                break
        if xy is None:
            continue  # no room: fewer distractors rather than overlapping ones
        placed.append((xy, r))
        placements.append(placement_of(obj, xy))

    distractors = []
    if occlusion > 0:
        colour = colorsys.hsv_to_rgb(rng.uniform(0, 1), rng.uniform(0.3, 0.7), rng.uniform(0.4, 0.8))
        distractors.append(DistractorSpec(
            "box", OCCLUDER_HALF_SIZE, (*_OCCLUDER_PARK_XY, table_z + OCCLUDER_HALF_SIZE[2] + 0.001),
            (1.0, 0.0, 0.0, 0.0), (*(float(c) for c in colour), 1.0)))

    lights = (
        LightSpec((0.3, -0.6, table_z + 1.4), tuple(_unit([-0.3, 0.6, -1.4])), tuple([float(rng.uniform(0.5, 0.7))] * 3),
                  0.2),
        LightSpec((-0.4, 0.7, table_z + 1.2), tuple(_unit([0.4, -0.7, -1.2])), tuple([float(rng.uniform(0.3, 0.5))] * 3),
                  0.1),
    )
    table_rgb = _jitter((0.62, 0.55, 0.46), rng, 0.05)
    table = SurfaceSpec("flat", table_rgb, table_rgb, 1.0, 0.0)
    floor = SurfaceSpec("checker", (0.35, 0.35, 0.37), (0.3, 0.3, 0.32), 2.0, 0.0)
    walls = SurfaceSpec("flat", (0.7, 0.7, 0.72), (0.7, 0.7, 0.72), 1.0, 0.0)
    spec = SceneSpec(scene_index=int(scene_index), attempt=0, objects=tuple(placements),
                     distractors=tuple(distractors), lights=lights, ambient=float(rng.uniform(0.3, 0.4)),
                     table=table, floor=floor, walls=walls, views=())
    return spec


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def _free_joint(model: mujoco.MjModel, body: int) -> tuple[int, int]:
    j = model.body_jntadr[body]
    return int(model.jnt_qposadr[j]), int(model.jnt_dofadr[j])


def _set_box(scene: GraspScene, data: mujoco.MjData, half: np.ndarray, pos: np.ndarray, yaw: float) -> None:
    """Resize the occluder box (model geom size) and put it at ``pos`` with ``yaw`` in ``data``, at rest."""
    m = scene.sim.model
    g = int(m.body_geomadr[scene.occluder_body])
    m.geom_size[g] = half
    m.geom_rbound[g] = float(np.linalg.norm(half))
    m.geom_aabb[g, 3:] = half
    qadr, vadr = _free_joint(m, scene.occluder_body)
    data.qpos[qadr:qadr + 3] = pos
    data.qpos[qadr + 3:qadr + 7] = _yaw_quat(yaw)
    data.qvel[vadr:vadr + 6] = 0.0


def tune_occluder(scene: GraspScene, renderer, camera_id: int, q_observe: np.ndarray, level: int,
                  rng: np.random.Generator, definition: str = "pascal3d+", steps: int = 8) -> OcclusionResult:
    """Stand the occluder box between the target and the observation camera and bisect its height until the
    target's occluded fraction (seen from arm configuration ``q_observe``) is near the level band's middle.

    The box stands ``OCCLUDER_GAP`` m beyond the target's footprint toward the camera, across the line of
    sight, a little wider than the target. Renders are made on a copy of the state; the box is then left
    standing in ``scene.sim.data`` (at rest).

    Args:
        scene: The settled scene (must have an occluder).
        renderer: A :class:`simtest.render.rasterizer.Renderer` of the scene's model.
        camera_id: The wrist camera id.
        q_observe: Arm configuration (7,) rad of the observation pose.
        level: 1..3.
        rng: Generator for the box's lateral offset.
        definition: Band definition (``pascal3d+`` or ``objectcentric``).
        steps: Bisection steps.
    """
    res = OcclusionResult(level)
    if level <= 0 or scene.occluder_body < 0:
        return res
    sim = scene.sim
    m = sim.model
    lo, hi = OCCLUSION_BANDS[definition][level][0]
    scratch = mujoco.MjData(m)
    scratch.qpos[:] = sim.data.qpos
    scratch.qpos[sim.panda.arm_qpos] = q_observe
    mujoco.mj_forward(m, scratch)
    cam_pos = scratch.cam_xpos[camera_id].copy()
    body = sim.instance_bodies[scene.target_instance]
    target_geoms = np.flatnonzero(sim.geom_instance == scene.target_instance)
    t_obj = sim.data.xpos[body].copy()
    # Footprint radius and top of the target as it rests (from its collision/visual geoms' world bounds).
    verts = _target_world_vertices(scene)
    r = float(np.linalg.norm(verts[:, :2] - t_obj[:2], axis=1).max())
    u = cam_pos[:2] - t_obj[:2]
    u /= np.linalg.norm(u)
    side = np.array([-u[1], u[0]])
    # Half-width: the target's extent across the line of sight plus 1.5 cm, with a small random offset.
    across = np.abs((verts[:, :2] - t_obj[:2]) @ side).max()
    half_w = across + 0.015
    centre = t_obj[:2] + u * (r + OCCLUDER_GAP + OCCLUDER_THICKNESS / 2) + side * rng.uniform(-0.3, 0.3) * across
    yaw = float(np.arctan2(u[1], u[0]))
    table_z = scene.table_height

    def visible(h: float | None) -> int:
        if h is None:
            _set_box(scene, scratch, np.array([0.01, 0.01, 0.01]), np.array([*_OCCLUDER_PARK_XY, -5.0]), 0.0)
        else:
            _set_box(scene, scratch, np.array([OCCLUDER_THICKNESS / 2, half_w, h / 2]),
                     np.array([centre[0], centre[1], table_z + h / 2]), yaw)
        mujoco.mj_kinematics(m, scratch)
        mujoco.mj_camlight(m, scratch)
        seg = renderer.render(scratch, camera_id, rgb=False, depth=False, seg=True).seg
        return int(np.isin(seg, target_geoms).sum())

    n_free = visible(None)
    if n_free == 0:
        h_best, f_best = 0.02, 0.0
    else:
        h_best, f_best = bisect_occlusion(lambda h: 1.0 - visible(h) / n_free, 0.005,
                                          float(min(cam_pos[2] - table_z - 0.08, 0.35)), (lo, hi), steps=steps,
                                          tol=0.03)
    half = np.array([OCCLUDER_THICKNESS / 2, half_w, h_best / 2])
    pos = np.array([centre[0], centre[1], table_z + h_best / 2 + 0.0005])
    _set_box(scene, sim.data, half, pos, yaw)
    mujoco.mj_forward(m, sim.data)
    res.occluded_fraction = float(f_best)
    res.in_band = bool(lo <= f_best <= hi)
    res.half_size = [float(v) for v in half]
    res.position = [float(v) for v in pos]
    return res


def _target_world_vertices(scene: GraspScene) -> np.ndarray:
    sim = scene.sim
    R, t = sim.object_pose_world(scene.target_instance)
    g = int(sim.model.body_geomadr[sim.instance_bodies[scene.target_instance]])  # the visual mesh geom
    mesh = int(sim.model.geom_dataid[g])
    adr, n = int(sim.model.mesh_vertadr[mesh]), int(sim.model.mesh_vertnum[mesh])
    v_geom = sim.model.mesh_vert[adr:adr + n]
    # Mesh vertices are stored in the geom frame; map geom -> world.
    Rg = sim.data.geom_xmat[g].reshape(3, 3)
    return v_geom @ Rg.T + sim.data.geom_xpos[g]
