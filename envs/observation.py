"""What the grasp env's wrist camera observes: the observation space, the captured images (the clean render,
the simulated depth sensor, the observation corruption) and the wrist camera's pose matrix.

Depth sensors (:data:`DEPTH_SENSORS`): ``"none"`` (the observation's depth is the renderer's exact planar
depth) or a stereo preset of :mod:`simtest.sensors.stereo` (``"d435-stereo"``, ``"passive-stereo"``: the
observation's depth is the sensed depth, metres, 0 = no measurement). The sensor's noise comes from a stream
of its own below the episode's corruption stream (:func:`sensor_stream`), so turning a sensor on draws
nothing from any other stream of the episode.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
from gymnasium import spaces

from simtest import robot
from simtest.envs.options import EpisodeConfig
from simtest.errors import ConfigError
from simtest.sensors.stereo import STEREO_PRESETS, StereoSensor

__all__ = ["Capture", "ObservationModel", "DEPTH_SENSORS", "OBSERVATION_PROFILES", "pbr_seed", "resolve_depth_sensor",
           "sensor_stream", "observation_space",
           "capture_images", "T_world_cam_matrix", "observation_dict"]

#: Depth sensor names the env takes: the exact depth, or a stereo preset.
DEPTH_SENSORS: tuple[str, ...] = ("none", *STEREO_PRESETS)

#: Spawn-key entry of the sensor's stream below the episode's corruption stream.
SENSOR_STREAM = 0x5E45
#: Spawn-key entry of the path tracer's sampler seeds below the episode's corruption stream.
PBR_STREAM = 0x9B12

#: How captures are rendered: ``fast`` (the rasterizer, no shadows), ``quality`` (the rasterizer with shadows
#: and 4x MSAA) or ``pbr`` (the path tracer for the observation's RGB; depth and masks from the rasterizer).
OBSERVATION_PROFILES: tuple[str, ...] = ("fast", "quality", "pbr")


@dataclass(frozen=True)
class Capture:
    """One wrist-camera capture of an episode, kept for writing (:mod:`simtest.envs.observation_record`).

    Attributes:
        frame: The clean render (rgb, exact planar depth in metres, segmentation).
        rgb: The observation's (H, W, 3) uint8 image, as the estimator saw it (corrupted if asked).
        depth: The observation's (H, W) float32 depth, metres (sensed or exact; 0 = no measurement).
        camera: The wrist camera at the capture (intrinsics and ``T_world_cam``, OpenCV).
        state: The scene's instances at the capture (:meth:`simtest.generators.builder.SimScene.state`).
    """

    frame: Any
    rgb: np.ndarray
    depth: np.ndarray
    camera: Any
    state: Any


def resolve_depth_sensor(name: str | None) -> StereoSensor | None:
    """The sensor of ``name`` (:data:`DEPTH_SENSORS`; ``None`` or ``"none"``: no sensor, exact depth).

    Raises:
        ConfigError: Another name (the message lists the allowed ones).
    """
    if name is None or name == "none":
        return None
    if not isinstance(name, str) or name not in STEREO_PRESETS:
        raise ConfigError(f"depth_sensor must be one of {', '.join(DEPTH_SENSORS)} (none: the exact depth; "
                          f"else a simulated stereo preset of simtest.sensors.stereo), got {name!r}")
    return STEREO_PRESETS[name]


@dataclass(frozen=True)
class ObservationModel:
    """How the wrist camera's captures become observations: the depth sensor, and the default image
    corruption and depth noise of every episode (``reset(options=...)`` may override those two per episode).

    Attributes:
        depth_sensor: ``"none"`` (the observation's depth is the exact rendered depth) or a simulated stereo
            sensor of :data:`DEPTH_SENSORS` (``"d435-stereo"``, ``"passive-stereo"``): the observation's depth is
            then the sensed depth, metres (0 = invalid); the exact depth stays beside it.
        corruption: Default corruption: a dict of :class:`~simtest.corrupt.CorruptionSpec` fields (e.g.
            ``{"weather": "fog", "severity": 4}``), or None.
        depth_noise: Default depth-noise preset of :data:`simtest.corrupt.DEPTH_PRESETS`, or None.
        profile: How captures are rendered, one of :data:`OBSERVATION_PROFILES`. With ``pbr`` only the
            captured observations are path-traced (one renderer per scene, reused across its captures; about
            1-3 s per 320 x 240 observation on two CPU cores); videos and the third-person view stay rasterized.

    Raises:
        ConfigError: An unknown sensor (listing :data:`DEPTH_SENSORS`) or profile; bad corruption values are
            named when the task takes the model.
    """

    depth_sensor: str = "none"
    corruption: Any = None
    depth_noise: str | None = None
    profile: str = "fast"

    def __post_init__(self) -> None:
        if self.profile not in OBSERVATION_PROFILES:
            raise ConfigError(f"observation profile must be one of {', '.join(OBSERVATION_PROFILES)} (fast, "
                              f"quality: rasterized; pbr: path-traced RGB), got {self.profile!r}")
        sensor = resolve_depth_sensor(self.depth_sensor)
        object.__setattr__(self, "depth_sensor", "none" if sensor is None else sensor.name)

    def sensor(self) -> StereoSensor | None:
        """The stereo sensor, or None for the exact depth."""
        return resolve_depth_sensor(self.depth_sensor)

    def episode_defaults(self, base: EpisodeConfig) -> EpisodeConfig:
        """``base`` (the episode defaults) with this model's corruption and depth noise, validated."""
        if self.corruption is None and self.depth_noise is None:
            return base
        return EpisodeConfig.build(base, {"corruption": self.corruption, "depth_noise": self.depth_noise})


def sensor_stream(episode_stream: np.random.Generator) -> np.random.Generator:
    """The sensor noise generator of an episode: the child at :data:`SENSOR_STREAM` of ``episode_stream``'s
    ``SeedSequence``, computed directly (nothing is drawn from ``episode_stream`` and its spawn count is
    untouched), so the same episode seed gives the same sensed bytes and every other stream is unchanged."""
    ss = episode_stream.bit_generator.seed_seq
    child = np.random.SeedSequence(ss.entropy, spawn_key=(*ss.spawn_key, SENSOR_STREAM), pool_size=ss.pool_size)
    return np.random.default_rng(child)


def pbr_seed(episode_stream: np.random.Generator, capture: int) -> int:
    """The path tracer's sampler seed (uint32) of capture ``capture`` of an episode: the child at
    ``(PBR_STREAM, capture)`` of ``episode_stream``'s ``SeedSequence`` (nothing is drawn from it)."""
    ss = episode_stream.bit_generator.seed_seq
    child = np.random.SeedSequence(ss.entropy, spawn_key=(*ss.spawn_key, PBR_STREAM, int(capture)),
                                   pool_size=ss.pool_size)
    return int(child.generate_state(1)[0])


def observation_space(width: int, height: int) -> spaces.Dict:
    """The env's observation space at a ``width`` x ``height`` wrist camera (see :mod:`simtest.envs.grasp_env`)."""
    h, w = int(height), int(width)
    return spaces.Dict({
        "rgb": spaces.Box(0, 255, (h, w, 3), np.uint8),
        "depth": spaces.Box(0.0, 100.0, (h, w), np.float32),
        "K": spaces.Box(-1e5, 1e5, (3, 3), np.float64),
        "T_base_cam": spaces.Box(-10.0, 10.0, (4, 4), np.float64),
        "joint_pos": spaces.Box(-2 * np.pi, 2 * np.pi, (7,), np.float64),
        "joint_vel": spaces.Box(-100.0, 100.0, (7,), np.float64),
        "gripper_width": spaces.Box(-0.01, 0.1, (1,), np.float64),
    })


def T_world_cam_matrix(data, camera_id: int) -> np.ndarray:
    """4x4 ``T_world_cam`` (OpenCV) of MuJoCo camera ``camera_id`` at ``data``'s state (the MuJoCo->OpenCV flip
    of :mod:`simtest.camera`, without building a :class:`~simtest.camera.CameraModel`)."""
    T = np.zeros((4, 4))
    x = data.cam_xmat[camera_id]
    T[:3, 0], T[:3, 1], T[:3, 2] = x[0::3], -x[1::3], -x[2::3]  # xmat @ diag(1, -1, -1)
    T[:3, 3] = data.cam_xpos[camera_id]
    T[3, 3] = 1.0
    return T


def capture_images(renderer, data, ids, K: np.ndarray, corruption, corrupt_rng: np.random.Generator,
                   sensor: StereoSensor | None = None, sensor_rng: np.random.Generator | None = None,
                   rgb_source: Callable[[], np.ndarray] | None = None):
    """One wrist-camera capture: ``(frame, rgb, depth)``.

    ``rgb_source`` (e.g. a path tracer's render of the same state) gives the RGB instead of the rasterizer;
    depth and segmentation stay the rasterizer's.

    ``frame`` is the clean render (RGB, exact depth, segmentation: the ground truth behind the observation);
    ``depth`` is the sensed depth of ``sensor`` (float32 metres, 0 = invalid) or the exact depth without one;
    ``corruption`` (a :class:`~simtest.corrupt.CorruptionSpec` or None) is applied to that RGB and depth with
    ``corrupt_rng``. The sensor restores the camera and intrinsics it moves, so ``frame`` is unaffected.
    """
    frame = renderer.render(data, ids.camera, rgb=rgb_source is None, depth=True, seg=True)
    if rgb_source is not None:
        frame = dataclasses.replace(frame, rgb=rgb_source())
    rgb, depth = frame.rgb, frame.depth
    if sensor is not None:
        depth = sensor.sense(renderer, data, ids.camera, robot.wrist_camera_model(data, ids), sensor_rng)
    if corruption is not None:
        rgb, depth, _ = corruption.apply(rgb, depth, None, corrupt_rng, K)
    return frame, np.ascontiguousarray(rgb, dtype=np.uint8), np.ascontiguousarray(depth, dtype=np.float32)


def observation_dict(images: tuple[np.ndarray, np.ndarray], K: np.ndarray, T_base_cam: np.ndarray, data,
                     ids) -> dict:
    """The observation dict of the captured ``images`` (rgb, depth) and the arm's current state."""
    return {
        "rgb": images[0],
        "depth": images[1],
        "K": K.copy(),
        "T_base_cam": T_base_cam.copy(),
        "joint_pos": data.qpos[ids.arm_qpos].copy(),
        "joint_vel": data.qvel[ids.arm_dof].copy(),
        "gripper_width": np.array([robot.gripper_width(data, ids)], dtype=np.float64),
    }
