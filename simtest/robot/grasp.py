"""The scripted grasp: pre-grasp -> straight approach -> close -> straight lift -> hold.

The phases after the pre-grasp pose (:func:`approach`, :func:`close_and_wait`, :func:`lift_to`) are shared by
:func:`grasp_and_lift` (a grasp pose in any MuJoCo scene with the Panda, success = the object rose) and the
closed-loop episodes of :mod:`simtest.envs.episode` (a planned grasp in the grasp env, with collision
monitoring and per-period hold checks); both time their motions with :func:`simtest.robot.motion.min_jerk`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

import simtest  # noqa: F401  (selects the GL backend before mujoco is imported)
import mujoco

from simtest.errors import ConfigError
from simtest.geometry import Pose
from simtest.robot.asset import GRIPPER_OPEN
from simtest.robot.ids import PandaIds
from simtest.robot.ik import UnreachableError, solve_ik
from simtest.robot.motion import Callback, move_to
from simtest.robot.state import close_gripper, gripper_width, step_for, tcp_pose

__all__ = ["GraspResult", "approach", "close_and_wait", "grasp_and_lift", "lift_to", "symmetric_grasp"]


@dataclass(frozen=True)
class GraspResult:
    """Outcome of :func:`grasp_and_lift`.

    Attributes:
        success: The object is at least ``success_height`` above its resting height after the hold.
        reason: ``"ok"``, ``"unreachable"`` (IK failed for a waypoint), ``"empty"`` (the gripper closed on
            nothing) or ``"dropped"`` (the object is not high enough after the hold).
        object_rise: Height gain of the object after the hold, m.
        gripper_width: Gap between the finger pads after the hold, m.
        sim_time: Simulated time spent, s.
    """

    success: bool
    reason: str
    object_rise: float
    gripper_width: float
    sim_time: float

    def __bool__(self) -> bool:
        return self.success


def symmetric_grasp(grasp_pose_world: Pose) -> Pose:
    """The same grasp with the fingers swapped: rotated by pi about the approach axis z.

    The Panda gripper is symmetric under this rotation, so both poses hold the object identically.
    """
    return grasp_pose_world @ Pose(np.diag([-1.0, -1.0, 1.0]), np.zeros(3))


def approach(model: mujoco.MjModel, data: mujoco.MjData, ids: PandaIds, grasp: Pose, distance: float,
             speed: float, q_ref: np.ndarray, *, settle: float = 1.0, callback: Callback | None = None) -> np.ndarray:
    """Straight approach of the TCP over ``distance`` m to ``grasp`` at a mean ``speed`` m/s (at least 1 s).

    Returns the final arm command (7,), rad (see :func:`simtest.robot.motion.move_to`).
    """
    return move_to(model, data, ids, grasp, max(1.0, distance / speed), q_ref=q_ref, settle=settle,
                   callback=callback)


def close_and_wait(model: mujoco.MjModel, data: mujoco.MjData, ids: PandaIds, close_time: float, *,
                   dt: float = 0.05, advance: Callable[[float], None] | None = None,
                   callback: Callback | None = None) -> None:
    """Command the gripper closed and run ``close_time`` s in periods of ``dt`` s, calling ``callback`` after
    each. ``advance(dt)`` runs the physics (default :func:`simtest.robot.state.step_for`)."""
    close_gripper(data, ids)
    for _ in range(int(round(close_time / dt))):
        if advance is None:
            step_for(model, data, dt)
        else:
            advance(dt)
        if callback is not None:
            callback(model, data)


def lift_to(model: mujoco.MjModel, data: mujoco.MjData, ids: PandaIds, lifted: Pose, height: float, speed: float,
            q_ref: np.ndarray, *, callback: Callback | None = None) -> np.ndarray:
    """Straight lift of the TCP by ``height`` m to ``lifted`` at a mean ``speed`` m/s (at least 1 s), without
    settling at the top. Returns the final arm command (7,), rad."""
    return move_to(model, data, ids, lifted, max(1.0, height / speed), settle=0.0, q_ref=q_ref, callback=callback)


def grasp_and_lift(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    ids: PandaIds,
    grasp_pose_world: Pose,
    object_body: int | str,
    lift: float = 0.15,
    *,
    pregrasp: float = 0.10,
    hold: float = 1.0,
    success_height: float = 0.10,
    speed: float = 0.25,
    approach_speed: float = 0.08,
    joint_speed: float = 1.0,
    close_time: float = 0.6,
    allow_flip: bool = True,
    callback: Callback | None = None,
) -> GraspResult:
    """Scripted grasp: pre-grasp -> approach -> close -> lift -> hold, then check the object is held.

    The grasp pose follows the gripper convention of :mod:`simtest.robot`: origin at the TCP (centre between
    the distal finger pads), z = approach direction (palm toward object), y = finger closing axis,
    x = y cross z. The pre-grasp pose is ``pregrasp`` metres back along -z from the grasp pose and is
    reached by a joint-space motion with the gripper open; the approach is a straight line; the lift
    moves the TCP straight up (world +z) by ``lift`` metres keeping the orientation.

    Args:
        model, data, ids: Model, state (advanced in place) and the Panda's ids.
        grasp_pose_world: ``T_world_grasp`` (m).
        object_body: Body id or name of the object to lift.
        lift: Lift height, m.
        pregrasp: Stand-off distance along the approach axis, m.
        hold: Hold time at the top, s.
        success_height: Minimum rise of the object (its body origin) after the hold, m.
        speed: Nominal TCP speed of the free motion to the pre-grasp pose, m/s.
        approach_speed: Mean TCP speed of the straight approach and of the lift, m/s (slow, so the
            TCP stays within about 2 mm of the straight line).
        joint_speed: Largest joint speed of the free motion to the pre-grasp pose, rad/s.
        close_time: Time given to the gripper to close, s.
        allow_flip: Execute whichever of the grasp and its :func:`symmetric_grasp` twin is closer to the
            current arm configuration (the gripper is symmetric under a half turn about z).
        callback: Called as ``callback(model, data)`` after every control period (e.g. to record frames).

    Returns:
        A :class:`GraspResult` (truthy on success).
    """
    object_body = _body_id(model, object_body)
    t0 = data.time
    mujoco.mj_forward(model, data)
    rest_z = float(data.xpos[object_body][2])
    if allow_flip:
        grasp_pose_world = _choose_grasp(model, data, ids, grasp_pose_world, pregrasp)

    def _result(success: bool, reason: str) -> GraspResult:
        mujoco.mj_forward(model, data)
        return GraspResult(success, reason, float(data.xpos[object_body][2] - rest_z),
                           gripper_width(data, ids), float(data.time - t0))

    try:
        if not _execute(model, data, ids, grasp_pose_world, lift, pregrasp, hold, speed, approach_speed,
                        joint_speed, close_time, callback):
            return _result(False, "unreachable")
    except UnreachableError:
        return _result(False, "unreachable")
    mujoco.mj_forward(model, data)
    rise = float(data.xpos[object_body][2] - rest_z)
    if rise >= success_height:
        return _result(True, "ok")
    if gripper_width(data, ids) < 0.002:
        return _result(False, "empty")
    return _result(False, "dropped")


def _body_id(model: mujoco.MjModel, body: int | str) -> int:
    """The id of a body given by id or name (not the world body)."""
    if isinstance(body, str):
        name = body
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
        if body < 0:
            raise ConfigError(f"model has no body named {name!r}")
    if not 0 < body < model.nbody:
        raise ConfigError(f"object_body must be a body id in [1, {model.nbody - 1}], got {body!r}")
    return body


def _execute(model: mujoco.MjModel, data: mujoco.MjData, ids: PandaIds, grasp: Pose, lift: float,
             pregrasp: float, hold: float, speed: float, approach_speed: float, joint_speed: float,
             close_time: float, callback: Callback | None) -> bool:
    """The motions of :func:`grasp_and_lift`; ``False`` if a waypoint is out of reach before the approach."""
    pre = Pose(grasp.R, grasp.t - pregrasp * grasp.R[:, 2])
    lifted = Pose(grasp.R, grasp.t + np.array([0.0, 0.0, lift]))
    q_now = ids.arm_q(data)
    pre_ik = solve_ik(model, data, ids, pre, q_now)
    if not pre_ik.success:
        return False
    free_time = max(max(0.5, float(np.linalg.norm(pre.t - tcp_pose(data, ids).t)) / speed),
                    float(np.abs(pre_ik.q - q_now).max()) / joint_speed)
    q = move_to(model, data, ids, pre, free_time, path="joint", gripper=GRIPPER_OPEN, q_ref=q_now,
                callback=callback)
    for pose in (grasp, lifted):  # reachability of the rest, before touching anything
        if not solve_ik(model, data, ids, pose, q).success:
            return False
    q = approach(model, data, ids, grasp, pregrasp, approach_speed, q, callback=callback)
    close_and_wait(model, data, ids, close_time, callback=callback)
    lift_to(model, data, ids, lifted, lift, approach_speed, q, callback=callback)
    for _ in range(int(round(hold / 0.05))):
        step_for(model, data, 0.05)
        if callback is not None:
            callback(model, data)
    return True


def _choose_grasp(model: mujoco.MjModel, data: mujoco.MjData, ids: PandaIds, grasp: Pose,
                  pregrasp: float) -> Pose:
    """Of ``grasp`` and its symmetric twin, the one whose pre-grasp needs the smallest joint motion."""
    q_now = ids.arm_q(data)
    best, best_cost = grasp, np.inf
    for cand in (grasp, symmetric_grasp(grasp)):
        pre = Pose(cand.R, cand.t - pregrasp * cand.R[:, 2])
        res = solve_ik(model, data, ids, pre, q_now)
        if res.success:
            cost = float(np.abs(res.q - q_now).max())
            if cost < best_cost:
                best, best_cost = cand, cost
    return best
