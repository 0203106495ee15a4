"""``GraspTask``: one grasp scene's reset, success checks and the physics queries planners and episodes need.

The task is the simulation side of closed-loop grasping (dm_control's *Task*): it owns the object sets, the
compiled model and its renderers (reused across resets through :class:`~simtest.envs.model_cache.GraspModelCache`),
the episode's random streams, the Panda's controller state and the ground truth. The gymnasium environment
(:class:`simtest.envs.grasp_env.PandaGraspEnv`) is a thin adapter over it; the planner
(:class:`simtest.envs.planner.GraspPlanner`) and the scripted episodes (:func:`simtest.envs.episode.run_episode`)
work from the task alone.

One episode::

    task = GraspTask(width=160, height=120, episode={"objects": "builtin-small", "n_distractors": 0})
    obs = task.reset(seed=3, options={"target": "can_0"})   # scene built, settled, first observation
    task.advance(0.5)                                        # physics with the current controls, s
    obs = task.observe()                                     # a new capture at the current wrist pose
    task.is_grasped(), task.lift_height()                    # success checks (contacts, metres)

Random streams: :meth:`reset` seeds the task's generator (``seed``) or continues it (``seed=None``) and spawns
the episode's independent streams from it in a fixed order: scene layout, occluder, observation (corruption;
the depth sensor draws from a child of the observation stream, :func:`~simtest.envs.observation.sensor_stream`).
A stream added later is spawned after these, so the existing ones (and their bytes) stay as they are. The
episode's looks (``looks=True``) come from the scene stream's appearance stream
(:func:`simtest.envs.looks.looks_stream`, derived without drawing from it), so they change no pose, mask or
depth of the scene: the same seed gives the same scene with and without looks, in other colours.

Every capture (:meth:`observe`) renders the wrist camera at the arm's current configuration, so an episode may
observe again at any time (e.g. at the pre-grasp pose); the corruption and sensor noise continue their streams.
Units: metres, radians, seconds; camera frames are OpenCV.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.utils import seeding

import simtest  # noqa: F401  (GL backend before mujoco)
import mujoco

from simtest import robot
from simtest.camera import CameraModel, look_at_pose
from simtest.envs.looks import dresser
from simtest.envs.model_cache import GraspModelCache
from simtest.envs.observation import (Capture, ObservationModel, T_world_cam_matrix, capture_images,
                                      observation_dict, pbr_seed, sensor_stream)
from simtest.envs.options import (CONTROL_DT, MAX_STEP_ROTATION, MAX_STEP_TRANSLATION, SUCCESS_HEIGHT,
                                  EpisodeConfig, load_objects, pick_target)
from simtest.envs.scene import (OBSERVATION_DISTANCE, OBSERVATION_ELEVATION, POOL_DISTRACTORS, build_grasp_scene,
                                observation_camera_pose, observation_directions, scene_config, tune_occluder)
from simtest.errors import ConfigError
from simtest.generators.builder import SceneBuilder
from simtest.geometry import Pose
from simtest.render.rasterizer import Frame, Renderer

__all__ = ["GraspTask", "as_task", "IK_MODES"]

#: Controllers of :meth:`GraspTask.control`: one damped least-squares step (:class:`simtest.robot.DiffIK`) or
#: :func:`simtest.robot.ik_step` (three iterations; slower).
IK_MODES = ("fast", "panda")


def as_task(source: Any) -> "GraspTask":
    """The :class:`GraspTask` of ``source``: a task itself, or an env (wrappers are looked through) over one.

    Raises:
        ConfigError: ``source`` is neither (the message names its type).
    """
    if isinstance(source, GraspTask):
        return source
    task = getattr(getattr(source, "unwrapped", None), "task", None)
    if isinstance(task, GraspTask):
        return task
    raise ConfigError(f"expected a GraspTask or a PandaGraspEnv (wrapped or not), got {type(source).__name__!r}")


class GraspTask:
    """Grasp a target object from a table with a Panda and its wrist RGB-D camera (see the module docstring).

    Args:
        width, height: Wrist camera image size, pixels (D435-like intrinsics scaled to ``width``), 16..4096.
        episode: Default episode settings: an :class:`~simtest.envs.options.EpisodeConfig` or a dict of
            ``reset`` options (``objects``, ``target``, ``n_distractors``, ``occlusion``, ``placement``,
            ``start``; see :data:`~simtest.envs.options.RESET_OPTIONS`); :meth:`reset`'s ``options`` override
            them per episode.
        observation: How captures become observations (:class:`~simtest.envs.observation.ObservationModel`:
            the depth sensor and the default corruption and depth noise); default: exact images.
        ik: Controller of :meth:`control`, one of :data:`IK_MODES`.
        model_pool: Reset on one model holding the whole object set (objects not in the episode parked asleep,
            :mod:`simtest.envs.model_cache`), or one model per scene structure (False).
        object_units, object_scale: Units (``"m"``, ``"cm"``, ``"mm"``, ``"auto"``) and scale factor of mesh
            files in the object sets (see :func:`simtest.objects.load_object_set`).
        render_width, render_height: Size of the third-person view, pixels (default: the wrist camera size).
        looks: Dress every scene in the generator's looks (materials, prints, environment, lights;
            :mod:`simtest.envs.looks`), as datasets are drawn; False: the plain look of earlier releases (flat
            table, checker floor). A dressed scene's looks are written into the kept pool model
            (:mod:`simtest.envs.looks_slots`); looks that do not fit its slots get a model of their own.
    """

    def __init__(self, *, width: int = 320, height: int = 240, episode: EpisodeConfig | dict | None = None,
                 observation: ObservationModel | None = None, ik: str = "fast", model_pool: bool = True,
                 object_units: str = "auto", object_scale: float = 1.0, render_width: int | None = None,
                 render_height: int | None = None, looks: bool = True) -> None:
        for name, v in (("width", width), ("height", height)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 16 <= v <= 4096:
                raise ConfigError(f"{name} must be an integer in [16, 4096] pixels, got {v!r}")
        if ik not in IK_MODES:
            raise ConfigError(f"ik must be 'fast' (one DLS step, simtest.robot.DiffIK) or 'panda' "
                              f"(simtest.robot.ik_step), got {ik!r}")
        if not isinstance(model_pool, bool):
            raise ConfigError(f"model_pool must be True or False, got {model_pool!r}")
        if not isinstance(looks, bool):
            raise ConfigError(f"looks must be True (the generator's looks) or False (the plain look), got {looks!r}")
        self.looks = looks
        self.observation = observation if observation is not None else ObservationModel()
        if not isinstance(self.observation, ObservationModel):
            raise ConfigError(f"observation must be an ObservationModel, got {type(observation).__name__!r}")
        base = episode if isinstance(episode, EpisodeConfig) else EpisodeConfig.build(EpisodeConfig(), episode)
        self.defaults = self.observation.episode_defaults(base)
        self.ik, self.model_pool = ik, model_pool
        self.object_units, self.object_scale = object_units, float(object_scale)
        self.width, self.height = int(width), int(height)
        self.render_width = int(render_width or width)
        self.render_height = int(render_height or height)
        self._sensor = self.observation.sensor()
        self.depth_sensor = self.observation.depth_sensor
        self.camera = CameraModel.default(self.width, self.height)
        self._cam_K = np.array(self.camera.K, dtype=np.float64)
        # The step limits as the env's float32 action space holds them (clipping happens in float64).
        self._act_hi = np.array([MAX_STEP_TRANSLATION] * 3 + [MAX_STEP_ROTATION] * 3 + [1.0],
                                dtype=np.float32).astype(np.float64)
        self._builders: dict[str, SceneBuilder] = {}
        self._models: GraspModelCache | None = None  # of the current object set, made on the first reset
        self._renderer: Renderer | None = None  # GL resources are made on the first reset, never here
        self._tp_renderer: Renderer | None = None
        self._pbr = None  # the path tracer of the current model (pbr profile), made at its first capture
        self._pbr_captures = 0
        self._sensor_rng: np.random.Generator | None = None
        self.np_random: np.random.Generator | None = None
        self.grasp_scene = None
        self.model: mujoco.MjModel | None = None
        self.data: mujoco.MjData | None = None
        self.ids: robot.PandaIds | None = None
        self.config = self.defaults
        self._frame: Frame | None = None
        self._obs: dict | None = None
        #: With a list (``task.captures = []``), every capture of an episode is appended to it as a
        #: :class:`Capture` (:mod:`simtest.envs.observation_record` writes them as a BOP scene); reset empties it.
        self.captures: list[Capture] | None = None

    # --- episode setup -------------------------------------------------------------------------------------
    def _builder(self, objects_name: str) -> SceneBuilder:
        if objects_name not in self._builders:
            cfg = scene_config(self.width, self.height, self.observation.profile)
            objects = load_objects(objects_name, self.object_units, self.object_scale)
            self._builders[objects_name] = SceneBuilder(objects, cfg, panda_physics=True)
        return self._builders[objects_name]

    def _episode_streams(self, seed: int | None, rng: np.random.Generator | None) -> list[np.random.Generator]:
        """The episode's streams (scene layout, occluder, observation) from ``rng``, else from the task's
        generator seeded with ``seed`` (continued when ``seed`` is None), as gymnasium seeds ``np_random``."""
        if rng is not None:
            self.np_random = rng
        elif seed is not None or self.np_random is None:
            self.np_random, _ = seeding.np_random(seed)
        return self.np_random.spawn(3)

    def reset(self, seed: int | None = None, options: dict | None = None, *,
              rng: np.random.Generator | None = None) -> dict:
        """Build and settle a new scene, set the arm and return the first observation.

        The compiled model and the renderer are reused while the object set and image size stay the same
        (:class:`~simtest.envs.model_cache.GraspModelCache`); the same seed gives the same observations whether
        the model was reused or compiled anew (a pooled model and a per-structure one differ by rounding only:
        settled poses within about 1e-7 m).

        Args:
            seed: Seeds the task's generator; ``None`` continues it (a random one the first time).
            options: Per-episode overrides of the defaults (:data:`~simtest.envs.options.RESET_OPTIONS`).
            rng: The generator to spawn the episode's streams from instead (the env passes its ``np_random``).

        Raises:
            ConfigError: Unknown option names or bad values, an unknown target.
        """
        cfg = EpisodeConfig.build(self.defaults, options)
        self.config = cfg
        scene_rng, occ_rng, self._corrupt_rng = self._episode_streams(seed, rng)
        self._sensor_rng = sensor_stream(self._corrupt_rng) if self._sensor is not None else None
        objects = load_objects(cfg.objects, self.object_units, self.object_scale)
        self.objects = objects
        target_id = pick_target(objects, cfg.target, scene_rng)
        builder = self._builder(cfg.objects)
        self.grasp_scene = build_grasp_scene(builder, objects, target_id, scene_rng,
                                             n_distractors=cfg.n_distractors, occlusion=cfg.occlusion,
                                             placement=cfg.placement, models=self._model_cache(cfg.objects),
                                             looks=dresser(objects, scene_rng, builder) if self.looks else None)
        sim = self.grasp_scene.sim
        if sim.model is not self.model:
            self._bind_model(sim)
        else:
            mujoco.mj_resetData(self.model, self._scratch)
            mujoco.mj_resetData(self.model, self._diffik.data)
            self._upload_looks(self._models.uploads)
        self.target_obj = objects.get(target_id)
        self._target_body = sim.instance_bodies[self.grasp_scene.target_instance]
        self._instance_bodies = np.asarray(sim.instance_bodies, dtype=np.int64)
        self._target_geoms = np.flatnonzero(sim.geom_instance == self.grasp_scene.target_instance)
        # Geom category lookup for contact checks: 1 target, 2 left finger, 4 right finger.
        self._geom_cat = np.zeros(self.model.ngeom, np.int8)
        self._geom_cat[self._target_geoms] = 1
        self._geom_cat[self._left_geoms] = 2
        self._geom_cat[self._right_geoms] = 4
        self.T_world_base = Pose(self.data.xmat[self.ids.base_body].reshape(3, 3),
                                 self.data.xpos[self.ids.base_body])
        self._T_base_world = self.T_world_base.inverse().matrix()
        self._T_world_base_m = self.T_world_base.matrix()
        self.rest_height = float(self.data.xpos[self._target_body][2])

        # Observation configuration: the wrist camera looking at the target from the robot's side.
        self.q_observe = self._observation_q()
        self.occlusion = tune_occluder(self.grasp_scene, self._renderer, self.ids.camera, self.q_observe,
                                       cfg.occlusion, occ_rng) if cfg.occlusion > 0 else None
        if self.occlusion is not None:
            mujoco.mj_step(self.model, self.data, 50)  # the box comes to rest on the table
        robot.reset_arm(self.model, self.data, self.ids, self.q_observe if cfg.start == "observe" else None)
        self.rest_height = float(self.data.xpos[self._target_body][2])
        self._ws_lo, self._ws_hi = self._workspace()
        self._obj_ids = tuple(int(i) for i in sim.instance_obj_ids)
        self._q_cmd = self.ids.arm_q(self.data)
        self._frame = None
        self._obs = None
        if self.captures is not None:
            self.captures.clear()
        self._pbr_captures = 0  # the episode's path-traced captures so far (their sampler seeds)
        return self.observe()

    def _model_cache(self, objects_name: str) -> GraspModelCache:
        """The compiled-model cache of the object set ``objects_name`` (one cache: a new set drops the old)."""
        builder = self._builder(objects_name)
        if self._models is None or self._models.builder is not builder:
            if self._models is not None:
                self._models.clear()
            self._models = GraspModelCache(builder, on_release=self._release_model,
                                           pool_distractors=POOL_DISTRACTORS, pool=self.model_pool)
        return self._models

    @property
    def models(self) -> GraspModelCache | None:
        """The compiled-model cache of the current object set (its counters: compiles, reuses, pool misses)."""
        return self._models

    def _bind_model(self, sim) -> None:
        """Make the renderer and the per-model helpers for a newly compiled model."""
        for r in (self._renderer, self._tp_renderer):  # normally closed already, when the cache dropped the model
            if r is not None:
                r.close()
        self._tp_renderer = None
        self.model, self.data, self.ids = sim.model, sim.data, sim.panda
        self._renderer = Renderer(self.model, self.width, self.height,
                                  profile="quality" if self.observation.profile == "quality" else "fast")
        self._pbr = None  # the path tracer of this model, made at its first capture (pbr profile)
        self._scratch = mujoco.MjData(self.model)
        self._diffik = robot.DiffIK(self.model, self.ids)
        self._lead = self.model.dof_damping[self.ids.arm_dof] / np.maximum(
            self.model.actuator_gainprm[self.ids.arm_actuators, 0], 1e-9)
        fb = self.model.geom_bodyid[self.ids.finger_geoms]
        bodies = sorted(set(fb.tolist()))
        self._left_geoms = self.ids.finger_geoms[fb == bodies[0]]
        self._right_geoms = self.ids.finger_geoms[fb == bodies[-1]]
        self._n_sub = max(1, int(round(CONTROL_DT / self.model.opt.timestep)))

    def _upload_looks(self, textures: list[int]) -> None:
        """Upload the textures (ids) a kept model's looks slots took to the renderers; the path tracer reads
        the model anew at its next capture."""
        for r in (self._renderer, self._tp_renderer) if textures else ():
            if r is not None:
                r.upload_textures(textures)
        if textures and self._pbr is not None:
            self._pbr.close()
            self._pbr = None

    def _release_model(self) -> None:
        """Close the renderers (their GL resources) and drop every reference to the current model."""
        for r in (self._renderer, self._tp_renderer, self._pbr):
            if r is not None:
                r.close()
        self._pbr = None
        self._renderer = self._tp_renderer = None
        self.model = self.data = self.ids = None
        self.grasp_scene = None
        self._scratch = self._diffik = None
        self._frame = self._obs = None
        robot.release_scratch()

    def _observation_q(self) -> np.ndarray:
        """The arm configuration (7,) rad whose wrist camera looks at the target (the nearest reachable view)."""
        p = self.data.xpos[self._target_body].copy()
        p[2] = self.grasp_scene.table_height + 0.5 * (p[2] - self.grasp_scene.table_height)
        side_a, side_b, base_side = observation_directions(p[:2], self.T_world_base.t[:2])
        best = None
        for u, dist, el in ((side_a, OBSERVATION_DISTANCE, OBSERVATION_ELEVATION),
                            (side_b, OBSERVATION_DISTANCE, OBSERVATION_ELEVATION),
                            (base_side, 0.38, np.deg2rad(65.0)), (base_side, 0.34, np.deg2rad(75.0))):
            T = observation_camera_pose(p, u, dist, el)
            res = robot.solve_ik(self.model, self.data, self.ids, T, robot.HOME_QPOS, frame="camera")
            if res.success:
                return res.q
            if best is None or res.pos_err < best.pos_err:
                best = res
        return best.q  # the nearest reachable view (within a few mm of the requested one)

    def _workspace(self) -> tuple[np.ndarray, np.ndarray]:
        """The box (lo, hi), world frame, m, that commanded TCP positions are kept in: above the table."""
        sc = self._builders[self.config.objects].options.room
        z0 = float(sc.table_height)
        lo = np.array([-sc.table_size[0] / 2, -sc.table_size[1] / 2, z0 + 0.005])
        hi = np.array([sc.table_size[0] / 2, sc.table_size[1] / 2, z0 + 0.7])
        return lo, hi

    def _require_reset(self, what: str) -> None:
        if self.data is None:
            raise ConfigError(f"call reset() before {what}")

    # --- control and physics ------------------------------------------------------------------------------
    def control(self, action: np.ndarray) -> None:
        """One 20 Hz control step: ``action`` = ``[dx, dy, dz, rx, ry, rz, g]`` (a checked (7,) array; see
        :mod:`simtest.envs.grasp_env`), clipped to the step limits; the TCP command integrates from the previous
        command, runs IK once and 25 physics steps of 2 ms, then updates kinematics and camera frames."""
        self._require_reset("control()")
        a = np.minimum(np.maximum(np.asarray(action, dtype=np.float64), -self._act_hi), self._act_hi)
        m, d, ids = self.model, self.data, self.ids
        q_prev = self._q_cmd
        if self.ik == "fast":  # from the commanded TCP pose, one DLS step
            q_new = self._diffik.step_delta(q_prev, a[:3], a[3:6], self._ws_lo, self._ws_hi)
        else:
            pos, R_cur = self._diffik.fk(q_prev)  # the commanded TCP pose
            t = np.clip(pos + a[:3], self._ws_lo, self._ws_hi)
            R = robot.rotvec_to_matrix(a[3:6]) @ R_cur
            max_d = float(np.sqrt(3)) * MAX_STEP_TRANSLATION + 1e-9
            max_a = float(np.sqrt(3)) * MAX_STEP_ROTATION + 1e-9
            q_new = robot.ik_step(m, d, ids, Pose(R, t), CONTROL_DT, q_ref=q_prev,
                                  max_lin_speed=max_d / CONTROL_DT, max_ang_speed=max_a / CONTROL_DT)
        d.ctrl[ids.arm_actuators] = q_new + self._lead * (q_new - q_prev) / CONTROL_DT
        d.ctrl[ids.gripper_actuator] = 0.5 * (a[6] + 1.0) * robot.GRIPPER_OPEN
        self._q_cmd = q_new
        mujoco.mj_step(m, d, self._n_sub)
        mujoco.mj_kinematics(m, d)
        mujoco.mj_camlight(m, d)

    def advance(self, duration: float) -> None:
        """Run the physics for ``duration`` seconds with the current controls (whole 2 ms steps), then update
        the kinematics so poses, contacts and camera frames describe the final state."""
        n = max(0, int(round(duration / self.model.opt.timestep)))
        mujoco.mj_step(self.model, self.data, n)
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)

    def sync_command(self) -> None:
        """Take the current arm servo targets as the command to integrate from (after scripted motion)."""
        self._q_cmd = self.data.ctrl[self.ids.arm_actuators].copy()

    @property
    def servo_lead(self) -> np.ndarray:
        """Per arm joint, the velocity lead (s) added to joint commands so the position servos track a moving
        command without lag: ``ctrl = q + lead * dq/dt`` (what :meth:`control` does)."""
        view = self._lead.view()
        view.flags.writeable = False
        return view

    @property
    def planning_data(self) -> mujoco.MjData:
        """A scratch ``MjData`` of the current model for planners' collision checks; :meth:`control` never reads
        it (copy the state in with ``planning_data.qpos[:] = task.data.qpos``)."""
        return self._scratch

    # --- observations --------------------------------------------------------------------------------------
    def camera_model(self) -> CameraModel:
        """The wrist camera (intrinsics and ``T_world_cam``) at the current state."""
        return robot.wrist_camera_model(self.data, self.ids)

    def _T_world_cam(self) -> np.ndarray:
        """4x4 ``T_world_cam`` (OpenCV) of the wrist camera at the current state."""
        return T_world_cam_matrix(self.data, self.ids.camera)

    def observe(self, render: bool = True) -> dict:
        """The observation dict at the current state (see :mod:`simtest.envs.grasp_env`).

        Args:
            render: Capture new wrist images at the arm's current configuration (corrupted and sensed as the
                episode asks, continuing its streams); with False the last captured images are returned with
                the current joint state (physics-only stepping).
        """
        self._require_reset("observe()")
        if render or self._obs is None:
            self._frame, *images = capture_images(self._renderer, self.data, self.ids, self._cam_K,
                                                  self.config.corruption, self._corrupt_rng, self._sensor,
                                                  self._sensor_rng, self._pbr_source())
            self._images = tuple(images)
            self._T_base_cam_at_capture = self._T_base_world @ self._T_world_cam()
            if self.captures is not None:
                self.captures.append(Capture(self._frame, *self._images, self.camera_model(),
                                             self.grasp_scene.sim.state()))
        self._obs = observation_dict(self._images, self._cam_K, self._T_base_cam_at_capture, self.data, self.ids)
        return self._obs

    def _pbr_source(self):
        """With the pbr profile: the path-traced RGB of the current state (the model's renderer, made at its
        first capture and reused; sampler seeds from the episode's stream, one per capture); else None."""
        if self.observation.profile != "pbr":
            return None
        if self._pbr is None:
            from simtest.generators.looks import environment_of  # the path tracer is an optional extra
            from simtest.render.pbr import PbrRenderer

            env = self.grasp_scene.sim.spec.environment
            env = None if env is None else (environment_of(env).radiance, env.strength)
            self._pbr = PbrRenderer(self.model, self.camera, spp="auto", environment=env)
            # every capture sees the arm elsewhere, i.e. another scene: recorded kernels would never replay
            self._pbr.freeze = False
        k = self._pbr_captures
        self._pbr_captures += 1
        return lambda: self._pbr.render(self.data, self.ids.camera, seed=pbr_seed(self._corrupt_rng, k)).rgb

    def capture(self) -> dict:
        """Render a new (corrupted) observation at the current state and return it (:meth:`observe`)."""
        return self.observe(render=True)

    @property
    def last_frame(self) -> Frame | None:
        """The clean render (rgb, exact depth, segmentation) behind the last captured observation."""
        return self._frame

    @property
    def depth_exact(self) -> np.ndarray | None:
        """The exact planar depth (H, W) float32 metres (0 = nothing hit) behind the last captured observation,
        whatever the depth sensor and corruption made of ``obs["depth"]``; None before the first capture."""
        return None if self._frame is None else self._frame.depth

    def target_mask(self) -> np.ndarray:
        """Visible mask (H, W) bool of the target in the last captured observation (ground truth)."""
        if self._frame is None:
            raise ConfigError("no observation captured yet")
        return np.isin(self._frame.seg, self._target_geoms)

    def render_wrist_rgb(self) -> np.ndarray:
        """The clean wrist-camera RGB image of the current state (no corruption; for videos), (H, W, 3) uint8."""
        return self._renderer.render(self.data, self.ids.camera, rgb=True, depth=False, seg=False).rgb

    # --- success checks and ground truth ----------------------------------------------------------------------
    def _finger_contacts(self) -> np.ndarray:
        """Per contact of the last physics step, the sum of its two geoms' categories (1 target, 2 left finger,
        4 right finger): 3 = target-left, 5 = target-right."""
        n = self.data.ncon
        return self._geom_cat[self.data.contact.geom[:n]].sum(axis=1) if n else np.zeros(0, np.int8)

    def is_grasped(self) -> bool:
        """Whether the target touches a pad of each finger (contacts of the last physics step)."""
        pair = self._finger_contacts()
        return bool((pair == 3).any() and (pair == 5).any())

    def touches_gripper(self) -> bool:
        """Whether the target touches a pad of either finger (contacts of the last physics step)."""
        pair = self._finger_contacts()
        return bool(((pair == 3) | (pair == 5)).any())

    def lift_height(self) -> float:
        """Height of the target above its resting height, m."""
        return float(self.data.xpos[self._target_body][2] - self.rest_height)

    def is_lifted(self) -> bool:
        """Whether the target is grasped and at least :data:`~simtest.envs.options.SUCCESS_HEIGHT` m up."""
        return self.is_grasped() and self.lift_height() >= SUCCESS_HEIGHT

    def object_poses_world(self) -> np.ndarray:
        """(N, 4, 4) ``T_world_obj`` of every instance (target first), metres."""
        b = self._instance_bodies
        out = np.zeros((len(b), 4, 4))
        out[:, :3, :3] = self.data.xmat[b].reshape(-1, 3, 3)
        out[:, :3, 3] = self.data.xpos[b]
        out[:, 3, 3] = 1.0
        return out

    @property
    def target_geoms(self) -> np.ndarray:
        """Geom ids of the target object's geoms (read-only)."""
        view = self._target_geoms.view()
        view.flags.writeable = False
        return view

    def current_info(self) -> dict:
        """The ground truth of the current state (the env's ``info``; see :mod:`simtest.envs.grasp_env`)."""
        T_world_obj = self.object_poses_world()
        T_world_cam = self._T_world_cam()
        T_cam_world = np.zeros((4, 4))
        Rt = T_world_cam[:3, :3].T
        T_cam_world[:3, :3] = Rt
        T_cam_world[:3, 3] = -Rt @ T_world_cam[:3, 3]
        T_cam_world[3, 3] = 1.0
        return {
            "target_obj_id": int(self.target_obj.obj_id),
            "target_name": self.target_obj.name,
            "target_instance": int(self.grasp_scene.target_instance),
            "obj_ids": list(self._obj_ids),
            "T_world_obj": T_world_obj,
            "T_cam_obj": T_cam_world[None] @ T_world_obj,
            "T_world_cam": T_world_cam,
            "T_world_base": self._T_world_base_m.copy(),
            "is_grasped": self.is_grasped(),
            "lift_height": self.lift_height(),
            "rest_height": self.rest_height,
            "occlusion": None if self.occlusion is None else self.occlusion.to_dict(),
            "q_observe": self.q_observe.copy(),
            "sim_time": float(self.data.time),
        }

    # --- third-person view ------------------------------------------------------------------------------------
    def third_person_camera(self) -> CameraModel:
        """A fixed view of the table and the robot from the front right (OpenCV ``T_world_cam``)."""
        z0 = self.grasp_scene.table_height
        cam = CameraModel.default(self.render_width, self.render_height)
        return cam.with_pose(look_at_pose(np.array([0.85, -0.95, z0 + 0.75]), np.array([-0.2, 0.0, z0 + 0.2])))

    def render_third_person(self) -> np.ndarray:
        """The third-person view of the current state, (render_height, render_width, 3) uint8."""
        self._require_reset("render_third_person()")
        renderer = self._third_person_renderer()
        sim = self.grasp_scene.sim
        sim.set_camera(self.third_person_camera())
        return renderer.render(self.data, sim.camera_id, rgb=True, depth=False, seg=False).rgb

    def _third_person_renderer(self) -> Renderer:
        if (self.render_width, self.render_height) == (self.width, self.height):
            return self._renderer
        r = self._tp_renderer
        if r is None or r.model is not self.model:
            if r is not None:
                r.close()
            self.model.vis.global_.offwidth = max(self.model.vis.global_.offwidth, self.render_width)
            self.model.vis.global_.offheight = max(self.model.vis.global_.offheight, self.render_height)
            r = Renderer(self.model, self.render_width, self.render_height)
            self._tp_renderer = r
        return r

    def close(self) -> None:
        """Free the renderers (GL resources) and the cached model; a later :meth:`reset` builds them again."""
        if self._models is not None:
            self._models.clear()  # calls _release_model
            self._models = None
        self._release_model()
