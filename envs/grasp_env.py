"""``PandaGraspEnv``: a Franka Panda with a wrist RGB-D camera, grasping an object from a table.

A gymnasium environment (registered as ``simtest/PandaGrasp-v0``) on the generator's table scenes
(:mod:`simtest.envs.scene`) with the real Panda model of :mod:`simtest.robot`.

Observation (a dict):

* ``rgb``: (H, W, 3) uint8 wrist-camera image (corrupted as asked);
* ``depth``: (H, W) float32 planar depth, metres, 0 = missing: the exact rendered depth, or with
  ``depth_sensor="d435-stereo"`` / ``"passive-stereo"`` the depth sensed by the simulated stereo camera
  (:mod:`simtest.sensors.stereo`: IR pair, projector, SGBM, registration; 0 = invalid), then the
  ``depth_noise`` / corruption as asked. The exact depth behind it is :attr:`PandaGraspEnv.depth_exact`
  (``last_frame.depth``), never in ``info`` (which stays small per step);
* ``K``: (3, 3) float64 intrinsics, pixels (D435-like: fx = fy = 615 px at 640 px width);
* ``T_base_cam``: (4, 4) pose of the wrist camera (OpenCV frame) in the robot base frame, metres;
* ``joint_pos``, ``joint_vel``: (7,) arm joint angles (rad) and velocities (rad/s);
* ``gripper_width``: (1,) gap between the finger pads, metres (0 closed .. 0.08 open).

Action: ``Box(7)`` float32, ``[dx, dy, dz, rx, ry, rz, g]``: a TCP displacement in the world frame (metres,
at most :data:`MAX_STEP_TRANSLATION` per axis), a rotation vector applied in the world frame about the TCP
(radians, at most :data:`MAX_STEP_ROTATION` per axis), and the gripper command ``g`` from -1 (closed) to
+1 (fully open, 0.08 m), linear in the pad gap. Each step runs differential IK (:func:`simtest.robot.ik_step`)
once at 20 Hz and 25 physics steps of 2 ms (500 Hz). The commanded TCP pose integrates from the previous
*command*, so IK lag does not accumulate; the target is kept inside a workspace box above the table.

Reward: 1 for every step with the target grasped and lifted at least :data:`SUCCESS_HEIGHT` above where it
rested; the episode terminates once that has held for :data:`HOLD_TIME` seconds.

``reset(seed=, options=)`` options (each overrides the constructor's default for that episode):
``objects`` (object set name or path), ``target`` (obj_id or name; default a random graspable object),
``n_distractors``, ``occlusion`` (``"L0".."L3"``), ``corruption`` (a dict of
:class:`simtest.corrupt.CorruptionSpec` fields, e.g. ``{"weather": "fog", "severity": 4}``),
``depth_noise`` (a preset name of :data:`simtest.corrupt.DEPTH_PRESETS`), ``placement``
(``"upright"`` | ``"random"``) and ``start`` (``"home"`` | ``"observe"``: the arm's initial configuration).
Corruption, depth noise and the depth sensor change observations only, never ``info``; they draw from the
episode's own generators (the sensor from a stream of its own below the corruption stream), so the same seed
gives the same images, and turning the sensor on changes nothing but ``obs["depth"]``.

``info`` (ground truth, for oracles and scoring): ``target_obj_id``, ``target_name``, ``target_instance``,
``obj_ids`` (per instance), ``T_world_obj`` and ``T_cam_obj`` ((N, 4, 4) per instance, metres),
``T_world_cam``, ``T_world_base``, ``is_grasped`` (the target touches both fingers), ``lift_height`` (target
rise above its resting height, m), ``rest_height`` (m), ``occlusion`` (the occluder's measured effect),
``q_observe`` (the observation configuration) and ``sim_time`` (s).

Images are rendered only when an observation is produced (each :meth:`step` and :meth:`reset`, or on
:meth:`capture` when ``observe_every_step=False``), never per physics step. ``render_mode="rgb_array"``
renders a third-person view.

For RL clients:

* :meth:`step` rejects an action that is not 7 finite numbers with a :class:`~simtest.errors.ConfigError`
  (a ``ValueError``) naming the bad entries, before anything changes: the next valid step continues as if the
  bad call had not been made.
* :meth:`reset` reuses one compiled model and its renderer while the object set and image size stay the same:
  a pool model holding every object of the set twice and the occluder, the objects not in the episode parked
  asleep out of view and out of collision (:mod:`simtest.envs.model_cache`). Episodes the pool cannot hold
  (an object three times or more) use a model of their own structure, kept while the structure repeats.
  Before another model is compiled, the old renderer and model are freed. The same seed gives the same
  observations whether a model was reused or compiled anew (a pool model and a per-structure one differ by
  rounding only: settled poses within about 1e-7 m). Parked objects cost physics time in every step, so physics-only envs
  (``observe_every_step=False``) keep one model per structure unless ``model_pool=True``.
* GL is made lazily, by the first :meth:`reset`, in the process that renders (never in ``__init__``). GL
  contexts do not survive ``fork()``: in a process forked after its parent rendered, :meth:`reset` raises a
  :class:`~simtest.errors.RenderError` instead of hanging. For ``gymnasium.make_vec(...,
  vectorization_mode="async")`` pass ``vector_kwargs={"context": "spawn"}``.
* With the CUDA wheels of torch, import ``torch._dynamo`` (or call :func:`simtest.render.gl.prepare_torch`) before
  the first render; simtest does it itself when torch is already imported (see :mod:`simtest.render.gl`).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

import simtest  # noqa: F401  (GL backend before mujoco)
import mujoco

from simtest import robot
from simtest.camera import CameraModel, look_at_pose
from simtest.envs.observation import (DEPTH_SENSORS, T_world_cam_matrix, capture_images,
                                      observation_dict, observation_space, resolve_depth_sensor,
                                      sensor_stream)
from simtest.envs.options import (CONTROL_DT, HOLD_TIME, MAX_STEP_ROTATION, MAX_STEP_TRANSLATION, SUCCESS_HEIGHT,
                                  EpisodeConfig, check_action, load_objects, pick_target)
from simtest.errors import ConfigError
from simtest.geometry import Pose
from simtest.robot import rotvec_to_matrix
from simtest.render.rasterizer import Frame, Renderer

__all__ = ["PandaGraspEnv", "EpisodeConfig", "CONTROL_DT", "MAX_STEP_TRANSLATION", "MAX_STEP_ROTATION",
           "SUCCESS_HEIGHT", "HOLD_TIME", "DEPTH_SENSORS", "load_objects"]



class PandaGraspEnv(gym.Env):
    """Grasp a target object from a table with a Panda and its wrist RGB-D camera (see the module docstring).

    Args:
        render_mode: ``None`` or ``"rgb_array"`` (third-person view of ``render_width`` x ``render_height``).
        width, height: Wrist camera image size, pixels (D435-like intrinsics scaled to ``width``).
        objects: Default object set (``"builtin"``, ``"builtin-small"`` or a path).
        target: Default target (obj_id or name); ``None`` picks a random graspable object per episode.
        n_distractors: Default number of distractor objects.
        occlusion: Default occlusion level, ``"L0".."L3"``.
        corruption: Default observation corruption: a dict of :class:`CorruptionSpec` fields, or None.
        depth_noise: Default depth-noise preset, or None.
        placement: ``"upright"`` or ``"random"``.
        start: ``"home"`` (the arm starts at :data:`simtest.robot.HOME_QPOS`) or ``"observe"`` (at the
            observation configuration looking at the target).
        observe_every_step: Render a new observation on every :meth:`step` (default). With False, steps
            return the last captured images (call :meth:`capture` to take new ones): physics-only stepping.
        render_width, render_height: Third-person view size (default: the wrist camera size).
        ik: ``"fast"`` (one damped least-squares step per control period, :class:`simtest.robot.DiffIK`)
            or ``"panda"`` (:func:`simtest.robot.ik_step`, three iterations; slower).
        object_units, object_scale: Units (``"m"``, ``"cm"``, ``"mm"``, ``"auto"``) and scale factor of mesh
            files in the object sets (see :func:`simtest.objects.load_object_set`).
        model_pool: Reset on one model holding the whole object set (objects not in the episode parked asleep;
            :mod:`simtest.envs.model_cache`): resets need no compilation and memory stays flat, but the parked
            objects cost physics time in every ``mj_step`` (about 10-15 % with the 27-object ``builtin`` set;
            about 1-2 % of a step that renders). ``None`` (default): the pool when ``observe_every_step``, else
            one model per scene structure (physics-only stepping at full speed; a reset with other objects
            compiles a new model).
        depth_sensor: ``"none"`` (the observation's depth is the exact rendered depth) or a simulated stereo
            sensor of :data:`DEPTH_SENSORS` (``"d435-stereo"``, ``"passive-stereo"``): the observation's depth is
            then the sensed depth (0 = invalid); the exact depth stays in :attr:`depth_exact`.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": int(round(1.0 / CONTROL_DT))}

    def __init__(self, render_mode: str | None = None, *, width: int = 320, height: int = 240,
                 objects: str = "builtin", target: int | str | None = None, n_distractors: int = 2,
                 occlusion: str | int = "L0", corruption: dict | None = None, depth_noise: str | None = None,
                 placement: str = "upright", start: str = "home", observe_every_step: bool = True,
                 render_width: int | None = None, render_height: int | None = None, ik: str = "fast",
                 object_units: str = "auto", object_scale: float = 1.0, model_pool: bool | None = None,
                 depth_sensor: str = "none") -> None:
        if render_mode not in (None, "rgb_array"):
            raise ConfigError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        for name, v in (("width", width), ("height", height)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 16 <= v <= 4096:
                raise ConfigError(f"{name} must be an integer in [16, 4096] pixels, got {v!r}")
        if ik not in ("fast", "panda"):
            raise ConfigError(f"ik must be 'fast' (one DLS step, simtest.robot.DiffIK) or 'panda' "
                              f"(simtest.robot.ik_step), got {ik!r}")
        self.ik = ik
        self._sensor = resolve_depth_sensor(depth_sensor)
        self.depth_sensor = "none" if self._sensor is None else self._sensor.name
        self._sensor_rng: np.random.Generator | None = None
        self.object_units, self.object_scale = object_units, float(object_scale)
        self.render_mode = render_mode
        self.width, self.height = int(width), int(height)
        self.render_width = int(render_width or width)
        self.render_height = int(render_height or height)
        self.observe_every_step = bool(observe_every_step)
        if model_pool is not None and not isinstance(model_pool, bool):
            raise ConfigError(f"model_pool must be True, False or None (the pool when observe_every_step), "
                              f"got {model_pool!r}")
        self.model_pool = self.observe_every_step if model_pool is None else model_pool
        self._defaults = EpisodeConfig.build(EpisodeConfig(), {
            "objects": objects, "target": target, "n_distractors": n_distractors, "occlusion": occlusion,
            "corruption": corruption, "depth_noise": depth_noise, "placement": placement, "start": start})
        self.camera = CameraModel.default(self.width, self.height)
        self.observation_space = observation_space(self.width, self.height)
        lim = np.array([MAX_STEP_TRANSLATION] * 3 + [MAX_STEP_ROTATION] * 3 + [1.0], dtype=np.float32)
        self.action_space = spaces.Box(-lim, lim, dtype=np.float32)
        self._act_lo, self._act_hi = -lim.astype(np.float64), lim.astype(np.float64)
        self._builders: dict[str, Any] = {}
        self._models = None  # GraspModelCache of the current object set, made on the first reset
        self._renderer: Renderer | None = None  # GL resources are made on the first reset, never here
        self._tp_renderer: Renderer | None = None
        self._cam_K = np.array(self.camera.K, dtype=np.float64)
        self.grasp_scene = None
        self.model: mujoco.MjModel | None = None
        self.data: mujoco.MjData | None = None
        self.ids: robot.PandaIds | None = None
        self.config = self._defaults
        self._frame: Frame | None = None
        self._obs: dict | None = None

    # --- episode setup -------------------------------------------------------------------------------------
    def _builder(self, objects_name: str):
        from simtest.envs.scene import scene_config
        from simtest.generators.builder import SceneBuilder

        if objects_name not in self._builders:
            cfg = scene_config(self.width, self.height)
            objects = load_objects(objects_name, self.object_units, self.object_scale)
            self._builders[objects_name] = SceneBuilder(objects, cfg, panda_physics=True)
        return self._builders[objects_name]

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """Build and settle a new scene and return the first observation (see the module docstring).

        The compiled model and the renderer are reused while the object set and image size stay the same
        (:class:`simtest.envs.model_cache.GraspModelCache`); the same seed gives the same observations whether the
        model was reused or compiled anew. (A pooled model and a per-structure one, e.g. ``observe_every_step``
        off, differ by rounding only: settled poses within about 1e-7 m.)
        """
        super().reset(seed=seed)
        from simtest.envs.scene import build_grasp_scene, tune_occluder

        cfg = EpisodeConfig.build(self._defaults, options)
        self.config = cfg
        # Independent streams: scene layout, occluder, observation corruption.
        scene_rng, occ_rng, self._corrupt_rng = self.np_random.spawn(3)
        self._sensor_rng = sensor_stream(self._corrupt_rng) if self._sensor is not None else None
        objects = load_objects(cfg.objects, self.object_units, self.object_scale)
        self.objects = objects
        target_id = pick_target(objects, cfg.target, scene_rng)
        self.grasp_scene = build_grasp_scene(self._builder(cfg.objects), objects, target_id, scene_rng,
                                             n_distractors=cfg.n_distractors, occlusion=cfg.occlusion,
                                             placement=cfg.placement, models=self._model_cache(cfg.objects))
        sim = self.grasp_scene.sim
        if sim.model is not self.model:
            self._bind_model(sim)
        else:
            mujoco.mj_resetData(self.model, self._scratch)
            mujoco.mj_resetData(self.model, self._diffik.data)
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
        self._hold_steps = 0
        self._frame = None
        self._obs = None
        obs = self._observe(render=True)
        return obs, self.current_info()

    def _model_cache(self, objects_name: str):
        """The compiled-model cache of the object set ``objects_name`` (one cache: a new set drops the old)."""
        from simtest.envs.model_cache import GraspModelCache
        from simtest.envs.scene import POOL_DISTRACTORS

        builder = self._builder(objects_name)
        if self._models is None or self._models.builder is not builder:
            if self._models is not None:
                self._models.clear()
            self._models = GraspModelCache(builder, on_release=self._release_model,
                                           pool_distractors=POOL_DISTRACTORS, pool=self.model_pool)
        return self._models

    def _bind_model(self, sim) -> None:
        """Make the renderer and the per-model helpers for a newly compiled model."""
        from simtest.robot import DiffIK

        for r in (self._renderer, self._tp_renderer):  # normally closed already, when the cache dropped the model
            if r is not None:
                r.close()
        self._tp_renderer = None
        self.model, self.data, self.ids = sim.model, sim.data, sim.panda
        self._renderer = Renderer(self.model, self.width, self.height)
        self._scratch = mujoco.MjData(self.model)
        self._diffik = DiffIK(self.model, self.ids)
        self._lead = self.model.dof_damping[self.ids.arm_dof] / np.maximum(
            self.model.actuator_gainprm[self.ids.arm_actuators, 0], 1e-9)
        fb = self.model.geom_bodyid[self.ids.finger_geoms]
        bodies = sorted(set(fb.tolist()))
        self._left_geoms = self.ids.finger_geoms[fb == bodies[0]]
        self._right_geoms = self.ids.finger_geoms[fb == bodies[-1]]
        self._n_sub = max(1, int(round(CONTROL_DT / self.model.opt.timestep)))

    def _release_model(self) -> None:
        """Close the renderers (their GL resources) and drop every reference to the current model."""
        for r in (self._renderer, self._tp_renderer):
            if r is not None:
                r.close()
        self._renderer = self._tp_renderer = None
        self.model = self.data = self.ids = None
        self.grasp_scene = None
        self._scratch = self._diffik = None
        self._frame = self._obs = None
        robot.release_scratch()

    def _observation_q(self) -> np.ndarray:
        from simtest.envs.scene import (OBSERVATION_DISTANCE, OBSERVATION_ELEVATION, observation_camera_pose,
                                        observation_directions)

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

    # --- stepping ------------------------------------------------------------------------------------------
    def step(self, action: np.ndarray) -> tuple[dict, float, bool, bool, dict]:
        """Apply one 20 Hz control step (see the module docstring for the action).

        Raises:
            ConfigError: Before :meth:`reset`, or when ``action`` is not 7 finite numbers; nothing changes then,
                so the next valid step continues as if the bad call had not been made.
        """
        if self.data is None:
            raise ConfigError("call reset() before step()")
        a = np.minimum(np.maximum(check_action(action), self._act_lo), self._act_hi)
        m, d, ids = self.model, self.data, self.ids
        q_prev = self._q_cmd
        if self.ik == "fast":  # from the commanded TCP pose, one DLS step
            q_new = self._diffik.step_delta(q_prev, a[:3], a[3:6], self._ws_lo, self._ws_hi)
        else:
            pos, R_cur = self._diffik.fk(q_prev)  # the commanded TCP pose
            t = np.clip(pos + a[:3], self._ws_lo, self._ws_hi)
            R = rotvec_to_matrix(a[3:6]) @ R_cur
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
        obs = self._observe(render=self.observe_every_step)
        info = self.current_info()
        lifted = info["is_grasped"] and info["lift_height"] >= SUCCESS_HEIGHT
        self._hold_steps = self._hold_steps + 1 if lifted else 0
        terminated = self._hold_steps * CONTROL_DT >= HOLD_TIME - 1e-9
        return obs, float(lifted), bool(terminated), False, info

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

    def _workspace(self) -> tuple[np.ndarray, np.ndarray]:
        sc = self._builders[self.config.objects].options.room
        z0 = float(sc.table_height)
        lo = np.array([-sc.table_size[0] / 2, -sc.table_size[1] / 2, z0 + 0.005])
        hi = np.array([sc.table_size[0] / 2, sc.table_size[1] / 2, z0 + 0.7])
        return lo, hi

    # --- observations --------------------------------------------------------------------------------------
    def camera_model(self) -> CameraModel:
        """The wrist camera (intrinsics and ``T_world_cam``) at the current state."""
        return robot.wrist_camera_model(self.data, self.ids)

    def _T_world_cam(self) -> np.ndarray:
        """4x4 ``T_world_cam`` (OpenCV) of the wrist camera at the current state."""
        return T_world_cam_matrix(self.data, self.ids.camera)

    def capture(self) -> dict:
        """Render a new (corrupted) observation at the current state and return it."""
        return self._observe(render=True)

    def _observe(self, render: bool) -> dict:
        if render or self._obs is None:
            self._frame, *images = capture_images(self._renderer, self.data, self.ids, self._cam_K,
                                                  self.config.corruption, self._corrupt_rng, self._sensor,
                                                  self._sensor_rng)
            self._images = tuple(images)
            self._T_base_cam_at_capture = self._T_base_world @ self._T_world_cam()
        self._obs = observation_dict(self._images, self._cam_K, self._T_base_cam_at_capture, self.data, self.ids)
        return self._obs

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

    # --- ground truth ----------------------------------------------------------------------------------------
    def is_grasped(self) -> bool:
        """Whether the target touches a pad of each finger (contacts of the last physics step)."""
        d = self.data
        n = d.ncon
        if n == 0:
            return False
        pair = self._geom_cat[d.contact.geom[:n]].sum(axis=1)  # 1 + 2: target-left, 1 + 4: target-right
        return bool((pair == 3).any() and (pair == 5).any())

    def touches_gripper(self) -> bool:
        """Whether the target touches a pad of either finger (contacts of the last physics step)."""
        d = self.data
        n = d.ncon
        if n == 0:
            return False
        pair = self._geom_cat[d.contact.geom[:n]].sum(axis=1)
        return bool(((pair == 3) | (pair == 5)).any())

    def lift_height(self) -> float:
        """Height of the target above its resting height, m."""
        return float(self.data.xpos[self._target_body][2] - self.rest_height)

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

    @property
    def servo_lead(self) -> np.ndarray:
        """Per arm joint, the velocity lead (s) added to joint commands so the position servos track a moving
        command without lag: ``ctrl = q + lead * dq/dt`` (what :meth:`step` does)."""
        view = self._lead.view()
        view.flags.writeable = False
        return view

    @property
    def planning_data(self) -> mujoco.MjData:
        """A scratch ``MjData`` of the current model for planners' collision checks; :meth:`step` never reads it
        (copy the state in with ``planning_data.qpos[:] = env.data.qpos``)."""
        return self._scratch

    def render_wrist_rgb(self) -> np.ndarray:
        """The clean wrist-camera RGB image of the current state (no corruption; for videos), (H, W, 3) uint8."""
        return self._renderer.render(self.data, self.ids.camera, rgb=True, depth=False, seg=False).rgb

    def current_info(self) -> dict:
        """The ``info`` dict of the current state (ground truth; see the module docstring), as :meth:`step`
        returns it."""
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

    # --- rendering -------------------------------------------------------------------------------------------
    def third_person_camera(self) -> CameraModel:
        """A fixed view of the table and the robot from the front right (OpenCV ``T_world_cam``)."""
        z0 = self.grasp_scene.table_height
        cam = CameraModel.default(self.render_width, self.render_height)
        return cam.with_pose(look_at_pose(np.array([0.85, -0.95, z0 + 0.75]), np.array([-0.2, 0.0, z0 + 0.2])))

    def render(self) -> np.ndarray | None:
        """The third-person view (H, W, 3) uint8 in ``rgb_array`` mode; None otherwise."""
        if self.render_mode != "rgb_array":
            return None
        if self.data is None:
            raise ConfigError("call reset() before render()")
        return self.render_third_person()

    def render_third_person(self) -> np.ndarray:
        """Render the third-person view now, whatever the render mode."""
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
