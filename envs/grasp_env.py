"""``PandaGraspEnv``: a Franka Panda with a wrist RGB-D camera, grasping an object from a table.

A gymnasium environment (registered as ``simtest/PandaGrasp-v0``) on the generator's table scenes
(:mod:`simtest.envs.scene`) with the real Panda model of :mod:`simtest.robot`. It is a thin adapter over a
:class:`~simtest.envs.task.GraspTask`, which owns the scene, the physics and the ground truth: the env maps
``reset`` / ``step`` / ``render`` onto the task and adds the spaces, the reward and the termination. Its
physics queries (``model``, ``data``, ``ids``, ``grasp_scene``, ``advance``, ``current_info``, ...) are the
task's (``env.unwrapped.task``).

Observation (a dict):

* ``rgb``: (H, W, 3) uint8 wrist-camera image (corrupted as asked);
* ``depth``: (H, W) float32 planar depth, metres, 0 = missing: the exact rendered depth, or with
  ``ObservationModel(depth_sensor="d435-stereo")`` / ``"passive-stereo"`` the depth sensed by the simulated
  stereo camera (:mod:`simtest.sensors.stereo`: IR pair, projector, SGBM, registration; 0 = invalid), then the
  ``depth_noise`` / corruption as asked (:class:`~simtest.envs.observation.ObservationModel`). The exact depth
  behind it is :attr:`GraspTask.depth_exact <simtest.envs.task.GraspTask.depth_exact>`
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
the task's :meth:`~simtest.envs.task.GraspTask.observe` when ``observe_every_step=False``), never per physics
step. ``render_mode="rgb_array"`` renders a third-person view.

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

import warnings
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from simtest.envs.observation import DEPTH_SENSORS, ObservationModel, observation_space
from simtest.envs.options import (CONTROL_DT, HOLD_TIME, MAX_STEP_ROTATION, MAX_STEP_TRANSLATION, RESET_OPTIONS,
                                  SUCCESS_HEIGHT, EpisodeConfig, check_action, load_objects)
from simtest.envs.task import GraspTask
from simtest.errors import ConfigError

__all__ = ["PandaGraspEnv", "EpisodeConfig", "CONTROL_DT", "MAX_STEP_TRANSLATION", "MAX_STEP_ROTATION",
           "SUCCESS_HEIGHT", "HOLD_TIME", "DEPTH_SENSORS", "load_objects", "OBSERVATION_KEYWORDS"]

#: Constructor keywords that moved into :class:`~simtest.envs.observation.ObservationModel` (``observation=``);
#: they still work, with a DeprecationWarning.
OBSERVATION_KEYWORDS = ("corruption", "depth_noise", "depth_sensor")


def _task_of(task: GraspTask | None, observe_every_step: bool, model_pool: bool | None, episode: dict,
             options: dict) -> GraspTask:
    """The env's task: ``task`` itself, or one made from the constructor's keywords (``options`` are
    :class:`GraspTask` keywords, ``episode`` the default reset options and the moved observation keywords)."""
    if model_pool is not None and not isinstance(model_pool, bool):
        raise ConfigError(f"model_pool must be True, False or None (the pool when observe_every_step), "
                          f"got {model_pool!r}")
    moved = {k: episode.pop(k) for k in OBSERVATION_KEYWORDS if k in episode}
    unknown = sorted(set(episode) - set(RESET_OPTIONS))
    if unknown:
        raise ConfigError(f"unknown PandaGraspEnv keyword(s) {unknown}; the task's: width, height, observation, "
                          f"ik, model_pool, object_units, object_scale, render_width, render_height, looks, task; "
                          f"episode defaults: "
                          f"{', '.join(o for o in RESET_OPTIONS if o not in OBSERVATION_KEYWORDS)}")
    if task is not None:
        extra = sorted([*options, *episode, *moved, *(["model_pool"] if model_pool is not None else [])])
        if extra:
            raise ConfigError(f"pass either task= or the task's settings, not both; got task= and {extra}")
        if not isinstance(task, GraspTask):
            raise ConfigError(f"task must be a GraspTask, got {type(task).__name__!r}")
        return task
    if moved:
        if options.get("observation") is not None:
            raise ConfigError(f"pass {sorted(moved)} inside observation=ObservationModel(...), not beside it")
        warnings.warn(f"PandaGraspEnv({', '.join(f'{k}=' for k in moved)}...) moved into the observation model: "
                      f"pass observation=simtest.envs.observation.ObservationModel({', '.join(sorted(moved))}=...)",
                      DeprecationWarning, stacklevel=3)
        options["observation"] = ObservationModel(**moved)
    pool = observe_every_step if model_pool is None else model_pool
    return GraspTask(episode=episode, model_pool=pool, **options)


class PandaGraspEnv(gym.Env):
    """Grasp a target object from a table with a Panda and its wrist RGB-D camera (see the module docstring):
    the gymnasium adapter over a :class:`~simtest.envs.task.GraspTask`.

    Args:
        render_mode: ``None`` or ``"rgb_array"`` (third-person view of ``render_width`` x ``render_height``).
        task: The task to adapt; without it one is made from the keywords below.
        observe_every_step: Render a new observation on every :meth:`step` (default). With False, steps
            return the last captured images (``env.unwrapped.task.observe()`` takes new ones): physics-only
            stepping.
        width, height: Wrist camera image size, pixels (D435-like intrinsics scaled to ``width``).
        observation: The :class:`~simtest.envs.observation.ObservationModel` (depth sensor, default corruption
            and depth noise); ``corruption=``, ``depth_noise=`` and ``depth_sensor=`` keywords still work
            (DeprecationWarning).
        ik: ``"fast"`` (one damped least-squares step per control period, :class:`simtest.robot.DiffIK`)
            or ``"panda"`` (:func:`simtest.robot.ik_step`, three iterations; slower).
        model_pool: Reset on one model holding the whole object set (objects not in the episode parked asleep;
            :mod:`simtest.envs.model_cache`): resets need no compilation and memory stays flat, but the parked
            objects cost physics time in every ``mj_step`` (about 10-15 % with the 27-object ``builtin`` set;
            about 1-2 % of a step that renders). ``None`` (default): the pool when ``observe_every_step``, else
            one model per scene structure (physics-only stepping at full speed; a reset with other objects
            compiles a new model).
        object_units, object_scale: Units (``"m"``, ``"cm"``, ``"mm"``, ``"auto"``) and scale factor of mesh
            files in the object sets (see :func:`simtest.objects.load_object_set`).
        render_width, render_height: Third-person view size (default: the wrist camera size).
        looks: The generator's looks on every scene (default; written into the pool model's looks slots at
            each reset, :mod:`simtest.envs.looks_slots`), or False for the plain look of earlier releases
            (:mod:`simtest.envs.looks`).
        **episode: Default reset options (:data:`~simtest.envs.options.RESET_OPTIONS`): ``objects``
            (``"builtin"``), ``target`` (None: a random graspable object), ``n_distractors`` (2), ``occlusion``
            (``"L0"``), ``placement`` (``"upright"``), ``start`` (``"home"`` or ``"observe"``).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": int(round(1.0 / CONTROL_DT))}

    def __init__(self, render_mode: str | None = None, *, task: GraspTask | None = None,
                 observe_every_step: bool = True, model_pool: bool | None = None, **settings: Any) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ConfigError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        task_keys = ("width", "height", "observation", "ik", "object_units", "object_scale", "render_width",
                     "render_height", "looks")
        options = {k: settings.pop(k) for k in task_keys if k in settings}
        self.task = _task_of(task, bool(observe_every_step), model_pool, settings, options)
        self.render_mode = render_mode
        self.observe_every_step = bool(observe_every_step)
        self.observation_space = observation_space(self.task.width, self.task.height)
        lim = np.array([MAX_STEP_TRANSLATION] * 3 + [MAX_STEP_ROTATION] * 3 + [1.0], dtype=np.float32)
        self.action_space = spaces.Box(-lim, lim, dtype=np.float32)
        self._hold_steps = 0

    def __getattr__(self, name: str) -> Any:
        """The task's public attributes and queries (``model``, ``data``, ``ids``, ``grasp_scene``,
        ``target_obj``, ``advance``, ``sync_command``, ``current_info``, ...), read through the env."""
        task = self.__dict__.get("task")
        if task is None or name.startswith("_"):
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
        return getattr(task, name)

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """Build and settle a new scene and return the first observation and ``info`` (see the module
        docstring and :meth:`GraspTask.reset <simtest.envs.task.GraspTask.reset>`)."""
        super().reset(seed=seed)
        obs = self.task.reset(options=options, rng=self.np_random)
        self._hold_steps = 0
        return obs, self.task.current_info()

    def step(self, action: np.ndarray) -> tuple[dict, float, bool, bool, dict]:
        """Apply one 20 Hz control step (see the module docstring for the action).

        Raises:
            ConfigError: Before :meth:`reset`, or when ``action`` is not 7 finite numbers; nothing changes then,
                so the next valid step continues as if the bad call had not been made.
        """
        if self.task.data is None:
            raise ConfigError("call reset() before step()")
        self.task.control(check_action(action))
        obs = self.task.observe(render=self.observe_every_step)
        info = self.task.current_info()
        lifted = info["is_grasped"] and info["lift_height"] >= SUCCESS_HEIGHT
        self._hold_steps = self._hold_steps + 1 if lifted else 0
        terminated = self._hold_steps * CONTROL_DT >= HOLD_TIME - 1e-9
        return obs, float(lifted), bool(terminated), False, info

    def capture(self) -> dict:
        """Render a new (corrupted) observation at the current state and return it (the task's ``observe``)."""
        return self.task.observe(render=True)

    def render(self) -> np.ndarray | None:
        """The third-person view (H, W, 3) uint8 in ``rgb_array`` mode; None otherwise."""
        if self.render_mode != "rgb_array":
            return None
        if self.task.data is None:
            raise ConfigError("call reset() before render()")
        return self.task.render_third_person()

    def close(self) -> None:
        """Free the renderers (GL resources) and the cached model; a later :meth:`reset` builds them again."""
        self.task.close()
