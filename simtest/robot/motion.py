"""Scripted arm motion: minimum-jerk timing, servo lead, and :func:`move_to` (Cartesian or joint-space paths).

Every scripted motion of the Panda (the scripted grasp of :mod:`simtest.robot.grasp`, the closed-loop episodes
of :mod:`simtest.envs.episode`) times its paths with :func:`min_jerk` and feeds the position servos a velocity
feed-forward of :func:`simtest.robot.state.servo_lead`.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

import simtest  # noqa: F401  (selects the GL backend before mujoco is imported)
import mujoco

from simtest.errors import ConfigError
from simtest.geometry import Pose
from simtest.robot.ids import PandaIds
from simtest.robot.ik import UnreachableError, ik_step, solve_ik
from simtest.robot.poses import lerp_pose, pose_error
from simtest.robot.state import check_arm_q, scratch_data, servo_lead, set_gripper, tcp_pose

__all__ = ["min_jerk", "move_to"]

Callback = Callable[[mujoco.MjModel, mujoco.MjData], None]


def min_jerk(s: float) -> float:
    """Minimum-jerk timing: the fraction of the path covered at time fraction ``s`` in [0, 1]
    (``10 s^3 - 15 s^4 + 6 s^5``; zero velocity and acceleration at both ends, peak speed 1.875x the mean)."""
    return s ** 3 * (10 - 15 * s + 6 * s * s)


def move_to(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    ids: PandaIds,
    target: Pose,
    duration: float,
    *,
    path: str = "cartesian",
    control_dt: float = 0.05,
    settle: float = 1.0,
    settle_tol: tuple[float, float] = (1e-3, np.deg2rad(0.5)),
    gripper: float | None = None,
    q_ref: np.ndarray | None = None,
    callback: Callback | None = None,
) -> np.ndarray:
    """Move the TCP to ``target`` (``T_world_tcp``, m) in ``duration`` seconds, then let it settle.

    The goal configuration is solved first (IK from the current command). With ``path="cartesian"`` the
    TCP follows a straight line (position) and a slerp (orientation) with minimum-jerk timing, re-solved
    with :func:`ik_step` every ``control_dt`` seconds; with ``path="joint"`` the joint targets move along
    a minimum-jerk straight line in joint space (for large free motions and reorientations). The servo
    targets get a velocity feed-forward ``(damping / kp) * qdot`` that cancels the lag of the position
    servos against the joint damping. The physics runs at the model's timestep in between. Afterwards
    the goal is held until the TCP is within ``settle_tol`` of the target and at rest, for at most
    ``settle`` seconds.

    Args:
        model, data, ids: Model, state (advanced in place) and the Panda's ids.
        target: Goal TCP pose in the world.
        duration: Motion time, s.
        path: ``"cartesian"`` or ``"joint"``.
        control_dt: Control period, s (0.05 = 20 Hz).
        settle: Longest time holding the goal after the motion, s.
        settle_tol: (position m, angle rad) at which settling stops early.
        gripper: If given, the pad gap command (m) during the motion; otherwise unchanged.
        q_ref: Arm command (7,) rad to start from; default the measured arm configuration. Pass the
            value returned by the previous call to chain motions without re-basing on the servo lag.
        callback: Called as ``callback(model, data)`` after every control period.

    Returns:
        The final arm command (7,), rad.

    Raises:
        ConfigError: On a bad ``path`` or ``duration``.
        UnreachableError: If IK cannot reach ``target`` (names the residual); nothing was simulated.
    """
    if path not in ("cartesian", "joint"):
        raise ConfigError(f"path must be 'cartesian' or 'joint', got {path!r}")
    if not duration >= 0:
        raise ConfigError(f"duration must be >= 0 s, got {duration!r}")
    q_cmd = ids.arm_q(data) if q_ref is None else np.asarray(q_ref, dtype=np.float64)
    check_arm_q(q_cmd, ids)
    goal = solve_ik(model, data, ids, target, q_cmd)
    if not goal.success:
        raise UnreachableError(
            f"TCP target at {np.round(target.t, 4).tolist()} m is out of reach: IK residual "
            f"{goal.pos_err * 1000:.1f} mm / {np.rad2deg(goal.rot_err):.2f} deg (tolerance 0.5 mm / 0.3 deg)")
    if gripper is not None:
        set_gripper(data, ids, gripper)
    n_sub = max(1, int(round(control_dt / model.opt.timestep)))
    q_cmd = _follow_path(model, data, ids, target, goal.q if path == "joint" else None, q_cmd, duration,
                         control_dt, n_sub, callback)
    if path == "cartesian":  # land exactly on the goal, from the solution tracked along the path
        final = solve_ik(model, data, ids, target, q_cmd)
        q_cmd = final.q if final.success else goal.q
    else:
        q_cmd = goal.q
    data.ctrl[ids.arm_actuators] = q_cmd
    _settle(model, data, ids, target, int(round(settle / control_dt)), settle_tol, n_sub, callback)
    return q_cmd


def _follow_path(model: mujoco.MjModel, data: mujoco.MjData, ids: PandaIds, target: Pose,
                 q_goal: np.ndarray | None, q_cmd: np.ndarray, duration: float, control_dt: float, n_sub: int,
                 callback: Callback | None) -> np.ndarray:
    """Drive the arm servos from the command ``q_cmd`` (rad) along a minimum-jerk path for ``duration`` s:
    a straight joint-space line to ``q_goal`` (rad) if given, else the TCP's straight line and slerp to
    ``target`` re-solved with :func:`ik_step` every ``control_dt`` s. Returns the last command (7,), rad."""
    scratch = scratch_data(model, data)
    scratch.qpos[ids.arm_qpos] = q_cmd
    mujoco.mj_kinematics(model, scratch)
    start = tcp_pose(scratch, ids)
    q_start = q_cmd.copy()
    n_ctrl = max(1, int(round(duration / control_dt)))
    lead = servo_lead(model, ids)
    for k in range(1, n_ctrl + 1):
        s = min_jerk(k / n_ctrl)
        q_prev = q_cmd
        if q_goal is not None:
            q_cmd = q_start + s * (q_goal - q_start)
        else:
            q_cmd = ik_step(model, data, ids, lerp_pose(start, target, s), control_dt, q_ref=q_cmd,
                            max_lin_speed=np.inf, max_ang_speed=np.inf)
        # Velocity feed-forward: a position servo against joint damping b lags by (b / kp) * qdot.
        data.ctrl[ids.arm_actuators] = q_cmd + lead * (q_cmd - q_prev) / control_dt
        mujoco.mj_step(model, data, n_sub)
        if callback is not None:
            callback(model, data)
    return q_cmd


def _settle(model: mujoco.MjModel, data: mujoco.MjData, ids: PandaIds, target: Pose, n_ctrl: int,
            settle_tol: tuple[float, float], n_sub: int, callback: Callback | None) -> None:
    """Hold the current command for at most ``n_ctrl`` control periods of ``n_sub`` physics steps, until the
    TCP is within ``settle_tol`` (m, rad) of ``target`` and the arm joints move slower than 0.02 rad/s."""
    for _ in range(n_ctrl):
        e_p, e_r = pose_error(target, data.site_xpos[ids.tcp_site], data.site_xmat[ids.tcp_site].reshape(3, 3))
        if (np.linalg.norm(e_p) <= settle_tol[0] and np.linalg.norm(e_r) <= settle_tol[1]
                and np.abs(data.qvel[ids.arm_dof]).max() < 0.02):
            break
        mujoco.mj_step(model, data, n_sub)
        if callback is not None:
            callback(model, data)
