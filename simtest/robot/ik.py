"""Inverse kinematics of the Panda's TCP: one damped least-squares solver with an iterative rule and a fast path.

:class:`DiffIK` owns the kinematics on a scratch MjData, the TCP Jacobian restricted to the arm joints, the
damped system ``J J^T + damping^2 I`` and the joint-limit clamp. On top of them it has two update rules:

* :meth:`DiffIK.solve`: iterate to a tolerance, dropping joints pinned at a limit from the step and pulling
  toward the preferred posture in the null space of the Jacobian (:func:`solve_ik`, :func:`ik_step`);
* :meth:`DiffIK.step_delta` / :meth:`DiffIK.step`: the fast path of the env's 20 Hz control, one DLS step
  (and one correcting step) with a damped null-space pull, using MuJoCo's rotation functions instead of
  SciPy; it keeps the env's work per control step a small fraction of its 25 physics steps (see
  :mod:`simtest.benchmarks.grasp`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

import simtest  # noqa: F401  (selects the GL backend before mujoco is imported)
import mujoco

from simtest.errors import ConfigError
from simtest.geometry import Pose
from simtest.robot.asset import HOME_QPOS
from simtest.robot.ids import PandaIds
from simtest.robot.poses import interpolate_pose, pose_error
from simtest.robot.state import (camera_to_tcp_target, check_arm_q, in_collision, scratch_data,
                                 tcp_pose)

__all__ = ["DiffIK", "IKResult", "UnreachableError", "ik_step", "is_reachable", "solve_ik"]


class UnreachableError(ConfigError):
    """A target pose has no inverse-kinematics solution within tolerance."""


class IKResult(NamedTuple):
    """Inverse kinematics outcome.

    Attributes:
        q: Arm joint angles (7,), rad, within the joint limits.
        success: Whether both residuals are within tolerance.
        pos_err: Position residual of the target frame, m.
        rot_err: Orientation residual (angle of the rotation error), rad.
    """

    q: np.ndarray
    success: bool
    pos_err: float
    rot_err: float


def _as_slice(idx: np.ndarray) -> slice | np.ndarray:
    """A slice for consecutive indices (cheaper to index with), the index array otherwise."""
    idx = np.asarray(idx)
    if len(idx) and np.all(np.diff(idx) == 1):
        return slice(int(idx[0]), int(idx[-1]) + 1)
    return idx


class DiffIK:
    """Damped least-squares IK on the Panda's TCP site.

    Args:
        model: The compiled model with the Panda.
        ids: The Panda's ids.
        damping: DLS damping (m, rad scale).
        posture_gain: Null-space pull toward ``posture`` per step (fraction of the offset).
        posture: Preferred configuration (7,) rad; default :data:`simtest.robot.HOME_QPOS`.
        refine: Take a second, correcting DLS step in :meth:`step_delta`.
        data: The MjData to compute kinematics in (overwritten); default a private one. Only the arm
            joints are set, so the other bodies stay where ``data`` has them.
    """

    def __init__(self, model: mujoco.MjModel, ids: PandaIds, damping: float = 0.03, posture_gain: float = 0.02,
                 posture: np.ndarray | None = None, refine: bool = True, *,
                 data: mujoco.MjData | None = None) -> None:
        self.model = model
        self.ids = ids
        self.data = mujoco.MjData(model) if data is None else data
        self.damping2 = float(damping) ** 2
        self.posture_gain = float(posture_gain)
        self.refine = bool(refine)
        self.posture = HOME_QPOS.copy() if posture is None else np.asarray(posture, dtype=np.float64)
        self.lo = ids.arm_limits[:, 0].copy()
        self.hi = ids.arm_limits[:, 1].copy()
        self._jacp = np.zeros((3, model.nv))
        self._jacr = np.zeros((3, model.nv))
        self._q_err = np.zeros(4)
        self._q_a = np.zeros(4)
        self._q_b = np.zeros(4)
        self._rv = np.zeros(3)
        self._q_target = np.zeros(4)
        self._e = np.zeros(6)
        self._J = np.zeros((6, 7))
        self._qsl = _as_slice(ids.arm_qpos)
        self._dsl = _as_slice(ids.arm_dof)

    # --- the shared core ----------------------------------------------------------------------------------
    def fk(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """TCP position (3,) m and rotation (3, 3) at arm configuration ``q`` (rad)."""
        d = self.data
        d.qpos[self.ids.arm_qpos] = q
        mujoco.mj_kinematics(self.model, d)
        s = self.ids.tcp_site
        return d.site_xpos[s].copy(), d.site_xmat[s].reshape(3, 3).copy()

    def _kinematics(self, q: np.ndarray) -> None:
        """Set the arm to ``q`` (rad) and compute the kinematics the Jacobian needs."""
        self.data.qpos[self._qsl] = q
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)

    def _jacobian(self) -> np.ndarray:
        """The TCP Jacobian (6, 7) (linear rows, then angular) over the arm joints, at the last kinematics."""
        mujoco.mj_jacSite(self.model, self.data, self._jacp, self._jacr, self.ids.tcp_site)
        J = self._J
        J[:3] = self._jacp[:, self._dsl]
        J[3:] = self._jacr[:, self._dsl]
        return J

    def _system(self, J: np.ndarray) -> np.ndarray:
        """The damped system ``J J^T + damping^2 I`` (6, 6)."""
        A = J @ J.T
        A[np.diag_indices(6)] += self.damping2
        return A

    def _clamp(self, q: np.ndarray) -> np.ndarray:
        return np.minimum(np.maximum(q, self.lo), self.hi)

    # --- iterative rule -------------------------------------------------------------------------------------
    def solve(self, target: Pose, q0: np.ndarray, *, max_iters: int, pos_tol: float, rot_tol: float,
              max_step: float) -> IKResult:
        """Iterate DLS steps from ``q0`` (rad) until the TCP is within ``pos_tol`` m / ``rot_tol`` rad of
        ``target`` (``T_world_tcp``), at most ``max_iters`` times; each step is at most ``max_step`` rad
        long (joint-space norm), clamped to the limits, and joints pinned at a limit and pushed beyond it
        are dropped from the step."""
        s = self.ids.tcp_site
        q = np.clip(q0, self.lo, self.hi)
        pos_err = rot_err = np.inf
        for _ in range(max_iters + 1):
            self._kinematics(q)
            e_p, e_r = pose_error(target, self.data.site_xpos[s], self.data.site_xmat[s].reshape(3, 3))
            pos_err, rot_err = float(np.linalg.norm(e_p)), float(np.linalg.norm(e_r))
            if pos_err <= pos_tol and rot_err <= rot_tol:
                return IKResult(q, True, pos_err, rot_err)
            dq = self._pinned_step(q, self._jacobian(), np.concatenate([e_p, e_r]))
            n = np.linalg.norm(dq)
            if n > max_step:
                dq *= max_step / n
            q = np.clip(q + dq, self.lo, self.hi)
        return IKResult(q, False, pos_err, rot_err)

    def _pinned_step(self, q: np.ndarray, J: np.ndarray, e: np.ndarray) -> np.ndarray:
        """A DLS step toward the pose error ``e`` (6,) plus the projected posture pull, re-solved without the
        joints pinned at a limit and pushed beyond it."""
        lo, hi = self.lo, self.hi
        free = np.ones(7, dtype=bool)
        for _ in range(3):
            Jf = J[:, free]
            dq_f = Jf.T @ np.linalg.solve(self._system(Jf), e)
            null = np.eye(Jf.shape[1]) - np.linalg.pinv(Jf, rcond=1e-3) @ Jf
            dq_f = dq_f + null @ (self.posture_gain * (self.posture - q)[free])
            dq = np.zeros(7)
            dq[free] = dq_f
            pinned = ((q <= lo + 1e-9) & (dq < 0)) | ((q >= hi - 1e-9) & (dq > 0))
            if not np.any(pinned & free):
                break
            free &= ~pinned
        return dq

    # --- fast path ------------------------------------------------------------------------------------------
    def _rot_error(self, R_target: np.ndarray, R: np.ndarray) -> np.ndarray:
        """World-frame rotation vector taking ``R`` to ``R_target`` (rad)."""
        mujoco.mju_mat2Quat(self._q_a, np.ascontiguousarray(R_target).reshape(9))
        mujoco.mju_mat2Quat(self._q_b, np.ascontiguousarray(R).reshape(9))
        mujoco.mju_negQuat(self._q_b, self._q_b)
        mujoco.mju_mulQuat(self._q_err, self._q_a, self._q_b)
        mujoco.mju_quat2Vel(self._rv, self._q_err, 1.0)
        return self._rv.copy()

    def step_delta(self, q: np.ndarray, dp: np.ndarray, rotvec: np.ndarray, lo: np.ndarray,
                   hi: np.ndarray) -> np.ndarray:
        """Joint targets (7,) rad that move the TCP at ``q`` by ``dp`` (m, world frame; the target is clipped
        to the box ``[lo, hi]``) and rotate it by ``rotvec`` (rad, world frame, about the TCP).

        A damped least-squares step on the TCP Jacobian at ``q`` with a null-space pull toward the ready
        posture, and (``refine``) a second step with the same Jacobian correcting the first's linearisation
        and damping error (five 2 cm steps then land within about 0.2 mm); clamped to the joint limits.
        """
        d, s = self.data, self.ids.tcp_site
        self._kinematics(q)
        pos = d.site_xpos[s]
        target = np.minimum(np.maximum(pos + dp, lo), hi)
        e = self._e
        e[:3] = target - pos
        e[3:] = rotvec
        J = self._jacobian()
        A_inv = np.linalg.inv(self._system(J))
        null = self.posture_gain * (self.posture - q)
        q1 = q + J.T @ (A_inv @ (e - J @ null)) + null
        if self.refine:
            q1 = q1 + J.T @ (A_inv @ self._residual(q1, target, rotvec))
        return self._clamp(q1)

    def _residual(self, q1: np.ndarray, target: np.ndarray, rotvec: np.ndarray) -> np.ndarray:
        """The pose error (6,) left at ``q1`` after a step toward ``target`` (m) rotated by ``rotvec`` (rad)
        from the orientation at the last kinematics: what a second (quasi-Newton) step with the same
        Jacobian corrects. Only the kinematics are recomputed."""
        m, d, s = self.model, self.data, self.ids.tcp_site
        qt, e = self._q_target, self._e
        mujoco.mju_mat2Quat(self._q_b, d.site_xmat[s])
        angle = float(np.sqrt(rotvec @ rotvec))
        if angle > 1e-12:
            mujoco.mju_axisAngle2Quat(self._q_a, rotvec / angle, angle)
            mujoco.mju_mulQuat(qt, self._q_a, self._q_b)
        else:
            qt[:] = self._q_b
        d.qpos[self._qsl] = q1
        mujoco.mj_kinematics(m, d)
        e[:3] = target - d.site_xpos[s]
        mujoco.mju_mat2Quat(self._q_b, d.site_xmat[s])
        mujoco.mju_negQuat(self._q_b, self._q_b)
        mujoco.mju_mulQuat(self._q_err, qt, self._q_b)
        mujoco.mju_quat2Vel(self._rv, self._q_err, 1.0)
        e[3:] = self._rv
        return e

    def step(self, q: np.ndarray, target_pos: np.ndarray, target_R: np.ndarray, max_dist: float,
             max_angle: float) -> np.ndarray:
        """Joint targets (7,) rad moving the TCP from its pose at ``q`` toward the target.

        The step is limited to ``max_dist`` metres and ``max_angle`` radians (scaled together, so the TCP
        moves along the straight line and the slerp toward the target) and clamped to the joint limits.
        """
        d, s = self.data, self.ids.tcp_site
        q = np.asarray(q, dtype=np.float64)
        self._kinematics(q)
        e_p = np.asarray(target_pos, dtype=np.float64) - d.site_xpos[s]
        e_r = self._rot_error(target_R, d.site_xmat[s].reshape(3, 3))
        dist, ang = float(np.sqrt(e_p @ e_p)), float(np.sqrt(e_r @ e_r))
        scale = 1.0
        if dist > max_dist:
            scale = max_dist / dist
        if ang > max_angle:
            scale = min(scale, max_angle / ang)
        e = np.concatenate([e_p, e_r]) * scale
        J = self._jacobian()
        B = np.empty((6, 8))
        B[:, 0] = e
        B[:, 1:] = J
        X = np.linalg.solve(self._system(J), B)  # (J J^T + l^2 I)^-1 [e, J]
        null = self.posture_gain * (self.posture - q)
        dq = J.T @ (X[:, 0] - X[:, 1:] @ null) + null
        return self._clamp(q + dq)


def solve_ik(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    ids: PandaIds,
    target: Pose,
    q_init: np.ndarray | None = None,
    *,
    frame: str = "tcp",
    pos_tol: float = 5e-4,
    rot_tol: float = np.deg2rad(0.3),
    max_iters: int = 150,
    damping: float = 0.03,
    posture: np.ndarray | None = None,
    posture_gain: float = 0.05,
    restarts: int = 4,
    rng: np.random.Generator | None = None,
) -> IKResult:
    """Joint angles that put the TCP (or the wrist camera) at ``target``.

    :meth:`DiffIK.solve`: damped least squares on the site Jacobian, with joints clamped to their limits
    (joints pinned at a limit are dropped from the step) and a null-space pull toward ``posture``. Iterates
    on a scratch MjData: ``data`` is only read (the non-arm state, e.g. a free object's pose, is irrelevant
    to the arm).
    If the solve from ``q_init`` fails it is retried from ``posture`` and then, if ``rng`` is given, from
    ``restarts`` random configurations.

    Args:
        model: Compiled model containing the Panda.
        data: Current state; read only.
        ids: The Panda's ids (:meth:`PandaHandles.bind`).
        target: Desired ``T_world_tcp`` (``frame="tcp"``) or ``T_world_cam`` of the wrist camera in OpenCV
            convention (``frame="camera"``), m.
        q_init: Start configuration (7,) rad; default the current arm configuration in ``data``.
        frame: ``"tcp"`` or ``"camera"``.
        pos_tol: Position tolerance, m.
        rot_tol: Orientation tolerance, rad.
        max_iters: Iterations per attempt.
        damping: DLS damping (m, rad scale).
        posture: Preferred configuration (7,) rad; default :data:`HOME_QPOS`.
        posture_gain: Null-space pull toward ``posture`` per iteration (fraction of the offset).
        restarts: Random restarts (only with ``rng``).
        rng: Generator for random restarts; ``None`` disables them.

    Returns:
        The best :class:`IKResult` found: ``(q, success, pos_err m, rot_err rad)``.
    """
    if frame not in ("tcp", "camera"):
        raise ConfigError(f"frame must be 'tcp' or 'camera', got {frame!r}")
    if frame == "camera":
        target = camera_to_tcp_target(target)
    posture = HOME_QPOS if posture is None else np.asarray(posture, dtype=np.float64)
    q0 = ids.arm_q(data) if q_init is None else np.asarray(q_init, dtype=np.float64)
    check_arm_q(q0, ids)
    solver = DiffIK(model, ids, damping, posture_gain, posture, data=scratch_data(model, data))
    starts = [q0, posture]
    if rng is not None:
        lo, hi = ids.arm_limits[:, 0], ids.arm_limits[:, 1]
        starts += [rng.uniform(lo, hi) for _ in range(restarts)]
    best: IKResult | None = None
    for start in starts:
        res = solver.solve(target, start, max_iters=max_iters, pos_tol=pos_tol, rot_tol=rot_tol,
                           max_step=0.5)
        if res.success:
            return res
        if best is None or res.pos_err + 0.1 * res.rot_err < best.pos_err + 0.1 * best.rot_err:
            best = res
    assert best is not None
    return best


def is_reachable(model: mujoco.MjModel, data: mujoco.MjData, ids: PandaIds, target: Pose,
                 q_init: np.ndarray | None = None, *, frame: str = "tcp", check_collisions: bool = False,
                 rng: np.random.Generator | None = None, **ik_kwargs) -> bool:
    """Whether IK reaches ``target`` (see :func:`solve_ik` for the arguments and tolerances).

    With ``check_collisions`` the solution must also be free of contacts between the robot and anything
    else (other robot links excluded) at the current state of the other bodies.
    """
    res = solve_ik(model, data, ids, target, q_init, frame=frame, rng=rng, **ik_kwargs)
    if not res.success:
        return False
    return not check_collisions or not in_collision(model, data, ids, res.q)


def ik_step(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    ids: PandaIds,
    target_pose: Pose,
    dt: float,
    *,
    q_ref: np.ndarray | None = None,
    max_lin_speed: float = 0.3,
    max_ang_speed: float = 1.5,
    iters: int = 3,
    damping: float = 0.03,
    posture_gain: float = 0.02,
) -> np.ndarray:
    """One differential-IK control step toward ``target_pose`` (``T_world_tcp``, m).

    The TCP is moved from its pose at ``q_ref`` toward the target by at most ``max_lin_speed * dt`` (m)
    and ``max_ang_speed * dt`` (rad), and the joint targets for that intermediate pose are returned
    (a few :meth:`DiffIK.solve` iterations, clamped to the joint limits). Feed them to the arm position actuators
    (``data.ctrl[ids.arm_actuators]``) and pass them back as ``q_ref`` next step to integrate the command
    rather than the lagging measured state.

    Args:
        model, data, ids: The model, its state (read only) and the Panda's ids.
        target_pose: Goal ``T_world_tcp``.
        dt: Control period, s (e.g. 0.05 for 20 Hz).
        q_ref: Configuration (7,) rad to step from; default the measured arm configuration.
        max_lin_speed: TCP speed limit, m/s.
        max_ang_speed: TCP angular speed limit, rad/s.

    Returns:
        Arm joint targets (7,), rad.
    """
    if not dt > 0:
        raise ConfigError(f"dt must be > 0 s, got {dt!r}")
    q = ids.arm_q(data) if q_ref is None else np.asarray(q_ref, dtype=np.float64)
    check_arm_q(q, ids)
    scratch = scratch_data(model, data)
    scratch.qpos[ids.arm_qpos] = q
    mujoco.mj_kinematics(model, scratch)
    current = tcp_pose(scratch, ids)
    waypoint = interpolate_pose(current, target_pose, max_lin_speed * dt, max_ang_speed * dt)
    solver = DiffIK(model, ids, damping, posture_gain, HOME_QPOS, data=scratch)
    return solver.solve(waypoint, q, max_iters=iters, pos_tol=1e-5, rot_tol=1e-4,
                        max_step=max(max_ang_speed * dt * 4.0, 0.05)).q
