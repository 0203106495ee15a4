"""State of an attached Panda: TCP and wrist-camera poses, gripper commands, arm resets, stepping, and the
per-model scratch state that IK and collision checks work on (``data`` itself is never touched by them)."""

from __future__ import annotations

import numpy as np

import simtest  # noqa: F401  (selects the GL backend before mujoco is imported)
import mujoco

from simtest.camera import CameraModel
from simtest.errors import ConfigError
from simtest.geometry import Pose
from simtest.robot.asset import GRIPPER_CLOSED, GRIPPER_OPEN, HOME_QPOS, T_TCP_CAM
from simtest.robot.ids import PandaIds

__all__ = ["camera_to_tcp_target", "check_arm_q", "close_gripper", "gripper_width", "in_collision",
           "open_gripper", "release_scratch", "reset_arm", "scratch_data", "servo_lead", "set_gripper", "step_for", "tcp_pose",
           "wrist_camera_model"]


def tcp_pose(data: mujoco.MjData, ids: PandaIds) -> Pose:
    """``T_world_tcp`` from the last kinematics pass on ``data`` (m)."""
    return Pose(data.site_xmat[ids.tcp_site].reshape(3, 3), data.site_xpos[ids.tcp_site])


def wrist_camera_model(data: mujoco.MjData, ids: PandaIds) -> CameraModel:
    """The wrist camera's :class:`CameraModel` with its world pose from the last forward pass.

    ``data.cam_xpos`` / ``cam_xmat`` are filled by ``mj_forward`` / ``mj_step`` (or ``mj_kinematics``
    followed by ``mj_camlight``).

    Raises:
        ConfigError: If the Panda was attached without a wrist camera.
    """
    if ids.camera < 0 or ids.wrist_camera is None:
        raise ConfigError("this Panda has no wrist camera (attach_panda(..., wrist_camera=None))")
    cam = ids.wrist_camera
    return CameraModel.from_mujoco(data.cam_xpos[ids.camera], data.cam_xmat[ids.camera], cam.K, cam.width,
                                   cam.height)


def camera_to_tcp_target(T_world_cam: Pose) -> Pose:
    """The TCP pose that puts the wrist camera (OpenCV frame) at ``T_world_cam``."""
    return T_world_cam @ T_TCP_CAM.inverse()


def gripper_width(data: mujoco.MjData, ids: PandaIds) -> float:
    """Current gap between the finger pads, m (0 = closed, 0.08 = fully open)."""
    return float(data.qpos[ids.finger_qpos].sum())


def set_gripper(data: mujoco.MjData, ids: PandaIds, width: float) -> None:
    """Command the pad gap, m, clipped to [:data:`GRIPPER_CLOSED`, :data:`GRIPPER_OPEN`].

    Commanding a gap smaller than an object squeezes it with up to :data:`GRIPPER_FORCE` N per finger.
    """
    data.ctrl[ids.gripper_actuator] = float(np.clip(width, GRIPPER_CLOSED, GRIPPER_OPEN))


def open_gripper(data: mujoco.MjData, ids: PandaIds) -> None:
    """Command the gripper fully open (0.08 m gap)."""
    set_gripper(data, ids, GRIPPER_OPEN)


def close_gripper(data: mujoco.MjData, ids: PandaIds) -> None:
    """Command the gripper closed (gap 0): grips any object between the pads at the force limit."""
    set_gripper(data, ids, GRIPPER_CLOSED)


def reset_arm(model: mujoco.MjModel, data: mujoco.MjData, ids: PandaIds,
              q: np.ndarray | None = None, gripper: float = GRIPPER_OPEN) -> None:
    """Teleport the arm to ``q`` (rad, default :data:`HOME_QPOS`) at rest, with matching commands.

    Also sets the fingers to the gap ``gripper`` (m) and runs ``mj_forward``.
    """
    q = HOME_QPOS if q is None else np.asarray(q, dtype=np.float64)
    check_arm_q(q, ids)
    data.qpos[ids.arm_qpos] = q
    data.qvel[ids.arm_dof] = 0.0
    data.ctrl[ids.arm_actuators] = q
    half = float(np.clip(gripper, GRIPPER_CLOSED, GRIPPER_OPEN)) / 2.0
    data.qpos[ids.finger_qpos] = half
    data.qvel[ids.finger_dof] = 0.0
    set_gripper(data, ids, gripper)
    mujoco.mj_forward(model, data)


def check_arm_q(q: np.ndarray, ids: PandaIds) -> None:
    """Raise :class:`ConfigError` unless ``q`` is 7 finite joint angles (rad)."""
    if q.shape != (7,) or not np.all(np.isfinite(q)):
        raise ConfigError(f"arm configuration must be 7 finite joint angles (rad), got {q!r}")


def step_for(model: mujoco.MjModel, data: mujoco.MjData, duration: float) -> None:
    """Advance the physics by ``duration`` seconds (rounded to whole timesteps) with the current controls."""
    n = max(0, int(round(duration / model.opt.timestep)))
    mujoco.mj_step(model, data, n)


#: The scratch MjData of the last model IK ran on. One entry only: an MjData keeps its model alive, so every
#: cached entry pins a whole compiled model (tens of MB with its meshes) in memory.
_SCRATCH: dict[int, tuple[mujoco.MjModel, mujoco.MjData]] = {}


def release_scratch() -> None:
    """Drop the IK scratch data (and with it the reference to its model), e.g. before the model is freed."""
    _SCRATCH.clear()


def scratch_data(model: mujoco.MjModel, data: mujoco.MjData) -> mujoco.MjData:
    """A scratch MjData for ``model`` (cached for the last model) holding ``data``'s current state."""
    entry = _SCRATCH.get(id(model))
    if entry is None or entry[0] is not model:
        _SCRATCH.clear()
        entry = (model, mujoco.MjData(model))
        _SCRATCH[id(model)] = entry
    scratch = entry[1]
    scratch.qpos[:] = data.qpos
    if model.nmocap:
        scratch.mocap_pos[:] = data.mocap_pos
        scratch.mocap_quat[:] = data.mocap_quat
    return scratch


def in_collision(model: mujoco.MjModel, data: mujoco.MjData, ids: PandaIds, q: np.ndarray) -> bool:
    """Whether the robot at ``q`` touches anything (including itself) at the current state of the rest."""
    scratch = scratch_data(model, data)
    scratch.qpos[ids.arm_qpos] = q
    mujoco.mj_fwdPosition(model, scratch)
    robot = set(ids.robot_geoms.tolist())
    for c in scratch.contact[: scratch.ncon]:
        if c.dist < 0.0 and (c.geom1 in robot or c.geom2 in robot):
            return True
    return False


def servo_lead(model: mujoco.MjModel, ids: PandaIds) -> np.ndarray:
    """Per arm joint, the lag time (s) of a position servo against joint damping: ``damping / kp``."""
    kp = model.actuator_gainprm[ids.arm_actuators, 0]
    return model.dof_damping[ids.arm_dof] / np.maximum(kp, 1e-9)
